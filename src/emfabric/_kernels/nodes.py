"""Node update of one fixed-point iteration: yarn + Lorentz (+ gravity) forces and the φ-scheme."""

import math

from numba import njit

REGION_HALF_SPACE = 1


@njit(cache=True, inline="always")
def in_field(z, region, z0):
    """Whether a point at height z feels the field (uniform, or the half-space z < z0)."""
    return region != REGION_HALF_SPACE or z < z0


@njit(cache=True)
def node_update(xk, x0, v0, f0, t_seg, nx, ny, mass, inv_mass, charge, phi, dt, efield, bfield,
                region, z0, grav, skip_err, x1, v1, f1, err_rows):
    """One iterate of eqs. 3.2/A12-A13 for every node, forces evaluated at the iterate xk.

    v1 = v0 + Δt/m (φ ψ(t+Δt) + (1−φ) ψ(t)),  x1 = x0 + Δt (φ v1 + (1−φ) v0), with the Lorentz
    force q(E + v1 × B) implicit in v1 (solved exactly per node). Writes x1, v1, f1 (ψ(t+Δt)
    without contact) and per-row sums of |x1 − xk| and |x1 − x0| (error measure 3.10-5a) for
    nodes with skip_err == 0.
    """
    nw = ny * (nx - 1)
    ex, ey, ez = efield[0], efield[1], efield[2]
    bx, by, bz = bfield[0], bfield[1], bfield[2]
    tx, ty, tz = t_seg[0], t_seg[1], t_seg[2]
    for j in range(ny):
        num = 0.0
        den = 0.0
        for i in range(nx):
            n = j * nx + i
            im = inv_mass[n]
            if im == 0.0:
                # fixed node: never moves
                for c in range(3):
                    x1[c, n] = x0[c, n]
                    v1[c, n] = v0[c, n]
                    f1[c, n] = 0.0
                continue
            # yarn forces: one difference per node and direction (mirror-exact assembly)
            sr = j * (nx - 1) + i
            su = nw + n
            fx = tx[sr] if i < nx - 1 else 0.0
            fy = ty[sr] if i < nx - 1 else 0.0
            fz = tz[sr] if i < nx - 1 else 0.0
            if i > 0:
                fx = fx - tx[sr - 1]
                fy = fy - ty[sr - 1]
                fz = fz - tz[sr - 1]
            gx = tx[su] if j < ny - 1 else 0.0
            gy = ty[su] if j < ny - 1 else 0.0
            gz = tz[su] if j < ny - 1 else 0.0
            if j > 0:
                gx = gx - tx[su - nx]
                gy = gy - ty[su - nx]
                gz = gz - tz[su - nx]
            m = mass[n]
            q = charge[n] if in_field(xk[2, n], region, z0) else 0.0
            # electric part of eq. 2.7 and gravity
            fx = fx + gx + (m * grav[0] + q * ex)
            fy = fy + gy + (m * grav[1] + q * ey)
            fz = fz + gz + (m * grav[2] + q * ez)
            h = dt * im
            ax = v0[0, n] + h * (phi * fx + (1.0 - phi) * f0[0, n])
            ay = v0[1, n] + h * (phi * fy + (1.0 - phi) * f0[1, n])
            az = v0[2, n] + h * (phi * fz + (1.0 - phi) * f0[2, n])
            # magnetic part implicit in v1: v1 − v1 × u = a with u = φΔt q B / m
            beta = phi * h * q
            ux = beta * bx
            uy = beta * by
            uz = beta * bz
            au = ax * ux + ay * uy + az * uz
            inv = 1.0 / (1.0 + ux * ux + uy * uy + uz * uz)
            vx = (ax + (ay * uz - az * uy) + au * ux) * inv
            vy = (ay + (az * ux - ax * uz) + au * uy) * inv
            vz = (az + (ax * uy - ay * ux) + au * uz) * inv
            v1[0, n] = vx
            v1[1, n] = vy
            v1[2, n] = vz
            f1[0, n] = fx + q * (vy * bz - vz * by)
            f1[1, n] = fy + q * (vz * bx - vx * bz)
            f1[2, n] = fz + q * (vx * by - vy * bx)
            px = x0[0, n] + dt * (phi * vx + (1.0 - phi) * v0[0, n])
            py = x0[1, n] + dt * (phi * vy + (1.0 - phi) * v0[1, n])
            pz = x0[2, n] + dt * (phi * vz + (1.0 - phi) * v0[2, n])
            x1[0, n] = px
            x1[1, n] = py
            x1[2, n] = pz
            if skip_err[n] == 0:
                dx = px - xk[0, n]
                dy = py - xk[1, n]
                dz = pz - xk[2, n]
                num += math.sqrt(dx * dx + dy * dy + dz * dz)
                dx = px - x0[0, n]
                dy = py - x0[1, n]
                dz = pz - x0[2, n]
                den += math.sqrt(dx * dx + dy * dy + dz * dz)
        err_rows[0, j] = num
        err_rows[1, j] = den
