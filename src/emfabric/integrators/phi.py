"""The φ-scheme with fixed-point iteration and adaptive Δt (section 3, eqs. 3.2–3.10).

``Integrator(model).step(s_in, s_out)`` advances one accepted step: it attempts Δt = s_in.dt,
and on failure shrinks Δt by the controller (3.9) and restarts from t (s_in is never written).
"""

from __future__ import annotations

import logging
import math
import time

import numba
import numpy as np

from emfabric._kernels.contact import travel_step
from emfabric._kernels.energy import step_energy
from emfabric._kernels.records import Solver, make_work
from emfabric._kernels.step import (
    BODY_NOT_CONVERGED,
    CONTACT_MISSED,
    CONVERGED,
    NOT_CONVERGED,
    NOT_FINITE,
    attempt_step,
)
from emfabric.integrators.base import DivergenceError, IntegratorBase, StepInfo
from emfabric.sim.fastcall import Direct
from emfabric.sim.model import Model
from emfabric.sim.state import State

log = logging.getLogger(__name__)


def step_factor(error: float, k: int, tol: float, k_target: int, p: float) -> float:
    """Φ_K of eq. 3.9 with ϖ_0 = 1: (TOL)^(1/(p K_d)) / (ϖ_K)^(1/(p K)). A tiny exponent p can
    put a power beyond a double's range: the factor is then inf (the denominator underflows to
    0) or 0 (it overflows)."""
    if error <= 0.0:
        return math.inf
    try:
        below = error ** (1.0 / (p * k))
    except OverflowError:
        return 0.0
    if below == 0.0:
        return math.inf
    return tol ** (1.0 / (p * k_target)) / below


THREADS_FROM_NODES = 250 * 250
"""Sheets with at least this many nodes use the threaded kernel by default (make_integrator,
default_threads); smaller ones the serial kernel, which is not slower idle and much faster on a
loaded machine."""


class Integrator(IntegratorBase):
    """The φ-scheme: holds the workspace of the step kernel for one Model."""

    name = "phi"

    def __init__(self, model: Model, *, threads: bool | None = None, adaptive: bool = False):
        """threads: use the row-block threaded kernel (default: for sheets of at least
        THREADS_FROM_NODES nodes when Numba has more than one thread); adaptive: choose
        between it and the serial kernel by timing both (IntegratorBase).

        A pack of plies meets with the penalty law of plies.ply_forces (docs/theory.md §5.1)."""
        n = model.node_count
        # threads pay off on large sheets only; block size fixed, so results never depend on them
        super().__init__(model, threads=threads if threads is not None else (
            n >= THREADS_FROM_NODES and numba.config.NUMBA_NUM_THREADS > 1), adaptive=adaptive)
        self.work = make_work(model.node_count, model.ny, model.seg_count,
                              model.seg_count if model.physics.contact.segments else 0,
                              model.ply_count)
        solver = model.options
        # None for the plain fixed point: the step kernel is then compiled without Anderson
        self.accel = None
        if solver.scheme == "anderson":
            depth = solver.anderson_depth
            self.accel = (np.empty((3, n)), np.empty((depth, 3, n)), np.empty((depth, 3, n)),
                          np.empty((3, n)), np.empty((3, n)), np.zeros((depth, depth)))
        # K_d of eq. 3.9 and the iteration limit of one attempt
        k_target = solver.target_iterations if solver.adaptive else solver.max_iterations
        self.solver = Solver(float(solver.phi), float(solver.tolerance), int(k_target),
                             solver.predictor == "explicit")
        # the same with max_iterations: for a collision whose contraction no step size improves
        # (step's docstring)
        self.patient_solver = self.solver._replace(
            iteration_limit=max(int(k_target), int(solver.max_iterations)))
        self._told_patient = False
        self.p = solver.exponent
        self.safety = solver.safety
        self.adaptive = solver.adaptive
        self.dt_max = solver.dt_max
        self.dt_min = solver.dt_min
        # the step and energy kernels without the per-call type dispatch (fastcall)
        self._attempt = Direct(attempt_step)
        self._energy = Direct(step_energy)
        self._travel = Direct(travel_step)

    def variant(self, threaded: bool | None = None) -> str:
        """Name of the compiled step kernel this integrator runs (or would run threaded)."""
        threaded = self.threaded if threaded is None else threaded
        return (f"{'threads' if threaded else 'serial'}-"
                f"{'anderson' if self.accel is not None else 'fixed-point'}"
                + self.switch_suffix())

    def precompile_targets(self, state: State) -> list[tuple]:
        """The serial step kernel's largest callees and the step's energy kernel, for the
        second process of a cold start (runner.precompile), with arguments of the types the
        run passes them (the records, the state's arrays, float64 times and weights, int64
        counts, a bool); a type that differs only costs the compile here again
        (tests/test_kernel_cache.py checks them). In the order the run reaches them: the row
        block of the φ-update first (fused_iterate is inlined into the step kernel), the
        no-tunnelling limit the run takes before its first attempt, then contact, the body and
        the energy of the accepted step."""
        from emfabric._kernels.body import body_update
        from emfabric._kernels.contact import node_contact, segment_contact
        from emfabric._kernels.nodes import ROWS_PER_BLOCK, _row_block
        from emfabric._kernels.plies import ply_forces
        from emfabric._kernels.step import ply_update

        a, phys, work = state.arrays, self.physics, self.work
        phi, dt, t = self.solver.phi, 0.0, 0.0
        rec, rowbuf = self._serial_rows()
        out = [(_row_block, (0, ROWS_PER_BLOCK, rec, a.x, a, a, work, t, phi, dt, rowbuf)),
               (travel_step, (phys, a.x, a.v, a.body))]
        plies, segs = self.switches
        if plies is not None:
            out += [(ply_forces, (phys, a.x, a.v, a.v, work, work.ply_force, phi * dt)),
                    (ply_update, (phys, work, a.x, a.v, a.f, a.x, a.x, phi, dt))]
        out.append((node_contact, (phys.nodes, phys.body, phys.contact, a.body, 0, a.x, a.v,
                                   work, phi, dt, False)))
        if segs is not None:
            out.append((segment_contact, (phys, a.body, 0, 0, a.x, a.v, work, 0.0,
                                          a.seg_contact, a.seg_contact)))
        out += [(body_update, (phys.body, phys.field, a.body, a.body, t, phi, dt, work.reaction,
                               work.body_scratch, self.solver.tolerance)),
                (step_energy, (phys, a, a, 0, work, t, phi, dt, state.energy))]
        return out

    def _compile_target(self, s_in: State, s_out: State, threads: np.ndarray):
        return attempt_step, self._args(s_in, s_out, 0.0, None, threads)

    def _args(self, s_in: State, s_out: State, dt: float, rowbuf, threads,
              solver: Solver | None = None) -> tuple:
        return (self.physics, self.solver if solver is None else solver, s_in.arrays,
                s_out.arrays, self.work, rowbuf, threads, *self.switches, s_in.t, dt, self.accel)

    def step(self, s_in: State, s_out: State, *, dt_limit: float = math.inf) -> StepInfo:
        """Advance s_in by one accepted step into s_out; s_in is left untouched.

        The adaptive controller (eq. 3.9) cuts Δt when an attempt has not converged in K_d
        iterations. Contact impulses make that fail for a collision of a light body with
        several yarns at once (a 1 g wire across three segments): the fixed point's
        contraction is then about the struck mass over the body's, whatever Δt, and cutting
        Δt to dt_min does not help. Before it would fail, the step is tried again from its
        first Δt with up to solver.max_iterations iterations ("patient"); the next step starts
        patient too while the previous one needed more than K_d iterations (State.iterations,
        so a resumed run does the same), its Δt from eq. 3.9 with max_iterations in place of
        K_d. A run whose steps converge within K_d iterations, as the paper's do, is unchanged
        to the bit."""
        self._before_step()
        clock = time.perf_counter()
        # no tunnelling: the body moves at most contact.CONTACT_TRAVEL of its radius relative
        # to the fabric per step (far above the controller's step in the paper's scenarios)
        travel = self._travel(None, self.physics, s_in.node_x, s_in.node_v, s_in.body)
        dt = min(s_in.dt, dt_limit, travel)
        tol, k_d = self.solver.tolerance, self.solver.iteration_limit
        can_wait = self.adaptive and self.patient_solver.iteration_limit > k_d
        patient = can_wait and s_in.iterations > k_d
        first_dt = dt
        rejected = 0
        evaluations = 0
        while True:
            args = self._args(s_in, s_out, dt, *self.kernel_buffers,
                              self.patient_solver if patient else self.solver)
            try:
                status, k, err, nc = self._attempt(self.threaded, *args)
            except ArithmeticError as exc:  # a division by zero or overflow in the kernel
                self.arithmetic_failure(s_in, dt, exc)
            evaluations += k
            if status == CONVERGED:
                break
            if not self.adaptive:
                self.fail(s_in, dt, f"no convergence in {k} iterations at fixed Δt "
                           f"(ϖ = {err:.3g} > tolerance {tol:g}); lower solver.dt_max")
            if status == NOT_CONVERGED:
                factor = self.safety * step_factor(err, k, tol, k_d, self.p)
                factor = min(factor, 0.9)
            elif status in (CONTACT_MISSED, BODY_NOT_CONVERGED):
                factor = 0.5
            else:  # NOT_FINITE
                factor = 0.1
            rejected += 1
            dt *= factor
            if dt < self.dt_min and status == NOT_CONVERGED and can_wait and not patient:
                patient = True
                dt = first_dt
                if not self._told_patient:
                    self._told_patient = True
                    log.info("t = %.6g s: no Δt lets the φ-iteration meet its tolerance in "
                             "K_d = %d iterations (a collision of a light body: contact's "
                             "contraction does not improve with Δt); patient steps of up to "
                             "%d iterations from here while needed", s_in.t, k_d,
                             self.patient_solver.iteration_limit)
                continue
            if dt < self.dt_min:
                what = {NOT_FINITE: "non-finite values",
                        CONTACT_MISSED: "a fabric node inside the projectile",
                        BODY_NOT_CONVERGED: "the projectile's rotation (eq. B16) did not "
                                            "converge in the body update"}.get(
                    status, f"ϖ = {err:.3g} after {k} iterations")
                self.fail(s_in, dt, f"step cannot converge even at Δt < dt_min = "
                           f"{self.dt_min:g} s ({what})")
        # accept: time advances by the step just taken
        s_out.t = s_in.t + dt
        if self.adaptive and k > k_d:
            # a patient step: eq. 3.9 against max_iterations (against K_d it would only shrink
            # a step that no smaller Δt helps)
            grow = self.safety * step_factor(err, k, tol, self.patient_solver.iteration_limit,
                                             self.p)
            s_out.dt = min(self.dt_max, dt * grow)
        elif self.adaptive:
            grow = self.safety * step_factor(err, k, tol, k_d, self.p)
            s_out.dt = min(self.dt_max, dt * grow)
        else:
            s_out.dt = s_in.dt
        s_out.energy[:] = s_in.energy
        self._energy(None, self.physics, s_in.arrays, s_out.arrays, nc, self.work, s_in.t,
                     self.solver.phi, dt, s_out.energy)
        s_out.energy_initial = s_in.energy_initial
        s_out.steps = s_in.steps + 1
        self._count_contacts(s_out, nc)
        s_out.rejected = s_in.rejected + rejected
        s_out.evaluations = s_in.evaluations + evaluations
        s_out.iterations = k
        s_out.error = err
        s_out.last_dt = dt
        s_out.contact_steps = s_in.contact_steps + (1 if nc > 0 else 0)
        s_out.contact_force[:] = self.work.reaction[0] / dt
        self._after_step(time.perf_counter() - clock)
        return StepInfo(t=s_out.t, dt=dt, iterations=k, error=err, rejected=rejected,
                        evaluations=evaluations, contacts=nc)


__all__ = ["DivergenceError", "Integrator", "StepInfo", "step_factor"]
