"""The field command: ``emfabric field SCENARIO --at X Y Z [--time T] [--plot FILE]``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from emfabric.cli.app import EXIT_INPUT, app, emit, error, load_or_exit, number, writing
from emfabric.config.scenario import ScenarioError
from emfabric.io import jsontext

_load = load_or_exit


def _points(args: list[str]) -> list[tuple[float, float, float]]:
    """The points of repeated `--at X Y Z` options (Typer has no repeated three-value option)."""
    import math

    points, k = [], 0
    while k < len(args):
        if args[k] != "--at":
            raise ValueError(f"unexpected argument {args[k]!r}; allowed: --at X Y Z, --time T, "
                             f"--set KEY=VALUE")
        vals = args[k + 1:k + 4]
        try:
            p = tuple(float(v) for v in vals)
        except ValueError:
            p = ()
        if len(p) != 3 or not all(math.isfinite(c) for c in p):
            raise ValueError(f"--at {' '.join(vals)}: allowed: three finite numbers X Y Z [m]")
        points.append(p)
        k += 4
    return points


def _check_format(path: Path) -> None:
    """Exit 2 unless matplotlib writes the file's format (its suffix)."""
    from matplotlib.backend_bases import FigureCanvasBase

    kinds = FigureCanvasBase.get_supported_filetypes()
    if path.suffix.lstrip(".").lower() not in kinds:
        error(f"--plot {path}: allowed: a file ending in "
              f"{', '.join('.' + k for k in sorted(kinds))}")
        raise typer.Exit(EXIT_INPUT)


@app.command(short_help="The applied E and B at points (--at X Y Z), or a plot.",
             context_settings={"ignore_unknown_options": True, "allow_extra_args": True})
def field(
    ctx: typer.Context,
    scenario: Annotated[str, typer.Argument(help="TOML file or built-in scenario name")],
    at_time: Annotated[float, typer.Option("--time", parser=number(float), help="Time [s]")] = 0.0,
    plot: Annotated[Path | None, typer.Option(
        "--plot", help="Draw B (and the induced E) over the sheet's plane with the coils, "
                       "and along the flight axis, to this file (PNG, PDF, SVG)")] = None,
    set_: Annotated[list[str] | None, typer.Option("--set", help="Override a value")] = None,
) -> None:
    """The applied field E [V/m] and B [T] at points given as --at X Y Z (repeat for more), as
    JSON on stdout: {"E": [..], "B": [..]} for one point, a list of {"at", "E", "B"} for
    several; with --plot, a figure of the field over the sheet and along the flight axis."""
    import math

    sc = _load(scenario, set_)
    try:
        at = _points(list(ctx.args))
    except ValueError as err:
        error(str(err))
        raise typer.Exit(EXIT_INPUT) from None
    if not at and plot is None:
        error("give at least one point: --at X Y Z (or --plot FILE)")
        raise typer.Exit(EXIT_INPUT)
    if not math.isfinite(at_time):
        error(f"--time {at_time}: allowed: a finite time [s]")
        raise typer.Exit(EXIT_INPUT)
    if plot is not None:
        _check_format(plot)
    from emfabric.sources.build import build_field
    from emfabric.sources.evaluate import fields_at

    try:
        fld = build_field(sc)
    except ScenarioError as err:
        error(str(err))
        raise typer.Exit(EXIT_INPUT) from None
    if plot is not None:
        from emfabric.sim.geometry import initial_pose
        from emfabric.sources.picture import field_picture
        from emfabric.viz.field_plot import draw

        # the projectile's start and flight direction, as the run would have them
        pose = initial_pose(sc.projectile)
        pic = field_picture(sc, fld, at_time, pose.position, pose.flight_direction)
        with writing(plot):
            drawn = draw(pic, plot)
        emit(str(drawn))
    if not at:
        return
    e, b = fields_at(fld, at, at_time)
    rows = [{"at": list(p), "E": e[k].tolist(), "B": b[k].tolist()} for k, p in enumerate(at)]
    if len(rows) == 1:
        emit(jsontext.dumps({"E": rows[0]["E"], "B": rows[0]["B"]}))
    else:
        emit(jsontext.dumps(rows))
