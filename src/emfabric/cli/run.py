"""The run commands: ``emfabric run | validate | new | scenarios``."""

from __future__ import annotations

import signal
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table
from rich.text import Text

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
    out_console,
    show_messages,
    writing,
)
from emfabric.config.scenario import (
    ScenarioError,
    apply_overrides,
    builtin_names,
    load_scenario,
    parse_override,
)
from emfabric.io import jsontext

_load = load_or_exit


@app.command(short_help="Run a scenario into a folder (--resume continues one).")
def run(
    scenario: Annotated[str | None, typer.Argument(
        help="TOML file or built-in scenario name (see `emfabric scenarios`); default "
             "paper-field")] = None,
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Output folder (default: runs/<scenario name>)")] = None,
    set_: Annotated[list[str] | None, typer.Option(
        "--set", help="Override a value, e.g. --set field.B=[0,0,0.1] (repeatable)")] = None,
    plot: Annotated[bool, typer.Option("--plot", help="Draw the figures after the run")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar")] = False,
    json_summary: Annotated[bool, typer.Option(
        "--json", help="Print the summary as JSON on stdout")] = False,
    resume: Annotated[Path | None, typer.Option(
        "--resume", help="Continue the run whose checkpoint is in this folder")] = None,
    force: Annotated[bool, typer.Option(
        "--force", help="Replace the run already in the output folder")] = False,
    threads: Annotated[int | None, typer.Option(
        "--threads", parser=number(int, 1),
        help="Numba threads for the node kernels (1: serial; default: 1 below 250 x 250 nodes, "
             "else every core); the results are the same")] = None,
) -> None:
    """Run a scenario; write history.nc, snapshots, ParaView files and a checkpoint into the output folder as the run goes (--resume DIR continues a stopped run)."""  # noqa: E501
    from emfabric.io.checkpoint import CHECKPOINT, CheckpointError, read_checkpoint
    from emfabric.io.lock import FolderInUse
    from emfabric.runner.loop import OutputError
    from emfabric.runner.loop import resume as resume_run
    from emfabric.runner.loop import run as run_scenario

    if resume is not None:
        if out is not None and out.resolve() != resume.resolve():
            error(f"--out {out} and --resume {resume} name different folders; a resumed run "
                  f"writes into the folder it resumes")
            raise typer.Exit(EXIT_INPUT)
        if resume.is_dir():
            hold_folder(resume)  # one run at a time in a folder: exit 2 naming the holder
        try:
            sc = read_checkpoint(resume / CHECKPOINT)[0]
        except CheckpointError as err:
            error(str(err))
            raise typer.Exit(EXIT_INPUT) from None
        given = None
        if scenario is not None:
            given = _load(scenario, set_)
        elif set_:  # overrides of the stored scenario: refused below unless they change
            # nothing or only make solver.end_time later (the run continued further)
            try:
                given = apply_overrides(sc, dict(parse_override(o) for o in set_))
            except ScenarioError as err:
                error(str(err))
                raise typer.Exit(EXIT_INPUT) from None
        if given is not None and given.solver.end_time > sc.solver.end_time:
            sc = given  # the progress display's end (resume refuses any other change)
        out_dir = resume

        def start(progress_fn):
            return resume_run(resume, given, progress=progress_fn, threads=threads)
    else:
        sc = _load(scenario or "paper-field", set_)
        if out is not None:
            out_dir = out
        elif scenario is not None and Path(scenario).is_file():
            out_dir = Path("runs") / Path(scenario).stem  # a copied file keeps its own folder
        else:
            out_dir = Path("runs") / sc.name
        hold_folder(out_dir)  # one run at a time in a folder: exit 2 naming the holder
        from emfabric.io.outputs import clear_run, has_run_files, run_in

        held = run_in(out_dir)
        if held is not None and not force:
            error(f"{out_dir} holds another run ({held}); use --force to replace it, "
                  f"--resume {out_dir} to continue it, or --out to write elsewhere")
            raise typer.Exit(EXIT_INPUT)
        if held is not None or has_run_files(out_dir):  # or a run stopped before its start
            clear_run(out_dir)

        def start(progress_fn):
            return run_scenario(sc, out_dir, progress=progress_fn, threads=threads)
    show_messages()
    # Ctrl-C, SIGTERM and a closed terminal (SIGHUP) all stop the run with its files kept
    from emfabric.runner.loop import interrupt
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), interrupt)
    from emfabric.cli.progress import make_progress

    result = None
    history = resume / "history.nc" if resume is not None else None
    # a terminal: a live display that fits its width; a log or a pipe: a plain line every
    # few seconds (cli/progress.py)
    with make_progress(None, sc, console, quiet=quiet, history=history) as progress:
        try:
            result = start(progress)
        except KeyboardInterrupt as exc:
            result = getattr(exc, "result", None)
            if result is None:
                if (out_dir / CHECKPOINT).is_file():
                    console.print("[yellow]interrupted[/] before the run went on; continue "
                                  f"with `emfabric run --resume {escape(str(out_dir))}`",
                                  highlight=False, soft_wrap=True)
                else:
                    console.print("[yellow]interrupted[/] before the run's first step: no "
                                  "checkpoint, nothing to resume; run it again (into the "
                                  "same folder: it holds nothing to keep)", highlight=False)
                raise typer.Exit(EXIT_INTERRUPTED) from None
            console.print("[yellow]interrupted[/]: the history written so far is marked partial;"
                          f" continue with `emfabric run --resume {escape(str(out_dir))}`",
                          markup=True, highlight=False, soft_wrap=True)
        except (CheckpointError, ScenarioError, FolderInUse) as exc:
            error(str(exc))
            raise typer.Exit(EXIT_INPUT) from None
        except OutputError as exc:  # a write failed (full disk, permissions): status failed
            result = getattr(exc, "result", None)
            hint = (f"; once it can be written, `emfabric run --resume {out_dir}` continues "
                    f"from the last checkpoint" if (out_dir / CHECKPOINT).is_file() else "")
            error(f"{exc}{hint}")
        except Exception as exc:  # DivergenceError and friends
            result = getattr(exc, "result", None)
            error(str(exc))
    if result is None:
        raise typer.Exit(EXIT_FAILED)
    _print_summary(result, json_summary)
    if plot:
        from emfabric.viz.plots import plot_runs

        with writing(out_dir / "figures"):
            files = plot_runs([out_dir])
        for f in files:
            emit(str(f))
    if result.status != "complete":
        raise typer.Exit(EXIT_INTERRUPTED if result.status == "partial" else EXIT_FAILED)


def _print_summary(result, as_json: bool) -> None:
    s = result.summary
    if as_json:
        emit(jsontext.dumps(s, indent=2))
        return
    # user text (scenario name, end reason, paths) is never read as console markup
    table = Table(title=escape(f"{result.model.scenario.name}: {s['status']} "
                               f"({s['end_reason']})"), show_header=False)
    table.add_column("quantity")
    table.add_column("value", justify="right")

    def fmt(v) -> str:
        if v is None:
            return "not given"  # (the yarn strength of a scenario without one)
        if isinstance(v, list) and not v:
            return "none"
        if isinstance(v, list):
            return "[" + ", ".join(f"{c:.4g}" for c in v) + "]"
        if isinstance(v, float):
            return f"{v:.5g}"
        return str(v)

    for key, value in s.items():
        if key in ("status", "end_reason"):
            continue
        if isinstance(value, list) and value and all(isinstance(c, str) for c in value):
            # text (the plausibility warnings) reads left-aligned, one item a line
            table.add_row(key, Text("\n".join(f"• {c}" for c in value), justify="left"))
            continue
        table.add_row(key, escape(fmt(value)))
    if result.out_dir is not None:
        table.add_row("output", escape(str(result.out_dir)))
    console.print(table)


@app.command(short_help="Check a scenario; --show prints it in full.")
def validate(
    scenario: Annotated[str, typer.Argument(help="TOML file or built-in scenario name")],
    set_: Annotated[list[str] | None, typer.Option("--set", help="Override a value")] = None,
    show: Annotated[bool, typer.Option("--show", help="Print the full scenario")] = False,
) -> None:
    """Check a scenario file; print the full scenario (defaults filled in) with --show."""
    sc = _load(scenario, set_)
    from emfabric.sim.builder import build_model

    show_messages()  # the model's warnings (a typing mistake?) as `run` shows them

    try:
        model = build_model(sc)
    except ScenarioError as err:
        error(str(err))
        raise typer.Exit(EXIT_INPUT) from None
    grids = [model.ply_grid(p) for p in range(model.ply_count)]
    pack = (f"{grids[0][0]} x {grids[0][1]} nodes" if len(grids) == 1 else
            f"{len(grids)} plies, {model.node_count} nodes")
    console.print(f"[green]ok[/]: {escape(sc.name)}: {pack}, "
                  f"{model.seg_count} yarn segments, projectile: {sc.projectile.shape}")
    _print_plausibility(model)
    if show:
        emit(sc.to_commented_toml())


def warn(message: str) -> None:
    """A warning line on stderr, in yellow; user text is never read as markup."""
    console.print("[yellow]warning:[/] " + escape(str(message)), highlight=False,
                  soft_wrap=True)


def _print_plausibility(model) -> None:
    """validate's lines on whether the charge and the applied field are physical
    (emfabric.sim.plausibility; docs/theory.md §3.1); its warnings in yellow."""
    from emfabric.sim.plausibility import actuation_report

    r = actuation_report(model)
    lines = [f"charge: {r['charge_C']:.3g} C on {r['area_m2']:.3g} m²: surface charge "
             f"σ = {r['surface_charge_C_m2']:.3g} C/m²"]
    if r["plies"] > 1:
        lines.append("per ply: " + ", ".join(
            f"{q:.3g} C (σ = {s:.3g} C/m²)"
            for q, s in zip(r["ply_charge_C"], r["ply_surface_charge_C_m2"], strict=True)))
    lines.append(f"surface field E_s = |σ|/(2ε0) = {r['max_surface_field_V_m']:.3g} V/m: "
                 f"{r['field_over_air_breakdown']:.3g} × air's breakdown field "
                 f"({r['air_breakdown_V_m']:.3g} V/m), {r['field_over_material_limit']:.3g} × "
                 f"the most any material holds ({r['material_limit_V_m']:.3g} V/m)")
    strength = ("no yarn strength given (fabric.material.tensile_strength)"
                if r["tensile_strength_Pa"] is None else
                f"{r['pressure_over_strength']:.3g} × the yarn's tensile strength "
                f"({r['tensile_strength_Pa']:.3g} Pa)")
    lines.append(f"electrostatic pressure p = σ²/(2ε0) = {r['electrostatic_pressure_Pa']:.3g} "
                 f"Pa: {strength}")
    when = "" if r["peak_B_time_s"] == 0.0 else f" (at t = {r['peak_B_time_s']:.3g} s)"
    lines.append(f"applied field at the fabric: peak |B| = {r['peak_B_T']:.3g} T{when} "
                 f"(NdFeB remanence ≈ 1.4 T, pulsed record ≈ 100 T), peak |E| = "
                 f"{r['peak_E_V_m']:.3g} V/m")
    for line in lines:
        console.print("  " + escape(line), highlight=False, soft_wrap=True)
    for w in r["warnings"]:
        warn(w)


@app.command(short_help="Print a scenario file to start from, keys explained.")
def new(
    scenario: Annotated[str, typer.Argument(
        help="Built-in scenario (see `emfabric scenarios`) or TOML file to start from")
    ] = "paper-field",
    set_: Annotated[list[str] | None, typer.Option("--set", help="Override a value")] = None,
) -> None:
    """Print a scenario file to start from, every key with its meaning and unit: `emfabric new
    paper-field > my.toml`, edit, then `emfabric run my.toml`."""
    emit(_load(scenario, set_).to_commented_toml())


@app.command(short_help="List the built-in scenarios.")
def scenarios() -> None:
    """List the built-in scenarios."""
    table = Table("name", "description")
    for name in builtin_names():
        table.add_row(name, load_scenario(name).description)
    out_console.print(table)
