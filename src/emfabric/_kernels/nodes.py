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
from emfabric._kernels.materials import damage_above, fung_stress, ksv_stress, stretch_sq
from emfabric._kernels.records import MATERIAL_FUNG


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


# rows of a block's row buffer, shape (ROWBUF_ROWS, nx + 1)
_TW, _TU, _TD, _D, _U2, _AL, _F, _A, _UU, _AU, _INV, _H = (
    0, 3, 6, 9, 12, 13, 14, 17, 20, 23, 24, 25)
ROWBUF_ROWS = 26


@njit(cache=True)
def _tensions(xa_x, xa_y, xa_z, xb_x, xb_y, xb_z, count, il2, alpha_c, alpha_t, thr2, coef, mat,
              buf, out, write_alpha):
    """Tension vectors of `count` segments joining a[i] to b[i] (row views) into out[:, :count].

    Split into short loops over few arrays so that the compiler vectorises them.
    """
    dx, dy, dz = buf[_D], buf[_D + 1], buf[_D + 2]
    u2 = buf[_U2]
    al = buf[_AL]
    for i in range(count):
        dx[i] = xb_x[i] - xa_x[i]
        dy[i] = xb_y[i] - xa_y[i]
        dz[i] = xb_z[i] - xa_z[i]
    for i in range(count):
        u2[i] = stretch_sq(dx[i], dy[i], dz[i], il2)
    for i in range(count):
        al[i] = damage_above(alpha_c[i], u2[i], thr2[i], mat)
    if write_alpha:
        for i in range(count):
            alpha_t[i] = al[i]
    tx, ty, tz = out[0], out[1], out[2]
    # one loop per law (stress_factor's two branches), so that each vectorises
    if mat.kind == MATERIAL_FUNG:
        fung_h = mat.fung_h
        for i in range(count):
            al[i] = al[i] * coef[i] * fung_stress(u2[i], fung_h)
    else:
        for i in range(count):
            al[i] = al[i] * coef[i] * ksv_stress(u2[i])
    for i in range(count):
        tx[i] = al[i] * dx[i]
        ty[i] = al[i] * dy[i]
        tz[i] = al[i] * dz[i]


@njit(cache=True)
def _row_block(j0, j1, nodes, yarns, mat, fld, nf, prev, x0, v0, f0, alpha_c, alpha_t, thr2, t1,
               phi, dt, skip_err, x1, v1, f1, err_num, err_den, buf):
    """Rows j0 ≤ j < j1 of the fused iterate. The tensions of row j (warp) and between rows j and
    j + 1 (fill) live in the block's row buffer and are consumed at once; a block recomputes the
    fill tensions below its first row (writing no damage), so blocks are independent."""
    nx, ny = nodes.nx, nodes.ny
    mass, inv_mass, charge = nodes.mass, nodes.inv_mass, nodes.charge
    coef = yarns.stiffness
    grav = fld.gravity
    nw = ny * (nx - 1)
    # rest lengths are uniform per yarn family on the regular grid
    il_w = yarns.inv_rest2[0]
    il_f = yarns.inv_rest2[yarns.inv_rest2.shape[0] - 1]
    xx, xy, xz = prev[0], prev[1], prev[2]
    # padded warp row: twp[:, i + 1] is the tension of segment (i, i + 1), zeros at both ends
    twp = buf[_TW:_TW + 3]
    tu = buf[_TU:_TU + 3]
    td = buf[_TD:_TD + 3]
    twp[:, 0] = 0.0
    twp[:, nx] = 0.0
    if j0 > 0:
        a = (j0 - 1) * nx
        _tensions(xx[a:a + nx], xy[a:a + nx], xz[a:a + nx], xx[a + nx:a + 2 * nx],
                  xy[a + nx:a + 2 * nx], xz[a + nx:a + 2 * nx], nx, il_f,
                  alpha_c[nw + a:nw + a + nx], alpha_t[nw + a:nw + a + nx],
                  thr2[nw + a:nw + a + nx], coef[nw + a:nw + a + nx], mat, buf, td, False)
    else:
        td[:] = 0.0
    f = buf[_F:_F + 3]
    acc = buf[_A:_A + 3]
    uu = buf[_UU:_UU + 3]
    au = buf[_AU]
    inv = buf[_INV]
    hh = buf[_H]
    for j in range(j0, j1):
        nb = j * nx
        sb = j * (nx - 1)
        e = nb + nx
        _tensions(xx[nb:e - 1], xy[nb:e - 1], xz[nb:e - 1], xx[nb + 1:e], xy[nb + 1:e],
                  xz[nb + 1:e], nx - 1, il_w, alpha_c[sb:sb + nx - 1],
                  alpha_t[sb:sb + nx - 1], thr2[sb:sb + nx - 1], coef[sb:sb + nx - 1], mat, buf,
                  twp[:, 1:], True)
        if j < ny - 1:
            _tensions(xx[nb:e], xy[nb:e], xz[nb:e], xx[e:e + nx], xy[e:e + nx], xz[e:e + nx],
                      nx, il_f, alpha_c[nw + nb:nw + e], alpha_t[nw + nb:nw + e],
                      thr2[nw + nb:nw + e], coef[nw + nb:nw + e], mat, buf, tu, True)
        else:
            tu[:, :nx] = 0.0
        m = mass[nb:e]
        im = inv_mass[nb:e]
        q = charge[nb:e]
        # the field at t + Δt where the node is now (the iterate). The uniform and half-space
        # fields: field_at in each loop that needs it (a compare and a select, cheaper than a
        # row of stores and loads: the stored variant made an evaluation ~7 % slower); a field
        # with sources: the value fields.fill_node_fields stored for this attempt (at the
        # predicted position). fields.node_field, chosen at compile time by the field's type
        px, py, pz = xx[nb:e], xy[nb:e], xz[nb:e]
        for i in range(nx):
            hh[i] = dt * im[i]
        for c in range(3):
            fc = f[c]
            tw = twp[c]
            tuc = tu[c]
            tdc = td[c]
            g = grav[c]
            # yarn force, one difference per node and direction (mirror-exact assembly),
            # then the electric part of eq. 2.7 and gravity
            for i in range(nx):
                fe, _fb = node_field(fld, nf, nb + i, (px[i], py[i], pz[i]), t1)
                fc[i] = ((tw[i + 1] - tw[i]) + (tuc[i] - tdc[i])) + (m[i] * g + q[i] * fe[c])
            ac = acc[c]
            v0c = v0[c, nb:e]
            f0c = f0[c, nb:e]
            for i in range(nx):
                ac[i] = v0c[i] + hh[i] * (phi * fc[i] + (1.0 - phi) * f0c[i])
        # magnetic part implicit in v1: v1 − v1 × u = a with u = φΔt q B / m (solved exactly)
        ux, uy, uz = uu[0], uu[1], uu[2]
        ax, ay, az = acc[0], acc[1], acc[2]
        for i in range(nx):
            _fe, fb = node_field(fld, nf, nb + i, (px[i], py[i], pz[i]), t1)
            beta = phi * hh[i] * q[i]
            ux[i] = beta * fb[0]
            uy[i] = beta * fb[1]
            uz[i] = beta * fb[2]
        for i in range(nx):
            au[i] = ax[i] * ux[i] + ay[i] * uy[i] + az[i] * uz[i]
            inv[i] = 1.0 / (1.0 + ux[i] * ux[i] + uy[i] * uy[i] + uz[i] * uz[i])
        vx, vy, vz = v1[0, nb:e], v1[1, nb:e], v1[2, nb:e]
        for i in range(nx):
            vx[i] = (ax[i] + (ay[i] * uz[i] - az[i] * uy[i]) + au[i] * ux[i]) * inv[i]
            vy[i] = (ay[i] + (az[i] * ux[i] - ax[i] * uz[i]) + au[i] * uy[i]) * inv[i]
            vz[i] = (az[i] + (ax[i] * uy[i] - ay[i] * ux[i]) + au[i] * uz[i]) * inv[i]
        fx, fy, fz = f[0], f[1], f[2]
        gx, gy, gz = f1[0, nb:e], f1[1, nb:e], f1[2, nb:e]
        for i in range(nx):
            _fe, fb = node_field(fld, nf, nb + i, (px[i], py[i], pz[i]), t1)
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
def fused_iterate(nodes, yarns, mat, fld, nf, prev, x0, v0, f0, alpha_c, alpha_t, thr2, x1, v1,
                  f1, skip_err, err_rows, err_num, err_den, t1, phi, dt, rowbuf):
    """Yarn tensions at the iterate `prev` and the φ-update of every node from the start state
    (x0, v0, f0, alpha_c) into (x1, v1, f1), trial damage into alpha_t (serial).

    rowbuf: (ROWBUF_ROWS, nx + 1). Walks the same row blocks as the threaded kernel, one after
    the other: the same arithmetic, and one compiled specialisation of _row_block for both.
    """
    ny = nodes.ny
    blocks = (ny + ROWS_PER_BLOCK - 1) // ROWS_PER_BLOCK
    for b in range(blocks):
        j0 = b * ROWS_PER_BLOCK
        j1 = min(ny, j0 + ROWS_PER_BLOCK)
        _row_block(j0, j1, nodes, yarns, mat, fld, nf, prev, x0, v0, f0, alpha_c, alpha_t, thr2,
                   t1, phi, dt, skip_err, x1, v1, f1, err_num, err_den, rowbuf)
    _row_sums(err_num, err_den, nodes.nx, ny, err_rows)


@njit(parallel=True)  # never cached on its own: see the docstring
def fused_iterate_threads(nodes, yarns, mat, fld, nf, prev, x0, v0, f0, alpha_c, alpha_t, thr2,
                          x1, v1, f1, skip_err, err_rows, err_num, err_den, t1, phi, dt, rowbuf):
    """fused_iterate over blocks of ROWS_PER_BLOCK rows in parallel threads; rowbuf (blocks,
    ROWBUF_ROWS, nx + 1). Every value is computed by the same arithmetic as in the serial
    kernel, so results do not depend on the number of threads.

    The records are arguments of this function, not taken apart here: Numba's parallel loops
    accept a named tuple only as a function argument.

    Not cached by itself, only inside its cached callers (the threaded step kernel): a cached
    caller compiled against this kernel loaded from the cache crashed when it was in turn
    loaded from the cache (reproduced: `bench.py` (a) caching it first, then a run compiling the
    threaded step kernel, then any later run; Numba issues #8578 and #10128 describe the same
    mismatch of a parallel callee's native names between processes). Compiled afresh with its
    caller, it is linked into the caller's cached code."""
    ny = nodes.ny
    blocks = (ny + ROWS_PER_BLOCK - 1) // ROWS_PER_BLOCK
    for b in prange(blocks):
        j0 = b * ROWS_PER_BLOCK
        j1 = min(ny, j0 + ROWS_PER_BLOCK)
        _row_block(j0, j1, nodes, yarns, mat, fld, nf, prev, x0, v0, f0, alpha_c, alpha_t, thr2,
                   t1, phi, dt, skip_err, x1, v1, f1, err_num, err_den, rowbuf[b])
    _row_sums(err_num, err_den, nodes.nx, ny, err_rows)
