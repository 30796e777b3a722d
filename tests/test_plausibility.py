"""Is the actuation physical? emfabric.sim.plausibility against closed forms, its warnings,
`emfabric validate` and the run summary (issue 24, item 4; docs/theory.md §3.1)."""

import dataclasses
import json
import logging
import math
import subprocess
import sys

import pytest
from typer.testing import CliRunner

from emfabric.cli import app
from emfabric.config.scenario import MaterialSpec, load_scenario
from emfabric.sim.builder import build_model
from emfabric.sim.plausibility import E_BREAKDOWN_AIR, E_MAX_SURFACE, actuation_report

from conftest import make

EPS0 = 8.8541878128e-12
L = 0.254  # the paper's sheet [m]


def _sheet(q_node: float, nodes: int = 11, **kw):
    """A nodes x nodes paper-size sheet carrying q_node per node as given (no rescaling)."""
    return build_model(make(**{"fabric.nodes": [nodes, nodes], "fabric.rescale": False,
                               "fabric.charge_per_node": q_node, **kw}))


def _q_node_for(e_s: float, nodes: int = 11) -> float:
    """The charge per node whose sheet has the surface field e_s: σ = 2 ε0 E_s."""
    return 2.0 * EPS0 * e_s * L * L / nodes**2


def test_the_papers_sheet_from_closed_forms():
    """1 C on each of 100 x 100 nodes of a 0.254 m sheet: σ = 1e4 C / 0.254² m² ≈ 1.55e5 C/m²,
    E_s = σ/(2ε0) ≈ 8.75e15 V/m, p = σ²/(2ε0) ≈ 1.36e21 Pa; beyond any material, loudly."""
    r = actuation_report(build_model(load_scenario("paper-field")))
    sigma = 1e4 / L**2
    assert r["charge_C"] == pytest.approx(1e4, rel=1e-12)
    assert r["surface_charge_C_m2"] == pytest.approx(sigma, rel=1e-12)
    assert r["surface_charge_C_m2"] == pytest.approx(1.55e5, rel=1e-3)
    assert r["surface_field_V_m"] == pytest.approx(sigma / (2 * EPS0), rel=1e-12)
    assert r["electrostatic_pressure_Pa"] == pytest.approx(sigma**2 / (2 * EPS0), rel=1e-12)
    assert r["ply_charge_C"] == pytest.approx([1e4], rel=1e-12)
    assert r["field_over_air_breakdown"] == pytest.approx(sigma / (2 * EPS0) / 3e6, rel=1e-12)
    assert r["charge_plausible"] is False
    assert r["peak_B_T"] == pytest.approx(0.05) and r["peak_E_V_m"] == 0.0
    assert len(r["warnings"]) == 1
    assert "beyond what any material holds" in r["warnings"][0]
    assert "discharge into air" in r["warnings"][0]
    json.dumps(r)  # plain values only


def test_no_charge_no_warning():
    """An uncharged sheet in a modest field: E_s = 0, p = 0, nothing to warn about."""
    r = actuation_report(_sheet(0.0))
    assert r["surface_field_V_m"] == 0.0 and r["electrostatic_pressure_Pa"] == 0.0
    assert r["charge_plausible"] is True and r["warnings"] == []


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_the_air_breakdown_limit(sign):
    """Just below air's breakdown field no warning; just above, the air warning (not the
    material one); the sign of the charge does not matter."""
    below = actuation_report(_sheet(sign * _q_node_for(E_BREAKDOWN_AIR * (1 - 1e-6))))
    above = actuation_report(_sheet(sign * _q_node_for(E_BREAKDOWN_AIR * (1 + 1e-6))))
    assert below["surface_field_V_m"] == pytest.approx(E_BREAKDOWN_AIR, rel=1e-5)
    assert below["warnings"] == [] and below["charge_plausible"] is True
    assert above["charge_plausible"] is False and len(above["warnings"]) == 1
    assert "discharge into air" in above["warnings"][0]
    assert "beyond what any material holds" not in above["warnings"][0]
    # the charge at air's limit, per node of the paper's 100 x 100 sheet (docs/theory.md §3.1)
    assert _q_node_for(E_BREAKDOWN_AIR, 100) == pytest.approx(3.427e-10, rel=1e-3)


def test_beyond_any_material():
    """Above the material limit the warning says so."""
    r = actuation_report(_sheet(_q_node_for(2 * E_MAX_SURFACE)))
    assert r["field_over_material_limit"] == pytest.approx(2.0, rel=1e-9)
    assert any("beyond what any material holds" in w for w in r["warnings"])


def test_a_pack_sums_each_plys_charge():
    """Two plies with different charges: each ply's total is its own nodes' sum, the pack's
    the sum of both; σ and E_s follow per ply and for the pack. With opposite charges the
    pack's field cancels, but each ply's own field still decides."""
    q1, q2 = 1e-9, 3e-9
    sc = make(**{"fabric.nodes": [11, 11], "fabric.rescale": False, "fabric.plies": 2,
                 "fabric.ply": [{"charge_per_node": q1}, {"charge_per_node": q2}]})
    r = actuation_report(build_model(sc))
    assert r["plies"] == 2
    assert r["ply_charge_C"] == pytest.approx([121 * q1, 121 * q2], rel=1e-12)
    assert r["charge_C"] == pytest.approx(121 * (q1 + q2), rel=1e-12)
    assert r["ply_surface_charge_C_m2"] == pytest.approx([121 * q1 / L**2, 121 * q2 / L**2],
                                                         rel=1e-12)
    assert r["surface_field_V_m"] == pytest.approx(121 * (q1 + q2) / L**2 / (2 * EPS0),
                                                   rel=1e-12)
    q = _q_node_for(10 * E_BREAKDOWN_AIR)
    sc = make(**{"fabric.nodes": [11, 11], "fabric.rescale": False, "fabric.plies": 2,
                 "fabric.ply": [{"charge_per_node": q}, {"charge_per_node": -q}]})
    r = actuation_report(build_model(sc))
    assert r["charge_C"] == pytest.approx(0.0, abs=1e-20)
    assert r["max_surface_field_V_m"] == pytest.approx(10 * E_BREAKDOWN_AIR, rel=1e-9)
    assert r["charge_plausible"] is False and len(r["warnings"]) == 1


def test_applied_fields_beyond_magnets_and_air():
    """|B| above the strongest non-destructive magnets and |E| above air's breakdown warn."""
    r = actuation_report(_sheet(0.0, **{"field.B": [0.0, 0.0, 150.0],
                                        "field.E": [4e6, 0.0, 0.0]}))
    assert r["peak_B_T"] == pytest.approx(150.0) and r["peak_E_V_m"] == pytest.approx(4e6)
    assert any("100 T" in w for w in r["warnings"])
    assert any("applied |E|" in w for w in r["warnings"])
    assert len(r["warnings"]) == 2


def test_pressure_against_the_yarn_strength():
    """With a yarn strength given, p = σ²/(2ε0) above it warns, below it does not."""
    if "tensile_strength" not in MaterialSpec.model_fields:
        pytest.skip("no fabric.material.tensile_strength in this scenario schema")
    q = _q_node_for(E_BREAKDOWN_AIR / 2)  # no field warning
    p = (q * 121 / L**2) ** 2 / (2 * EPS0)
    weak = actuation_report(_sheet(q, **{"fabric.material.tensile_strength": p / 2}))
    strong = actuation_report(_sheet(q, **{"fabric.material.tensile_strength": p * 2}))
    assert weak["pressure_over_strength"] == pytest.approx(2.0, rel=1e-9)
    assert any("tensile strength" in w for w in weak["warnings"])
    assert strong["warnings"] == []
    none = actuation_report(_sheet(q))
    assert none["tensile_strength_Pa"] is None and none["pressure_over_strength"] is None


def test_a_model_without_scenario_takes_the_nodes_extent():
    """A Model put together in Python has no fabric.size: the nodes' extent is the sheet."""
    model = _sheet(1e-9)
    bare = dataclasses.replace(model, scenario=None)
    assert actuation_report(bare)["surface_charge_C_m2"] == pytest.approx(
        actuation_report(model)["surface_charge_C_m2"], rel=1e-12)


def test_validate_prints_the_report_and_the_warning():
    """`emfabric validate` prints σ, E_s, p and |B| after "ok" and the warning; exit 0."""
    r = CliRunner().invoke(app, ["validate", "demo-small", "--set", "fabric.nodes=[11,11]"])
    out = r.output + (r.stderr if r.stderr_bytes is not None else "")
    assert r.exit_code == 0, out
    assert "surface charge" in out and "σ =" in out and "air's breakdown field" in out
    assert "electrostatic pressure" in out and "peak |B|" in out
    assert "warning:" in out and "beyond what any material holds" in out
    quiet = CliRunner().invoke(app, ["validate", "demo-small", "--set", "fabric.nodes=[11,11]",
                                     "--set", "fabric.charge_per_node=0"])
    assert quiet.exit_code == 0 and "warning:" not in quiet.output


def test_run_summary_and_start_log(tmp_path, caplog):
    """`emfabric run --json` carries the plausibility keys (valid JSON); a run logs each
    warning once at its start; the printed summary table renders the warning list."""
    args = [sys.executable, "-m", "emfabric", "run", "demo-small", "-q",
            "--set", "fabric.nodes=[11,11]", "--set", "solver.end_time=2e-6"]
    r = subprocess.run(args + ["--out", str(tmp_path / "a"), "--json"], capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    for key in ("surface_charge_C_m2", "surface_field_V_m", "electrostatic_pressure_Pa"):
        assert isinstance(s[key], float) and math.isfinite(s[key]), key
    assert s["charge_plausible"] is False
    assert isinstance(s["plausibility_warnings"], list) and len(s["plausibility_warnings"]) == 1
    assert s["surface_charge_C_m2"] == pytest.approx(1e4 / L**2, rel=1e-9)  # rescaled q
    # against air's dielectric strength (σ/(2ε0) over 3 MV/m) and the yarn's strength (the
    # paper's Zylon names none: null)
    assert s["field_over_air_breakdown"] == pytest.approx(1e4 / L**2 / (2 * EPS0) / 3e6,
                                                          rel=1e-9)
    assert s["tensile_strength_Pa"] is None and s["pressure_over_strength"] is None
    km2 = subprocess.run(args + ["--out", str(tmp_path / "c"), "--json", "--set",
                                 'fabric.material.name="kevlar-km2"'],
                         capture_output=True, text=True)
    assert km2.returncode == 0, km2.stderr
    k = json.loads(km2.stdout)
    assert k["tensile_strength_Pa"] == pytest.approx(3.88e9)
    assert k["pressure_over_strength"] == pytest.approx(
        k["electrostatic_pressure_Pa"] / 3.88e9, rel=1e-9)
    t = subprocess.run(args + ["--out", str(tmp_path / "b")], capture_output=True, text=True)
    assert t.returncode == 0, t.stderr
    assert "plausibility_warnings" in t.stderr and "charge_plausible" in t.stderr

    from emfabric.runner.loop import run

    sc = load_scenario("demo-small", {"fabric.nodes": [11, 11], "solver.end_time": 2e-6})
    with caplog.at_level(logging.WARNING, logger="emfabric"):
        res = run(sc)
    logged = [rec.getMessage() for rec in caplog.records if rec.levelno == logging.WARNING]
    assert logged == res.summary["plausibility_warnings"]
