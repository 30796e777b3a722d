"""Outputs of a pack of plies: snapshots.nc's ply variables and attributes, the ParaView files'
ply arrays (what carries nothing left out), and the figures and movie of a pack."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import meshio
import numpy as np
import pytest
import xarray as xr

import emfabric
from emfabric.sim.builder import build_model
from emfabric.viz import animation, plots

NODES = 11
PACK = {
    "fabric.nodes": [NODES, NODES],
    "fabric.plies": 2,
    "solver.end_time": 2e-6,
    "output.snapshot_interval": 1e-6,
}
ANGLED = {**PACK, "fabric.ply_angles": [0, 45]}


def scenario(overrides: dict):
    return emfabric.load_scenario("paper-no-field", overrides)


def run_pack(out: Path, overrides: dict) -> Path:
    emfabric.run(scenario(overrides), out_dir=out)
    return out


@pytest.fixture(scope="module")
def pack_run(tmp_path_factory) -> Path:
    return run_pack(tmp_path_factory.mktemp("pack"), PACK)


@pytest.fixture(scope="module")
def angled_run(tmp_path_factory) -> Path:
    return run_pack(tmp_path_factory.mktemp("angled"), ANGLED)


def last_vtu(run_dir: Path) -> meshio.Mesh:
    return meshio.read(sorted((run_dir / "vtk").glob("fabric_*.vtu"))[-1])


def test_snapshots_name_the_ply_of_each_node_and_segment(pack_run):
    """Two plies of 11 x 11 nodes: node_ply and segment_ply count 121 nodes and 2·11·10
    segments in each ply, consecutive, as the model numbers them; the attributes give the
    plies and their grids, and grid_nx/grid_ny stay ply 1's."""
    model = build_model(scenario(PACK))
    assert model.ply_count == 2
    with xr.open_dataset(pack_run / "snapshots.nc") as ds:
        # 1-based in the file (1 is the top ply), 0-based in the model
        node_ply, seg_ply = ds["node_ply"].values - 1, ds["segment_ply"].values - 1
        assert ds["node_ply"].dims == ("node",) and ds["segment_ply"].dims == ("segment",)
        assert node_ply.dtype == np.int32 and seg_ply.dtype == np.int32
        assert "long_name" in ds["node_ply"].attrs and "long_name" in ds["segment_ply"].attrs
        assert ds.sizes["node"] == 2 * NODES * NODES
        assert ds.sizes["segment"] == 2 * 2 * NODES * (NODES - 1)
        assert ds["node_position"].shape[1:] == (ds.sizes["node"], 3)
        assert ds["yarn_damage"].shape[1] == ds.sizes["segment"]
        attrs = ds.attrs
        carries = ds["node_carries_load"].values, ds["segment_carries_load"].values
    assert np.bincount(node_ply).tolist() == [NODES * NODES] * 2
    assert np.bincount(seg_ply).tolist() == [2 * NODES * (NODES - 1)] * 2
    np.testing.assert_array_equal(node_ply, model.node_ply())
    np.testing.assert_array_equal(seg_ply, model.segment_ply())
    # a ply's nodes and segments are consecutive
    assert np.all(np.diff(node_ply) >= 0) and np.all(np.diff(seg_ply) >= 0)
    assert int(attrs["plies"]) == 2
    assert np.atleast_1d(attrs["ply_grid_nx"]).tolist() == [NODES, NODES]
    assert np.atleast_1d(attrs["ply_grid_ny"]).tolist() == [NODES, NODES]
    assert (int(attrs["grid_nx"]), int(attrs["grid_ny"])) == model.ply_grid(0)
    assert all(c.all() for c in carries)  # aligned plies: everything carries load


def test_paraview_has_point_and_cell_ply_arrays(pack_run):
    """fabric_*.vtu: "ply" on points and cells, 1-based; nothing left out of aligned plies."""
    mesh = last_vtu(pack_run)
    n, s = 2 * NODES * NODES, 2 * 2 * NODES * (NODES - 1)
    assert mesh.points.shape == (n, 3)
    assert len(mesh.cells_dict["line"]) == s
    point_ply = np.asarray(mesh.point_data["ply"])
    cell_ply = np.asarray(mesh.cell_data["ply"][0])
    assert np.bincount(point_ply).tolist() == [0, n // 2, n // 2]
    assert np.bincount(cell_ply).tolist() == [0, s // 2, s // 2]
    np.testing.assert_array_equal(mesh.point_data["node_index"], np.arange(n))
    np.testing.assert_array_equal(mesh.cell_data["segment_index"][0], np.arange(s))
    with xr.open_dataset(pack_run / "snapshots.nc") as ds:
        np.testing.assert_array_equal(mesh.cells_dict["line"], ds["segment_nodes"].values)
        np.testing.assert_array_equal(mesh.points, ds["node_position"][-1].values)


def test_clipped_rotated_ply(angled_run):
    """Ply 2 at 45°: its grid is larger than ply 1's and clipped to the frame. snapshots.nc
    counts each ply's nodes and segments as the model does and says what carries load; the
    .vtu leaves out the nodes of mass 0 and the segments of stiffness 0, its points renumbered
    (node_index / segment_index lead back to snapshots.nc)."""
    model = build_model(scenario(ANGLED))
    per_ply_nodes = np.diff(model.nodes.ply_nodes).tolist()
    per_ply_segments = np.diff(model.yarns.ply_segments).tolist()
    gx, gy = model.ply_grid(1)
    assert per_ply_nodes == [NODES * NODES, gx * gy]
    assert per_ply_nodes[0] != per_ply_nodes[1]
    assert per_ply_segments == [2 * NODES * (NODES - 1), gy * (gx - 1) + gx * (gy - 1)]
    live_nodes = model.nodes.mass != 0
    live_segments = model.yarns.stiffness != 0
    assert not live_nodes.all() and not live_segments.all()  # something is clipped
    with xr.open_dataset(angled_run / "snapshots.nc") as ds:
        assert np.bincount(ds["node_ply"].values - 1).tolist() == per_ply_nodes
        assert np.bincount(ds["segment_ply"].values - 1).tolist() == per_ply_segments
        np.testing.assert_array_equal(ds["node_carries_load"].values, live_nodes)
        np.testing.assert_array_equal(ds["segment_carries_load"].values, live_segments)
        assert np.atleast_1d(ds.attrs["ply_grid_nx"]).tolist() == [NODES, gx]
        assert np.atleast_1d(ds.attrs["ply_grid_ny"]).tolist() == [NODES, gy]
        assert (int(ds.attrs["grid_nx"]), int(ds.attrs["grid_ny"])) == (NODES, NODES)
        x_last = ds["node_position"][-1].values
        seg_nodes = ds["segment_nodes"].values
    mesh = last_vtu(angled_run)
    node_index = np.asarray(mesh.point_data["node_index"])
    seg_index = np.asarray(mesh.cell_data["segment_index"][0])
    np.testing.assert_array_equal(seg_index, np.flatnonzero(live_segments))
    # every node that carries load is shown, and every end of a shown segment
    shown = live_nodes.copy()
    shown[model.yarns.ends[live_segments].ravel()] = True
    np.testing.assert_array_equal(node_index, np.flatnonzero(shown))
    np.testing.assert_array_equal(mesh.points, x_last[node_index])
    np.testing.assert_array_equal(node_index[mesh.cells_dict["line"]], seg_nodes[seg_index])
    np.testing.assert_array_equal(mesh.point_data["ply"], model.node_ply()[node_index] + 1)
    np.testing.assert_array_equal(mesh.cell_data["ply"][0], model.segment_ply()[seg_index] + 1)


@pytest.mark.parametrize("which", ["pack_run", "angled_run"])
def test_plot_and_animate_a_pack(which, request, tmp_path):
    """plot_runs and animate draw a pack: the files are written; the impact sequence has a
    section with a line per ply under each 3-D view, and its 3-D views draw only the yarns that
    carry load."""
    run_dir = request.getfixturevalue(which)
    files = plots.plot_runs([run_dir], tmp_path / "figures")
    expected = {f"{stem}.{ext}" for stem in plots.FIGURE_STEMS for ext in ("png", "pdf")}
    assert {f.name for f in files} == expected
    assert all(f.stat().st_size > 0 for f in files)
    with plots.open_snapshots(run_dir) as snaps:
        fig = plots.sequence_figure(snaps)
        count = len(plots.pick_snapshots(snaps["time"].values))
        live = int(snaps["segment_carries_load"].values.sum())
        # the projectile's y moved a third of a spacing off the middle grid line: the section
        # is that line, and its label gives the line's y, not the projectile's
        ref = snaps["reference_position"].values
        off = snaps.copy(deep=True)
        off["projectile_position"][:, 1] += (ref[NODES, 1] - ref[0, 1]) / 3
        drawn_y = float(ref[plots.section_nodes(off)[0][0], 1])
        assert drawn_y == float(ref[plots.section_nodes(snaps)[0][0], 1])
        label = plots.SectionView(plots.new_figure((4, 2)).add_subplot(), off).ax.get_xlabel()
        assert f"section at y = {drawn_y * 1e3:.3g} mm" in label
    sections = [ax for ax in fig.axes if ax.name != "3d" and ax.get_ylabel() == "z [m]"]
    assert len(sections) == count
    for ax in sections:
        assert [line.get_label() for line in ax.get_lines()] == ["ply 1", "ply 2"]
        assert all(len(line.get_xdata()) > 2 for line in ax.get_lines())
    views = [ax for ax in fig.axes if ax.name == "3d"]
    assert len(views) == count
    assert all(len(ax.collections[0].get_array()) == live for ax in views)  # α per yarn
    movies = animation.animate(run_dir, gif=True, mp4=animation.mp4_available())
    assert movies and all(f.is_file() and f.stat().st_size > 0 for f in movies)


def test_plot_and_animate_commands_on_a_pack(angled_run, tmp_path):
    """`emfabric plot` and `emfabric animate --gif --no-mp4` succeed on a pack's folder."""
    exe = [sys.executable, "-m", "emfabric"]
    out = tmp_path / "figs"
    r = subprocess.run(exe + ["plot", str(angled_run), "--out", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert (out / "impact_sequence.png").is_file()
    r = subprocess.run(exe + ["animate", str(angled_run), "--gif", "--no-mp4"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert (angled_run / "figures" / "impact.gif").is_file()
