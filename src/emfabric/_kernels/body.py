"""Rigid body update inside the fixed-point loop: translation (4.12–4.13), rotation (B1–B18)."""


from numba import njit

from emfabric._kernels.fields import field_at, lorentz_force
from emfabric._kernels.records import BODY_F, BODY_M, BODY_R0, BODY_V, BODY_W, BODY_X
from emfabric._kernels.shapes import bounding_radius
from emfabric._kernels.vec3 import (
    cross,
    mat_mul,
    mat_vec,
    norm,
    rotation_increment,
    vec,
    world_inertia_solve,
    world_inertia_times,
)


@njit(cache=True, _nrt=True)
def field_wrench(body, fld, t, b_state, force, moment):
    """Force and moment about the centre of mass of the body's charges (6.2–6.6) and gravity,
    for the body state b_state (BODY_ROWS, 3) at time t."""
    grav = fld.gravity
    centre = b_state[BODY_X]
    vel = b_state[BODY_V]
    rot = b_state[BODY_R0:BODY_R0 + 3]
    for c in range(3):
        force[c] = body.mass * grav[c]
        moment[c] = 0.0
    w = vec(b_state[BODY_W])
    for k in range(body.charge.shape[0]):
        r = mat_vec(rot, body.charge_pos[k])
        e, b = field_at(fld, (centre[0] + r[0], centre[1] + r[1], centre[2] + r[2]), t)
        # velocity of the charged point, eq. 6.1
        wr = cross(w, r)
        vp = (vel[0] + wr[0], vel[1] + wr[1], vel[2] + wr[2])
        psi = lorentz_force(body.charge[k], e, b, vp)
        rp = cross(r, psi)
        for c in range(3):
            force[c] += psi[c]
            moment[c] += rp[c]


BODY_ITERATION_LIMIT = 100
"""Iterations of the rotation's fixed point (eq. B16) within one body update."""


@njit(cache=True, _nrt=True)
def body_update(body, fld, b_in, b_out, t1, phi, dt, reaction, scratch, tol):
    """One fixed-point update of the body from the previous iterate in b_out, at time t1, with
    the contact reaction (2, 3) (impulse [N s] and its moment [N m s]) taken whole; scratch:
    Work.body_scratch (nothing is allocated).

    Returns the body's error-measure numerator and denominator [m] (displacement units) and
    whether the rotation's own iteration (eq. B16) met `tol` within BODY_ITERATION_LIMIT.
    """
    mass = body.mass
    inertia_body = body.inertia
    imp_force = reaction[0]
    imp_moment = reaction[1]
    x0 = b_in[BODY_X]
    v0 = b_in[BODY_V]
    w0 = b_in[BODY_W]
    rot0 = b_in[BODY_R0:BODY_R0 + 3]
    xk = vec(b_out[BODY_X])
    wk = vec(b_out[BODY_W])
    # the field's force and moment at the previous iterate, written in place (field_wrench
    # reads the position, velocity and rotation rows only)
    f1 = b_out[BODY_F]
    m1 = b_out[BODY_M]
    field_wrench(body, fld, t1, b_out, f1, m1)
    # translation, eqs. 4.12–4.13, with the contact impulses taken whole
    v1 = (v0[0] + dt / mass * (phi * f1[0] + (1.0 - phi) * b_in[BODY_F, 0]) + imp_force[0] / mass,
          v0[1] + dt / mass * (phi * f1[1] + (1.0 - phi) * b_in[BODY_F, 1]) + imp_force[1] / mass,
          v0[2] + dt / mass * (phi * f1[2] + (1.0 - phi) * b_in[BODY_F, 2]) + imp_force[2] / mass)
    x1 = (x0[0] + dt * (phi * v1[0] + (1.0 - phi) * v0[0]),
          x0[1] + dt * (phi * v1[1] + (1.0 - phi) * v0[1]),
          x0[2] + dt * (phi * v1[2] + (1.0 - phi) * v0[2]))
    # rotation, eqs. B3–B6 in the inertial frame: H1 = I0·ω0 + Δt·M(t+φΔt) + contact moments
    h0 = world_inertia_times(rot0, inertia_body, w0)
    mo = b_in[BODY_M]
    h1 = (h0[0] + dt * (phi * m1[0] + (1.0 - phi) * mo[0]) + imp_moment[0],
          h0[1] + dt * (phi * m1[1] + (1.0 - phi) * mo[1]) + imp_moment[1],
          h0[2] + dt * (phi * m1[2] + (1.0 - phi) * mo[2]) + imp_moment[2])
    w = wk
    inc = scratch[0:3]
    solve_scratch = scratch[3:7]
    # the new rotation is written into b_out's rows at once (the previous iterate's rotation
    # was read by field_wrench above and is not needed again)
    rot1 = b_out[BODY_R0:BODY_R0 + 3]
    converged = False
    for _ in range(BODY_ITERATION_LIMIT):
        # axis at t + φΔt, eq. B8; inertia rotated with the body, eq. B15
        theta = (dt * (phi * w[0] + (1.0 - phi) * w0[0]), dt * (phi * w[1] + (1.0 - phi) * w0[1]),
                 dt * (phi * w[2] + (1.0 - phi) * w0[2]))
        rotation_increment(theta, inc)
        mat_mul(inc, rot0, rot1)
        w_new = world_inertia_solve(rot1, inertia_body, h1, solve_scratch)
        change = norm((w_new[0] - w[0], w_new[1] - w[1], w_new[2] - w[2]))
        w = w_new
        # eq. B16
        if change <= tol * norm(w):
            converged = True
            break
    theta = (dt * (phi * w[0] + (1.0 - phi) * w0[0]), dt * (phi * w[1] + (1.0 - phi) * w0[1]),
             dt * (phi * w[2] + (1.0 - phi) * w0[2]))
    rotation_increment(theta, inc)
    mat_mul(inc, rot0, rot1)
    for c in range(3):
        b_out[BODY_X, c] = x1[c]
        b_out[BODY_V, c] = v1[c]
        b_out[BODY_W, c] = w[c]
    # error measure in displacement units: the centre plus a surface point at the bounding radius
    arm = bounding_radius(body)
    num = (norm((x1[0] - xk[0], x1[1] - xk[1], x1[2] - xk[2]))
           + arm * dt * phi * norm((w[0] - wk[0], w[1] - wk[1], w[2] - wk[2])))
    wm = (phi * w[0] + (1.0 - phi) * w0[0], phi * w[1] + (1.0 - phi) * w0[1],
          phi * w[2] + (1.0 - phi) * w0[2])
    den = norm((x1[0] - x0[0], x1[1] - x0[1], x1[2] - x0[2])) + arm * dt * norm(wm)
    return num, den, converged
