"""Diagnostics of a State: the history record, the fabric's summary, and the run's stop rule.

Physics lives in the kernels (emfabric._kernels.diagnostics: one pass over the fabric, then the
record); this module names what they return. The recorder (emfabric.io.history) stores rows this
module fills; it computes nothing.
"""

from __future__ import annotations

import functools
import math
import weakref
from collections.abc import Mapping
from types import MappingProxyType
from typing import NamedTuple

import numpy as np

from emfabric._kernels import diagnostics as _k
from emfabric._kernels.fields import fields_at_points
from emfabric._kernels.records import (
    COL_BALANCE,
    COL_CONTACT_SEGMENTS,
    COL_DEFLECTION,
    COL_FIELD_B,
    COL_FIELD_E,
    COL_STRETCH,
    ENERGY_WORK_FIELD,
    ENERGY_WORK_GRAVITY,
    HISTORY_COLUMN,
    HISTORY_COLUMNS,
    HISTORY_VARIABLES,
    StepStats,
)
from emfabric.sim.fastcall import Direct
from emfabric.sim.model import Model
from emfabric.sim.reach import out_of_reach
from emfabric.sim.state import State
from emfabric.sources.evaluate import fields_at, magnets_outside_kernels

ATTRIBUTES: dict[str, tuple[str, str]] = {
    "dt": ("s", "accepted time step"),
    "iterations": ("1", "fixed-point iterations of the accepted step"),
    "error": ("1", "normalised iteration error at acceptance (eq. 3.10 step 5a)"),
    "rejected_steps": ("1", "rejected attempts so far (cumulative)"),
    "force_evaluations": ("1", "force evaluations so far (cumulative)"),
    "projectile_position": ("m", "projectile centre of mass"),
    "projectile_velocity": ("m s-1", "projectile centre-of-mass velocity"),
    "angular_velocity": ("rad s-1", "projectile angular velocity (inertial frame)"),
    "projectile_nose": ("m", "nose marker relative to the centre of mass"),
    "tilt": ("rad", "tilt angle of the nose marker (eq. 5.2)"),
    "contact_nodes": ("1", "fabric nodes in contact with the projectile (touching it, or an "
                              "end of a yarn segment that touches it)"),
    "max_deflection": ("m", "largest out-of-plane node displacement"),
    "max_stretch": ("1", "largest stretch U = L/L0 of the yarns not broken"),
    "fabric_momentum": ("kg m s-1", "linear momentum of the fabric"),
    "fabric_angular_momentum": ("kg m2 s-1", "angular momentum of the fabric about the origin"),
    "projectile_momentum": ("kg m s-1", "linear momentum of the projectile"),
    "projectile_angular_momentum": ("kg m2 s-1",
                                    "angular momentum of the projectile about the origin"),
    "kinetic_energy_projectile": ("J", "projectile kinetic energy (translation + rotation)"),
    "kinetic_energy_projectile_rotation": ("J", "projectile rotational kinetic energy"),
    "kinetic_energy_fabric": ("J", "fabric kinetic energy"),
    "strain_energy": ("J", "stored yarn energy (damaged)"),
    "broken_yarns": ("1", "yarns with damage α below fabric.damage.broken_below"),
    "min_damage": ("1", "smallest yarn damage variable α (1 intact)"),
    "work_field": ("J", "work of the electric field on fabric and projectile (cumulative)"),
    "work_gravity": ("J", "work of gravity (cumulative)"),
    "dissipation_friction": ("J", "work of friction against the slip (cumulative)"),
    "dissipation_contact": ("J", "kinetic energy the contact impulses remove, less friction's "
                            "(cumulative)"),
    "dissipation_projection": ("J", "work lost in contact position projections (cumulative)"),
    "dissipation_damage": ("J", "energy released by yarn damage (cumulative)"),
    "dissipation_viscous": ("J", "work of the yarns' bulk viscosity, solver.bulk_viscosity "
                            "(cumulative)"),
    "energy_balance_error": ("J", "kinetic + strain + dissipated − work − initial energy"),
    "yaw": ("rad", "angle between the projectile's axis (nose marker) and its velocity"),
    "contact_force": ("N", "total contact + friction force on the projectile (mean over "
                              "the step)"),
    "field_B": ("T", "magnetic field at the projectile's centre of mass (the sheet's centre "
                        "without a projectile)"),
    "field_E": ("V m-1", "electric field there (the induced E of a pulsed coil included)"),
    "contact_segments": ("1", "yarn segments in contact with the projectile (contact.segments)"),
}
"""Units and long name of each history variable (netCDF attributes)."""

RECORD: dict[str, tuple[int, str, str]] = {
    name: (width, *ATTRIBUTES[name]) for name, width in HISTORY_VARIABLES}
"""The history record: name -> (width, units, long name); width 3 means a (time, xyz)
variable. The columns are records.HISTORY_VARIABLES' (the layout the record kernel writes)."""
COLUMNS = HISTORY_COLUMNS
"""Columns of a history record (time first)."""
LAYOUT: dict[str, slice] = {name: slice(HISTORY_COLUMN[name], HISTORY_COLUMN[name] + width)
                            for name, width in HISTORY_VARIABLES}
"""Columns of each RECORD variable in a history row."""

PLY_RECORD: dict[str, tuple[str, str]] = {
    "broken_yarns_per_ply": ("1", "yarns of each ply with damage α below "
                                  "fabric.damage.broken_below"),
    "max_deflection_per_ply": ("m", "largest out-of-plane node displacement of each ply"),
    "contact_nodes_per_ply": ("1", "nodes of each ply in contact with the projectile (as "
                                   "contact_nodes)"),
}
"""The per-ply history variables (time, ply): name -> (units, long name). A history row holds
them after the COLUMNS of RECORD, one block of `plies` columns each, in this order."""


def row_width(plies: int) -> int:
    """Columns of a history row of a pack of `plies` plies."""
    return COLUMNS + len(PLY_RECORD) * plies


@functools.cache
def ply_layout(plies: int) -> Mapping[str, slice]:
    """Columns of each PLY_RECORD variable in a history row of a pack of `plies` plies (built
    once per ply count and read-only: the record of every step looks it up)."""
    return MappingProxyType({name: slice(COLUMNS + k * plies, COLUMNS + (k + 1) * plies)
                             for k, name in enumerate(PLY_RECORD)})


class FabricDiagnostics(NamedTuple):
    """The fabric's state in a few numbers (the kernel's order)."""

    kinetic_energy: float
    """[J]"""
    momentum_x: float
    momentum_y: float
    momentum_z: float
    angular_momentum_x: float
    angular_momentum_y: float
    angular_momentum_z: float
    max_deflection: float
    """Largest |z − z_ref| [m]."""
    max_stretch: float
    strain_energy: float
    """[J]"""
    broken_yarns: float
    min_damage: float
    ahead_min: float
    """Smallest position of a node along the flight direction, relative to the body centre [m]."""
    ahead_max: float
    approach_max: float
    """Fastest node speed against the flight direction [m/s]."""
    recede_max: float
    """Fastest node speed along the flight direction [m/s]."""


_DIRECT: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
"""Per Model: its diagnostics kernels called without the per-call type dispatch (fastcall)."""


def _record(model: Model, state: State, row: np.ndarray, e_initial: float,
            fabric: np.ndarray | None = None,
            contacts: np.ndarray | None = None) -> tuple[FabricDiagnostics, float]:
    direct = _DIRECT.get(model)
    if direct is None:
        direct = _DIRECT[model] = (Direct(_k.fabric_diagnostics), Direct(_k.history_row),
                                   Direct(fields_at_points),
                                   tuple(np.empty((1, 3)) for _ in range(3)))
    centre = state.body_x if model.has_body else np.zeros(3)
    if fabric is None:
        out = np.empty(_k.COUNT)
        direct[0](None, model.physics, state.node_x, state.node_v, state.seg_alpha, centre,
                  model.flight_direction, out)
    else:
        out = fabric
    step = StepStats(float(state.t), float(state.last_dt), int(state.iterations),
                     float(state.error), int(state.rejected), int(state.evaluations),
                     int(state.contact_count))
    e0 = direct[1](None, step, state.body, model.body, out, state.energy, float(e_initial),
                   state.contact_force, row)
    # the applied field where the projectile is: when a pulse rises, how strong it got
    fld = model.field
    if magnets_outside_kernels(fld):
        e, b = fields_at(fld, centre.reshape(1, 3), state.t)
    else:  # sources.evaluate.fields_at's kernel, without its dispatch and allocations
        pts, e, b = direct[3]
        pts[0] = centre
        direct[2](None, fld, pts, float(state.t), e, b)
    row[COL_FIELD_B:COL_FIELD_B + 3] = b[0]
    row[COL_FIELD_E:COL_FIELD_E + 3] = e[0]
    row[COL_CONTACT_SEGMENTS] = state.contact_segments
    _per_ply(model, state, row, contacts)
    return FabricDiagnostics._make(out.tolist()), float(e0)


def _per_ply(model: Model, state: State, row: np.ndarray,
             contacts: np.ndarray | None = None) -> None:
    """The per-ply columns of a history row (PLY_RECORD): one pass of NumPy over the nodes and
    segments, reduced per ply; a single sheet copies its totals. contacts: the nodes in contact
    per ply, where the integrator counted them (its contacts_of), else from the state's contact
    flags."""
    plies = model.ply_count
    lay = ply_layout(plies)
    if plies == 1:
        row[lay["broken_yarns_per_ply"]] = row[LAYOUT["broken_yarns"]]
        row[lay["max_deflection_per_ply"]] = row[LAYOUT["max_deflection"]]
        row[lay["contact_nodes_per_ply"]] = row[LAYOUT["contact_nodes"]]
        return
    nodes, yarns = model.nodes, model.yarns
    first_node, first_seg = nodes.ply_nodes[:-1], yarns.ply_segments[:-1]
    broken = state.seg_alpha < model.material.broken_below
    row[lay["broken_yarns_per_ply"]] = np.add.reduceat(broken.astype(np.int64), first_seg)
    row[lay["max_deflection_per_ply"]] = np.maximum.reduceat(
        np.abs(state.node_x[2] - nodes.x0[2]), first_node)
    if contacts is not None:
        row[lay["contact_nodes_per_ply"]] = contacts
    else:
        touching = state.node_contact[3] != 0.0
        row[lay["contact_nodes_per_ply"]] = np.add.reduceat(touching.astype(np.int64),
                                                            first_node)



def measure(model: Model, state: State, row: np.ndarray,
            fabric: np.ndarray | None = None,
            contacts: np.ndarray | None = None) -> FabricDiagnostics:
    """Fill `row` (row_width(model.ply_count) columns) with the history record of `state` (the
    order of RECORD, then PLY_RECORD) and return the fabric diagnostics it was made from.
    fabric: those diagnostics (the kernel's order) where the step that wrote the state
    computed them (the integrator's fabric_of), else they are computed here; contacts: the
    nodes in contact per ply where the integrator counted them (its contacts_of)."""
    return _record(model, state, row, state.energy_initial, fabric, contacts)[0]


def held_nodes(model: Model, alpha: np.ndarray) -> np.ndarray:
    """Nodes the fabric still holds: joined by intact yarns to a clamped node (free edges: the
    largest piece; one union-find pass either way). The rest are fragments — a lone node or a
    piece of yarn torn out — that the projectile may carry along while the fabric they came
    from is behind."""
    ends = model.yarns.ends
    intact = (alpha >= model.material.broken_below) & (model.yarns.stiffness > 0.0)
    fixed = (model.nodes.inv_mass == 0.0) & (model.nodes.mass > 0.0)
    out = np.zeros(model.node_count, dtype=bool)
    if fixed.any():
        _k.joined_to(ends, intact, fixed, out)
        return out
    # free edges: the largest piece
    root = np.empty(model.node_count, dtype=np.int64)
    _k.piece_roots(ends, intact, root)
    if not (root >= 0).any():
        return out
    largest = int(np.bincount(root[root >= 0]).argmax())
    return root == largest


def through_the_pack(model: Model, state: State, check_every: int = 1) -> bool:
    """Whether the projectile has gone through the fabric carrying a plug: moving forward, its
    centre past the pack's last plane and every node still held by an intact yarn behind it by
    more than its bounding radius, none of them following faster than it moves on. Loose
    fragments (held_nodes: pieces no longer joined to the frame) may still touch it. A cheap
    test first (the centre's depth), the nodes only after it, and during a run only every
    `check_every` force evaluations (the stop is then at most that many steps late)."""
    if not model.has_body:
        return False
    # the step count first: it is the cheapest test, and the result does not depend on the
    # order of the tests (each alone says False)
    if check_every > 1 and int(state.evaluations) % check_every:
        return False
    d = model.flight_direction
    vb = float(state.body_v @ d)
    clear = 1.05 * model.geometry.bound
    back = float(model.nodes.x0[2, model.nodes.ply_nodes[-2]])
    if not vb > 0.0 or float((state.body_x - np.array([0.0, 0.0, back])) @ d) <= clear:
        return False
    held = held_nodes(model, state.seg_alpha)
    if not held.any():
        return True
    ahead = (state.node_x[:, held] - state.body_x[:, None]).T @ d
    follow = state.node_v[:, held].T @ d
    return bool(ahead.max() < -clear and follow.max() < vb)


THROUGH_EVERY = 16
"""The stop rule looks for a projectile through the pack with a plug every this many steps."""


def left_for_good(model: Model, state: State, fab: FabricDiagnostics) -> str | None:
    """'rebound' or 'perforation' once no node can reach the projectile any more (the run's
    stop rule), else None. A projectile that carries a plug of broken yarn (loose nodes still
    in contact) has perforated once the fabric that holds together is behind it
    (through_the_pack). A sheet that keeps ringing faster than the projectile recedes (a charged
    sheet in a magnetic field) lets it go once its energy cannot carry a node to it
    (emfabric.sim.reach.out_of_reach)."""
    if not model.has_body:
        return None
    if state.contact_count > 0:
        if state.contact_steps and through_the_pack(model, state, THROUGH_EVERY):
            return "perforation"
        return None
    vb = float(state.body_v @ model.flight_direction)
    clear = 1.05 * model.geometry.bound
    if vb < 0 and fab.ahead_min > clear and fab.approach_max < -vb:
        return "rebound" if state.contact_steps else "never touched"
    if vb > 0 and fab.ahead_max < -clear and fab.recede_max < vb:
        return "perforation" if state.contact_steps else "never touched"
    if vb > 0 and state.contact_steps and through_the_pack(model, state, THROUGH_EVERY):
        return "perforation"
    if vb != 0 and out_of_reach(model, state, fab.kinetic_energy, fab.strain_energy):
        # the sheet still moves faster than the projectile recedes, but its energy can no
        # longer carry any node to it (emfabric.sim.reach)
        if not state.contact_steps:
            return "never touched"
        return "rebound" if vb < 0 else "perforation"
    return None


ENERGY_BALANCE_FRACTION = 0.05
"""A run whose energy balance error exceeds this fraction of the energy put in has diverged."""
ENERGY_FLOOR = 1e-9
"""[J] added to the energy put in (a run at rest has none)."""
SPEED_FACTOR = 100.0
"""A speed above this many times the fastest plausible one (initial speeds, yarn wave speed)."""
SIZE_FACTOR = 1000.0
"""A position farther than this many times the scene's size from the origin."""
STRETCH_LIMIT = 100.0
"""A yarn stretched beyond U = L/L0 = 100."""


class Limits(NamedTuple):
    """The bounds of plausible motion for one model (check_plausible)."""

    speed: float
    """[m/s]"""
    distance: float
    """[m]"""


def wave_speed(rest_length: np.ndarray, stiffness: np.ndarray, lightest: float) -> float:
    """The fastest longitudinal wave of yarn segments, max L0·√(k/m) with m the lightest free
    node [m/s]; √k/√m, so that absurd scales give a large number rather than an overflow."""
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        return float((rest_length * np.sqrt(stiffness)).max() / math.sqrt(lightest))


def limits(model: Model) -> Limits:
    nodes, yarns = model.nodes, model.yarns
    free = nodes.inv_mass > 0
    # longitudinal wave speed of the yarn network, L0·sqrt(k/m), the fastest a disturbance runs
    m = float(nodes.mass[free].min()) if free.any() else float(nodes.mass.min())
    wave = wave_speed(yarns.rest_length, yarns.stiffness, m)
    spin = float(np.linalg.norm(model.body_w0)) * model.geometry.bound if model.has_body else 0.0
    fastest = max(wave, float(np.linalg.norm(model.body_v0)), spin,
                  float(np.abs(model.node_v0).max(initial=0.0)) * 3 ** 0.5)
    size = float(np.abs(nodes.x0).max()) + float(np.linalg.norm(model.body_x0)) \
        + model.geometry.bound
    return Limits(SPEED_FACTOR * fastest, SIZE_FACTOR * size)


def _apart(value: float, limit: float) -> tuple[str, str]:
    """value and limit (value > limit) with the fewest significant digits, at least 3, that
    show them apart ("180.02 beyond 180", not "180 beyond 180")."""
    for digits in range(3, 18):
        a, b = f"{value:.{digits}g}", f"{limit:.{digits}g}"
        if a != b:
            return a, b
    return f"{value!r}", f"{limit!r}"


def check_plausible(model: Model, state: State, row: np.ndarray, lim: Limits) -> str | None:
    """Why the state just recorded is not physical (non-finite values, an energy balance error
    beyond ENERGY_BALANCE_FRACTION of the energy put in, motion beyond the limits), else None."""
    # called every step: a non-finite sum first (every value finite then), plain floats after
    if not math.isfinite(float(row.sum())):
        bad = ~np.isfinite(row)
        if bad.any():
            names = [n for n, (w, _u, _l) in RECORD.items() if bad[LAYOUT[n]].any()]
            return f"non-finite values in {', '.join(names[:4])}"
    energy = state.energy
    energy_in = (abs(state.energy_initial) + abs(energy.item(ENERGY_WORK_FIELD))
                 + abs(energy.item(ENERGY_WORK_GRAVITY)) + ENERGY_FLOOR)
    balance = row.item(COL_BALANCE)
    # the φ-scheme with φ > 1/2 dissipates by design (backward Euler at φ = 1: after n steps
    # of a constant force a fraction 1/(n + 1) of its work, docs/theory.md §11): a loss is the
    # scheme's, and only energy gained is a sign of divergence
    dissipative = model.options.integrator == "phi" and model.options.phi > 0.5
    if (balance if dissipative else abs(balance)) > ENERGY_BALANCE_FRACTION * energy_in:
        return (f"energy balance error {balance:.3g} J exceeds "
                f"{ENERGY_BALANCE_FRACTION:.0%} of the energy put in ({energy_in:.3g} J)")
    if model.has_body:
        v = math.hypot(*state.body_v.tolist())
        x = math.hypot(*state.body_x.tolist())
        if v > lim.speed:
            a, b = _apart(v, lim.speed)
            return f"projectile speed {a} m/s beyond the plausible {b} m/s"
        if x > lim.distance:
            a, b = _apart(x, lim.distance)
            return f"projectile {a} m from the origin, beyond the plausible {b} m"
    defl = row.item(COL_DEFLECTION)
    if defl > lim.distance:
        a, b = _apart(defl, lim.distance)
        return f"fabric deflection {a} m beyond the plausible {b} m"
    stretch = row.item(COL_STRETCH)
    if stretch > STRETCH_LIMIT:
        return f"yarn stretch U = {stretch:.3g} beyond the plausible {STRETCH_LIMIT:g}"
    return None
