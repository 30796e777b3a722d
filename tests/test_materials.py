"""Constitutive laws (2.3–2.5, section 6) and the damage law (2.6) at known stretches."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from emfabric._kernels.nodes import ROWBUF_ROWS
from emfabric._kernels.records import (
    MATERIAL_FUNG,
    SHAPE_SPHERE,
    Body,
    Contact,
    Field,
    Material,
    Physics,
    StateArrays,
    Yarns,
    grid_nodes,
    make_work,
)
from emfabric._kernels.step import fabric_iterate

E_MOD, A0, L0 = 126e9, math.pi * 0.000185**2, 0.01


def _node_forces(x, nx, ny, coef, rest_w, rest_f, alpha, kind=0, fung_h=0.0, u_crit=10.0,
                 rate=0.0):
    """Yarn force on every node and the trial damage, from the production kernel (Δt = 0)."""
    n, s = nx * ny, ny * (nx - 1) + (ny - 1) * nx
    rest = np.concatenate([np.full(ny * (nx - 1), rest_w), np.full((ny - 1) * nx, rest_f)])
    # the kernel reads only the stiffness 𝔼A0/L0 (coef) of the yarn record
    yarns = Yarns(np.zeros((s, 2), np.int64), rest, 1 / rest**2, coef, coef * rest / A0, A0,
                  np.array([0, s]))
    phys = Physics(
        grid_nodes(nx, ny, x.copy(), np.ones(n), np.ones(n), np.zeros(n)),
        yarns,
        Material(kind, fung_h, u_crit, rate, 0.5),
        Field(np.zeros(3), np.zeros(3), 0, 0.0, np.zeros(3)),
        Body(False, SHAPE_SPHERE, 0.0, 1.0, np.eye(3), np.zeros((0, 3)), np.zeros(0),
             np.zeros(3)),
        Contact(0.0, 0.0),
    )
    start = StateArrays(x, np.zeros((3, n)), np.zeros((3, n)), alpha, np.zeros((8, 3)))
    f1, a_out = np.empty((3, n)), np.empty(s)
    work = make_work(n, ny, s)
    work.flag[:] = 1  # no error measure
    out = StateArrays(np.empty((3, n)), np.empty((3, n)), f1, a_out, np.zeros((8, 3)))
    fabric_iterate(phys, x, start, out, work, np.empty((ROWBUF_ROWS, nx + 1)), None, 0.0, 1.0,
                   0.0)
    return f1, a_out


def _pair_tension(stretch, kind=0, fung_h=0.0, modulus=E_MOD, alpha=1.0, u_crit=1.03,
                  rate=0.0):
    """Force on node 0 of a 2×2 grid whose bottom warp segment (0–1) has the given stretch;
    the other three yarns are at their rest length (no force)."""
    x = np.zeros((3, 4))
    x[0] = [0.0, stretch * L0, 0.0, stretch * L0]
    x[1] = [0.0, 0.0, L0, L0]
    coef = np.full(4, modulus * A0 / L0)
    coef[1] = 0.0  # the top warp yarn (2–3) carries nothing
    f, a_out = _node_forces(x, 2, 2, coef, L0, L0, np.full(4, alpha), kind, fung_h, u_crit,
                            rate)
    return f[:, 0], a_out[0]


@pytest.mark.parametrize("u", [1.001, 1.02, 1.05, 1.3])
def test_ksv_force_at_known_stretch(u):
    """ψ = U·S·A0 with S = 𝔼 (U²−1)/2, pulling node 0 towards node 1 (eq. 2.4)."""
    t, _ = _pair_tension(u)
    expected = u * E_MOD * (u * u - 1) / 2 * A0
    assert t[0] == pytest.approx(expected, rel=1e-12)
    assert t[1] == 0.0 and t[2] == 0.0


@pytest.mark.parametrize("u", [0.5, 0.9, 0.999999, 1.0])
def test_no_force_in_compression(u):
    """The relaxed law carries no compression: S = 0 for U ≤ 1."""
    t, _ = _pair_tension(u)
    assert np.all(t == 0.0)


@pytest.mark.parametrize("u", [1.01, 1.1])
def test_fung_force_at_known_stretch(u):
    """Fung (section 6): S = c·H·E·exp(H E²/2)."""
    c, h = 2e8, 50.0
    t, _ = _pair_tension(u, kind=MATERIAL_FUNG, fung_h=h, modulus=c)
    e = (u * u - 1) / 2
    assert t[0] == pytest.approx(u * c * h * e * math.exp(h * e * e / 2) * A0, rel=1e-12)


@pytest.mark.parametrize("u,rate", [(1.02, 0.1), (1.06, 0.1), (1.06, 50.0), (1.5, 2.0)])
def test_damage_law(u, rate):
    """α = min(α_prev, exp(−λ (U − U_crit)/U_crit)) scales the stress (eqs. 2.5–2.6)."""
    t, alpha = _pair_tension(u, rate=rate, alpha=0.97)
    law = min(0.97, math.exp(-rate * (u - 1.03) / 1.03))
    assert alpha == pytest.approx(law, rel=1e-14)
    assert t[0] == pytest.approx(law * u * E_MOD * (u * u - 1) / 2 * A0, rel=1e-12)


def test_paper_damage_rate_is_gentle():
    """With the paper's λ = 0.1, a yarn at 6 % strain keeps α ≈ 0.997 (reported, not tuned)."""
    _, alpha = _pair_tension(1.06, rate=0.1)
    assert alpha == pytest.approx(math.exp(-0.1 * 0.03 / 1.03), rel=1e-14)
    assert alpha > 0.99


def _reference_forces(x, nx, ny, coef, rest_w, rest_f, alpha_c):
    """Plain-NumPy reference: segment tensions scattered to their end nodes (KSV, no damage)."""
    idx = np.arange(nx * ny).reshape(ny, nx)
    a = np.concatenate([idx[:, :-1].ravel(), idx[:-1, :].ravel()])
    b = np.concatenate([idx[:, 1:].ravel(), idx[1:, :].ravel()])
    rest = np.concatenate([np.full(ny * (nx - 1), rest_w), np.full((ny - 1) * nx, rest_f)])
    d = x[:, b] - x[:, a]
    u2 = (d * d).sum(axis=0) / rest**2
    t = alpha_c * coef * np.maximum(u2 - 1, 0) / 2 * d
    f = np.zeros_like(x)
    for c in range(3):
        np.add.at(f[c], a, t[c])
        np.add.at(f[c], b, -t[c])
    return f


@settings(max_examples=25, deadline=None)
@given(st.integers(2, 7), st.integers(2, 7), st.integers(0, 2**32 - 1))
def test_kernel_matches_numpy_reference(nx, ny, seed):
    """The fused grid kernel's node forces equal a plain-NumPy segment scatter on random input."""
    rng = np.random.default_rng(seed)
    n, s = nx * ny, ny * (nx - 1) + (ny - 1) * nx
    x = rng.normal(size=(3, n)) * 0.01
    coef = rng.uniform(1e5, 1e7, s)
    rest_w, rest_f = rng.uniform(0.001, 0.01, 2)
    alpha = rng.uniform(0.2, 1.0, s)
    f, _ = _node_forces(x, nx, ny, coef, rest_w, rest_f, alpha)
    ref = _reference_forces(x, nx, ny, coef, rest_w, rest_f, alpha)
    assert np.allclose(f, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


@settings(max_examples=200, deadline=None)
@given(rate=st.floats(0.05, 500.0), u_crit=st.floats(1.0, 1.3),
       alpha=st.one_of(st.just(1.0), st.just(0.0), st.floats(1e-300, 1.0)),
       stretch=st.floats(0.5, 3.0), near=st.booleans())
def test_damage_is_skipped_only_where_it_cannot_change(rate, u_crit, alpha, stretch, near):
    """damage_above with damage_thresholds' stretch gives damage()'s value to the bit (also
    next to the threshold, where α = exp(−λ(U − U_c)/U_c) would give back α itself), and it
    skips the law only where that value is the committed α."""
    from emfabric._kernels.materials import damage, damage_above, damage_thresholds

    mat = Material(0, 0.0, u_crit, rate, 0.5)
    thr = np.empty(1)
    damage_thresholds(np.array([alpha]), mat, np.zeros(0), thr, np.full(1, np.nan))
    if near and 0.0 < alpha < 1.0:
        # the stretch at which the law gives back α: its own value, to round-off
        stretch = u_crit * (1.0 - math.log(alpha) / rate) * (1.0 + 1e-15 * (stretch - 1.75))
    u2 = stretch * stretch
    assert damage_above(alpha, u2, thr[0], mat) == damage(alpha, u2, mat)
    if not u2 > thr[0]:
        assert damage(alpha, u2, mat) == alpha


def test_damage_thresholds_follow_a_changed_alpha():
    """Thresholds are kept per α: a segment whose α changed gets its threshold recomputed, the
    others keep theirs (the same values as computed afresh)."""
    from emfabric._kernels.materials import damage_thresholds

    mat = Material(0, 0.0, 1.05, 2.0, 0.5)
    alpha = np.array([1.0, 0.9, 0.5])
    thr, done = np.empty(3), np.full(3, np.nan)
    damage_thresholds(alpha, mat, np.zeros(0), thr, done)
    alpha[0], alpha[2] = 0.95, 0.0
    damage_thresholds(alpha, mat, np.zeros(0), thr, done)
    fresh = np.empty(3)
    damage_thresholds(alpha, mat, np.zeros(0), fresh, np.full(3, np.nan))
    np.testing.assert_array_equal(thr, fresh)
    assert thr[0] > 1.05**2 and thr[2] == np.inf
