"""The applied field, one function: ``field_at(fld, x, t) -> (E, B)``; and the Lorentz force.

Every kernel that needs the field at a point (node update, body wrench, energy bookkeeping)
calls field_at; a new field source is a new branch here and a new scenario entry.
"""

from numba import njit

from emfabric._kernels.records import REGION_HALF_SPACE

_ZERO = (0.0, 0.0, 0.0)


@njit(cache=True, inline="always")
def field_at(fld, x, t):
    """Electric [V/m] and magnetic [T] field at the point x (a 3-tuple, m) and time t [s].

    Uniform, or confined to the half-space z < z0 (zero field outside). Branch-free (a weight
    of 1 or 0), so that the node kernel's loops that call it stay vectorised."""
    w = 1.0 if (fld.region != REGION_HALF_SPACE or x[2] < fld.z0) else 0.0
    e = fld.E
    b = fld.B
    return (w * e[0], w * e[1], w * e[2]), (w * b[0], w * b[1], w * b[2])


@njit(cache=True, inline="always")
def has_electric_field(fld):
    """Whether E can be non-zero anywhere (the energy bookkeeping skips field work if not)."""
    return fld.E[0] != 0.0 or fld.E[1] != 0.0 or fld.E[2] != 0.0


@njit(cache=True, inline="always")
def magnetic_force(q, v, b):
    """q v × B [N]: the magnetic part of the Lorentz force, no work."""
    return (q * (v[1] * b[2] - v[2] * b[1]), q * (v[2] * b[0] - v[0] * b[2]),
            q * (v[0] * b[1] - v[1] * b[0]))


@njit(cache=True, inline="always")
def lorentz_force(q, e, b, v):
    """q (E + v × B) [N], eq. 2.7 / 6.2 (a charge q at velocity v in the fields E, B).

    The fabric nodes take it in two parts, q E explicit and q v × B implicit in the new velocity
    (solved exactly per node, emfabric._kernels.nodes), then magnetic_force for the record."""
    return (q * (e[0] + (v[1] * b[2] - v[2] * b[1])), q * (e[1] + (v[2] * b[0] - v[0] * b[2])),
            q * (e[2] + (v[0] * b[1] - v[1] * b[0])))
