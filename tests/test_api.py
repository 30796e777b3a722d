"""The public Python API: run a Scenario or a Model, the projectile's initial pose."""

import dataclasses
import re

import numpy as np
import pytest

import emfabric
from emfabric.config.scenario import load_scenario
from emfabric.sim.geometry import initial_pose

from conftest import make


def _small(**kw):
    return make(**{"fabric.nodes": [9, 9], "solver.end_time": 3e-6, **kw})


def test_run_accepts_a_model_and_gives_the_scenarios_run(tmp_path):
    """emfabric.run(build_model(sc)) is emfabric.run(sc), bit for bit; a Model put together in
    Python (no scenario) runs too, writes its history, and no checkpoint (nothing to rebuild
    it from on resume)."""
    sc = _small()
    a = emfabric.run(sc)
    model = emfabric.build_model(sc)
    b = emfabric.run(model)
    # every variable of the history, bit for bit (NaN where NaN)
    for name in a.history.data_vars:
        assert np.array_equal(a.history[name].values, b.history[name].values,
                              equal_nan=a.history[name].dtype.kind == "f"), name
    bare = dataclasses.replace(model, scenario=None)
    c = emfabric.run(bare, tmp_path / "bare")
    for name in a.history.data_vars:
        assert np.array_equal(a.history[name].values, c.history[name].values,
                              equal_nan=a.history[name].dtype.kind == "f"), name
    assert (tmp_path / "bare" / "history.nc").is_file()
    assert not (tmp_path / "bare" / "checkpoint.nc").exists()
    assert c.summary["fabric"] == "built in Python"


@pytest.mark.parametrize("gap", [0.0, 1e-3])
def test_initial_pose_of_a_sphere_and_an_ogive(gap):
    """The start pose from the scenario alone: a sphere's lowest point and an ogive's nose tip
    (pointing down its velocity) lie `gap` above the sheet; the flight direction is the unit
    velocity; an ogive's nose marker is its tip, (L − base) along the axis."""
    r = 0.01
    pose = initial_pose(make(**{"projectile.radius": r, "projectile.gap": gap,
                                "projectile.velocity": [0.0, 0.0, -300.0]}).projectile)
    assert pose.position == pytest.approx([0.0, 0.0, r + gap], abs=1e-15)
    assert pose.flight_direction == pytest.approx([0.0, 0.0, -1.0])
    assert pose.nose == pytest.approx([0.0, 0.0, -r])
    length, nose_len = 0.05, 0.02
    pose = initial_pose(make(**{"projectile.shape": "ogive", "projectile.radius": r,
                                "projectile.length": length, "projectile.nose_length": nose_len,
                                "projectile.gap": gap}).projectile)
    tip = length - pose.geometry.base
    assert pose.position == pytest.approx([0.0, 0.0, tip + gap], rel=1e-12)
    assert pose.nose == pytest.approx([0.0, 0.0, -tip], rel=1e-12)
    # and the Model the builder makes starts there
    model = emfabric.build_model(make(**{"projectile.shape": "ogive", "projectile.radius": r,
                                         "projectile.length": length,
                                         "projectile.nose_length": nose_len,
                                         "projectile.gap": gap, "fabric.nodes": [5, 5]}))
    assert np.array_equal(model.body_x0, pose.position)


def test_thread_count_chooses_the_kernel():
    """threads=1 runs the serial kernel, more the threaded one; by default a sheet below
    THREADS_FROM_NODES nodes runs serially (not slower idle, much faster on a loaded machine)."""
    import numba

    from emfabric.integrators import default_threads, make_integrator

    for integrator in ("phi", "central-difference"):
        model = emfabric.build_model(_small(**{"solver.integrator": integrator}))
        assert default_threads(model) == 1
        assert not make_integrator(model).threaded
        assert not make_integrator(model, threads=1).threaded
        assert make_integrator(model, threads=2).threaded == (numba.config.NUMBA_NUM_THREADS > 1)


def test_study_cases_run_on_the_threads_asked_for(monkeypatch):
    """`--threads N` on a study reaches each case's run (threads=N); without it a case runs on
    the default within its share of the cores: default_threads counts the Numba threads the
    process is set to (numba.set_num_threads, as run_case sets the share), not every core."""
    import numba

    import emfabric.runner
    from emfabric.integrators import THREADS_FROM_NODES, default_threads
    from emfabric.studies.sweep import run_case

    seen = []
    before = numba.get_num_threads()  # run_case sets it: restored at the end

    def fake_run(sc, out, threads=None):
        seen.append(threads)
        raise RuntimeError("not run")

    monkeypatch.setattr(emfabric.runner, "run", fake_run)
    # run_case filters the plausibility warnings out of its process's run log for good (a
    # worker's): here, only for this test
    import logging

    monkeypatch.setattr(logging.getLogger("emfabric.runner.loop"), "filters", [])
    text = _small().to_toml()

    class Big:
        node_count = THREADS_FROM_NODES

    try:
        assert run_case(text, None, 2, explicit=True)["status"] == "failed"
        assert run_case(text, None, 2)["status"] == "failed"
        assert seen == [2, None]
        numba.set_num_threads(1)
        assert default_threads(Big()) == 1
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        assert default_threads(Big()) == numba.config.NUMBA_NUM_THREADS
    finally:
        numba.set_num_threads(before)


@pytest.mark.parametrize("threads", [0, -3, 1.7, "2", True])
def test_threads_must_be_a_whole_number_of_at_least_one(threads, tmp_path):
    """As the CLI's --threads: refused before anything is written, naming the value."""
    sc = load_scenario("paper-field", {"fabric.nodes": [12, 12], "solver.end_time": 1e-7})
    with pytest.raises(ValueError, match=rf"threads = {re.escape(repr(threads))}: allowed"):
        emfabric.run(sc, tmp_path / "out", threads=threads)
    assert not (tmp_path / "out").exists()


def test_numpy_values_are_overrides_like_any_other():
    """A seed from np.arange, nodes from an array: the same scenario as Python numbers."""
    sc = load_scenario("paper-field", {"fabric.material.seed": np.int64(3),
                                       "fabric.nodes": np.array([30, 30]),
                                       "projectile.velocity": (0.0, np.float64(0.0), -250.0)})
    assert sc == load_scenario("paper-field", {"fabric.material.seed": 3,
                                               "fabric.nodes": [30, 30],
                                               "projectile.velocity": [0.0, 0.0, -250.0]})


def test_the_summary_has_one_schema_with_or_without_a_projectile():
    """A script reads one set of summary keys: the fabric alone (projectile.shape = "none")
    gives the same keys as an impact, the projectile's figures NaN (null in --json) and
    perforation undecided (-1)."""
    import math

    impact = emfabric.run(_small()).summary
    alone = emfabric.run(make(**{"fabric.nodes": [9, 9], "projectile.shape": "none",
                                 "solver.end_time": 1e-6})).summary
    assert sorted(alone) == sorted(impact)
    assert all(math.isnan(c) for c in alone["final_velocity_m_s"])
    assert math.isnan(alone["max_tilt_deg"]) and alone["perforated"] == -1
    assert alone["plies"] == 1 and alone["plies_perforated"] == -1
