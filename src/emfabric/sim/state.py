"""State (everything a step writes) and the initial State of a Model: t = 0, the scenario's
positions and velocities, ψ(0) and the energy reference. (States after that are written by the
integrator or read from a checkpoint.)"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from emfabric._kernels.body import field_wrench
from emfabric._kernels.diagnostics import total_energy
from emfabric._kernels.fields import fill_node_fields
from emfabric._kernels.nodes import ROWBUF_ROWS, _kick_block
from emfabric._kernels.records import (
    BODY_F,
    BODY_M,
    BODY_R0,
    BODY_ROWS,
    BODY_V,
    BODY_W,
    BODY_X,
    ENERGY_TERMS,
    StateArrays,
    make_work,
    row_records,
)
from emfabric.sim.model import Model


@dataclass(eq=False)
class State:
    """Everything a step writes; a checkpoint is just a State."""

    t: float
    """Time [s]."""
    dt: float
    """Next step size to try (the controller's state) [s]."""
    node_x: np.ndarray
    """Node positions [m], shape (3, node_count)."""
    node_v: np.ndarray
    """Node velocities [m/s], shape (3, node_count)."""
    node_f: np.ndarray
    """Non-impulsive force on each node at time t (ψ(t) of the φ-scheme) [N], (3, node_count)."""
    node_e: np.ndarray
    """The electric field [V/m] in each node's ψ(t), (3, node_count): the energy bookkeeping's
    field work uses the field the φ-update used (emfabric._kernels.energy)."""
    seg_alpha: np.ndarray
    """Committed yarn damage α (1 intact, 0 broken), shape (seg_count,)."""
    body: np.ndarray
    """Rigid body, shape (BODY_ROWS, 3): the rows of emfabric._kernels.records (x [m], v [m/s],
    ω [rad/s], F [N], M [N m] (non-impulsive force and moment at t), rotation matrix)."""
    node_contact: np.ndarray
    """Each node's contact at t (central differences; zeros for the φ-scheme), (4,
    node_count): rows 0–2 the body-frame point it sticks to [m], row 3 its mode (0 none,
    contact.STICK, contact.SLIDE): a node that sticks is put where that material point has
    moved to in the next step."""
    node_fv: np.ndarray = field(default_factory=lambda: np.zeros((3, 0)))
    """The viscous part of node_f (central differences with solver.bulk_viscosity) [N], (3,
    node_count): the next half kick books its work; (3, 0) without viscosity."""
    seg_strain: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """Each segment's averaged stretch² (brittle yarns with fabric.damage.strain_averaging:
    records.Yarns.averaging_rate), (seg_count,); (0,) where it is not kept."""
    seg_contact: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """Each segment's contact mode with the projectile at t (0 none, contact.STICK,
    contact.SLIDE), (seg_count,): central differences with contact.segments, whose segments
    that slid stop only where kinetic friction stops them; (0,) otherwise."""
    steps: int = 0
    """Accepted steps so far."""
    rejected: int = 0
    """Rejected attempts so far."""
    evaluations: int = 0
    """Force evaluations so far."""
    iterations: int = 0
    """Fixed-point iterations of the last accepted step."""
    error: float = 0.0
    """ϖ_K of the last accepted step."""
    last_dt: float = 0.0
    """The last accepted step [s]."""
    contact_count: int = 0
    """Distinct fabric nodes in contact with the projectile after the last step: touching it,
    or an end of a yarn segment that touches it (history: contact_nodes)."""
    contact_segments: int = 0
    """Yarn segments in contact with the projectile after the last step (contact.segments;
    history: contact_segments)."""
    contact_steps: int = 0
    """Accepted steps that ended with a node in contact (0: the projectile never touched)."""
    energy: np.ndarray = field(default_factory=lambda: np.zeros(len(ENERGY_TERMS)))
    """Cumulative energy terms [J], see ENERGY_TERMS."""
    contact_force: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """Total contact + friction force on the body over the last step, ΣJ/Δt [N]."""
    energy_initial: float = math.nan
    """Total energy of the initial state [J] (reference of the energy balance)."""

    @property
    def arrays(self) -> StateArrays:
        """The arrays a step kernel reads or writes, as a named record."""
        return StateArrays(self.node_x, self.node_v, self.node_f, self.seg_alpha, self.body,
                           self.node_e, self.node_contact, self.node_fv, self.seg_strain,
                           self.seg_contact)

    @property
    def body_x(self) -> np.ndarray:
        return self.body[BODY_X]

    @property
    def body_v(self) -> np.ndarray:
        return self.body[BODY_V]

    @property
    def body_omega(self) -> np.ndarray:
        return self.body[BODY_W]

    @property
    def body_rotation(self) -> np.ndarray:
        return self.body[BODY_R0:BODY_R0 + 3]

    def copy(self) -> State:
        return State(**{f.name: (v.copy() if isinstance(v, np.ndarray) else v)
                        for f in fields(self) for v in [getattr(self, f.name)]})


def initial_state(model: Model) -> State:
    """A fresh State at t = 0 with the non-impulsive forces ψ(0) on nodes and body (the first
    step's explicit part) and the total energy that the energy balance is measured against."""
    m = model
    st = blank_state(m)
    update_forces(m, st)
    st.energy_initial = float(total_energy(m.physics, st.node_x, st.node_v, st.seg_alpha,
                                           st.body, st.energy, st.body[BODY_X],
                                           m.flight_direction))
    return st


def blank_state(model: Model) -> State:
    """The State at t = 0 before its forces are computed (initial_state computes them): the
    initial positions, velocities and body, zero forces, intact yarns."""
    m = model
    n, s = m.node_count, m.seg_count
    st = State(
        t=0.0,
        dt=m.options.dt_initial,
        node_x=m.nodes.x0.copy(),
        node_v=m.node_v0.copy(),
        node_f=np.zeros((3, n)),
        node_e=np.zeros((3, n)),
        seg_alpha=np.ones(s),
        body=np.zeros((BODY_ROWS, 3)),
        node_contact=np.zeros((4, n)),
        node_fv=np.zeros((3, n if m.physics.yarns.damping.size else 0)),
        seg_strain=np.zeros(0),
        seg_contact=np.zeros(segment_modes(m)),
    )
    if m.physics.yarns.averaging_rate.size:
        # the average starts at the initial stretch² (a slack yarn's at 1: unstrained)
        ends = m.physics.yarns.ends
        d = st.node_x[:, ends[:, 1]] - st.node_x[:, ends[:, 0]]
        st.seg_strain = np.maximum((d * d).sum(axis=0) * m.physics.yarns.inv_rest2, 1.0)
    st.body[BODY_X] = m.body_x0
    st.body[BODY_V] = m.body_v0
    st.body[BODY_W] = m.body_w0
    st.body[BODY_R0:BODY_R0 + 3] = np.eye(3)
    return st


def segment_modes(model: Model) -> int:
    """The length of State.seg_contact: the segment count where central differences resolve
    segment contact (they keep each segment's stick or slide), else 0."""
    keep = model.physics.contact.segments and model.options.integrator == "central-difference"
    return model.seg_count if keep else 0


def update_forces(model: Model, state: State) -> None:
    """Set the non-impulsive forces ψ(x, v, t) of the state's positions and velocities on nodes
    (yarn + Lorentz + gravity) and body (field + gravity), the explicit part of the next step.

    Central differences' force-and-kick kernel with Δt = 0 (it kicks and turns nothing) writes
    ψ, the magnetic part with v itself, and the electric field at the nodes: the same numbers as
    the φ-update with Δt = 0 and φ = 1, and the kernel a default run compiles anyway."""
    m = model
    scratch = state.copy()
    work = make_work(m.node_count, m.ny, m.seg_count,
                     m.seg_count if m.physics.contact.segments else 0, m.ply_count,
                     viscous=m.yarns.damping.size > 0)
    work.flag[:] = 0  # no contact candidates
    fill_node_fields(m.field, state.node_x, state.node_v, 0.0, state.t, work.node_field)
    start = StateArrays(state.node_x, state.node_v, np.zeros_like(state.node_f),
                        state.seg_alpha, state.body, state.node_e, state.node_contact,
                        np.zeros_like(state.node_fv), state.seg_strain, state.seg_contact)
    out = StateArrays(scratch.node_x, scratch.node_v, state.node_f, scratch.seg_alpha,
                      scratch.body, state.node_e, scratch.node_contact, state.node_fv,
                      scratch.seg_strain, scratch.seg_contact)
    # kick_rows's one row block, called from here: kick_rows itself is inlined into the step
    # kernel and never compiled on its own in a run (its docstring says why); the arguments
    # have the types kick_rows gives _kick_block, so this compiles nothing the step kernel
    # does not use (tests/test_kernel_cache.py)
    phys = m.physics
    rec = row_records(phys)
    rowbuf = np.empty((ROWBUF_ROWS, m.nx + 1))
    _kick_block(0, int(phys.nodes.ny), rec, start, out, work, state.t, 0.0, rowbuf)
    if m.has_body:
        b = state.body
        field_wrench(m.body, m.field, state.t, b, b[BODY_F], b[BODY_M])
