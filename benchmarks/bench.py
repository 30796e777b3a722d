"""emfabric speed suite: ``python benchmarks/bench.py`` prints one table (see benchmarks/README.md).

(a) one force evaluation + node update (``fabric_iterate``) on a deformed 100×100 and 1000×1000
    sheet, in ns per segment, against the same evaluation in NVIDIA Warp on its CPU device;
(b) the paper-field full run, warm, and where its time goes;
(c) start-up: a fresh process up to its first accepted step, with a cold and a warm Numba cache;
(d) memory per node and peak resident memory;
(e) the spin's error at the default settings against a converged run (paper-field by default);
(f) a struck 1000×1000 sheet: time per step, Δt, memory; (g) whole-run cost against the grid.
``--packs`` instead runs (j): packs of 1, 4 and 16 plies of 100×100, time per simulated µs
with and without ply contact, memory per node.
``--schemes`` instead weighs solver settings on paper-field against (e)'s converged run.
``--ladder SCENARIO`` instead runs (l): central differences at courant / 2^k, each run against
the next finer and the finest.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import gc
import importlib.util
import json
import math
import os
import platform
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SCENARIO = "paper-field"
# the realistic state of (a): a smooth dent of the sheet centre, moving, in physical units
BUMP_DEPTH = 0.03  # [m]
BUMP_RADIUS = 0.09  # [m]; yarns outside stay slack (the wave has not reached them yet)
BUMP_SPEED = 150.0  # [m/s] at the centre, along −z like the projectile
DT = 4e-8  # [s], about the step the paper-field run settles at
STARTUP_END_TIME = 2e-6  # [s] of the short runs that time start-up
TARGETS = {"ns_100": 5.0, "warp_speedup": 4.0, "ns_1000": 5.0, "run_wall": 4.0, "start": 3.0}


# --- helpers -------------------------------------------------------------------------------

def say(text: str = "") -> None:
    print(text, flush=True)


def best_and_median(fn, repeats: int, target_s: float = 0.25) -> tuple[float, float]:
    """Seconds per call of fn(count) / count: best and median of `repeats` samples."""
    fn(1)  # the first call may compile: calibrate on the second
    t0 = time.perf_counter()
    fn(1)
    once = time.perf_counter() - t0
    count = max(1, int(target_s / max(once, 1e-7)))
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(count)
        samples.append((time.perf_counter() - t0) / count)
    return min(samples), statistics.median(samples)


def sheet(n: int) -> dict:
    """The overrides of SCENARIO for an n×n sheet. These runs write no files (in memory), so the
    snapshot volume guard (sim/sanity.py: 26.6 GB of snapshots and ParaView files at 1000 × 1000
    over 1.5 ms, above output.size_limit) must not refuse them: ParaView output off, the limit
    raised."""
    return {"fabric.nodes": [n, n], "output.paraview": False, "output.size_limit": 1e13}


def child(mode: str, *args: str, env: dict[str, str] | None = None) -> dict:
    """Run this script's child mode in a fresh interpreter; its last stdout line is JSON."""
    full_env = dict(os.environ, **(env or {}))
    full_env["EMFABRIC_BENCH_LAUNCH"] = repr(time.time())
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", mode,
                          *args], env=full_env, capture_output=True, text=True)
    if out.returncode != 0:
        lines = [re.sub(r"\x1b\[[0-9;]*m", "", x).strip() for x in out.stderr.splitlines()]
        errors = [x for x in lines if "Error" in x] or [x for x in lines if x] or ["no output"]
        raise RuntimeError(f"child '{mode}' failed: {errors[-1][:300]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def cpu_snapshot() -> tuple[float, float, float]:
    """(CPU seconds of the whole machine, of this process and its children, wall time)."""
    try:
        ticks = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:9]]
        busy = (sum(ticks) - ticks[3] - ticks[4]) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError):
        busy = math.nan
    t = os.times()
    return busy, t.user + t.system + t.children_user + t.children_system, time.perf_counter()


def other_cpu(start: tuple[float, float, float]) -> float:
    """Cores other processes kept busy on average since `start` (nan where unknown)."""
    busy, own, wall = cpu_snapshot()
    return max(0.0, (busy - start[0]) - (own - start[1])) / (wall - start[2])


def busy_note(start: tuple[float, float, float]) -> None:
    """Say so when other processes took CPU time during a section."""
    busy = other_cpu(start)
    if busy >= 0.1:
        say(f"    ! other processes used {busy:.2f} cores on average during this section: "
            "its figures may be perturbed")


def machine() -> list[str]:
    import numba

    cpu = platform.processor() or "unknown"
    flags: set[str] = set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
            elif line.startswith("flags"):
                flags = set(line.split(":", 1)[1].split())
    except OSError:
        pass
    simd = " ".join(f for f in ("avx2", "fma", "avx512f") if f in flags) or "-"
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    try:
        import warp

        warp_version = warp.__version__
    except ImportError:
        warp_version = "not installed"
    try:
        tree = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=HERE,
                              capture_output=True, text=True).stdout.strip() or "unknown"
    except OSError:
        tree = "unknown"
    return [
        f"CPU: {cpu} ({simd}), {os.cpu_count()} cores, {usable} usable; source tree {tree}",
        f"Python {platform.python_version()}, numpy {np.__version__}, numba {numba.__version__} "
        f"(NUMBA_NUM_THREADS = {numba.config.NUMBA_NUM_THREADS}), warp-lang {warp_version}",
    ]


# --- (a) one evaluation ------------------------------------------------------------------

def deformed_sheet(n: int, overrides: dict | None = None):
    """A paper-field n×n sheet (no projectile) dented and moving: (model, integrator, state)."""
    from emfabric import load_scenario
    from emfabric.integrators import Integrator
    from emfabric.sim.builder import build_model
    from emfabric.sim.state import initial_state, update_forces

    # no outputs are written: output.paraview off keeps a large sheet within the output guard
    sc = load_scenario(SCENARIO, {"fabric.nodes": [n, n], "projectile.shape": "none",
                                  "output.paraview": False, **(overrides or {})})
    model = build_model(sc)
    # the row-block threaded kernel, whatever the size (the default below 250 × 250 nodes is
    # the serial one): its 1-thread and N-thread rows are the figures (a) has always shown
    import numba

    integ = Integrator(model, threads=numba.config.NUMBA_NUM_THREADS > 1)
    s = initial_state(model)
    rho2 = (s.node_x[0] ** 2 + s.node_x[1] ** 2) / BUMP_RADIUS**2
    shape = np.where(rho2 < 1.0, (1.0 - rho2) ** 2, 0.0) * (model.nodes.inv_mass > 0)
    s.node_x[2] = -BUMP_DEPTH * shape
    s.node_v[2] = -BUMP_SPEED * shape
    update_forces(model, s)  # ψ(t) of the dented state
    return model, integ, s


def stretch(model, x: np.ndarray) -> np.ndarray:
    """Stretch U = L/L0 of every segment at positions x, shape (seg_count,)."""
    a, b = model.yarns.ends[:, 0], model.yarns.ends[:, 1]
    return np.sqrt(np.sum((x[:, b] - x[:, a]) ** 2, axis=0)) / model.yarns.rest_length


def iterate_args(integ, s, s2, dt: float) -> tuple:
    """fabric_iterate's arguments for one iterate from state s into s2, in the integrator's own
    workspace (its layout is the kernel's business): the first iterate of a step at dt."""
    from emfabric._kernels.materials import damage_thresholds

    work = integ.work
    work.xbuf[:] = s.node_x
    # as an attempt does: where the damage law can change α (the kernel skips it elsewhere)
    damage_thresholds(s.seg_alpha, integ.physics.material, integ.physics.yarns.failure_stretch2,
                      work.damage_thr, work.damage_alpha)
    return (integ.physics, work.xbuf, s.arrays, s2.arrays, work, *integ.kernel_buffers,
            s.t + dt, integ.solver.phi, dt)


@functools.cache
def _compiled_repeat():
    """fabric_iterate called `count` times from compiled code (no Python dispatch per call)."""
    from numba import njit

    from emfabric._kernels.step import fabric_iterate

    @njit
    def repeat(count, phys, prev, start, out, work, rowbuf, threads, t1, phi, dt):
        for _ in range(count):
            fabric_iterate(phys, prev, start, out, work, rowbuf, threads, t1, phi, dt)

    return repeat


@functools.cache
def _cd_repeat(kernel):
    """Central differences' force-and-kick row kernel called `count` times from compiled code."""
    from numba import njit

    @njit
    def repeat(count, phys, sin, sout, work, t1, dt, rowbuf):
        for _ in range(count):
            kernel(phys, sin, sout, work, t1, dt, rowbuf)

    return repeat


def _triad_bandwidth(threads: int, repeats: int) -> float:
    """STREAM-triad bandwidth [B/s] (3 arrays of 64 MiB, write-allocate not counted)."""
    import numba
    from numba import njit, prange

    @njit(parallel=True)
    def triad(count, a, b, c):
        for _ in range(count):
            for i in prange(a.size):
                a[i] = b[i] + 0.5 * c[i]

    size = 1 << 23
    a, b, c = np.zeros(size), np.ones(size), np.ones(size)
    numba.set_num_threads(threads)
    best, _ = best_and_median(lambda k: triad(k, a, b, c), repeats)
    return 3 * 8 * size / best


def bench_evaluation(n: int, threads: list[int], repeats: int, use_warp: bool) -> dict:
    """Time one fabric_iterate on the dented n×n sheet, and Warp's version of it."""
    import numba

    from emfabric._kernels.step import fabric_iterate

    model, integ, s = deformed_sheet(n)
    s2 = s.copy()
    args = iterate_args(integ, s, s2, DT)
    xbuf, flag = integ.work.xbuf, integ.work.flag
    err_rows = integ.work.row_sums[:2]  # the error sums Warp's kernel computes
    flag[:] = 0  # no contact candidates: every free node counts in the error measure
    fabric_iterate(*args)
    segs, nodes = model.seg_count, model.node_count
    u = stretch(model, s.node_x)
    res = {"n": n, "segs": segs, "nodes": nodes, "tension": np.mean(u > 1.0),
           "past_crit": np.mean(u > model.material.critical_stretch), "max_u": u.max()}
    # compulsory memory traffic: every input read once, every output written once
    reads = sum(x.nbytes for x in (xbuf, s.node_x, s.node_v, s.node_f, s.seg_alpha, flag,
                                   *(getattr(model.nodes, k) for k in ("mass", "inv_mass",
                                                                       "charge")),
                                   model.yarns.stiffness, model.yarns.inv_rest2))
    writes = sum(x.nbytes for x in (s2.node_x, s2.node_v, s2.node_f, s2.seg_alpha))
    res["bytes_per_seg"] = (reads + writes) / segs

    repeat = _compiled_repeat()
    res["emf"] = {}
    for k in threads:
        numba.set_num_threads(k)
        best, med = best_and_median(lambda c: repeat(c, *args), repeats)
        res["emf"][k] = (best, med)
    # central differences' one evaluation: the force fused with the node's half kick
    from emfabric._kernels.nodes import kick_rows, kick_rows_threads

    integ.work.xbuf[:] = s.node_x
    res["cd"] = {}
    for k in threads:
        numba.set_num_threads(k)
        buf = integ.threads if k > 1 else np.empty(integ.rowbuf.shape if integ.rowbuf
                                                    is not None else integ.threads.shape[1:])
        kern = kick_rows_threads if k > 1 else kick_rows
        cd_args = (model.physics, s.arrays, s2.arrays, integ.work, s.t + DT, DT, buf)
        best, med = best_and_median(lambda c, f=kern, a=cd_args: _cd_repeat(f)(c, *a), repeats)
        res["cd"][k] = (best, med)
    numba.set_num_threads(threads[0])

    def python_calls(count):
        for _ in range(count):
            fabric_iterate(*args)

    res["emf_python"] = best_and_median(python_calls, repeats)

    res["warp"] = None
    if use_warp:
        import warp_kernels as wk

        nd, yr, mt, fd = model.nodes, model.yarns, model.material, model.field
        ev = wk.WarpEvaluation((nd.nx, nd.ny), (nd.mass, nd.inv_mass, nd.charge, yr.stiffness,
                                                yr.inv_rest2),
                               (mt.kind, mt.fung_h, mt.critical_stretch, mt.damage_rate),
                               (fd.E, fd.B, fd.region, fd.z0, fd.gravity), xbuf, s.node_x,
                               s.node_v, s.node_f, s.seg_alpha, flag, integ.solver.phi, DT)
        ev.evaluate()
        theirs = ev.results()
        ours = {"alpha_t": s2.seg_alpha, "x1": s2.node_x, "v1": s2.node_v,
                "f1": s2.node_f, "err_rows": err_rows}
        diffs = {k: float(np.max(np.abs(theirs[k] - v)) / max(np.max(np.abs(v)), 1e-300))
                 for k, v in ours.items()}
        worst = max(diffs, key=diffs.get)
        res["warp_diff"] = (worst, diffs[worst])

        def warp_calls(count):
            for _ in range(count):
                ev.evaluate()

        res["warp"] = best_and_median(warp_calls, repeats)
    return res


def print_gpu(info: dict, rows: list[dict]) -> None:
    """(k): the evaluation of (a) on a GPU (gpu.py's JSON), beside this run's (a)."""
    say(f"(k) the same evaluation on a GPU with numba.cuda (benchmarks/gpu.py, "
        f"cuda_kernels.py): {info['device']}, numba {info['numba']}, best of {info['repeat']} "
        f"samples of {info['count']} evaluations")
    say(f"    {'grid':>11} | {'GPU ns/seg':>10} {'µs/eval':>8} {'GB/s':>6} | "
        f"{'from Python µs/eval':>19} | {'(a) best CPU µs/eval':>20} {'÷ GPU':>7} | check")
    cpu = {r["n"]: min(v[0] for v in r["emf"].values()) for r in rows}
    for c in info["cases"]:
        n, segs = c["n"], c["segments"]
        here = cpu.get(n)
        ratio = f"{here / c['gpu_s']:6.0f}×" if here else "    n/a"
        here_s = f"{here * 1e6:20.1f}" if here else f"{'n/a':>20}"
        say(f"    {n:>5}×{n:<5} | {c['gpu_s'] / segs * 1e9:10.3f} {c['gpu_s'] * 1e6:8.2f} "
            f"{c['bytes'] / c['gpu_s'] / 1e9:6.0f} | {c['python_s'] * 1e6:19.1f} | {here_s} "
            f"{ratio} | max rel. diff {c['max_rel_diff']:.1e} ({c['worst_array']})")
    say("    GPU time: the kernels back to back (a spin kernel holds the GPU while the "
        "evaluations queue); from Python: launched one by one from a Python loop. The CPU "
        "column is this run's (a) on this machine, the GPU's a run on another.")
    say()


def print_evaluations(rows: list[dict], threads: list[int], warp_note: str,
                      bandwidth: dict[int, float]) -> None:
    say("(a) one force evaluation + node update on a dented, moving sheet: the φ-scheme's "
        "fabric_iterate, and central differences' kick_rows (force, magnetic rotation, kick, "
        "and the history record's fabric diagnostics)")
    say(f"    state: reference grid + centre dent {BUMP_DEPTH * 1e3:g} mm deep over r < "
        f"{BUMP_RADIUS * 1e3:g} mm, v_z up to {BUMP_SPEED:g} m/s, Δt = {DT:g} s")
    say("    times: best (median) of the samples; emfabric called in a compiled loop")
    head = (f"    {'grid':>9} {'segments':>9} {'thr':>3} | {'emfabric ns/seg':>16} "
            f"{'µs/eval':>8} | {'Warp CPU ns/seg':>16} {'µs/eval':>8} | {'Warp ÷ emfabric':>15}"
            f" | {'central diff. ns/seg':>20}")
    say(head)
    say("    " + "-" * (len(head) - 4))
    for r in rows:
        for k in threads:
            best, med = r["emf"][k]
            warp = r["warp"]
            if warp is None:
                wcol, ratio = f"{'n/a':>16} {'':>8}", f"{'n/a':>15}"
            else:
                wcol = (f"{warp[0] / r['segs'] * 1e9:7.2f} ({warp[1] / r['segs'] * 1e9:6.2f})"
                        f" {warp[0] * 1e6:8.1f}")
                ratio = f"{warp[0] / best:14.2f}×"
            cb, cm = r["cd"][k]
            say(f"    {r['n']:>4}×{r['n']:<4} {r['segs']:>9} {k:>3} | "
                f"{best / r['segs'] * 1e9:7.2f} ({med / r['segs'] * 1e9:6.2f}) "
                f"{best * 1e6:8.1f} | {wcol} | {ratio} | "
                f"{cb / r['segs'] * 1e9:9.2f} ({cm / r['segs'] * 1e9:6.2f})")
    if any(r["warp"] for r in rows) and len(threads) > 1:
        say("    Warp's CPU device runs a launch on one thread: the same figure in both rows.")
    if warp_note:
        say(f"    {warp_note}")
    for r in rows:
        say(f"    {r['n']}×{r['n']}: {100 * r['tension']:.0f}% of yarns in tension, "
            f"{100 * r['past_crit']:.0f}% past U_crit, max stretch {r['max_u']:.3f}")
        if r.get("warp_diff"):
            name, d = r["warp_diff"]
            say(f"      Warp vs emfabric: max relative difference {d:.2e} (in {name})"
                + ("" if d <= 1e-12 else "  <- above 1e-12: CHECK"))
        say(f"      fabric_iterate called from Python (dispatch included): "
            f"{r['emf_python'][0] * 1e6:.1f} µs/eval")
        line = (f"      compulsory traffic {r['bytes_per_seg']:.0f} B/segment "
                f"({r['bytes_per_seg'] * r['segs'] / 2**20:.0f} MiB per evaluation)")
        if bandwidth:
            floors = ", ".join(f"{r['bytes_per_seg'] / bw * 1e9:.2f} ({k} thr)"
                               for k, bw in sorted(bandwidth.items()))
            line += f"; from DRAM at triad speed ≥ {floors} ns/seg"
        say(line)
    if bandwidth:
        say("    STREAM triad: " + ", ".join(f"{bw / 1e9:.1f} GB/s on {k} thread(s)"
                                             for k, bw in sorted(bandwidth.items())))


# --- (b) full run --------------------------------------------------------------------------

def _step_loop(sc, steps: int, samples: list | None):
    """The run's steps as a bare Integrator.step loop (no recording): (seconds, model, integ);
    appends 10 evenly spaced (state, candidate flags) pairs to `samples` when given one."""
    from emfabric.integrators import make_integrator
    from emfabric.sim.builder import build_model
    from emfabric.sim.state import initial_state

    t_end = sc.solver.end_time
    keep_at = set(np.linspace(max(1, steps // 10), steps, 10, dtype=int).tolist())
    t0 = time.perf_counter()
    model = build_model(sc)
    integ = make_integrator(model)
    s_in = initial_state(model)
    s_out = s_in.copy()
    flag = integ.work.flag
    while s_in.steps < steps:
        integ.step(s_in, s_out, dt_limit=t_end - s_in.t)
        s_in, s_out = s_out, s_in
        if samples is not None and s_in.steps in keep_at:
            samples.append((s_in.copy(), flag.copy()))
    return time.perf_counter() - t0, model, integ


def bench_full_run(runs: int, repeats: int, base: dict) -> dict:
    from emfabric import load_scenario
    from emfabric import run as run_scenario

    sc = load_scenario(SCENARIO, base)
    run_scenario(load_scenario(SCENARIO, {**base, "solver.end_time": STARTUP_END_TIME}))
    # runs and bare step loops alternate, so that a drift of the machine's speed hits both
    summaries, loops, samples = [], [], []
    for i in range(runs):
        gc.collect()
        summaries.append(run_scenario(sc).summary)
        gc.collect()
        loop, model, integ = _step_loop(sc, summaries[0]["steps"], samples if i == 0 else None)
        loops.append(loop)
    # one evaluation timed on the states sampled along the run (contact candidates as that
    # step left them): the run's own mix of slack, stretched and damaging yarns
    per_eval, tension, past = [], [], []
    flag = integ.work.flag
    for st, fl in samples:
        flag[:] = fl
        if integ.name == "central-difference":
            from emfabric._kernels.nodes import kick_rows, kick_rows_threads

            rowbuf, threads = integ.kernel_buffers
            integ.work.xbuf[:] = st.node_x
            kern, buf = (kick_rows, rowbuf) if rowbuf is not None else (kick_rows_threads,
                                                                        threads)
            args = (model.physics, st.arrays, st.copy().arrays, integ.work, st.t + st.dt,
                    st.dt, buf)
            per_eval.append(best_and_median(lambda c, a=args, f=kern: _cd_repeat(f)(c, *a),
                                            max(3, repeats // 2), target_s=0.1)[0])
        else:
            args = iterate_args(integ, st, st.copy(), st.dt)
            per_eval.append(best_and_median(lambda c, a=args: _compiled_repeat()(c, *a),
                                            max(3, repeats // 2), target_s=0.1)[0])
        u = stretch(model, st.node_x)
        tension.append(np.mean(u > 1.0))
        past.append(np.mean(u > model.material.critical_stretch))
    return {"summaries": summaries, "loops": loops, "loop_steps": summaries[0]["steps"],
            "loop_evals": summaries[0]["force_evaluations"], "segs": model.seg_count,
            "eval": float(np.mean(per_eval)), "eval_range": (min(per_eval), max(per_eval)),
            "kernel": "kick_rows" if integ.name == "central-difference" else "fabric_iterate",
            "tension": (min(tension), max(tension)), "past_crit": (min(past), max(past)),
            "samples": len(samples)}


def print_full_run(fr: dict) -> None:
    s = fr["summaries"][0]
    walls = [x["wall_time_s"] for x in fr["summaries"]]
    best, med = min(walls), statistics.median(walls)
    ev, steps = s["force_evaluations"], s["steps"]
    say(f"(b) full '{SCENARIO}' run (100×100 sheet, sphere, B field; JIT warm), "
        f"best (median) of {len(walls)}")
    say(f"    emfabric.run wall time        {best:8.2f} s ({med:.2f} s) to t = "
        f"{s['time_s'] * 1e6:.0f} µs ({s['end_reason']})")
    say(f"    accepted / rejected steps     {steps:8d} / {s['rejected_steps']}")
    say(f"    force evaluations             {ev:8d} (mean iterations {s['mean_iterations']:.2f})")
    say(f"    wall time per evaluation      {best / ev * 1e6:8.0f} µs "
        f"({best / ev / fr['segs'] * 1e9:.1f} ns/segment); per step {best / steps * 1e6:.0f} µs")
    lb = min(fr["loops"])
    say(f"    bare Integrator.step loop     {lb:8.2f} s ({statistics.median(fr['loops']):.2f} s; "
        f"{fr['loop_steps']} steps, {fr['loop_evals']} evaluations, no recording)")
    say(f"    recording + run loop          {best - lb:8.2f} s ({(best - lb) / steps * 1e6:.0f} "
        "µs/step)")
    kern = ev * fr["eval"]
    say(f"    evaluation kernel share       {kern:8.2f} s = {100 * kern / best:.0f}% "
        f"(evaluations × {fr['eval'] * 1e6:.0f} µs of {fr['kernel']}, the mean over "
        f"{fr['samples']} states")
    lo, hi = fr["eval_range"]
    say(f"{'':36}along the run: {lo * 1e6:.0f}–{hi * 1e6:.0f} µs; "
        f"{100 * fr['tension'][0]:.0f}–{100 * fr['tension'][1]:.0f}% of yarns in tension, "
        f"{100 * fr['past_crit'][0]:.0f}–{100 * fr['past_crit'][1]:.0f}% past U_crit)")
    say(f"    rest of Integrator.step       {lb - kern:8.2f} s "
        f"({(lb - kern) / steps * 1e6:.0f} µs/step: contact, body, energy, step control)")


# --- (c) start-up ------------------------------------------------------------------------

def child_startup() -> dict:
    """In a fresh interpreter: import, then a short paper-field run twice."""
    launch = float(os.environ["EMFABRIC_BENCH_LAUNCH"])
    import emfabric.cli  # noqa: F401  (the command line's own imports: typer, rich)
    from emfabric import load_scenario
    from emfabric import run as run_scenario

    t_import = time.time() - launch
    first: list[float] = []

    def progress(state, info) -> None:
        if not first:
            first.append(time.time() - launch)

    sc = load_scenario(SCENARIO, {"solver.end_time": STARTUP_END_TIME})
    t0 = time.perf_counter()
    run_scenario(sc, progress=progress)
    run1 = time.perf_counter() - t0
    t0 = time.perf_counter()
    run_scenario(sc)
    run2 = time.perf_counter() - t0
    return {"import": t_import, "first_step": first[0], "run1": run1, "run2": run2}


def bench_startup(cold: bool) -> dict:
    res = {}
    if cold:
        with tempfile.TemporaryDirectory() as cache:
            res["cold"] = child("startup", env={"NUMBA_CACHE_DIR": cache})
    warm = [child("startup") for _ in range(3)]  # the first may refresh a stale cache
    res["warm"] = min(warm[1:], key=lambda r: r["first_step"])
    with tempfile.TemporaryDirectory() as out:
        cmd = [sys.executable, "-m", "emfabric", "run", SCENARIO, "--set",
               f"solver.end_time={STARTUP_END_TIME}", "--quiet", "--force", "--out", out]
        walls = []
        for _ in range(3):
            t0 = time.perf_counter()
            out = subprocess.run(cmd, capture_output=True, text=True)
            walls.append(time.perf_counter() - t0)
            if out.returncode != 0:
                raise RuntimeError(f"`{' '.join(cmd[1:4])}` failed: {out.stderr.strip()[-200:]}")
    res["cli"] = min(walls)
    return res


def print_startup(st: dict) -> None:
    say(f"(c) start-up: fresh process, '{SCENARIO}' with solver.end_time = "
        f"{STARTUP_END_TIME:g} s (times from process launch)")
    say(f"    {'Numba cache':<12} {'import s':>9} {'first step s':>13} {'1st run s':>10} "
        f"{'2nd run s':>10} {'JIT load/compile s':>19}")
    for name in ("cold", "warm"):
        if name in st:
            r = st[name]
            say(f"    {name:<12} {r['import']:9.2f} {r['first_step']:13.2f} {r['run1']:10.2f} "
                f"{r['run2']:10.2f} {r['run1'] - r['run2']:19.2f}")
    say(f"    `python -m emfabric run {SCENARIO} --set solver.end_time={STARTUP_END_TIME:g} "
        f"--quiet` (warm cache, writes its files): {st['cli']:.2f} s end to end")


# --- (d) memory ---------------------------------------------------------------------------

def _array_bytes(obj, seen: set) -> int:
    """Bytes of the numpy arrays in obj (arrays, tuples, lists), each buffer counted once."""
    if isinstance(obj, np.ndarray):
        key = (obj.__array_interface__["data"][0], obj.nbytes)
        if key in seen:
            return 0
        seen.add(key)
        return obj.nbytes
    if isinstance(obj, tuple | list):
        return sum(_array_bytes(o, seen) for o in obj)
    return 0


def peak_rss() -> int:
    """This process's peak resident memory [B]: VmHWM (reset by exec), else getrusage."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def child_memory(n: int) -> dict:
    """In a fresh interpreter: build the n×n paper-field model, integrator and two states."""
    from emfabric import load_scenario
    from emfabric.integrators import make_integrator
    from emfabric.sim.builder import build_model
    from emfabric.sim.state import initial_state

    rss0 = peak_rss()
    model = build_model(load_scenario(SCENARIO, sheet(n)))
    integ = make_integrator(model)
    s_in = initial_state(model)
    s_out = s_in.copy()
    seen: set = set()
    fields = dataclasses.fields
    parts = {
        "model": sum(_array_bytes(getattr(model, f.name), seen) for f in fields(model)),
        "states": sum(_array_bytes(getattr(st, f.name), seen) for st in (s_in, s_out)
                      for f in fields(st)),
        "integrator": sum(_array_bytes(v, seen) for k, v in vars(integ).items()
                          if k != "model"),
    }
    rss = peak_rss()
    return {"nodes": model.node_count, **parts, "rss": rss, "rss_import": rss0}


def print_memory(rows: list[dict]) -> None:
    say("(d) memory: bytes of the arrays of Model + 2 States (a run's two buffers) + Integrator "
        "workspace, per node")
    say(f"    {'grid':>9} {'Model':>7} {'States':>7} {'Integ.':>7} {'total B/node':>13} "
        f"{'arrays MiB':>11} {'peak RSS MiB':>13} {'RSS after imports':>18}")
    for r in rows:
        n = r["nodes"]
        tot = r["model"] + r["states"] + r["integrator"]
        side = int(round(n**0.5))
        say(f"    {side:>4}×{side:<4} {r['model'] / n:7.0f} {r['states'] / n:7.0f} "
            f"{r['integrator'] / n:7.0f} {tot / n:13.0f} {tot / 2**20:11.1f} "
            f"{r['rss'] / 2**20:13.0f} {r['rss_import'] / 2**20:18.0f}")


# --- schemes ------------------------------------------------------------------------------

LEVERS = [
    ("default", {}),
    ("predictor = explicit", {"solver.predictor": "explicit"}),
    ("scheme = anderson", {"solver.scheme": "anderson"}),
    ("target_iterations = 4", {"solver.target_iterations": 4}),
    ("target_iterations = 8", {"solver.target_iterations": 8}),
    ("tolerance = 1e-5", {"solver.tolerance": 1e-5}),
    ("safety = 1 (the paper's controller)", {"solver.safety": 1.0}),
    ("placement = closest-point (paper)", {"contact.placement": "closest-point"}),
    ("closest-point, dt_max = 2e-8", {"contact.placement": "closest-point",
                                      "solver.dt_max": 2e-8}),
]
"""The solver settings --schemes weighs: each changes one thing from the defaults."""


def bench_schemes(ref_dt: float, cache: Path | None) -> None:
    """paper-field with each of LEVERS: cost, and error against the converged run of (e)."""
    from emfabric import load_scenario
    from emfabric import run as run_scenario

    run_scenario(load_scenario(SCENARIO, {"solver.end_time": STARTUP_END_TIME}))
    ref, _ = _history_run(SCENARIO, {"solver.dt_max": ref_dt, **REFERENCE}, cache)
    say(f"Solver settings on '{SCENARIO}', each against the converged run of (e) (tolerance "
        f"{REFERENCE_TOL:g}, dt_max {ref_dt:g} s): ω_x error over the contact phase (fraction "
        "of its peak) and at its end")
    say(f"    {'settings':<42} {'wall s':>7} {'steps':>6} {'rej.':>5} {'evals':>7} "
        f"{'µs/eval':>8} {'mean Δt s':>10} {'ω(t) error':>11} {'exit error':>11}")
    for name, overrides in LEVERS:
        gc.collect()  # start each run from the same small heap
        start = cpu_snapshot()
        try:
            run, s = _history_run(SCENARIO, overrides, None)
        except Exception as err:  # noqa: BLE001 - a setting that fails is a result too
            say(f"    {name:<42} failed: {type(err).__name__}: {str(err)[:120]}")
            continue
        busy = other_cpu(start)
        e = spin_error(run, ref, (0,))
        ev = s["force_evaluations"]
        say(f"    {name:<42} {s['wall_time_s']:7.2f} {s['steps']:6d} {s['rejected_steps']:5d} "
            f"{ev:7d} {s['wall_time_s'] / ev * 1e6:8.0f} {s['time_s'] / s['steps']:10.3g} "
            f"{100 * e['track']:10.2f}% {100 * e['exit']:10.2f}%"
            + ("" if busy < 0.1 else f"  ! machine busy ({busy:.2f} other cores)"))


# --- (e) accuracy at the default settings --------------------------------------------------

ACCURACY = {"paper-field": (0,), "paper-spin": (1, 2), "ogive-field": (0,)}
"""Scenarios of (e) and the components of ω compared (the field-induced ones)."""
REFERENCE_TOL = 1e-9
REFERENCE = {"solver.tolerance": REFERENCE_TOL, "solver.predictor": "explicit"}
"""Settings of the converged runs besides dt_max (the explicit predictor: fewer iterations,
the same solution to the tolerance)."""
TARGET_TRACK = 0.02  # ω(t) within this fraction of its peak over the contact phase
TARGET_EXIT = 0.03  # ω when contact ends within this fraction of |ω| then


def _history_run(name: str, overrides: dict, cache: Path | None) -> tuple[dict, dict]:
    """(time, angular_velocity, contact_nodes as arrays; summary) of one run, from `cache`
    when a run of the same scenario text and emfabric version is stored there."""
    import hashlib

    import emfabric
    from emfabric import load_scenario
    from emfabric import run as run_scenario

    sc = load_scenario(name, overrides)
    key = hashlib.sha256((emfabric.__version__ + sc.to_toml()).encode()).hexdigest()[:16]
    path = cache / f"{name}-{key}.json" if cache is not None else None
    if path is not None and path.exists():
        stored = json.loads(path.read_text())
        return {k: np.array(v) for k, v in stored["history"].items()}, stored["summary"]
    res = run_scenario(sc)
    h = res.history
    hist = {"time": h["time"].values, "omega": h["angular_velocity"].values,
            "contacts": h["contact_nodes"].values}
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps({"history": {k: v.tolist() for k, v in hist.items()},
                                   "summary": res.summary}))
        tmp.replace(path)
    return hist, res.summary


def spin_error(run: dict, ref: dict, comps: tuple[int, ...]) -> dict:
    """How far run's ω is from ref's over ref's contact phase (first to last step with a node
    in contact, up to the end both runs reach): the largest |Δω_c| as a fraction of the
    peak |ω_c| of ref there, worst over the components `comps`; and at the end of contact,
    |Δω| (all three components) as a fraction of |ω| of ref then."""
    t_r, w_r, n_r = ref["time"], ref["omega"], ref["contacts"]
    touching = np.nonzero(n_r > 0)[0]
    t0, t1 = float(t_r[touching[0]]), float(t_r[touching[-1]])
    t1 = min(t1, float(run["time"][-1]))
    t = run["time"]
    m = (t >= t0) & (t <= t1)
    track = 0.0
    for c in comps:
        mr = (t_r >= t0) & (t_r <= t1)
        peak = float(np.abs(w_r[mr, c]).max())
        err = np.abs(run["omega"][m, c] - np.interp(t[m], t_r, w_r[:, c]))
        track = max(track, float(err.max()) / peak)
    w_end = np.array([np.interp(t1, t, run["omega"][:, c]) for c in range(3)])
    w_ref = np.array([np.interp(t1, t_r, w_r[:, c]) for c in range(3)])
    return {"track": track, "exit": float(np.linalg.norm(w_end - w_ref) / np.linalg.norm(w_ref)),
            "t0": t0, "t1": t1, "w_end": w_end, "w_ref": w_ref}


def bench_accuracy(names: list[str], ref_dt: float, cache: Path | None) -> list[dict]:
    """Each scenario at its defaults against a converged run: tolerance 1e-9 and
    dt_max = ref_dt, checked by the same at ref_dt / 2."""
    out = []
    for name in names:
        gc.collect()
        start = cpu_snapshot()
        run, summary = _history_run(name, {}, None)
        busy = other_cpu(start)
        ref, ref_summary = _history_run(name, {"solver.dt_max": ref_dt, **REFERENCE}, cache)
        chk, _ = _history_run(name, {"solver.dt_max": ref_dt / 2, **REFERENCE}, cache)
        comps = ACCURACY.get(name, (0, 1, 2))
        out.append({"name": name, "comps": comps, "summary": summary, "busy": busy,
                    "ref_summary": ref_summary, "default": spin_error(run, ref, comps),
                    "check": spin_error(ref, chk, comps)})
    return out


def print_accuracy(rows: list[dict], ref_dt: float) -> None:
    say(f"(e) accuracy at the default settings: ω against a converged run (tolerance "
        f"{REFERENCE_TOL:g}, dt_max {ref_dt:g} s), itself checked at dt_max {ref_dt / 2:g} s")
    say("    over the reference's contact phase: largest |Δω| of the components named, as a "
        "fraction of their peak; at its end, |Δω| / |ω|")
    say(f"    {'scenario':<13} {'ω':<8} {'wall s':>7} {'steps':>6} {'evals':>7} "
        f"{'ω(t) error':>11} {'exit error':>11} {'exit ω, default → converged (rad/s)':>44}"
        f" {'ref vs check':>17}")
    names = "xyz"
    for r in rows:
        s, d, c = r["summary"], r["default"], r["check"]
        comps = ",".join("ω_" + names[k] for k in r["comps"])
        we, wr = d["w_end"], d["w_ref"]
        ends = (f"({we[0]:.0f}, {we[1]:.0f}, {we[2]:.0f}) → "
                f"({wr[0]:.0f}, {wr[1]:.0f}, {wr[2]:.0f})")
        say(f"    {r['name']:<13} {comps:<8} {s['wall_time_s']:7.2f} {s['steps']:6d} "
            f"{s['force_evaluations']:7d} {100 * d['track']:10.2f}% {100 * d['exit']:10.2f}% "
            f"{ends:>44} {100 * c['track']:7.2f}% {100 * c['exit']:7.2f}%"
            + ("" if r["busy"] < 0.1 else f"  ! machine busy ({r['busy']:.2f} other cores)"))
    phases = [f"{r['name']} {r['default']['t0'] * 1e6:.0f}–{r['default']['t1'] * 1e6:.0f} µs"
              for r in rows]
    say(f"    contact phase: {', '.join(phases)}")


# --- (h) both schemes side by side ---------------------------------------------------------

SIDE_BY_SIDE = {"paper-field": ((0,), 0.02, 0.03), "paper-spin": ((1, 2), 0.02, None),
                "ogive-field": ((0,), 0.03, 0.05)}
"""Scenarios of (h): the components of ω compared and the targets (largest |Δω(t)| over the
contact phase as a fraction of the peak; |Δω| / |ω| when contact ends; None: no target)."""
LOADED_END = {100: 100e-6, 200: 30e-6, 400: 10e-6, 1000: 3e-6}
"""(i)'s simulated time per grid [s] (from the start: the sphere reaches the sheet at once)."""
FINE = {"ogive-field": 16}
"""(h)'s converged run: central differences at courant / FINE (4 where not named), checked at
courant / (2 FINE). ogive-field needs 16: down to courant / 4 its segment contacts stick where
the converged run's slide (docs/theory.md §5.2; `--ladder ogive-field`)."""


def bench_side_by_side(names: list[str], cache: Path | None,
                       courants: tuple[float, ...] = ()) -> list[dict]:
    """Each scenario run by the φ-scheme (its defaults) and by central differences (the default
    courant, and each of `courants` too), against central differences at courant / FINE,
    itself checked at half that."""
    from emfabric import load_scenario

    out = []
    for name in names:
        comps = SIDE_BY_SIDE.get(name, ((0, 1, 2), None, None))[0]
        courant = load_scenario(name, {"solver.integrator": "central-difference"}).solver.courant
        k = FINE.get(name, 4)
        fine = {"solver.integrator": "central-difference", "solver.courant": courant / k}
        ref, ref_summary = _history_run(name, fine, cache)
        chk, _ = _history_run(name, {**fine, "solver.courant": courant / (2 * k)}, cache)
        row = {"name": name, "comps": comps, "courant": courant, "fine": k,
               "ref_summary": ref_summary,
               "check": spin_error(ref, chk, comps), "schemes": {}}
        settings = [("phi", {"solver.integrator": "phi"}),
                    ("central-difference", {"solver.integrator": "central-difference"})]
        settings += [(f"central-difference {c:g}", {"solver.integrator": "central-difference",
                                                    "solver.courant": c}) for c in courants]
        for scheme, over in settings:
            gc.collect()
            start = cpu_snapshot()
            run, summary = _history_run(name, over, None)
            row["schemes"][scheme] = {"summary": summary, "busy": other_cpu(start),
                                      "error": spin_error(run, ref, comps)}
        out.append(row)
    return out


def print_side_by_side(rows: list[dict]) -> None:
    say("(h) both schemes, warm, one thread, against central differences at courant / FINE "
        "(checked at courant / 2 FINE); ω error over the contact phase as a fraction of "
        "the peak of the components named, and |Δω|/|ω| when contact ends")
    say(f"    {'scenario':<12} {'ω':<9} {'scheme':<20} {'wall s':>7} {'steps':>7} {'evals':>7} "
        f"{'ω(t) error':>11} {'exit error':>11}   target")
    names = "xyz"
    for r in rows:
        comps = ",".join("ω_" + names[k] for k in r["comps"])
        _c, track_t, exit_t = SIDE_BY_SIDE.get(r["name"], (None, None, None))
        evals = {}
        for scheme, x in r["schemes"].items():
            s, e = x["summary"], x["error"]
            evals[scheme] = s["force_evaluations"]
            label = scheme if scheme == "phi" else (
                f"central-diff. {r['courant']:g}" if scheme == "central-difference"
                else "central-diff. " + scheme.split()[-1])
            ok = ""
            if scheme != "phi" and track_t is not None:
                good = e["track"] <= track_t and (exit_t is None or e["exit"] <= exit_t)
                ok = (f"{100 * track_t:.0f}%" + (f" / {100 * exit_t:.0f}%" if exit_t else "")
                      + ("  met" if good else "  MISSED"))
            say(f"    {r['name']:<12} {comps:<9} {label:<20} {s['wall_time_s']:7.2f} "
                f"{s['steps']:7d} {s['force_evaluations']:7d} {100 * e['track']:10.2f}% "
                f"{100 * e['exit']:10.2f}%   {ok}"
                + ("" if x["busy"] < 0.1 else f"  ! machine busy ({x['busy']:.2f} other cores)"))
        c = r["check"]
        ratio = evals["phi"] / max(evals["central-difference"], 1)
        walls = {k: x["summary"]["wall_time_s"] for k, x in r["schemes"].items()}
        say(f"    {'':<12} {'':<9} converged run (courant / {r['fine']}) vs its half-step "
            "check: "
            f"{100 * c['track']:.2f}% / {100 * c['exit']:.2f}%; φ ÷ central differences: "
            f"{ratio:.1f}× the evaluations, {walls['phi'] / walls['central-difference']:.1f}× "
            "the wall time")


# --- (l) a convergence ladder -----------------------------------------------------------------

LADDER_TIMES = (50e-6, 100e-6, 200e-6, 300e-6, 400e-6, 600e-6)
"""(l): the times at which the ladder prints ω [s]."""


def bench_ladder(name: str, levels: int, cache: Path | None) -> dict:
    """`name` by central differences at its courant / 2**k, k = 0 … levels − 1: each run's ω
    against the next finer run's and against the finest (spin_error's measures, over the
    contact phase of the run compared with; the components of SIDE_BY_SIDE, else all
    three). Shows
    whether (h)'s converged run is converged and at what order: a first-order error halves
    from one rung to the next."""
    from emfabric import load_scenario

    comps = SIDE_BY_SIDE.get(name, ((0, 1, 2), None, None))[0]
    courant = load_scenario(name, {"solver.integrator": "central-difference"}).solver.courant
    rungs = []
    for k in range(levels):
        c = courant / 2 ** k
        gc.collect()
        start = cpu_snapshot()
        hist, summary = _history_run(name, {"solver.integrator": "central-difference",
                                            "solver.courant": c}, cache)
        rungs.append({"courant": c, "history": hist, "summary": summary,
                      "busy": other_cpu(start)})
    finest = rungs[-1]["history"]
    for i, r in enumerate(rungs):
        r["next"] = (spin_error(r["history"], rungs[i + 1]["history"], comps)
                     if i + 1 < len(rungs) else None)
        r["finest"] = spin_error(r["history"], finest, comps) if i + 1 < len(rungs) else None
    return {"name": name, "comps": comps, "rungs": rungs}


def print_ladder(out: dict) -> None:
    names = "xyz"
    comps = ",".join("ω_" + names[k] for k in out["comps"])
    rungs = out["rungs"]
    say(f"(l) convergence ladder of {out['name']}: central differences at courant / 2^k "
        "(residual speed and energy absorbed at the run's end); "
        f"{comps} error over the contact phase as a fraction of the peak, and "
        "|Δω|/|ω| when contact ends, against the next rung and against the finest")
    say(f"    {'courant':>9} {'steps':>8} {'wall s':>8} {'speed m/s':>10} {'absorbed J':>11} "
        f"{'vs next':>17} {'vs finest':>17}   "
        + " ".join(f"ω_{names[out['comps'][0]]}({t * 1e6:.0f} µs)".rjust(14)
                   for t in LADDER_TIMES))
    for r in rungs:
        h, s = r["history"], r["summary"]
        cols = []
        for key in ("next", "finest"):
            e = r[key]
            cols.append("" if e is None else
                        f"{100 * e['track']:6.2f}% / {100 * e['exit']:6.2f}%")
        w = [np.interp(t, h["time"], h["omega"][:, out["comps"][0]]) if t <= h["time"][-1]
             else math.nan for t in LADDER_TIMES]
        say(f"    {r['courant']:9.5g} {s['steps']:8d} {s['wall_time_s']:8.1f} "
            f"{s.get('residual_speed_m_s', math.nan):10.1f} "
            f"{s.get('energy_absorbed_J', math.nan):11.1f} {cols[0]:>17} "
            f"{cols[1]:>17}   " + " ".join(f"{x:14.1f}" for x in w)
            + ("" if r["busy"] < 0.1 else f"  ! machine busy ({r['busy']:.2f} other cores)"))


# --- (i) a loaded machine ------------------------------------------------------------------

def _busy() -> None:
    """Spin one core (a busy neighbour of (i)'s runs) until killed."""
    x = 0
    while True:
        x += 1


def child_threads(n: int, end_time: float, threads: int) -> dict:
    """In a fresh interpreter: paper-field on an n×n sheet to end_time, warm (a first short run
    compiles), with `threads` Numba threads (0: the default, chosen at run time)."""
    from emfabric import load_scenario
    from emfabric import run as run_scenario

    over = {"fabric.nodes": [n, n]}
    k = None if threads == 0 else threads
    run_scenario(load_scenario(SCENARIO, {**over, "solver.end_time": 2e-7}), threads=k)
    t0 = time.perf_counter()
    res = run_scenario(load_scenario(SCENARIO, {**over, "solver.end_time": end_time}), threads=k)
    return {"wall": time.perf_counter() - t0, "steps": res.summary["steps"]}


def bench_loaded(cases: list[tuple[int, float]], busy: int) -> list[dict]:
    """Each case (n, end time) with the default threads and with one, idle and beside `busy`
    processes that spin."""
    import multiprocessing as mp

    rows = []
    for n, end in cases:
        row = {"n": n, "end": end}
        for label in ("idle", "loaded"):
            procs = []
            if label == "loaded":
                procs = [mp.get_context("spawn").Process(target=_busy, daemon=True)
                         for _ in range(busy)]
                for pr in procs:
                    pr.start()
            try:
                for k in (0, 1):
                    row[(label, k)] = child("threads", str(n), repr(end), str(k))
            finally:
                for pr in procs:
                    pr.kill()
        rows.append(row)
    return rows


def print_loaded(rows: list[dict], busy: int) -> None:
    import numba

    say(f"(i) threads on an idle machine and beside {busy} busy processes: paper-field, warm, "
        f"default threads (up to {numba.config.NUMBA_NUM_THREADS}, chosen at run time) against "
        "one thread")
    say(f"    {'grid':>9} {'to µs':>6} {'steps':>6} | {'idle default':>12} {'idle 1 thr':>10} "
        f"{'ratio':>6} | {'loaded default':>14} {'loaded 1 thr':>12} {'ratio':>6}")
    for r in rows:
        i0, i1, l0, l1 = (r[("idle", 0)]["wall"], r[("idle", 1)]["wall"],
                          r[("loaded", 0)]["wall"], r[("loaded", 1)]["wall"])
        say(f"    {r['n']:>4}×{r['n']:<4} {r['end'] * 1e6:6.0f} {r[('idle', 0)]['steps']:6d} | "
            f"{i0:10.2f} s {i1:8.2f} s {i0 / i1:5.2f}× | {l0:12.2f} s {l1:10.2f} s "
            f"{l0 / l1:5.2f}×")
    say("    target: default ≤ 1.1× one thread, loaded")


# --- (f) a large struck sheet, and the cost of a run against the grid ---------------------

# --- (j) packs of plies ----------------------------------------------------------------------

PACK_PLIES = (1, 4, 16)
PACK_END = 20e-6  # [s]: 19.6 µs of contact (the sphere touches at 0.4 µs)


def child_pack(plies: int, end_time: float) -> dict:
    """In a fresh interpreter: pack-no-field with `plies` plies of 100×100 to end_time, one
    thread, warm (a first short run compiles); the wall time touching and with the plies 10 cm
    apart (nothing reaches ply 2 within end_time: what ply contact costs when it finds
    nothing), peak memory."""
    from emfabric import load_scenario
    from emfabric import run as run_scenario

    over = {"fabric.plies": plies}
    run_scenario(load_scenario("pack-no-field", {**over, "solver.end_time": 2e-7}), threads=1)
    rss0 = peak_rss()
    out = {"plies": plies}
    for label, extra in (("contact", {}), ("apart", {"fabric.ply_spacing": 0.1})):
        if plies == 1 and label == "apart":
            continue
        t0 = time.perf_counter()
        res = run_scenario(load_scenario("pack-no-field", {**over, **extra,
                                                           "solver.end_time": end_time}),
                           threads=1)
        out[label] = time.perf_counter() - t0
        out["steps"] = res.summary["steps"]
        out["nodes"] = res.model.node_count
    out["rss"] = peak_rss()
    out["rss_warm"] = rss0
    return out


def bench_packs(plies: list[int], end_time: float) -> list[dict]:
    return [child("pack", str(k), repr(end_time)) for k in plies]


def print_packs(rows: list[dict], end_time: float) -> None:
    say(f"(j) Packs of 100×100 plies of the paper's sheet struck by its sphere (pack-no-field), "
        f"one thread, warm, to {end_time * 1e6:g} µs")
    say(f"    {'plies':>5} {'nodes':>7} {'steps':>6} {'s/µs':>7} {'÷ plies×1 ply':>13} "
        f"{'10 cm apart s/µs':>16} {'÷ plies×1 ply':>13} {'peak MB':>8} {'B/node':>7}")
    one = next((r for r in rows if r["plies"] == 1), None)
    for r in rows:
        per_us = r["contact"] / (end_time * 1e6)
        ratio = (f"{r['contact'] / (r['plies'] * one['contact']):.2f}" if one else "-")
        apart = f"{r['apart'] / (end_time * 1e6):.3f}" if "apart" in r else "-"
        apart_ratio = (f"{r['apart'] / (r['plies'] * one['contact']):.2f}"
                       if one and "apart" in r else "-")
        # memory beyond the one-ply run's (imports, compiled code) per node added
        extra = (f"{(r['rss'] - one['rss']) / (r['nodes'] - one['nodes']):.0f}"
                 if one and r["nodes"] > one["nodes"] else "-")
        say(f"    {r['plies']:>5} {r['nodes']:>7} {r['steps']:>6} {per_us:>7.3f} {ratio:>13} "
            f"{apart:>16} {apart_ratio:>13} {r['rss'] / 2**20:>8.0f} {extra:>7}")
    say("    ÷ plies×1 ply: the pack's wall over plies × one ply's (target: about 1 plus the ply "
        "contact); 10 cm apart: the same pack with nothing reaching ply 2 (what ply contact "
        "costs when it finds nothing); B/node: peak memory beyond the 1-ply run's per node "
        "added")


def bench_large(n: int, after_contact: float) -> dict:
    """In a fresh interpreter: paper-field on an n×n sheet from the start until `after_contact`
    seconds after the first contact; the steps after the first contact are timed (the
    controller's first shrinking from dt_max is not what a run spends its time on). Time per
    step, Δt, evaluations per step, bytes of the run's arrays, peak memory."""
    from emfabric import load_scenario
    from emfabric.integrators import make_integrator
    from emfabric.sim.builder import build_model
    from emfabric.sim.state import initial_state

    sc = load_scenario(SCENARIO, sheet(n))
    rss0 = peak_rss()
    t0 = time.perf_counter()
    model = build_model(sc)
    integ = make_integrator(model)
    s_in = initial_state(model)
    s_out = s_in.copy()
    setup = time.perf_counter() - t0
    seen: set = set()
    arrays = (sum(_array_bytes(getattr(model, f.name), seen) for f in dataclasses.fields(model))
              + sum(_array_bytes(getattr(st, f.name), seen) for st in (s_in, s_out)
                    for f in dataclasses.fields(st))
              + sum(_array_bytes(v, seen) for k, v in vars(integ).items() if k != "model"))
    t_contact = None
    timed = {"steps": 0, "evals": 0, "wall": 0.0, "sim": 0.0}
    t_start = time.perf_counter()
    while True:
        t0 = time.perf_counter()
        info = integ.step(s_in, s_out)
        wall = time.perf_counter() - t0
        s_in, s_out = s_out, s_in
        if t_contact is None:
            if info.contacts == 0:
                continue
            t_contact = s_in.t
            continue
        timed["steps"] += 1
        timed["evals"] += info.evaluations
        timed["wall"] += wall
        timed["sim"] += info.dt
        if s_in.t >= t_contact + after_contact:
            break
    return {"n": n, "nodes": model.node_count, "segs": model.seg_count, "setup": setup,
            "t_end": s_in.t, "t_contact": t_contact, "contacts": info.contacts,
            "total": time.perf_counter() - t_start, "arrays": arrays,
            "rss": peak_rss(), "rss0": rss0, **timed}


def print_large(r: dict, small: dict | None) -> None:
    n = r["n"]
    say(f"(f) '{SCENARIO}' on a {n}×{n} sheet ({r['nodes']:,} nodes), from the start to "
        f"{(r['t_end'] - r['t_contact']) * 1e6:.1f} µs after the first contact "
        f"({r['contacts']} nodes in contact then)")
    per_step = r["wall"] / r["steps"]
    dt = r["sim"] / r["steps"]
    say(f"    after the first contact: steps {r['steps']}, mean Δt {dt:.3g} s, "
        f"{r['evals'] / r['steps']:.2f} evaluations per step; {per_step:.3f} s per step, "
        f"{r['wall'] / r['evals'] * 1e3:.1f} ms per evaluation "
        f"({r['wall'] / r['evals'] / r['segs'] * 1e9:.1f} ns/segment)")
    say(f"    arrays {r['arrays'] / r['nodes']:.0f} B per node ({r['arrays'] / 2**20:.0f} MiB); "
        f"peak resident memory {r['rss'] / 2**20:.0f} MiB (after imports "
        f"{r['rss0'] / 2**20:.0f} MiB); set-up {r['setup']:.1f} s, the run "
        f"{r['total']:.0f} s (from the start, first-step kernel load included)")
    if small is not None:
        dt_small = small["sim"] / small["steps"]
        say(f"    against {small['n']}×{small['n']}: Δt {dt / dt_small:.3g}×, "
            f"time per step {per_step / (small['wall'] / small['steps']):.0f}×, "
            f"nodes {r['nodes'] / small['nodes']:.0f}×")
    say(f"    simulating 1 µs costs {per_step / dt * 1e-6:.1f} s at this Δt")


def cost_table(rows: list[dict], full: dict[int, dict], contact_time: float) -> None:
    """Whole-run cost against the grid: steps × evaluations per step × cost per evaluation,
    measured (full run) where `full` has the size, else projected from a short run."""
    say(f"(g) cost of a whole '{SCENARIO}' run against the grid (to the rebound, "
        f"{contact_time * 1e6:.0f} µs on 100×100)")
    say(f"    {'grid':>9} {'nodes':>9} {'mean Δt s':>10} {'steps':>8} {'evals/step':>10} "
        f"{'ms/eval':>8} {'wall':>12}  how")
    for r in rows:
        n = r["n"]
        if n in full:
            s = full[n]
            steps, evs = s["steps"], s["force_evaluations"] / s["steps"]
            wall = s["wall_time_s"]
            per_eval = wall / s["force_evaluations"]
            dt = s["time_s"] / steps
            how = f"measured, whole run to {s['time_s'] * 1e6:.0f} µs"
        else:
            dt = r["sim"] / r["steps"]
            steps = int(contact_time / dt)
            evs = r["evals"] / r["steps"]
            per_eval = r["wall"] / r["evals"]
            wall = steps * evs * per_eval
            how = (f"projected: {r['steps']} steps timed over "
                   f"{(r['t_end'] - r['t_contact']) * 1e6:.1f} µs after contact")
        say(f"    {n:>4}×{n:<4} {r['nodes']:>9,} {dt:10.3g} {steps:8d} {evs:10.2f} "
            f"{per_eval * 1e3:8.2f} {_duration(wall):>12}  {how}")


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.1f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


# --- main ---------------------------------------------------------------------------------

def _target_line(text, value, ok):
    state = "n/a" if value is None else ("met" if ok else "NOT met")
    say(f"    {text:<58} {value or '-':>22}  {state}")


def targets_accuracy(acc: list[dict]) -> None:
    for r in acc:
        d = r["default"]
        _target_line(f"{r['name']} defaults: ω(t) within 2 % of peak (contact)",
                     f"{100 * d['track']:.2f} %", d["track"] <= TARGET_TRACK)
        _target_line(f"{r['name']} defaults: exit ω within 3 %", f"{100 * d['exit']:.2f} %",
                     d["exit"] <= TARGET_EXIT)


def targets(rows: list[dict], fr: dict | None, st: dict | None,
            large: dict | None = None) -> None:
    say("Targets (from the issue)")
    line = _target_line

    by_n = {r["n"]: r for r in rows}
    r = by_n.get(100)
    v = r["emf"][1][0] / r["segs"] * 1e9 if r and 1 in r["emf"] else None
    line("100×100, one core: ≤ 5 ns/segment", v and f"{v:.2f} ns/seg",
         v is not None and v <= TARGETS["ns_100"])
    w = r["warp"][0] / r["emf"][1][0] if r and r["warp"] and 1 in r["emf"] else None
    line("100×100, one core: ≥ 4× faster than Warp's CPU device", w and f"{w:.2f}×",
         w is not None and w >= TARGETS["warp_speedup"])
    r = by_n.get(1000)
    k = 2 if r and 2 in r["emf"] else None
    v = r["emf"][k][0] / r["segs"] * 1e9 if k else None
    line("1000×1000, two threads: ≤ 5 ns/segment", v and f"{v:.2f} ns/seg",
         v is not None and v <= TARGETS["ns_1000"])
    v = min(x["wall_time_s"] for x in fr["summaries"]) if fr else None
    line(f"{SCENARIO} to the rebound at the defaults: ≤ 4 s wall", v and f"{v:.2f} s",
         v is not None and v <= TARGETS["run_wall"])
    if large is not None:
        line(f"{large['n']}×{large['n']} struck sheet runs in memory",
             f"{large['rss'] / 2**20:.0f} MiB peak", True)
    v = st["warm"]["first_step"] if st else None
    line("warm cache: simulating within 3 s of launch", v and f"{v:.2f} s to 1st step",
         v is not None and v <= TARGETS["start"])


FIELD_CASES = {
    "uniform (the paper's)": {},
    "one loop": {"field.B": [0.0, 0.0, 0.0], "field.sources": [
        {"kind": "loop", "centre": [0.0, 0.0, -0.05], "normal": [1.0, 0.0, 0.0],
         "radius": 0.2, "current": 1.6e4}]},
    "one loop, pulsed": {"field.B": [0.0, 0.0, 0.0], "field.sources": [
        {"kind": "loop", "centre": [0.0, 0.0, -0.05], "normal": [1.0, 0.0, 0.0],
         "radius": 0.2, "current": 1.6e4, "waveform": "damped-sine", "frequency": 1e3,
         "decay_time": 1e-3}]},
}
"""Field sources timed by --fields (a map needs a file: `bench_fields` writes one)."""


def bench_fields(repeats: int, runs: int = 3) -> None:
    """The field sources: (e) their per-attempt pass over the nodes and one evaluation + node
    update of the dented 100×100 sheet (one thread), next to the uniform field; (f) 300 µs of
    the paper's impact with each source (the issue's measure of cost), best of `runs`."""
    import tempfile

    import numba
    import xarray as xr

    from emfabric._kernels.fields import fill_node_fields

    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        # a field map over the sheet: 65 × 65 × 33 points of B = 0.05 e_x + a gradient
        xs = np.linspace(-0.16, 0.16, 65)
        zs = np.linspace(-0.1, 0.05, 33)
        gx, gy, gz = np.meshgrid(xs, xs, zs, indexing="ij")
        path = f"{tmp}/map.nc"
        xr.Dataset({"Bx": (("x", "y", "z"), 0.05 + 0.1 * gz), "By": (("x", "y", "z"), 0 * gx),
                    "Bz": (("x", "y", "z"), 0.02 * gy)},
                   coords={"x": xs, "y": xs, "z": zs}).to_netcdf(path)
        cases = {**FIELD_CASES, "field map 65×65×33": {
            "field.B": [0.0, 0.0, 0.0], "field.sources": [{"kind": "map", "file": path}]}}
        say("(e) field sources, dented 100 × 100 sheet, 1 thread: the field pass (once per "
            "attempted step) and one evaluation + node update (every iterate)")
        say(f"    {'field':<30}{'pass [µs]':>11}{'ns/node':>9}{'eval [µs]':>11}"
            f"{'× uniform':>11}")
        base = None
        repeat = _compiled_repeat()
        for name, over in cases.items():
            model, integ, s = deformed_sheet(100, over)
            s2 = s.copy()
            args = iterate_args(integ, s, s2, DT)
            integ.work.flag[:] = 0
            repeat(1, *args)
            best, _med = best_and_median(lambda c, a=args: repeat(c, *a), repeats)
            base = best if base is None else base
            nf = integ.work.node_field
            fld = model.field

            def field_pass(count, fld=fld, s=s, nf=nf):
                for _ in range(count):
                    fill_node_fields(fld, s.node_x, s.node_v, DT, s.t + DT, nf)

            if name.startswith("uniform"):
                pass_us, per_node = "-", "-"
            else:
                field_pass(1)
                sec = best_and_median(field_pass, repeats)[0]
                pass_us, per_node = f"{sec * 1e6:.1f}", f"{sec * 1e9 / model.node_count:.0f}"
            say(f"    {name:<30}{pass_us:>11}{per_node:>9}{best * 1e6:>11.1f}"
                f"{best / base:>11.2f}")
        numba.set_num_threads(threads)
        say(f"(f) 300 µs of the paper's impact ({SCENARIO}, {threads} threads), best "
            f"wall_time_s of {runs}")
        cases = dict(RUN_FIELD_CASES)
        if importlib.util.find_spec("magpylib") is None:  # the "magnets" extra
            del cases["one magnet (cylinder)"]
        _field_runs(cases, {}, runs)
        say("(g) the same on an uncharged sheet (fabric.charge_per_node = 0): one impact, "
            "identical in every run, so the ratio is the cost of evaluating the field alone")
        _field_runs(cases, {"fabric.charge_per_node": 0.0}, runs)


def _field_runs(cases: dict, extra: dict, runs: int) -> None:
    """Best wall_time_s of `runs` runs of 300 µs of the paper's impact per field source."""
    from emfabric import load_scenario
    from emfabric import run as run_scenario

    say(f"    {'field':<30}{'wall [s]':>10}{'× uniform':>11}{'steps':>7}{'evals':>7}")
    base = None
    for name, over in cases.items():
        over = {**over, **extra}
        sc = load_scenario(SCENARIO, {"solver.end_time": 3e-4, **over})
        run_scenario(load_scenario(SCENARIO, {"solver.end_time": 2e-6, **over}))  # compile
        walls = []
        for _ in range(runs):
            gc.collect()
            res = run_scenario(sc)
            walls.append(res.summary["wall_time_s"])
        base = min(walls) if base is None else base
        say(f"    {name:<30}{min(walls):>10.2f}{min(walls) / base:>11.2f}"
            f"{res.summary['steps']:>7}{res.summary['force_evaluations']:>7}")


RUN_FIELD_CASES = {
    "uniform (the paper's)": {},
    **{k: v for k, v in FIELD_CASES.items() if k != "uniform (the paper's)"},
    "one loop, no grid (exact)": {**FIELD_CASES["one loop"], "field.grid": False},
    "one magnet (cylinder)": {"field.B": [0.0, 0.0, 0.0], "field.sources": [
        {"kind": "magnet", "shape": "cylinder", "polarization": [0.0, 0.0, 0.3],
         "dimension": [0.2, 0.05], "position": [0.0, 0.0, -0.1]}]},
}
"""Sources of the run-level comparison (f)."""


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true",
                   help="100×100 evaluation, warm start-up and memory only (about a minute)")
    p.add_argument("--sizes", type=int, nargs="+", default=[100, 1000],
                   help="sheet sizes n (n×n) of (a) and (d) (default: 100 1000)")
    p.add_argument("--repeat", type=int, default=7, help="timing samples per figure")
    p.add_argument("--runs", type=int, default=3, help="full paper-field runs in (b)")
    p.add_argument("--no-full-run", action="store_true", help="skip (b)")
    p.add_argument("--end-time", type=float, metavar="SECONDS",
                   help="solver.end_time of the runs of (b) (default: the "
                        "scenario's)")
    p.add_argument("--no-cold", action="store_true",
                   help="skip the cold-cache start-up (it recompiles every kernel)")
    p.add_argument("--no-warp", action="store_true", help="leave Warp out of (a)")
    p.add_argument("--gpu-json", type=Path, metavar="FILE",
                   help="(k): print beside (a) the GPU figures of `gpu.py run --json FILE` "
                        "(the same evaluation with numba.cuda on a GPU machine)")
    p.add_argument("--schemes", action="store_true",
                   help="only weigh solver settings on paper-field against (e)'s converged "
                        "run (minutes)")
    p.add_argument("--fields", action="store_true",
                   help="only time the field sources (uniform, loop, pulsed loop, map)")
    p.add_argument("--accuracy", nargs="*", metavar="SCENARIO", default=["paper-field"],
                   help="scenarios of (e), the error at the default settings (default: "
                        "paper-field; also paper-spin, ogive-field; none: skip (e))")
    p.add_argument("--accuracy-only", action="store_true", help="only (e)")
    p.add_argument("--reference-dt", type=float, default=1e-8,
                   help="dt_max of the converged runs of (e), checked at half (default 1e-8)")
    p.add_argument("--reference-cache", type=Path, default=Path("runs/bench-reference"),
                   help="where (e) stores its converged runs, reused while the scenario "
                        "and the emfabric version are the same (default runs/bench-reference)")
    p.add_argument("--large", type=int, default=1000, metavar="N",
                   help="(f): the struck N×N sheet (default 1000; 0 skips (f) and (g))")
    p.add_argument("--after-contact", type=float, default=2e-6, metavar="SECONDS",
                   help="(f), (g): how long past the first contact the large sheets run")
    p.add_argument("--side-by-side", nargs="*", metavar="SCENARIO",
                   default=list(SIDE_BY_SIDE),
                   help="(h): these scenarios by both schemes (none: skip)")
    p.add_argument("--side-by-side-only", action="store_true", help="only (h)")
    p.add_argument("--side-by-side-courant", type=float, nargs="*", default=[],
                   metavar="C", help="(h): central differences at these courant numbers too "
                   "(e.g. 0.5, the fifth of the φ-scheme's evaluations)")
    p.add_argument("--ladder", metavar="SCENARIO",
                   help="only (l): SCENARIO by central differences at its courant / 2^k, "
                        "each run against the next and the finest (long: the finest of 5 "
                        "levels takes 16× the default run)")
    p.add_argument("--ladder-levels", type=int, default=5, metavar="K",
                   help="(l): rungs of the ladder (default 5: courant to courant / 16)")
    p.add_argument("--loaded", type=int, nargs="*", default=[100, 400], metavar="N",
                   help="(i): these grids with default threads and one, idle and loaded "
                        "(none: skip)")
    p.add_argument("--loaded-only", action="store_true", help="only (i)")
    p.add_argument("--busy", type=int, default=3, help="busy processes beside (i)'s runs")
    p.add_argument("--measure-up-to", type=int, default=100, metavar="N",
                   help="(g): whole runs measured up to this grid, projected above")
    p.add_argument("--cost-sizes", type=int, nargs="+", default=[40, 70, 100, 200, 400],
                   help="(g): grid sizes besides --large (≤ 100: whole runs)")
    p.add_argument("--packs", type=int, nargs="*", default=None, metavar="PLIES",
                   help="only (j): packs of these many 100×100 plies (default 1 4 16)")
    p.add_argument("--pack-end", type=float, default=PACK_END, metavar="SECONDS",
                   help="(j): simulated time of each pack run")
    p.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    a = p.parse_args(argv)

    if a.child:
        mode, *rest = a.child
        if mode == "large":
            out = bench_large(int(rest[0]), float(rest[1]))
        elif mode == "pack":
            out = child_pack(int(rest[0]), float(rest[1]))
        else:
            out = (child_startup() if mode == "startup" else
                   child_threads(int(rest[0]), float(rest[1]), int(rest[2]))
                   if mode == "threads" else child_memory(int(rest[0])))
        print(json.dumps(out))
        return

    import numba

    cpu0 = cpu_snapshot()
    say("emfabric benchmark suite: python benchmarks/bench.py " + " ".join(sys.argv[1:]))
    for line in machine():
        say(f"  {line}")
    say()
    base = {} if a.end_time is None else {"solver.end_time": a.end_time}
    if a.packs is not None:
        print_packs(bench_packs(a.packs or list(PACK_PLIES), a.pack_end), a.pack_end)
        say(f"Other processes used {other_cpu(cpu0):.2f} cores on average while this ran")
        return
    if a.fields:
        bench_fields(a.repeat, a.runs)
        say(f"Other processes used {other_cpu(cpu0):.2f} cores on average while this ran")
        return
    if a.schemes:
        bench_schemes(a.reference_dt, a.reference_cache)
        say(f"Other processes used {other_cpu(cpu0):.2f} cores on average while this ran")
        return
    loaded_cases = [(n, LOADED_END.get(n, 5e-6)) for n in a.loaded]
    if a.ladder:
        if a.ladder_levels < 1:
            p.error(f"--ladder-levels {a.ladder_levels}: allowed: a whole number ≥ 1")
        print_ladder(bench_ladder(a.ladder, a.ladder_levels, a.reference_cache))
        say(f"Other processes used {other_cpu(cpu0):.2f} cores on average while this ran")
        return
    if a.side_by_side_only:
        print_side_by_side(bench_side_by_side(a.side_by_side, a.reference_cache,
                                              tuple(a.side_by_side_courant)))
        say(f"Other processes used {other_cpu(cpu0):.2f} cores on average while this ran")
        return
    if a.loaded_only:
        print_loaded(bench_loaded(loaded_cases, a.busy), a.busy)
        return
    if a.accuracy_only:
        acc = bench_accuracy(a.accuracy, a.reference_dt, a.reference_cache)
        print_accuracy(acc, a.reference_dt)
        say()
        targets_accuracy(acc)
        say(f"Other processes used {other_cpu(cpu0):.2f} cores on average while this ran")
        return
    sizes = [s for s in a.sizes if not (a.quick and s > 100)]
    max_threads = numba.config.NUMBA_NUM_THREADS
    threads = [1] if max_threads == 1 else [1, max_threads]

    warp_note = ""
    use_warp = not a.no_warp
    if use_warp:
        try:
            sys.path.insert(0, str(HERE))
            import warp_kernels

            warp_kernels.init()
        except ImportError as err:
            use_warp = False
            warp_note = (f"Warp: not installed ({err}); `pip install warp-lang` "
                         "(the `bench` extra) to compare")
    else:
        warp_note = "Warp: left out (--no-warp)"

    section = cpu_snapshot()
    bandwidth = {k: _triad_bandwidth(k, a.repeat) for k in threads}
    rows = [bench_evaluation(n, threads, a.repeat, use_warp) for n in sizes]
    numba.set_num_threads(max_threads)
    print_evaluations(rows, threads, warp_note, bandwidth)
    busy_note(section)
    say()
    if a.gpu_json is not None:
        print_gpu(json.loads(a.gpu_json.read_text()), rows)

    fr = None
    if not (a.quick or a.no_full_run):
        section = cpu_snapshot()
        fr = bench_full_run(a.runs, a.repeat, base)
        print_full_run(fr)
        busy_note(section)
        say()

    acc = []
    if a.accuracy and not a.quick:
        section = cpu_snapshot()
        acc = bench_accuracy(a.accuracy, a.reference_dt, a.reference_cache)
        print_accuracy(acc, a.reference_dt)
        busy_note(section)
        say()

    large = None
    if a.large and not a.quick:
        section = cpu_snapshot()
        from emfabric import load_scenario
        from emfabric import run as run_scenario

        numba.set_num_threads(max_threads)
        full = {} if fr is None or a.end_time is not None else {100: fr["summaries"][0]}
        short = {}
        for n in sorted(set(a.cost_sizes + [a.large])):
            if n <= a.measure_up_to and n not in full:
                full[n] = run_scenario(load_scenario(SCENARIO, sheet(n))).summary
            # in a fresh interpreter: its peak memory is the sheet's alone
            short[n] = child("large", str(n), repr(a.after_contact))
        large = short[a.large]
        print_large(large, short.get(100))
        say()
        contact = full[100]["time_s"] if 100 in full else 1e-3
        cost_table([short[n] for n in sorted(short)], full, contact)
        busy_note(section)
        say()

    if a.side_by_side and not a.quick:
        section = cpu_snapshot()
        print_side_by_side(bench_side_by_side(a.side_by_side, a.reference_cache,
                                              tuple(a.side_by_side_courant)))
        busy_note(section)
        say()

    if a.loaded and not a.quick:
        print_loaded(bench_loaded(loaded_cases, a.busy), a.busy)
        say()

    st = None
    section = cpu_snapshot()
    try:
        st = bench_startup(cold=not (a.quick or a.no_cold))
        print_startup(st)
        busy_note(section)
    except RuntimeError as err:
        say(f"(c) start-up: not measured, {err}")
    say()

    try:
        print_memory([child("memory", str(n)) for n in sizes])
    except RuntimeError as err:
        say(f"(d) memory: not measured, {err}")
    say(f"    this benchmark process: peak RSS {peak_rss() / 2**20:.0f} MiB "
        f"(getrusage: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**10:.0f} MiB)")
    say()
    targets(rows, fr if a.end_time is None else None, st, large)
    targets_accuracy(acc)
    say()
    busy = other_cpu(cpu0)
    say(f"Other processes used {busy:.2f} cores on average while this ran"
        + ("" if busy < 0.1 else " (the figures above may be perturbed: rerun on an idle machine)"))


if __name__ == "__main__":
    main()
