"""build_model(scenario) -> Model: grid, yarn segments, masses, charges, moduli, body."""

from __future__ import annotations

import logging
import math
import os

import numpy as np
from pydantic import BaseModel

from emfabric._kernels.records import (
    BODY_R0,
    BODY_ROWS,
    BODY_X,
    MATERIAL_FUNG,
    MATERIAL_KSV,
    SHAPE_SPHERE,
    Body,
    Contact,
    Material,
    Nodes,
    Physics,
    Yarns,
)
from emfabric._kernels.shapes import SHAPES
from emfabric.config.scenario import Scenario, ScenarioError
from emfabric.sim.geometry import initial_pose
from emfabric.sim.model import Model, Options
from emfabric.sources.build import build_field, nodes_outside_map
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
    """Everything a step reads, from a validated scenario.

    A scenario whose numbers are valid one by one but so extreme that a quantity built from them
    overflows (a yarn radius of 1e200 m: its area) is a ScenarioError naming that value."""
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
    return model


def _assemble(scenario: Scenario) -> Model:
    """The Model of a scenario, not yet checked."""
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
    pose = initial_pose(pr)
    geo, frame = pose.geometry, pose.frame
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
                        scenario.contact.placement == "phi-update"),
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


def extreme_value_error(scenario: Scenario, problem: str) -> ScenarioError:
    """The error for a model that is not finite (`problem`: what went wrong). Every number of a
    scenario is finite (validated), so one is too extreme for what is computed from it; named is
    the most extreme one, counted in decades away from 1 (the defaults lie within 1e-13 … 1e11,
    and only a value some 100 decades out overflows a square, a product or a volume)."""
    key, value, _ = max(_numbers(scenario, ""), key=lambda item: item[2])
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
