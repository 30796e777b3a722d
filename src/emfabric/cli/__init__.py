"""The command line: one typer application (``app``), one module per command group.

- app.py: the application object, stderr/stdout helpers, scenario loading with clear errors;
- run.py: ``run``, ``validate``, ``new``, ``scenarios``;
- field.py: ``field`` (E and B at points, the field figure);
- plot.py: ``plot``, ``animate``;
- study.py: ``sweep``, ``estimate``, ``design-field``, ``ballistic-limit``;
- materials.py: ``materials`` (the material and fabric-style library).

May import every other layer; nothing imports it. Heavy modules (the simulator, plotting,
Dask) are imported inside the commands that need them, so that ``emfabric --help`` is quick.
"""

from __future__ import annotations

import sys

# each module registers its commands, in the order `emfabric --help` lists them
# isort: off
from emfabric.cli import run, field, plot, study, materials  # noqa: F401
# isort: on
from emfabric.cli.app import app, error
from emfabric.config.scenario import ScenarioError


def main() -> None:  # pragma: no cover - console entry
    try:
        app()
    except ScenarioError as err:
        error(str(err))
        sys.exit(2)


__all__ = ["app", "main"]
