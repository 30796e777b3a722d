"""Node–sphere contact with stick/slip friction as an impulse exchange (section 4, eqs. 4.5–4.11).

A node predicted inside the sphere is moved to the closest surface point (4.5, 5.1); this
projection carries no momentum. The node is first made to stick to the body's surface point
velocity v_cm + ω × r (4.6, 4.9); the velocity jump times the node mass is the contact impulse J.
Its normal part never pulls (a separating node is let go); if the tangential part exceeds
μ_s times the normal part (4.8) the node slides with a tangential impulse μ_d·|J_n| along the
relative sliding velocity (4.10–4.11). The body receives −J at the contact point.
"""

import math

from numba import njit


@njit(cache=True)
def find_candidates(x, inv_mass, centre, reach, cand, flag):
    """Nodes within `reach` of the body centre (once per step); returns their count."""
    count = 0
    r2 = reach * reach
    for n in range(x.shape[1]):
        dx = x[0, n] - centre[0]
        dy = x[1, n] - centre[1]
        dz = x[2, n] - centre[2]
        if inv_mass[n] > 0.0 and dx * dx + dy * dy + dz * dz < r2:
            cand[count] = n
            flag[n] = 1
            count += 1
        else:
            flag[n] = 0
    return count


@njit(cache=True)
def sphere_contact(cand, ncand, nx, x0, xk, x1, v1, mass, centre, vel, omega, radius, mu_s,
                   mu_d, err_rows, c_node, c_imp, c_arm, c_proj):
    """Resolve contact of the candidate nodes against a sphere at (centre, vel, omega).

    Writes corrected x1, v1; records per contact the node, the impulse J on the node [N s],
    the arm r = x_cp − centre [m] and the projection displacement [m]; adds the candidates'
    error-measure terms to err_rows. Returns the number of contacts.
    """
    nc = 0
    for idx in range(ncand):
        n = cand[idx]
        dx = x1[0, n] - centre[0]
        dy = x1[1, n] - centre[1]
        dz = x1[2, n] - centre[2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < radius * radius and d2 > 0.0:
            d = math.sqrt(d2)
            nxh = dx / d
            nyh = dy / d
            nzh = dz / d
            # closest point on the surface, eq. 5.1
            rx = radius * nxh
            ry = radius * nyh
            rz = radius * nzh
            # stick: the surface point's velocity, eqs. 4.6, 4.9
            sx = vel[0] + (omega[1] * rz - omega[2] * ry)
            sy = vel[1] + (omega[2] * rx - omega[0] * rz)
            sz = vel[2] + (omega[0] * ry - omega[1] * rx)
            m = mass[n]
            jx = m * (sx - v1[0, n])
            jy = m * (sy - v1[1, n])
            jz = m * (sz - v1[2, n])
            jn = jx * nxh + jy * nyh + jz * nzh
            if jn > 0.0:
                tx = jx - jn * nxh
                ty = jy - jn * nyh
                tz = jz - jn * nzh
                jt = math.sqrt(tx * tx + ty * ty + tz * tz)
                # Coulomb check, eq. 4.8; slide with μ_d along the sliding velocity, eq. 4.11
                if jt > mu_s * jn:
                    scale = mu_d * jn / jt
                    jx = jn * nxh + scale * tx
                    jy = jn * nyh + scale * ty
                    jz = jn * nzh + scale * tz
            else:
                # separating: the normal impulse never pulls, and without it no friction
                jx = 0.0
                jy = 0.0
                jz = 0.0
            c_node[nc] = n
            c_imp[0, nc] = jx
            c_imp[1, nc] = jy
            c_imp[2, nc] = jz
            c_arm[0, nc] = rx
            c_arm[1, nc] = ry
            c_arm[2, nc] = rz
            px = centre[0] + rx
            py = centre[1] + ry
            pz = centre[2] + rz
            c_proj[0, nc] = px - x1[0, n]
            c_proj[1, nc] = py - x1[1, n]
            c_proj[2, nc] = pz - x1[2, n]
            x1[0, n] = px
            x1[1, n] = py
            x1[2, n] = pz
            im = 1.0 / m
            v1[0, n] += jx * im
            v1[1, n] += jy * im
            v1[2, n] += jz * im
            nc += 1
        j = n // nx
        ex = x1[0, n] - xk[0, n]
        ey = x1[1, n] - xk[1, n]
        ez = x1[2, n] - xk[2, n]
        err_rows[0, j] += math.sqrt(ex * ex + ey * ey + ez * ez)
        ex = x1[0, n] - x0[0, n]
        ey = x1[1, n] - x0[1, n]
        ez = x1[2, n] - x0[2, n]
        err_rows[1, j] += math.sqrt(ex * ex + ey * ey + ez * ez)
    return nc
