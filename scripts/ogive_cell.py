"""Where the contacts of a nose sit on it, and whether they stick, over a window of a run
(docs/theory.md §5.2): the run goes to --start by central differences at each --courant, then
steps on to --end and prints, per bin of --bin seconds, each contact's steps in contact, its
distance from the nose's end along the axis and from the axis, its mean normal force (ΣJ_n over
the bin's steps / the bin's time) and the friction it used, Σ|J_t| / ΣJ_n (μ_d, 0.95 by default,
when it slid all the bin; less where it stuck).

    python scripts/ogive_cell.py                                   # ogive-field, 400–840 µs
    python scripts/ogive_cell.py --start 835e-6 --end 880e-6 --bin 1e-6   # the release

A segment contact is named by its two end nodes, a node contact by its node. Each courant runs
the scenario from the start (a minute at the default step, ten at courant / 4 over the default
window, on two cores).
"""

from __future__ import annotations

import argparse
import logging

import numpy as np

from emfabric import load_scenario
from emfabric._kernels.records import BODY_R0
from emfabric.integrators import make_integrator
from emfabric.runner import loop


def trace(name: str, courant: float, t0: float, t1: float, width: float) -> list[dict]:
    """Per bin of `width` seconds over [t0, t1]: {"t": end time, "steps": n, "span": time
    stepped, contact key: [steps, Σ tip distance, Σ axis distance, ΣJ_n,
    Σ|J_t|]}."""
    over = {"solver.integrator": "central-difference", "solver.courant": courant}
    start = loop.run(load_scenario(name, {**over, "solver.end_time": t0}), None)
    state, model = start.state, start.model
    body = model.body
    frame = np.asarray(body.frame)
    integ = make_integrator(model)
    nxt = state.copy()
    work = integ.work
    bins: dict[int, dict] = {}
    while state.t < t1:
        info = integ.step(state, nxt)
        rot = nxt.body[BODY_R0:BODY_R0 + 3]
        ent = bins.setdefault(int((nxt.t - t0) // width), {"steps": 0, "span": 0.0})
        for k in range(info.contacts):
            key = (int(work.c_node[k]), int(work.c_node2[k]))
            # the contact point in the shape's frame: e3 the nose axis, s the height above the
            # base face (shapes.py)
            q = frame @ (rot.T @ work.c_arm[:, k])
            j = work.c_imp[:, k]
            n = work.c_nrm[:, k]
            jn = float(j @ n)
            acc = ent.setdefault(key, np.zeros(5))
            acc += [1.0, body.length - (q[2] + body.base), float(np.hypot(q[0], q[1])), jn,
                    float(np.linalg.norm(j - jn * n))]
        ent["steps"] += 1
        ent["span"] += nxt.t - state.t
        ent["t"] = nxt.t
        state, nxt = nxt, state
    return [bins[b] for b in sorted(bins)]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="ogive-field")
    p.add_argument("--courant", type=float, nargs="+", default=[0.25, 0.0625])
    p.add_argument("--start", type=float, default=400e-6, help="t0 [s]")
    p.add_argument("--end", type=float, default=840e-6, help="t1 [s]")
    p.add_argument("--bin", type=float, default=10e-6, help="bin width [s]")
    a = p.parse_args()
    logging.getLogger("emfabric").setLevel(logging.ERROR)
    print(f"{a.scenario}, {a.start * 1e6:g}–{a.end * 1e6:g} µs, bins of {a.bin * 1e6:g} µs: "
          "per contact, steps in contact / steps, distance from the nose's end and from the "
          "axis [mm], mean normal force [N], friction used Σ|J_t|/ΣJ_n")
    for c in a.courant:
        print(f"courant {c:g}")
        for ent in trace(a.scenario, c, a.start, a.end, a.bin):
            span = ent["span"]
            parts = []
            for key in sorted(k for k in ent if isinstance(k, tuple)):
                n, tip, rho, jn, jt = ent[key]
                what = f"{key[0]}–{key[1]}" if key[1] >= 0 else f"{key[0]}"
                used = jt / jn if jn > 0.0 else float("nan")
                parts.append(f"{what} {int(n)}/{ent['steps']} {tip / n * 1e3:5.2f} "
                             f"{rho / n * 1e3:5.3f} {jn / span:7.0f} N {used:.2f}")
            print(f"  t = {ent['t'] * 1e6:7.2f} µs  " + (" | ".join(parts) or "no contact"))


if __name__ == "__main__":
    main()
