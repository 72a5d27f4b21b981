"""Cumulative-Gaussian fits: the paper's glmfit, degenerate data, bootstrap.

The peer is statsmodels' GLM with a binomial family and a probit link, the
counterpart of MATLAB's ``glmfit(x, [k n], 'binomial', 'link', 'probit')``
used in §4.1.2 of the 2015 paper. Batches are padded to a few shapes so that
the whole file compiles the fit only a handful of times.
"""

import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import statsmodels.api as sm
from hypothesis import given
from hypothesis import strategies as st
from scipy.optimize import brentq
from scipy.stats import norm

from jaxadapt.psychophysics import bootstrap as Boot  # noqa: N812
from jaxadapt.psychophysics import psychometric as F  # noqa: N812

#: The afterimage experiment's tests, log10 relative to the 27 cd/m2 standard.
X = np.log10(np.array([14.0, 19, 27, 35, 49]) / 27)
B = 64  # batch size of the compiled fit used across this file


def _pad(*arrays):
    """Pad ``(b, 5)`` arrays to ``(B, 5)`` with copies of row 0."""
    return [np.concatenate([a, np.repeat(a[:1], B - len(a), axis=0)]) for a in arrays]


def _fit(levels, k, n, **kw):
    b = len(k)
    out = F.fit(*_pad(np.broadcast_to(levels, np.shape(k)), k, n), **kw)
    return jax.tree.map(lambda a: np.asarray(a)[:b], out)


def _random_datasets(seed, b=B):
    """Random designs: levels, trials per level (some 0 = padding), and counts
    from a cumulative Gaussian."""
    rng = np.random.default_rng(seed)
    levels = np.sort(rng.uniform(-0.5, 0.5, (b, 5)), axis=1)
    n = rng.integers(0, 40, (b, 5))
    mu, sigma = rng.normal(0, 0.15, (b, 1)), rng.uniform(0.05, 0.4, (b, 1))
    k = rng.binomial(n, norm.cdf((levels - mu) / sigma))
    return levels, k, n


def _statsmodels(levels, k, n):
    keep = n > 0
    X_ = sm.add_constant(levels[keep])
    model = sm.GLM(
        np.c_[k[keep], n[keep] - k[keep]],
        X_,
        family=sm.families.Binomial(link=sm.families.links.Probit()),
    )
    result = model.fit(tol=1e-14, maxiter=1000)
    cov = np.linalg.inv(-model.hessian(result.params, observed=True))
    return result, cov


@pytest.mark.slow
def test_matches_statsmodels_probit_glm():
    levels, k, n = _random_datasets(0)
    ours = _fit(levels, k, n)
    exists = (ours.flags & F.NO_MLE) == 0
    assert exists.sum() > 40  # the comparison covers most datasets
    for i in np.flatnonzero(exists):
        ref, cov = _statsmodels(levels[i], k[i], n[i])
        b0, b1 = ref.params
        np.testing.assert_allclose([ours.b0[i], ours.b1[i]], ref.params, rtol=1e-6, atol=1e-10)
        np.testing.assert_allclose([ours.se_b0[i], ours.se_b1[i]], np.sqrt(np.diag(cov)), rtol=1e-6)
        g = np.array([-1 / b1, b0 / b1**2])  # gradient of -b0/b1: delta method
        assert ours.pse[i] == pytest.approx(-b0 / b1, rel=1e-6, abs=1e-10)
        assert ours.sigma[i] == pytest.approx(1 / b1, rel=1e-6)
        assert ours.se_pse[i] == pytest.approx(np.sqrt(g @ cov @ g), rel=1e-6)
        assert ours.loglik[i] == pytest.approx(ref.llf, rel=1e-9)
        assert ours.deviance[i] == pytest.approx(ref.deviance, rel=1e-6, abs=1e-9)
    assert ours.converged.all()


@pytest.mark.slow
def test_float32_follows_inputs_and_matches_float64():
    levels, k, n = _random_datasets(1)
    f64 = _fit(levels, k, n)
    f32 = F.fit(*(a.astype(np.float32) for a in _pad(levels, k, n)))
    assert f32.pse.dtype == jnp.float32 and f32.flags.dtype == jnp.int32
    ok = (f64.flags & F.NO_MLE) == 0
    assert np.all(np.asarray(f32.converged)[ok])
    np.testing.assert_allclose(np.asarray(f32.pse)[ok], f64.pse[ok], rtol=1e-3, atol=1e-4)
    np.testing.assert_allclose(np.asarray(f32.b1)[ok], f64.b1[ok], rtol=1e-3)
    # A Python number follows the arrays' dtype (n_total=30.0 does not make
    # the fit float64).
    x, k32 = (a.astype(np.float32) for a in _pad(levels, k))
    for total in (40, 40.0):  # n < 40 trials at each level
        assert F.fit(x, k32, total).pse.dtype == jnp.float32


@pytest.mark.slow
def test_vmapped_batch_equals_a_loop_and_does_not_retrace(count_calls):
    levels, k, n = _random_datasets(2)
    batch = F.fit(levels, k, n)
    for i in range(4):
        single = F.fit(levels[i], k[i], n[i])
        for name in ("b0", "b1", "pse", "se_pse", "loglik"):
            assert float(getattr(single, name)) == pytest.approx(
                float(getattr(batch, name)[i]), rel=1e-9, abs=1e-12
            )
        assert int(single.flags) == int(batch.flags[i])
    traces = count_calls(F, "_fit_one")
    F.fit(levels, np.minimum(k + 1, n), n)
    F.fit(levels + 0.1, k, n)
    assert traces == []


#: Hand-made degenerate datasets (30 trials per level) and their flags.
DEGENERATE = [
    ([0, 0, 0, 0, 0], F.ALL_SAME | F.EXTRAPOLATED | F.FLAT),
    ([30, 30, 30, 30, 30], F.ALL_SAME | F.EXTRAPOLATED | F.FLAT),
    ([0, 0, 30, 30, 30], F.SEPARATION),  # complete separation
    ([0, 0, 12, 30, 30], F.SEPARATION),  # quasi-complete: mixed at one level
    ([30, 30, 0, 0, 0], F.SEPARATION),  # decreasing
    ([15, 15, 15, 15, 15], F.FLAT),  # MLE exists: b1 = 0, PSE undefined
    ([0, 1, 2, 3, 5], F.EXTRAPOLATED),  # PSE above the highest test
    ([2, 9, 15, 20, 28], 0),
]


def test_degenerate_data_give_flags_not_nan():
    k = np.array([d for d, _ in DEGENERATE])
    out = _fit(X, k, np.full_like(k, 30))
    np.testing.assert_array_equal(out.flags, [f for _, f in DEGENERATE])
    for name, values in out._asdict().items():
        assert np.all(np.isfinite(values)), name
    assert out.converged.all()
    separated = out.flags == F.SEPARATION
    # Separation: a steep finite slope and a PSE between the last "no" level
    # and the first "yes" level.
    assert np.all(np.abs(out.sigma[separated]) < 0.05)
    assert X[1] < out.pse[2] < X[2] and X[1] < out.pse[4] < X[2]


def test_all_no_places_the_pse_above_the_levels_and_all_yes_below():
    # The slope of such data is zero up to rounding, so its sign must not
    # pick the side (levels shifted by 0.5 would put all "no" at -5e5), or
    # the group test would rank the participant at either end.
    for offset in (0.0, 0.5, -0.5, 3.0):
        levels = X + offset
        out = _fit(np.stack([levels] * 2), np.array([[0] * 5, [30] * 5]), np.full((2, 5), 30))
        assert out.pse[0] > levels.max() and out.pse[1] < levels.min(), offset
        assert np.all(out.flags & F.FLAT)


def _all_same_gradient(levels, k, n, b0, b1):
    """Gradient in ``(b0, b1)`` of the negative log-likelihood of all-"no"
    (``k = 0``) or all-"yes" (``k = n``) counts plus the fit's prior on the
    standardised intercept and slope (``a0 = b0 + b1 c``, ``a1 = b1 s``),
    computed with scipy."""
    c = np.sum(n * levels) / np.sum(n)
    s = np.sqrt(np.sum(n * (levels - c) ** 2) / np.sum(n))
    eta = b0 + b1 * levels
    if np.all(k == 0):  # -n log(1 - Phi(eta))
        r = n * np.exp(norm.logpdf(eta) - norm.logsf(eta))
    else:  # -n log Phi(eta)
        r = -n * np.exp(norm.logpdf(eta) - norm.logcdf(eta))
    a0, a1 = b0 + b1 * c, b1 * s
    prior = np.array([a0, a0 * c + a1 * s]) / F.PRIOR_SD**2
    return np.array([np.sum(r), np.sum(r * levels)]) + prior


def test_all_same_responses_with_uneven_trials_converge_to_the_optimum():
    # All "no" at n = 4, 3, 3, 3, 4 (found by hypothesis): glmfit's start,
    # whose probits then differ only through n, would give a slope of
    # -1.7e-5, from which BFGS would creep back towards the optimum's 0 by
    # 2% a step (its curvature along the slope the start's, 45 times too
    # large, and never updated: y's ~ 1e-17 < eps) until max_steps. (Even n,
    # symmetric about the middle level, give a start at 0.)
    n = np.array([[4, 3, 3, 3, 4], [3, 4, 4, 4, 3]] * 2, float)
    k = np.concatenate([np.zeros((2, 5)), n[2:]])  # all "no", then all "yes"
    out = _fit(X, k, n)
    assert out.converged.all()
    assert np.all(out.flags == F.ALL_SAME | F.EXTRAPOLATED | F.FLAT)
    assert np.all(out.b1 == 0)
    assert np.all(out.pse[:2] > X.max()) and np.all(out.pse[2:] < X.min())
    # The reported state is the optimum: on a1 = 0 (the optimum's slope for
    # such data) the objective's gradient is 0 along the intercept and, as
    # the levels are centred on their trial-weighted mean, along the slope,
    # and the intercept is the root scipy finds for the first.
    for i in range(len(k)):
        gradient = _all_same_gradient(X, k[i], n[i], out.b0[i], out.b1[i])
        np.testing.assert_allclose(gradient, 0.0, atol=1e-12 * n[i].sum())

        def along_b0(b0, i=i):
            return _all_same_gradient(X, k[i], n[i], b0, 0.0)[0]

        assert out.b0[i] == pytest.approx(brentq(along_b0, -40, 40, xtol=1e-14), rel=1e-12)


@pytest.mark.slow
def test_all_no_and_all_yes_take_their_side_in_float32_on_any_design():
    # In float32 (the command line's default precision) the solver stops at
    # slopes of up to 0.15 (not below MIN_SLOPE), whose sign would put about
    # a third of such participants on the wrong side of the levels.
    levels, _, n = _random_datasets(5)
    n = np.maximum(n, 1)  # every level tested, so that "all the same" is all of them
    half = B // 2
    k = np.concatenate([np.zeros_like(n[:half]), n[half:]])
    with jax.enable_x64(False):
        out = F.fit(*(jnp.asarray(a, jnp.float32) for a in (levels, k, n)))
    pse = np.asarray(out.pse, float)
    assert np.all(pse[:half] > levels[:half].max(axis=1))
    assert np.all(pse[half:] < levels[half:].min(axis=1))
    assert np.all(np.asarray(out.flags) & F.ALL_SAME) and np.all(np.asarray(out.b1) == 0)


def test_single_level_and_empty_dataset():
    n = np.array([[0, 0, 30, 0, 0], [0, 0, 0, 0, 0]])
    out = _fit(X, np.array([[0, 0, 12, 0, 0], [0, 0, 0, 0, 0]]), n)
    assert out.flags[0] == F.SINGLE_LEVEL | F.EXTRAPOLATED | F.FLAT
    assert out.flags[1] & F.SINGLE_LEVEL and out.flags[1] & F.ALL_SAME
    for values in out:
        assert np.all(np.isfinite(values))
    assert out.loglik[1] == 0.0 and out.deviance[1] == 0.0


def _reference_flags(levels, k, n):
    """The flags from their definitions, pair by pair."""
    valid = n > 0
    yes = levels[valid & (k > 0)]
    no = levels[valid & (k < n)]
    all_same = yes.size == 0 or no.size == 0
    single = np.unique(levels[valid]).size < 2
    overlap = np.any(no[:, None] > yes[None, :]) and np.any(yes[:, None] > no[None, :])
    return (
        F.ALL_SAME * all_same
        + F.SINGLE_LEVEL * single
        + F.SEPARATION * (not (all_same or single or overlap))
    )


@given(
    st.lists(st.integers(0, 4), min_size=5, max_size=5),
    st.lists(st.floats(0, 1), min_size=5, max_size=5),
)
def test_any_small_dataset_is_finite_and_flagged_by_definition(n, fraction):
    n = np.array([n])
    k = np.floor(np.array([fraction]) * (n + 1)).clip(0, n)
    out = _fit(X, k, n)
    for name, values in out._asdict().items():
        assert np.all(np.isfinite(values)), name
    assert out.converged[0]
    assert out.flags[0] & F.NO_MLE == _reference_flags(X, k[0], n[0])
    tested = X[n[0] > 0]
    outside = tested.size == 0 or not tested.min() <= out.pse[0] <= tested.max()
    assert bool(out.flags[0] & F.EXTRAPOLATED) == outside


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="levels: expected an array"):
        F.fit(0.0, 1, 2)
    with pytest.raises(ValueError, match=r"expected broadcastable shapes, got levels \(5,\)"):
        F.fit(X, np.zeros(4), 30)
    with pytest.raises(ValueError, match=r"lapse: expected a fixed rate or bounds"):
        F.fit(X, np.zeros(5), 30, lapse=(0.1, 0.05))
    # A rate of another batch shape is named, not left to JAX's broadcasting error.
    with pytest.raises(ValueError, match=r"^guess: expected a rate of the batch shape \(4,\)"):
        F.fit(X, np.zeros((4, 5)), 30, guess=np.full(3, 0.1))
    for steps in (0, -5):  # would run zero steps and report the start
        with pytest.raises(ValueError, match=rf"^max_steps: expected at least 1, got {steps}"):
            F.fit(X, np.zeros(5), 30, max_steps=steps)
    with pytest.raises(ValueError, match="method: expected one of"):
        Boot.bootstrap(jax.random.key(0), X, np.zeros(5), 30, method="bca")
    # No levels would give ZeroDivisionError; 2.5 resamples would run 2.
    with pytest.raises(ValueError, match=r"levels: expected .* got shape \(0,\), no levels"):
        F.fit(np.zeros(0), np.zeros(0), np.zeros(0))
    for bad in (2.5, True, 1):
        with pytest.raises(ValueError, match="n_resamples: expected a whole number >= 2"):
            Boot.bootstrap(jax.random.key(0), X, np.zeros(5), 30, n_resamples=bad)
    import equinox as eqx

    # The message is the error's first line (an EquinoxRuntimeError began with
    # the stack outside and inside jit); inside the caller's jit it stays one.
    for n_yes, n_total in ((np.array([1, 2, 31, 4, 5]), 30), (np.zeros(5), [30] * 4 + [np.inf])):
        with pytest.raises(ValueError, match="^n_yes, n_total: expected finite 0 <="):
            F.fit(X, n_yes, np.asarray(n_total, float))
    with pytest.raises(ValueError, match="^levels: expected finite"):
        F.fit(np.r_[X[:4], np.nan], np.zeros(5), 30)
    with pytest.raises(ValueError, match="^levels: expected finite"):
        Boot.bootstrap(jax.random.key(0), np.r_[X[:4], np.nan], np.zeros(5), 30, n_resamples=2)
    with pytest.raises(eqx.EquinoxRuntimeError, match="levels: expected finite"):
        eqx.filter_jit(lambda x: F.fit(x, np.zeros(5), 30).pse)(np.r_[X[:4], np.nan])


def test_recovery_and_observed_information_errors():
    # 64 simulated observers, the paper's 30 trials per level.
    mu, sigma = 0.03, 0.12
    rng = np.random.default_rng(4)
    n = np.full((B, 5), 30)
    k = rng.binomial(n, norm.cdf((X - mu) / sigma))
    out = _fit(X, k, n)
    assert abs(out.pse.mean() - mu) < 3 * out.pse.std() / np.sqrt(B)
    assert abs(np.median(out.sigma) - sigma) < 0.02
    # The delta-method errors describe the spread of the estimates.
    assert out.se_pse.mean() == pytest.approx(out.pse.std(), rel=0.25)


@pytest.mark.slow
def test_bootstrap_intervals_cover_the_true_pse_and_are_deterministic():
    # 5 x 64 simulated datasets x 200 resamples; 95% intervals. Over 7000 such
    # datasets the percentile intervals of both methods covered the true PSE
    # 93% of the time (they undercover slightly at 30 trials a level, as
    # Wichmann and Hill 2001b found), so the band is that +-3 binomial sd.
    mu, sigma, batches = 0.03, 0.12, 5
    rng = np.random.default_rng(100)
    n = np.full((batches, B, 5), 30)
    k = rng.binomial(n, norm.cdf((X - mu) / sigma))
    k[0, 1] = k[0, 0]
    for method in Boot.METHODS:
        boots = [
            Boot.bootstrap(jax.random.key(i), X, k[i], n[i], n_resamples=200, method=method)
            for i in range(batches)
        ]
        low, high = np.concatenate([b.pse_ci for b in boots]).T
        coverage = np.mean((low <= mu) & (mu <= high))
        assert 0.885 <= coverage <= 0.975, (method, coverage)
        slope_low, slope_high = np.concatenate([b.slope_ci for b in boots]).T
        slope_coverage = np.mean((slope_low <= 1 / sigma) & (1 / sigma <= slope_high))
        assert 0.8 <= slope_coverage <= 0.99, (method, slope_coverage)
        assert np.all(np.isfinite(low) & np.isfinite(high))
        assert np.mean([b.flagged for b in boots]) < 0.05  # resamples with separated data
        assert not np.array_equal(low[0], low[1])  # each dataset has its own resamples
    again = Boot.bootstrap(jax.random.key(2), X, k[2], n[2], n_resamples=200, method=method)
    np.testing.assert_array_equal(again.pse_ci, boots[2].pse_ci)
    np.testing.assert_array_equal(again.fit.pse, F.fit(X, k[2], n[2]).pse)


@pytest.mark.slow
def test_the_bootstrap_in_batches_gives_the_one_call_result():
    # 6 datasets (a 2 x 3 batch) of 50 resamples in one call, and within a
    # budget of 20 fits: one dataset a call, resamples in blocks of 20 (the
    # last padded, its extra resamples dropped). Same resamples, same
    # intervals up to rounding (XLA vectorises a batch of 1 and one of 6
    # differently, and the fits' iterations carry the last bits further:
    # 4e-12 relative seen); the datasets reported done add up to all.
    rng = np.random.default_rng(3)
    n = np.full((2, 3, 5), 30)
    k = rng.binomial(n, norm.cdf((X - 0.02) / 0.15))
    whole = Boot.bootstrap(jax.random.key(5), X, k, n, n_resamples=50)
    done = []
    parts = Boot.bootstrap(
        jax.random.key(5), X, k, n, n_resamples=50, budget=20 * Boot.FIT_BYTES, progress=done.append
    )
    assert Boot.bootstrap_blocks(6, 50, 20 * Boot.FIT_BYTES) == (1, 20)
    assert done == [1] * 6
    assert whole.pse_ci.shape == (2, 3, 2)
    for a, b in zip(jax.tree.leaves(whole), jax.tree.leaves(parts), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-15)
    assert np.all(whole.pse_ci[..., 0] < whole.pse_ci[..., 1])


#: Bootstraps 16, then 1,024 datasets x 100 resamples in float64 within a
#: budget of 1,600 fits, in one process: prints the peak memory after each.
BOOTSTRAPS = """
import resource, jax, numpy as np
jax.config.update("jax_enable_x64", True)
from jaxadapt.psychophysics import bootstrap as Boot
for D in (16, 1024):
    k = np.tile([2.0, 6, 10, 14, 18], (D, 1))
    b = Boot.bootstrap(jax.random.key(0), np.linspace(-0.3, 0.3, 5), k, 20.0,
                    n_resamples=100, budget=1600 * Boot.FIT_BYTES)
    jax.block_until_ready(b)
    print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


@pytest.mark.slow
def test_bootstrap_memory_does_not_grow_with_the_datasets():
    # The same batches for 1,024 datasets as for 16, so the same peak: it
    # grows by 0.2 to 26 MB, where all 102,400 fits in one call take 241 MB more.
    done = subprocess.run(
        [sys.executable, "-c", BOOTSTRAPS], capture_output=True, text=True, check=True
    )
    small, large = (int(kb) for kb in done.stdout.split())
    assert large - small < 80_000, (small, large)  # KB


@pytest.mark.slow
def test_fitted_lapse_and_guess_rates_are_recovered():
    # Wichmann & Hill (2001): lapses bias the slope of a plain probit fit.
    mu, sigma, guess, lapse = 0.05, 0.1, 0.03, 0.06
    rng = np.random.default_rng(7)
    levels = np.linspace(-0.4, 0.4, 5)
    n = np.full((B, 5), 400)
    k = rng.binomial(n, F.psychometric(levels, mu, sigma, guess, lapse))
    free = _fit(levels, k, n, guess=(0.0, 0.1), lapse=(0.0, 0.1))
    plain = _fit(levels, k, n)
    assert free.converged.all()
    assert abs(np.median(free.sigma) - sigma) < 0.01 < abs(np.median(plain.sigma) - sigma)
    assert np.median(free.guess) == pytest.approx(guess, abs=0.01)
    assert np.median(free.lapse) == pytest.approx(lapse, abs=0.015)
    assert np.all((free.lapse >= 0) & (free.lapse <= 0.1))
    # Fixed rates at their true values: the errors describe the spread.
    fixed = _fit(levels, k, n, guess=guess, lapse=lapse)
    assert fixed.se_pse.mean() == pytest.approx(fixed.pse.std(), rel=0.3)


@pytest.mark.slow
def test_gradient_of_the_pse_matches_finite_differences():
    k, n = np.array([2.0, 9, 15, 20, 28]), np.full(5, 30.0)

    def pse(k):
        return F.fit(X, k, n).pse

    g = np.asarray(jax.grad(pse)(k))
    h = 1e-5
    fd = [(pse(k + h * e) - pse(k - h * e)) / (2 * h) for e in np.eye(5)]
    np.testing.assert_allclose(g, fd, rtol=1e-5, atol=1e-9)
    assert np.all(g < 0)  # more "brighter" answers: a lower PSE


@pytest.mark.slow
def test_fitted_lapse_rates_in_float32_reach_the_optimum_whatever_the_batch():
    # A dataset whose float32 fit, in a batch of 100, can stop 0.27
    # log-likelihood units short of its optimum, saying it has converged,
    # where BFGS's inverse Hessian loses positive definiteness to rounding.
    # The same fit alone and in the batch, and no converged fit of the
    # batch below its float64 optimum by more than 0.01. (Alone: in a batch
    # of its copies, which stops when it does, compiled once with the batch.)
    rng = np.random.default_rng(5)
    x = np.sort(rng.uniform(-0.5, 0.5, (2000, 7)), axis=1)
    n = rng.integers(5, 60, (2000, 7)).astype(float)
    pse, sig = rng.normal(0, 0.15, 2000), rng.uniform(0.02, 0.5, 2000)
    k = rng.binomial(n.astype(int), norm.cdf((x - pse[:, None]) / sig[:, None])).astype(float)
    x, k, n = (a[1458:1558] for a in (x, k, n))
    f64 = F.fit(x, k, n, lapse=(0.0, 0.1))
    with jax.enable_x64(False):
        X, K, N = (jnp.asarray(a, jnp.float32) for a in (x, k, n))
        batch = F.fit(X, K, N, lapse=(0.0, 0.1))
        alone = F.fit(*(jnp.broadcast_to(a[:1], a.shape) for a in (X, K, N)), lapse=(0.0, 0.1))
    assert bool(alone.converged[0]) and bool(batch.converged[0])
    assert float(batch.loglik[0]) == pytest.approx(float(alone.loglik[0]), abs=1e-3)
    short = np.asarray(f64.loglik) - np.asarray(batch.loglik, float)
    assert np.all(short[np.asarray(batch.converged)] < 0.01)


@pytest.mark.slow
def test_deviance_is_not_negative_in_float32():
    # One level among zero-trial ones: loglik and the saturated loglik agree
    # but for rounding, which would make the deviance -1.9e-6 in float32.
    x = np.log10(np.array([14.0, 19, 27, 35, 49]) / 27)
    with jax.enable_x64(False):
        f = F.fit(
            jnp.asarray(x, jnp.float32),
            jnp.array([0, 0, 12.0, 0, 0]),
            jnp.array([0, 0, 30.0, 0, 0]),
        )
    assert float(f.deviance) >= 0


@pytest.mark.slow
def test_the_fit_is_a_program_the_compilation_cache_keeps(tmp_path, own_cache_env):
    # JAX's persistent cache keeps no program with a host callback, which
    # the value checks raise through: with them inside, every `jaxadapt
    # psychometric fit` would compile the fit (3-6 s) again.
    import subprocess
    import sys

    code = (
        "from jaxadapt import runtime\n"
        "runtime.cache_compilations()\n"
        "from jaxadapt.psychophysics import psychometric as F\n"
        "F.fit([-0.1, 0.0, 0.1], [[3, 15, 27]], 30).pse.block_until_ready()\n"
    )
    run = [sys.executable, "-c", code]
    done = subprocess.run(run, env=own_cache_env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    kept = [p.name for p in (tmp_path / "jaxadapt" / "xla").iterdir()]
    assert any(name.startswith("jit__fit-") for name in kept), sorted(kept)
