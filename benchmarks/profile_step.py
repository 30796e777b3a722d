"""Profile the central-difference step with `perf`, the compiled kernels named.

Runs a scenario to --warm-up seconds of simulated time, then calls the step kernel
(`explicit.central_step`) --calls times on that state. Before the loop it writes
/tmp/perf-<pid>.map, the symbol map `perf report` reads for JIT code, with every compiled
function of the process (its kernels compile afresh in a temporary cache for this: functions
loaded from Numba's cache carry no names).

    python benchmarks/profile_step.py paper-no-field     # compiles (~1 min), then prints:
    perf record -F 2999 -p PID -o /tmp/step.data -- sleep 5   # the command, with its PID
    perf report -i /tmp/step.data --sort sym

(sampling the loop only: recording the whole process would be mostly the compile).
`--set KEY=VALUE` changes the scenario as `emfabric run --set` does, e.g. `--set
"fabric.nodes=[1000,1000]" --set output.snapshot_interval=1e-4` for a million nodes.

benchmarks/PEER.md quotes what it found (Numba's reference counting, NRT_incref/NRT_decref,
at 21 % of a step before the row functions were inlined). Load the machine with nothing else.
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import tempfile
import time


def write_map(path: str) -> int:
    """Write a perf map (start, size, name per line) of every compiled function of this
    process; returns how many it named."""
    from numba.core.registry import CPUDispatcher

    libraries = {cres.library for obj in gc.get_objects() if isinstance(obj, CPUDispatcher)
                 for cres in obj.overloads.values()}
    named: dict[int, str] = {}
    for lib in libraries:
        module = getattr(lib, "_final_module", None)
        if module is None:
            continue
        for fn in module.functions:
            if fn.is_declaration:
                continue
            address = lib.get_pointer_to_function(fn.name)
            if address:
                named[address] = fn.name
    starts = sorted(named)
    with open(path, "w") as f:
        for i, a in enumerate(starts):
            gap = starts[i + 1] - a if i + 1 < len(starts) else 1 << 16
            f.write(f"{a:x} {min(gap, 1 << 16):x} {named[a]}\n")
    return len(starts)


def step_call(scenario: str, warm_up: float, overrides: dict | None = None) -> tuple:
    """(model, state, arguments of explicit.central_step) for `scenario` under central
    differences, run to `warm_up` seconds of simulated time: calling the step kernel with them
    repeats the step from that state (step_time.py times it too)."""
    from emfabric.config.scenario import load_scenario
    from emfabric.integrators import make_integrator
    from emfabric.integrators.central import ROTATION_TOLERANCE, CentralDifference
    from emfabric.sim.builder import build_model
    from emfabric.sim.state import initial_state

    model = build_model(load_scenario(scenario, {"solver.integrator": "central-difference",
                                                 **(overrides or {})}))
    integ = make_integrator(model)
    assert isinstance(integ, CentralDifference)
    s = initial_state(model)
    s2 = s.copy()
    while s.t < warm_up:
        integ.step(s, s2)
        s, s2 = s2, s
    rowbuf, threads = integ.kernel_buffers
    call = (integ.physics, s.arrays, s2.arrays, integ.work, rowbuf, threads, *integ.switches,
            s.t, s.dt, ROTATION_TOLERANCE, s2.energy.copy())
    return model, s, call


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenario", nargs="?", default="paper-no-field")
    ap.add_argument("--warm-up", type=float, default=30e-6,
                    help="simulated time before the profiled calls [s] (default 3e-5)")
    ap.add_argument("--calls", type=int, default=20000,
                    help="step kernel calls (default 20000, ~10 s)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scenario override, as `emfabric run --set` (repeatable), e.g. "
                         "--set fabric.nodes=[1000,1000]")
    args = ap.parse_args()
    if "EMFABRIC_PROFILE_CACHE" not in os.environ:
        # compile in this process (named functions): a fresh cache, then this script again
        with tempfile.TemporaryDirectory() as cache:
            env = dict(os.environ, NUMBA_CACHE_DIR=cache, EMFABRIC_PROFILE_CACHE="1")
            os.execve(sys.executable, [sys.executable, __file__, *sys.argv[1:]], env)
    from emfabric._kernels.explicit import central_step
    from emfabric.config.scenario import parse_override

    overrides = dict(parse_override(text) for text in args.set)
    model, s, call = step_call(args.scenario, args.warm_up, overrides)
    central_step(*call)
    count = write_map(f"/tmp/perf-{os.getpid()}.map")
    print(f"{count} compiled functions named in /tmp/perf-{os.getpid()}.map; now, in another "
          f"shell: perf record -F 2999 -p {os.getpid()} -o /tmp/step.data -- sleep 5",
          flush=True)
    t0 = time.perf_counter()
    for _ in range(args.calls):
        central_step(*call)
    per = (time.perf_counter() - t0) / args.calls
    print(f"{args.scenario}: {model.node_count} nodes, central_step {per * 1e6:.1f} µs a call "
          f"(t = {s.t * 1e6:.1f} µs, Δt = {s.dt:.3g} s)")


if __name__ == "__main__":
    main()
