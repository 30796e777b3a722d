"""Command line of the studies: ``emfabric sweep``."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from emfabric.cli_app import app, console, emit, error

WorkersOpt = Annotated[int | None, typer.Option(
    "--workers", help="Local Dask cluster of N worker processes (default: one per two cores)")]
SchedulerOpt = Annotated[str | None, typer.Option(
    "--scheduler", help="Address of an existing Dask scheduler (e.g. tcp://host:8786); its "
                        "workers run the cases")]
ThreadsOpt = Annotated[int | None, typer.Option(
    "--threads", help="Numba threads per case (default: cores / workers locally, 1 on a "
                      "scheduler)")]


def _progress(quiet: bool) -> Progress:
    """A progress bar over cases, with throughput and the time left."""
    return Progress(TextColumn("[bold]{task.description}"), BarColumn(),
                   TextColumn("{task.completed}/{task.total} cases  {task.fields[rate]:6.1f} "
                              "cases/min"), TimeElapsedColumn(), TimeRemainingColumn(),
                   console=console, disable=quiet)


@app.command()
def sweep(
    study: Annotated[Path, typer.Argument(help="Study file (TOML: base, [set], [axes] or "
                                               "[lhs])")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Study folder: results.nc, "
                                                          "cases/, runs/")],
    workers: WorkersOpt = None,
    scheduler: SchedulerOpt = None,
    threads: ThreadsOpt = None,
    json_summary: Annotated[bool, typer.Option("--json", help="Print the summary as JSON on "
                                                              "stdout")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar")] = False,
) -> None:
    """Run every case of a study on Dask (reusing the cases already in the folder) and write
    DIR/results.nc."""
    from emfabric.study import StudyError, load_study, read_case
    from emfabric.study import sweep as run_sweep

    try:
        plan = load_study(study)
    except StudyError as err:
        error(str(err))
        raise typer.Exit(2) from None
    bar = _progress(quiet)
    t0 = time.perf_counter()
    reused = sum(read_case(out, c) is not None for c in plan.cases)
    with bar:
        task = bar.add_task(study.stem, total=len(plan.cases), completed=reused, rate=0.0)

        def progress(done: int, _todo: int) -> None:
            minutes = max(time.perf_counter() - t0, 1e-9) / 60.0
            bar.update(task, completed=reused + done, rate=done / minutes)

        try:
            outcome = run_sweep(plan, out, workers=workers, scheduler=scheduler,
                                threads=threads, progress=progress)
        except StudyError as err:
            bar.stop()
            error(str(err))
            raise typer.Exit(2) from None
        except KeyboardInterrupt:
            bar.stop()
            console.print("[yellow]interrupted[/]: the finished cases are kept in "
                          f"{out / 'cases'}; run the same command again to do the rest")
            raise typer.Exit(130) from None
        bar.update(task, completed=len(plan.cases))
    summary = outcome.summary()
    if json_summary:
        emit(json.dumps(summary))
    else:
        console.print(f"{summary['cases']} cases: {summary['ran']} ran, {summary['reused']} "
                      f"reused, {summary['failed']} failed or diverged; results in "
                      f"{summary['results']}")
    if summary["failed"] and not json_summary:
        console.print("[yellow]the failed cases' messages are in results.nc (variable "
                      "message) and cases/<key>.json[/]")
