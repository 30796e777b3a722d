"""The command-line application object and its output helpers, shared by the command modules
(emfabric.cli: run, validate, scenarios; emfabric.cli.plot: plot, animate)."""

from __future__ import annotations

import sys
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Simulate a rigid projectile striking electromagnetically sensitive fabric.",
)
console = Console(stderr=True)
"""Messages, progress and the summary table: stderr."""
out_console = Console()
"""Tables meant for reading on stdout (`scenarios`); machine-readable output uses emit()."""


def error(message: str) -> None:
    """An error line on stderr: user text is never read as console markup, and long lines
    are not wrapped (a piped message stays one line)."""
    console.print("[bold red]error:[/] " + escape(str(message)), highlight=False,
                  soft_wrap=True)


def emit(text: str) -> None:
    """Machine-readable output (JSON, file paths, TOML) on stdout, exactly as given."""
    sys.stdout.write(text if text.endswith("\n") else text + "\n")
    sys.stdout.flush()


def _version(value: bool) -> None:
    if value:
        from emfabric import __version__

        emit(f"emfabric {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[bool, typer.Option(
        "--version", callback=_version, is_eager=True, help="Print the version and exit")] = False,
) -> None:
    """Simulate a rigid projectile striking electromagnetically sensitive fabric."""


def show_messages() -> None:
    """Send emfabric's log messages (compiling kernels, incomplete runs, ...) to stderr."""
    import logging

    from rich.logging import RichHandler

    logger = logging.getLogger("emfabric")
    if not any(isinstance(h, RichHandler) for h in logger.handlers):
        logger.addHandler(RichHandler(console=console, show_time=False, show_path=False,
                                      show_level=False, markup=False))
    logger.setLevel(logging.INFO)


def load_or_exit(scenario: str, overrides: list[str] | None):
    """The scenario with its --set overrides, or a clear error and exit status 2."""
    from emfabric.config.scenario import ScenarioError, load_scenario, parse_override

    try:
        pairs = dict(parse_override(o) for o in (overrides or []))
        return load_scenario(scenario, pairs)
    except ScenarioError as err:
        error(str(err))
        raise typer.Exit(2) from None
