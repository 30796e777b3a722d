"""The applied field, one function: ``field_at(fld, x, t) -> (E, B)``; and the Lorentz force.

The field is the uniform part (E, B, optionally confined to z < z0) plus the current loops that
coils are made of, each with its current waveform I(t) (emfabric._kernels.coils).

Every kernel that needs the field at a point (node update, body wrench, energy bookkeeping)
calls field_at; a new field source is a new branch here and a new scenario entry.
"""

import math

from numba import njit
from numba.core import types
from numba.extending import overload

from emfabric._kernels.coils import WAVE_CONSTANT, current_at, loop_unit_field
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
    eu = (w * e[0], w * e[1], w * e[2])
    bu = (w * b[0], w * b[1], w * b[2])
    eu, bu = map_fields(fld.map_axes, fld.map_size, fld.map_step, fld.map_values, x, eu, bu)
    return loop_fields(fld.loops, fld.currents, fld.tables, fld.table_len, x, t, eu, bu)


def map_fields(axes, size, step, values, x, e, b):
    """e, b plus the field map's E and B at x (trilinear; nothing outside the map); axes None:
    e, b unchanged. Compiled by the type of `axes`, as loop_fields."""
    if axes is None:
        return e, b
    return _map_lookup(axes, size, step, values, x, e, b)


@overload(map_fields, inline="always")
def _map_fields_typed(axes, size, step, values, x, e, b):
    if isinstance(axes, types.NoneType):
        def no_map(axes, size, step, values, x, e, b):
            return e, b
        return no_map

    def with_map(axes, size, step, values, x, e, b):
        return _map_lookup(axes, size, step, values, x, e, b)
    return with_map


@njit(cache=True, inline="always")
def _cell(grid, n, step, v):
    """(index i, weight w) with grid[i] ≤ v ≤ grid[i + 1], v = (1 − w) grid[i] + w grid[i + 1];
    i = −1 outside [grid[0], grid[n − 1]]. An evenly spaced grid (step > 0) finds the cell by
    division (then checks it against the grid's values), an uneven one by bisection."""
    if not (grid[0] <= v <= grid[n - 1]):
        return -1, 0.0
    if step > 0.0:
        lo = min(max(int((v - grid[0]) / step), 0), n - 2)
        # rounding of the division: step to the neighbour that holds v
        if v < grid[lo] and lo > 0:
            lo -= 1
        elif v > grid[lo + 1] and lo < n - 2:
            lo += 1
        return lo, (v - grid[lo]) / (grid[lo + 1] - grid[lo])
    lo, hi = 0, n - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if grid[mid] <= v:
            lo = mid
        else:
            hi = mid
    return lo, (v - grid[lo]) / (grid[hi] - grid[lo])


@njit(cache=True)
def _map_lookup(axes, size, step, values, x, e, b):
    """Trilinear interpolation of the map's six components at x, added to e, b."""
    i, wx = _cell(axes[0], size[0], step[0], x[0])
    j, wy = _cell(axes[1], size[1], step[1], x[1])
    k, wz = _cell(axes[2], size[2], step[2], x[2])
    if i < 0 or j < 0 or k < 0:
        return e, b
    e0, e1, e2, b0, b1, b2 = e[0], e[1], e[2], b[0], b[1], b[2]
    for di in range(2):
        fx = wx if di == 1 else 1.0 - wx
        for dj in range(2):
            fy = wy if dj == 1 else 1.0 - wy
            for dk in range(2):
                f = fx * fy * (wz if dk == 1 else 1.0 - wz)
                if f == 0.0:
                    continue
                p = values[i + di, j + dj, k + dk]
                e0 += f * p[0]
                e1 += f * p[1]
                e2 += f * p[2]
                b0 += f * p[3]
                b1 += f * p[4]
                b2 += f * p[5]
    return (e0, e1, e2), (b0, b1, b2)


def loop_fields(loops, currents, tables, table_len, x, t, e, b):
    """e, b plus the fields of the current loops; loops None: e, b unchanged.

    Compiled code gets one of two implementations chosen by the type of `loops` when it is
    compiled (the overload below): for None (no loops, the paper's case) nothing at all, so
    that the node kernel's loops stay vectorised; else _sum_loops. Called from Python, this
    body does the same."""
    if loops is None:
        return e, b
    return _sum_loops(loops, currents, tables, table_len, x, t, e, b)


@overload(loop_fields, inline="always")
def _loop_fields_typed(loops, currents, tables, table_len, x, t, e, b):
    if isinstance(loops, types.NoneType):
        def no_loops(loops, currents, tables, table_len, x, t, e, b):
            return e, b
        return no_loops

    def with_loops(loops, currents, tables, table_len, x, t, e, b):
        return _sum_loops(loops, currents, tables, table_len, x, t, e, b)
    return with_loops


@njit(cache=True)
def _sum_loops(loops, currents, tables, table_len, x, t, e, b):
    """e, b plus the fields of the current loops (coils are sums of loops): B from each loop's
    current I(t), and the induced E = −(dI/dt) A_φ φ̂ (emfabric._kernels.coils)."""
    ex, ey, ez = e
    bx, by, bz = b
    for k in range(loops.shape[0]):
        current, rate = current_at(currents[k], tables[k], table_len[k], t)
        if current == 0.0 and rate == 0.0:
            continue
        lp = loops[k]
        dx, dy, dz = x[0] - lp[0], x[1] - lp[1], x[2] - lp[2]
        nx, ny, nz = lp[3], lp[4], lp[5]
        z = dx * nx + dy * ny + dz * nz
        rx, ry, rz = dx - z * nx, dy - z * ny, dz - z * nz
        rho = math.sqrt(rx * rx + ry * ry + rz * rz)
        b_rho, b_ax, a_phi = loop_unit_field(lp[6], lp[7], rho, z)
        if rho > 0.0:
            ux, uy, uz = rx / rho, ry / rho, rz / rho
        else:
            ux, uy, uz = 0.0, 0.0, 0.0
        bx += current * (b_rho * ux + b_ax * nx)
        by += current * (b_rho * uy + b_ax * ny)
        bz += current * (b_rho * uz + b_ax * nz)
        # φ̂ = n × ρ̂
        ex -= rate * a_phi * (ny * uz - nz * uy)
        ey -= rate * a_phi * (nz * ux - nx * uz)
        ez -= rate * a_phi * (nx * uy - ny * ux)
    return (ex, ey, ez), (bx, by, bz)


@njit(cache=True, inline="always")
def has_electric_field(fld):
    """Whether E can be non-zero anywhere (the energy bookkeeping skips field work if not):
    a uniform E, or a loop whose current changes in time (its induced E)."""
    if fld.E[0] != 0.0 or fld.E[1] != 0.0 or fld.E[2] != 0.0:
        return True
    for k in range(fld.currents.shape[0]):
        if int(fld.currents[k, 0]) != WAVE_CONSTANT:
            return True
    return fld.map_has_e


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


@njit(cache=True, inline="always")
def _with_sources(fld):
    """Whether the field has loops or a map. Both members are None in the record of a uniform
    field, so this is a constant of the record's type, folded when the caller is compiled."""
    return not (fld.loops is None and fld.map_axes is None)


@njit(cache=True, inline="always")
def fill_row_fields(fld, px, py, pz, count, t, out):
    """Field at `count` points of a grid row into out (6, ≥ count): Ex Ey Ez Bx By Bz — only
    for a field with sources; for the uniform field nothing (row_field computes it inline)."""
    if _with_sources(fld):
        for i in range(count):
            e, b = field_at(fld, (px[i], py[i], pz[i]), t)
            for c in range(3):
                out[c, i] = e[c]
                out[3 + c, i] = b[c]


@njit(cache=True, inline="always")
def row_field(fld, out, i, x, t):
    """(E, B) at node i of a row: field_at itself for the uniform field (a compare and a
    select: cheaper than a store and a load), the value fill_row_fields stored otherwise (the
    sources are evaluated once per node and iterate, not in every loop that needs them)."""
    if _with_sources(fld):
        return (out[0, i], out[1, i], out[2, i]), (out[3, i], out[4, i], out[5, i])
    return field_at(fld, x, t)
