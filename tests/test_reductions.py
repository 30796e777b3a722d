"""The vectorised reductions (emfabric._kernels.reductions) and the block scans built on them give
the results of the plain loops they replaced: the same doubles to the bit, the same lists."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

from emfabric._kernels.contact import find_candidates
from emfabric._kernels.materials import damage_thresholds
from emfabric._kernels.nodes import _buf_total
from emfabric._kernels.records import BODY_R0, BODY_ROWS, SHAPE_SPHERE, Material
from emfabric._kernels.reductions import SCAN_BLOCK, from_key, lane_sums, order_key

doubles = st.floats(allow_nan=False, allow_infinity=True, allow_subnormal=True, width=64)


@njit(cache=False)
def _key(x):
    return order_key(x)


@njit(cache=False)
def _back(k):
    return from_key(k)


@njit(cache=False)
def _lanes(buf, r, count):
    return lane_sums(buf, r, count)


@njit(cache=False)
def _total(buf, r, count):
    return _buf_total(buf, r, count)


@njit(cache=False)
def _extremes(a):
    """(max, min) over integer keys, as the kernels take them."""
    hi = order_key(-math.inf)
    lo = order_key(math.inf)
    for i in range(a.shape[0]):
        k = order_key(a[i])
        hi = max(hi, k)
        lo = min(lo, k)
    return from_key(hi), from_key(lo)


def _bits(x: float) -> int:
    return int(np.array(x).view(np.int64))


@settings(deadline=None)
@given(doubles, doubles)
def test_keys_order_as_the_doubles_do(x, y):
    """x < y ⇔ key(x) < key(y) for any two doubles but NaN (−0.0 below +0.0, the one tie the
    doubles do not order), and the key comes back to the same bits."""
    kx, ky = _key(x), _key(y)
    if x == y == 0.0:
        assert (kx < ky) == (math.copysign(1.0, x) < math.copysign(1.0, y))
    else:
        assert (kx < ky) == (x < y)
        assert (kx == ky) == (x == y)
    assert _bits(_back(kx)) == _bits(x)
    if x >= 0.0 and math.copysign(1.0, x) > 0.0:
        assert kx == _bits(x)  # a non-negative double's key is its bits


@settings(deadline=None)
@given(st.lists(st.floats(allow_nan=False, width=64), min_size=1, max_size=300))
def test_extremes_over_keys_are_the_largest_and_smallest(values):
    a = np.array(values)
    hi, lo = _extremes(a)
    assert hi == a.max() and lo == a.min()


def _four_lanes(row: np.ndarray, count: int) -> tuple[float, ...]:
    """The four interleaved partial sums of row[:4⌊count/4⌋] in plain Python floats."""
    lanes = [0.0, 0.0, 0.0, 0.0]
    for i in range(count - count % 4):
        lanes[i % 4] += float(row[i])
    return tuple(lanes)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(0, 131))
def test_lane_sums_are_the_four_scalar_sums(seed, count):
    """One 4-wide vector add is four IEEE additions: each lane is the scalar partial sum, and
    _buf_total ((s₀ + tail) + s₁) + (s₂ + s₃) the old loop's value, whatever the magnitudes."""
    rng = np.random.default_rng(seed)
    buf = rng.standard_normal((3, 132)) * 10.0 ** rng.integers(-30, 30, (3, 132))
    for r in range(3):
        lanes = _lanes(buf, r, count)
        assert [_bits(v) for v in lanes] == [_bits(v) for v in _four_lanes(buf[r], count)]
        s0, s1, s2, s3 = _four_lanes(buf[r], count)
        for i in range(count - count % 4, count):
            s0 += float(buf[r, i])
        assert _bits(_total(buf, r, count)) == _bits((s0 + s1) + (s2 + s3))


def test_lane_sums_refuse_what_they_cannot_read_as_rows():
    """A non-contiguous or integer array is a typing error, not a wrong sum."""
    import pytest
    from numba.core.errors import TypingError

    with pytest.raises(TypingError):
        _lanes(np.zeros((3, 8))[:, ::2], 0, 4)
    with pytest.raises(TypingError):
        _lanes(np.zeros((3, 8), dtype=np.int64), 0, 4)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 5 * SCAN_BLOCK + 3))
def test_candidates_are_the_free_nodes_within_reach(seed, n):
    """Block by block, the candidates are every free node within reach, in node order, and the
    flags mark exactly them (sizes across the block boundaries)."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1.0, 1.0, (3, n))
    inv_mass = np.where(rng.random(n) < 0.2, 0.0, 1.0)
    centre = np.array([0.1, -0.2, 0.05])
    reach = float(rng.uniform(0.0, 1.2))
    cand = np.full(n, -1, dtype=np.int64)
    flag = np.full(n, 7, dtype=np.uint8)
    count = find_candidates(x, inv_mass, centre, reach, cand, flag)
    d = x - centre[:, None]
    expect = np.flatnonzero((inv_mass > 0.0)
                            & (d[0] * d[0] + d[1] * d[1] + d[2] * d[2] < reach * reach))
    np.testing.assert_array_equal(cand[:count], expect)
    np.testing.assert_array_equal(flag, np.isin(np.arange(n), expect).astype(np.uint8))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 4 * SCAN_BLOCK + 5))
def test_nodes_inside_counts_the_unflagged_free_nodes_in_the_body(seed, n):
    """A sphere of radius R: the count is the free nodes with flag 0 closer than R."""
    from emfabric._kernels.shapes import nodes_inside

    body = _sphere_body()
    radius = body.radius
    rng = np.random.default_rng(seed)
    x = rng.uniform(-2.0 * radius, 2.0 * radius, (3, n))
    inv_mass = np.where(rng.random(n) < 0.2, 0.0, 1.0)
    flag = (rng.random(n) < 0.3).astype(np.uint8)
    state = np.zeros((BODY_ROWS, 3))
    state[BODY_R0:BODY_R0 + 3] = np.eye(3)
    count = nodes_inside(x, inv_mass, flag, body, state)
    d2 = (x * x).sum(axis=0)
    assert count == int(((flag == 0) & (inv_mass > 0.0) & (d2 < radius * radius)).sum())


def _sphere_body():
    from emfabric.config.scenario import load_scenario
    from emfabric.sim.builder import build_model

    body = build_model(load_scenario("demo-small", {})).body
    assert body.shape == SHAPE_SPHERE
    return body


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 4 * SCAN_BLOCK + 7))
def test_damage_thresholds_recompute_every_changed_segment(seed, n):
    """After α changes in a few scattered segments, the kept thresholds equal thresholds
    computed afresh for every segment (the blocks with no change are skipped)."""
    rng = np.random.default_rng(seed)
    mat = Material(0, 0.0, 1.05, 2.0, 0.5)
    alpha = rng.uniform(0.2, 1.0, n)
    alpha[rng.random(n) < 0.3] = 1.0
    thr, done = np.empty(n), np.full(n, np.nan)
    damage_thresholds(alpha, mat, np.zeros(0), thr, done)
    changed = rng.random(n) < 0.05
    alpha[changed] *= rng.uniform(0.0, 1.0, int(changed.sum()))
    damage_thresholds(alpha, mat, np.zeros(0), thr, done)
    fresh = np.empty(n)
    damage_thresholds(alpha, mat, np.zeros(0), fresh, np.full(n, np.nan))
    np.testing.assert_array_equal(thr, fresh)
    np.testing.assert_array_equal(done, alpha)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_damage_release_sums_every_segment_whose_alpha_fell(seed):
    """The energy released is the sum, in segment order, over the segments whose α fell (a few,
    scattered over the blocks) of drop × (stored energy − the unpaid work), to the bit."""
    from emfabric._kernels.energy import damage_release
    from emfabric._kernels.materials import strain_energy_density, stress_factor
    from emfabric.config.scenario import load_scenario
    from emfabric.sim.builder import build_model

    model = build_model(load_scenario("demo-small", {}))
    yarns, mat = model.yarns, model.material
    rng = np.random.default_rng(seed)
    x0 = model.nodes.x0 * (1.0 + 0.02 * rng.random(model.nodes.x0.shape))
    x1 = x0 * (1.0 + 0.02 * rng.random(x0.shape))
    before = rng.uniform(0.5, 1.0, yarns.ends.shape[0])
    after = before.copy()
    fell = rng.random(after.shape[0]) < 0.01
    after[fell] *= rng.uniform(0.0, 1.0, int(fell.sum()))
    expect = 0.0
    for s in np.flatnonzero(fell):
        a, b = yarns.ends[s]
        dx, dy, dz = (float(x1[c, b] - x1[c, a]) for c in range(3))
        u2 = (dx * dx + dy * dy + dz * dz) * float(yarns.inv_rest2[s])
        paid = (dx * (dx - (x0[0, b] - x0[0, a])) + dy * (dy - (x0[1, b] - x0[1, a]))
                + dz * (dz - (x0[2, b] - x0[2, a])))
        drop = before[s] - after[s]
        if drop > 0.0:
            expect += drop * yarns.stiffness[s] * (
                yarns.rest_length[s] * yarns.rest_length[s] * strain_energy_density(u2, mat)
                - 0.5 * stress_factor(u2, mat) * paid)
    assert damage_release(yarns, mat, x0, x1, before, after, 0.5) == expect
