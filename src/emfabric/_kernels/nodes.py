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

The functions called once per row or row block (_tensions, _block_start, _row_block,
_drift_block, _kick_block) are compiled with `_nrt=False`, without Numba's reference counting:
with it, every call references and releases each array of its arguments on entry and exit (the
records hold ~90), an atomic operation each: `NRT_incref`/`NRT_decref` were 10.4 % of a
paper-field step, and are 1.9 % without them (`perf`, benchmarks/profile_step.py). They
allocate no array and return none, so the references their callers hold are enough; Numba
refuses to compile one that would need the counts.
"""

import math

from numba import int64, njit, prange, uint64

from emfabric._kernels.fields import magnetic_force, node_field_of, uniform_field
from emfabric._kernels.materials import (
    damage_above,
    fung_energy,
    fung_stress,
    fung_tangent,
    ksv_energy,
    ksv_stress,
    ksv_tangent,
    stretch_sq,
)
from emfabric._kernels.records import (
    DIAG_AHEAD_MAX,
    DIAG_AHEAD_MIN,
    DIAG_APPROACH_MAX,
    DIAG_BROKEN,
    DIAG_DEFLECTION,
    DIAG_KE,
    DIAG_MIN_ALPHA,
    DIAG_RECEDE_MAX,
    DIAG_STRAIN,
    DIAG_STRETCH,
    GYRATION_TURN,
    MATERIAL_FUNG,
    ROW_COUNT,
    ROW_FILL,
    ROW_NODE,
    ROW_WARP,
    SUM_DIAG,
    SUM_ERROR_DEN,
    SUM_ERROR_NUM,
    SUM_MOTION,
    SUM_PROJECTION,
    SUM_SPEED,
    SUM_STIFFNESS,
    SUM_WORK_FIELD,
    SUM_WORK_GRAVITY,
    SUM_WORK_VISCOUS,
    RowArrays,
    RowRecords,
)
from emfabric._kernels.reductions import from_key, lane_sums, order_key


@njit(cache=True, _nrt=True)
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
VISC = 29
"""With VISCOUS: the viscous part of the tension vectors of ROW_WARP_TENSION, ROW_FILL_UP and
ROW_FILL_DOWN is in the 3 rows VISC further on (padded as they are; the row after each, 32, 36
and 40, is not theirs)."""
ROW_VISC_RATE = 32
"""With VISCOUS: the viscous tension per unit length of d of the segments being computed."""
ROW_VISC_WORK = 36
"""With VISCOUS: per-node work of the viscous force in a half kick."""
ROW_VISC_FORCE = 40
"""With VISCOUS: the viscous part of the row's node force (3 rows)."""
ROWBUF_ROWS = 43
RKW = ROW_WARP_TENSION + 3
"""The warp segments' tangent stiffness (padded as their tensions)."""
ROW_SEGMENT_ENERGY = ROW_FORCE
"""_tensions with STATS: each segment's stored energy (the force rows are written only after
the row's tensions)."""
ROW_DIAG = ROW_SEGMENT
"""Central differences' kick: per-node terms of the fabric diagnostics' sums (7 rows: kinetic
energy, momentum, angular momentum), once the row's force is consumed."""

# brittle yarns failing on the averaged stretch: a segment whose Green strain passes this
# multiple of its strain at break breaks at once (records.Yarns.averaging_rate)
OVERSTRAIN = 1.25
ALPHA = 1
"""_tensions mode bit: write the trial damage α."""
VISCOUS = 8
"""_tensions and _row_force mode bit: add the axial viscous tension η·α·L̇ of a taut segment
(records.Yarns.damping), with L̇ from the displacement since the step's start over Δt, and write
its part of the tension vectors VISC rows on (and of the node force into ROW_VISC_FORCE)."""
TANGENT = 2
"""_tensions mode bit: write each segment's axial tangent stiffness (the stable step's)."""
STATS = 4
"""_tensions mode bit: return the segments' share of the fabric diagnostics (_segment_stats)."""
ROW_ERRORS = "numpy"
"""Numba's error model of the row-block kernels (_row_block, _drift_block, _kick_block):
NumPy's, not Python's. Python's tests every division for a zero divisor to raise
ZeroDivisionError: a branch out of each loop that divides, which keeps the compiler from
vectorising it (the Boris rotation's, the φ-update's). These kernels divide only by numbers
that cannot be zero (1 + |t|², a Δt tested > 0), so the tests never fired and the numbers are
the same to the bit; a non-finite value still stops the step (the step kernels' NOT_FINITE).
Measured (`python benchmarks/bench.py --quick`, docs/performance.md): see "Vectorised rows"."""
NO_STATS = (0.0, 0.0, 0.0, 1.0)
"""_segment_stats of no segments: (max U² of the unbroken, strain energy, broken, min α)."""


@njit(cache=True, inline="always")
def _segment_stats(buf, s, coef, rest2, mat, count):
    """The fabric diagnostics' share of `count` segments s + i with damage buf[ROW_STRESS] and
    stretch² buf[ROW_STRETCH_SQ] (diagnostics.fabric_diagnostics's terms): (max U² of those
    not broken, strain energy Σ α stiffness L0² W(U²) in _buf_total's order, broken count,
    min α); buf[ROW_SEGMENT_ENERGY]: scratch."""
    bb = mat.broken_below
    if mat.kind == MATERIAL_FUNG:
        h = mat.fung_h
        for i in range(count):
            u = uint64(i)
            buf[ROW_SEGMENT_ENERGY, u] = (buf[ROW_STRESS, u] * coef[uint64(s + i)] * rest2
                                          * fung_energy(buf[ROW_STRETCH_SQ, u], h))
    else:
        for i in range(count):
            u = uint64(i)
            buf[ROW_SEGMENT_ENERGY, u] = (buf[ROW_STRESS, u] * coef[uint64(s + i)] * rest2
                                          * ksv_energy(buf[ROW_STRETCH_SQ, u]))
    # the extremes over integer keys, the count as an integer: one branch-free loop that
    # vectorises (reductions.py); U² ≥ 0 and α ≥ 0, so the keys of 0 and 1 start them
    ku2 = order_key(0.0)
    kamin = order_key(1.0)
    broken = 0
    for i in range(count):
        u = uint64(i)
        a = buf[ROW_STRESS, u]
        intact = int64(a >= bb)  # 1 or 0, arithmetic rather than a branch: it vectorises
        ku2 = max(ku2, order_key(buf[ROW_STRETCH_SQ, u]) * intact)
        broken += 1 - intact
        kamin = min(kamin, order_key(a))
    return (from_key(ku2), _buf_total(buf, ROW_SEGMENT_ENERGY, count), float(broken),
            from_key(kamin))


@njit(cache=True, _nrt=False)
def _tensions(x, span, rest, alpha, damage_thr, coef, mat, buf, out, mode, visc):
    """Tension vectors of `count` segments into buf[r:r + 3, c:c + count], out = (r, c), and
    with mode & TANGENT their axial tangent stiffness α·stiffness·materials.tangent_factor
    into buf[r + 3, c:c + count]. Returns, with mode & STATS, the segments' share of the
    fabric diagnostics at the trial α (_segment_stats), else NO_STATS.

    span = (a, step, s, count): segment s + i joins node a + i to node a + i + step, at the
    positions x (3, N); the segment arrays (damage thresholds U², stiffness) are whole; rest =
    (1/L0², L0²) of them. alpha = (committed α, trial α written when mode & ALPHA, committed
    averaged stretch², trial averaged stretch² written when mode & ALPHA, Yarns.averaging_rate,
    Δt): where the averaged stretch² is kept (brittle yarns, fabric.damage.strain_averaging),
    its trial is the backward-Euler update ū² + g max(U², 1) over 1 + g, g = Δt/τ (a slack
    yarn counts as unstrained), and a segment breaks where that passes its threshold or where
    its Green strain passes OVERSTRAIN times the threshold's; else where U² passes it.
    visc = (damping, base, 1/Δt): with mode & VISCOUS a taut segment's tension gains
    η·α·L̇ with L̇ = d·(d − d_base)/(|d| Δt) (the rate over the step from the positions base;
    the total tension is kept ≥ 0: a yarn does not push), and that part of the tension vectors
    goes VISC rows on.

    Every array is indexed directly, with unsigned indices (no views: Numba references and
    releases each view it makes, an atomic operation each, ~16 % of a step when this took row
    views; unsigned, the index needs no wrap-around test and the loops vectorise as over
    views). Split into short loops over few arrays so that the compiler vectorises them.
    """
    a, step, s, count = span
    inv_rest2, rest2 = rest
    r, col = out
    for i in range(count):
        u = uint64(i)
        ka = uint64(a + i)
        kb = uint64(a + step + i)
        buf[ROW_SEGMENT, u] = x[0, kb] - x[0, ka]
        buf[ROW_SEGMENT + 1, u] = x[1, kb] - x[1, ka]
        buf[ROW_SEGMENT + 2, u] = x[2, kb] - x[2, ka]
    for i in range(count):
        u = uint64(i)
        buf[ROW_STRETCH_SQ, u] = stretch_sq(buf[ROW_SEGMENT, u], buf[ROW_SEGMENT + 1, u],
                                            buf[ROW_SEGMENT + 2, u], inv_rest2)
    alpha_c, alpha_t, strain_c, strain_t, avg_rate, dt = alpha
    if strain_c.shape[0] == 0:
        for i in range(count):
            u = uint64(i)
            k = uint64(s + i)
            buf[ROW_STRESS, u] = damage_above(alpha_c[k], buf[ROW_STRETCH_SQ, u],
                                              damage_thr[k], mat)
    else:
        # brittle failure on the averaged stretch² (records.Yarns.averaging_rate); the trial
        # average in ROW_VISC_RATE until it is stored (that row is written below, if at all)
        for i in range(count):
            u = uint64(i)
            k = uint64(s + i)
            g = dt * avg_rate[k]
            u2 = buf[ROW_STRETCH_SQ, u]
            thr = damage_thr[k]
            avg = (strain_c[k] + g * max(u2, 1.0)) / (1.0 + g)
            buf[ROW_VISC_RATE, u] = avg
            over = avg > thr or u2 - 1.0 > OVERSTRAIN * (thr - 1.0)
            buf[ROW_STRESS, u] = 0.0 if over else alpha_c[k]
        if mode & ALPHA:
            for i in range(count):
                strain_t[uint64(s + i)] = buf[ROW_VISC_RATE, uint64(i)]
    if mode & ALPHA:
        for i in range(count):
            alpha_t[uint64(s + i)] = buf[ROW_STRESS, uint64(i)]
    viscous = mode & VISCOUS
    if viscous:
        damping, base, inv_dt = visc
        for i in range(count):
            u = uint64(i)
            ka = uint64(a + i)
            kb = uint64(a + step + i)
            dx, dy, dz = buf[ROW_SEGMENT, u], buf[ROW_SEGMENT + 1, u], buf[ROW_SEGMENT + 2, u]
            ddx = dx - (base[0, kb] - base[0, ka])
            ddy = dy - (base[1, kb] - base[1, ka])
            ddz = dz - (base[2, kb] - base[2, ka])
            taut = buf[ROW_STRETCH_SQ, u] > 1.0
            # η α (d·ḋ)/|d|²: the viscous tension η α L̇ per unit length of d
            buf[ROW_VISC_RATE, u] = ((buf[ROW_STRESS, u] * damping[uint64(s + i)] * inv_dt
                                      * (dx * ddx + dy * ddy + dz * ddz)
                                      / (dx * dx + dy * dy + dz * dz)) if taut else 0.0)
    # the material's kind is dispatched outside each loop: left to the compiler, a large
    # enough function is not unswitched, and the vectorised loop then calls exp for every
    # segment of every law
    fung = mat.kind == MATERIAL_FUNG
    h = mat.fung_h
    if mode & TANGENT:
        rt = r + 3
        if fung:
            for i in range(count):
                u = uint64(i)
                buf[rt, uint64(col + i)] = (buf[ROW_STRESS, u] * coef[uint64(s + i)]
                                            * fung_tangent(buf[ROW_STRETCH_SQ, u], h))
        else:
            for i in range(count):
                u = uint64(i)
                buf[rt, uint64(col + i)] = (buf[ROW_STRESS, u] * coef[uint64(s + i)]
                                            * ksv_tangent(buf[ROW_STRETCH_SQ, u]))
    stats = NO_STATS
    if mode & STATS:
        stats = _segment_stats(buf, s, coef, rest2, mat, count)
    # the stress law (materials.stress_factor's two laws)
    if fung:
        for i in range(count):
            u = uint64(i)
            buf[ROW_STRESS, u] = (buf[ROW_STRESS, u] * coef[uint64(s + i)]
                                  * fung_stress(buf[ROW_STRETCH_SQ, u], h))
    else:
        for i in range(count):
            u = uint64(i)
            buf[ROW_STRESS, u] = (buf[ROW_STRESS, u] * coef[uint64(s + i)]
                                  * ksv_stress(buf[ROW_STRETCH_SQ, u]))
    if viscous:
        # elastic + viscous, at least 0; the viscous part is what the sum adds to the elastic
        for i in range(count):
            u = uint64(i)
            elastic = buf[ROW_STRESS, u]
            total = max(elastic + buf[ROW_VISC_RATE, u], 0.0)
            buf[ROW_VISC_RATE, u] = total - elastic
            buf[ROW_STRESS, u] = total
        _scaled_segments(buf, ROW_VISC_RATE, r + VISC, col, count)
    _scaled_segments(buf, ROW_STRESS, r, col, count)
    return stats


@njit(cache=True, inline="always")
def _scaled_segments(buf, scale, r, col, count):
    """buf[r:r + 3, col:col + count] = buf[scale] × the segment vectors buf[ROW_SEGMENT:+3]
    (_tensions' tension vectors, or their viscous part)."""
    for i in range(count):
        u = uint64(i)
        o = uint64(col + i)
        buf[r, o] = buf[scale, u] * buf[ROW_SEGMENT, u]
        buf[r + 1, o] = buf[scale, u] * buf[ROW_SEGMENT + 1, u]
        buf[r + 2, o] = buf[scale, u] * buf[ROW_SEGMENT + 2, u]


@njit(cache=True, _nrt=False)
def _block_start(j0, phys, prev, sin, sout, work, buf, mode, dt, base):
    """Prepare a block's row buffer before its first row j0: zero the padding of the warp row
    and set the fill tensions (with mode & TANGENT their stiffness, with mode & VISCOUS their
    viscous part at the rate since the positions `base` over the step dt: the base the block's
    rows take theirs from, RowArrays.base) from the row below (recomputed, writing no damage or
    averaged stretch, so that blocks are independent; zero for the first row of a ply): the
    same numbers as the row below computes, so that the threaded kernel's blocks give the
    serial kernel's. Returns the first buffer rows (fill up, fill down): ROW_FILL_UP,
    ROW_FILL_DOWN."""
    nodes, yarns, mat = phys.nodes, phys.yarns, phys.material
    rows = nodes.rows
    inv_dt = 1.0 / dt if dt > 0.0 else 0.0
    for c in range(4):
        buf[ROW_WARP_TENSION + c, 0] = 0.0
    for c in range(3):
        buf[ROW_WARP_TENSION + VISC + c, 0] = 0.0
    s = rows[j0 - 1, ROW_FILL] if j0 > 0 else -1
    if s >= 0:
        a = rows[j0 - 1, ROW_NODE]
        nx = rows[j0 - 1, ROW_COUNT]
        _tensions(prev, (a, nx, s, nx), (yarns.inv_rest2[s], 0.0),
                  (sin.alpha, sout.alpha, sin.strain, sout.strain, yarns.averaging_rate, dt),
                  work.damage_thr, yarns.stiffness, mat, buf, (int64(ROW_FILL_DOWN), int64(0)),
                  mode & (TANGENT | VISCOUS), (yarns.damping, base, inv_dt))
    else:
        buf[ROW_FILL_DOWN:ROW_FILL_DOWN + 4] = 0.0
        buf[ROW_FILL_DOWN + VISC:ROW_FILL_DOWN + VISC + 3] = 0.0
    return ROW_FILL_UP, ROW_FILL_DOWN


@njit(cache=True, inline="always")
def _row_force(j, arr, mat, uni, sourced, grav, prev, buf, ru, rd, mode, inv_dt):
    """The non-magnetic force of grid row j at the positions `prev` (and the step's end time:
    the field is uniform, or the node fields stored for it) into the row buffer's ROW_FORCE
    rows: yarn tensions (the warp segments of row j and the fill segments to row j + 1, into
    buffer rows ru; rows rd hold those from row j − 1), one difference per node and
    direction, plus the electric part of eq. 2.7 and gravity. Trial damage into
    arr.alpha_trial; with mode & TANGENT the segments' tangent stiffness into row 3 of the
    warp rows, ru and rd. With mode & VISCOUS the yarns' viscous tensions are part of the force
    (_tensions, at the rate since arr.base over 1/inv_dt) and their share of it goes into
    ROW_VISC_FORCE as well. Returns, with mode & STATS, the fabric diagnostics' share of the
    row's warp segments and of the fill segments to row j + 1 (_segment_stats, merged), else
    NO_STATS.

    The one force evaluation of both schemes: the φ-update (_row_block) and central
    differences (_kick_block) call it row by row, inlined, given arrays and numbers rather than
    Physics's records (_rotate_row says why): arr a records.RowArrays built once per block, the
    material, the field as fields.uniform_field gives it, gravity as a tuple."""
    (rows, mass, charge, inv_rest2, rest, coef, alpha_c, alpha_t, damage_thr, node_fields,
     damping, base, strain_c, strain_t, avg_rate, dt) = arr
    visc = (damping, base, inv_dt)
    alpha = (alpha_c, alpha_t, strain_c, strain_t, avg_rate, dt)
    # the row's nodes and first segments (records.Nodes.rows); rest lengths are uniform per
    # yarn family within a ply
    nb = rows[j, ROW_NODE]
    nx = rows[j, ROW_COUNT]
    sb = rows[j, ROW_WARP]
    sf = rows[j, ROW_FILL]
    # padded warp rows: column i + 1 is the tension of segment (i, i + 1), zeros at both ends
    for c in range(4):
        buf[ROW_WARP_TENSION + c, nx] = 0.0
    for c in range(3):
        buf[ROW_WARP_TENSION + VISC + c, nx] = 0.0
    # (int64(): a constant in a tuple is typed as a literal, and each literal would compile
    # _tensions again)
    sw = _tensions(prev, (nb, int64(1), sb, nx - 1), (inv_rest2[sb], rest[sb] ** 2), alpha,
                   damage_thr, coef, mat, buf, (int64(ROW_WARP_TENSION), int64(1)),
                   mode | ALPHA, visc)
    sfl = NO_STATS
    if sf >= 0:
        sfl = _tensions(prev, (nb, nx, sf, nx), (inv_rest2[sf], rest[sf] ** 2), alpha,
                        damage_thr, coef, mat, buf, (int64(ru), int64(0)), mode | ALPHA,
                        visc)
    else:
        # the ply's last row: no fill above it (the whole width, so that the first row of the
        # next ply finds no tension from below)
        buf[ru:ru + 4] = 0.0
        buf[ru + VISC:ru + VISC + 3] = 0.0
    # the field at t1 where the node is now (the iterate). The uniform and half-space
    # fields: field_at in each loop that needs it (a compare and a select, cheaper than a
    # row of stores and loads: the stored variant made an evaluation ~7 % slower); a field
    # with sources: the value fields.fill_node_fields stored for this attempt (at the
    # predicted position). fields.node_field_of, chosen at compile time by the field's type
    for c in range(3):
        rw = ROW_WARP_TENSION + c
        rf = ROW_FORCE + c
        rfu = ru + c
        rfd = rd + c
        g = grav[c]
        # yarn force, one difference per node and direction (mirror-exact assembly),
        # then the electric part of eq. 2.7 and gravity
        for i in range(nx):
            u = uint64(i)
            k = uint64(nb + i)
            fe, _fb = node_field_of(uni, sourced, node_fields, nb + i,
                                    (prev[0, k], prev[1, k], prev[2, k]))
            buf[rf, u] = (((buf[rw, u + uint64(1)] - buf[rw, u]) + (buf[rfu, u] - buf[rfd, u]))
                          + (mass[k] * g + charge[k] * fe[c]))
    if mode & VISCOUS:
        for c in range(3):
            rw = ROW_WARP_TENSION + VISC + c
            rfu = ru + VISC + c
            rfd = rd + VISC + c
            rv = ROW_VISC_FORCE + c
            for i in range(nx):
                u = uint64(i)
                buf[rv, u] = (buf[rw, u + uint64(1)] - buf[rw, u]) + (buf[rfu, u] - buf[rfd, u])
    return (max(sw[0], sfl[0]), sw[1] + sfl[1], sw[2] + sfl[2], min(sw[3], sfl[3]))


@njit(cache=True, _nrt=False, error_model=ROW_ERRORS)
def _row_block(j0, j1, phys, prev, sin, sout, work, t1, phi, dt, buf):
    """Rows j0 ≤ j < j1 of the fused φ iterate: the force of each row (_row_force), consumed at
    once by the φ-update of its nodes (eqs. 3.2, A12–A13) and the error terms of eq. 3.10."""
    nodes, yarns, mat, fld = phys.nodes, phys.yarns, phys.material, phys.field
    uni, sourced = uniform_field(fld)
    grav = (fld.gravity[0], fld.gravity[1], fld.gravity[2])
    node_fields = work.node_field
    arr = RowArrays(nodes.rows, nodes.mass, nodes.charge, yarns.inv_rest2, yarns.rest_length,
                    yarns.stiffness, sin.alpha, sout.alpha, work.damage_thr, node_fields,
                    yarns.damping, sin.x, sin.strain, sout.strain, yarns.averaging_rate, dt)
    x0, v0, f0 = sin.x, sin.v, sin.f
    x1, v1, f1 = sout.x, sout.v, sout.f
    skip_err = work.flag
    err_num, err_den = work.err_num, work.err_den
    inv_mass, charge = nodes.inv_mass, nodes.charge
    ru, rd = _block_start(j0, phys, prev, sin, sout, work, buf, 0, dt, sin.x)
    rf, ra, rr = ROW_FORCE, ROW_VEL_EXPLICIT, ROW_ROTATION
    # arrays indexed directly with unsigned indices, no row views (_tensions says why)
    for j in range(j0, j1):
        _row_force(j, arr, mat, uni, sourced, grav, prev, buf, ru, rd, 0, 0.0)
        nb = nodes.rows[j, ROW_NODE]
        nx = nodes.rows[j, ROW_COUNT]
        for i in range(nx):
            buf[ROW_DT_OVER_MASS, uint64(i)] = dt * inv_mass[uint64(nb + i)]
        for c in range(3):
            for i in range(nx):
                u = uint64(i)
                k = uint64(nb + i)
                buf[ra + c, u] = v0[c, k] + buf[ROW_DT_OVER_MASS, u] * (
                    phi * buf[rf + c, u] + (1.0 - phi) * f0[c, k])
        # magnetic part implicit in v1: v1 − v1 × u = a with u = φΔt q B / m (solved exactly)
        for i in range(nx):
            u = uint64(i)
            k = uint64(nb + i)
            _fe, fb = node_field_of(uni, sourced, node_fields, nb + i,
                                    (prev[0, k], prev[1, k], prev[2, k]))
            beta = phi * buf[ROW_DT_OVER_MASS, u] * charge[k]
            buf[rr, u] = beta * fb[0]
            buf[rr + 1, u] = beta * fb[1]
            buf[rr + 2, u] = beta * fb[2]
        for i in range(nx):
            u = uint64(i)
            ax, ay, az = buf[ra, u], buf[ra + 1, u], buf[ra + 2, u]
            ux, uy, uz = buf[rr, u], buf[rr + 1, u], buf[rr + 2, u]
            buf[ROW_PROJECTION, u] = ax * ux + ay * uy + az * uz
            buf[ROW_INV_DENOM, u] = 1.0 / (1.0 + ux * ux + uy * uy + uz * uz)
        for i in range(nx):
            u = uint64(i)
            k = uint64(nb + i)
            ax, ay, az = buf[ra, u], buf[ra + 1, u], buf[ra + 2, u]
            ux, uy, uz = buf[rr, u], buf[rr + 1, u], buf[rr + 2, u]
            a_dot_u = buf[ROW_PROJECTION, u]
            inv = buf[ROW_INV_DENOM, u]
            v1[0, k] = (ax + (ay * uz - az * uy) + a_dot_u * ux) * inv
            v1[1, k] = (ay + (az * ux - ax * uz) + a_dot_u * uy) * inv
            v1[2, k] = (az + (ax * uy - ay * ux) + a_dot_u * uz) * inv
        for i in range(nx):
            u = uint64(i)
            k = uint64(nb + i)
            _fe, fb = node_field_of(uni, sourced, node_fields, nb + i,
                                    (prev[0, k], prev[1, k], prev[2, k]))
            fm = magnetic_force(charge[k], (v1[0, k], v1[1, k], v1[2, k]), fb)
            f1[0, k] = buf[rf, u] + fm[0]
            f1[1, k] = buf[rf + 1, u] + fm[1]
            f1[2, k] = buf[rf + 2, u] + fm[2]
        for c in range(3):
            for i in range(nx):
                k = uint64(nb + i)
                x1[c, k] = x0[c, k] + dt * (phi * v1[c, k] + (1.0 - phi) * v0[c, k])
        # error measure terms (3.10 step 5a); contact candidates are measured after contact
        for i in range(nx):
            k = uint64(nb + i)
            keep = 1.0 if skip_err[k] == 0 else 0.0
            dx = x1[0, k] - prev[0, k]
            dy = x1[1, k] - prev[1, k]
            dz = x1[2, k] - prev[2, k]
            err_num[k] = keep * math.sqrt(dx * dx + dy * dy + dz * dz)
            dx = x1[0, k] - x0[0, k]
            dy = x1[1, k] - x0[1, k]
            dz = x1[2, k] - x0[2, k]
            err_den[k] = keep * math.sqrt(dx * dx + dy * dy + dz * dz)
        ru, rd = rd, ru


ROWS_PER_BLOCK = 16


@njit(cache=True, inline="always")
def fused_iterate(phys, prev, sin, sout, work, t1, phi, dt, rowbuf):
    """Yarn tensions at the iterate `prev` and the φ-update of every node from the start state
    sin (x, v, f, committed α) into sout (x, v, f; trial damage into sout.alpha), serially.

    work: the step's Work record (node fields, damage thresholds, flag — nodes left out of the
    error measure —, the error terms and their per-row sums row_sums). rowbuf: (ROWBUF_ROWS,
    nx + 1). Every row in one block (kick_rows says why): the same arithmetic as the threaded
    kernel's blocks, and one compiled specialisation of _row_block for both. Inlined into the
    step kernel (step.fabric_iterate), as kick_rows is (its docstring says why).
    """
    rec = RowRecords(phys.nodes, phys.yarns, phys.material, phys.field)
    _row_block(int64(0), phys.nodes.ny, rec, prev, sin, sout, work, t1, phi, dt, rowbuf)
    _row_sums(work.err_num, work.err_den, phys.nodes.rows, work.row_sums)


@njit(_nrt=True)  # never cached on its own: see fused_iterate_threads' docstring
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
def _rotate_row(nb, count, inv_mass, charge, uni, sourced, nf, x, tau, v, vat, buf):
    """Turn the velocities of `count` nodes from node nb, v[r + c, col + i] for node nb + i
    (vat = (r, col): a state's velocities, or rows of the row buffer), by the magnetic force
    alone for a time tau: dv/dt = (q/m) v × B(x), B constant over tau (the field as
    fields.uniform_field gives it, or the node fields nf of a field with sources).

    Boris's rotation v' = v + v × t, v ← v + v' × 2t/(1 + |t|²) with t = tan(θ/2) B̂·sign(q)
    turns by exactly θ = |q B/m| tau (the standard t = q B tau/(2m) turns by 2 atan(θ/2)): the
    cyclotron frequency is exact, |v| kept to round-off. t = (q B tau/(2m))·tan(y)/y with y =
    θ/2, the ratio from tan_ratio where every node's y² < TAN_SERIES_LIMIT (branch-free, so
    vectorised), else each node by Rodrigues's formula (rodrigues: any angle). Clamped
    nodes (1/m = 0) and uncharged ones are left exactly as they are. Returns the largest y²
    of the row.

    Inlined (Numba IR), as _row_force, and given arrays and numbers, not records: Numba
    references every array of a record bound to a function's argument on entry and releases
    it on exit (an atomic increment and decrement each). Called per row with the Physics
    record, and then inlined with its sub-records, that was ~60 arrays a row and 21 % of a
    central-difference step (`perf`). Row views cost the same (each is referenced and
    released): the arrays are indexed directly with unsigned indices (_tensions says why).
    """
    r, col = vat
    for i in range(count):
        u = uint64(i)
        k = uint64(nb + i)
        _e, b = node_field_of(uni, sourced, nf, nb + i, (x[0, k], x[1, k], x[2, k]))
        s = 0.5 * tau * charge[k] * inv_mass[k]
        buf[ROW_ROTATION, u] = s * b[0]
        buf[ROW_ROTATION + 1, u] = s * b[1]
        buf[ROW_ROTATION + 2, u] = s * b[2]
    for i in range(count):
        u = uint64(i)
        buf[ROW_PROJECTION, u] = (buf[ROW_ROTATION, u] * buf[ROW_ROTATION, u]
                                  + buf[ROW_ROTATION + 1, u] * buf[ROW_ROTATION + 1, u]
                                  + buf[ROW_ROTATION + 2, u] * buf[ROW_ROTATION + 2, u])
    # the largest apart (_buf_max: a maximum in the loop above would not vectorise)
    big = _buf_max(buf, ROW_PROJECTION, count)
    if big == 0.0:
        return big
    if big < TAN_SERIES_LIMIT:
        for i in range(count):
            u = uint64(i)
            g = tan_ratio(buf[ROW_PROJECTION, u])
            buf[ROW_ROTATION, u] *= g
            buf[ROW_ROTATION + 1, u] *= g
            buf[ROW_ROTATION + 2, u] *= g
        for i in range(count):
            u = uint64(i)
            w = uint64(col + i)
            ax, ay, az = buf[ROW_ROTATION, u], buf[ROW_ROTATION + 1, u], buf[ROW_ROTATION + 2, u]
            k = 2.0 / (1.0 + (ax * ax + ay * ay + az * az))
            sx, sy, sz = k * ax, k * ay, k * az
            vx, vy, vz = v[r, w], v[r + 1, w], v[r + 2, w]
            ux = vx + (vy * az - vz * ay)
            uy = vy + (vz * ax - vx * az)
            uz = vz + (vx * ay - vy * ax)
            v[r, w] = vx + (uy * sz - uz * sy)
            v[r + 1, w] = vy + (uz * sx - ux * sz)
            v[r + 2, w] = vz + (ux * sy - uy * sx)
        return big
    for i in range(count):
        if buf[ROW_PROJECTION, uint64(i)] == 0.0:
            continue
        k = uint64(nb + i)
        w = uint64(col + i)
        _e, b = node_field_of(uni, sourced, nf, nb + i, (x[0, k], x[1, k], x[2, k]))
        rv = rodrigues((v[r, w], v[r + 1, w], v[r + 2, w]), charge[k] * inv_mass[k], b, tau)
        v[r, w] = rv[0]
        v[r + 1, w] = rv[1]
        v[r + 2, w] = rv[2]
    return big


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


@njit(cache=True, inline="always")
def _buf_max(buf, r, count):
    """max(0, buf[r, :count]) of non-negative values, over integer keys (reductions.py: a
    maximum of doubles is not vectorised)."""
    k = order_key(0.0)
    for i in range(count):
        k = max(k, order_key(buf[r, uint64(i)]))
    return from_key(k)


@njit(cache=True, inline="always")
def _buf_total(buf, r, count):
    """Σ buf[r, :count] in a fixed order: four interleaved partial sums, as _row_sums, the
    first taking the last count mod 4 (reductions.lane_sums: in a vector register)."""
    s0, s1, s2, s3 = lane_sums(buf, r, count)
    for i in range(count - count % 4, count):
        s0 += buf[r, uint64(i)]
    return (s0 + s1) + (s2 + s3)


@njit(cache=True, _nrt=False, error_model=ROW_ERRORS)
def _drift_block(j0, j1, phys, sin, sout, work, t0, dt, buf):
    """Rows j0 ≤ j < j1 of the first half of a central-difference step (explicit.central_step):
    v⁻ = v + h/(2m) f (f without its magnetic part), v_{n+½} = v⁻ turned by B(x_n, t0) for h/2,
    x_{n+1} = x_n + h v_{n+½} (a clamped node stays), into sout.v and sout.x; each row's field
    and gravity work of the half kick (h/2 f·v̄) into work.row_sums, and with bulk viscosity
    (sin.fv the viscous part of f) the viscous force's."""
    nodes, fld = phys.nodes, phys.field
    uni, sourced = uniform_field(fld)
    nf = work.node_field
    sums = work.row_sums
    grav = (fld.gravity[0], fld.gravity[1], fld.gravity[2])
    half = 0.5 * dt
    inv_mass, mass, charge = nodes.inv_mass, nodes.mass, nodes.charge
    x0, v0, f0, e0, fv0 = sin.x, sin.v, sin.f, sin.e, sin.fv
    viscous = phys.yarns.damping.size > 0
    x1, v1 = sout.x, sout.v
    vm = ROW_VEL_EXPLICIT
    # arrays indexed directly with unsigned indices, no row views (_tensions says why)
    for j in range(j0, j1):
        nb = nodes.rows[j, ROW_NODE]
        nx = nodes.rows[j, ROW_COUNT]
        for i in range(nx):
            u = uint64(i)
            k = uint64(nb + i)
            # the State's force is the whole ψ(t) (as the φ-scheme's): without q v × B
            _e, b = node_field_of(uni, sourced, nf, nb + i, (x0[0, k], x0[1, k], x0[2, k]))
            fm = magnetic_force(charge[k], (v0[0, k], v0[1, k], v0[2, k]), b)
            hk = half * inv_mass[k]
            buf[vm, u] = v0[0, k] + hk * (f0[0, k] - fm[0])
            buf[vm + 1, u] = v0[1, k] + hk * (f0[1, k] - fm[1])
            buf[vm + 2, u] = v0[2, k] + hk * (f0[2, k] - fm[2])
        for i in range(nx):
            u = uint64(i)
            k = uint64(nb + i)
            bx = 0.5 * (v0[0, k] + buf[vm, u])
            by = 0.5 * (v0[1, k] + buf[vm + 1, u])
            bz = 0.5 * (v0[2, k] + buf[vm + 2, u])
            buf[ROW_INV_DENOM, u] = half * charge[k] * ((e0[0, k] * bx + e0[1, k] * by)
                                                        + e0[2, k] * bz)
            buf[ROW_DT_OVER_MASS, u] = half * mass[k] * ((grav[0] * bx + grav[1] * by)
                                                         + grav[2] * bz)
        sums[SUM_WORK_FIELD, j] = _buf_total(buf, ROW_INV_DENOM, nx)
        sums[SUM_WORK_GRAVITY, j] = _buf_total(buf, ROW_DT_OVER_MASS, nx)
        if viscous:
            for i in range(nx):
                u = uint64(i)
                k = uint64(nb + i)
                buf[ROW_VISC_WORK, u] = half * (
                    (fv0[0, k] * (0.5 * (v0[0, k] + buf[vm, u]))
                     + fv0[1, k] * (0.5 * (v0[1, k] + buf[vm + 1, u])))
                    + fv0[2, k] * (0.5 * (v0[2, k] + buf[vm + 2, u])))
            sums[SUM_WORK_VISCOUS, j] = _buf_total(buf, ROW_VISC_WORK, nx)
        _rotate_row(nb, nx, inv_mass, charge, uni, sourced, nf, x0, half, buf, (vm, 0), buf)
        for c in range(3):
            for i in range(nx):
                u = uint64(i)
                k = uint64(nb + i)
                w = buf[vm + c, u]
                v1[c, k] = w
                x1[c, k] = x0[c, k] + (dt if inv_mass[k] > 0.0 else 0.0) * w


@njit(cache=True, _nrt=False, error_model=ROW_ERRORS)
def _kick_block(j0, j1, phys, sin, sout, work, t1, dt, buf):
    """Rows j0 ≤ j < j1 of the second half of a central-difference step: the force at sout.x
    and t1 (_row_force, trial damage from sin.alpha into sout.alpha: the step's one force
    evaluation), consumed at once by the node update v_{n+½} (sout.v, after contact) turned by
    B(x_{n+1}, t1) for h/2, then v_{n+1} = v⁺ + h/(2m) f; sout.f = f + q v_{n+1} × B and sout.e
    = E. Per row into work.row_sums: the half kick's field and gravity work, the projection
    term of the contact candidates (explicit.central_step), Σ|v_{n+1}|², the largest
    2 Σ k_t/m of its nodes (the Gershgorin bound of ω² of explicit.stable_step) or, where
    larger, their gyration's (2 ω_c/GYRATION_TURN)² (records.SUM_STIFFNESS), and its share
    of the fabric diagnostics of the end state (records.SUM_DIAG; the frame in work.frame):
    the nodes and segments are in the cache here, so the history record costs no pass of its
    own."""
    nodes, yarns, mat, fld = phys.nodes, phys.yarns, phys.material, phys.field
    uni, sourced = uniform_field(fld)
    nf = work.node_field
    # the viscous rate from work.visc_base: x_n, or where contact placed a node, where its
    # velocity after contact puts it a step back (records.Work.visc_base)
    arr = RowArrays(nodes.rows, nodes.mass, nodes.charge, yarns.inv_rest2, yarns.rest_length,
                    yarns.stiffness, sin.alpha, sout.alpha, work.damage_thr, nf, yarns.damping,
                    work.visc_base, sin.strain, sout.strain, yarns.averaging_rate, dt)
    viscous = yarns.damping.size > 0
    mode = TANGENT | STATS | (VISCOUS if viscous else 0)
    inv_dt = 1.0 / dt if dt > 0.0 else 0.0
    fvo = sout.fv
    sums = work.row_sums
    flag, xbuf, v_pre = work.flag, work.xbuf, work.v_pre
    grav = (fld.gravity[0], fld.gravity[1], fld.gravity[2])
    half = 0.5 * dt
    gyration = 64.0 / (GYRATION_TURN * GYRATION_TURN) * inv_dt * inv_dt
    x1, v1 = sout.x, sout.v
    zref = nodes.x0
    frame = work.frame
    cx, cy, cz = frame[0, 0], frame[0, 1], frame[0, 2]
    dirx, diry, dirz = frame[1, 0], frame[1, 1], frame[1, 2]
    ru, rd = _block_start(j0, phys, x1, sin, sout, work, buf, mode, dt,
                          work.visc_base)
    inv_mass, mass, charge = nodes.inv_mass, nodes.mass, nodes.charge
    fo, eo = sout.f, sout.e
    rf = ROW_FORCE
    # arrays indexed directly with unsigned indices, no row views (_tensions says why)
    for j in range(j0, j1):
        seg_stats = _row_force(j, arr, mat, uni, sourced, grav, x1, buf, ru, rd, mode, inv_dt)
        nb = nodes.rows[j, ROW_NODE]
        nx = nodes.rows[j, ROW_COUNT]
        # the Gershgorin bound: 2 Σ k_t/m over the node's four segments
        rku, rkd = ru + 3, rd + 3
        for i in range(nx):
            u = uint64(i)
            ksum = (buf[RKW, u] + buf[RKW, u + uint64(1)]) + (buf[rku, u] + buf[rkd, u])
            buf[ROW_PROJECTION, u] = 2.0 * ksum * inv_mass[uint64(nb + i)]
        # the largest apart, as in _rotate_row (ROW_PROJECTION is scratch here)
        sums[SUM_STIFFNESS, j] = _buf_max(buf, ROW_PROJECTION, nx)
        # the work of the yarn force over the placement of the candidates (central_step); the
        # field's and gravity's are booked from the kicks' velocities, which see no placement
        proj = 0.0
        # the row's candidates counted first, in a loop that vectorises: most rows have none
        held = 0
        for i in range(nx):
            held += 1 if flag[uint64(nb + i)] != 0 else 0
        for i in range(nx if held != 0 else 0):
            n = nb + i
            if flag[n] != 0:
                ee, _b = node_field_of(uni, sourced, nf, n, (x1[0, n], x1[1, n], x1[2, n]))
                for c in range(3):
                    fy = buf[rf + c, i] - (charge[n] * ee[c] + mass[n] * grav[c])
                    if viscous:
                        # the yarns' elastic force: the viscous one has no energy that a
                        # placement changes (its work is the kicks', records.SUM_WORK_VISCOUS)
                        fy -= buf[ROW_VISC_FORCE + c, i]
                    proj += fy * (x1[c, n] - xbuf[c, n] - half * (v1[c, n] - v_pre[c, n]))
        sums[SUM_PROJECTION, j] = proj
        big = _rotate_row(nb, nx, inv_mass, charge, uni, sourced, nf, x1, half, v1, (0, nb), buf)
        # the gyration's ω² beside the yarns' (records.GYRATION_TURN): big is the row's largest
        # (ω_c h/4)², turned for h/2, so (2 ω_c/GYRATION_TURN)² = big · gyration
        sums[SUM_STIFFNESS, j] = max(sums[SUM_STIFFNESS, j], gyration * big)
        # the second half kick in short loops over few arrays, so that each vectorises (one loop
        # writing v1, fo, eo and the row buffer did not): v_{n+1} into the buffer's rotation
        # rows (free once _rotate_row is done) with the half kick's field and gravity work and
        # |v_{n+1}|², then v1, f and E from there
        nv = ROW_ROTATION
        for i in range(nx):
            u = uint64(i)
            k = uint64(nb + i)
            ee, _b = node_field_of(uni, sourced, nf, nb + i, (x1[0, k], x1[1, k], x1[2, k]))
            hk = half * inv_mass[k]
            vx, vy, vz = v1[0, k], v1[1, k], v1[2, k]
            nvx = vx + hk * buf[rf, u]
            nvy = vy + hk * buf[rf + 1, u]
            nvz = vz + hk * buf[rf + 2, u]
            bx = 0.5 * (vx + nvx)
            by = 0.5 * (vy + nvy)
            bz = 0.5 * (vz + nvz)
            buf[ROW_INV_DENOM, u] = half * charge[k] * ((ee[0] * bx + ee[1] * by) + ee[2] * bz)
            buf[ROW_DT_OVER_MASS, u] = half * mass[k] * ((grav[0] * bx + grav[1] * by)
                                                         + grav[2] * bz)
            buf[ROW_VEL_EXPLICIT, u] = (nvx * nvx + nvy * nvy) + nvz * nvz
            buf[nv, u] = nvx
            buf[nv + 1, u] = nvy
            buf[nv + 2, u] = nvz
            if viscous:
                # the viscous force's work in this half kick (the force for the next one below)
                buf[ROW_VISC_WORK, u] = half * ((buf[ROW_VISC_FORCE, u] * bx
                                                 + buf[ROW_VISC_FORCE + 1, u] * by)
                                                + buf[ROW_VISC_FORCE + 2, u] * bz)
        for c in range(3):
            for i in range(nx):
                v1[c, uint64(nb + i)] = buf[nv + c, uint64(i)]
        for i in range(nx):
            u = uint64(i)
            k = uint64(nb + i)
            ee, b = node_field_of(uni, sourced, nf, nb + i, (x1[0, k], x1[1, k], x1[2, k]))
            fm = magnetic_force(charge[k], (buf[nv, u], buf[nv + 1, u], buf[nv + 2, u]), b)
            fo[0, k] = buf[rf, u] + fm[0]
            fo[1, k] = buf[rf + 1, u] + fm[1]
            fo[2, k] = buf[rf + 2, u] + fm[2]
            eo[0, k] = ee[0]
            eo[1, k] = ee[1]
            eo[2, k] = ee[2]
        if viscous:
            for c in range(3):
                for i in range(nx):
                    fvo[c, uint64(nb + i)] = buf[ROW_VISC_FORCE + c, uint64(i)]
        sums[SUM_WORK_FIELD, j] = _buf_total(buf, ROW_INV_DENOM, nx)
        sums[SUM_WORK_GRAVITY, j] = _buf_total(buf, ROW_DT_OVER_MASS, nx)
        sums[SUM_SPEED, j] = _buf_total(buf, ROW_VEL_EXPLICIT, nx)
        if viscous:
            sums[SUM_WORK_VISCOUS, j] = _buf_total(buf, ROW_VISC_WORK, nx)
        _node_stats(nb, nx, mass, x1, v1, zref, (cx, cy, cz, dirx, diry, dirz), buf, sums, j)
        sums[SUM_DIAG + DIAG_STRETCH, j] = seg_stats[0]
        sums[SUM_DIAG + DIAG_STRAIN, j] = seg_stats[1]
        sums[SUM_DIAG + DIAG_BROKEN, j] = seg_stats[2]
        sums[SUM_DIAG + DIAG_MIN_ALPHA, j] = seg_stats[3]
        ru, rd = rd, ru


@njit(cache=True, inline="always")
def _node_stats(nb, count, mass, x, v, xref, frame, buf, sums, j):
    """The fabric diagnostics' share of `count` nodes from node nb (mass, positions x,
    velocities v, |v|² in buf[ROW_VEL_EXPLICIT]) into sums[SUM_DIAG + DIAG_*, j]: kinetic
    energy, momentum and angular momentum about the origin (sums in _buf_total's order),
    largest |z − z_ref| (xref: the reference positions), the extent along the flight
    direction from the body centre and the fastest speeds against and along it (frame:
    centre, then direction); diagnostics.fabric_diagnostics's terms. Then, into
    sums[SUM_MOTION:SUM_MOTION + 7, j], the largest |v|² and the smallest and largest of
    each velocity component (the no-tunnelling limit's). Unsigned indices, no views."""
    cx, cy, cz, dx, dy, dz = frame
    rd = ROW_DIAG
    for i in range(count):
        u = uint64(i)
        k = uint64(nb + i)
        mi = mass[k]
        vx, vy, vz = v[0, k], v[1, k], v[2, k]
        px, py, pz = x[0, k], x[1, k], x[2, k]
        buf[rd, u] = 0.5 * mi * buf[ROW_VEL_EXPLICIT, u]
        buf[rd + 1, u] = mi * vx
        buf[rd + 2, u] = mi * vy
        buf[rd + 3, u] = mi * vz
        buf[rd + 4, u] = mi * (py * vz - pz * vy)
        buf[rd + 5, u] = mi * (pz * vx - px * vz)
        buf[rd + 6, u] = mi * (px * vy - py * vx)
    # the extremes over integer keys (reductions.py): the loop vectorises, where twelve maxima
    # and minima of doubles were one scalar compare after another (~15 % of the kick)
    low = order_key(math.inf)
    high = order_key(-math.inf)
    kdefl = kfast = order_key(0.0)
    kamin, kamax, kapp, krec = low, high, high, high
    klox = kloy = kloz = low
    khix = khiy = khiz = high
    for i in range(count):
        k = uint64(nb + i)
        vx, vy, vz = v[0, k], v[1, k], v[2, k]
        kdefl = max(kdefl, order_key(abs(x[2, k] - xref[2, k])))
        ks = order_key((x[0, k] - cx) * dx + (x[1, k] - cy) * dy + (x[2, k] - cz) * dz)
        kamin = min(kamin, ks)
        kamax = max(kamax, ks)
        vd = vx * dx + vy * dy + vz * dz
        kapp = max(kapp, order_key(-vd))
        krec = max(krec, order_key(vd))
        kfast = max(kfast, order_key(buf[ROW_VEL_EXPLICIT, uint64(i)]))
        kx, ky, kz = order_key(vx), order_key(vy), order_key(vz)
        klox = min(klox, kx)
        kloy = min(kloy, ky)
        kloz = min(kloz, kz)
        khix = max(khix, kx)
        khiy = max(khiy, ky)
        khiz = max(khiz, kz)
    d = SUM_DIAG
    for c in range(7):
        sums[d + DIAG_KE + c, j] = _buf_total(buf, rd + c, count)
    sums[d + DIAG_DEFLECTION, j] = from_key(kdefl)
    sums[d + DIAG_AHEAD_MIN, j] = from_key(kamin)
    sums[d + DIAG_AHEAD_MAX, j] = from_key(kamax)
    sums[d + DIAG_APPROACH_MAX, j] = from_key(kapp)
    sums[d + DIAG_RECEDE_MAX, j] = from_key(krec)
    m = SUM_MOTION
    sums[m, j] = from_key(kfast)
    sums[m + 1, j] = from_key(klox)
    sums[m + 2, j] = from_key(kloy)
    sums[m + 3, j] = from_key(kloz)
    sums[m + 4, j] = from_key(khix)
    sums[m + 5, j] = from_key(khiy)
    sums[m + 6, j] = from_key(khiz)


@njit(cache=True, inline="always")
def drift_rows(phys, sin, sout, work, t0, dt, rowbuf):
    """The first half of a central-difference step for every row (_drift_block), serially;
    rowbuf (ROWBUF_ROWS, nx + 1). Row sums in work.row_sums.

    Inlined where compiled code calls it (explicit.central_step), as kick_rows is: a
    dispatcher of its own would be one more library whose final module re-optimises and emits
    the whole of _drift_block again (2.1 s of a cold start). Every row in one block, as
    kick_rows."""
    rec = RowRecords(phys.nodes, phys.yarns, phys.material, phys.field)
    _drift_block(int64(0), phys.nodes.ny, rec, sin, sout, work, t0, dt, rowbuf)


@njit(cache=True, inline="always")
def kick_rows(phys, sin, sout, work, t1, dt, rowbuf):
    """The force evaluation and second half of a central-difference step for every row
    (_kick_block), serially, every row in one block; rowbuf (ROWBUF_ROWS, nx + 1). Row sums in
    work.row_sums. The same numbers as kick_rows_threads' blocks of ROWS_PER_BLOCK rows (a
    block's first row recomputes the fill tensions of the row below as that row computes
    them), and one call rather than one a block: each call references and releases every
    array of the records it is given (~100, an atomic operation each) and recomputes a row of
    fill tensions: in blocks of 16 rows the serial step on paper-field's 100 × 100 sheet took
    2–3 % longer (`python benchmarks/step_time.py --against ...`).

    Inlined where compiled code calls it (explicit.central_step): compiled on its own, its
    library's final module re-optimises and emits the whole of _kick_block once more (3.3 s of
    a cold start's critical path), so the run never calls it from Python either
    (sim.state.update_forces calls _kick_block itself, one block). Called from Python
    (the benchmarks), it compiles as any kernel."""
    rec = RowRecords(phys.nodes, phys.yarns, phys.material, phys.field)
    # int64(0): a literal 0 would type (and compile) _kick_block a second time
    _kick_block(int64(0), phys.nodes.ny, rec, sin, sout, work, t1, dt, rowbuf)


@njit(_nrt=True)  # never cached on its own, as fused_iterate_threads
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


@njit(_nrt=True)  # never cached on its own, as fused_iterate_threads
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
