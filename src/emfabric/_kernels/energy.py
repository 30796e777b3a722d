"""Energy bookkeeping of one accepted step, every term computed on its own.

With v̄ = (v0 + v1)/2 the φ-scheme gives exactly ΔKE = (Δt ψ̄ + J)·v̄ for a node, and the same
for the body, so the work of a contact impulse J on the pair (node, body point) is
J·(v̄_node − v̄_point); its negative is what contact (normal part) and friction (tangential part)
dissipate. Field and gravity work use the displacements. A contact node's displacement differs
from the φ-update's Δt(φ v1 + (1−φ) v0) by δ = Δ − φΔt J/m (Δ: the projection jump); the work
the non-impulsive, non-magnetic forces do over δ is not seen by the velocity update and is booked
as projection dissipation. Damage releases α-drop × stored energy.
"""


from numba import njit

from emfabric._kernels.nodes import in_field
from emfabric._kernels.vec3 import cross, dot, mat_vec, norm, vec
from emfabric._kernels.yarn import strain_energy_density


@njit(cache=True)
def step_energy(x0, x1, v0, v1, f1, mass, inv_mass, charge, efield, bfield, region, z0, grav,
                phi, dt, nc, c_node, c_imp, c_arm, c_proj, b_in, b_out, q_pos, q_val, b_mass,
                seg_nodes, alpha_old, alpha_new, coef, rest, kind, fung_h, out):
    """Add this step's field work, gravity work and dissipations to out (6,) [J]."""
    w_field = 0.0
    w_grav = 0.0
    # E = 0 and g = 0 (the paper's case): nothing works on the nodes, skip the node pass
    active = False
    for c in range(3):
        active = active or efield[c] != 0.0 or grav[c] != 0.0
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
    e = vec(efield)
    for k in range(q_val.shape[0]):
        r0 = mat_vec(rot0, q_pos[k])
        r1 = mat_vec(rot1, q_pos[k])
        d = ((b_out[0, 0] + r1[0]) - (b_in[0, 0] + r0[0]),
             (b_out[0, 1] + r1[1]) - (b_in[0, 1] + r0[1]),
             (b_out[0, 2] + r1[2]) - (b_in[0, 2] + r0[2]))
        q0 = q_val[k] if in_field(b_in[0, 2] + r0[2], region, z0) else 0.0
        q1 = q_val[k] if in_field(b_out[0, 2] + r1[2], region, z0) else 0.0
        w_field += (phi * q1 + (1.0 - phi) * q0) * dot(e, d)
    for c in range(3):
        w_grav += b_mass * grav[c] * (b_out[0, c] - b_in[0, c])

    d_fric = 0.0
    d_cont = 0.0
    d_proj = 0.0
    b = vec(bfield)
    for k in range(nc):
        n = c_node[k]
        r = vec(c_arm[:, k])
        rr = norm(r)
        nh = (r[0] / rr, r[1] / rr, r[2] / rr)
        jv = vec(c_imp[:, k])
        wr = cross((0.5 * (b_in[2, 0] + b_out[2, 0]), 0.5 * (b_in[2, 1] + b_out[2, 1]),
                    0.5 * (b_in[2, 2] + b_out[2, 2])), r)
        rel = (0.5 * (b_in[1, 0] + b_out[1, 0]) + wr[0] - 0.5 * (v0[0, n] + v1[0, n]),
               0.5 * (b_in[1, 1] + b_out[1, 1]) + wr[1] - 0.5 * (v0[1, n] + v1[1, n]),
               0.5 * (b_in[1, 2] + b_out[1, 2]) + wr[2] - 0.5 * (v0[2, n] + v1[2, n]))
        jn = dot(jv, nh)
        d_cont += jn * dot(nh, rel)
        d_fric += dot((jv[0] - jn * nh[0], jv[1] - jn * nh[1], jv[2] - jn * nh[2]), rel)
        # forces of the φ-update over the unseen displacement δ (magnetic part does no work)
        q1 = charge[n] if in_field(x1[2, n], region, z0) else 0.0
        m = mass[n]
        vb = cross((v1[0, n] - jv[0] / m, v1[1, n] - jv[1] / m, v1[2, n] - jv[2] / m), b)
        for c in range(3):
            fnm = f1[c, n] - q1 * vb[c]
            d_proj += fnm * (c_proj[c, k] - phi * dt * jv[c] / m)

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
