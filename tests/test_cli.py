"""Command-line conventions: data on stdout, messages on stderr, errors never wrapped or
read as markup, `--version`."""

import json
import subprocess
import sys

import pytest

from emfabric import __version__

EXE = [sys.executable, "-m", "emfabric"]


def _run(*args):
    return subprocess.run(EXE + list(args), capture_output=True, text=True)


def test_version():
    """`emfabric --version` prints the package version on stdout."""
    r = _run("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"emfabric {__version__}"


def test_error_message_is_one_unwrapped_line_with_the_text_as_given():
    """A long error message piped to a file stays on one line, and brackets in the user's
    value are printed, not taken as console markup."""
    value = "[/x] not-an-edge-condition-" + "z" * 90
    r = _run("validate", "demo-small", "--set", f"fabric.edges={value}")
    assert r.returncode == 2 and r.stdout == ""
    assert any(value in line for line in r.stderr.splitlines())


def test_json_summary_alone_on_stdout(tmp_path):
    """`run --json` writes only the JSON summary on stdout (messages go to stderr)."""
    r = _run("run", "demo-small", "--out", str(tmp_path / "d"), "--json", "-q",
             "--set", "fabric.nodes=[8,8]", "--set", "solver.end_time=2e-6")
    assert r.returncode == 0, r.stderr
    summary = _strict(r.stdout)
    assert summary["status"] == "complete" and summary["steps"] > 0


def test_json_summary_says_what_the_history_says(tmp_path):
    """MODEL §7's summary (final velocity, max tilt, final ω, energy absorbed, broken yarns,
    steps, wall time) through the command line, with --threads: each figure is the history's
    (the energy absorbed the sphere's kinetic energy lost, I = 2/5 M R²)."""
    import math

    import numpy as np
    import xarray as xr

    out = tmp_path / "d"
    r = _run("run", "demo-small", "--out", str(out), "--json", "-q", "--threads", "1",
             "--set", "fabric.nodes=[13,13]", "--set", "solver.end_time=2e-5")
    assert r.returncode == 0, r.stderr
    s = _strict(r.stdout)
    h = xr.open_dataset(out / "history.nc")
    u, w = h.projectile_velocity.values, h.angular_velocity.values
    assert s["final_velocity_m_s"] == u[-1].tolist()
    assert s["residual_speed_m_s"] == math.hypot(*u[-1])
    assert s["final_omega_rad_s"] == w[-1].tolist()
    assert s["max_tilt_rad"] == float(h.tilt.max())
    assert s["max_tilt_deg"] == math.degrees(float(h.tilt.max()))
    assert s["broken_yarns"] == int(h.broken_yarns[-1])
    assert s["steps"] == h.sizes["time"] - 1 and s["steps"] > 10
    assert s["wall_time_s"] > 0.0
    m, radius = 0.037, 0.02635  # demo-small's sphere (the defaults)
    lost = 0.5 * m * (u[0] @ u[0] - u[-1] @ u[-1]) + 0.2 * m * radius**2 * (
        w[0] @ w[0] - w[-1] @ w[-1])
    assert s["energy_absorbed_J"] == pytest.approx(lost, rel=1e-9) and lost > 1.0
    assert np.isclose(s["time_s"], float(h.time[-1]), rtol=0, atol=0)


def _strict(text):
    """json.loads that refuses NaN and Infinity, as jq and JSON.parse do."""
    def refuse(word):
        raise ValueError(f"not JSON: {word}")
    return json.loads(text, parse_constant=refuse)


def test_json_output_is_strict_json_when_a_number_overflows(tmp_path):
    """A charge whose surface field overflows a double is reported as null in `run --json`,
    not as the bare word Infinity that JSON readers refuse. (No magnetic field: in the demo's
    0.05 T such a charge gyrates at 1e300 × qB/m, a step below dt_min.)"""
    r = _run("run", "demo-small", "--out", str(tmp_path / "d"), "--json", "-q",
             "--set", "fabric.nodes=[8,8]", "--set", "solver.end_time=1e-7",
             "--set", "fabric.charge_per_node=1e300", "--set", "field.B=[0,0,0]")
    assert r.returncode == 0, r.stderr
    summary = _strict(r.stdout)
    assert summary["surface_field_V_m"] is None and summary["charge_plausible"] is False
    assert summary["surface_charge_C_m2"] > 1e300


def test_non_finite_numbers_become_null():
    from emfabric.io.jsontext import dumps

    np = __import__("numpy")
    text = dumps({"a": float("nan"), "b": [np.float64(np.inf), np.array([1.5, -np.inf])],
                  "c": np.int64(3), "d": (2.0, "x"), "e": np.longdouble(0.5),
                  "f": np.array([np.longdouble("nan")])})
    assert _strict(text) == {"a": None, "b": [None, [1.5, None]], "c": 3, "d": [2.0, "x"],
                             "e": 0.5, "f": [None]}


def test_help_shows_units_in_brackets():
    """Help text is plain text, not console markup: `[s]` and `[set]` are printed (Rich's
    markup read them as a strike-through tag and an unknown tag, and dropped them)."""
    r = _run("field", "--help")
    assert r.returncode == 0 and "Time [s]" in r.stdout
    r = _run("sweep", "--help")
    assert r.returncode == 0 and "[set]" in r.stdout
