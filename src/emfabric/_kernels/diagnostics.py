"""Fabric-wide diagnostics of one state in a single pass over nodes and segments."""

import math

import numpy as np
from numba import int64, njit

from emfabric._kernels.materials import strain_energy_density, stretch_sq
from emfabric._kernels.records import (
    BODY_R0,
    BODY_V,
    BODY_W,
    BODY_X,
    COL_BALANCE,
    COL_BODY_ANGULAR,
    COL_BODY_MOMENTUM,
    COL_BROKEN,
    COL_CONTACT_FORCE,
    COL_CONTACTS,
    COL_DEFLECTION,
    COL_DT,
    COL_ENERGY_TERMS,
    COL_ERROR,
    COL_EVALUATIONS,
    COL_FABRIC_ANGULAR,
    COL_FABRIC_MOMENTUM,
    COL_ITERATIONS,
    COL_KE_BODY,
    COL_KE_BODY_ROTATION,
    COL_KE_FABRIC,
    COL_MIN_DAMAGE,
    COL_NOSE,
    COL_OMEGA,
    COL_POSITION,
    COL_REJECTED,
    COL_STRAIN,
    COL_STRETCH,
    COL_TILT,
    COL_TIME,
    COL_VELOCITY,
    COL_YAW,
    DIAG_AHEAD_MAX,
    DIAG_AHEAD_MIN,
    DIAG_APPROACH_MAX,
    DIAG_BROKEN,
    DIAG_COUNT,
    DIAG_DEFLECTION,
    DIAG_KE,
    DIAG_LX,
    DIAG_LY,
    DIAG_LZ,
    DIAG_MIN_ALPHA,
    DIAG_PX,
    DIAG_PY,
    DIAG_PZ,
    DIAG_RECEDE_MAX,
    DIAG_STRAIN,
    DIAG_STRETCH,
    ENERGY_CONTACT,
    ENERGY_DAMAGE,
    ENERGY_FRICTION,
    ENERGY_PROJECTION,
    ENERGY_VISCOUS,
    ENERGY_WORK_FIELD,
    ENERGY_WORK_GRAVITY,
    ROW_COUNT,
    ROW_FILL,
    ROW_NODE,
    ROW_WARP,
    SUM_DIAG,
)
from emfabric._kernels.vec3 import (
    cross,
    dot,
    mat_vec,
    tilt_angle,
    vec,
    world_inertia_times,
    yaw_angle,
)

# indices of the scalar results (records.DIAG_*)
KE, PX, PY, PZ, LX, LY, LZ = DIAG_KE, DIAG_PX, DIAG_PY, DIAG_PZ, DIAG_LX, DIAG_LY, DIAG_LZ
DEFLECTION, STRETCH, STRAIN, BROKEN = DIAG_DEFLECTION, DIAG_STRETCH, DIAG_STRAIN, DIAG_BROKEN
MIN_ALPHA, AHEAD_MIN, AHEAD_MAX = DIAG_MIN_ALPHA, DIAG_AHEAD_MIN, DIAG_AHEAD_MAX
APPROACH_MAX, RECEDE_MAX = DIAG_APPROACH_MAX, DIAG_RECEDE_MAX
COUNT = DIAG_COUNT


@njit(cache=True)
def _yarn_stats(x, a0, count, step, s0, alpha, coef, rest2, il2, mat, stats):
    """Max U² of the yarns not broken (α ≥ broken_below: a broken yarn carries no load, and
    its ends fly apart), strain energy, broken count and min α of `count` consecutive segments
    s0 + k joining a0 + k and a0 + k + step, merged into stats."""
    xx, xy, xz = x[0], x[1], x[2]
    broken_below = mat.broken_below
    u2max, strain, broken, amin = stats
    for k in range(count):
        a = a0 + k
        b = a + step
        s = s0 + k
        u2 = stretch_sq(xx[b] - xx[a], xy[b] - xy[a], xz[b] - xz[a], il2)
        al = alpha[s]
        if al >= broken_below:
            u2max = max(u2max, u2)
        strain += al * coef[s] * rest2 * strain_energy_density(u2, mat)
        broken += 1.0 if al < broken_below else 0.0
        amin = min(amin, al)
    return u2max, strain, broken, amin


@njit(cache=True)
def fabric_diagnostics(phys, x, v, alpha, centre, direction, out):
    """Kinetic energy, momentum, angular momentum (about the origin), max |Δz|, max stretch,
    strain energy, broken yarns, min α, and the nodes' extent/speed along the flight direction.
    """
    nodes, yarns = phys.nodes, phys.yarns
    xref, mass = nodes.x0, nodes.mass
    coef, rest, il2 = yarns.stiffness, yarns.rest_length, yarns.inv_rest2
    ke = 0.0
    p = np.zeros(3)
    ang = np.zeros(3)
    defl = 0.0
    ahead_min = math.inf
    ahead_max = -math.inf
    approach = -math.inf
    recede = -math.inf
    for n in range(x.shape[1]):
        m = mass[n]
        vx, vy, vz = v[0, n], v[1, n], v[2, n]
        ke += 0.5 * m * (vx * vx + vy * vy + vz * vz)
        p[0] += m * vx
        p[1] += m * vy
        p[2] += m * vz
        ang[0] += m * (x[1, n] * vz - x[2, n] * vy)
        ang[1] += m * (x[2, n] * vx - x[0, n] * vz)
        ang[2] += m * (x[0, n] * vy - x[1, n] * vx)
        dz = abs(x[2, n] - xref[2, n])
        if dz > defl:
            defl = dz
        s = ((x[0, n] - centre[0]) * direction[0] + (x[1, n] - centre[1]) * direction[1]
             + (x[2, n] - centre[2]) * direction[2])
        ahead_min = min(ahead_min, s)
        ahead_max = max(ahead_max, s)
        vd = vx * direction[0] + vy * direction[1] + vz * direction[2]
        approach = max(approach, -vd)
        recede = max(recede, vd)
    # rest lengths are uniform per family within a ply: per ply, its warp rows, then its fill
    # block (records' layout)
    rows = nodes.rows
    stats = (0.0, 0.0, 0.0, 1.0)
    for ply in range(nodes.ply_rows.shape[0] - 1):
        j0 = nodes.ply_rows[ply]
        j1 = nodes.ply_rows[ply + 1]
        nx = rows[j0, ROW_COUNT]
        sw = rows[j0, ROW_WARP]
        for j in range(j0, j1):
            # int64(1): a literal 1 would compile _yarn_stats a second time
            stats = _yarn_stats(x, rows[j, ROW_NODE], nx - 1, int64(1), rows[j, ROW_WARP], alpha,
                                coef, rest[sw] ** 2, il2[sw], phys.material, stats)
        if j1 - j0 > 1:
            sf = rows[j0, ROW_FILL]
            stats = _yarn_stats(x, rows[j0, ROW_NODE], (j1 - j0 - 1) * nx, nx, sf, alpha,
                                coef, rest[sf] ** 2, il2[sf], phys.material, stats)
    u2max, strain, broken, amin = stats
    out[KE] = ke
    out[PX] = p[0]
    out[PY] = p[1]
    out[PZ] = p[2]
    out[LX] = ang[0]
    out[LY] = ang[1]
    out[LZ] = ang[2]
    out[DEFLECTION] = defl
    out[STRETCH] = math.sqrt(u2max)
    out[STRAIN] = strain
    out[BROKEN] = broken
    out[MIN_ALPHA] = amin
    out[AHEAD_MIN] = ahead_min
    out[AHEAD_MAX] = ahead_max
    out[APPROACH_MAX] = approach
    out[RECEDE_MAX] = recede


@njit(cache=True, _nrt=True)
def fabric_from_rows(sums, ny, out):
    """fabric_diagnostics's results from the rows' shares that central differences' kick
    leaves in the row sums (records.SUM_DIAG: sums, largest or smallest values per grid
    row), reduced over the ny rows in row order: the same values but for the sums' rounding
    (summed per row, then over rows), whatever the thread count."""
    for k in (KE, PX, PY, PZ, LX, LY, LZ, STRAIN, BROKEN):
        acc = 0.0
        for j in range(ny):
            acc += sums[SUM_DIAG + k, j]
        out[k] = acc
    # the largest and smallest values from fabric_diagnostics's starting values
    for k, start in ((DEFLECTION, 0.0), (STRETCH, 0.0), (AHEAD_MAX, -math.inf),
                     (APPROACH_MAX, -math.inf), (RECEDE_MAX, -math.inf)):
        acc = start
        for j in range(ny):
            acc = max(acc, sums[SUM_DIAG + k, j])
        out[k] = acc
    for k, start in ((MIN_ALPHA, 1.0), (AHEAD_MIN, math.inf)):
        acc = start
        for j in range(ny):
            acc = min(acc, sums[SUM_DIAG + k, j])
        out[k] = acc
    out[STRETCH] = math.sqrt(out[STRETCH])


@njit(cache=True, inline="always")
def _body_energy(body, b_state):
    """The body's angular momentum about its centre (inertial frame) [kg m² s⁻¹] and its
    translational and rotational kinetic energy [J] (zeros without a body)."""
    rot = b_state[BODY_R0:BODY_R0 + 3]
    v = vec(b_state[BODY_V])
    w = vec(b_state[BODY_W])
    if not body.active:
        return (0.0, 0.0, 0.0), 0.0, 0.0
    h = world_inertia_times(rot, body.inertia, w)
    return h, 0.5 * body.mass * dot(v, v), 0.5 * dot(w, h)


@njit(cache=True, inline="always")
def _total_energy(ke_t, ke_r, diag, energy):
    """Kinetic + strain energy + dissipated − work so far [J] (the energy balance's total; the
    terms of energy in the order of records.ENERGY_TERMS)."""
    return (ke_t + ke_r + diag[KE] + diag[STRAIN] + energy[ENERGY_FRICTION]
            + energy[ENERGY_CONTACT] + energy[ENERGY_PROJECTION] + energy[ENERGY_DAMAGE]
            + energy[ENERGY_VISCOUS] - energy[ENERGY_WORK_FIELD] - energy[ENERGY_WORK_GRAVITY])


@njit(cache=True)
def total_energy(phys, x, v, alpha, b_state, energy, centre, direction):
    """The total energy of a state (_total_energy) without a history record [J]."""
    diag = np.empty(COUNT)
    fabric_diagnostics(phys, x, v, alpha, centre, direction, diag)
    _h, ke_t, ke_r = _body_energy(phys.body, b_state)
    return _total_energy(ke_t, ke_r, diag, energy)


@njit(cache=True)
def history_row(step, b_state, body, diag, energy, e_initial, contact_force, row):
    """Write one history record into row (the columns of records.HISTORY_VARIABLES): the step's
    statistics (a StepStats), the body state, the fabric diagnostics `diag` (fabric_diagnostics),
    the cumulative energy terms, the contact force; e_initial: the energy reference (NaN: this
    record's own total).

    Returns the record's total energy (kinetic + strain + dissipated − work) [J].
    """
    rot = b_state[BODY_R0:BODY_R0 + 3]
    x = vec(b_state[BODY_X])
    v = vec(b_state[BODY_V])
    w = vec(b_state[BODY_W])
    has_body = body.active
    b_mass = body.mass
    nose_body = body.nose
    nose = mat_vec(rot, nose_body)
    zero = (0.0, 0.0, 0.0)
    h, ke_t, ke_r = _body_energy(body, b_state)
    p = (b_mass * v[0], b_mass * v[1], b_mass * v[2]) if has_body else zero
    xp = cross(x, p)
    ang = (xp[0] + h[0], xp[1] + h[1], xp[2] + h[2])
    # tilt, eq. 5.2, in atan2 form (accurate at small angles)
    tilt = tilt_angle(rot, nose_body) if has_body else 0.0
    yaw = yaw_angle(rot, nose_body, v) if has_body else 0.0
    total = _total_energy(ke_t, ke_r, diag, energy)
    e0 = total if math.isnan(e_initial) else e_initial
    row[COL_TIME] = step.t
    row[COL_DT] = step.dt
    row[COL_ITERATIONS] = step.iterations
    row[COL_ERROR] = step.error
    row[COL_REJECTED] = step.rejected
    row[COL_EVALUATIONS] = step.evaluations
    for c in range(3):
        row[COL_POSITION + c] = x[c]
        row[COL_VELOCITY + c] = v[c]
        row[COL_OMEGA + c] = w[c]
        row[COL_NOSE + c] = nose[c]
    row[COL_TILT] = tilt
    row[COL_CONTACTS] = step.contacts
    row[COL_DEFLECTION] = diag[DEFLECTION]
    row[COL_STRETCH] = diag[STRETCH]
    for c in range(3):
        row[COL_FABRIC_MOMENTUM + c] = diag[PX + c]
        row[COL_FABRIC_ANGULAR + c] = diag[LX + c]
        row[COL_BODY_MOMENTUM + c] = p[c]
        row[COL_BODY_ANGULAR + c] = ang[c]
    row[COL_KE_BODY] = ke_t + ke_r
    row[COL_KE_BODY_ROTATION] = ke_r
    row[COL_KE_FABRIC] = diag[KE]
    row[COL_STRAIN] = diag[STRAIN]
    row[COL_BROKEN] = diag[BROKEN]
    row[COL_MIN_DAMAGE] = diag[MIN_ALPHA]
    for c in range(energy.shape[0]):
        row[COL_ENERGY_TERMS + c] = energy[c]
    row[COL_BALANCE] = total - e0
    row[COL_YAW] = yaw
    for c in range(3):
        row[COL_CONTACT_FORCE + c] = contact_force[c]
    return e0


@njit(cache=True)
def _root(parent, i):
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True)
def joined_to(ends, intact, anchor, out):
    """out[n] = whether node n is joined through intact segments to an anchor node (union-find
    over the intact segments; anchor and out: (node_count,) bool). A node with no intact
    segment is joined to nothing (not even when it is an anchor)."""
    n = anchor.shape[0]
    parent = np.arange(n)
    touched = np.zeros(n, dtype=np.bool_)
    for s in range(ends.shape[0]):
        if intact[s]:
            a = _root(parent, ends[s, 0])
            b = _root(parent, ends[s, 1])
            touched[ends[s, 0]] = True
            touched[ends[s, 1]] = True
            if a != b:
                parent[max(a, b)] = min(a, b)
    held = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        if anchor[i] and touched[i]:
            held[_root(parent, i)] = True
    for i in range(n):
        out[i] = touched[i] and held[_root(parent, i)]


@njit(cache=True)
def piece_roots(ends, intact, out):
    """out[n] = a label of the piece node n belongs to (joined through intact segments; the
    same label for every node of a piece), −1 for a node with no intact segment."""
    n = out.shape[0]
    parent = np.arange(n)
    touched = np.zeros(n, dtype=np.bool_)
    for s in range(ends.shape[0]):
        if intact[s]:
            a = _root(parent, ends[s, 0])
            b = _root(parent, ends[s, 1])
            touched[ends[s, 0]] = True
            touched[ends[s, 1]] = True
            if a != b:
                parent[max(a, b)] = min(a, b)
    for i in range(n):
        out[i] = _root(parent, i) if touched[i] else -1
