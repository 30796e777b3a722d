"""build_model(scenario) -> Model: grid, yarn segments, masses, charges, moduli, body."""

from __future__ import annotations

import logging
import os

import numpy as np

from emfabric._kernels.coils import WAVE_CONSTANT, WAVE_DAMPED_SINE, WAVE_RAMP, WAVE_TABLE
from emfabric._kernels.records import (
    BODY_R0,
    BODY_ROWS,
    BODY_X,
    MATERIAL_FUNG,
    MATERIAL_KSV,
    REGION_HALF_SPACE,
    REGION_UNIFORM,
    SHAPE_SPHERE,
    Body,
    Contact,
    Field,
    Material,
    Nodes,
    Physics,
    Yarns,
)
from emfabric._kernels.shapes import SHAPES
from emfabric.geometry import geometry_of, shape_frame
from emfabric.model import Model
from emfabric.scenario import Scenario, ScenarioError
from emfabric.source_grid import build_source_grid

log = logging.getLogger(__name__)


def grid_coordinates(n: int, size: float) -> np.ndarray:
    """Node coordinates along one axis, exactly mirror-symmetric about 0 [m], shape (n,)."""
    h = size / (n - 1)
    # (i - (n-1)/2) is an exact half-integer, so x[i] == -x[n-1-i] bit for bit
    return h * (np.arange(n, dtype=np.float64) - 0.5 * (n - 1))


BYTES_PER_NODE = 1200
"""Memory a run needs per fabric node [B], rounded up from `python benchmarks/bench.py` (d):
model, two states and the step workspace take ~500 B per node; snapshots waiting to be written,
the threaded kernel's row buffers and NumPy temporaries while building take the rest."""


def memory_needed(scenario: Scenario) -> int:
    """Bytes a run of this scenario needs (estimate, before anything is allocated)."""
    nx, ny = scenario.fabric.nodes
    return BYTES_PER_NODE * nx * ny


def memory_available() -> int | None:
    """Physical memory of this machine [B] (None where the OS does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(scenario: Scenario) -> None:
    """Refuse a grid that cannot fit in this machine's memory, before allocating it."""
    need = memory_needed(scenario)
    have = memory_available()
    if have is not None and need > 0.8 * have:
        nx, ny = scenario.fabric.nodes
        raise ScenarioError(
            f"fabric.nodes = [{nx}, {ny}]: a run needs about {need / 2**30:.3g} GiB "
            f"({BYTES_PER_NODE} B per node), this machine has {have / 2**30:.3g} GiB; allowed: "
            f"grids up to about {int((0.8 * have / BYTES_PER_NODE) ** 0.5)} × "
            f"{int((0.8 * have / BYTES_PER_NODE) ** 0.5)} nodes here"
        )


def build_model(scenario: Scenario) -> Model:
    """Everything a step reads, from a validated scenario."""
    check_memory(scenario)
    fab = scenario.fabric
    nx, ny = fab.nodes
    lx, ly = fab.size
    n = nx * ny
    xs, ys = grid_coordinates(nx, lx), grid_coordinates(ny, ly)
    node_x0 = np.zeros((3, n))
    node_x0[0] = np.tile(xs, ny)
    node_x0[1] = np.repeat(ys, nx)

    # lumped mass: total mass / number of nodes (paper 2.2); charge per node (2.5)
    mass = fab.areal_density * lx * ly / n
    area = np.pi * fab.yarn_radius**2
    charge = fab.charge_per_node
    if fab.rescale:
        # same fabric at another resolution: stiffness per unit width and q/m kept
        rnx, rny = fab.reference_nodes
        ref_h = 0.5 * (lx / (rnx - 1) + ly / (rny - 1))
        h = 0.5 * (lx / (nx - 1) + ly / (ny - 1))
        area *= h / ref_h
        charge *= mass / (fab.areal_density * lx * ly / (rnx * rny))
    node_mass = np.full(n, mass)
    node_inv_mass = np.full(n, 1.0 / mass)
    if fab.edges == "clamped":
        grid = node_inv_mass.reshape(ny, nx)
        grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = 0.0
    node_charge = np.full(n, charge)

    # warp (x-neighbours) then fill (y-neighbours)
    ii, jj = np.meshgrid(np.arange(nx - 1), np.arange(ny), indexing="xy")
    warp_a = (jj * nx + ii).ravel()
    ii, jj = np.meshgrid(np.arange(nx), np.arange(ny - 1), indexing="xy")
    fill_a = (jj * nx + ii).ravel()
    seg_nodes = np.concatenate(
        [np.stack([warp_a, warp_a + 1], axis=1), np.stack([fill_a, fill_a + nx], axis=1)]
    ).astype(np.int64)
    seg_rest = np.concatenate(
        [np.full(warp_a.size, lx / (nx - 1)), np.full(fill_a.size, ly / (ny - 1))]
    )

    mat = fab.material
    base = mat.youngs_modulus if mat.model == "kirchhoff-saint-venant" else mat.c
    seg_modulus = base * _modulus_factors(seg_nodes.shape[0], mat.modulus_cv, mat.seed)

    node_v0 = np.zeros((3, n))
    free = node_inv_mass > 0
    node_v0[:, free] = np.asarray(fab.velocity, dtype=float)[:, None]

    pr = scenario.projectile
    has_body = pr.shape in SHAPES
    geo = geometry_of(pr)
    body_v0 = np.asarray(pr.velocity, dtype=float)
    speed = np.linalg.norm(body_v0)
    flight = body_v0 / speed if speed > 0 else np.array([0.0, 0.0, -1.0])
    # the nose: the shape's axis at t = 0 (default: the flight direction); its leading surface
    # point is the tilt and yaw marker (5.2)
    lead = flight
    if pr.axis is not None:
        axis = np.asarray(pr.axis, dtype=float)
        length = float(np.linalg.norm(axis))
        if not length > 0.0:
            raise ScenarioError(f"projectile.axis = {list(pr.axis)}: the nose direction must "
                                f"be a non-zero vector")
        lead = axis / length
    # the body frame is the world frame at t = 0; the shape frame has e3 along the nose
    frame = np.eye(3) if geo.kind == "sphere" else shape_frame(lead)
    moments = (geo.principal_inertia(pr.mass) if pr.principal_inertia is None
               else np.asarray(pr.principal_inertia, dtype=float))
    inertia = frame.T @ np.diag(moments) @ frame
    if geo.kind == "sphere":
        nose = geo.radius * lead
        lowest = geo.radius
    else:
        nose = (geo.length - geo.base) * lead
        lowest = geo.extent(frame @ np.array([0.0, 0.0, -1.0]))
    if pr.position is None:
        body_x0 = np.array([0.0, 0.0, lowest + pr.gap])
    else:
        body_x0 = np.asarray(pr.position, dtype=float)
    charge_pos = np.array([c.position for c in pr.charges], dtype=float).reshape(-1, 3)
    charge_q = np.array([c.charge for c in pr.charges], dtype=float)
    segments = scenario.contact.segments
    if segments == "auto":
        segments = geo.kind != "sphere"

    physics = Physics(
        nodes=Nodes(nx, ny, node_x0, node_mass, node_inv_mass, node_charge),
        yarns=Yarns(
            ends=seg_nodes,
            rest_length=seg_rest,
            inv_rest2=1.0 / seg_rest**2,
            stiffness=seg_modulus * area / seg_rest,
            modulus=seg_modulus,
            area=float(area),
        ),
        material=Material(
            kind=MATERIAL_KSV if mat.model == "kirchhoff-saint-venant" else MATERIAL_FUNG,
            fung_h=float(mat.H or 0.0),
            critical_stretch=float(fab.damage.critical_stretch),
            damage_rate=float(fab.damage.rate),
            broken_below=float(fab.damage.broken_below),
        ),
        field=build_source_grid(build_field(scenario), node_x0, scenario.field.grid_cells,
                                scenario.field.grid_tolerance, scenario.field.grid),
        body=Body(
            active=has_body,
            shape=SHAPES.get(pr.shape, SHAPE_SPHERE),  # "none": no body, shape unused
            radius=float(geo.radius),
            mass=float(pr.mass),
            inertia=inertia,
            charge_pos=charge_pos,
            charge=charge_q,
            nose=nose,
            length=float(geo.length),
            nose_length=float(geo.nose_length),
            base=float(geo.base),
            arc_radius=float(geo.arc_radius),
            flat_half_width=float(geo.flat_half_width),
            bevel_cos=float(np.cos(geo.bevel)),
            bevel_sin=float(np.sin(geo.bevel)),
            frame=frame,
            bound=float(geo.bound),
        ),
        contact=Contact(float(scenario.contact.static_friction),
                        float(scenario.contact.dynamic_friction), bool(segments),
                        scenario.contact.placement == "phi-update"),
    )
    model = Model(
        scenario=scenario,
        physics=physics,
        geometry=geo,
        flight_direction=flight,
        body_x0=body_x0,
        body_v0=body_v0,
        body_w0=np.asarray(pr.angular_velocity, dtype=float),
        node_v0=node_v0,
    )
    check_geometry(model)
    check_stability(model)
    outside = nodes_outside_map(model.field, node_x0)
    if outside:
        log.warning("%d of %d fabric nodes start outside the field map (they see no field "
                    "from it there)", outside, n)
    return model


SOLENOID_MAX_LOOPS = 200
"""A solenoid of more turns is this many loops, each carrying current × turns / loops."""
WIRE_FRACTION = 0.01
"""Default wire radius of a loop or solenoid, as a fraction of its radius."""


def build_field(scenario: Scenario) -> Field:
    """The Field record of a scenario: the uniform part (field.E, field.B and the "uniform"
    sources, summed) and the current loops (a solenoid is a row of loops), each with its
    waveform. Needs no fabric (``emfabric field`` uses it alone)."""
    fld = scenario.field
    e = np.asarray(fld.E, dtype=float)
    b = np.asarray(fld.B, dtype=float)
    loops, waves, tables = [], [], []
    field_map = None
    magnets: list[list[float]] = []
    kinds = {"constant": WAVE_CONSTANT, "ramp": WAVE_RAMP, "damped-sine": WAVE_DAMPED_SINE,
             "table": WAVE_TABLE}
    for i, src in enumerate(fld.sources):
        if src.kind == "uniform":
            e = e + np.asarray(src.E, dtype=float)
            b = b + np.asarray(src.B, dtype=float)
            continue
        if src.kind == "magnet":
            from emfabric.source_grid import import_magpylib
            try:
                import_magpylib()
            except ImportError as err:
                raise ScenarioError(f"field.sources[{i}].kind = \"magnet\": {err}") from None
            magnets.append([0.0 if src.shape == "cuboid" else 1.0, *src.polarization,
                            *(list(src.dimension) + [0.0])[:3], *src.position,
                            *np.radians(np.asarray(src.orientation, dtype=float))])
            continue
        if src.kind == "map":
            if field_map is not None:
                raise ScenarioError(f"field.sources[{i}]: a second field map; allowed: one "
                                    f"source of kind \"map\" (sum the maps into one file)")
            field_map = read_field_map(src.file, src.scale, f"field.sources[{i}].file")
            continue
        direction = np.asarray(src.normal if src.kind == "loop" else src.axis, dtype=float)
        size = float(np.linalg.norm(direction))
        if not size > 0.0:
            key = "normal" if src.kind == "loop" else "axis"
            raise ScenarioError(f"field.sources[{i}].{key} = {list(direction)}: allowed: a "
                                f"non-zero vector")
        n = direction / size
        wire = src.wire_radius if src.wire_radius is not None else WIRE_FRACTION * src.radius
        if src.kind == "loop":
            centres, per_loop = [np.asarray(src.centre, dtype=float)], float(src.turns)
        else:
            count = min(src.turns, SOLENOID_MAX_LOOPS)
            offsets = (np.arange(count) + 0.5) / count - 0.5
            centres = [np.asarray(src.centre, dtype=float) + o * src.length * n
                       for o in offsets]
            per_loop = src.turns / count
        amp = per_loop * (src.current if src.current is not None else 1.0)
        wave = [kinds[src.waveform], amp, src.start_time, src.rise_time or 0.0,
                src.frequency or 0.0, src.decay_time or 1.0]
        table = np.asarray(src.table if src.table is not None else [(0.0, 0.0)], dtype=float)
        for c in centres:
            loops.append([*c, *n, src.radius, wire])
            waves.append(wave)
            tables.append(table)
    width = max((len(tb) for tb in tables), default=1)
    padded = np.zeros((len(tables), width, 2))
    for k, tb in enumerate(tables):
        padded[k, :len(tb)] = tb
    return Field(
        E=e,
        B=b,
        region=REGION_UNIFORM if fld.region == "uniform" else REGION_HALF_SPACE,
        z0=float(fld.z0),
        gravity=np.asarray(fld.gravity, dtype=float),
        loops=np.asarray(loops, dtype=float).reshape(-1, 8) if loops else None,
        currents=np.asarray(waves, dtype=float).reshape(-1, 6),
        tables=padded,
        table_len=np.array([len(tb) for tb in tables], dtype=np.int64),
        magnets=np.asarray(magnets, dtype=float).reshape(-1, 13),
        **({} if field_map is None else field_map),
    )


def read_field_map(path: str, scale: float, key: str) -> dict:
    """The map_axes, map_size and map_values of a Field record from a netCDF field map
    (coordinates x, y, z [m], increasing; Bx, By, Bz [T], optional Ex, Ey, Ez [V/m]), times
    `scale`. Errors name the key, the file and what is wrong."""
    import xarray as xr

    try:
        ds = xr.open_dataset(path)
    except (OSError, ValueError) as err:
        raise ScenarioError(f"{key} = {path!r}: cannot be read as netCDF ({err}); allowed: a "
                            f"netCDF file with coordinates x, y, z and variables Bx, By, Bz") \
            from None
    with ds:
        axes = []
        for name in "xyz":
            if name not in ds.variables or ds[name].ndim != 1:
                raise ScenarioError(f"{key} = {path!r}: no one-dimensional coordinate {name!r}")
            a = np.asarray(ds[name].values, dtype=float)
            if a.size < 2 or not np.all(np.isfinite(a)) or np.any(np.diff(a) <= 0):
                raise ScenarioError(f"{key} = {path!r}: coordinate {name!r} must hold at least "
                                    f"two finite, increasing values [m]")
            axes.append(a)
        values = np.zeros((axes[0].size, axes[1].size, axes[2].size, 6))
        for c, name in enumerate(("Ex", "Ey", "Ez", "Bx", "By", "Bz")):
            if name not in ds.variables:
                if name.startswith("B"):
                    raise ScenarioError(f"{key} = {path!r}: variable {name!r} is missing "
                                        f"(B in T on the grid x, y, z)")
                continue
            var = ds[name]
            if set(var.dims) != {"x", "y", "z"}:
                raise ScenarioError(f"{key} = {path!r}: {name} has dimensions {var.dims}; "
                                    f"allowed: x, y, z")
            v = np.asarray(var.transpose("x", "y", "z").values, dtype=float)
            if not np.all(np.isfinite(v)):
                raise ScenarioError(f"{key} = {path!r}: {name} holds non-finite values")
            values[..., c] = scale * v
    width = max(a.size for a in axes)
    padded = np.zeros((3, width))
    for c, a in enumerate(axes):
        padded[c, :a.size] = a
    steps = np.array([(a[-1] - a[0]) / (a.size - 1)
                      if np.allclose(np.diff(a), (a[-1] - a[0]) / (a.size - 1), rtol=1e-9, atol=0)
                      else 0.0 for a in axes])
    return {"map_axes": padded, "map_size": np.array([a.size for a in axes], dtype=np.int64),
            "map_step": steps,
            "map_values": values, "map_has_e": bool(np.any(values[..., :3] != 0.0))}


def nodes_outside_map(fld: Field, points: np.ndarray) -> int:
    """How many of the points (3, N) lie outside the field map's box (0 without a map)."""
    if fld.map_axes is None:
        return 0
    inside = np.ones(points.shape[1], dtype=bool)
    for c in range(3):
        grid = fld.map_axes[c, :fld.map_size[c]]
        inside &= (points[c] >= grid[0]) & (points[c] <= grid[-1])
    return int((~inside).sum())


def check_geometry(model: Model) -> None:
    """Refuse a projectile that overlaps the fabric at t = 0 (it would start inside the sheet
    and create energy from nothing): a node inside the body, or the sheet's plane cutting the
    body within the sheet's extent."""
    if not model.has_body:
        return
    from emfabric._kernels.step import _nodes_inside

    state = np.zeros((BODY_ROWS, 3))
    state[BODY_X] = model.body_x0
    state[BODY_R0:BODY_R0 + 3] = np.eye(3)
    n = model.node_count
    inside = _nodes_inside(model.nodes.x0, np.ones(n), np.zeros(n, dtype=np.uint8), model.body,
                           state)
    x0 = model.nodes.x0
    geo = model.geometry
    frame = model.body.frame
    # the body's extent below and above its centre (z), and its reach sideways
    below = geo.extent(frame @ np.array([0.0, 0.0, -1.0]))
    above = geo.extent(frame @ np.array([0.0, 0.0, 1.0]))
    reach = geo.bound
    c = model.body_x0
    plane_cut = (c[2] - below < 0.0 < c[2] + above
                 and x0[0].min() - reach < c[0] < x0[0].max() + reach
                 and x0[1].min() - reach < c[1] < x0[1].max() + reach)
    if inside or plane_cut:
        sc = model.scenario.projectile
        where = (f"projectile.position = {list(sc.position)}" if sc.position is not None else
                 f"projectile.gap = {sc.gap}")
        raise ScenarioError(
            f"{where}: the projectile (centre {[round(float(v), 6) for v in c]} m, reaching "
            f"{below:.6g} m below it) overlaps the fabric at t = 0 ({inside} nodes inside it); "
            f"allowed: a start clear of the sheet, e.g. centre z ≥ {below:.6g} m + gap above it"
        )


STABILITY_MARGIN = 1.5
"""Stiffening the explicit stability limit allows for: the relaxed law's tangent stiffness grows
as (3U² − 1)/2 with the stretch U (1.5 at U ≈ 1.15)."""


def check_stability(model: Model) -> None:
    """Refuse a φ < 1/2 scheme whose dt_max exceeds the network's stability limit (the scheme is
    only conditionally stable there and nothing iterates to notice): Δt ≤ 2/(ω_max √(1 − 2φ))
    with ω_max² = 8·k_max/m_min, k the yarn stiffness 𝔼A0/L0 at rest times STABILITY_MARGIN."""
    solver = model.scenario.solver
    if solver.phi >= 0.5:
        return
    free = model.nodes.inv_mass > 0
    if not free.any():
        return
    k = STABILITY_MARGIN * float(model.yarns.stiffness.max())
    m = float(model.nodes.mass[free].min())
    if model.material.kind == MATERIAL_FUNG:
        k *= max(float(model.material.fung_h), 1.0)
    limit = 2.0 / ((8.0 * k / m) ** 0.5 * (1.0 - 2.0 * solver.phi) ** 0.5)
    if solver.dt_max > limit:
        raise ScenarioError(
            f"solver.dt_max = {solver.dt_max:g} s with solver.phi = {solver.phi}: the φ-scheme "
            f"is only conditionally stable for φ < 0.5 and this fabric's limit is "
            f"{limit:.3g} s; allowed: dt_max ≤ {limit:.3g} s, or phi ≥ 0.5"
        )


def _modulus_factors(count: int, cv: float, seed: int) -> np.ndarray:
    """1 + cv·ξ with ξ standard normal from default_rng(seed); a factor ≤ 0 is an error."""
    if cv == 0.0:
        return np.ones(count)
    xi = np.random.default_rng(seed).standard_normal(count)
    factors = 1.0 + cv * xi
    if np.any(factors <= 0.0):
        worst = float(factors.min())
        raise ScenarioError(
            f"fabric.material.modulus_cv = {cv}: with seed {seed} a yarn draws a modulus factor "
            f"1 + cv·ξ = {worst:.3g} ≤ 0; use a smaller modulus_cv (allowed: every draw > 0)"
        )
    return factors
