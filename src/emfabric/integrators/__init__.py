"""Time integration: one module per scheme behind one interface. ``Integrator(model)`` with
``step(s_in, s_out) -> StepInfo``; a step that cannot go on raises ``DivergenceError``.

- phi.py: the paper's φ-scheme, fixed-point (or Anderson) iteration with the adaptive Δt of
  eq. 3.9.

A scheme owns its update, its step-size rule and its bookkeeping; the forces, contact law and
body update are the kernels' (emfabric._kernels). May import: sim, _kernels (the numerical
settings come as model.options, never from the scenario).
"""

from emfabric.integrators.base import DivergenceError, StepInfo
from emfabric.integrators.phi import Integrator, step_factor

__all__ = ["DivergenceError", "Integrator", "StepInfo", "step_factor"]
