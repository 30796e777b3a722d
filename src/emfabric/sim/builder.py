"""build_model(scenario) -> Model: grid, yarn segments, masses, charges, moduli, body."""

from __future__ import annotations

import dataclasses
import logging
import math
import os

import numpy as np
from pydantic import BaseModel

from emfabric._kernels.plies import PLY_STIFFNESS
from emfabric._kernels.records import (
    BODY_R0,
    BODY_ROWS,
    BODY_X,
    DAMAGE_BRITTLE,
    DAMAGE_ZOHDI,
    MATERIAL_FUNG,
    MATERIAL_KSV,
    ROW_COUNT,
    SHAPE_SPHERE,
    Body,
    Contact,
    Material,
    Nodes,
    Physics,
    Yarns,
    pack_tables,
)
from emfabric._kernels.shapes import SHAPES
from emfabric.config.scenario import LIGHT_SPEED, Scenario, ScenarioError
from emfabric.sim.geometry import initial_pose
from emfabric.sim.model import Model, Options
from emfabric.sources.build import build_field, nodes_outside_map, one_type
from emfabric.sources.grid import build_source_grid

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
    """Bytes a run of this scenario needs (estimate, before anything is allocated): every ply's
    grid (a ply at an angle that is not a multiple of 90° is a grid about twice as large)."""
    fab = scenario.fabric
    total = 0
    for p in range(fab.plies):
        nx, ny = fab.ply_fabric(p).nodes
        angle = fab.ply_angles[p] if fab.ply_angles else 0.0
        total += nx * ny * (1 if angle % 90.0 == 0.0 else 2)
    return BYTES_PER_NODE * total


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
        gib = f"{need / 2**30:.3g}" if need < 2**1000 else "more than 1e290"
        raise ScenarioError(
            f"fabric.nodes = [{nx}, {ny}]: a run needs about {gib} GiB "
            f"({BYTES_PER_NODE} B per node), this machine has {have / 2**30:.3g} GiB; allowed: "
            f"grids up to about {int((0.8 * have / BYTES_PER_NODE) ** 0.5)} × "
            f"{int((0.8 * have / BYTES_PER_NODE) ** 0.5)} nodes here"
        )


def build_model(scenario: Scenario, *, writes: bool = True) -> Model:
    """Everything a step reads, from a validated scenario.

    A scenario whose numbers are valid one by one but so extreme that a quantity built from them
    overflows (a yarn radius of 1e200 m: its area) is a ScenarioError naming that value.
    writes: the run writes its files, so its output volume is checked against
    output.size_limit (emfabric.sim.sanity); False for a run kept in memory, which writes
    nothing."""
    check_memory(scenario)
    try:
        # overflow is checked below, on what was built: numpy's warnings would only repeat it
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            model = _assemble(scenario)
            part = non_finite_part(model)
            problem = None if part is None else f"a non-finite {part}"
            if problem is None:
                check_geometry(model, scenario.projectile)
                check_stability(model)
    except (OverflowError, ZeroDivisionError, FloatingPointError) as err:
        problem = ("an overflow" if isinstance(err, OverflowError) else
                   "a division by zero" if isinstance(err, ZeroDivisionError) else
                   f"a floating-point error ({err})")
    if problem is not None:
        raise extreme_value_error(scenario, problem)
    outside = nodes_outside_map(model.field, model.nodes.x0)
    if outside:
        log.warning("%d of %d fabric nodes start outside the field map (they see no field "
                    "from it there)", outside, model.node_count)
    from emfabric.sim.sanity import check_output_volume, pre_run_warnings

    if writes:
        check_output_volume(model)
    for line in pre_run_warnings(model):
        log.warning("%s", line)
    return model


def _damping(q: float, stiffness: np.ndarray, mass: np.ndarray,
             ends: np.ndarray) -> np.ndarray:
    """Yarns.damping: each segment's bulk viscosity η = q·√(k m̄) [N s/m], k its stiffness and
    m̄ the mean mass of its end nodes (for a chain of equal nodes and segments the highest
    mode's damping ratio is then q); empty for q = 0."""
    if q == 0.0:
        return np.zeros(0)
    return q * np.sqrt(stiffness * _end_mass(mass, ends))


def _end_mass(mass: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """m̄ of each segment: the mean mass of its two end nodes [kg]."""
    return 0.5 * (mass[ends[:, 0]] + mass[ends[:, 1]])


def _averaging_rate(n: float, stiffness: np.ndarray, mass: np.ndarray,
                    ends: np.ndarray) -> np.ndarray:
    """Yarns.averaging_rate: each segment's 1/τ, τ = n·√(m̄/k), n times the time a wave takes to
    cross it (for a chain of equal nodes and segments, L0/c = √(m/k)), k its stiffness and m̄
    the mean mass of its end nodes [1/s]; empty for n = 0 (the instantaneous stretch). 0 for
    a segment of no stiffness between massless nodes: a rotated ply's lattice outside the frame
    (_ply), which carries no load."""
    if n == 0.0:
        return np.zeros(0)
    m = _end_mass(mass, ends)
    out = np.zeros_like(stiffness)
    np.divide(stiffness, m, out=out, where=m > 0.0)
    return np.sqrt(out) / n


def _assemble(scenario: Scenario) -> Model:
    """The Model of a scenario, not yet checked."""
    fab = scenario.fabric
    lx, ly = fab.size
    plies = [_ply(scenario, p) for p in range(fab.plies)]
    for p in range(1, fab.plies):
        touch = plies[p - 1].thickness + plies[p].thickness
        if fab.ply_spacing is not None and fab.ply_spacing < touch * (1.0 - 1e-12):
            raise ScenarioError(
                f"fabric.ply_spacing = {fab.ply_spacing} m: plies {p} and {p + 1} would start "
                f"interpenetrating (their yarn radii sum to {touch:.4g} m); allowed: a spacing "
                f"≥ {touch:.4g} m (leave it out for touching plies)")
    node_x0 = np.concatenate([p.x0 for p in plies], axis=1)
    node_mass = np.concatenate([p.mass for p in plies])
    node_inv_mass = np.concatenate([p.inv_mass for p in plies])
    node_charge = np.concatenate([p.charge for p in plies])
    node_v0 = np.concatenate([p.v0 for p in plies], axis=1)
    offsets = np.cumsum([0] + [p.x0.shape[1] for p in plies])
    seg_nodes = np.concatenate([p.ends + off for p, off in zip(plies, offsets, strict=False)])
    seg_rest = np.concatenate([p.rest for p in plies])
    seg_modulus = np.concatenate([p.modulus for p in plies])
    seg_stiffness = np.concatenate([p.stiffness for p in plies])
    seg_fail2 = np.concatenate([p.fail2 for p in plies])
    rows, ply_nodes, ply_rows, ply_segments = pack_tables([p.grid for p in plies])
    nx = int(rows[:, ROW_COUNT].max())
    ny = int(rows.shape[0])
    mat = fab.material
    pr = scenario.projectile
    has_body = pr.shape in SHAPES
    pose = initial_pose(pr)
    geo, frame = pose.geometry, pose.frame
    if has_body:
        # Newtonian mechanics: no point of the body may start as fast as light (the velocity
        # alone is checked with the scenario: LIGHT_SPEED)
        surface = (math.hypot(*pose.angular_velocity) * float(geo.bound)
                   + math.hypot(*pose.velocity))
        if not surface < LIGHT_SPEED:
            raise ScenarioError(
                f"projectile.angular_velocity = {list(pr.angular_velocity)}: its surface would "
                f"start at up to {surface:.4g} m/s (|ω| × {float(geo.bound):.4g} m + |v|); "
                f"allowed: below the speed of light, {LIGHT_SPEED:.9g} m/s (the model is "
                f"Newtonian)")
    charge_pos = np.array([c.position for c in pr.charges], dtype=float).reshape(-1, 3)
    charge_q = np.array([c.charge for c in pr.charges], dtype=float)
    segments = scenario.contact.segments
    if segments == "auto":
        segments = geo.kind != "sphere"

    physics = Physics(
        nodes=Nodes(nx, ny, node_x0, node_mass, node_inv_mass, node_charge, rows, ply_nodes,
                    ply_rows),
        yarns=Yarns(
            ends=seg_nodes,
            rest_length=seg_rest,
            inv_rest2=1.0 / seg_rest**2,
            stiffness=seg_stiffness,
            modulus=seg_modulus,
            area=float(plies[0].area),
            ply_segments=ply_segments,
            failure_stretch2=seg_fail2,
            damping=_damping(scenario.bulk_viscosity, seg_stiffness, node_mass, seg_nodes),
            averaging_rate=_averaging_rate(
                fab.damage.strain_averaging if fab.damage.brittle else 0.0, seg_stiffness,
                node_mass, seg_nodes),
        ),
        material=Material(
            kind=MATERIAL_KSV if mat.model == "kirchhoff-saint-venant" else MATERIAL_FUNG,
            fung_h=float(mat.H or 0.0),
            critical_stretch=float(fab.damage.critical_stretch),
            damage_rate=float(fab.damage.rate),
            broken_below=float(fab.damage.broken_below),
            damage_law=DAMAGE_BRITTLE if fab.damage.brittle else DAMAGE_ZOHDI,
        ),
        field=one_type(build_source_grid(build_field(scenario), node_x0,
                                         scenario.field.grid_cells,
                                         scenario.field.grid_tolerance, scenario.field.grid)),
        body=Body(
            active=has_body,
            shape=SHAPES.get(pr.shape, SHAPE_SPHERE),  # "none": no body, shape unused
            radius=float(geo.radius),
            mass=float(pr.mass),
            inertia=pose.inertia,
            charge_pos=charge_pos,
            charge=charge_q,
            nose=pose.nose,
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
                        scenario.contact.placement == "phi-update", *_ply_contact(plies)),
    )
    model = Model(
        physics=physics,
        options=Options.of(scenario),
        geometry=geo,
        flight_direction=pose.flight_direction,
        body_x0=pose.position,
        body_v0=pose.velocity,
        body_w0=pose.angular_velocity,
        node_v0=node_v0,
        projectile_shape=pr.shape,
        scenario=scenario,
    )
    return model


@dataclasses.dataclass
class _Ply:
    """One ply's nodes and segments, numbered within the ply (records' layout)."""

    grid: tuple[int, int]
    x0: np.ndarray
    mass: np.ndarray
    inv_mass: np.ndarray
    charge: np.ndarray
    v0: np.ndarray
    ends: np.ndarray
    rest: np.ndarray
    modulus: np.ndarray
    stiffness: np.ndarray
    area: float
    thickness: float
    """The ply's yarn radius as given (its half-thickness for ply contact) [m]."""
    fail2: np.ndarray
    """Brittle law: each segment's stretch² at break (failure_stretches); else empty."""
    spacing: tuple[float, float]
    """Node spacing along its weave's two directions [m]."""
    cos: float
    sin: float
    """The weave's first direction (cos, sin) in the frame."""


def ply_z(fab, index: int) -> float:
    """The mid-plane of ply `index` (0 = the top one, at z = 0) [m]: fabric.ply_spacing apart,
    or touching (the sum of neighbouring yarn radii)."""
    z = 0.0
    for p in range(1, index + 1):
        z -= (fab.ply_spacing if fab.ply_spacing is not None else
              fab.ply_fabric(p - 1).yarn_radius + fab.ply_fabric(p).yarn_radius)
    return z


def _ply(scenario: Scenario, index: int) -> _Ply:
    """Ply `index` of the scenario's pack: its weave's grid, rotated by its angle and clipped to
    the frame, at its depth."""
    pack = scenario.fabric
    fab = pack.ply_fabric(index)
    lx, ly = pack.size
    angle = pack.ply_angles[index] if pack.ply_angles else 0.0
    quarter = angle / 90.0
    aligned = quarter == round(quarter)
    nx, ny = fab.nodes
    hx, hy = lx / (nx - 1), ly / (ny - 1)
    if aligned:
        turns = int(round(quarter)) % 4
        cos, sin = ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[turns]
        su, sv = lx, ly
        if turns % 2:
            # the weave's first direction along y: its grid is the frame's, transposed
            nx, ny, hx, hy, su, sv = ny, nx, hy, hx, ly, lx
        gx, gy = nx, ny
        us = grid_coordinates(gx, su)
        vs = grid_coordinates(gy, sv)
    else:
        rad = math.radians(angle)
        cos, sin = math.cos(rad), math.sin(rad)
        # the rotated grid that covers the frame, one node beyond it
        half_u = 0.5 * (lx * abs(cos) + ly * abs(sin))
        half_v = 0.5 * (lx * abs(sin) + ly * abs(cos))
        gx = 2 * (int(half_u / hx) + 1) + 1
        gy = 2 * (int(half_v / hy) + 1) + 1
        us = grid_coordinates(gx, hx * (gx - 1))
        vs = grid_coordinates(gy, hy * (gy - 1))
    n = gx * gy
    u = np.tile(us, gy)
    v = np.repeat(vs, gx)
    x0 = np.zeros((3, n))
    if aligned and cos == 1.0:
        x0[0], x0[1] = u, v
    else:
        x0[0] = cos * u - sin * v
        x0[1] = sin * u + cos * v
    x0[2] = ply_z(pack, index)

    live = np.ones(n, dtype=bool)
    free = np.ones(n, dtype=bool)
    if aligned:
        if pack.edges == "clamped":
            g = free.reshape(gy, gx)
            g[0, :] = g[-1, :] = g[:, 0] = g[:, -1] = False
    else:
        # clipped to the frame: nodes strictly inside are free; a node next to a free one
        # (along its yarns) is clamped; the rest carry nothing (no mass, no load)
        eps = 1e-9 * max(lx, ly)
        inside = (np.abs(x0[0]) < 0.5 * lx - eps) & (np.abs(x0[1]) < 0.5 * ly - eps)
        g = inside.reshape(gy, gx)
        near = g.copy()
        near[:, 1:] |= g[:, :-1]
        near[:, :-1] |= g[:, 1:]
        near[1:, :] |= g[:-1, :]
        near[:-1, :] |= g[1:, :]
        if pack.edges == "clamped":
            live = near.ravel()
        else:
            live = inside.copy()
        free = inside.copy()

    # lumped mass: the ply's mass over its nodes (paper 2.2); charge per node (2.5)
    count = int(live.sum())
    mass = fab.areal_density * lx * ly / count
    area = np.pi * fab.yarn_radius**2
    charge = fab.charge_per_node
    if fab.rescale:
        # same fabric at another resolution: q/m kept (the yarn area below)
        rnx, rny = fab.reference_nodes
        charge *= mass / (fab.areal_density * lx * ly / (rnx * rny))
    node_mass = np.where(live, mass, 0.0)
    node_inv_mass = np.where(free, 1.0 / mass, 0.0)
    node_charge = np.where(live, charge, 0.0)
    node_v0 = np.zeros((3, n))
    node_v0[:, free] = np.asarray(fab.velocity, dtype=float)[:, None]

    # warp (along the weave's first direction) then fill
    ii, jj = np.meshgrid(np.arange(gx - 1), np.arange(gy), indexing="xy")
    warp_a = (jj * gx + ii).ravel()
    ii, jj = np.meshgrid(np.arange(gx), np.arange(gy - 1), indexing="xy")
    fill_a = (jj * gx + ii).ravel()
    ends = np.concatenate(
        [np.stack([warp_a, warp_a + 1], axis=1), np.stack([fill_a, fill_a + gx], axis=1)]
    ).astype(np.int64)
    rest = np.concatenate([np.full(warp_a.size, hx), np.full(fill_a.size, hy)])
    mat = fab.material
    base = mat.youngs_modulus if mat.model == "kirchhoff-saint-venant" else mat.c
    own_seed = bool(pack.ply and pack.ply[index].material is not None
                    and pack.ply[index].material.seed is not None)
    seed = mat.seed if index == 0 or own_seed else (mat.seed, index)
    modulus = base * _modulus_factors(ends.shape[0], mat.modulus_cv, seed)
    warp = np.arange(ends.shape[0]) < warp_a.size
    rnx, rny = fab.reference_nodes
    if aligned and turns % 2:
        rnx, rny = rny, rnx
    # each family's spacing on the reference grid, along its own direction
    ref_hx, ref_hy = (su / (rnx - 1), sv / (rny - 1)) if aligned else (
        lx / (fab.reference_nodes[0] - 1), ly / (fab.reference_nodes[1] - 1))
    ref_rest = np.where(warp, ref_hx, ref_hy)
    if fab.rescale:
        # same fabric at another resolution: each family's stiffness per unit width kept. A
        # warp line stands for the yarns of the hy between two of them, a fill line for hx:
        # A0 ← A0·hy/hy_ref along the warp, A0·hx/hx_ref along the fill (exactly 1 at the
        # reference grid; the same factor for both where the grid keeps the reference's
        # aspect, as every square grid of a square sheet does)
        seg_area = area * np.where(warp, hy / ref_hy, hx / ref_hx)
    else:
        seg_area = np.full(ends.shape[0], area)
    stiffness = modulus * seg_area / rest
    if not aligned:
        # clipped: a segment carries load where it has a free end (clamped frame) or joins two
        # nodes of the sheet (free edges)
        a, b = free[ends[:, 0]], free[ends[:, 1]]
        stiffness[~((a | b) if pack.edges == "clamped" else (a & b))] = 0.0
    fail2 = failure_stretches(fab, rest, ref_rest, seed)
    return _Ply((gx, gy), x0, node_mass, node_inv_mass, node_charge, node_v0, ends, rest,
                modulus, stiffness, float(seg_area[0] if seg_area.size else area),
                float(fab.yarn_radius), fail2, (hx, hy), cos,
                sin)


STRENGTH_STREAM = 1
"""The random stream of the strength scatter (the modulus scatter draws from the seed alone)."""


def failure_stretches(fab, rest: np.ndarray, ref_rest: np.ndarray, seed) -> np.ndarray:
    """Each segment's stretch² at break (1 + ε_s)² under damage.law = "brittle" (empty
    otherwise). Without scatter (weibull_shape = 0) ε_s = failure_strain. With Weibull modulus
    m, ε_s is Weibull distributed, mean failure_strain for a segment of the reference spacing
    ref_rest, and weakest-link scaled to other lengths: scale ∝ (L_ref/L0)^(1/m), so that a
    coarse segment is as strong as the weakest of the reference segments it stands for and the
    strength of a yarn does not depend on the network's resolution. Drawn from
    default_rng([seed, STRENGTH_STREAM]) (seeded: the same draws on every run)."""
    eps = fab.failure_strain()
    if eps is None:
        return np.zeros(0)
    m = float(fab.damage.weibull_shape)
    if m == 0.0:
        strain = np.full(rest.shape[0], float(eps))
    else:
        seq = [*np.atleast_1d(seed).tolist(), STRENGTH_STREAM]
        scale = eps / math.gamma(1.0 + 1.0 / m) * (ref_rest / rest) ** (1.0 / m)
        strain = scale * np.random.default_rng(seq).weibull(m, rest.shape[0])
    return (1.0 + strain) ** 2


def _nearest(master: _Ply, x: np.ndarray) -> np.ndarray:
    """The node of `master`'s grid nearest to each point x (3, n) in the plane (reference
    state), numbered within the ply."""
    gx, gy = master.grid
    u = master.cos * x[0] + master.sin * x[1]
    v = -master.sin * x[0] + master.cos * x[1]
    i = np.clip(np.rint(u / master.spacing[0] + 0.5 * (gx - 1)), 0, gx - 1).astype(np.int64)
    j = np.clip(np.rint(v / master.spacing[1] + 0.5 * (gy - 1)), 0, gy - 1).astype(np.int64)
    return j * gx + i


def _ply_contact(plies: list[_Ply]):
    """Contact's ply fields (records.Contact): ply_gap, ply_reach, ply_box, ply_guess,
    ply_quantum, ply_stiffness."""
    gap = np.array([a.thickness + b.thickness for a, b in zip(plies, plies[1:], strict=False)])
    # a node's share of its ply's surface reaches one spacing (the shares are normalised where
    # they are used: no bumps where the lattice is sparse or clipped)
    reach = np.array([max(p.spacing) for p in plies])
    box = np.array([[int(r / p.spacing[0] + 0.5), int(r / p.spacing[1] + 0.5)]
                    for p, r in zip(plies, reach, strict=False)], dtype=np.int64).reshape(-1, 2)
    offsets = np.cumsum([0] + [p.x0.shape[1] for p in plies])
    guess = np.full((2, int(offsets[-1])), -1, dtype=np.int64)
    for q in range(len(plies)):
        if q > 0:
            guess[0, offsets[q]:offsets[q + 1]] = offsets[q - 1] + _nearest(plies[q - 1],
                                                                           plies[q].x0)
        if q < len(plies) - 1:
            guess[1, offsets[q]:offsets[q + 1]] = offsets[q + 1] + _nearest(plies[q + 1],
                                                                           plies[q].x0)
    m = max(float(p.mass.max()) for p in plies)
    # impulses up to m·1e5 m/s and placements up to m·(gap + reach) in units of 2^-52 of
    # them: sums of thousands fit an int64
    span = float(gap.max() + reach.max()) if gap.size else 1.0
    # the φ-scheme's normal stiffness of a node's share: PLY_STIFFNESS × EA/L0 of the softer
    # ply's yarns (the axial stiffness of one of its segments); forces up to stiffness·span
    def axial(p):  # the median over the segments that carry load (a rotated ply's grid has
        k = p.stiffness[p.stiffness > 0.0]  # stiffless segments outside the frame)
        return float(np.median(k)) if k.size else 0.0

    stiff = PLY_STIFFNESS * np.array([min(axial(a), axial(b))
                                      for a, b in zip(plies, plies[1:], strict=False)])
    top = float(stiff.max()) * span if stiff.size and stiff.max() > 0.0 else 1.0
    quantum = np.array([2.0 ** (math.ceil(math.log2(m * 1e5)) - 52),
                        2.0 ** (math.ceil(math.log2(m * span)) - 52),
                        2.0 ** (math.ceil(math.log2(top)) - 52)])
    return gap, reach, box, guess, quantum, stiff


def non_finite_part(model: Model) -> str | None:
    """The first part of a model (record.field, or a start value) holding a number that is not
    finite, e.g. "yarns.area"; None when every number is finite."""
    parts = {f"{name}.{key}": value for name, record in model.physics._asdict().items()
             for key, value in record._asdict().items()}
    parts.update(body_x0=model.body_x0, body_v0=model.body_v0, body_w0=model.body_w0,
                 node_v0=model.node_v0, flight_direction=model.flight_direction)
    for name, value in parts.items():
        if value is None or isinstance(value, bool | int | str):
            continue
        arr = np.asarray(value)
        if arr.dtype.kind in "fc" and not np.isfinite(arr).all():
            return name
    return None


def _numbers(value, key: str):
    """(key, value, decades) of each number, vector or table of a scenario (section): decades =
    |log10|x|| of its most extreme element (0 for 0); sources and charges by index."""
    if isinstance(value, BaseModel):
        for name in type(value).model_fields:
            yield from _numbers(getattr(value, name), f"{key}.{name}" if key else name)
    elif isinstance(value, tuple) and value and all(isinstance(v, BaseModel) for v in value):
        for i, item in enumerate(value):
            yield from _numbers(item, f"{key}[{i}]")
    else:
        flat = list(_flatten(value))
        if flat:
            # math.log10 takes ints of any size (a float() of them may overflow)
            yield key, value, max(abs(math.log10(abs(x))) if x else 0.0 for x in flat)


def _flatten(value):
    if isinstance(value, tuple | list):
        for v in value:
            yield from _flatten(v)
    elif isinstance(value, int | float) and not isinstance(value, bool):
        yield value


def _shown(value) -> str:
    return str(_listed(value)) if isinstance(value, tuple) else repr(value)


def _listed(value):
    return [_listed(v) for v in value] if isinstance(value, tuple) else value


PHYSICAL_DECADES = 30
"""extreme_value_error blames the scenario's most extreme value only beyond this many decades
from 1: the built-in scenarios' values lie within 1e-13 … 1e11, and a square, product or volume
of values within 1e±30 stays far from overflow."""


def extreme_value_error(scenario: Scenario, problem: str) -> ScenarioError:
    """The error for a model that is not finite (`problem`: what went wrong). Every number of a
    scenario is finite (validated), so one is too extreme for what is computed from it; named is
    the most extreme one, counted in decades away from 1 (the defaults lie within 1e-13 … 1e11,
    and only a value some 100 decades out overflows a square, a product or a volume)."""
    key, value, decades = max(_numbers(scenario, ""), key=lambda item: item[2])
    if decades <= PHYSICAL_DECADES:
        # nothing the user gave is extreme: the model's own arithmetic failed
        return ScenarioError(
            f"building the model gives {problem}, although no value of the scenario is extreme "
            f"(the most extreme: {key} = {_shown(value)}): an emfabric bug; please report it "
            "with the output of `emfabric validate SCENARIO --show`")
    return ScenarioError(
        f"{key} = {_shown(value)}: building the model gives {problem}, and this is the "
        f"scenario's most extreme value; allowed: a value of physical size (every quantity "
        f"derived from it, such as an area, volume, mass, inertia or stiffness, and their "
        f"inverses, must be a finite number: below about 1e308 in magnitude)")


def check_geometry(model: Model, projectile) -> None:
    """Refuse a projectile that overlaps the fabric at t = 0 (it would start inside the sheet
    and create energy from nothing): a node inside the body, or the sheet's plane cutting the
    body within the sheet's extent."""
    if not model.has_body:
        return
    from emfabric._kernels.shapes import nodes_inside

    state = np.zeros((BODY_ROWS, 3))
    state[BODY_X] = model.body_x0
    state[BODY_R0:BODY_R0 + 3] = np.eye(3)
    n = model.node_count
    inside = nodes_inside(model.nodes.x0, np.ones(n), np.zeros(n, dtype=np.uint8), model.body,
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
        sc = projectile
        where = (f"projectile.position = {list(sc.position)}" if sc.position is not None else
                 f"projectile.gap = {sc.gap}")
        raise ScenarioError(
            f"{where}: the projectile (centre {[round(float(v), 6) for v in c]} m, reaching "
            f"{below:.6g} m below it) overlaps the fabric at t = 0 ("
            + (f"{inside} node{'s' if inside > 1 else ''} inside it" if inside else
               "the sheet's plane cuts it") + "); "
            f"allowed: a start clear of the sheet, e.g. centre z ≥ {below:.6g} m + gap above it"
        )


STABILITY_MARGIN = 1.5
"""Stiffening the explicit stability limit allows for: the relaxed law's tangent stiffness grows
as (3U² − 1)/2 with the stretch U (1.5 at U ≈ 1.15)."""


def check_stability(model: Model) -> None:
    """Refuse a φ < 1/2 scheme whose dt_max exceeds the network's stability limit (the scheme is
    only conditionally stable there and nothing iterates to notice): Δt ≤ 2/(ω_max √(1 − 2φ))
    with ω_max² = 8·k_max/m_min, k the yarn stiffness 𝔼A0/L0 at rest times STABILITY_MARGIN."""
    solver = model.options
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
