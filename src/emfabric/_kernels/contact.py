"""Node–body contact with stick/slip friction as an impulse exchange (section 4, eqs. 4.5–4.11).

A node predicted inside the body is moved to the closest surface point (4.5, 5.1; the shape's
``surface_point``); this projection carries no momentum. ``contact_impulse`` is the
contact law: the node is first made to stick to the body's surface point velocity v_cm + ω × r
(4.6, 4.9); the velocity jump times the node mass is the contact impulse J. Its normal part
never pulls (a separating node is let go); if the tangential part exceeds μ_s times the normal
part (4.8) the node slides with a tangential impulse μ_d·|J_n| along the relative sliding
velocity (4.10–4.11). The body receives −J at the contact point.
"""

import math

from numba import njit, uint64

from emfabric._kernels.records import (
    BODY_R0,
    BODY_V,
    BODY_W,
    BODY_X,
    ROW_COUNT,
    SUM_ERROR_DEN,
    SUM_ERROR_NUM,
)
from emfabric._kernels.reductions import SCAN_BLOCK
from emfabric._kernels.shapes import (
    bounding_radius,
    contact_margin,
    pressing_point,
    surface_point,
    thinnest_radius,
)
from emfabric._kernels.sums import fsum
from emfabric._kernels.vec3 import cross, distance_sq, norm

STICK, SLIDE = 2, 3
"""work.flag of a node in contact at the latest iterate: sticking, sliding (0: no candidate,
1: candidate not in contact)."""
KINETIC = 4
"""coulomb_cone's mode for a contact that slid in the previous step (central differences): it
sticks only where μ_d times its normal impulse stops it. Static friction holds a contact at
rest; a sliding one stops when kinetic friction has taken its slip. The test with μ_s would
also stop a contact whose slip exceeds what kinetic friction takes in the step by up to
(μ_s − μ_d) F_n Δt/m (docs/theory.md §5.2, "Kinetic friction until the slip stops")."""

FREEZE_AFTER = 3
"""Iterations of an attempt after which each contact keeps the stick or slide decision of the
previous iterate (and a contact is kept within shapes.contact_margin outside the surface)."""


@njit(cache=True, inline="always")
def contact_impulse(m, v_node, v_surface, n, law, mode):
    """Impulse J [N s] on a node of mass m at velocity v_node touching a surface point moving at
    v_surface, with outward normal n, under the Contact record `law`, and whether it slides.

    mode 0 decides stick or slide by the Coulomb check; KINETIC by the same check with μ_d in
    place of μ_s (a contact that slid in the previous step); STICK or SLIDE imposes that
    decision (an attempt's late iterates keep the previous iterate's: the switch is a jump in
    J, and a fixed-point iteration across a jump cycles instead of converging)."""
    return coulomb_cone((m * (v_surface[0] - v_node[0]), m * (v_surface[1] - v_node[1]),
                         m * (v_surface[2] - v_node[2])), n, law, mode)


@njit(cache=True, inline="always")
def coulomb_cone(j, n, law, mode):
    """The impulse j that would make a contact of outward normal n stick, cut to what the
    contact law gives, and whether it slides: nothing where its normal part would pull; j
    itself where its tangential part is at most μ_s times the normal part (stick, eq. 4.8; μ_d
    times it with mode KINETIC); else the normal part and μ_d times it along the tangential
    part (slide, eq. 4.11). mode as contact_impulse's."""
    jx, jy, jz = j
    jn = jx * n[0] + jy * n[1] + jz * n[2]
    if jn > 0.0:
        tx = jx - jn * n[0]
        ty = jy - jn * n[1]
        tz = jz - jn * n[2]
        jt = math.sqrt(tx * tx + ty * ty + tz * tz)
        # Coulomb check, eq. 4.8 (with μ_d for a contact that was sliding: KINETIC); slide with
        # μ_d along the sliding velocity, eq. 4.11
        if mode == 0:
            slide = jt > law.static_friction * jn
        elif mode == KINETIC:
            slide = jt > law.dynamic_friction * jn
        else:
            slide = mode == SLIDE
        if slide and jt > 0.0:
            scale = law.dynamic_friction * jn / jt
            return (jn * n[0] + scale * tx, jn * n[1] + scale * ty, jn * n[2] + scale * tz), True
        return (jx, jy, jz), False
    # separating: the normal impulse never pulls, and without it no friction
    return (0.0, 0.0, 0.0), False


PLY_DAMPING = 1.0
"""The φ-scheme's ply contact: damping ratio of the normal penalty (critical: a pair in contact
does not rebound, as the impulse law of central differences is inelastic)."""
PLY_DAMPING_RAMP = 0.05
"""The damping grows from nothing at first contact to its full value at this overlap, as a
fraction of the contact distance (continuous: a force that jumps as a pair comes into contact
is one a fixed point cannot converge across)."""
PLY_CLOSE = 0.5
"""The φ-scheme's ply contact stiffens as k/(1 − o/d) (o the overlap, d the contact distance) up
to o = PLY_CLOSE·d (tangent 4k there) and goes on linearly beyond: a penalty of constant
stiffness let an FSP's point load (kN through one node) close an 8-ply pack's top gap
completely (tests/test_plies.py). Stiffening on to 0.9 d (tangent 100 k) kept the gap no better
and put the φ-scheme's oblique ogive run on a free pack 5 % off its energy budget."""
PLY_STICK = 0.5
"""The φ-scheme's ply friction: below the Coulomb force μ_d F_n it is viscous, −c_t v_t with
c_t = PLY_STICK·m_nk/(φΔt): a step removes at most half the pair's relative sliding at its
start (the friction is taken from the start-of-step velocities: a friction of the iterate's
would contract the fixed point by a ratio that does not fall with Δt, and the step controller
would then never let Δt grow back)."""


@njit(cache=True, inline="always")
def ply_penalty(share, stiff, gap, g, m_nk, nh, v, v0, n, km, law, phi_dt):
    """The φ-scheme's ply contact force on node n from node km of the other ply (−it on km;
    plies.ply_forces): the share of a damped normal penalty, never pulling,
    F_n = max(k·o/(1 − o/d) − c·v_N·min(o/(PLY_DAMPING_RAMP·d), 1), 0) with o = d − g the
    overlap, k = stiff, d = gap (continued linearly beyond o = PLY_CLOSE·d), c = 2ζ√(k_t·m_nk)
    with the tangent stiffness k_t = k/(1 − o/d)², v_N the relative normal velocity along nh
    (the damping grows from nothing where contact begins: Hunt–Crossley), and friction
    −min(μ_d F_n/|v_t|, c_t)·v_t against the relative sliding velocity v_t at the start of the
    step (v0; Coulomb's, viscous where it would stop the sliding at once: PLY_STICK). The
    normal part takes the iterate's velocities v. Mirror-exact formulas (sums of squares as ply
    contact's others)."""
    rx = v[0, n] - v[0, km]
    ry = v[1, n] - v[1, km]
    rz = v[2, n] - v[2, km]
    rn = (nh[0] * rx + nh[1] * ry) + nh[2] * rz
    overlap = gap - g
    # stiffening as the mid-planes close (a fabric's through-thickness compaction): k_t =
    # k/(1 − o/d)², linear with the slope it has at o = PLY_CLOSE·d beyond
    close = PLY_CLOSE * gap
    if overlap < close:
        left = 1.0 - overlap / gap
        elastic = stiff * overlap / left
        tangent = stiff / (left * left)
    else:
        left = 1.0 - PLY_CLOSE
        tangent = stiff / (left * left)
        elastic = stiff * close / left + tangent * (overlap - close)
    c = 2.0 * PLY_DAMPING * math.sqrt(tangent * m_nk)
    # damping grows with the overlap from nothing where contact begins (Hunt–Crossley): a
    # force that jumps as a pair comes into contact is one a fixed point cannot converge across
    fn = share * max(elastic - c * rn * min(overlap / (PLY_DAMPING_RAMP * gap), 1.0), 0.0)
    sx = v0[0, n] - v0[0, km]
    sy = v0[1, n] - v0[1, km]
    sz = v0[2, n] - v0[2, km]
    sn = (nh[0] * sx + nh[1] * sy) + nh[2] * sz
    tx = sx - sn * nh[0]
    ty = sy - sn * nh[1]
    tz = sz - sn * nh[2]
    vt = math.sqrt((tx * tx + ty * ty) + tz * tz)
    stick = PLY_STICK * share * m_nk / phi_dt
    k = min(law.dynamic_friction * fn / vt, stick) if vt > 0.0 else 0.0
    return fn * nh[0] - k * tx, fn * nh[1] - k * ty, fn * nh[2] - k * tz


@njit(cache=True, _nrt=True)
def find_candidates(x, inv_mass, centre, reach, cand, flag):
    """Free nodes within `reach` of the body centre; returns their count."""
    count = 0
    r2 = reach * reach
    c = (centre[0], centre[1], centre[2])
    nodes = x.shape[1]
    for b0 in range(0, nodes, SCAN_BLOCK):
        b1 = min(nodes, b0 + SCAN_BLOCK)
        # the flags, and how many are set, in a loop that vectorises; the candidates listed
        # only from blocks that have any (reductions.SCAN_BLOCK)
        near = 0
        for n in range(b0, b1):
            u = uint64(n)
            hit = (inv_mass[u] > 0.0) & (distance_sq(x, u, c) < r2)
            flag[u] = 1 if hit else 0
            near += 1 if hit else 0
        if near == 0:
            continue
        for n in range(b0, b1):
            if flag[n] != 0:
                cand[count] = n
                count += 1
    return count


SEGMENT_SWEEPS = 256
"""The most Jacobi passes of segment contact per call: a guard, not the criterion. The passes
stop when no contact point is inside by more than SEGMENT_INSIDE and none's velocity changes by
more than SEGMENT_SETTLED; the ogive at the default step needs 33 passes on average, 47 at most
(8, the cap before, left the shared corrections unconverged at kN loads: docs/theory.md §5.2)."""
SEGMENT_INSIDE = 1e-9
"""A contact point inside the body by less than this fraction of its bounding radius counts as
on the surface (the round-off of the move to the surface: 2e-11 m for a body 2 cm across)."""
SEGMENT_SETTLED = 1e-9
"""Velocity change at every contact point that ends the passes, as a fraction of the body's
speed scale |v| + R|ω|."""


@njit(cache=True, _nrt=True)
def find_segment_candidates(yarns, alpha, broken_below, x, inv_mass, centre, reach, work,
                            ncand):
    """Unbroken segments with a free end that pass within `reach` of the body centre (at the
    positions x); their free end nodes join the node candidates. Returns the new node-candidate
    count and the segment count."""
    ends = yarns.ends
    cand, flag, seg_cand = work.cand, work.flag, work.seg_cand
    r2 = reach * reach
    count = 0
    for s in range(ends.shape[0]):
        a = ends[s, 0]
        b = ends[s, 1]
        if (inv_mass[a] == 0.0 and inv_mass[b] == 0.0) or alpha[s] <= broken_below:
            continue
        # from the midpoint, odd in the half-vector: the same test read from either end
        mx = 0.5 * (x[0, a] + x[0, b]) - centre[0]
        my = 0.5 * (x[1, a] + x[1, b]) - centre[1]
        mz = 0.5 * (x[2, a] + x[2, b]) - centre[2]
        hx = 0.5 * (x[0, b] - x[0, a])
        hy = 0.5 * (x[1, b] - x[1, a])
        hz = 0.5 * (x[2, b] - x[2, a])
        hh = hx * hx + hy * hy + hz * hz
        t = -(mx * hx + my * hy + mz * hz) / hh if hh > 0.0 else 0.0
        t = min(max(t, -1.0), 1.0)
        px, py, pz = mx + t * hx, my + t * hy, mz + t * hz
        if px * px + py * py + pz * pz < r2:
            seg_cand[count] = s
            work.seg_active[count] = 0
            count += 1
            for node in (a, b):
                if flag[node] == 0 and inv_mass[node] > 0.0:
                    flag[node] = 1
                    cand[ncand] = node
                    ncand += 1
    # in node order, as find_candidates gives them: the error terms are then added in the same
    # order in a mirrored run
    cand[:ncand].sort()
    return ncand, count


@njit(cache=True, _nrt=True)
def node_contact(nodes, body, law, b_state, ncand, x1, v1, work, phi, dt, frozen):
    """Resolve contact of the candidate nodes against the body in the state b_state.

    A node inside is given the contact law's impulse J and put on the body's surface where the
    φ-update with its velocity after contact takes it: the closest surface point to
    x1 + φΔt·J/m (a sticking node moves with the surface; moving it only to the closest point
    of its free-flight position left its tangential position lagging the surface by φΔt J_t/m
    every step, an O(Δt) error in the spin: docs/theory.md §5, docs/performance.md (e)). A
    contact kept within the margin outside the surface and given an impulse is put on the
    surface the same way. When `frozen` (late iterates of an attempt) a contact keeps the
    stick/slide decision of the previous iterate, and a node in contact at the previous
    iterate keeps its contact while it stays within
    shapes.contact_margin outside the surface (so does any contact with segment contact on):
    neither then switches on and off from one iterate to the next. Keeps the candidates'
    velocities before contact (work.v_pre), writes corrected x1, v1 and records per contact
    the node, the impulse J on the node [N s], the arm r = x_cp − centre [m] and the outward
    normal; work.flag is STICK or SLIDE for a node in contact. Returns the number of contacts.
    """
    mass = nodes.mass
    cand = work.cand
    v_pre = work.v_pre
    c_node, c_node2, c_w = work.c_node, work.c_node2, work.c_w
    c_imp, c_arm, c_nrm = work.c_imp, work.c_arm, work.c_nrm
    centre = b_state[BODY_X]
    vel = b_state[BODY_V]
    omega = (b_state[BODY_W, 0], b_state[BODY_W, 1], b_state[BODY_W, 2])
    rot = b_state[BODY_R0:BODY_R0 + 3]
    flag = work.flag
    keep = contact_margin(body) if (law.segments or frozen) else 0.0
    nc = 0
    for idx in range(ncand):
        n = cand[idx]
        for c in range(3):
            v_pre[c, n] = v1[c, n]
        d = (x1[0, n] - centre[0], x1[1, n] - centre[1], x1[2, n] - centre[2])
        g, r, nh = surface_point(body, rot, d)
        was = flag[n]
        if g < 0.0 or (was >= STICK and g < keep):
            # stick: the surface point's velocity, eqs. 4.6, 4.9
            wr = cross(omega, r)
            vs = (vel[0] + wr[0], vel[1] + wr[1], vel[2] + wr[2])
            m = mass[n]
            mode = was if (frozen and was >= STICK) else 0
            j, slid = contact_impulse(m, (v1[0, n], v1[1, n], v1[2, n]), vs, nh, law, mode)
            c_node[nc] = n
            c_node2[nc] = -1
            c_w[0, nc] = 1.0
            c_w[1, nc] = 0.0
            moved = g < 0.0
            if phi > 0.0 and (j[0] != 0.0 or j[1] != 0.0 or j[2] != 0.0):
                # where the φ-update with the velocity after contact puts the node, on the
                # surface
                h = phi * dt / m
                _g, r, nh = surface_point(body, rot, (d[0] + h * j[0], d[1] + h * j[1],
                                                      d[2] + h * j[2]))
                # the impulse again, at that point (the same decision): its normal part along
                # the normal where the reaction acts (through a sphere's centre)
                wr = cross(omega, r)
                vs = (vel[0] + wr[0], vel[1] + wr[1], vel[2] + wr[2])
                j, slid = contact_impulse(m, (v1[0, n], v1[1, n], v1[2, n]), vs, nh, law,
                                          SLIDE if slid else STICK)
                moved = True
            # the reaction acts where the node is put: on the surface, or (a contact kept
            # outside and not moved) where it is
            arm = r if moved else d
            for c in range(3):
                c_imp[c, nc] = j[c]
                c_arm[c, nc] = arm[c]
                c_nrm[c, nc] = nh[c]
            if moved:
                x1[0, n] = centre[0] + r[0]
                x1[1, n] = centre[1] + r[1]
                x1[2, n] = centre[2] + r[2]
            flag[n] = SLIDE if slid else STICK
            im = 1.0 / m
            for c in range(3):
                v1[c, n] += j[c] * im
            nc += 1
        elif was >= STICK:
            flag[n] = 1
    return nc


@njit(cache=True, inline="always")
def _segment_point(x1, a, b, centre, body, rot):
    """Weights (w_a, w_b) and position relative to the centre of the point where segment (a, b)
    presses against the body (shapes.pressing_point), symmetric in a and b."""
    m = (0.5 * (x1[0, a] + x1[0, b]) - centre[0], 0.5 * (x1[1, a] + x1[1, b]) - centre[1],
         0.5 * (x1[2, a] + x1[2, b]) - centre[2])
    h = (0.5 * (x1[0, b] - x1[0, a]), 0.5 * (x1[1, b] - x1[1, a]), 0.5 * (x1[2, b] - x1[2, a]))
    tau = pressing_point(body, rot, m, h)
    d = (m[0] + tau * h[0], m[1] + tau * h[1], m[2] + tau * h[2])
    return 0.5 * (1.0 - tau), 0.5 * (1.0 + tau), d


@njit(cache=True)
def _drift_segment_ends(inv_mass, first, nc, x1, work, lag):
    """segment_contact's move of the end nodes of its contacts first … nc−1 by lag × the
    tangential part of their velocity change (summed per yarn family, as the sweeps sum: the
    result does not depend on the order of the contacts)."""
    share, acc, flag = work.share, work.acc, work.flag
    c_node, c_node2, c_w = work.c_node, work.c_node2, work.c_w
    c_imp, c_nrm = work.c_imp, work.c_nrm
    for kc in range(first, nc):
        for node in (c_node[kc], c_node2[kc]):
            share[0, node] = 0.0
            for f in range(2):
                for c in range(3):
                    acc[0, f, c, node] = 0.0
    for kc in range(first, nc):
        a = c_node[kc]
        b = c_node2[kc]
        jn = c_imp[0, kc] * c_nrm[0, kc] + c_imp[1, kc] * c_nrm[1, kc] + c_imp[2, kc] * c_nrm[2, kc]
        jt = (c_imp[0, kc] - jn * c_nrm[0, kc], c_imp[1, kc] - jn * c_nrm[1, kc],
              c_imp[2, kc] - jn * c_nrm[2, kc])
        fam = 0 if b - a == 1 else 1
        for node, w in ((a, c_w[0, kc]), (b, c_w[1, kc])):
            if flag[node] >= STICK:
                continue
            share[0, node] = 1.0
            wi = lag * w * inv_mass[node]
            for c in range(3):
                acc[0, fam, c, node] += wi * jt[c]
    for kc in range(first, nc):
        for node in (c_node[kc], c_node2[kc]):
            if share[0, node] > 0.0:
                for c in range(3):
                    x1[c, node] += acc[0, 0, c, node] + acc[0, 1, c, node]
                share[0, node] = 0.0


@njit(cache=True, _nrt=True)
def segment_contact(phys, b_state, nseg, nc, x1, v1, work, lag, was, now):
    """Resolve contact of the candidate segments (phys: the Physics record) against the body,
    after node contact.

    A segment presses on the body at its point P = w_a x_a + w_b x_b nearest the body's axis
    (shapes.pressing_point). If P is inside, it is moved to the closest surface point and given
    the contact law's impulse J for the effective mass 1/(w_a²/m_a + w_b²/m_b) of that point;
    the end nodes share the move and J in proportion w/m, so that P lands on the surface and
    node a receives w_a J, node b w_b J (their sum J; moment P × J).

    All segments are resolved from the same positions and velocities (Jacobi). Where several
    segment contacts share a node, each is scaled by its share of their penetration depths at
    that node (the smaller share of its two nodes): the corrections a node receives never add
    up to more than one full correction (no overshoot), and the share varies continuously as a
    segment enters or leaves the body (a count would jump, and the fixed-point iteration would
    cycle). The pass is repeated on the corrected positions and velocities for the segments in
    contact, until none is inside (SEGMENT_INSIDE) and no contact point's velocity changes by
    more than SEGMENT_SETTLED of the body's speed (SEGMENT_SWEEPS passes at most, a guard),
    each contact's impulses adding up, so that the shared corrections converge to the full
    ones; the later passes visit only the segments the first found in contact. With lag > 0
    (central differences) each pass adds its share of the stick impulse to the sum of the
    passes' and cuts that sum to the Coulomb cone (coulomb_cone), so that the passes converge
    to impulses that obey the contact law at every point at once; cut pass by pass, a pass
    whose own normal impulse is small (a point already held) could not stop the slip its
    neighbours gave it, and friction fell short of μ_d (docs/theory.md §5.2). The φ-scheme
    (lag = 0) keeps the pass-by-pass cut: its fixed point did not converge across the sum's
    stick and slide decisions. As for
    nodes, a segment in contact earlier in the step keeps its contact within
    shapes.contact_margin outside the surface (impulse, no move). Each node sums its warp and
    its fill contributions apart: the result does not depend on the order of the segments, so
    mirror images stay mirror images.

    With lag > 0 (central differences: lag = Δt) the end nodes of the segments in contact are
    then moved by lag times the tangential part of the velocity change their impulses gave
    them (w J_t/m for each of their contacts, J_t the impulse less its part along the contact's
    normal), except a node in node contact itself (work.flag STICK or SLIDE), which its own
    placement puts: the drift x_{n+1} = x_n + Δt v_{n+½} redone with the velocity after
    contact. Without it a sticking segment point keeps the tangential drift of its free flight
    every step (nodes are put at their material point instead), the next step's impulse takes
    that back as well, and the friction it needs grows with it: at the default step the
    ogive's segments stuck where converged runs slide (docs/theory.md §5.2). The φ-scheme
    passes lag = 0 (no move: its bits are those of the paper's scheme as shipped).

    was, now: each segment's contact mode at the start and the end of the step (0 none,
    STICK, SLIDE; StateArrays.seg_contact), by segment; a segment in contact that slid in the
    previous step is cut with mode KINETIC. now must hold zeros; each contact's last cut
    writes it. (0,)-long arrays keep no modes (the φ-scheme: the paper's law, μ_s always).
    Appends the contacts after the first nc; returns the new count.
    """
    body, law = phys.body, phys.contact
    inv_mass = phys.nodes.inv_mass
    ends = phys.yarns.ends
    seg_cand, share, acc = work.seg_cand, work.share, work.acc
    active, slot, tmp, seg_list = work.seg_active, work.seg_slot, work.seg_tmp, work.seg_list
    c_node, c_node2, c_w = work.c_node, work.c_node2, work.c_w
    c_imp, c_arm, c_nrm = work.c_imp, work.c_arm, work.c_nrm
    keep = contact_margin(body)
    centre = b_state[BODY_X]
    vel = b_state[BODY_V]
    omega = (b_state[BODY_W, 0], b_state[BODY_W, 1], b_state[BODY_W, 2])
    rot = b_state[BODY_R0:BODY_R0 + 3]
    first = nc
    for idx in range(nseg):
        slot[idx] = -1
    # a velocity change below this at every contact point ends the sweeps [m/s]
    settled = SEGMENT_SETTLED * (
        math.sqrt(vel[0] * vel[0] + vel[1] * vel[1] + vel[2] * vel[2])
        + bounding_radius(body) * math.sqrt(omega[0] * omega[0] + omega[1] * omega[1]
                                            + omega[2] * omega[2]))
    inside = -SEGMENT_INSIDE * bounding_radius(body)
    # the first pass visits every candidate and lists those in contact; the later passes
    # revisit only these (a pass then costs the contacts, not the candidates)
    listed = 0
    for sweep in range(SEGMENT_SWEEPS):
        visit = nseg if sweep == 0 else listed
        for i in range(visit):
            idx = i if sweep == 0 else seg_list[i]
            for node in (ends[seg_cand[idx], 0], ends[seg_cand[idx], 1]):
                for f in range(2):
                    share[f, node] = 0.0
                    for q in range(2):
                        for c in range(3):
                            acc[q, f, c, node] = 0.0
        found = 0
        inside_count = 0
        for i in range(visit):
            idx = i if sweep == 0 else seg_list[i]
            tmp[6, idx] = 0.0
            s = seg_cand[idx]
            a = ends[s, 0]
            b = ends[s, 1]
            if sweep == 0:
                wa, wb, d = _segment_point(x1, a, b, centre, body, rot)
            else:
                # the same material point of the segment as in the first pass, so that each
                # node's share of the summed impulse is w J with one w (energy and moments)
                wa = c_w[0, slot[idx]]
                wb = c_w[1, slot[idx]]
                d = (wa * (x1[0, a] - centre[0]) + wb * (x1[0, b] - centre[0]),
                     wa * (x1[1, a] - centre[1]) + wb * (x1[1, b] - centre[1]),
                     wa * (x1[2, a] - centre[2]) + wb * (x1[2, b] - centre[2]))
            k = wa * wa * inv_mass[a] + wb * wb * inv_mass[b]
            if not k > 0.0:
                continue
            g, r, nh = surface_point(body, rot, d)
            if not (g < 0.0 or (active[idx] == 1 and g < keep)):
                continue
            active[idx] = 1
            wr = cross(omega, r)
            vs = (vel[0] + wr[0], vel[1] + wr[1], vel[2] + wr[2])
            vp = (wa * v1[0, a] + wb * v1[0, b], wa * v1[1, a] + wb * v1[1, b],
                  wa * v1[2, a] + wb * v1[2, b])
            # the impulse that would make the point stick; cut to the law on the sum of the
            # passes' impulses below (the cone of the contact's whole normal impulse)
            m = 1.0 / k
            j = (m * (vs[0] - vp[0]), m * (vs[1] - vp[1]), m * (vs[2] - vp[2]))
            if slot[idx] < 0:
                seg_list[listed] = idx
                listed += 1
                slot[idx] = nc
                c_node[nc] = a
                c_node2[nc] = b
                for c in range(3):
                    c_imp[c, nc] = 0.0
                nc += 1
            kc = slot[idx]
            c_w[0, kc] = wa
            c_w[1, kc] = wb
            for c in range(3):
                c_nrm[c, kc] = nh[c]
                tmp[c, idx] = j[c]
                tmp[3 + c, idx] = r[c] - d[c]
            # weight of this contact among those at its nodes: keep − g, continuous as the
            # segment enters (g = 0) and leaves (g = keep)
            dep = keep - g
            tmp[6, idx] = dep
            if g < inside:
                inside_count += 1
            fam = 0 if b - a == 1 else 1
            share[fam, a] += dep
            share[fam, b] += dep
            found += 1
        if found == 0:
            break
        worst = 0.0
        for i in range(listed):
            idx = seg_list[i]
            dep = tmp[6, idx]
            if dep == 0.0:
                continue
            s = seg_cand[idx]
            a = ends[s, 0]
            b = ends[s, 1]
            kc = slot[idx]
            wa = c_w[0, kc]
            wb = c_w[1, kc]
            fam = 0 if b - a == 1 else 1
            k = wa * wa * inv_mass[a] + wb * wb * inv_mass[b]
            total = max(share[0, a] + share[1, a], share[0, b] + share[1, b])
            scale = dep / total if total > 0.0 else 1.0
            # only a point inside is moved (to the surface); a kept contact outside is not
            move = scale / k if dep > keep else 0.0
            if lag > 0.0:
                # the passes' impulses so far plus this pass's share of the stick impulse, cut
                # to the Coulomb cone as a whole: a pass whose own normal impulse is small (the
                # point already held) still stops the slip its neighbours' impulses gave it,
                # as far as the contact's whole normal impulse allows
                kinetic = was.shape[0] > 0 and was[s] == SLIDE
                total_j, slid = coulomb_cone(
                    (c_imp[0, kc] + scale * tmp[0, idx], c_imp[1, kc] + scale * tmp[1, idx],
                     c_imp[2, kc] + scale * tmp[2, idx]),
                    (c_nrm[0, kc], c_nrm[1, kc], c_nrm[2, kc]), law, KINETIC if kinetic else 0)
                if now.shape[0] > 0:
                    held = total_j[0] != 0.0 or total_j[1] != 0.0 or total_j[2] != 0.0
                    now[s] = SLIDE if slid else (STICK if held else 0.0)
                dj = (total_j[0] - c_imp[0, kc], total_j[1] - c_imp[1, kc],
                      total_j[2] - c_imp[2, kc])
                for c in range(3):
                    c_imp[c, kc] = total_j[c]
                worst = max(worst, k * math.sqrt(dj[0] ** 2 + dj[1] ** 2 + dj[2] ** 2))
                f = 1.0
            else:
                # the φ-scheme: each pass's share cut to the cone of its own normal impulse
                cut, _slid = coulomb_cone((tmp[0, idx], tmp[1, idx], tmp[2, idx]),
                                          (c_nrm[0, kc], c_nrm[1, kc], c_nrm[2, kc]), law, 0)
                dj = (scale * cut[0], scale * cut[1], scale * cut[2])
                for c in range(3):
                    c_imp[c, kc] += dj[c]
                worst = max(worst, scale * k * math.sqrt(cut[0] ** 2 + cut[1] ** 2
                                                         + cut[2] ** 2))
                f, dj = scale, cut
            # each end node's velocity change: its share w/m of the impulse f × dj
            for node, w in ((a, wa), (b, wb)):
                wi = w * inv_mass[node]
                for c in range(3):
                    acc[0, fam, c, node] += wi * move * tmp[3 + c, idx]
                    acc[1, fam, c, node] += wi * f * dj[c]
        for i in range(listed):
            idx = seg_list[i]
            for node in (ends[seg_cand[idx], 0], ends[seg_cand[idx], 1]):
                if share[0, node] + share[1, node] > 0.0:
                    for c in range(3):
                        x1[c, node] += acc[0, 0, c, node] + acc[0, 1, c, node]
                        v1[c, node] += acc[1, 0, c, node] + acc[1, 1, c, node]
                    share[0, node] = 0.0
                    share[1, node] = 0.0
        if inside_count == 0 and worst <= settled:
            break
    if lag > 0.0 and nc > first:
        _drift_segment_ends(inv_mass, first, nc, x1, work, lag)
    # the body's reaction acts where the fabric point now is (the node, or w_a x_a + w_b x_b):
    # the moments the two receive are then exactly opposite, about any point
    for kc in range(nc):
        a = c_node[kc]
        b = c_node2[kc]
        wa = c_w[0, kc]
        for c in range(3):
            if b >= 0:
                c_arm[c, kc] = wa * x1[c, a] + c_w[1, kc] * x1[c, b] - centre[c]
            else:
                c_arm[c, kc] = x1[c, a] - centre[c]
    return nc


@njit(cache=True, inline="always")
def node_row(nodes, n):
    """The grid row of node n (records' layout)."""
    p = 0
    while n >= nodes.ply_nodes[p + 1]:
        p += 1
    j0 = nodes.ply_rows[p]
    return j0 + (n - nodes.ply_nodes[p]) // nodes.rows[j0, ROW_COUNT]


@njit(cache=True, _nrt=True)
def candidate_errors(nodes, ncand, cand, x0, xk, x1, row_sums):
    """Add the contact candidates' terms of the error measure (after contact moved them)."""
    for idx in range(ncand):
        n = cand[idx]
        row = node_row(nodes, n)
        ex = x1[0, n] - xk[0, n]
        ey = x1[1, n] - xk[1, n]
        ez = x1[2, n] - xk[2, n]
        row_sums[SUM_ERROR_NUM, row] += math.sqrt(ex * ex + ey * ey + ez * ez)
        ex = x1[0, n] - x0[0, n]
        ey = x1[1, n] - x0[1, n]
        ez = x1[2, n] - x0[2, n]
        row_sums[SUM_ERROR_DEN, row] += math.sqrt(ex * ex + ey * ey + ez * ez)


@njit(cache=True, _nrt=True)
def reaction_sums(nc, c_imp, c_arm, buf, imp_force, imp_moment):
    """Exactly rounded totals of −J and −r × J over the contacts (order-independent)."""
    for c in range(3):
        for k in range(nc):
            buf[k] = -c_imp[c, k]
        imp_force[c] = fsum(buf, nc)
    for c in range(3):
        a, b = (c + 1) % 3, (c + 2) % 3
        for k in range(nc):
            buf[k] = -(c_arm[a, k] * c_imp[b, k] - c_arm[b, k] * c_imp[a, k])
        imp_moment[c] = fsum(buf, nc)


CONTACT_TRAVEL = 0.25
"""The largest fraction of the body's radius it may move relative to the fabric in one step:
the no-tunnelling limit of the step (a thin, fast body cannot pass a yarn between two steps)."""
PLY_TRAVEL = 1.0
"""Central differences' step lets no two nodes of a pack move relative to each other by more
than this fraction of the plies' contact distance d (contact.travel_step): a node that meets a
ply starts a step at a gap of at least 0 and ends it above −d, where ply contact sees it."""


@njit(cache=True)
def travel_step(phys, x, v, b_state):
    """The no-tunnelling limit [s]: the body moves at most CONTACT_TRAVEL of its radius relative
    to any node in one step, and in a pack no two nodes move relative to each other by more
    than PLY_TRAVEL of the plies' contact distance (inf without a body, plies or motion)."""
    vmax = 0.0
    lo = (math.inf, math.inf, math.inf)
    hi = (-math.inf, -math.inf, -math.inf)
    for n in range(x.shape[1]):
        vmax = max(vmax, v[0, n] ** 2 + v[1, n] ** 2 + v[2, n] ** 2)
        lo = (min(lo[0], v[0, n]), min(lo[1], v[1, n]), min(lo[2], v[2, n]))
        hi = (max(hi[0], v[0, n]), max(hi[1], v[1, n]), max(hi[2], v[2, n]))
    return travel_limit(phys, vmax, lo, hi, b_state)


@njit(cache=True)
def travel_limit(phys, vmax, lo, hi, b_state):
    """travel_step from the nodes' largest |v|² (vmax), and the smallest and largest of each
    velocity component (lo, hi; tuples)."""
    body = phys.body
    gaps = phys.contact.ply_gap
    limit = math.inf
    if gaps.shape[0] > 0:
        # the largest relative speed of two nodes is at most the spread of each component
        spread = math.sqrt((hi[0] - lo[0]) ** 2 + (hi[1] - lo[1]) ** 2 + (hi[2] - lo[2]) ** 2)
        if spread > 0.0:
            limit = PLY_TRAVEL * gaps.min() / spread
    if not body.active:
        return limit
    speed = (norm(b_state[BODY_V]) + bounding_radius(body) * norm(b_state[BODY_W])
             + math.sqrt(vmax))
    if speed > 0.0:
        limit = min(limit, CONTACT_TRAVEL * thinnest_radius(body) / speed)
    return limit


@njit(cache=True)
def contact_tally(nc, c_node, c_node2, ply_nodes, mark, per_ply):
    """The step's contact list (c_node, c_node2 of its nc contacts) counted: per ply, the
    distinct fabric nodes in contact with the projectile, directly or as an end of a yarn
    segment in contact, into per_ply; returns the number of segment contacts. `mark` (one
    entry a node, all 0) is left all 0."""
    for p in range(per_ply.shape[0]):
        per_ply[p] = 0
    segments = 0
    for k in range(nc):
        if c_node2[k] >= 0:
            segments += 1
        for end in range(2):
            n = c_node[k] if end == 0 else c_node2[k]
            if n < 0 or mark[n] != 0:
                continue
            mark[n] = 1
            p = 0
            while n >= ply_nodes[p + 1]:
                p += 1
            per_ply[p] += 1
    for k in range(nc):
        mark[c_node[k]] = 0
        if c_node2[k] >= 0:
            mark[c_node2[k]] = 0
    return segments
