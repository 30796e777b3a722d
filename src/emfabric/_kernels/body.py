"""Rigid body update inside the fixed-point loop: translation (4.12–4.13), rotation (B1–B18)."""

import math

import numpy as np
from numba import njit

from emfabric._kernels.nodes import in_field

X, V, W, F, M, R0 = 0, 1, 2, 3, 4, 5


@njit(cache=True)
def rotation_increment(theta):
    """Rotation matrix by the vector angle theta (Rodrigues; equals Aᵀ·R(Δθ)·A of B13–B14)."""
    angle = math.sqrt(theta[0] ** 2 + theta[1] ** 2 + theta[2] ** 2)
    out = np.eye(3)
    if angle == 0.0:
        return out
    kx, ky, kz = theta[0] / angle, theta[1] / angle, theta[2] / angle
    s = math.sin(angle)
    c1 = 1.0 - math.cos(angle)
    k = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
    return out + s * k + c1 * (k @ k)


@njit(cache=True)
def field_wrench(centre, vel, omega, rot, charge_pos, charge_q, efield, bfield, region, z0,
                 mass, grav, force, moment):
    """Force and moment about the centre of mass of the body's charges (6.2–6.6) and gravity."""
    for c in range(3):
        force[c] = mass * grav[c]
        moment[c] = 0.0
    for k in range(charge_q.shape[0]):
        r = rot @ charge_pos[k]
        if not in_field(centre[2] + r[2], region, z0):
            continue
        q = charge_q[k]
        # velocity of the charged point, eq. 6.1
        vp = vel + np.cross(omega, r)
        psi = q * (efield + np.cross(vp, bfield))
        force += psi
        moment += np.cross(r, psi)


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
    xk = b_out[X].copy()
    vk = b_out[V].copy()
    wk = b_out[W].copy()
    rotk = b_out[R0:R0 + 3].copy()
    f1 = np.empty(3)
    m1 = np.empty(3)
    field_wrench(xk, vk, wk, rotk, charge_pos, charge_q, efield, bfield, region, z0, mass, grav,
                 f1, m1)
    # translation, eqs. 4.12–4.13, with the contact impulses taken whole
    v1 = v0 + dt / mass * (phi * f1 + (1.0 - phi) * b_in[F]) + imp_force / mass
    x1 = x0 + dt * (phi * v1 + (1.0 - phi) * v0)
    # rotation, eqs. B3–B6 in the inertial frame: H1 = I0·ω0 + Δt·M(t+φΔt) + contact moments
    inertia0 = rot0 @ inertia_body @ rot0.T
    h1 = inertia0 @ w0 + dt * (phi * m1 + (1.0 - phi) * b_in[M]) + imp_moment
    w = wk.copy()
    rot1 = rot0.copy()
    for _ in range(100):
        # axis at t + φΔt, eq. B8; inertia rotated with the body, eq. B15
        rot1 = rotation_increment(dt * (phi * w + (1.0 - phi) * w0)) @ rot0
        inertia1 = rot1 @ inertia_body @ rot1.T
        w_new = np.linalg.solve(inertia1, h1)
        change = math.sqrt(np.sum((w_new - w) ** 2))
        w = w_new
        # eq. B16
        if change <= tol * math.sqrt(np.sum(w * w)):
            break
    rot1 = rotation_increment(dt * (phi * w + (1.0 - phi) * w0)) @ rot0
    b_out[X] = x1
    b_out[V] = v1
    b_out[W] = w
    b_out[F] = f1
    b_out[M] = m1
    b_out[R0:R0 + 3] = rot1
    # error measure in displacement units: the centre plus a surface point at distance `arm`
    num = math.sqrt(np.sum((x1 - xk) ** 2)) + arm * dt * phi * math.sqrt(np.sum((w - wk) ** 2))
    wm = phi * w + (1.0 - phi) * w0
    den = math.sqrt(np.sum((x1 - x0) ** 2)) + arm * dt * math.sqrt(np.sum(wm * wm))
    return num, den
