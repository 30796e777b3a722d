"""Central differences: explicit, one force evaluation per step (emfabric._kernels.explicit).

Δt = min(courant × the stability limit of the current state (× √(1 + q²) − q with the yarns'
bulk viscosity q), the no-tunnelling limit, dt_max, what is left to the end), recomputed every
step: the limit 2/ω_max follows the yarns as they stretch or break (explicit.stable_step) and
the charged nodes' gyration in B (records.GYRATION_TURN: ω ≥ 2 ω_c/GYRATION_TURN), the
no-tunnelling limit keeps the body from moving more than a quarter of its radius relative to
the fabric per step (explicit.travel_step). A step whose body rotation does not converge or
that leaves a free node inside the body is retried at half the step; a non-finite step is a
DivergenceError.
"""

from __future__ import annotations

import math
import time

import numba
import numpy as np

from emfabric._kernels.contact import travel_step
from emfabric._kernels.explicit import (
    BODY_NOT_CONVERGED,
    CONTACT_MISSED,
    NOT_FINITE,
    OK,
    central_step,
    stable_step,
)
from emfabric._kernels.fields import fill_node_fields
from emfabric._kernels.records import GYRATION_TURN, make_work, ply_box_size
from emfabric.integrators.base import IntegratorBase, StepInfo
from emfabric.sim.fastcall import Direct
from emfabric.sim.model import Model
from emfabric.sim.state import State

RETRIES = 30
"""Halvings of a step before the run is declared diverged."""
ROTATION_TOLERANCE = 1e-12
"""Relative tolerance of the body's mid-step rotation (eq. B16)."""


class CentralDifference(IntegratorBase):
    """Central differences for one Model."""

    name = "central-difference"

    def __init__(self, model: Model, *, threads: bool | None = None, adaptive: bool = False):
        """threads: use the row-block threaded node kernels (default: as the φ-scheme, for
        sheets of at least phi.THREADS_FROM_NODES nodes when Numba has more than one thread);
        the numbers are the same either way. adaptive: choose between them and the serial
        kernels by timing both (IntegratorBase)."""
        from emfabric.integrators.phi import THREADS_FROM_NODES

        if threads is None:
            threads = (model.node_count >= THREADS_FROM_NODES
                       and numba.config.NUMBA_NUM_THREADS > 1)
        super().__init__(model, threads=threads, adaptive=adaptive)
        opts = model.options
        self.courant = opts.courant
        # the yarns' viscosity shortens the stable step: for damping ratio ξ of the highest
        # mode 2/ω (√(1 + ξ²) − ξ); ξ ≤ q (builder._damping; less where yarns are stretched)
        q = opts.bulk_viscosity
        self.viscous_factor = math.sqrt(1.0 + q * q) - q
        self.dt_max = opts.dt_max
        self.dt_min = opts.dt_min
        self.work = make_work(model.node_count, model.ny, model.seg_count,
                              model.seg_count if model.physics.contact.segments else 0,
                              model.ply_count,
                              ply_box_size(model.physics.contact.ply_box),
                              viscous=model.yarns.damping.size > 0)
        self.work.frame[1] = model.flight_direction
        self.scratch = np.empty(model.node_count)
        self._measured: State | None = None  # the state work.diag belongs to
        self._measured_steps = -1
        self._step = Direct(central_step)
        self._stable = Direct(stable_step)
        self._travel = Direct(travel_step)

    def variant(self, threaded: bool | None = None) -> str:
        threaded = self.threaded if threaded is None else threaded
        return (f"central-difference-{'threads' if threaded else 'serial'}"
                + self.switch_suffix())

    def precompile_targets(self, state: State) -> list[tuple]:
        """The serial step kernel's largest callees, with arguments of the types it passes
        them (the records, the state's arrays, float64 times, an int64 count); a type that
        differs only costs the compile here again (tests/test_kernel_cache.py checks them)."""
        from emfabric._kernels.contact import segment_contact
        from emfabric._kernels.explicit import (
            _body_field_work,
            _friction_work,
            _mid_rotation,
            _node_contact,
            _travel_from_rows,
        )
        from emfabric._kernels.nodes import ROWS_PER_BLOCK, _drift_block
        from emfabric._kernels.plies import ply_contact
        from emfabric._kernels.records import BODY_R0

        a, phys, work = state.arrays, self.physics, self.work
        # the drift's row block (drift_rows is inlined into the step kernel; 0 and
        # ROWS_PER_BLOCK: int64 row bounds, as drift_rows passes them)
        rec, rowbuf = self._serial_rows()
        out = [(_drift_block, (0, ROWS_PER_BLOCK, rec, a, a, work, 0.0, 0.0, rowbuf)),
               (_node_contact, (phys, a, a, work, 0, 0.0))]
        plies, segs = self.switches
        if plies is not None:
            out.append((ply_contact, (phys, a, a.x, a.v, work, 0.0, a.contact[3])))
        if segs is not None:
            out.append((segment_contact, (phys, a.body, 0, 0, a.x, a.v, work, 0.0,
                                          a.seg_contact, a.seg_contact)))
        out += [(stable_step, (phys, a.x, a.alpha, self.scratch)),
                (travel_step, (phys, a.x, a.v, a.body))]
        # then what the step kernel's own compile reaches after them, in its order: the run
        # gets there after the force kernel and the initial state's record (the second
        # process's list above is done by then, docs/performance.md "The first run")
        rot = a.body[BODY_R0:BODY_R0 + 3]
        out += [(_mid_rotation, (phys.body, rot, (0.0, 0.0, 0.0), 0.0, ROTATION_TOLERANCE,
                                 work.body_scratch, rot)),
                (_friction_work, (phys, a, a, work, 0, 0.0, (0.0, 0.0, 0.0))),
                (_body_field_work, (phys, a.body, a.body, 0.0, 0.0)),
                (_travel_from_rows, (phys, work.row_sums, phys.nodes.ny, a.body))]
        return out

    def _compile_target(self, s_in: State, s_out: State, threads: np.ndarray):
        return central_step, (self.physics, s_in.arrays, s_out.arrays, self.work, None, threads,
                              *self.switches, s_in.t, 1e-9, ROTATION_TOLERANCE, s_out.energy)

    def fabric_of(self, state: State) -> np.ndarray | None:
        """The step kernel's fabric diagnostics of the state the last step wrote (its kick
        reduces them on the way: the record needs no pass of its own); None for another."""
        if state is self._measured and state.steps == self._measured_steps:
            return self.work.diag
        return None

    def stable_dt(self, state: State, crit: float | None = None,
                  travel: float | None = None) -> float:
        """The step central differences take from this state [s] (before dt_limit); crit and
        travel: the stability and no-tunnelling limits if known (the step kernel computes both
        at its end state), else explicit.stable_step and contact.travel_step."""
        if crit is None:
            crit = min(self._stable(None, self.physics, state.node_x, state.seg_alpha,
                                    self.scratch), self._gyration_limit(state))
        if travel is None:
            travel = self._travel(None, self.physics, state.node_x, state.node_v, state.body)
        return min(self.courant * self.viscous_factor * crit, travel, self.dt_max)

    def _gyration_limit(self, state: State) -> float:
        """GYRATION_TURN/ω_c [s], ω_c = |q B|/m the largest cyclotron frequency of the free
        charged nodes at the state (the step kernel takes the same limit from its own rotation
        at the end state: nodes._kick_block); inf without one."""
        nodes = self.physics.nodes
        qm = np.abs(nodes.charge) * nodes.inv_mass
        if not np.any(qm > 0.0):
            return math.inf
        # field_at at every node, whatever the field (the kernel every run's initial forces
        # call: sim.state.update_forces)
        nf = np.empty((6, state.node_x.shape[1]))
        fill_node_fields(self.physics.field, state.node_x, state.node_v, 0.0, state.t, nf)
        wc = float(np.max(qm * np.sqrt(nf[3] ** 2 + nf[4] ** 2 + nf[5] ** 2)))
        return GYRATION_TURN / wc if wc > 0.0 else math.inf

    def _which_limit(self, state: State) -> str:
        """Which limit sets the step at this state, in words (for a step below dt_min)."""
        crit = self._stable(None, self.physics, state.node_x, state.seg_alpha, self.scratch)
        gyration = self._gyration_limit(state)
        travel = self._travel(None, self.physics, state.node_x, state.node_v, state.body)
        if gyration < crit and self.courant * self.viscous_factor * gyration <= travel:
            return (f"the gyration limit {gyration:.3g} s × courant {self.courant:g}: a charged "
                    f"node may turn about B by {GYRATION_TURN:g} rad × courant a step (its "
                    "cyclotron frequency |q B|/m: check the field and the nodes' charge and "
                    "mass)")
        if self.courant * self.viscous_factor * crit <= travel:
            return (f"the stability limit 2/ω_max = {crit:.3g} s × courant {self.courant:g} "
                    + (f"× {self.viscous_factor:.3g} for the bulk viscosity "
                       if self.viscous_factor < 1.0 else "")
                    + "(the stiffest yarn over the lightest node: check the material's modulus "
                    "and the fabric's areal density)")
        return (f"the no-tunnelling limit {travel:.3g} s (the body may move a quarter of its "
                "radius relative to the fastest node a step: check the speeds and the "
                "projectile's size)")

    def step(self, s_in: State, s_out: State, *, dt_limit: float = math.inf) -> StepInfo:
        """Advance s_in by one step into s_out; s_in is left untouched. The step is the one the
        previous step computed for this state (State.dt; also in a checkpoint), or computed here
        for the initial state."""
        self._before_step()
        self._measured = None
        clock = time.perf_counter()
        step = s_in.dt if s_in.steps > 0 else self.stable_dt(s_in)
        if step < self.dt_min:
            self.fail(s_in, step, f"the explicit step {step:.3g} s is below solver.dt_min = "
                      f"{self.dt_min:g} s: {self._which_limit(s_in)}")
        dt = min(step, dt_limit)
        rejected = 0
        s_out.energy[:] = s_in.energy
        while True:
            try:
                status, nc, crit, travel = self._step(
                    self.threaded, self.physics, s_in.arrays, s_out.arrays, self.work,
                    *self.kernel_buffers, *self.switches, s_in.t, dt, ROTATION_TOLERANCE,
                    s_out.energy)
            except ArithmeticError as exc:  # a division by zero or overflow in the kernel
                self.arithmetic_failure(s_in, dt, exc)
            if status == OK:
                break
            if status == NOT_FINITE:
                self.fail(s_in, dt, "non-finite values in an explicit step (the step is "
                          f"{dt / self.courant:.3g} s × courant; the state is not physical)",
                          s_out)
            rejected += 1
            s_out.energy[:] = s_in.energy
            dt *= 0.5
            if rejected > RETRIES or dt < self.dt_min:
                what = ("the projectile's rotation (eq. B16) did not converge"
                        if status == BODY_NOT_CONVERGED else
                        "a fabric node inside the projectile" if status == CONTACT_MISSED
                        else f"status {status}")
                self.fail(s_in, dt, f"{what} even at Δt = {dt:.3g} s")
        s_out.t = s_in.t + dt
        s_out.energy_initial = s_in.energy_initial
        s_out.steps = s_in.steps + 1
        self._count_contacts(s_out, nc)
        s_out.rejected = s_in.rejected + rejected
        s_out.evaluations = s_in.evaluations + 1 + rejected
        s_out.iterations = 1
        s_out.error = 0.0
        s_out.last_dt = dt
        s_out.contact_steps = s_in.contact_steps + (1 if nc > 0 else 0)
        s_out.contact_force[:] = self.work.reaction[0] / dt
        s_out.dt = self.stable_dt(s_out, crit, travel)
        self._measured, self._measured_steps = s_out, s_out.steps
        self._after_step(time.perf_counter() - clock)
        return StepInfo(t=s_out.t, dt=dt, iterations=1, error=0.0, rejected=rejected,
                        evaluations=1 + rejected, contacts=nc)


__all__ = ["CentralDifference"]
