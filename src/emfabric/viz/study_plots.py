"""Figures of studies: each metric of results.nc against the axes; the design-field search."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from emfabric.viz.plots import new_figure, save_figure

PLOTTED = ("residual_speed", "max_tilt", "max_yaw", "final_angular_velocity",
           "energy_absorbed", "broken_yarns", "max_deflection", "perforated", "wall_time")


def _axis_values(ds: xr.Dataset, dim: str) -> tuple[np.ndarray, list[str] | None]:
    """Plot positions of an axis and, for a vector-valued or text axis, tick labels."""
    if f"{dim}.values" in ds:
        vals = ds[f"{dim}.values"].values
        return np.arange(len(vals)), ["[" + ", ".join(f"{v:g}" for v in row) + "]"
                                      for row in vals]
    coord = ds[dim].values
    if coord.dtype.kind in "ifu":
        return coord.astype(float), None
    return np.arange(len(coord)), [str(c) for c in coord]


def _label(ds: xr.Dataset, name: str) -> str:
    units = ds[name].attrs.get("units", "")
    return f"{name} [{units}]" if units and units != "1" else name


def study_figures(study_dir: str | Path, out: str | Path | None = None) -> list[Path]:
    """One figure per metric: a line per value of the other axis (one or two axes), or a heat
    map over two axes; for more axes, lines over the first with the rest at their first
    value. Returns the files written (PNG and PDF)."""
    study_dir = Path(study_dir)
    path = study_dir / "results.nc"
    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist (not a study folder: run `emfabric "
                                f"sweep STUDY --out {study_dir}`)")
    out = Path(out) if out is not None else study_dir / "figures"
    out.mkdir(parents=True, exist_ok=True)
    files: list[Path] = []
    with xr.open_dataset(path) as ds:
        dims = [d for d in ds["residual_speed"].dims]
        for name in PLOTTED:
            if name not in ds:
                continue
            da = ds[name]
            if name == "final_angular_velocity":
                da = da.sel(xyz="x")
                label = "final_angular_velocity x [rad s-1]"
            else:
                label = _label(ds, name)
            values = np.asarray(da.values, dtype=float)
            if np.all(~np.isfinite(values)):
                continue
            fig = new_figure((6.0, 4.0))
            ax = fig.add_subplot()
            x, ticks = _axis_values(ds, dims[0])
            if len(dims) == 2 and ticks is None and _axis_values(ds, dims[1])[1] is None \
                    and len(x) > 3 and len(ds[dims[1]]) > 3:
                y, _ = _axis_values(ds, dims[1])
                mesh = ax.pcolormesh(x, y, values.T, shading="nearest")
                fig.colorbar(mesh, ax=ax, label=label)
                ax.set_ylabel(dims[1])
            else:
                rest = values.reshape(len(x), -1)
                other = dims[1] if len(dims) >= 2 else None
                for k in range(rest.shape[1]):
                    tag = None
                    if other is not None and k < len(ds[other]):
                        oth, oticks = _axis_values(ds, other)
                        tag = f"{other} = {oticks[k] if oticks else f'{oth[k]:g}'}"
                    ax.plot(x, rest[:, k], "o-", label=tag)
                    if len(dims) > 2 and k == 0:
                        break
                if other is not None:
                    ax.legend(fontsize=7)
                ax.set_ylabel(label)
            if ticks is not None:
                ax.set_xticks(x, ticks, rotation=20, fontsize=7)
            ax.set_xlabel(dims[0])
            ax.set_title(name)
            files += save_figure(fig, out / f"study_{name}")
    return files


def design_figure(res: dict[str, Any], path: str | Path) -> Path:
    """Max tilt (by the target time) against |B| at the sheet centre for the design-field
    probes, with the target tilt, the answer and the eq 5.4 estimate."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    b_per_scale = res["B_centre_norm"] / res["scale"]
    probes = [p for p in res["probes"] if np.isfinite(p["max_tilt"])]
    fig = new_figure((6.0, 4.0))
    ax = fig.add_subplot()
    ax.plot([p["scale"] * b_per_scale for p in probes], [p["max_tilt"] for p in probes], "o",
            label="runs")
    ax.axhline(res["target_tilt"], color="0.5", ls="--", label="target tilt")
    ax.axvline(res["B_centre_norm"], color="C2", label=f"found: {res['B_centre_norm']:.3g} T")
    ax.axvline(res["estimate_eq54"], color="C3", ls=":",
               label=f"eq 5.4: {res['estimate_eq54']:.3g} T")
    ax.set_xscale("log")
    from matplotlib.ticker import NullFormatter

    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("|B| at the sheet centre [T]")
    ax.set_ylabel(f"max tilt by {res['by'] * 1e6:g} µs [rad]")
    ax.legend(fontsize=8)
    stem = path.with_suffix("")
    return save_figure(fig, stem)[0]


def ballistic_figure(res: dict[str, Any], path: str | Path, lambert_jonas) -> Path:
    """Residual against striking speed with the Lambert–Jonas fit (the curve function given:
    emfabric.studies.ballistic.lambert_jonas); with seeds, the perforation probability with the
    logistic fit beside it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    seeded = "v50" in res
    fig = new_figure((10.0 if seeded else 6.0, 4.0))
    ax = fig.add_subplot(1, 2 if seeded else 1, 1)
    det = [s for s in res["shots"] if s["seed"] is None and s["perforated"] in (0, 1)]
    vs = np.array([s["speed"] for s in det])
    vr = np.array([s["residual_speed"] if s["perforated"] == 1 else 0.0 for s in det])
    ax.plot(vs, vr, "o", label="runs (0: stopped)")
    lj = res["lambert_jonas"]
    grid = np.linspace(0.0, max(vs.max(), 1.0) * 1.05, 300)
    ax.plot(grid, lambert_jonas(grid, lj["a"], lj["p"], lj["v_bl"]), "-",
            label=f"Lambert–Jonas: a = {lj['a']:.3g}, p = {lj['p']:.3g}, "
                  f"V_BL = {lj['v_bl']:.4g} m/s")
    ax.axvline(res["v_bl"], color="0.5", ls="--", label=f"bisection: {res['v_bl']:.4g} m/s")
    ax.set_xlabel("striking speed [m/s]")
    ax.set_ylabel("residual speed [m/s]")
    ax.legend(fontsize=7)
    if seeded:
        ax2 = fig.add_subplot(1, 2, 2)
        sh = [s for s in res["shots"] if s["seed"] is not None and s["perforated"] in (0, 1)]
        v = np.array([s["speed"] for s in sh])
        y = np.array([s["perforated"] for s in sh])
        ax2.plot(v, y + np.linspace(-0.03, 0.03, y.size), "o", alpha=0.5, label="shots")
        fit = res["v50"]
        g = np.linspace(v.min(), v.max(), 300)
        ax2.plot(g, 1.0 / (1.0 + np.exp(-(g - fit["v50"]) / fit["scale"])), "-",
                 label=f"logistic: V50 = {fit['v50']:.4g} m/s, 95 % "
                       f"[{fit['ci95'][0]:.4g}, {fit['ci95'][1]:.4g}]")
        ax2.set_xlabel("striking speed [m/s]")
        ax2.set_ylabel("perforation")
        ax2.legend(fontsize=7)
    return save_figure(fig, path.with_suffix(""))[0]
