"""The time loop: step, swap states, record, snapshot, checkpoint, interrupt, summary."""

from __future__ import annotations

import contextlib
import logging
import math
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

from emfabric._kernels import cache_dir, cache_persistent, is_compiled, mark_compiled
from emfabric.config.scenario import Scenario
from emfabric.integrators import DivergenceError, StepInfo, check_threads, make_integrator
from emfabric.io.checkpoint import (
    CHECKPOINT,
    END_TIME,
    CheckpointError,
    RunPosition,
    check_matches,
    read_checkpoint,
    write_checkpoint,
)
from emfabric.io.history import (
    Recorder,
    append_history,
    history_status,
    mark_status,
    read_history_rows,
    run_attributes,
    write_history,
)
from emfabric.io.lock import folder_lock
from emfabric.io.netcdf import record_digest
from emfabric.io.snapshots import Snapshots, snapshot_times, truncate_snapshots
from emfabric.runner import precompile
from emfabric.runner.summary import summarize
from emfabric.sim.builder import build_model
from emfabric.sim.diagnostics import check_plausible, left_for_good, limits, measure
from emfabric.sim.model import Model
from emfabric.sim.plausibility import log_warnings
from emfabric.sim.state import State, initial_state, segment_modes

ProgressFn = Callable[[State, StepInfo], None]
log = logging.getLogger(__name__)

RUNNING = ("running; if it is not (killed), `emfabric run --resume` on this folder continues "
           "it from its last checkpoint")
"""history.nc's end_reason while the run goes (status "partial"). Long enough on purpose: a
write error on a full disk is recorded in its place, in the file's header as it stands
(emfabric.io.history.mark_status)."""
NOT_STARTED = ("interrupted before its first step: no checkpoint, nothing to resume; run the "
               "scenario again")
"""history.nc's end_reason for a run stopped before its first step (no longer than RUNNING:
it replaces it in the header as it stands, emfabric.io.history.mark_status)."""

# Set by `interrupt` (the command line's SIGINT/SIGTERM/SIGHUP handler). The handler also raises
# KeyboardInterrupt at once, but Python drops an exception raised while it runs a weakref
# callback or a __del__ ("Exception ignored in ..."): the time loop checks this flag every
# step, so a signal that lands there still stops the run, one step later.
_STOP = threading.Event()


def interrupt(*_args) -> None:
    """Signal handler: ask the running time loop to stop (files kept, marked partial)."""
    _STOP.set()
    raise KeyboardInterrupt


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


def _paraview(model: Model) -> bool:
    """Whether the run writes ParaView files (output.paraview; a Model built in Python: yes)."""
    return model.scenario is None or model.scenario.output.paraview


def run(
    scenario: Scenario | Model,
    out_dir: str | Path | None = None,
    *,
    progress: ProgressFn | None = None,
    end_time: float | None = None,
    threads: int | None = None,
) -> RunResult:
    """Run a scenario (or a Model from build_model, or one put together in Python) to its end;
    write history.nc, snapshots and checkpoints into out_dir if given, as the run goes. A Model
    without a scenario writes no checkpoint (a checkpoint is resumed by rebuilding the Model
    from its scenario).

    Ctrl-C (KeyboardInterrupt) and divergence leave valid files marked partial/diverged and a
    checkpoint; the exception is re-raised after the files are written, with the result
    attached as `.result`. threads: Numba threads for the node kernels (1: the serial kernel;
    default: integrators.default_threads for the problem's size); the numbers are the same.
    """
    check_threads(threads)  # before anything is built or written
    # a run kept in memory writes nothing: no output-volume limit (sim.sanity)
    model = scenario if isinstance(scenario, Model) else build_model(
        scenario, writes=out_dir is not None)
    log_warnings(model, log)  # is the charge physical? (emfabric.sim.plausibility)
    if out_dir is None:
        return _loop(model, None, None, None, progress, end_time, threads)
    out = Path(out_dir)
    # one run at a time per folder (emfabric.io.lock): FolderInUse before anything is written
    with folder_lock(out):
        try:
            return _loop(model, None, None, out, progress, end_time, threads)
        except KeyboardInterrupt as exc:
            if getattr(exc, "result", None) is None and not (out / CHECKPOINT).is_file():
                # stopped before its first step (while the kernels compiled): the empty
                # history says so, not that a resume would continue it
                mark_status(out / "history.nc", "partial", NOT_STARTED)
            raise


def resume(out_dir: str | Path, scenario: Scenario | None = None, *,
           progress: ProgressFn | None = None, threads: int | None = None) -> RunResult:
    """Continue the run whose checkpoint is in out_dir. The history it writes is bitwise the one
    an uninterrupted run writes. A scenario, if given, must equal the checkpoint's. The folder
    is held while the run goes (emfabric.io.lock: FolderInUse if another process holds it)."""
    check_threads(threads)
    out = Path(out_dir)
    if not out.is_dir():
        read_checkpoint(out / CHECKPOINT)  # raises: no checkpoint, nothing to resume
    with folder_lock(out):
        return _resume(out, scenario, progress, threads)


def _resume(out: Path, scenario: Scenario | None, progress: ProgressFn | None,
            threads: int | None) -> RunResult:
    path = out / CHECKPOINT
    stored, version, state, pos = read_checkpoint(path)
    # a later solver.end_time alone continues the run further (check_matches)
    extends = check_matches(scenario if scenario is not None else stored, version, stored, path)
    model = build_model(scenario if extends else stored)
    if (state.node_x.shape != (3, model.node_count) or state.seg_alpha.shape
            != (model.seg_count,) or state.seg_strain.shape
            != model.physics.yarns.averaging_rate.shape
            or state.seg_contact.shape != (segment_modes(model),)):
        raise CheckpointError(f"{path}: its arrays do not fit the scenario's grid")
    history = out / "history.nc"
    status = history_status(history)
    if status is not None and status[0] == "complete":
        if status[1] != "end_time":
            raise CheckpointError(
                f"the run in {out} is complete ({status[1]}): nothing to resume; it ended by "
                f"its stop rule (the projectile had left the fabric for good), which a later "
                f"{END_TIME} would meet again at once")
        if not extends:
            raise CheckpointError(
                f"the run in {out} is complete (end_time): nothing to resume; to continue it "
                f"past its end, give a later end time: emfabric run --resume {out} --set "
                f"{END_TIME}=T")
    if status is not None and status[0] == "diverged":
        # its checkpoint holds the state it diverged from (or in): the same scenario diverges
        # again, a step further each time it is resumed
        raise CheckpointError(
            f"the run in {out} diverged ({status[1]}): nothing to resume; run the scenario "
            f"again with what the message points to changed (a smaller solver.courant, or the "
            f"value it names), into a new folder or this one")
    try:
        rows = read_history_rows(history, pos.history_rows, model.ply_count)
        times = snapshot_times(out / "snapshots.nc", pos.snapshots)
    except (OSError, ValueError, KeyError) as err:
        raise CheckpointError(f"{out}: the history or snapshots written with the checkpoint "
                              f"cannot be read ({err})") from None
    try:
        _kept_outputs(out, pos, state, rows[:, 0], times)
    except (OSError, ValueError, KeyError, IndexError) as err:
        raise CheckpointError(
            f"{out}: {err}; nothing resumed (the run's past is not on disk any more): run the "
            f"scenario again, into a new --out or this one with --force") from None
    return _loop(model, state, (pos, rows, times, extends), out, progress, None, threads)


def _kept_outputs(out: Path, pos: RunPosition, state: State, history_times: np.ndarray,
                  snapshot_times_: list[float]) -> None:
    """ValueError unless history.nc and snapshots.nc still hold what the checkpoint counts: a
    file cut short (a copy that stopped, a full disk, a truncation) can still open, its lost
    records read as zeros, and a resume would keep them as the run's past. The records'
    times rise from 0 to the checkpoint's (the last history record is the checkpoint's own
    state), and the last record of each is the one the checkpoint saw (its digest)."""
    t = np.asarray(history_times)
    if t.size == 0 or t[0] != 0.0 or np.any(np.diff(t) <= 0.0) or t[-1] != state.t:
        bad = (0 if t.size == 0 or t[0] != 0.0 else
               int(np.argmax(np.diff(t) <= 0.0)) + 1 if np.any(np.diff(t) <= 0.0)
               else t.size - 1)
        raise ValueError(f"history.nc is not what the checkpoint was written with: its record "
                         f"{bad} is not one of the run's (the times do not rise from 0 to the "
                         f"checkpoint's t = {state.t:.9g} s), the file lost records since")
    s = np.asarray(snapshot_times_)
    if s.size and (s[0] != 0.0 or np.any(np.diff(s) <= 0.0) or s[-1] > state.t):
        raise ValueError("snapshots.nc is not what the checkpoint was written with: its times "
                         f"do not rise from 0 to at most the checkpoint's t = {state.t:.9g} s, "
                         f"the file lost snapshots since")
    for name, dim, index, digest in (
            ("history.nc", "time", pos.history_rows - 1, pos.history_digest),
            ("snapshots.nc", "snapshot", pos.snapshots - 1, pos.snapshots_digest)):
        if digest and record_digest(out / name, dim, index) != digest:
            raise ValueError(f"{name} is not what the checkpoint was written with: its {dim} "
                             f"record {index} differs from the one the checkpoint saw")


def _loop(model: Model, s_in: State | None, resumed, out: Path | None,
          progress: ProgressFn | None, end_time: float | None,
          threads: int | None = None) -> RunResult:
    # NumPy's floating-point warnings stay out of the run's output: a state that overflows or
    # divides by zero is the run's own to detect and report (the step's non-finite check, the
    # history's, the guards: a diverged run names the time, Δt and where), and NumPy would
    # only add its "RuntimeWarning: overflow encountered" lines (from the summary, a snapshot)
    # to that message (errstate is per thread, so a study's other cases are not touched)
    with np.errstate(all="ignore"):
        return _run_loop(model, s_in, resumed, out, progress, end_time, threads)


def _run_loop(model: Model, s_in: State | None, resumed, out: Path | None,
              progress: ProgressFn | None, end_time: float | None,
              threads: int | None = None) -> RunResult:
    wall0 = time.perf_counter()
    options = model.options
    integ = make_integrator(model, threads=threads)
    # the .vtu files are written beside a serial step kernel (io.snapshots)
    vtu_beside = not integ.threaded
    # on a cold kernel cache, run serially and compile the threaded kernel beside the run
    deferred = integ.defer_threads()
    second = None  # the process that compiles some kernels beside this one (cold cache)
    if not is_compiled(integ.variant()):
        log.info("compiling kernels (first run only, about half a minute; cached in %s)" if
                 cache_persistent() else "compiling kernels (no writable cache folder: "
                 "every run compiles; cached in %s for this process)", cache_dir())
        if model.scenario is not None and cache_persistent() and precompile.wanted():
            second = precompile.start(model.scenario.to_toml())
    t_end = end_time if end_time is not None else options.end_time
    interval = options.snapshot_interval
    if resumed is None:
        if out is not None:
            # a readable (empty) history before anything compiles: killed at any moment, the
            # folder says what was run and that it did not finish
            with _naming(out / "history.nc"):
                write_history(Recorder(plies=model.ply_count).to_dataset(
                    run_attributes(model, "partial", RUNNING, 0.0)), out / "history.nc")
        s_in = initial_state(model)
        recorder = Recorder(plies=model.ply_count)
        snaps = Snapshots(model, out, paraview=_paraview(model),
                          background=vtu_beside)
        measure(model, s_in, recorder.new_row())
        with _signals_deferred(stop=True), _snapshot_naming(out):
            snaps.take(s_in)
        next_snap = interval
        wall_before = 0.0
        written = 0
    else:
        pos, rows, times, extends = resumed
        recorder = Recorder(rows, model.ply_count)
        snaps = Snapshots(model, out, times, paraview=_paraview(model),
                          background=vtu_beside)
        next_snap = pos.next_snapshot
        wall_before = pos.wall_time
        # records and snapshots written after the checkpoint are written again
        with _naming(out / "history.nc"):
            write_history(recorder.to_dataset(run_attributes(model, "partial", RUNNING,
                                                             wall_before)), out / "history.nc")
        with _naming(out / "snapshots.nc"):
            # continued past its end: the files say so (the later end_time in the scenario)
            truncate_snapshots(out / "snapshots.nc", pos.snapshots, run_attributes(
                model, "partial", RUNNING, wall_before) if extends else None)
        written = recorder.count
        log.info("resuming at t = %.6g s (step %d)", s_in.t, s_in.steps)
    s_out = s_in.copy()
    lim = limits(model)
    status, reason = "complete", "end_time"
    error: BaseException | None = None

    def wall() -> float:
        return wall_before + time.perf_counter() - wall0

    def save(status: str, reason: str, history: xr.Dataset | None = None,
             regular: int | None = None,
             at: tuple[State, RunPosition] | None = None) -> None:
        """Append the new records and snapshots (or write the whole `history` with its final
        attributes), then write the checkpoint: in this order, so that the checkpoint only
        counts what is on disk. at: the checkpoint's state and position, where not the last
        state and all that is written."""
        nonlocal written
        if out is None:
            return
        attrs = run_attributes(model, status, reason, wall())
        with _naming(out / "history.nc"):
            if history is None:
                written = append_history(out / "history.nc", recorder.rows[written:], attrs,
                                         written)
            else:
                write_history(history, out / "history.nc")
                written = recorder.count
        with _snapshot_naming(out):
            snaps.wait()  # the .vtu files written beside the run, before the .pvd lists them
        with _naming(out / "snapshots.nc"):
            snaps.flush(attrs)
            if history is not None and (out / "snapshots.nc").is_file():
                # the run's end in snapshots.nc's header too (its attributes are those it was
                # created with: status partial), in place (its records stay where they are)
                mark_status(out / "snapshots.nc", status, reason,
                            history.attrs["wall_time_s"])
        if model.scenario is None:
            return  # nothing to rebuild the Model from on resume
        state, position = at if at is not None else (s_in, RunPosition(
            written, snaps.count if regular is None else regular, next_snap, wall()))
        with _naming(out / CHECKPOINT):
            # the last history record and snapshot the checkpoint counts, as on disk: a resume
            # keeps only files that still hold them (_kept_outputs)
            position.history_digest = record_digest(out / "history.nc", "time",
                                                    position.history_rows - 1)
            if position.snapshots > 0:
                position.snapshots_digest = record_digest(out / "snapshots.nc", "snapshot",
                                                          position.snapshots - 1)
            write_checkpoint(out / CHECKPOINT, model, state, position)

    next_checkpoint = 0.0  # the first step is saved at once: a killed run always has files
    first_step = True
    before_last = None  # (snapshots taken, next snapshot time) before the step in hand
    try:
        if resumed is None:
            # the initial record on disk before the step kernel compiles (seconds on a cold
            # cache): a run killed meanwhile still leaves a readable history
            with _signals_deferred(stop=True):
                save("partial", RUNNING)
        while s_in.t < t_end * (1 - 1e-12):
            if _STOP.is_set():
                raise KeyboardInterrupt
            before_last = (snaps.count, next_snap)
            info = integ.step(s_in, s_out, dt_limit=t_end - s_in.t)
            s_in, s_out = s_out, s_in
            row = recorder.new_row()
            fab = measure(model, s_in, row, integ.fabric_of(s_in), integ.contacts_of(s_in))
            wrong = check_plausible(model, s_in, row, lim)
            if wrong is not None:
                raise DivergenceError(
                    f"diverged at t = {s_in.t:.6g} s, Δt = {info.dt:.3g} s: {wrong} (the state "
                    f"of this step is the history's last record)", s_in.t, info.dt, -1, 0.0)
            if first_step:
                first_step = False
                mark_compiled(integ.variant())
                if deferred:
                    integ.start_background_compile(s_in, s_out)
            if s_in.t >= next_snap * (1 - 1e-12):
                # the .vtu files are written as it is taken
                with _signals_deferred(stop=True), _snapshot_naming(out):
                    snaps.take(s_in)
                next_snap = interval * (math.floor(s_in.t / interval + 1e-9) + 1)
            if progress is not None:
                progress(s_in, info)
            left = left_for_good(model, s_in, fab)
            if left is not None:
                reason = left
                break
            if out is not None and time.perf_counter() > next_checkpoint:
                with _signals_deferred(stop=True):
                    save("partial", RUNNING)
                next_checkpoint = time.perf_counter() + options.checkpoint_seconds
    except KeyboardInterrupt as exc:
        status, reason, error = "partial", f"interrupted at t = {s_in.t:.6g} s", exc
    except DivergenceError as exc:
        status, reason, error = "diverged", str(exc), exc
    except OutputError as exc:
        status, reason, error = "failed", exc.reason, exc
    _STOP.clear()  # handled: a later run in this process starts afresh
    # the last state as a snapshot too (the figures of a partial run end there); a resumed run
    # drops it: the checkpoint counts only the snapshots of the regular interval
    regular = snaps.count
    if snaps.times[-1] != s_in.t:
        try:
            with _signals_deferred(), _snapshot_naming(out):
                snaps.take(s_in)
        except OutputError as exc:
            if error is None:
                status, reason, error = "failed", exc.reason, exc
    try:
        # the .vtu files written beside the run: one that failed is the run's end reason, as
        # if written in line, before the final history says how the run ended
        with _signals_deferred(), _snapshot_naming(out):
            snaps.wait()
    except OutputError as exc:
        if error is None:
            status, reason, error = "failed", exc.reason, exc
    total = wall()
    attrs = run_attributes(model, status, reason, total)
    ds = recorder.to_dataset(attrs)
    at = None
    if status == "complete" and reason == "end_time" and before_last is not None:
        # the checkpoint of a run that reached end_time holds the state before its last step,
        # which end_time cut short (s_out: the integrators leave a step's input untouched):
        # continued past its end (a later solver.end_time on resume), the run takes that step
        # whole, as a run given the later end from the start does, to the bit
        at = (s_out, RunPosition(recorder.count - 1, *before_last, total))
    # the final attributes (status, end reason, wall time): one rewrite of history.nc per run;
    # a second Ctrl-C (or SIGTERM, SIGHUP) while the files are written waits for them
    with _signals_deferred():
        try:
            save(status, reason, ds, regular, at)
        except OutputError as exc:
            log.error("%s; the files written before are kept%s", exc,
                      "" if model.scenario is None else
                      " (the last checkpoint resumes: `emfabric run --resume`)")
            if error is None:
                status, reason, error = "failed", exc.reason, exc
            ds.attrs.update(status=status, end_reason=reason)
            # the full rewrite failed (a full disk?): the status in history.nc's header as it
            # stands, so that the folder does not claim a run still going
            if out is not None and (out / "history.nc").is_file() and \
                    not mark_status(out / "history.nc", status, reason):
                log.error("%s still reads status = partial: its end could not be recorded",
                          out / "history.nc")
    snaps.close()
    result = RunResult(model, s_in, ds, status, reason, total, out)
    result.summary = summarize(result)
    if integ.compiling_in_background and status != "partial":
        log.info("finishing the threaded kernel's compile for later runs (first run only)")
        integ.finish_background_compile()
    if second is not None and status == "partial":
        second.kill()  # interrupted: the cache keeps what it finished (atomic writes)
    else:
        precompile.finish(second)
    if error is not None:
        error.result = result  # type: ignore[attr-defined]
        raise error
    return result


class OutputError(OSError):
    """An output file could not be written (full disk, permissions): names the file."""

    def __init__(self, path: Path | str, why: str) -> None:
        super().__init__(f"cannot write {path}: {why}")
        self.path = Path(path)
        self.why = why

    def __reduce__(self):
        return (type(self), (str(self.path), self.why))

    @property
    def reason(self) -> str:
        """The run's end reason: short enough for history.nc's header in place (RUNNING)."""
        return f"write error: cannot write {self.path.name}: {self.why}"


def target_of(name: str | Path) -> Path:
    """The file a temporary name of emfabric.io.atomic stands for (".x.ab12cd34.partial.nc"
    -> "x.nc"), or the name itself."""
    import re

    path = Path(name)
    m = re.fullmatch(r"\.(.+)\.[A-Za-z0-9_]{8}\.partial(\.[^.]*)?", path.name)
    return path.with_name(m[1] + (m[2] or "")) if m else path


@contextlib.contextmanager
def _naming(path: Path | None, *, exact: bool = True):
    """Turn an OS error (or netCDF's "NetCDF: HDF error", which a full disk gives) while
    writing `path` into an OutputError that names it; exact=False: `path` is the folder being
    written, the error's own file name is named where it has one."""
    try:
        yield
    except OutputError:
        raise
    except OSError as err:
        _keep_unclosed(err)
        where = path if exact or not err.filename else target_of(err.filename)
        raise OutputError(where if where is not None else "?", err.strerror or str(err)) \
            from err
    except RuntimeError as err:
        if path is None or not _keep_unclosed(err):
            raise
        note = _free_space(path) if "NetCDF" in str(err) else ""  # "NetCDF: HDF error"
        raise OutputError(path, f"{err}{note}") from err


_UNCLOSED: list = []
"""netCDF4 Datasets whose close failed (a full disk), kept for the life of the process:
netCDF4 would close them again when they are collected, by then perhaps another file's
handle (a crash, seen on a full disk, before the run's status was recorded)."""


def _keep_unclosed(err: BaseException) -> bool:
    """Keep the netCDF4 Datasets that the frames of `err` (and the errors it arose from)
    hold; return whether netCDF4 raised it (its "NetCDF: …" errors and the OS errors it
    passes on as RuntimeError)."""
    from_netcdf = False
    seen: set[int] = set()
    while err is not None and id(err) not in seen:
        seen.add(id(err))
        tb = err.__traceback__
        while tb is not None:
            frame = tb.tb_frame
            from_netcdf |= "netCDF4" in frame.f_code.co_filename
            for value in list(frame.f_locals.values()):
                kind = type(value)
                if kind.__name__ == "Dataset" and kind.__module__.startswith("netCDF4") \
                        and not any(value is k for k in _UNCLOSED):
                    _UNCLOSED.append(value)
            tb = tb.tb_next
        err = err.__context__
    return from_netcdf


def _snapshot_naming(out: Path | None):
    """_naming for Snapshots.take, which writes the snapshot's .vtu files into out/vtk."""
    return _naming(out / "vtk" if out is not None else None, exact=False)


def _free_space(path: Path) -> str:
    """" (N bytes free on its disk)" where the disk of `path` is (nearly) full, else ""."""
    import shutil

    try:
        free = shutil.disk_usage(path.parent).free
    except OSError:
        return ""
    return f" ({free} bytes free on its disk)" if free < 1 << 24 else ""


@contextlib.contextmanager
def _signals_deferred(stop: bool = False):
    """Hold SIGINT, SIGTERM and SIGHUP while files are written (main thread only). The
    handler's KeyboardInterrupt must not land inside a write: raised while xarray held its
    netCDF lock (a plain, not reentrant lock) it left the lock taken, and closing the file then
    waited on it for ever (a run given SIGHUP as it wrote a checkpoint never exited).
    stop: a signal that arrived meanwhile stops the run at its next step (_STOP), as the
    handler would have; else (the final files) it is only logged."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    names = [n for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n)]
    old = {}
    for n in names:
        sig = getattr(signal, n)
        old[sig] = signal.signal(sig, lambda s, _f: caught.append(s))
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
    if caught:
        if stop:
            _STOP.set()
        else:
            log.info("signal received while writing the files: they are complete")
