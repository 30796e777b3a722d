"""Angular momentum of a free pack struck obliquely by a spinning sphere, against the step.

A free sheet of the paper's fabric, 15 x 15 nodes (no field), or a pack of its plies, struck
by the paper's sphere at (40, -25, -250) m/s spinning at (300, -200, 1000) rad/s, for 60 us
(the case of tests/test_central.py::test_free_fabric_struck_conserves_momentum). Nothing
external acts, so the angular momentum of fabric + projectile is a constant of the motion;
the scheme keeps it to a first-order drift (the contact placements move nodes without
momentum). Prints, for each courant number, the largest |L(t) - L(0)| / |L(0)| and
|p(t) - p(0)| / |p(0)| over the run.

    python scripts/pack_angular_momentum.py                    # 2 plies
    python scripts/pack_angular_momentum.py --plies 1
    python scripts/pack_angular_momentum.py --frictionless     # mu_s = mu_d = 0

docs/theory.md section 5.1 ("The reaction on the line of action") quotes its output. A few
seconds a run once the kernels are compiled.
"""

from __future__ import annotations

import argparse

import numpy as np

from emfabric.config.scenario import Scenario
from emfabric.runner.loop import run


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--plies", type=int, default=2)
    p.add_argument("--frictionless", action="store_true")
    p.add_argument("--courant", type=float, nargs="*", default=[0.5, 0.25, 0.125])
    args = p.parse_args(argv)
    base = {"fabric.nodes": [15, 15], "fabric.edges": "free", "fabric.plies": args.plies,
            "field.B": [0.0, 0.0, 0.0], "projectile.velocity": [40.0, -25.0, -250.0],
            "projectile.angular_velocity": [300.0, -200.0, 1000.0], "projectile.gap": 0.0,
            "solver.integrator": "central-difference", "solver.end_time": 60e-6}
    if args.frictionless:
        base.update({"contact.static_friction": 0.0, "contact.dynamic_friction": 0.0})
    print(f"{'courant':>8} {'max|dL|/|L0|':>13} {'max|dp|/|p0|':>13}")
    for courant in args.courant:
        ds = run(Scenario().replace(**{**base, "solver.courant": courant})).history
        mom = ds.fabric_momentum.values + ds.projectile_momentum.values
        ang = ds.fabric_angular_momentum.values + ds.projectile_angular_momentum.values
        d_ang = np.linalg.norm(ang - ang[0], axis=1).max() / np.linalg.norm(ang[0])
        d_mom = np.linalg.norm(mom - mom[0], axis=1).max() / np.linalg.norm(mom[0])
        print(f"{courant:8.4g} {d_ang:13.3e} {d_mom:13.3e}")


if __name__ == "__main__":
    main()
