"""Brittle failure on the averaged stretch against the instantaneous one, as the spacing halves.

`km2-fsp` (the .22 FSP into one ply of KM2) on a 3 cm frame for 60 µs, struck at 300 and at
120 m/s, on 41 × 41 nodes (one network line per yarn) and on 81 × 81 (half the spacing), with
`fabric.damage.strain_averaging` = 5 (the default) and 0 (the instantaneous stretch): the energy
released by rupture (history `dissipation_damage`), the FSP's speed at the end, the viscous
dissipation, the broken yarns and the largest stretch of an intact yarn. The averaged
criterion's extra release should shrink as the spacing does (docs/theory.md §2.1 quotes the
output).

    python scripts/rupture_convergence.py               # the eight runs, ~1 min
    python scripts/rupture_convergence.py --speeds 300 --nodes 41
"""

from __future__ import annotations

import argparse
import logging

import numpy as np

from emfabric.config.scenario import load_scenario
from emfabric.runner.loop import run


def shot(nodes: int, averaging: float, speed: float) -> dict:
    sc = load_scenario("km2-fsp", {
        "fabric.size": [0.03, 0.03], "solver.end_time": 6e-5, "fabric.nodes": [nodes, nodes],
        "fabric.damage.strain_averaging": averaging, "projectile.velocity": [0, 0, -speed]})
    res = run(sc, None)
    h = res.history
    return {"release": float(h.dissipation_damage[-1]),
            "speed": float(np.linalg.norm(res.state.body_v)),
            "viscous": float(h.dissipation_viscous[-1]), "broken": int(h.broken_yarns[-1]),
            "stretch": float(h.max_stretch.max()), "end": res.end_reason}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--speeds", type=float, nargs="+", default=[300.0, 120.0])
    ap.add_argument("--nodes", type=int, nargs="+", default=[41, 81])
    args = ap.parse_args()
    logging.getLogger("emfabric").setLevel(logging.ERROR)
    print("| striking speed, network | averaged (default) | instantaneous | ratio of the "
          "releases |")
    print("|---|---|---|---|")
    for speed in args.speeds:
        for nodes in args.nodes:
            avg, inst = shot(nodes, 5.0, speed), shot(nodes, 0.0, speed)
            print(f"| {speed:g} m/s, {nodes} × {nodes} | {avg['release']:.3f} J, "
                  f"{avg['speed']:.1f} m/s | {inst['release']:.3f} J, {inst['speed']:.1f} m/s | "
                  f"{avg['release'] / inst['release']:.2f} |")
            for name, r in (("averaged", avg), ("instantaneous", inst)):
                print(f"  {name}: viscous {r['viscous']:.3f} J, {r['broken']} broken, largest "
                      f"intact stretch {r['stretch']:.4f}, {r['end']}")


if __name__ == "__main__":
    main()
