"""The yarn material law, one function each: stretch, stress (relaxed KSV 2.3–2.5 or Fung,
section 6), stored energy, and damage (2.6). Every kernel that needs one of them calls it here.

The tension vector of segment s is the force its first node feels, t_s = (S·A0/L0)·d with
d = x_b − x_a: from ψ = U·S·A0 along d/L and U = L/L0, so no square root is needed for the force.
With ``Yarns.stiffness`` = 𝔼·A0/L0 (or c·A0/L0), t_s = stiffness·α·stress_factor(U²)·d.
"""

import math

from numba import njit, uint64

from emfabric._kernels.records import DAMAGE_BRITTLE, MATERIAL_FUNG
from emfabric._kernels.reductions import SCAN_BLOCK


@njit(cache=True, inline="always")
def stretch_sq(dx, dy, dz, inv_rest2):
    """U² = |d|²/L0² of a segment d = x_b − x_a."""
    return (dx * dx + dy * dy + dz * dz) * inv_rest2


@njit(cache=True, inline="always")
def ksv_stress(u2):
    """Relaxed Kirchhoff–Saint-Venant S/𝔼 = max(U² − 1, 0)/2 (2.3–2.4; no compression)."""
    return 0.5 * max(u2 - 1.0, 0.0)


@njit(cache=True, inline="always")
def fung_stress(u2, fung_h):
    """Relaxed Fung S/c = H·e·exp(H e²/2), e = max(U² − 1, 0)/2 (section 6)."""
    e = 0.5 * max(u2 - 1.0, 0.0)
    return fung_h * e * math.exp(0.5 * fung_h * e * e)


@njit(cache=True, inline="always")
def stress_factor(u2, mat):
    """S/𝔼 (KSV) or S/c (Fung) at stretch² u2 for the Material record mat."""
    if mat.kind == MATERIAL_FUNG:
        return fung_stress(u2, mat.fung_h)
    return ksv_stress(u2)


@njit(cache=True, inline="always")
def tangent_factor(u2, mat):
    """The axial tangent stiffness dT/dL of a yarn at stretch² u2, over its stiffness 𝔼·A0/L0
    (or c·A0/L0) and α: with T = stiffness·α·S/𝔼·L, dT/dL = stiffness·α·(S'·U² + S)/𝔼 where S'
    = dS/dE. KSV: (3U² − 1)/2 above U = 1; Fung: H e^{He²/2}(1 + He²)·U² + S/c. At least the
    value at U = 1 (1, or H for Fung): a slack yarn may be taut within the step. The largest
    eigenvalue of the network's stiffness, and so the explicit stable step, follow from it."""
    if mat.kind == MATERIAL_FUNG:
        return fung_tangent(u2, mat.fung_h)
    return ksv_tangent(u2)


@njit(cache=True, inline="always")
def ksv_tangent(u2):
    """tangent_factor of relaxed KSV: (3U² − 1)/2, at least 1."""
    return max(1.0, 0.5 * (3.0 * u2 - 1.0))


@njit(cache=True, inline="always")
def fung_tangent(u2, fung_h):
    """tangent_factor of relaxed Fung."""
    e = 0.5 * max(u2 - 1.0, 0.0)
    h = fung_h
    g = math.exp(0.5 * h * e * e)
    return h * g * (1.0 + h * e * e) * max(u2, 1.0) + h * e * g


@njit(cache=True, inline="always")
def ksv_energy(u2):
    """Relaxed KSV stored energy per unit reference volume over 𝔼: e²/2 above U = 1."""
    if u2 <= 1.0:
        return 0.0
    e = 0.5 * (u2 - 1.0)
    return 0.5 * e * e


@njit(cache=True, inline="always")
def fung_energy(u2, fung_h):
    """Relaxed Fung stored energy per unit reference volume over c: exp(H e²/2) − 1 above
    U = 1."""
    if u2 <= 1.0:
        return 0.0
    e = 0.5 * (u2 - 1.0)
    return math.expm1(0.5 * fung_h * e * e)


@njit(cache=True, inline="always")
def strain_energy_density(u2, mat):
    """Stored energy per unit reference volume divided by the modulus (𝔼 or c), relaxed."""
    if mat.kind == MATERIAL_FUNG:
        return fung_energy(u2, mat.fung_h)
    return ksv_energy(u2)


@njit(cache=True, _nrt=True)
def damage_thresholds(alpha, mat, fail2, out, done):
    """For each segment, the stretch² above which damage_above() can give less than its
    committed α. Eq. 2.6: α falls only where exp(−λ(U − U_c)/U_c) < α, i.e. U > U_c (1 − ln α /
    λ) — the largest stretch the segment has reached past U_c; a relative margin of 1e-9 below
    it keeps every result of damage() to the bit (near the threshold it is still evaluated).
    Brittle: the segment's stretch² at break fail2[s] while it is intact. `done` holds the α
    each threshold in `out` belongs to: only segments whose α differs are recomputed (a
    logarithm each; most steps change few α)."""
    u_crit = mat.critical_stretch
    rate = mat.damage_rate
    brittle = mat.damage_law == DAMAGE_BRITTLE
    count = alpha.shape[0]
    for b0 in range(0, count, SCAN_BLOCK):
        b1 = min(count, b0 + SCAN_BLOCK)
        # the block's segments whose α changed, counted in a loop that vectorises (most steps
        # change none: reductions.SCAN_BLOCK)
        changed = 0
        for s in range(b0, b1):
            changed += 1 if alpha[uint64(s)] != done[uint64(s)] else 0
        if changed != 0:
            _block_thresholds(b0, b1, alpha, u_crit, rate, brittle, fail2, out, done)


@njit(cache=True, inline="always")
def _block_thresholds(b0, b1, alpha, u_crit, rate, brittle, fail2, out, done):
    """damage_thresholds of segments b0 ≤ s < b1."""
    for s in range(b0, b1):
        a = alpha[s]
        if a == done[s]:
            continue
        done[s] = a
        if brittle:
            out[s] = fail2[s] if a > 0.0 else math.inf
        elif not rate > 0.0 or not a > 0.0:
            out[s] = math.inf  # no damage law, or broken: α cannot change
        elif a >= 1.0:
            out[s] = u_crit * u_crit  # intact: damage()'s own test
        else:
            u = u_crit * (1.0 - math.log(a) / rate)
            out[s] = u * u * (1.0 - 1e-9)


@njit(cache=True, inline="always")
def damage_above(alpha, u2, thr2, mat):
    """The trial damage of a segment at stretch² u2 from its committed α, where the stretch² thr2
    (damage_thresholds) says it can change, else the committed alpha: eq. 2.6 (damage()), or
    brittle rupture, α = 0 once the stretch passes the segment's stretch at break."""
    if u2 > thr2:
        if mat.damage_law == DAMAGE_BRITTLE:
            return 0.0
        return damage(alpha, u2, mat)
    return alpha


@njit(cache=True, inline="always")
def damage(alpha, u2, mat):
    """Damage α after a stretch² u2, from the committed α (eq. 2.6): irreversible, only past the
    critical stretch U_c, α = min(α, exp(−λ (U − U_c)/U_c))."""
    u_crit = mat.critical_stretch
    rate = mat.damage_rate
    if u2 > u_crit * u_crit and rate > 0.0:
        return min(alpha, math.exp(-rate * (math.sqrt(u2) - u_crit) / u_crit))
    return alpha
