"""The initial State of a Model: t = 0, the scenario's positions and velocities, ψ(0) and the
energy reference. (States after that are written by the integrator or read from a checkpoint.)"""

from __future__ import annotations

import numpy as np

from emfabric._kernels.body import field_wrench
from emfabric._kernels.fields import electric_at_nodes, fill_node_fields
from emfabric._kernels.nodes import ROWBUF_ROWS, fused_iterate
from emfabric._kernels.records import (
    BODY_F,
    BODY_M,
    BODY_R0,
    BODY_ROWS,
    BODY_V,
    BODY_W,
    BODY_X,
    make_work,
)
from emfabric.diagnostics import total_energy
from emfabric.model import Model, State


def initial_state(model: Model) -> State:
    """A fresh State at t = 0 with the non-impulsive forces ψ(0) on nodes and body (the first
    step's explicit part) and the total energy that the energy balance is measured against."""
    m = model
    n, s = m.node_count, m.seg_count
    solver = m.scenario.solver
    st = State(
        t=0.0,
        dt=solver.dt_initial or solver.dt_max,
        node_x=m.nodes.x0.copy(),
        node_v=m.node_v0.copy(),
        node_f=np.zeros((3, n)),
        node_e=np.zeros((3, n)),
        seg_alpha=np.ones(s),
        body=np.zeros((BODY_ROWS, 3)),
    )
    st.body[BODY_X] = m.body_x0
    st.body[BODY_V] = m.body_v0
    st.body[BODY_W] = m.body_w0
    st.body[BODY_R0:BODY_R0 + 3] = np.eye(3)
    update_forces(m, st)
    st.energy_initial = total_energy(m, st)
    return st


def update_forces(model: Model, state: State) -> None:
    """Set the non-impulsive forces ψ(x, v, t) of the state's positions and velocities on nodes
    (yarn + Lorentz + gravity) and body (field + gravity), the explicit part of the next step.

    The node update with Δt = 0 and φ = 1 returns v1 = v and ψ in its force output."""
    m = model
    n = m.node_count
    scratch = state.copy()
    work = make_work(m.nx, m.ny, m.seg_count if m.physics.contact.segments else 0)
    fill_node_fields(m.field, state.node_x, state.node_v, 0.0, state.t, work.node_field)
    fused_iterate(m.nodes, m.yarns, m.material, m.field, work.node_field, state.node_x,
                  state.node_x, state.node_v, np.zeros_like(state.node_f), state.seg_alpha,
                  scratch.seg_alpha, work.damage_thr, scratch.node_x, scratch.node_v,
                  state.node_f, np.ones(n, dtype=np.uint8), work.err_rows, work.err_num,
                  work.err_den, state.t, 1.0, 0.0, np.empty((ROWBUF_ROWS, m.nx + 1)))
    electric_at_nodes(m.field, work.node_field, state.node_x, state.t, state.node_e)
    if m.has_body:
        b = state.body
        field_wrench(m.body, m.field, state.t, b, b[BODY_F], b[BODY_M])
