"""Studies: many runs of one scenario, on Dask (``emfabric sweep``, ``ballistic-limit``,
``design-field``).

A study file names a base scenario, overrides for every case and the axes whose product are
the cases (or a Latin hypercube over scalar ranges)::

    base = "paper-field"              # built-in name, or a scenario file (relative: to the study)
    keep_histories = false            # keep each case's run folder (history, snapshots)
    [set]
    "fabric.nodes" = [40, 40]
    [axes]
    "field.B" = [[0, 0, 0], [0.025, 0, 0], [0.05, 0, 0]]
    "fabric.material.seed" = [1, 2, 3]
    # or, instead of [axes]:
    # [lhs]
    # samples = 20
    # seed = 1
    # ranges = {"projectile.radius" = [0.008, 0.012], "field.B" = ...}   (scalars only)

Each case is a full scenario, validated before anything runs, and keyed by the SHA-256 of its
TOML text and the package version: its result is one small JSON file in ``DIR/cases/`` written
atomically when it arrives, so a rerun of the study reuses every finished case (a diverged or
failed case is finished too: it is recorded with its message) and runs only the rest; a case
whose worker died is retried by Dask (and if the whole study was killed, simply run on the next
invocation). The worker receives the scenario's TOML text, never a pickled model.

The study folder is held by the study while it runs (emfabric.io.lock; a case kept with
``keep_histories`` holds its own ``runs/<key>/`` while it runs). Dask's own log messages and
warnings (a busy dashboard port, a worker restarted) stay out of the terminal unless
``EMFABRIC_DASK_VERBOSE=1`` (the study commands' ``--verbose``); the local workers ignore
Ctrl-C (the study stops them: no worker tracebacks).
"""

from __future__ import annotations

import contextlib
import difflib
import hashlib
import itertools
import json
import logging
import math
import os
import signal
import threading
import time
import tomllib
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    ValidationError,
    model_validator,
)

from emfabric.config.scenario import (
    Scenario,
    ScenarioError,
    apply_overrides,
    load_scenario,
    scenario_from_dict,
)

METRICS: dict[str, tuple[str, str]] = {
    "residual_speed": ("m s-1", "speed of the projectile at the end of the run"),
    "perforated": ("1", "1 if the run ended by perforation (or at end_time moving forward, "
                        "past the sheet's plane and clear of the fabric), 0 if it rebounded, "
                        "stopped or never reached the sheet, -1 undecided (still in contact "
                        "at end_time, diverged, failed)"),
    "plies_perforated": ("1", "plies of the pack the projectile has passed (every node of the "
                              "ply still held by an intact yarn behind it), -1 failed"),
    "max_tilt": ("rad", "largest angle of the projectile's axis from its initial direction"),
    "max_yaw": ("rad", "largest angle between the projectile's axis and its velocity"),
    "final_angular_velocity": ("rad s-1", "angular velocity of the projectile at the end"),
    "energy_absorbed": ("J", "projectile kinetic energy lost (translation and rotation)"),
    "broken_yarns": ("1", "yarn segments broken at the end"),
    "max_deflection": ("m", "largest out-of-plane displacement of the fabric"),
    "status": ("", "complete | partial | diverged | failed"),
    "wall_time": ("s", "wall time of the case's run"),
}
"""The per-case results (variable name -> (units, meaning)) of results.nc."""


class StudyError(ValueError):
    """A study file or study option that cannot be used: says what and what is allowed."""


class _Lhs(BaseModel):
    model_config = ConfigDict(extra="forbid")
    samples: int = Field(ge=1, le=100000)
    seed: int = 0
    ranges: dict[str, tuple[float, float]]


class Study(BaseModel):
    """A study file (see the module docstring)."""

    model_config = ConfigDict(extra="forbid")
    base: str
    set: dict[str, Any] = {}
    axes: dict[str, list[Any]] = {}
    lhs: _Lhs | None = None
    keep_histories: StrictBool = False

    @model_validator(mode="after")
    def _axes_or_lhs(self) -> Study:
        if self.lhs is not None and self.axes:
            raise ValueError("give [axes] or [lhs], not both")
        if self.lhs is None and not self.axes:
            raise ValueError("no [axes] or [lhs]: a study varies at least one key over its "
                             "cases (for one run of a scenario: emfabric run)")
        for key, values in self.axes.items():
            if not values:
                raise ValueError(f"axes.{key!r} is empty; allowed: a list of values")
            for i, value in enumerate(values):
                if any(value == earlier for earlier in values[:i]):
                    raise ValueError(f"axes.{key!r} has the value {value!r} twice; allowed: "
                                     "distinct values (each is a coordinate of results.nc)")
        return self

    def set_and_varied(self) -> list[str]:
        """Keys both under [set] and varied by [axes] or [lhs] (the varied values win)."""
        varied = set(self.axes) | (set(self.lhs.ranges) if self.lhs is not None else set())
        return sorted(varied & set(self.set))


@dataclass
class Case:
    """One case of a study: where it sits on the axes, its overrides and scenario."""

    index: tuple[int, ...]
    overrides: dict[str, Any]
    scenario: Scenario
    key: str = ""
    text: str = ""


@dataclass
class Plan:
    """A study's cases, in the order of their axes (the first axis varies slowest)."""

    study: Study
    base: Scenario
    dims: list[str]
    coords: dict[str, list[Any]]
    cases: list[Case] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    """What in the study file is probably not what was meant (load_study; the command line
    prints them)."""


def case_key(text: str) -> str:
    """The case's identity: SHA-256 of its scenario TOML and the package version (16 hex)."""
    from emfabric import __version__

    return hashlib.sha256(f"{__version__}\n{text}".encode()).hexdigest()[:16]


def _flatten(table: dict[str, Any], prefix: str, out: dict[str, Any], where: str) -> None:
    for key, value in table.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            _flatten(value, f"{name}.", out, where)
        elif name in out:
            raise StudyError(f"{where}: the key {name!r} is given twice (quoted and as TOML "
                             f"dotted keys)")
        else:
            out[name] = value


def _dotted(data: dict[str, Any], path: Path) -> dict[str, Any]:
    """[set], [axes] and [lhs].ranges keyed by dotted scenario keys, whichever way the file
    writes them: quoted ("fabric.nodes" = …) or as TOML dotted keys (fabric.nodes = …, which
    TOML reads as nested tables)."""
    data = dict(data)
    for section in ("set", "axes"):
        if isinstance(data.get(section), dict):
            flat: dict[str, Any] = {}
            _flatten(data[section], "", flat, f"study file {str(path)!r}, [{section}]")
            data[section] = flat
    lhs = data.get("lhs")
    if isinstance(lhs, dict) and isinstance(lhs.get("ranges"), dict):
        flat = {}
        _flatten(lhs["ranges"], "", flat, f"study file {str(path)!r}, [lhs].ranges")
        data["lhs"] = {**lhs, "ranges": flat}
    return data


_STUDY_FORMS = {
    "base": "a built-in scenario name or a scenario file, in quotes",
    "set": "a table of dotted scenario keys and their values",
    "axes": "a table of dotted scenario keys and their lists of values",
    "lhs": "a table with samples, seed and ranges",
    "keep_histories": "true or false",
    "samples": "an integer from 1 to 100000",
    "seed": "an integer",
    "ranges": "a table of dotted scenario keys and their [low, high]",
}
"""What each key of a study file takes, in its messages."""


def _study_problem(e: dict) -> str:
    """One line for a study file's validation error, in the file's terms (the key, the value,
    what is allowed) rather than pydantic's."""
    loc = [str(p) for p in e["loc"]]
    kind = e["type"]
    if loc[:2] == ["lhs", "ranges"] and len(loc) > 2:
        # a range's own problem (not two numbers, or not numbers): the whole range
        return (f"lhs.ranges.{loc[2]!r} = {e.get('input')!r}: allowed: two numbers "
                f"[low, high]")
    if loc[:1] == ["axes"] and len(loc) > 1:
        return f"axes.{loc[1]!r} = {e.get('input')!r}: allowed: a list of values"
    where = ".".join(loc)
    if kind == "extra_forbidden":
        allowed = ["samples", "seed", "ranges"] if loc[:-1] == ["lhs"] else list(
            Study.model_fields)
        close = difflib.get_close_matches(loc[-1], allowed, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        return f"{where}: unknown key{hint}; allowed: {', '.join(allowed)}"
    if kind == "missing":
        return f"{where}: missing; needs {_STUDY_FORMS[loc[-1]]}"
    if kind in ("value_error", "assertion_error"):
        msg = str(e.get("ctx", {}).get("error", e["msg"]))
        return f"{where}: {msg}" if loc else msg
    needs = _STUDY_FORMS.get(loc[-1] if loc else "", e["msg"])
    return f"{where or 'the study file'} = {e.get('input')!r}: allowed: {needs}"


def load_study(path: str | Path) -> Plan:
    """Read and check a study file; every case's scenario is validated here, before any run
    (errors name the case's overrides and the key)."""
    path = Path(path)
    if not path.is_file():
        raise StudyError(f"study file {str(path)!r} does not exist")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise StudyError(f"study file {str(path)!r}: invalid TOML ({err})") from None
    try:
        study = Study.model_validate(_dotted(data, path))
    except ValidationError as err:
        lines = [f"  {_study_problem(e)}" for e in err.errors()]
        raise StudyError(f"study file {str(path)!r}:\n" + "\n".join(lines)) from None
    base_path = Path(study.base)
    if base_path.suffix == ".toml" and not base_path.is_absolute():
        base_path = path.parent / base_path
    plan = plan_study(study, str(base_path) if base_path.suffix == ".toml" else study.base)
    for key in study.set_and_varied():
        plan.warnings.append(f"study file {str(path)!r}: {key!r} is both set in [set] and "
                             "varied; the varied values replace the set one")
    for w in plan.warnings:
        logging.getLogger("emfabric").warning(w)
    return plan


def plan_study(study: Study, base: str) -> Plan:
    """The cases of a study (scenarios validated; keys computed)."""
    try:
        scenario = load_scenario(base, dict(study.set))
    except ScenarioError as err:
        raise StudyError(f"base = {study.base!r}{' with [set]' if study.set else ''}: {err}"
                         ) from None
    if study.lhs is not None:
        dims = ["case"]
        rng = np.random.default_rng(study.lhs.seed)
        n = study.lhs.samples
        coords: dict[str, list[Any]] = {"case": list(range(n))}
        columns = {}
        for key, (lo, hi) in study.lhs.ranges.items():
            if not (math.isfinite(lo) and math.isfinite(hi) and hi >= lo):
                raise StudyError(f"lhs.ranges.{key!r} = [{lo}, {hi}]: allowed: finite low ≤ "
                                 f"high")
            # the range itself, before any sample: a key that takes integers (a seed, a ply
            # count) was refused case by case, naming a drawn 5.277… the file does not hold
            try:
                apply_overrides(scenario, {key: 0.5 * (lo + hi)})
            except ScenarioError as err:
                why = " ".join(str(err).split())  # one line
                raise StudyError(f"lhs.ranges.{key!r} = [{lo}, {hi}]: its middle is refused "
                                 f"({why}); allowed: a key of real values over a range it "
                                 f"takes (a Latin hypercube draws real numbers: vary a key of "
                                 f"integers under [axes])") from None
            # one point in each of n equal strata, the strata shuffled per key
            u = (rng.permutation(n) + rng.random(n)) / n
            columns[key] = [float(lo + (hi - lo) * x) for x in u]
        combos = [((i,), {k: columns[k][i] for k in columns}) for i in range(n)]
    else:
        dims = list(study.axes)
        coords = {k: list(v) for k, v in study.axes.items()}
        combos = [(idx, {k: study.axes[k][i] for k, i in zip(dims, idx, strict=True)})
                  for idx in itertools.product(*(range(len(v)) for v in study.axes.values()))]
    plan = Plan(study, scenario, dims, coords)
    for idx, over in combos:
        try:
            sc = apply_overrides(scenario, over)
        except ScenarioError as err:
            raise StudyError(f"case {over}: {err}") from None
        text = sc.to_toml()
        plan.cases.append(Case(idx, over, sc, case_key(text), text))
    return plan


# --- one case, on a worker ------------------------------------------------------------------

def run_case(text: str, out: str | None, threads: int, explicit: bool = False
             ) -> dict[str, Any]:
    """Run the scenario whose TOML text is given and return its metrics (never raises for a
    run that diverges or fails: the status and message say so). Called on a Dask worker.
    threads: the Numba threads the case may use; explicit (the user's --threads): the case
    runs on that many, else on integrators.default_threads within them (one thread below
    its size threshold)."""
    import numba

    from emfabric.runner import DivergenceError, run

    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    t0 = time.perf_counter()
    sc = scenario_from_dict(tomllib.loads(text), "<study case>")
    message = ""
    if out is not None:
        from emfabric.io.lock import drop_foreign

        # a case Dask runs again after its worker on another host was lost: its lock is void
        drop_foreign(out)
    # the case's warnings (is the charge physical? a value far outside ballistic practice)
    # would print from every worker, once per case and without the command's "warning:": the
    # command that started the study prints the first case's once (cli.study._warn_actuation)
    # and each case keeps its own in its record (cases/<key>.json, "warnings")
    with captured_warnings() as warned:
        try:
            result = run(sc, out, threads=threads if explicit else None)
        except (DivergenceError, OSError, RuntimeError, ValueError, ArithmeticError) as exc:
            result = getattr(exc, "result", None)
            # a divergence's message says what it is; anything else is named by its class
            message = str(exc) if isinstance(exc, DivergenceError) else \
                f"{type(exc).__name__}: {exc}"
            if result is None:
                return {**_failed(message, time.perf_counter() - t0), "warnings": warned}
    metrics = metrics_of(result)
    metrics["message"] = message or result.end_reason
    metrics["warnings"] = warned
    return metrics


class _ThreadWarnings(logging.Handler):
    """The warnings one thread logs (captured_warnings)."""

    def __init__(self, thread: int) -> None:
        super().__init__(logging.WARNING)
        self.thread = thread
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.thread == self.thread:
            self.lines.append(record.getMessage())


@contextlib.contextmanager
def captured_warnings():
    """The warnings this thread logs to emfabric's logger inside the block, as a list (filled
    as they come), kept from the terminal: while a handler is attached, Python's last-resort
    handler, which would print each warning bare on stderr (a local cluster's workers share
    the terminal's), stays out. Another thread's records are not this block's (a worker may
    run cases in several threads, each in a block of its own); a handler of the process's own
    (the CLI's) still gets every record."""
    handler = _ThreadWarnings(threading.get_ident())
    logger = logging.getLogger("emfabric")
    logger.addHandler(handler)
    try:
        yield handler.lines
    finally:
        logger.removeHandler(handler)


def _failed(message: str, wall: float) -> dict[str, Any]:
    out: dict[str, Any] = {k: math.nan for k in METRICS}
    out.update(final_angular_velocity=[math.nan] * 3, perforated=-1, broken_yarns=-1,
               plies_perforated=-1,
               status="failed", message=message, wall_time=wall)
    return out


def metrics_of(result) -> dict[str, Any]:
    """The METRICS of a finished (or diverged) run: the run summary's figures under the
    study's names (emfabric.runner.summary)."""
    s = result.summary
    return {
        "status": s["status"],
        "wall_time": s["wall_time_s"],
        "broken_yarns": s["broken_yarns"],
        "max_deflection": s["max_deflection_m"],
        "perforated": s["perforated"],
        "plies_perforated": s.get("plies_perforated", -1),
        "residual_speed": s["residual_speed_m_s"],
        "max_tilt": s["max_tilt_rad"],
        "max_yaw": s["max_yaw_rad"],
        "final_angular_velocity": s["final_omega_rad_s"],
        "energy_absorbed": s["energy_absorbed_J"],
    }


# --- running a study ------------------------------------------------------------------------

@dataclass
class Outcome:
    """What a study did: counts and the results' path."""

    cases: int
    ran: int
    reused: int
    failed: int
    results: Path
    wall_time: float

    def summary(self) -> dict[str, Any]:
        return {"cases": self.cases, "ran": self.ran, "reused": self.reused,
                "failed": self.failed, "results": str(self.results),
                "wall_time": round(self.wall_time, 3)}


def _case_file(out: Path, case: Case) -> Path:
    return out / "cases" / f"{case.key}.json"


def read_case(out: Path, case: Case) -> dict[str, Any] | None:
    """The stored result of a case, or None (absent, unreadable, or another case's)."""
    path = _case_file(out, case)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and data.get("key") == case.key else None


def _store(out: Path, case: Case, metrics: dict[str, Any]) -> None:
    from emfabric.io.atomic import write_atomic

    record = {"key": case.key, "overrides": case.overrides, **metrics}
    text = json.dumps(record, indent=1, allow_nan=True)
    write_atomic(_case_file(out, case), lambda tmp: tmp.write_text(text, encoding="utf-8"))


DASK_VERBOSE = "EMFABRIC_DASK_VERBOSE"
"""Environment variable: "1" lets Dask's own log messages and warnings through."""


def dask_verbose() -> bool:
    return os.environ.get(DASK_VERBOSE, "").strip().lower() in ("1", "true", "yes", "on")


def _quiet_dask() -> None:
    """Dask's log messages below ERROR and its warnings out of the terminal (unless
    dask_verbose()): they speak of ports, heartbeats and restarts, not of the study."""
    if dask_verbose():
        return
    logging.getLogger("distributed").setLevel(logging.ERROR)
    warnings.filterwarnings("ignore", module=r"distributed(\.|$)")


@contextlib.contextmanager
def _shielded() -> Any:
    """While the local cluster starts its worker processes (or closes): SIGINT ignored (a
    child inherits SIG_IGN through exec and Python keeps it: the workers never see the
    terminal's Ctrl-C, which reaches the whole process group, so they print no tracebacks; the
    study stops them when it closes the cluster); SIGTERM and SIGHUP held until the cluster is
    up (an interrupted start leaves a half-made cluster that Dask fails to close at exit).
    Yields a list that holds the signals held. A Ctrl-C in these seconds is lost: press it
    again."""
    held: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield held
        return
    old = {signal.SIGINT: signal.signal(signal.SIGINT, signal.SIG_IGN)}
    for name in ("SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            sig = getattr(signal, name)
            old[sig] = signal.signal(sig, lambda s, _f: held.append(s))
    try:
        yield held
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def connect(workers: int | None, scheduler: str | None, threads: int | None
            ) -> tuple[Any, Any, int]:
    """(client, cluster or None, Numba threads per case). A local cluster of `workers`
    processes (default: one per two cores, at least one), or the scheduler at `scheduler`;
    threads per case default to cores // workers locally (no oversubscription), 1 on a
    scheduler (its workers' cores are theirs to share). The local cluster serves no dashboard
    on a fixed port (":0": none in use, no "Port 8787 is already in use"), its workers ignore
    Ctrl-C, and Dask's own messages stay quiet unless EMFABRIC_DASK_VERBOSE=1."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise StudyError("studies need Dask: pip install 'emfabric[studies]'") from None
    _quiet_dask()
    cores = os.cpu_count() or 1
    if scheduler is not None:
        if workers is not None:
            raise StudyError("--workers and --scheduler exclude each other: the scheduler's "
                             "workers are started by you")
        try:
            client = Client(scheduler, timeout="5s")
        except (ValueError, TypeError) as err:  # an address Dask cannot parse
            raise StudyError(f"--scheduler {scheduler!r}: not a Dask scheduler address "
                             f"({err}); allowed: tcp://HOST:PORT (or HOST:PORT), as `dask "
                             f"scheduler` prints it") from None
        except (OSError, TimeoutError) as err:
            raise StudyError(f"cannot reach the Dask scheduler at {scheduler!r} ({err}); "
                             f"start one with `dask scheduler` and `dask worker ADDRESS`, or "
                             f"leave out --scheduler for a local cluster") from None
        return client, None, threads or 1
    n = workers if workers is not None else max(1, cores // 2)
    if n < 1:
        raise StudyError(f"--workers {n}: allowed: 1 or more")
    per_case = threads or max(1, cores // n)
    with _shielded() as held:
        # dashboard_address None: no dashboard; the scheduler's HTTP server (which it starts
        # anyway) on any free port rather than 8787
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=None,
                               scheduler_kwargs={"dashboard_address": ":0"},
                               silence_logs=logging.WARNING if dask_verbose() else 50,
                               env={"NUMBA_NUM_THREADS": str(per_case)})
        client = Client(cluster)
    if held:  # SIGTERM or SIGHUP while the workers started: stop now, cluster closed
        client.close()
        cluster.close()
        raise KeyboardInterrupt
    return client, cluster, per_case


def run_cases(cases: list[Case], out: Path, client, threads: int, keep: bool,
              progress: Callable[[int, int], None] | None = None,
              explicit: bool = False) -> None:
    """Run the cases on the Dask client, storing each result (read_case) as it arrives. A
    worker that dies mid-case: Dask runs the case again (retries). threads, explicit: as
    run_case's."""
    from dask.distributed import as_completed

    futures = {}
    for case in cases:
        where = str(out / "runs" / case.key) if keep else None
        fut = client.submit(run_case, case.text, where, threads, explicit,
                            key=f"emfabric-case-{case.key}", pure=False, retries=2)
        futures[fut] = case
    done = 0
    for fut in as_completed(futures):
        case = futures[fut]
        try:
            metrics = fut.result()
        except Exception as exc:  # the worker died repeatedly, or an unexpected error
            metrics = _failed(f"{type(exc).__name__}: {exc}", math.nan)
        _store(out, case, metrics)
        done += 1
        if progress is not None:
            progress(done, len(cases))


def sweep(plan: Plan, out: str | Path, *, workers: int | None = None,
          scheduler: str | None = None, threads: int | None = None,
          progress: Callable[[int, int], None] | None = None) -> Outcome:
    """Run the study's cases that have no stored result, then write DIR/results.nc. The folder
    is held while the study runs (emfabric.io.lock: FolderInUse if another process holds it)."""
    from emfabric.io.lock import folder_lock

    out = Path(out)
    with folder_lock(out):
        return _sweep(plan, out, workers, scheduler, threads, progress)


def _sweep(plan: Plan, out: Path, workers: int | None, scheduler: str | None,
           threads: int | None, progress: Callable[[int, int], None] | None) -> Outcome:
    t0 = time.perf_counter()
    from emfabric.io.atomic import write_atomic

    text = _study_text(plan)  # the study as run, beside its results
    write_atomic(out / "study.json", lambda tmp: tmp.write_text(text, encoding="utf-8"))
    # a case stored without its run folder (the study once ran with keep_histories = false)
    # runs again to keep it; not one that failed before its run wrote anything
    keep = plan.study.keep_histories

    def stored(case: Case) -> bool:
        rec = read_case(out, case)
        return rec is not None and (not keep or (out / "runs" / case.key).is_dir()
                                    or rec.get("status") == "failed")

    todo = [c for c in plan.cases if not stored(c)]
    reused = len(plan.cases) - len(todo)
    if todo:
        client, cluster, per_case = connect(workers, scheduler, threads)
        interrupted = False
        try:
            run_cases(todo, out, client, per_case, plan.study.keep_histories, progress,
                      explicit=threads is not None)
        except KeyboardInterrupt:
            interrupted = True
            raise
        finally:
            release(client, cluster, interrupted)
    results, failed = collect(plan, out)
    return Outcome(len(plan.cases), len(todo), reused, failed, results,
                   time.perf_counter() - t0)


INTERRUPTED_CLOSE = 10.0
"""[s] How long an interrupted study waits for Dask to close its client and cluster."""


def release(client, cluster, interrupted: bool) -> None:
    """Close the client and the local cluster (if any). Interrupted: the local workers are
    ended first (stop_workers_now) and Dask's close is bounded (INTERRUPTED_CLOSE): nothing a
    study keeps depends on it, and the user is waiting. A second Ctrl-C does not break off the
    close."""
    with _shielded():
        if interrupted and cluster is not None:
            stop_workers_now()
        wait = {"timeout": INTERRUPTED_CLOSE} if interrupted else {}
        try:
            client.close(**wait)
            if cluster is not None:
                cluster.close(**wait)
        except (TimeoutError, OSError, RuntimeError):
            if not interrupted:
                raise


def stop_workers_now() -> None:
    """Interrupted: end the local cluster's worker processes at once (SIGTERM, then SIGKILL
    after a second). A worker compiling kernels (minutes on an empty cache) holds the
    interpreter and answers the cluster's polite close only when it is done; the cases they
    were running are lost either way (a study keeps only finished cases) and run again next
    time."""
    import multiprocessing

    children = multiprocessing.active_children()
    for proc in children:
        proc.terminate()
    deadline = time.monotonic() + 1.0
    for proc in children:
        proc.join(max(0.0, deadline - time.monotonic()))
        if proc.is_alive():
            proc.kill()
            proc.join(1.0)


def _study_text(plan: Plan) -> str:
    return json.dumps({"base": plan.study.base, "set": plan.study.set,
                       "axes": plan.study.axes,
                       "lhs": None if plan.study.lhs is None else plan.study.lhs.model_dump(),
                       "keep_histories": plan.study.keep_histories}, indent=1)


def collect(plan: Plan, out: Path) -> tuple[Path, int]:
    """Assemble DIR/results.nc from the stored case results (a case not run yet: NaN,
    status "missing"); return its path and the number of diverged or failed cases."""
    import xarray as xr

    from emfabric import __version__
    from emfabric.config.scenario import key_unit
    from emfabric.io.netcdf import write_netcdf, xyz_coordinate

    shape = tuple(len(plan.coords[d]) for d in plan.dims)
    data: dict[str, np.ndarray] = {k: np.full(shape, np.nan) for k in METRICS}
    data["perforated"] = np.full(shape, -1, dtype=np.int8)
    data["plies_perforated"] = np.full(shape, -1, dtype=np.int64)
    data["broken_yarns"] = np.full(shape, -1, dtype=np.int64)
    data["status"] = np.full(shape, "missing", dtype=object)
    data["message"] = np.full(shape, "", dtype=object)
    data["final_angular_velocity"] = np.full((*shape, 3), np.nan)
    data["case_key"] = np.full(shape, "", dtype=object)
    for case in plan.cases:
        rec = read_case(out, case)
        data["case_key"][case.index] = case.key
        if rec is None:
            continue
        for k in METRICS:
            if k in rec and rec[k] is not None:
                data[k][case.index] = rec[k]
        data["message"][case.index] = str(rec.get("message", ""))
    dims = plan.dims
    variables = {}
    for k, (units, meaning) in METRICS.items():
        d = (*dims, "xyz") if k == "final_angular_velocity" else dims
        attrs = {"long_name": meaning}
        if units:
            attrs["units"] = units
        variables[k] = (d, data[k].astype(str) if k == "status" else data[k], attrs)
    variables["message"] = (dims, data["message"].astype(str),
                            {"long_name": "why a case did not complete (or its end reason)"})
    variables["case_key"] = (dims, data["case_key"].astype(str),
                             {"long_name": "the case's key: cases/<key>.json, runs/<key>/"})
    coords: dict[str, Any] = {}
    for d in dims:
        values = plan.coords[d]
        arr = np.asarray(values) if d != "case" else np.arange(len(values))
        # the scenario key's unit on a numeric axis (its docstring's; "1": none)
        unit = {"units": u} if (u := key_unit(d)) is not None else {}
        if arr.ndim == 1 and arr.dtype.kind in "ifub":
            coords[d] = (d, arr, unit if arr.dtype.kind in "if" else {})
        elif arr.ndim == 1:
            coords[d] = (d, arr.astype(str))
        else:  # a vector-valued axis: an index dimension and the vectors as a variable
            coords[d] = (d, np.arange(len(values)))
            comp = f"{d}.component"
            variables[f"{d}.values"] = ((d, comp), arr.astype(float),
                                        {"long_name": f"the values of the axis {d}", **unit})
    if plan.study.lhs is not None:
        for key in plan.study.lhs.ranges:
            unit = {"units": u} if (u := key_unit(key)) is not None else {}
            variables[key] = (("case",), np.array([c.overrides[key] for c in plan.cases]),
                              {"long_name": f"sampled value of {key} (Latin hypercube)",
                               **unit})
    name, labels, attrs = xyz_coordinate()
    coords[name] = (name, labels, attrs)
    ds = xr.Dataset(variables, coords=coords)
    ds.attrs.update({"title": "emfabric study results", "emfabric_version": __version__,
                     "study": _study_text(plan), "base_scenario": plan.base.to_toml(),
                     "Conventions": "CF-1.10"})
    path = out / "results.nc"
    write_netcdf(ds, path)
    failed = int(np.isin(data["status"].astype(str), ("failed", "diverged")).sum())
    return path, failed
