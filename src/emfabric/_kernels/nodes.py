"""One fixed-point iterate of the fabric: yarn tensions, node forces and the φ-update.

v1 = v0 + Δt/m (φ ψ(t+Δt) + (1−φ) ψ(t)),  x1 = x0 + Δt (φ v1 + (1−φ) v0)  (eqs. 3.2, A12–A13),
with the Lorentz force q(E + v1 × B) implicit in v1 (solved exactly per node) and the yarn force
assembled as one difference per node and direction, (t_R − t_L) + (t_U − t_D), which keeps
mirror-symmetric states exactly symmetric. The material law is emfabric._kernels.materials, the
field emfabric._kernels.fields.field_at (at each node's iterate position and at t + Δt).

The kernels walk the regular weave row by row (the layout of emfabric._kernels.records): the
tensions of a row never leave the cache.
"""

import math

from numba import njit, prange

from emfabric._kernels.fields import magnetic_force, node_field
from emfabric._kernels.materials import damage_above, stress_factor, stretch_sq
from emfabric._kernels.records import RowRecords


@njit(cache=True)
def _row_sums(err_num, err_den, nx, ny, err_rows):
    """Per-row sums of the error terms in a fixed order (four interleaved partial sums).

    No fastmath here: a reassociated reduction may be vectorised differently when compiled
    afresh or loaded from Numba's cache, and a last-bit change of ϖ changes Δt and so the run.
    """
    for j in range(ny):
        a0 = a1 = a2 = a3 = 0.0
        b0 = b1 = b2 = b3 = 0.0
        start = j * nx
        stop = start + nx
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
        err_rows[0, j] = (a0 + a1) + (a2 + a3)
        err_rows[1, j] = (b0 + b1) + (b2 + b3)


# rows of a block's row buffer, shape (ROWBUF_ROWS, nx + 1): the first row of each quantity
ROW_WARP_TENSION = 0
"""Tension vectors of a grid row's warp segments, padded with zeros at both ends (3 rows)."""
ROW_FILL_UP = 3
"""Tension vectors of the fill segments from a row to the next (3 rows)."""
ROW_FILL_DOWN = 6
"""Tension vectors of the fill segments from the row below (3 rows)."""
ROW_SEGMENT = 9
"""Segment vectors d = x_b − x_a of the tensions being computed (3 rows)."""
ROW_STRETCH_SQ = 12
"""Their stretch² U²."""
ROW_STRESS = 13
"""Their trial damage α, then α·stiffness·S/𝔼 (the tension per unit length of d)."""
ROW_FORCE = 14
"""Non-magnetic node force of the row: yarns + electric + gravity (3 rows)."""
ROW_VEL_EXPLICIT = 17
"""v0 + Δt/m (φ ψ + (1−φ) ψ0) without the magnetic force: the right side of the implicit
magnetic solve (3 rows)."""
ROW_ROTATION = 20
"""u = φΔt q B / m, the rotation vector of the implicit magnetic solve (3 rows)."""
ROW_PROJECTION = 23
"""a·u."""
ROW_INV_DENOM = 24
"""1/(1 + |u|²)."""
ROW_DT_OVER_MASS = 25
"""Δt/m (0 for a clamped node)."""
ROWBUF_ROWS = 26


@njit(cache=True)
def _tensions(xa, xb, count, inv_rest2, seg, mat, buf, out, write_alpha):
    """Tension vectors of `count` segments joining a[i] to b[i] into out[:, :count].

    xa, xb: the (x, y, z) row views of the end nodes; seg: the segments' views (committed α,
    trial α written when write_alpha, damage thresholds U², stiffness); inv_rest2: their 1/L0².
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
    if write_alpha:
        for i in range(count):
            alpha_t[i] = al[i]
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
def _block_start(j0, phys, prev, sin, sout, work, buf):
    """Prepare a block's row buffer before its first row j0: zero the padding of the warp row
    and set the fill tensions from the row below (recomputed, writing no damage, so that blocks
    are independent; zero for the first row). Returns (fill_up, fill_down) views."""
    nodes, yarns, mat = phys.nodes, phys.yarns, phys.material
    nx, ny = nodes.nx, nodes.ny
    nw = ny * (nx - 1)
    xx, xy, xz = prev[0], prev[1], prev[2]
    twp = buf[ROW_WARP_TENSION:ROW_WARP_TENSION + 3]
    tu = buf[ROW_FILL_UP:ROW_FILL_UP + 3]
    td = buf[ROW_FILL_DOWN:ROW_FILL_DOWN + 3]
    twp[:, 0] = 0.0
    twp[:, nx] = 0.0
    if j0 > 0:
        a = (j0 - 1) * nx
        s = nw + a
        coef = yarns.stiffness
        _tensions((xx[a:a + nx], xy[a:a + nx], xz[a:a + nx]),
                  (xx[a + nx:a + 2 * nx], xy[a + nx:a + 2 * nx], xz[a + nx:a + 2 * nx]), nx,
                  yarns.inv_rest2[yarns.inv_rest2.shape[0] - 1],
                  (sin.alpha[s:s + nx], sout.alpha[s:s + nx], work.damage_thr[s:s + nx],
                   coef[s:s + nx]), mat, buf, td, False)
    else:
        td[:] = 0.0
    return tu, td


@njit(cache=True)
def _row_force(j, phys, prev, sin, sout, work, t1, buf, tu, td):
    """The non-magnetic force of grid row j at the positions `prev` and time t1 into the row
    buffer's ROW_FORCE rows: yarn tensions (the warp segments of row j and the fill segments to
    row j + 1, into tu; td holds those from row j − 1), one difference per node and direction,
    plus the electric part of eq. 2.7 and gravity. Trial damage into sout.alpha.

    The one force evaluation of both schemes: the φ-update (_row_block) and central
    differences (_force_block) call it row by row."""
    nodes, yarns, mat, fld = phys.nodes, phys.yarns, phys.material, phys.field
    node_fields = work.node_field
    alpha_c, alpha_t, damage_thr = sin.alpha, sout.alpha, work.damage_thr
    nx, ny = nodes.nx, nodes.ny
    mass, charge = nodes.mass, nodes.charge
    coef = yarns.stiffness
    grav = fld.gravity
    nw = ny * (nx - 1)
    # rest lengths are uniform per yarn family on the regular grid
    inv_rest2_warp = yarns.inv_rest2[0]
    inv_rest2_fill = yarns.inv_rest2[yarns.inv_rest2.shape[0] - 1]
    xx, xy, xz = prev[0], prev[1], prev[2]
    # padded warp row: twp[:, i + 1] is the tension of segment (i, i + 1), zeros at both ends
    twp = buf[ROW_WARP_TENSION:ROW_WARP_TENSION + 3]
    f = buf[ROW_FORCE:ROW_FORCE + 3]
    nb = j * nx
    sb = j * (nx - 1)
    e = nb + nx
    _tensions((xx[nb:e - 1], xy[nb:e - 1], xz[nb:e - 1]), (xx[nb + 1:e], xy[nb + 1:e],
              xz[nb + 1:e]), nx - 1, inv_rest2_warp,
              (alpha_c[sb:sb + nx - 1], alpha_t[sb:sb + nx - 1],
               damage_thr[sb:sb + nx - 1], coef[sb:sb + nx - 1]), mat, buf, twp[:, 1:],
              True)
    if j < ny - 1:
        _tensions((xx[nb:e], xy[nb:e], xz[nb:e]), (xx[e:e + nx], xy[e:e + nx],
                  xz[e:e + nx]), nx, inv_rest2_fill,
                  (alpha_c[nw + nb:nw + e], alpha_t[nw + nb:nw + e],
                   damage_thr[nw + nb:nw + e], coef[nw + nb:nw + e]), mat, buf, tu, True)
    else:
        tu[:, :nx] = 0.0
    m = mass[nb:e]
    q = charge[nb:e]
    # the field at t1 where the node is now (the iterate). The uniform and half-space
    # fields: field_at in each loop that needs it (a compare and a select, cheaper than a
    # row of stores and loads: the stored variant made an evaluation ~7 % slower); a field
    # with sources: the value fields.fill_node_fields stored for this attempt (at the
    # predicted position). fields.node_field, chosen at compile time by the field's type
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
            fe, _fb = node_field(fld, node_fields, nb + i, (px[i], py[i], pz[i]), t1)
            fc[i] = ((tw[i + 1] - tw[i]) + (tuc[i] - tdc[i])) + (m[i] * g + q[i] * fe[c])


@njit(cache=True)
def _row_block(j0, j1, phys, prev, sin, sout, work, t1, phi, dt, buf):
    """Rows j0 ≤ j < j1 of the fused φ iterate: the force of each row (_row_force), consumed at
    once by the φ-update of its nodes (eqs. 3.2, A12–A13) and the error terms of eq. 3.10."""
    nodes, fld = phys.nodes, phys.field
    node_fields = work.node_field
    x0, v0, f0 = sin.x, sin.v, sin.f
    x1, v1, f1 = sout.x, sout.v, sout.f
    skip_err = work.flag
    err_num, err_den = work.err_num, work.err_den
    nx = nodes.nx
    inv_mass, charge = nodes.inv_mass, nodes.charge
    xx, xy, xz = prev[0], prev[1], prev[2]
    tu, td = _block_start(j0, phys, prev, sin, sout, work, buf)
    f = buf[ROW_FORCE:ROW_FORCE + 3]
    acc = buf[ROW_VEL_EXPLICIT:ROW_VEL_EXPLICIT + 3]
    uu = buf[ROW_ROTATION:ROW_ROTATION + 3]
    a_dot_u = buf[ROW_PROJECTION]
    inv = buf[ROW_INV_DENOM]
    dt_over_m = buf[ROW_DT_OVER_MASS]
    for j in range(j0, j1):
        _row_force(j, phys, prev, sin, sout, work, t1, buf, tu, td)
        nb = j * nx
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
            _fe, fb = node_field(fld, node_fields, nb + i, (px[i], py[i], pz[i]), t1)
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
            _fe, fb = node_field(fld, node_fields, nb + i, (px[i], py[i], pz[i]), t1)
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


@njit(cache=True)
def _force_block(j0, j1, phys, x, sin, sout, work, t, buf):
    """Rows j0 ≤ j < j1 of node_forces: each row's force (_row_force) into sout.f."""
    nx = phys.nodes.nx
    f1 = sout.f
    tu, td = _block_start(j0, phys, x, sin, sout, work, buf)
    f = buf[ROW_FORCE:ROW_FORCE + 3]
    for j in range(j0, j1):
        _row_force(j, phys, x, sin, sout, work, t, buf, tu, td)
        nb = j * nx
        for c in range(3):
            fc = f[c]
            oc = f1[c, nb:nb + nx]
            for i in range(nx):
                oc[i] = fc[i]
        tu, td = td, tu


ROWS_PER_BLOCK = 16



@njit(cache=True)
def fused_iterate(phys, prev, sin, sout, work, t1, phi, dt, rowbuf):
    """Yarn tensions at the iterate `prev` and the φ-update of every node from the start state
    sin (x, v, f, committed α) into sout (x, v, f; trial damage into sout.alpha), serially.

    work: the step's Work record (node fields, damage thresholds, flag — nodes left out of the
    error measure —, the error terms and their per-row sums err_rows). rowbuf: (ROWBUF_ROWS,
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
    _row_sums(work.err_num, work.err_den, phys.nodes.nx, ny, work.err_rows)


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
    _row_sums(work.err_num, work.err_den, phys.nodes.nx, phys.nodes.ny, work.err_rows)


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


@njit(cache=True)
def node_forces(phys, x, sin, sout, work, t, rowbuf):
    """The non-magnetic force on every node at the positions x and time t into sout.f (yarn
    tensions with trial damage from the committed sin.alpha into sout.alpha, electric force,
    gravity), serially: the force evaluation of central differences. rowbuf (ROWBUF_ROWS,
    nx + 1); the field of sources from work.node_field (fields.fill_node_fields at x)."""
    rec = RowRecords(phys.nodes, phys.yarns, phys.material, phys.field)
    ny = phys.nodes.ny
    blocks = (ny + ROWS_PER_BLOCK - 1) // ROWS_PER_BLOCK
    for b in range(blocks):
        j0 = b * ROWS_PER_BLOCK
        _force_block(j0, min(ny, j0 + ROWS_PER_BLOCK), rec, x, sin, sout, work, t, rowbuf)


@njit  # never cached on its own, as fused_iterate_threads
def node_forces_threads(phys, x, sin, sout, work, t, rowbuf):
    """node_forces over blocks of ROWS_PER_BLOCK rows in parallel threads (rowbuf (blocks,
    ROWBUF_ROWS, nx + 1)); the same arithmetic as the serial kernel."""
    _force_rows_threads(phys.nodes, phys.yarns, phys.material, phys.field, x, sin, sout, work,
                        t, rowbuf)


@njit(parallel=True)  # never cached on its own, as fused_iterate_threads
def _force_rows_threads(nodes, yarns, mat, fld, x, sin, sout, work, t, rowbuf):
    """The row blocks of node_forces_threads, in parallel."""
    ny = nodes.ny
    blocks = (ny + ROWS_PER_BLOCK - 1) // ROWS_PER_BLOCK
    for b in prange(blocks):
        j0 = b * ROWS_PER_BLOCK
        _force_block(j0, min(ny, j0 + ROWS_PER_BLOCK), RowRecords(nodes, yarns, mat, fld), x,
                     sin, sout, work, t, rowbuf[b])
