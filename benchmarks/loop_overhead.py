"""Where a run's time goes around the step kernel: the Python the run loop spends per step.

    python benchmarks/loop_overhead.py                  # demo-small, three runs in memory
    python benchmarks/loop_overhead.py paper-field --runs 1

Runs the scenario in memory (`emfabric.run(scenario, None)`: no files) after a short warm-up
run, with timers around the loop's per-step calls: the step kernel itself (the integrator's
compiled step), the rest of `Integrator.step` (choosing Δt, counting contacts, the state's
bookkeeping), `measure` (the history record), `check_plausible` and `left_for_good` (the
stop rule); "other" is the loop's remainder. Microseconds per step; each timer adds ~0.3 µs.
Central differences only (the default integrator).
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict

import emfabric
import emfabric.integrators.central as central
import emfabric.runner.loop as loop
from emfabric.config.scenario import load_scenario


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("scenario", nargs="?", default="demo-small")
    p.add_argument("--runs", type=int, default=3)
    args = p.parse_args(argv)
    emfabric.run(load_scenario(args.scenario, {"solver.end_time": 2e-6}), None)  # warm
    acc: dict[str, float] = defaultdict(float)

    def timed(f, label):
        def g(*a, **k):
            t = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                acc[label] += time.perf_counter() - t
        return g

    for name in ("measure", "check_plausible", "left_for_good"):
        setattr(loop, name, timed(getattr(loop, name), name))
    step = central.CentralDifference.step
    central.CentralDifference.step = timed(step, "step")
    init = central.CentralDifference.__init__

    def init_timed(self, *a, **k):
        init(self, *a, **k)
        self._step = timed(self._step, "kernel")

    central.CentralDifference.__init__ = init_timed
    sc = load_scenario(args.scenario)
    if sc.solver.integrator != "central-difference":
        raise SystemExit(f"{args.scenario}: solver.integrator = {sc.solver.integrator!r}; "
                         "this script times central differences")
    print(f"{args.scenario}: µs per step (in memory, no files)")
    for _ in range(args.runs):
        acc.clear()
        t0 = time.perf_counter()
        res = emfabric.run(sc, None)
        wall = time.perf_counter() - t0
        n = res.state.steps
        acc["step"] -= acc["kernel"]
        other = wall - sum(acc.values())
        parts = {"kernel": acc["kernel"], "rest of step": acc["step"],
                 "measure": acc["measure"], "check_plausible": acc["check_plausible"],
                 "left_for_good": acc["left_for_good"], "other": other}
        print(f"  {wall:7.3f} s, {n} steps: "
              + ", ".join(f"{k} {v / n * 1e6:.1f}" for k, v in parts.items()))


if __name__ == "__main__":
    main()
