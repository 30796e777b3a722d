"""The energy budget of brittle packs that the projectile tears through.

Runs a pack of plies of KM2 style 706 (31 x 31 nodes on a 5 cm frame, rescaled from the
style's 68 x 68 network; no field, no charge) struck head-on by the km2-fsp .22 FSP (or a
4 mm sphere of the same mass) at the speeds of the cases below, and prints for each how the
run ended, its largest |energy balance error| against the energy put in, and what the
viscosity, the projection and the damage booked.

    python scripts/pack_rupture_energy.py             # the five cases of docs/theory.md §5.1
    python scripts/pack_rupture_energy.py --case 3x300

Each run takes 10-60 s on two cores. docs/theory.md §5.1 ("Placements in a torn pack")
quotes its output.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from emfabric.config.scenario import Scenario
from emfabric.integrators import DivergenceError
from emfabric.runner.loop import run

BASE = {"fabric.style": "km2-600d-plain", "fabric.size": [0.05, 0.05],
        "fabric.nodes": [31, 31], "fabric.charge_per_node": 0.0, "field.B": [0.0, 0.0, 0.0],
        "projectile.shape": "fsp", "projectile.radius": 0.00278, "projectile.mass": 0.0011,
        "solver.end_time": 3e-4}
"""A pack of KM2 style 706 under the km2-fsp .22 FSP; the cases set plies and speed."""

CASES = {
    "2x100": {"fabric.plies": 2, "projectile.velocity": [0.0, 0.0, -100.0],
              "solver.end_time": 2e-4},
    "2x150": {"fabric.plies": 2, "projectile.velocity": [0.0, 0.0, -150.0]},
    "3x150": {"fabric.plies": 3, "projectile.velocity": [0.0, 0.0, -150.0]},
    "3x300": {"fabric.plies": 3, "projectile.velocity": [0.0, 0.0, -300.0]},
    "3x300-sphere": {"fabric.plies": 3, "projectile.velocity": [0.0, 0.0, -300.0],
                     "projectile.shape": "sphere", "projectile.radius": 0.004},
}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--case", nargs="*", default=list(CASES), choices=list(CASES))
    args = p.parse_args(argv)
    print(f"{'case':>13} {'end':>24} {'t_end µs':>9} {'E in J':>7} {'max|err| J':>10} "
          f"{'%':>5} {'viscous J':>9} {'projection J':>12} {'damage J':>8} {'broken':>6}")
    for name in args.case:
        sc = Scenario().replace(**{**BASE, **CASES[name]})
        clock = time.perf_counter()
        try:
            ds = run(sc).history
        except DivergenceError as exc:
            ds = exc.result.history
        wall = time.perf_counter() - clock
        err = np.abs(ds.energy_balance_error.values).max()
        e_in = float(ds.kinetic_energy_projectile.values[0])
        status = ds.attrs["status"]
        end = f"complete ({ds.attrs.get('end_reason', '')})" if status == "complete" else status
        print(f"{name:>13} {end:>24} {1e6 * float(ds.time.values[-1]):9.1f} {e_in:7.2f} "
              f"{err:10.3f} {100 * err / e_in:5.1f} "
              f"{float(ds.dissipation_viscous.values[-1]):9.2f} "
              f"{float(ds.dissipation_projection.values[-1]):12.2f} "
              f"{float(ds.dissipation_damage.values[-1]):8.2f} "
              f"{int(ds.broken_yarns.values[-1]):6d}   ({wall:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
