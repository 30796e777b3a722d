"""A run: the time loop (step, swap states, record, snapshot, checkpoint, interrupt), resuming
from a checkpoint, and the run summary (the one used by ``emfabric run``, the studies and the
command line).

May import: integrators, io, sim, config, _kernels.
"""

from emfabric.integrators import DivergenceError
from emfabric.runner.loop import RunResult, interrupt, resume, run
from emfabric.runner.summary import summarize

__all__ = ["DivergenceError", "RunResult", "interrupt", "resume", "run", "summarize"]
