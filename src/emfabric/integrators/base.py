"""The seam every integrator shares: ``IntegratorBase`` (what the runner, the checkpoint and the
studies may call), the record of one accepted step (``StepInfo``) and the error of a step that
cannot go on (``DivergenceError``). A scheme (phi.py, central.py) subclasses IntegratorBase;
``emfabric.integrators.make_integrator(model)`` picks it from ``model.options.integrator``."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

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


class IntegratorBase(ABC):
    """One time-integration scheme for one Model: ``step(s_in, s_out, dt_limit=…)`` advances
    s_in by one accepted step into s_out (s_in is never written) and returns a StepInfo; a
    State holds everything a scheme needs to continue (so a checkpoint is a State).

    Compile handling, for the runner: ``variant()`` names the compiled kernels in use (the
    kernel cache marks them compiled after the first step); a scheme that compiles its threaded
    kernel beside the run overrides ``defer_threads`` and the background-compile methods (the
    defaults do nothing)."""

    name = "base"

    def __init__(self, model: Model):
        self.model = model
        self.physics = model.physics

    @abstractmethod
    def step(self, s_in: State, s_out: State, *, dt_limit: float = math.inf) -> StepInfo:
        """Advance s_in by one accepted step into s_out (s_in untouched), at most dt_limit."""

    def variant(self, threaded: bool | None = None) -> str:
        """Name of the compiled step kernels this integrator runs."""
        return self.name

    def defer_threads(self) -> bool:
        """Run serially until a threaded kernel is compiled (default: nothing deferred)."""
        return False

    def start_background_compile(self, s_in: State, s_out: State) -> None:  # noqa: B027
        """Compile a deferred threaded kernel beside the run (default: none)."""

    @property
    def compiling_in_background(self) -> bool:
        return False

    def finish_background_compile(self) -> None:  # noqa: B027
        """Wait for a background compile still running (default: none)."""

    def fail(self, s_in: State, dt: float, why: str) -> None:
        """Raise the DivergenceError of a step from s_in at Δt: when, why, and the node with the
        largest force."""
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
