"""Ply-to-ply contact: neighbouring plies of a pack meet with the stick/slip impulse law of the
projectile's contact (contact.coulomb_cone), both ways, with exact action and reaction.

A node n of ply q meets the surface of its neighbour ply p through the nodes of p nearest to it:
k0, the nearest node of p (a walk over p's grid from the node k that was nearest in the
reference state, Contact.ply_guess), and the nodes of p's grid around k0 (Contact.ply_box).
Each such node k stands for the patch of p's surface around it: its normal N_k (the unit
t_i × t_j of p's grid, oriented from p towards q), the gap g = (x_n − x_k)·N_k and the in-plane
distance r² = |x_n − x_k|² − g². Its share of the contact is w_k/Σw with w = (1 − r²/ρ²)² for r
< ρ (Contact.ply_reach) and |g| < ρ. Where g < Contact.ply_gap (the sum of the two plies' yarn
radii) and g > −gap, the pair (n, k) with the reduced mass m_nk = 1/(1/m_n + 1/m_k) gets its share
of the stick impulse m_nk (v_k − v_n) (inelastic in N_k, stick in the plane) and of the
placement that opens the gap to ply_gap: +J on n and −J on k, the placement split by the inverse
masses (the centre of mass stays). Central differences' sweeps (ply_contact) meet a pair again
and again in a step: each adds its share of the stick impulse to the pair's sum over the step's
sweeps so far and cuts that sum to the Coulomb cone of N_k (contact.coulomb_cone: stick within
μ_s, else slide with μ_d), so that the sweeps converge to impulses that obey the contact law
for the step as a whole (records.Work.ply_sum). Every node of p meets q and every node of q
meets p, each pass with half of its share (a node above a node is one pair, seen twice).

All pairs are computed from the same state and their impulses and mass-weighted placements are
summed per node in integers (units Contact.ply_quantum): the sum does not depend on the order of
the pairs, so a mirror-symmetric state stays mirror-symmetric to the bit, and the momentum the
pairs exchange cancels exactly. Only then are they applied (_apply): Δv = ΣJ/m, Δx = Σ(mΔx)/m.

The functions the sweeps call for every pair of plies (_region, _normals, _pass, _apply, and the
box helpers) are compiled with `_nrt=False`, as the node kernels are (emfabric._kernels.nodes
says why): their reference counts were 11.6 % of a pack-field step, and are gone.
"""

import math

import numpy as np
from numba import int64, njit

from emfabric._kernels.contact import coulomb_cone, ply_penalty
from emfabric._kernels.fields import magnetic_force, node_field_of, uniform_field
from emfabric._kernels.records import ROW_COUNT
from emfabric._kernels.vec3 import copy_into


@njit(cache=True, _nrt=False)
def _region(nodes, ply, x, out):
    """out[:] = (i_lo, i_hi, j_lo, j_hi): the grid box of ply `ply` outside which every node
    and its four grid neighbours are at their reference height (so its normal is exactly e_z):
    the box of the nodes that moved off it, widened by one and clipped; i_lo > i_hi if none."""
    n0 = nodes.ply_nodes[ply]
    j0 = nodes.ply_rows[ply]
    nx = nodes.rows[j0, ROW_COUNT]
    ny = nodes.ply_rows[ply + 1] - j0
    z0 = nodes.x0[2]
    ilo, ihi, jlo, jhi = nx, -1, ny, -1
    for j in range(ny):
        row = n0 + j * nx
        for i in range(nx):
            if x[2, row + i] != z0[row + i]:
                ilo = min(ilo, i)
                ihi = max(ihi, i)
                jlo = min(jlo, j)
                jhi = max(jhi, j)
    if ihi < 0:
        out[0], out[1], out[2], out[3] = 1, 0, 1, 0
    else:
        out[0], out[1] = max(ilo - 1, 0), min(ihi + 1, nx - 1)
        out[2], out[3] = max(jlo - 1, 0), min(jhi + 1, ny - 1)


@njit(cache=True, _nrt=False)
def _normals(nodes, ply, x, out, box):
    """The unit normal t_i × t_j of ply `ply`'s grid at each of its nodes n in the grid box
    `box` (_region) into out[:, n] (central differences along the grid's rows and columns,
    one-sided at its edges: the same numbers for mirror-image nodes of a mirror-symmetric
    state). Outside the box it is e_z exactly (_normal)."""
    n0 = nodes.ply_nodes[ply]
    j0 = nodes.ply_rows[ply]
    nx = nodes.rows[j0, ROW_COUNT]
    ny = nodes.ply_rows[ply + 1] - j0
    for j in range(box[2], box[3] + 1):
        jm = j - 1 if j > 0 else j
        jp = j + 1 if j < ny - 1 else j
        for i in range(box[0], box[1] + 1):
            im = i - 1 if i > 0 else i
            ip = i + 1 if i < nx - 1 else i
            a = n0 + j * nx + ip
            b = n0 + j * nx + im
            c = n0 + jp * nx + i
            d = n0 + jm * nx + i
            ux, uy, uz = x[0, a] - x[0, b], x[1, a] - x[1, b], x[2, a] - x[2, b]
            wx, wy, wz = x[0, c] - x[0, d], x[1, c] - x[1, d], x[2, c] - x[2, d]
            nx_ = uy * wz - uz * wy
            ny_ = uz * wx - ux * wz
            nz_ = ux * wy - uy * wx
            size = math.sqrt(nx_ * nx_ + ny_ * ny_ + nz_ * nz_)
            k = n0 + j * nx + i
            if size > 0.0:
                out[0, k] = nx_ / size
                out[1, k] = ny_ / size
                out[2, k] = nz_ / size
            else:
                out[0, k] = 0.0
                out[1, k] = 0.0
                out[2, k] = 1.0


@njit(cache=True, inline="always")
def _normal(nrm, k, i, j, box, sign):
    """sign × the normal of the master node k at grid (i, j) (_normals inside box, e_z
    outside)."""
    if box[0] <= i <= box[1] and box[2] <= j <= box[3]:
        return sign * nrm[0, k], sign * nrm[1, k], sign * nrm[2, k]
    return 0.0, 0.0, sign


PLY_PLACEMENT_LIMIT = 1.0
"""The furthest ply contact places a node in one step, in contact distances d of its pair
(_apply). The step keeps every relative motion of two nodes of a pack below d
(contact.PLY_TRAVEL), so no pair that met at a gap of at least 0 needs more; where the sweeps
would place a node further, they are resolving a tear or a fold that no placement satisfies
(torn flaps crossing, a tangent plane extrapolated over a fold, passed back and forth sweep
after sweep), and the strain a placement of a millimetre puts into the node's yarns is the
scheme's, not the impact's (docs/theory.md §5.1)."""


LEVEL_BOX = 3
"""Half-width (in master grid nodes) of the level neighbourhood that lets _pass skip a node:
more than the 3 × 3 box around the nearest node plus the in-plane drift between plies that a
longitudinal wave alone makes."""


@njit(cache=True, inline="always")
def _units(value, per_unit):
    """value·per_unit (1/the unit, a power of two: exact) rounded to the nearest integer, halves
    away from zero (odd: −x gives −n)."""
    r = math.floor(abs(value) * per_unit + 0.5)
    return np.int64(-r if value < 0.0 else r)


@njit(cache=True, inline="always")
def _dist2(x, a, b):
    dx = x[0, a] - x[0, b]
    dy = x[1, a] - x[1, b]
    dz = x[2, a] - x[2, b]
    return dx * dx + dy * dy + dz * dz


@njit(cache=True, _nrt=False)
def _pass(phys, master, slave, sign, x, v, nrm, acc, nearest, shares, boxes, penalty):
    """The nodes of ply `slave` against the surface of ply `master` (normals nrm of master's
    nodes, times sign to point towards slave): impulses and placements into acc (integers).
    nearest = (guess, near, memo, stamp, epoch, sums): the reference-nearest master node of each
    node, and each node's nearest master node, written where the walk finds it; in the sweeps
    of impulses alone (place False: the positions do not change between them) each node's
    shares, gaps, their total and whether one acts, kept in memo[n] (records.Work.ply_memo)
    with stamp[n] = epoch the first time and read from there after; sums = (summed, at, stamp):
    each pair's impulse summed over this call's sweeps (records.Work.ply_sum, ply_sum_at,
    ply_sum_stamp; unused by the φ-scheme's forces); shares: scratch, (5, box count): each
    box node's w and gap (and _move_sums's); boxes = (box, hot): master's _region, and the
    nodes to meet (below); penalty = (stiffness, φΔt, start-of-step velocities, driven, place):
    a stiffness > 0 takes the φ-scheme's penalty law instead (ply_forces): forces into acc[0],
    nothing into acc[1]; driven (node_count,) or empty: nonzero for the nodes the projectile
    drives (central differences: ply_contact); place: False gives the impulses alone, no
    placements (ply_contact's sweeps once the placements have converged: PLY_VELOCITY_SWEEPS).
    With hot[0] ≠ 0, only the slave nodes in slave's grid box hot[1:5] (i_lo, i_hi, j_lo,
    j_hi), or whose nearest master node (near) lies within one box (Contact.ply_box) plus one
    node of master's grid box hot[5:9], are met: the nodes ply_contact's later sweeps revisit.

    A node at its reference height whose reference-nearest master node lies more than
    LEVEL_BOX outside master's region is skipped: every gap there is the plies' reference
    distance, at least the contact distance (the transverse wave has not come). Only there
    does ply contact cost less than its full pass."""
    nodes, law = phys.nodes, phys.contact
    guess, near, memo, stamp, epoch, sums = nearest
    summed, summed_at, summed_stamp = sums
    box, hot = boxes
    inv_mass, mass = nodes.inv_mass, nodes.mass
    m0 = nodes.ply_nodes[master]
    jm = nodes.ply_rows[master]
    mnx = nodes.rows[jm, ROW_COUNT]
    mny = nodes.ply_rows[master + 1] - jm
    rho = law.ply_reach[master]
    bi = law.ply_box[master, 0]
    bj = law.ply_box[master, 1]
    wide = 2 * bi + 1
    qi, qx, qf = 1.0 / law.ply_quantum[0], 1.0 / law.ply_quantum[1], 1.0 / law.ply_quantum[2]
    gap = law.ply_gap[min(master, slave)]
    stiff, phi_dt, v_start, driven, place = penalty
    forces = stiff > 0.0
    keep = not place and not forces
    count = (2 * bj + 1) * wide
    steered = driven.shape[0] > 0
    s0 = nodes.ply_nodes[slave]
    snx = nodes.rows[nodes.ply_rows[slave], ROW_COUNT]
    only = hot[0] != 0
    # the hot boxes' bounds, the master's widened by a box and one node; the master's rows
    # as a range of node offsets, so that most nodes are passed over without a division
    ri_lo, ri_hi = hot[5] - bi - 1, hot[6] + bi + 1
    r_lo, r_hi = 1, 0  # an empty master box (bounds _FAR, −1): no node's nearest is in it
    if hot[5] <= hot[6] and hot[7] <= hot[8]:
        r_lo = max(hot[7] - bj - 1, 0) * mnx
        r_hi = (hot[8] + bj + 2) * mnx
    si = -1  # n's column and row in slave's grid, counted along
    sj = 0
    for n in range(s0, nodes.ply_nodes[slave + 1]):
        si += 1
        if si == snx:
            si = 0
            sj += 1
        k = guess[n]
        if k < 0 or mass[n] == 0.0:
            continue
        if only and not (hot[1] <= si <= hot[2] and hot[3] <= sj <= hot[4]):
            r = (near[n] if near[n] >= 0 else k) - m0
            if r < r_lo or r >= r_hi:
                continue
            ni = r % mnx
            if ni < ri_lo or ni > ri_hi:
                continue
        ci = (k - m0) % mnx
        cj = (k - m0) // mnx
        # at its reference height over a level neighbourhood: no contact
        if x[2, n] == nodes.x0[2, n] and (
                box[0] > box[1] or ci < box[0] - LEVEL_BOX or ci > box[1] + LEVEL_BOX
                or cj < box[2] - LEVEL_BOX or cj > box[3] + LEVEL_BOX):
            near[n] = k
            continue
        if keep and stamp[n] == epoch:
            # a sweep of impulses alone met n before, on these positions
            r = near[n] - m0
            ci = r % mnx
            cj = r // mnx
            for b in range(count):
                shares[0, b] = memo[n, b]
                shares[1, b] = memo[n, count + b]
            total = memo[n, 2 * count]
            if memo[n, 2 * count + 1] == 0.0:
                continue
        else:
            ci, cj, total, acting = _shares(x, n, ci, cj, (m0, mnx, mny, bi, bj), nrm, box,
                                            sign, (mass, rho, gap), shares, near)
            if keep:
                for b in range(count):
                    memo[n, b] = shares[0, b]
                    memo[n, count + b] = shares[1, b]
                memo[n, 2 * count] = total
                memo[n, 2 * count + 1] = 1.0 if acting else 0.0
                stamp[n] = epoch
            if not acting:
                continue
        if not forces:
            # the impulses n's pairs have had in this call's sweeps, by box position around
            # its nearest master node: none yet, or moved with the box where that changed
            at = m0 + cj * mnx + ci
            if summed_stamp[n] != epoch:
                summed_stamp[n] = epoch
                summed_at[n] = at
                for b in range(3 * count):
                    summed[n, b] = 0.0
            elif summed_at[n] != at:
                _move_sums(summed, n, summed_at[n] - m0, (ci, cj, mnx, bi, bj), shares)
                summed_at[n] = at
        # the reaction of n's pairs on master, summed here (integers) and spread over the
        # master nodes around the point where its line of action meets master's surface
        # (_spread): impulses (or forces) in rx, placements in px
        rx0, rx1, rx2 = int64(0), int64(0), int64(0)
        px0, px1, px2 = int64(0), int64(0), int64(0)
        for dj in range(-bj, bj + 1):
            for di in range(-bi, bi + 1):
                w = shares[0, (dj + bj) * wide + di + bi]
                g = shares[1, (dj + bj) * wide + di + bi]
                if w == 0.0 or not (g < gap and g > -gap):
                    continue
                km = m0 + (cj + dj) * mnx + ci + di
                inv_sum = inv_mass[n] + inv_mass[km]
                if inv_sum == 0.0:
                    continue
                nh = _normal(nrm, km, ci + di, cj + dj, box, sign)
                share = 0.5 * w / total
                m_nk = 1.0 / inv_sum
                if forces:
                    fp = ply_penalty(share, stiff, gap, g, m_nk, nh, v, v_start, n, km, law,
                                     phi_dt)
                    rx0 += _units(fp[0], qf)
                    rx1 += _units(fp[1], qf)
                    rx2 += _units(fp[2], qf)
                    continue
                # a node the projectile drives (in contact with it) acts as one of infinite
                # mass: the other takes the whole placement and the impulse that brings it to
                # the driven node's velocity; the driven node takes −J (momentum is exact) and
                # the projectile's next contact brings it back to the surface's velocity
                move_n = not (steered and driven[n] != 0.0)
                move_k = not (steered and driven[km] != 0.0)
                if not (move_n or move_k):
                    continue
                if not move_n:
                    m_nk = mass[km]
                elif not move_k:
                    m_nk = mass[n]
                # the pair's share of the stick impulse added to what the step's sweeps gave it
                # so far, and that sum cut to the Coulomb cone: a sweep whose own normal
                # impulse is small (the pair already held) still stops the slip that other
                # pairs' impulses gave it, as far as the pair's whole normal impulse allows.
                # Cut sweep by sweep, it could not (docs/theory.md §5.1; segment contact's
                # passes do the same, contact.segment_contact)
                o = 3 * ((dj + bj) * wide + di + bi)
                had = (summed[n, o], summed[n, o + 1], summed[n, o + 2])
                s_m = share * m_nk
                tot, _slid = coulomb_cone((had[0] + s_m * (v[0, km] - v[0, n]),
                                           had[1] + s_m * (v[1, km] - v[1, n]),
                                           had[2] + s_m * (v[2, km] - v[2, n])), nh, law, 0)
                j = (tot[0] - had[0], tot[1] - had[1], tot[2] - had[2])
                summed[n, o] = tot[0]
                summed[n, o + 1] = tot[1]
                summed[n, o + 2] = tot[2]
                lift = share * m_nk * (gap - g)
                rx0 += _units(j[0], qi)
                rx1 += _units(j[1], qi)
                rx2 += _units(j[2], qi)
                if not place:
                    continue
                for c in range(3):
                    units = _units(lift * nh[c], qx)
                    if move_n:
                        acc[1, c, n] += units
                    if move_k:
                        if c == 0:
                            px0 += units
                        elif c == 1:
                            px1 += units
                        else:
                            px2 += units
        _spread(x, n, acc, (rx0, rx1, rx2), (px0, px1, px2),
                (m0 + cj * mnx + ci, m0, mnx, mny, ci, cj),
                _normal(nrm, m0 + cj * mnx + ci, ci, cj, box, sign), mass, driven, steered)


FACET_SLACK = 1e-9
"""How far outside its facet (in barycentric weight) a point may lie for _spread to put a reaction
there: a point on an edge between two facets has weights of round-off size below zero in both.
A line of action that meets no facet within the quads around the slave node's nearest master
node (an impulse nearly along the surface: a later sweep's correction of friction) is replaced
by the master's normal through the slave node; one that misses them too (a slave beyond
master's edge) leaves the reaction on that nearest node. Wider, the facet that came nearest
to the meeting point was chosen among facets mirror images of each other by the order of the
search, and a head-on pack impact spun the projectile (tests/test_plies.py)."""


@njit(cache=True, inline="always")
def _cross_dot(ax, ay, az, bx, by, bz, n):
    """(a × b)·n, each component of a × b as a difference of two products and the dot product
    summed x, y, z: a mirror image (a component of a, b and n negated) gives the same number
    to the bit."""
    cx = ay * bz - az * by
    cy = az * bx - ax * bz
    cz = ax * by - ay * bx
    return (cx * n[0] + cy * n[1]) + cz * n[2]


@njit(cache=True, _nrt=False)
def _facet(x, n, d, grid, mass):
    """Where the line x_n + λd meets master's surface, as barycentric weights of a facet of it.
    The surface is faceted: each grid quad of master around its node (ci, cj) nearest to n
    (grid = (that node, master's first node, nx, ny, ci, cj)) is four triangles, one per edge
    with the quad's centre (the mean of its corners: the same facets for a mirror image, where
    splitting the quad along a diagonal would not be); of the sixteen, the one whose weights of
    the meeting point have the largest least weight, and of those that tie, the one whose
    meeting point is nearest x_n (the smallest |λ|; then the first in the search's order).
    Returns (that least weight, −inf if no line
    meets a facet; the quad's first node a, its corners a, a + 1, a + 1 + nx, a + nx in cyclic
    order; t, the facet's edge from corner t to corner t + 1; the weights of corner t, corner
    t + 1 and the centre): Σ of the weights times the vertices is the meeting point, to
    round-off."""
    _k0, m0, mnx, mny, ci, cj = grid
    best = -math.inf
    best_lam = math.inf
    best_a, best_t = -1, 0
    best_u, best_w, best_v = 0.0, 0.0, 0.0
    xn0, xn1, xn2 = x[0, n], x[1, n], x[2, n]
    for qj in range(cj - 1, cj + 1):
        for qi in range(ci - 1, ci + 1):
            if qi < 0 or qj < 0 or qi + 1 >= mnx or qj + 1 >= mny:
                continue
            a = m0 + qj * mnx + qi
            quad = (a, a + 1, a + 1 + mnx, a + mnx)  # cyclic
            if (mass[quad[0]] == 0.0 or mass[quad[1]] == 0.0 or mass[quad[2]] == 0.0
                    or mass[quad[3]] == 0.0):
                continue
            v0 = ((x[0, quad[0]] + x[0, quad[2]]) + (x[0, quad[1]] + x[0, quad[3]])) * 0.25
            v1 = ((x[1, quad[0]] + x[1, quad[2]]) + (x[1, quad[1]] + x[1, quad[3]])) * 0.25
            v2 = ((x[2, quad[0]] + x[2, quad[2]]) + (x[2, quad[1]] + x[2, quad[3]])) * 0.25
            for t in range(4):
                u = quad[t]
                w = quad[(t + 1) % 4]
                ux, uy, uz = x[0, u] - v0, x[1, u] - v1, x[2, u] - v2
                wx, wy, wz = x[0, w] - v0, x[1, w] - v1, x[2, w] - v2
                nf = (uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx)
                area = (nf[0] * nf[0] + nf[1] * nf[1]) + nf[2] * nf[2]
                along = (d[0] * nf[0] + d[1] * nf[1]) + d[2] * nf[2]
                if area == 0.0 or along == 0.0:
                    continue
                lam = (((v0 - xn0) * nf[0] + (v1 - xn1) * nf[1]) + (v2 - xn2) * nf[2]) / along
                q0, q1, q2 = xn0 + lam * d[0], xn1 + lam * d[1], xn2 + lam * d[2]
                # each weight: the area of the triangle the point makes with the other two
                # vertices, in the facet's order (u, w, centre), over the facet's
                cu = _cross_dot(x[0, w] - q0, x[1, w] - q1, x[2, w] - q2,
                                v0 - q0, v1 - q1, v2 - q2, nf) / area
                cw = _cross_dot(v0 - q0, v1 - q1, v2 - q2,
                                x[0, u] - q0, x[1, u] - q1, x[2, u] - q2, nf) / area
                cv = _cross_dot(x[0, u] - q0, x[1, u] - q1, x[2, u] - q2,
                                x[0, w] - q0, x[1, w] - q1, x[2, w] - q2, nf) / area
                least = min(cu, min(cw, cv))
                # ties (a line in a plane of grid nodes meets every facet with an edge there
                # at a weight of exactly 0, at different points where the ply is folded):
                # the nearer meeting point, which a mirror image chooses alike; the search's
                # order does not mirror, and a reversed field did not mirror a torn pack
                # (tests/test_plies.py)
                near = abs(lam)
                if least > best or (least == best and near < best_lam):
                    best = least
                    best_lam = near
                    best_a, best_t = a, t
                    best_u, best_w, best_v = cu, cw, cv
    return best, best_a, best_t, best_u, best_w, best_v


@njit(cache=True, _nrt=False)
def _spread(x, n, acc, r, pl, grid, normal, mass, driven, steered):
    """Node n's reaction on its master ply: n receives the impulses (or forces) r of its pairs
    (integers), and master the opposite, spread over the four master nodes around the point
    where their line of action through x_n meets master's surface (_facet), so that action and
    reaction act along one line: the pairs keep the angular momentum to round-off, as they keep
    the momentum (n receives exactly the sum of the parts its master nodes give back). Applied
    at each pair's master node, as before, the reaction's moment differed from the action's by
    the pair's in-plane offset (up to a node spacing) times its impulse, and a free pack's
    angular momentum drifted by an amount that did not shrink with the step. The master's
    placements pl (integers, mass times distance) are spread with the same weights over the
    master nodes the projectile does not drive. grid: _facet's; normal: master's normal at the
    nearest master node, the line taken where the line of action meets no facet around it
    (FACET_SLACK: there the moment of the reaction's part along the surface is kept only to
    the pair's gap times it); a line that misses them too (a slave beyond master's edge) leaves
    the whole reaction on the nearest master node, grid[0]."""
    if r[0] == 0 and r[1] == 0 and r[2] == 0 and pl[0] == 0 and pl[1] == 0 and pl[2] == 0:
        return
    d = (float(r[0]), float(r[1]), float(r[2]))
    if d[0] == 0.0 and d[1] == 0.0 and d[2] == 0.0:
        d = (float(pl[0]), float(pl[1]), float(pl[2]))
    least, a, t, cu, cw, cv = _facet(x, n, d, grid, mass)
    if least < -FACET_SLACK:
        least, a, t, cu, cw, cv = _facet(x, n, normal, grid, mass)
    count = 4
    if least < -FACET_SLACK:
        count = 1
    mnx = grid[2]
    got0, got1, got2 = int64(0), int64(0), int64(0)
    for c in range(count):
        if count == 1:
            k = grid[0]
            weight = 1.0
        else:
            k = a if c == 0 else (a + 1 if c == 1 else (a + 1 + mnx if c == 2 else a + mnx))
            weight = 0.25 * cv
            if c == t:
                weight += cu
            elif c == (t + 1) % 4:
                weight += cw
        u0 = _units(weight * float(r[0]), 1.0)
        u1 = _units(weight * float(r[1]), 1.0)
        u2 = _units(weight * float(r[2]), 1.0)
        acc[0, 0, k] -= u0
        acc[0, 1, k] -= u1
        acc[0, 2, k] -= u2
        got0 += u0
        got1 += u1
        got2 += u2
        if not (steered and driven[k] != 0.0):
            acc[1, 0, k] -= _units(weight * float(pl[0]), 1.0)
            acc[1, 1, k] -= _units(weight * float(pl[1]), 1.0)
            acc[1, 2, k] -= _units(weight * float(pl[2]), 1.0)
    acc[0, 0, n] += got0
    acc[0, 1, n] += got1
    acc[0, 2, n] += got2


@njit(cache=True, _nrt=False)
def _move_sums(summed, n, was, grid, shares):
    """Node n's summed impulses (ply_contact's ply_sum row, by box position) moved from the box
    around master grid offset `was` (its first node's) to the box around (ci, cj), grid = (ci,
    cj, nx, bi, bj): each pair keeps its sum, a pair new to the box starts from none (shares'
    rows 2–4: scratch)."""
    ci, cj, mnx, bi, bj = grid
    wide = 2 * bi + 1
    count = (2 * bj + 1) * wide
    for b in range(count):
        for c in range(3):
            shares[2 + c, b] = summed[n, 3 * b + c]
    oi = was % mnx
    oj = was // mnx
    for dj in range(-bj, bj + 1):
        for di in range(-bi, bi + 1):
            o = 3 * ((dj + bj) * wide + di + bi)
            # the same master node's position in the old box
            ei = ci + di - oi
            ej = cj + dj - oj
            inside = -bi <= ei <= bi and -bj <= ej <= bj
            b = (ej + bj) * wide + ei + bi
            for c in range(3):
                summed[n, o + c] = shares[2 + c, b] if inside else 0.0


@njit(cache=True, inline="always")
def _shares(x, n, ci, cj, grid, nrm, box, sign, law, shares, near):
    """_pass's geometry of node n: from master's grid node (ci, cj) a walk over master's grid to
    its node nearest to n (written to near[n]), then the shares w and gaps g of the master
    nodes in the box around that one into shares (by box position), and their total in
    mirror-paired order. grid = (first node, nx, ny, box half-widths bi, bj) of master, law =
    (node masses, reach ρ, contact distance). Returns (ci, cj of the nearest node, total,
    whether a pair acts: within the contact distance)."""
    m0, mnx, mny, bi, bj = grid
    mass, rho, gap = law
    rho2 = rho * rho
    wide = 2 * bi + 1
    # walk over master's grid to its node nearest to n
    best = _dist2(x, n, m0 + cj * mnx + ci)
    for _step in range(mnx + mny):
        ni, nj = ci, cj
        for dj in range(-1, 2):
            for di in range(-1, 2):
                ii = ci + di
                jj = cj + dj
                if (di == 0 and dj == 0) or ii < 0 or ii >= mnx or jj < 0 or jj >= mny:
                    continue
                d2 = _dist2(x, n, m0 + jj * mnx + ii)
                if d2 < best:
                    best = d2
                    ni, nj = ii, jj
        if ni == ci and nj == cj:
            break
        ci, cj = ni, nj
    near[n] = m0 + cj * mnx + ci
    # the shares w of the master nodes around it, and their sum in mirror-paired order
    total = 0.0
    acting = False
    for dj in range(-bj, bj + 1):
        for di in range(-bi, bi + 1):
            ii = ci + di
            jj = cj + dj
            w = 0.0
            g = 0.0
            if 0 <= ii < mnx and 0 <= jj < mny:
                km = m0 + jj * mnx + ii
                if mass[km] > 0.0:
                    dx = x[0, n] - x[0, km]
                    dy = x[1, n] - x[1, km]
                    dz = x[2, n] - x[2, km]
                    nh = _normal(nrm, km, ii, jj, box, sign)
                    g = (nh[0] * dx + nh[1] * dy) + nh[2] * dz
                    r2 = ((dx * dx + dy * dy) + dz * dz) - g * g
                    if r2 < rho2 and abs(g) < rho:
                        q = 1.0 - r2 / rho2
                        w = q * q
                        if g < gap and g > -gap:
                            acting = True
            shares[0, (dj + bj) * wide + di + bi] = w
            shares[1, (dj + bj) * wide + di + bi] = g
    if not acting:
        return ci, cj, total, acting
    for b in range(bj + 1):
        row = 0.0
        for jsign in range(2 if b > 0 else 1):
            jrow = (bj + b if jsign == 0 else bj - b) * wide
            part = shares[0, jrow + bi]
            for a in range(1, bi + 1):
                part += shares[0, jrow + bi - a] + shares[0, jrow + bi + a]
            row = part if jsign == 0 else row + part
        total += row
    return ci, cj, total, acting

PLY_STIFFNESS = 10.0
"""The φ-scheme's ply contact: its stiffness k_c over the axial stiffness EA/L0 of one segment
of the softer ply (sim.builder). Ten times: with EA/L0 alone, on the hard impact of
tests/test_plies.py (400 m/s), a node of the second ply came within the projectile."""


@njit(cache=True)
def _shares_buffer(law, plies):
    """_pass's scratch for the shares and gaps of a node's box of master nodes (rows 0, 1) and
    its summed impulses while their box moves (rows 2–4, _move_sums): (5, the largest box of
    any ply)."""
    box = 1
    for p in range(plies):
        box = max(box, (2 * law.ply_box[p, 0] + 1) * (2 * law.ply_box[p, 1] + 1))
    return np.empty((5, box))


@njit(cache=True)
def _all_pairs(phys, x, v, nrm, acc, phi_dt, v_start, near):
    """Every ply's region and normals (into nrm), then both passes of every pair of neighbouring
    plies (ply p + 1's nodes against ply p's underside, then ply p's against ply p + 1) into
    acc: the φ-scheme's forces (stiffness Contact.ply_stiffness, φΔt = phi_dt, friction from
    v_start), all from the one state x, v; near: scratch (node_count,) int64."""
    nodes, law = phys.nodes, phys.contact
    plies = nodes.ply_nodes.shape[0] - 1
    shares = _shares_buffer(law, plies)
    region = np.empty((plies, 4), dtype=np.int64)
    for p in range(plies):
        _region(nodes, p, x, region[p])
        _normals(nodes, p, x, nrm, region[p])
    every = np.zeros(9, dtype=np.int64)
    memo = np.empty((1, 1))  # the φ-scheme's passes place: no sweeps of impulses alone
    stamp = np.empty(1, dtype=np.int64)
    none = np.int64(0)  # (not a literal: the type ply_contact's epoch has)
    sums = (memo, stamp, stamp)  # and its forces sum no impulses
    for p in range(plies - 1):
        law_p = (law.ply_stiffness[p], phi_dt, v_start, np.empty(0), True)
        _pass(phys, p, p + 1, -1.0, x, v, nrm, acc,
              (law.ply_guess[0], near, memo, stamp, none, sums), shares, (region[p], every),
              law_p)
        _pass(phys, p + 1, p, 1.0, x, v, nrm, acc,
              (law.ply_guess[1], near, memo, stamp, none, sums), shares, (region[p + 1], every),
              law_p)


@njit(cache=True, _nrt=True)
def ply_forces(phys, x, v, v_start, work, out, phi_dt):
    """The φ-scheme's ply contact: the force on every node [N] at positions x and velocities v
    into out (3, node_count), summed exactly (integers of Contact.ply_quantum[2]: +F on one node
    of a pair, −F on the other, order-free); the pairs, shares and normals of ply_contact, each
    pair with the law of contact.ply_penalty (stiffness Contact.ply_stiffness; phi_dt = φΔt of
    the step). Returns the number of nodes with a force."""
    nodes, law = phys.nodes, phys.contact
    plies = nodes.ply_nodes.shape[0] - 1
    if plies < 2:
        return 0
    acc = work.ply_acc
    _all_pairs(phys, x, v, work.ply_normals, acc, phi_dt, v_start, work.ply_near[0])
    qf = law.ply_quantum[2]
    touched = 0
    for n in range(x.shape[1]):
        if acc[0, 0, n] == 0 and acc[0, 1, n] == 0 and acc[0, 2, n] == 0:
            out[0, n] = 0.0
            out[1, n] = 0.0
            out[2, n] = 0.0
            continue
        touched += 1
        for c in range(3):
            out[c, n] = float(acc[0, c, n]) * qf
            acc[0, c, n] = 0
    return touched


@njit(cache=True, inline="always")
def _yarn_force(phys, sin, nf, n):
    """The yarns' elastic force on node n at the start of the step: the State's force sin.f
    (the whole ψ_n with q v_n × B) less the electric force q E (sin.e), gravity, q v_n × B(x_n)
    (nf: the node fields of the step's start, as the drift used them) and the yarns' viscous
    force (sin.fv, where the yarns have one)."""
    nodes, fld = phys.nodes, phys.field
    uni, sourced = uniform_field(fld)
    x0, v0 = sin.x, sin.v
    _e, b = node_field_of(uni, sourced, nf, n, (x0[0, n], x0[1, n], x0[2, n]))
    q, m = nodes.charge[n], nodes.mass[n]
    fm = magnetic_force(q, (v0[0, n], v0[1, n], v0[2, n]), b)
    g = fld.gravity
    fx = sin.f[0, n] - q * sin.e[0, n] - m * g[0] - fm[0]
    fy = sin.f[1, n] - q * sin.e[1, n] - m * g[1] - fm[1]
    fz = sin.f[2, n] - q * sin.e[2, n] - m * g[2] - fm[2]
    if sin.fv.shape[1] > 0:
        # the elastic part: the yarns' viscous force (sin.fv) has no energy a placement changes
        fx -= sin.fv[0, n]
        fy -= sin.fv[1, n]
        fz -= sin.fv[2, n]
    return fx, fy, fz


@njit(cache=True, _nrt=False)
def _apply(phys, sin, x, v, acc, lag, span, flag, nf, mark, start):
    """Apply the summed impulses and placements of nodes lo..hi − 1, span = (lo, hi) (and clear
    them). Returns (dissipation [J]: the kinetic energy the impulses took; the work of the yarn
    force at the step's start (_yarn_force) over the displacement the velocity update does not
    see, Δx − lag·Δv [J]: the contact placement's term of the energy budget, for the nodes with
    flag 0 (a projectile contact candidate's is booked by the kick that follows, with the
    projectile's placement); the largest placement of a node along an axis [m]). lo..hi − 1 are
    the nodes of plies p and p + 1, mark = (hot, p, tol, vtol, driven): the grid box of each
    ply's nodes that changed by more than the tolerances — placed by more than tol, or their
    velocity changed by Δv with 2·lag·|Δv| (the step's drift of it) more than vtol, along an
    axis — is widened to hold them (hot, (plies, 4): i_lo, i_hi, j_lo, j_hi). Nodes with
    driven ≠ 0 are left as they are, their impulses kept in acc (_apply_driven). Returns also
    the largest 2·lag·|Δv| [m].

    The yarn force only: the electric field's and gravity's work are booked from the kicks'
    velocities, which see no placement (nodes._drift_block, _kick_block), and the magnetic
    force does none; with them, a ply pressed onto the next by a field booked h²|qE|²/2m a
    step twice (tests/test_plies.py)."""
    nodes, law = phys.nodes, phys.contact
    lo, hi = span
    hot, p, tol, vtol, driven = mark
    qi, qx = law.ply_quantum[0], law.ply_quantum[1]
    inv_mass, mass = nodes.inv_mass, nodes.mass
    steered = driven.shape[0] > 0
    limit = PLY_PLACEMENT_LIMIT * law.ply_gap[p]
    limit2 = limit * limit
    lost = 0.0
    work = 0.0
    moved = 0.0
    sped = 0.0
    for n in range(lo, hi):
        if steered and driven[n] != 0.0:
            continue  # its impulses wait in acc until the sweeps end (_apply_driven)
        if (acc[0, 0, n] == 0 and acc[0, 1, n] == 0 and acc[0, 2, n] == 0
                and acc[1, 0, n] == 0 and acc[1, 1, n] == 0 and acc[1, 2, n] == 0):
            continue
        im = inv_mass[n]
        fy = _yarn_force(phys, sin, nf, n)
        mine = 0.0
        kick = 0.0
        # the placement, cut where it would take the node further than the pair's contact
        # distance from where the step put it (PLY_PLACEMENT_LIMIT)
        px = float(acc[1, 0, n]) * qx * im
        py = float(acc[1, 1, n]) * qx * im
        pz = float(acc[1, 2, n]) * qx * im
        tx = x[0, n] + px - start[0, n]
        ty = x[1, n] + py - start[1, n]
        tz = x[2, n] + pz - start[2, n]
        far = (tx * tx + ty * ty) + tz * tz
        if far > limit2:
            cut = math.sqrt(limit2 / far)
            px = start[0, n] + cut * tx - x[0, n]
            py = start[1, n] + cut * ty - x[1, n]
            pz = start[2, n] + cut * tz - x[2, n]
        for c in range(3):
            dv = float(acc[0, c, n]) * qi * im
            dx = px if c == 0 else (py if c == 1 else pz)
            lost -= mass[n] * (v[c, n] * dv + 0.5 * dv * dv)
            if flag[n] == 0:
                work += fy[c] * (dx - lag * dv)
            mine = max(mine, abs(dx))
            kick = max(kick, 2.0 * lag * abs(dv))
            v[c, n] += dv
            x[c, n] += dx
            acc[0, c, n] = 0
            acc[1, c, n] = 0
        moved = max(moved, mine)
        sped = max(sped, kick)
        if mine > tol or kick > vtol:
            q = p if n < nodes.ply_nodes[p + 1] else p + 1
            local = n - nodes.ply_nodes[q]
            nx = nodes.rows[nodes.ply_rows[q], ROW_COUNT]
            i = local % nx
            j = local // nx
            hot[q, 0] = min(hot[q, 0], i)
            hot[q, 1] = max(hot[q, 1], i)
            hot[q, 2] = min(hot[q, 2], j)
            hot[q, 3] = max(hot[q, 3], j)
    return lost, work, moved, sped


@njit(cache=True, _nrt=False)
def _apply_driven(phys, x, v, acc, driven):
    """Apply the impulses the sweeps gave the nodes the projectile drives (held in acc while
    the sweeps ran: a held node moves with the projectile, a boundary the pack below is brought
    to within the step) and clear them. Returns the kinetic energy they took [J]."""
    nodes, law = phys.nodes, phys.contact
    qi = law.ply_quantum[0]
    lost = 0.0
    for n in range(x.shape[1]):
        if driven[n] == 0.0:
            continue
        im = nodes.inv_mass[n]
        for c in range(3):
            dv = float(acc[0, c, n]) * qi * im
            lost -= nodes.mass[n] * (v[c, n] * dv + 0.5 * dv * dv)
            v[c, n] += dv
            acc[0, c, n] = 0
            acc[1, c, n] = 0
    return lost


PLY_SWEEPS = 32
"""Central differences' ply contact: the most sweeps over the pack's pairs in one step (down,
up, …) that place nodes (PLY_VELOCITY_SWEEPS more may follow that do not). Where the plies
fold sharply (the rim of a sphere on a 16-ply pack, the FSP of pack-fsp) nodes are passed
back and forth without end and the sweeps run to this limit, so it is a resolution:
pack-fsp's ω_x at 12 µs with 8 / 16 / 32 / 64 sweeps is −3872 / −3775 / −3723 / −3692 rad/s.
The limit was 8 (5 % from 64 sweeps); 32 is 0.8 %, and with the later sweeps meeting only the
nodes that changed it costs about half what 8 sweeps of every node did (docs/theory.md
§5.1). With 4, the second gap of pack-fsp at 21 × 21 closed to zero at the default step
(scripts/ply_gaps.py)."""
PLY_TOLERANCE = 0.01
"""Central differences' ply contact sweeps until no node is placed by more than this fraction of
the contact distance (Contact.ply_gap) along any axis in a sweep (and PLY_VELOCITY_TOLERANCE
holds). (Not until no pair overlaps: a node under a sharp fold of the ply above meets tangent
planes that no placement satisfies at once, and its overlap with the tilted ones, up to
≈ d(1 − cos θ), stays while the placements that balance it are tiny.)"""
PLY_VELOCITY_SWEEPS = 8
"""Central differences' ply contact: once the placements have converged (a sweep placed no node
by more than PLY_TOLERANCE) or PLY_SWEEPS sweeps have placed, at most this many more sweeps
give impulses alone, on the geometry as it is, until PLY_VELOCITY_TOLERANCE holds. Placing on,
the placements cycle at a sharp fold: a node of pack-field's second ply beside the sphere's
axis was moved 1.6e-7 m back and forth every sweep (4e-4 of the contact distance, below
PLY_TOLERANCE: the overlap it leaves is no larger), and the impulses, whose pairs came and
went with it, changed by ~2 % of the first sweep's every sweep without end. Without
placements they fall to ~3.5 % of it in 40 sweeps and slowly after (the pack's thickness:
docs/theory.md §5.1, "Where the sweeps converge slowly"); pack-field's ω_x at 100 µs with 8 / 32 /
64 such sweeps: −461 / −457 / −453 rad/s, and with 2 / 4 / 8: −453 / −458 / −460 (worktree runs,
the first three before the pair skip was removed); they made the whole pack-field run 3.9 × as
long as with none, 1.6 × since the sweeps keep what does not change between them (their
nodes' shares and gaps, the plies' normals: docs/packs.md)."""
PLY_VELOCITY_TOLERANCE = 0.01
"""Central differences' ply contact sweeps also until no node's velocity changes in a sweep by more
than this fraction of the largest change of the step's first sweep (along any axis). A tolerance
on the placements alone stopped after one sweep wherever the plies move slowly relative to each
other, since a step's overlaps are then below PLY_TOLERANCE · d: at courant 0.125 every step of
pack-field's first 100 µs had one sweep, at 0.25 one to three, so the impulses down the pack
were resolved one pair a step and the pack's spin moved with the step (ω_x at 100 µs −434 / −456
rad/s at courant 0.25 / 0.125; docs/theory.md §5.1). Relative to the step's own first sweep, the
velocities are resolved to the same fraction at any step."""


@njit(cache=True, _nrt=True)
def ply_contact(phys, sin, x, v, work, lag, driven):
    """Ply-to-ply contact of every pair of neighbouring plies at positions x and velocities v
    (changed in place); work.ply_normals holds the plies' normals afterwards; sin: the state
    at the step's start, whose yarn force does the placement's work (_apply), with the node
    fields of the step's start in work.node_field; lag: the time over which the scheme's
    position update sees a velocity change (energy bookkeeping: Δt/2 for central
    differences); driven: nonzero for the nodes in contact with the projectile
    (State.contact[3] after its contact).
    Returns (dissipation [J], placement work [J]); (0, 0) for one ply.

    Gauss–Seidel over the pairs: each pair's impulses and placements are applied before the next
    pair is met, downwards through the pack (pair 1–2 first) and upwards on the next sweep,
    until a sweep places no node by more than PLY_TOLERANCE of the contact distance and changes
    no node's velocity by more than PLY_VELOCITY_TOLERANCE of the first sweep's largest change
    (at most PLY_SWEEPS sweeps that place, until the placements converge, and then at most
    PLY_VELOCITY_SWEEPS that give impulses alone; a pair none of whose plies' nodes changed by
    more than the tolerances since it was last met is not met again). A ply's _region and
    normals are computed again only after a sweep placed some of its nodes, so the sweeps of
    impulses alone compute them once, and those sweeps keep each node's shares and gaps from
    their first visit (work.ply_memo, _pass). The first sweep meets every node; the later
    ones only the nodes near those that changed by more than the tolerances since their pair
    was met (_apply's hot boxes, _pass): elsewhere a pass would give the same impulses and
    placements within them. Under a projectile the sweeps rarely converge (a sharp fold), and
    the first sweep costs what every sweep cost before; the sweeps of impulses alone made the
    whole pack-field run 1.6 × as long (3.9 × before they kept the shares and normals:
    docs/packs.md, docs/theory.md §5.1). A node the projectile drives acts as one of infinite
    mass (_pass): the projectile put it on its surface, and the pack below is placed against
    it. Its velocity stays as the
    projectile left it until the sweeps end, and only then takes the −J its pairs gave it
    (_apply_driven; the projectile's next contact brings it back to the surface): applied sweep
    by sweep, it slowed by its first −J/m and then parted from the node below, so the projectile
    pushed the pack through it once a step, and the push reached down the pack as fast as the
    steps came.
    One simultaneous (Jacobi) pass per step with shared placements, before the projectile's
    contact, let the upper plies of an 8-ply pack under an FSP's flat face close their gaps
    (docs/theory.md §5.1). The order is fixed, so the numbers are the same for any thread
    count, and every pair keeps exact action and reaction."""
    nodes, law = phys.nodes, phys.contact
    plies = nodes.ply_nodes.shape[0] - 1
    if plies < 2:
        return 0.0, 0.0
    acc = work.ply_acc
    nrm = work.ply_normals
    tol = PLY_TOLERANCE * law.ply_gap.min()
    # where the step put the nodes, against which _apply bounds their placements
    start = work.ply_start
    copy_into(start, x)
    shares = _shares_buffer(law, plies)
    # each ply's _region and normals, computed again only after its nodes were placed: the
    # sweeps of impulses alone leave the positions, and so these, as they are
    region = np.empty((plies, 4), dtype=np.int64)
    stale = np.ones(plies, dtype=np.uint8)
    # this call's mark on the nodes' memos of the sweeps of impulses alone (_pass)
    work.ply_epoch[0] += 1
    epoch = work.ply_epoch[0]
    lost = 0.0
    placed = 0.0
    vtol = 0.0  # the velocity tolerance, set by the first sweep
    # per ply, the grid box of its nodes that changed by more than the tolerances (tol for a
    # placement, vtol for Δt|Δv|: _apply; in the first sweep any Δv) in the previous
    # sweep (rows 0..plies − 1) and in this one (rows plies..): the later sweeps meet only the
    # nodes near them (_pass's hot boxes)
    hot = np.empty((2 * plies, 4), dtype=np.int64)
    _clear_boxes(hot, int64(0), 2 * plies)  # int64: a literal compiles it once more
    box = np.zeros(9, dtype=np.int64)
    placing = True
    velocity_sweeps = 0
    for sweep in range(PLY_SWEEPS + PLY_VELOCITY_SWEEPS):
        if sweep > 0:
            for r in range(plies):
                for c in range(4):
                    hot[r, c] = hot[plies + r, c]
            _clear_boxes(hot, plies, 2 * plies)
        box[0] = 1 if sweep > 0 else 0
        moved = 0.0
        sped = 0.0
        for q in range(plies - 1):
            p = q if sweep % 2 == 0 else plies - 2 - q
            if sweep > 0:
                # since this pair was met: where its plies' nodes changed in the last sweep
                # and so far in this one (none: the pair is not met again). A pair whose
                # neighbours' last changes were within the tolerances was once skipped as
                # well, but a neighbour met again since could have changed this pair's
                # plies before and nothing after: a sweep then stopped with the pair below a
                # held ply at half its speed (tests/test_plies.py)
                # int64(): each literal position would compile _hot_union once more
                lo = _hot_union(hot, plies, p, box, int64(5))
                up = _hot_union(hot, plies, p + 1, box, int64(1))
                if not (lo or up):
                    continue
            for s in range(2):
                if stale[p + s]:
                    _region(nodes, p + s, x, region[p + s])
                    _normals(nodes, p + s, x, nrm, region[p + s])
                    stale[p + s] = 0
            # bool(): while its type is inferred, placing is also the literal True, and _pass
            # would be compiled for that too
            law_p = (0.0, 0.0, v, driven, bool(placing))
            _pass(phys, p, p + 1, -1.0, x, v, nrm, acc,
                  (law.ply_guess[0], work.ply_near[0], work.ply_memo[0], work.ply_stamp[0],
                   epoch, (work.ply_sum[0], work.ply_sum_at[0], work.ply_sum_stamp[0])),
                  shares, (region[p], box), law_p)
            if sweep > 0:  # the other way round: ply p is the slave
                for c in range(4):
                    box[1 + c], box[5 + c] = box[5 + c], box[1 + c]
            _pass(phys, p + 1, p, 1.0, x, v, nrm, acc,
                  (law.ply_guess[1], work.ply_near[1], work.ply_memo[1], work.ply_stamp[1],
                   epoch, (work.ply_sum[1], work.ply_sum_at[1], work.ply_sum_stamp[1])),
                  shares, (region[p + 1], box), law_p)
            d_lost, d_placed, d_moved, d_sped = _apply(
                phys, sin, x, v, acc, lag, (nodes.ply_nodes[p], nodes.ply_nodes[p + 2]),
                work.flag, work.node_field, (hot[plies:], p, tol, vtol, driven), start)
            if d_moved > 0.0:
                stale[p] = 1
                stale[p + 1] = 1
            lost += d_lost
            placed += d_placed
            moved = max(moved, d_moved)
            sped = max(sped, d_sped)
        if sweep == 0:
            vtol = PLY_VELOCITY_TOLERANCE * sped
        if moved <= tol and sped <= vtol:
            break
        if placing:
            # the placements have converged (or reached PLY_SWEEPS): the later sweeps resolve
            # the velocities on the geometry as it is (PLY_VELOCITY_SWEEPS)
            if moved <= tol or sweep + 1 >= PLY_SWEEPS:
                placing = False
        else:
            velocity_sweeps += 1
            if velocity_sweeps >= PLY_VELOCITY_SWEEPS:
                break
    if driven.shape[0] > 0:
        lost += _apply_driven(phys, x, v, acc, driven)
    return lost, placed


_FAR = 1 << 62
"""An empty hot box's lower bounds (_clear_boxes)."""


@njit(cache=True, _nrt=False)
def _clear_boxes(hot, r0, r1):
    """Rows r0..r1 − 1 of ply_contact's hot boxes: empty (i_lo > i_hi)."""
    for r in range(r0, r1):
        hot[r, 0] = _FAR
        hot[r, 1] = -1
        hot[r, 2] = _FAR
        hot[r, 3] = -1


@njit(cache=True, _nrt=False)
def _hot_union(hot, plies, ply, box, at):
    """box[at:at + 4] = the union of ply `ply`'s hot boxes of the last sweep and this one
    (ply_contact); returns whether it holds a node."""
    a, b = hot[ply], hot[plies + ply]
    box[at] = min(a[0], b[0])
    box[at + 1] = max(a[1], b[1])
    box[at + 2] = min(a[2], b[2])
    box[at + 3] = max(a[3], b[3])
    return box[at] <= box[at + 1]
