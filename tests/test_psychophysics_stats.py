"""Group statistics against SciPy: the rank-sum test of §4.1.2 and §4.2.2."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats
from hypothesis import given
from hypothesis import strategies as st

from jaxadapt.psychophysics import stats

# Values on a coarse grid, so that ties are common.
samples = st.lists(st.integers(-6, 6).map(lambda i: i / 20), min_size=1, max_size=12)
SIZE = 15  # samples are padded to this size and masked: one compiled shape


def _padded(values):
    values = np.asarray(values, dtype=float)
    mask = np.arange(SIZE) < values.size
    return np.pad(values, (0, SIZE - values.size)), mask


@jax.jit
def _tests(x, x_mask, y, y_mask):
    kw = dict(x_mask=x_mask, y_mask=y_mask)
    return stats.ranksum(x, y, **kw), stats.ranksum(x, y, continuity=False, **kw)


@given(samples, samples)
def test_ranksum_matches_scipy_mannwhitneyu_with_ties(x, y):
    ours = _tests(*_padded(x), *_padded(y))
    for continuity, result in zip((True, False), ours, strict=True):
        ref = scipy.stats.mannwhitneyu(
            x, y, alternative="two-sided", method="asymptotic", use_continuity=continuity
        )
        assert float(result.u) == pytest.approx(ref.statistic)
        if len(set(x + y)) > 1:  # SciPy gives NaN when every value is tied
            assert float(result.p) == pytest.approx(ref.pvalue, rel=1e-9, abs=1e-15)
        else:
            assert float(result.p) == 1.0 and float(result.z) == 0.0


@given(
    # No subnormals: XLA on the CPU flushes them to zero, which makes ties.
    st.lists(st.floats(-1, 1, allow_subnormal=False), min_size=2, max_size=SIZE, unique=True),
    st.integers(1, SIZE - 1),
)
def test_ranksum_without_ties_matches_scipy_ranksums(values, n_x):
    n_x = min(n_x, len(values) - 1)
    x, y = values[:n_x], values[n_x:]
    _, ours = _tests(*_padded(x), *_padded(y))
    ref = scipy.stats.ranksums(x, y)
    assert float(ours.z) == pytest.approx(ref.statistic, rel=1e-9, abs=1e-12)
    assert float(ours.p) == pytest.approx(ref.pvalue, rel=1e-9, abs=1e-15)
    ranks = scipy.stats.rankdata(values)
    assert float(ours.statistic) == pytest.approx(ranks[:n_x].sum())


def test_paper_sized_groups_and_effect_sizes():
    # 11 participants per condition, as in §4.1-4.2 after exclusions.
    rng = np.random.default_rng(0)
    control = rng.normal(0.0, 0.05, 11)
    mesopic = rng.normal(0.13, 0.05, 11)
    c = stats.compare(jnp.array(mesopic), jnp.array(control))
    ref = scipy.stats.mannwhitneyu(mesopic, control, method="asymptotic")
    assert float(c.test.p) == pytest.approx(ref.pvalue, rel=1e-9)
    assert float(c.test.p) < 1e-3
    assert float(c.median_x) == pytest.approx(np.median(mesopic))
    assert float(c.median_y) == pytest.approx(np.median(control))
    assert float(c.shift) == pytest.approx(np.median(np.subtract.outer(mesopic, control)))
    u_y = scipy.stats.mannwhitneyu(control, mesopic).statistic
    assert float(c.rank_biserial) == pytest.approx((ref.statistic - u_y) / 121)
    assert 0 < float(c.rank_biserial) <= 1


def test_masks_equal_the_subsets_and_batches_equal_a_loop():
    rng = np.random.default_rng(1)
    x, y = rng.normal(size=(200, 9)), rng.normal(0.5, 1, size=(200, 7))
    x_mask, y_mask = rng.random((200, 9)) < 0.8, rng.random((200, 7)) < 0.8
    batch = jax.jit(stats.compare)(x, y, x_mask=x_mask, y_mask=y_mask)
    for i in range(0, 200, 40):
        xi, yi = x[i][x_mask[i]], y[i][y_mask[i]]
        ref = scipy.stats.mannwhitneyu(xi, yi, method="asymptotic")
        assert float(batch.test.p[i]) == pytest.approx(ref.pvalue, rel=1e-9)
        assert float(batch.test.n_x[i]) == len(xi)
        assert float(batch.median_x[i]) == pytest.approx(np.median(xi))
        assert float(batch.shift[i]) == pytest.approx(np.median(np.subtract.outer(xi, yi)))
    vmapped = jax.vmap(stats.compare)(x, y, x_mask=x_mask, y_mask=y_mask)
    np.testing.assert_allclose(vmapped.test.p, batch.test.p, rtol=1e-12)


def test_empty_group_and_no_variation_give_no_evidence():
    x = jnp.array([0.1, 0.2, 0.3])
    empty = stats.compare(x, jnp.array([0.5, 0.6]), y_mask=jnp.array([False, False]))
    assert float(empty.test.p) == 1.0 and float(empty.test.z) == 0.0
    assert float(empty.rank_biserial) == 0.0
    assert np.isnan(float(empty.median_y)) and np.isnan(float(empty.shift))
    tied = stats.ranksum(jnp.full(4, 0.2), jnp.full(3, 0.2))
    assert float(tied.p) == 1.0


def test_float32_stays_float32():
    r = stats.ranksum(jnp.array([0.1, 0.3], jnp.float32), jnp.array([0.2, 0.0], jnp.float32))
    assert r.p.dtype == jnp.float32 and r.z.dtype == jnp.float32
