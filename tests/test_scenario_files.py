"""Scenario files round-trip (`emfabric new`, `validate --show`), and hostile input gives only
clean errors (a fuzz test over files and --set values)."""

import subprocess
import sys
import tomllib

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


@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(key=st.sampled_from(KEYS + ["fabric", "nope.key", "fabric.material.nope"]),
       value=_values)
def test_fuzz_overrides_give_clean_errors_or_scenarios(key, value):
    try:
        sc = load_scenario("demo-small", {key: value})
        _build_if_small(sc)
    except ScenarioError as err:
        assert str(err)


@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(text=st.text(max_size=80))
def test_fuzz_set_text_gives_clean_errors_or_scenarios(text):
    try:
        key, value = parse_override(text)
        sc = load_scenario("demo-small", {key: value})
        _build_if_small(sc)
    except ScenarioError as err:
        assert str(err)


@settings(max_examples=100, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=st.one_of(st.binary(max_size=120),
                      st.lists(st.sampled_from(KEYS), min_size=1, max_size=3).flatmap(
                          lambda ks: st.tuples(st.just(ks), st.lists(_values, min_size=len(ks),
                                                                     max_size=len(ks))))))
def test_fuzz_files_give_clean_errors_or_scenarios(tmp_path_factory, data):
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
    try:
        sc = load_scenario(path)
        _build_if_small(sc)
    except ScenarioError as err:
        assert str(err)


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
