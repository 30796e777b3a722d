"""Outputs: history.nc contract, snapshots, ParaView files, partial runs, determinism."""

import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from emfabric import __version__
from emfabric.io.history import VARIABLES
from emfabric.runner.loop import run

from conftest import make

SMALL = {
    "fabric.nodes": [13, 13], "fabric.rescale": True, "solver.end_time": 6e-6,
    "output.snapshot_interval": 2e-6, "projectile.gap": 0.0,
}


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    return run(make(**SMALL), out), out


def test_history_contract(small_run):
    """history.nc has MODEL §7's variables with units, the version and the full scenario."""
    res, out = small_run
    ds = xr.open_dataset(out / "history.nc")
    required = ["dt", "iterations", "projectile_position", "projectile_velocity",
                "angular_velocity", "tilt", "contact_nodes", "max_deflection", "max_stretch",
                "fabric_momentum", "kinetic_energy_projectile", "kinetic_energy_fabric",
                "strain_energy", "broken_yarns", "min_damage"]
    for name in required + list(VARIABLES):
        assert name in ds, name
        assert "units" in ds[name].attrs
    # MODEL §7's variables in their SI units, written as CF/UDUNITS spells them
    si = {"dt": "s", "iterations": "1", "projectile_position": "m",
          "projectile_velocity": "m s-1", "angular_velocity": "rad s-1", "tilt": "rad",
          "contact_nodes": "1", "max_deflection": "m", "max_stretch": "1",
          "fabric_momentum": "kg m s-1", "kinetic_energy_projectile": "J",
          "kinetic_energy_fabric": "J", "strain_energy": "J", "broken_yarns": "1",
          "min_damage": "1", "yaw": "rad", "contact_force": "N",
          "fabric_angular_momentum": "kg m2 s-1", "energy_balance_error": "J"}
    assert {name: ds[name].attrs["units"] for name in si} == si
    assert ds.projectile_position.dims == ("time", "xyz")
    assert ds.time.attrs["units"] == "s"
    assert ds.attrs["emfabric_version"] == __version__
    assert ds.attrs["status"] == "complete"
    scenario = tomllib.loads(ds.attrs["scenario"])
    assert scenario["fabric"]["nodes"] == [13, 13]
    assert scenario["solver"]["tolerance"] == 1e-6  # defaults written out too
    # the full scenario: read back, it is the run's, every key
    from emfabric.config.scenario import scenario_from_dict

    assert scenario_from_dict(scenario, "history.nc").to_dict() == \
        res.model.scenario.to_dict()
    assert int(ds.contact_nodes.max()) > 0
    assert float(ds.time[-1]) == pytest.approx(6e-6)


def test_snapshots_and_paraview(small_run):
    """Snapshots hold positions, velocities and damage; the .pvd collections list the VTU files."""
    res, out = small_run
    snap = xr.open_dataset(out / "snapshots.nc")
    assert snap.sizes["snapshot"] == 4  # t = 0, 2, 4, 6 µs
    assert snap.node_position.shape == (4, 169, 3)
    assert snap.yarn_damage.shape == (4, res.model.seg_count)
    np.testing.assert_array_equal(snap.node_position[-1].values, res.state.node_x.T)
    # the velocities (MODEL §7): the run's last state, and Σ m v of every snapshot is the
    # fabric momentum history.nc records at the same time
    assert (snap.node_position.attrs["units"], snap.node_velocity.attrs["units"],
            snap.yarn_damage.attrs["units"]) == ("m", "m s-1", "1")
    np.testing.assert_array_equal(snap.node_velocity[-1].values, res.state.node_v.T)
    hist = xr.open_dataset(out / "history.nc")
    mass = res.model.nodes.mass
    for k, t in enumerate(snap.time.values):
        p = hist.fabric_momentum.sel(time=t).values
        np.testing.assert_allclose(mass @ snap.node_velocity[k].values, p, rtol=1e-12,
                                   atol=1e-12 * max(np.abs(p).max(), 1e-30))
    assert np.abs(snap.node_velocity[-1].values).max() > 1.0  # the struck sheet moves
    # the run's end in its header too, as in history.nc's (it was created "partial"), and
    # the run's wall time (it said the wall time at its first snapshot before 2026-12-07)
    assert (snap.attrs["status"], snap.attrs["end_reason"]) == (res.status, res.end_reason)
    assert snap.attrs["wall_time_s"] == hist.attrs["wall_time_s"] == f"{res.wall_time:.3f}"
    pvd = (out / "fabric.pvd").read_text()
    assert pvd.count("<DataSet") == 4
    import meshio

    mesh = meshio.read(out / "vtk" / "fabric_00003.vtu")
    assert mesh.points.shape == (169, 3)
    assert "damage" in mesh.cell_data and "velocity" in mesh.point_data
    assert (out / "projectile.pvd").exists()


def test_paraview_files_can_be_turned_off(tmp_path):
    """output.paraview = false: snapshots.nc as usual, no vtk/ folder and no .pvd files."""
    run(make(**SMALL, **{"output.paraview": False}), tmp_path)
    snap = xr.open_dataset(tmp_path / "snapshots.nc")
    assert snap.sizes["snapshot"] == 4
    assert not (tmp_path / "vtk").exists()
    assert not list(tmp_path.glob("*.pvd"))


def test_vtu_files_written_beside_the_run_are_those_written_in_line(tmp_path, monkeypatch):
    """A serial run writes its .vtu files from a thread of its own while it steps
    (io.snapshots): the files, and the .pvd collections listing them, are byte for byte those
    of the same run writing them in line, and every one is there when the run returns."""
    import threading

    import emfabric.runner.loop as runner
    from emfabric.io.snapshots import Snapshots

    sc = make(**{**SMALL, "solver.end_time": 2e-5, "output.snapshot_interval": 1e-6})
    writers: list[str] = []
    real = Snapshots._write_vtk

    def record(self, k, snap):
        writers.append(threading.current_thread().name)
        return real(self, k, snap)

    monkeypatch.setattr(Snapshots, "_write_vtk", record)
    beside = run(sc, tmp_path / "beside", threads=1)
    assert len(writers) == 21 and all(w.startswith("emfabric-vtu") for w in writers)

    class InLine(Snapshots):
        def __init__(self, *args, background=False, **kwargs):
            super().__init__(*args, background=False, **kwargs)

    writers.clear()
    monkeypatch.setattr(runner, "Snapshots", InLine)
    in_line = run(sc, tmp_path / "in_line", threads=1)
    assert len(writers) == 21 and set(writers) == {threading.main_thread().name}
    assert beside.status == in_line.status == "complete"
    names = sorted(p.name for p in (tmp_path / "in_line" / "vtk").iterdir())
    assert len(names) == 42  # fabric and projectile, t = 0, 1, ..., 20 µs
    assert sorted(p.name for p in (tmp_path / "beside" / "vtk").iterdir()) == names
    for name in names:
        assert (tmp_path / "beside" / "vtk" / name).read_bytes() == \
            (tmp_path / "in_line" / "vtk" / name).read_bytes(), name
    for pvd in ("fabric.pvd", "projectile.pvd"):
        assert (tmp_path / "beside" / pvd).read_text() == (tmp_path / "in_line" / pvd).read_text()


@pytest.mark.parametrize("failing", [5, 41])
def test_a_vtu_write_that_fails_beside_the_run_stops_it_naming_the_file(tmp_path, monkeypatch,
                                                                        failing):
    """A .vtu write that fails in the writing thread (disk full) ends the run as one in line
    would: "failed", the file named, history.nc readable with that status — also when it is
    the last snapshot's, whose failure the run learns only after its last step."""
    import errno

    import emfabric.io.snapshots as snapshots
    import emfabric.runner.loop as runner

    real = snapshots.meshio.write
    written = []

    def fill_up(path, mesh, **kwargs):
        written.append(path)
        if len(written) == failing:  # fabric_00002.vtu, fabric_00020.vtu (the last)
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(path, mesh, **kwargs)

    monkeypatch.setattr(snapshots.meshio, "write", fill_up)
    sc = make(**{**SMALL, "solver.end_time": 2e-5, "output.snapshot_interval": 1e-6})
    name = f"fabric_{(failing - 1) // 2:05d}.vtu"
    with pytest.raises(runner.OutputError, match=rf"{name}: No space left on device") as info:
        run(sc, tmp_path, threads=1)
    assert info.value.result.status == "failed"
    with xr.open_dataset(tmp_path / "history.nc") as ds:
        assert ds.attrs["status"] == "failed"
        assert ds.attrs["end_reason"] == (f"write error: cannot write {name}: No space left "
                                          "on device")
        assert ds.sizes["time"] >= 2


def test_same_seed_same_history():
    """Same scenario and seed ⇒ bit-identical history; another seed ⇒ another fabric."""
    a = run(make(**SMALL)).history
    b = run(make(**SMALL)).history
    for name in VARIABLES:
        np.testing.assert_array_equal(a[name].values, b[name].values)
    c = run(make(**{**SMALL, "fabric.material.seed": 7})).history
    assert not np.array_equal(a.angular_velocity.values, c.angular_velocity.values)


def interrupt_after(steps: int):
    """A progress callback that raises KeyboardInterrupt (Ctrl-C) at its `steps`-th step."""
    calls = []

    def progress(state, info):
        calls.append(state.t)
        if len(calls) == steps:
            raise KeyboardInterrupt

    return progress


def test_interrupt_leaves_partial_history(tmp_path):
    """Ctrl-C mid-run leaves a readable history marked partial, with the steps done so far."""
    with pytest.raises(KeyboardInterrupt):
        run(make(**SMALL), tmp_path, progress=interrupt_after(5))
    ds = xr.open_dataset(tmp_path / "history.nc")
    assert ds.attrs["status"] == "partial"
    assert "interrupted" in ds.attrs["end_reason"]
    assert ds.sizes["time"] == 6
    assert xr.open_dataset(tmp_path / "snapshots.nc").sizes["snapshot"] >= 2
    assert not list(tmp_path.glob(".*partial*"))


def test_a_run_without_projectile_records_its_variables_as_nan(tmp_path):
    """projectile.shape = "none": the variables of the projectile itself are not a number in
    history.nc (as written during the run, when it ends and after a resume) and in memory;
    its momenta, kinetic energy and contact force are 0; the fabric's are recorded (the same
    records as without the interruption)."""
    from emfabric.io.history import NO_PROJECTILE
    from emfabric.runner.loop import resume

    from conftest import fabric_only

    sc = fabric_only(**{"fabric.nodes": [7, 7], "field.B": [0.5, 0.0, 0.0],
                        "fabric.velocity": [0.0, 0.0, 1.0], "solver.end_time": 2e-5})
    ref = run(sc).history
    assert all(np.isnan(ref[n].values).all() for n in NO_PROJECTILE)
    with pytest.raises(KeyboardInterrupt):
        run(sc, tmp_path, progress=interrupt_after(4))
    with xr.open_dataset(tmp_path / "history.nc") as part:
        assert part.attrs["has_projectile"] == 0 and part.sizes["time"] == 5
        assert all(np.isnan(part[n].values).all() for n in NO_PROJECTILE)
    whole = resume(tmp_path).history
    with xr.open_dataset(tmp_path / "history.nc") as ds:
        for h in (ds, whole):
            assert h.sizes["time"] > 5
            for name in NO_PROJECTILE:
                assert np.isnan(h[name].values).all(), name
            for name in ("projectile_momentum", "projectile_angular_momentum",
                         "kinetic_energy_projectile", "contact_force"):
                assert (h[name].values == 0.0).all(), name
            # the fabric's records are those of the run without the interruption
            for name in ("fabric_momentum", "kinetic_energy_fabric", "max_deflection"):
                np.testing.assert_array_equal(h[name].values, ref[name].values)
            assert np.abs(h["fabric_momentum"].values).max() > 0.0
        assert "no projectile" in ds["tilt"].attrs["comment"]


def test_cli_run_validate_scenarios(tmp_path):
    """The command line runs a scenario with overrides and prints a summary; errors exit 2."""
    exe = [sys.executable, "-m", "emfabric"]
    r = subprocess.run(exe + ["scenarios"], capture_output=True, text=True)
    assert r.returncode == 0 and "paper-field" in r.stdout
    r = subprocess.run(exe + ["validate", "paper-spin"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    r = subprocess.run(exe + ["validate", "paper-spin", "--set", "solver.phi=2"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "solver.phi" in r.stderr
    args = ["run", "demo-small", "--out", str(tmp_path / "d"), "-q", "--json",
            "--set", "fabric.nodes=[10,10]", "--set", "solver.end_time=3e-6"]
    r = subprocess.run(exe + args, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    import json

    summary = json.loads(r.stdout)
    assert summary["status"] == "complete" and summary["steps"] > 0
    assert (tmp_path / "d" / "history.nc").exists()


def test_history_record_matches_diagnostics(small_run):
    """The compiled history row agrees with the plain diagnostics of the final state."""
    from emfabric.sim.state import ENERGY_TERMS

    res, _ = small_run
    ds, st, m = res.history, res.state, res.model
    last = ds.isel(time=-1)
    # by hand: Ī = R I Rᵀ (B15), KE = M v²/2 + ω·Īω/2, L = x × Mv + Īω, tilt from eq. 5.2
    rot, w = st.body_rotation, st.body_omega
    inertia = rot @ m.body.inertia @ rot.T
    ke_t, ke_r = 0.5 * m.body.mass * st.body_v @ st.body_v, 0.5 * w @ inertia @ w
    p = m.body.mass * st.body_v
    ang = np.cross(st.body_x, p) + inertia @ w
    nose = rot @ m.body.nose
    cos = nose @ m.body.nose / (np.linalg.norm(nose) * np.linalg.norm(m.body.nose))
    assert float(last.tilt) == pytest.approx(np.arccos(min(cos, 1.0)), rel=1e-6, abs=1e-7)
    assert float(last.kinetic_energy_projectile) == pytest.approx(ke_t + ke_r, rel=1e-12)
    assert float(last.kinetic_energy_projectile_rotation) == pytest.approx(ke_r, rel=1e-12,
                                                                           abs=1e-18)
    np.testing.assert_allclose(last.projectile_momentum.values, p, rtol=1e-12)
    np.testing.assert_allclose(last.projectile_angular_momentum.values, ang, rtol=1e-10,
                               atol=1e-15)
    np.testing.assert_array_equal(last.projectile_velocity.values, st.body_v)
    for i, name in enumerate(ENERGY_TERMS):
        assert float(last[name]) == st.energy[i]
    ke_f = 0.5 * float((m.nodes.mass * (st.node_v**2).sum(axis=0)).sum())
    assert float(last.kinetic_energy_fabric) == pytest.approx(ke_f, rel=1e-12)


@pytest.mark.parametrize("umask", [0o022, 0o027, 0o077])
def test_output_files_respect_the_umask(tmp_path, umask):
    """Files are created with the permissions of any new file under the user's umask (a
    shared run folder stays readable by the group), not mkstemp's owner-only 0600."""
    code = ("import os, sys; os.umask(int(sys.argv[2])); from emfabric.io.atomic import "
            "write_atomic; write_atomic(sys.argv[1], lambda p: p.write_text('x'))")
    target = tmp_path / "f.txt"
    subprocess.run([sys.executable, "-c", code, str(target), str(umask)], check=True)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask
    assert [p.name for p in tmp_path.iterdir()] == ["f.txt"]


def test_netcdf_files_follow_cf_conventions(tmp_path):
    """history.nc and snapshots.nc carry what a CF checker asks for: units and long_name on
    every variable, simulated time without CF's calendar `time` standard name, `xyz` stored
    as a character label (not a variable-length string), source and references."""
    import netCDF4

    from conftest import run_demo

    run_demo(tmp_path, {"fabric.nodes": [6, 6], "solver.end_time": 2e-6})
    for name in ("history.nc", "snapshots.nc"):
        with netCDF4.Dataset(tmp_path / name) as nc:
            assert nc.Conventions == "CF-1.8"
            assert __version__ in nc.source and "Zohdi" in nc.references
            assert nc["xyz"].dtype == np.dtype("S1")
            assert "standard_name" not in nc["time"].ncattrs()
            for var in nc.variables.values():
                if var.name == "xyz":
                    continue
                assert {"units", "long_name"} <= set(var.ncattrs()), (name, var.name)
        ds = xr.open_dataset(tmp_path / name)
        assert list(ds["xyz"].values) == ["x", "y", "z"]
        ds["projectile_velocity"].sel(xyz="z")


def test_whole_files_read_back_as_xarray_writes_them(tmp_path):
    """write_netcdf(ds, path) (netCDF-4, checkpoint.nc) goes through xarray's encoding and
    store without to_netcdf: read back, the file is xarray's own write of the dataset (values,
    dtypes, fill values, attributes, the char `xyz` label, scalars)."""
    from emfabric.io.netcdf import write_netcdf, xyz_coordinate

    rng = np.random.default_rng(5)
    ds = xr.Dataset(
        {"x": (("node", "xyz"), rng.normal(size=(4, 3)), {"units": "m"}),
         "n": ((), np.int64(2**40)), "t": ((), np.float64(0.5)),
         "alpha": (("segment",), np.array([1.0, np.nan, 0.25]))},
        coords={"xyz": xyz_coordinate()}, attrs={"title": "t", "grid": np.int32([3, 4])})
    write_netcdf(ds, tmp_path / "ours.nc")
    ds.to_netcdf(tmp_path / "xarray.nc", engine="netcdf4", format="NETCDF4",
                 encoding={"xyz": {"dtype": "S1"}})
    with xr.open_dataset(tmp_path / "ours.nc") as ours, \
            xr.open_dataset(tmp_path / "xarray.nc") as theirs:
        xr.testing.assert_identical(ours.load(), theirs.load())
        for name in theirs.variables:
            assert ours[name].encoding["dtype"] == theirs[name].encoding["dtype"], name
            np.testing.assert_equal(ours[name].encoding.get("_FillValue"),
                                    theirs[name].encoding.get("_FillValue"), err_msg=name)


def test_a_run_imports_neither_dask_array_nor_distributed(tmp_path):
    """Writing a run's files imports no part of dask an array of NumPy does not need: where
    dask is installed, xarray would import dask.array (with scipy.fft) to ask whether each
    array is a dask array, and distributed to look for a scheduler (~0.5 s of every run;
    io.netcdf)."""
    pytest.importorskip("distributed")
    code = ("import sys; from emfabric.runner.loop import run; from conftest import make; "
            f"run(make(**{dict(SMALL)!r}), {str(tmp_path / 'out')!r}); "
            "print([m for m in ('dask.array', 'distributed') if m in sys.modules])")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       cwd=str(Path(__file__).parent), timeout=600)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().splitlines()[-1] == "[]"


def test_xarray_sees_dask_arrays_made_after_emfabric_wrote_files(tmp_path):
    """io.netcdf answers xarray's "is it a dask array?" without importing dask.array only
    while dask.array is not imported: arrays made after it is, in the same process, are
    dask arrays to xarray as always (chunks, version, lazy compute)."""
    pytest.importorskip("dask.array")
    code = f"""
import sys
import numpy as np
import xarray as xr
from emfabric.io.netcdf import write_netcdf
write_netcdf(xr.Dataset({{"a": (("n",), np.arange(3.0))}}), {str(tmp_path / "a.nc")!r})
assert "dask.array" not in sys.modules
import dask
import dask.array as da
from xarray.namedarray import pycompat
v = xr.DataArray(da.ones(4, chunks=2), dims="n")
assert v.chunks == ((2, 2),), v.chunks
assert isinstance(v.data, da.Array) and float(v.sum().compute()) == 4.0
assert pycompat.array_type("dask") == (da.Array,)
assert str(pycompat.mod_version("dask")) == dask.__version__
print("ok")
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "ok"


@pytest.mark.parametrize("records", [0, 1, 2, 37])
def test_record_files_read_back_as_xarray_writes_them(tmp_path, records):
    """write_netcdf(..., unlimited=dim) writes the header and first record through xarray and
    appends the rest directly: read back, the file is xarray's own write of the same dataset
    (values, dtypes, attributes, the char `xyz` label, a non-index coordinate along the record
    dimension), and the record dimension stays unlimited (appendable)."""
    from emfabric.io.netcdf import append_records, write_netcdf, xyz_coordinate

    rng = np.random.default_rng(3)
    ds = xr.Dataset(
        {"x": (("snapshot", "node", "xyz"), rng.normal(size=(records, 4, 3)),
               {"units": "m", "long_name": "x"}),
         "n": (("snapshot",), np.arange(records, dtype=np.int64), {"units": "1"}),
         "fixed": (("node",), np.arange(4, dtype=np.int32), {"units": "1"})},
        coords={"time": ("snapshot", np.linspace(0.0, 1.0, records), {"units": "s"}),
                "xyz": xyz_coordinate()},
        attrs={"title": "t", "count": np.int32(records)})
    if records:
        ds["x"][-1, 0, 0] = np.nan
    write_netcdf(ds, tmp_path / "ours.nc", unlimited="snapshot")
    ds.to_netcdf(tmp_path / "xarray.nc", engine="netcdf4", format="NETCDF3_64BIT_OFFSET",
                 encoding={"xyz": {"dtype": "S1"}}, unlimited_dims=["snapshot"])
    with xr.open_dataset(tmp_path / "ours.nc") as ours, \
            xr.open_dataset(tmp_path / "xarray.nc") as theirs:
        xr.testing.assert_identical(ours.load(), theirs.load())
        assert ours.encoding["unlimited_dims"] == {"snapshot"}
        for name in theirs.variables:
            assert ours[name].encoding["dtype"] == theirs[name].encoding["dtype"], name
    more = {"x": np.ones((2, 4, 3)), "n": np.array([7, 8]), "time": np.array([2.0, 3.0])}
    assert append_records(tmp_path / "ours.nc", "snapshot", more) == records + 2
    with xr.open_dataset(tmp_path / "ours.nc") as back:
        assert back.sizes["snapshot"] == records + 2
        assert (back["n"].values[-2:] == [7, 8]).all()
