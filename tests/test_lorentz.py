"""MODEL §8 cases 1 and 2: charged nodes in uniform fields (closed forms)."""

import math

import numpy as np
import pytest

from emfabric.integrators import Integrator
from emfabric.runner.loop import run
from emfabric.sim.builder import build_model
from emfabric.sim.state import initial_state

from conftest import fabric_only


def _free_sheet(n=2, **kw):
    # a rigid sheet: every node gets the same velocity, so no yarn ever stretches; soft yarns
    # keep the fixed-point iteration contracting at these millisecond steps
    return fabric_only(**{
        "fabric.nodes": [n, n], "fabric.size": [0.1, 0.1], "fabric.edges": "free",
        "fabric.areal_density": 0.04, "fabric.material.youngs_modulus": 1.0,
        "solver.adaptive": False, **kw,
    })


def _march(sc, steps):
    model = build_model(sc)
    integ = Integrator(model)
    s, s2 = initial_state(model), initial_state(model)
    for _ in range(steps):
        integ.step(s, s2)
        s, s2 = s2, s
    return model, s


@pytest.mark.parametrize("dt", [2e-3, 1e-3])
def test_gyration_in_uniform_B(dt):
    """A charged node in uniform B gyrates at ω_c = qB/m: speed exact, phase error O((ω_c Δt)²)."""
    sc = _free_sheet(**{"fabric.velocity": [3.0, 0.0, 0.0], "field.B": [0.0, 0.0, 0.01],
                        "fabric.charge_per_node": 1.0, "solver.dt_max": dt})
    steps = round(0.2 / dt)
    model, s = _march(sc, steps)
    m, q, b = model.nodes.mass[0], 1.0, 0.01
    wc = q * b / m  # 100 rad/s
    v = s.node_v[:, 0]
    # the midpoint (Cayley) update preserves |v| exactly
    assert np.linalg.norm(v) == pytest.approx(3.0, rel=1e-12)
    # velocity rotates clockwise about +z for q > 0: v = 3 (cos θ, −sin θ, 0); the midpoint
    # rule turns it by exactly 2·atan(ω_c Δt / 2) per step
    t = steps * dt
    theta = steps * 2 * math.atan(wc * dt / 2)
    assert np.allclose(v, [3 * math.cos(theta), -3 * math.sin(theta), 0.0], atol=1e-9)
    # ... which converges to ω_c t at second order
    assert 0 < wc * t - theta < wc * t * (wc * dt) ** 2 / 12 * 1.01
    # the guiding centre stays put and the radius is v/ω_c: the discrete orbit is the exact
    # circle (chord Δt·|v̄| = 2 r sin(θ/2) with tan(θ/2) = ω_c Δt/2)
    centre = s.node_x[:2, 0] + np.array([v[1], -v[0]]) / wc
    x0 = model.nodes.x0[:2, 0] + np.array([0.0, -3.0 / wc])
    assert np.allclose(centre, x0, rtol=0, atol=1e-12)


def test_uniform_E_gives_linear_momentum_growth():
    """A charged node in uniform E: p(t) = qEt exactly (constant force)."""
    sc = _free_sheet(**{"field.E": [2.0, -1.0, 0.5], "solver.dt_max": 1e-3})
    model, s = _march(sc, 50)
    p = model.nodes.mass[0] * s.node_v[:, 0]
    assert np.allclose(p, np.array([2.0, -1.0, 0.5]) * 1.0 * s.t, rtol=1e-12, atol=0)
    # uniform acceleration: x − x0 = qE t² / (2m), exact for the trapezoidal rule
    dx = s.node_x[:, 0] - model.nodes.x0[:, 0]
    assert np.allclose(dx, np.array([2.0, -1.0, 0.5]) * s.t**2 / (2 * model.nodes.mass[0]),
                       rtol=1e-12, atol=0)


def test_free_fabric_rotates_rigidly_in_B():
    """Case 2: a free 6×6 sheet moving in its plane in B ⟂ sheet: COM velocity turns at qB/m,
    and no yarn is strained."""
    sc = _free_sheet(n=6, **{"fabric.velocity": [0.0, 2.0, 0.0], "field.B": [0.0, 0.0, 0.02],
                             "solver.dt_max": 5e-4, "solver.end_time": 0.1,
                             "solver.tolerance": 1e-10})
    res = run(sc)
    ds = res.history
    m_total = res.model.nodes.mass.sum()
    vc = ds.fabric_momentum.values / m_total
    speed = np.linalg.norm(vc, axis=1)
    assert np.allclose(speed, 2.0, rtol=1e-10)
    wc = 1.0 * 0.02 / res.model.nodes.mass[0]
    turned = np.unwrap(np.arctan2(vc[:, 1], vc[:, 0]) - math.pi / 2)
    t = ds.time.values
    dt = 5e-4
    assert np.allclose(-turned, t / dt * 2 * np.arctan(wc * dt / 2), atol=1e-8)
    assert float(ds.max_stretch.max()) - 1.0 < 1e-12
    assert float(ds.strain_energy.max()) < 1e-20
