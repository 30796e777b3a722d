"""MODEL §8 case 6: longitudinal pulses along a yarn line (lumped network speed)."""

import math

import numpy as np

from emfabric.integrators import Integrator
from emfabric.sim.builder import build_model
from emfabric.sim.state import initial_state, update_forces

from conftest import fabric_only


def _chain(nx, v_split, dt=2e-8):
    """A free 2-row strip whose left half moves at −v and right half at +v (along x)."""
    sc = fabric_only(**{"fabric.nodes": [nx, 2], "fabric.size": [(nx - 1) * 0.002, 0.002],
                        "fabric.edges": "free", "solver.adaptive": False, "solver.dt_max": dt,
                        "solver.tolerance": 1e-10})
    model = build_model(sc)
    s = initial_state(model)
    i = np.arange(model.node_count) % nx
    s.node_v[0] = np.where(i < nx // 2, -v_split, v_split)
    update_forces(model, s)
    return model, s


def test_tensile_pulse_speed():
    """A tension front travels at h·sqrt(k/m) = sqrt(𝔼 A0 h / m_node) along the yarn."""
    nx, v = 120, 5.0
    model, s = _chain(nx, v)
    integ = Integrator(model)
    s2 = s.copy()
    h = 0.002
    k = model.yarns.modulus[0] * model.yarns.area / h
    c = h * math.sqrt(k / model.nodes.mass[0])
    arrival = {}
    watch = [nx // 2 - 1 - d for d in (10, 20, 30, 40)]
    t = 0.0
    while len(arrival) < len(watch):
        integ.step(s, s2)
        s, s2 = s2, s
        t = s.t
        for col in watch:
            # the front has passed when the node has lost half its outward velocity
            if col not in arrival and s.node_v[0, col] > -v / 2:
                arrival[col] = t
        assert t < 1e-4
    cols = np.array(watch, dtype=float)
    times = np.array([arrival[cc] for cc in watch])
    speed = -np.polyfit(times, cols * h, 1)[0]
    assert abs(speed - c) / c < 0.03, (speed, c)
    # the lumped speed is ≈ sqrt(𝔼/ρ)/√2 of the solid with density ρ = m/(A0 h) on each family
    rho = model.nodes.mass[0] / (model.yarns.area * h)
    assert math.isclose(c, math.sqrt(model.yarns.modulus[0] / rho), rel_tol=1e-12)


def test_compression_does_not_propagate():
    """Two halves pushed together: the relaxed law carries no compression, so far nodes keep
    their velocity."""
    nx, v = 60, 5.0
    model, s = _chain(nx, -v)
    integ = Integrator(model)
    s2 = s.copy()
    for _ in range(200):
        integ.step(s, s2)
        s, s2 = s2, s
    left = s.node_v[0, : nx // 2 - 2]
    # unchanged up to round-off strains of rigidly translating segments (a tension front would
    # change them by O(v) within 200 steps: it travels ~60 spacings)
    assert np.allclose(left, v, rtol=0, atol=1e-9 * v)
    assert float(np.abs(s.node_v[1:]).max()) == 0.0
