"""Group statistics against SciPy: the rank-sum test of §4.1.2 and §4.2.2."""

import math
import warnings
from types import SimpleNamespace

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


#: ``ranksum`` and ``compare`` compiled whole, for the tests that call them on
#: a few shapes: one compilation per shape and method instead of one per
#: operation. The paper's values, the float32 test and the doctests call
#: them eagerly.
ranksum = jax.jit(stats.ranksum, static_argnames=("continuity", "method"))
compare = jax.jit(stats.compare, static_argnames=("continuity", "method"))


def _padded(values):
    values = np.asarray(values, dtype=float)
    mask = np.arange(SIZE) < values.size
    return np.pad(values, (0, SIZE - values.size)), mask


@jax.jit
def _tests(x, x_mask, y, y_mask):
    kw = dict(x_mask=x_mask, y_mask=y_mask, method="asymptotic")
    return stats.ranksum(x, y, **kw), stats.ranksum(x, y, continuity=False, **kw)


@jax.jit
def _exact_and_auto(x, x_mask, y, y_mask):
    kw = dict(x_mask=x_mask, y_mask=y_mask)
    return stats.ranksum(x, y, method="exact", **kw), stats.ranksum(x, y, **kw)


@jax.jit
def _exact_and_auto_unmasked(x, y):
    """Both methods without masks: the group sizes are the static shapes, so
    each pair of sizes is one compilation (instead of one per operation)."""
    return stats.ranksum(x, y, method="exact"), stats.ranksum(x, y)


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
        assert not bool(result.exact)


@given(samples, samples)
def test_exact_and_auto_match_scipy_mannwhitneyu(x, y):
    # Masked (sizes known at run time only), with and without ties: SciPy's
    # exact method (no tie correction, U rounded down) and its automatic
    # choice (exact when a group has at most 8 values and nothing is tied).
    exact, auto = _exact_and_auto(*_padded(x), *_padded(y))
    ref = scipy.stats.mannwhitneyu(x, y, method="exact")
    assert float(exact.p) == pytest.approx(ref.pvalue, rel=1e-9, abs=1e-300)
    assert bool(exact.exact)
    tied = len(set(x + y)) < len(x + y)
    assert bool(auto.exact) == (min(len(x), len(y)) <= 8 and not tied)
    if len(set(x + y)) > 1:  # SciPy gives NaN when every value is tied
        ref = scipy.stats.mannwhitneyu(x, y, method="auto")
        assert float(auto.p) == pytest.approx(ref.pvalue, rel=1e-9, abs=1e-300)


@pytest.mark.slow
@given(
    st.lists(st.floats(-1, 1, allow_subnormal=False), min_size=2, max_size=30, unique=True),
    st.data(),
)
def test_exact_without_masks_matches_scipy(values, data):
    # Static sizes (one stored distribution), no ties, up to 29 against 1.
    n_x = data.draw(st.integers(1, len(values) - 1))
    x, y = values[:n_x], values[n_x:]
    r, auto = _exact_and_auto_unmasked(jnp.array(x), jnp.array(y))
    ref = scipy.stats.mannwhitneyu(x, y, method="exact")
    assert float(r.p) == pytest.approx(ref.pvalue, rel=1e-9, abs=1e-300)
    ref = scipy.stats.mannwhitneyu(x, y, method="auto")
    assert float(auto.p) == pytest.approx(ref.pvalue, rel=1e-9, abs=1e-300)
    assert bool(auto.exact) == (min(len(x), len(y)) <= 8)


@pytest.mark.slow
def test_papers_mesopic_p_is_the_exact_p_of_complete_separation():
    # §4.2.2: p = 2.84e-6, two-sided, with all 11 manipulated PSEs above all
    # 11 control ones: 2 of the C(22, 11) equally likely arrangements are as
    # extreme.
    rng = np.random.default_rng(2)
    control = rng.normal(0.0, 0.03, 11)
    mesopic = control.max() + 0.01 + rng.exponential(0.1, 11)
    exact = stats.ranksum(jnp.array(mesopic), jnp.array(control), method="exact")
    assert float(exact.u) == 121.0 and bool(exact.exact)
    assert float(exact.p) == pytest.approx(2 / math.comb(22, 11), rel=1e-12)
    assert f"{float(exact.p):.2e}" == "2.84e-06"
    assert float(exact.p) == pytest.approx(
        scipy.stats.mannwhitneyu(mesopic, control, method="exact").pvalue, rel=1e-12
    )
    # The same in float32, and with the groups swapped.
    x32, y32 = jnp.array(mesopic, jnp.float32), jnp.array(control, jnp.float32)
    assert float(stats.ranksum(y32, x32, method="exact").p) == pytest.approx(2.835142e-6, 1e-6)
    # SciPy's automatic choice, like MATLAB's default, is the approximation at
    # 11 against 11, which cannot go below 8.15e-5.
    auto = stats.ranksum(jnp.array(mesopic), jnp.array(control))
    assert not bool(auto.exact)
    ref = scipy.stats.mannwhitneyu(mesopic, control, method="auto").pvalue
    assert float(auto.p) == pytest.approx(ref, rel=1e-9)
    assert float(auto.p) == pytest.approx(8.1515e-5, rel=1e-4)


def test_exact_approaches_the_asymptotic_p_for_large_groups():
    # The continuity-corrected normal approximation is off by O(1 / N) in p:
    # at most a few thousandths at 20 against 25, less at 150 against 150.
    rng = np.random.default_rng(3)
    worst = {}
    for n, m in ((20, 25), (150, 150)):
        worst[n] = 0.0
        for shift in np.linspace(0.0, 0.6, 13):
            x, y = rng.normal(shift, 1, n), rng.normal(0, 1, m)
            exact, auto = _exact_and_auto_unmasked(jnp.array(x), jnp.array(y))
            assert bool(exact.exact) and not bool(auto.exact)  # both groups larger than 8
            ref = scipy.stats.mannwhitneyu(x, y, method="exact").pvalue
            assert float(exact.p) == pytest.approx(ref, rel=1e-9, abs=1e-300)
            worst[n] = max(worst[n], abs(float(auto.p) - float(exact.p)))
    assert worst[20] < 5e-3 and worst[150] < 1e-3 and worst[150] < worst[20]


def test_exact_batches_with_masks_equal_a_loop_and_vmap():
    rng = np.random.default_rng(4)
    x, y = rng.normal(0.8, 1, size=(300, 12)), rng.normal(size=(300, 10))
    x_mask, y_mask = rng.random((300, 12)) < 0.6, rng.random((300, 10)) < 0.6
    for method in ("exact", "auto"):
        batch = jax.jit(
            lambda *a, m=method: stats.ranksum(*a[:2], x_mask=a[2], y_mask=a[3], method=m)
        )(x, y, x_mask, y_mask)
        vmapped = jax.jit(
            jax.vmap(lambda *a, m=method: stats.ranksum(*a[:2], x_mask=a[2], y_mask=a[3], method=m))
        )(x, y, x_mask, y_mask)
        np.testing.assert_allclose(vmapped.p, batch.p, rtol=1e-12)
        for i in range(0, 300, 23):
            xi, yi = x[i][x_mask[i]], y[i][y_mask[i]]
            if not len(xi) or not len(yi):
                assert float(batch.p[i]) == 1.0
                continue
            ref = scipy.stats.mannwhitneyu(xi, yi, method=method).pvalue
            assert float(batch.p[i]) == pytest.approx(ref, rel=1e-9)
    assert 0 < np.mean(batch.exact) < 1  # auto: both methods occur in the batch


def test_exact_tables_have_limits_and_methods_are_named():
    big = jnp.linspace(0, 1, 400)
    with pytest.raises(ValueError, match="method='exact'.*use method='asymptotic'"):
        ranksum(big[:200], big[200:], method="exact")
    with pytest.raises(ValueError, match="method: expected 'auto', 'exact' or 'asymptotic'"):
        ranksum(big[:3], big[3:6], method="permutation")
    # NaN where valid is refused (it would rank as the largest value); where
    # masked it is left out. Lists are taken as arrays.
    with pytest.raises(Exception, match="x, y: expected finite values where valid"):
        ranksum(jnp.array([1.0, 2.0, jnp.nan]), jnp.array([0.5, 3.0, 4.0]))
    masked = ranksum(jnp.array([1.0, 2.0, jnp.nan]), [0.5, 3.0, 4.0], x_mask=[True, True, False])
    ref = scipy.stats.mannwhitneyu([1.0, 2.0], [0.5, 3.0, 4.0])
    assert float(masked.p) == pytest.approx(ref.pvalue, rel=1e-12)
    # Masked groups padded past the table's limit: auto falls back to the
    # approximation for every element and says so.
    x, y = jnp.linspace(0, 1, 9), jnp.linspace(2, 3, 800)
    r = ranksum(x, y, x_mask=jnp.arange(9) < 5, y_mask=jnp.arange(800) < 700)
    assert not bool(r.exact)
    ref = scipy.stats.mannwhitneyu(np.asarray(x[:5]), np.asarray(y[:700]), method="asymptotic")
    assert float(r.p) == pytest.approx(ref.pvalue, rel=1e-9)
    # Unmasked, the same sizes need one distribution: exact, as SciPy's auto.
    r = ranksum(x[:5], y[:700])
    assert bool(r.exact)
    ref = scipy.stats.mannwhitneyu(np.asarray(x[:5]), np.asarray(y[:700]))
    assert float(r.p) == pytest.approx(ref.pvalue, rel=1e-9)


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
    ref = scipy.stats.mannwhitneyu(mesopic, control, method="auto")  # asymptotic at 11
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
        ref = scipy.stats.mannwhitneyu(xi, yi)  # auto: exact where a group has <= 8
        assert float(batch.test.p[i]) == pytest.approx(ref.pvalue, rel=1e-9)
        assert float(batch.test.n_x[i]) == len(xi)
        assert float(batch.median_x[i]) == pytest.approx(np.median(xi))
        assert float(batch.shift[i]) == pytest.approx(np.median(np.subtract.outer(xi, yi)))
    vmapped = jax.jit(jax.vmap(stats.compare))(x, y, x_mask=x_mask, y_mask=y_mask)
    np.testing.assert_allclose(vmapped.test.p, batch.test.p, rtol=1e-12)


def test_no_variation_gives_no_evidence():
    tied = ranksum(jnp.full(4, 0.2), jnp.full(3, 0.2))
    assert float(tied.p) == 1.0 and not bool(tied.exact)  # auto: tied, asymptotic
    assert float(ranksum(jnp.full(4, 0.2), jnp.full(3, 0.2), method="exact").p) == 1.0


@pytest.mark.parametrize("method", ["auto", "exact", "asymptotic"])
def test_an_empty_group_gives_no_test_as_scipy(method):
    # A group left without values (every PSE undetermined) gives NaN, as
    # SciPy does: W = 0, z = 0, p = 1, "exact" and rank-biserial 0 would
    # report a test that was not run as one that found nothing.
    x, y = np.array([0.1, 0.2, 0.3]), np.array([0.5, 0.6])
    for x_valid, y_valid in ((True, False), (False, True), (False, False)):
        x_mask, y_mask = np.full(3, x_valid), np.full(2, y_valid)
        c = compare(x, y, x_mask=x_mask, y_mask=y_mask, method=method)
        xs, ys = x[x_mask], y[y_mask]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # SciPy warns of the empty sample
            refs = (scipy.stats.mannwhitneyu(xs, ys, method=method), scipy.stats.ranksums(xs, ys))
        assert all(np.isnan(r.pvalue) and np.isnan(r.statistic) for r in refs)
        t = c.test
        assert all(np.isnan(float(v)) for v in (t.p, t.statistic, t.u, t.z, c.rank_biserial))
        assert not bool(t.exact) and np.isnan(float(c.shift))
        assert (float(t.n_x), float(t.n_y)) == (xs.size, ys.size)


def test_one_value_against_one_is_a_test_as_scipys():
    # The smallest groups that have a test: p = 1, the least p they can reach.
    for x, y in (([0.1], [0.5]), ([0.1], [0.5, 0.7]), ([0.9], [0.5, 0.7])):
        for method in ("exact", "asymptotic"):
            ours = stats.ranksum(jnp.array(x), jnp.array(y), method=method)
            ref = scipy.stats.mannwhitneyu(x, y, method=method)
            assert float(ours.u) == ref.statistic
            assert float(ours.p) == pytest.approx(ref.pvalue, rel=1e-12)
    assert float(stats.ranksum(jnp.array([0.1]), jnp.array([0.5])).p) == 1.0


def test_only_the_batch_elements_with_an_empty_group_are_untested():
    x, y = jnp.array([[0.1, 0.2], [0.3, 0.4]]), jnp.array([[0.5, 0.6], [0.0, 0.05]])
    y_mask = jnp.array([[True, True], [False, False]])
    r = ranksum(x, y, y_mask=y_mask, method="exact")
    assert float(r.p[0]) == pytest.approx(scipy.stats.mannwhitneyu([0.1, 0.2], [0.5, 0.6]).pvalue)
    assert bool(r.exact[0]) and np.isnan(float(r.p[1])) and not bool(r.exact[1])


def test_group_tests_say_why_a_condition_has_no_test():
    # Every manipulated PSE undetermined (NaN): the row has no test, and
    # untested says why; a row with a test has none to say.
    table = _fit_table(
        ["control"] * 3 + ["manip"] * 3 + ["other"] * 2,
        [0.01, -0.02, 0.0, np.nan, np.nan, np.nan, 0.1, 0.2],
    )
    manip, other = stats.group_tests(table, "control")
    assert (manip["n"], manip["n_control"], manip["p_exact"]) == (0, 3, "false")
    assert all(np.isnan(manip[k]) for k in ("p", "W", "z", "rank_biserial", "shift", "median"))
    assert stats.untested(manip) == "manip has no determined PSE"
    assert stats.untested(other) is None and 0 < other["p"] <= 1
    both = dict(manip, n_control=0)
    assert stats.untested(both) == "neither manip nor control has a determined PSE"


def _fit_table(condition, pse):
    """The columns of a fit table that :func:`stats.group_tests` reads."""
    return SimpleNamespace(condition=list(condition), pse=np.asarray(pse, float))


def test_float32_stays_float32():
    x, y = jnp.array([0.1, 0.3], jnp.float32), jnp.array([0.2, 0.0], jnp.float32)
    for method in ("auto", "exact", "asymptotic"):
        r = stats.ranksum(x, y, method=method)
        assert r.p.dtype == jnp.float32 and r.z.dtype == jnp.float32


@pytest.mark.slow
def test_an_empty_group_gives_nan_medians_as_a_masked_out_one():
    # NaN, as for a group masked out: nanmedian of no entries at all would
    # raise IndexError (in median, hodges_lehmann and so compare).
    empty, y = jnp.zeros(0), jnp.array([0.5, 3.0, 4.0])
    masked = stats.compare(jnp.ones(2), y, x_mask=jnp.zeros(2, bool))
    c = stats.compare(empty, y)
    assert np.isnan(c.median_x) and np.isnan(c.shift) and np.isnan(masked.median_x)
    assert float(c.median_y) == 3.0 and np.isnan(c.test.p) and np.isnan(masked.test.p)
    assert stats.median(jnp.zeros((2, 0))).shape == (2,)


def test_bad_groups_and_masks_are_named():
    # Named, not left to JAX's "Zero-dimensional arrays cannot be
    # concatenated" or its broadcasting error.
    y = jnp.array([0.5, 3.0, 4.0])
    with pytest.raises(ValueError, match="^x: expected a group on the last axis, got a scalar"):
        stats.ranksum(jnp.array(1.0), y)
    with pytest.raises(
        ValueError, match=r"^y_mask: expected a shape that broadcasts to y's \(3,\)"
    ):
        stats.ranksum(y, y, y_mask=jnp.ones(2, bool))
