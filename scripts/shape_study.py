"""Run the built-in shape scenarios on the paper's sheet and tabulate the field-induced yaw.

    python scripts/shape_study.py [--out runs] [--figures docs/img]

Runs `ogive-no-field`, `ogive-field`, `ogive-yawed` and `fsp`, and the last two with B = 0 (until
the projectile has left the sheet or end_time), draws each built-in run's figures, a yaw-and-tilt
figure of the ogive with and without the field, and prints the Markdown table quoted in
docs/shapes.md.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from reproduce_paper import print_table  # scripts/ is on the path when run

import emfabric
from emfabric.viz.plots import plot_runs

NAMES = ("ogive-no-field", "ogive-field", "ogive-yawed", "fsp")
RUNS = {  # run name: (built-in scenario, overrides)
    "ogive-no-field": ("ogive-no-field", {}),
    "ogive-field": ("ogive-field", {}),
    "ogive-yawed, B = 0": ("ogive-yawed", {"field.B": [0.0, 0.0, 0.0]}),
    "ogive-yawed": ("ogive-yawed", {}),
    "fsp, B = 0": ("fsp", {"field.B": [0.0, 0.0, 0.0]}),
    "fsp": ("fsp", {}),
}


def _forward(ds) -> np.ndarray:
    """Records where the projectile still moves along its initial direction (before a
    rebound the yaw is the angle of attack; after it, the velocity has turned round)."""
    v = ds.projectile_velocity.values
    return v @ v[0] > 0


def _row(name: str, res) -> dict[str, str]:
    ds, s = res.history, res.summary
    t = ds.time.values * 1e6
    w = ds.angular_velocity.values
    tilt = np.degrees(ds.tilt.values)
    yaw = np.degrees(ds.yaw.values)
    fwd = _forward(ds)
    k = int(np.argmax(tilt))
    kf = int(np.flatnonzero(fwd)[-1])
    v = ds.projectile_velocity.values
    fast = np.linalg.norm(v, axis=1) > 0.5 * np.linalg.norm(v[0])
    fast &= fwd
    touched = np.flatnonzero(ds.contact_nodes.values > 0)
    t_hit = t[touched[0]] if touched.size else float("nan")
    return {
        "scenario": name,
        "end": f"{s['end_reason']} at {s['time_s'] * 1e6:.0f} µs",
        "first contact [µs]": f"{t_hit:.1f}",
        "yaw at impact [deg]": f"{yaw[touched[0]] if touched.size else yaw[0]:.2f}",
        "max yaw above half speed [deg]": f"{yaw[fast].max():.2f}",
        "tilt when stopped [deg]": f"{tilt[kf]:.2f} (t = {t[kf]:.0f} µs)",
        "max tilt [deg]": f"{tilt[k]:.2f} (t = {t[k]:.0f} µs)",
        "max \\|ω\\| [rad/s]": f"{np.linalg.norm(w, axis=1).max():.0f}",
        "final ω [rad/s]": "(" + ", ".join(f"{c:.0f}" for c in w[-1]) + ")",
        "final velocity [m/s]": "(" + ", ".join(f"{c:.1f}" for c in v[-1]) + ")",
        "max contact force [kN]":
            f"{np.linalg.norm(ds.contact_force.values, axis=1).max() / 1e3:.1f}",
        "energy absorbed [J]": f"{s['energy_absorbed_J']:.1f}",
        "max stretch": f"{s['max_stretch']:.3f}",
        "broken yarns": str(s["broken_yarns"]),
        "balance error [J]": f"{s['energy_balance_error_J']:.2f}",
        "steps": str(s["steps"]),
        "wall [s]": f"{s['wall_time_s']:.1f}",
    }


def yaw_figure(runs: dict[str, object], path: Path) -> None:
    """Tilt, yaw (while moving forward) and ω_x of the ogive with and without the field."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(11, 3.4), layout="constrained")
    for name, style in (("ogive-no-field", "--"), ("ogive-field", "-")):
        ds = runs[name].history
        t = ds.time.values * 1e6
        fwd = _forward(ds)
        axes[0].plot(t, np.degrees(ds.tilt.values), style, label=name)
        axes[1].plot(t[fwd], np.degrees(ds.yaw.values[fwd]), style, label=name)
        axes[2].plot(t, ds.angular_velocity.values[:, 0], style, label=name)
    for ax, label in zip(axes, ("tilt Θ [deg]", "yaw (moving forward) [deg]", "ω_x [rad/s]"),
                         strict=True):
        ax.set_xlabel("t [µs]")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("runs"))
    ap.add_argument("--figures", type=Path, default=None,
                    help="also copy the PNG figures here (e.g. docs/img)")
    args = ap.parse_args()
    # compile (or load the cache) outside the timed runs
    emfabric.run(emfabric.load_scenario("ogive-field", {"fabric.nodes": [20, 20],
                                                        "solver.end_time": 2e-6}))
    runs, rows = {}, []
    for name, (scenario, overrides) in RUNS.items():
        folder = args.out / name.replace(", B = 0", "-B0")
        t0 = time.perf_counter()
        runs[name] = emfabric.run(emfabric.load_scenario(scenario, overrides), folder)
        print(f"{name}: {time.perf_counter() - t0:.1f} s wall", flush=True)
        rows.append(_row(name, runs[name]))
        if name in NAMES:
            plot_runs([folder])
    yaw_png = args.out / "ogive_yaw_tilt.png"
    yaw_figure(runs, yaw_png)
    print_table(rows)
    if args.figures is not None:
        args.figures.mkdir(parents=True, exist_ok=True)
        _small_copy(yaw_png, args.figures / yaw_png.name)
        for name in ("ogive-field", "ogive-yawed", "fsp"):
            png = args.out / name / "figures" / "impact_sequence.png"
            if png.exists():
                _small_copy(png, args.figures / f"{name}_impact_sequence.png")


def _small_copy(src: Path, dst: Path, width: int = 1440) -> None:
    """Copy a PNG for the docs: at most `width` pixels wide, 256 colours (a tenth the bytes)."""
    from PIL import Image

    with Image.open(src) as im:
        im = im.convert("RGB")
        if im.width > width:
            im = im.resize((width, round(im.height * width / im.width)), Image.LANCZOS)
        im.quantize(colors=256).save(dst, optimize=True)


if __name__ == "__main__":
    main()
