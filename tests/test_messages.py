"""Messages in the user's words (issue 25, item 5): a scenario's typical mistakes are told in
the key's own terms (what it takes, its unit from the key's docstring, the value as written),
never in pydantic's vocabulary; a scenario that is a folder, a missing file or an unknown name
says what is allowed; an empty scenario file runs the defaults with a warning."""

import logging

import pytest

from emfabric.config.scenario import ScenarioError, load_scenario, parse_override

PYDANTIC_WORDS = ("Input should be", "Field required", "Value error", "Tuple should have",
                  "Input tag", "Assertion failed", "after validation", "literal[",
                  "function-after", "constrained-")

FABRIC_KEYS = ("areal_density, charge_per_node, damage, edges, material, nodes, plies, ply, "
               "ply_angles, ply_spacing, reference_nodes, rescale, size, style, thread_count, "
               "velocity, yarn_denier, yarn_linear_density, yarn_radius")

# (a mistake as the scenario file writes it, the message's line for it)
MISTAKES = [
    # a vector of the wrong length, and a scalar for a vector (--set field.B=0.1)
    ("[field]\nB = [0.05, 0]", "field.B = [0.05, 0]: needs 3 numbers [Bx, By, Bz] in T"),
    ("[field]\nB = 0.1", "field.B = 0.1: needs 3 numbers [Bx, By, Bz] in T"),
    ("[field]\nB = [0, 0, nan]", "field.B = [0, 0, nan]: needs 3 finite numbers [Bx, By, Bz] in T"),
    ("[field]\nB = [0, 0, 'x']", "field.B = [0, 0, 'x']: needs 3 numbers [Bx, By, Bz] in T; "
                                 "Bz = 'x' is text"),
    ("[fabric]\nsize = [0.1, 0.1, 0.1]",
     "fabric.size = [0.1, 0.1, 0.1]: needs 2 numbers [Lx, Ly] in m, each > 0"),
    ("[fabric]\nnodes = [1, 5]", "fabric.nodes = [1, 5]: needs 2 integers [nx, ny], each ≥ 2"),
    ("[fabric]\nnodes = [10.0, 10]",
     "fabric.nodes = [10.0, 10]: needs 2 integers [nx, ny], each ≥ 2; nx = 10.0 is not an "
     "integer"),
    # the wrong type: text, a boolean or a float for a number, a number for a boolean
    ("[projectile]\nmass = '0.037'",
     "projectile.mass = '0.037': needs a number > 0 (kg), not text (write 0.037 without "
     "quotes)"),
    ('[solver]\ndt_max = "1e-6"',
     "solver.dt_max = '1e-6': needs a number > 0 (s), not text (write 1e-6 without quotes)"),
    ("[projectile]\nmass = true", "projectile.mass = true: needs a number > 0 (kg), not a "
                                  "boolean"),
    ("[fabric]\nrescale = 1", "fabric.rescale = 1: needs true or false, not a number"),
    ("[fabric]\nplies = 2.0", "fabric.plies = 2.0: needs an integer from 1 to 64, not 2.0 "
                              "(write 2)"),
    # text for a choice
    ("[solver]\nintegrator = 'cd'",
     "solver.integrator = 'cd': allowed: 'phi', 'central-difference'"),
    ("[projectile]\nshape = 'ogiv'", "projectile.shape = 'ogiv': allowed: 'sphere', 'ogive', "
                                     "'cylinder', 'fsp', 'none' (did you mean 'ogive'?)"),
    ("[contact]\nsegments = 'sometimes'",
     "contact.segments = 'sometimes': allowed: 'auto', true, false"),
    # out of range, with the unit
    ("[projectile]\nmass = -0.01", "projectile.mass = -0.01: must be > 0 (kg)"),
    ("[fabric]\nplies = 1000", "fabric.plies = 1000: must be from 1 to 64"),
    ("[solver]\nphi = 1.5", "solver.phi = 1.5: must be from 0 to 1"),
    ("[fabric.material]\nyoungs_modulus = inf",
     "fabric.material.youngs_modulus = inf: must be a finite number > 0 (Pa)"),
    # unknown keys: the closest name in the section, or the section that has it
    ("[fabric]\nareal_densit = 0.1", "fabric.areal_densit: unknown key (did you mean "
                                     f"'areal_density'?); allowed keys here: {FABRIC_KEYS}"),
    ("[fabric]\ncourant = 0.5", "fabric.courant: unknown key (did you mean 'solver.courant'?); "
                                f"allowed keys here: {FABRIC_KEYS}"),
    # a key missing from a table, and an array of tables
    ("[[field.sources]]\nkind = 'loop'\nnormal = [0, 0, 1]\nradius = 0.1\ncurrent = 1.0",
     "field.sources[0].centre: missing; needs 3 numbers [x, y, z] in m"),
    ("[[field.sources]]\nradius = 0.1", "field.sources[0].kind: missing; allowed: 'uniform', "
                                        "'loop', 'solenoid', 'map', 'magnet'"),
    ("[[projectile.charges]]\nposition = [0, 0, 'a']\ncharge = 1.0",
     "projectile.charges[0].position = [0, 0, 'a']: needs 3 numbers [x, y, z] in m; z = 'a' "
     "is text"),
]


@pytest.mark.parametrize("text,line", MISTAKES, ids=[m[1].split(":")[0] for m in MISTAKES])
def test_a_mistake_in_a_file_is_told_in_the_keys_terms(tmp_path, text, line):
    path = tmp_path / "s.toml"
    path.write_text(text + "\n", encoding="utf-8")
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert str(info.value) == f"invalid scenario ({path}):\n  {line}"
    assert not any(word in str(info.value) for word in PYDANTIC_WORDS)


@pytest.mark.parametrize("text,line", [
    ("field.B=0.1", "field.B = 0.1: needs 3 numbers [Bx, By, Bz] in T"),
    ("field.B=[0.05, 0]", "field.B = [0.05, 0]: needs 3 numbers [Bx, By, Bz] in T"),
    ("projectile.mass=0.037kg", "projectile.mass = '0.037kg': needs a number > 0 (kg), not "
                                "text"),
    ("fabric.nodes=[1, 5]", "fabric.nodes = [1, 5]: needs 2 integers [nx, ny], each ≥ 2"),
])
def test_a_mistake_in_set_is_told_in_the_keys_terms(text, line):
    """`--set key=value`: the same words, the value as parsed from the command line."""
    key, value = parse_override(text)
    with pytest.raises(ScenarioError) as info:
        load_scenario("demo-small", {key: value})
    assert str(info.value) == f"invalid scenario (overrides {key}):\n  {line}"


def test_a_rule_of_the_whole_scenario_names_its_keys():
    """A rule between sections is its own line, without pydantic's prefix or a `{...}`."""
    with pytest.raises(ScenarioError) as info:
        load_scenario("demo-small", {"contact.placement": "closest-point",
                                     "solver.integrator": "central-difference"})
    line = str(info.value).split("\n")[1]
    assert line.startswith("  contact.placement = 'closest-point' is an option of the φ-scheme")
    assert not any(word in str(info.value) for word in PYDANTIC_WORDS)


def test_a_folder_is_not_a_scenario(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs" / "x").mkdir(parents=True)
    with pytest.raises(ScenarioError) as info:
        load_scenario("runs/x")
    assert str(info.value) == ("scenario 'runs/x' is a folder, not a TOML file; allowed: a "
                               ".toml file or a built-in name (emfabric scenarios)")
    # a folder named like a built-in (the output of `run pack-field --out pack-field`) does
    # not hide the built-in
    (tmp_path / "demo-small").mkdir()
    assert load_scenario("demo-small").name == "demo-small"


def test_a_missing_file_says_so_and_names_a_close_one(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ScenarioError) as info:
        load_scenario("x.toml")
    assert str(info.value) == "scenario file 'x.toml' does not exist"
    (tmp_path / "my-run.toml").write_text("", encoding="utf-8")
    with pytest.raises(ScenarioError) as info:
        load_scenario("my_run.toml")
    assert str(info.value) == ("scenario file 'my_run.toml' does not exist; did you mean "
                               "'my-run.toml'?")
    with pytest.raises(ScenarioError) as info:
        load_scenario("paper-field.toml")
    assert str(info.value) == ("scenario file 'paper-field.toml' does not exist; "
                               "'paper-field' is a built-in scenario: give its name without "
                               ".toml")


def test_an_unknown_name_lists_the_close_built_in_one():
    with pytest.raises(ScenarioError) as info:
        load_scenario("paper-feild")
    msg = str(info.value)
    assert msg.startswith("no built-in scenario named 'paper-feild' and no such file; did you "
                          "mean 'paper-field', 'paper-no-field' or 'paper-spin'? allowed: a "
                          ".toml file or a built-in name: ")
    assert "demo-small, " in msg and msg.endswith(" (emfabric scenarios)")
    with pytest.raises(ScenarioError) as info:
        load_scenario("ogive")
    assert "did you mean 'ogive-field', 'ogive-no-field' or 'ogive-yawed'? " in str(info.value)
    with pytest.raises(ScenarioError) as info:
        load_scenario("nope")
    assert "did you mean" not in str(info.value)


@pytest.mark.parametrize("text,what", [("", "is empty"),
                                       ("# to do\n", "has no keys (only comments)")])
def test_an_empty_file_runs_the_defaults_with_a_warning(tmp_path, caplog, text, what):
    path = tmp_path / "x.toml"
    path.write_text(text, encoding="utf-8")
    with caplog.at_level(logging.WARNING, logger="emfabric.config.scenario"):
        sc = load_scenario(path)
    assert sc.name == "x" and sc.field.B == (0.05, 0.0, 0.0)  # the paper's field-on case
    warned = [r for r in caplog.records if r.name == "emfabric.config.scenario"]
    assert [r.getMessage() for r in warned] == [
        f"scenario file {path} {what}: running the built-in defaults (the paper's field-on "
        "case)"]
    assert warned[0].levelno == logging.WARNING
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="emfabric.config.scenario"):
        load_scenario("demo-small")  # a scenario with keys: no warning
    assert not [r for r in caplog.records if r.name == "emfabric.config.scenario"]


@pytest.mark.parametrize("source, shown", [
    ('{kind="loop", centre=[0, 0, -0.1], normal=[0, 0, 0], radius=0.1, current=1000}',
     "field.sources[0].normal = [0.0, 0.0, 0.0]: allowed: a non-zero vector"),
    ('{kind="solenoid", centre=[0, 0, -0.1], axis=[0, 0, 0], radius=0.1, length=0.05, '
     'turns=10, current=1000}',
     "field.sources[0].axis = [0.0, 0.0, 0.0]: allowed: a non-zero vector"),
])
def test_a_zero_source_direction_is_shown_as_written_numbers(source, shown):
    """The value in the message is the user's numbers, not NumPy's reprs (np.float64(0.0))."""
    from emfabric.sim.builder import build_model

    with pytest.raises(ScenarioError) as info:
        build_model(load_scenario("demo-small", dict([parse_override(
            f"field.sources=[{source}]")])))
    assert str(info.value) == shown
