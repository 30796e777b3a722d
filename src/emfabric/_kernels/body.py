"""Rigid body update inside the fixed-point loop: translation (4.12–4.13), rotation (B1–B18)."""


import numpy as np
from numba import njit

from emfabric._kernels.nodes import in_field
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

X, V, W, F, M, R0 = 0, 1, 2, 3, 4, 5


@njit(cache=True)
def field_wrench(centre, vel, omega, rot, charge_pos, charge_q, efield, bfield, region, z0,
                 mass, grav, force, moment):
    """Force and moment about the centre of mass of the body's charges (6.2–6.6) and gravity."""
    for c in range(3):
        force[c] = mass * grav[c]
        moment[c] = 0.0
    w = vec(omega)
    e = vec(efield)
    b = vec(bfield)
    for k in range(charge_q.shape[0]):
        r = mat_vec(rot, charge_pos[k])
        if not in_field(centre[2] + r[2], region, z0):
            continue
        q = charge_q[k]
        # velocity of the charged point, eq. 6.1
        wr = cross(w, r)
        vp = (vel[0] + wr[0], vel[1] + wr[1], vel[2] + wr[2])
        vb = cross(vp, b)
        psi = (q * (e[0] + vb[0]), q * (e[1] + vb[1]), q * (e[2] + vb[2]))
        rp = cross(r, psi)
        for c in range(3):
            force[c] += psi[c]
            moment[c] += rp[c]


@njit(cache=True)
def body_update(b_in, b_out, inertia_body, mass, charge_pos, charge_q, efield, bfield, region,
                z0, grav, phi, dt, imp_force, imp_moment, tol, arm):
    """One fixed-point update of the body from the previous iterate in b_out.

    Returns the body's error-measure numerator and denominator [m] (displacement units).
    """
    x0 = b_in[X]
    v0 = b_in[V]
    w0 = b_in[W]
    rot0 = b_in[R0:R0 + 3]
    xk = vec(b_out[X])
    wk = vec(b_out[W])
    f1 = np.empty(3)
    m1 = np.empty(3)
    field_wrench(b_out[X], b_out[V], b_out[W], b_out[R0:R0 + 3], charge_pos, charge_q, efield,
                 bfield, region, z0, mass, grav, f1, m1)
    # translation, eqs. 4.12–4.13, with the contact impulses taken whole
    v1 = np.empty(3)
    x1 = np.empty(3)
    for c in range(3):
        v1[c] = v0[c] + dt / mass * (phi * f1[c] + (1.0 - phi) * b_in[F, c]) + imp_force[c] / mass
        x1[c] = x0[c] + dt * (phi * v1[c] + (1.0 - phi) * v0[c])
    # rotation, eqs. B3–B6 in the inertial frame: H1 = I0·ω0 + Δt·M(t+φΔt) + contact moments
    h0 = world_inertia_times(rot0, inertia_body, w0)
    h1 = (h0[0] + dt * (phi * m1[0] + (1.0 - phi) * b_in[M, 0]) + imp_moment[0],
          h0[1] + dt * (phi * m1[1] + (1.0 - phi) * b_in[M, 1]) + imp_moment[1],
          h0[2] + dt * (phi * m1[2] + (1.0 - phi) * b_in[M, 2]) + imp_moment[2])
    w = wk
    inc = np.empty((3, 3))
    rot1 = np.empty((3, 3))
    theta = np.empty(3)
    for _ in range(100):
        # axis at t + φΔt, eq. B8; inertia rotated with the body, eq. B15
        for c in range(3):
            theta[c] = dt * (phi * w[c] + (1.0 - phi) * w0[c])
        rotation_increment(theta, inc)
        mat_mul(inc, rot0, rot1)
        w_new = world_inertia_solve(rot1, inertia_body, h1)
        change = norm((w_new[0] - w[0], w_new[1] - w[1], w_new[2] - w[2]))
        w = w_new
        # eq. B16
        if change <= tol * norm(w):
            break
    for c in range(3):
        theta[c] = dt * (phi * w[c] + (1.0 - phi) * w0[c])
    rotation_increment(theta, inc)
    mat_mul(inc, rot0, rot1)
    for c in range(3):
        b_out[X, c] = x1[c]
        b_out[V, c] = v1[c]
        b_out[W, c] = w[c]
        b_out[F, c] = f1[c]
        b_out[M, c] = m1[c]
        for d in range(3):
            b_out[R0 + c, d] = rot1[c, d]
    # error measure in displacement units: the centre plus a surface point at distance `arm`
    num = (norm((x1[0] - xk[0], x1[1] - xk[1], x1[2] - xk[2]))
           + arm * dt * phi * norm((w[0] - wk[0], w[1] - wk[1], w[2] - wk[2])))
    wm = (phi * w[0] + (1.0 - phi) * w0[0], phi * w[1] + (1.0 - phi) * w0[1],
          phi * w[2] + (1.0 - phi) * w0[2])
    den = norm((x1[0] - x0[0], x1[1] - x0[1], x1[2] - x0[2])) + arm * dt * norm(wm)
    return num, den
