"""Time integration: one module per scheme behind one interface. ``Integrator(model)`` with
``step(s_in, s_out) -> StepInfo``; a step that cannot go on raises ``DivergenceError``.

- base.py: IntegratorBase (the seam), StepInfo, DivergenceError;
- phi.py: the paper's φ-scheme, fixed-point (or Anderson) iteration with the adaptive Δt of
  eq. 3.9 (``Integrator``);
- central.py: central differences, explicit, one force evaluation per step
  (``CentralDifference``).

``make_integrator(model)`` picks the scheme of ``model.options.integrator``.

A scheme owns its update, its step-size rule and its bookkeeping; the forces, contact law and
body update are the kernels' (emfabric._kernels). May import: sim, _kernels (the numerical
settings come as model.options, never from the scenario).
"""

import logging
import operator

from emfabric.integrators.base import DivergenceError, IntegratorBase, StepInfo
from emfabric.integrators.central import CentralDifference
from emfabric.integrators.phi import THREADS_FROM_NODES, Integrator, step_factor


def default_threads(model) -> int:
    """Numba threads for a run of this model when none are asked for: 1 below
    THREADS_FROM_NODES nodes (issue 22 measured the two-thread kernel on the paper's 100 × 100
    sheet 6 % faster on the idle 2-core machine and 2× slower with three busy processes beside
    it: every iterate ends at a barrier that waits for a descheduled thread), else every core
    Numba has — and then the integrator keeps checking, by timing, that the threaded kernels
    are faster than the serial ones (adaptive threads, IntegratorBase). "Every core" is the
    thread count Numba is set to (numba.get_num_threads(): NUMBA_NUM_THREADS unless lowered,
    as a study case lowers it to its share of the cores)."""
    import numba

    return numba.get_num_threads() if model.node_count >= THREADS_FROM_NODES else 1


def check_threads(threads) -> int | None:
    """`threads` as given to a run (None: chosen for the problem's size), as an int: a whole
    number ≥ 1 (a NumPy integer too); anything else is a ValueError naming it."""
    if threads is None:
        return None
    try:
        count = operator.index(threads)  # an int or NumPy integer, never a float or text
    except TypeError:
        count = 0
    if isinstance(threads, bool) or count < 1:
        raise ValueError(f"threads = {threads!r}: allowed: None (chosen for the problem's "
                         "size) or a whole number ≥ 1")
    return count


def make_integrator(model, *, threads: int | None = None) -> IntegratorBase:
    """The integrator the model's options name ("phi" or "central-difference"), on `threads`
    Numba threads (None: default_threads(model); 1: the serial kernel; more than Numba has:
    as many as it has, said in the log)."""
    import numba

    threads = check_threads(threads)
    count = default_threads(model) if threads is None else threads
    if count > numba.config.NUMBA_NUM_THREADS:
        logging.getLogger(__name__).warning(
            "threads = %d: Numba has %d (NUMBA_NUM_THREADS, the cores it found): running on %d",
            count, numba.config.NUMBA_NUM_THREADS, numba.config.NUMBA_NUM_THREADS)
    count = min(count, numba.config.NUMBA_NUM_THREADS)
    if count > 1:
        numba.set_num_threads(count)
    # threads chosen for the user are checked against the serial kernel as the run goes
    adaptive = threads is None and count > 1
    if model.options.integrator == "central-difference":
        return CentralDifference(model, threads=count > 1, adaptive=adaptive)
    return Integrator(model, threads=count > 1, adaptive=adaptive)


__all__ = ["CentralDifference", "DivergenceError", "Integrator", "IntegratorBase", "StepInfo",
           "check_threads", "default_threads", "make_integrator", "step_factor"]
