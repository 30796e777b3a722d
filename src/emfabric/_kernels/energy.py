"""Energy bookkeeping of one accepted step, every term computed on its own.

With v̄ = (v0 + v1)/2 the φ-scheme gives exactly ΔKE = (Δt ψ̄ + J)·v̄ for a node, and the same
for the body, so the work of a contact impulse J on the pair (node, body point) is
J·(v̄_node − v̄_point); its negative is what contact (normal part) and friction (tangential part)
dissipate. Field and gravity work use the displacements. A contact node's displacement differs
from the φ-update's Δt(φ v1 + (1−φ) v0) by δ = Δ − φΔt J/m (Δ: the projection jump); the work
the non-impulsive, non-magnetic forces do over δ is not seen by the velocity update and is booked
as projection dissipation. Damage releases α-drop × stored energy.
"""

import math

import numpy as np
from numba import njit

from emfabric._kernels.nodes import in_field
from emfabric._kernels.yarn import strain_energy_density


@njit(cache=True)
def step_energy(x0, x1, v0, v1, f1, mass, inv_mass, charge, efield, bfield, region, z0, grav,
                phi, dt, nc, c_node, c_imp, c_arm, c_proj, b_in, b_out, q_pos, q_val, b_mass,
                seg_nodes, alpha_old, alpha_new, coef, rest, kind, fung_h, out):
    """Add this step's field work, gravity work and dissipations to out (6,) [J]."""
    w_field = 0.0
    w_grav = 0.0
    # E = 0 and g = 0 (the paper's case): nothing works on the nodes, skip the node pass
    active = np.any(efield != 0.0) or np.any(grav != 0.0)
    for n in range(x0.shape[1] if active else 0):
        if inv_mass[n] == 0.0:
            continue
        q0 = charge[n] if in_field(x0[2, n], region, z0) else 0.0
        q1 = charge[n] if in_field(x1[2, n], region, z0) else 0.0
        qe = phi * q1 + (1.0 - phi) * q0
        m = mass[n]
        for c in range(3):
            d = x1[c, n] - x0[c, n]
            w_field += qe * efield[c] * d
            w_grav += m * grav[c] * d
    # the body: charged points and gravity
    rot0 = b_in[5:8]
    rot1 = b_out[5:8]
    for k in range(q_val.shape[0]):
        p0 = b_in[0] + rot0 @ q_pos[k]
        p1 = b_out[0] + rot1 @ q_pos[k]
        q0 = q_val[k] if in_field(p0[2], region, z0) else 0.0
        q1 = q_val[k] if in_field(p1[2], region, z0) else 0.0
        w_field += (phi * q1 + (1.0 - phi) * q0) * np.sum(efield * (p1 - p0))
    w_grav += b_mass * np.sum(grav * (b_out[0] - b_in[0]))

    d_fric = 0.0
    d_cont = 0.0
    d_proj = 0.0
    vbar = 0.5 * (b_in[1] + b_out[1])
    wbar = 0.5 * (b_in[2] + b_out[2])
    for k in range(nc):
        n = c_node[k]
        r = c_arm[:, k]
        rr = math.sqrt(np.sum(r * r))
        nh = r / rr
        jv = c_imp[:, k]
        point = vbar + np.cross(wbar, r)
        rel = point - 0.5 * (v0[:, n] + v1[:, n])
        jn = np.sum(jv * nh)
        d_cont += jn * np.sum(nh * rel)
        d_fric += np.sum((jv - jn * nh) * rel)
        # forces of the φ-update over the unseen displacement δ (magnetic part does no work)
        q1 = charge[n] if in_field(x1[2, n], region, z0) else 0.0
        vpred = v1[:, n] - jv / mass[n]
        fnm = f1[:, n] - q1 * np.cross(vpred, bfield)
        d_proj += np.sum(fnm * (c_proj[:, k] - phi * dt * jv / mass[n]))

    d_dam = 0.0
    for s in range(alpha_old.shape[0]):
        drop = alpha_old[s] - alpha_new[s]
        if drop > 0.0:
            a = seg_nodes[s, 0]
            b = seg_nodes[s, 1]
            u2 = ((x1[0, b] - x1[0, a]) ** 2 + (x1[1, b] - x1[1, a]) ** 2
                  + (x1[2, b] - x1[2, a]) ** 2) / (rest[s] * rest[s])
            d_dam += drop * coef[s] * rest[s] * rest[s] * strain_energy_density(u2, kind, fung_h)
    out[0] += w_field
    out[1] += w_grav
    out[2] += d_fric
    out[3] += d_cont
    out[4] += d_proj
    out[5] += d_dam
