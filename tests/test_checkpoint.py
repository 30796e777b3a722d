"""A checkpoint is a State: a stopped or killed run resumes to the history an uninterrupted run
writes, bit for bit; a checkpoint that does not belong to the scenario or version is refused."""

import dataclasses
import os
import signal
import subprocess
import sys
import time

import netCDF4
import numpy as np
import pytest
import xarray as xr

import emfabric
from emfabric.config.scenario import builtin_names, load_scenario
from emfabric.io.checkpoint import (
    CHECKPOINT,
    CheckpointError,
    RunPosition,
    read_checkpoint,
    write_checkpoint,
)
from emfabric.runner.loop import resume, run
from emfabric.sim.builder import build_model
from emfabric.sim.state import State, initial_state

from conftest import interrupted_demo

# a 12 × 12 sheet of the paper's fabric, field on: contact, friction, damage and spin within
# 300 µs, a few hundred steps
SMALL = {"fabric.nodes": [12, 12], "solver.end_time": 300e-6, "output.snapshot_interval": 5e-6,
         "projectile.gap": 0.0}


def _same_files(a, b) -> None:
    """history.nc and snapshots.nc hold the same numbers (attributes aside: wall time)."""
    for name in ("history.nc", "snapshots.nc"):
        x, y = xr.open_dataset(a / name), xr.open_dataset(b / name)
        assert x.sizes == y.sizes, name
        for v in y.variables:
            np.testing.assert_array_equal(x[v].values, y[v].values, err_msg=f"{name}: {v}")
    assert (a / "fabric.pvd").read_text() == (b / "fabric.pvd").read_text()


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    out = tmp_path_factory.mktemp("full")
    run(load_scenario("demo-small", SMALL), out)
    return out


def test_ctrl_c_then_resume_is_bitwise_the_uninterrupted_run(uninterrupted, tmp_path):
    interrupted_demo(tmp_path, SMALL, after=150)
    partial = xr.open_dataset(tmp_path / "history.nc")
    assert partial.attrs["status"] == "partial" and partial.sizes["time"] == 151
    result = resume(tmp_path)
    assert result.status == "complete"
    assert xr.open_dataset(tmp_path / "history.nc").attrs["status"] == "complete"
    _same_files(tmp_path, uninterrupted)
    with pytest.raises(CheckpointError, match="complete .*nothing to resume"):
        resume(tmp_path)


def test_resume_twice(uninterrupted, tmp_path):
    """Stopping a resumed run and resuming again still gives the same history."""
    interrupted_demo(tmp_path, SMALL, after=60)
    calls = []

    def stop(state, info):
        calls.append(1)
        if len(calls) == 80:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        resume(tmp_path, progress=stop)
    resume(tmp_path)
    _same_files(tmp_path, uninterrupted)


def test_sigkill_then_resume(uninterrupted, tmp_path):
    """`emfabric run` killed with SIGKILL in the middle of the run leaves a readable history up
    to its last checkpoint and a checkpoint that `emfabric run --resume` continues."""
    out = tmp_path / "killed"
    args = [f"--set={k}={v}".replace(" ", "") for k, v in SMALL.items()]
    cmd = [sys.executable, "-m", "emfabric", "run", "demo-small", "--out", str(out), "--quiet",
           "--set=output.checkpoint_seconds=0.01", *args]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    seen: set[int] = set()
    deadline = time.monotonic() + 300
    # kill once three different checkpoints have been written (the run is well under way)
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            seen.add((out / CHECKPOINT).stat().st_mtime_ns)
        except FileNotFoundError:
            pass
        if len(seen) >= 3:
            os.kill(proc.pid, signal.SIGKILL)
            break
        time.sleep(0.002)
    proc.wait()
    # a run of this length writes a checkpoint every 0.01 s of wall time, dozens in all: one
    # that ends unkilled wrote fewer than three (periodic checkpoints broken), which fails
    assert proc.returncode == -signal.SIGKILL, (
        f"the run ended (exit {proc.returncode}) with {len(seen)} checkpoint writes seen; "
        f"output.checkpoint_seconds = 0.01 should have given many")
    ds = xr.open_dataset(out / "history.nc")
    assert ds.attrs["status"] == "partial"
    _scenario, _v, state, pos = read_checkpoint(out / CHECKPOINT)
    assert 0 < state.t < SMALL["solver.end_time"]
    # the history holds at least the records the checkpoint counts, the last one its State's
    assert ds.sizes["time"] >= pos.history_rows
    assert float(ds.time[pos.history_rows - 1]) == state.t
    r = subprocess.run([sys.executable, "-m", "emfabric", "run", "--resume", str(out),
                        "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    _same_files(out, uninterrupted)


def test_checkpoint_round_trips_every_state_field(tmp_path):
    """Every field of the State comes back exactly (the checkpoint is the whole State)."""
    # a brittle law with strain averaging: the averaged stretch² (seg_strain) is a real array;
    # segment contact under central differences: so are the segments' contact modes
    model = build_model(load_scenario("demo-small", {
        **SMALL, "fabric.material.name": "kevlar-km2", "fabric.damage.law": "brittle",
        "contact.segments": True, "solver.integrator": "central-difference"}))
    rng = np.random.default_rng(3)
    shapes = initial_state(model)  # every field's shape and type, from a real State
    values = {}
    for f in dataclasses.fields(State):
        like = getattr(shapes, f.name)
        if isinstance(like, np.ndarray):  # random values of the field's own shape
            values[f.name] = rng.normal(size=like.shape).astype(like.dtype)
        elif f.type == "int":
            values[f.name] = int(rng.integers(1, 10**9))
        else:
            values[f.name] = float(rng.normal())
    state = State(**values)
    arrays = [f.name for f in dataclasses.fields(State) if isinstance(values[f.name], np.ndarray)]
    for name in ("node_x", "node_v", "node_f", "seg_alpha", "body", "energy", "node_e",
                 "node_contact", "node_fv", "seg_strain", "seg_contact", "contact_force"):
        assert name in arrays and values[name].size > 0, name
    pos = RunPosition(17, 4, 2.5e-5, 12.25)
    write_checkpoint(tmp_path / CHECKPOINT, model, state, pos)
    sc, version, back, pos_back = read_checkpoint(tmp_path / CHECKPOINT)
    assert version == emfabric.__version__ and sc.to_dict() == model.scenario.to_dict()
    assert pos_back == pos
    for f in dataclasses.fields(State):
        a, b = getattr(state, f.name), getattr(back, f.name)
        assert type(a) is type(b), f.name
        np.testing.assert_array_equal(a, b, err_msg=f.name)


def test_edited_scenario_is_refused(tmp_path):
    interrupted_demo(tmp_path, SMALL, after=20)
    other = load_scenario("demo-small", {**SMALL, "field.B": [0.0, 0.05, 0.0]})
    with pytest.raises(CheckpointError, match=r"field\.B"):
        resume(tmp_path, other)
    # the same scenario, given explicitly, is accepted
    resume(tmp_path, load_scenario("demo-small", SMALL))


@pytest.mark.parametrize("damage", ["history cut", "history record", "snapshot record"])
def test_outputs_that_lost_records_are_not_resumed(tmp_path, damage):
    """A history.nc or snapshots.nc that lost records since the checkpoint was written (a
    truncated copy, a full disk: the file still opens, the lost records read as zeros) is
    refused, naming the file, and nothing is written: an audit found `--resume` keeping 3666
    records of zeros as the run's past and reporting the run complete. Cut: the history's
    later records zero; record: only the last one the checkpoint counts differs (its digest);
    snapshot: the last snapshot's positions zero."""
    interrupted_demo(tmp_path, SMALL, after=40)
    _, _, _, pos = read_checkpoint(tmp_path / CHECKPOINT)
    assert pos.history_rows > 20 and pos.snapshots >= 2
    if damage == "snapshot record":
        with netCDF4.Dataset(tmp_path / "snapshots.nc", "a") as nc:
            nc["node_position"][pos.snapshots - 1] = 0.0
    else:
        with netCDF4.Dataset(tmp_path / "history.nc", "a") as nc:
            if damage == "history cut":
                for var in nc.variables.values():
                    if var.dimensions[:1] == ("time",):
                        var[20:pos.history_rows] = 0
            else:
                nc["projectile_velocity"][pos.history_rows - 1] = [0.0, 0.0, 0.0]
    name = "snapshots.nc" if damage == "snapshot record" else "history.nc"
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    with pytest.raises(CheckpointError, match=f"{name} is not what the checkpoint was "
                                              f"written with.*nothing resumed"):
        resume(tmp_path)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before
    r = subprocess.run([sys.executable, "-m", "emfabric", "run", "--resume", str(tmp_path),
                        "--quiet"], capture_output=True, text=True)
    assert r.returncode == 2 and name in r.stderr and "Traceback" not in r.stderr


def test_a_run_stopped_before_its_first_step_leaves_a_folder_to_run_again(tmp_path,
                                                                           monkeypatch):
    """Ctrl-C after history.nc is created but before the first checkpoint (the first record
    is measured while kernels compile: minutes on a cold cache): the empty history says the
    run was stopped before its first step and that nothing resumes, not that `--resume`
    continues it; `emfabric run` into the folder again runs without --force (it holds no
    result), and the temporary file of a write killed halfway is cleared. An audit found
    such a folder refused by both `--resume` ("no checkpoint") and a new run ("holds another
    run ... use --force")."""
    import emfabric.runner.loop as loop
    from emfabric.io.outputs import run_in

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(loop, "measure", stopped)
    with pytest.raises(KeyboardInterrupt):
        run(load_scenario("demo-small", SMALL), tmp_path)
    monkeypatch.undo()
    h = xr.open_dataset(tmp_path / "history.nc")
    assert h.sizes["time"] == 0 and h.attrs["status"] == "partial"
    assert h.attrs["end_reason"] == loop.NOT_STARTED
    assert not (tmp_path / CHECKPOINT).exists() and run_in(tmp_path) is None
    (tmp_path / ".history.abc123.partial.nc").write_bytes(b"killed halfway")
    r = subprocess.run([sys.executable, "-m", "emfabric", "run", "demo-small", "--out",
                        str(tmp_path), "--quiet", "--set", "fabric.nodes=[8, 8]", "--set",
                        "solver.end_time=2e-6"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert xr.open_dataset(tmp_path / "history.nc").attrs["status"] == "complete"
    assert not (tmp_path / ".history.abc123.partial.nc").exists()


def test_other_version_is_refused(tmp_path, monkeypatch):
    interrupted_demo(tmp_path, SMALL, after=20)
    monkeypatch.setattr(emfabric, "__version__", "0.0.0-other")
    with pytest.raises(CheckpointError, match="0.0.0-other"):
        resume(tmp_path)


def test_cli_refuses_a_mismatched_resume(tmp_path):
    interrupted_demo(tmp_path, SMALL, after=20)
    r = subprocess.run([sys.executable, "-m", "emfabric", "run", "demo-small", "--resume",
                        str(tmp_path), "--set", "solver.end_time=1e-4", "--quiet"],
                       capture_output=True, text=True)
    assert r.returncode == 2
    assert "solver.end_time" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([sys.executable, "-m", "emfabric", "run", "--resume",
                        str(tmp_path / "nowhere")], capture_output=True, text=True)
    assert r.returncode == 2 and "nothing to resume" in r.stderr


@pytest.mark.parametrize("integrator", ["central-difference", "phi"])
def test_a_complete_run_continued_past_its_end_is_the_longer_run_to_the_bit(
        uninterrupted, tmp_path, integrator):
    """A run that reached its end_time, resumed with a later solver.end_time (the one change
    a resume accepts), goes on to it and writes the history and snapshots of a run given the
    later end from the start, bit for bit: its checkpoint holds the state before the last step,
    which end_time cut short, and that step is taken again whole. Its files then carry the
    later end in their scenario. An earlier end is refused, and so is a later one for a run
    that ended by its stop rule."""
    sc = {**SMALL, "solver.integrator": integrator}
    if integrator == "central-difference":
        longer = uninterrupted  # SMALL, to 300 µs
    else:
        sc["solver.end_time"] = 120e-6
        longer = tmp_path / "longer"
        run(load_scenario("demo-small", sc), longer)
    end = sc["solver.end_time"]
    first = run(load_scenario("demo-small", {**sc, "solver.end_time": 0.45 * end}),
                tmp_path / "x")
    assert (first.status, first.end_reason) == ("complete", "end_time")
    with pytest.raises(CheckpointError, match=r"solver\.end_time can only be made later"):
        resume(tmp_path / "x", load_scenario("demo-small", {**sc, "solver.end_time": 0.3 * end}))
    result = resume(tmp_path / "x", load_scenario("demo-small", sc))
    assert (result.status, result.end_reason) == ("complete", "end_time")
    assert float(result.history.time[-1]) == end
    _same_files(tmp_path / "x", longer)
    for name in ("history.nc", "snapshots.nc"):
        with xr.open_dataset(tmp_path / "x" / name) as ds:
            assert f"end_time = {end!r}" in ds.attrs["scenario"], name
            assert ds.attrs["status"] == "complete"
    assert read_checkpoint(tmp_path / "x" / CHECKPOINT)[0].solver.end_time == end
    if integrator == "phi":
        return
    # through the command line: the complete run says how to go further, and goes
    r = subprocess.run([sys.executable, "-m", "emfabric", "run", "--resume", str(tmp_path / "x"),
                        "-q"], capture_output=True, text=True)
    assert r.returncode == 2 and "--set solver.end_time=T" in r.stderr, r.stderr
    r = subprocess.run([sys.executable, "-m", "emfabric", "run", "--resume", str(tmp_path / "x"),
                        "--set", "solver.end_time=0.00031", "-q", "--json"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    with xr.open_dataset(tmp_path / "x" / "history.nc") as ds:
        assert float(ds.time[-1]) == 0.00031 and ds.attrs["status"] == "complete"
    # a run that ended by its stop rule (the sphere rebounded) is not continued
    whole = tmp_path / "whole"
    assert run(load_scenario("demo-small", {"fabric.nodes": [12, 12]}), whole).end_reason \
        == "rebound"
    with pytest.raises(CheckpointError, match="stop rule"):
        resume(whole, load_scenario("demo-small", {"fabric.nodes": [12, 12],
                                                   "solver.end_time": 1.0}))


def test_history_is_appended_along_an_unlimited_time(tmp_path):
    """history.nc and snapshots.nc are record files: written as the run goes by appending."""
    interrupted_demo(tmp_path, SMALL, after=30)
    for name, dim in (("history.nc", "time"), ("snapshots.nc", "snapshot")):
        with netCDF4.Dataset(tmp_path / name) as nc:
            assert nc.dimensions[dim].isunlimited()
            assert nc.file_format == "NETCDF3_64BIT_OFFSET"


def test_cli_resume_with_overrides_only(tmp_path):
    """`--resume DIR --set k=v` changes the stored scenario, so it is refused naming the key;
    an override that changes nothing is accepted."""
    interrupted_demo(tmp_path, SMALL, after=20)
    r = subprocess.run([sys.executable, "-m", "emfabric", "run", "--resume", str(tmp_path),
                        "--set", "field.B=[0,0,0.1]", "-q"], capture_output=True, text=True)
    assert r.returncode == 2 and "field.B" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([sys.executable, "-m", "emfabric", "run", "--resume", str(tmp_path),
                        "--set", "solver.end_time=0.0003", "-q"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("integrator", ["central-difference", "phi"])
def test_a_pack_resumes_bitwise(tmp_path, integrator):
    """A 2-ply pack (ply contact, per-ply history columns) stopped by Ctrl-C and resumed writes
    the history and snapshots of the uninterrupted run, bit for bit, with either scheme (the
    φ-scheme's ply forces are part of the stored end-of-step force)."""
    over = {**SMALL, "fabric.plies": 2, "solver.end_time": 120e-6,
            "solver.integrator": integrator}
    full = tmp_path / "full"
    run(load_scenario("demo-small", over), full)
    part = interrupted_demo(tmp_path / "part", over, after=120)
    assert xr.open_dataset(part / "history.nc").sizes["time"] == 121
    assert resume(part).status == "complete"
    _same_files(part, full)
    ds = xr.open_dataset(full / "history.nc")
    assert ds.sizes["ply"] == 2 and float(ds.max_deflection_per_ply[-1, 1]) > 0.0


@pytest.mark.parametrize("integrator", ["central-difference", "phi"])
@pytest.mark.parametrize("name", builtin_names())
def test_every_builtin_scenario_resumes_bitwise(tmp_path, name, integrator):
    """Every built-in scenario, with either scheme (coarse, the projectile touching the sheet at
    the start, 12 µs: at least 8 steps): stopped by Ctrl-C halfway through and resumed, it
    writes the history and snapshots of the uninterrupted run, bit for bit. (Issue 22: both
    schemes run every built-in scenario, checkpoint and resume bit for bit.)"""
    base = load_scenario(name)
    # the FSP and the ogive need cells smaller than their nose (the φ-scheme's segment contact)
    n = 21 if base.projectile.shape in ("fsp", "ogive") else 11
    over = {"fabric.nodes": [n, n], "solver.integrator": integrator,
            "output.snapshot_interval": 1e-6, "solver.end_time": 12e-6}
    if base.projectile.shape != "none":
        over["projectile.gap"] = 0.0
    full = tmp_path / "full"
    res = run(load_scenario(name, over), full)
    assert res.status == "complete"
    steps = xr.open_dataset(full / "history.nc").sizes["time"] - 1
    assert steps >= 8
    if base.projectile.shape != "none":
        assert int(res.history.contact_nodes.max()) > 0
    stop = steps // 2
    part = tmp_path / "part"
    with pytest.raises(KeyboardInterrupt):
        run(load_scenario(name, over), part, progress=_stop_after(stop))
    assert xr.open_dataset(part / "history.nc").sizes["time"] == stop + 1
    assert resume(part).status == "complete"
    _same_files(part, full)


def _stop_after(count):
    """A progress callback that presses Ctrl-C after `count` steps."""
    seen = []

    def stop(state, info) -> None:
        seen.append(state.t)
        if len(seen) >= count:
            raise KeyboardInterrupt

    return stop


def test_patient_steps_resume_bit_for_bit(tmp_path):
    """The φ-scheme's patient step (a 1 g wire striking three yarn segments at once: no Δt
    lets K_d iterations meet the tolerance, phi.Integrator.step) is taken at step 9; a run
    stopped right after it resumes into a step that starts patient as the uninterrupted run's
    did (State.iterations, in the checkpoint), and the files are the same bit for bit."""
    cell = 0.254 / 20
    over = {"fabric.nodes": [21, 21], "field.B": [0, 0, 0], "fabric.material.modulus_cv": 0.0,
            "projectile.shape": "cylinder", "projectile.radius": 5e-5,
            "projectile.length": 3 * cell, "projectile.mass": 1e-3,
            "projectile.axis": [1.0, 0.0, 0.0], "projectile.position": [0.0, cell / 2, 1.5e-4],
            "projectile.velocity": [0.0, 0.0, -300.0], "solver.end_time": 4e-6,
            "solver.integrator": "phi", "output.snapshot_interval": 5e-7}
    full = tmp_path / "full"
    run(load_scenario("demo-small", over), full)
    iterations = xr.open_dataset(full / "history.nc").iterations.values
    k_d = load_scenario("demo-small", over).solver.target_iterations
    patient = np.flatnonzero(iterations > k_d)
    assert patient.size and patient[0] == 9
    part = interrupted_demo(tmp_path / "part", over, after=9)
    assert int(xr.open_dataset(part / "history.nc").iterations[-1]) > k_d
    assert resume(part).status == "complete"
    _same_files(part, full)


def test_a_diverged_run_is_not_resumed(tmp_path):
    """A run that diverged (here: a projectile mass of 5e-324 kg, whose inertia underflows to 0)
    keeps a checkpoint of the state it diverged from or in; resuming one diverged again, one
    step later each time, adding a record of a rejected state. It is refused instead, naming
    the divergence, and the files stay as they were."""
    from emfabric.integrators import DivergenceError

    sc = load_scenario("demo-small", {"fabric.nodes": [8, 8], "solver.end_time": 5e-5,
                                      "field.B": [0.0, 0.0, 0.0], "output.paraview": False,
                                      "projectile.mass": 5e-324})
    with pytest.raises(DivergenceError):
        run(sc, tmp_path)
    before = (tmp_path / "history.nc").read_bytes()
    with pytest.raises(CheckpointError, match="diverged .*nothing to resume"):
        resume(tmp_path)
    assert (tmp_path / "history.nc").read_bytes() == before
    r = subprocess.run([sys.executable, "-m", "emfabric", "run", "--resume", str(tmp_path)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "nothing to resume" in r.stderr and "Traceback" not in r.stderr
