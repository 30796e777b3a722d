"""How far a clamped fabric can ever reach with the energy it has (the stop rule of a run whose
sheet keeps moving after the projectile has left: emfabric.sim.reach).

A node of a clamped ply hangs on its warp and its fill yarn, each held at both ends by clamped
nodes. A yarn's half from clamp c to the node, of rest length P and compliance C = Σ 1/k (the
segments in series), stores at least ½ e²/C once the node is a distance P + e from c (the
stretch spreads evenly over the segments at least energy; every yarn law here stores at
least the linear spring's energy ½ k ΔL²). With at most the energy E in the fabric, a node
therefore lies inside balls around its four clamps whose radii share E; the kernel bounds the
node's largest coordinate along a direction over every split of E, rigorously (each split's
interval bounded by its ends: the radii only grow with the energy)."""

import math

import numpy as np
from numba import njit

from emfabric._kernels.records import ROW_COUNT, ROW_FILL, ROW_NODE, ROW_WARP

SPLITS = 8
"""Intervals of the split of a yarn's energy between its two halves."""
BISECTIONS = 24
"""Bisections of the split of the node's energy between its warp and its fill yarn."""


@njit(cache=True)
def two_ball_max(c1, r1, c2, r2, e):
    """The largest x·e over the intersection of the balls (c1, r1) and (c2, r2) (c, e: three
    numbers, a tuple or a (3,) array; an empty intersection gives the smaller ball's own
    largest value, an upper bound either way)."""
    top1 = c1[0] * e[0] + c1[1] * e[1] + c1[2] * e[2] + r1
    top2 = c2[0] * e[0] + c2[1] * e[1] + c2[2] * e[2] + r2
    ux = c2[0] - c1[0]
    uy = c2[1] - c1[1]
    uz = c2[2] - c1[2]
    dist = math.sqrt(ux * ux + uy * uy + uz * uz)
    if dist == 0.0:
        return min(top1, top2)
    # ball 1's top inside ball 2, or ball 2's top inside ball 1: that top is the answer
    px = c1[0] + r1 * e[0] - c2[0]
    py = c1[1] + r1 * e[1] - c2[1]
    pz = c1[2] + r1 * e[2] - c2[2]
    if px * px + py * py + pz * pz <= r2 * r2:
        return top1
    px = c2[0] + r2 * e[0] - c1[0]
    py = c2[1] + r2 * e[1] - c1[1]
    pz = c2[2] + r2 * e[2] - c1[2]
    if px * px + py * py + pz * pz <= r1 * r1:
        return top2
    # otherwise the top lies on the circle where the spheres meet
    a = (dist * dist + r1 * r1 - r2 * r2) / (2.0 * dist)
    rad2 = r1 * r1 - a * a
    if rad2 < 0.0:
        return min(top1, top2)
    ux /= dist
    uy /= dist
    uz /= dist
    eu = ux * e[0] + uy * e[1] + uz * e[2]
    centre = (c1[0] * e[0] + c1[1] * e[1] + c1[2] * e[2]) + a * eu
    return centre + math.sqrt(rad2) * math.sqrt(max(1.0 - eu * eu, 0.0))


@njit(cache=True)
def yarn_reach(ca, pa, cmpa, cb, pb, cmpb, energy, e):
    """Upper bound of x·e for a node on one yarn whose halves (clamp c, rest length p,
    compliance cmp) store at most `energy` together."""
    best = -math.inf
    for k in range(SPLITS):
        lo = energy * k / SPLITS
        hi = energy * (k + 1) / SPLITS
        ra = pa + math.sqrt(2.0 * hi * cmpa)
        rb = pb + math.sqrt(2.0 * (energy - lo) * cmpb)
        best = max(best, two_ball_max(ca, ra, cb, rb, e))
    return best


@njit(cache=True)
def _halves(rows, j0, j1, inv_mass, rest, keff, fam, clamp, length, comp):
    """For every node of one ply (rows j0 ≤ j < j1) and both directions along its yarn of
    family `fam` (0 warp, along a row; 1 fill, along a column): the clamped node at that end
    (−1 if a broken segment or a free end comes first), the rest length and the compliance
    between. Writes clamp/length/comp[fam * 2 + side, node]."""
    nx = rows[j0, ROW_COUNT]
    ny = j1 - j0
    first = rows[j0, ROW_NODE]
    lines = ny if fam == 0 else nx
    count = nx if fam == 0 else ny
    for line in range(lines):
        for side in range(2):
            c = -1
            p = 0.0
            q = 0.0
            for step in range(count):
                k = step if side == 0 else count - 1 - step
                if fam == 0:
                    node = first + line * nx + k
                else:
                    node = first + k * nx + line
                if step > 0:
                    # the segment between this node and the previous one along the walk
                    kk = k - 1 if side == 0 else k
                    if fam == 0:
                        s = rows[j0 + line, ROW_WARP] + kk
                    else:
                        s = rows[j0 + kk, ROW_FILL] + line
                    if c >= 0 and keff[s] > 0.0:
                        p += rest[s]
                        q += 1.0 / keff[s]
                    else:
                        c = -1
                if inv_mass[node] == 0.0:
                    c = node
                    p = 0.0
                    q = 0.0
                row = fam * 2 + side
                clamp[row, node] = c
                length[row, node] = p
                comp[row, node] = q


@njit(cache=True, inline="always")
def _point(x, k):
    """Node k's position in x (3, N) as three numbers."""
    return (x[0, k], x[1, k], x[2, k])


@njit(cache=True)
def fabric_reach(rows, ply_rows, x0, inv_mass, rest, keff, energy, e, limit, first):
    """A bound on the largest x·e any free node of the clamped fabric can ever reach with at
    most `energy` in it (keff: each segment's lower-bound stiffness, 0 for a broken one), or
    +inf as soon as a node's bound passes `limit` or a node hangs on no yarn clamped at both
    ends. The verdict against `limit` is that of each node's tightest bound; a node shown below
    it stops tightening its bound there. Node `first` is tried first (the one likeliest to
    fail: the test then ends at once)."""
    n = x0.shape[1]
    clamp = np.full((4, n), -1, dtype=np.int64)
    length = np.zeros((4, n))
    comp = np.zeros((4, n))
    for ply in range(ply_rows.shape[0] - 1):
        j0 = ply_rows[ply]
        j1 = ply_rows[ply + 1]
        _halves(rows, j0, j1, inv_mass, rest, keff, 0, clamp, length, comp)
        _halves(rows, j0, j1, inv_mass, rest, keff, 1, clamp, length, comp)
    # the clamps' positions and the direction as numbers, not array views: a view per call
    # (each reference-counted) made a pass over the nodes 2–3 × slower (docs/performance.md)
    et = (e[0], e[1], e[2])
    reach = -math.inf
    for idx in range(-1, n):
        node = first if idx < 0 else idx
        if inv_mass[node] == 0.0:
            continue
        warp = clamp[0, node] >= 0 and clamp[1, node] >= 0
        fill = clamp[2, node] >= 0 and clamp[3, node] >= 0
        if not warp and not fill:
            return math.inf
        bw = math.inf
        bf = math.inf
        # (et stands in for the clamps of a yarn that does not hold the node: never read)
        wa = _point(x0, clamp[0, node]) if warp else et
        wb = _point(x0, clamp[1, node]) if warp else et
        fa = _point(x0, clamp[2, node]) if fill else et
        fb = _point(x0, clamp[3, node]) if fill else et
        if warp:
            bw = yarn_reach(wa, length[0, node], comp[0, node],
                            wb, length[1, node], comp[1, node], energy, et)
        if fill:
            bf = yarn_reach(fa, length[2, node], comp[2, node],
                            fb, length[3, node], comp[3, node], energy, et)
        bound = min(bw, bf)  # each yarn alone with all the energy: a first, cheap bound
        if bound > limit and warp and fill:
            # the energy is shared between the two yarns: bisect the split where the warp's
            # bound meets the fill's (each grows with its share). The crossing lies in
            # [lo, hi], so min(warp's bound at hi, fill's at energy − lo) bounds the node at
            # every bisection, and it only falls: once below the limit, the node passes (the
            # same verdict as bisecting on; its bound then a little looser)
            lo = 0.0
            hi = energy
            gw_hi = bw  # the warp's bound with hi = energy, the fill's with energy − lo
            gf_lo = bf
            for _ in range(BISECTIONS):
                if min(gw_hi, gf_lo) < limit:
                    break
                mid = 0.5 * (lo + hi)
                gw = yarn_reach(wa, length[0, node], comp[0, node],
                                wb, length[1, node], comp[1, node], mid, et)
                gf = yarn_reach(fa, length[2, node], comp[2, node],
                                fb, length[3, node], comp[3, node], energy - mid, et)
                if gw < gf:
                    lo = mid
                    gf_lo = gf
                else:
                    hi = mid
                    gw_hi = gw
            bound = min(bound, gw_hi, gf_lo)
        if bound > limit:
            return math.inf
        reach = max(reach, bound)
    return reach


@njit(cache=True)
def _held(u, alpha, k, l2, rate, uc):
    """Energy (lower bound: the linear spring) a segment holds stretched to U with the damage
    eq. 2.6 gives it there."""
    a = min(alpha, math.exp(-rate * max(u - uc, 0.0) / uc))
    return 0.5 * a * k * l2 * (u - 1.0) ** 2


@njit(cache=True)
def least_stiffness(alpha, k, l2, brittle, rate, uc, fail2, energy, out):
    """out[s] = the least axial stiffness segment s can have while the fabric holds at most
    `energy` (k: its linear spring below the law, l2: L0²; 0 when broken). Returns False when
    some segment could break (brittle: its energy at the failure strain is within reach) or
    soften without bound (eq. 2.6 past the peak of the energy it holds)."""
    for s in range(k.shape[0]):
        al = alpha[s]
        if not (k[s] > 0.0 and al > 0.0):
            out[s] = 0.0
            continue
        if brittle:
            ef = math.sqrt(fail2[s]) - 1.0
            if 0.5 * al * k[s] * l2[s] * ef * ef <= energy:
                return False
            out[s] = al * k[s]
            continue
        if rate <= 0.0:
            out[s] = al * k[s]
            continue
        # the energy held rises up to the later of the peak of (U − 1)² exp(−λ(U − U_c)/U_c)
        # and the stretch where eq. 2.6 starts to lower the present α, then falls
        top = max(1.0 + 2.0 * uc / rate, uc * (1.0 - math.log(al) / rate))
        if _held(top, al, k[s], l2[s], rate, uc) <= energy:
            return False
        lo = 1.0
        hi = top
        for _ in range(BISECTIONS + 6):
            mid = 0.5 * (lo + hi)
            if _held(mid, al, k[s], l2[s], rate, uc) > energy:
                hi = mid
            else:
                lo = mid
        out[s] = min(al, math.exp(-rate * max(hi - uc, 0.0) / uc)) * k[s]
    return True
