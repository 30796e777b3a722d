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
from emfabric.cli.app import EXIT_FAILED, EXIT_INPUT, EXIT_INTERRUPTED, app, error
from emfabric.config.scenario import ScenarioError


def main() -> None:  # pragma: no cover - console entry
    """The console entry: the commands' own exit statuses (docs/errors.md), and for an error
    no command caught, one line instead of a traceback: 2 for an input error (a scenario, an
    output folder in use), 1 for an operating-system error (a file that could not be
    written). Interrupts exit 130 (typer)."""
    from emfabric.io.lock import FolderInUse

    try:
        app()
    except SystemExit as exc:
        if exc.code == EXIT_INTERRUPTED:
            _exit_within(EXIT_GRACE)
        raise
    except (ScenarioError, FolderInUse) as err:
        error(str(err))
        sys.exit(EXIT_INPUT)
    except OSError as err:
        if err.filename:
            from emfabric.runner.loop import target_of

            error(f"{target_of(err.filename)}: {err.strerror or err}")
        else:
            error(str(err))
        sys.exit(EXIT_FAILED)


EXIT_GRACE = 15.0
"""[s] An interrupted command that has said what it kept is gone this long after, whatever is
still winding down in the interpreter (a study's Dask threads and exit handlers)."""


def _exit_within(seconds: float) -> None:
    """Exit 130 within `seconds` even if the interpreter's shutdown waits on something: a
    daemon timer (the command has returned: its files are written and its folder's lock
    released)."""
    import os
    import threading

    def leave() -> None:
        sys.stderr.flush()
        sys.stdout.flush()
        os._exit(EXIT_INTERRUPTED)

    timer = threading.Timer(seconds, leave)
    timer.daemon = True
    timer.start()


__all__ = ["app", "main"]
