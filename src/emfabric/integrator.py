"""The φ-scheme with fixed-point iteration and adaptive Δt (section 3, eqs. 3.2–3.10).

``Integrator(model).step(s_in, s_out)`` advances one accepted step: it attempts Δt = s_in.dt,
and on failure shrinks Δt by the controller (3.9) and restarts from t (s_in is never written).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numba
import numpy as np

from emfabric._kernels import is_compiled, mark_compiled
from emfabric._kernels.body import field_wrench
from emfabric._kernels.energy import step_energy
from emfabric._kernels.nodes import (
    ROWBUF_ROWS,
    ROWS_PER_BLOCK,
    fused_iterate,
    fused_iterate_threads,
)
from emfabric._kernels.step import (
    CONTACT_MISSED,
    CONVERGED,
    NOT_CONVERGED,
    NOT_FINITE,
    attempt_step,
)
from emfabric.model import BODY_F, BODY_M, BODY_R0, BODY_V, BODY_W, BODY_X, Model, State


class DivergenceError(RuntimeError):
    """The step cannot converge even at dt_min; carries where and when."""

    def __init__(self, message: str, t: float, dt: float, node: int, force: float):
        super().__init__(message)
        self.t, self.dt, self.node, self.force = t, dt, node, force


@dataclass(frozen=True)
class StepInfo:
    """What one accepted step did."""

    t: float
    """Time reached [s]."""
    dt: float
    """Step just taken [s]."""
    iterations: int
    """Fixed-point iterations of the accepted attempt."""
    error: float
    """ϖ_K at acceptance."""
    rejected: int
    """Attempts rejected before this one."""
    evaluations: int
    """Force evaluations spent, rejected attempts included."""
    contacts: int
    """Nodes in contact at t + Δt."""


def step_factor(error: float, k: int, tol: float, k_target: int, p: float) -> float:
    """Φ_K of eq. 3.9 with ϖ_0 = 1: (TOL)^(1/(p K_d)) / (ϖ_K)^(1/(p K))."""
    if error <= 0.0:
        return math.inf
    return tol ** (1.0 / (p * k_target)) / error ** (1.0 / (p * k))


THREADS_FROM_NODES = 32 * 32
"""Sheets with at least this many nodes use the two-thread kernel."""


class Integrator:
    """Holds the workspace of the step kernel for one Model."""

    def __init__(self, model: Model, *, threads: bool | None = None):
        """threads: use the row-block threaded kernel (default: for sheets of at least
        THREADS_FROM_NODES nodes when Numba has more than one thread)."""
        self.model = model
        m = model
        n = m.node_count
        sc = m.scenario
        coef = m.seg_modulus * m.yarn_area / m.seg_rest_length
        self.coef = coef
        self.grid = (m.nx, m.ny)
        self.fab = (m.node_mass, m.node_inv_mass, m.node_charge, coef,
                    1.0 / m.seg_rest_length**2)
        self.mat = (m.material_kind, m.fung_H, m.critical_stretch, m.damage_rate)
        self.fld = (m.field_E, m.field_B, m.field_region, m.field_z0, m.gravity)
        self.body = (m.has_body, m.body_radius, m.body_mass, m.body_inertia, m.body_charge_pos,
                     m.body_charge, sc.contact.static_friction, sc.contact.dynamic_friction)
        # threads pay off on large sheets only; block size fixed, so results never depend on them
        self._use_threads(threads if threads is not None else (
            n >= THREADS_FROM_NODES and numba.config.NUMBA_NUM_THREADS > 1))
        self._deferred = False  # serial until the threaded kernel is compiled
        self._background: threading.Thread | None = None
        self._background_ok = False
        self.work = (
            np.empty((3, n)),  # second iterate buffer
            (np.empty((2, m.ny)), np.empty(n), np.empty(n)),  # error sums: per row, per node
            np.empty(n, dtype=np.int64),  # contact candidates
            np.zeros(n, dtype=np.uint8),  # candidate flags
            np.empty(n, dtype=np.int64),  # contact nodes
            np.empty((3, n)),  # contact impulses
            np.empty((3, n)),  # contact arms
            np.empty((3, n)),  # projection displacements
            np.empty(n),  # summation buffer
        )
        solver = sc.solver
        # None for the plain fixed point: the step kernel is then compiled without Anderson
        self.accel = None
        if solver.scheme == "anderson":
            depth = solver.anderson_depth
            self.accel = (np.empty((3, n)), np.empty((depth, 3, n)), np.empty((depth, 3, n)),
                          np.empty((3, n)), np.empty((3, n)), np.zeros((depth, depth)))
        self.phi = solver.phi
        self.tol = solver.tolerance
        self.k_target = solver.target_iterations if solver.adaptive else solver.max_iterations
        self.p = solver.exponent
        self.safety = solver.safety
        self.adaptive = solver.adaptive
        self.dt_max = solver.dt_max
        self.dt_min = solver.dt_min

    def _use_threads(self, on: bool) -> None:
        """Pick the serial or the threaded node kernel (the same numbers, bit for bit).

        The row buffers are one block for the serial kernel or one per row block for the
        threaded one; the other is None, so that only the kernel in use is compiled."""
        m = self.model
        self.threaded = on
        self.rowbuf = None if on else np.empty((ROWBUF_ROWS, m.nx + 1))
        self.threads = self._threads_buffer() if on else None

    def _threads_buffer(self) -> np.ndarray:
        """Row buffers of the threaded kernel, one per row block."""
        m = self.model
        return np.empty((-(-m.ny // ROWS_PER_BLOCK), ROWBUF_ROWS, m.nx + 1))

    def variant(self, threaded: bool | None = None) -> str:
        """Name of the compiled step kernel this integrator runs (or would run threaded)."""
        threaded = self.threaded if threaded is None else threaded
        return (f"{'threads' if threaded else 'serial'}-"
                f"{'anderson' if self.accel is not None else 'fixed-point'}")

    def defer_threads(self) -> bool:
        """Run serially until the threaded kernel is compiled, if it is not cached yet.

        Returns whether it deferred; start_background_compile() then compiles the threaded
        kernel beside the run, and step() switches to it once it is ready. Serial and threaded
        kernels give identical results, so the switch does not change the run."""
        if not self.threaded or is_compiled(self.variant(True)):
            return False
        self._use_threads(False)
        self._deferred = True
        return True

    def start_background_compile(self, s_in: State, s_out: State) -> None:
        """Compile the threaded step kernel in a background thread (after defer_threads)."""
        if not self._deferred or self._background is not None:
            return
        args = self._args(s_in, s_out, 0.0, None, self._threads_buffer())
        sig = tuple(numba.typeof(a) for a in args)

        def compile_threaded() -> None:
            try:
                attempt_step.compile(sig)
                self._background_ok = True
            except Exception:  # noqa: BLE001 - the serial kernel simply stays in use
                self._background_ok = False

        self._background = threading.Thread(target=compile_threaded, name="emfabric-compile",
                                            daemon=True)
        self._background.start()

    @property
    def compiling_in_background(self) -> bool:
        return self._background is not None and self._background.is_alive()

    def finish_background_compile(self) -> None:
        """Wait for a background compile still running (a daemon thread: a process that exits
        without waiting abandons it, and the next run compiles again)."""
        if self._background is not None:
            self._background.join()
            if self._background_ok:
                mark_compiled(self.variant(True))

    def _args(self, s_in: State, s_out: State, dt: float, rowbuf, threads) -> tuple:
        sin = (s_in.node_x, s_in.node_v, s_in.node_f, s_in.seg_alpha, s_in.body)
        sout = (s_out.node_x, s_out.node_v, s_out.node_f, s_out.seg_alpha, s_out.body)
        return (self.grid, self.fab, self.mat, self.fld, self.body, sin, sout, self.work, rowbuf,
                threads, self.phi, dt, self.tol, self.k_target, self.accel)

    def step(self, s_in: State, s_out: State, *, dt_limit: float = math.inf) -> StepInfo:
        """Advance s_in by one accepted step into s_out; s_in is left untouched."""
        m = self.model
        bg = self._background
        if bg is not None and not bg.is_alive():
            # one try: on failure the serial kernel simply stays in use
            self._background = None
            self._deferred = False
            if self._background_ok:
                mark_compiled(self.variant(True))
                self._use_threads(True)
        dt = min(s_in.dt, dt_limit)
        rejected = 0
        evaluations = 0
        while True:
            args = self._args(s_in, s_out, dt, self.rowbuf, self.threads)
            status, k, err, nc = attempt_step(*args)
            evaluations += k
            if status == CONVERGED:
                break
            if not self.adaptive:
                self._fail(s_in, dt, f"no convergence in {k} iterations at fixed Δt "
                           f"(ϖ = {err:.3g} > tolerance {self.tol:g}); lower solver.dt_max")
            if status == NOT_CONVERGED:
                factor = self.safety * step_factor(err, k, self.tol, self.k_target, self.p)
                factor = min(factor, 0.9)
            elif status == CONTACT_MISSED:
                factor = 0.5
            else:  # NOT_FINITE
                factor = 0.1
            rejected += 1
            dt *= factor
            if dt < self.dt_min:
                what = "non-finite values" if status == NOT_FINITE else (
                    f"ϖ = {err:.3g} after {k} iterations")
                self._fail(s_in, dt, f"step cannot converge even at Δt < dt_min = "
                           f"{self.dt_min:g} s ({what})")
        # accept: time advances by the step just taken
        s_out.t = s_in.t + dt
        if self.adaptive:
            grow = self.safety * step_factor(err, k, self.tol, self.k_target, self.p)
            s_out.dt = min(self.dt_max, dt * grow)
        else:
            s_out.dt = s_in.dt
        s_out.energy[:] = s_in.energy
        xbuf, _e, _c, _f, c_node, c_imp, c_arm, c_proj, _b = self.work
        step_energy(s_in.node_x, s_out.node_x, s_in.node_v, s_out.node_v, s_out.node_f,
                    m.node_mass, m.node_inv_mass, m.node_charge, m.field_E, m.field_B,
                    m.field_region, m.field_z0, m.gravity, self.phi, dt, nc, c_node, c_imp, c_arm,
                    c_proj, s_in.body, s_out.body, m.body_charge_pos, m.body_charge,
                    m.body_mass, m.seg_nodes, s_in.seg_alpha, s_out.seg_alpha, self.coef,
                    m.seg_rest_length, m.material_kind, m.fung_H, s_out.energy)
        s_out.steps = s_in.steps + 1
        s_out.rejected = s_in.rejected + rejected
        s_out.evaluations = s_in.evaluations + evaluations
        s_out.iterations = k
        s_out.error = err
        s_out.contact_count = nc
        return StepInfo(t=s_out.t, dt=dt, iterations=k, error=err, rejected=rejected,
                        evaluations=evaluations, contacts=nc)

    def _fail(self, s_in: State, dt: float, why: str) -> None:
        f = np.linalg.norm(s_in.node_f, axis=0)
        node = int(np.argmax(f)) if f.size else -1
        fmax = float(f[node]) if f.size else 0.0
        i, j = node % self.model.nx, node // self.model.nx
        raise DivergenceError(
            f"diverged at t = {s_in.t:.6g} s, Δt = {dt:.3g} s: {why}; largest force "
            f"{fmax:.3g} N on node {node} (grid i={i}, j={j}) at "
            f"{tuple(round(float(c), 6) for c in s_in.node_x[:, node])} m",
            s_in.t, dt, node, fmax,
        )


def initial_forces(model: Model, state: State) -> None:
    """ψ(t) of the start state: yarn + Lorentz + gravity on the nodes, field and gravity on the
    body (the first step's explicit part).

    Calls the node kernel the step kernel uses (compiled with it, so nothing more to compile)
    with Δt = 0 and φ = 1: the update returns v1 = v0 and ψ(x0, v0) in node_f."""
    integ = Integrator(model)
    integ.defer_threads()
    scratch = state.copy()
    m = model
    mass, inv_mass, charge, coef, inv_l02 = integ.fab
    kind, fung_h, u_crit, rate = integ.mat
    efield, bfield, region, z0, grav = integ.fld
    err_rows, err_num, err_den = integ.work[1]
    kernel, rows = ((fused_iterate_threads, integ.threads) if integ.threaded
                    else (fused_iterate, integ.rowbuf))
    kernel(state.node_x, state.node_x, state.node_v, np.zeros_like(state.node_f),
           state.seg_alpha, scratch.seg_alpha, m.nx, m.ny, coef, inv_l02, kind, fung_h, u_crit,
           rate, mass, inv_mass, charge, 1.0, 0.0, efield, bfield, region, z0, grav,
           np.ones(m.node_count, dtype=np.uint8), scratch.node_x, scratch.node_v, state.node_f,
           err_rows, err_num, err_den, rows)
    if m.has_body:
        b = state.body
        field_wrench(b[BODY_X], b[BODY_V], b[BODY_W], b[BODY_R0:BODY_R0 + 3], m.body_charge_pos,
                     m.body_charge, efield, bfield, region, z0, m.body_mass, grav, b[BODY_F],
                     b[BODY_M])


__all__ = ["DivergenceError", "Integrator", "StepInfo", "initial_forces", "step_factor"]
