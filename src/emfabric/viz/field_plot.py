"""`emfabric field SCENARIO --plot OUT.png`: the applied field over the sheet's plane and along
the flight axis, before a run (drawing only: the field values are computed by the caller)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from emfabric.sources.picture import FieldPicture


def draw(pic: FieldPicture, path: Path) -> Path:
    """Write the two-panel figure to `path` (format from its suffix)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11.5, 4.6), layout="constrained")
    mag = np.linalg.norm(pic.b_plane, axis=2)
    mesh = ax0.pcolormesh(pic.xs, pic.ys, mag, shading="auto", cmap="viridis")
    fig.colorbar(mesh, ax=ax0, label="|B| [T]")
    # in-plane direction of B (unit arrows), on a coarser grid
    step = max(1, len(pic.xs) // 16)
    bx = pic.b_plane[::step, ::step, 0]
    by = pic.b_plane[::step, ::step, 1]
    norm = np.hypot(bx, by)
    norm[norm == 0] = 1.0
    ax0.quiver(pic.xs[::step], pic.ys[::step], bx / norm, by / norm, color="w", alpha=0.8,
               scale=30, width=0.003)
    x0, x1, y0, y1 = pic.sheet
    ax0.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], "w--", lw=1, label="sheet")
    ax0.plot(pic.start[0], pic.start[1], "r+", ms=12, mew=2, label="projectile start")
    ax0.set_aspect("equal")
    ax0.set_xlabel("x [m]")
    ax0.set_ylabel("y [m]")
    ax0.set_title("in the sheet's plane z = 0: |B| and the in-plane direction of B", fontsize=9)
    ax0.legend(loc="upper right", fontsize=7, framealpha=0.6)
    for c, name in enumerate("xyz"):
        ax1.plot(pic.s, pic.b_axis[:, c], label=f"B_{name}")
    ax1.plot(pic.s, np.linalg.norm(pic.b_axis, axis=1), "k", lw=1.5, label="|B|")
    if np.isfinite(pic.s_sheet):
        ax1.axvline(pic.s_sheet, color="0.4", ls="--", lw=1, label="sheet")
    ax1.axvline(0.0, color="r", ls=":", lw=1, label="projectile start")
    ax1.set_xlabel("distance along the flight axis from the start [m]")
    ax1.set_ylabel("B [T]")
    ax1.set_title("along the flight axis", fontsize=9)
    ax1.grid(alpha=0.3)
    ax1.legend(fontsize=7)
    fig.suptitle(f"{pic.title}: applied field at t = {pic.time:g} s")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
