"""Magnetoquasistatic fields of circular current loops (the building block of coils).

A loop of radius a carrying the current I, at cylindrical coordinates (ρ, z) about its centre
and normal (z along the normal, right-handed with the current):

    k² = 4aρ / ((a + ρ)² + z²),
    B_z = μ₀I/(2π) [K + (a² − ρ² − z²)/((a − ρ)² + z²) E] / √((a + ρ)² + z²),
    B_ρ = μ₀I/(2π) z/ρ [−K + (a² + ρ² + z²)/((a − ρ)² + z²) E] / √((a + ρ)² + z²),
    A_φ = μ₀I/(πk) √(a/ρ) [(1 − k²/2) K − E],

K = K(k²), E = E(k²) the complete elliptic integrals (parameter m = k²), computed by the
arithmetic–geometric mean, (1 − k²/2)K − E without cancellation. Near the axis (ρ < 10⁻⁴ a) the
first terms of the series in ρ are used (B_ρ and A_φ vanish on the axis like ρ; the series'
relative error there is below (ρ/a)² ≈ 1e-8, the cancellation in B_ρ's closed form just above it
about 1e-8). The field diverges at the wire: within the wire
radius r_w of its centre line the field is that of the wire's surface scaled by d/r_w (d the
distance to the centre line), as inside a straight round conductor carrying the current
uniformly, continuous at d = r_w. These functions take unit current (I = 1 A); sources scale by
I(t) and the induced electric field is −(dI/dt) A_φ φ̂.
"""

import math

from numba import njit, prange

MU0 = 4e-7 * math.pi
"""Vacuum permeability [T m/A] (the SI value before 2019; the 2019 value differs by 5e-10)."""


@njit(cache=True)
def elliptic_ke(m):
    """Complete elliptic integrals K(m), E(m) of the parameter m = k² ∈ [0, 1) by the
    arithmetic–geometric mean (quadratic convergence: round-off in a handful of steps), and
    (1 − m/2) K − E = K Σ_{n≥1} 2^{n−1} c_n², computed without the cancellation of the
    difference (the vector potential near the axis needs it)."""
    a = 1.0
    b = math.sqrt(1.0 - m)
    c2 = m  # c_0²
    rest = 0.0  # Σ_{n≥1} 2^{n−1} c_n²
    power = 0.5
    c_sq = m
    for _ in range(40):
        an = 0.5 * (a + b)
        bn = math.sqrt(a * b)
        # c_n = (a_{n−1} − b_{n−1})/2 = c_{n−1}²/(4 a_n): no cancellation as a and b meet
        c_sq = (c_sq / (4.0 * an)) ** 2
        power *= 2.0
        term = power * c_sq
        rest += term
        a, b = an, bn
        if term <= 1e-17 * rest or c_sq == 0.0:
            break
    k = math.pi / (2.0 * a)
    return k, k * (1.0 - 0.5 * c2 - rest), k * rest


@njit(cache=True)
def _loop_exact(a, rho, z):
    """(B_ρ, B_z, A_φ) per ampere of a loop of radius a at (ρ, z), outside the wire."""
    if rho < 1e-4 * a:
        # on-axis series: B_z exact on the axis, B_ρ and A_φ to first order in ρ
        s2 = a * a + z * z
        s = math.sqrt(s2)
        bz = MU0 * a * a / (2.0 * s2 * s)
        br = 3.0 * MU0 * a * a * z * rho / (4.0 * s2 * s2 * s)
        ap = MU0 * a * a * rho / (4.0 * s2 * s)
        return br, bz, ap
    p2 = (a + rho) ** 2 + z * z
    q2 = (a - rho) ** 2 + z * z
    m = 4.0 * a * rho / p2
    kk, ee, diff = elliptic_ke(m)
    p = math.sqrt(p2)
    c = MU0 / (2.0 * math.pi * p)
    bz = c * (kk + (a * a - rho * rho - z * z) / q2 * ee)
    br = c * z / rho * (-kk + (a * a + rho * rho + z * z) / q2 * ee)
    k = math.sqrt(m)
    ap = MU0 / (math.pi * k) * math.sqrt(a / rho) * diff
    return br, bz, ap


@njit(cache=True)
def loop_unit_field(a, wire, rho, z):
    """(B_ρ, B_z, A_φ) per ampere of a loop of radius a and wire radius `wire` at (ρ, z), with
    the inside-the-wire treatment of the module docstring."""
    dr = rho - a
    d = math.sqrt(dr * dr + z * z)
    if d >= wire:
        return _loop_exact(a, rho, z)
    if d == 0.0:
        # the centre line itself: the field of a uniform round conductor vanishes there; the
        # loop's own curvature field is left out with it
        br, bz, ap = _loop_exact(a, a + wire, 0.0)
        return 0.0, 0.0, ap
    # on the wire's surface along the same ray, scaled by d/r_w
    s = wire / d
    br, bz, ap = _loop_exact(a, a + dr * s, z * s)
    f = d / wire
    return br * f, bz * f, ap


WAVE_CONSTANT, WAVE_RAMP, WAVE_DAMPED_SINE, WAVE_TABLE = 0, 1, 2, 3


@njit(cache=True)
def current_at(wave, table, count, t):
    """(I, dI/dt) [A, A/s] of one source's waveform at time t, times its turns.

    wave: [kind, amplitude, start_time, rise_time, frequency, decay_time], amplitude = current ×
    turns (for WAVE_TABLE: turns); table: (points, 2) of (t, I) with `count` points used (kind
    WAVE_TABLE, linear between points, held before the first and after the last)."""
    kind = int(wave[0])
    amp = wave[1]
    start = wave[2]
    if kind == WAVE_CONSTANT:
        return amp, 0.0
    if kind == WAVE_RAMP:
        rise = wave[3]
        if t < start:
            return 0.0, 0.0
        if t < start + rise:
            return amp * (t - start) / rise, amp / rise
        return amp, 0.0
    if kind == WAVE_DAMPED_SINE:
        if t < start:
            return 0.0, 0.0
        u = t - start
        om = 2.0 * math.pi * wave[4]
        decay = math.exp(-u / wave[5])
        s = math.sin(om * u)
        return amp * decay * s, amp * decay * (om * math.cos(om * u) - s / wave[5])
    # table
    if t <= table[0, 0]:
        return amp * table[0, 1], 0.0
    for i in range(1, count):
        if t < table[i, 0]:
            slope = (table[i, 1] - table[i - 1, 1]) / (table[i, 0] - table[i - 1, 0])
            return amp * (table[i - 1, 1] + slope * (t - table[i - 1, 0])), amp * slope
    return amp * table[count - 1, 1], 0.0


@njit(cache=True, inline="always")
def loop_vectors(lp, x):
    """B [T] and vector potential A [T m] per ampere of the loop lp (a Field.loops row: centre,
    unit normal, radius, wire radius) at the point x, as Cartesian 3-tuples: B = B_ρ ρ̂ + B_z n,
    A = A_φ φ̂ with φ̂ = n × ρ̂ (zero on the axis)."""
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
    return ((b_rho * ux + b_ax * nx, b_rho * uy + b_ax * ny, b_rho * uz + b_ax * nz),
            (a_phi * (ny * uz - nz * uy), a_phi * (nz * ux - nx * uz),
             a_phi * (nx * uy - ny * ux)))


@njit(cache=True)
def point_values(loops, group_of, x, out):
    """out (groups, 6) = each group's b and a at the point x, summed over its loops in their
    order. A call of its own: inlined into the parallel loop below, Numba's array analysis
    failed on the tuples."""
    out[:, :] = 0.0
    for m in range(loops.shape[0]):
        bu, au = loop_vectors(loops[m], x)
        o = out[group_of[m]]
        for c in range(3):
            o[c] += bu[c]
            o[3 + c] += au[c]


@njit(cache=True, parallel=True)
def loop_values_on_grid(loops, group_of, origin, step, shape, offset, out):
    """Each group's b [T per unit waveform] and a [T m] at the points origin + (index +
    offset)·step (offset a 3-vector): out (groups, *shape, 6)."""
    nx, ny, nz = shape[0], shape[1], shape[2]
    for i in prange(nx):
        px = origin[0] + (i + offset[0]) * step[0]
        for j in range(ny):
            py = origin[1] + (j + offset[1]) * step[1]
            for k in range(nz):
                pz = origin[2] + (k + offset[2]) * step[2]
                point_values(loops, group_of, (px, py, pz), out[:, i, j, k])
