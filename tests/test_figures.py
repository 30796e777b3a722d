"""Figures worth publishing (issue 25, item 6), drawn from small synthetic datasets and result
dicts built here (no simulation): the study plots' words, units, degrees, components,
perforation probability and numeric vector axes; the field figure's components, coils and
induced E; yaw in the run figures; ballistic.png's title, legend, rebounds and non-monotone
outcomes. Assertions are on the matplotlib objects, not on pixels."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import xarray as xr
from matplotlib.colors import to_rgba

from emfabric.studies.ballistic import lambert_jonas, non_monotone, write_outputs
from emfabric.studies.sweep import METRICS
from emfabric.viz import plots
from emfabric.viz.study_plots import (
    ballistic_plot,
    cf_units,
    metric_figure,
    setting_unit,
    study_figures,
    vector_axis,
)

B_AXIS = [[0.05, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0]]
MASSES = [0.005, 0.01]


def results(b_axis=B_AXIS, perforated=None, seed: int = 0, masses=MASSES) -> xr.Dataset:
    """A results.nc as emfabric.studies.sweep.collect writes it, over a vector axis field.B
    (3 values) and a scalar axis projectile.mass (2 values), with made-up numbers."""
    rng = np.random.default_rng(seed)
    dims = ("field.B", "projectile.mass")
    shape = (len(b_axis), len(masses))
    data = {k: rng.uniform(0.1, 1.0, shape) for k in METRICS if k not in ("status",)}
    data["perforated"] = (np.array(perforated, dtype=np.int8) if perforated is not None
                          else np.array([[1, 0], [1, 1], [-1, 0]], dtype=np.int8))
    data["broken_yarns"] = np.arange(np.prod(shape)).reshape(shape) + 3
    data["broken_yarns"][1, 1] = -1
    omega = rng.uniform(-900.0, 900.0, (*shape, 3))
    variables = {}
    for k, (units, meaning) in METRICS.items():
        if k == "status":
            continue
        attrs = {"long_name": meaning, **({"units": units} if units else {})}
        if k == "final_angular_velocity":
            variables[k] = ((*dims, "xyz"), omega, attrs)
        else:
            variables[k] = (dims, data[k], attrs)
    variables["field.B.values"] = (("field.B", "field.B.component"),
                                   np.asarray(b_axis, dtype=float), {})
    coords = {"field.B": ("field.B", np.arange(len(b_axis))),
              "projectile.mass": ("projectile.mass", np.array(masses)),
              "xyz": ("xyz", np.array(["x", "y", "z"]))}
    return xr.Dataset(variables, coords=coords,
                      attrs={"study": json.dumps({"base": "demo-small"})})


def texts(fig) -> list[str]:
    """Every title, axis label, tick label and legend entry of a figure."""
    out = [fig.get_suptitle()]
    for ax in fig.axes:
        out += [ax.get_title(), ax.get_title("left"), ax.get_xlabel(), ax.get_ylabel()]
        out += [t.get_text() for t in ax.get_xticklabels() + ax.get_yticklabels()]
        if ax.get_legend() is not None:
            out += [t.get_text() for t in ax.get_legend().get_texts()]
    return [t for t in out if t]


# --- study plots ------------------------------------------------------------------------------


@pytest.mark.parametrize("cf, text", [("m s-1", "m/s"), ("rad s-1", "rad/s"), ("1", ""),
                                      ("m s-2", "m/s²"), ("kg m2", "kg m²"), ("J", "J"),
                                      ("W m-2 K-1", "W/(m² K)"), ("kg m-3", "kg/m³")])
def test_cf_units_in_the_conventional_form(cf, text):
    assert cf_units(cf) == text


def test_setting_units_come_from_the_scenario_documentation():
    assert setting_unit("projectile.mass") == "kg"
    assert setting_unit("field.B") == "T"
    assert setting_unit("solver.phi") == ""
    assert setting_unit("field.sources.0.current") == "A"
    assert setting_unit("no.such.key") is None


@pytest.mark.parametrize("name", ["residual_speed", "max_tilt", "max_yaw",
                                  "final_angular_velocity", "energy_absorbed", "broken_yarns",
                                  "max_deflection", "perforated", "wall_time"])
def test_study_figures_speak_words_and_conventional_units(name):
    """No variable name and no CF unit string anywhere on a study figure; a title in words
    against the axis in words."""
    fig = metric_figure(results(), name)
    shown = " | ".join(texts(fig))
    assert "_" not in name or name not in shown  # "perforated" is also a word
    assert "s-1" not in shown and "rad s" not in shown
    assert " against magnetic field" in fig.get_suptitle()
    assert "(study of demo-small)" in fig.get_suptitle()


def test_study_labels_with_units():
    ds = results()
    fig = metric_figure(ds, "residual_speed")
    assert fig.axes[0].get_ylabel() == "residual speed v_r [m/s]"
    assert fig.get_suptitle().startswith("Residual speed v_r against magnetic field")
    assert metric_figure(ds, "energy_absorbed").axes[0].get_ylabel().endswith("[J]")
    assert metric_figure(ds, "wall_time").axes[0].get_ylabel() == "wall time per case [s]"
    deflection = metric_figure(ds, "max_deflection").axes[0]
    assert deflection.get_ylabel() == "largest deflection [mm]"
    np.testing.assert_allclose(deflection.lines[0].get_ydata(),
                               ds["max_deflection"].values[:, 0] * 1e3)


@pytest.mark.parametrize("name, symbol", [("max_tilt", "Θ"), ("max_yaw", "ψ")])
def test_angles_are_drawn_in_degrees(name, symbol):
    ds = results()
    ax = metric_figure(ds, name).axes[0]
    assert ax.get_ylabel().endswith(f"{symbol} [deg]")
    assert len(ax.lines) == len(MASSES)  # a line per mass
    for k, line in enumerate(ax.lines):
        np.testing.assert_allclose(line.get_ydata(), ds[name].values[:, k] * 180.0 / math.pi)
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["$m$ = 0.005 kg", "$m$ = 0.01 kg"]


def test_every_component_of_the_angular_velocity():
    """ω_x, ω_y and ω_z each get a panel, with the values of that component."""
    ds = results()
    fig = metric_figure(ds, "final_angular_velocity")
    assert len(fig.axes) == 3
    for c, ax in enumerate(fig.axes):
        assert ax.get_ylabel() == f"$\\omega_{'xyz'[c]}$ [rad/s]"
        for k, line in enumerate(ax.lines):
            np.testing.assert_allclose(line.get_ydata(),
                                       ds["final_angular_velocity"].values[:, k, c])
    assert fig.get_suptitle().startswith("Final angular velocity ω against")


def test_perforation_is_a_probability_and_failed_cases_are_counted():
    """perforated (1, 0, −1 undecided) is the fraction perforated of the decided cases at
    each value of each axis; the −1 cases are left out and counted in the title."""
    ds = results(perforated=[[1, 0], [1, 1], [-1, 0]])
    fig = metric_figure(ds, "perforated")
    by_b, by_mass = fig.axes
    np.testing.assert_allclose(by_b.lines[0].get_ydata(), [0.5, 1.0, 0.0])
    np.testing.assert_allclose(by_b.lines[0].get_xdata(), [0.05, 0.1, 0.2])
    np.testing.assert_allclose(by_mass.lines[0].get_ydata(), [1.0, 1 / 3])
    np.testing.assert_allclose(by_mass.lines[0].get_xdata(), MASSES)
    assert "probability" in by_b.get_ylabel()
    assert "1 of 6 cases undecided or failed (perforated = −1): left out" in fig.get_suptitle()
    assert all(np.all(np.asarray(line.get_ydata()) >= 0) for ax in fig.axes
               for line in ax.lines)
    assert "n = 1" in [t.get_text() for t in by_b.texts]  # decided cases at B_x = 0.2


def test_failed_cases_of_other_metrics_are_gaps_and_counted():
    fig = metric_figure(results(), "broken_yarns")
    assert np.isnan(fig.axes[0].lines[1].get_ydata()[1])  # -1: no value, not a point at -1
    assert "1 of 6 cases without a value" in fig.get_suptitle()


def test_diverged_cases_are_gaps_in_every_metric_but_their_wall_time():
    """A case that diverged keeps in results.nc the state it stopped in (a residual speed of
    250 m/s, a deflection of 6e5 m: no result), so its metrics are gaps, counted in the title,
    not points joined to the others (an audit found them drawn at 6.5e8 mm); its wall time is
    its own and is drawn."""
    ds = results()
    status = np.full((3, 2), "complete", dtype=object)
    status[2, 1] = "diverged"
    ds["status"] = (("field.B", "projectile.mass"), status)
    ds["max_deflection"][2, 1] = 6.5e5
    fig = metric_figure(ds, "max_deflection")
    drawn = np.concatenate([line.get_ydata() for line in fig.axes[0].lines])
    assert np.isnan(fig.axes[0].lines[1].get_ydata()[2]) and np.nanmax(drawn) < 1e4
    assert "1 of 6 cases without a value (diverged, failed or not run)" in fig.get_suptitle()
    for name in ("final_angular_velocity", "residual_speed"):
        assert "1 of 6 cases without a value" in metric_figure(ds, name).get_suptitle()
    wall = metric_figure(ds, "wall_time")
    assert np.isfinite(wall.axes[0].lines[1].get_ydata()[2])
    assert "without a value" not in wall.get_suptitle()


def test_a_vector_axis_is_numeric_on_the_component_that_varies():
    """field.B = [[0.05,0,0],[0.1,0,0],[0.2,0,0]]: x is B_x in T, numeric, not labels."""
    ax = metric_figure(results(), "residual_speed").axes[0]
    np.testing.assert_allclose(ax.lines[0].get_xdata(), [0.05, 0.1, 0.2])
    assert ax.get_xlabel() == "magnetic field $B_x$ [T]"
    assert not any("[" in t.get_text() for t in ax.get_xticklabels())


def test_a_vector_axis_along_one_direction_is_drawn_against_the_magnitude():
    vectors = [[0.03, 0.04, 0.0], [0.06, 0.08, 0.0], [0.0, 0.0, 0.0]]
    axis = vector_axis("field.B", np.array(vectors))
    np.testing.assert_allclose(axis.x, [0.05, 0.1, 0.0])
    assert axis.ticks is None and axis.label.startswith("magnetic field $|B|$ [T] along (0.6")
    fixed = vector_axis("field.B", np.array([[0.01, 0.0, 0.1], [0.02, 0.0, 0.1]]))
    assert fixed.label == "magnetic field $B_x$ [T]  ($B_z$ = 0.1)"
    # directions that differ: the vectors as tick labels (no number can stand for them)
    other = vector_axis("field.B", np.array([[0.1, 0.0, 0.0], [0.0, 0.1, 0.0]]))
    assert other.ticks == ["[0.1, 0, 0]", "[0, 0.1, 0]"]


def test_heat_map_over_two_numeric_axes():
    b = [[v, 0.0, 0.0] for v in (0.0, 0.05, 0.1, 0.15)]
    ds = results(b_axis=b, perforated=np.ones((4, 4)), masses=[0.001, 0.002, 0.003, 0.004])
    fig = metric_figure(ds, "max_tilt")
    ax = fig.axes[0]
    assert ax.get_xlabel() == "magnetic field $B_x$ [T]"
    assert ax.get_ylabel() == "projectile mass $m$ [kg]"
    assert fig.axes[1].get_ylabel() == "largest tilt Θ [deg]"  # the colour bar
    np.testing.assert_allclose(np.asarray(ax.collections[0].get_array()).reshape(4, 4),
                               np.degrees(ds["max_tilt"].transpose("projectile.mass",
                                                                   "field.B").values))


def test_three_axes_with_a_text_axis():
    """A text axis keeps its values as tick labels; a third axis is held at its first value,
    said in the title; perforation gets a panel per axis."""
    dims = ("projectile.shape", "solver.phi", "fabric.material.seed")
    rng = np.random.default_rng(2)
    tilt = rng.uniform(0.0, 0.3, (2, 3, 2))
    ds = xr.Dataset({
        "max_tilt": (dims, tilt, {"units": "rad"}),
        "perforated": (dims, np.ones((2, 3, 2), dtype=np.int8), {"units": "1"}),
    }, coords={"projectile.shape": ["sphere", "ogive"], "solver.phi": [0.3, 0.5, 0.7],
               "fabric.material.seed": [1, 2]})
    fig = metric_figure(ds, "max_tilt")
    ax = fig.axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["sphere", "ogive"]
    assert fig.get_suptitle() == ("Largest tilt Θ against projectile shape\n"
                                  "at modulus seed = 1")
    np.testing.assert_allclose(ax.lines[2].get_ydata(), np.degrees(tilt[:, 2, 0]))
    perf = metric_figure(ds, "perforated")
    assert [a.get_xlabel() for a in perf.axes] == ["projectile shape",
                                                   "φ-scheme parameter $\\phi$",
                                                   "modulus seed"]


def test_latin_hypercube_against_each_sampled_setting():
    n = 6
    rng = np.random.default_rng(1)
    mass = rng.uniform(0.004, 0.01, n)
    radius = rng.uniform(0.002, 0.005, n)
    ds = xr.Dataset({
        "residual_speed": (("case",), rng.uniform(10, 50, n), {"units": "m s-1"}),
        "projectile.mass": (("case",), mass, {"long_name": "sampled value of projectile.mass"}),
        "projectile.radius": (("case",), radius,
                              {"long_name": "sampled value of projectile.radius"}),
    }, coords={"case": np.arange(n)})
    fig = metric_figure(ds, "residual_speed")
    assert [ax.get_xlabel() for ax in fig.axes] == ["projectile mass $m$ [kg]",
                                                    "projectile radius $R$ [m]"]
    np.testing.assert_allclose(fig.axes[0].lines[0].get_xdata(), mass)
    np.testing.assert_allclose(fig.axes[1].lines[0].get_xdata(), radius)


def test_study_figures_from_a_results_file(tmp_path):
    results().to_netcdf(tmp_path / "results.nc")
    files = study_figures(tmp_path)
    names = {f.name for f in files}
    assert "study_final_angular_velocity.png" in names and "study_perforated.pdf" in names
    assert all(f.stat().st_size > 1000 for f in files)


# --- the field figure -------------------------------------------------------------------------


def _scenario(waveform="ramp"):
    from emfabric.config.scenario import Scenario

    extra = {"rise_time": 1e-4} if waveform == "ramp" else {}
    return Scenario().replace(**{"field.sources": [
        {"kind": "loop", "centre": [0.0, 0.0, -0.05], "normal": [0.0, 0.0, 1.0],
         "radius": 0.05, "current": 1.6e4, "waveform": waveform, **extra},
        {"kind": "solenoid", "centre": [0.06, 0.0, 0.03], "axis": [1.0, 0.0, 0.0],
         "radius": 0.02, "length": 0.04, "current": 1e3, "turns": 10}]})


def picture(waveform="ramp", e_value=1.0):
    """A FieldPicture with made-up fields: B along x (B_x = |B|: the case B_x was hidden in)
    and E where `e_value` is not 0; the outlines of the scenario's loop and solenoid."""
    from emfabric.sources.picture import FieldPicture, source_outlines

    sc = _scenario(waveform)
    xs = np.linspace(-0.2, 0.2, 21)
    ys = np.linspace(-0.2, 0.2, 17)
    s = np.linspace(0.0, 0.1, 50)
    b_plane = np.zeros((17, 21, 3))
    b_plane[..., 0] = 0.05
    b_axis = np.zeros((50, 3))
    b_axis[:, 0] = np.linspace(0.06, 0.05, 50)
    e_plane = np.zeros((17, 21, 3))
    e_plane[..., 1] = e_value
    e_axis = np.zeros((50, 3))
    return FieldPicture(xs, ys, b_plane, (-0.15, 0.15, -0.15, 0.15),
                        np.array([0.0, 0.0, 0.03]), s, b_axis, 0.03, 0.0, sc.name, e_plane,
                        e_axis, source_outlines(sc), np.array([0.0, 0.0, -1.0]))


def test_field_figure_draws_the_coils_projected_onto_the_plane():
    from emfabric.viz.field_plot import field_figure

    fig = field_figure(picture())
    plane = fig.axes[0]
    loop = [ln for ln in plane.lines if ln.get_gid() == "source:loop 1 (ramp)"]
    assert len(loop) == 1  # the loop's circle (normal z: a circle of its radius about (0, 0))
    r = np.hypot(loop[0].get_xdata(), loop[0].get_ydata())
    np.testing.assert_allclose(r, 0.05, rtol=1e-12)
    solenoid = [ln for ln in plane.lines if ln.get_gid() == "source:solenoid 2"]
    assert len(solenoid) == 6  # two end circles and four sides
    legend = [t.get_text() for t in plane.get_legend().get_texts()]
    assert "loop 1 (ramp)" in legend and "solenoid 2" in legend
    # the loop (centre on the flight axis, 8 cm below the start) marked where the axis meets it
    axis_panel = fig.axes[1]
    marks = [ln for ln in axis_panel.lines if ln.get_label() == "loop 1 (ramp) plane"]
    assert len(marks) == 1 and marks[0].get_xdata()[0] == pytest.approx(0.08)


def test_field_figure_shows_b_x_over_the_magnitude():
    from emfabric.viz.field_plot import field_figure

    pic = picture()
    fig = field_figure(pic)
    along = fig.axes[1]
    assert along.get_ylabel() == "B [T]"
    lines = {ln.get_label(): ln for ln in along.lines}
    assert {"$B_x$", "$B_y$", "$B_z$", "|B|"} <= set(lines)
    bx, mag = lines["$B_x$"], lines["|B|"]
    np.testing.assert_allclose(bx.get_ydata(), pic.b_axis[:, 0])
    np.testing.assert_allclose(mag.get_ydata(), pic.b_axis[:, 0])  # the same curve ...
    assert bx.get_zorder() > mag.get_zorder()  # ... with B_x drawn on top, visible
    assert to_rgba(bx.get_color()) != to_rgba(mag.get_color())


def test_field_figure_shows_the_induced_e_of_a_time_varying_source():
    from emfabric.viz.field_plot import field_figure

    fig = field_figure(picture("ramp"))
    titles = [ax.get_title() for ax in fig.axes]
    assert any(t.startswith("induced E of the time-varying currents") for t in titles)
    assert any(ax.get_ylabel() == "E [V/m]" for ax in fig.axes)
    steady = field_figure(picture("constant", e_value=0.0))
    assert not any("E" in ax.get_ylabel() for ax in steady.axes)
    assert len(steady.axes) == 3  # B in the plane, its colour bar, B along the axis


def test_field_picture_samples_the_induced_e():
    """The picture keeps the E that emfabric.sources.evaluate gives: a ramping loop (normal
    z, centre on the z axis) induces an azimuthal E in the sheet's plane, none on its axis."""
    from emfabric.sim.geometry import initial_pose
    from emfabric.sources.build import build_field
    from emfabric.sources.picture import field_picture

    sc = _scenario("ramp")
    pose = initial_pose(sc.projectile)
    pic = field_picture(sc, build_field(sc), 0.0, pose.position, pose.flight_direction)
    assert pic.time_varying and pic.has_e
    gx, gy = np.meshgrid(pic.xs, pic.ys)
    radial = (pic.e_plane[..., 0] * gx + pic.e_plane[..., 1] * gy)
    mag = np.linalg.norm(pic.e_plane, axis=2)
    assert mag.max() > 0.0
    assert np.max(np.abs(radial)) <= 1e-9 * mag.max() * np.hypot(gx, gy).max()
    np.testing.assert_allclose(pic.e_axis[:, :2], 0.0, atol=1e-9 * mag.max())


# --- run figures ------------------------------------------------------------------------------


def history(n: int = 40) -> xr.Dataset:
    t = np.linspace(0.0, 40e-6, n)
    return xr.Dataset({
        "tilt": ("time", 0.2 * t / t[-1], {"units": "rad"}),
        "yaw": ("time", 0.5 * np.sin(np.linspace(0, 3, n)) ** 2, {"units": "rad"}),
        "angular_velocity": (("time", "xyz"), np.outer(t / t[-1], [900.0, 20.0, -5.0])),
    }, coords={"time": t, "xyz": ["x", "y", "z"]}, attrs={"scenario_name": "shape-ogive"})


def test_spin_figure_draws_yaw_beside_tilt_in_degrees():
    h = history()
    fig = plots.spin_figure([h])
    top = fig.axes[0]
    assert top.get_ylabel() == "tilt Θ, yaw ψ [deg]"
    tilt, yaw = top.lines
    np.testing.assert_allclose(yaw.get_ydata(), h["yaw"].values * 180.0 / math.pi)
    np.testing.assert_allclose(tilt.get_ydata(), h["tilt"].values * 180.0 / math.pi)
    assert [t.get_text() for t in top.get_legend().get_texts()] == ["tilt Θ", "yaw ψ"]
    # an overlay: a tilt and a yaw line per run
    assert len(plots.spin_figure([h, history(30)]).axes[0].lines) == 4


def test_spin_figure_of_a_history_without_yaw_draws_the_tilt():
    fig = plots.spin_figure([history().drop_vars("yaw")])
    assert fig.axes[0].get_ylabel() == "tilt Θ [deg]" and len(fig.axes[0].lines) == 1


# --- ballistic limit --------------------------------------------------------------------------


def shots(rows):
    return [{"speed": v, "seed": None, "perforated": p, "residual_speed": r,
             "status": "complete", "key": f"k{i}"} for i, (v, p, r) in enumerate(rows)]


ROWS = [(30.0, 0, 12.0), (45.0, 0, 8.0), (52.0, 0, 3.0), (54.4, 1, 6.0), (55.3, 0, 4.0),
        (55.6, 1, 9.0), (60.0, 1, 25.0), (70.0, 1, 40.0), (80.0, 1, 52.0), (90.0, -1, math.nan)]
"""Made-up shots: a stopped shot at 55.3 m/s between perforating ones at 54.4 and 55.6 m/s
(the case of issue 25), above V_BL; one undecided shot."""


def ballistic_result():
    sh = shots(ROWS)
    res = {"v_bl": 53.2, "v_bl_bracket": [52.0, 54.4], "tolerance": 2.0,
           "lambert_jonas": {"a": 0.82, "p": 2.3, "v_bl": 53.0, "rms_residual": 1.0},
           "shots": sh, "runs": len(sh), "scenario": "rupture"}
    res["non_monotone"] = non_monotone(sh, res["v_bl"])
    return res


def test_non_monotone_outcomes_are_listed():
    res = ballistic_result()
    assert res["non_monotone"] == [{"stopped": 55.3, "perforated": 54.4}]
    # seeded shots scatter by design: never flagged
    seeded = [{**s, "seed": 1} for s in shots([(50.0, 1, 5.0), (51.0, 0, 0.0)])]
    assert non_monotone(seeded, 50.0) == []
    # a stopped shot above V_BL with no perforating shot below it
    assert non_monotone(shots([(40.0, 0, 1.0), (60.0, 0, 1.0), (61.0, 1, 5.0)]), 50.0) == [
        {"stopped": 60.0, "perforated": None}]


def test_ballistic_figure_title_legend_rebounds_and_flags():
    res = ballistic_result()
    fig = ballistic_plot(res, lambert_jonas)
    ax = fig.axes[0]
    assert fig.get_suptitle().startswith("Ballistic limit: rupture")
    assert "1 non-monotone outcome" in fig.get_suptitle()
    assert "1 shot undecided or failed" in fig.get_suptitle()
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "perforated (residual speed)" in legend
    assert "stopped (rebound): no residual speed" in legend
    assert any(t.startswith("Lambert–Jonas fit a = 0.82, p = 2.3") for t in legend)
    assert any(t.startswith("V_BL = 53.2 m/s") for t in legend)
    assert any(t.startswith("non-monotone") for t in legend)
    lines = {ln.get_label(): ln for ln in ax.lines}
    perforated = lines["perforated (residual speed)"]
    assert list(perforated.get_xdata()) == [54.4, 55.6, 60.0, 70.0, 80.0]  # no stopped shot
    assert list(perforated.get_ydata()) == [6.0, 9.0, 25.0, 40.0, 52.0]
    stopped = lines["stopped (rebound): no residual speed"]
    assert list(stopped.get_xdata()) == [30.0, 45.0, 52.0, 55.3]
    assert np.all(stopped.get_ydata() == 0.0) and stopped.get_marker() != perforated.get_marker()
    notes = [t.get_text() for t in ax.texts]
    assert any("non-monotone: stopped at 55.3 m/s" in t and "54.4 m/s" in t for t in notes)


def test_ballistic_json_carries_the_non_monotone_outcomes(tmp_path):
    res = ballistic_result()
    files = write_outputs(res, tmp_path)
    saved = json.loads((tmp_path / "ballistic.json").read_text())
    assert saved["non_monotone"] == [{"stopped": 55.3, "perforated": 54.4}]
    assert saved["scenario"] == "rupture"
    assert files[-1].name == "ballistic.png" and files[-1].stat().st_size > 1000


def test_ballistic_figure_with_seeds():
    res = ballistic_result()
    rng = np.random.default_rng(0)
    v = np.repeat(np.linspace(45, 60, 9), 2)
    seeded = [{"speed": float(x), "seed": 1 + k % 2, "perforated": int(x + rng.normal(0, 3) > 53),
               "residual_speed": 1.0, "status": "complete", "key": f"s{k}"}
              for k, x in enumerate(v)]
    res["shots"] += seeded
    res["v50"] = {"v50": 53.0, "scale": 1.5, "sigma": 2.7, "ci95": [51.0, 55.0], "shots": 18}
    res["seeds"] = 2
    fig = ballistic_plot(res, lambert_jonas)
    assert len(fig.axes) == 2
    assert fig.axes[1].get_ylabel() == "perforation probability"
    legend = [t.get_text() for t in fig.axes[1].get_legend().get_texts()]
    assert any(t.startswith("logistic fit: V50 = 53 m/s") for t in legend)
    # the seeded shots stay out of the first panel and of the flags
    assert non_monotone(res["shots"], res["v_bl"]) == res["non_monotone"]


def test_ballistic_figure_of_shots_that_separate(recwarn):
    """Seeded shots that separate completely have no logistic fit (fit_v50): the panel draws
    the step at the gap's middle, without an overflow warning."""
    from emfabric.studies.ballistic import fit_v50

    res = ballistic_result()
    v = np.repeat(np.linspace(45, 60, 9), 2)
    seeded = [{"speed": float(x), "seed": 1 + k % 2, "perforated": int(x > 53),
               "residual_speed": 1.0, "status": "complete", "key": f"s{k}"}
              for k, x in enumerate(v)]
    res["shots"] += seeded
    res["v50"] = fit_v50([s["speed"] for s in seeded], [s["perforated"] for s in seeded])
    res["seeds"] = 2
    fig = ballistic_plot(res, lambert_jonas)
    legend = [t.get_text() for t in fig.axes[1].get_legend().get_texts()]
    assert any(t.startswith("shots separate: V50 = 53.44 m/s, between 52.5 and 54.38")
               for t in legend), legend
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]
