"""The central-difference step kernel alone: ns per segment of its two halves, µs per step.

    python benchmarks/step_time.py                   # this checkout, 3 samples
    python benchmarks/step_time.py --against /path/to/other/checkout --against-cache DIR

Three figures, each the best (and the median) of seven timings, warm kernel cache, one thread:
`kick_rows` (the force evaluation, second half kick and the history record's fabric
diagnostics) and `drift_rows` (first half kick, magnetic rotation, drift) in ns per yarn
segment on bench.py (a)'s dented, moving 100 × 100 sheet (--size), called in a compiled loop;
and the whole step kernel `explicit.central_step` in µs per call on `paper-field` at
--warm-up seconds (the state the run reaches there; contact, damage and the record included),
called from Python with the same state each time. Each sample is a fresh process; with
--against the same script runs from another checkout of emfabric (PYTHONPATH=CHECKOUT/src,
its kernel cache in --against-cache), alternating sample by sample with this one, so that
both see the same machine: compare the figures of one invocation. The last line gives the
load average at the start and the end.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def measure(size: int, warm_up: float) -> dict[str, float]:
    """The three figures in this process (emfabric from sys.path)."""
    import numba
    import numpy as np

    sys.path.insert(0, str(HERE))
    import bench
    import profile_step

    from emfabric._kernels.explicit import central_step
    from emfabric._kernels.nodes import drift_rows, kick_rows

    numba.set_num_threads(1)
    model, integ, s = bench.deformed_sheet(size)
    s2 = s.copy()
    integ.work.xbuf[:] = s.node_x
    shape = integ.rowbuf.shape if integ.rowbuf is not None else integ.threads.shape[1:]
    buf = np.empty(shape)
    dt = bench.DT
    kick = bench._cd_repeat(kick_rows)
    drift = bench._cd_repeat(drift_rows)
    kick_args = (model.physics, s.arrays, s2.arrays, integ.work, s.t + dt, dt, buf)
    drift_args = (model.physics, s.arrays, s2.arrays, integ.work, s.t, dt, buf)
    calls = max(3, 2_000_000 // model.seg_count)
    out: dict[str, float] = {}
    for name, rep, args in (("kick", kick, kick_args), ("drift", drift, drift_args)):
        rep(1, *args)
        samples = []
        for _ in range(7):
            t0 = time.perf_counter()
            rep(calls, *args)
            samples.append((time.perf_counter() - t0) / calls / model.seg_count * 1e9)
        out[name] = min(samples)
        out[name + "_median"] = statistics.median(samples)

    _model, _state, call = profile_step.step_call("paper-field", warm_up)
    central_step(*call)
    samples = []
    for _ in range(7):
        t0 = time.perf_counter()
        for _ in range(300):
            central_step(*call)
        samples.append((time.perf_counter() - t0) / 300 * 1e6)
    out["step"] = min(samples)
    out["step_median"] = statistics.median(samples)
    return out


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--size", type=int, default=100, help="n of the n × n sheet (default 100)")
    p.add_argument("--warm-up", type=float, default=300e-6,
                   help="paper-field's simulated time before the step is timed [s]")
    p.add_argument("--samples", type=int, default=3, help="processes per checkout")
    p.add_argument("--against", type=Path, metavar="CHECKOUT",
                   help="another checkout of emfabric to time alternately (its src/ is used)")
    p.add_argument("--against-cache", type=Path, metavar="DIR",
                   help="NUMBA_CACHE_DIR for --against (default: a folder in the temp dir)")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        print(json.dumps(measure(args.size, args.warm_up)))
        return
    kinds = {"this": dict(os.environ, PYTHONPATH=str(HERE.parent / "src"))}
    if args.against is not None:
        kinds["against"] = dict(
            os.environ, PYTHONPATH=str(args.against.resolve() / "src"),
            NUMBA_CACHE_DIR=str(args.against_cache or Path(tempfile.gettempdir())
                                / "emfabric-step-time-against"))
    cmd = [sys.executable, __file__, "--child", "--size", str(args.size),
           "--warm-up", str(args.warm_up)]
    load0 = os.getloadavg()[0]
    results: dict[str, list[dict[str, float]]] = {k: [] for k in kinds}
    for env in kinds.values():  # compile or load each checkout's kernels first, untimed
        subprocess.run(cmd, env=env, capture_output=True, check=True)
    for _ in range(args.samples):
        for k, env in kinds.items():
            done = subprocess.run(cmd, env=env, capture_output=True, text=True)
            if done.returncode != 0:
                raise SystemExit(f"{k}: step_time failed: {done.stderr.strip()[-400:]}")
            results[k].append(json.loads(done.stdout.strip().splitlines()[-1]))
    print(f"central differences, one thread, warm cache: kick_rows and drift_rows on the dented "
          f"{args.size} × {args.size} sheet [ns/segment], central_step on paper-field at "
          f"{args.warm_up * 1e6:g} µs [µs/step]; best (median) of 7 per process, "
          f"{args.samples} processes each")
    for k, rows in results.items():
        cells = []
        for name, unit in (("kick", "ns/seg"), ("drift", "ns/seg"), ("step", "µs")):
            best = [r[name] for r in rows]
            cells.append(f"{name} {min(best):.2f}–{max(best):.2f} {unit}")
        where = HERE.parent if k == "this" else args.against
        print(f"  {k:8s} " + ", ".join(cells) + f"  ({where})")
    print(f"machine: {os.cpu_count()} cores, load average {load0:.2f} at the start and "
          f"{os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()
