"""What every integrator shares: the record of one accepted step and the error of a step that
cannot go on. A scheme (phi.py, …) provides ``Integrator(model)`` with ``step(s_in, s_out, *,
dt_limit) -> StepInfo``; the runner knows it only through that call."""

from __future__ import annotations

from dataclasses import dataclass


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
