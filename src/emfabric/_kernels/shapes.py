"""The projectile's shape, one interface: inside test, closest surface point and outward normal,
and the bounding radius. The sphere is the first implementation; a new shape is a new function
and one branch in each dispatcher below (and its key in the scenario).

Points are given relative to the centre of mass in the inertial frame (d = x − x_cm) with the
body's rotation ``rot`` (body → inertial), so that a shape without rotational symmetry rotates
d into its own frame; the sphere needs no rotation.
"""

import math

from numba import njit

from emfabric._kernels.records import SHAPE_SPHERE


@njit(cache=True, inline="always")
def _sphere_closest(radius, d):
    d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    if d2 < radius * radius and d2 > 0.0:
        dd = math.sqrt(d2)
        n = (d[0] / dd, d[1] / dd, d[2] / dd)
        # closest point on the surface, eq. 5.1
        return True, (radius * n[0], radius * n[1], radius * n[2]), n
    return False, d, d


@njit(cache=True, inline="always")
def closest_surface_point(body, rot, d):
    """(inside, r, n) for a point at d: whether it lies strictly inside the body, and if so the
    closest surface point r (relative to the centre, inertial frame) and the outward unit
    normal n there."""
    return _sphere_closest(body.radius, d)


@njit(cache=True, inline="always")
def is_inside(body, rot, d):
    """Whether the point at d lies strictly inside the body."""
    return d[0] * d[0] + d[1] * d[1] + d[2] * d[2] < body.radius * body.radius


@njit(cache=True, inline="always")
def bounding_radius(body):
    """Radius of the smallest sphere about the centre of mass that holds the body [m]."""
    return body.radius


SHAPES = {"sphere": SHAPE_SPHERE}
