"""One attempted φ-step: the coupled fixed-point iteration of section 3 (3.3–3.10, step 5a).

Every iterate evaluates, in this order: yarn tensions and damage at the previous iterate; node
forces (yarn + Lorentz + gravity) and the φ-update; contact and friction against the body's
previous iterate; the body's translation and rotation from the summed reactions; the error
measure ϖ_K. The initial iterate is the start-of-step state (ϖ_0 = 1).

attempt_step is compiled without reference counting in its own body, as central_step is
(emfabric._kernels.explicit says why and what its callees must then set).
"""

import math

from numba import njit

from emfabric._kernels.anderson import anderson_mix
from emfabric._kernels.body import body_update
from emfabric._kernels.contact import (
    FREEZE_AFTER,
    candidate_errors,
    find_candidates,
    find_segment_candidates,
    node_contact,
    reaction_sums,
    segment_contact,
)
from emfabric._kernels.fields import (
    electric_at_nodes,
    fill_node_fields,
    fill_node_fields_threads,
    node_field,
    with_sources,
)
from emfabric._kernels.materials import damage_thresholds
from emfabric._kernels.nodes import fused_iterate, fused_iterate_threads
from emfabric._kernels.plies import ply_forces
from emfabric._kernels.records import (
    BODY_V,
    BODY_W,
    BODY_X,
    ROW_COUNT,
    ROW_NODE,
    SUM_ERROR_DEN,
    SUM_ERROR_NUM,
    StateArrays,
)
from emfabric._kernels.shapes import bounding_radius, nodes_inside
from emfabric._kernels.vec3 import copy_into, norm

CONVERGED, NOT_CONVERGED, NOT_FINITE, CONTACT_MISSED, BODY_NOT_CONVERGED = 0, 1, 2, 3, 4
"""Status of an attempted step: accepted; ϖ above tolerance after the iteration limit; a
non-finite value; a free node found inside the body that was no contact candidate; the body's
rotation (eq. B16) not converged within body.BODY_ITERATION_LIMIT at the last iterate."""


@njit(cache=True, _nrt=True)
def _predict(x0, v0, f0, inv_mass, phi, dt, out):
    """The initial iterate x0 + Δt v0 + φΔt² ψ(t)/m: the φ-update with the start-of-step forces
    (an explicit predictor; the iteration then starts O(Δt³) from its fixed point, not O(Δt))."""
    h = phi * dt * dt
    for c in range(3):
        for n in range(x0.shape[1]):
            out[c, n] = x0[c, n] + dt * v0[c, n] + h * f0[c, n] * inv_mass[n]


@njit(cache=True, inline="always")
def fabric_iterate(phys, prev, sin, sout, work, rowbuf, threads, t1, phi, dt):
    """One force evaluation + node update: yarn tensions and damage at the iterate `prev`, then
    the φ-update of every node from the start state sin into sout (x, v, f; trial damage into
    sout.alpha); the field is taken at time t1 = t + Δt.

    Exactly one of rowbuf, threads is an array, the other None: rowbuf (ROWBUF_ROWS, nx + 1)
    runs the serial kernel, threads (blocks, ROWBUF_ROWS, nx + 1) the threaded one.

    Numba drops a branch at compile time only on an argument typed None, hence the pair: only
    the kernel in use is compiled. Inlined (Numba IR) into the step kernel: one compiled level
    less (each level re-optimises and re-emits the machine code of everything below it, which
    is most of the first run's compile time)."""
    if rowbuf is None:
        if threads is not None:
            fused_iterate_threads(phys, prev, sin, sout, work, t1, phi, dt, threads)
    else:
        fused_iterate(phys, prev, sin, sout, work, t1, phi, dt, rowbuf)


@njit(cache=True, _nrt=True)
def ply_update(phys, work, x1, v1, f1, xk, x0, phi, dt):
    """Add ply contact to the φ-update of the nodes it acts on: the force at the iterate xk
    (work.ply_force, plies.ply_forces) weighted φ and the force at the start of the step
    (work.ply_force0, from x0 and v0) weighted 1 − φ. The update is linear in the force, so
    its share is Δv = M(u)·(Δt/m)(φF₁ + (1−φ)F₀) (M the closed-form inverse of the magnetic
    part, u = φΔt q B/m with the B the node update used), Δx = φΔt Δv, Δf = q Δv × B: the
    node force f carried to the next step holds no ply force (the next step recomputes it at
    its start, so the update and the energy bookkeeping use the same F₀); the rows' error
    sums follow the moved nodes (contact candidates' are computed later, from the final
    positions)."""
    nodes, fld = phys.nodes, phys.field
    fp, fp0 = work.ply_force, work.ply_force0
    sums = work.row_sums
    flag = work.flag
    inv_mass, charge = nodes.inv_mass, nodes.charge
    for j in range(nodes.rows.shape[0]):
        nb = nodes.rows[j, ROW_NODE]
        for n in range(nb, nb + nodes.rows[j, ROW_COUNT]):
            if ((fp[0, n] == 0.0 and fp[1, n] == 0.0 and fp[2, n] == 0.0
                 and fp0[0, n] == 0.0 and fp0[1, n] == 0.0 and fp0[2, n] == 0.0)
                    or inv_mass[n] == 0.0):
                continue
            q = charge[n]
            _e, b = node_field(fld, work.node_field, n, (xk[0, n], xk[1, n], xk[2, n]))
            h = dt * inv_mass[n]
            s = phi * h * q
            u0, u1, u2 = s * b[0], s * b[1], s * b[2]
            a0 = h * (phi * fp[0, n] + (1.0 - phi) * fp0[0, n])
            a1 = h * (phi * fp[1, n] + (1.0 - phi) * fp0[1, n])
            a2 = h * (phi * fp[2, n] + (1.0 - phi) * fp0[2, n])
            au = (a0 * u0 + a1 * u1) + a2 * u2
            inv = 1.0 / (1.0 + ((u0 * u0 + u1 * u1) + u2 * u2))
            d0 = ((a0 + (a1 * u2 - a2 * u1)) + au * u0) * inv
            d1 = ((a1 + (a2 * u0 - a0 * u2)) + au * u1) * inv
            d2 = ((a2 + (a0 * u1 - a1 * u0)) + au * u2) * inv
            if flag[n] == 0:
                e_old = math.sqrt((x1[0, n] - xk[0, n]) ** 2 + (x1[1, n] - xk[1, n]) ** 2
                                  + (x1[2, n] - xk[2, n]) ** 2)
                g_old = math.sqrt((x1[0, n] - x0[0, n]) ** 2 + (x1[1, n] - x0[1, n]) ** 2
                                  + (x1[2, n] - x0[2, n]) ** 2)
            k = phi * dt
            x1[0, n] += k * d0
            x1[1, n] += k * d1
            x1[2, n] += k * d2
            v1[0, n] += d0
            v1[1, n] += d1
            v1[2, n] += d2
            f1[0, n] += q * (d1 * b[2] - d2 * b[1])
            f1[1, n] += q * (d2 * b[0] - d0 * b[2])
            f1[2, n] += q * (d0 * b[1] - d1 * b[0])
            if flag[n] == 0:
                sums[SUM_ERROR_NUM, j] += math.sqrt(
                    (x1[0, n] - xk[0, n]) ** 2 + (x1[1, n] - xk[1, n]) ** 2
                    + (x1[2, n] - xk[2, n]) ** 2) - e_old
                sums[SUM_ERROR_DEN, j] += math.sqrt(
                    (x1[0, n] - x0[0, n]) ** 2 + (x1[1, n] - x0[1, n]) ** 2
                    + (x1[2, n] - x0[2, n]) ** 2) - g_old


@njit(cache=True, nogil=True, _nrt=False)
def attempt_step(phys, solver, sin, sout, work, rowbuf, threads, plies, segs, t, dt, accel):
    """Iterate the coupled step from time t to t + Δt to ϖ_K ≤ solver.tolerance within
    solver.iteration_limit iterations (phys: a Physics record, sin/sout: StateArrays).

    Returns (status, K, ϖ_K, contact count). On CONVERGED, sout holds the state at t + Δt and
    sout.alpha the trial damage to commit; sin is never written. plies, segs: an array where the
    model is a pack (ply contact) or its projectile meets segments (phys.contact.segments),
    else None: Numba then leaves that code out of the compiled kernel.
    """
    nodes = phys.nodes
    body = phys.body
    inv_mass = nodes.inv_mass
    phi = solver.phi
    tol = solver.tolerance
    kmax = solver.iteration_limit
    t1 = t + dt
    x0, v0, b_in = sin.x, sin.v, sin.body
    x1, v1, f1, alpha_t, b_out = sout.x, sout.v, sout.f, sout.alpha, sout.body
    xbuf, flag, row_sums = work.xbuf, work.flag, work.row_sums

    # one pass over the start state: the fastest node (contact reach) and the size of the
    # coordinates (a displacement below their round-off is no motion: ϖ would be noise/noise)
    vmax = 0.0
    still = 0.0
    for n in range(x0.shape[1]):
        vmax = max(vmax, v0[0, n] ** 2 + v0[1, n] ** 2 + v0[2, n] ** 2)
        still += abs(x0[0, n]) + abs(x0[1, n]) + abs(x0[2, n])
    still *= 1e-13
    ncand = 0
    nseg = 0
    if body.active:
        # contact candidates: nodes that can reach the body within this step
        radius = bounding_radius(body)
        speed = norm(b_in[BODY_V]) + radius * norm(b_in[BODY_W])
        reach = 1.05 * radius + 2.0 * dt * (speed + math.sqrt(vmax))
        ncand = find_candidates(x0, inv_mass, b_in[BODY_X], reach, work.cand, flag)
        if segs is not None:
            ncand, nseg = find_segment_candidates(phys.yarns, sin.alpha,
                                                  phys.material.broken_below, x0, inv_mass,
                                                  b_in[BODY_X], reach, work, ncand)
    else:
        flag[:] = 0
    work.counts[0] = ncand
    work.counts[1] = nseg

    imp_force = work.reaction[0]
    imp_moment = work.reaction[1]
    for c in range(3):
        imp_force[c] = 0.0
        imp_moment[c] = 0.0
    copy_into(b_out, b_in)
    if with_sources(phys.field):
        # the sources' field at the nodes, once for the attempt (fields.fill_node_fields)
        if threads is not None:
            fill_node_fields_threads(phys.field, x0, v0, dt, t1, work.node_field)
        else:
            fill_node_fields(phys.field, x0, v0, dt, t1, work.node_field)
    # a pack: ply contact's force at the start of the step (the energy bookkeeping's)
    if plies is not None:
        ply_forces(phys, x0, v0, v0, work, work.ply_force0, phi * dt)
    # where the damage law can change α this attempt (materials.damage_thresholds)
    damage_thresholds(sin.alpha, phys.material, phys.yarns.failure_stretch2,
                      work.damage_thr, work.damage_alpha)
    # the initial iterate: the start-of-step state (the paper's, ϖ_0 = 1) or the prediction
    if solver.predict:
        _predict(x0, v0, sin.f, inv_mass, phi, dt, xbuf)
        for c in range(3):
            b_out[BODY_X, c] = b_in[BODY_X, c] + dt * b_in[BODY_V, c]
    else:
        copy_into(xbuf, x0)
    if accel is not None:
        copy_into(accel[0], xbuf)
    # iterate K-1 is read from `prev`, iterate K written to `cur`. Plain fixed point: prev and
    # cur alternate between xbuf and x1. Anderson: cur is always x1 = G(prev) and the next prev
    # is the mixed iterate in accel[0]. accel is None for the plain fixed point: Numba then
    # drops the Anderson branches when it compiles this kernel.
    err = 1.0
    nc = 0
    k = 0
    body_ok = True
    for k in range(1, kmax + 1):
        if accel is not None:
            prev = accel[0]
            cur = x1
        else:
            prev = xbuf if k % 2 == 1 else x1
            cur = x1 if k % 2 == 1 else xbuf
        if plies is not None:
            # ply contact at the iterate, with its velocities (the start's at the first)
            ply_forces(phys, prev, v0 if k == 1 else v1, v0, work, work.ply_force, phi * dt)
        fabric_iterate(phys, prev, sin, StateArrays(cur, v1, f1, alpha_t, b_out, sout.e,
                                                    sout.contact, sout.fv, sout.strain,
                                                    sout.seg_contact), work,
                       rowbuf, threads, t1, phi, dt)
        if plies is not None:
            ply_update(phys, work, cur, v1, f1, prev, x0, phi, dt)
        num_b = 0.0
        den_b = 0.0
        if body.active:
            nc = node_contact(nodes, body, phys.contact, b_out, ncand, cur, v1, work,
                              phi if phys.contact.follow else 0.0, dt, k > FREEZE_AFTER)
            if segs is not None:
                nc = segment_contact(phys, b_out, nseg, nc, cur, v1, work, 0.0,
                                     sin.seg_contact, sout.seg_contact)
            candidate_errors(nodes, ncand, work.cand, x0, prev, cur, row_sums)
            reaction_sums(nc, work.c_imp, work.c_arm, work.sum_buf, imp_force, imp_moment)
            num_b, den_b, body_ok = body_update(body, phys.field, b_in, b_out, t1, phi, dt,
                                                work.reaction, work.body_scratch, tol)
        # error measure, eq. 3.10 step 5a (fabric), and the same for the body
        num = 0.0
        den = 0.0
        # per ply, its rows j and ny−1−j first: a run mirrored in y (B reversed along x) gets
        # the same ϖ bit for bit, hence the same steps
        for p in range(nodes.ply_rows.shape[0] - 1):
            r0 = nodes.ply_rows[p]
            ny = nodes.ply_rows[p + 1] - r0
            for j in range(ny // 2):
                num += (row_sums[SUM_ERROR_NUM, r0 + j]
                        + row_sums[SUM_ERROR_NUM, r0 + ny - 1 - j])
                den += (row_sums[SUM_ERROR_DEN, r0 + j]
                        + row_sums[SUM_ERROR_DEN, r0 + ny - 1 - j])
            if ny % 2 == 1:
                num += row_sums[SUM_ERROR_NUM, r0 + ny // 2]
                den += row_sums[SUM_ERROR_DEN, r0 + ny // 2]
        err_f = num / den if den > still else (0.0 if num <= still else 1.0)
        err_b = num_b / den_b if den_b > 0.0 else (0.0 if num_b == 0.0 else 1.0)
        err = max(err_f, err_b)
        if not (math.isfinite(num) and math.isfinite(den) and math.isfinite(num_b)):
            if accel is None and k % 2 == 0:
                copy_into(x1, xbuf)
            return NOT_FINITE, k, math.inf, nc
        if err <= tol:
            break
        if accel is not None:
            anderson_mix(k, accel[0], x1, accel[1], accel[2], accel[3], accel[4], accel[5])
    if accel is None and k % 2 == 0:
        copy_into(x1, xbuf)
    if err > tol:
        return NOT_CONVERGED, k, err, nc
    if not body_ok:
        return BODY_NOT_CONVERGED, k, err, nc
    if body.active and nodes_inside(x1, inv_mass, flag, body, b_out) > 0:
        return CONTACT_MISSED, k, err, nc
    # the electric field in the new state's forces (the energy bookkeeping's field work)
    electric_at_nodes(phys.field, work.node_field, x1, sout.e)
    if plies is not None:
        # a pack's nodes in contact with the projectile, per node (contact_nodes_per_ply):
        # the contact state's flag row, which central differences keep for their placement
        for n in range(sout.contact.shape[1]):
            sout.contact[3, n] = 0.0
        for c in range(nc):
            sout.contact[3, work.c_node[c]] = 1.0
            if work.c_node2[c] >= 0:
                sout.contact[3, work.c_node2[c]] = 1.0
    return CONVERGED, k, err, nc
