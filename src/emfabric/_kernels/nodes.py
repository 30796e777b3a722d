"""The node kernels of both schemes: yarn tensions and node forces (_row_force), the φ-scheme's
fixed-point iterate (fused_iterate) and central differences' half steps (drift_rows, kick_rows).

φ-scheme:

v1 = v0 + Δt/m (φ ψ(t+Δt) + (1−φ) ψ(t)),  x1 = x0 + Δt (φ v1 + (1−φ) v0)  (eqs. 3.2, A12–A13),
with the Lorentz force q(E + v1 × B) implicit in v1 (solved exactly per node) and the yarn force
assembled as one difference per node and direction, (t_R − t_L) + (t_U − t_D), which keeps
mirror-symmetric states exactly symmetric. The material law is emfabric._kernels.materials, the
field emfabric._kernels.fields.field_at (at each node's iterate position and at t + Δt).

Central differences (emfabric._kernels.explicit): drift_rows kicks, turns (Boris with the exact
angle) and drifts every node; kick_rows evaluates the force and consumes it at once in the second
turn and kick, with the row sums the step needs (records.SUM_*).

The kernels walk the plies' regular weaves row by row (the layout of emfabric._kernels.records): the
tensions of a row never leave the cache. Each has a serial and a row-block threaded form with
the same arithmetic.
"""

import math

from numba import njit, prange

from emfabric._kernels.fields import magnetic_force, node_field_of, uniform_field
from emfabric._kernels.materials import damage_above, stress_factor, stretch_sq, tangent_factor
from emfabric._kernels.records import (
    ROW_COUNT,
    ROW_FILL,
    ROW_NODE,
    ROW_WARP,
    SUM_ERROR_DEN,
    SUM_ERROR_NUM,
    SUM_PROJECTION,
    SUM_SPEED,
    SUM_STIFFNESS,
    SUM_WORK_FIELD,
    SUM_WORK_GRAVITY,
    RowArrays,
    RowRecords,
)


@njit(cache=True)
def _row_sums(err_num, err_den, rows, row_sums):
    """Per-row sums of the error terms in a fixed order (four interleaved partial sums).

    No fastmath here: a reassociated reduction may be vectorised differently when compiled
    afresh or loaded from Numba's cache, and a last-bit change of ϖ changes Δt and so the run.
    """
    for j in range(rows.shape[0]):
        a0 = a1 = a2 = a3 = 0.0
        b0 = b1 = b2 = b3 = 0.0
        start = rows[j, ROW_NODE]
        stop = start + rows[j, ROW_COUNT]
        i = start
        while i + 3 < stop:
            a0 += err_num[i]
            a1 += err_num[i + 1]
            a2 += err_num[i + 2]
            a3 += err_num[i + 3]
            b0 += err_den[i]
            b1 += err_den[i + 1]
            b2 += err_den[i + 2]
            b3 += err_den[i + 3]
            i += 4
        while i < stop:
            a0 += err_num[i]
            b0 += err_den[i]
            i += 1
        row_sums[SUM_ERROR_NUM, j] = (a0 + a1) + (a2 + a3)
        row_sums[SUM_ERROR_DEN, j] = (b0 + b1) + (b2 + b3)


# rows of a block's row buffer, shape (ROWBUF_ROWS, nx + 1): the first row of each quantity
ROW_WARP_TENSION = 0
"""Tension vectors of a grid row's warp segments, padded with zeros at both ends (3 rows), then
their axial tangent stiffness (one row; written only with TANGENT)."""
ROW_FILL_UP = 4
"""Tension vectors of the fill segments from a row to the next (3 rows), then their tangent
stiffness."""
ROW_FILL_DOWN = 8
"""Tension vectors of the fill segments from the row below (3 rows), then their tangent
stiffness."""
ROW_SEGMENT = 12
"""Segment vectors d = x_b − x_a of the tensions being computed (3 rows)."""
ROW_STRETCH_SQ = 15
"""Their stretch² U²."""
ROW_STRESS = 16
"""Their trial damage α, then α·stiffness·S/𝔼 (the tension per unit length of d)."""
ROW_FORCE = 17
"""Non-magnetic node force of the row: yarns + electric + gravity (3 rows)."""
ROW_VEL_EXPLICIT = 20
"""v0 + Δt/m (φ ψ + (1−φ) ψ0) without the magnetic force: the right side of the implicit
magnetic solve (3 rows). Central differences: the half-kicked velocity v⁻, then per-node terms
of the row's sums."""
ROW_ROTATION = 23
"""u = φΔt q B / m, the rotation vector of the implicit magnetic solve (3 rows); central
differences: Boris's t vector."""
ROW_PROJECTION = 26
"""a·u; central differences: |t|² before the tan correction."""
ROW_INV_DENOM = 27
"""1/(1 + |u|²)."""
ROW_DT_OVER_MASS = 28
"""Δt/m (0 for a clamped node)."""
ROWBUF_ROWS = 29

ALPHA = 1
"""_tensions mode bit: write the trial damage α."""
TANGENT = 2
"""_tensions mode bit: write each segment's axial tangent stiffness (the stable step's)."""


@njit(cache=True)
def _tensions(xa, xb, count, inv_rest2, seg, mat, buf, out, mode):
    """Tension vectors of `count` segments joining a[i] to b[i] into out[:3, :count], and with
    mode & TANGENT their axial tangent stiffness α·stiffness·materials.tangent_factor into
    out[3, :count].

    xa, xb: the (x, y, z) row views of the end nodes; seg: the segments' views (committed α,
    trial α written when mode & ALPHA, damage thresholds U², stiffness); inv_rest2: their 1/L0².
    Split into short loops over few arrays so that the compiler vectorises them.
    """
    xa_x, xa_y, xa_z = xa
    xb_x, xb_y, xb_z = xb
    alpha_c, alpha_t, damage_thr, coef = seg
    dx, dy, dz = buf[ROW_SEGMENT], buf[ROW_SEGMENT + 1], buf[ROW_SEGMENT + 2]
    u2 = buf[ROW_STRETCH_SQ]
    al = buf[ROW_STRESS]
    for i in range(count):
        dx[i] = xb_x[i] - xa_x[i]
        dy[i] = xb_y[i] - xa_y[i]
        dz[i] = xb_z[i] - xa_z[i]
    for i in range(count):
        u2[i] = stretch_sq(dx[i], dy[i], dz[i], inv_rest2)
    for i in range(count):
        al[i] = damage_above(alpha_c[i], u2[i], damage_thr[i], mat)
    if mode & ALPHA:
        for i in range(count):
            alpha_t[i] = al[i]
    if mode & TANGENT:
        kt = out[3]
        for i in range(count):
            kt[i] = al[i] * coef[i] * tangent_factor(u2[i], mat)
    tx, ty, tz = out[0], out[1], out[2]
    # the stress law (materials.stress_factor, the one dispatch on the material's kind: the
    # branch is loop-invariant, so the compiler splits the loop and vectorises each law)
    for i in range(count):
        al[i] = al[i] * coef[i] * stress_factor(u2[i], mat)
    for i in range(count):
        tx[i] = al[i] * dx[i]
        ty[i] = al[i] * dy[i]
        tz[i] = al[i] * dz[i]


@njit(cache=True)
def _block_start(j0, phys, prev, sin, sout, work, buf, mode):
    """Prepare a block's row buffer before its first row j0: zero the padding of the warp row
    and set the fill tensions (with mode & TANGENT their stiffness) from the row below
    (recomputed, writing no damage, so that blocks are independent; zero for the first row of
    a ply). Returns (fill_up, fill_down) views."""
    nodes, yarns, mat = phys.nodes, phys.yarns, phys.material
    rows = nodes.rows
    xx, xy, xz = prev[0], prev[1], prev[2]
    twp = buf[ROW_WARP_TENSION:ROW_WARP_TENSION + 4]
    tu = buf[ROW_FILL_UP:ROW_FILL_UP + 4]
    td = buf[ROW_FILL_DOWN:ROW_FILL_DOWN + 4]
    twp[:, 0] = 0.0
    s = rows[j0 - 1, ROW_FILL] if j0 > 0 else -1
    if s >= 0:
        a = rows[j0 - 1, ROW_NODE]
        nx = rows[j0 - 1, ROW_COUNT]
        coef = yarns.stiffness
        _tensions((xx[a:a + nx], xy[a:a + nx], xz[a:a + nx]),
                  (xx[a + nx:a + 2 * nx], xy[a + nx:a + 2 * nx], xz[a + nx:a + 2 * nx]), nx,
                  yarns.inv_rest2[s],
                  (sin.alpha[s:s + nx], sout.alpha[s:s + nx], work.damage_thr[s:s + nx],
                   coef[s:s + nx]), mat, buf, td, mode & TANGENT)
    else:
        td[:] = 0.0
    return tu, td


@njit(cache=True, inline="always")
def _row_force(j, arr, mat, uni, sourced, grav, prev, buf, tu, td, mode):
    """The non-magnetic force of grid row j at the positions `prev` (and the step's end time:
    the field is uniform, or the node fields stored for it) into the row buffer's ROW_FORCE
    rows: yarn tensions (the warp segments of row j and the fill segments to row j + 1, into
    tu; td holds those from row j − 1), one difference per node and direction, plus the
    electric part of eq. 2.7 and gravity. Trial damage into arr.alpha_trial; with
    mode & TANGENT the segments' tangent stiffness into row 3 of the warp row, tu and td.

    The one force evaluation of both schemes: the φ-update (_row_block) and central
    differences (_kick_block) call it row by row, inlined, given arrays and numbers rather than
    Physics's records (_rotate_row says why): arr a records.RowArrays built once per block, the
    material, the field as fields.uniform_field gives it, gravity as a tuple."""
    rows, mass, charge, inv_rest2, coef, alpha_c, alpha_t, damage_thr, node_fields = arr
    # the row's nodes and first segments (records.Nodes.rows); rest lengths are uniform per
    # yarn family within a ply
    nb = rows[j, ROW_NODE]
    nx = rows[j, ROW_COUNT]
    sb = rows[j, ROW_WARP]
    sf = rows[j, ROW_FILL]
    xx, xy, xz = prev[0], prev[1], prev[2]
    # padded warp row: twp[:, i + 1] is the tension of segment (i, i + 1), zeros at both ends
    twp = buf[ROW_WARP_TENSION:ROW_WARP_TENSION + 4]
    twp[:, nx] = 0.0
    f = buf[ROW_FORCE:ROW_FORCE + 3]
    e = nb + nx
    _tensions((xx[nb:e - 1], xy[nb:e - 1], xz[nb:e - 1]), (xx[nb + 1:e], xy[nb + 1:e],
              xz[nb + 1:e]), nx - 1, inv_rest2[sb],
              (alpha_c[sb:sb + nx - 1], alpha_t[sb:sb + nx - 1],
               damage_thr[sb:sb + nx - 1], coef[sb:sb + nx - 1]), mat, buf, twp[:, 1:],
              mode | ALPHA)
    if sf >= 0:
        _tensions((xx[nb:e], xy[nb:e], xz[nb:e]), (xx[e:e + nx], xy[e:e + nx],
                  xz[e:e + nx]), nx, inv_rest2[sf],
                  (alpha_c[sf:sf + nx], alpha_t[sf:sf + nx],
                   damage_thr[sf:sf + nx], coef[sf:sf + nx]), mat, buf, tu,
                  mode | ALPHA)
    else:
        # the ply's last row: no fill above it (the whole width, so that the first row of the
        # next ply finds no tension from below)
        tu[:, :] = 0.0
    m = mass[nb:e]
    q = charge[nb:e]
    # the field at t1 where the node is now (the iterate). The uniform and half-space
    # fields: field_at in each loop that needs it (a compare and a select, cheaper than a
    # row of stores and loads: the stored variant made an evaluation ~7 % slower); a field
    # with sources: the value fields.fill_node_fields stored for this attempt (at the
    # predicted position). fields.node_field_of, chosen at compile time by the field's type
    px, py, pz = xx[nb:e], xy[nb:e], xz[nb:e]
    for c in range(3):
        fc = f[c]
        tw = twp[c]
        tuc = tu[c]
        tdc = td[c]
        g = grav[c]
        # yarn force, one difference per node and direction (mirror-exact assembly),
        # then the electric part of eq. 2.7 and gravity
        for i in range(nx):
            fe, _fb = node_field_of(uni, sourced, node_fields, nb + i, (px[i], py[i], pz[i]))
            fc[i] = ((tw[i + 1] - tw[i]) + (tuc[i] - tdc[i])) + (m[i] * g + q[i] * fe[c])


@njit(cache=True)
def _row_block(j0, j1, phys, prev, sin, sout, work, t1, phi, dt, buf):
    """Rows j0 ≤ j < j1 of the fused φ iterate: the force of each row (_row_force), consumed at
    once by the φ-update of its nodes (eqs. 3.2, A12–A13) and the error terms of eq. 3.10."""
    nodes, yarns, mat, fld = phys.nodes, phys.yarns, phys.material, phys.field
    uni, sourced = uniform_field(fld)
    grav = (fld.gravity[0], fld.gravity[1], fld.gravity[2])
    node_fields = work.node_field
    arr = RowArrays(nodes.rows, nodes.mass, nodes.charge, yarns.inv_rest2, yarns.stiffness,
                    sin.alpha, sout.alpha, work.damage_thr, node_fields)
    x0, v0, f0 = sin.x, sin.v, sin.f
    x1, v1, f1 = sout.x, sout.v, sout.f
    skip_err = work.flag
    err_num, err_den = work.err_num, work.err_den
    inv_mass, charge = nodes.inv_mass, nodes.charge
    xx, xy, xz = prev[0], prev[1], prev[2]
    tu, td = _block_start(j0, phys, prev, sin, sout, work, buf, 0)
    f = buf[ROW_FORCE:ROW_FORCE + 3]
    acc = buf[ROW_VEL_EXPLICIT:ROW_VEL_EXPLICIT + 3]
    uu = buf[ROW_ROTATION:ROW_ROTATION + 3]
    a_dot_u = buf[ROW_PROJECTION]
    inv = buf[ROW_INV_DENOM]
    dt_over_m = buf[ROW_DT_OVER_MASS]
    for j in range(j0, j1):
        _row_force(j, arr, mat, uni, sourced, grav, prev, buf, tu, td, 0)
        nb = nodes.rows[j, ROW_NODE]
        nx = nodes.rows[j, ROW_COUNT]
        e = nb + nx
        im = inv_mass[nb:e]
        q = charge[nb:e]
        px, py, pz = xx[nb:e], xy[nb:e], xz[nb:e]
        for i in range(nx):
            dt_over_m[i] = dt * im[i]
        for c in range(3):
            fc = f[c]
            ac = acc[c]
            v0c = v0[c, nb:e]
            f0c = f0[c, nb:e]
            for i in range(nx):
                ac[i] = v0c[i] + dt_over_m[i] * (phi * fc[i] + (1.0 - phi) * f0c[i])
        # magnetic part implicit in v1: v1 − v1 × u = a with u = φΔt q B / m (solved exactly)
        ux, uy, uz = uu[0], uu[1], uu[2]
        ax, ay, az = acc[0], acc[1], acc[2]
        for i in range(nx):
            _fe, fb = node_field_of(uni, sourced, node_fields, nb + i, (px[i], py[i], pz[i]))
            beta = phi * dt_over_m[i] * q[i]
            ux[i] = beta * fb[0]
            uy[i] = beta * fb[1]
            uz[i] = beta * fb[2]
        for i in range(nx):
            a_dot_u[i] = ax[i] * ux[i] + ay[i] * uy[i] + az[i] * uz[i]
            inv[i] = 1.0 / (1.0 + ux[i] * ux[i] + uy[i] * uy[i] + uz[i] * uz[i])
        vx, vy, vz = v1[0, nb:e], v1[1, nb:e], v1[2, nb:e]
        for i in range(nx):
            vx[i] = (ax[i] + (ay[i] * uz[i] - az[i] * uy[i]) + a_dot_u[i] * ux[i]) * inv[i]
            vy[i] = (ay[i] + (az[i] * ux[i] - ax[i] * uz[i]) + a_dot_u[i] * uy[i]) * inv[i]
            vz[i] = (az[i] + (ax[i] * uy[i] - ay[i] * ux[i]) + a_dot_u[i] * uz[i]) * inv[i]
        fx, fy, fz = f[0], f[1], f[2]
        gx, gy, gz = f1[0, nb:e], f1[1, nb:e], f1[2, nb:e]
        for i in range(nx):
            _fe, fb = node_field_of(uni, sourced, node_fields, nb + i, (px[i], py[i], pz[i]))
            fm = magnetic_force(q[i], (vx[i], vy[i], vz[i]), fb)
            gx[i] = fx[i] + fm[0]
            gy[i] = fy[i] + fm[1]
            gz[i] = fz[i] + fm[2]
        for c in range(3):
            x0c = x0[c, nb:e]
            v0c = v0[c, nb:e]
            v1c = v1[c, nb:e]
            x1c = x1[c, nb:e]
            for i in range(nx):
                x1c[i] = x0c[i] + dt * (phi * v1c[i] + (1.0 - phi) * v0c[i])
        # error measure terms (3.10 step 5a); contact candidates are measured after contact
        px, py, pz = x1[0, nb:e], x1[1, nb:e], x1[2, nb:e]
        kx, ky, kz = xx[nb:e], xy[nb:e], xz[nb:e]
        sx, sy, sz = x0[0, nb:e], x0[1, nb:e], x0[2, nb:e]
        skip = skip_err[nb:e]
        en = err_num[nb:e]
        ed = err_den[nb:e]
        for i in range(nx):
            keep = 1.0 if skip[i] == 0 else 0.0
            dx = px[i] - kx[i]
            dy = py[i] - ky[i]
            dz = pz[i] - kz[i]
            en[i] = keep * math.sqrt(dx * dx + dy * dy + dz * dz)
            dx = px[i] - sx[i]
            dy = py[i] - sy[i]
            dz = pz[i] - sz[i]
            ed[i] = keep * math.sqrt(dx * dx + dy * dy + dz * dz)
        tu, td = td, tu


ROWS_PER_BLOCK = 16



@njit(cache=True)
def fused_iterate(phys, prev, sin, sout, work, t1, phi, dt, rowbuf):
    """Yarn tensions at the iterate `prev` and the φ-update of every node from the start state
    sin (x, v, f, committed α) into sout (x, v, f; trial damage into sout.alpha), serially.

    work: the step's Work record (node fields, damage thresholds, flag — nodes left out of the
    error measure —, the error terms and their per-row sums row_sums). rowbuf: (ROWBUF_ROWS,
    nx + 1). Walks the same row blocks as the threaded kernel, one after the other: the same
    arithmetic, and one compiled specialisation of _row_block for both.
    """
    rec = RowRecords(phys.nodes, phys.yarns, phys.material, phys.field)
    ny = phys.nodes.ny
    blocks = (ny + ROWS_PER_BLOCK - 1) // ROWS_PER_BLOCK
    for b in range(blocks):
        j0 = b * ROWS_PER_BLOCK
        j1 = min(ny, j0 + ROWS_PER_BLOCK)
        _row_block(j0, j1, rec, prev, sin, sout, work, t1, phi, dt, rowbuf)
    _row_sums(work.err_num, work.err_den, phys.nodes.rows, work.row_sums)


@njit  # never cached on its own: see fused_iterate_threads' docstring
def fused_iterate_threads(phys, prev, sin, sout, work, t1, phi, dt, rowbuf):
    """fused_iterate over blocks of ROWS_PER_BLOCK rows in parallel threads; rowbuf (blocks,
    ROWBUF_ROWS, nx + 1). Every value is computed by the same arithmetic as in the serial
    kernel, so results do not depend on the number of threads.

    The parallel loop (_iterate_rows_threads) takes the flat records as arguments: Numba's
    parallel loops accept a named tuple only as a function argument, and not a nested one.

    Not cached by itself, only inside its cached callers (the threaded step kernel): a cached
    caller compiled against a parallel kernel loaded from the cache crashed when it was in turn
    loaded from the cache (reproduced: `bench.py` (a) caching it first, then a run compiling the
    threaded step kernel, then any later run; Numba issues #8578 and #10128 describe the same
    mismatch of a parallel callee's native names between processes). Compiled afresh with its
    caller, it is linked into the caller's cached code."""
    _iterate_rows_threads(phys.nodes, phys.yarns, phys.material, phys.field, prev, sin, sout,
                          work, t1, phi, dt, rowbuf)
    _row_sums(work.err_num, work.err_den, phys.nodes.rows, work.row_sums)


@njit(parallel=True)  # never cached on its own, as fused_iterate_threads
def _iterate_rows_threads(nodes, yarns, mat, fld, prev, sin, sout, work, t1, phi, dt, rowbuf):
    """The row blocks of fused_iterate_threads, in parallel."""
    ny = nodes.ny
    blocks = (ny + ROWS_PER_BLOCK - 1) // ROWS_PER_BLOCK
    for b in prange(blocks):
        j0 = b * ROWS_PER_BLOCK
        j1 = min(ny, j0 + ROWS_PER_BLOCK)
        _row_block(j0, j1, RowRecords(nodes, yarns, mat, fld), prev, sin, sout, work, t1, phi,
                   dt, rowbuf[b])


TAN_SERIES_LIMIT = 0.01
"""Below this |t|² = (θ/2)², tan_ratio's series is exact to the last bit."""


@njit(cache=True, inline="always")
def tan_ratio(y2):
    """tan(y)/y from y² < TAN_SERIES_LIMIT (its Taylor series to y¹²; the first term left out,
    929569 y¹⁴/638512875, is below 1.5e-17)."""
    return 1.0 + y2 * (1.0 / 3.0 + y2 * (2.0 / 15.0 + y2 * (17.0 / 315.0 + y2 * (
        62.0 / 2835.0 + y2 * (1382.0 / 155925.0 + y2 * (21844.0 / 6081075.0))))))


@njit(cache=True, inline="always")
def _rotate_row(nb, count, inv_mass, charge, uni, sourced, nf, pos, tau, v, buf):
    """Turn the velocities v (a tuple of three row views of `count` nodes from node nb) by the
    magnetic force alone for a time tau: dv/dt = (q/m) v × B(pos), B constant over tau (the
    field as fields.uniform_field gives it, or the node fields nf of a field with sources).

    Boris's rotation v' = v + v × t, v ← v + v' × 2t/(1 + |t|²) with t = tan(θ/2) B̂·sign(q)
    turns by exactly θ = |q B/m| tau (the standard t = q B tau/(2m) turns by 2 atan(θ/2)): the
    cyclotron frequency is exact, |v| kept to round-off. t = (q B tau/(2m))·tan(y)/y with y =
    θ/2, the ratio from tan_ratio where every node's y² < TAN_SERIES_LIMIT (branch-free, so
    vectorised), else each node by Rodrigues's formula (rodrigues: any angle). Clamped
    nodes (1/m = 0) and uncharged ones are left exactly as they are.

    Inlined (Numba IR), as _row_force, and given arrays and numbers, not records: Numba
    references every array of a record bound to a function's argument on entry and releases
    it on exit (an atomic increment and decrement each). Called per row with the Physics
    record, and then inlined with its sub-records, that was ~60 arrays a row and 21 % of a
    central-difference step (`perf`); now a few.
    """
    im = inv_mass[nb:nb + count]
    q = charge[nb:nb + count]
    px, py, pz = pos
    vx, vy, vz = v
    tx, ty, tz = buf[ROW_ROTATION], buf[ROW_ROTATION + 1], buf[ROW_ROTATION + 2]
    y2 = buf[ROW_PROJECTION]
    for i in range(count):
        _e, b = node_field_of(uni, sourced, nf, nb + i, (px[i], py[i], pz[i]))
        s = 0.5 * tau * q[i] * im[i]
        tx[i] = s * b[0]
        ty[i] = s * b[1]
        tz[i] = s * b[2]
    for i in range(count):
        y2[i] = tx[i] * tx[i] + ty[i] * ty[i] + tz[i] * tz[i]
    big = 0.0
    for i in range(count):
        big = max(big, y2[i])
    if big == 0.0:
        return
    if big < TAN_SERIES_LIMIT:
        for i in range(count):
            g = tan_ratio(y2[i])
            tx[i] *= g
            ty[i] *= g
            tz[i] *= g
        for i in range(count):
            ax, ay, az = tx[i], ty[i], tz[i]
            k = 2.0 / (1.0 + (ax * ax + ay * ay + az * az))
            sx, sy, sz = k * ax, k * ay, k * az
            ux = vx[i] + (vy[i] * az - vz[i] * ay)
            uy = vy[i] + (vz[i] * ax - vx[i] * az)
            uz = vz[i] + (vx[i] * ay - vy[i] * ax)
            vx[i] += uy * sz - uz * sy
            vy[i] += uz * sx - ux * sz
            vz[i] += ux * sy - uy * sx
        return
    for i in range(count):
        if y2[i] == 0.0:
            continue
        _e, b = node_field_of(uni, sourced, nf, nb + i, (px[i], py[i], pz[i]))
        r = rodrigues((vx[i], vy[i], vz[i]), q[i] * im[i], b, tau)
        vx[i] = r[0]
        vy[i] = r[1]
        vz[i] = r[2]


@njit(cache=True, inline="always")
def rodrigues(v, q_over_m, b, h):
    """v after a time h of dv/dt = (q/m) v × B at constant B: the rotation about Ω = −(q/m) B by
    the angle |Ω| h (Rodrigues's formula), exact at any angle; keeps |v|."""
    bb = math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2])
    theta = abs(q_over_m) * bb * h
    if theta == 0.0:
        return v
    s = -1.0 / bb if q_over_m > 0.0 else 1.0 / bb
    kx, ky, kz = s * b[0], s * b[1], s * b[2]
    cs = math.cos(theta)
    sn = math.sin(theta)
    kv = (kx * v[0] + ky * v[1] + kz * v[2]) * (1.0 - cs)
    return (v[0] * cs + (ky * v[2] - kz * v[1]) * sn + kx * kv,
            v[1] * cs + (kz * v[0] - kx * v[2]) * sn + ky * kv,
            v[2] * cs + (kx * v[1] - ky * v[0]) * sn + kz * kv)


@njit(cache=True)
def _row_total(a, count):
    """Σ a[:count] in a fixed order (four interleaved partial sums, as _row_sums)."""
    s0 = s1 = s2 = s3 = 0.0
    i = 0
    while i + 3 < count:
        s0 += a[i]
        s1 += a[i + 1]
        s2 += a[i + 2]
        s3 += a[i + 3]
        i += 4
    while i < count:
        s0 += a[i]
        i += 1
    return (s0 + s1) + (s2 + s3)


@njit(cache=True)
def _drift_block(j0, j1, phys, sin, sout, work, t0, dt, buf):
    """Rows j0 ≤ j < j1 of the first half of a central-difference step (explicit.central_step):
    v⁻ = v + h/(2m) f (f without its magnetic part), v_{n+½} = v⁻ turned by B(x_n, t0) for h/2,
    x_{n+1} = x_n + h v_{n+½} (a clamped node stays), into sout.v and sout.x; each row's field
    and gravity work of the half kick (h/2 f·v̄) into work.row_sums."""
    nodes, fld = phys.nodes, phys.field
    uni, sourced = uniform_field(fld)
    nf = work.node_field
    sums = work.row_sums
    grav = (fld.gravity[0], fld.gravity[1], fld.gravity[2])
    half = 0.5 * dt
    vm = buf[ROW_VEL_EXPLICIT:ROW_VEL_EXPLICIT + 3]
    wfield, wgrav = buf[ROW_INV_DENOM], buf[ROW_DT_OVER_MASS]
    for j in range(j0, j1):
        nb = nodes.rows[j, ROW_NODE]
        nx = nodes.rows[j, ROW_COUNT]
        e = nb + nx
        im = nodes.inv_mass[nb:e]
        m = nodes.mass[nb:e]
        q = nodes.charge[nb:e]
        px, py, pz = sin.x[0, nb:e], sin.x[1, nb:e], sin.x[2, nb:e]
        ux, uy, uz = sin.v[0, nb:e], sin.v[1, nb:e], sin.v[2, nb:e]
        fx, fy, fz = sin.f[0, nb:e], sin.f[1, nb:e], sin.f[2, nb:e]
        ex, ey, ez = sin.e[0, nb:e], sin.e[1, nb:e], sin.e[2, nb:e]
        wx, wy, wz = vm[0], vm[1], vm[2]
        for i in range(nx):
            # the State's force is the whole ψ(t) (as the φ-scheme's): without q v × B
            _e, b = node_field_of(uni, sourced, nf, nb + i, (px[i], py[i], pz[i]))
            fm = magnetic_force(q[i], (ux[i], uy[i], uz[i]), b)
            k = half * im[i]
            wx[i] = ux[i] + k * (fx[i] - fm[0])
            wy[i] = uy[i] + k * (fy[i] - fm[1])
            wz[i] = uz[i] + k * (fz[i] - fm[2])
        for i in range(nx):
            bx = 0.5 * (ux[i] + wx[i])
            by = 0.5 * (uy[i] + wy[i])
            bz = 0.5 * (uz[i] + wz[i])
            wfield[i] = half * q[i] * ((ex[i] * bx + ey[i] * by) + ez[i] * bz)
            wgrav[i] = half * m[i] * ((grav[0] * bx + grav[1] * by) + grav[2] * bz)
        sums[SUM_WORK_FIELD, j] = _row_total(wfield, nx)
        sums[SUM_WORK_GRAVITY, j] = _row_total(wgrav, nx)
        _rotate_row(nb, nx, nodes.inv_mass, nodes.charge, uni, sourced, nf, (px, py, pz), half,
                    (wx, wy, wz), buf)
        for c in range(3):
            x0c = sin.x[c, nb:e]
            x1c = sout.x[c, nb:e]
            v1c = sout.v[c, nb:e]
            wc = vm[c]
            for i in range(nx):
                v1c[i] = wc[i]
                x1c[i] = x0c[i] + (dt if im[i] > 0.0 else 0.0) * wc[i]


@njit(cache=True)
def _kick_block(j0, j1, phys, sin, sout, work, t1, dt, buf):
    """Rows j0 ≤ j < j1 of the second half of a central-difference step: the force at sout.x
    and t1 (_row_force, trial damage from sin.alpha into sout.alpha: the step's one force
    evaluation), consumed at once by the node update v_{n+½} (sout.v, after contact) turned by
    B(x_{n+1}, t1) for h/2, then v_{n+1} = v⁺ + h/(2m) f; sout.f = f + q v_{n+1} × B and sout.e
    = E. Per row into work.row_sums: the half kick's field and gravity work, the projection
    term of the contact candidates (explicit.central_step), Σ|v_{n+1}|² and the largest
    2 Σ k_t/m of its nodes (the Gershgorin bound of ω² of explicit.stable_step)."""
    nodes, yarns, mat, fld = phys.nodes, phys.yarns, phys.material, phys.field
    uni, sourced = uniform_field(fld)
    nf = work.node_field
    arr = RowArrays(nodes.rows, nodes.mass, nodes.charge, yarns.inv_rest2, yarns.stiffness,
                    sin.alpha, sout.alpha, work.damage_thr, nf)
    sums = work.row_sums
    flag, xbuf, v_pre = work.flag, work.xbuf, work.v_pre
    grav = (fld.gravity[0], fld.gravity[1], fld.gravity[2])
    half = 0.5 * dt
    x1, v1 = sout.x, sout.v
    tu, td = _block_start(j0, phys, x1, sin, sout, work, buf, TANGENT)
    f = buf[ROW_FORCE:ROW_FORCE + 3]
    kw = buf[ROW_WARP_TENSION + 3]
    wfield, wgrav, speed2 = buf[ROW_INV_DENOM], buf[ROW_DT_OVER_MASS], buf[ROW_VEL_EXPLICIT]
    for j in range(j0, j1):
        _row_force(j, arr, mat, uni, sourced, grav, x1, buf, tu, td, TANGENT)
        nb = nodes.rows[j, ROW_NODE]
        nx = nodes.rows[j, ROW_COUNT]
        e = nb + nx
        im = nodes.inv_mass[nb:e]
        m = nodes.mass[nb:e]
        q = nodes.charge[nb:e]
        # the Gershgorin bound: 2 Σ k_t/m over the node's four segments
        ku, kd = tu[3], td[3]
        worst = 0.0
        for i in range(nx):
            worst = max(worst, 2.0 * ((kw[i] + kw[i + 1]) + (ku[i] + kd[i])) * im[i])
        sums[SUM_STIFFNESS, j] = worst
        # the work of the force over the placement of the candidates (central_step)
        proj = 0.0
        for i in range(nx):
            n = nb + i
            if flag[n] != 0:
                for c in range(3):
                    proj += f[c, i] * (x1[c, n] - xbuf[c, n] - half * (v1[c, n] - v_pre[c, n]))
        sums[SUM_PROJECTION, j] = proj
        px, py, pz = x1[0, nb:e], x1[1, nb:e], x1[2, nb:e]
        vx, vy, vz = v1[0, nb:e], v1[1, nb:e], v1[2, nb:e]
        _rotate_row(nb, nx, nodes.inv_mass, nodes.charge, uni, sourced, nf, (px, py, pz), half,
                    (vx, vy, vz), buf)
        fx, fy, fz = f[0], f[1], f[2]
        gx, gy, gz = sout.f[0, nb:e], sout.f[1, nb:e], sout.f[2, nb:e]
        ex, ey, ez = sout.e[0, nb:e], sout.e[1, nb:e], sout.e[2, nb:e]
        for i in range(nx):
            ee, b = node_field_of(uni, sourced, nf, nb + i, (px[i], py[i], pz[i]))
            k = half * im[i]
            nvx = vx[i] + k * fx[i]
            nvy = vy[i] + k * fy[i]
            nvz = vz[i] + k * fz[i]
            bx = 0.5 * (vx[i] + nvx)
            by = 0.5 * (vy[i] + nvy)
            bz = 0.5 * (vz[i] + nvz)
            wfield[i] = half * q[i] * ((ee[0] * bx + ee[1] * by) + ee[2] * bz)
            wgrav[i] = half * m[i] * ((grav[0] * bx + grav[1] * by) + grav[2] * bz)
            speed2[i] = (nvx * nvx + nvy * nvy) + nvz * nvz
            vx[i] = nvx
            vy[i] = nvy
            vz[i] = nvz
            fm = magnetic_force(q[i], (nvx, nvy, nvz), b)
            gx[i] = fx[i] + fm[0]
            gy[i] = fy[i] + fm[1]
            gz[i] = fz[i] + fm[2]
            ex[i] = ee[0]
            ey[i] = ee[1]
            ez[i] = ee[2]
        sums[SUM_WORK_FIELD, j] = _row_total(wfield, nx)
        sums[SUM_WORK_GRAVITY, j] = _row_total(wgrav, nx)
        sums[SUM_SPEED, j] = _row_total(speed2, nx)
        tu, td = td, tu


@njit(cache=True)
def drift_rows(phys, sin, sout, work, t0, dt, rowbuf):
    """The first half of a central-difference step for every row (_drift_block), serially;
    rowbuf (ROWBUF_ROWS, nx + 1). Row sums in work.row_sums."""
    rec = RowRecords(phys.nodes, phys.yarns, phys.material, phys.field)
    ny = phys.nodes.ny
    for b in range((ny + ROWS_PER_BLOCK - 1) // ROWS_PER_BLOCK):
        j0 = b * ROWS_PER_BLOCK
        _drift_block(j0, min(ny, j0 + ROWS_PER_BLOCK), rec, sin, sout, work, t0, dt, rowbuf)


@njit(cache=True)
def kick_rows(phys, sin, sout, work, t1, dt, rowbuf):
    """The force evaluation and second half of a central-difference step for every row
    (_kick_block), serially, in the same row blocks as kick_rows_threads; rowbuf (ROWBUF_ROWS,
    nx + 1). Row sums in work.row_sums."""
    rec = RowRecords(phys.nodes, phys.yarns, phys.material, phys.field)
    ny = phys.nodes.ny
    for b in range((ny + ROWS_PER_BLOCK - 1) // ROWS_PER_BLOCK):
        j0 = b * ROWS_PER_BLOCK
        _kick_block(j0, min(ny, j0 + ROWS_PER_BLOCK), rec, sin, sout, work, t1, dt, rowbuf)


@njit  # never cached on its own, as fused_iterate_threads
def drift_rows_threads(phys, sin, sout, work, t0, dt, rowbuf):
    """drift_rows over blocks of ROWS_PER_BLOCK rows in parallel threads (rowbuf (blocks,
    ROWBUF_ROWS, nx + 1)); the same arithmetic as the serial kernel."""
    _drift_threads(phys.nodes, phys.yarns, phys.material, phys.field, sin, sout, work, t0, dt,
                   rowbuf)


@njit(parallel=True)  # never cached on its own, as fused_iterate_threads
def _drift_threads(nodes, yarns, mat, fld, sin, sout, work, t0, dt, rowbuf):
    """The row blocks of drift_rows_threads, in parallel."""
    ny = nodes.ny
    for b in prange((ny + ROWS_PER_BLOCK - 1) // ROWS_PER_BLOCK):
        j0 = b * ROWS_PER_BLOCK
        _drift_block(j0, min(ny, j0 + ROWS_PER_BLOCK), RowRecords(nodes, yarns, mat, fld), sin,
                     sout, work, t0, dt, rowbuf[b])


@njit  # never cached on its own, as fused_iterate_threads
def kick_rows_threads(phys, sin, sout, work, t1, dt, rowbuf):
    """kick_rows over blocks of ROWS_PER_BLOCK rows in parallel threads (rowbuf (blocks,
    ROWBUF_ROWS, nx + 1)); the same arithmetic as the serial kernel."""
    _kick_threads(phys.nodes, phys.yarns, phys.material, phys.field, sin, sout, work, t1, dt,
                  rowbuf)


@njit(parallel=True)  # never cached on its own, as fused_iterate_threads
def _kick_threads(nodes, yarns, mat, fld, sin, sout, work, t1, dt, rowbuf):
    """The row blocks of kick_rows_threads, in parallel."""
    ny = nodes.ny
    for b in prange((ny + ROWS_PER_BLOCK - 1) // ROWS_PER_BLOCK):
        j0 = b * ROWS_PER_BLOCK
        _kick_block(j0, min(ny, j0 + ROWS_PER_BLOCK), RowRecords(nodes, yarns, mat, fld), sin,
                    sout, work, t1, dt, rowbuf[b])
