"""The rebound speed of a sharp ogive caught by segment contact, per courant number.

docs/theory.md §5.2; the shot of tests/test_shapes.py::
test_segment_contact_catches_a_nose_that_passes_between_nodes.

    python scripts/sharp_ogive.py                              # courant 0.25 … 0.0078125
    python scripts/sharp_ogive.py --courant 0.25 0.0625

An ogive narrower than a cell's diagonal (R = 0.6 h) aimed at a cell centre of an 11 × 11
clamped sheet without damage, at 50 m/s: no node is ever inside it, the four segments around
the cell catch it and throw it back, sliding along the nose. Each courant runs the shot from the
start (a second to a minute on two cores).
"""

from __future__ import annotations

import argparse
import logging

import emfabric

H = 0.01  # node spacing [m]
SHARP = {"projectile.shape": "ogive", "fabric.nodes": [11, 11], "fabric.size": [0.1, 0.1],
         "field.B": [0, 0, 0], "fabric.damage.rate": 0.0, "fabric.material.modulus_cv": 0.0,
         "contact.segments": True, "projectile.radius": 0.6 * H, "projectile.length": 3 * H,
         "projectile.nose_length": 1.8 * H, "projectile.mass": 0.005,
         "projectile.position": [H / 2, H / 2, 0.021], "projectile.velocity": [0, 0, -50.0],
         "solver.end_time": 3e-3}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--courant", type=float, nargs="+",
                   default=[0.25, 0.125, 0.0625, 0.03125, 0.015625, 0.0078125])
    a = p.parse_args()
    logging.getLogger("emfabric").setLevel(logging.ERROR)
    print(f"{'courant':>10} {'steps':>8}  end          rebound v_z [m/s]")
    for c in a.courant:
        sc = emfabric.Scenario().replace(**SHARP, **{"solver.courant": c})
        res = emfabric.run(sc, None)
        h = res.history
        print(f"{c:>10g} {len(h.time) - 1:>8d}  {res.end_reason:<12} "
              f"{float(h.projectile_velocity[-1, 2]):.2f}", flush=True)


if __name__ == "__main__":
    main()
