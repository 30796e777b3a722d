"""Central differences: one explicit step, one force evaluation (kick, rotate, drift, contact,
force, rotate, kick).

With h = Δt, f the non-magnetic node force (yarns + electric + gravity, nodes._row_force) and
the magnetic force time-centred as two exact rotations of half a step each (Boris's two-step
rotation with the angle |q B/m|·h/2 exactly: the cyclotron frequency is exact and |v| is kept):

    v⁻ = v_n + h/(2m) f_n,   v_{n+½} = R(B(x_n, t_n), h/2) v⁻,   x_{n+1} = x_n + h v_{n+½},
    contact and friction impulses on v_{n+½} at x_{n+1} (the reaction on the body),
    f_{n+1} = f(x_{n+1}, t_{n+1}),   v⁺ = R(B(x_{n+1}, t_{n+1}), h/2) v_{n+½},
    v_{n+1} = v⁺ + h/(2m) f_{n+1}.

The body the same way: V and the angular momentum H = Ī ω get half kicks from the field's force
and moment (body.field_wrench), the rotation R_{n+1} = exp(h ω_{n+½}) R_n with ω_{n+½} =
Ī(R_{n+¼})⁻¹ H_{n+½} at the mid-rotation (a small fixed point, as eq. B16), and the contact
reaction −J at the contact points between the drift and the second half kick.

Contact: a candidate node inside the body after the drift is given the impulse of the contact
law (contact.contact_impulse: stick to the surface point's velocity, else Coulomb slip). A node
that sticks is put on the surface and remembers the body-frame material point it sticks to
(StateArrays.contact); a node that stuck in the previous step is put where that material point
has moved to — not projected radially, which lags the surface by the tangential drift of the
step. Segments (contact.segment_contact) as in the φ-scheme, and then the end nodes of the
segments in contact drift again by Δt times the tangential part of their velocity change, so
that a sticking segment point moves with the surface too (docs/theory.md §5.2).

Energy: the kicks and the impulses change the kinetic energy by exactly the work booked (field
and gravity work as h/2 f·v̄ of each kick, the impulses' J·(v̄_point − v̄_node), of which the
work friction does against the slip is booked as friction (_friction_work), the rest as
contact); the yarns' work is the trapezoid h/2 (f_n + f_{n+1})·v_{n+½} of their energy change,
and their work over the placement as projection, so the balance error measures the scheme's
own error, O(h²) per unit time. The yarns' viscous force (solver.bulk_viscosity) is not
conservative: its work is booked by the kicks as the field's is (h/2 f_v·v̄ each, with the
State's fv for the first), as viscous dissipation.

The step kernel (central_step, and the φ-scheme's step.attempt_step) is compiled with
`_nrt=False`, without Numba's reference counting in its own body: called from Python, its entry
then wraps the ~100 arrays of its records without a reference-counted MemInfo each (a malloc,
an atomic count and a free per array per call: 5.3 µs of a demo-small step), and every
reference count its callees take on those arrays is a test for null, not an atomic operation.
A function compiled from it inherits the flag unless it sets its own, and one without counts
cannot allocate, so each function it calls directly (past those inlined) sets `_nrt=True`
(or `_nrt=False`, the row kernels): they compile as they would from Python
(tests/test_architecture.py checks that none inherits; docs/performance.md measures it).
"""

import math

from numba import njit, uint64

from emfabric._kernels.body import BODY_ITERATION_LIMIT, field_wrench
from emfabric._kernels.contact import (
    KINETIC,
    SLIDE,
    STICK,
    contact_impulse,
    find_candidates,
    find_segment_candidates,
    reaction_sums,
    segment_contact,
    travel_limit,
)
from emfabric._kernels.diagnostics import fabric_from_rows
from emfabric._kernels.energy import damage_release, impulse_dissipation
from emfabric._kernels.fields import (
    field_at,
    fill_node_fields,
    has_electric_field,
    magnetic_force,
    node_field_of,
    uniform_field,
    with_sources,
)
from emfabric._kernels.materials import damage_thresholds, stretch_sq, tangent_factor
from emfabric._kernels.nodes import (
    drift_rows,
    drift_rows_threads,
    kick_rows,
    kick_rows_threads,
)
from emfabric._kernels.plies import ply_contact
from emfabric._kernels.records import (
    BODY_F,
    BODY_M,
    BODY_R0,
    BODY_V,
    BODY_W,
    BODY_X,
    ENERGY_CONTACT,
    ENERGY_DAMAGE,
    ENERGY_FRICTION,
    ENERGY_PROJECTION,
    ENERGY_VISCOUS,
    ENERGY_WORK_FIELD,
    ENERGY_WORK_GRAVITY,
    SUM_MOTION,
    SUM_PROJECTION,
    SUM_SPEED,
    SUM_STIFFNESS,
    SUM_WORK_FIELD,
    SUM_WORK_GRAVITY,
    SUM_WORK_VISCOUS,
)
from emfabric._kernels.reductions import from_key, order_key
from emfabric._kernels.shapes import (
    bounding_radius,
    contact_margin,
    nodes_inside,
    surface_point,
)
from emfabric._kernels.vec3 import (
    copy_into,
    cross,
    mat_mul,
    mat_vec,
    norm,
    rotation_increment,
    to_body_frame,
    vec,
    world_inertia_solve,
    world_inertia_times,
)

OK, NOT_FINITE, CONTACT_MISSED, BODY_NOT_CONVERGED = 0, 2, 3, 4
"""Status of a step (the φ kernel's codes where they mean the same)."""

@njit(cache=True, _nrt=True)
def _sum_rows(a, ny):
    """Σ a[:ny] in row order (a fixed order, whatever the thread count)."""
    total = 0.0
    for j in range(ny):
        total += a[j]
    return total


@njit(cache=True)
def stable_step(phys, x, alpha, scratch):
    """The explicit stability limit 2/ω_max of the fabric at the positions x and damage α [s]:
    ω_max² ≤ max over free nodes of 2 Σ k_t/m (Gershgorin), k_t the axial tangent stiffness of
    each segment at its stretch (materials.tangent_factor); scratch (node_count,). inf for a
    fabric without free nodes."""
    nodes, yarns, mat = phys.nodes, phys.yarns, phys.material
    ends, coef, il2 = yarns.ends, yarns.stiffness, yarns.inv_rest2
    for n in range(scratch.shape[0]):
        scratch[n] = 0.0
    for s in range(ends.shape[0]):
        a = ends[s, 0]
        b = ends[s, 1]
        u2 = stretch_sq(x[0, b] - x[0, a], x[1, b] - x[1, a], x[2, b] - x[2, a], il2[s])
        k = coef[s] * alpha[s] * tangent_factor(u2, mat)
        scratch[a] += k
        scratch[b] += k
    worst = 0.0
    for n in range(scratch.shape[0]):
        if nodes.inv_mass[n] > 0.0:
            worst = max(worst, 2.0 * scratch[n] * nodes.inv_mass[n])
    return 2.0 / math.sqrt(worst) if worst > 0.0 else math.inf


@njit(cache=True, inline="always")
def _spin_solve(rot, body, h_vec, scratch):
    """ω = Ī(R)⁻¹ H for the body at rotation R."""
    return world_inertia_solve(rot, body.inertia, h_vec, scratch[3:7])


@njit(cache=True, _nrt=True)
def _mid_rotation(body, rot0, h_half, dt, tol, scratch, rot1):
    """ω_{n+½} = Ī(exp(Δt/2 ω) R_n)⁻¹ H_{n+½} by fixed-point iteration from the Ī(R_n)⁻¹ H
    guess, then R_{n+1} = exp(Δt ω) R_n into rot1. Returns (ω, converged)."""
    inc = scratch[0:3]
    w = _spin_solve(rot0, body, h_half, scratch)
    for _ in range(BODY_ITERATION_LIMIT):
        rotation_increment((0.5 * dt * w[0], 0.5 * dt * w[1], 0.5 * dt * w[2]), inc)
        mat_mul(inc, rot0, rot1)
        w_new = _spin_solve(rot1, body, h_half, scratch)
        change = norm((w_new[0] - w[0], w_new[1] - w[1], w_new[2] - w[2]))
        w = w_new
        if change <= tol * norm(w):
            rotation_increment((dt * w[0], dt * w[1], dt * w[2]), inc)
            mat_mul(inc, rot0, rot1)
            return w, True
    rotation_increment((dt * w[0], dt * w[1], dt * w[2]), inc)
    mat_mul(inc, rot0, rot1)
    return w, False


@njit(cache=True, _nrt=True)
def _node_contact(phys, sin, sout, work, ncand, dt):
    """Contact of the candidate nodes after the drift (see the module docstring): impulses on
    sout.v (the velocity before them in work.v_pre), placement on sout.x, the contact records
    in work.c_*, the new contact state in sout.contact. The body's state in sout.body holds
    the drifted position and rotation, its half-step velocity and the angular velocity at the
    new rotation. Returns the number of contacts."""
    nodes, body, law = phys.nodes, phys.body, phys.contact
    mass = nodes.mass
    b_state = sout.body
    centre = b_state[BODY_X]
    vel = b_state[BODY_V]
    omega = (b_state[BODY_W, 0], b_state[BODY_W, 1], b_state[BODY_W, 2])
    rot = b_state[BODY_R0:BODY_R0 + 3]
    x1, v1 = sout.x, sout.v
    was, now = sin.contact, sout.contact
    cand, v_pre = work.cand, work.v_pre
    c_node, c_node2, c_w = work.c_node, work.c_node2, work.c_w
    c_imp, c_arm, c_nrm = work.c_imp, work.c_arm, work.c_nrm
    keep = contact_margin(body)
    nc = 0
    for idx in range(ncand):
        n = cand[idx]
        for c in range(3):
            v_pre[c, n] = v1[c, n]
        d = (x1[0, n] - centre[0], x1[1, n] - centre[1], x1[2, n] - centre[2])
        g, r, nh = surface_point(body, rot, d)
        stuck = was[3, n] == STICK
        if not (g < 0.0 or (was[3, n] != 0.0 and g < keep)):
            continue
        if stuck:
            # where the material point it stuck to has moved
            r = mat_vec(rot, (was[0, n], was[1, n], was[2, n]))
            _g, _r, nh = surface_point(body, rot, r)
        wr = cross(omega, r)
        vs = (vel[0] + wr[0], vel[1] + wr[1], vel[2] + wr[2])
        m = mass[n]
        # a node that slid in the previous step stops only where kinetic friction stops it
        j, slid = contact_impulse(m, (v1[0, n], v1[1, n], v1[2, n]), vs, nh, law,
                                  KINETIC if was[3, n] == SLIDE else 0)
        if j[0] == 0.0 and j[1] == 0.0 and j[2] == 0.0:
            # separating: let go; a node inside is still put on the surface where it is (the
            # move carries no momentum)
            if g < 0.0:
                _g, r, nh = surface_point(body, rot, d)
                for c in range(3):
                    x1[c, n] = centre[c] + r[c]
            continue
        if slid or not stuck:
            # a node that slides (or sticks afresh) is put where its drift with the velocity
            # after the impulse takes it (the tangential part: the normal one is the
            # projection's), as the φ-scheme's step 6 and segment contact do: without it the
            # node keeps the slip of its velocity before the impulse, Δt J_t/m a step
            # (docs/theory.md §5.2); the impulse again there with the same decision, so that
            # its normal part lies along the normal where the reaction acts
            jn = j[0] * nh[0] + j[1] * nh[1] + j[2] * nh[2]
            k = dt / m
            _g, r, nh = surface_point(body, rot, (d[0] + k * (j[0] - jn * nh[0]),
                                                  d[1] + k * (j[1] - jn * nh[1]),
                                                  d[2] + k * (j[2] - jn * nh[2])))
            wr = cross(omega, r)
            vs = (vel[0] + wr[0], vel[1] + wr[1], vel[2] + wr[2])
            j, slid = contact_impulse(m, (v1[0, n], v1[1, n], v1[2, n]), vs, nh, law,
                                      SLIDE if slid else STICK)
        if not slid:
            a = to_body_frame(rot, r)
            for c in range(3):
                now[c, n] = a[c]
        now[3, n] = SLIDE if slid else STICK
        # (segment contact does not move a node in node contact: contact.segment_contact)
        work.flag[n] = SLIDE if slid else STICK
        c_node[nc] = n
        c_node2[nc] = -1
        c_w[0, nc] = 1.0
        c_w[1, nc] = 0.0
        for c in range(3):
            c_imp[c, nc] = j[c]
            c_arm[c, nc] = r[c]
            c_nrm[c, nc] = nh[c]
            x1[c, n] = centre[c] + r[c]
            v1[c, n] += j[c] / m
        nc += 1
    return nc


@njit(cache=True, _nrt=True)
def _friction_work(phys, sin, sout, work, nc, half, omega):
    """The work friction does against the slip over the step [J]: for each of the nc contacts,
    J_t·(s₀ + s₁)/2, the slip velocities s = v_point − v_fabric of the contact point (a node, or
    w_a, w_b of a segment's two nodes) at the start of the step, v_n − h/(2m)(f_n − q v_n × B)
    (the velocity after the previous step's contact), and after the impulses, against the
    surface point's velocity the impulses were computed with (the body's half-step velocity in
    sout.body, `omega`). A contact that sticks (s₀ = s₁ = 0) does no work; one that slides at s
    does μ_d J_n |s|; a node that strikes sliding, μ_d J_n times the mean slip of its impulse.
    The identity split of impulse_dissipation books J_t·(s⁻ + s₁)/2 instead, with s⁻ before
    the impulse: that holds the tangential velocity the step's own force gave the contact too,
    k|J_t|²/2 a step for a contact held by friction, which the placement's work cancels (at
    kilonewton loads hundreds of joules over a run, none of it slip)."""
    nodes, fld = phys.nodes, phys.field
    inv_mass, charge = nodes.inv_mass, nodes.charge
    uni, sourced = uniform_field(fld)
    nf = work.node_field
    x0, v0, f0, v1 = sin.x, sin.v, sin.f, sout.v
    vel = sout.body[BODY_V]
    c_node, c_node2, c_w = work.c_node, work.c_node2, work.c_w
    c_imp, c_arm, c_nrm = work.c_imp, work.c_arm, work.c_nrm
    d = 0.0
    for k in range(nc):
        start = (0.0, 0.0, 0.0)
        after = (0.0, 0.0, 0.0)
        for e in range(2):
            n = c_node[k] if e == 0 else c_node2[k]
            if n < 0:
                continue
            w = c_w[e, k]
            _e, b = node_field_of(uni, sourced, nf, n, (x0[0, n], x0[1, n], x0[2, n]))
            fm = magnetic_force(charge[n], (v0[0, n], v0[1, n], v0[2, n]), b)
            hk = half * inv_mass[n]
            start = (start[0] + w * (v0[0, n] - hk * (f0[0, n] - fm[0])),
                     start[1] + w * (v0[1, n] - hk * (f0[1, n] - fm[1])),
                     start[2] + w * (v0[2, n] - hk * (f0[2, n] - fm[2])))
            after = (after[0] + w * v1[0, n], after[1] + w * v1[1, n], after[2] + w * v1[2, n])
        wr = cross(omega, (c_arm[0, k], c_arm[1, k], c_arm[2, k]))
        u = (vel[0] + wr[0], vel[1] + wr[1], vel[2] + wr[2])
        nh = (c_nrm[0, k], c_nrm[1, k], c_nrm[2, k])
        jv = (c_imp[0, k], c_imp[1, k], c_imp[2, k])
        jn = jv[0] * nh[0] + jv[1] * nh[1] + jv[2] * nh[2]
        for c in range(3):
            d += (jv[c] - jn * nh[c]) * 0.5 * ((u[c] - start[c]) + (u[c] - after[c]))
    return d


@njit(cache=True, _nrt=True)
def _body_field_work(phys, b0, b1, t0, t1):
    """Work of the electric field on the body's charges over the step [J] (the mean field at
    the two ends times each charge's displacement)."""
    body, fld = phys.body, phys.field
    w = 0.0
    rot0 = b0[BODY_R0:BODY_R0 + 3]
    rot1 = b1[BODY_R0:BODY_R0 + 3]
    for k in range(body.charge.shape[0]):
        r0 = mat_vec(rot0, body.charge_pos[k])
        r1 = mat_vec(rot1, body.charge_pos[k])
        p0 = (b0[BODY_X, 0] + r0[0], b0[BODY_X, 1] + r0[1], b0[BODY_X, 2] + r0[2])
        p1 = (b1[BODY_X, 0] + r1[0], b1[BODY_X, 1] + r1[1], b1[BODY_X, 2] + r1[2])
        e0, _b0 = field_at(fld, p0, t0)
        e1, _b1 = field_at(fld, p1, t1)
        for c in range(3):
            w += body.charge[k] * 0.5 * (e0[c] + e1[c]) * (p1[c] - p0[c])
    return w


@njit(cache=True, _nrt=True)
def _travel_from_rows(phys, sums, ny, b_state):
    """contact.travel_step at the kick's end state from its per-row largest |v|² and velocity
    bounds (records.SUM_MOTION): the same value (maxima and minima are exact)."""
    fastest = 0.0
    lo = (math.inf, math.inf, math.inf)
    hi = (-math.inf, -math.inf, -math.inf)
    m = SUM_MOTION
    for j in range(ny):
        fastest = max(fastest, sums[m, j])
        lo = (min(lo[0], sums[m + 1, j]), min(lo[1], sums[m + 2, j]), min(lo[2], sums[m + 3, j]))
        hi = (max(hi[0], sums[m + 4, j]), max(hi[1], sums[m + 5, j]), max(hi[2], sums[m + 6, j]))
    return travel_limit(phys, fastest, lo, hi, b_state)


@njit(cache=True, _nrt=False)
def _viscous_base(x0, x1, v, dt, base):
    """base (the drifted positions on entry) = the positions the kick's viscous rate is taken
    from (records.Work.visc_base): x0 where the node is where the drift put it, x1 − Δt v
    (v: its velocity after the contact impulses) where contact placed it."""
    for n in range(x1.shape[1]):
        u = uint64(n)
        if x1[0, u] == base[0, u] and x1[1, u] == base[1, u] and x1[2, u] == base[2, u]:
            base[0, u] = x0[0, u]
            base[1, u] = x0[1, u]
            base[2, u] = x0[2, u]
        else:
            base[0, u] = x1[0, u] - dt * v[0, u]
            base[1, u] = x1[1, u] - dt * v[1, u]
            base[2, u] = x1[2, u] - dt * v[2, u]


@njit(cache=True, nogil=True, _nrt=False)
def central_step(phys, sin, sout, work, rowbuf, threads, plies, segs, t, dt, tol, energy):
    """One central-difference step from sin (at t) to sout (at t + Δt): nodes, body, contact,
    damage committed, the energy terms of the step added to energy (records.ENERGY_TERMS). sin
    is never written.
    Exactly one of rowbuf (ROWBUF_ROWS, nx + 1: the serial force kernel) and threads (blocks,
    ROWBUF_ROWS, nx + 1: the threaded one) is an array, the other None (only the kernel in use
    is compiled); both give the same numbers. plies, segs: an array where the model is a pack
    (ply contact) or its projectile meets segments (phys.contact.segments), else None: Numba
    then leaves that code out of the compiled kernel.

    Returns (status, contacts, stable, travel): stable the explicit stability limit at the new
    state (stable_step's Gershgorin bound, from the force evaluation's tangent stiffnesses)
    [s]; travel its no-tunnelling limit (contact.travel_step's, from the kick's row sums) [s];
    status OK; NOT_FINITE (a non-finite value: Δt too large or the run
    diverged); CONTACT_MISSED (a free node ended inside the body without being a contact
    candidate); BODY_NOT_CONVERGED (the mid-step rotation did not converge).

    The fabric diagnostics of sout (diagnostics.fabric_diagnostics's values, their sums
    rounded in row order) go into work.diag, about the body centre of sout and the flight
    direction in work.frame[1]."""
    nodes, body, fld = phys.nodes, phys.body, phys.field
    inv_mass = nodes.inv_mass
    b_in, b_out = sin.body, sout.body
    t1 = t + dt
    half = 0.5 * dt
    copy_into(b_out, b_in)
    # where the damage law can change α this step (materials.damage_thresholds)
    damage_thresholds(sin.alpha, phys.material, phys.yarns.failure_stretch2,
                      work.damage_thr, work.damage_alpha)
    # contact candidates: nodes that can reach the body within this step (from the start)
    ncand = 0
    nseg = 0
    flag = work.flag
    if body.active:
        # the largest |v|², over integer keys (a loop that vectorises: reductions.py)
        kv = order_key(0.0)
        v0 = sin.v
        for n in range(v0.shape[1]):
            u = uint64(n)
            kv = max(kv, order_key(v0[0, u] ** 2 + v0[1, u] ** 2 + v0[2, u] ** 2))
        vmax = from_key(kv)
        radius = bounding_radius(body)
        speed = norm(b_in[BODY_V]) + radius * norm(b_in[BODY_W])
        reach = 1.05 * radius + 2.0 * dt * (speed + math.sqrt(vmax))
        ncand = find_candidates(sin.x, inv_mass, b_in[BODY_X], reach, work.cand, flag)
        if segs is not None:
            ncand, nseg = find_segment_candidates(phys.yarns, sin.alpha,
                                                  phys.material.broken_below, sin.x,
                                                  inv_mass, b_in[BODY_X], reach, work, ncand)
    else:
        flag[:] = 0
    work.counts[0] = ncand
    work.counts[1] = nseg
    # nodes: the first half kick and rotation at (x_n, t), then the drift
    if with_sources(fld):
        fill_node_fields(fld, sin.x, sin.v, 0.0, t, work.node_field)
    if rowbuf is None:
        if threads is not None:
            drift_rows_threads(phys, sin, sout, work, t, dt, threads)
    else:
        drift_rows(phys, sin, sout, work, t, dt, rowbuf)
    sums = work.row_sums
    ny = nodes.ny
    w_field = _sum_rows(sums[SUM_WORK_FIELD], ny)
    w_grav = _sum_rows(sums[SUM_WORK_GRAVITY], ny)
    viscous = phys.yarns.damping.size > 0
    w_visc = _sum_rows(sums[SUM_WORK_VISCOUS], ny) if viscous else 0.0
    if viscous:
        # the drifted positions, against which _viscous_base tells the placed nodes
        copy_into(work.visc_base, sout.x)
    contact = sout.contact
    for c in range(4):  # row by row: contiguous stores
        for n in range(contact.shape[1]):
            contact[c, uint64(n)] = 0.0
    # body: half kick of V and H, the drift of the centre and the rotation
    scratch = work.body_scratch
    reaction = work.reaction
    for c in range(3):
        reaction[0, c] = 0.0
        reaction[1, c] = 0.0
    nc = 0
    h_half = (0.0, 0.0, 0.0)
    w_pre = (0.0, 0.0, 0.0)
    if body.active:
        mass = body.mass
        rot0 = b_in[BODY_R0:BODY_R0 + 3]
        rot1 = b_out[BODY_R0:BODY_R0 + 3]
        h0 = world_inertia_times(rot0, body.inertia, vec(b_in[BODY_W]))
        h_half = (h0[0] + half * b_in[BODY_M, 0], h0[1] + half * b_in[BODY_M, 1],
                  h0[2] + half * b_in[BODY_M, 2])
        for c in range(3):
            v_half = b_in[BODY_V, c] + half * b_in[BODY_F, c] / mass
            w_grav += half * mass * fld.gravity[c] * 0.5 * (b_in[BODY_V, c] + v_half)
            b_out[BODY_V, c] = v_half
            b_out[BODY_X, c] = b_in[BODY_X, c] + dt * v_half
        _w_mid, ok = _mid_rotation(body, rot0, h_half, dt, tol, scratch, rot1)
        if not ok:
            return BODY_NOT_CONVERGED, 0, math.inf, math.inf
        # the angular velocity at the new rotation before contact: the surface's velocity
        w_pre = _spin_solve(rot1, body, h_half, scratch)
        for c in range(3):
            b_out[BODY_W, c] = w_pre[c]
        # contact and friction at the drifted positions (kept for the energy bookkeeping)
        for idx in range(ncand):
            n = work.cand[idx]
            for c in range(3):
                work.xbuf[c, n] = sout.x[c, n]
        nc = _node_contact(phys, sin, sout, work, ncand, dt)
        if segs is not None:
            seg_modes = sout.seg_contact
            for s in range(seg_modes.shape[0]):
                seg_modes[s] = 0.0
            nc = segment_contact(phys, b_out, nseg, nc, sout.x, sout.v, work, dt,
                                 sin.seg_contact, seg_modes)
        reaction_sums(nc, work.c_imp, work.c_arm, work.sum_buf, reaction[0], reaction[1])
    # energy of the contacts (velocities before and after the impulses, at the half step)
    d_cont = 0.0
    d_fric = 0.0
    if body.active:
        h_after = (h_half[0] + reaction[1, 0], h_half[1] + reaction[1, 1],
                   h_half[2] + reaction[1, 2])
        rot1 = b_out[BODY_R0:BODY_R0 + 3]
        w_post = _spin_solve(rot1, body, h_after, scratch)
        mass = body.mass
        v_mean = (b_out[BODY_V, 0] + 0.5 * reaction[0, 0] / mass,
                  b_out[BODY_V, 1] + 0.5 * reaction[0, 1] / mass,
                  b_out[BODY_V, 2] + 0.5 * reaction[0, 2] / mass)
        w_mean = (0.5 * (w_pre[0] + w_post[0]), 0.5 * (w_pre[1] + w_post[1]),
                  0.5 * (w_pre[2] + w_post[2]))
        d_cont, d_fric = impulse_dissipation(nc, work, work.v_pre, sout.v, v_mean, w_mean)
        # friction is booked as the work it does against the slip (_friction_work); the
        # kinetic energy its impulse takes beyond that (what the step's force gave a contact
        # before the impulse, ~k|J_t|²/2 a step: O(Δt) in all, which the placement's work
        # cancels) goes with the normal part: the two still add up to what the impulses remove
        d_slip = _friction_work(phys, sin, sout, work, nc, half, w_pre)
        d_cont += d_fric - d_slip
        d_fric = d_slip
        # the body after the impulses, then its field wrench and the second half kick
        for c in range(3):
            b_out[BODY_V, c] += reaction[0, c] / body.mass
            b_out[BODY_W, c] = w_post[c]
        field_wrench(body, fld, t1, b_out, b_out[BODY_F], b_out[BODY_M])
        h1 = (h_after[0] + half * b_out[BODY_M, 0], h_after[1] + half * b_out[BODY_M, 1],
              h_after[2] + half * b_out[BODY_M, 2])
        for c in range(3):
            v_half = b_out[BODY_V, c]
            v_end = v_half + half * b_out[BODY_F, c] / body.mass
            w_grav += half * body.mass * fld.gravity[c] * 0.5 * (v_half + v_end)
            b_out[BODY_V, c] = v_end
        w1 = _spin_solve(rot1, body, h1, scratch)
        for c in range(3):
            b_out[BODY_W, c] = w1[c]
        if has_electric_field(fld):
            w_field += _body_field_work(phys, b_in, b_out, t, t1)
    # plies meet their neighbours after the projectile's contact: the nodes it touches are
    # where it put them, and act in ply contact as of infinite mass (plies.ply_contact)
    d_ply = 0.0
    w_ply = 0.0
    if plies is not None:
        d_ply, w_ply = ply_contact(phys, sin, sout.x, sout.v, work, half, sout.contact[3])
    if viscous:
        _viscous_base(sin.x, sout.x, sout.v, dt, work.visc_base)
    # the forces at the new positions and time (the one force evaluation of the step), the
    # second half rotation and kick
    if with_sources(fld):
        fill_node_fields(fld, sout.x, sout.v, 0.0, t1, work.node_field)
    for c in range(3):
        work.frame[0, c] = b_out[BODY_X, c] if body.active else 0.0
    if rowbuf is None:
        if threads is not None:
            kick_rows_threads(phys, sin, sout, work, t1, dt, threads)
    else:
        kick_rows(phys, sin, sout, work, t1, dt, rowbuf)
    # the history record's fabric diagnostics of the end state, from the kick's row shares,
    # and the next step's no-tunnelling limit
    fabric_from_rows(sums, ny, work.diag)
    travel = _travel_from_rows(phys, sums, ny, b_out)
    w_field += _sum_rows(sums[SUM_WORK_FIELD], ny)
    w_grav += _sum_rows(sums[SUM_WORK_GRAVITY], ny)
    if viscous:
        w_visc += _sum_rows(sums[SUM_WORK_VISCOUS], ny)
    # the work of the node force over the displacement the kicks do not see: the kicks book
    # h/2 f·v̄ with the velocity before contact in the first and after it in the second, i.e. a
    # displacement h (v⁻ + v⁺)/2, while the node moved h v⁻ and then was placed: the difference
    # is the placement jump less h/2 of the contact's velocity change (nodes._kick_block)
    d_proj = _sum_rows(sums[SUM_PROJECTION], ny)
    size = _sum_rows(sums[SUM_SPEED], ny)
    worst = 0.0
    for j in range(ny):
        worst = max(worst, sums[SUM_STIFFNESS, j])
    d_dam = damage_release(phys.yarns, phys.material, sin.x, sout.x, sin.alpha, sout.alpha,
                           0.5)
    energy[ENERGY_WORK_FIELD] += w_field
    energy[ENERGY_WORK_GRAVITY] += w_grav
    energy[ENERGY_FRICTION] += d_fric
    energy[ENERGY_CONTACT] += d_cont + d_ply
    energy[ENERGY_PROJECTION] += d_proj + w_ply
    energy[ENERGY_DAMAGE] += d_dam
    energy[ENERGY_VISCOUS] -= w_visc
    total = w_field + w_grav + d_cont + d_fric + d_proj + d_dam + size + d_ply + w_ply + w_visc
    for c in range(3):
        total += b_out[BODY_V, c] + b_out[BODY_W, c]
    stable = 2.0 / math.sqrt(worst) if worst > 0.0 else math.inf
    if not math.isfinite(total):
        return NOT_FINITE, nc, stable, travel
    if body.active and nodes_inside(sout.x, inv_mass, flag, body, b_out) > 0:
        return CONTACT_MISSED, nc, stable, travel
    return OK, nc, stable, travel
