"""How close the plies of a pack come to one another, in each integrator.

Runs a pack scenario (default: the built-in pack-fsp on a 21 x 21 grid to 10 µs) with central
differences and with the φ-scheme, and prints for each pair of neighbouring plies the smallest
height of the lower ply's nodes under the upper ply's triangulated surface over all snapshots
(in mm and as a fraction of the contact distance d, the sum of the yarn radii), the projectile's
velocity at the end, the steps and the energy budget's error.

    python scripts/ply_gaps.py                       # pack-fsp, 21 x 21, 10 µs
    python scripts/ply_gaps.py pack-field --nodes 41 --end 2e-5
    python scripts/ply_gaps.py hard                  # tests/test_plies.py's hard impact
    python scripts/ply_gaps.py --courant 0.1 0.02    # central differences at smaller steps too

docs/theory.md §5.1 and docs/packs.md quote its output.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import xarray as xr
from matplotlib.tri import LinearTriInterpolator, Triangulation

from emfabric.config.scenario import Scenario, load_scenario
from emfabric.runner.loop import run

HARD = {"fabric.nodes": [21, 21], "fabric.size": [0.1, 0.1], "fabric.rescale": False,
        "fabric.material.modulus_cv": 0.0, "fabric.plies": 3, "field.B": [0.0, 0.0, 0.0],
        "projectile.radius": 0.01, "projectile.mass": 0.01, "fabric.damage.rate": 0.0,
        "projectile.velocity": [0.0, 0.0, -400.0], "solver.end_time": 60e-6}
"""tests/test_plies.py's hard impact: 3 touching plies of the paper's fabric, 21 x 21 on a
10 cm frame, no damage, a 1 cm sphere of 10 g at 400 m/s, 60 µs."""


def min_gaps(snapshots: Path, nodes: int) -> np.ndarray:
    """(snapshots, plies − 1): the smallest height of ply k + 1's nodes under ply k [m]."""
    snaps = xr.open_dataset(snapshots)
    ply = snaps.node_ply.values - 1
    x = snaps.node_position.values
    i, j = np.meshgrid(np.arange(nodes - 1), np.arange(nodes - 1))
    a = (j * nodes + i).ravel()
    tri = np.concatenate([np.stack([a, a + 1, a + nodes + 1], 1),
                          np.stack([a, a + nodes + 1, a + nodes], 1)])
    out = np.empty((x.shape[0], int(ply.max())))
    for s in range(x.shape[0]):
        for k in range(out.shape[1]):
            up, lo = x[s][ply == k], x[s][ply == k + 1]
            z = LinearTriInterpolator(Triangulation(up[:, 0], up[:, 1], tri), up[:, 2])
            h = z(lo[:, 0], lo[:, 1]) - lo[:, 2]
            out[s, k] = float(h.min())
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenario", nargs="?", default="pack-fsp")
    ap.add_argument("--nodes", type=int, default=21, help="nodes per side of every ply")
    ap.add_argument("--end", type=float, default=1e-5, help="end time [s]")
    ap.add_argument("--snapshots", type=int, default=10, help="snapshots over the run")
    ap.add_argument("--courant", type=float, nargs="*", default=[],
                    help="also run central differences at these solver.courant")
    args = ap.parse_args()
    runs = [("central-difference", {}), ("phi", {})]
    runs += [("central-difference", {"solver.courant": c}) for c in args.courant]
    for integrator, extra in runs:
        if args.scenario == "hard":
            args.nodes = 21
            args.end = HARD["solver.end_time"]
            sc = Scenario().replace(**HARD, **{
                "solver.integrator": integrator,
                "output.snapshot_interval": args.end / args.snapshots, **extra})
        else:
            sc = load_scenario(args.scenario, {
                "fabric.nodes": [args.nodes, args.nodes], "solver.end_time": args.end,
                "solver.integrator": integrator,
                "output.snapshot_interval": args.end / args.snapshots, **extra})
        with tempfile.TemporaryDirectory() as tmp:
            clock = time.perf_counter()
            res = run(sc, Path(tmp) / "run")
            wall = time.perf_counter() - clock
            d = float(res.model.physics.contact.ply_gap.min())
            gaps = min_gaps(Path(tmp) / "run" / "snapshots.nc", args.nodes)
            h = res.history
            impact = float(h.kinetic_energy_projectile[0])
            defl = " / ".join(f"{v * 1e3:.2f}" for v in h.max_deflection_per_ply[-1].values)
            label = integrator + "".join(f" {k.split('.')[-1]} {v}" for k, v in extra.items())
            print(f"{label}: {res.status}, {res.state.steps} steps, wall {wall:.1f} s; "
                  f"projectile v_z {float(h.projectile_velocity[-1, 2]):.2f} m/s; energy "
                  f"balance error {float(h.energy_balance_error[-1]):.3g} J of {impact:.4g} J")
            print(f"  deflection per ply [mm]: {defl}")
            print(f"  d = {d * 1e3:.4f} mm; smallest gap per pair over {gaps.shape[0]} "
                  "snapshots [mm] (fraction of d):")
            low = gaps.min(axis=0)
            print("  " + "  ".join(f"{g * 1e3:.3f} ({g / d:.2f})" for g in low))


if __name__ == "__main__":
    main()
