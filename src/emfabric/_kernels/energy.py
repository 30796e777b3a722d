"""Energy bookkeeping of one accepted step, every term computed on its own.

With v̄ = (v0 + v1)/2 the φ-scheme gives exactly ΔKE = (Δt ψ̄ + J)·v̄ for a node, and the same
for the body, so the work of a contact impulse J on the pair (node, body point) is
J·(v̄_node − v̄_point); its negative is what contact (normal part) and friction (tangential part)
dissipate; for a segment contact the fabric point is w_a x_a + w_b x_b and its velocity
w_a v̄_a + w_b v̄_b. Field and gravity work use the displacements. A contact candidate's
displacement differs from the φ-update's Δt(φ v1 + (1−φ) v0) by δ (the projection's jump, less
φΔt J/m); the work the non-impulsive, non-magnetic forces do over δ is not seen by the velocity
update and is booked as projection dissipation. Damage releases α-drop × stored energy, less
the work of the step's last stretch that the update never paid (damage_release).
"""


from numba import njit, uint64

from emfabric._kernels.fields import (
    field_at,
    has_electric_field,
    magnetic_force,
    node_field,
)
from emfabric._kernels.materials import strain_energy_density, stress_factor, stretch_sq
from emfabric._kernels.records import (
    BODY_R0,
    BODY_V,
    BODY_W,
    BODY_X,
    ENERGY_CONTACT,
    ENERGY_DAMAGE,
    ENERGY_FRICTION,
    ENERGY_PROJECTION,
    ENERGY_WORK_FIELD,
    ENERGY_WORK_GRAVITY,
)
from emfabric._kernels.reductions import SCAN_BLOCK
from emfabric._kernels.vec3 import cross, dot, mat_vec, vec


@njit(cache=True)
def step_energy(phys, sin, sout, nc, work, t0, phi, dt, out):
    """Add the field work, gravity work and dissipations of the accepted step from sin (at t0)
    to sout (at t0 + Δt) to out [J] (the order of records.ENERGY_TERMS)."""
    nodes, yarns, mat, fld, body = phys.nodes, phys.yarns, phys.material, phys.field, phys.body
    mass, inv_mass, charge = nodes.mass, nodes.inv_mass, nodes.charge
    grav = fld.gravity
    x0, v0 = sin.x, sin.v
    x1, v1, f1 = sout.x, sout.v, sout.f
    b_in, b_out = sin.body, sout.body
    t1 = t0 + dt
    w_field = 0.0
    w_grav = 0.0
    # no E and no gravity (the paper's case): nothing works on the nodes, skip the node pass
    electric = has_electric_field(fld)
    active = electric or grav[0] != 0.0 or grav[1] != 0.0 or grav[2] != 0.0
    e0s, e1s = sin.e, sout.e
    for n in range(x0.shape[1] if active else 0):
        if inv_mass[n] == 0.0:
            continue
        # electric work q Ē·Δx with Ē the φ-weighted field the node update used at the two
        # ends (the State's e; magnetic: none)
        e0 = (e0s[0, n], e0s[1, n], e0s[2, n])
        e1 = (e1s[0, n], e1s[1, n], e1s[2, n])
        q = charge[n]
        m = mass[n]
        for c in range(3):
            d = x1[c, n] - x0[c, n]
            w_field += q * (phi * e1[c] + (1.0 - phi) * e0[c]) * d
            w_grav += m * grav[c] * d
    # the body: charged points and gravity
    rot0 = b_in[BODY_R0:BODY_R0 + 3]
    rot1 = b_out[BODY_R0:BODY_R0 + 3]
    for k in range(body.charge.shape[0] if electric else 0):
        r0 = mat_vec(rot0, body.charge_pos[k])
        r1 = mat_vec(rot1, body.charge_pos[k])
        p0 = (b_in[BODY_X, 0] + r0[0], b_in[BODY_X, 1] + r0[1], b_in[BODY_X, 2] + r0[2])
        p1 = (b_out[BODY_X, 0] + r1[0], b_out[BODY_X, 1] + r1[1], b_out[BODY_X, 2] + r1[2])
        d = (p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2])
        e0, _b0 = field_at(fld, p0, t0)
        e1, _b1 = field_at(fld, p1, t1)
        w_field += body.charge[k] * (phi * dot(e1, d) + (1.0 - phi) * dot(e0, d))
    for c in range(3):
        w_grav += body.mass * grav[c] * (b_out[BODY_X, c] - b_in[BODY_X, c])

    d_proj = 0.0
    vbar = (0.5 * (b_in[BODY_V, 0] + b_out[BODY_V, 0]), 0.5 * (b_in[BODY_V, 1] + b_out[BODY_V, 1]),
            0.5 * (b_in[BODY_V, 2] + b_out[BODY_V, 2]))
    wbar = (0.5 * (b_in[BODY_W, 0] + b_out[BODY_W, 0]), 0.5 * (b_in[BODY_W, 1] + b_out[BODY_W, 1]),
            0.5 * (b_in[BODY_W, 2] + b_out[BODY_W, 2]))
    d_cont, d_fric = impulse_dissipation(nc, work, v0, v1, vbar, wbar)
    # the contact candidates' displacement beyond the φ-update, δ = Δx − Δt(φ v1 + (1−φ) v0):
    # the work of the non-impulsive, non-magnetic forces over it is not seen by the velocity
    # update (zero, to round-off, for a node that contact did not move)
    cand = work.cand
    for idx in range(work.counts[0]):
        n = cand[idx]
        # the B the node update used (the attempt's stored field for sources)
        _e1, b1 = node_field(fld, work.node_field, n, (x1[0, n], x1[1, n], x1[2, n]))
        fm = magnetic_force(charge[n], (work.v_pre[0, n], work.v_pre[1, n], work.v_pre[2, n]),
                            b1)
        for c in range(3):
            delta = x1[c, n] - x0[c, n] - dt * (phi * v1[c, n] + (1.0 - phi) * v0[c, n])
            d_proj += (f1[c, n] - fm[c]) * delta

    d_dam = damage_release(yarns, mat, x0, x1, sin.alpha, sout.alpha, phi)
    # a pack: the work of ply contact's forces (stored in the penalty while plies press,
    # dissipated by its damping and friction) is booked as contact dissipation, −Δt ψ̄·v̄
    if nodes.ply_nodes.shape[0] > 2:
        fp0, fp1 = work.ply_force0, work.ply_force
        for n in range(x0.shape[1]):
            for c in range(3):
                d_cont -= dt * (phi * fp1[c, n] + (1.0 - phi) * fp0[c, n]) * 0.5 * (
                    v0[c, n] + v1[c, n])
    out[ENERGY_WORK_FIELD] += w_field
    out[ENERGY_WORK_GRAVITY] += w_grav
    out[ENERGY_FRICTION] += d_fric
    out[ENERGY_CONTACT] += d_cont
    out[ENERGY_PROJECTION] += d_proj
    out[ENERGY_DAMAGE] += d_dam


@njit(cache=True, _nrt=True)
def damage_release(yarns, mat, x0, x, alpha_before, alpha_after, weight):
    """Energy released by damage over a step from x0 to x [J]: each segment's α drop times its
    stored energy at the positions x (eq. 2.6 lowers α at fixed stretch; a brittle yarn loses
    it all), less the part of its last stretch the scheme never paid: the update weighs the
    end-of-step force with `weight` (1/2 for central differences' second kick, φ for the
    φ-scheme) and that force is the damaged one, so the intact segment's work weight·t·Δd over
    the step's stretch Δd was not drawn from the kinetic energy. Without it a rupture books
    O(Δt) too much (a first-order error per broken yarn); with it the budget closes to
    O(Δt²)."""
    d_dam = 0.0
    ends, rest, coef = yarns.ends, yarns.rest_length, yarns.stiffness
    count = alpha_before.shape[0]
    for b0 in range(0, count, SCAN_BLOCK):
        b1 = min(count, b0 + SCAN_BLOCK)
        # the block's segments whose α fell, counted in a loop that vectorises: most blocks
        # of most steps have none (reductions.SCAN_BLOCK)
        fell = 0
        for s in range(b0, b1):
            fell += 1 if alpha_after[uint64(s)] < alpha_before[uint64(s)] else 0
        if fell == 0:
            continue
        for s in range(b0, b1):
            drop = alpha_before[s] - alpha_after[s]
            if not drop > 0.0:
                continue
            a = ends[s, 0]
            b = ends[s, 1]
            dx = x[0, b] - x[0, a]
            dy = x[1, b] - x[1, a]
            dz = x[2, b] - x[2, a]
            u2 = stretch_sq(dx, dy, dz, yarns.inv_rest2[s])
            # the intact tension vector on node a at x: stiffness·S/𝔼·d; its work over Δd
            paid = (dx * (dx - (x0[0, b] - x0[0, a])) + dy * (dy - (x0[1, b] - x0[1, a]))
                    + dz * (dz - (x0[2, b] - x0[2, a])))
            d_dam += drop * coef[s] * (rest[s] * rest[s] * strain_energy_density(u2, mat)
                                       - weight * stress_factor(u2, mat) * paid)
    return d_dam


@njit(cache=True, _nrt=True)
def impulse_dissipation(nc, work, v_before, v_after, v_body, w_body):
    """Normal and friction dissipation [J] of the step's nc contact impulses (work.c_*): for
    each, −J·(v̄_point − v̄_fabric) split along the normal, v̄_fabric the mean of the fabric
    point's velocity before and after (a node, or w_a, w_b of a segment's two nodes), v̄_point
    the body surface point's from the body's mean velocity v_body and angular velocity w_body.
    The kinetic energy the impulses remove from fabric + body is exactly their sum."""
    d_cont = 0.0
    d_fric = 0.0
    c_node, c_node2, c_w = work.c_node, work.c_node2, work.c_w
    c_imp, c_arm, c_nrm = work.c_imp, work.c_arm, work.c_nrm
    for k in range(nc):
        # the fabric point the impulse acts on: a node, or w_a x_a + w_b x_b on a segment
        a = c_node[k]
        b = c_node2[k]
        wa = c_w[0, k]
        vp = (wa * 0.5 * (v_before[0, a] + v_after[0, a]),
              wa * 0.5 * (v_before[1, a] + v_after[1, a]),
              wa * 0.5 * (v_before[2, a] + v_after[2, a]))
        if b >= 0:
            wb = c_w[1, k]
            vp = (vp[0] + wb * 0.5 * (v_before[0, b] + v_after[0, b]),
                  vp[1] + wb * 0.5 * (v_before[1, b] + v_after[1, b]),
                  vp[2] + wb * 0.5 * (v_before[2, b] + v_after[2, b]))
        r = vec(c_arm[:, k])
        nh = vec(c_nrm[:, k])
        jv = vec(c_imp[:, k])
        wr = cross(w_body, r)
        rel = (v_body[0] + wr[0] - vp[0], v_body[1] + wr[1] - vp[1], v_body[2] + wr[2] - vp[2])
        jn = dot(jv, nh)
        d_cont += jn * dot(nh, rel)
        d_fric += dot((jv[0] - jn * nh[0], jv[1] - jn * nh[1], jv[2] - jn * nh[2]), rel)
    return d_cont, d_fric
