"""Figures of studies: each metric of results.nc against the axes; the design-field search;
the ballistic limit.

Labels are words and conventional units, never the file's variable names or CF unit strings:
`final_angular_velocity` [rad s-1] is drawn as "final angular velocity ω [rad/s]" with a panel
per component ω_x, ω_y, ω_z; angles (`max_tilt`, `max_yaw`) in degrees; the deflection in mm;
`perforated` as the fraction of the decided cases that perforated at each value of an axis
(−1, undecided or failed, left out and counted in the title). A vector-valued axis (e.g.
``"field.B" = [[0.05, 0, 0], [0.1, 0, 0]]``) is drawn on a numeric axis: the one component that
varies, or the magnitude when the vectors share a direction; a Latin hypercube study against
each sampled setting.
"""

from __future__ import annotations

import json
import logging
import math
import re
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from emfabric.viz.plots import _SCALARS, _VECTORS, _math, new_figure, save_figure

log = logging.getLogger(__name__)

PLOTTED = ("residual_speed", "max_tilt", "max_yaw", "final_angular_velocity",
           "energy_absorbed", "broken_yarns", "max_deflection", "perforated", "wall_time")
"""The metrics of results.nc drawn by `study_figures` (study_<name>.png and .pdf)."""


@dataclass(frozen=True)
class MetricLabel:
    """How a metric of results.nc is named on a figure."""

    words: str
    """What it is, in words ("final angular velocity")."""
    symbol: str = ""
    """Its symbol, unicode ("ω"); components are drawn as mathtext `tex` with a subscript."""
    tex: str = ""
    """The symbol as mathtext without the dollars (r"\\omega"), for the component labels."""
    unit: str | None = None
    """The unit drawn, when it differs from the file's ("deg" for "rad", "mm" for "m")."""


METRIC_LABELS: dict[str, MetricLabel] = {
    "residual_speed": MetricLabel("residual speed", "v_r", "v_r"),
    "max_tilt": MetricLabel("largest tilt", "Θ", r"\Theta", "deg"),
    "max_yaw": MetricLabel("largest yaw", "ψ", r"\psi", "deg"),
    "final_angular_velocity": MetricLabel("final angular velocity", "ω", r"\omega"),
    "energy_absorbed": MetricLabel("energy absorbed", "ΔE", r"\Delta E"),
    "broken_yarns": MetricLabel("broken yarn segments"),
    "plies_perforated": MetricLabel("plies perforated"),
    "max_deflection": MetricLabel("largest deflection", "", "", "mm"),
    "perforated": MetricLabel("perforation probability"),
    "wall_time": MetricLabel("wall time per case"),
}
"""Variable name of results.nc -> its words, symbol and drawn unit."""

CONVERSIONS: dict[tuple[str, str], float] = {
    ("rad", "deg"): 180.0 / math.pi,
    ("m", "mm"): 1e3,
    ("s", "µs"): 1e6,
}
"""(file unit, drawn unit) -> factor on the values."""

SETTING_NAMES: dict[str, str] = {
    "field.B": "magnetic field",
    "field.E": "electric field",
    "field.gravity": "gravity",
    "projectile.velocity": "striking velocity",
    "projectile.angular_velocity": "initial angular velocity",
    "projectile.radius": "projectile radius",
    "projectile.mass": "projectile mass",
    "projectile.gap": "initial gap",
    "projectile.shape": "projectile shape",
    "projectile.length": "projectile length",
    "fabric.size": "sheet size",
    "fabric.plies": "plies",
    "fabric.edges": "edges",
    "fabric.style": "fabric style",
    "fabric.material.name": "material",
    "fabric.damage.law": "damage law",
    "solver.integrator": "integrator",
    "contact.segments": "segment contact",
    "fabric.velocity": "fabric velocity",
    "fabric.charge_per_node": "charge per node",
    "fabric.nodes": "grid nodes",
    "fabric.material.youngs_modulus": "Young's modulus",
    "fabric.material.modulus_cv": "modulus scatter (cv)",
    "fabric.material.seed": "modulus seed",
    "fabric.damage.rate": "damage rate",
    "fabric.damage.critical_stretch": "critical stretch",
    "contact.static_friction": "static friction",
    "contact.dynamic_friction": "dynamic friction",
    "solver.phi": "φ-scheme parameter",
    "solver.dt_max": "largest time step",
    "solver.end_time": "end time",
}
"""Scenario keys (sweep axes) -> words; other keys are drawn as the dotted key itself."""

_NO_VALUE = {"perforated", "broken_yarns", "plies_perforated"}
"""Integer metrics whose −1 means "no value" (undecided or failed)."""

_SUPERSCRIPT = str.maketrans("0123456789-", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻")


def cf_units(units: str) -> str:
    """A CF/UDUNITS unit string in the conventional form: "m s-1" -> "m/s", "rad s-1" ->
    "rad/s", "m s-2" -> "m/s²", "kg m2" -> "kg m²", "W m-2 K-1" -> "W/(m² K)", "1" -> ""."""
    units = units.strip()
    if units in ("", "1", "-"):
        return ""
    num, den = [], []
    for token in units.split():
        m = re.fullmatch(r"([^\d\-+^]+)\^?([+-]?\d+)?", token)
        if m is None:
            return units
        base, power = m.group(1), int(m.group(2) or 1)
        text = base if abs(power) == 1 else base + str(abs(power)).translate(_SUPERSCRIPT)
        (den if power < 0 else num).append(text)
    top = " ".join(num) or "1"
    if not den:
        return top
    bottom = den[0] if len(den) == 1 else "(" + " ".join(den) + ")"
    return f"{top}/{bottom}"


def _drawn_unit(file_units: str, wanted: str | None) -> tuple[str, float]:
    """The unit drawn and the factor on the file's values."""
    if file_units == "rad":
        return "deg", CONVERSIONS[("rad", "deg")]
    if wanted is not None and (file_units, wanted) in CONVERSIONS:
        return wanted, CONVERSIONS[(file_units, wanted)]
    return cf_units(file_units), 1.0


def _unit_suffix(unit: str) -> str:
    return f" [{unit}]" if unit else ""


# the settings of a sweep axis: words, symbol and unit


def _models(annotation) -> list[type]:
    """The pydantic models inside an annotation (unions, tuples, Annotated)."""
    from pydantic import BaseModel

    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    out: list[type] = []
    for arg in typing.get_args(annotation):
        out += _models(arg)
    return out


def setting_unit(key: str) -> str | None:
    """The unit [..] a scenario key's documentation gives ("projectile.mass" -> "kg"), "" for
    a dimensionless one, None for a key not found or not documented with a unit."""
    from emfabric.config.scenario import Scenario

    models: list[type] = [Scenario]
    field = None
    for part in key.split("."):
        if part.isdigit():  # an index into a list of tables
            continue
        found = [m for m in models if part in m.model_fields]
        if not found:
            return None
        field = found[0].model_fields[part]
        models = _models(field.annotation)
    if field is None or not field.description:
        return None
    m = re.search(r"\[([^\]]+)\]", field.description)
    if m is None:
        return None
    unit = m.group(1).split("=")[0].strip()
    return "" if unit in ("-", "1") else unit


def _setting_words(key: str) -> str:
    return SETTING_NAMES.get(key, key)


@dataclass
class StudyAxis:
    """How one axis of a study is drawn."""

    x: np.ndarray
    """Positions along the plot's x axis (the values, or 0, 1, … for a categorical axis)."""
    label: str
    """Axis label, with the unit."""
    words: str
    """The setting in words, for titles."""
    ticks: list[str] | None = None
    """Tick labels of a categorical axis (None: numeric)."""
    short: str = ""
    """A short name for legends ("$B_x$ = 0.05 T" is built from it)."""
    unit: str = ""


def _scalar_axis(key: str, values: np.ndarray) -> StudyAxis:
    words = _setting_words(key)
    sym, unit = _SCALARS.get(key, ("", None))
    if unit is None:
        unit = setting_unit(key) or ""
    label = " ".join(p for p in (words, sym) if p) + _unit_suffix(unit)
    return StudyAxis(values.astype(float), label, words, None, sym or words, unit)


def vector_axis(key: str, vectors: np.ndarray) -> StudyAxis:
    """A vector-valued axis on a numeric x: the one component that varies (labelled B_x
    [T]), or the magnitude |B| [T] when the vectors share a direction (given in the label);
    categorical (the vectors as tick labels) when neither."""
    vectors = np.asarray(vectors, dtype=float)
    words = _setting_words(key)
    sym, sub, unit = _VECTORS.get(key, (key.split(".")[-1], "", None))
    if unit is None:
        unit = setting_unit(key) or ""
    names = "xyz" if vectors.shape[1] == 3 else [str(i) for i in range(vectors.shape[1])]
    varies = [c for c in range(vectors.shape[1]) if np.ptp(vectors[:, c]) > 0]
    if len(varies) == 1:
        c = varies[0]
        short = _math(sym, sub + names[c])
        fixed = [f"{_math(sym, sub + names[i])} = {vectors[0, i]:g}"
                 for i in range(vectors.shape[1]) if i != c and vectors[0, i] != 0]
        label = (f"{words} {short}{_unit_suffix(unit)}"
                 + (f"  ({', '.join(fixed)})" if fixed else ""))
        return StudyAxis(vectors[:, c], label, f"{words} {short}", None, short, unit)
    norms = np.linalg.norm(vectors, axis=1)
    live = norms > 0
    if live.any():
        dirs = vectors[live] / norms[live, None]
        if np.allclose(dirs, dirs[0], atol=1e-9):
            short = f"$|{sym}{'_{' + sub + '}' if sub else ''}|$"
            along = ", ".join(f"{d:.3g}" for d in dirs[0])
            label = f"{words} {short}{_unit_suffix(unit)} along ({along})"
            return StudyAxis(norms, label, f"{words} {short}", None, short, unit)
    ticks = ["[" + ", ".join(f"{v:g}" for v in row) + "]" for row in vectors]
    return StudyAxis(np.arange(len(vectors), dtype=float), f"{words}{_unit_suffix(unit)}",
                     words, ticks, _math(sym, sub), unit)


def study_axis(ds: xr.Dataset, dim: str) -> StudyAxis:
    """How the axis `dim` of results.nc is drawn (see `vector_axis` for a vector axis)."""
    if f"{dim}.values" in ds:
        return vector_axis(dim, ds[f"{dim}.values"].values)
    coord = ds[dim].values
    if coord.dtype.kind in "ifu":
        return _scalar_axis(dim, coord)
    words = _setting_words(dim)
    return StudyAxis(np.arange(len(coord), dtype=float), words, words,
                     [str(c) for c in coord], words)


def _sampled_axes(ds: xr.Dataset) -> list[tuple[str, StudyAxis]]:
    """A Latin hypercube study's sampled settings (variables over `case`)."""
    out = []
    for name, var in ds.data_vars.items():
        if var.dims == ("case",) and str(var.attrs.get("long_name", "")).startswith("sampled"):
            out.append((name, _scalar_axis(name, np.asarray(var.values, dtype=float))))
    return out


# the metric figures


def metric_values(ds: xr.Dataset, name: str) -> tuple[xr.DataArray, str, int]:
    """The metric in its drawn unit (−1 of the integer metrics as NaN, and every metric of a
    case that diverged or failed: results.nc keeps the state a diverged run stopped in, which
    is no result; its wall time is), the unit, and how many cases have no value."""
    da = ds[name].astype(float)
    if name in _NO_VALUE:
        da = da.where(da >= 0)
    if "status" in ds and name != "wall_time":
        da = da.where(~ds["status"].astype(str).isin(["diverged", "failed"]))
    lab = METRIC_LABELS.get(name, MetricLabel(name.replace("_", " ")))
    unit, factor = _drawn_unit(str(ds[name].attrs.get("units", "")), lab.unit)
    da = da * factor
    cases = int(np.prod([ds.sizes[d] for d in ds[name].dims if d != "xyz"]))
    valid = np.isfinite(da.values)
    if "xyz" in da.dims:
        valid = valid.all(axis=da.dims.index("xyz"))
    return da, unit, cases - int(valid.sum())


def _component_label(lab: MetricLabel, comp: str | None, unit: str) -> str:
    if comp is None:
        head = " ".join(p for p in (lab.words, lab.symbol) if p)
    else:
        head = f"${lab.tex}_{comp}$" if lab.tex else f"{lab.words} {comp}"
    return head + _unit_suffix(unit)


def metric_figure(ds: xr.Dataset, name: str) -> Figure | None:
    """The figure of one metric of results.nc (None when it has no finite value): against the
    first axis, a line per value of the second (further axes at their first value), or a heat
    map over two numeric axes of more than three values each; `perforated` as the fraction
    perforated at each value of each axis; a Latin hypercube study against each sampled
    setting. A vector metric gets a panel per component."""
    if name not in ds:
        return None
    da, unit, missing = metric_values(ds, name)
    if not np.isfinite(da.values).any():
        return None
    lab = METRIC_LABELS.get(name, MetricLabel(name.replace("_", " ")))
    comps = [str(c) for c in ds["xyz"].values] if "xyz" in da.dims else [None]
    dims = [d for d in da.dims if d != "xyz"]
    sampled = _sampled_axes(ds) if dims == ["case"] else []
    axes_info = [study_axis(ds, d) for d in dims]
    total = int(np.prod([ds.sizes[d] for d in dims]))
    note = ""
    if name == "perforated":
        ylabel = "perforation probability (fraction of the cases perforated)"
        if missing:
            note = (f"{missing} of {total} cases undecided or failed (perforated = −1): "
                    f"left out")
    elif missing:
        note = f"{missing} of {total} cases without a value (diverged, failed or not run)"

    heat = (name != "perforated" and not sampled and len(dims) == 2
            and all(a.ticks is None for a in axes_info)
            and all(len(a.x) > 3 for a in axes_info))
    if sampled:
        panels = [(key, ax) for key, ax in sampled]
    elif name == "perforated":
        panels = list(zip(dims, axes_info, strict=True))
    else:
        panels = [(dims[0], axes_info[0])]
    ncols = len(comps) if heat else len(panels)
    nrows = 1 if heat else len(comps)
    fig = new_figure((max(6.0, 4.6 * ncols), 3.2 * nrows + 1.0))
    grid = fig.subplots(nrows, ncols, squeeze=False, sharex="col" if nrows > 1 else False)
    for r, comp in enumerate(comps):
        part = da.sel(xyz=comp) if comp is not None else da
        for c, (dim, info) in enumerate(panels):
            ax = grid[0, r] if heat else grid[r, c]
            if heat:
                _heat_map(fig, ax, part, dims, axes_info, _component_label(lab, comp, unit))
                continue
            if sampled:
                ax.plot(info.x, part.values, "o", ms=4)
                ax.set_ylabel(_component_label(lab, comp, unit))
            elif name == "perforated":
                _probability(ax, part, dim, info)
                ax.set_ylabel(ylabel if c == 0 else "")
            else:
                _lines(ax, part, dims, axes_info)
                ax.set_ylabel(_component_label(lab, comp, unit))
            if r == nrows - 1:
                ax.set_xlabel(info.label)
            if info.ticks is not None:
                ax.set_xticks(info.x, info.ticks, rotation=20, fontsize=7)
            elif np.all(info.x == np.round(info.x)):
                ax.xaxis.set_major_locator(MaxNLocator(integer=True))
            if comp is not None and len(comps) > 1:
                ax.set_title(f"component {comp}", fontsize=9, loc="left")
    words = [p[1].words for p in panels]
    over = words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]
    title = f"{lab.words[0].upper()}{lab.words[1:]}"
    if lab.symbol:
        title += f" {lab.symbol}"
    title += f" against {over}"
    base = _study_base(ds)
    if base:
        title += f" (study of {base})"
    rest = list(dims[2:]) if not sampled and name != "perforated" and not heat else []
    if rest:
        fixed = ", ".join(f"{study_axis(ds, d).words} = {_tick(study_axis(ds, d), 0)}"
                          for d in rest)
        note = "; ".join(p for p in (note, f"at {fixed}") if p)
    fig.suptitle(title + (f"\n{note}" if note else ""), fontsize=11)
    return fig


def _tick(info: StudyAxis, k: int) -> str:
    if info.ticks is not None:
        return info.ticks[k]
    return f"{info.x[k]:g}{' ' + info.unit if info.unit else ''}"


def _study_base(ds: xr.Dataset) -> str:
    try:
        return str(json.loads(str(ds.attrs.get("study", "{}"))).get("base", ""))
    except (json.JSONDecodeError, AttributeError):
        return ""


def _lines(ax, part: xr.DataArray, dims: list[str], infos: list[StudyAxis]) -> None:
    """A line over the first axis per value of the second (further axes at index 0)."""
    part = part.isel({d: 0 for d in dims[2:]}) if len(dims) > 2 else part
    x = infos[0].x
    if len(dims) == 1:
        ax.plot(x, part.values, "o-")
        return
    values = part.transpose(dims[0], dims[1]).values
    other = infos[1]
    for k in range(values.shape[1]):
        ax.plot(x, values[:, k], "o-", label=f"{other.short} = {_tick(other, k)}")
    ax.legend(fontsize=7)


def _probability(ax, part: xr.DataArray, dim: str, info: StudyAxis) -> None:
    """The fraction of the decided cases that perforated at each value of `dim` (over every
    other axis), with the number of decided cases beside each point."""
    others = [d for d in part.dims if d != dim]
    decided = np.isfinite(part).sum(others) if others else np.isfinite(part).astype(int)
    frac = part.mean(others, skipna=True) if others else part
    ax.plot(info.x, frac.values, "o-", color="tab:red")
    for xv, fv, n in zip(info.x, frac.values, np.asarray(decided.values), strict=True):
        if np.isfinite(fv):
            ax.annotate(f"n = {int(n)}", (xv, fv), textcoords="offset points", xytext=(0, 6),
                        ha="center", fontsize=7, color="0.35")
    ax.set_ylim(-0.08, 1.12)


def _heat_map(fig, ax, part: xr.DataArray, dims: list[str], infos: list[StudyAxis],
              label: str) -> None:
    values = part.transpose(dims[0], dims[1]).values
    mesh = ax.pcolormesh(infos[0].x, infos[1].x, values.T, shading="nearest")
    fig.colorbar(mesh, ax=ax, label=label)
    ax.set_xlabel(infos[0].label)
    ax.set_ylabel(infos[1].label)


def study_figures(study_dir: str | Path, out: str | Path | None = None) -> list[Path]:
    """One figure per metric (`metric_figure`), study_<metric>.png and .pdf in `out`
    (default STUDY/figures). Returns the files written."""
    study_dir = Path(study_dir)
    path = study_dir / "results.nc"
    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist (not a study folder: run `emfabric "
                                f"sweep STUDY --out {study_dir}`)")
    out = Path(out) if out is not None else study_dir / "figures"
    out.mkdir(parents=True, exist_ok=True)
    files: list[Path] = []
    with xr.open_dataset(path) as ds:
        ds = ds.load()
    if not [d for d in ds.dims if d != "xyz"]:
        # a study with neither [axes] nor [lhs] (refused since 2026-12-07): one case, no axis
        raise FileNotFoundError(f"{path} has no study axis to draw against (one case, no "
                                f"[axes] or [lhs]); its case's numbers are in {path}")
    for name in PLOTTED:
        fig = metric_figure(ds, name)
        if fig is not None:
            files += save_figure(fig, out / f"study_{name}")
        elif name in ds:
            # said, not dropped in silence: e.g. every case still in contact at its end time
            # leaves `perforated` undecided (−1) in each
            log.warning("study_%s not drawn: no case of %s has a value of %s (undecided, "
                        "diverged or failed in every case)", name, path, name)
    return files


def design_figure(res: dict[str, Any], path: str | Path) -> Path:
    """Max tilt [deg] (by the target time) against |B| at the sheet centre for the
    design-field probes, with the target tilt, the answer and the eq 5.4 estimate."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    b_per_scale = res["B_centre_norm"] / res["scale"]
    probes = [p for p in res["probes"] if np.isfinite(p["max_tilt"])]
    fig = new_figure((6.0, 4.0))
    ax = fig.add_subplot()
    ax.plot([p["scale"] * b_per_scale for p in probes],
            [math.degrees(p["max_tilt"]) for p in probes], "o", label="runs")
    ax.axhline(math.degrees(res["target_tilt"]), color="0.5", ls="--",
               label=f"target tilt {math.degrees(res['target_tilt']):.3g}°")
    ax.axvline(res["B_centre_norm"], color="C2", label=f"found: {res['B_centre_norm']:.3g} T")
    ax.axvline(res["estimate_eq54"], color="C3", ls=":",
               label=f"eq 5.4: {res['estimate_eq54']:.3g} T")
    ax.set_xscale("log")
    from matplotlib.ticker import NullFormatter

    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("|B| at the sheet centre [T]")
    ax.set_ylabel(f"largest tilt Θ by {res['by'] * 1e6:g} µs [deg]")
    ax.set_title("Field design: tilt against the field strength")
    ax.legend(fontsize=8)
    stem = path.with_suffix("")
    return save_figure(fig, stem)[0]


NON_MONOTONE_SHOWN = 3
"""Non-monotone stopped shots annotated one by one on ballistic.png (the rest counted)."""


def ballistic_plot(res: dict[str, Any], lambert_jonas) -> Figure:
    """The figure of `emfabric ballistic-limit`: residual speed against striking speed of the
    shots of the scenario as given (perforated: their residual speed; stopped: a distinct
    marker at 0, no residual speed, not part of the fit), the Lambert–Jonas fit (the curve
    function given: emfabric.studies.ballistic.lambert_jonas), V_BL and its bracket, and the
    non-monotone outcomes of res["non_monotone"] (a stopped shot faster than a perforating
    one) ringed and annotated; with seeds, the perforation of the seeded shots and the
    logistic fit of V50 beside it."""
    seeded = "v50" in res
    fig = new_figure((11.0 if seeded else 7.0, 4.8))
    ax = fig.add_subplot(1, 2 if seeded else 1, 1)
    det = [s for s in res["shots"] if s["seed"] is None]
    perf = [s for s in det if s["perforated"] == 1 and math.isfinite(s["residual_speed"])]
    held = [s for s in det if s["perforated"] == 0]
    undecided = [s for s in det if s["perforated"] not in (0, 1)
                 or (s["perforated"] == 1 and not math.isfinite(s["residual_speed"]))]
    speeds = [s["speed"] for s in det] or [res["v_bl"]]
    lj = res["lambert_jonas"]
    lo_x = min(min(speeds), res["v_bl"]) * 0.9
    hi_x = max(max(speeds), res["v_bl"]) * 1.05
    grid = np.linspace(lo_x, hi_x, 400)
    ax.plot(grid, lambert_jonas(grid, lj["a"], lj["p"], lj["v_bl"]), "-", color="C0", lw=1.2,
            label=f"Lambert–Jonas fit a = {lj['a']:.3g}, p = {lj['p']:.3g} "
                  f"(its V_BL {lj['v_bl']:.4g} m/s)")
    ax.plot([s["speed"] for s in perf], [s["residual_speed"] for s in perf], "o", color="C0",
            label="perforated (residual speed)")
    if held:
        ax.plot([s["speed"] for s in held], np.zeros(len(held)), "v", color="C3", ms=8,
                mfc="none", mew=1.6, clip_on=False,
                label="stopped (rebound): no residual speed")
    lo, hi = res.get("v_bl_bracket", [res["v_bl"], res["v_bl"]])
    if hi > lo:
        ax.axvspan(lo, hi, color="0.85", zorder=0)
    ax.axvline(res["v_bl"], color="0.3", ls="--",
               label=f"V_BL = {res['v_bl']:.4g} m/s (bracket {lo:.4g} – {hi:.4g})")
    flags = list(res.get("non_monotone", []))
    if flags:
        ax.plot([f["stopped"] for f in flags], np.zeros(len(flags)), "o", ms=16, mfc="none",
                mec="red", mew=1.5, clip_on=False,
                label="non-monotone: stopped faster than a perforating shot")
        top = max([s["residual_speed"] for s in perf] + [1.0])
        for k, f in enumerate(flags[:NON_MONOTONE_SHOWN]):
            why = (f"perforating shot at {f['perforated']:.4g} m/s"
                   if f.get("perforated") is not None else f"V_BL {res['v_bl']:.4g} m/s")
            ax.annotate(f"non-monotone: stopped at {f['stopped']:.4g} m/s,\nabove a {why}",
                        xy=(f["stopped"], 0.0), xytext=(f["stopped"], top * (0.35 + 0.17 * k)),
                        ha="center", fontsize=7, color="red",
                        arrowprops={"arrowstyle": "->", "color": "red", "lw": 0.8},
                        bbox={"boxstyle": "round", "fc": "white", "ec": "red", "alpha": 0.85})
    ax.set_xlim(lo_x, hi_x)
    ax.set_ylim(bottom=0.0)
    ax.set_xlabel("striking speed $v_s$ [m/s]")
    ax.set_ylabel("residual speed $v_r$ [m/s]")
    ax.set_title("shots of the scenario as given", fontsize=9, loc="left")
    ax.legend(fontsize=7, loc="upper left")
    if seeded:
        ax2 = fig.add_subplot(1, 2, 2)
        sh = [s for s in res["shots"] if s["seed"] is not None and s["perforated"] in (0, 1)]
        v = np.array([s["speed"] for s in sh])
        y = np.array([s["perforated"] for s in sh], dtype=float)
        ax2.plot(v, y + np.linspace(-0.03, 0.03, y.size), "o", alpha=0.5,
                 label="seeded shots (1 perforated, 0 stopped)")
        fit = res["v50"]
        g = np.linspace(v.min(), v.max(), 300)
        if fit.get("separated") or fit["scale"] <= 0.0:
            # no spread resolved: the shots separate at the gap (studies.ballistic.fit_v50)
            ax2.plot(g, (g >= fit["v50"]).astype(float), "-",
                     label=f"shots separate: V50 = {fit['v50']:.4g} m/s, between "
                           f"{fit['ci95'][0]:.4g} and {fit['ci95'][1]:.4g}")
        else:
            # 1/(1 + e^{-z}) as (1 + tanh(z/2))/2: no overflow for a small scale
            ax2.plot(g, 0.5 * (1.0 + np.tanh(0.5 * (g - fit["v50"]) / fit["scale"])), "-",
                     label=f"logistic fit: V50 = {fit['v50']:.4g} m/s, 95 % "
                           f"[{fit['ci95'][0]:.4g}, {fit['ci95'][1]:.4g}]")
        ax2.set_xlabel("striking speed $v_s$ [m/s]")
        ax2.set_ylabel("perforation probability")
        ax2.set_title(f"{res.get('seeds', '')} seeds: modulus scatter and impact jitter",
                      fontsize=9, loc="left")
        ax2.legend(fontsize=7)
    notes = []
    if flags:
        notes.append(f"({len(flags)} non-monotone outcome{'s' if len(flags) > 1 else ''}: "
                     f"stopped faster than a perforating shot, ringed)")
    if undecided:
        notes.append(f"({len(undecided)} shot{'s' if len(undecided) > 1 else ''} undecided or "
                     f"failed, not drawn)")
    title = f"Ballistic limit: {res.get('scenario') or 'model'}"
    fig.suptitle("\n".join([title, *notes]), fontsize=12)
    return fig


def ballistic_figure(res: dict[str, Any], path: str | Path, lambert_jonas) -> Path:
    """Draw `ballistic_plot` and save it to `path` (.png, and .pdf beside it); return the
    PNG's path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return save_figure(ballistic_plot(res, lambert_jonas), path.with_suffix(""))[0]
