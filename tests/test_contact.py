"""Contact and friction as impulses (section 4): projection, stick, Coulomb slip, no moment."""

import numpy as np
import pytest

from emfabric._kernels.contact import node_contact, reaction_sums
from emfabric._kernels.records import (
    BODY_R0,
    BODY_ROWS,
    BODY_V,
    BODY_W,
    BODY_X,
    SHAPE_SPHERE,
    Body,
    Contact,
    grid_nodes,
    make_work,
)

R = 0.02


def _contact(x_node, v_node, centre=(0, 0, 0), vel=(0, 0, 0), omega=(0, 0, 0), mu_s=1.0,
             mu_d=0.95, mass=1e-6):
    x1 = np.array(x_node, dtype=float).reshape(3, 1).copy()
    v1 = np.array(v_node, dtype=float).reshape(3, 1).copy()
    x0 = x1.copy()
    nodes = grid_nodes(1, 1, x0.copy(), np.array([mass]), np.array([1 / mass]), np.zeros(1))
    body = Body(True, SHAPE_SPHERE, R, 1.0, np.eye(3), np.zeros((0, 3)), np.zeros(0),
                np.zeros(3))
    state = np.zeros((BODY_ROWS, 3))
    state[BODY_X], state[BODY_V], state[BODY_W] = centre, vel, omega
    state[BODY_R0:BODY_R0 + 3] = np.eye(3)
    work = make_work(1, 1, 0)
    work.cand[0] = 0
    work.row_sums[:] = 0.0
    nc = node_contact(nodes, body, Contact(mu_s, mu_d), state, 1, x1, v1, work, 0.0, 0.0,
                      False)
    f = np.zeros(3)
    m = np.zeros(3)
    reaction_sums(nc, work.c_imp, work.c_arm, work.sum_buf, f, m)
    return nc, x1[:, 0], v1[:, 0], work.c_imp[:, 0].copy() if nc else np.zeros(3), f, m


def test_inside_node_lands_on_surface():
    """A node inside the sphere is moved to the closest surface point (eq. 5.1)."""
    nc, x, v, j, f, m = _contact([0.003, -0.004, -0.012], [0, 0, 0])
    assert nc == 1
    assert np.linalg.norm(x) == pytest.approx(R, rel=1e-14)
    direction = np.array([0.003, -0.004, -0.012]) / np.linalg.norm([0.003, -0.004, -0.012])
    np.testing.assert_allclose(x, R * direction, rtol=1e-14)


def test_outside_node_untouched():
    """A node outside the sphere gets no impulse."""
    nc, x, v, j, f, m = _contact([0.0, 0.0, -0.021], [1.0, 0, 0])
    assert nc == 0 and np.all(v == [1.0, 0, 0])


def test_pure_normal_impulse_gives_no_moment():
    """A head-on impulse acts through the centre: the body gets −J and no moment."""
    nc, x, v, j, f, m = _contact([0.0, 0.0, -0.019], [0, 0, 0], vel=(0, 0, -250.0))
    assert np.allclose(v, [0, 0, -250.0])
    np.testing.assert_array_equal(f, -j)
    assert np.all(m == 0.0)


def test_stick_below_static_limit():
    """Tangential demand below μ_s·|J_n|: the node takes the surface point's velocity."""
    # surface moving down at 100 m/s and sideways at 50 m/s: |J_t| = 0.5 |J_n| < μ_s |J_n|
    nc, x, v, j, f, m = _contact([0, 0, -0.019], [0, 0, 0], vel=(50.0, 0, -100.0))
    np.testing.assert_allclose(v, [50.0, 0, -100.0], rtol=1e-14)
    np.testing.assert_array_equal(f, -j)
    # the friction impulse acts at the contact point r = −R e_z: moment r × (−J)
    np.testing.assert_allclose(m, np.cross([0, 0, -R], -j), rtol=1e-14, atol=0)
    # friction drags the bottom of a sphere moving +x backwards: it starts to roll, ω_y > 0
    assert m[1] > 0


def test_slip_above_static_limit():
    """Tangential demand above μ_s·|J_n|: slide with |J_t| = μ_d·|J_n| along the slip."""
    mass = 1e-6
    nc, x, v, j, f, m = _contact([0, 0, -0.019], [0, 0, 0], vel=(300.0, 0, -100.0), mu_s=1.0,
                                 mu_d=0.6, mass=mass)
    jn = mass * 100.0
    np.testing.assert_allclose(j, [0.6 * jn, 0.0, -jn], rtol=1e-14)
    assert v[2] == pytest.approx(-100.0)  # normal velocity matched
    assert v[0] == pytest.approx(60.0)  # slid: 0.6·100 m/s, not the 300 m/s of the surface


def test_separating_node_is_not_held():
    """A node inside but leaving faster than the surface gets no (pulling) impulse."""
    nc, x, v, j, f, m = _contact([0, 0, -0.019], [5.0, 0, -50.0], vel=(0, 0, -10.0))
    assert nc == 1 and np.all(j == 0.0) and np.all(v == [5.0, 0, -50.0])
    assert np.linalg.norm(x) == pytest.approx(R)


def test_spinning_surface_velocity():
    """The contact law takes the surface point's velocity v_cm + ω × r (eq. 4.9): a spinning
    body whose surface slips past the node faster than friction holds drags it sideways by
    μ_d times the normal velocity demand (a sliding contact; sticking to v_cm + ω × r is
    test_sticking_node_lands_where_its_phi_update_puts_it)."""
    omega = np.array([0.0, 0.0, 1000.0])
    # node on the −x side of a body moving −x at 10 m/s; the surface there moves −20 m/s along y
    nc, x, v, j, f, m = _contact([-0.019, 0, 0], [0, 0, 0], omega=omega, vel=(-10.0, 0, 0))
    surface = np.array([-10.0, 0, 0]) + np.cross(omega, [-R, 0, 0])
    assert surface[1] == pytest.approx(-20.0)
    # normal demand 10 m/s, tangential 20 m/s > μ_s·10: it slides with 0.95·10 m/s along −y
    np.testing.assert_allclose(v, [-10.0, -9.5, 0.0], rtol=1e-13, atol=1e-12)
    # the body is braked in spin: moment about +z is negative
    assert m[2] < 0


def test_sticking_node_lands_where_its_phi_update_puts_it():
    """With the step's φ and Δt, a node that sticks to a spinning sphere ends where the φ-update
    with its velocity after contact puts it, moved only along the surface normal:
    x1 − (x_trial + φΔt (v1 − v_trial)) ∥ n (to O(Δt|ω|)). Its velocity is the surface point's
    there, and the impulse recorded is m (v1 − v_trial). (Without the move along the velocity
    change the node lags the surface by φΔt J_t/m every step: an O(Δt) error in the spin.)"""
    m, phi, dt = 1e-6, 0.5, 1e-7
    x_trial = np.array([0.003, -0.004, -0.019])
    omega = np.array([0.0, 2000.0, 500.0])
    vel = np.array([0.0, 0.0, 40.0])
    # approaching the surface at 40 m/s, sliding along it at 5 m/s: μ_s = 1 holds it
    n0 = x_trial / np.linalg.norm(x_trial)
    tangent = np.cross(n0, [1.0, 0.0, 0.0])
    tangent /= np.linalg.norm(tangent)
    v_trial = vel + np.cross(omega, R * n0) - 40.0 * n0 + 5.0 * tangent
    x1 = x_trial.reshape(3, 1).copy()
    v1 = v_trial.reshape(3, 1).copy()
    nodes = grid_nodes(1, 1, x1.copy(), np.array([m]), np.array([1 / m]), np.zeros(1))
    body = Body(True, SHAPE_SPHERE, R, 1.0, np.eye(3), np.zeros((0, 3)), np.zeros(0),
                np.zeros(3))
    state = np.zeros((BODY_ROWS, 3))
    state[BODY_V], state[BODY_W] = vel, omega
    state[BODY_R0:BODY_R0 + 3] = np.eye(3)
    work = make_work(1, 1, 0)
    work.cand[0] = 0
    assert node_contact(nodes, body, Contact(1.0, 0.95), state, 1, x1, v1, work, phi, dt,
                        False) == 1
    x, v = x1[:, 0], v1[:, 0]
    n = x / np.linalg.norm(x)
    assert np.linalg.norm(x) == pytest.approx(R, rel=1e-14)
    np.testing.assert_allclose(v, vel + np.cross(omega, x), rtol=1e-12)
    np.testing.assert_allclose(work.c_imp[:, 0], m * (v - v_trial), rtol=1e-12)
    # (up to the surface velocity's change over the move, relative φΔt|ω| = 1e-4 here; the
    # closest point of x_trial alone would leave all of it: relative 1)
    off = x - (x_trial + phi * dt * (v - v_trial))
    along = phi * dt * (v - v_trial)
    along -= (along @ n) * n
    assert np.linalg.norm(off - (off @ n) * n) < 1e-3 * np.linalg.norm(along)
    # the move along the surface is what separates it from the closest point of x_trial
    moved = np.linalg.norm(x - R * x_trial / np.linalg.norm(x_trial))
    assert moved > 0.5 * phi * dt * np.linalg.norm((v - v_trial) - ((v - v_trial) @ n) * n)
    # the normal impulse passes through the centre: only friction turns the sphere
    f, mo = np.zeros(3), np.zeros(3)
    reaction_sums(1, work.c_imp, work.c_arm, work.sum_buf, f, mo)
    jt = work.c_imp[:, 0] - (work.c_imp[:, 0] @ n) * n
    np.testing.assert_allclose(mo, -np.cross(x, jt), rtol=1e-12, atol=1e-18)
