"""Figures drawn from a tiny run's files: contents of the matplotlib objects, not pixels."""

from __future__ import annotations

import ast
import logging
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from mpl_toolkits.mplot3d import Axes3D

from emfabric.viz import plots

from conftest import interrupted_demo, run_demo

# 13 x 13 nodes (a centre node under the sphere), 20 µs, snapshots every 5 µs; a low critical
# stretch so that the yarns take some damage within that time
TINY = {
    "fabric.nodes": [13, 13],
    "solver.end_time": 20e-6,
    "output.snapshot_interval": 5e-6,
    "fabric.damage.critical_stretch": 1.001,
    "fabric.damage.rate": 2.0,
}
SIMULATOR = ("emfabric.runner", "emfabric.integrators", "emfabric._kernels",
             "emfabric.sim", "emfabric.sources", "numba")


def tiny_run(out: Path, **overrides) -> Path:
    """Run the tiny scenario into ``out`` (the tests may use the simulator; plots may not)."""
    return run_demo(out, {**TINY, **overrides})


@pytest.fixture(scope="session")
def field_run(tmp_path_factory) -> Path:
    return tiny_run(tmp_path_factory.mktemp("field"))


@pytest.fixture(scope="session")
def nofield_run(tmp_path_factory) -> Path:
    return tiny_run(tmp_path_factory.mktemp("nofield"), **{"field.B": [0.0, 0.0, 0.0]})


@pytest.fixture(scope="session")
def partial_run(tmp_path_factory) -> Path:
    return interrupted_demo(tmp_path_factory.mktemp("partial"), TINY, after=8)


def ylabels(fig) -> list[str]:
    return [ax.get_ylabel() for ax in fig.axes if ax.get_ylabel()]


def test_single_run_writes_four_figures_as_png_and_pdf(field_run):
    """One run gives spin, impact sequence, energy and velocity figures, each as PNG and PDF."""
    files = plots.plot_runs([field_run])
    expected = {f"{stem}.{ext}" for stem in plots.FIGURE_STEMS for ext in ("png", "pdf")}
    assert {f.name for f in files} == expected
    for f in files:
        assert f.parent == field_run / "figures" and f.is_file() and f.stat().st_size > 1000


def test_spin_figure_has_tilt_and_three_spin_components(field_run):
    """The spin figure has a tilt and a yaw line [deg] and three ω lines [rad/s] against
    time [µs]."""
    h = plots.open_history(field_run)
    fig = plots.spin_figure([h])
    tilt_ax, *omega_axes = fig.axes
    assert tilt_ax.get_ylabel() == "tilt Θ, yaw ψ [deg]" and len(tilt_ax.lines) == 2
    np.testing.assert_allclose(tilt_ax.lines[1].get_ydata(), np.degrees(h["yaw"]))
    assert len(omega_axes) == 3
    for c, ax in enumerate(omega_axes):
        assert "[rad/s]" in ax.get_ylabel() and "xyz"[c] in ax.get_ylabel()
        assert len(ax.lines) == 1
        np.testing.assert_array_equal(ax.lines[0].get_ydata(), h["angular_velocity"][:, c])
    np.testing.assert_allclose(tilt_ax.lines[0].get_ydata(), np.degrees(h["tilt"]))
    np.testing.assert_allclose(tilt_ax.lines[0].get_xdata(), h["time"] * 1e6)
    assert fig.axes[-1].get_xlabel() == "time [µs]"


def test_overlay_doubles_the_lines(field_run, nofield_run):
    """Two overlaid runs draw two tilt and two yaw lines and six ω lines, with a legend entry
    per run."""
    hs = [plots.open_history(field_run), plots.open_history(nofield_run)]
    fig = plots.spin_figure(hs, ["a", "b"])
    assert len(fig.axes[0].lines) == 4
    assert sum(len(ax.lines) for ax in fig.axes[1:]) == 6
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["a", "b"]


def test_overlay_legend_of_long_labels_stays_on_the_figure(field_run):
    """Labels of runs that differ in many settings are wrapped and listed one per row: the
    legend lies within the figure (three columns of such labels ran off both edges)."""
    ds = plots.open_history(field_run)
    long = ", ".join(f"fabric.setting_{k} = {k / 7:.4f}" for k in range(6))
    fig = plots.energy_figure([ds, ds, ds], [long + " (a)", long + " (b)", "short"])
    fig.canvas.draw()
    box = fig.legends[0].get_window_extent()
    page = fig.bbox
    assert page.x0 <= box.x0 and box.x1 <= page.x1 and page.y0 <= box.y0, (box, page)


def test_energy_figure_terms_and_units(field_run):
    """The energy figure draws every budget term and the balance error, all in [J]."""
    h = plots.open_history(field_run)
    fig = plots.energy_figure(h)
    assert all("[J]" in label for label in ylabels(fig)) and len(ylabels(fig)) == 3
    drawn = [line.get_label() for ax in fig.axes for line in ax.lines]
    for term in ("projectile kinetic", "projectile rotation", "fabric kinetic", "strain",
                 "work of the field", "friction", "contact", "projection", "damage",
                 "balance error"):
        assert term in drawn
    error = next(line for line in fig.axes[2].lines if line.get_label() == "balance error")
    np.testing.assert_array_equal(error.get_ydata(), h["energy_balance_error"])
    assert fig.axes[-1].get_xlabel() == "time [µs]"


def test_velocity_figure_components_speed_and_deflection(field_run):
    """The velocity figure shows v_z and speed, v_x and v_y [m/s], and deflection [mm]."""
    h = plots.open_history(field_run)
    fig = plots.velocity_figure(h)
    labels = ylabels(fig)
    assert labels[:2] == ["velocity [m/s]"] * 2 and labels[2] == "max deflection [mm]"
    assert [len(ax.lines) for ax in fig.axes] == [2, 2, 1]
    speed = np.linalg.norm(h["projectile_velocity"].values, axis=1)
    np.testing.assert_allclose(fig.axes[0].lines[1].get_ydata(), speed)
    np.testing.assert_allclose(fig.axes[2].lines[0].get_ydata(), h["max_deflection"] * 1e3)


def test_sequence_colour_bar_spans_the_damage_shown(field_run):
    """The impact sequence's one colour bar spans min..max of α over the shown snapshots."""
    with plots.open_snapshots(field_run) as s:
        idx = plots.pick_snapshots(s["time"].values, 4)
        alpha = s["yarn_damage"].values[idx]
        fig = plots.sequence_figure(s, count=4)
    assert alpha.min() < alpha.max()  # the tiny run does damage its yarns
    views = [ax for ax in fig.axes if isinstance(ax, Axes3D)]
    bars = [ax for ax in fig.axes if ax.get_ylabel() == plots.DAMAGE_LABEL]
    assert len(views) == len(idx) == 4 and len(bars) == 1
    np.testing.assert_allclose(bars[0].get_ylim(), (alpha.min(), alpha.max()))
    for ax, k in zip(views, idx, strict=True):
        sheet = ax.collections[0]
        assert sheet.get_clim() == (alpha.min(), alpha.max())
        np.testing.assert_array_equal(sheet.get_array(), alpha[list(idx).index(k)])
        assert f"t = {float(s['time'][k]) * 1e6:.1f} µs" in ax.get_title()
        assert f"ψ = {plots.snapshot_yaw_deg(s, int(k)):.2f}°" in ax.get_title()


def test_sequence_pdf_holds_the_yarns_as_one_image_per_view(field_run, tmp_path):
    """In the PDF the yarns of each view are an embedded image (rasterized), not one vector
    path per segment; the axes and the projectile stay vector: the PDF has no more paths than
    the views' other artists need, whatever the sheet's size."""
    import matplotlib

    with plots.open_snapshots(field_run) as s:
        fig = plots.sequence_figure(s, count=2)
        segments = len(plots.shown_segments(s))
    views = [ax for ax in fig.axes if isinstance(ax, Axes3D)]
    assert all(ax.collections[0].get_rasterized() for ax in views)
    assert not any(c.get_rasterized() for ax in views for c in ax.collections[1:])
    with matplotlib.rc_context({**plots.STYLE, "pdf.compression": 0}):  # readable streams
        fig.savefig(tmp_path / "seq.pdf")
    pdf = (tmp_path / "seq.pdf").read_bytes()
    assert pdf.count(b"/Subtype /Image") >= len(views)
    # drawn as paths, each view's segments would be a move-to ("x y m") each
    assert pdf.count(b" m\n") + pdf.count(b" m ") < segments


def test_snapshot_yaw_from_the_rotation_equals_the_history(field_run):
    """ψ of a snapshot from its rotation and velocity is the history's yaw at that time."""
    h = plots.open_history(field_run)
    with plots.open_snapshots(field_run) as s:
        for k in range(s.sizes["snapshot"]):
            assert plots.snapshot_yaw_deg(s, k) == pytest.approx(
                plots.snapshot_yaw_deg(s, k, h), abs=1e-6)


def test_sequence_draws_sphere_and_nose_arrow(field_run):
    """Each view holds the sheet, the sphere wireframe and the nose arrow R·nose_body."""
    with plots.open_snapshots(field_run) as s:
        fig = plots.sequence_figure(s, count=2)
        k = plots.pick_snapshots(s["time"].values, 2)[-1]
        nose = s["projectile_rotation"].values[k] @ s["projectile_nose_body"].values
        centre = s["projectile_position"].values[k]
    ax = [a for a in fig.axes if isinstance(a, Axes3D)][-1]
    assert len(ax.collections) == 3  # sheet, wireframe, arrow
    shaft = sorted(np.asarray(ax.collections[2]._segments3d[0]).tolist())  # its two ends
    tip = centre + plots.NOSE_ARROW * nose
    np.testing.assert_allclose(shaft, sorted([centre.tolist(), tip.tolist()]), atol=1e-12)


def test_fabric_alone_draws_no_sphere(tmp_path):
    """A run without a projectile draws the sheet only."""
    run_dir = tiny_run(tmp_path / "alone", **{"projectile.shape": "none",
                                               "fabric.velocity": [0.0, 0.0, -10.0]})
    with plots.open_snapshots(run_dir) as s:
        assert int(s.attrs["has_projectile"]) == 0
        fig = plots.sequence_figure(s, count=2)
    for ax in (a for a in fig.axes if isinstance(a, Axes3D)):
        assert len(ax.collections) == 1
    # no spin figure, and a velocity figure of the deflection alone (no empty panels)
    files = plots.plot_runs([run_dir], tmp_path / "figs")
    assert sorted({f.stem for f in files}) == ["energy", "impact_sequence", "velocity"]
    with plots.open_history(run_dir) as ds:
        fig = plots.velocity_figure(ds)
    assert len(fig.axes) == 1 and len(fig.axes[0].lines) == 1
    assert float(np.nanmax(fig.axes[0].lines[0].get_ydata())) > 0.0


def test_flat_damage_gets_a_tiny_range_ending_at_the_value():
    """All yarns at the same α give the colour range (α − 1e-6, α); otherwise the data range."""
    assert plots.damage_range(np.ones((3, 5))) == (1.0 - plots.FLAT_RANGE, 1.0)
    assert plots.damage_range(np.array([0.5, 0.9, 1.0])) == (0.5, 1.0)


def test_pick_snapshots_spreads_over_the_run():
    """Shown snapshots are the ones nearest evenly spaced times, first and last included."""
    times = np.array([0.0, 5.1, 10.2, 15.0, 20.3, 25.0, 30.0])
    assert list(plots.pick_snapshots(times, 3)) == [0, 3, 6]
    assert list(plots.pick_snapshots(times[:2], 6)) == [0, 1]


def test_overlay_files_and_labels_from_scenario_difference(field_run, nofield_run, tmp_path):
    """Overlaying runs writes compare_* files, labelled by the differing scenario key (B)."""
    files = plots.plot_runs([field_run, nofield_run], tmp_path)
    assert {f.name for f in files} == {f"{stem}.{ext}" for stem in plots.COMPARE_STEMS
                                       for ext in ("png", "pdf")}
    assert all(f.parent == tmp_path and f.is_file() for f in files)
    hs = [plots.open_history(field_run), plots.open_history(nofield_run)]
    assert plots.scenario_labels(hs, ["a", "b"]) == ["$B_x$ = 0.05 T", "$B$ = 0"]


def test_scenario_labels_fall_back_to_names():
    """Without a differing setting the labels are scenario names, then folder names."""
    def ds(text: str) -> xr.Dataset:
        return xr.Dataset(attrs={"scenario": text})

    same = [ds('name = "a"\n[field]\nB = [0.0, 0.0, 0.0]\n')] * 2
    assert plots.scenario_labels(same, ["run1", "run2"]) == ["run1", "run2"]
    named = [ds('name = "a"\ndescription = "x"\n'), ds('name = "b"\ndescription = "y"\n')]
    assert plots.scenario_labels(named, ["run1", "run2"]) == ["a", "b"]
    assert plots.scenario_labels([xr.Dataset(), xr.Dataset()], ["p", "q"]) == ["p", "q"]
    many = [ds("[solver]\nphi = 0.5\ntolerance = 1e-6\n[fabric]\nnodes = [10, 10]\n"),
            ds("[solver]\nphi = 1.0\ntolerance = 1e-7\n[fabric]\nnodes = [20, 20]\n")]
    assert plots.scenario_labels(many, ["p", "q"]) == [
        r"$\phi$ = 0.5, solver.tolerance = 1e-06, 10 × 10 nodes",
        r"$\phi$ = 1, solver.tolerance = 1e-07, 20 × 20 nodes"]


@pytest.mark.parametrize(("key", "value", "text"), [
    ("field.B", [0.05, 0.0, 0.0], "$B_x$ = 0.05 T"),
    ("field.B", [0.0, 0.0, 0.0], "$B$ = 0"),
    ("field.E", [1.0, 0.0, 2.0], "$E$ = (1, 0, 2) V/m"),
    ("projectile.angular_velocity", [0, 0, 10000.0], r"$\omega_{0z}$ = 10000 rad/s"),
    ("contact.static_friction", 0.5, r"$\mu_s$ = 0.5"),
    ("fabric.material.model", "fung", "fabric.material.model = fung"),
])
def test_pretty_setting(key, value, text):
    """Known settings print with symbol and unit; others as dotted key = value."""
    assert plots.pretty_setting(key, value) == text


def test_partial_run_is_drawn_and_says_so(partial_run, tmp_path, caplog):
    """An interrupted run still plots; its titles say partial and a warning is logged."""
    h = plots.open_history(partial_run)
    assert h.attrs["status"] == "partial"
    with caplog.at_level(logging.WARNING, logger="emfabric.viz.plots"):
        files = plots.plot_runs([partial_run], tmp_path)
    assert len(files) == 8
    assert any("partial" in r.getMessage() for r in caplog.records)
    for make in (plots.spin_figure, plots.energy_figure, plots.velocity_figure):
        assert "(partial: interrupted at t =" in make(h).get_suptitle()
    with plots.open_snapshots(partial_run) as s:
        assert "(partial: " in plots.sequence_figure(s, history=h).get_suptitle()


def test_diverged_status_from_attributes(field_run):
    """A history marked diverged carries its reason into the title."""
    h = plots.open_history(field_run)
    h.attrs.update(status="diverged", end_reason="no convergence at t = 1e-05 s")
    assert plots.status_note(h) == "diverged: no convergence at t = 1e-05 s"
    assert "diverged: no convergence" in plots.spin_figure(h).get_suptitle()
    h.attrs.update(status="complete")
    assert plots.status_note(h) is None


def test_plot_modules_import_nothing_from_the_simulator():
    """plots.py, animation.py and study_plots.py import no simulator module (source check)."""
    src = Path(plots.__file__).parent
    for name in ("plots.py", "animation.py", "study_plots.py"):
        tree = ast.parse((src / name).read_text(encoding="utf-8"))
        imported = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
        imported += [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)
                     and n.module]
        bad = [m for m in imported if m.startswith(SIMULATOR)]
        assert not bad, f"{name} imports {bad}"


def test_plot_modules_load_without_numba():
    """Importing the plot modules (package __init__ bypassed) loads neither Numba nor
    kernels."""
    code = (
        "import importlib.util, sys, types\n"
        "spec = importlib.util.find_spec('emfabric')\n"
        "pkg = types.ModuleType('emfabric')\n"
        "pkg.__path__ = list(spec.submodule_search_locations)\n"
        "sys.modules['emfabric'] = pkg\n"
        "import emfabric.viz.plots, emfabric.viz.animation, emfabric.viz.study_plots\n"
        "import emfabric.viz.field_plot\n"
        f"bad = [m for m in sys.modules if m.startswith({SIMULATOR!r})]\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_package_import_of_plots_loads_no_numba():
    """`import emfabric.viz.plots` loads no Numba (the package loads the simulator lazily)."""
    code = "import emfabric.viz.plots, sys; assert 'numba' not in sys.modules"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr


def test_a_study_metric_without_a_value_is_said_not_dropped(tmp_path, caplog):
    """Two cases both still in contact at their end time (perforated = −1 in each): the other
    metrics are drawn, and the perforation figure, which has nothing to draw, is named in a
    warning instead of missing without a word."""
    from emfabric.viz import study_plots

    xr.Dataset({"residual_speed": (("field.B",), [240.0, 230.0]),
                "perforated": (("field.B",), np.array([-1, -1], dtype=np.int8))},
               coords={"field.B": [0.0, 0.05]}).to_netcdf(tmp_path / "results.nc")
    with caplog.at_level(logging.WARNING):
        files = study_plots.study_figures(tmp_path)
    assert {f.name for f in files} == {"study_residual_speed.png", "study_residual_speed.pdf"}
    assert any("study_perforated not drawn" in r.getMessage() for r in caplog.records)


def test_a_study_folder_without_axes_is_one_line_not_a_traceback(tmp_path):
    """results.nc of a study with neither [axes] nor [lhs] (one case, accepted before
    2026-12-07) has nothing to draw against: `emfabric plot` said IndexError in a traceback;
    now exit 2 and one line naming the file."""
    xr.Dataset({"residual_speed": ((), 240.0), "final_angular_velocity": (("xyz",),
                                                                          [1.0, 0.0, 0.0])},
               coords={"xyz": ["x", "y", "z"]}).to_netcdf(tmp_path / "results.nc")
    r = subprocess.run([sys.executable, "-m", "emfabric", "plot", str(tmp_path)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "has no study axis to draw against" in r.stderr
