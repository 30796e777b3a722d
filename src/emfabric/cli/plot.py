"""`emfabric plot` and `emfabric animate`: figures and movies from a run's files.

Exit statuses (docs/errors.md): a missing or unreadable run folder 2, a figure or movie that
cannot be written (a read-only folder, a full disk) 1, with one line naming the file."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from emfabric.cli.app import (
    EXIT_INPUT,
    app,
    check_readable,
    emit,
    error,
    number,
    show_messages,
    writing,
)


@app.command(short_help="Draw a run's or a study's figures (PNG and PDF).")
def plot(
    runs: Annotated[list[Path], typer.Argument(help="Run folder(s); several are overlaid")],
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Figure folder (default: <first run>/figures)")] = None,
) -> None:
    """Draw the spin, impact-sequence, energy and velocity figures (PNG and PDF); for a study
    folder (results.nc), each metric against the study's axes."""
    from emfabric.viz.plots import plot_runs

    show_messages()
    study = len(runs) == 1 and (runs[0] / "results.nc").is_file() and \
        not (runs[0] / "history.nc").is_file()
    check_readable(*(r / name for r in runs for name in ("history.nc", "snapshots.nc",
                                                         "results.nc")))
    with writing(out if out is not None else runs[0] / "figures"):
        if study:
            from emfabric.viz.study_plots import study_figures

            files = study_figures(runs[0], out)
        else:
            files = plot_runs(runs, out)
    for f in files:
        emit(str(f))


@app.command(short_help="Write an MP4 (and GIF) of a run's impact.")
def animate(
    run_dir: Annotated[Path, typer.Argument(help="Run folder")],
    gif: Annotated[bool, typer.Option("--gif", help="Also write a GIF")] = False,
    mp4: Annotated[bool, typer.Option(
        "--mp4/--no-mp4", help="Write the MP4 (needs the `mp4` extra: imageio-ffmpeg)")] = True,
    fps: Annotated[int, typer.Option(parser=number(int, 1), help="Frames per second")] = 10,
) -> None:
    """Write an MP4 (and GIF) of the impact from the run's snapshots; prints their paths."""
    from emfabric.viz.animation import MP4_MISSING
    from emfabric.viz.animation import animate as make

    show_messages()
    if not (mp4 or gif):
        error("nothing to write: --no-mp4 without --gif")
        raise typer.Exit(EXIT_INPUT)
    check_readable(run_dir / "history.nc", run_dir / "snapshots.nc")
    try:
        with writing(run_dir / "figures"):
            files = make(run_dir, gif=gif, fps=fps, mp4=mp4)
    except RuntimeError as err:
        if str(err) != MP4_MISSING:
            raise
        error(MP4_MISSING)
        raise typer.Exit(EXIT_INPUT) from None
    for f in files:
        emit(str(f))
