"""What a kernel call costs besides its work, and what the stop rule's bound costs.

    python benchmarks/call_cost.py               # about 30 s on 2 cores, warm kernel cache

1. The step kernel's entry: two kernels that take `explicit.central_step`'s twelve arguments
   (demo-small's records, as the integrator passes them) and do nothing, one compiled with
   Numba's reference counting and one with `_nrt=False` as the step kernels are, each called
   through sim/fastcall.py's `Direct` as the integrator calls its kernel: µs a call. With
   the counts, the entry wraps every array of the records in a MemInfo and frees it again.
2. The stop rule's bound (`emfabric.sim.reach.reach_along`, every 64 steps once every node is
   behind the projectile) on paper-field's last state: against the limit the run stopped at
   (the projectile's trailing side) and against no limit, with the damage's least stiffness
   (`lower_stiffness`) and one pass of the kernel (`_kernels.reach.fabric_reach`) alone: ms a
   call.

docs/performance.md quotes both ("the step kernel called without reference counts").
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from numba import njit


@njit(cache=False)
def _counted(phys, sin, sout, work, rowbuf, threads, plies, segs, t, dt, tol, energy):
    return 0, 0, 0.0, 0.0


@njit(cache=False, _nrt=False)
def _uncounted(phys, sin, sout, work, rowbuf, threads, plies, segs, t, dt, tol, energy):
    return 0, 0, 0.0, 0.0


def _per_call(f, n: int) -> float:
    f()
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        for _ in range(n):
            f()
        best = min(best, (time.perf_counter() - t0) / n)
    return best


def entry_cost(calls: int) -> None:
    import emfabric
    import emfabric.integrators.central as central
    from emfabric.config.scenario import load_scenario
    from emfabric.sim.fastcall import Direct

    captured: dict = {}
    step = central.CentralDifference.step

    def capture(self, s_in, s_out, *a, **k):
        captured.setdefault("args", (self.physics, s_in.arrays, s_out.arrays, self.work,
                                     *self.kernel_buffers, *self.switches, s_in.t, 1e-9,
                                     1e-12, s_out.energy))
        return step(self, s_in, s_out, *a, **k)

    central.CentralDifference.step = capture
    try:
        emfabric.run(load_scenario("demo-small", {"solver.end_time": 1e-6}), None)
    finally:
        central.CentralDifference.step = step
    args = captured["args"]
    print("1. a call with central_step's arguments (demo-small), best of 3 × "
          f"{calls} calls through fastcall.Direct")
    for kernel, label in ((_counted, "reference-counted"), (_uncounted, "_nrt=False")):
        d = Direct(kernel)
        print(f"   {label:18} {1e6 * _per_call(lambda d=d: d(None, *args), calls):6.2f} µs")


def reach_cost(repeat: int) -> None:
    import emfabric
    from emfabric._kernels import reach as kernels
    from emfabric.config.scenario import load_scenario
    from emfabric.sim import reach

    res = emfabric.run(load_scenario("paper-field"), None)
    model, state, hist = res.model, res.state, res.history
    energy = reach.fabric_energy_bound(float(hist["kinetic_energy_fabric"].values[-1]),
                                       float(hist["strain_energy"].values[-1]))
    away = model.flight_direction * np.sign(float(state.body_v @ model.flight_direction))
    trailing = float(state.body_x @ away) - 1.05 * model.geometry.bound
    nodes, yarns = model.nodes, model.yarns
    e = np.ascontiguousarray(away, dtype=float)
    first = int(np.argmax(e @ state.node_x))
    keff = np.where(state.seg_alpha > 0.0, state.seg_alpha * yarns.stiffness, 0.0)
    print(f"2. the stop rule's bound on paper-field's last state (t = {state.t:.4g} s, "
          f"{res.end_reason}), best of 3 × {repeat}")
    for label, f in (
            ("reach_along, limit the trailing side",
             lambda: reach.reach_along(model, state, away, energy, trailing)),
            ("reach_along, no limit", lambda: reach.reach_along(model, state, away, energy, 1e9)),
            ("  lower_stiffness", lambda: reach.lower_stiffness(model, state.seg_alpha, energy)),
            ("  fabric_reach, limit the trailing side",
             lambda: kernels.fabric_reach(nodes.rows, nodes.ply_rows, nodes.x0, nodes.inv_mass,
                                          yarns.rest_length, keff, energy, e, trailing, first))):
        print(f"   {label:40} {1e3 * _per_call(f, repeat):7.2f} ms")


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--calls", type=int, default=20000, help="calls per sample (part 1)")
    p.add_argument("--repeat", type=int, default=10, help="calls per sample (part 2)")
    args = p.parse_args(argv)
    entry_cost(args.calls)
    reach_cost(args.repeat)


if __name__ == "__main__":
    main()
