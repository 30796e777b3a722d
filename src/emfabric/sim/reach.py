"""Has the projectile left for good although the sheet still moves? (the stop rule's second
test, docs/theory.md §6.3).

The first test of the stop rule (diagnostics.left_for_good) asks that every node be behind the
projectile and slower than it. A charged sheet in a magnetic field keeps ringing after the
projectile has gone — its nodes gyrate faster than the projectile recedes — and that test never
passes. This one bounds where the sheet can ever be: once the applied field can do no more
work (no electric field, the magnetic one static: magnetic forces do no work), the fabric's
energy (kinetic + stored) can only fall, apart from the integrator's error (ENERGY_MARGIN;
with gravity on, the test does not apply). A clamped yarn holding a node a distance P + e from
a clamp stores at least ½ e²/C (its compliance C along that rest length P): the kernel
(emfabric._kernels.reach) turns the energy into a bound on how far along the flight direction
any node can get. When the projectile's trailing side is beyond it and nothing brings the
projectile back (no charge on it in a field), nothing can touch it again.

The bound holds for any future damage: a segment whose energy could reach the point where it
breaks (brittle) or where its damage takes its stiffness down faster than its stretch builds
energy (eq. 2.6) makes the bound give up (None); otherwise each segment's stiffness is taken at
the least value its damage can still fall to with the energy there is.
"""

from __future__ import annotations

import numpy as np

from emfabric._kernels import reach as _k
from emfabric._kernels.coils import WAVE_CONSTANT, WAVE_RAMP, WAVE_TABLE
from emfabric._kernels.records import DAMAGE_BRITTLE, MATERIAL_FUNG, Field
from emfabric.sim.model import Model
from emfabric.sim.state import State

ENERGY_MARGIN = 0.05
"""Fraction added to the fabric's energy for the integrator's energy error (the budget closes to
well below 1 % on the built-in scenarios, docs/verification.md)."""
REACH_EVERY = 64
"""The test runs every this many accepted steps (a fixed schedule: a resumed run stops at the
same step; steps rather than force evaluations, which the φ-scheme counts several at a
time)."""


def field_static_after(fld: Field, t: float) -> bool:
    """Whether the applied field does no work from time t on: no electric field (uniform or
    mapped) and every loop's current constant from t (a constant source, a ramp that has
    risen, a table past its last point; a damped sine never is)."""
    if np.any(np.asarray(fld.E) != 0.0) or (fld.map_axes is not None and fld.map_has_e):
        return False
    for k in range(fld.currents.shape[0]):
        wave = fld.currents[k]
        kind = int(wave[0])
        if kind == WAVE_CONSTANT:
            continue
        if kind == WAVE_RAMP and t >= wave[2] + wave[3]:
            continue
        if kind == WAVE_TABLE and t >= fld.tables[k, int(fld.table_len[k]) - 1, 0]:
            continue
        return False
    return True


def field_is_zero(fld: Field) -> bool:
    """No applied field at all (E, B, loops, magnets, map)."""
    return (not np.any(np.asarray(fld.E) != 0.0) and not np.any(np.asarray(fld.B) != 0.0)
            and fld.loops is None and fld.magnets.shape[0] == 0 and fld.map_axes is None
            and fld.grid_values is None)


def lower_stiffness(model: Model, alpha: np.ndarray, energy: float) -> np.ndarray | None:
    """Each segment's least axial stiffness [N/m] while the fabric holds at most `energy`: the
    linear spring below its law (KSV: 𝔼A0/L0; Fung: c·H·A0/L0) times the least damage α it
    can fall to; 0 for a broken segment. None when some segment could break or soften
    without bound with that energy (_kernels.reach.least_stiffness)."""
    mat, yarns = model.material, model.yarns
    k = yarns.stiffness * (mat.fung_h if mat.kind == MATERIAL_FUNG else 1.0)
    brittle = mat.damage_law == DAMAGE_BRITTLE
    fail2 = yarns.failure_stretch2 if brittle else np.zeros(1)
    out = np.empty_like(k)
    if not _k.least_stiffness(alpha, k, yarns.rest_length ** 2, brittle, mat.damage_rate,
                              mat.critical_stretch, fail2, energy, out):
        return None
    return out


def fabric_energy_bound(kinetic: float, strain: float) -> float:
    """[J] The most energy the fabric can hold from now on (no work done on it): its kinetic
    and stored energy and the margin for the integrator's error."""
    return (1.0 + ENERGY_MARGIN) * (kinetic + strain)


def reach_along(model: Model, state: State, direction: np.ndarray, energy: float,
                limit: float) -> float:
    """A bound on the largest x·direction any node of the fabric can ever reach with at most
    `energy` (+inf when it cannot be bounded or passes `limit`; below `limit` it may be looser
    than the tightest: _kernels.reach.fabric_reach)."""
    nodes = model.nodes
    if not np.any(nodes.inv_mass == 0.0):
        return float("inf")
    e = np.ascontiguousarray(direction, dtype=float)
    first = int(np.argmax(e @ state.node_x))  # the node farthest out now: tried first

    def bound(keff: np.ndarray) -> float:
        return float(_k.fabric_reach(nodes.rows, nodes.ply_rows, nodes.x0, nodes.inv_mass,
                                     model.yarns.rest_length, keff, energy, e, limit, first))

    # first with today's damage: softer yarns only reach farther, so a fail here is final
    # and costs no search for the damage to come
    mat = model.material
    k = model.yarns.stiffness * (mat.fung_h if mat.kind == MATERIAL_FUNG else 1.0)
    if bound(np.where(state.seg_alpha > 0.0, state.seg_alpha * k, 0.0)) > limit:
        return float("inf")
    keff = lower_stiffness(model, state.seg_alpha, energy)
    if keff is None:
        return float("inf")
    return bound(keff)


def out_of_reach(model: Model, state: State, kinetic: float, strain: float) -> bool:
    """Whether the projectile, out of contact, has left the fabric for good although nodes may
    still move faster than it (module docstring). Runs every REACH_EVERY accepted steps."""
    if not model.has_body or state.contact_count > 0:
        return False
    if int(state.steps) % REACH_EVERY:
        return False
    fld = model.field
    if not field_static_after(fld, state.t):
        return False
    if np.any(model.body.charge != 0.0) and not field_is_zero(fld):
        return False
    vb = float(state.body_v @ model.flight_direction)
    if vb == 0.0:
        return False
    away = model.flight_direction * np.sign(vb)
    if np.any(np.asarray(fld.gravity) != 0.0):
        return False  # gravity works on the sheet (and may bring the projectile back)
    trailing = float(state.body_x @ away) - 1.05 * model.geometry.bound
    if not float((state.node_x.T @ away).max()) < trailing:
        return False
    energy = fabric_energy_bound(kinetic, strain)
    return reach_along(model, state, away, energy, trailing) < trailing
