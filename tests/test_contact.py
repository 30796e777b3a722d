"""Contact and friction as impulses (section 4): projection, stick, Coulomb slip, no moment."""

import numpy as np
import pytest

from emfabric._kernels.contact import node_contact
from emfabric._kernels.records import (
    BODY_R0,
    BODY_ROWS,
    BODY_V,
    BODY_W,
    BODY_X,
    SHAPE_SPHERE,
    Body,
    Contact,
    Nodes,
    make_work,
)
from emfabric._kernels.step import _reaction_sums

R = 0.02


def _contact(x_node, v_node, centre=(0, 0, 0), vel=(0, 0, 0), omega=(0, 0, 0), mu_s=1.0,
             mu_d=0.95, mass=1e-6):
    x1 = np.array(x_node, dtype=float).reshape(3, 1).copy()
    v1 = np.array(v_node, dtype=float).reshape(3, 1).copy()
    x0 = x1.copy()
    nodes = Nodes(1, 1, x0.copy(), np.array([mass]), np.array([1 / mass]), np.zeros(1))
    body = Body(True, SHAPE_SPHERE, R, 1.0, np.eye(3), np.zeros((0, 3)), np.zeros(0),
                np.zeros(3))
    state = np.zeros((BODY_ROWS, 3))
    state[BODY_X], state[BODY_V], state[BODY_W] = centre, vel, omega
    state[BODY_R0:BODY_R0 + 3] = np.eye(3)
    work = make_work(1, 1)
    work.cand[0] = 0
    work.err_rows[:] = 0.0
    nc = node_contact(nodes, body, Contact(mu_s, mu_d), state, 1, x1, v1, work)
    f = np.zeros(3)
    m = np.zeros(3)
    _reaction_sums(nc, work.c_imp, work.c_arm, work.sum_buf, f, m)
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
    """Stick uses v_cm + ω × r (eq. 4.9): a spinning body drags the node sideways."""
    omega = np.array([0.0, 0.0, 1000.0])
    # node on the −x side of a body moving −x at 10 m/s; the surface there moves −20 m/s along y
    nc, x, v, j, f, m = _contact([-0.019, 0, 0], [0, 0, 0], omega=omega, vel=(-10.0, 0, 0))
    surface = np.array([-10.0, 0, 0]) + np.cross(omega, [-R, 0, 0])
    assert surface[1] == pytest.approx(-20.0)
    # normal demand 10 m/s, tangential 20 m/s > μ_s·10: it slides with 0.95·10 m/s along −y
    np.testing.assert_allclose(v, [-10.0, -9.5, 0.0], rtol=1e-13, atol=1e-12)
    # the body is braked in spin: moment about +z is negative
    assert m[2] < 0
