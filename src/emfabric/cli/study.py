"""Command line of the studies: ``emfabric sweep``, ``estimate``, ``design-field``,
``ballistic-limit``.

Exit statuses (docs/errors.md): 2 for what is wrong before a case runs (the study file, an
option, the scenario, the folder in use); 1 for a study that ran and found no answer (no
bracket, the runs stopped completing) and for a file that cannot be written; 130 for an
interrupt, with one line saying what is kept and how to go on. A sweep whose cases diverged or
failed exits 0: those cases are results (results.nc, `status` and `message`)."""

from __future__ import annotations

import signal
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from emfabric.cli.app import (
    EXIT_FAILED,
    EXIT_INPUT,
    EXIT_INTERRUPTED,
    app,
    console,
    emit,
    error,
    hold_folder,
    load_or_exit,
    number,
    writing,
)
from emfabric.io import jsontext

WorkersOpt = Annotated[int | None, typer.Option(
    "--workers", parser=number(int, 1),
    help="Local Dask cluster of N worker processes (default: one per two cores)")]
SchedulerOpt = Annotated[str | None, typer.Option(
    "--scheduler", help="Address of an existing Dask scheduler (e.g. tcp://host:8786); its "
                        "workers run the cases")]
ThreadsOpt = Annotated[int | None, typer.Option(
    "--threads", parser=number(int, 1),
    help="Numba threads per case (default: each case's default within cores / workers "
         "locally, 1 on a scheduler)")]
VerboseOpt = Annotated[bool, typer.Option(
    "--verbose", "-v", help="Show Dask's own log messages and warnings (also: "
                            "EMFABRIC_DASK_VERBOSE=1)")]


def _warn_actuation(scenario, what: str) -> None:
    """The warnings of a study's scenario — what building it logs (a value far outside
    ballistic practice: emfabric.sim.sanity) and its plausibility (is the charge physical?
    emfabric.sim.plausibility) — once, before its runs, each as "warning: WHAT: …": the runs
    on the workers keep theirs to their case records (studies.sweep.run_case), which would
    print them once per case."""
    from emfabric.cli.run import warn
    from emfabric.sim.builder import build_model
    from emfabric.sim.plausibility import actuation_report
    from emfabric.studies.sweep import captured_warnings

    with captured_warnings() as built:  # what building it logs
        try:
            found = actuation_report(build_model(scenario, writes=False))["warnings"]
        except (ValueError, RuntimeError):
            return  # the study reports an unbuildable scenario itself
    for w in [*built, *found]:
        warn(f"{what}: {w}")


def _verbose(on: bool) -> None:
    if on:
        import os

        os.environ["EMFABRIC_DASK_VERBOSE"] = "1"  # read by emfabric.studies.sweep.connect


def _interrupted(out: Path, what: str) -> typer.Exit:
    """The one line an interrupted study prints (what is kept, how to go on); exit 130."""
    kept = len(list((out / "cases").glob("*.json"))) if (out / "cases").is_dir() else 0
    console.print(f"[yellow]interrupted[/]: {what}; {kept} finished runs are kept in "
                  f"{out / 'cases'}: run the same command again to reuse them and do the rest",
                  highlight=False, soft_wrap=True)
    return typer.Exit(EXIT_INTERRUPTED)



def _stop_on_signals() -> None:
    """SIGTERM and SIGHUP (a job scheduler's stop, a closed terminal) stop a study like Ctrl-C:
    the finished cases are on disk already, the local cluster is shut down."""
    from emfabric.runner.loop import interrupt

    for name in ("SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), interrupt)


def _progress(quiet: bool) -> Progress:
    """A progress bar over cases, with throughput and the time left."""
    return Progress(TextColumn("[bold]{task.description}"), BarColumn(),
                   TextColumn("{task.completed}/{task.total} cases  {task.fields[rate]:6.1f} "
                              "cases/min"), TimeElapsedColumn(), TimeRemainingColumn(),
                   console=console, disable=quiet)


@app.command(short_help="Run every case of a study on Dask: results.nc.")
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
    verbose: VerboseOpt = False,
) -> None:
    """Run every case of a study on Dask (reusing the cases already in the folder) and write
    DIR/results.nc."""
    from emfabric.studies.sweep import StudyError, load_study, read_case
    from emfabric.studies.sweep import sweep as run_sweep

    try:
        plan = load_study(study)
    except StudyError as err:
        error(str(err))
        raise typer.Exit(EXIT_INPUT) from None
    except OSError as err:
        error(f"cannot read {study}: {err.strerror or err}")
        raise typer.Exit(EXIT_INPUT) from None
    _verbose(verbose)
    hold_folder(out)  # one study at a time in a folder: exit 2 naming the holder
    from emfabric.cli.run import warn

    for w in plan.warnings:
        warn(w)
    if plan.cases:
        _warn_actuation(plan.cases[0].scenario, "the study's first case")
    _stop_on_signals()
    bar = _progress(quiet)
    t0 = time.perf_counter()
    reused = sum(read_case(out, c) is not None for c in plan.cases)
    with bar:
        task = bar.add_task(study.stem, total=len(plan.cases), completed=reused, rate=0.0)

        def progress(done: int, _todo: int) -> None:
            minutes = max(time.perf_counter() - t0, 1e-9) / 60.0
            bar.update(task, completed=reused + done, rate=done / minutes)

        try:
            with writing(out):
                outcome = run_sweep(plan, out, workers=workers, scheduler=scheduler,
                                    threads=threads, progress=progress)
        except StudyError as err:  # the options (workers, scheduler): before any case ran
            bar.stop()
            error(str(err))
            raise typer.Exit(EXIT_INPUT) from None
        except KeyboardInterrupt:
            bar.stop()
            done = sum(read_case(out, c) is not None for c in plan.cases)
            console.print(f"[yellow]interrupted[/]: {done} of {len(plan.cases)} cases finished "
                          f"and kept in {out / 'cases'}; run the same command again to do the "
                          f"rest", highlight=False, soft_wrap=True)
            raise typer.Exit(EXIT_INTERRUPTED) from None
        bar.update(task, completed=len(plan.cases))
    summary = outcome.summary()
    if json_summary:
        emit(jsontext.dumps(summary))
    else:
        console.print(f"{summary['cases']} cases: {summary['ran']} ran, {summary['reused']} "
                      f"reused, {summary['failed']} failed or diverged; results in "
                      f"{summary['results']}")
    if summary["failed"] and not json_summary:
        console.print("[yellow]the failed cases' messages are in results.nc (variable "
                      "message) and cases/<key>.json[/]")


SetOpt = Annotated[list[str] | None, typer.Option(
    "--set", help="Override a scenario value, e.g. --set fabric.nodes=[40,40] (repeatable)")]


@app.command(short_help="The paper's estimate of the field for a target tilt.")
def estimate(
    scenario: Annotated[str, typer.Argument(help="TOML file or built-in scenario name")],
    target_tilt: Annotated[float, typer.Option("--target-tilt", parser=number(float),
                                             help="Tilt to reach [rad]")],
    by: Annotated[float, typer.Option("--by", parser=number(float),
                                    help="Time by which to reach it [s]")],
    set_: SetOpt = None,
) -> None:
    """The paper's back-of-envelope field for a target tilt (eqs 5.3-5.4, with the node
    charge): JSON on stdout."""
    from emfabric.studies.design import estimate as eq54

    sc = load_or_exit(scenario, set_)
    try:
        est = eq54(sc, target_tilt, by)
    except ValueError as err:
        error(str(err))
        raise typer.Exit(EXIT_INPUT) from None
    emit(jsontext.dumps(est.as_dict()))


@app.command("design-field",
             short_help="Find the smallest field scale reaching a target tilt.")
def design_field(
    scenario: Annotated[str, typer.Argument(help="TOML file or built-in scenario name")],
    target_tilt: Annotated[float, typer.Option("--target-tilt", parser=number(float),
                                             help="Tilt to reach [rad]")],
    by: Annotated[float, typer.Option("--by", parser=number(float),
                                    help="Time by which to reach it [s]")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder: design.json, the probes' "
                                                          "cases, the figure")],
    workers: WorkersOpt = None,
    scheduler: SchedulerOpt = None,
    threads: ThreadsOpt = None,
    tolerance: Annotated[float, typer.Option(
        "--tolerance", parser=number(float),
        help="Relative width of the final bracket on the field scale")] = 0.02,
    set_: SetOpt = None,
    json_summary: Annotated[bool, typer.Option("--json", help="Print the result as JSON on "
                                                              "stdout")] = False,
    verbose: VerboseOpt = False,
) -> None:
    """The smallest scale of the scenario's field whose run reaches the target tilt by the
    given time, found by a bracketed search over runs on Dask (eq 5.4 beside it)."""
    from emfabric.io.atomic import write_atomic
    from emfabric.studies.design import design_field as search
    from emfabric.studies.sweep import StudyError

    sc = load_or_exit(scenario, set_)
    if not 0.0 < tolerance < 1.0:
        error(f"--tolerance {tolerance}: allowed: between 0 and 1")
        raise typer.Exit(EXIT_INPUT)
    _verbose(verbose)
    hold_folder(out)  # one study at a time in a folder: exit 2 naming the holder
    _warn_actuation(sc, "the scenario")
    _stop_on_signals()
    # the search reports each round of runs: an error after one is the study's failure (1),
    # before any, an input error (2)
    rounds: list[int] = []
    try:
        with writing(out):
            res = search(sc, target_tilt, by, out, workers=workers, scheduler=scheduler,
                         threads=threads, rel_tol=tolerance, progress=rounds.append)
    except KeyboardInterrupt:
        raise _interrupted(out, "no field found yet") from None
    except (StudyError, ValueError) as err:
        error(str(err))
        raise typer.Exit(EXIT_FAILED if rounds else EXIT_INPUT) from None
    text = jsontext.dumps(res, indent=1)
    from emfabric.viz.study_plots import design_figure

    with writing(out):
        write_atomic(out / "design.json", lambda tmp: tmp.write_text(text, encoding="utf-8"))
        fig = design_figure(res, out / "design.png")
    if json_summary:
        emit(jsontext.dumps({k: res[k] for k in ("scale", "B_centre", "estimate_eq54",
                                              "target_tilt", "by", "runs")}))
    else:
        console.print(f"field × {res['scale']:.4g} (|B| = {res['B_centre_norm']:.4g} T at the "
                      f"sheet centre) tilts by {target_tilt} rad within {by} s; eq 5.4 says "
                      f"{res['estimate_eq54']:.3g} T; {res['runs']} runs; figure {fig}")


@app.command("ballistic-limit",
             short_help="The ballistic limit V_BL (V50 with --seeds) and residual speeds.")
def ballistic_limit(
    scenario: Annotated[str, typer.Argument(help="TOML file or built-in scenario name (a "
                                                 "shot perforates where yarns break or a "
                                                 "pointed nose parts them: e.g. `rupture`)")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder: ballistic.json, .nc, .png "
                                                          "and the shots' cases")],
    seeds: Annotated[int, typer.Option(
        "--seeds", parser=number(int, 0),
        help="Seeded shots (modulus scatter and impact-point jitter) for V50")] = 0,
    tolerance: Annotated[float, typer.Option(
        "--tolerance", parser=number(float), help="Width of the final V_BL bracket [m/s]")] = 2.0,
    workers: WorkersOpt = None,
    scheduler: SchedulerOpt = None,
    threads: ThreadsOpt = None,
    set_: SetOpt = None,
    json_summary: Annotated[bool, typer.Option("--json", help="Print the result as JSON on "
                                                              "stdout")] = False,
    verbose: VerboseOpt = False,
) -> None:
    """V_BL of the model by bracketing and bisecting the striking speed, the Lambert-Jonas fit
    of the residual speeds above it, and with --seeds, V50 and its spread (runs on Dask)."""
    from emfabric.studies.ballistic import ballistic_limit as search
    from emfabric.studies.ballistic import (
        unresolved_bracket,
        v_bl_outside_v50,
        write_outputs,
    )
    from emfabric.studies.sweep import StudyError

    sc = load_or_exit(scenario, set_)
    if seeds < 0:
        error(f"--seeds {seeds}: allowed: 0 or more")
        raise typer.Exit(EXIT_INPUT)
    _verbose(verbose)
    hold_folder(out)  # one study at a time in a folder: exit 2 naming the holder
    _warn_actuation(sc, "the scenario")
    _stop_on_signals()
    # the search reports each round of shots: an error after one is the study's failure (1),
    # before any, an input error (2)
    rounds: list[int] = []
    try:
        with writing(out):
            res = search(sc, out, seeds=seeds, tolerance=tolerance, workers=workers,
                         scheduler=scheduler, threads=threads, progress=rounds.append)
    except KeyboardInterrupt:
        raise _interrupted(out, "no ballistic limit yet") from None
    except ImportError as err:
        error(f"the ballistic limit needs the studies extra: pip install 'emfabric[studies]' "
              f"({err})")
        raise typer.Exit(EXIT_INPUT) from None
    except typer.Exit:
        raise
    except (StudyError, ValueError, RuntimeError) as err:
        error(str(err))
        raise typer.Exit(EXIT_FAILED if rounds else EXIT_INPUT) from None
    with writing(out):
        files = write_outputs(res, out)
    if "v50_error" in res:  # V_BL written; the V50 asked for was not found
        error(f"{res['v50_error']} (V_BL and every shot are in {out})")
        raise typer.Exit(EXIT_FAILED)
    for nm in res.get("non_monotone", []):
        console.print("[yellow]warning:[/] non-monotone: a shot at "
                      f"{nm['stopped']:.4g} m/s stopped " + (
                          f"although one at {nm['perforated']:.4g} m/s perforated"
                          if nm["perforated"] is not None else
                          f"above V_BL = {res['v_bl']:.4g} m/s")
                      + " (the limit is not sharp here: see ballistic.png; --seeds gives V50)",
                      highlight=False, soft_wrap=True)
    note = v_bl_outside_v50(res)
    if note:
        console.print(f"[yellow]note:[/] {note}", highlight=False, soft_wrap=True)
    unresolved = unresolved_bracket(res)
    if json_summary:
        keep = ("v_bl", "v_bl_bracket", "lambert_jonas", "v50", "runs", "non_monotone") + (
            ("unresolved",) if res.get("unresolved") else ())
        # every key docs/studies.md lists, v50 null without --seeds (as ballistic.nc's)
        emit(jsontext.dumps({k: res.get(k) for k in keep}))
    else:
        lj = res["lambert_jonas"]
        console.print(f"V_BL = {res['v_bl']:.4g} m/s (bracket {res['v_bl_bracket'][0]:.4g} – "
                      f"{res['v_bl_bracket'][1]:.4g}); Lambert–Jonas a = {lj['a']:.3g}, "
                      f"p = {lj['p']:.3g}, V_BL = {lj['v_bl']:.4g} m/s; {res['runs']} runs; "
                      f"{', '.join(str(f) for f in files)}")
        if "v50" in res:
            v = res["v50"]
            if v.get("separated"):
                console.print(f"V50 = {v['v50']:.4g} m/s: the seeded shots separate completely "
                              f"(every shot at {v['ci95'][0]:.4g} m/s or slower stopped, every "
                              f"one at {v['ci95'][1]:.4g} m/s or faster perforated), so V50 "
                              "lies in that gap and no spread is resolved (σ below the gap)")
            else:
                console.print(f"V50 = {v['v50']:.4g} m/s, 95 % [{v['ci95'][0]:.4g}, "
                              f"{v['ci95'][1]:.4g}], σ = {v['sigma']:.3g} m/s")
    if unresolved:
        # the result is written and printed, but it is not the limit to the tolerance asked
        error(f"{unresolved} ({out})")
        raise typer.Exit(EXIT_FAILED)
