"""Progress of a run, for people at a terminal and for logs (issue 25, item 4).

`make_progress` picks one of two displays by whether the console (stderr) is a terminal:

* a terminal: a rich live display, laid out for the console's width so that nothing is cut at
  80 columns: a bar line, then the labelled fields packed into as many lines as they need (a
  field never split), e.g. (a real demo-small run, 11 x 11 nodes, at 80 columns)::

      demo-small ━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━━  27 %
        t = 400 µs / 1.5 ms · step 700 · Δt = 5.4e-7 s · contact nodes 5
        elapsed 0:00:02 · left ~0:00:00 · end of contact ~697 µs

* not a terminal (stderr sent to a file, a pipe, a batch system's log): a plain line at once,
  then one every `interval` seconds of wall time (default 5 s), and a last one at the end,
  each written straight to the stream (never wrapped: one line each, wrapped here) and
  flushed::

      emfabric: t = 586.1 µs (39 %), step 1025, Δt = 6.0e-7 s, contact nodes 2,
          wall 0:00:02, left ~0:00:00 (to the expected end of contact at ~697 µs)
      emfabric: t = 723.1 µs (48 %), step 1252, Δt = 6.0e-7 s, contact nodes 0,
          wall 0:00:03, ended

The time left is wall time per simulated second so far (measured from the end of the first
step, so the kernels' compile is not counted) × the simulated time still to run, and the
simulated time still to run is the one to the *expected end of contact* (`expected_end`), not
only to `solver.end_time` (the line says which).

``emfabric run`` (cli/run.py) wraps the run in ``with make_progress(None, sc, console,
quiet=quiet, history=...) as progress:`` and passes ``progress`` (None with --quiet) to the
runner as its progress callback.
"""

from __future__ import annotations

import contextlib
import math
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import IO, NamedTuple

import numpy as np
from rich.console import Console, ConsoleOptions, RenderResult
from rich.text import Text

INTERVAL = 5.0
"""Wall seconds between two progress lines when stderr is not a terminal."""
SAMPLES = 2000
"""Samples of the projectile's motion a run keeps at most (one every end_time / SAMPLES of
simulated time): enough to place the start of contact and the turning point to 0.05 % of
end_time, few enough to cost nothing."""
FIT = 8
"""Samples the deceleration is fitted over (least squares: a straight line v_n(t))."""
DEPTH_FRACTION = 0.25
"""Before contact: the depth at which the fabric is expected to stop the projectile, as a
fraction of the sheet's smaller side (demo-small, 250 m/s on 25.4 cm: 6 cm)."""


class Sample(NamedTuple):
    """The projectile's motion at one time: what `expected_end` reads."""

    t: float
    """Time [s]."""
    v_n: float
    """Centre-of-mass velocity along the flight direction [m/s]: positive while it moves into
    the sheet, negative once it comes back; NaN without a projectile."""
    contacts: int
    """Nodes in contact."""
    gap: float = math.nan
    """Clearance along the flight direction between the projectile and the nearest node under
    it [m] (before contact; inf: no node under its path; NaN: not measured)."""


def expected_end(samples: Sequence[Sample], end_time: float, *,
                 depth: float | None = None, fit: int = FIT) -> float:
    """When the projectile's contact with the fabric is expected to end [s], from its motion
    so far (`samples`, in time order); `end_time` where no estimate can be made. The result
    lies between the last sample's time and end_time.

    The model is a constant-deceleration rebound. A body that meets the sheet at t0 with
    normal speed v0 and is slowed at a constant rate d stops (deepest point) at
    t_s = t0 + v0/d and, if the fabric gives back what it took, comes back along the same path
    in the same time: contact ends at t_end = 2·t_s − t0, symmetric about the turning point.
    The same closed form read at a later time t, where the speed is v_n, is t_s = t + v_n/d, so

        t_end = 2·(t + v_n/d) − t0.

    * In contact, still moving in (v_n > 0), decelerating: d is the slope of a least-squares
      line through v_n(t) over the last `fit` samples since contact began, and t0 the first
      sample in contact. A membrane stiffens as it deflects, so d grows on the way in and
      v_n/d overestimates the time to the turning point: the estimate comes down towards the
      true end as the run goes, and is exact for a constant deceleration.
    * Past the turning point (v_n has changed sign since contact began, at t_s found by linear
      interpolation between samples): t_end = 2·t_s − t0 while that lies ahead.
    * Before contact, moving towards the sheet with a measured `gap`: contact at
      t_c = t + gap/v_n, and, given a `depth` at which the fabric is expected to stop it, a
      contact of 4·depth/v_n (constant deceleration from v_n to rest over `depth` takes
      2·depth/v_n, and as long again back): t_end = t_c + 4·depth/v_n.
    * No estimate (end_time): no samples or no projectile (v_n NaN); not yet in contact and not
      approaching, no node under its path, or no `depth`; in contact and not decelerating (it
      perforates, or a field drives it); contact over, or the symmetric end already passed.

    The contact start of a resumed run is the first sample given: pass the resumed history's
    records (`samples_from_history`) so that it is the true one.
    """
    if not samples:
        return end_time
    last = samples[-1]
    t, v = float(last.t), float(last.v_n)
    if not math.isfinite(v):
        return end_time

    def clamp(te: float) -> float:
        return end_time if not te > t else min(te, end_time)

    first = next((k for k, s in enumerate(samples) if s.contacts > 0), None)
    if first is None:  # not touched yet: time to contact and a typical contact
        gap = float(last.gap)
        if v > 0 and math.isfinite(gap) and depth is not None and depth > 0:
            return clamp(t + max(gap, 0.0) / v + 4.0 * depth / v)
        return end_time
    t0 = float(samples[first].t)
    since = samples[first:]
    # the turning point: v_n from > 0 to <= 0 after contact began
    for a, b in zip(since, since[1:], strict=False):
        if a.v_n > 0 >= b.v_n:
            ts = a.t + (b.t - a.t) * a.v_n / (a.v_n - b.v_n)
            if last.contacts == 0:
                return end_time  # contact over: the stop rule ends the run
            te = 2.0 * ts - t0
            return clamp(te) if te > t else end_time
    if v <= 0:  # moving out without having moved in since contact: nothing to go by
        return end_time
    window = since[-fit:]
    if len(window) < 2:
        return end_time
    ts_ = np.array([s.t for s in window], dtype=float)
    vs = np.array([s.v_n for s in window], dtype=float)
    slope = float(np.polyfit(ts_ - ts_[-1], vs, 1)[0]) if len(window) > 2 else \
        float((vs[1] - vs[0]) / (ts_[1] - ts_[0]))
    decel = -slope
    if not (decel > 0 and math.isfinite(decel)):
        return end_time  # not slowing down: perforating or driven
    return clamp(2.0 * (t + v / decel) - t0)


def samples_from_history(history, direction) -> list[Sample]:
    """The Samples of a run's history (an xarray Dataset of history.nc, or its path): time,
    the projectile velocity along `direction` (the flight direction) and the contact nodes."""
    import xarray as xr

    ds = xr.open_dataset(history) if isinstance(history, (str, Path)) else history
    try:
        t = np.asarray(ds["time"].values, dtype=float)
        v = np.asarray(ds["projectile_velocity"].values, dtype=float) @ np.asarray(
            direction, dtype=float)
        k = np.asarray(ds["contact_nodes"].values)
    finally:
        if ds is not history:
            ds.close()
    return [Sample(float(a), float(b), int(c)) for a, b, c in zip(t, v, k, strict=True)]


def clock_text(seconds: float) -> str:
    """Wall time as h:mm:ss."""
    s = max(int(round(seconds)), 0)
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def time_text(seconds: float, digits: int = 3) -> str:
    """Simulated time with a unit that keeps the number between 1 and 1000: 312 µs, 1.5 ms."""
    a = abs(seconds)
    units = ((1.0, "s"), (1e-3, "ms"), (1e-6, "µs"), (1e-9, "ns"))
    scale, unit = next(((sc, u) for sc, u in units if a >= sc * (1 - 0.5 * 10 ** -digits)),
                       units[-1])
    if a == 0:
        scale, unit = 1e-6, "µs"
    return f"{seconds / scale:.{digits}g} {unit}"


def step_text(dt: float) -> str:
    """A time step as 9.1e-8 s."""
    mantissa, exponent = f"{dt:.1e}".split("e")
    return f"{mantissa}e{int(exponent)} s"


class RunProgress:
    """The numbers a progress display shows, kept up to date by the runner's callback
    (call the object: (State, StepInfo)). Per step it copies a few numbers; every
    end_time / SAMPLES of simulated time it samples the projectile's motion for the estimate
    of the time left. Subclasses show the numbers (`tick` each step, `close` at the end).

    clock: wall time source (time.monotonic; tests inject a fake one)."""

    def __init__(self, *, name: str, end_time: float, direction=(0.0, 0.0, -1.0),
                 bound: float = 0.0, has_body: bool = True,
                 clock: Callable[[], float] = time.monotonic,
                 seed: Sequence[Sample] = ()) -> None:
        self.name = name
        self.end_time = float(end_time)
        self.direction = np.asarray(direction, dtype=float)
        self.bound = float(bound)
        self.has_body = has_body
        self.clock = clock
        self.started = clock()
        self.samples: list[Sample] = list(seed)
        self._seed = len(self.samples)
        self._spacing = self.end_time / SAMPLES
        self._next_sample = -math.inf
        self._depth: float | None = None
        self._first: tuple[float, float] | None = None  # (wall, t) after the first step
        self._touched = any(s.contacts for s in self.samples)
        self.t = 0.0
        self.steps = 0
        self.dt = 0.0
        self.contacts = 0
        self.calls = 0

    def __call__(self, state, info) -> None:
        now = self.clock()
        t = float(state.t)
        if self._first is None:
            self._first = (now, t)
            if self._seed:  # a resumed run: drop the records past the resumed state
                self.samples = [s for s in self.samples if s.t < t]
                self._touched = any(s.contacts for s in self.samples)
            if state.node_x.size:
                xs, ys = state.node_x[0], state.node_x[1]
                side = min(float(np.ptp(xs)), float(np.ptp(ys)))
                self._depth = DEPTH_FRACTION * side if side > 0 else None
        self.calls += 1
        self.t, self.steps, self.dt, self.contacts = t, int(state.steps), float(info.dt), \
            int(info.contacts)
        if t >= self._next_sample:
            self._next_sample = t + self._spacing
            self.samples.append(self._sample(state, info))
        self.tick(now)

    def _sample(self, state, info) -> Sample:
        if not self.has_body:
            return Sample(float(state.t), math.nan, int(info.contacts))
        d = self.direction
        body_x = np.asarray(state.body_x, dtype=float)
        v_n = float(np.asarray(state.body_v, dtype=float) @ d)
        gap = math.nan
        self._touched = self._touched or int(info.contacts) > 0
        if not self._touched:
            # before contact: the nearest node under the projectile's path
            rel = state.node_x - body_x[:, None]
            along = d @ rel
            lateral2 = np.einsum("ij,ij->j", rel, rel) - along**2
            under = (lateral2 <= self.bound**2) & (along > -self.bound)
            gap = float(along[under].min()) - self.bound if under.any() else math.inf
        return Sample(float(state.t), v_n, int(info.contacts), gap)

    # what the displays show
    def expected(self) -> float:
        """The expected end of contact, or end_time (see expected_end)."""
        return expected_end(self.samples, self.end_time, depth=self._depth)

    def elapsed(self, now: float | None = None) -> float:
        return (self.clock() if now is None else now) - self.started

    def left(self, now: float | None = None) -> tuple[float | None, float]:
        """(wall seconds left or None while not known, the simulated time it runs to)."""
        target = self.expected()
        if self._first is None:
            return None, target
        now = self.clock() if now is None else now
        wall0, t0 = self._first
        if not (self.t > t0 and now > wall0):
            return None, target
        rate = (now - wall0) / (self.t - t0)
        return rate * max(target - self.t, 0.0), target

    def fraction(self) -> float:
        return min(max(self.t / self.end_time, 0.0), 1.0) if self.end_time > 0 else 1.0

    def tick(self, now: float) -> None:
        """Called after every step."""

    def close(self) -> None:
        """Called once when the run is over."""


class LineProgress(RunProgress):
    """Plain progress lines into a stream (a log): the first at once, then one every
    `interval` wall seconds, a last one at the end; each flushed."""

    def __init__(self, stream: IO[str], *, interval: float = INTERVAL, **kwargs) -> None:
        super().__init__(**kwargs)
        self.stream = stream
        self.interval = float(interval)
        self._next_line = -math.inf

    def tick(self, now: float) -> None:
        if now >= self._next_line:
            self._next_line = now + self.interval
            self.write(now)

    def line(self, now: float | None = None, final: bool = False) -> str:
        now = self.clock() if now is None else now
        head = (f"emfabric: t = {time_text(self.t, 4)} ({100 * self.fraction():.0f} %), "
                f"step {self.steps}, Δt = {step_text(self.dt)}, contact nodes "
                f"{self.contacts}, wall {clock_text(self.elapsed(now))}")
        if final:
            return head + ", ended"
        wall, target = self.left(now)
        left = "left ?" if wall is None else f"left ~{clock_text(wall)}"
        if target < self.end_time:
            why = f"to the expected end of contact at ~{time_text(target)}"
        else:
            why = f"to end_time {time_text(self.end_time)}"
        return f"{head}, {left} ({why})"

    def write(self, now: float | None = None, final: bool = False) -> None:
        self.stream.write(self.line(now, final) + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.calls:
            self.write(final=True)


class _View:
    """The live display's renderable: laid out at render time for the width it gets."""

    def __init__(self, progress: LiveProgress) -> None:
        self.progress = progress

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        yield from self.progress.lines(options.max_width)


class LiveProgress(RunProgress):
    """A rich live display on a terminal: a bar line, then labelled fields packed into lines
    that fit the width (a field is never cut: one that does not fit goes to the next line)."""

    def __init__(self, console: Console, *, auto_refresh: bool = True,
                 refresh_every: float = 0.25, **kwargs) -> None:
        super().__init__(**kwargs)
        from rich.live import Live

        self.console = console
        self.refresh_every = refresh_every
        self._next_refresh = -math.inf
        self.final = False
        self.live = Live(_View(self), console=console, auto_refresh=auto_refresh,
                         refresh_per_second=1.0 / refresh_every, transient=False)
        self.live.start()

    def fields(self, now: float | None = None) -> list[str]:
        now = self.clock() if now is None else now
        if not self.calls:
            return [f"t = 0 / {time_text(self.end_time)}", "starting (the first step)",
                    f"elapsed {clock_text(self.elapsed(now))}"]
        out = [f"t = {time_text(self.t)} / {time_text(self.end_time)}",
               f"step {self.steps}", f"Δt = {step_text(self.dt)}",
               f"contact nodes {self.contacts}"]
        if self.final:
            out.append(f"elapsed {clock_text(self.elapsed(now))} · ended")
            return out
        wall, target = self.left(now)
        left = "left ?" if wall is None else f"left ~{clock_text(wall)}"
        out.append(f"elapsed {clock_text(self.elapsed(now))} · {left}")
        if target < self.end_time:
            out.append(f"end of contact ~{time_text(target)}")
        return out

    def lines(self, width: int) -> list[Text]:
        pct = f" {100 * self.fraction():3.0f} %"
        name = self.name if len(self.name) <= max(width // 3, 8) else \
            self.name[:max(width // 3, 8) - 1] + "…"
        bar_width = max(width - len(name) - len(pct) - 1, 0)
        done = int(round(bar_width * self.fraction()))
        head = Text(name, style="bold", no_wrap=True, overflow="crop")
        head.append(" ")
        head.append("━" * done, style="bar.finished" if self.final else "bar.complete")
        head.append("━" * (bar_width - done), style="bar.back")
        head.append(pct, style="progress.percentage")
        out = [head]
        indent, sep = "  ", " · "
        line = ""
        for f in self.fields():
            if line and len(indent) + len(line) + len(sep) + len(f) > width:
                out.append(Text(indent + line, no_wrap=True, overflow="fold"))
                line = f
            else:
                line = f if not line else line + sep + f
        if line:
            out.append(Text(indent + line, no_wrap=True, overflow="fold"))
        return out

    def tick(self, now: float) -> None:
        if now >= self._next_refresh:
            self._next_refresh = now + self.refresh_every
            self.live.refresh()

    def close(self) -> None:
        self.final = True
        if not self.calls:  # the run failed before its first step: leave nothing behind
            self.live.transient = True
        self.live.stop()  # renders once more: the final numbers stay on the screen


def _describe(model, scenario) -> dict:
    """What the display needs from the Model (preferred) or the Scenario."""
    if model is not None:
        sc = model.scenario
        return {"name": sc.name if sc is not None else "run",
                "end_time": model.options.end_time,
                "direction": model.flight_direction,
                "bound": model.geometry.bound if model.has_body else 0.0,
                "has_body": model.has_body}
    from emfabric.sim.geometry import geometry_of

    pr = scenario.projectile
    has_body = pr.shape != "none"
    v = np.asarray(pr.velocity, dtype=float)
    speed = float(np.linalg.norm(v))
    direction = v / speed if speed > 0 else np.array([0.0, 0.0, -1.0])  # as the builder's
    bound = 0.0
    if has_body:
        # a shape the builder refuses is reported by the run itself, not here
        with contextlib.suppress(Exception):
            bound = float(geometry_of(pr).bound)
    return {"name": scenario.name, "end_time": scenario.solver.end_time,
            "direction": direction, "bound": bound, "has_body": has_body}


@contextlib.contextmanager
def make_progress(model=None, scenario=None, console: Console | None = None,
                  stream: IO[str] | None = None, *, quiet: bool = False,
                  interval: float = INTERVAL, clock: Callable[[], float] = time.monotonic,
                  history: str | Path | None = None,
                  auto_refresh: bool = True) -> Iterator[RunProgress | None]:
    """The progress display of one run, as a context manager that yields the callback to pass
    to emfabric.runner.loop.run / resume (`progress=`); None with quiet.

    model or scenario: what is run (a Model, else its Scenario). console: where messages go
    (default: a rich Console on stderr); a terminal gets the live display (LiveProgress),
    anything else plain lines (LineProgress) into `stream` (default: the console's file)
    every `interval` wall seconds. history: a resumed run's history.nc, whose records seed
    the estimate of the end of contact. clock and auto_refresh: for tests."""
    if quiet:
        yield None
        return
    if model is None and scenario is None:
        raise ValueError("make_progress needs the model or the scenario it shows")
    console = console if console is not None else Console(stderr=True)
    info = _describe(model, scenario)
    seed: list[Sample] = []
    if history is not None and info["has_body"] and Path(history).is_file():
        with contextlib.suppress(OSError, ValueError, KeyError):
            seed = samples_from_history(history, info["direction"])
    common = dict(clock=clock, seed=seed, **info)
    if console.is_terminal and not console.is_dumb_terminal:
        shown: RunProgress = LiveProgress(console, auto_refresh=auto_refresh, **common)
    else:
        shown = LineProgress(stream if stream is not None else (console.file or sys.stderr),
                             interval=interval, **common)
    try:
        yield shown
    finally:
        shown.close()
