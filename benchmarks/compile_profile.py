"""Where the first run's compile time goes: Numba compile time per kernel, cold cache.

    python benchmarks/compile_profile.py            # paper-field to 2 µs, empty kernel cache

Runs in a fresh kernel cache (a temporary NUMBA_CACHE_DIR) and prints the launch-to-first-step
time and the inclusive compile time of every kernel (a kernel's time includes the callees it
compiled first). NUMBA_NUM_THREADS=1 shows the serial path alone; EMFABRIC_PRECOMPILE=0 leaves
out the second process that compiles part of the kernels beside the run (runner.precompile):
the kernels it compiles are then listed here too.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time


def child() -> None:
    launch = float(os.environ["EMFABRIC_BENCH_LAUNCH"])
    from numba.core import event

    rec = event.RecordingListener()
    event.register("numba:compile", rec)
    from emfabric import load_scenario, run

    t_import = time.time() - launch
    first: list[float] = []

    def progress(state, info) -> None:
        if not first:
            first.append(time.time() - launch)

    sc = load_scenario("paper-field", {"solver.end_time": 2e-6})
    with tempfile.TemporaryDirectory() as out:
        run(sc, out, progress=progress)
    total = time.time() - launch
    print(f"import {t_import:.2f} s, first step {first[0]:.2f} s after launch, "
          f"process {total:.2f} s (incl. the background compile of the threaded kernel)")
    starts, rows = {}, []
    for ts, ev in rec.buffer:
        key = (ev.data["dispatcher"].py_func.__qualname__, str(ev.data["args"]))
        if ev.is_start:
            starts[key] = ts
        else:
            rows.append((ts - starts.pop(key), key[0]))
    print("compile s  kernel (inclusive of callees compiled first)")
    for dt, name in sorted(rows, reverse=True):
        if dt >= 0.1:
            print(f"{dt:9.2f}  {name}")


def main() -> None:
    if "--child" in sys.argv:
        child()
        return
    # --help says what this does instead of running it (a minute or more)
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, EMFABRIC_BENCH_LAUNCH=repr(time.time()))
        subprocess.run([sys.executable, __file__, "--child"], env=env, check=True)


if __name__ == "__main__":
    main()
