"""The paper's impact in a pulsed Helmholtz pair (`coil-pulse`) next to the uniform 0.05 T field
(`paper-field`): when the field rose and how much spin it gave.

    python scripts/coil_study.py [--out runs] [--figures docs/img]

Runs both built-in scenarios to the end, prints the Markdown table quoted in docs/fields.md and
draws ω_x(t) of both runs with the coil's B_x at the sheet centre.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from reproduce_paper import print_table  # scripts/ is on the path when run

import emfabric
from emfabric.sources.build import build_field
from emfabric.sources.evaluate import fields_at

NAMES = ("paper-field", "coil-pulse")


def _row(name: str, res) -> dict[str, str]:
    ds, s = res.history, res.summary
    t = ds.time.values * 1e6
    w = ds.angular_velocity.values
    k = int(np.argmax(np.abs(w[:, 0])))
    return {
        "scenario": name,
        "end": f"{s['end_reason']} at {s['time_s'] * 1e6:.0f} µs",
        "max \\|ω_x\\| [rad/s]": f"{abs(w[k, 0]):.0f} (t = {t[k]:.0f} µs)",
        "ω_x at 100 µs [rad/s]": f"{np.interp(100.0, t, w[:, 0]):.0f}",
        "ω_x at 300 µs [rad/s]": f"{np.interp(300.0, t, w[:, 0]):.0f}",
        "final ω [rad/s]": "(" + ", ".join(f"{c:.0f}" for c in w[-1]) + ")",
        "max tilt [deg]": f"{s['max_tilt_deg']:.2f}",
        "residual speed [m/s]": f"{s['residual_speed_m_s']:.1f}",
        "field work [J]": f"{float(ds.work_field[-1]):.2f}",
        "balance error [J]": f"{s['energy_balance_error_J']:.2f}",
        "steps": str(s["steps"]),
        "wall [s]": f"{s['wall_time_s']:.1f}",
    }


def figure(runs: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 3.8), layout="constrained")
    for name, style in (("paper-field", "--"), ("coil-pulse", "-")):
        ds = runs[name].history
        ax.plot(ds.time.values * 1e6, ds.angular_velocity.values[:, 0], style, label=name)
    ax.set_xlabel("t [µs]")
    ax.set_ylabel("ω_x [rad/s]")
    ax.grid(alpha=0.3)
    twin = ax.twinx()
    fld = build_field(emfabric.load_scenario("coil-pulse"))
    ts = np.linspace(0.0, 1.1e-3, 300)
    bx = [fields_at(fld, [[0.0, 0.0, 0.0]], t)[1][0, 0] for t in ts]
    twin.plot(ts * 1e6, bx, color="0.6", lw=1, label="coil B_x at the sheet centre")
    twin.axhline(0.05, color="0.8", lw=0.8, ls=":")
    twin.set_ylabel("B_x [T]")
    lines = ax.get_lines() + twin.get_lines()[:1]
    ax.legend(lines, [ln.get_label() for ln in lines], fontsize=8, loc="lower right")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("runs"))
    ap.add_argument("--figures", type=Path, default=None, help="also write the figure here")
    args = ap.parse_args()
    emfabric.run(emfabric.load_scenario("coil-pulse", {"fabric.nodes": [20, 20],
                                                       "solver.end_time": 2e-6}))
    runs, rows = {}, []
    for name in NAMES:
        t0 = time.perf_counter()
        runs[name] = emfabric.run(emfabric.load_scenario(name), args.out / name)
        print(f"{name}: {time.perf_counter() - t0:.1f} s wall", flush=True)
        rows.append(_row(name, runs[name]))
    png = args.out / "coil_spin.png"
    figure(runs, png)
    if args.figures is not None:
        args.figures.mkdir(parents=True, exist_ok=True)
        figure(runs, args.figures / "coil_spin.png")
    print_table(rows)


if __name__ == "__main__":
    main()
