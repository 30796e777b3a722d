"""Yarn tensions on the regular grid: relaxed KSV (2.3-2.5) or Fung (section 6), damage (2.6).

The tension vector of segment s is the force its first node feels, t_s = (S·A0/L0)·d with
d = x_b − x_a: from ψ = U·S·A0 along d/L and U = L/L0, so no square root is needed for the force.
Segments are numbered warp first (s = j·(nx−1) + i joins nodes a = j·nx + i and a + 1), then
fill (s = warp_count + a joins a and a + nx). The grid loops live in nodes.py.
"""

import math

from numba import njit

MATERIAL_FUNG = 1


@njit(cache=True, inline="always")
def _stress_factor(u2, kind, fung_h):
    """S/𝔼 (KSV) or S/c (Fung) at stretch² u2, relaxed: 0 for U ≤ 1."""
    e = 0.5 * max(u2 - 1.0, 0.0)
    if kind == MATERIAL_FUNG:
        return fung_h * e * math.exp(0.5 * fung_h * e * e)
    return e


@njit(cache=True, inline="always")
def strain_energy_density(u2, kind, fung_h):
    """Stored energy per unit reference volume divided by the modulus (𝔼 or c), relaxed."""
    if u2 <= 1.0:
        return 0.0
    e = 0.5 * (u2 - 1.0)
    if kind == MATERIAL_FUNG:
        return math.expm1(0.5 * fung_h * e * e)
    return 0.5 * e * e
