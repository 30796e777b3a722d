"""The seam every integrator shares: ``IntegratorBase`` (what the runner, the checkpoint and the
studies may call), the record of one accepted step (``StepInfo``) and the error of a step that
cannot go on (``DivergenceError``). A scheme (phi.py, central.py) subclasses IntegratorBase;
``emfabric.integrators.make_integrator(model)`` picks it from ``model.options.integrator``."""

from __future__ import annotations

import math
import statistics
import threading
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numba
import numpy as np

from emfabric._kernels import is_compiled, mark_compiled
from emfabric._kernels.contact import contact_tally
from emfabric._kernels.nodes import ROWBUF_ROWS, ROWS_PER_BLOCK
from emfabric._kernels.records import row_records
from emfabric.sim.fastcall import Direct
from emfabric.sim.model import Model
from emfabric.sim.state import State


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


PROBE_EVERY = 1000
"""Steps between two probes of the other node kernel (serial against threaded) when the thread
count is chosen at run time (IntegratorBase, adaptive threads)."""
PROBE_STEPS = 12
"""Steps timed per probe (the first step of a probe window is not counted)."""
PROBE_FIRST = 3 * PROBE_STEPS
"""The first probe comes after this many steps (then every PROBE_EVERY)."""


_SWITCH_ON = np.zeros(1)
"""The array that switches a part of the step kernels on (IntegratorBase.switches)."""


class IntegratorBase(ABC):
    """One time-integration scheme for one Model: ``step(s_in, s_out, dt_limit=…)`` advances
    s_in by one accepted step into s_out (s_in is never written) and returns a StepInfo; a
    State holds everything a scheme needs to continue (so a checkpoint is a State).

    Node kernels, for both schemes: a serial one (row buffer ``rowbuf``) and a threaded one
    over row blocks (``threads``, one buffer per block); the other is None, so only the kernel
    in use is compiled. They give the same numbers to the bit, so switching never changes a
    run. ``variant()`` names the compiled kernels in use (the kernel cache marks them compiled
    after the first step). On a cold cache the threaded kernel is compiled beside the run
    (``defer_threads``, ``start_background_compile``: the subclass gives the kernel and its
    arguments, ``_compile_target``).

    Adaptive threads (``adaptive=True``, the default where threads may pay off): the scheme
    times its steps, and after PROBE_FIRST steps and then every PROBE_EVERY runs PROBE_STEPS
    with the other kernel; it keeps whichever was faster. On a loaded machine the threaded
    kernel waits at each barrier for a descheduled thread and the serial one wins; idle, the
    threaded one wins on large sheets. A subclass calls ``_before_step()`` first and
    ``_after_step(seconds)`` with the kernel's wall time last in ``step``."""

    name = "base"

    def __init__(self, model: Model, *, threads: bool = False, adaptive: bool = False):
        self.model = model
        self.physics = model.physics
        self._deferred = False  # serial until the threaded kernel is compiled
        self._background: threading.Thread | None = None
        self._background_ok = False
        self.adaptive_threads = bool(adaptive and threads)
        self._steps_timed = 0
        self._probe_left = 0
        self._recent: dict[bool, list[float]] = {False: [], True: []}
        self.rowbuf: np.ndarray | None = None
        """The serial kernel's row buffer (None until it is used)."""
        self.threads: np.ndarray | None = None
        """The threaded kernel's row buffers, one per row block (None until it is used)."""
        self.switches: tuple[np.ndarray | None, np.ndarray | None] = (
            _SWITCH_ON if model.ply_count > 1 else None,
            _SWITCH_ON if model.physics.contact.segments else None)
        """(plies, segments) for the step kernels: an array where a pack's ply contact, or the
        projectile's contact with segments, is used; None where not, so that Numba leaves that
        code out of the compiled kernel (a single sheet's step kernel does not compile ply
        contact: seconds off a cold start). Each combination is its own compiled kernel."""
        self._use_threads(threads)
        self._tally = Direct(contact_tally)
        self._mark = np.zeros(model.node_count, dtype=np.int8)
        self.contacts_per_ply = np.zeros(model.ply_count, dtype=np.int64)
        """Per ply, the fabric nodes in contact after the last step (contact_tally)."""
        self._tallied: tuple[State | None, int] = (None, -1)

    @abstractmethod
    def step(self, s_in: State, s_out: State, *, dt_limit: float = math.inf) -> StepInfo:
        """Advance s_in by one accepted step into s_out (s_in untouched), at most dt_limit."""

    def fabric_of(self, state: State) -> np.ndarray | None:
        """The fabric diagnostics of `state` (diagnostics.fabric_diagnostics's values) where
        the step that wrote it computed them on the way, else None (the history record then
        computes them). Valid until the next step."""
        return None

    def contacts_of(self, state: State) -> np.ndarray | None:
        """Per ply, the fabric nodes in contact with the projectile in `state` if the last step
        wrote it (the history's contact_nodes_per_ply), else None. Valid until the next step."""
        if state is self._tallied[0] and state.steps == self._tallied[1]:
            return self.contacts_per_ply
        return None

    def _count_contacts(self, s_out: State, nc: int) -> None:
        """The accepted step's contacts (its `nc` entries of work.c_node, c_node2) counted into
        s_out: contact_count the distinct nodes touching, contact_segments the segments."""
        if nc == 0:
            self.contacts_per_ply[:] = 0
            segments = 0
        else:
            work = self.work  # type: ignore[attr-defined]
            segments = self._tally(None, nc, work.c_node, work.c_node2,
                                   self.model.nodes.ply_nodes, self._mark,
                                   self.contacts_per_ply)
        per_ply = self.contacts_per_ply  # one ply: its count (no NumPy reduction a step)
        s_out.contact_count = int(per_ply[0] if per_ply.shape[0] == 1 else per_ply.sum())
        s_out.contact_segments = int(segments)
        self._tallied = (s_out, s_out.steps)

    def variant(self, threaded: bool | None = None) -> str:
        """Name of the compiled step kernels this integrator runs (or would run threaded)."""
        return self.name + self.switch_suffix()

    def switch_suffix(self) -> str:
        """The part of a variant's name that says which switches (self.switches) are on."""
        plies, segs = self.switches
        return ("-plies" if plies is not None else "") + ("-segments" if segs is not None else "")

    def precompile_targets(self, state: State) -> list[tuple]:
        """(kernel, arguments) pairs that a second process may compile into the kernel cache
        while this one compiles the rest (a cold cache: runner.precompile): callees of the
        serial step kernel, with arguments of the types the step kernel passes them (`state`
        gives the arrays). [] where the scheme names none."""
        return []

    def _serial_rows(self) -> tuple:
        """(row records, a serial row buffer): the row-block kernels' arguments that
        precompile_targets passes as the serial step kernel does."""
        rowbuf = self.rowbuf if self.rowbuf is not None else np.empty((ROWBUF_ROWS,
                                                                       self.model.nx + 1))
        return row_records(self.physics), rowbuf

    def _compile_target(self, s_in: State, s_out: State, threads: np.ndarray):
        """(dispatcher, arguments) of the threaded step kernel, for its background compile
        (None: nothing to compile beside the run)."""
        return None

    # --- the node kernel in use -----------------------------------------------------------

    def _use_threads(self, on: bool) -> None:
        """Pick the serial or the threaded node kernel (the same numbers, bit for bit)."""
        m = self.model
        self.threaded = bool(on)
        if on and self.threads is None:
            self.threads = np.empty((-(-m.ny // ROWS_PER_BLOCK), ROWBUF_ROWS, m.nx + 1))
        if not on and self.rowbuf is None:
            self.rowbuf = np.empty((ROWBUF_ROWS, m.nx + 1))
        self._kernel_buffers = ((None, self.threads) if on else (self.rowbuf, None))

    @property
    def kernel_buffers(self) -> tuple:
        """(rowbuf, threads) for the step kernel: exactly one is an array."""
        return self._kernel_buffers

    def _before_step(self) -> None:
        """Switch to the threaded kernel once its background compile has finished."""
        bg = self._background
        if bg is not None and not bg.is_alive():
            # one try: on failure the serial kernel simply stays in use
            self._background = None
            self._deferred = False
            if self._background_ok:
                mark_compiled(self.variant(True))
                self._use_threads(True)
                self._steps_timed = 0

    def _after_step(self, seconds: float) -> None:
        """Adaptive threads: time the step just taken; probe the other kernel every
        PROBE_EVERY steps and keep the faster."""
        if not self.adaptive_threads or self._deferred:
            return
        self._steps_timed += 1
        if self._probe_left > 0:
            self._probe_left -= 1
            if self._probe_left < PROBE_STEPS:  # the window's first step may compile
                self._recent[self.threaded].append(seconds)
            if self._probe_left == 0:
                mine = statistics.median(self._recent[self.threaded])
                theirs = statistics.median(self._recent[not self.threaded] or [math.inf])
                if theirs < mine:
                    self._use_threads(not self.threaded)
                self._recent = {False: [], True: []}
            return
        recent = self._recent[self.threaded]
        recent.append(seconds)
        del recent[:-PROBE_STEPS]
        due = self._steps_timed == PROBE_FIRST or self._steps_timed % PROBE_EVERY == 0
        if due and len(recent) == PROBE_STEPS:
            self._use_threads(not self.threaded)
            self._probe_left = PROBE_STEPS + 1

    # --- compiling the threaded kernel beside the run --------------------------------------

    def defer_threads(self) -> bool:
        """Run serially until the threaded kernel is compiled, if it is not cached yet.

        Returns whether it deferred; start_background_compile() then compiles the threaded
        kernel beside the run, and the next step after it is ready switches to it. Serial and
        threaded kernels give identical results, so the switch does not change the run."""
        if not self.threaded or is_compiled(self.variant(True)):
            return False
        self._use_threads(False)
        self._deferred = True
        return True

    def start_background_compile(self, s_in: State, s_out: State) -> None:
        """Compile the threaded step kernel in a background thread (after defer_threads)."""
        if not self._deferred or self._background is not None:
            return
        m = self.model
        target = self._compile_target(
            s_in, s_out, np.empty((-(-m.ny // ROWS_PER_BLOCK), ROWBUF_ROWS, m.nx + 1)))
        if target is None:
            return
        kernel, args = target
        sig = tuple(numba.typeof(a) for a in args)

        def compile_threaded() -> None:
            try:
                kernel.compile(sig)
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

    def arithmetic_failure(self, s_in: State, dt: float, exc: ArithmeticError) -> None:
        """Raise the DivergenceError of a step kernel stopped by a division by zero or an
        overflow (Numba raises them as Python does)."""
        self.fail(s_in, dt, f"the step kernel stopped on {exc!r}: a quantity of the scenario is "
                  "too small or too large to compute with (a mass, size, stiffness, charge or "
                  "field at the end of a double's range; the warnings name the keys outside "
                  "physical ranges)")

    def _grid_of(self, node: int) -> str:
        """" (ply p, grid i=…, j=…)" of a node."""
        m = self.model
        ply = int(np.searchsorted(m.nodes.ply_nodes, node, side="right") - 1)
        nx = m.ply_grid(ply)[0]
        local = node - int(m.nodes.ply_nodes[ply])
        return ((f" (ply {ply + 1}, " if m.ply_count > 1 else " (")
                + f"grid i={local % nx}, j={local // nx})")

    def fail(self, s_in: State, dt: float, why: str, s_out: State | None = None) -> None:
        """Raise the DivergenceError of a step from s_in at Δt: when, why, the free node with
        the largest force, and with the step's failed result s_out where it first went non-finite
        (a node's position, velocity or force, or the projectile's state)."""
        f = np.linalg.norm(s_in.node_f, axis=0)
        # a clamped node's force drives nothing (its reaction): the free nodes' largest
        free = self.model.nodes.inv_mass > 0
        if free.any() and f.size:
            f = np.where(free, f, -1.0)
        node = int(np.argmax(f)) if f.size else -1
        fmax = float(f[node]) if f.size else 0.0
        where = self._grid_of(node) if node >= 0 else ""
        first = ""
        if s_out is not None:
            for name, arr in (("position", s_out.node_x), ("velocity", s_out.node_v),
                              ("force", s_out.node_f)):
                bad = ~np.isfinite(arr).all(axis=0)
                if bad.any():
                    k = int(np.argmax(bad))
                    first = f"; the first non-finite {name} is node {k}'s{self._grid_of(k)}"
                    break
            else:
                if not np.isfinite(s_out.body).all():
                    first = "; the projectile's state is non-finite"
        raise DivergenceError(
            f"diverged at t = {s_in.t:.6g} s, Δt = {dt:.3g} s: {why}; largest force "
            f"{fmax:.3g} N on node {node}{where} at "
            f"{tuple(round(float(c), 6) for c in s_in.node_x[:, node])} m{first}",
            s_in.t, dt, node, fmax,
        )
