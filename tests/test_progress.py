"""Progress for people and for logs (issue 25, item 4): emfabric.cli.progress."""

from __future__ import annotations

import io
import math
import re
from types import SimpleNamespace

import numpy as np
import pytest
from rich.console import Console

from emfabric.cli.progress import (
    LineProgress,
    LiveProgress,
    Sample,
    clock_text,
    expected_end,
    make_progress,
    samples_from_history,
    step_text,
    time_text,
)

ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


class FakeClock:
    """A wall clock the test moves by hand."""

    def __init__(self, now: float = 0.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def fake_step(t, steps=1, dt=1e-7, contacts=0, body_v=(0.0, 0.0, -250.0),
              body_x=(0.0, 0.0, 0.03)):
    """A (State, StepInfo) pair with what the progress display reads."""
    xs, ys = np.meshgrid(np.linspace(-0.127, 0.127, 11), np.linspace(-0.127, 0.127, 11))
    node_x = np.array([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    state = SimpleNamespace(t=t, steps=steps, node_x=node_x, body_x=np.array(body_x, float),
                            body_v=np.array(body_v, float))
    return state, SimpleNamespace(dt=dt, contacts=contacts)


# expected_end: the constant-deceleration rebound

def rebound_samples(t0=1e-5, v0=250.0, decel=5e5, until=None, dt=1e-6, free=True):
    """A body at v0 that touches at t0 and is slowed at `decel` while in contact (then
    leaves at t0 + 2 v0/decel): samples every dt up to `until`."""
    t_end = t0 + 2 * v0 / decel
    out = []
    for k in range(int(round((until if until is not None else t_end) / dt)) + 1):
        t = k * dt
        if t < t0 - 1e-15:
            out.append(Sample(t, v0 if free else math.nan, 0, 0.0))
        elif t <= t_end:
            out.append(Sample(t, v0 - decel * (t - t0), 5))
        else:
            out.append(Sample(t, -v0, 0))
    return out


@pytest.mark.parametrize("until", [2e-5, 1e-4, 3e-4, 5e-4, 5.09e-4, 7e-4, 1e-3])
def test_expected_end_is_the_closed_form_rebound_time(until):
    t0, v0, decel = 1e-5, 250.0, 5e5
    samples = rebound_samples(t0, v0, decel, until)
    assert expected_end(samples, 5e-3) == pytest.approx(t0 + 2 * v0 / decel, rel=1e-9)


def test_expected_end_falls_back_to_end_time():
    end = 1.5e-3
    assert expected_end([], end) == end
    # no projectile
    assert expected_end([Sample(0.0, math.nan, 0), Sample(1e-6, math.nan, 3)], end) == end
    # in contact, speeding up (a field drives it) or not slowing (perforating)
    pushed = [Sample(k * 1e-6, 100.0 + k, 4) for k in range(10)]
    assert expected_end(pushed, end) == end
    steady = [Sample(k * 1e-6, 100.0, 4) for k in range(10)]
    assert expected_end(steady, end) == end
    # contact over after the rebound: the stop rule ends the run
    over = rebound_samples(until=1.2e-3)
    assert expected_end(over, 5e-3) == 5e-3
    # a rebound expected beyond end_time: end_time
    assert expected_end(rebound_samples(decel=1e5, until=1e-4), end) == end
    # before contact: moving away, no node under its path, or no typical depth
    assert expected_end([Sample(0.0, -10.0, 0, 1e-3)], end, depth=0.06) == end
    assert expected_end([Sample(0.0, 250.0, 0, math.inf)], end, depth=0.06) == end
    assert expected_end([Sample(0.0, 250.0, 0, 1e-3)], end) == end


def test_expected_end_before_contact_from_gap_speed_and_depth():
    s = [Sample(2e-6, 250.0, 0, 0.01)]
    # contact in gap/v = 40 µs, then 4·depth/v = 4·0.02/250 = 320 µs
    assert expected_end(s, 1.0, depth=0.02) == pytest.approx(2e-6 + 4e-5 + 3.2e-4)


def test_expected_end_uses_the_recent_deceleration():
    # a stiffening membrane (deceleration grows): the estimate is above the true end and
    # comes down to it as the turning point nears
    t0, v0, omega = 0.0, 250.0, math.pi / 6e-4  # harmonic: contact ends at π/ω = 600 µs
    dt = 1e-6
    est = []
    for until in (1e-4, 2e-4, 2.9e-4):
        ts = np.arange(0.0, until + dt / 2, dt)
        samples = [Sample(float(t), v0 * math.cos(omega * (t - t0)), 3) for t in ts]
        est.append(expected_end(samples, 5e-3))
    assert est[0] > est[1] > est[2] > 6e-4
    assert est[2] == pytest.approx(6e-4, rel=0.01)


# the text

def test_formats():
    assert time_text(3.124e-4, 4) == "312.4 µs"
    assert time_text(1.5e-3) == "1.5 ms"
    assert time_text(6.5e-4) == "650 µs"
    assert time_text(0.0) == "0 µs"
    assert step_text(9.1e-8) == "9.1e-8 s"
    assert clock_text(83.4) == "0:01:23"
    assert clock_text(3725) == "1:02:05"


# plain lines when stderr is not a terminal

LINE = re.compile(
    r"^emfabric: t = [\d.]+ (ns|µs|ms|s) \(\d+ %\), step \d+, Δt = \d\.\de-?\d+ s, "
    r"contact nodes \d+, wall \d+:\d\d:\d\d, (left (~\d+:\d\d:\d\d|\?) \((to the expected end "
    r"of contact at ~[\d.]+ (µs|ms|s)|to end_time [\d.]+ (µs|ms|s))\)|ended)$")


def test_lines_at_the_interval_with_every_field():
    clock = FakeClock(100.0)
    buf = io.StringIO()
    shown = LineProgress(buf, interval=5.0, name="x", end_time=1.5e-3, bound=0.02635,
                         clock=clock)
    # one step a wall second, from t = 0.1 µs (after a 2 s compile): lines at 0, 5, 10 s
    clock.now = 102.0
    for k in range(12):
        shown(*fake_step((k + 1) * 1e-7, steps=k + 1, contacts=2 if k else 0,
                         body_v=(0.0, 0.0, -250.0 + 1000.0 * k)))
        assert buf.getvalue().count("\n") == 1 + (k // 5)
        clock.now += 1.0
    shown.close()
    lines = buf.getvalue().splitlines()
    assert len(lines) == 4
    for line in lines:
        assert LINE.match(line), line
    assert lines[0].startswith("emfabric: t = 100 ns (0 %), step 1, Δt = 1.0e-7 s, "
                               "contact nodes 0, wall 0:00:02, left ? (")
    assert "step 6, " in lines[1] and "wall 0:00:07, left ~" in lines[1]
    assert lines[-1].endswith(", ended") and "step 12," in lines[-1]


def test_lines_tell_the_time_left_to_the_expected_end_of_contact():
    clock = FakeClock()
    buf = io.StringIO()
    shown = LineProgress(buf, interval=5.0, name="x", end_time=1.5e-3, clock=clock)
    # touched at 0, slowed at 5e5 m/s² from 250 m/s: contact ends at 1 ms
    for k in range(0, 301):
        t = k * 1e-6
        clock.now = 1.0 + k * 0.1  # 0.1 s a µs
        shown(*fake_step(t, steps=k, contacts=3, body_v=(0.0, 0.0, -(250.0 - 5e5 * t))))
    shown.write()
    last = buf.getvalue().splitlines()[-1]
    # 300 µs simulated in 30 s of wall: 700 µs more take 70 s
    assert "t = 300 µs (20 %)" in last
    assert last.endswith("left ~0:01:10 (to the expected end of contact at ~1 ms)")


# the live display on a terminal

def test_terminal_at_80_columns_shows_the_labelled_times_whole():
    clock = FakeClock(0.0)
    out = io.StringIO()
    console = Console(file=out, width=80, force_terminal=True, color_system="truecolor")
    end, t, t1, left = 1.5e-3, 3.12e-4, 1e-5, 130.0
    with make_progress(None, _scenario(), console, clock=clock,
                       auto_refresh=False) as shown:
        assert isinstance(shown, LiveProgress)
        # the first step done at w1: (83 − w1) s of wall for (t − t1) simulated, and
        # left = that rate × (end − t) = 130 s
        clock.now = 83.0 - left * (t - t1) / (end - t)
        shown(*fake_step(t1, steps=1, contacts=0, body_v=(0, 0, 0)))
        clock.now = 83.0
        shown(*fake_step(t, steps=8123, dt=9.1e-8, contacts=87, body_v=(0, 0, 0)))
        text = ANSI.sub("", out.getvalue())
        assert "elapsed 0:01:23 · left ~0:02:10" in text
        assert "t = 312 µs / 1.5 ms" in text
        assert "contact nodes 87" in text and "step 8123" in text
        assert "Δt = 9.1e-8 s" in text
    final = ANSI.sub("", out.getvalue()).splitlines()
    assert any("elapsed 0:01:23 · ended" in line for line in final)
    for line in final:
        assert len(line) <= 80, line
        assert "…" not in line


def _scenario(**over):
    """demo-small without a projectile (the time left then runs to end_time) on 11 × 11."""
    from emfabric.config.scenario import load_scenario

    return load_scenario("demo-small", {"fabric.nodes": [11, 11], "projectile.shape": "none",
                                        **over})


def test_the_display_follows_the_console():
    sc = _scenario()
    with make_progress(None, sc, Console(file=io.StringIO())) as shown:
        assert isinstance(shown, LineProgress)
    out = io.StringIO()
    with make_progress(None, sc, Console(file=out, force_terminal=True),
                       auto_refresh=False) as shown:
        assert isinstance(shown, LiveProgress)
    assert shown.live.transient  # no step seen: the display is erased, nothing left behind
    with make_progress(None, sc, Console(file=io.StringIO()), quiet=True) as shown:
        assert shown is None


# a real run

def test_a_tiny_run_logs_progress_lines():
    from emfabric.config.scenario import load_scenario
    from emfabric.runner.loop import run

    sc = load_scenario("demo-small", {"fabric.nodes": [11, 11]})
    buf = io.StringIO()
    console = Console(file=io.StringIO())  # not a terminal: the lines go to `stream`
    with make_progress(None, sc, console, buf, interval=0.05) as shown:
        result = run(sc, None, progress=shown)
    lines = buf.getvalue().splitlines()
    assert len(lines) >= 2
    for line in lines:
        assert LINE.match(line), line
    assert lines[-1].endswith(", ended") and f"step {result.state.steps}," in lines[-1]
    # the estimate from the run's own history: past the turning point it names the end of
    # contact within 5 %
    h = result.history
    samples = samples_from_history(h, result.model.flight_direction)
    touched = np.nonzero(h["contact_nodes"].values > 0)[0]
    last_contact = float(h["time"].values[touched[-1]])
    v_n = h["projectile_velocity"].values @ result.model.flight_direction
    turned = int(np.nonzero((v_n <= 0) & (np.arange(len(v_n)) > touched[0]))[0][0])
    at = turned + (touched[-1] - turned) // 2
    estimate = expected_end(samples[:at + 1], sc.solver.end_time)
    assert estimate == pytest.approx(last_contact, rel=0.05)


def test_a_resumed_run_takes_the_contact_start_from_its_history(tmp_path):
    import xarray as xr

    # touched at 10 µs at 250 m/s, slowed at 5e5 m/s²: contact ends at 1.01 ms; the history
    # on disk runs to 400 µs, the checkpoint (where the run resumes) is at 300 µs
    samples = rebound_samples(until=4e-4)
    t = np.array([s.t for s in samples])
    v = np.array([[0.0, 0.0, -s.v_n] for s in samples])
    k = np.array([s.contacts for s in samples])
    xr.Dataset({"projectile_velocity": (("time", "xyz"), v), "contact_nodes": ("time", k)},
               coords={"time": t}).to_netcdf(tmp_path / "history.nc")
    clock = FakeClock()
    sc = load_demo()
    with make_progress(None, sc, Console(file=io.StringIO()), io.StringIO(), clock=clock,
                       history=tmp_path / "history.nc") as shown:
        for j in range(3):
            tj = 3e-4 + j * 1e-6
            shown(*fake_step(tj, contacts=5, body_v=(0, 0, -(250.0 - 5e5 * (tj - 1e-5)))))
        assert max(s.t for s in shown.samples) == pytest.approx(3.02e-4)
        assert shown.expected() == pytest.approx(1.01e-3, rel=1e-6)


def load_demo():
    from emfabric.config.scenario import load_scenario

    return load_scenario("demo-small", {"fabric.nodes": [11, 11]})


def test_before_contact_the_gap_under_the_projectile_and_the_sheet_size():
    shown = LineProgress(io.StringIO(), name="x", end_time=5e-3, bound=0.02635,
                         clock=FakeClock())
    shown(*fake_step(1e-6))  # centre 30 mm above the sheet, 250 m/s towards it
    assert shown.samples[-1].gap == pytest.approx(0.03 - 0.02635)
    depth = 0.25 * 0.254  # DEPTH_FRACTION of the sheet's smaller side
    assert shown.expected() == pytest.approx(1e-6 + (0.03 - 0.02635) / 250 + 4 * depth / 250)
    # aimed off the sheet: no node under its path, no estimate
    off = LineProgress(io.StringIO(), name="x", end_time=5e-3, bound=0.02635,
                       clock=FakeClock())
    off(*fake_step(1e-6, body_x=(0.5, 0.0, 0.03)))
    assert off.samples[-1].gap == math.inf and off.expected() == 5e-3
