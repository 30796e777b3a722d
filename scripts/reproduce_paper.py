"""Run the paper's three model problems on the full 100 × 100 sheet and tabulate the results.

    python scripts/reproduce_paper.py [--out runs] [--figures docs/img]
                                      [--integrator central-difference phi phi-literal]

Runs `paper-no-field`, `paper-field` and `paper-spin` (until the sphere has left the sheet) with
each setting asked for — the default (central differences), the paper's φ-scheme at its
defaults (`solver.integrator = "phi"`), and the φ-scheme at the paper's literal settings
(safety 1 in eq. 3.9, contact placement at the closest point: `phi-literal`) —, draws each
run's figures (from the first setting) and an overlay of the first two, and prints a Markdown
table of the numbers quoted in docs/reproduction.md.
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

import numpy as np

import emfabric
from emfabric.viz.plots import plot_runs

NAMES = ("paper-no-field", "paper-field", "paper-spin")
SETTINGS = {
    "central-difference": ("CD", {"solver.integrator": "central-difference"}),
    "phi": ("φ", {"solver.integrator": "phi"}),
    "phi-literal": ("φ literal", {"solver.integrator": "phi", "solver.safety": 1.0,
                                  "contact.placement": "closest-point"}),
}
"""The runs: the default (central differences), the φ-scheme at its defaults, and the φ-scheme
with the paper's literal controller (safety 1) and contact placement (closest point)."""


def _row(name: str, res) -> dict[str, str]:
    ds, s = res.history, res.summary
    w = ds.angular_velocity.values
    t = ds.time.values * 1e6
    k = int(np.argmax(np.abs(w[:, 0])))
    return {
        "scenario": name,
        "end": f"{s['end_reason']} at {s['time_s'] * 1e6:.0f} µs",
        "max |ω_x| [rad/s]": f"{abs(w[k, 0]):.1f} (t = {t[k]:.0f} µs)",
        "final ω [rad/s]": "(" + ", ".join(f"{c:.1f}" for c in w[-1]) + ")",
        "max |ω_y| [rad/s]": f"{np.abs(w[:, 1]).max():.1f}",
        "max tilt [deg]": f"{s['max_tilt_deg']:.2f}",
        "residual speed [m/s]": f"{s['residual_speed_m_s']:.1f}",
        "energy absorbed [J]": f"{s['energy_absorbed_J']:.1f}",
        "max stretch": f"{s['max_stretch']:.3f}",
        "min α": f"{s['min_damage']:.4f}",
        "broken yarns": str(s["broken_yarns"]),
        "balance error [J]": f"{s['energy_balance_error_J']:.2f}",
        "steps": str(s["steps"]),
        "rejected": str(s["rejected_steps"]),
        "evaluations": str(s["force_evaluations"]),
        "mean iterations": f"{s['mean_iterations']:.2f}",
        "final Δt [s]": f"{s['final_dt_s']:.2e}",
        "wall [s]": f"{s['wall_time_s']:.1f}",
    }


def print_table(rows: list[dict[str, str]]) -> None:
    """Print rows (one per run, the first key its name) as a Markdown table, a column per run."""
    keys = list(rows[0])
    print("\n| quantity | " + " | ".join(r["scenario"] for r in rows) + " |")
    print("|---|" + "---|" * len(rows))
    for key in keys[1:]:
        print(f"| {key} | " + " | ".join(r[key] for r in rows) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("runs"))
    ap.add_argument("--figures", type=Path, default=None,
                    help="also copy the PNG figures here (e.g. docs/img)")
    ap.add_argument("--integrator", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    args = ap.parse_args()
    rows = []
    for k, integ in enumerate(args.integrator):
        label, over = SETTINGS[integ]
        # compile (or load the cache) outside the timed runs
        emfabric.run(emfabric.load_scenario("paper-field", {**over, "solver.end_time": 2e-7}))
        for name in NAMES:
            t0 = time.perf_counter()
            where = args.out / (name if k == 0 else f"{name}-{integ}")
            res = emfabric.run(emfabric.load_scenario(name, over), where)
            print(f"{name} ({integ}): {time.perf_counter() - t0:.1f} s wall", flush=True)
            rows.append(_row(f"{name} ({label})", res))
            if k == 0:
                plot_runs([where])
    overlay = args.out / "compare"
    plot_runs([args.out / "paper-no-field", args.out / "paper-field"], overlay)
    print_table(rows)
    if args.figures is not None:
        args.figures.mkdir(parents=True, exist_ok=True)
        for name in NAMES:
            for png in (args.out / name / "figures").glob("*.png"):
                shutil.copy(png, args.figures / f"{name}_{png.name}")
        for png in overlay.glob("*.png"):
            shutil.copy(png, args.figures / f"overlay_{png.name}")


if __name__ == "__main__":
    main()
