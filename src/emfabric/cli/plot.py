"""`emfabric plot` and `emfabric animate`: figures and movies from a run's files."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from emfabric.cli.app import app, emit, error, show_messages


def _missing(err: FileNotFoundError) -> typer.Exit:
    error(str(err))
    return typer.Exit(2)


@app.command()
def plot(
    runs: Annotated[list[Path], typer.Argument(help="Run folder(s); several are overlaid")],
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Figure folder (default: <first run>/figures)")] = None,
) -> None:
    """Draw the spin, impact-sequence, energy and velocity figures (PNG and PDF); for a study
    folder (results.nc), each metric against the study's axes."""
    from emfabric.viz.plots import plot_runs

    show_messages()
    try:
        if len(runs) == 1 and (runs[0] / "results.nc").is_file() and \
                not (runs[0] / "history.nc").is_file():
            from emfabric.viz.study_plots import study_figures

            files = study_figures(runs[0], out)
        else:
            files = plot_runs(runs, out)
    except FileNotFoundError as err:
        raise _missing(err) from None
    for f in files:
        emit(str(f))


@app.command()
def animate(
    run_dir: Annotated[Path, typer.Argument(help="Run folder")],
    gif: Annotated[bool, typer.Option("--gif", help="Also write a GIF")] = False,
    mp4: Annotated[bool, typer.Option(
        "--mp4/--no-mp4", help="Write the MP4 (needs the `mp4` extra: imageio-ffmpeg)")] = True,
    fps: Annotated[int, typer.Option(min=1, help="Frames per second")] = 10,
) -> None:
    """Write an MP4 (and GIF) of the impact from the run's snapshots; prints their paths."""
    from emfabric.viz.animation import MP4_MISSING
    from emfabric.viz.animation import animate as make

    show_messages()
    if not (mp4 or gif):
        error("nothing to write: --no-mp4 without --gif")
        raise typer.Exit(2)
    try:
        files = make(run_dir, gif=gif, fps=fps, mp4=mp4)
    except FileNotFoundError as err:
        raise _missing(err) from None
    except RuntimeError as err:
        if str(err) != MP4_MISSING:
            raise
        error(MP4_MISSING)
        raise typer.Exit(2) from None
    for f in files:
        emit(str(f))
