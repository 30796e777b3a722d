"""The yarns' bulk viscosity (solver.bulk_viscosity, central differences): its force against the
damped oscillator's closed form, its work in the energy budget, and when it is on."""

import math

import numpy as np
import pytest

from emfabric._kernels.diagnostics import total_energy
from emfabric._kernels.records import BODY_X, ENERGY_VISCOUS
from emfabric.config.scenario import BULK_VISCOSITY, ScenarioError, load_scenario
from emfabric.integrators import make_integrator
from emfabric.sim.builder import build_model
from emfabric.sim.state import initial_state, update_forces

from conftest import fabric_only, make

L0, E, RHO, R = 1e-3, 100e9, 1440.0, 1e-4  # spacing [m], modulus [Pa], density, yarn radius [m]
V0 = 0.05  # each column's speed [m/s]: the pair parts at 2 V0, a peak strain ~3e-6


def _pair(q: float, courant: float):
    """A free 2 × 2 square whose right column moves at +V0 and left at −V0 along x: each x-yarn is
    a pair of masses m on a spring k = 𝔼A0/L0 (the y-yarns only translate), with the dashpot
    q·√(k m) while taut. Returns (model, state, m, k)."""
    sc = fabric_only(**{"fabric.nodes": [2, 2], "fabric.size": [L0, L0], "fabric.edges": "free",
                        "fabric.areal_density": 0.05, "fabric.yarn_radius": R,
                        "fabric.material.youngs_modulus": E, "solver.bulk_viscosity": q,
                        "solver.courant": courant})
    model = build_model(sc)
    s = initial_state(model)
    s.node_v[0] = np.where(np.arange(4) % 2 == 1, V0, -V0)
    update_forces(model, s)
    s.energy_initial = float(total_energy(model.physics, s.node_x, s.node_v, s.seg_alpha, s.body,
                                          s.energy, s.body[BODY_X], model.flight_direction))
    m = 0.05 * L0 * L0 / 4  # every node carries a quarter of the square
    return model, s, m, E * math.pi * R**2 / L0


def _first_peak(model, s):
    """March to the x-yarns' first greatest extension; (extension [m], the state there)."""
    integ = make_integrator(model)
    s2 = s.copy()
    best, at = -1.0, None
    while True:
        integ.step(s, s2)
        s, s2 = s2, s
        ext = float(s.node_x[0, 1] - s.node_x[0, 0]) - L0
        if ext < best:
            return best, at
        best, at = ext, s.copy()


@pytest.mark.parametrize("q", [0.0, 0.3])
def test_a_stretching_yarn_is_the_damped_oscillator(q):
    """Relative motion r of the pair: μ r̈ + η ṙ + k r = 0 with μ = m/2, η = q√(k m), r(0) = 0,
    ṙ(0) = 2V0: ξ = η/(2√(kμ)) = q/√2, and the first greatest extension is
    (2V0/ω_d) e^{−ξω t*} sin(ω_d t*) at tan(ω_d t*) = √(1 − ξ²)/ξ (t* = π/(2ω) without
    damping). The viscous tension reads the rate over the step, v_{n+½}, half a step behind
    the force: first order in Δt, 1.0 % over at courant 0.1, 0.45 % at 0.05, 0.21 % at 0.025
    (measured), so within 0.3 % at 0.025. The viscous dissipation is what the pair lost,
    KE(0) − KE − strain energy, to 0.5 %."""
    model, s, m, k = _pair(q, 0.025)
    mu = m / 2
    omega = math.sqrt(k / mu)
    xi = q * math.sqrt(k * m) / (2 * math.sqrt(k * mu))
    assert xi == pytest.approx(q / math.sqrt(2))
    wd = omega * math.sqrt(1 - xi * xi)
    ts = math.atan2(math.sqrt(1 - xi * xi), xi) / wd
    expected = 2 * V0 / wd * math.exp(-xi * omega * ts) * math.sin(wd * ts)
    ext, at = _first_peak(model, s)
    assert ext == pytest.approx(expected, rel=3e-3)
    # two yarns, each giving up (1/2)μ(2V0)² less what it holds at the peak (and moves)
    ke = 0.5 * m * float((at.node_v**2).sum())
    lost = 2 * 0.5 * mu * (2 * V0) ** 2 - ke - 2 * 0.5 * k * ext**2
    if q == 0.0:
        assert at.energy[ENERGY_VISCOUS] == 0.0
    else:
        assert at.energy[ENERGY_VISCOUS] == pytest.approx(lost, rel=5e-3)
        assert lost > 0.2 * 2 * 0.5 * mu * (2 * V0) ** 2  # a fifth of the energy: q matters


def test_viscous_work_closes_the_energy_budget_to_second_order():
    """The kicks book the viscous force's work as they change the kinetic energy (h/2 f_v·v̄,
    the first half with the State's f_v): what the balance leaves is the scheme's own error
    (the yarns' trapezoid, as without viscosity), ~4× smaller per halving of Δt (measured 0.70,
    0.17, 0.04 % of the pair's energy, of which the dashpot takes two thirds)."""
    errors = []
    for courant in (0.2, 0.1, 0.05):
        model, s, m, k = _pair(0.3, courant)
        integ = make_integrator(model)
        s2 = s.copy()
        worst = 0.0
        while s.t < 3 * math.pi * math.sqrt(m / (2 * k)):  # three half periods
            integ.step(s, s2)
            s, s2 = s2, s
            tot = total_energy(model.physics, s.node_x, s.node_v, s.seg_alpha, s.body, s.energy,
                               s.body[BODY_X], model.flight_direction)
            worst = max(worst, abs(tot - s.energy_initial))
        errors.append(worst)
        assert s.energy[ENERGY_VISCOUS] > 0.0
    assert errors[-1] < 1e-3 * s.energy[ENERGY_VISCOUS]
    assert errors[0] / errors[1] > 3.0 and errors[1] / errors[2] > 3.0, errors


def test_bulk_viscosity_is_on_where_yarns_break_and_central_differences_only():
    """Not given: BULK_VISCOSITY for brittle yarns under central differences, 0 for the paper's
    law or the φ-scheme; given, it is the run's; the φ-scheme refuses a non-zero one, naming
    the key and what is allowed. It shortens the stable step by √(1 + q²) − q."""
    assert BULK_VISCOSITY == 0.06
    assert load_scenario("km2-fsp").bulk_viscosity == BULK_VISCOSITY
    assert load_scenario("paper-field").bulk_viscosity == 0.0
    assert load_scenario("km2-fsp", {"solver.bulk_viscosity": 0.0}).bulk_viscosity == 0.0
    assert load_scenario("paper-field", {"solver.bulk_viscosity": 0.2}).bulk_viscosity == 0.2
    assert load_scenario("km2-fsp", {"solver.integrator": "phi"}).bulk_viscosity == 0.0
    with pytest.raises(ScenarioError, match=r"solver\.bulk_viscosity = 0\.1 .*Allowed"):
        load_scenario("km2-fsp", {"solver.integrator": "phi", "solver.bulk_viscosity": 0.1})
    with pytest.raises(ScenarioError, match="bulk_viscosity"):
        load_scenario("km2-fsp", {"solver.bulk_viscosity": 1.5})
    model = build_model(load_scenario("paper-field", {"solver.bulk_viscosity": 0.2}))
    assert model.physics.yarns.damping.shape == (model.seg_count,)
    assert model.options.bulk_viscosity == 0.2
    assert build_model(load_scenario("paper-field")).physics.yarns.damping.size == 0
    integ = make_integrator(model)
    assert integ.viscous_factor == pytest.approx(math.sqrt(1.04) - 0.2)


def _overlapping_pack():
    """Two clamped 5 × 5 plies at rest, the second lifted by half their contact distance d
    (a state no scenario starts from: it refuses interpenetrating plies): the first step's ply
    contact places the interior nodes of both apart (the pairs at rest: no impulse), which
    stretches the segments to the clamped edges."""
    sc = fabric_only(**{"fabric.nodes": [5, 5], "fabric.size": [0.02, 0.02],
                        "fabric.plies": 2, "fabric.yarn_radius": 2e-4,
                        "fabric.charge_per_node": 0.0, "solver.bulk_viscosity": 0.06,
                        "solver.end_time": 1e-6})
    model = build_model(sc)
    integ = make_integrator(model)
    s, s2 = initial_state(model), initial_state(model)
    second = model.node_ply() == 1  # 0-based
    s.node_x[2, second] += 2e-4  # d = 4e-4: half of it
    update_forces(model, s)
    integ.step(s, s2)
    return model, s, s2


def test_a_placement_is_not_a_strain_rate():
    """A node placed by contact has not moved as a yarn does: the viscous force of the step's
    kick takes the rate from its velocity after contact, here 0 (the plies are at rest), so the
    viscous force is exactly 0 while the placement stretched the yarns to the frame. Taken from
    the positions, the placement δ over the step Δt made a rate δ/Δt: on a pack perforated by
    an FSP, viscous forces of 2000 m/s of rate (docs/theory.md §2.1)."""
    model, s, s2 = _overlapping_pack()
    assert np.all(s.node_v == 0.0) and np.all(s.node_fv == 0.0)
    moved = np.abs(s2.node_x - s.node_x).max()
    assert moved > 5e-5  # placed apart by a good part of the overlap
    # the elastic force of the yarns the placement stretched is there, the viscous one is not
    assert np.abs(s2.node_f).max() > 0.0
    assert np.all(s2.node_fv == 0.0)


def test_a_viscous_pack_s_budget_closes_as_an_elastic_one_s():
    """The projection term of the energy budget is the work of the yarns' elastic force over
    the placements; the viscous force has no energy a placement changes (its work is the
    kicks'). A pack struck hard (two clamped 21 × 21 plies, no yarn breaks, 300 m/s) closes its
    budget with the bulk viscosity as without it: with the viscous force in the projection
    term and the rate taken from the velocities it was 0.33 J of the 49.5 J."""
    base = {"fabric.plies": 2, "fabric.nodes": [21, 21], "fabric.style": "km2-600d-plain",
            "fabric.size": [0.05, 0.05], "fabric.charge_per_node": 0.0,
            "fabric.damage.failure_strain": 0.25, "field.B": [0.0, 0.0, 0.0],
            "projectile.shape": "fsp", "projectile.radius": 0.00278,
            "projectile.mass": 0.0011, "projectile.velocity": [0.0, 0.0, -300.0],
            "solver.end_time": 1e-4}
    from emfabric.runner.loop import run

    errors = {}
    for q in (0.0, 0.06):
        ds = run(make(**base, **{"solver.bulk_viscosity": q})).history
        assert ds.attrs["status"] == "complete"
        assert int(ds.broken_yarns.values[-1]) == 0
        energy_in = float(ds.kinetic_energy_projectile.values[0])
        errors[q] = np.abs(ds.energy_balance_error.values).max() / energy_in
    assert errors[0.06] < 2e-3 and errors[0.0] < 2e-3
