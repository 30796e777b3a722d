"""Plausibility before the run (issue 25 item 2): warnings for what is probably a typing
mistake, a refusal for an output volume nobody wants."""

import logging
import math
import tomllib

import pytest

from emfabric.config.scenario import (
    ScenarioError,
    builtin_names,
    load_scenario,
    scenario_from_dict,
)
from emfabric.sim.builder import build_model
from emfabric.sim.sanity import output_volume, pre_run_warnings

from conftest import make


@pytest.mark.parametrize("overrides, expected", [
    ({"projectile.radius": 26.35}, "did you type mm as m? (26.35 mm = 0.02635 m)"),
    ({"projectile.radius": 26.35}, "larger than the sheet"),
    ({"projectile.mass": 37.0}, "did you type g as kg? (37 g = 0.037 kg)"),
    # the .22 FSP's 1.1 g typed as kg: within the masses of projectiles, not of its volume
    ({"projectile.shape": "fsp", "projectile.radius": 0.00278, "projectile.mass": 1.1},
     "is a mean density of 8.49e+06 kg/m³, outside any solid's (10–23000 kg/m³); did you "
     "type g as kg? (1.1 g = 0.0011 kg)"),
    ({"fabric.size": [254.0, 254.0]}, "did you type mm as m? (254 mm = 0.254 m)"),
    ({"fabric.size": [254.0, 254.0]}, "can fall between the nodes"),
    ({"projectile.position": [0.5, 0.0, 0.05]}, "it will miss the fabric"),
    # aimed at the clamped edge of the 0.254 m sheet: the frame does not stop it
    ({"projectile.position": [0.127, 0.0, 0.05]}, "reaches the clamped edge x = 0.127 m"),
    ({"projectile.position": [0.0, -0.11, 0.05], "projectile.velocity": [0.0, -50.0, -250.0]},
     "reaches the clamped edge y = -0.127 m"),
    ({"projectile.velocity": [0.0, 0.0, 250.0]}, "leads away from the sheet"),
    ({"projectile.velocity": [0.0, 0.0, -2e4]}, "far outside ballistic impacts"),
    # 1000 times the paper's 0.128 kg/m²: the wave speed falls by √1000 to 242 m/s, in range
    ({"fabric.areal_density": 128.0}, "the fabric's areal density is 128 kg/m²"),
    ({"fabric.areal_density": 1e-300}, "areal density is 1e-300 kg/m²"),
    # one mistyped ply of four (kg/m² × 1000) is not averaged away with the other three
    ({"fabric.plies": 4, "fabric.ply": [{}, {"areal_density": 128.0}, {}, {}]},
     "ply 2's areal density is 128 kg/m²"),
    # the speed scales as 1/√(areal density): 7714 m/s × √(0.12784/1e-300) on this sheet
    ({"fabric.areal_density": 1e-300}, "wave speed is 2.758e+153 m/s"),
    # denier typed as tex: KM2's 600 denier is 66.7 tex; 600 tex × 2 × 13.39 per cm = 1.607
    # kg/m² of straight yarns against the style's 0.18
    ({"fabric.style": "km2-600d-plain", "fabric.yarn_linear_density": 600.0},
     "is 0.112 × the mass of its straight yarns"),
    ({"fabric.material.name": "kevlar-km2", "fabric.damage.failure_strain": 3.5},
     "failure strain is 3.5 (350 %)"),
    ({"fabric.material.name": "kevlar-km2", "fabric.material.tensile_strength": 3.88},
     "did you type GPa as Pa?"),
    # a charge the sphere (radius 0.02635 m) carries, half a metre from its centre
    ({"projectile.charges": [{"position": [0.5, 0.0, 0.0], "charge": 1e-6}]},
     "lies 0.5 m from the centre of mass, outside the projectile (it reaches 0.02635 m)"),
    # a solver key the chosen integrator does not read (it ran without it, silently)
    ({"projectile.position": [0.0, 0.0, 0.05], "projectile.gap": 0.01},
     "projectile.gap = 0.01 m is not used"),
    ({"solver.integrator": "central-difference", "solver.safety": 0.5},
     "solver.safety = 0.5: read only by the φ-scheme"),
    ({"solver.integrator": "phi", "solver.courant": 0.5},
     "solver.courant = 0.5: read only by central differences"),
    ({"solver.integrator": "central-difference", "solver.phi": 1.0, "solver.tolerance": 1e-4},
     "solver.phi = 1.0, solver.tolerance = 0.0001: read only by the φ-scheme"),
])
def test_typing_mistakes_are_warned_with_the_fix(overrides, expected, caplog):
    """Each mistake of the issue's new user runs (a warning, not an error) and says why and
    what was probably meant; the warning is logged when the model is built (validate, run)."""
    sc = make(**{"fabric.nodes": [21, 21], **overrides})
    with caplog.at_level(logging.WARNING, logger="emfabric"):
        model = build_model(sc)
    assert any(expected in w for w in pre_run_warnings(model)), pre_run_warnings(model)
    assert any(expected in r.getMessage() for r in caplog.records)


def test_a_heavy_driver_is_legitimate():
    """A 1000 kg body (a constant-speed driver) is warned about, not refused."""
    model = build_model(make(**{"fabric.nodes": [21, 21], "projectile.mass": 1000.0}))
    (warning,) = pre_run_warnings(model)
    assert "constant speed" in warning or "g as kg" in warning


def test_a_charge_on_the_surface_is_no_mistake():
    """The paper's charges sit on the projectile's surface (section 6): no warning there."""
    r = 0.02635
    model = build_model(make(**{"fabric.nodes": [21, 21], "projectile.charges": [
        {"position": [r, 0.0, 0.0], "charge": 1e-6},
        {"position": [0.0, r / 2 ** 0.5, -r / 2 ** 0.5], "charge": -1e-6}]}))
    assert pre_run_warnings(model) == []


def test_the_builtin_scenarios_raise_no_warning():
    for name in builtin_names():
        assert pre_run_warnings(build_model(load_scenario(name))) == [], name


def test_a_full_scenario_written_back_raises_no_solver_warning():
    """A run's own scenario (a checkpoint's, a study case's) writes every key, the φ-scheme's
    included: read back, its default values are no mistake."""
    for over in ({}, {"solver.integrator": "phi"},
                 {"solver.integrator": "phi", "solver.bulk_viscosity": 0.0}):
        sc = make(**{"fabric.nodes": [21, 21], **over})
        again = scenario_from_dict(tomllib.loads(sc.to_toml()), "<written back>")
        assert pre_run_warnings(build_model(again)) == []


def test_output_volume_is_refused_above_the_limit_unless_asked_for():
    """output.snapshot_interval = 1e-9 on the paper's sheet: 1.5 million snapshots, refused
    naming the key and the interval that fits; a larger size_limit or fewer snapshots run.
    The default run's estimate: 151 snapshots (t = 0 … 1.5 ms every 10 µs)."""
    sc = load_scenario("paper-field")
    # snapshots.nc: 6 doubles a node and one a segment, .vtu 112 B a node (measured)
    per = 48 * 10_000 + 8 * 19_800 + 112 * 10_000
    assert output_volume(build_model(sc)) == 151 * per
    with pytest.raises(ScenarioError, match=r"output.snapshot_interval = 1e-09 s: .* GB, "
                                            r"above output.size_limit = 20 GB"):
        build_model(sc.replace(**{"output.snapshot_interval": 1e-9}))
    build_model(sc.replace(**{"output.snapshot_interval": 1e-7, "output.size_limit": 1e13}))
    off = sc.replace(**{"output.paraview": False})
    assert output_volume(build_model(off)) == 151 * (per - 112 * 10_000)


def test_output_volume_limit_applies_only_to_runs_that_write(tmp_path):
    """A run kept in memory writes nothing: the scenario whose files would pass
    output.size_limit runs there (and in a study case that keeps no files); written to a
    folder it is refused before anything is written."""
    from emfabric.runner.loop import run

    sc = load_scenario("paper-field").replace(**{"output.snapshot_interval": 1e-9})
    result = run(sc, None, end_time=2e-8)
    assert result.status == "complete" and result.state.t == pytest.approx(2e-8)
    with pytest.raises(ScenarioError, match="above output.size_limit"):
        run(sc, tmp_path / "out", end_time=2e-8)
    assert not (tmp_path / "out" / "history.nc").exists()


@pytest.mark.parametrize("command", [["validate"], ["run", "-q", "--set",
                                                   "solver.end_time=1e-7"]])
def test_cli_prints_a_typing_mistake_as_a_warning(tmp_path, command):
    """`validate` and `run` print the model's warnings as every other warning reads:
    "warning: …" on stderr (validate printed them bare, through Python's last-resort handler)."""
    import os
    import subprocess
    import sys

    args = [sys.executable, "-m", "emfabric", command[0], "demo-small", "--set",
            "projectile.mass=37", "--set", "fabric.nodes=[11,11]", *command[1:]]
    if command[0] == "run":
        args += ["--out", str(tmp_path / "out")]
    r = subprocess.run(args, capture_output=True, text=True,
                       env={**os.environ, "COLUMNS": "300"})
    assert r.returncode == 0, r.stderr
    assert "warning: projectile.mass = 37 kg is far outside ballistic projectiles" in r.stderr


@pytest.mark.parametrize("overrides, expected", [
    ({"solver.end_time": 1e300}, r"output.snapshot_interval = 1e-05 s: 1e\+305 snapshots .* "
                                 r"write about more than 1e300 GB, .* allowed: a longer "
                                 r"snapshot_interval \(≥ \d\.\d+e\+29\d s\)"),
    ({"output.snapshot_interval": 5e-324}, r"output.snapshot_interval = 4.94066e-324 s: inf "
                                           r"snapshots"),
    ({"fabric.plies": 2, "fabric.ply": [{"thread_count": [1e300, 1e300]}, {}]},
     r"fabric.nodes = \[.*\]: a run needs about more than 1e290 GiB"),
    ({"field.sources": [{"kind": "loop", "centre": [0, 0, 1e300], "normal": [0, 0, 1],
                         "radius": 0.2, "current": 1000.0}]},
     r"centre = \[0.0, 0.0, 1e\+300\]: allowed: at most 10000 m"),
    ({"field.sources": [{"kind": "solenoid", "centre": [0, 0, 0.05], "axis": [0, 0, 1],
                         "radius": 0.2, "length": 1e300, "current": 10.0, "turns": 50}]},
     r"length = \[1e\+300\]: allowed: at most 10000 m"),
    ({"field.sources": [{"kind": "magnet", "shape": "cuboid", "polarization": [0, 0, 1.3],
                         "dimension": [0.02, 0.02, 0.01], "position": [0, 0, 0.05],
                         "orientation": [0, 0, 1e300]}]},
     r"orientation = \[0.0, 0.0, 1e\+300\]: allowed: a rotation vector of at most 3600"),
    ({"field.sources": [{"kind": "magnet", "shape": "cylinder", "polarization": [0, 0, 1.3],
                         "dimension": [0.02, 0.01], "position": [1e300, 0, 0.05]}]},
     r"position = \[1e\+300, 0.0, 0.05\]: allowed: at most 10000 m"),
    ({"field.sources": [{"kind": "loop", "centre": [0, 0, 0.05], "normal": [0, 0, 1],
                         "radius": 5e-324, "current": 1000.0}]},
     r"radius = 4.94066e-324 m: allowed: at least 1e-06 m"),
    ({"field.sources": [{"kind": "solenoid", "centre": [0, 0, 0.05], "axis": [0, 0, 1],
                         "radius": 0.05, "length": 0.1, "current": 10.0, "turns": 100,
                         "wire_radius": 1e-300}]},
     r"wire_radius = 1e-300 m: allowed: at least 1e-08 m"),
    ({"field.sources": [{"kind": "magnet", "shape": "cylinder", "polarization": [0, 0, 1.3],
                         "dimension": [1e-160, 1e-160], "position": [0, 0, 0.05]}]},
     r"dimension = \[1e-160, 1e-160\]: allowed: lengths of at least 1e-06 m"),
    # Newtonian mechanics: an initial speed at or above c is refused (|v| without overflow)
    ({"projectile.velocity": [0, 0, -1e300]},
     r"projectile.velocity = \[0, 0, -1e\+300\]: a speed of 1e\+300 m/s; allowed: below the "
     r"speed of light, 299792458 m/s"),
    ({"fabric.velocity": [3e8, 0, 0]}, r"fabric.velocity = .*: a speed of 3e\+08 m/s"),
    ({"fabric.velocity": [2.2e8, 2.2e8, 0]}, r"a speed of 3.111e\+08 m/s"),
    # the sphere (radius 0.02635 m) spun so that its surface would outrun light
    ({"projectile.angular_velocity": [0, 0, 1e12]},
     r"projectile.angular_velocity = .*: its surface would start at up to 2.635e\+10 m/s"),
    # principal moments no rigid body has (3 > 1 + 1)
    ({"projectile.principal_inertia": [1.0, 1.0, 3.0]}, r"no rigid body has these moments"),
])
def test_extreme_numbers_are_refused_in_words(overrides, expected):
    """Numbers far outside any physical run (found by fuzzing the scenario keys) are refused
    with the key, the value and what is allowed, not an OverflowError or a division by zero
    inside a kernel."""
    with pytest.raises(ScenarioError, match=expected):
        build_model(load_scenario("paper-field", {"fabric.nodes": [10, 10], **overrides}))


def test_a_non_finite_model_of_plain_values_is_not_blamed_on_one():
    """A model that comes out non-finite from values of physical size is the builder's fault,
    not the scenario's most extreme value (a rotated brittle ply once blamed the untouched
    solver.dt_min = 1e-13): the error says so and names no key as the cause."""
    from emfabric.sim.builder import extreme_value_error

    err = extreme_value_error(load_scenario("demo-small"), "a non-finite yarns.area")
    assert "no value of the scenario is extreme" in str(err) and "emfabric bug" in str(err)
    err = extreme_value_error(load_scenario("demo-small", {"projectile.radius": 1e200}),
                              "a non-finite body.inertia")
    assert str(err).startswith("projectile.radius = 1e+200: building the model gives")


def test_an_axis_is_a_direction_whatever_its_length():
    """projectile.axis = [0, 0, −1e200] is the nose pointing down, as [0, 0, −1] is (its
    length squared overflowed to a zero direction and a division by zero inside the step
    kernel); 5e-324 along x is x."""
    base = {"fabric.nodes": [10, 10], "projectile.shape": "fsp", "projectile.radius": 0.00278,
            "projectile.mass": 0.0011}
    ref = build_model(load_scenario("demo-small", {**base, "projectile.axis": [0, 0, -1]}))
    for axis in ([0, 0, -1e200], [0, 0, -1e-300]):
        m = build_model(load_scenario("demo-small", {**base, "projectile.axis": axis}))
        assert (m.body.nose == ref.body.nose).all()
    tiny = build_model(load_scenario("demo-small", {**base, "projectile.axis": [5e-324, 0, 0]}))
    assert tiny.body.nose[0] > 0 and tiny.body.nose[1] == tiny.body.nose[2] == 0.0


def test_an_arithmetic_error_in_the_step_ends_the_run_as_diverged(tmp_path):
    """projectile.mass = 5e-324 passes the scenario's rules (a positive number) but its inertia
    underflows to 0 and the step kernel divides by it: the run ends "diverged" with the time,
    Δt and the error, its files readable, not with a bare "division by zero"."""
    import logging

    import xarray as xr

    from emfabric.integrators import DivergenceError
    from emfabric.runner.loop import run

    sc = load_scenario("demo-small", {"fabric.nodes": [8, 8], "solver.end_time": 2e-6,
                                      "projectile.mass": 5e-324, "output.paraview": False})
    log = logging.getLogger("emfabric")
    level = log.level
    try:
        with pytest.raises(DivergenceError) as err:
            run(sc, tmp_path / "r")
    finally:
        log.setLevel(level)
    out = err.value.result
    assert out.status == "diverged"
    assert "diverged at t = 0 s" in out.end_reason and "ZeroDivisionError" in out.end_reason
    with xr.open_dataset(tmp_path / "r" / "history.nc") as h:
        assert h.attrs["status"] == "diverged" and h.sizes["time"] >= 1


def test_a_nil_stable_step_says_which_limit(tmp_path):
    """fabric.areal_density = 1e-300 makes the nodes so light that 2/ω_max underflows: the run
    ends diverged at t = 0 naming the stability limit and the keys that set it (it said only
    "courant × the stability limit, or the no-tunnelling limit")."""
    import logging

    from emfabric.integrators import DivergenceError
    from emfabric.runner.loop import run

    sc = load_scenario("demo-small", {"fabric.nodes": [8, 8], "solver.end_time": 2e-6,
                                      "fabric.areal_density": 1e-300, "output.paraview": False})
    log = logging.getLogger("emfabric")
    level = log.level
    try:
        with pytest.raises(DivergenceError, match=r"the stability limit 2/ω_max = .* check the "
                                                  r"material's modulus and the fabric's areal "
                                                  r"density"):
            run(sc, tmp_path / "r")
    finally:
        log.setLevel(level)


def test_a_step_below_dt_min_in_a_strong_field_names_the_gyration():
    """In 1e6 T a charged node of demo-small turns about B so fast that courant × 0.1/ω_c is
    below dt_min: the run ends diverged at t = 0 naming the gyration limit and what sets it, not
    the yarns' stability limit."""
    from emfabric.integrators import DivergenceError
    from emfabric.runner.loop import run

    sc = load_scenario("demo-small", {"fabric.nodes": [8, 8], "solver.end_time": 2e-6,
                                      "field.B": [1e6, 0.0, 0.0], "solver.dt_min": 1e-12})
    with pytest.raises(DivergenceError, match=r"the gyration limit .* a charged node may turn "
                                              r"about B .* check the field and the nodes' "
                                              r"charge and mass"):
        run(sc)


@pytest.mark.parametrize("name, overrides, between", [
    # the .22 FSP (5.56 mm across) aimed at the middle of a 30 × 30 sheet (8.76 mm cells, no
    # yarn through the middle) and of a 31 × 31 one (a node there)
    ("fsp", {"fabric.nodes": [30, 30]}, True),
    ("fsp", {"fabric.nodes": [31, 31]}, False),
    # a 6 mm cylinder nose first through a 13.4 mm cell, and the same lying across the yarns
    ("demo-small", {"fabric.nodes": [20, 20], "projectile.shape": "cylinder",
                    "projectile.radius": 0.003, "projectile.length": 0.02}, True),
    ("demo-small", {"fabric.nodes": [20, 20], "projectile.shape": "cylinder",
                    "projectile.radius": 0.003, "projectile.length": 0.02,
                    "projectile.axis": [1.0, 0.0, 0.0]}, False),
])
def test_a_projectile_that_fits_between_the_yarns_is_warned_and_does_pass(name, overrides,
                                                                          between):
    """A body whose silhouette along its flight fits inside one cell of the lumped network,
    between its yarn lines, passes through the sheet without a contact, reported "never
    touched" (a new user's coarse what-if: the grid's parity decided whether the projectile
    struck at all). It is warned about before the run with the grid that would catch it; a
    body that meets a yarn line is not, and does touch."""
    sc = load_scenario(name, {**overrides, "solver.end_time": 3e-5, "output.paraview": False})
    model = build_model(sc)
    warned = [w for w in pre_run_warnings(model) if "fits between the yarns" in w]
    assert bool(warned) == between, pre_run_warnings(model)
    from emfabric import run

    h = run(sc).history
    assert (int(h.contact_nodes.max()) + int(h.contact_segments.max()) > 0) != between
    if between:
        # the grid it names would catch it: a yarn line inside its silhouette
        need = [int(n) for n in warned[0].split("fabric.nodes ≥ [")[1].split("]")[0].split(",")]
        finer = build_model(load_scenario(name, {**overrides, "fabric.nodes": need}))
        assert not any("fits between the yarns" in w for w in pre_run_warnings(finer))


def test_a_limit_passed_by_a_little_is_shown_apart():
    """A diverged run's message shows the value and the limit it passed with the digits that
    tell them apart ("fabric deflection 180 m beyond the plausible 180 m" said nothing)."""
    from emfabric.sim.diagnostics import _apart

    assert _apart(180.02, 180.0) == ("180.02", "180")
    assert _apart(2.5e3, 180.0) == ("2.5e+03", "180")
    assert _apart(math.nextafter(180.0, 1e3), 180.0)[0] != "180"
