"""`emfabric plot` and `emfabric animate`: figures and movies from a run's files."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated

import typer

from emfabric.cli import app, console


def _show_warnings() -> None:
    """Send the plotting modules' warnings (e.g. "not a complete run") to the console."""
    from rich.logging import RichHandler

    for name in ("emfabric.plots", "emfabric.animation"):
        logger = logging.getLogger(name)
        if not any(isinstance(h, RichHandler) for h in logger.handlers):
            logger.addHandler(RichHandler(console=console, show_time=False, show_path=False))
        logger.setLevel(logging.INFO)


def _missing(err: FileNotFoundError) -> typer.Exit:
    console.print(f"[bold red]error:[/] {err}", highlight=False)
    return typer.Exit(2)


@app.command()
def plot(
    runs: Annotated[list[Path], typer.Argument(help="Run folder(s); several are overlaid")],
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Figure folder (default: <first run>/figures)")] = None,
) -> None:
    """Draw the spin, impact-sequence, energy and velocity figures (PNG and PDF)."""
    from emfabric.plots import plot_runs

    _show_warnings()
    try:
        files = plot_runs(runs, out)
    except FileNotFoundError as err:
        raise _missing(err) from None
    for f in files:
        console.print(str(f))


@app.command()
def animate(
    run_dir: Annotated[Path, typer.Argument(help="Run folder")],
    gif: Annotated[bool, typer.Option("--gif", help="Also write a GIF")] = False,
    fps: Annotated[int, typer.Option(min=1, help="Frames per second")] = 10,
) -> None:
    """Write an MP4 (and GIF) of the impact from the run's snapshots."""
    from emfabric.animation import animate as make

    _show_warnings()
    try:
        files = make(run_dir, gif=gif, fps=fps)
    except FileNotFoundError as err:
        raise _missing(err) from None
    for f in files:
        console.print(str(f))
