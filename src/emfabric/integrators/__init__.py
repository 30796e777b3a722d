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

from emfabric.integrators.base import DivergenceError, IntegratorBase, StepInfo
from emfabric.integrators.central import CentralDifference
from emfabric.integrators.phi import Integrator, step_factor


def make_integrator(model) -> IntegratorBase:
    """The integrator the model's options name ("phi" or "central-difference")."""
    if model.options.integrator == "central-difference":
        return CentralDifference(model)
    return Integrator(model)


__all__ = ["CentralDifference", "DivergenceError", "Integrator", "IntegratorBase", "StepInfo",
           "make_integrator", "step_factor"]
