"""The time loop: step, swap states, record, snapshot, checkpoint, interrupt, summary."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

from emfabric._kernels import CACHE_DIR, CACHE_PERSISTENT, is_compiled, mark_compiled
from emfabric._kernels import diagnostics as _k
from emfabric.builder import build_model
from emfabric.diagnostics import flight_direction
from emfabric.integrator import DivergenceError, Integrator, StepInfo
from emfabric.io.history import Recorder, run_attributes, write_history
from emfabric.io.snapshots import Snapshots
from emfabric.model import Model, State
from emfabric.scenario import Scenario

ProgressFn = Callable[[State, StepInfo], None]
log = logging.getLogger(__name__)


@dataclass
class RunResult:
    """What a run produced: the history, the final state and a summary."""

    model: Model
    state: State
    history: xr.Dataset
    status: str
    """"complete", "partial" (interrupted) or "diverged"."""
    end_reason: str
    wall_time: float
    out_dir: Path | None = None
    summary: dict[str, float | int | str] = field(default_factory=dict)


def _left_for_good(model: Model, state: State, diag: np.ndarray) -> str | None:
    """'rebound' or 'perforation' once no node can reach the projectile any more."""
    if not model.has_body or state.contact_count > 0:
        return None
    d = flight_direction(model)
    vb = float(state.body_v @ d)
    clear = 1.05 * model.body_radius
    if vb < 0 and diag[_k.AHEAD_MIN] > clear and diag[_k.APPROACH_MAX] < -vb:
        return "rebound"
    if vb > 0 and diag[_k.AHEAD_MAX] < -clear and diag[_k.RECEDE_MAX] < vb:
        return "perforation"
    return None


def run(
    scenario: Scenario,
    out_dir: str | Path | None = None,
    *,
    progress: ProgressFn | None = None,
    end_time: float | None = None,
) -> RunResult:
    """Run a scenario to its end; write history.nc and snapshots into out_dir if given.

    Ctrl-C (KeyboardInterrupt) and divergence leave valid files marked partial/diverged; the
    exception is re-raised after the files are written, with the result attached as `.result`.
    """
    wall0 = time.perf_counter()
    model = build_model(scenario)
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    integ = Integrator(model)
    # on a cold kernel cache, run serially and compile the threaded kernel beside the run
    deferred = integ.defer_threads()
    if not is_compiled(integ.variant()):
        log.info("compiling kernels (first run only, about half a minute; cached in %s)" if
                 CACHE_PERSISTENT else "compiling kernels (no writable cache folder: "
                 "every run compiles; cached in %s for this process)", CACHE_DIR)
    s_in = model.state()
    s_out = s_in.copy()
    recorder = Recorder(model, integ.coef)
    snaps = Snapshots(model, out)
    t_end = end_time if end_time is not None else scenario.solver.end_time
    interval = scenario.output.snapshot_interval
    recorder.record(s_in)
    snaps.take(s_in)
    next_snap = interval
    next_checkpoint = wall0 + scenario.output.checkpoint_seconds
    status, reason = "complete", "end_time"
    error: BaseException | None = None

    def finish(status: str, reason: str) -> RunResult:
        wall = time.perf_counter() - wall0
        attrs = run_attributes(model, status, reason, wall)
        ds = recorder.to_dataset(attrs)
        if out is not None:
            write_history(ds, out / "history.nc")
            snaps.write(attrs)
        res = RunResult(model, s_in, ds, status, reason, wall, out)
        res.summary = summarize(res)
        return res

    try:
        while s_in.t < t_end * (1 - 1e-12):
            info = integ.step(s_in, s_out, dt_limit=t_end - s_in.t)
            s_in, s_out = s_out, s_in
            recorder.record(s_in, info.dt, info.iterations, info.error)
            if s_in.steps == 1:
                mark_compiled(integ.variant())
                if deferred:
                    integ.start_background_compile(s_in, s_out)
            if s_in.t >= next_snap * (1 - 1e-12):
                snaps.take(s_in)
                next_snap = interval * (math.floor(s_in.t / interval + 1e-9) + 1)
            if progress is not None:
                progress(s_in, info)
            left = _left_for_good(model, s_in, recorder.last_diag)
            if left is not None:
                reason = left
                break
            if out is not None and time.perf_counter() > next_checkpoint:
                attrs = run_attributes(model, "partial", "running (checkpoint)",
                                       time.perf_counter() - wall0)
                write_history(recorder.to_dataset(attrs), out / "history.nc")
                next_checkpoint = time.perf_counter() + scenario.output.checkpoint_seconds
    except KeyboardInterrupt as exc:
        status, reason, error = "partial", f"interrupted at t = {s_in.t:.6g} s", exc
    except DivergenceError as exc:
        status, reason, error = "diverged", str(exc), exc
    if snaps.times[-1] != s_in.t:
        snaps.take(s_in)
    result = finish(status, reason)
    if integ.compiling_in_background and status != "partial":
        log.info("finishing the threaded kernel's compile for later runs (first run only)")
        integ.finish_background_compile()
    if error is not None:
        error.result = result  # type: ignore[attr-defined]
        raise error
    return result


def summarize(result: RunResult) -> dict[str, float | int | str]:
    """The end-of-run figures a user reads first."""
    ds, st, m = result.history, result.state, result.model
    steps = int(ds.sizes["time"]) - 1
    out: dict[str, float | int | str] = {
        "status": result.status,
        "end_reason": result.end_reason,
        "time_s": float(st.t),
        "steps": steps,
        "rejected_steps": int(st.rejected),
        "force_evaluations": int(st.evaluations),
        "mean_iterations": float(ds["iterations"][1:].mean()) if steps else 0.0,
        "final_dt_s": float(ds["dt"][-1]) if steps else 0.0,
        "wall_time_s": float(result.wall_time),
        "broken_yarns": int(ds["broken_yarns"][-1]),
        "min_damage": float(ds["min_damage"].min()),
        "max_stretch": float(ds["max_stretch"].max()),
        "max_deflection_m": float(ds["max_deflection"].max()),
        "energy_balance_error_J": float(ds["energy_balance_error"][-1]),
    }
    if m.has_body:
        v = ds["projectile_velocity"][-1].values
        w = ds["angular_velocity"][-1].values
        ke = ds["kinetic_energy_projectile"].values
        out.update({
            "final_velocity_m_s": [float(c) for c in v],
            "residual_speed_m_s": float(np.linalg.norm(v)),
            "final_omega_rad_s": [float(c) for c in w],
            "max_tilt_deg": float(np.degrees(ds["tilt"].max())),
            "energy_absorbed_J": float(ke[0] - ke[-1]),
        })
    return out
