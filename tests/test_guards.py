"""Never silently wrong: physical guards in the loop, geometry and stability checks before the
run, strict scenario values, hostile input, SIGHUP."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import xarray as xr

from emfabric.config.scenario import ScenarioError, load_scenario, parse_override
from emfabric.integrators import DivergenceError
from emfabric.runner.loop import run
from emfabric.sim.builder import BYTES_PER_NODE, build_model, memory_available

SMALL = {"fabric.nodes": [12, 12], "output.snapshot_interval": 5e-6, "projectile.gap": 0.0}


def _small(**kw):
    return load_scenario("demo-small", {**SMALL, **kw})


def test_blow_up_is_diverged_not_complete(tmp_path):
    """E = 1e12 V/m on charged nodes: the explicit part explodes within a step; the energy
    guard stops the run as diverged, history marked, the reason names the quantity."""
    with pytest.raises(DivergenceError, match="energy balance error") as info:
        run(_small(**{"field.E": [1e12, 0.0, 0.0], "solver.end_time": 50e-6}), tmp_path)
    assert info.value.result.status == "diverged"
    ds = xr.open_dataset(tmp_path / "history.nc")
    assert ds.attrs["status"] == "diverged" and "energy balance" in ds.attrs["end_reason"]


def test_explicit_scheme_above_its_stability_limit_is_refused():
    with pytest.raises(ScenarioError, match=r"solver\.dt_max = 1e-05 s with solver\.phi = 0"):
        build_model(_small(**{"solver.phi": 0.0, "solver.dt_max": 1e-5}))
    # the same scheme well inside the limit (2/ω_max ≈ 0.2 µs here at φ = 0) is accepted
    build_model(_small(**{"solver.phi": 0.0, "solver.dt_max": 1e-8, "solver.dt_min": 1e-14}))


def test_projectile_overlapping_the_fabric_is_refused():
    with pytest.raises(ScenarioError, match=r"projectile\.position = \[0\.0, 0\.0, 0\.0\]"):
        build_model(_small(**{"projectile.position": [0.0, 0.0, 0.0]}))


def test_a_projectile_that_never_touches_says_so():
    res = run(_small(**{"projectile.velocity": [0.0, 0.0, 250.0], "solver.end_time": 100e-6}))
    assert res.end_reason == "never touched"
    res = run(_small(**{"solver.end_time": 60e-6}))
    assert res.end_reason == "end_time" and res.state.contact_steps > 0


@pytest.mark.parametrize("key, value", [
    ("projectile.mass", "0.037"),          # a string where a number is meant
    ("fabric.nodes", [True, 5]),           # a boolean where an integer is meant
    ("solver.adaptive", 1),                # a number where a boolean is meant
    ("fabric.size", [10**400, 0.2]),       # an integer too large for a float
    ("name", ".."),                        # names the output folder
    ("name", "a/b"),
])
def test_strict_values(key, value):
    with pytest.raises(ScenarioError, match=key.replace(".", r"\.")):
        load_scenario("paper-field", {key: value})


def test_hostile_files_and_overrides(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b'name = "caf\xe9"\n')
    with pytest.raises(ScenarioError, match="not UTF-8 text"):
        load_scenario(bad)
    deep = tmp_path / "deep.toml"
    deep.write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(ScenarioError):
        load_scenario(deep)
    with pytest.raises(ScenarioError, match="nested too deeply"):
        parse_override("fabric.size=" + "[" * 100000 + "]" * 100000)


def test_grid_beyond_memory_is_refused_before_allocating():
    have = memory_available()
    if have is None:
        pytest.skip("this OS does not report its memory")
    n = int((have / BYTES_PER_NODE) ** 0.5) + 10
    with pytest.raises(ScenarioError, match=r"fabric\.nodes = \[\d+, \d+\]: a run needs about"):
        build_model(load_scenario("paper-field", {"fabric.nodes": [n, n]}))


def test_sighup_keeps_a_readable_partial_history(tmp_path):
    """Closing the terminal (SIGHUP) is handled like SIGTERM: valid files, marked partial."""
    out = tmp_path / "hup"
    cmd = [sys.executable, "-m", "emfabric", "run", "demo-small", "--out", str(out), "--quiet",
           "--set=solver.end_time=5e-3", "--set=projectile.velocity=[0,0,0]",
           "--set=output.checkpoint_seconds=0.05"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    # the signal comes once the checkpoint has been replaced at least once after its first
    # write, so that the run has recorded more than its first step whatever the machine's load
    # (a fixed 0.3 s after the first write was not always enough beside other jobs)
    deadline = time.monotonic() + 300
    first = None
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            st = os.stat(out / "checkpoint.nc")
        except FileNotFoundError:
            st = None
        if st is not None:
            stamp = (st.st_ino, st.st_mtime_ns)
            if first is None:
                first = stamp
            elif stamp != first:
                os.kill(proc.pid, signal.SIGHUP)
                break
        time.sleep(0.01)
    _out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    ds = xr.open_dataset(out / "history.nc")
    assert ds.attrs["status"] == "partial" and ds.sizes["time"] > 1
    assert "Traceback" not in err
    assert not (out / ".emfabric.lock").exists()  # the folder is free again


def test_a_signal_during_a_checkpoint_write_lets_the_write_finish(tmp_path, monkeypatch):
    """A signal that arrives while a checkpoint is written stops the run only after the write:
    its KeyboardInterrupt, raised inside xarray's netCDF lock (not reentrant), once left the
    lock taken, and closing the file waited on it for ever (a run given SIGHUP as it wrote a
    checkpoint never exited). Here the signal comes from inside the second write."""
    from emfabric.io import checkpoint
    from emfabric.runner import loop as runner

    writes = []
    real = checkpoint.write_checkpoint

    def write(*args, **kwargs):
        if len(writes) == 1:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)  # the handler runs at the next bytecode: here, if not held
        real(*args, **kwargs)
        writes.append(True)

    monkeypatch.setattr(runner, "write_checkpoint", write)
    old = signal.signal(signal.SIGINT, runner.interrupt)
    try:
        sc = load_scenario("demo-small", {"solver.end_time": 1e-3,
                                          "projectile.velocity": [0, 0, 0],
                                          "output.checkpoint_seconds": 1e-6})
        with pytest.raises(KeyboardInterrupt) as caught:
            run(sc, tmp_path / "sig")
    finally:
        signal.signal(signal.SIGINT, old)
    assert len(writes) >= 3  # the interrupted write finished, and the final one ran
    assert caught.value.result.status == "partial"
    ds = xr.open_dataset(tmp_path / "sig" / "history.nc")
    assert ds.attrs["status"] == "partial"
    assert xr.open_dataset(tmp_path / "sig" / "checkpoint.nc").sizes


def test_a_signal_whose_exception_python_dropped_still_stops_the_run(tmp_path):
    """Python drops an exception raised while it runs a weakref callback or __del__: the
    handler's flag alone must stop the run at the next step, files kept, marked partial."""
    from emfabric.runner import loop as runner

    sc = load_scenario("demo-small", {"solver.end_time": 1e-3, "projectile.velocity": [0, 0, 0]})
    steps = []

    def progress(state, _info):
        steps.append(state.t)
        if len(steps) == 3:
            runner._STOP.set()  # what the handler leaves behind when its raise is dropped

    with pytest.raises(KeyboardInterrupt) as caught:
        run(sc, tmp_path / "drop", progress=progress)
    assert len(steps) == 3 and not runner._STOP.is_set()
    assert caught.value.result.status == "partial"
    ds = xr.open_dataset(tmp_path / "drop" / "history.nc")
    assert ds.attrs["status"] == "partial" and ds.sizes["time"] == 4


def _cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "emfabric", *args], capture_output=True,
                          text=True, cwd=cwd)


def test_output_folder_holding_a_run_is_refused_unless_forced(tmp_path):
    out = tmp_path / "d"
    quick = ["--set=solver.end_time=2e-6", "--set=fabric.nodes=[8,8]", "-q"]
    assert _cli("run", "demo-small", "--out", str(out), *quick).returncode == 0
    (out / "vtk" / "stale_99999.vtu").write_text("old")
    r = _cli("run", "demo-small", "--out", str(out), *quick)
    assert r.returncode == 2 and "--force" in r.stderr and "demo-small" in r.stderr
    r = _cli("run", "demo-small", "--out", str(out), "--force", *quick)
    assert r.returncode == 0, r.stderr
    assert not (out / "vtk" / "stale_99999.vtu").exists()


def test_default_folder_comes_from_the_file_name(tmp_path):
    """A copied scenario keeps name = "paper-field"; its runs go to runs/<file stem>."""
    text = (load_scenario("demo-small").to_toml())
    (tmp_path / "mine.toml").write_text(text)
    r = _cli("run", "mine.toml", "--set=solver.end_time=2e-6", "--set=fabric.nodes=[8,8]", "-q",
             cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "runs" / "mine" / "history.nc").exists()
    assert not (tmp_path / "runs" / "demo-small").exists()


def test_a_coarser_grid_is_the_same_fabric_by_default(tmp_path):
    """fabric.nodes = [40, 40] without more: the paper's fabric at another resolution (MODEL §1):
    the same stiffness per unit width (𝔼A0 of a yarn over the spacing) and the same q/m;
    rescale = false, the explicit other choice, is a 2.5 × softer sheet."""
    paper = build_model(load_scenario("paper-field"))
    coarse = build_model(load_scenario("paper-field", {"fabric.nodes": [40, 40]}))
    given = build_model(load_scenario("paper-field", {"fabric.nodes": [40, 40],
                                                      "fabric.rescale": False}))

    def per_width(m):  # axial stiffness 𝔼A0 of one yarn per unit width of sheet [N/m]
        return m.yarns.modulus[0] * m.yarns.area / m.yarns.rest_length[0]

    def q_over_m(m):
        return m.nodes.charge[0] / m.nodes.mass[0]

    assert per_width(coarse) / per_width(paper) == pytest.approx(1.0, rel=1e-12)
    assert q_over_m(coarse) == pytest.approx(q_over_m(paper), rel=1e-12)
    assert per_width(given) / per_width(paper) == pytest.approx(39 / 99, rel=1e-12)
    res = run(load_scenario("paper-field", {"fabric.nodes": [12, 12],
                                            "solver.end_time": 1e-6}), tmp_path)
    assert "100 x 100 reference" in xr.open_dataset(tmp_path / "history.nc").attrs[
        "fabric_reference"]
    assert "100 x 100 reference" in res.summary["fabric"]


def test_a_grid_of_another_aspect_keeps_each_family_s_stiffness_per_width():
    """fabric.nodes = [30, 10] on the paper's square sheet (reference 100 × 100): a warp line
    stands for the yarns between two warp lines, hy apart, a fill line for hx, so each family
    keeps 𝔼A0 per unit width when A0 scales with the spacing across it (MODEL §1). With one
    mean spacing for both, the warp was 0.66 × and the fill 2.1 × as stiff per unit width as
    the paper's sheet, and a tension front ran along the warp at 5481 m/s, not 6890."""
    paper = build_model(load_scenario("paper-field"))
    odd = build_model(load_scenario("paper-field", {"fabric.nodes": [30, 10]}))
    y0, y = paper.yarns, odd.yarns
    area0 = y0.stiffness[0] * y0.rest_length[0] / y0.modulus[0]
    size = load_scenario("paper-field").fabric.size
    h0 = size[0] / 99
    hx, hy = size[0] / 29, size[1] / 9
    seg_area = y.stiffness * y.rest_length / y.modulus
    warp = np.isclose(y.rest_length, hx, rtol=1e-12)
    fill = np.isclose(y.rest_length, hy, rtol=1e-12)
    assert warp.sum() == 29 * 10 and fill.sum() == 30 * 9
    # 𝔼A0 per unit width across each family, as on the reference grid
    assert np.allclose(seg_area[warp] / hy, area0 / h0, rtol=1e-12)
    assert np.allclose(seg_area[fill] / hx, area0 / h0, rtol=1e-12)


def test_full_disk_stops_the_run_naming_the_file(tmp_path, monkeypatch):
    """A write that fails (disk full) ends the run as failed with the file's name; what was
    written before stays readable."""
    import errno

    import emfabric.runner.loop as runner

    real = runner.append_history
    calls = []

    def append_then_fill_up(path, rows, attrs, written):
        calls.append(1)
        if len(calls) > 1:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(path, rows, attrs, written)

    monkeypatch.setattr(runner, "append_history", append_then_fill_up)
    sc = _small(**{"solver.end_time": 300e-6, "output.checkpoint_seconds": 1e-9})
    with pytest.raises(runner.OutputError, match=r"history\.nc: No space left on device") as info:
        run(sc, tmp_path)
    assert info.value.result.status == "failed"
    ds = xr.open_dataset(tmp_path / "history.nc")
    assert ds.sizes["time"] >= 2


@pytest.mark.parametrize("override, key", [
    ("projectile.position=[0,0,0]", "projectile.position"),
    ("fabric.nodes=[100000,100000]", "fabric.nodes"),
    ("solver.phi=0", "solver.dt_max"),
    ('fabric.edges="[/x]"', "fabric.edges"),
])
def test_cli_refuses_with_exit_code_2(tmp_path, override, key):
    r = _cli("run", "demo-small", "--set", override, "--out", str(tmp_path / "o"), "-q")
    assert r.returncode == 2, r.stderr
    assert key in r.stderr and "Traceback" not in r.stderr


def test_sigkill_while_compiling_leaves_a_readable_history(tmp_path):
    """A run killed before its first step (kernels still compiling in a cold cache) leaves a
    readable history that says it did not finish."""
    out = tmp_path / "k"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cold-cache"))
    proc = subprocess.Popen([sys.executable, "-m", "emfabric", "run", "demo-small", "--out",
                             str(out), "-q"], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < deadline:
        if (out / "history.nc").exists():
            os.kill(proc.pid, signal.SIGKILL)
            break
        time.sleep(0.005)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL
    ds = xr.open_dataset(out / "history.nc")
    assert ds.attrs["status"] == "partial" and ds.attrs["scenario_name"] == "demo-small"


def test_max_stretch_counts_only_the_yarns_not_broken():
    """A node whose two yarns are broken flies off: their 'stretch' is no load and must not
    trip the plausibility limit (it did: fragments of a perforated sheet stopped runs)."""
    import numpy as np

    from emfabric._kernels.diagnostics import COUNT, STRETCH, fabric_diagnostics

    model = build_model(_small(**{"fabric.nodes": [5, 5]}))
    x = model.nodes.x0.copy()
    x[:, 0] += [1.0, 1.0, -1.0]  # the corner node, 1.7 m away
    alpha = np.ones(model.seg_count)
    ends = model.yarns.ends
    touching = np.where((ends[:, 0] == 0) | (ends[:, 1] == 0))[0]
    assert len(touching) == 2
    out = np.zeros(COUNT)
    args = (model.physics, x, np.zeros_like(x), alpha, np.zeros(3), np.array([0, 0, -1.0]), out)
    fabric_diagnostics(*args)
    assert out[STRETCH] > 10.0
    alpha[touching] = 0.0
    fabric_diagnostics(*args)
    assert out[STRETCH] == 1.0


# --- a write that fails during a run (issue 25 item 3) ---------------------------------------

def _failing_scenario():
    return load_scenario("demo-small", {"fabric.nodes": [11, 11], "solver.end_time": 2e-5,
                                        "output.checkpoint_seconds": 1e-9,
                                        "output.paraview": False})


def _same_history(a, b):
    import numpy as np

    with xr.open_dataset(a / "history.nc") as x, xr.open_dataset(b / "history.nc") as y:
        assert x.sizes == y.sizes
        for v in y.variables:
            np.testing.assert_array_equal(x[v].values, y[v].values, err_msg=v)


@pytest.mark.parametrize("disk", ["checkpoint write fails", "disk full"])
def test_failed_write_says_so_and_the_last_good_checkpoint_resumes(tmp_path, monkeypatch,
                                                                   disk):
    """ENOSPC at the second checkpoint: the run ends "failed" with the reason in history.nc
    (not "partial", as if still going), the checkpoint in the folder is the first (the last
    good one) and --resume continues from it to the numbers of a run that never stopped.
    "disk full": from then on nothing can be written (history, snapshots, checkpoint): the
    status is recorded in history.nc's header as it stands."""
    import errno

    import emfabric.runner.loop as runner
    from emfabric.io.checkpoint import read_checkpoint
    from emfabric.io.snapshots import Snapshots
    from emfabric.runner.loop import resume

    full = tmp_path / "full"
    run(_failing_scenario(), full)
    armed, calls = [], []

    def enospc(path=None):
        return OSError(errno.ENOSPC, "No space left on device", None if path is None
                       else str(path))

    real_checkpoint = runner.write_checkpoint

    def checkpoint(path, *args):
        calls.append(path)
        if len(calls) >= 2:
            armed.append(True)
            raise enospc(path)
        real_checkpoint(path, *args)

    def when_armed(real):
        def write(*args, **kwargs):
            if armed:
                raise enospc()
            return real(*args, **kwargs)
        return write

    monkeypatch.setattr(runner, "write_checkpoint", checkpoint)
    if disk == "disk full":
        monkeypatch.setattr(runner, "append_history", when_armed(runner.append_history))
        monkeypatch.setattr(runner, "write_history", when_armed(runner.write_history))
        monkeypatch.setattr(Snapshots, "flush", when_armed(Snapshots.flush))
    out = tmp_path / "x"
    with pytest.raises(runner.OutputError, match=r"checkpoint\.nc: No space left on device") \
            as info:
        run(_failing_scenario(), out)
    assert info.value.result.status == "failed"
    with xr.open_dataset(out / "history.nc") as ds:
        assert ds.attrs["status"] == "failed"
        assert ds.attrs["end_reason"] == ("write error: cannot write checkpoint.nc: No space "
                                          "left on device")
    monkeypatch.undo()
    assert read_checkpoint(out / "checkpoint.nc")[3].history_rows == 1  # the first one
    assert not (out / ".emfabric.lock").exists()
    assert resume(out).status == "complete"
    _same_history(out, full)


def test_status_in_place_never_grows_the_header(tmp_path):
    """mark_status (the full-disk path) changes history.nc's header where it stands: a longer
    reason is cut to the room of the one it replaces; the file's size and records stay."""
    import numpy as np

    from emfabric.io.history import mark_status, write_history
    from emfabric.runner.loop import RUNNING

    path = tmp_path / "history.nc"
    write_history(xr.Dataset({"x": (("time",), np.arange(100.0))},
                             coords={"time": np.arange(100.0)},
                             attrs={"status": "partial", "end_reason": RUNNING}), path)
    size = path.stat().st_size
    assert mark_status(path, "failed", "write error: " + "x" * 500)
    with xr.open_dataset(path) as ds:
        assert ds.attrs["status"] == "failed" and ds.attrs["end_reason"].endswith("…")
        assert len(ds.attrs["end_reason"].encode()) <= len(RUNNING.encode()) + 3
        np.testing.assert_array_equal(ds["x"].values, np.arange(100.0))
    assert path.stat().st_size == size
    assert not mark_status(tmp_path / "none.nc", "failed", "x")
    assert not (tmp_path / "none.nc").exists()  # netCDF4's "a" would have created it


def test_temporary_names_are_reported_as_the_file_they_stand_for():
    from emfabric.runner.loop import target_of

    assert str(target_of("/r/figures/.spin.ab_12cd3.partial.png")) == "/r/figures/spin.png"
    assert str(target_of("/r/.history.a1b2c3d4.partial.nc")) == "/r/history.nc"
    assert str(target_of("/r/spin.png")) == "/r/spin.png"
