"""The whole `emfabric run SCENARIO --out DIR --quiet` command, end to end, warm kernel cache.

    python benchmarks/cli_time.py                          # paper-field and demo-small, 5 each
    python benchmarks/cli_time.py --scenarios demo-small --repeat 8
    python benchmarks/cli_time.py --against /path/to/other/checkout --against-cache DIR

Each run is a fresh process (`python -m emfabric run ...`, what a user types) into a fresh
folder, timed from launch to exit; the first of each kind only warms the kernel cache and is
not counted. With --against, the same command runs from another checkout of emfabric
(PYTHONPATH=CHECKOUT/src, its kernel cache in --against-cache: a cache is tied to the source
path), alternating run by run with this one, so that both see the same machine: compare the
medians of one invocation. The last line gives the load average at the start and the end
(this benchmark keeps about one core busy itself).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent


def one_run(scenario: str, env: dict[str, str]) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "emfabric", "run", scenario, "--out", str(Path(tmp) / "o"),
               "--quiet"]
        t0 = time.perf_counter()
        out = subprocess.run(cmd, capture_output=True, text=True, env=env)
        wall = time.perf_counter() - t0
    if out.returncode != 0:
        raise SystemExit(f"`{' '.join(cmd[1:5])}` failed ({out.returncode}): "
                         f"{out.stderr.strip()[-400:]}")
    return wall


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenarios", nargs="+", default=["paper-field", "demo-small"])
    p.add_argument("--repeat", type=int, default=5, help="timed runs per scenario and checkout")
    p.add_argument("--against", type=Path, metavar="CHECKOUT",
                   help="another checkout of emfabric to time alternately (its src/ is used)")
    p.add_argument("--against-cache", type=Path, metavar="DIR",
                   help="NUMBA_CACHE_DIR for --against (default: a folder in the temp dir)")
    args = p.parse_args(argv)
    kinds = {"this": dict(os.environ)}
    kinds["this"]["PYTHONPATH"] = str(HERE / "src")
    if args.against is not None:
        other = dict(os.environ, PYTHONPATH=str(args.against.resolve() / "src"))
        other["NUMBA_CACHE_DIR"] = str(args.against_cache or Path(tempfile.gettempdir())
                                       / "emfabric-cli-time-against")
        kinds["against"] = other
    load0 = os.getloadavg()[0]
    t_start = time.perf_counter()
    print(f"`python -m emfabric run SCENARIO --out DIR --quiet`, warm cache, seconds from launch "
          f"to exit ({args.repeat} runs each{', alternating' if len(kinds) > 1 else ''})")
    for scenario in args.scenarios:
        for env in kinds.values():
            one_run(scenario, env)  # warms the cache (compiles once on an empty one)
        walls: dict[str, list[float]] = {k: [] for k in kinds}
        for _ in range(args.repeat):
            for kind, env in kinds.items():
                walls[kind].append(one_run(scenario, env))
        for kind, w in walls.items():
            where = str(HERE) if kind == "this" else str(args.against)
            print(f"  {scenario:<14} {kind:<8} median {statistics.median(w):6.2f}  "
                  f"[{', '.join(f'{x:.2f}' for x in w)}]  ({where})")
    elapsed = time.perf_counter() - t_start
    load1 = os.getloadavg()[0]
    print(f"machine: {os.cpu_count()} cores, load average {load0:.2f} at the start and "
          f"{load1:.2f} at the end ({elapsed:.0f} s); this benchmark keeps about one core busy")


if __name__ == "__main__":
    main()
