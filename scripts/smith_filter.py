"""Failure criteria weighed on the struck yarn's recorded strains (docs/theory.md §2.1).

The test yarn of scripts/smith_critical.py is struck (a driven node, or a heavy sphere) with
failure off, and every segment's engineering strain of the struck row is recorded each step
for 10 µs after contact. Candidate criteria are then applied to the record: the strain itself
(emfabric's), the mean of a segment and its two neighbours, and the strain filtered with time
constant τ = k h/c. For each speed (a fraction of Smith's V_c at ε_f = 0.02) it prints the
largest criterion value over Smith's strain ε(V), and when ε_f is first reached (in h/c after
contact; "never" within 10 µs).

    python scripts/smith_filter.py              # all: driven node, spheres (some frictionless)
    python scripts/smith_filter.py --cases 0 4  # driven node, 3 mm frictionless sphere
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import smith_critical as S
from scipy.optimize import brentq

from emfabric.integrators import make_integrator

EPS_F = 0.02
CASES = [(None, None), (0.002, None), (0.005, None), (0.02, None), (0.003, 0.0), (0.01, 0.0)]
"""(sphere radius [m] or None for the driven node, friction or None for the scenario's)."""


def strains(speed: float, radius: float | None, friction: float | None, until: float = 10e-6,
            viscosity: float | None = None):
    """(times [s], strains (steps, segments) of the struck row, time of first contact [s])."""
    model, s = S.struck_yarn(speed, 5.0, radius, friction, viscosity)  # ε_f = 5: no failure
    integ = make_integrator(model)
    s2 = s.copy()
    a, b = model.yarns.ends[:, 0], model.yarns.ends[:, 1]
    row = (a >= S.NX) & (a < 2 * S.NX) & (b >= S.NX) & (b < 2 * S.NX)
    sel = np.nonzero(row & (model.yarns.stiffness > 0))[0]
    rest = model.yarns.rest_length[sel]
    ts, eps, touched = [], [], None
    while touched is None or s.t - touched <= until:
        integ.step(s, s2)
        s, s2 = s2, s
        d = s.node_x[:, b[sel]] - s.node_x[:, a[sel]]
        eps.append(np.linalg.norm(d, axis=0) / rest - 1.0)
        ts.append(s.t)
        if touched is None and (radius is None or s.contact_count > 0):
            touched = s.t
    return np.array(ts), np.array(eps), touched


def filtered(ts: np.ndarray, eps: np.ndarray, tau: float) -> np.ndarray:
    """The largest over the segments, each step, of the strain filtered with time constant τ."""
    out = np.empty(len(ts))
    f = np.zeros(eps.shape[1])
    before = 0.0
    for i, t in enumerate(ts):
        f += (eps[i] - f) * (1.0 - math.exp(-(t - before) / tau))
        before = t
        out[i] = f.max()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, nargs="*", default=list(range(len(CASES))),
                    help="which impactors (0 driven node; 1-3 spheres 2, 5, 20 mm; 4-5 "
                         "frictionless spheres 3, 10 mm)")
    ap.add_argument("--ratios", type=float, nargs="*", default=[0.8, 0.9, 0.95, 1.02, 1.1],
                    help="impact speeds as fractions of V_c")
    ap.add_argument("--bulk-viscosity", type=float, default=None,
                    help="solver.bulk_viscosity (default: the scenario's, 0.06 for these brittle "
                         "yarns; docs/theory.md's table: 0)")
    args = ap.parse_args()
    vc = S.smith_speed(EPS_F)
    hc = S.H / math.sqrt(S.E / S.RHO)
    print(f"ε_f = {EPS_F}: V_c = {vc:.1f} m/s; h/c = {hc * 1e6:.4f} µs; each entry: largest "
          f"criterion / Smith's ε(V), and when ε_f is first reached")
    for k in args.cases:
        radius, friction = CASES[k]
        what = ("driven node" if radius is None else f"sphere {radius * 1e3:g} mm"
                + (", frictionless" if friction == 0.0 else ""))
        print(f"== {what}")
        for ratio in args.ratios:
            ts, eps, t0 = strains(ratio * vc, radius, friction, viscosity=args.bulk_viscosity)
            smith = brentq(lambda e, r=ratio: S.smith_speed(e) - r * vc, 1e-9, 0.5)
            pad = np.pad(eps, ((0, 0), (1, 1)), mode="edge")
            mean3 = ((pad[:, :-2] + pad[:, 1:-1] + pad[:, 2:]) / 3.0).max(axis=1)
            criteria = [("strain", eps.max(axis=1)), ("mean of 3", mean3)]
            criteria += [(f"τ={m:g}h/c", filtered(ts, eps, m * hc)) for m in (2, 5, 10)]
            cells = []
            for name, c in criteria:
                hit = np.nonzero(c >= EPS_F)[0]
                when = f"{(ts[hit[0]] - t0) / hc:.1f} h/c" if len(hit) else "never"
                cells.append(f"{name} {c.max() / smith:.3f} ({when})")
            print(f"  {ratio:.2f} V_c: " + " | ".join(cells), flush=True)


if __name__ == "__main__":
    main()
