"""The applied field, one function: ``field_at(fld, x, t) -> (E, B)``; and the Lorentz force.

The field is the uniform part (E, B, optionally confined to z < z0) plus the current loops that
coils are made of, each with its current waveform I(t) (emfabric._kernels.coils).

Every kernel that needs the field at a point (node update, body wrench, energy bookkeeping)
calls field_at; a new field source is a new branch here and a new scenario entry.
"""

import math

import numpy as np
from numba import njit, prange
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
    return source_fields(fld.grid_values, fld, x, t, eu, bu)


@njit(cache=True)
def group_waves(fld, t):
    """Each grid group's waveform and its rate at t: (w, dw/dt), arrays (groups,)."""
    count = fld.grid_wave.shape[0]
    cur = np.empty(count)
    rate = np.empty(count)
    for g in range(count):
        k = fld.grid_wave[g]
        if k < 0:
            cur[g], rate[g] = 1.0, 0.0
        else:
            cur[g], rate[g] = current_at(fld.currents[k], fld.tables[k], fld.table_len[k], t)
    return cur, rate


def source_fields(grid, fld, x, t, e, b):
    """e, b plus the loops' and magnets' fields at x, t: from the source grid if there is one
    (_grid_sum), else the loops exactly. Compiled by the type of `grid`, as loop_fields."""
    if grid is None:
        return loop_fields(fld.loops, fld.currents, fld.tables, fld.table_len, x, t, e, b)
    cur, rate = group_waves(fld, t)
    return _grid_sum(fld, x, t, cur, rate, e, b)


@overload(source_fields, inline="always")
def _source_fields_typed(grid, fld, x, t, e, b):
    if isinstance(grid, types.NoneType):
        def no_grid(grid, fld, x, t, e, b):
            return loop_fields(fld.loops, fld.currents, fld.tables, fld.table_len, x, t, e, b)
        return no_grid

    def with_grid(grid, fld, x, t, e, b):
        cur, rate = group_waves(fld, t)
        return _grid_sum(fld, x, t, cur, rate, e, b)
    return with_grid


@njit(cache=True)
def _grid_sum(fld, x, t, cur, rate, e, b):
    """e, b plus the grid's groups at x, and the loops exactly where the grid does not hold
    them (_grid_lookup). A call, not inlined: the per-point path (body charges, the command
    line); inlined it reached the node kernel's dead uniform branch and tripped a Numba IR
    check (the node pass uses the hoisted loop of fill_fields instead)."""
    e, b, loops_in = _grid_lookup(fld.grid_values, fld.grid_origin, fld.grid_step,
                                  fld.grid_cells, fld.grid_exact, fld.grid_wave,
                                  fld.grid_loops, cur, rate, x, e, b)
    if not loops_in:
        return loop_fields(fld.loops, fld.currents, fld.tables, fld.table_len, x, t, e, b)
    return e, b


@njit(cache=True, inline="always")
def _grid_lookup(vals, origin, step, cells, exact, wave, grid_loops, cur, rate, x, e, b):
    """(e, b plus the grid's groups at x, whether the loops are among them). Trilinear: each
    group's b times its waveform w and the induced −(dw/dt) a. The loops are not taken from
    the grid outside it, in a cell marked exact, or at all when grid_loops is False (the caller
    adds them exactly then); the magnets exist only in the grid: nothing outside it.

    Takes the record's arrays, not the record: a per-point access of a record's array member
    costs a reference count (the node pass hoists them out of its loop)."""
    gx = (x[0] - origin[0]) / step[0]
    gy = (x[1] - origin[1]) / step[1]
    gz = (x[2] - origin[2]) / step[2]
    ex, ey, ez = e
    bx, by, bz = b
    if not (0.0 <= gx <= cells[0] and 0.0 <= gy <= cells[1] and 0.0 <= gz <= cells[2]):
        return (ex, ey, ez), (bx, by, bz), False
    i = min(int(gx), cells[0] - 1)
    j = min(int(gy), cells[1] - 1)
    k = min(int(gz), cells[2] - 1)
    wx, wy, wz = gx - i, gy - j, gz - k
    loops_in = grid_loops and exact[k, j, i] == 0
    ux, uy, uz = 1.0 - wx, 1.0 - wy, 1.0 - wz
    for g in range(vals.shape[0]):
        if not (loops_in or wave[g] < 0):
            continue
        w, dw = cur[g], rate[g]
        if w == 0.0 and dw == 0.0:
            continue
        r0 = r1 = r2 = r3 = r4 = r5 = 0.0
        for di in range(2):
            fx = wx if di == 1 else ux
            for dj in range(2):
                fxy = fx * (wy if dj == 1 else uy)
                f0 = fxy * uz
                f1 = fxy * wz
                a, bb = i + di, j + dj
                r0 += f0 * vals[g, k, bb, a, 0] + f1 * vals[g, k + 1, bb, a, 0]
                r1 += f0 * vals[g, k, bb, a, 1] + f1 * vals[g, k + 1, bb, a, 1]
                r2 += f0 * vals[g, k, bb, a, 2] + f1 * vals[g, k + 1, bb, a, 2]
                if dw != 0.0:
                    r3 += f0 * vals[g, k, bb, a, 3] + f1 * vals[g, k + 1, bb, a, 3]
                    r4 += f0 * vals[g, k, bb, a, 4] + f1 * vals[g, k + 1, bb, a, 4]
                    r5 += f0 * vals[g, k, bb, a, 5] + f1 * vals[g, k + 1, bb, a, 5]
        bx += w * r0
        by += w * r1
        bz += w * r2
        if dw != 0.0:
            ex -= dw * r3
            ey -= dw * r4
            ez -= dw * r5
    return (ex, ey, ez), (bx, by, bz), loops_in


def fill_fields(grid, fld, x, v, dt, t, out):
    """out (6, N) = E, B at the points x + Δt v (3, N) and time t: field_at at each point,
    with the record's arrays taken out once (compiled by the type of `grid`, as
    loop_fields)."""
    _fill_plain(fld, x, v, dt, t, out)


@njit(cache=True)
def _fill_plain(fld, x, v, dt, t, out):
    """fill_fields point by point through field_at (no source grid)."""
    for n in range(x.shape[1]):
        e, b = field_at(fld, (x[0, n] + dt * v[0, n], x[1, n] + dt * v[1, n],
                              x[2, n] + dt * v[2, n]), t)
        for c in range(3):
            out[c, n] = e[c]
            out[3 + c, n] = b[c]


@overload(fill_fields)
def _fill_fields_typed(grid, fld, x, v, dt, t, out):
    if isinstance(grid, types.NoneType):
        def plain(grid, fld, x, v, dt, t, out):
            _fill_plain(fld, x, v, dt, t, out)
        return plain

    def hoisted(grid, fld, x, v, dt, t, out):
        cur, rate = group_waves(fld, t)
        ue, ub, region, z0 = fld.E, fld.B, fld.region, fld.z0
        axes, size, mstep, mvals = fld.map_axes, fld.map_size, fld.map_step, fld.map_values
        origin, step, cells, exact = fld.grid_origin, fld.grid_step, fld.grid_cells, \
            fld.grid_exact
        wave, grid_loops = fld.grid_wave, fld.grid_loops
        for n in range(x.shape[1]):
            p = (x[0, n] + dt * v[0, n], x[1, n] + dt * v[1, n], x[2, n] + dt * v[2, n])
            w = 1.0 if (region != REGION_HALF_SPACE or p[2] < z0) else 0.0
            e = (w * ue[0], w * ue[1], w * ue[2])
            b = (w * ub[0], w * ub[1], w * ub[2])
            e, b = map_fields(axes, size, mstep, mvals, p, e, b)
            e, b, loops_in = _grid_lookup(grid, origin, step, cells, exact, wave, grid_loops,
                                          cur, rate, p, e, b)
            if not loops_in:
                e, b = loop_fields(fld.loops, fld.currents, fld.tables, fld.table_len, p, t,
                                   e, b)
            for c in range(3):
                out[c, n] = e[c]
                out[3 + c, n] = b[c]
    return hoisted


def map_fields(axes, size, step, values, x, e, b):
    """e, b plus the field map's E and B at x (trilinear; nothing outside the map); axes None:
    e, b unchanged. Compiled by the type of `axes`, as loop_fields."""
    if axes is None or axes.shape[1] == 0:
        return e, b
    return _map_lookup(axes, size, step, values, x, e, b)


@overload(map_fields, inline="always")
def _map_fields_typed(axes, size, step, values, x, e, b):
    if isinstance(axes, types.NoneType):
        def no_map(axes, size, step, values, x, e, b):
            return e, b
        return no_map

    def with_map(axes, size, step, values, x, e, b):
        if axes.shape[1] == 0:  # a record of sources without a map (sources.build.one_type)
            return e, b
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
        # loop_vectors' geometry, written out: the E of a compiled caller of loop_vectors
        # differed by an ulp between the node pass and field_at (tests compare them bit for bit)
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
def with_sources(fld):
    """Whether the field has loops, a map or a source grid. These members are None in the
    record of a uniform field, so this is a constant of the record's type, folded when the
    caller is compiled."""
    return not (fld.loops is None and fld.map_axes is None and fld.grid_values is None)


@njit(cache=True, _nrt=True)
def fill_node_fields(fld, x, v, dt, t, out):
    """The field of a field with sources at every node, once per attempted step: out (6, N)
    = Ex Ey Ez Bx By Bz at the predicted position x + Δt v and time t (the step's end).

    The node update takes the field from here in every fixed-point iterate instead of at the
    iterate itself: the iterates differ from the prediction by O(Δt² a), so the field's error
    is O(Δt² |a| |∇B|), a local error of the φ-scheme's own order (second)."""
    fill_fields(fld.grid_values, fld, x, v, dt, t, out)


@njit(cache=True, _nrt=True)
def electric_at_nodes(fld, nf, x, out):
    """out (3, N) = the electric field the node update used at the nodes x: the stored field of
    the attempt for sources (nf, at its time), field_at's for the uniform field."""
    for n in range(x.shape[1]):
        e, _b = node_field(fld, nf, n, (x[0, n], x[1, n], x[2, n]))
        out[0, n] = e[0]
        out[1, n] = e[1]
        out[2, n] = e[2]


FIELD_CHUNK = 512
"""Nodes per task of fill_node_fields_threads."""


@njit(parallel=True, _nrt=True)  # never cached on its own, as nodes.fused_iterate_threads
def fill_node_fields_threads(fld, x, v, dt, t, out):
    """fill_node_fields over chunks of nodes in parallel threads (each node's field is the
    same arithmetic whatever the thread count)."""
    n = x.shape[1]
    for c in prange((n + FIELD_CHUNK - 1) // FIELD_CHUNK):
        a = c * FIELD_CHUNK
        b = min(n, a + FIELD_CHUNK)
        fill_fields(fld.grid_values, fld, x[:, a:b], v[:, a:b], dt, t, out[:, a:b])


@njit(cache=True, inline="always")
def uniform_field(fld):
    """((E, B, region, z0), sourced): the uniform part of the Field record as plain numbers and
    whether it has sources (a constant of the record's type). What node_field_of needs, with no
    array in it: an inlined per-row function that is given the record itself references and
    releases each of its arrays (atomic operations) on every call (nodes._rotate_row)."""
    e, b = fld.E, fld.B
    return ((e[0], e[1], e[2]), (b[0], b[1], b[2]), fld.region, fld.z0), with_sources(fld)


@njit(cache=True, inline="always")
def node_field_of(uni, sourced, nf, n, x):
    """node_field from uniform_field's numbers: the same values (a field without sources is
    uniform or a half-space, field_at's w·E, w·B; a field with sources is what
    fill_node_fields stored)."""
    if sourced:
        return (nf[0, n], nf[1, n], nf[2, n]), (nf[3, n], nf[4, n], nf[5, n])
    e, b, region, z0 = uni
    w = 1.0 if (region != REGION_HALF_SPACE or x[2] < z0) else 0.0
    return (w * e[0], w * e[1], w * e[2]), (w * b[0], w * b[1], w * b[2])


@njit(cache=True, inline="always")
def node_field(fld, nf, n, x):
    """(E, B) at node n, at its iterate x, from the Field record: field_at's values for a field
    without sources (a compare and a select: cheaper than a store and a load), what
    fill_node_fields stored otherwise (node_field_of; per-row code calls that directly).
    """
    uni, sourced = uniform_field(fld)
    return node_field_of(uni, sourced, nf, n, x)


@njit(cache=True)
def fields_at_points(fld, points, t, e, b):
    """e, b (N, 3) = field_at at each of the points (N, 3) [m] and time t [s]."""
    for k in range(points.shape[0]):
        ek, bk = field_at(fld, (points[k, 0], points[k, 1], points[k, 2]), t)
        for c in range(3):
            e[k, c] = ek[c]
            b[k, c] = bk[c]
