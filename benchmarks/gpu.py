"""The force evaluation of section (a) on an NVIDIA GPU (numba.cuda), checked against emfabric.

Two steps, because a GPU machine need not have emfabric's dependencies:

    python benchmarks/gpu.py export runs/gpu-cases --sizes 100 1000
        # here, with emfabric installed: the dented sheet of bench.py (a) at each size, the
        # inputs of one φ-scheme fixed-point iterate and emfabric's outputs of it
        # (fabric_iterate, one thread), compressed (.npz, no pickle): 0.7 MB at 100 × 100,
        # 56 MB at 1000 × 1000 (within the 64 MiB a GPU machine's call can carry)
    python benchmarks/gpu.py run runs/gpu-cases [--json FILE]
        # on the GPU machine (NumPy + numba-cuda): the same iterate in cuda_kernels.py, its
        # outputs compared with emfabric's, then timed

Two timings per size, each the best of --repeat samples of --count evaluations:
- **GPU time**: a spin kernel keeps the GPU busy while all evaluations are queued behind it, so
  the events around them time the kernels back to back, without Python's launch cost;
- **from Python**: the evaluations launched one by one from a Python loop, wall time to the
  last one's end: what a Python-driven time loop would get.
Figures in ns per yarn segment (as (a)) and the compulsory memory traffic's bandwidth.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ARRAYS_IN = ("xk", "x0", "v0", "f0", "alpha_c", "coef", "inv_l02", "mass", "inv_mass", "charge",
             "skip_err", "efield", "bfield", "grav")
ARRAYS_OUT = ("alpha_t", "x1", "v1", "f1", "err_rows")


def export(folder: Path, sizes: list[int]) -> None:
    """Write case_<n>.npz: inputs and emfabric's outputs of one iterate on the dented sheet."""
    import numba

    sys.path.insert(0, str(HERE))
    import bench

    from emfabric import __version__
    from emfabric._kernels.step import fabric_iterate

    numba.set_num_threads(1)
    folder.mkdir(parents=True, exist_ok=True)
    for n in sizes:
        model, integ, s = bench.deformed_sheet(n)
        s2 = s.copy()
        args = bench.iterate_args(integ, s, s2, bench.DT)
        work = integ.work
        work.flag[:] = 0  # no contact candidates: every free node counts in the error sums
        fabric_iterate(*args)
        nd, yr, mt, fd = model.nodes, model.yarns, model.material, model.field
        case = {
            "nx": nd.nx, "ny": nd.ny, "xk": work.xbuf, "x0": s.node_x, "v0": s.node_v,
            "f0": s.node_f, "alpha_c": s.seg_alpha, "coef": yr.stiffness,
            "inv_l02": yr.inv_rest2, "mass": nd.mass, "inv_mass": nd.inv_mass,
            "charge": nd.charge, "skip_err": work.flag.astype(np.uint8),
            "kind": mt.kind, "fung_h": mt.fung_h, "u_crit": mt.critical_stretch,
            "rate": mt.damage_rate, "efield": fd.E, "bfield": fd.B, "region": fd.region,
            "z0": fd.z0, "grav": fd.gravity, "phi": integ.solver.phi, "dt": bench.DT,
            "alpha_t": s2.seg_alpha, "x1": s2.node_x, "v1": s2.node_v, "f1": s2.node_f,
            "err_rows": work.row_sums[:2], "emfabric_version": __version__,
        }
        # smaller files: the iterate starts at x0 (xk = x0, not stored twice) and x1 is stored
        # as x1 − x0 (mostly zeros away from the dent; x0 + (x1 − x0) is x1 within an ulp)
        if np.array_equal(case["xk"], case["x0"]):
            del case["xk"]
        case["x1_minus_x0"] = case.pop("x1") - case["x0"]
        if n > 500:  # within the 64 MiB a GPU machine's call can carry: f1 = f + q v1 × B,
            del case["f1"]  # checked at the smaller sizes
        path = folder / f"case_{n}.npz"
        tmp = path.with_suffix(".tmp.npz")
        np.savez_compressed(tmp, **{k: np.asarray(v) for k, v in case.items()})
        tmp.replace(path)
        print(f"{path}: {n}×{n}, {model.seg_count} segments, {path.stat().st_size / 1e6:.1f} MB")


def _load(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as z:
        case = {k: z[k] for k in z.files}
    case.setdefault("xk", case["x0"])
    case["x1"] = case["x0"] + case.pop("x1_minus_x0")
    return case


def compulsory_bytes(case: dict) -> int:
    """Every input read once, every output written once (as bench.py (a) counts them)."""
    reads = sum(case[k].nbytes for k in ("xk", "x0", "v0", "f0", "alpha_c", "coef", "inv_l02",
                                          "mass", "inv_mass", "charge", "skip_err"))
    writes = case["alpha_t"].nbytes + 3 * case["x1"].nbytes  # x1, v1, f1
    return reads + writes


def run(folder: Path, count: int, repeat: int, out: Path | None) -> None:
    """Check and time cuda_kernels.py on every case of the folder."""
    sys.path.insert(0, str(HERE))
    import cuda_kernels as ck
    import numba
    from numba import cuda
    from numba.core.errors import NumbaPerformanceWarning

    warnings.simplefilter("ignore", NumbaPerformanceWarning)  # a 100×100 sheet is a small grid
    warnings.filterwarnings("ignore", message=".*under-utilization")  # numba-cuda's own class

    try:
        dev = cuda.get_current_device()
        name = dev.name.decode() if isinstance(dev.name, bytes) else str(dev.name)
        cc = list(dev.compute_capability)
    except AttributeError:  # numba's CUDA simulator (NUMBA_ENABLE_CUDASIM=1): checks only
        name, cc = "CUDA simulator", []
    info = {"device": name, "compute_capability": cc, "numba": numba.__version__,
            "numpy": np.__version__, "python": platform.python_version(),
            "count": count, "repeat": repeat, "cases": []}
    print(f"device {info['device']} (compute capability {info['compute_capability']}), "
          f"numba {numba.__version__}, numpy {np.__version__}")
    for path in sorted(folder.glob("case_*.npz"), key=lambda p: int(p.stem.split("_")[1])):
        case = _load(path)
        ev = ck.CudaEvaluation(case)
        ev.evaluate()
        got = ev.results()
        diffs = {k: float(np.max(np.abs(got[k] - case[k])) / max(np.max(np.abs(case[k])), 1e-300))
                 for k in ARRAYS_OUT if k in case}
        worst = max(diffs, key=diffs.get)
        if not cc:  # the simulator checks the arithmetic; its timings mean nothing
            print(f"{int(case['nx'])}×{int(case['ny'])}: vs emfabric: max relative difference "
                  f"{diffs[worst]:.2e} (in {worst}); " + ", ".join(
                      f"{k} {v:.1e}" for k, v in diffs.items()))
            continue
        for _ in range(3):  # warm: module load, first launches
            ev.evaluate()
        ev.synchronize()
        gpu, python = [], []
        start, end = cuda.event(), cuda.event()
        for _ in range(repeat):
            ev.synchronize()
            t0 = time.perf_counter()
            for _ in range(count):
                ev.evaluate()
            ev.synchronize()
            python.append((time.perf_counter() - t0) / count)
            # the spin outlasts the queueing of the evaluations behind it (twice Python's time)
            ck.spin[1, 1](int(2e3 * count * python[-1]) + 1)
            start.record()
            for _ in range(count):
                ev.evaluate()
            end.record()
            end.synchronize()
            gpu.append(cuda.event_elapsed_time(start, end) * 1e-3 / count)
        segs, nbytes = ev.seg_count, compulsory_bytes(case)
        row = {"n": int(case["nx"]), "segments": segs, "max_rel_diff": diffs[worst],
               "worst_array": worst, "gpu_s": min(gpu), "gpu_median_s": float(np.median(gpu)),
               "python_s": min(python), "python_median_s": float(np.median(python)),
               "bytes": nbytes, "emfabric_version": str(case["emfabric_version"])}
        info["cases"].append(row)
        print(f"{row['n']:>5}×{row['n']:<5} {segs:>9} segments | GPU time "
              f"{row['gpu_s'] / segs * 1e9:7.3f} ns/seg {row['gpu_s'] * 1e6:8.2f} µs/eval "
              f"({nbytes / row['gpu_s'] / 1e9:6.0f} GB/s) | from Python "
              f"{row['python_s'] / segs * 1e9:7.3f} ns/seg {row['python_s'] * 1e6:8.2f} µs/eval"
              f" | vs emfabric: max relative difference {diffs[worst]:.2e} (in {worst})")
    if out is not None:
        out.write_text(json.dumps(info, indent=1))


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="export [--sizes N ...]; run [--count N] [--repeat N] "
                                       "[--json FILE]")
    sub = p.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("export", help="write the cases (needs emfabric)")
    e.add_argument("folder", type=Path)
    e.add_argument("--sizes", type=int, nargs="+", default=[100, 1000])
    r = sub.add_parser("run", help="check and time the cases on the GPU (needs numba-cuda)")
    r.add_argument("folder", type=Path)
    r.add_argument("--count", type=int, default=200, help="evaluations per sample")
    r.add_argument("--repeat", type=int, default=7, help="samples (the best is shown)")
    r.add_argument("--json", type=Path, default=None, help="also write the figures here")
    a = p.parse_args(argv)
    if a.cmd == "export":
        export(a.folder, a.sizes)
    else:
        run(a.folder, a.count, a.repeat, a.json)


if __name__ == "__main__":
    main()
