"""The projectile's shape, one interface: inside test, closest surface point and outward normal,
the point a yarn segment presses against, and the bounding radius.

Points are given relative to the centre of mass in the inertial frame (d = x − x_cm) with the
body's rotation ``rot`` (body → inertial). The sphere needs no rotation. The other shapes are
described in their own frame (``Body.frame``: rows e1, e2, e3 in the body frame; e3 the nose
axis, the origin at the centre of mass, s = q3 + ``Body.base`` the height above the base face):

- cylinder: 0 ≤ s ≤ L, ρ ≤ R (ρ the distance from the axis);
- ogive: a tangent-ogive nose of length L_n on a cylinder of length L − L_n: for s ≥ L − L_n the
  meridian profile is the arc of radius ϱ = (R² + L_n²)/(2R) centred at (s, ρ) = (L − L_n,
  R − ϱ), tangent to the cylinder and closing to a point at s = L;
- fsp: the cylinder cut by two chisel faces y·cos β + s·sin β ≤ w/2·cos β + L·sin β (and the
  mirror face in −y), which meet the end face s = L in a flat of width w along e1.

Each body is convex and is written as the intersection of constraints g_i(q) ≤ 0, each g_i the
signed distance to its own surface on the inside (a plane, the cylinder, the ogive arc). For an
interior point the distance to the body's surface is then −max_i g_i, reached on the surface of
the arg-max constraint (the nearest point of the complement is a boundary point): the closest
point and normal are exact, not sampled. The ogive's arc and its cylinder are one constraint,
g = |(max(s − L + L_n, 0), ρ + ϱ − R)| − ϱ (which is ρ − R below the nose).
"""

import math

from numba import njit, uint64

from emfabric._kernels.records import (
    BODY_R0,
    BODY_X,
    SHAPE_CYLINDER,
    SHAPE_FSP,
    SHAPE_OGIVE,
    SHAPE_SPHERE,
)
from emfabric._kernels.reductions import SCAN_BLOCK
from emfabric._kernels.vec3 import distance_sq, from_shape_frame, to_shape_frame


@njit(cache=True, inline="always")
def _sphere_surface(radius, d):
    d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    if d2 > 0.0:
        dd = math.sqrt(d2)
        n = (d[0] / dd, d[1] / dd, d[2] / dd)
        # closest point on the surface, eq. 5.1
        # g has the sign of d2 − R² exactly: a node left on the surface by the previous
        # projection is in or out by the same rounding as in the paper's runs
        g = (d2 - radius * radius) / (dd + radius)
        return g, (radius * n[0], radius * n[1], radius * n[2]), n
    return math.inf, d, d


@njit(cache=True, inline="always")
def _radial(q):
    """Distance from the axis and the unit radial direction (e1 on the axis itself)."""
    rr = math.sqrt(q[0] * q[0] + q[1] * q[1])
    if rr > 0.0:
        return rr, q[0] / rr, q[1] / rr
    return 0.0, 1.0, 0.0


@njit(cache=True)
def _local_closest(body, q):
    """(g, surface point, normal) in the shape frame for a point q of that frame: g = max_i g_i
    (< 0 inside, −g the distance to the surface) and the projection onto the arg-max surface."""
    s = q[2] + body.base
    big_l = body.length
    big_r = body.radius
    rr, ux, uy = _radial(q)
    # base face s = 0
    g = -s
    p = (q[0], q[1], -body.base)
    n = (0.0, 0.0, -1.0)
    if body.shape == SHAPE_OGIVE:
        rho = body.arc_radius
        lb = big_l - body.nose_length
        ds = max(s - lb, 0.0)
        dr = rr + rho - big_r
        h = math.sqrt(ds * ds + dr * dr)
        gi = h - rho
        if rr == 0.0 and ds > 0.0:
            # on the axis in the nose every meridian is equally close: take the one point
            # that keeps the symmetry, the tip (a node met dead centre rides on the tip)
            gi = s - big_l
            if gi > g:
                g = gi
                p = (0.0, 0.0, big_l - body.base)
                n = (0.0, 0.0, 1.0)
        elif gi > g:
            # h = 0 only on the axis of a hemispherical nose's base circle: the side point
            ns, nr = (ds / h, dr / h) if h > 0.0 else (0.0, 1.0)
            pr = big_r - rho + rho * nr
            g = gi
            # below the nose (ds = 0, ns = 0) the side point keeps the height s
            p = (pr * ux, pr * uy, min(s, lb) + rho * ns - body.base)
            n = (nr * ux, nr * uy, ns)
        return g, p, n
    # cylinder and fsp: end face s = L and the side ρ = R
    gi = s - big_l
    if gi > g:
        g = gi
        p = (q[0], q[1], big_l - body.base)
        n = (0.0, 0.0, 1.0)
    gi = rr - big_r
    if gi > g:
        g = gi
        p = (big_r * ux, big_r * uy, q[2])
        n = (ux, uy, 0.0)
    if body.shape == SHAPE_FSP:
        cb = body.bevel_cos
        sb = body.bevel_sin
        level = body.flat_half_width * cb + big_l * sb
        for sign in (1.0, -1.0):
            gi = sign * q[1] * cb + s * sb - level
            if gi > g:
                g = gi
                p = (q[0], q[1] - gi * sign * cb, q[2] - gi * sb)
                n = (0.0, sign * cb, sb)
    return g, p, n


@njit(cache=True, inline="always")
def surface_point(body, rot, d):
    """(g, r, n) for a point at d: g < 0 inside the body (−g the distance to the surface),
    r the surface point it projects to (relative to the centre, inertial frame) and n the
    outward unit normal there. Exact for a point inside. For a point outside, g and r belong to
    the most violated constraint: exact for a point just outside a face, which is where contact
    uses it (a contact kept within shapes.contact_margin); farther out, e.g. beyond the ogive's
    tip, r may lie on that constraint's surface off the body."""
    if body.shape == SHAPE_SPHERE:
        return _sphere_surface(body.radius, d)
    g, p, n = _local_closest(body, to_shape_frame(rot, body.frame, d))
    return g, from_shape_frame(rot, body.frame, p), from_shape_frame(rot, body.frame, n)


@njit(cache=True, inline="always")
def closest_surface_point(body, rot, d):
    """(inside, r, n) for a point at d: whether it lies strictly inside the body, and if so the
    closest surface point r (relative to the centre, inertial frame) and the outward unit
    normal n there."""
    g, r, n = surface_point(body, rot, d)
    if g < 0.0:
        return True, r, n
    return False, d, d


@njit(cache=True, inline="always")
def contact_margin(body):
    """Distance outside the surface [m] within which a contact made earlier in the same step is
    kept (so that a contact whose reaction lifts the body off by a hair does not switch on and
    off from one iterate to the next): 10⁻³ of the bounding radius."""
    return 1e-3 * bounding_radius(body)


@njit(cache=True, inline="always")
def is_inside(body, rot, d):
    """Whether the point at d lies strictly inside the body."""
    if body.shape == SHAPE_SPHERE:
        return d[0] * d[0] + d[1] * d[1] + d[2] * d[2] < body.radius * body.radius
    g, _p, _n = _local_closest(body, to_shape_frame(rot, body.frame, d))
    return g < 0.0


@njit(cache=True, inline="always")
def bounding_radius(body):
    """Radius of the smallest sphere about the centre of mass that holds the body [m]."""
    if body.shape == SHAPE_SPHERE:
        return body.radius
    return body.bound


@njit(cache=True, inline="always")
def thinnest_radius(body):
    """The body's smallest radius [m]: the sphere's, or the calibre's half of the other shapes
    (a contact cannot be resolved if the body moves by a sizeable part of it in one step)."""
    return body.radius


@njit(cache=True, inline="always")
def pressing_point(body, rot, m, h):
    """Where a yarn segment x(τ) = c + m + τ·h, τ ∈ [−1, 1] (m: its midpoint relative to the
    centre of mass c, h: half the vector from its first to its second end) presses against the
    body: the parameter τ of its point nearest the centre (sphere) or the body's axis (other
    shapes), clamped to the segment. Odd in h (τ(m, −h) = −τ(m, h) bit for bit), so a segment
    gives the same point whichever end comes first and mirror-image segments mirror-image
    points."""
    if body.shape == SHAPE_SPHERE:
        mp = m
        hp = h
    else:
        a = from_shape_frame(rot, body.frame, (0.0, 0.0, 1.0))
        ma = m[0] * a[0] + m[1] * a[1] + m[2] * a[2]
        ha = h[0] * a[0] + h[1] * a[1] + h[2] * a[2]
        mp = (m[0] - ma * a[0], m[1] - ma * a[1], m[2] - ma * a[2])
        hp = (h[0] - ha * a[0], h[1] - ha * a[1], h[2] - ha * a[2])
    hh = hp[0] * hp[0] + hp[1] * hp[1] + hp[2] * hp[2]
    hfull = h[0] * h[0] + h[1] * h[1] + h[2] * h[2]
    if not hh > 1e-24 * hfull:
        return 0.0
    tau = -(mp[0] * hp[0] + mp[1] * hp[1] + mp[2] * hp[2]) / hh
    return min(max(tau, -1.0), 1.0)


SHAPES = {"sphere": SHAPE_SPHERE, "ogive": SHAPE_OGIVE, "cylinder": SHAPE_CYLINDER,
          "fsp": SHAPE_FSP}


@njit(cache=True, _nrt=True)
def nodes_inside(x, inv_mass, flag, body, b_state):
    """Free nodes (inv_mass > 0) with flag 0 inside the body in state b_state (BODY_ROWS, 3):
    after a step, nodes that were no contact candidates (must be none); before a run, every
    node (flag all 0, inv_mass all 1: the start must be clear of the sheet)."""
    count = 0
    centre = b_state[BODY_X]
    rot = b_state[BODY_R0:BODY_R0 + 3]
    r2 = bounding_radius(body) ** 2
    c = (centre[0], centre[1], centre[2])
    nodes = x.shape[1]
    for b0 in range(0, nodes, SCAN_BLOCK):
        b1 = min(nodes, b0 + SCAN_BLOCK)
        # free nodes of the block that are no candidates and within the bounding sphere,
        # counted in a loop that vectorises (reductions.SCAN_BLOCK): almost always none
        near = 0
        for n in range(b0, b1):
            u = uint64(n)
            near += 1 if ((flag[u] == 0) & (inv_mass[u] > 0.0)
                          & (distance_sq(x, u, c) <= r2)) else 0
        if near != 0:
            count += _inside_in(b0, b1, x, inv_mass, flag, body, centre, rot, r2)
    return count


@njit(cache=True, inline="always")
def _inside_in(b0, b1, x, inv_mass, flag, body, centre, rot, r2):
    """nodes_inside's count over nodes b0 ≤ n < b1."""
    count = 0
    for n in range(b0, b1):
        if flag[n] == 0 and inv_mass[n] > 0.0:
            d = (x[0, n] - centre[0], x[1, n] - centre[1], x[2, n] - centre[2])
            # outside the bounding sphere is outside the body: the shape's test only within
            if d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= r2 and is_inside(body, rot, d):
                count += 1
    return count
