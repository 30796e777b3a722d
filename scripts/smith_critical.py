"""The lumped network's critical speed for a transversely struck yarn, against Smith's V_c.

A single yarn (0.6 m, 1 mm spacing, E = 100 GPa, ρ = 1440 kg/m³, r = 0.1 mm, both ends
clamped; the test yarn of tests/test_rupture.py) of brittle yarns with failure strain ε_f is
struck at its middle, either by driving the middle node at constant speed (Smith's point impact)
or by a heavy sphere of the given radius. Bisects the impact speed, as a fraction of Smith's
critical velocity V_c = V(ε_f) for the relaxed KSV law (docs/theory.md §2.1), at which some
yarn breaks within `--time` of the impact.

    python scripts/smith_critical.py                        # driven node, spheres of 3 and 10 mm
    python scripts/smith_critical.py --radius 0.005 --friction 0
    python scripts/smith_critical.py --no-node --radius 0.003 --failure-strain 0.035
    python scripts/smith_critical.py --radius --time 30e-6 --bulk-viscosity 0   # without it

docs/theory.md §2.1 quotes its output.
"""

from __future__ import annotations

import argparse
import logging
import math

import numpy as np
from scipy.optimize import brentq

from emfabric.config.scenario import Scenario
from emfabric.integrators import make_integrator
from emfabric.sim.builder import build_model
from emfabric.sim.state import initial_state

H, NX = 1e-3, 601  # node spacing [m], nodes of the struck yarn
HY = 2.0  # the strip's side rows are 2 m away
E, RHO, R = 100e9, 1440.0, 1e-4  # modulus [Pa], fibre density [kg/m³], yarn radius [m]


def smith_speed(eps: float) -> float:
    """Smith's impact speed V for the strain ε behind the waves, relaxed KSV yarn [m/s]
    (docs/theory.md §2.1: V² = 2(1 + ε)U_L w − w²)."""
    u = 1.0 + eps
    t = E / RHO * u * (u * u - 1.0) / 2.0
    w = math.sqrt(t / eps) * eps
    ul = math.sqrt(t / u)
    return math.sqrt(2.0 * u * ul * w - w * w)


def struck_yarn(speed: float, eps_f: float, radius: float | None, friction: float | None,
                viscosity: float | None = None, averaging: float | None = None):
    """(model, initial state) of the test yarn of brittle yarns with failure strain eps_f, struck
    at `speed` by the driven middle node (radius None) or by a 5 kg sphere of that radius
    (friction: static and dynamic, None for the scenario's; viscosity: solver.bulk_viscosity,
    None for the default; averaging: fabric.damage.strain_averaging, None for the default)."""
    lin = RHO * math.pi * R**2
    ly = 2 * HY
    keys = {"fabric.rescale": False, "fabric.material.modulus_cv": 0.0, "field.B": [0, 0, 0],
            "fabric.nodes": [NX, 3], "fabric.size": [(NX - 1) * H, ly],
            "fabric.areal_density": lin * H * (3 * NX) / ((NX - 1) * H * ly),
            "fabric.yarn_radius": R, "fabric.material.youngs_modulus": E,
            "fabric.damage.law": "brittle", "fabric.damage.failure_strain": eps_f}
    if viscosity is not None:
        keys["solver.bulk_viscosity"] = viscosity
    if averaging is not None:
        keys["fabric.damage.strain_averaging"] = averaging
    if radius is None:
        keys["projectile.shape"] = "none"
    else:
        keys.update({"projectile.shape": "sphere", "projectile.radius": radius,
                     "projectile.mass": 5.0, "projectile.velocity": [0.0, 0.0, -speed]})
        if friction is not None:
            keys.update({"contact.static_friction": friction,
                         "contact.dynamic_friction": friction})
    model = build_model(Scenario().replace(**keys))
    s = initial_state(model)
    if radius is None:
        mid = NX + NX // 2
        model.nodes.mass[mid] *= 1e9
        model.nodes.inv_mass[mid] /= 1e9
        s.node_v[2, mid] = -speed
    return model, s


def breaks(speed: float, eps_f: float, radius: float | None, friction: float | None,
           until: float, viscosity: float | None = None,
           averaging: float | None = None) -> bool:
    """Whether a yarn breaks within `until` of the impact at `speed` (radius None: the driven
    node)."""
    model, s = struck_yarn(speed, eps_f, radius, friction, viscosity, averaging)
    integ = make_integrator(model)
    s2 = s.copy()
    touched = None
    while True:
        integ.step(s, s2)
        s, s2 = s2, s
        if (s.seg_alpha == 0.0).any():
            return True
        if touched is None and (radius is None or s.contact_count > 0):
            touched = s.t
        if touched is not None and s.t - touched > until:
            return False


def critical(eps_f: float, radius: float | None, friction: float | None, until: float,
             tol: float, viscosity: float | None = None,
             averaging: float | None = None) -> tuple[float, float]:
    """(lo, hi): the fraction of V_c that breaks no yarn, and the one that breaks one."""
    vc = smith_speed(eps_f)
    lo, hi = 0.5, 1.3
    if not breaks(hi * vc, eps_f, radius, friction, until, viscosity, averaging):
        return hi, math.inf
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if breaks(mid * vc, eps_f, radius, friction, until, viscosity, averaging):
            hi = mid
        else:
            lo = mid
    return lo, hi


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--radius", type=float, nargs="*", default=[0.003, 0.01],
                    help="sphere radii [m] (default 0.003 0.01)")
    ap.add_argument("--no-node", action="store_true", help="leave out the driven node")
    ap.add_argument("--friction", type=float, default=None,
                    help="static and dynamic friction of the spheres (default: the scenario's)")
    ap.add_argument("--failure-strain", type=float, default=0.02, help="ε_f (default 0.02)")
    ap.add_argument("--time", type=float, default=10e-6,
                    help="how long after the first contact a yarn may break [s] (default 1e-5)")
    ap.add_argument("--bulk-viscosity", type=float, default=None,
                    help="solver.bulk_viscosity (default: the scenario's, 0.06 for these brittle "
                         "yarns)")
    ap.add_argument("--strain-averaging", type=float, default=None,
                    help="fabric.damage.strain_averaging (default: the scenario's, 5)")
    ap.add_argument("--tol", type=float, default=0.01,
                    help="bisection width, as a fraction of V_c (default 0.01)")
    args = ap.parse_args()
    # the test yarn is a strip with side rows 2 m away: the plausibility warnings hold for it
    logging.getLogger("emfabric").setLevel(logging.ERROR)
    vc = smith_speed(args.failure_strain)
    eps = brentq(lambda e: smith_speed(e) - vc, 1e-9, 0.5)
    print(f"ε_f = {args.failure_strain:g}: Smith's V_c = {vc:.1f} m/s (check: ε(V_c) = {eps:.6f})")
    cases: list[float | None] = ([] if args.no_node else [None]) + list(args.radius)
    for radius in cases:
        lo, hi = critical(args.failure_strain, radius, args.friction, args.time, args.tol,
                          args.bulk_viscosity, args.strain_averaging)
        what = "driven node" if radius is None else f"sphere r = {radius * 1e3:g} mm"
        if radius is not None and args.friction is not None:
            what += f", friction {args.friction:g}"
        shown = "above 1.3" if not np.isfinite(hi) else f"{lo:.3f}–{hi:.3f}"
        print(f"{what:32s} breaks from {shown} V_c")


if __name__ == "__main__":
    main()
