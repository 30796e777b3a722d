"""emfabric: rigid projectile impact on electromagnetically sensitive woven fabric.

A lumped-mass yarn network with damage, Lorentz forces q(E + v × B) on charged nodes, contact
with stick/slip friction, a rigid projectile that translates and rotates, and the paper's
adaptive implicit φ-scheme (Zohdi, "High-speed impact of electromagnetically sensitive fabric
and induced projectile spin").
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("emfabric")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+unknown"

from emfabric.config.scenario import (
    Scenario,
    ScenarioError,
    builtin_names,
    load_scenario,
    scenario_from_dict,
)

# the simulator (Numba kernels) loads on first use, so that plotting never imports it
_LAZY = {
    "build_model": "emfabric.sim.builder",
    "DivergenceError": "emfabric.integrators",
    "Integrator": "emfabric.integrators",
    "StepInfo": "emfabric.integrators",
    "Model": "emfabric.sim.model",
    "State": "emfabric.sim.state",
    "RunResult": "emfabric.runner.loop",
    "run": "emfabric.runner.loop",
    "resume": "emfabric.runner.loop",
    "initial_state": "emfabric.sim.state",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'emfabric' has no attribute {name!r}")


__all__ = [
    "DivergenceError",
    "Integrator",
    "Model",
    "RunResult",
    "Scenario",
    "ScenarioError",
    "State",
    "StepInfo",
    "__version__",
    "build_model",
    "builtin_names",
    "initial_state",
    "load_scenario",
    "resume",
    "run",
    "scenario_from_dict",
]
