"""Scenario files round-trip (`emfabric new`, `validate --show`), and hostile input gives only
clean errors (a fuzz test over files and --set values)."""

import re
import subprocess
import sys
import tomllib
from types import UnionType
from typing import Annotated, Union, get_args, get_origin

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import BaseModel

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


def test_a_commented_file_follows_an_edited_material():
    """`emfabric new km2-fsp`: what the style and the library supply is shown commented out,
    so a file whose style is edited takes the new fabric's values (it pinned KM2's before);
    bulk_viscosity shows the value this scenario takes."""
    text = load_scenario("km2-fsp").to_commented_toml()
    assert '\n# youngs_modulus = 84620000000.0  # (derived from the material' in text
    assert "\n# bulk_viscosity = (not set: 0.06 in this scenario)" in text
    edited = tomllib.loads(text.replace('style = "km2-600d-plain"',
                                        'style = "sk76-1760dtex-plain"'))
    fab = scenario_from_dict(edited).fabric
    assert fab.material.name == "dyneema-sk76" and fab.material.density == 970.0
    assert fab.areal_density == load_scenario(
        "km2-fsp", {"fabric.style": "sk76-1760dtex-plain"}).fabric.areal_density


@pytest.mark.parametrize("overrides,line", [
    ({"solver.phi": 1.5}, "solver.phi = 1.5: must be from 0 to 1"),
    ({"fabric.edges": "open"}, "fabric.edges = 'open': allowed: 'clamped', 'free'"),
    ({"fabric.nodes": [1, 5]}, "fabric.nodes = [1, 5]: needs 2 integers [nx, ny], each ≥ 2"),
    ({"projectile.mass": "0.037"}, "projectile.mass = '0.037': needs a number > 0 (kg), not "
                                   "text (write 0.037 without quotes)"),
    ({"fabric.material.nope": 1}, "fabric.material.nope: unknown key; allowed keys here: H, c, "
                                  "density, failure_strain, model, modulus_cv, name, seed, "
                                  "tensile_strength, youngs_modulus"),
    ({"contact.dynamic_friction": 2.0}, "contact = {...}: dynamic_friction = 2.0 exceeds "
     "static_friction = 1.0; allowed: dynamic_friction ≤ static_friction"),
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

RULES = ("needs ", "must be ", "allowed: ")
"""How a validation line states what is allowed, in the key's own terms."""

PYDANTIC_WORDS = ("Input should be", "Field required", "Value error", "Tuple should have",
                  "Input tag", "Assertion failed", "after validation", "literal[",
                  "function-after", "constrained-")
"""pydantic's vocabulary, which no message shows."""


def _flat(parts, value):
    """(path parts, value) of a given value and of each of its parts (table keys, items)."""
    out = [(parts, value)]
    if isinstance(value, dict):
        for k, v in value.items():
            out += _flat((*parts, k), v)
    elif isinstance(value, list | tuple):
        for i, v in enumerate(value):
            out += _flat((*parts, i), v)
    return out


def _path(parts):
    """The path as a message writes it: keys dotted, array items indexed (sources[0].kind)."""
    out = ""
    for part in parts:
        out += f"[{part}]" if isinstance(part, int) else f".{part}" if out else str(part)
    return out


def _shown(value):
    """A value as a message quotes it: as the file writes it, a table as {...}."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, dict):
        return "{...}"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_shown(v) for v in value) + "]"
    return repr(value)


def _bare(ann):
    while True:
        if get_origin(ann) is Annotated:
            ann = get_args(ann)[0]
        elif get_origin(ann) in (Union, UnionType) and len(
                [a for a in get_args(ann) if a is not type(None)]) == 1:
            ann = next(a for a in get_args(ann) if a is not type(None))
        else:
            return ann


def _table_at(parts, flat):
    """The table type at `parts` (of a union of tables, the one its given `kind` names), or
    None where `parts` is no table of the schema."""
    ann = Scenario
    for part in parts:
        base = _bare(ann)
        if isinstance(part, int) and get_origin(base) is tuple:
            ann = get_args(base)[0]
        elif isinstance(base, type) and issubclass(base, BaseModel) and part in \
                base.model_fields:
            ann = base.model_fields[part].annotation
        else:
            return None
    base = _bare(ann)
    if get_origin(base) in (Union, UnionType):
        kind = flat.get((*parts, "kind"))
        members = [_bare(m) for m in get_args(base)]
        if not all(isinstance(m, type) and issubclass(m, BaseModel) for m in members):
            return None
        base = next((m for m in members if kind in get_args(
            m.model_fields["kind"].annotation)), members[0])
    return base if isinstance(base, type) and issubclass(base, BaseModel) else None


def _spellings(value):
    """How a message may write a value it quotes."""
    out = {repr(value), str(value), _shown(value)}
    if isinstance(value, int | float) and not isinstance(value, bool):
        out |= {repr(float(value)), f"{value:g}"}
    if isinstance(value, list | tuple):
        out.add(str(list(value)))
    return out


def _check_validation_message(msg, given):
    """A validation error names a key path inside what was given, shows the value found there
    and says what is allowed (for an unknown key: exactly the keys of its section; for a key
    missing from a table given: a key of that table, and what it needs), in the scenario's
    words, never pydantic's."""
    assert msg.startswith("invalid scenario ("), msg
    if msg.endswith("nested too deeply"):
        return
    assert not any(word in msg for word in PYDANTIC_WORDS), msg
    flat = dict(p for k, v in given.items() for p in _flat(tuple(k.split(".")), v))
    for parts, value in flat.items():
        # a key missing from a table given: its path, and what it takes
        table = _table_at(parts, flat) if isinstance(value, dict) else None
        if table is None:
            continue
        for rest in msg.split(f"\n  {_path(parts)}.")[1:]:
            child, sep, rule = rest.split("\n", 1)[0].partition(": missing; ")
            if sep and child in table.model_fields and child not in value:
                assert rule.startswith(RULES), msg
                return
    for path in flat:
        for n in range(len(path), 0, -1):
            prefix = path[:n]
            unknown = re.search(rf"\n  {re.escape(_path(prefix))}: unknown key(?: \(did you "
                                rf"mean (.+?)\?\))?; allowed keys here: (.*)", msg)
            if unknown:
                table = _table_at(prefix[:-1], flat)
                assert unknown.group(2) == ", ".join(sorted(table.model_fields)), msg
                assert prefix[-1] not in table.model_fields, msg
                for name in re.findall(r"'([^']+)'", unknown.group(1) or ""):
                    assert name in table.model_fields or name in KEYS, (name, msg)
                return
            head = f"\n  {_path(prefix)} = "
            if head not in msg:
                continue
            rest = msg.split(head, 1)[1].split("\n", 1)[0]
            if prefix in flat:  # the value there, as given, and the rule it breaks
                shown = _shown(flat[prefix])
                if rest.startswith(shown + ": "):
                    rule = rest[len(shown) + 2:]
                    if rule.startswith(RULES):
                        return
                    # a rule of the schema: on a key, it says what is allowed; on a table,
                    # it names a key of that table
                    table = _table_at(prefix, flat) if shown == "{...}" else None
                    if table is None:
                        assert "allowed" in rule.lower(), msg
                    else:
                        assert any(re.search(rf"\b{re.escape(k)}\b", rule)
                                   for k in table.model_fields), msg
                    return
                # a rule between keys of the whole scenario: `key = value with …`, allowed
                assert rest.startswith(shown + " ") and "allowed" in rest.lower(), (shown, msg)
            else:  # a rule between keys of a section (or of its sections): it names the key,
                # by its path within the section, and its value
                assert rest.startswith("{...}: "), msg
                leaf, value = _path(path[n:]), flat[path]
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
