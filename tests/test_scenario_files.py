"""Scenario files round-trip (`emfabric new`, `validate --show`), and hostile input gives only
clean errors (a fuzz test over files and --set values)."""

import subprocess
import sys
import tomllib

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from emfabric.config.scenario import (
    Scenario,
    ScenarioError,
    _model_in,
    builtin_names,
    load_scenario,
    parse_override,
    scenario_from_dict,
)
from emfabric.sim.builder import build_model


def _keys(model=Scenario, prefix=""):
    out = []
    for name, field in model.model_fields.items():
        sub = _model_in(field.annotation)
        if sub is not None and not str(field.annotation).startswith("tuple"):
            out += _keys(sub, f"{prefix}{name}.")
        else:
            out.append(f"{prefix}{name}")
    return out


KEYS = _keys()


def test_every_builtin_round_trips_through_its_commented_file():
    for name in builtin_names():
        sc = load_scenario(name, {"projectile.charges": [{"position": [0.01, 0, 0],
                                                          "charge": -2.0}]})
        text = sc.to_commented_toml()
        assert scenario_from_dict(tomllib.loads(text)).to_dict() == sc.to_dict(), name
        # one line per key: arrays are never spread over lines, every key says what it is
        for line in text.splitlines():
            if "=" in line and not line.startswith("#"):
                assert line.count("[") == line.count("]"), line
                assert "  # " in line, line


def test_new_then_run_a_custom_file(tmp_path):
    """The README's path: `emfabric new paper-field > my.toml`, edit, `emfabric run my.toml`."""
    text = subprocess.run([sys.executable, "-m", "emfabric", "new", "paper-field"],
                          capture_output=True, text=True, check=True).stdout
    assert tomllib.loads(text)["name"] == "paper-field"
    text = text.replace("end_time = 0.0015", "end_time = 2e-06")
    text = text.replace("nodes = [100, 100]", "nodes = [12, 12]")
    (tmp_path / "my.toml").write_text(text, encoding="utf-8")
    r = subprocess.run([sys.executable, "-m", "emfabric", "run", "my.toml", "-q", "--json"],
                       capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "runs" / "my" / "history.nc").exists()
    shown = subprocess.run([sys.executable, "-m", "emfabric", "validate", "my.toml", "--show"],
                           capture_output=True, text=True, cwd=tmp_path, check=True).stdout
    assert tomllib.loads(shown)["fabric"]["nodes"] == [12, 12]


@pytest.mark.parametrize("overrides,line", [
    ({"solver.phi": 1.5}, "solver.phi = 1.5: Input should be less than or equal to 1"),
    ({"fabric.edges": "open"}, "fabric.edges = 'open': must be one of 'clamped' or 'free'"),
    ({"fabric.nodes": [1, 5]}, "fabric.nodes.0 = 1: Input should be greater than or equal to 2"),
    ({"projectile.mass": "0.037"}, "projectile.mass = '0.037': Input should be a valid number"),
    ({"fabric.material.nope": 1}, "fabric.material.nope: unknown key; allowed keys here: H, c, "
                                  "density, failure_strain, model, modulus_cv, name, seed, "
                                  "tensile_strength, youngs_modulus"),
    ({"contact.dynamic_friction": 2.0}, "contact = {...}: Value error, dynamic_friction = 2.0 "
     "exceeds static_friction = 1.0; allowed: dynamic_friction ≤ static_friction"),
])
def test_error_names_key_value_and_what_is_allowed(overrides, line):
    """A bad value's message is `key.path = value: what is allowed`, one line per error."""
    with pytest.raises(ScenarioError) as info:
        load_scenario("demo-small", overrides)
    assert str(info.value) == (f"invalid scenario (overrides {', '.join(overrides)}):\n  "
                               f"{line}")
    _check_validation_message(str(info.value), overrides)


def test_build_errors_name_key_value_and_what_is_allowed():
    """Errors found when building (modulus draw, stability of φ < 1/2): key, value, limit."""
    sc = load_scenario("demo-small", {"fabric.nodes": [12, 12],
                                      "fabric.material.modulus_cv": 5.0})
    with pytest.raises(ScenarioError) as info:
        build_model(sc)
    msg = str(info.value)
    assert msg.startswith("fabric.material.modulus_cv = 5.0: with seed 0 a yarn draws")
    assert msg.endswith("(allowed: every draw > 0)")
    _check_build_message(msg, sc)
    sc = load_scenario("demo-small", {"solver.phi": 0.0, "solver.dt_max": 1e-5})
    with pytest.raises(ScenarioError) as info:
        build_model(sc)
    msg = str(info.value)
    assert msg.startswith("solver.dt_max = 1e-05 s with solver.phi = 0.0: ")
    assert "allowed: dt_max ≤ " in msg and msg.endswith(" s, or phi ≥ 0.5")
    _check_build_message(msg, sc)


@pytest.mark.parametrize("overrides", [
    {"contact.segments": "sometimes"},  # "auto" | bool
    {"field.sources": [{}]},  # a table told apart by its `kind`
])
def test_keys_of_several_types_name_their_path_and_what_is_allowed(overrides):
    """A key taking one of several forms gets `its.path = value: every allowed form`."""
    with pytest.raises(ScenarioError) as info:
        load_scenario("demo-small", overrides)
    _check_validation_message(str(info.value), overrides)


@pytest.mark.parametrize("key", ["fabric.yarn_radius", "projectile.radius"])
def test_a_huge_length_is_a_scenario_error(key):
    """A finite but absurd length (1e200 m) is refused with its key, not an OverflowError."""
    sc = load_scenario("demo-small", {key: 1e200})
    with pytest.raises(ScenarioError, match=key.replace(".", r"\.")):
        build_model(sc)


_scalars = st.one_of(
    st.text(max_size=12), st.booleans(), st.none(),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.floats(allow_nan=True, allow_infinity=True),
)
_values = st.recursive(_scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=8)


def _build_if_small(sc: Scenario) -> None:
    nx, ny = sc.fabric.nodes
    if nx * ny <= 4000:  # bounded time: build (validation, geometry, stability) small grids
        build_model(sc)


# --- what an error message must say: the key's path, the value given there, what is allowed ---

RULES = ("Input should be ", "must be one of ", "Tuple should have ", "Field required",
         "Value error, ", "Input tag ")
"""How a validation line states what is allowed (pydantic's wording, or the schema's own)."""


def _flat(key, value):
    """(dotted path, value) of a given value and of each of its parts (table keys, items)."""
    out = [(key, value)]
    if isinstance(value, dict):
        for k, v in value.items():
            out += _flat(f"{key}.{k}" if key else str(k), v)
    elif isinstance(value, list | tuple):
        for i, v in enumerate(value):
            out += _flat(f"{key}.{i}", v)
    return out


def _as_validated(value):
    """The value as validation sees it: arrays as tuples (strict vectors), tables kept."""
    if isinstance(value, dict):
        return {k: _as_validated(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return tuple(_as_validated(v) for v in value)
    return value


def _section_keys(path):
    """Sorted key names of the section that holds `path` (list indices skipped)."""
    model = Scenario
    for part in path.split(".")[:-1]:
        if part.isdigit():
            continue
        model = _model_in(model.model_fields[part].annotation)
    return sorted(model.model_fields)


def _spellings(value):
    """How a message may write a value it quotes."""
    out = {repr(value), str(value)}
    if isinstance(value, int | float) and not isinstance(value, bool):
        out |= {repr(float(value)), f"{value:g}"}
    if isinstance(value, list | tuple):
        out.add(str(list(value)))
    return out


def _check_validation_message(msg, given):
    """A validation error names a key path inside what was given, shows the value found there
    and says what is allowed (for an unknown key: exactly the keys of its section)."""
    assert msg.startswith("invalid scenario ("), msg
    if msg.endswith("nested too deeply"):
        return
    flat = dict(p for k, v in given.items() for p in _flat(k, v))
    for path, value in flat.items():
        # an item or key missing inside the value given: its path, the value it is missing from
        shown = "{...}" if isinstance(value, dict) else repr(_as_validated(value))
        missing = f"\n  {path}."
        if missing in msg and msg.split(missing, 1)[1].split(" = ", 1)[-1].startswith(
                shown + ": Field required"):
            return
    for path in flat:
        parts = path.split(".")
        for n in range(len(parts), 0, -1):
            prefix = ".".join(parts[:n])
            head = f"\n  {prefix}: unknown key; allowed keys here: "
            if head in msg:
                listed = msg.split(head, 1)[1].split("\n", 1)[0]
                assert listed == ", ".join(_section_keys(prefix)), msg
                return
            head = f"\n  {prefix} = "
            if head not in msg:
                continue
            rest = msg.split(head, 1)[1]
            if prefix in flat:  # the value there, as given, and the rule it breaks
                value = flat[prefix]
                shown = "{...}" if isinstance(value, dict) else repr(_as_validated(value))
                assert rest.startswith(shown + ": "), (shown, msg)
                assert rest[len(shown) + 2:].startswith(RULES), msg
            else:  # a rule between keys of a section (or of its sections): it names the key,
                # by its path within the section, and its value
                assert rest.startswith("{...}: Value error, "), msg
                leaf, value = ".".join(parts[n:]), flat[path]
                assert any(f"{leaf} = {s}" in rest for s in _spellings(value)), (leaf, msg)
            return
    raise AssertionError(f"no line names a key path of {list(given)!r}: {msg}")


def _check_build_message(msg, sc):
    """An error found while building the model starts `key = value:` (the value as the
    scenario holds it) and says what is allowed."""
    key, _, rest = msg.partition(" = ")
    assert key in KEYS, msg
    value = sc
    for part in key.split("."):
        value = getattr(value, part)
    assert any(rest.startswith(s) for s in _spellings(value)), (value, msg)
    assert "allowed" in rest, msg


def _check_override_error(err, key, value, build):
    """Errors of one --set key=value: validation, a value used as a section, or the build."""
    msg = str(err)
    if msg.startswith("invalid scenario ("):
        _check_validation_message(msg, {key: value})
    elif msg.startswith(f"override {key!r}: "):
        tail = msg[len(f"override {key!r}: "):]
        if tail != "value nested too deeply":
            prefix, _, why = tail.partition(" is a value, not a section")
            assert why == "" and key.startswith(prefix.strip("'") + "."), msg
            assert prefix.strip("'") in KEYS, msg
    else:
        assert build is not None, msg
        _check_build_message(msg, build)


@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(key=st.sampled_from(KEYS + ["fabric", "nope.key", "fabric.material.nope"]),
       value=_values)
def test_fuzz_overrides_give_clean_errors_or_scenarios(key, value):
    """A bad override is a ScenarioError naming the key path, the value and what is allowed."""
    sc = None
    try:
        sc = load_scenario("demo-small", {key: value})
        _build_if_small(sc)
    except ScenarioError as err:
        _check_override_error(err, key, value, sc)


@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(text=st.text(max_size=80))
def test_fuzz_set_text_gives_clean_errors_or_scenarios(text):
    """A bad --set text is a ScenarioError that quotes it and says the form, or names the key."""
    sc = None
    try:
        key, value = parse_override(text)
    except ScenarioError as err:
        assert str(err) == f"override {text!r} must look like section.key=value", str(err)
        return
    try:
        sc = load_scenario("demo-small", {key: value})
        _build_if_small(sc)
    except ScenarioError as err:
        _check_override_error(err, key, value, sc)


@settings(max_examples=100, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=st.one_of(st.binary(max_size=120),
                      st.lists(st.sampled_from(KEYS), min_size=1, max_size=3).flatmap(
                          lambda ks: st.tuples(st.just(ks), st.lists(_values, min_size=len(ks),
                                                                     max_size=len(ks))))))
def test_fuzz_files_give_clean_errors_or_scenarios(tmp_path_factory, data):
    """A bad file is a ScenarioError naming the byte, the TOML position or key, value, rule."""
    path = tmp_path_factory.mktemp("fuzz") / "s.toml"
    if isinstance(data, bytes):
        path.write_bytes(data)
    else:
        keys, values = data
        lines = []
        for k, v in zip(keys, values, strict=True):
            try:
                lines.append(f"{k} = {_toml(v)}")
            except ValueError:
                lines.append(f"{k} = {v!r}")
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    sc = None
    try:
        sc = load_scenario(path)
        _build_if_small(sc)
    except ScenarioError as err:
        msg = str(err)
        raw = path.read_bytes()
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as bad:  # names the file, the byte and where it is
            assert msg == (f"scenario file {str(path)!r} is not UTF-8 text (byte "
                           f"{raw[bad.start]:#04x} at offset {bad.start}); save it as UTF-8")
            return
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as bad:  # the parser's line and column
            assert msg == f"invalid TOML in {path}: {bad}"
            return
        if sc is None:
            _check_validation_message(msg, data)
        else:
            _check_build_message(msg, sc)


def _toml(v):
    import json
    import math

    if v is None:
        raise ValueError
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_toml(x)}" for k, x in v.items()) + "}"
    raise ValueError
