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

from emfabric.builder import build_model
from emfabric.integrator import DivergenceError, Integrator, StepInfo
from emfabric.model import Model, State
from emfabric.run import RunResult, run
from emfabric.scenario import (
    Scenario,
    ScenarioError,
    builtin_names,
    load_scenario,
    scenario_from_dict,
)

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
    "load_scenario",
    "run",
    "scenario_from_dict",
]
