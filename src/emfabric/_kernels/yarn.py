"""Yarn tensions on the regular grid: relaxed KSV (2.3-2.5) or Fung (section 6), damage (2.6).

The tension vector of segment s is the force its first node feels, t_s = (S·A0/L0)·d with
d = x_b − x_a: from ψ = U·S·A0 along d/L and U = L/L0, so no square root is needed for the force.
"""

import math

from numba import njit

MATERIAL_FUNG = 1


@njit(cache=True, inline="always")
def _tension(x, a, b, s, alpha_c, coef, inv_l02, kind, fung_h, u_crit, rate, t_out, alpha_out):
    dx = x[0, b] - x[0, a]
    dy = x[1, b] - x[1, a]
    dz = x[2, b] - x[2, a]
    u2 = (dx * dx + dy * dy + dz * dz) * inv_l02[s]
    alpha = alpha_c[s]
    # damage, eq. 2.6: irreversible, only past the critical stretch
    if u2 > u_crit * u_crit and rate > 0.0:
        trial = math.exp(-rate * (math.sqrt(u2) - u_crit) / u_crit)
        if trial < alpha:
            alpha = trial
    alpha_out[s] = alpha
    c = 0.0
    # relaxed law: no stress in compression (U <= 1)
    if u2 > 1.0:
        e = 0.5 * (u2 - 1.0)
        if kind == MATERIAL_FUNG:
            c = alpha * coef[s] * fung_h * e * math.exp(0.5 * fung_h * e * e)
        else:
            c = alpha * coef[s] * e
    t_out[0, s] = c * dx
    t_out[1, s] = c * dy
    t_out[2, s] = c * dz


@njit(cache=True)
def yarn_tensions(x, nx, ny, alpha_c, coef, inv_l02, kind, fung_h, u_crit, rate, t_out,
                  alpha_out):
    """Tension vectors t_out (3, seg_count) [N] and trial damage alpha_out at positions x."""
    nw = ny * (nx - 1)
    for j in range(ny):
        for i in range(nx - 1):
            a = j * nx + i
            _tension(x, a, a + 1, j * (nx - 1) + i, alpha_c, coef, inv_l02, kind, fung_h,
                     u_crit, rate, t_out, alpha_out)
    for j in range(ny - 1):
        for i in range(nx):
            a = j * nx + i
            _tension(x, a, a + nx, nw + a, alpha_c, coef, inv_l02, kind, fung_h, u_crit, rate,
                     t_out, alpha_out)


@njit(cache=True)
def strain_energy_density(u2, kind, fung_h):
    """Stored energy per unit reference volume divided by the modulus (𝔼 or c), relaxed."""
    if u2 <= 1.0:
        return 0.0
    e = 0.5 * (u2 - 1.0)
    if kind == MATERIAL_FUNG:
        return math.expm1(0.5 * fung_h * e * e)
    return 0.5 * e * e
