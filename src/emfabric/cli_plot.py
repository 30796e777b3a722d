"""`emfabric plot` and `emfabric animate`: figures and movies from a run's files."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from emfabric.cli import app, console


@app.command()
def plot(
    runs: Annotated[list[Path], typer.Argument(help="Run folder(s); several are overlaid")],
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Figure folder (default: <first run>/figures)")] = None,
) -> None:
    """Draw the spin, impact-sequence, energy and velocity figures (PNG and PDF)."""
    from emfabric.plots import plot_runs

    files = plot_runs(runs, out)
    for f in files:
        console.print(str(f))


@app.command()
def animate(
    run_dir: Annotated[Path, typer.Argument(help="Run folder")],
    gif: Annotated[bool, typer.Option("--gif", help="Also write a GIF")] = False,
    fps: Annotated[int, typer.Option(help="Frames per second")] = 10,
) -> None:
    """Write an MP4 (and GIF) of the impact from the run's snapshots."""
    from emfabric.animation import animate as make

    for f in make(run_dir, gif=gif, fps=fps):
        console.print(str(f))
