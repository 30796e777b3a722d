"""Rigid projectile: torque-free rotation (B1–B18), charged bodies (section 6, eqs. 6.2–6.14)."""

import numpy as np
import pytest

from emfabric._kernels.body import field_wrench
from emfabric._kernels.records import BODY_R0, BODY_ROWS, BODY_V, BODY_W, SHAPE_SPHERE, Body, Field
from emfabric.integrators import Integrator
from emfabric.sim.builder import build_model
from emfabric.sim.state import initial_state

from conftest import make


def _free_body(**kw):
    """A body far above a fixed 2×2 patch: nothing touches it."""
    return make(**{"fabric.nodes": [2, 2], "fabric.size": [0.01, 0.01],
                   "projectile.position": [0.0, 0.0, 1.0], "projectile.velocity": [0, 0, 0],
                   "field.B": [0, 0, 0], **kw})


def _spin(dt, steps, omega0):
    sc = _free_body(**{"projectile.principal_inertia": [1e-5, 2e-5, 3e-5],
                       "projectile.angular_velocity": omega0, "solver.adaptive": False,
                       "solver.dt_max": dt, "solver.tolerance": 1e-13,
                       "solver.max_iterations": 50})
    model = build_model(sc)
    integ = Integrator(model)
    s, s2 = initial_state(model), initial_state(model)
    hist = []
    for _ in range(steps):
        integ.step(s, s2)
        s, s2 = s2, s
        rot = s.body_rotation
        inertia = rot @ np.diag([1e-5, 2e-5, 3e-5]) @ rot.T  # B15
        w = s.body_omega
        hist.append((inertia @ w, 0.5 * w @ inertia @ w, s.body_rotation.T @ w))
    return hist


def test_torque_free_asymmetric_body():
    """Three distinct principal moments, no torque: angular momentum and kinetic energy are
    conserved, and a spin about the intermediate axis is unstable (it flips)."""
    omega0 = [1e-3, 200.0, 1e-3]
    hist = _spin(1e-4, 2500, omega0)
    h0 = np.array([1e-5 * 1e-3, 2e-5 * 200.0, 3e-5 * 1e-3])
    e0 = 0.5 * (1e-5 * 1e-6 + 2e-5 * 200.0**2 + 3e-5 * 1e-6)
    h = np.array([x[0] for x in hist])
    e = np.array([x[1] for x in hist])
    wb = np.array([x[2] for x in hist])
    assert np.abs(h - h0).max() / np.linalg.norm(h0) < 1e-9
    drift = np.abs(e - e0).max() / e0
    assert drift < 1e-3
    # intermediate-axis instability: the body-frame ω_y reverses, growth ~ exp(115 t)
    assert wb[:, 1].min() < -0.9 * 200.0
    # energy drift is a discretisation error: second order in Δt
    hist2 = _spin(0.5e-4, 5000, omega0)
    drift2 = np.abs(np.array([x[1] for x in hist2]) - e0).max() / e0
    assert drift / drift2 > 3.0


def _four_charges(q, radius):
    return np.array([[radius, 0, 0], [0, radius, 0], [-radius, 0, 0], [0, -radius, 0]]), q


def _wrench(pos, q, v, w, rot, e, b):
    """field_wrench of a massless body with charges q at pos (body frame), centre at 0."""
    body = Body(True, SHAPE_SPHERE, 0.02, 0.0, np.eye(3), np.asarray(pos, float),
                np.asarray(q, float), np.zeros(3))
    fld = Field(np.asarray(e, float), np.asarray(b, float), 0, 0.0, np.zeros(3))
    state = np.zeros((BODY_ROWS, 3))
    state[BODY_V], state[BODY_W], state[BODY_R0:BODY_R0 + 3] = v, w, rot
    f, m = np.zeros(3), np.zeros(3)
    field_wrench(body, fld, 0.0, state, f, m)
    return f, m


def _direct(pos, q, v, w, e, b):
    """Eqs. 6.3–6.4 summed by hand."""
    force = np.zeros(3)
    moment = np.zeros(3)
    for r, qi in zip(pos, q, strict=True):
        psi = qi * (e + np.cross(v + np.cross(w, r), b))
        force += psi
        moment += np.cross(r, psi)
    return force, moment


@pytest.mark.parametrize("seed", range(5))
def test_charged_body_wrench_equals_direct_sums(seed):
    """The code's field force and moment equal the direct sums (6.3)–(6.6) for random input."""
    rng = np.random.default_rng(seed)
    pos = rng.normal(size=(6, 3)) * 0.02
    q = rng.normal(size=6)
    v, w, e, b = (rng.normal(size=3) * s for s in (100, 1e3, 1e3, 0.1))
    rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    f, m = _wrench(pos, q, v, w, rot, e, b)
    fd, md = _direct(pos @ rot.T, q, v, w, e, b)
    np.testing.assert_allclose(f, fd, rtol=1e-12, atol=1e-12 * np.abs(fd).max())
    np.testing.assert_allclose(m, md, rtol=1e-12, atol=1e-12 * np.abs(md).max())


@pytest.mark.parametrize("seed", range(5))
def test_four_charge_closed_forms(seed):
    """Eqs. 6.9–6.12 and 6.14 agree with the direct sums; the printed 6.13 does not, and the
    corrected form M = v_o R ((q1 − q3) B_x + (q2 − q4) B_y) k does."""
    rng = np.random.default_rng(100 + seed)
    radius, v0, w0 = 0.013, 250.0, 1e4
    q = rng.normal(size=4)
    q1, q2, q3, q4 = q
    ex, ey, ez = e = rng.normal(size=3) * 1e3
    bx, by, bz = b = rng.normal(size=3) * 0.1
    pos, _ = _four_charges(q, radius)
    k = np.array([0, 0, 1.0])
    i, j = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    f, m = _wrench(pos, q, v0 * k, w0 * k, np.eye(3), e, b)
    f_e = e * q.sum()  # 6.9
    f_lin = (-by * v0 * i + bx * v0 * j) * q.sum()  # 6.10
    f_rot = ((q1 - q3) * (bz * w0 * radius * i - bx * w0 * radius * k)
             + (q2 - q4) * (bz * w0 * radius * j - by * w0 * radius * k))  # 6.11
    m_e = radius * ez * ((q2 - q4) * i + (q3 - q1) * j) + radius * (
        ey * (q1 - q3) + ex * (q4 - q2)) * k  # 6.12
    m_lin_printed = v0 * radius * ((q3 - q1) * by * i + (q2 - q4) * bx * j)  # 6.13 as printed
    m_lin = v0 * radius * ((q1 - q3) * bx + (q2 - q4) * by) * k  # 6.13 corrected
    m_rot = w0 * radius**2 * (-(q2 + q4) * by * i + (q1 + q3) * bx * j)  # 6.14
    scale_f, scale_m = np.abs(f).max(), np.abs(m).max()
    np.testing.assert_allclose(f, f_e + f_lin + f_rot, rtol=0, atol=1e-12 * scale_f)
    np.testing.assert_allclose(m, m_e + m_lin + m_rot, rtol=0, atol=1e-12 * scale_m)
    assert np.abs(m - (m_e + m_lin_printed + m_rot)).max() > 1e-3 * scale_m


def test_free_charged_body_accelerates_in_E():
    """Four equal charges in uniform E: V(t) = (Σq) E t / M and no rotation (observation 3)."""
    charges = [{"position": p, "charge": 0.5} for p in
               ([0.02, 0, 0], [0, 0.02, 0], [-0.02, 0, 0], [0, -0.02, 0])]
    sc = _free_body(**{"projectile.charges": charges, "field.E": [100.0, 0.0, -50.0],
                       "solver.adaptive": False, "solver.dt_max": 1e-4})
    model = build_model(sc)
    integ = Integrator(model)
    s, s2 = initial_state(model), initial_state(model)
    for _ in range(30):
        integ.step(s, s2)
        s, s2 = s2, s
    np.testing.assert_allclose(s.body_v, 2.0 * np.array([100.0, 0, -50.0]) * s.t / 0.037,
                               rtol=1e-12)
    assert np.abs(s.body_omega).max() < 1e-12


def _update_spinning(dt, omega0, tol=1e-12):
    """One body_update of a free body with three distinct principal moments, no field, no
    contact: (ω after it, the angular momentum Ī(t+Δt)·ω, the one before, converged)."""
    from emfabric._kernels.body import body_update

    inertia = np.diag([1e-5, 2e-5, 3e-5])
    body = Body(True, SHAPE_SPHERE, 0.01, 1.0, inertia, np.zeros((0, 3)), np.zeros(0),
                np.zeros(3))
    fld = Field(np.zeros(3), np.zeros(3), 0, 0.0, np.zeros(3))
    b_in = np.zeros((BODY_ROWS, 3))
    b_in[BODY_W] = omega0
    b_in[BODY_R0:BODY_R0 + 3] = np.eye(3)
    b_out = b_in.copy()
    _num, _den, ok = body_update(body, fld, b_in, b_out, dt, 0.5, dt, np.zeros((2, 3)),
                                 np.zeros((7, 3)), tol)
    rot = b_out[BODY_R0:BODY_R0 + 3]
    w = b_out[BODY_W].copy()
    return w, rot @ inertia @ rot.T @ w, inertia @ np.asarray(omega0), ok


def test_body_update_conserves_angular_momentum_and_says_when_it_did_not_converge():
    """Torque-free: the body update's rotation (B3–B16) keeps Ī·ω = H exactly to its tolerance
    when its fixed point converges; where it cannot (tens of radians in one step) it
    says so instead of returning its last iterate silently."""
    w0 = [150.0, 200.0, 100.0]
    w, h, h0, ok = _update_spinning(1e-4, w0)
    assert ok
    assert np.abs(h - h0).max() <= 1e-10 * np.linalg.norm(h0)
    assert np.abs(w - w0).max() > 1.0  # Ī turned with the body: ω changed, H did not
    # a rotation of |ω|Δt ≈ 27 rad in one step: the fixed point ω = Ī(ω)⁻¹H does not contract
    *_rest, ok = _update_spinning(0.1, w0)
    assert not ok
