"""`emfabric field SCENARIO --plot OUT.png`: the applied field over the sheet's plane and along
the flight axis, before a run (drawing only: the field values are computed by the caller,
emfabric.sources.picture).

Top row, B: |B| over the plane z = 0 with arrows for the in-plane part of B (their length the
in-plane fraction of |B|, so a field normal to the sheet shows no arrows), the sheet, the
projectile's start and the sources' outlines (the loops' and solenoids' windings, the
magnets' bodies) projected onto the plane; beside it B_x, B_y, B_z along the flight axis drawn
over a wide grey band of |B| (no component hidden under the magnitude), with where the coils
cross the axis. Bottom row, when there is an E (a time-varying current inducing one, or a
uniform E): the same for E [V/m].
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure

from emfabric.viz.plots import new_figure

if TYPE_CHECKING:
    from emfabric.sources.picture import FieldPicture

SOURCE_COLOURS = {"loop": "tab:orange", "solenoid": "tab:pink", "magnet": "0.55"}
"""Outline colour of each kind of source."""
VIEW_REACH = 3.0
"""The plane panels widen to hold the sources' outlines, up to this many times the sampled
grid's extent."""
_COMPONENTS = (("x", "tab:red", "-"), ("y", "tab:green", "--"), ("z", "tab:blue", "-."))


def _plane(fig, ax, pic: FieldPicture, values: np.ndarray, what: str, unit: str,
           cmap: str) -> None:
    """|V| over the plane with arrows for V's in-plane part, the sheet, the start, the
    sources."""
    mag = np.linalg.norm(values, axis=2)
    mesh = ax.pcolormesh(pic.xs, pic.ys, mag, shading="auto", cmap=cmap)
    fig.colorbar(mesh, ax=ax, label=f"|{what}| [{unit}]")
    step = max(1, len(pic.xs) // 16)
    vx = values[::step, ::step, 0]
    vy = values[::step, ::step, 1]
    full = mag[::step, ::step].copy()
    full[full == 0] = 1.0
    ax.quiver(pic.xs[::step], pic.ys[::step], vx / full, vy / full, color="w", alpha=0.85,
              scale=30, width=0.003)
    x0, x1, y0, y1 = pic.sheet
    ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], "w--", lw=1, label="sheet")
    ax.plot(pic.start[0], pic.start[1], "r+", ms=12, mew=2, label="projectile start")
    shown: set[str] = set()
    for src in pic.sources:
        for k, line in enumerate(src.lines):
            ax.plot(line[:, 0], line[:, 1], color=SOURCE_COLOURS.get(src.kind, "k"), lw=1.5,
                    label=src.label if k == 0 and src.label not in shown else None,
                    gid=f"source:{src.label}")
        shown.add(src.label)
    _fit_view(ax, pic)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="upper right", fontsize=7, framealpha=0.6)


def _fit_view(ax, pic: FieldPicture) -> None:
    """Limits holding the sampled grid and the sources' outlines (up to VIEW_REACH times the
    grid)."""
    lo = np.array([pic.xs[0], pic.ys[0]])
    hi = np.array([pic.xs[-1], pic.ys[-1]])
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    for src in pic.sources:
        for line in src.lines:
            lo = np.minimum(lo, line[:, :2].min(axis=0))
            hi = np.maximum(hi, line[:, :2].max(axis=0))
    lo = np.maximum(lo, centre - VIEW_REACH * half)
    hi = np.minimum(hi, centre + VIEW_REACH * half)
    pad = 0.03 * (hi - lo)
    ax.set_xlim(lo[0] - pad[0], hi[0] + pad[0])
    ax.set_ylim(lo[1] - pad[1], hi[1] + pad[1])


def _along(ax, pic: FieldPicture, values: np.ndarray, what: str, unit: str) -> None:
    """The components along the flight axis over a grey band of the magnitude."""
    ax.plot(pic.s, np.linalg.norm(values, axis=1), color="0.75", lw=6, alpha=0.7,
            solid_capstyle="butt", zorder=1, label=f"|{what}|")
    for name, colour, style in _COMPONENTS:
        c = "xyz".index(name)
        ax.plot(pic.s, values[:, c], color=colour, ls=style, lw=1.6, zorder=3,
                label=f"${what}_{name}$")
    if np.isfinite(pic.s_sheet):
        ax.axvline(pic.s_sheet, color="0.4", ls="--", lw=1, label="sheet")
    ax.axvline(0.0, color="r", ls=":", lw=1, label="projectile start")
    _coils_on_axis(ax, pic)
    ax.set_xlabel("distance along the flight axis from the start [m]")
    ax.set_ylabel(f"{what} [{unit}]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)


def _coils_on_axis(ax, pic: FieldPicture) -> None:
    """Where each loop or solenoid the flight axis passes through lies along it."""
    if pic.direction is None:
        return
    d = pic.direction
    for src in pic.sources:
        if src.kind not in ("loop", "solenoid"):
            continue
        rel = src.centre - pic.start
        sc = float(rel @ d)
        if np.linalg.norm(rel - sc * d) >= src.radius or not pic.s[0] <= sc <= pic.s[-1]:
            continue
        colour = SOURCE_COLOURS[src.kind]
        if src.kind == "loop":
            ax.axvline(sc, color=colour, lw=1.2, ls=(0, (1, 1)), label=f"{src.label} plane")
        else:
            half = 0.5 * src.length * abs(float(src.axis @ d))
            ax.axvspan(sc - half, sc + half, color=colour, alpha=0.15, label=src.label)


def field_figure(pic: FieldPicture) -> Figure:
    """The field figure: B over the sheet's plane and along the flight axis; with an E (a
    time-varying current, or a uniform E), a second row for E."""
    show_e = pic.has_e and pic.e_plane is not None and pic.e_axis is not None
    rows = 2 if show_e else 1
    fig = new_figure((12.0, 4.8 * rows))
    axes = fig.subplots(rows, 2, squeeze=False)
    _plane(fig, axes[0, 0], pic, pic.b_plane, "B", "T", "viridis")
    axes[0, 0].set_title("B in the sheet's plane z = 0: |B| and arrows for its in-plane part",
                         fontsize=9)
    _along(axes[0, 1], pic, pic.b_axis, "B", "T")
    axes[0, 1].set_title("B along the flight axis", fontsize=9)
    if show_e:
        _plane(fig, axes[1, 0], pic, pic.e_plane, "E", "V/m", "magma")
        _along(axes[1, 1], pic, pic.e_axis, "E", "V/m")
        what = ("induced E of the time-varying currents (−dI/dt × their vector potential)"
                if pic.time_varying else "applied E")
        if not (np.any(pic.e_plane != 0) or np.any(pic.e_axis != 0)):
            what += f": zero at t = {pic.time:g} s (dI/dt = 0 then)"
        axes[1, 0].set_title(f"{what}, in the plane z = 0", fontsize=9)
        axes[1, 1].set_title("E along the flight axis", fontsize=9)
    fig.suptitle(f"{pic.title}: applied field at t = {pic.time:g} s")
    return fig


def draw(pic: FieldPicture, path: Path) -> Path:
    """Write the field figure (`field_figure`) to `path` (format from its suffix)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    field_figure(pic).savefig(path, dpi=110)
    return path
