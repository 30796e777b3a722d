"""Scenario files: defaults are the paper's, bad input gives errors naming key, value, allowed."""

import pytest

from emfabric import ScenarioError, build_model, builtin_names, load_scenario, scenario_from_dict
from emfabric.config.scenario import Scenario, parse_override


def test_defaults_are_the_papers_section_5():
    """The empty scenario is the paper's model problem (section 5)."""
    s = Scenario()
    assert s.fabric.nodes == (100, 100) and s.fabric.size == (0.254, 0.254)
    assert s.fabric.areal_density == 0.12784 and s.fabric.yarn_radius == 0.000185
    assert s.fabric.material.youngs_modulus == 126e9 and s.fabric.material.modulus_cv == 0.1
    assert s.fabric.damage.critical_stretch == 1.03 and s.fabric.damage.rate == 0.1
    assert s.projectile.radius == 0.02635 and s.projectile.mass == 0.037
    assert s.projectile.velocity == (0.0, 0.0, -250.0)
    assert s.field.B == (0.05, 0.0, 0.0) and s.field.E == (0.0, 0.0, 0.0)
    assert s.contact.static_friction == 1.0 and s.contact.dynamic_friction == 0.95
    assert (s.solver.phi, s.solver.tolerance, s.solver.target_iterations) == (0.5, 1e-6, 6)
    assert s.solver.dt_max == 1e-6 and s.solver.safety == 0.9


def test_builtin_scenarios_load():
    """The three paper scenarios and the demo are shipped and valid."""
    names = builtin_names()
    for name in ("paper-field", "paper-no-field", "paper-spin", "demo-small"):
        assert name in names
        assert load_scenario(name).name == name
    assert load_scenario("paper-spin").projectile.angular_velocity == (0.0, 0.0, 10000.0)
    assert load_scenario("paper-no-field").field.B == (0.0, 0.0, 0.0)


@pytest.mark.parametrize(
    "data,needles",
    [
        ({"fabric": {"nodez": [3, 3]}}, ["fabric.nodez", "unknown key", "nodes"]),
        ({"solver": {"phi": 1.5}}, ["solver.phi = 1.5: must be from 0 to 1"]),
        ({"projectile": {"mass": -0.01}}, ["projectile.mass = -0.01: must be > 0 (kg)"]),
        ({"fabric": {"nodes": [1, 5]}},
         ["fabric.nodes = [1, 5]: needs 2 integers [nx, ny], each ≥ 2"]),
        ({"fabric": {"size": [0.1, 0.1, 0.1]}}, ["fabric.size", "0.1"]),
        ({"fabric": {"areal_density": "heavy"}}, ["fabric.areal_density", "heavy"]),
        ({"fabric": {"edges": "pinned"}}, ["fabric.edges", "pinned", "clamped", "free"]),
        ({"contact": {"static_friction": 0.5, "dynamic_friction": 0.9}},
         ["contact", "dynamic_friction = 0.9", "≤ static_friction"]),
        ({"solver": {"dt_min": 1e-5, "dt_max": 1e-6}}, ["solver", "dt_min"]),
        ({"fabric": {"material": {"model": "fung"}}}, ["fabric.material", "needs c and H"]),
        ({"field": {"B": [0, 0, float("nan")]}},
         ["field.B = [0, 0, nan]: needs 3 finite numbers [Bx, By, Bz] in T"]),
        ({"projectile": {"charges": [{"position": [0, 0, 0.01]}]}},
         ["projectile.charges[0].charge: missing; needs a number (C)"]),
    ],
)
def test_bad_scenarios_name_key_value_and_allowed(data, needles):
    """Every validation error names the dotted key, the value and what is allowed."""
    with pytest.raises(ScenarioError) as info:
        scenario_from_dict(data)
    msg = str(info.value)
    for needle in needles:
        assert needle in msg, msg


def test_modulus_scatter_must_stay_positive():
    """A modulus draw 1 + cv·ξ ≤ 0 is an error, not a silent clip."""
    sc = Scenario().replace(**{"fabric.material.modulus_cv": 0.6, "fabric.nodes": [30, 30]})
    with pytest.raises(ScenarioError, match="modulus_cv = 0.6"):
        build_model(sc)


def test_overrides_by_dotted_key():
    """--set style overrides parse TOML values and are validated like the file."""
    key, value = parse_override("field.B=[0,0,0.1]")
    assert (key, value) == ("field.B", [0, 0, 0.1])
    s = load_scenario("paper-field", {key: value, "solver.phi": 1})
    assert s.field.B == (0.0, 0.0, 0.1) and s.solver.phi == 1.0
    with pytest.raises(ScenarioError, match="solver.bogus"):
        load_scenario("paper-field", {"solver.bogus": 1})
    with pytest.raises(ScenarioError, match="no built-in scenario named 'nope'"):
        load_scenario("nope")


def test_toml_round_trip(tmp_path):
    """A scenario written out as TOML loads back identical."""
    s = load_scenario("paper-spin", {"fabric.nodes": [12, 14]})
    path = tmp_path / "s.toml"
    path.write_text(s.to_toml())
    assert load_scenario(path) == s


def test_bad_toml_file(tmp_path):
    """A file that is not TOML gives an error naming the file."""
    path = tmp_path / "broken.toml"
    path.write_text("[fabric\nnodes = 3")
    with pytest.raises(ScenarioError, match="invalid TOML in .*broken.toml"):
        load_scenario(path)


def test_a_section_that_is_not_a_table_is_refused_with_contact_placement_written():
    """contact.placement written without an integrator chooses the φ-scheme; a `solver` that
    is not a table next to it is still refused (it was replaced by the default section)."""
    with pytest.raises(ScenarioError, match=r"solver = 1: needs a table"):
        load_scenario("paper-field", {"solver": 1})
    with pytest.raises(ScenarioError, match=r"solver = 'fast': needs a table"):
        scenario_from_dict({"contact": {"placement": "phi-update"}, "solver": "fast"})
    assert scenario_from_dict({"contact": {"placement": "phi-update"}}).solver.integrator == "phi"
