"""What central differences' friction delivers at the segment contacts of a run, per courant
number (docs/theory.md §5.2): the run goes to --start, then steps on to --end recording every
contact of every step, and prints for each segment (or node) in contact the steps it touched,
the summed normal impulse as a mean force ΣJ_n / (t1 − t0), and |ΣJ_t| / |ΣJ_n| — μ_d (0.95 by
default) for a contact that slides all along, less where it sticks. A contact that slides in the
converged run but sticks at a larger step is the stick band of time-stepped Coulomb friction.

    python scripts/segment_friction.py                       # ogive-field, 20–30 µs
    python scripts/segment_friction.py --courant 0.25 0.0078125 --scenario ogive-field

Each courant runs the scenario from the start (a few seconds to a minute on two cores).
"""

from __future__ import annotations

import argparse
import logging

import numpy as np

from emfabric import load_scenario
from emfabric.integrators import make_integrator
from emfabric.runner import loop


def contacts(name: str, courant: float, t0: float, t1: float) -> tuple[dict, int, float]:
    """{(node, second node or −1): [ΣJ_n n (3), ΣJ_t (3), steps]}, steps, mean Δt over
    [t0, t1] of `name` by central differences at `courant`."""
    over = {"solver.integrator": "central-difference", "solver.courant": courant}
    start = loop.run(load_scenario(name, {**over, "solver.end_time": t0}), None)
    state, model = start.state, start.model
    integ = make_integrator(model)
    nxt = state.copy()
    work = integ.work
    acc: dict[tuple[int, int], np.ndarray] = {}
    steps = 0
    begin = state.t
    while state.t < t1:
        info = integ.step(state, nxt)
        for k in range(info.contacts):
            key = (int(work.c_node[k]), int(work.c_node2[k]))
            j = work.c_imp[:, k].copy()
            n = work.c_nrm[:, k].copy()
            jn = float(j @ n)
            a = acc.setdefault(key, np.zeros(7))
            a[:3] += jn * n
            a[3:6] += j - jn * n
            a[6] += 1
        state, nxt = nxt, state
        steps += 1
    return acc, steps, (state.t - begin) / max(steps, 1)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="ogive-field")
    p.add_argument("--courant", type=float, nargs="+",
                   default=[0.25, 0.0625, 0.03125, 0.015625, 0.0078125])
    p.add_argument("--start", type=float, default=20e-6, help="t0 [s]")
    p.add_argument("--end", type=float, default=30e-6, help="t1 [s]")
    a = p.parse_args()
    logging.getLogger("emfabric").setLevel(logging.ERROR)
    mu = load_scenario(a.scenario).contact.dynamic_friction
    print(f"{a.scenario}, {a.start * 1e6:g}–{a.end * 1e6:g} µs: each contact's mean normal "
          f"force ΣJ_n/(t1 − t0) and |ΣJ_t|/|ΣJ_n| (μ_d = {mu:g}: sliding all along)")
    for c in a.courant:
        acc, steps, dt = contacts(a.scenario, c, a.start, a.end)
        print(f"courant {c:g}: {steps} steps, mean Δt {dt:.3g} s")
        span = a.end - a.start
        for key in sorted(acc):
            v = acc[key]
            jn = float(np.linalg.norm(v[:3]))
            ratio = float(np.linalg.norm(v[3:6])) / jn if jn > 0.0 else float("nan")
            what = f"segment {key[0]}–{key[1]}" if key[1] >= 0 else f"node {key[0]}"
            print(f"    {what:<22} in contact {int(v[6]):6d} steps   mean normal force "
                  f"{jn / span:8.1f} N   |ΣJ_t|/|ΣJ_n| {ratio:.3f}")


if __name__ == "__main__":
    main()
