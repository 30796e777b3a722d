"""MODEL §8 case 6: longitudinal pulses along a yarn line (lumped network speed)."""

import math

import numpy as np
from scipy.optimize import brentq
from scipy.special import itairy

from emfabric.integrators import Integrator
from emfabric.sim.builder import build_model
from emfabric.sim.state import initial_state, update_forces

from conftest import fabric_only

H = 0.002  # node spacing [m]


def _chain(nx, v_split, ny=2, dt=2e-8):
    """A free nx × ny strip whose left half moves at −v and right half at +v (along x)."""
    sc = fabric_only(**{"fabric.nodes": [nx, ny], "fabric.size": [(nx - 1) * H, (ny - 1) * H],
                        "fabric.edges": "free", "solver.adaptive": False, "solver.dt_max": dt,
                        "solver.tolerance": 1e-10})
    model = build_model(sc)
    s = initial_state(model)
    i = np.arange(model.node_count) % nx
    s.node_v[0] = np.where(i < nx // 2, -v_split, v_split)
    update_forces(model, s)
    return sc, model, s


def _airy_half() -> float:
    """ξ with ∫_ξ^∞ Ai = 1/2: where a dispersive step front of the chain reaches half its jump."""
    # itairy(a)[2] = ∫_0^a Ai(−t) dt = ∫_{−a}^0 Ai, and ∫_0^∞ Ai = 1/3
    return -brentq(lambda a: itairy(a)[2] - 1.0 / 6.0, 0.0, 2.0)


def test_tensile_pulse_speed():
    """MODEL §8.6: a tension front runs at c = c_yarn/√2 · h/√(area per node), c_yarn = √(𝔼/ρ)."""
    nx, ny, v = 161, 5, 1.0
    sc, model, s = _chain(nx, v, ny)
    # expected speed from the inputs alone: each yarn family puts A0/h of fibre volume on a unit
    # of sheet, so the fibre density is ρ = ρ_A h / (2 A0) and a yarn's bar speed √(𝔼/ρ); two
    # families share each node's mass, so a node carries twice the mass one yarn line would give
    # it: c = h √(k/m) = √(𝔼 A0 h / m_node) = c_yarn/√2 when m_node = ρ_A h² (MODEL §1 spreads
    # the sheet's mass over all nx·ny nodes: area per node Lx Ly/(nx ny), a bit less than h²)
    fab = sc.fabric
    a0 = math.pi * fab.yarn_radius**2
    rho = fab.areal_density * H / (2.0 * a0)
    c_yarn = math.sqrt(fab.material.youngs_modulus / rho)
    area = fab.size[0] * fab.size[1] / (nx * ny)
    c = c_yarn / math.sqrt(2.0) * H / math.sqrt(area)
    # the lumped chain is dispersive (ω = 2√(k/m) sin(qh/2) ≈ cq − c h² q³/24): the front is an
    # Airy function of (x − ct)/λ, λ = (c h² t/8)^(1/3), and reaches half its jump |ξ|λ behind
    # x = ct (0.7 h at 40 spacings); the front started between columns nx/2 − 1 and nx/2
    xi = _airy_half()
    integ = Integrator(model)
    s2 = s.copy()
    dists = (20, 40, 60)  # spacings from the split to the watched node (plus the half spacing)
    arrival = {}
    while len(arrival) < len(dists):
        v_before, t_before = s.node_v[0].copy(), s.t
        integ.step(s, s2)
        s, s2 = s2, s
        for d in dists:
            col = nx // 2 - 1 - d
            # the front has passed once the node has lost half its outward velocity −v
            if d not in arrival and s.node_v[0, col] > -v / 2:
                frac = (-v / 2 - v_before[col]) / (s.node_v[0, col] - v_before[col])
                arrival[d] = t_before + frac * (s.t - t_before)
        assert s.t < 1e-4
    for d in dists:
        x, ct = (d + 0.5) * H, c * arrival[d]
        lam = (ct * H**2 / 8.0) ** (1.0 / 3.0)
        # within a tenth of a spacing of the dispersive front (c off by 0.3 % would show at 60 h)
        assert abs(ct + xi * lam - x) < 0.1 * H, (d, (ct + xi * lam - x) / H)
        # and within one spacing of the non-dispersive x = ct (MODEL: "a few grid spacings")
        assert 0.0 < ct - x < H, (d, (ct - x) / H)


def test_compression_does_not_propagate():
    """Two halves pushed together: the relaxed law carries no compression, so far nodes keep
    their velocity."""
    nx, v = 60, 5.0
    _sc, model, s = _chain(nx, -v)
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
