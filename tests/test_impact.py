"""Projectile impact: conservation, symmetry, the sense of the field-induced spin, energy."""

import numpy as np
import pytest

from emfabric._kernels.records import BODY_X
from emfabric.runner.loop import run

from conftest import make

H = 0.254 / 99  # the paper's node spacing


def _patch(n, **kw):
    """An n×n patch cut from the paper's sheet (its spacing, yarns and node charge: rescale
    off, the patch is not a 100 × 100 grid of its own size), sphere just touching the centre."""
    return make(**{"fabric.nodes": [n, n], "fabric.size": [(n - 1) * H, (n - 1) * H],
                   "fabric.rescale": False, "projectile.gap": 0.0, **kw})


def _momenta(ds):
    p = ds.fabric_momentum.values + ds.projectile_momentum.values
    ang = ds.fabric_angular_momentum.values + ds.projectile_angular_momentum.values
    return p, ang


def _oblique(dt):
    return make(**{
        "fabric.nodes": [15, 15], "fabric.size": [0.1, 0.1], "fabric.edges": "free",
        "fabric.rescale": True, "field.B": [0, 0, 0], "projectile.radius": 0.01,
        "projectile.position": [0.013, -0.007, 0.0101],
        "projectile.velocity": [30.0, -20.0, -200.0],
        "projectile.angular_velocity": [100.0, -300.0, 2000.0], "solver.end_time": 40e-6,
        "solver.adaptive": False, "solver.dt_max": dt, "solver.tolerance": 1e-10,
        "solver.max_iterations": 100,
    })


def _oblique_run(dt):
    """The oblique impact at Δt: total linear and angular momentum per record, and which steps
    changed the set of nodes in contact (a node in contact sits on the sphere, |r − c| = R)."""
    sc = _oblique(dt)
    radius = sc.projectile.radius
    touching = [frozenset()]

    def watch(state, _info):
        gap = np.linalg.norm(state.node_x - state.body[BODY_X][:, None], axis=0) - radius
        touching.append(frozenset(np.flatnonzero(np.abs(gap) < 1e-9 * radius).tolist()))

    ds = run(sc, progress=watch).history
    p, ang = _momenta(ds)
    changed = np.array([a != b for a, b in zip(touching[:-1], touching[1:], strict=True)])
    return ds, p, ang, changed


def test_momentum_conserved_free_edges():
    """Case 3: linear momentum to round-off; angular momentum to a first-order error in Δt."""
    # Free fabric, no field, oblique off-centre hit with spin. Each contact impulse J enters
    # node and body with opposite signs (linear momentum exact), but the node's angular momentum
    # changes by x̄ × J (trapezoidal rule: x̄ the step's mean position) while the body receives
    # the moment about the end-of-step arm, which differs by half the step's relative
    # displacement, O(Δt); the projection onto the surface moves a node without momentum. Over
    # sustained contact that is O(Δt²) per step, O(Δt) in all, smooth in Δt: it halves with Δt.
    # The steps where a node enters or leaves contact make O(Δt) errors too, but their size
    # depends on where in the step the event falls, which changes with Δt (measured per halving
    # from 2e-7 s: ratios 1.5, 2.4, 1.4); so the per-halving test is on the sustained-contact
    # part, and the total is asked the same rate as a mean over three halvings.
    dts = (2e-7, 1e-7, 5e-8, 2.5e-8)
    sustained, total = [], []
    for dt in dts:
        ds, p, ang, changed = _oblique_run(dt)
        assert int(ds.contact_nodes.max()) > 3 and changed.sum() > 10
        assert np.abs(p - p[0]).max() < 1e-13 * np.abs(p[0]).max()
        step = np.diff(ang, axis=0)
        sustained.append(np.linalg.norm(step[~changed].sum(axis=0)))
        total.append(np.linalg.norm(ang - ang[0], axis=1).max() / np.linalg.norm(ang[0]))
    rates = [sustained[i] / sustained[i + 1] for i in range(len(dts) - 1)]
    assert min(rates) >= 1.8, (sustained, rates)
    mean_rate = (total[0] / total[-1]) ** (1 / (len(dts) - 1))
    assert mean_rate >= 1.8, (total, mean_rate)
    # and small, not only shrinking: a drift that halves with Δt could still be a gross error
    # in the momentum exchange (1.2e-7 of |L| measured at 2e-7 s, 1.1e-8 at 2.5e-8 s)
    assert max(total) < 1e-6, total


@pytest.mark.parametrize("integrator", ["central-difference", "phi"])
@pytest.mark.parametrize("n,end", [(31, 30e-6), (100, 12e-6)])
def test_symmetric_impact_no_spin(n, end, integrator):
    """Case 4: no field, no modulus scatter, central hit: ω stays exactly zero and the sphere
    stays on the axis (mirror-exact force assembly and exactly rounded reaction sums); the
    100×100 case is the paper's full grid. Both schemes: the paper's φ-scheme (its claim of
    machine precision) and the default central differences."""
    sc = _patch(n, **{"field.B": [0, 0, 0], "fabric.material.modulus_cv": 0.0,
                      "solver.end_time": end, "solver.integrator": integrator})
    ds = run(sc).history
    assert int(ds.contact_nodes.max()) >= 5
    assert float(np.abs(ds.angular_velocity).max()) == 0.0
    assert float(np.abs(ds.projectile_position[:, :2]).max()) == 0.0
    assert float(ds.tilt.max()) == 0.0


def _field_run(bx, end=25e-6):
    sc = _patch(31, **{"field.B": [bx, 0, 0], "fabric.material.modulus_cv": 0.0,
                       "solver.end_time": end, "solver.adaptive": False, "solver.dt_max": 1e-7,
                       "solver.tolerance": 1e-9, "solver.max_iterations": 60})
    return run(sc).history


def test_sense_of_field_induced_spin():
    """B = +B e_x, sphere moving −z: contact nodes move −z, so q v × B = −qVB e_y pushes the
    fabric towards −y; friction drags the sphere's lower surface (r = −R e_z) towards −y, a
    moment (−R e_z) × (−F e_y) = −R F e_x: ω_x < 0. Reversing B mirrors the run in y exactly:
    ω_x and ω_z change sign, ω_y does not."""
    a = _field_run(0.05)
    b = _field_run(-0.05)
    wa, wb = a.angular_velocity.values, b.angular_velocity.values
    assert wa[-1, 0] < 0 and abs(wa[-1, 0]) > 10 * abs(wa[-1, 1])
    assert float(a.fabric_momentum[-1, 1]) < 0  # the fabric is pushed towards −y
    np.testing.assert_array_equal(wb[:, 0], -wa[:, 0])
    np.testing.assert_array_equal(wb[:, 1], wa[:, 1])
    np.testing.assert_array_equal(wb[:, 2], -wa[:, 2])


def test_energy_budget_closes_with_the_scheme():
    """Every energy term is computed on its own; the balance error is the scheme's own
    discretisation error: small (under 1e-3 of the energy exchanged at the default step; 8e-5
    measured) and second order (a quarter at half the step: 4.2× measured), the dissipations
    never negative along the run."""
    def err(courant):
        ds = run(_patch(31, **{"solver.end_time": 30e-6, "solver.courant": courant})).history
        exchanged = float(ds.kinetic_energy_projectile[0] - ds.kinetic_energy_projectile[-1])
        for term in ("dissipation_friction", "dissipation_contact", "dissipation_damage"):
            assert float(ds[term].min()) >= 0.0, term
        assert exchanged > 5.0
        return abs(float(ds.energy_balance_error[-1])) / exchanged

    coarse = err(0.25)  # the default step
    fine = err(0.125)
    assert coarse < 1e-3
    assert coarse / fine > 3.0, (coarse, fine)


def test_contact_force_is_the_momentum_the_fabric_gives():
    """No field, no gravity: the projectile's momentum changes only by the contact impulses, so
    Σ contact_force·Δt over the steps equals M (v_end − v_0) (eq. 4.12 with ψ = 0); yaw starts
    at 0 (the nose marker leads along the velocity) and stays an angle in [0, π]."""
    ds = run(_patch(21, **{"solver.end_time": 20e-6, "field.B": [0.0, 0.0, 0.0]})).history
    impulse = (ds.contact_force.values[1:] * ds.dt.values[1:, None]).sum(axis=0)
    dp = 0.037 * (ds.projectile_velocity.values[-1] - ds.projectile_velocity.values[0])
    np.testing.assert_allclose(impulse, dp, rtol=1e-9, atol=1e-12 * np.abs(dp).max())
    assert np.abs(dp).max() > 1e-3  # the sphere was really braked
    assert ds.attrs and ds.contact_force.attrs["units"] == "N"
    assert float(ds.yaw[0]) == 0.0
    assert (ds.yaw.values >= 0).all() and (ds.yaw.values <= np.pi).all()


def test_axis_sets_the_initial_yaw():
    """projectile.axis gives the nose direction at t = 0: yaw(0) is its angle to the velocity."""
    ds = run(_patch(11, **{"solver.end_time": 1e-6, "projectile.axis": [1.0, 0.0, -1.0]})).history
    assert float(ds.yaw[0]) == pytest.approx(np.pi / 4, rel=1e-12)
    assert float(ds.tilt[0]) == 0.0


def test_default_settings_give_the_converged_spin():
    """The field-induced spin at the default solver settings (central differences) against the same
    impact by the φ-scheme at a Δt of 2e-8 s and tolerance 1e-9 (the spin converges at first
    order in Δt, so the fine run is within a few tenths of a percent of the limit): the
    default's ω_x(t) stays within 4 % of the peak. On this 40 × 40 version of paper-field,
    contact.placement = "closest-point" (sticking nodes left at the closest point of their
    free-flight position, lagging the surface) is 21 % off."""
    from emfabric.config.scenario import load_scenario

    base = {"fabric.nodes": [40, 40], "solver.end_time": 3e-4}
    default = run(load_scenario("paper-field", base)).history
    fine = run(load_scenario("paper-field", {**base, "solver.dt_max": 2e-8,
                                             "solver.tolerance": 1e-9})).history
    w, wf = default.angular_velocity.values[:, 0], fine.angular_velocity.values[:, 0]
    peak = np.abs(wf).max()
    assert peak > 1000.0  # the field spins the sphere
    err = np.abs(w - np.interp(default.time.values, fine.time.values, wf)).max()
    assert err < 0.04 * peak, err / peak
    # the paper's placement, kept available: its O(Δt) lag shows at the default Δt
    paper = run(load_scenario("paper-field", {**base, "solver.integrator": "phi",
                                              "contact.placement": "closest-point"}))
    wp = paper.history.angular_velocity.values[:, 0]
    err = np.abs(wp - np.interp(paper.history.time.values, fine.time.values, wf)).max()
    assert err > 0.1 * peak, err / peak
