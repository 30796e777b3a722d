"""ω of a run's first microseconds per courant number, central differences (docs/theory.md §5.2):
where the error of one courant to the next halves, the scheme is in its first-order range.

    python scripts/ogive_early.py                          # ogive-field to 60 µs
    python scripts/ogive_early.py --scenario ogive-field --end-time 60e-6 --courant 0.25 0.03125

Each courant runs the scenario from the start (seconds to a minute and a half on two cores).
"""

from __future__ import annotations

import argparse
import logging

import emfabric


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="ogive-field")
    p.add_argument("--end-time", type=float, default=60e-6, help="[s]")
    p.add_argument("--courant", type=float, nargs="+",
                   default=[0.25, 0.125, 0.0625, 0.03125, 0.015625, 0.0078125, 0.00390625])
    a = p.parse_args()
    logging.getLogger("emfabric").setLevel(logging.ERROR)
    print(f"{a.scenario} to {a.end_time * 1e6:g} µs, central differences")
    print(f"{'courant':>10} {'steps':>7} {'ω_x':>10} {'ω_y':>9} {'ω_z':>9}  change from the "
          "previous courant")
    last = None
    for c in a.courant:
        res = emfabric.run(emfabric.load_scenario(a.scenario, {
            "solver.integrator": "central-difference", "solver.courant": c,
            "solver.end_time": a.end_time}))
        w = res.history["angular_velocity"].values[-1]
        change = "" if last is None else f"{w[0] - last:+.4f}"
        print(f"{c:10.6g} {res.summary['steps']:7d} {w[0]:10.4f} {w[1]:9.4f} {w[2]:9.4f}  "
              f"{change}")
        last = w[0]


if __name__ == "__main__":
    main()
