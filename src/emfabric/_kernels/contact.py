"""Node–body contact with stick/slip friction as an impulse exchange (section 4, eqs. 4.5–4.11).

A node predicted inside the body is moved to the closest surface point (4.5, 5.1; the shape's
``closest_surface_point``); this projection carries no momentum. ``contact_impulse`` is the
contact law: the node is first made to stick to the body's surface point velocity v_cm + ω × r
(4.6, 4.9); the velocity jump times the node mass is the contact impulse J. Its normal part
never pulls (a separating node is let go); if the tangential part exceeds μ_s times the normal
part (4.8) the node slides with a tangential impulse μ_d·|J_n| along the relative sliding
velocity (4.10–4.11). The body receives −J at the contact point.
"""

import math

from numba import njit

from emfabric._kernels.records import BODY_R0, BODY_V, BODY_W, BODY_X
from emfabric._kernels.shapes import closest_surface_point
from emfabric._kernels.vec3 import cross


@njit(cache=True, inline="always")
def contact_impulse(m, v_node, v_surface, n, law):
    """Impulse J [N s] on a node of mass m at velocity v_node touching a surface point moving at
    v_surface, with outward normal n, under the Contact record `law` (stick, else slide)."""
    jx = m * (v_surface[0] - v_node[0])
    jy = m * (v_surface[1] - v_node[1])
    jz = m * (v_surface[2] - v_node[2])
    jn = jx * n[0] + jy * n[1] + jz * n[2]
    if jn > 0.0:
        tx = jx - jn * n[0]
        ty = jy - jn * n[1]
        tz = jz - jn * n[2]
        jt = math.sqrt(tx * tx + ty * ty + tz * tz)
        # Coulomb check, eq. 4.8; slide with μ_d along the sliding velocity, eq. 4.11
        if jt > law.static_friction * jn:
            scale = law.dynamic_friction * jn / jt
            return (jn * n[0] + scale * tx, jn * n[1] + scale * ty, jn * n[2] + scale * tz)
        return (jx, jy, jz)
    # separating: the normal impulse never pulls, and without it no friction
    return (0.0, 0.0, 0.0)


@njit(cache=True)
def find_candidates(x, inv_mass, centre, reach, cand, flag):
    """Free nodes within `reach` of the body centre; returns their count."""
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
def node_contact(nodes, body, law, b_state, ncand, x0, xk, x1, v1, work):
    """Resolve contact of the candidate nodes against the body in the state b_state.

    Writes corrected x1, v1; records per contact the node, the impulse J on the node [N s], the
    arm r = x_cp − centre [m] and the projection displacement [m]; adds the candidates'
    error-measure terms to work.err_rows. Returns the number of contacts.
    """
    nx = nodes.nx
    mass = nodes.mass
    cand = work.cand
    err_rows = work.err_rows
    c_node, c_imp, c_arm, c_proj = work.c_node, work.c_imp, work.c_arm, work.c_proj
    centre = b_state[BODY_X]
    vel = b_state[BODY_V]
    omega = (b_state[BODY_W, 0], b_state[BODY_W, 1], b_state[BODY_W, 2])
    rot = b_state[BODY_R0:BODY_R0 + 3]
    nc = 0
    for idx in range(ncand):
        n = cand[idx]
        d = (x1[0, n] - centre[0], x1[1, n] - centre[1], x1[2, n] - centre[2])
        inside, r, nh = closest_surface_point(body, rot, d)
        if inside:
            # stick: the surface point's velocity, eqs. 4.6, 4.9
            wr = cross(omega, r)
            vs = (vel[0] + wr[0], vel[1] + wr[1], vel[2] + wr[2])
            m = mass[n]
            j = contact_impulse(m, (v1[0, n], v1[1, n], v1[2, n]), vs, nh, law)
            c_node[nc] = n
            px = centre[0] + r[0]
            py = centre[1] + r[1]
            pz = centre[2] + r[2]
            for c in range(3):
                c_imp[c, nc] = j[c]
                c_arm[c, nc] = r[c]
            c_proj[0, nc] = px - x1[0, n]
            c_proj[1, nc] = py - x1[1, n]
            c_proj[2, nc] = pz - x1[2, n]
            x1[0, n] = px
            x1[1, n] = py
            x1[2, n] = pz
            im = 1.0 / m
            for c in range(3):
                v1[c, n] += j[c] * im
            nc += 1
        row = n // nx
        ex = x1[0, n] - xk[0, n]
        ey = x1[1, n] - xk[1, n]
        ez = x1[2, n] - xk[2, n]
        err_rows[0, row] += math.sqrt(ex * ex + ey * ey + ez * ez)
        ex = x1[0, n] - x0[0, n]
        ey = x1[1, n] - x0[1, n]
        ez = x1[2, n] - x0[2, n]
        err_rows[1, row] += math.sqrt(ex * ex + ey * ey + ez * ez)
    return nc
