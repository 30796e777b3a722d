"""Figures from a run's files: spin, impact sequence, energy budget, velocity; overlays of runs.

Reads ``history.nc`` and ``snapshots.nc`` only and never imports the simulator (no Numba), so
it works anywhere the output files are. Figures are ``matplotlib.figure.Figure`` objects on an
Agg canvas (no pyplot, no display): build them with the ``*_figure`` functions, or let
``plot_runs`` build and save them all. Times are drawn in µs, angles in degrees, everything
else in SI units.

A pack of plies (snapshots.nc's `plies` > 1): the 3-D views draw every ply's yarns (the top
ply over the deeper ones; the parts of a clipped rotated ply that carry nothing are left
out), and each view gets a section under it: z of each ply's nodes along x through the impact
point, a colour per ply. A single sheet's figures are drawn as before.
"""

from __future__ import annotations

import logging
import math
import textwrap
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import numpy as np
import xarray as xr
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.gridspec import GridSpec
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

log = logging.getLogger(__name__)

STYLE = {
    "font.size": 11,
    "axes.titlesize": 11,
    "axes.labelsize": 11,
    "legend.fontsize": 9,
    "figure.titlesize": 13,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "lines.linewidth": 1.4,
    "savefig.dpi": 150,
}
"""Matplotlib settings every figure is drawn and saved with."""

DAMAGE_CMAP = "coolwarm"
"""Yarn colours: blue at the smallest damage variable α shown, red at the largest (α = 1 intact)."""

DAMAGE_LABEL = "damage α [1]  (1 intact, 0 broken)"
FLAT_RANGE = 1e-6
"""Width of the colour range below α_max when every shown yarn has the same α (e.g. all intact)."""

NOSE_ARROW = 1.6
"""Length of the orientation arrow: the nose marker (centre of mass to the leading surface
point) times this."""

FIGURE_STEMS = ("spin", "impact_sequence", "energy", "velocity")
"""File stems of the single-run figures, each saved as .png and .pdf."""

COMPARE_STEMS = ("compare_spin", "compare_energy", "compare_velocity")
"""File stems of the overlay figures of several runs."""

_LINESTYLES = ("-", "--", ":", "-.")
_AXIS_COLOURS = ("tab:red", "tab:green", "tab:blue")
_US = 1e6  # s -> µs


# reading


def open_history(run_dir: str | Path) -> xr.Dataset:
    """The run's ``history.nc`` loaded into memory (the file is closed again)."""
    path = Path(run_dir) / "history.nc"
    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist: is {run_dir} a run folder?")
    with xr.open_dataset(path) as ds:
        return ds.load()


def open_snapshots(run_dir: str | Path) -> xr.Dataset:
    """The run's ``snapshots.nc``, opened lazily (read a snapshot at a time; close when done)."""
    path = Path(run_dir) / "snapshots.nc"
    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist: is {run_dir} a run folder?")
    return xr.open_dataset(path)


def status_note(ds: xr.Dataset) -> str | None:
    """``"partial: interrupted at t = …"`` for a run that did not complete, else None."""
    status = str(ds.attrs.get("status", "complete"))
    if status == "complete":
        return None
    reason = " ".join(str(ds.attrs.get("end_reason", "")).split()) or "no reason recorded"
    if "t =" not in reason and "time" in ds.coords and ds.sizes.get("time", 0):
        reason += f"; last record t = {float(ds['time'][-1]) * _US:.2f} µs"
    if len(reason) > 100:
        reason = reason[:99] + "…"
    return f"{status}: {reason}"


def run_name(ds: xr.Dataset, run_dir: str | Path | None = None) -> str:
    """The scenario name, with the folder name when that differs."""
    name = str(ds.attrs.get("scenario_name", ""))
    folder = Path(run_dir).resolve().name if run_dir is not None else ""
    if not name:
        return folder or "run"
    return name if folder in ("", name) else f"{name} [{folder}]"


# labels from what differs between scenarios

_VECTORS = {
    "field.B": ("B", "", "T"),
    "field.E": ("E", "", "V/m"),
    "field.gravity": ("g", "", "m/s²"),
    "projectile.velocity": ("v", "0", "m/s"),
    "projectile.angular_velocity": (r"\omega", "0", "rad/s"),
    "fabric.velocity": ("v", "f", "m/s"),
}
_SCALARS = {
    "projectile.radius": ("$R$", "m"),
    "projectile.mass": ("$m$", "kg"),
    "fabric.charge_per_node": ("$q$", "C"),
    "fabric.material.youngs_modulus": (r"$\mathbb{E}$", "Pa"),
    "fabric.material.modulus_cv": ("modulus cv", ""),
    "fabric.damage.rate": (r"$\lambda$", ""),
    "fabric.damage.critical_stretch": (r"$U_{crit}$", ""),
    "contact.static_friction": (r"$\mu_s$", ""),
    "contact.dynamic_friction": (r"$\mu_d$", ""),
    "solver.phi": (r"$\phi$", ""),
    "solver.dt_max": (r"$\Delta t_{max}$", "s"),
}
_NOT_COMPARED = ("name", "description")


def _flatten(table: dict, prefix: str = "") -> dict[str, object]:
    out: dict[str, object] = {}
    for key, value in table.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten(value, dotted + "."))
        else:
            out[dotted] = value
    return out


def _num(v: object) -> str:
    return f"{v:g}" if isinstance(v, int | float) and not isinstance(v, bool) else str(v)


def _math(symbol: str, sub: str) -> str:
    if not sub:
        return f"${symbol}$"
    return f"${symbol}_{sub}$" if len(sub) == 1 else f"${symbol}_{{{sub}}}$"


def pretty_setting(key: str, value: object) -> str:
    """One scenario setting as a legend entry: ``field.B = [0.05, 0, 0]`` -> ``$B_x$ = 0.05 T``."""
    if key in _VECTORS and isinstance(value, list) and len(value) == 3:
        sym, sub, unit = _VECTORS[key]
        nonzero = [i for i, v in enumerate(value) if v != 0]
        if len(nonzero) == 1:
            i = nonzero[0]
            return f"{_math(sym, sub + 'xyz'[i])} = {_num(value[i])} {unit}"
        if not nonzero:
            return f"{_math(sym, sub)} = 0"
        return f"{_math(sym, sub)} = ({', '.join(_num(v) for v in value)}) {unit}"
    if key == "fabric.nodes" and isinstance(value, list) and len(value) == 2:
        return f"{value[0]} × {value[1]} nodes"
    if key in _SCALARS:
        sym, unit = _SCALARS[key]
        return f"{sym} = {_num(value)} {unit}".rstrip()
    if isinstance(value, list):
        return f"{key} = [{', '.join(_num(v) for v in value)}]"
    return f"{key} = {_num(value)}"


def scenario_labels(histories: Sequence[xr.Dataset], names: Sequence[str]) -> list[str]:
    """Legend labels from the scenario settings that differ between runs.

    Each history's ``scenario`` attribute (the full TOML text) is flattened to dotted keys;
    the label of a run lists its values of the differing keys (at most three). Falls back to
    the scenario names, then to ``names`` (folder names), when nothing else tells runs apart.
    """
    names = list(names)
    try:
        flats = [_flatten(tomllib.loads(str(ds.attrs["scenario"]))) for ds in histories]
    except (KeyError, tomllib.TOMLDecodeError):
        return names
    keys: list[str] = []
    for flat in flats:
        keys += [k for k in flat if k not in keys]

    def differs(key: str) -> bool:
        return len({repr(flat.get(key)) for flat in flats}) > 1

    diff = [k for k in keys if k not in _NOT_COMPARED and differs(k)]
    if diff:
        labels = []
        for flat in flats:
            parts = [pretty_setting(k, flat.get(k)) for k in diff[:3]]
            labels.append(", ".join(parts) + (", …" if len(diff) > 3 else ""))
    elif differs("name"):
        labels = [str(flat.get("name")) for flat in flats]
    else:
        labels = names
    if len(set(labels)) < len(labels):
        labels = [f"{lab} [{n}]" for lab, n in zip(labels, names, strict=True)]
    return labels


# figure plumbing


def new_figure(figsize: tuple[float, float], layout: str | None = "constrained") -> Figure:
    """An empty Figure on an Agg canvas (no pyplot, no display)."""
    fig = Figure(figsize=figsize, layout=layout)
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, stem: Path) -> list[Path]:
    """Save as ``stem.png`` and ``stem.pdf``; return both paths."""
    files = [stem.with_suffix(".png"), stem.with_suffix(".pdf")]
    with matplotlib.rc_context(STYLE):
        for f in files:
            fig.savefig(f)
    return files


@dataclass(frozen=True)
class _Series:
    label: str
    values: Callable[[xr.Dataset], np.ndarray]
    colour: str


def _time_us(ds: xr.Dataset) -> np.ndarray:
    return ds["time"].values * _US


def _panel(ax, histories: Sequence[xr.Dataset], series: Sequence[_Series], *,
           colour_by: str, ylabel: str) -> None:
    """Draw series of every run on one axis. One run: a colour per series. Several runs:
    colour per run and line style per series (``colour_by="run"``), or the other way round."""
    multi = len(histories) > 1
    for i, ds in enumerate(histories):
        t = _time_us(ds)
        for j, s in enumerate(series):
            if not multi:
                colour, style = s.colour, "-"
            elif colour_by == "run":
                colour, style = f"C{i % 10}", _LINESTYLES[j % len(_LINESTYLES)]
            else:
                colour, style = s.colour, _LINESTYLES[i % len(_LINESTYLES)]
            ax.plot(t, s.values(ds), color=colour, linestyle=style, label=s.label)
    ax.set_ylabel(ylabel)
    if len(series) > 1:
        if multi and colour_by == "run":
            handles = [Line2D([], [], color="0.3", linestyle=_LINESTYLES[j % 4], label=s.label)
                       for j, s in enumerate(series)]
        else:
            handles = [Line2D([], [], color=s.colour, label=s.label) for s in series]
        ax.legend(handles=handles, loc="best", ncols=2 if len(series) > 3 else 1)


LEGEND_WIDTH = 90
"""Characters of a run's label per line in an overlay's legend (the figure's width at its font
size): longer labels are wrapped, and then listed one under the other, never cut off."""


def _run_legend(fig: Figure, labels: Sequence[str], colour_by: str) -> None:
    # three columns while the labels fit a third of the width; wrapped, one column, else
    columns = min(len(labels), 3) if max(map(len, labels)) <= LEGEND_WIDTH // 3 - 4 else 1
    labels = [textwrap.fill(lab, LEGEND_WIDTH) for lab in labels]
    if colour_by == "run":
        handles = [Line2D([], [], color=f"C{i % 10}", label=lab) for i, lab in enumerate(labels)]
    else:
        handles = [Line2D([], [], color="k", linestyle=_LINESTYLES[i % 4], label=lab)
                   for i, lab in enumerate(labels)]
    fig.legend(handles=handles, loc="outside lower center", ncols=columns)


def _finish(fig: Figure, axes, what: str, histories: Sequence[xr.Dataset],
            labels: Sequence[str] | None, colour_by: str) -> None:
    axes[-1].set_xlabel("time [µs]")
    if len(histories) > 1:
        labels = list(labels) if labels else [run_name(ds) for ds in histories]
        labels = [lab + (" (incomplete)" if status_note(ds) else "")
                  for lab, ds in zip(labels, histories, strict=True)]
        fig.suptitle(f"comparison: {what}")
        _run_legend(fig, labels, colour_by)
    else:
        ds = histories[0]
        note = status_note(ds)
        name = labels[0] if labels else run_name(ds)
        fig.suptitle(f"{name}: {what}" + (f"\n({note})" if note else ""))


def _as_list(histories) -> list[xr.Dataset]:
    return [histories] if isinstance(histories, xr.Dataset) else list(histories)


# history figures


def spin_figure(histories: Sequence[xr.Dataset] | xr.Dataset,
                labels: Sequence[str] | None = None) -> Figure:
    """Tilt Θ and yaw ψ [deg], and ω_x, ω_y, ω_z [rad/s] against time (paper Figs. 7, 9, 12).

    Four stacked axes sharing the time axis, one line per run on each, so a small component
    (Fig. 12's ω_y next to ω_z = 10⁴ rad/s) stays readable. The top axis holds the tilt Θ
    (the nose marker from its initial direction, eq. 5.2) and the yaw ψ (the body axis from
    the velocity, docs/shapes.md), both in degrees; a history without `yaw` (written before
    it was recorded) draws the tilt alone.
    """
    histories = _as_list(histories)
    with matplotlib.rc_context(STYLE):
        fig = new_figure((8.0, 9.0))
        axes = fig.subplots(4, 1, sharex=True)
        angles = [_Series("tilt Θ", lambda ds: np.degrees(ds["tilt"].values), "k")]
        if any("yaw" in ds for ds in histories):
            angles.append(_Series("yaw ψ", _yaw_deg, "tab:purple"))
        _panel(axes[0], histories, angles, colour_by="run",
               ylabel="tilt Θ, yaw ψ [deg]" if len(angles) > 1 else "tilt Θ [deg]")
        for c, ax in enumerate(axes[1:]):
            axis = "xyz"[c]
            s = _Series(f"ω_{axis}", lambda ds, c=c: ds["angular_velocity"].values[:, c],
                        _AXIS_COLOURS[c])
            _panel(ax, histories, [s], colour_by="run", ylabel=f"$\\omega_{axis}$ [rad/s]")
        _field_overlay(axes[0], histories)
        _finish(fig, axes, "tilt and spin of the projectile", histories, labels, "run")
    return fig


def _yaw_deg(ds: xr.Dataset) -> np.ndarray:
    """The history's yaw ψ [deg] (NaN where the history has none)."""
    if "yaw" not in ds:
        return np.full(ds.sizes["time"], np.nan)
    return np.degrees(ds["yaw"].values)


def _field_overlay(ax, histories: Sequence[xr.Dataset]) -> None:
    """|B| at the projectile on a second axis of the tilt panel, when the field changes in time
    in some run (a pulsed coil: when it rose, against the tilt it gave)."""
    series = []
    for ds in histories:
        if "field_B" not in ds:
            continue
        b = np.linalg.norm(ds["field_B"].values, axis=1)
        if b.size and b.max() - b.min() > 1e-9 * max(b.max(), 1e-300):
            series.append((ds, b))
    if not series:
        return
    twin = ax.twinx()
    for k, (ds, b) in enumerate(series):
        twin.plot(_time_us(ds), b, ls="--", color="0.5", lw=1.0,
                  label="|B| at the projectile" if k == 0 else None)
    twin.set_ylabel("|B| [T] (dashed)", color="0.4")
    twin.tick_params(axis="y", colors="0.4")


def _dissipated(ds: xr.Dataset) -> np.ndarray:
    return sum(ds[v].values for v in ds.data_vars if v.startswith("dissipation_"))


def energy_figure(histories: Sequence[xr.Dataset] | xr.Dataset,
                  labels: Sequence[str] | None = None) -> Figure:
    """Energy budget [J] against time: the large terms, the small terms, the balance error.

    Top: projectile kinetic (translation + rotation), fabric kinetic, strain, all dissipation,
    work of the field (and of gravity when any run has it). Middle: projectile rotation and
    each dissipation (friction, contact, projection, damage, viscous). Bottom: the balance error
    (kinetic + strain + dissipated − work − initial energy). Several runs: colour per quantity,
    line style per run.
    """
    histories = _as_list(histories)
    big = [
        _Series("projectile kinetic", lambda ds: ds["kinetic_energy_projectile"].values,
                "tab:red"),
        _Series("fabric kinetic", lambda ds: ds["kinetic_energy_fabric"].values, "tab:orange"),
        _Series("strain", lambda ds: ds["strain_energy"].values, "tab:blue"),
        _Series("dissipated (all)", _dissipated, "tab:purple"),
        _Series("work of the field", lambda ds: ds["work_field"].values, "tab:green"),
    ]
    if any(np.any(ds["work_gravity"].values != 0) for ds in histories):
        big.append(_Series("work of gravity", lambda ds: ds["work_gravity"].values, "tab:olive"))
    small = [
        _Series("projectile rotation", lambda ds: ds["kinetic_energy_projectile_rotation"].values,
                "tab:red"),
        _Series("friction", lambda ds: ds["dissipation_friction"].values, "tab:brown"),
        _Series("contact", lambda ds: ds["dissipation_contact"].values, "tab:gray"),
        _Series("projection", lambda ds: ds["dissipation_projection"].values, "tab:cyan"),
        _Series("damage", lambda ds: ds["dissipation_damage"].values, "tab:purple"),
        _Series("viscous", lambda ds: (ds["dissipation_viscous"].values  # older histories: none
                                       if "dissipation_viscous" in ds
                                       else np.zeros(ds.sizes["time"])), "tab:olive"),
    ]
    error = _Series("balance error", lambda ds: ds["energy_balance_error"].values, "k")
    with matplotlib.rc_context(STYLE):
        fig = new_figure((8.0, 9.5))
        axes = fig.subplots(3, 1, sharex=True, height_ratios=[3, 2, 1.4])
        _panel(axes[0], histories, big, colour_by="series", ylabel="energy [J]")
        _panel(axes[1], histories, small, colour_by="series", ylabel="energy [J]")
        _panel(axes[2], histories, [error], colour_by="series", ylabel="error [J]")
        axes[0].set_title("budget", loc="left")
        axes[1].set_title("projectile rotation and dissipations (cumulative)", loc="left")
        axes[2].set_title("balance error: kinetic + strain + dissipated − work − initial",
                          loc="left")
        _finish(fig, axes, "energy budget", histories, labels, "series")
    return fig


def has_projectile(ds: xr.Dataset) -> bool:
    """Whether the run of a history.nc or snapshots.nc had a projectile (a file without the
    attribute, written before it was recorded, had one)."""
    return bool(int(ds.attrs.get("has_projectile", 1)))


def velocity_figure(histories: Sequence[xr.Dataset] | xr.Dataset,
                    labels: Sequence[str] | None = None) -> Figure:
    """Projectile velocity (v_z and speed; v_x, v_y) [m/s] and largest deflection [mm] vs time;
    the deflection alone where no run had a projectile."""
    histories = _as_list(histories)

    def comp(c: int):
        return lambda ds: ds["projectile_velocity"].values[:, c]

    deflection = _Series("max deflection", lambda ds: ds["max_deflection"].values * 1e3,
                         "tab:purple")
    with matplotlib.rc_context(STYLE):
        if not any(has_projectile(ds) for ds in histories):
            fig = new_figure((8.0, 3.6))
            axes = [fig.subplots(1, 1)]
            _panel(axes[0], histories, [deflection], colour_by="run",
                   ylabel="max deflection [mm]")
            axes[0].set_title("largest out-of-plane node displacement", loc="left")
            _finish(fig, axes, "fabric deflection (no projectile)", histories, labels, "run")
            return fig
        fig = new_figure((8.0, 8.5))
        axes = fig.subplots(3, 1, sharex=True)
        speed = _Series("speed |v|", lambda ds: np.linalg.norm(
            ds["projectile_velocity"].values, axis=1), "k")
        _panel(axes[0], histories, [_Series("$v_z$", comp(2), _AXIS_COLOURS[2]), speed],
               colour_by="run", ylabel="velocity [m/s]")
        _panel(axes[1], histories, [_Series("$v_x$", comp(0), _AXIS_COLOURS[0]),
                                    _Series("$v_y$", comp(1), _AXIS_COLOURS[1])],
               colour_by="run", ylabel="velocity [m/s]")
        _panel(axes[2], histories, [deflection], colour_by="run", ylabel="max deflection [mm]")
        axes[0].set_title("projectile velocity", loc="left")
        axes[1].set_title("projectile velocity, in-plane components", loc="left")
        axes[2].set_title("largest out-of-plane node displacement", loc="left")
        _finish(fig, axes, "projectile velocity and fabric deflection", histories, labels,
                "run")
    return fig


# the 3-D view of the sheet and the projectile


def pick_snapshots(times: np.ndarray, count: int = 6) -> np.ndarray:
    """Indices of the snapshots nearest ``count`` evenly spaced times from first to last."""
    times = np.asarray(times, dtype=float)
    if len(times) <= count:
        return np.arange(len(times))
    targets = np.linspace(times[0], times[-1], count)
    return np.unique([int(np.argmin(np.abs(times - t))) for t in targets])


def ply_count(snapshots: xr.Dataset) -> int:
    """The plies of the run's fabric (1 for a file written before packs)."""
    return int(snapshots.attrs.get("plies", 1))


def shown_nodes(snapshots: xr.Dataset) -> np.ndarray:
    """Indices of the nodes drawn: those that carry load (every node of a file without
    `node_carries_load`)."""
    if "node_carries_load" in snapshots:
        return np.flatnonzero(snapshots["node_carries_load"].values != 0)
    return np.arange(snapshots.sizes["node"])


def shown_segments(snapshots: xr.Dataset) -> np.ndarray:
    """Indices of the yarn segments drawn, in drawing order: those that carry load (all, in a
    file without `segment_carries_load`), the deepest ply's first, so that the top ply is
    drawn over the others (a single sheet: every segment, in order)."""
    if "segment_carries_load" in snapshots:
        idx = np.flatnonzero(snapshots["segment_carries_load"].values != 0)
    else:
        idx = np.arange(snapshots.sizes["segment"])
    if "segment_ply" in snapshots:
        ply = snapshots["segment_ply"].values[idx] - 1
        idx = idx[np.argsort(-ply, kind="stable")]
    return idx


def damage_range(alpha: np.ndarray) -> tuple[float, float]:
    """Colour range (α_min, α_max) of the yarns shown; (α_max − FLAT_RANGE, α_max) if all equal."""
    lo, hi = float(np.min(alpha)), float(np.max(alpha))
    return (hi - FLAT_RANGE, hi) if hi <= lo else (lo, hi)


def scene_limits(snapshots: xr.Dataset, indices: Sequence[int]) -> np.ndarray:
    """Axis limits [m], shape (3, 2), holding the sheet and the projectile at ``indices``.

    Reads one snapshot at a time, so a long run is never loaded whole. Nodes that carry
    nothing (a clipped ply's outside the frame) are left out.
    """
    shown = shown_nodes(snapshots)
    ref = snapshots["reference_position"].values[shown]
    lo, hi = ref.min(axis=0), ref.max(axis=0)
    for k in indices:
        x = snapshots["node_position"][int(k)].values[shown]
        lo, hi = np.minimum(lo, x.min(axis=0)), np.maximum(hi, x.max(axis=0))
    radius = float(snapshots.attrs.get("projectile_size",
                                       snapshots.attrs.get("projectile_radius", 0.0)))
    if has_projectile(snapshots) and radius > 0:
        body = snapshots["projectile_position"].values[np.asarray(indices, dtype=int)]
        reach = NOSE_ARROW * radius
        lo = np.minimum(lo, body.min(axis=0) - reach)
        hi = np.maximum(hi, body.max(axis=0) + reach)
    span = hi - lo
    # a flat sheet still gets some height, and a little margin all round
    floor = 0.05 * max(span[0], span[1], 1e-9)
    grow = np.maximum(span, floor) - span
    lo, hi = lo - grow / 2, hi + grow / 2
    pad = 0.02 * (hi - lo)
    return np.stack([lo - pad, hi + pad], axis=1)


def yarn_linewidth(snapshots: xr.Dataset, scale: float = 1.0) -> float:
    """Yarn line width [pt]: thinner on finer grids, so a 100 x 100 sheet does not fill in."""
    n = max(int(snapshots.attrs.get("grid_nx", 30)), int(snapshots.attrs.get("grid_ny", 30)))
    return scale * float(np.clip(24.0 / n, 0.2, 0.9))


def _unit_sphere(n_lat: int = 9, n_lon: int = 17) -> np.ndarray:
    """Points of a latitude-longitude grid on the unit sphere, shape (3, n_lat, n_lon)."""
    th, ph = np.meshgrid(np.linspace(0, np.pi, n_lat), np.linspace(0, 2 * np.pi, n_lon),
                         indexing="ij")
    return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])


class SheetView:
    """One 3-D view: yarns as line segments coloured by damage α (every ply of a pack, the top
    one drawn last; what carries nothing left out), the projectile as its real surface (a
    wireframe sphere, or the triangulated ogive, cylinder or FSP of the run's snapshots.nc),
    turning with the body, and an arrow from its centre along the nose."""

    def __init__(self, ax, snapshots: xr.Dataset, norm: Normalize, limits: np.ndarray, *,
                 linewidth: float | None = None, elev: float = 22.0, azim: float = -60.0):
        self.ax = ax
        self.shown = shown_segments(snapshots)
        self.seg = snapshots["segment_nodes"].values.astype(np.int64)[self.shown]
        self.radius = float(snapshots.attrs.get("projectile_radius", 0.0))
        if not has_projectile(snapshots):
            self.radius = 0.0
        self.nose = snapshots["projectile_nose_body"].values
        self._sphere = _unit_sphere() * self.radius  # body frame, shape (3, n_lat, n_lon)
        # a shape other than the sphere: its surface mesh (body frame) from the file
        self._surface = None
        if (snapshots.attrs.get("projectile_shape", "sphere") != "sphere"
                and "projectile_surface" in snapshots):
            self._surface = (snapshots["projectile_surface"].values,
                             snapshots["projectile_surface_triangles"].values.astype(np.int64))
        self._body_artists: list = []
        if linewidth is None:
            linewidth = yarn_linewidth(snapshots)
        ax.computed_zorder = False  # sheet first, then the projectile on top, always visible
        # rasterized: in a vector file (PDF) the yarns are one image at the figure's dpi, the
        # axes, text and projectile stay vector (six views of a 100 × 100 sheet are 120 000
        # segments: 5 s to write as paths, 2 MB, slow to display; 1 s and 0.8 MB so)
        self.lines = Line3DCollection(np.zeros((len(self.seg), 2, 3)), cmap=DAMAGE_CMAP,
                                      norm=norm, linewidths=linewidth, rasterized=True)
        ax.add_collection3d(self.lines, autolim=False)
        ax.set_xlim(*limits[0])
        ax.set_ylim(*limits[1])
        ax.set_zlim(*limits[2])
        ax.set_box_aspect(tuple(limits[:, 1] - limits[:, 0]))  # zoom > 1 mis-draws the lines
        ax.view_init(elev=elev, azim=azim)
        for name, axis in zip("xyz", (ax.xaxis, ax.yaxis, ax.zaxis), strict=True):
            axis.set_major_locator(MaxNLocator(3))
            axis.set_label_text(f"{name} [m]", fontsize=8)
            axis.labelpad = 0
        ax.tick_params(labelsize=7, pad=1.5)

    def update(self, snapshots: xr.Dataset, k: int) -> None:
        """Show snapshot ``k`` (reads only that snapshot)."""
        x = snapshots["node_position"][k].values
        self.lines.set_segments(x[self.seg])
        self.lines.set_array(snapshots["yarn_damage"][k].values[self.shown])
        for artist in self._body_artists:
            artist.remove()
        self._body_artists = []
        if self.radius <= 0:
            return
        centre = snapshots["projectile_position"][k].values
        rot = snapshots["projectile_rotation"][k].values  # body -> inertial
        if self._surface is not None:
            pts, tris = self._surface
            world = pts @ rot.T + centre
            skin = Poly3DCollection(world[tris], facecolor=(0.55, 0.55, 0.6, 0.35),
                                    edgecolor=(0.25, 0.25, 0.25, 0.5), linewidths=0.2)
            self.ax.add_collection3d(skin, autolim=False)
            self._body_artists.append(skin)
        else:
            pts = np.einsum("ij,jab->iab", rot, self._sphere) + centre[:, None, None]
            self._body_artists.append(self.ax.plot_wireframe(
                pts[0], pts[1], pts[2], color="0.25", linewidth=0.4))
        # the nose marker (centre of mass to the leading surface point), lengthened
        arrow = NOSE_ARROW * (rot @ self.nose)
        self._body_artists.append(self.ax.quiver(
            *centre, *arrow, color="k", linewidth=1.8, arrow_length_ratio=0.25))


def ply_colour(ply: int) -> str:
    """The colour of ply `ply` (0-based) in the sections."""
    return f"C{ply % 10}"


def section_y(snapshots: xr.Dataset) -> float:
    """y [m] of the section: the projectile's at the first snapshot (0 without one), within the
    sheet."""
    ref = snapshots["reference_position"].values[shown_nodes(snapshots)]
    y = 0.0
    if has_projectile(snapshots) and snapshots.sizes["snapshot"]:
        y = float(snapshots["projectile_position"][0, 1])
    return float(np.clip(y, ref[:, 1].min(), ref[:, 1].max()))


def section_nodes(snapshots: xr.Dataset) -> list[np.ndarray]:
    """For each ply, the indices of its nodes on the grid line nearest the section y (those
    within half a yarn spacing of the node nearest it), ordered by their reference x."""
    ref = snapshots["reference_position"].values
    plies = ply_count(snapshots)
    n = ref.shape[0]
    node_ply = (snapshots["node_ply"].values - 1 if "node_ply" in snapshots
                else np.zeros(n, dtype=np.int64))
    live = np.zeros(n, dtype=bool)
    live[shown_nodes(snapshots)] = True
    seg = snapshots["segment_nodes"].values.astype(np.int64)[shown_segments(snapshots)]
    length = np.linalg.norm(ref[seg[:, 0]] - ref[seg[:, 1]], axis=1)
    y0 = section_y(snapshots)
    out = []
    for p in range(plies):
        idx = np.flatnonzero(live & (node_ply == p))
        if idx.size == 0:
            out.append(idx)
            continue
        own = length[node_ply[seg[:, 0]] == p]
        tol = 0.49 * float(own[own > 0].min()) if np.any(own > 0) else 0.0
        near = ref[idx[np.argmin(np.abs(ref[idx, 1] - y0))], 1]
        line = idx[np.abs(ref[idx, 1] - near) <= tol]
        out.append(line[np.argsort(ref[line, 0], kind="stable")])
    return out


def section_limits(snapshots: xr.Dataset, indices: Sequence[int],
                   nodes: Sequence[np.ndarray]) -> np.ndarray:
    """Axis limits [m], shape (2, 2), of the sections (x, z) over the snapshots ``indices``."""
    every = np.concatenate([np.asarray(i, dtype=np.int64) for i in nodes])
    ref = snapshots["reference_position"].values[every]
    lo = np.array([ref[:, 0].min(), ref[:, 2].min()])
    hi = np.array([ref[:, 0].max(), ref[:, 2].max()])
    for k in indices:
        x = snapshots["node_position"][int(k)].values[every]
        lo = np.minimum(lo, [x[:, 0].min(), x[:, 2].min()])
        hi = np.maximum(hi, [x[:, 0].max(), x[:, 2].max()])
    span = hi - lo
    # never an empty range; a little margin all round (more in z, for the legend)
    grow = np.maximum(span, 1e-9) - span
    lo, hi = lo - grow / 2, hi + grow / 2
    pad = np.array([0.02, 0.12]) * (hi - lo)
    return np.stack([lo - pad, hi + pad], axis=1)


class SectionView:
    """A pack's section along x through the impact point: z of each ply's nodes on the grid
    line nearest it (``section_nodes``), a line per ply (``ply_colour``), so the plies are seen
    one under the other as they deflect."""

    def __init__(self, ax, snapshots: xr.Dataset, limits: np.ndarray | None = None,
                 indices: Sequence[int] | None = None, *, legend: bool = True,
                 nodes: list[np.ndarray] | None = None):
        """limits: ``section_limits`` (default: over ``indices``, or every snapshot); nodes:
        ``section_nodes`` when already known."""
        self.ax = ax
        self.nodes = section_nodes(snapshots) if nodes is None else nodes
        if limits is None:
            if indices is None:
                indices = range(snapshots.sizes["snapshot"])
            limits = section_limits(snapshots, indices, self.nodes)
        self.lines = [ax.plot([], [], color=ply_colour(p), lw=1.2, marker=".", ms=2.5,
                              label=f"ply {p + 1}")[0] for p in range(len(self.nodes))]
        ax.set_xlim(*limits[0])
        ax.set_ylim(*limits[1])
        ax.ticklabel_format(axis="both", style="sci", scilimits=(-2, 3))
        ax.tick_params(labelsize=7)
        # the y of the grid line drawn (the top ply's, at rest), not the projectile's, which
        # can fall between two lines
        ref = snapshots["reference_position"].values
        drawn = next((line for line in self.nodes if line.size), None)
        y_line = float(ref[drawn[0], 1]) if drawn is not None else section_y(snapshots)
        ax.set_xlabel(f"x [m]   (section at y = {y_line * 1e3:.3g} mm)", fontsize=8)
        ax.set_ylabel("z [m]", fontsize=8)
        if legend:
            ax.legend(loc="best", fontsize=7, ncols=min(len(self.lines), 4),
                      framealpha=0.6)

    def update(self, snapshots: xr.Dataset, k: int) -> None:
        """Show snapshot ``k`` (reads only that snapshot)."""
        x = snapshots["node_position"][k].values
        for line, idx in zip(self.lines, self.nodes, strict=True):
            line.set_data(x[idx, 0], x[idx, 2])


def snapshot_tilt_deg(snapshots: xr.Dataset, k: int, history: xr.Dataset | None = None) -> float:
    """Tilt Θ [deg] at snapshot ``k``: from the history at that time, else from the rotation."""
    t = float(snapshots["time"][k])
    if history is not None and history.sizes.get("time", 0):
        return float(np.degrees(np.interp(t, history["time"].values, history["tilt"].values)))
    ref = snapshots["projectile_nose_body"].values
    now = snapshots["projectile_rotation"][k].values @ ref
    return math.degrees(math.atan2(np.linalg.norm(np.cross(now, ref)), float(now @ ref)))


def snapshot_yaw_deg(snapshots: xr.Dataset, k: int, history: xr.Dataset | None = None) -> float:
    """Yaw ψ [deg] at snapshot ``k`` (the body axis from the velocity): from the history's
    `yaw` at that time, else from the snapshot's rotation and velocity (0 at rest)."""
    t = float(snapshots["time"][k])
    if history is not None and "yaw" in history and history.sizes.get("time", 0):
        return float(np.degrees(np.interp(t, history["time"].values, history["yaw"].values)))
    axis = snapshots["projectile_rotation"][k].values @ snapshots["projectile_nose_body"].values
    v = (snapshots["projectile_velocity"][k].values if "projectile_velocity" in snapshots
         else np.zeros(3))
    return math.degrees(math.atan2(np.linalg.norm(np.cross(axis, v)), float(axis @ v)))


def damage_colourbar(fig: Figure, norm: Normalize, cax) -> None:
    """The one colour bar of a figure: α over the range reached, red = least damaged."""
    bar = fig.colorbar(ScalarMappable(norm=norm, cmap=DAMAGE_CMAP), cax=cax)
    bar.set_label(DAMAGE_LABEL)
    if norm.vmax - norm.vmin <= FLAT_RANGE * (1 + 1e-9):
        bar.set_ticks([norm.vmin, norm.vmax])  # one α everywhere: just the ends
    bar.formatter.set_useOffset(False)
    bar.update_ticks()


def sequence_figure(snapshots: xr.Dataset, count: int = 6, history: xr.Dataset | None = None,
                    title: str | None = None) -> Figure:
    """The impact as a grid of 3-D views at ``count`` evenly spaced snapshots (paper Figs. 6, 8).

    Yarns are coloured by damage α with one colour bar over the range of α in the shown
    snapshots (see ``damage_range``); the sphere carries an arrow along its nose marker. A pack
    of plies: a section of the plies (``SectionView``) under each view.
    """
    idx = pick_snapshots(snapshots["time"].values, count)
    shown = shown_segments(snapshots)
    alpha = snapshots["yarn_damage"].values[idx][:, shown] if len(idx) else np.ones(1)
    norm = Normalize(*damage_range(alpha))
    limits = scene_limits(snapshots, idx)
    ncols = min(3, max(len(idx), 1))
    nrows = max(1, math.ceil(len(idx) / ncols))
    pack = ply_count(snapshots) > 1
    with matplotlib.rc_context(STYLE):
        if pack:
            # under each 3-D view, the plies' section at that time
            fig = new_figure((4.4 * ncols + 1.2, 5.9 * nrows + 0.8), layout=None)
            grid = GridSpec(2 * nrows, ncols, figure=fig, height_ratios=[3.9, 1.6] * nrows)
            nodes = section_nodes(snapshots)
            cut = section_limits(snapshots, idx, nodes)
        else:
            fig = new_figure((4.4 * ncols + 1.2, 3.9 * nrows + 0.8), layout=None)
        for p, k in enumerate(idx):
            if pack:
                r, c = divmod(p, ncols)
                ax = fig.add_subplot(grid[2 * r, c], projection="3d")
                SectionView(fig.add_subplot(grid[2 * r + 1, c]), snapshots, cut,
                            legend=p == 0, nodes=nodes).update(snapshots, int(k))
            else:
                ax = fig.add_subplot(nrows, ncols, p + 1, projection="3d")
            SheetView(ax, snapshots, norm, limits).update(snapshots, int(k))
            t = float(snapshots["time"][k]) * _US
            angles = f"Θ = {snapshot_tilt_deg(snapshots, k, history):.2f}°"
            if has_projectile(snapshots):
                angles += f",  ψ = {snapshot_yaw_deg(snapshots, k, history):.2f}°"
            ax.set_title(f"t = {t:.1f} µs,  {angles}", fontsize=10)
        if pack:
            fig.subplots_adjust(left=0.06, right=0.86, bottom=0.1 / nrows, top=0.9,
                                wspace=0.25, hspace=0.3)
        else:
            fig.subplots_adjust(left=0.0, right=0.86, bottom=0.02, top=0.88, wspace=0.02,
                                hspace=0.08)
        damage_colourbar(fig, norm, fig.add_axes((0.895, 0.2, 0.015, 0.6)))
        meta = history if history is not None else snapshots
        note = status_note(meta)
        head = title or f"{run_name(meta)}: impact sequence"
        fig.suptitle(head + (f"\n({note})" if note else ""))
    return fig


# the command


def plot_runs(runs: list[Path], out: Path | None = None) -> list[Path]:
    """Draw and save the figures of one run, or the overlays of several; return the files.

    One run: ``spin``, ``impact_sequence``, ``energy``, ``velocity`` (.png and .pdf) in
    ``out`` or ``RUN/figures``; without a projectile no ``spin``, and ``velocity`` the
    deflection alone. Several runs: ``compare_spin``, ``compare_energy``,
    ``compare_velocity`` in ``out`` or the first run's ``figures``, labelled by what differs
    between their scenarios. An incomplete run is drawn with its status in the title.
    """
    runs = [Path(r) for r in runs]
    if not runs:
        raise ValueError("give at least one run folder")
    out_dir = Path(out) if out is not None else runs[0] / "figures"
    histories = [open_history(r) for r in runs]
    out_dir.mkdir(parents=True, exist_ok=True)
    for r, ds in zip(runs, histories, strict=True):
        note = status_note(ds)
        if note:
            log.warning("%s is not a complete run (%s); drawing what it holds", r, note)
    files: list[Path] = []
    # the spin figure is the projectile's: none where no run had one
    spin = any(has_projectile(ds) for ds in histories)
    if not spin:
        log.info("no projectile in %s: no spin figure", ", ".join(str(r) for r in runs))
    if len(runs) == 1:
        ds, name = histories[0], run_name(histories[0], runs[0])
        if spin:
            files += save_figure(spin_figure([ds], [name]), out_dir / "spin")
        if (runs[0] / "snapshots.nc").is_file():
            with open_snapshots(runs[0]) as snaps:
                fig = sequence_figure(snaps, history=ds, title=f"{name}: impact sequence")
                files += save_figure(fig, out_dir / "impact_sequence")
        else:
            log.warning("%s has no snapshots.nc: no impact sequence", runs[0])
        files += save_figure(energy_figure([ds], [name]), out_dir / "energy")
        files += save_figure(velocity_figure([ds], [name]), out_dir / "velocity")
    else:
        names = [r.resolve().name for r in runs]
        labels = scenario_labels(histories, names)
        if spin:
            files += save_figure(spin_figure(histories, labels), out_dir / "compare_spin")
        files += save_figure(energy_figure(histories, labels), out_dir / "compare_energy")
        files += save_figure(velocity_figure(histories, labels), out_dir / "compare_velocity")
    return files
