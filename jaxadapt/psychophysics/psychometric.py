"""Cumulative-Gaussian psychometric functions fitted by maximum likelihood.

§4.1.2 of the 2015 paper fits, per participant and condition, the fraction of
trials on which the test was judged brighter than the standard with a
cumulative Gaussian, using MATLAB's ``glmfit(x, [k n], 'binomial', 'link',
'probit')``, and reads the point of subjective equality (PSE) at 50%. With
levels ``x`` in log10 units relative to the standard, the model here is::

    P(x) = gamma + (1 - gamma - lambda) Phi(b0 + b1 x)
         = gamma + (1 - gamma - lambda) Phi((x - mu) / sigma),
    mu = PSE = -b0 / b1,   sigma = 1 / b1,

with the guess rate ``gamma`` and the lapse rate ``lambda`` zero by default,
which is exactly the probit GLM of ``glmfit``. Every function takes arrays
whose last axis holds the levels of one dataset and whose leading axes are
datasets (participants x conditions x bootstrap resamples): one compiled call
fits them all.

Fitting
-------
The negative log-likelihood of the binomial counts is minimised with
optimistix's BFGS (a quasi-Newton direction and a backtracking Armijo line
search). Four things make it robust in a batch where nobody looks at the
individual fits:

- the levels are standardised first (``z = (x - c) / s``, ``c`` and ``s`` the
  trial-weighted mean and standard deviation of the levels) and the objective
  is divided by the number of trials, so that the identity is a good first
  Hessian whatever the units and the trial counts;
- the start is one iteratively reweighted least-squares step from glmfit's own
  starting values (empirical probits of ``(k + 1/2) / (n + 1)``), and BFGS
  starts from the exact inverse Hessian there (the identity where it is not
  positive definite), so that its first steps are Newton steps;
- the probit log-likelihood is concave in ``(b0, b1)``, so the line search
  cannot be trapped, and BFGS, which keeps its Hessian estimate positive
  definite, also descends the non-concave likelihood with fitted guess and
  lapse rates, where a plain Newton step could climb;
- the line search also accepts steps whose predicted decrease is below the
  rounding error of the objective (see :class:`_Backtracking`), so that BFGS
  converges to machine precision instead of stalling within ``sqrt(eps)``.

The tolerance follows the dtype (``eps**0.7``: 1e-11 in float64, 1.4e-5 in
float32); with fitted rates the fit also stops when the log-likelihood a
further step could gain is below ``sqrt(eps)/2`` (see :class:`_BFGS`). A
typical dataset takes 6-14 iterations, a separated one up to about 40. In
float64 the estimates agree with statsmodels' to about 1e-8 relative (the
precision of statsmodels' own IRLS); in float32 the PSEs agree with the
float64 ones to about 1e-5 log units.

Fitted rates are ``low + (high - low) sigmoid(u)`` with a weak Gaussian prior
(standard deviation ``PRIOR_SD`` = 10) on ``u``, which keeps a rate that wants
to leave its bounds finite (within about 1% of its range from the bound) and
the information matrix invertible. The estimate is then the posterior mode,
not the maximum of the likelihood, where the likelihood's maximum lies near
a bound: on 7 levels of 40 trials, ``lapse=(0, 0.2)``, a lapse rate of
0.0138 against the bounded maximum's 0.0030 (SciPy's L-BFGS-B on the same
likelihood), the log-likelihood 0.010 lower and the slope's standard error
24% smaller. Rates held fixed (the default, and the command line's) are
plain maximum likelihood.

Degenerate data
---------------
No output is ever NaN. The data flags (bits of :attr:`Fit.flags`) are

| flag | bit | meaning |
| --- | --- | --- |
| ``ALL_SAME`` | 1 | every response is "yes", or every one "no" |
| ``SEPARATION`` | 2 | the levels separate yes from no responses, completely or quasi-completely |
| ``SINGLE_LEVEL`` | 4 | fewer than two distinct levels have trials |
| ``EXTRAPOLATED`` | 8 | the PSE lies outside the tested levels |
| ``FLAT`` | 16 | the slope is (numerically) zero |

With ``ALL_SAME``, ``SEPARATION`` or ``SINGLE_LEVEL`` the maximum-likelihood
estimate does not exist (or is not unique); those datasets are fitted with a
weak Gaussian prior, standard deviation ``PRIOR_SD`` = 10, on the
standardised intercept and slope, which gives finite estimates (a steep but finite slope under
separation) and a positive-definite information matrix. The PSE and sigma are
computed with the standardised slope kept at least ``1e-6`` in magnitude
(``FLAT`` is set when that bound is used), so that a flat function gives a very
large but finite PSE. A flat function counts as increasing, as a
psychometric function of the test level is: every response "no" puts the
PSE far above the tested levels and every one "yes" far below them, on the
side the data imply (the slope of such data is 0 at the optimum, and is set
to 0: the solver leaves it within its tolerance, whose sign would
otherwise pick the side, and a group test would rank the participant at
either end). ``EXTRAPOLATED`` PSEs are returned, as the paper
does for its participant 11, and flagged.

References
----------
Jacobs, Gallo, Cooper, Pulli, Levoy (2015), *Simulating the Visual Experience
of Very Bright and Very Dark Scenes*, ACM TOG 34(3), §4.1.2.
Wichmann, Hill (2001), *The psychometric
function I and II*, Perception & Psychophysics 63 (lapse rates, bootstrap).
"""

from collections.abc import Callable
from functools import partial
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jax.scipy.special import gammaln, log_ndtr, ndtr, xlogy
from jax.sharding import AxisType, NamedSharding
from jax.sharding import PartitionSpec as P

from jaxadapt._checks import check_whole
from jaxadapt.fitting import NEWTON_STEP
from jaxadapt.operators.checks import plain_errors

ALL_SAME = 1
SEPARATION = 2
SINGLE_LEVEL = 4
EXTRAPOLATED = 8
FLAT = 16
#: Names of the flag bits, in bit order.
FLAG_NAMES = {
    ALL_SAME: "all_same",
    SEPARATION: "separation",
    SINGLE_LEVEL: "single_level",
    EXTRAPOLATED: "extrapolated",
    FLAT: "flat",
}
#: Flags under which the maximum-likelihood estimate does not exist.
NO_MLE = ALL_SAME | SEPARATION | SINGLE_LEVEL
#: Flags under which the data place no PSE: it is set by the prior and the
#: least slope (under separation it still lies between two levels).
NO_PSE = ALL_SAME | SINGLE_LEVEL | FLAT

#: Standard deviation of the weak Gaussian priors: on the standardised
#: intercept and slope when the MLE does not exist (``NO_MLE``), and on the
#: logit ``u`` of fitted rates.
PRIOR_SD = 10.0
#: Smallest standardised slope |b1 s| used for the PSE and sigma (``FLAT``).
MIN_SLOPE = 1e-6
#: Default iteration cap of BFGS.
MAX_STEPS = 256


class Fit(NamedTuple):
    """A fitted psychometric function; every field has the datasets' batch
    shape.

    Attributes
    ----------
    b0, b1 : array
        Probit intercept and slope (per log10 unit), as glmfit returns them.
    pse : array
        Point of subjective equality ``mu = -b0/b1``, log10 units.
    sigma : array
        Spread ``1/b1``, log10 units (negative for a decreasing function).
    guess, lapse : array
        Guess and lapse rates, fixed or fitted.
    se_b0, se_b1, se_pse, se_sigma : array
        Standard errors from the observed information (the inverse Hessian of
        the negative log-likelihood at the estimate, fitted rates included),
        by the delta method for ``pse`` and ``sigma``; ``inf`` when undefined.
    loglik : array
        Log-likelihood of the counts, binomial coefficients included (as
        statsmodels' ``llf``). A sum of terms of order ``n log n`` that
        cancel: its rounding is about ``eps n log n``, in float32 0.01 at
        3,000 trials a level and more beyond (``jaxadapt psychometric fit``
        fits in float64).
    deviance : array
        ``2 (loglik_saturated - loglik)``, rounded likewise, and set to 0
        where rounding makes it negative.
    converged : array of bool
        Whether the optimiser met its tolerance within ``max_steps`` and a
        Newton step from the estimate (exact Hessian) would move it by at
        most ``jaxadapt.fitting.NEWTON_STEP`` (0.1) standard errors.
    flags : array of int
        Bit flags, see the module notes and :func:`flag_names`.
    """

    b0: jax.Array
    b1: jax.Array
    pse: jax.Array
    sigma: jax.Array
    guess: jax.Array
    lapse: jax.Array
    se_b0: jax.Array
    se_b1: jax.Array
    se_pse: jax.Array
    se_sigma: jax.Array
    loglik: jax.Array
    deviance: jax.Array
    converged: jax.Array
    flags: jax.Array


class Bootstrap(NamedTuple):
    """Bootstrap confidence intervals around a fit.

    Attributes
    ----------
    fit : Fit
        The fit of the original data.
    pse_ci, slope_ci : array, shape (..., 2)
        Percentile intervals ``(low, high)`` for the PSE (log10 units) and the
        slope ``b1`` (per log10 unit); the interval for sigma is the
        reciprocal of ``slope_ci``.
    pse_se, slope_se : array
        Standard deviations of the resampled PSEs and slopes.
    flagged : array
        Fraction of resamples whose data had ``NO_MLE`` flags or whose fit did
        not converge.
    """

    fit: Fit
    pse_ci: jax.Array
    slope_ci: jax.Array
    pse_se: jax.Array
    slope_se: jax.Array
    flagged: jax.Array


def flag_names(flags):
    """Names of the bits set in one integer flag value.

    >>> flag_names(SEPARATION | EXTRAPOLATED)
    ('separation', 'extrapolated')
    """
    return tuple(name for bit, name in FLAG_NAMES.items() if int(flags) & bit)


def psychometric(x, pse, sigma, guess=0.0, lapse=0.0):
    """``P(x) = guess + (1 - guess - lapse) Phi((x - pse) / sigma)``.

    Parameters
    ----------
    x : array
        Test levels, log10 units relative to the standard.
    pse, sigma : array
        Location and spread, log10 units.
    guess, lapse : array, optional
        Lower and upper asymptote offsets, probabilities.

    Returns
    -------
    array
        Probability of a "test brighter" response.

    Examples
    --------
    >>> float(psychometric(0.1, 0.1, 0.2))
    0.5
    """
    return guess + (1.0 - guess - lapse) * ndtr((x - pse) / sigma)


def sample_counts(key, n_total, p):
    """Binomial counts of "yes" responses, ``n_yes ~ Binomial(n_total, p)``.

    Parameters
    ----------
    key : PRNG key
    n_total : array
        Trials per level.
    p : array
        Probability of "yes" per level, broadcast against ``n_total``.

    Returns
    -------
    array
        Counts in ``p``'s floating dtype, same key same counts.
    """
    n_total, p = jnp.broadcast_arrays(n_total, p)
    return jax.random.binomial(key, n_total.astype(p.dtype), p)


# -- rates --------------------------------------------------------------------


class _Rate(eqx.Module):
    """A guess or lapse rate: fixed (``low == high``) or fitted in
    ``[low, high]`` as ``low + (high - low) * sigmoid(u)``."""

    low: jax.Array
    high: jax.Array
    free: bool = eqx.field(static=True)

    def log(self, u):
        if not self.free:
            return jnp.log(self.low)
        return jnp.logaddexp(
            jnp.log(self.low), jnp.log(self.high - self.low) + jax.nn.log_sigmoid(u)
        )


def _rate(value, name):
    """Parse ``guess=``/``lapse=``: a number or array is fixed, a pair
    ``(low, high)`` is fitted within those bounds."""
    if isinstance(value, tuple | list):
        if len(value) != 2 or not 0.0 <= value[0] < value[1] < 1.0:
            raise ValueError(
                f"{name}: expected a fixed rate or bounds (low, high) with "
                f"0 <= low < high < 1, got {value!r}"
            )
        low, high = (jnp.asarray(v, dtype=jnp.result_type(float)) for v in value)
        return _Rate(low, high, free=True)
    value = jnp.asarray(value, dtype=jnp.result_type(float))
    return _Rate(value, value, free=False)


# -- one dataset --------------------------------------------------------------


class _Data(NamedTuple):
    """One dataset, standardised: ``z = (x - c) / s``."""

    z: jax.Array
    k: jax.Array
    n: jax.Array
    c: jax.Array
    s: jax.Array
    lo: jax.Array
    hi: jax.Array
    flags: jax.Array


def _prepare(x, k, n):
    """Standardise the levels and flag data for which no MLE exists."""
    total = jnp.sum(n)
    w = n / jnp.maximum(total, 1.0)
    c = jnp.sum(w * x)
    s = jnp.sqrt(jnp.sum(w * (x - c) ** 2))

    def lowest(mask):
        return jnp.min(jnp.where(mask, x, jnp.inf))

    def highest(mask):
        return jnp.max(jnp.where(mask, x, -jnp.inf))

    valid = n > 0
    yes, no = valid & (k > 0), valid & (k < n)
    lo, hi = lowest(valid), highest(valid)
    single = ~(hi > lo)
    all_same = ~jnp.any(yes) | ~jnp.any(no)
    increasing = highest(no) <= lowest(yes)  # every "no" at or below every "yes"
    decreasing = highest(yes) <= lowest(no)
    separated = (increasing | decreasing) & ~all_same & ~single
    flags = ALL_SAME * all_same + SEPARATION * separated + SINGLE_LEVEL * single
    s = jnp.where(single, 1.0, s)
    return _Data((x - c) / s, k, n, jnp.where(total > 0, c, 0.0), s, lo, hi, flags)


def _unpack(theta, guess, lapse):
    """``theta = (a0, a1, u_guess?, u_lapse?)`` to ``(a, log_guess, log_lapse)``."""
    free = iter(theta[2:])
    log_guess = guess.log(next(free) if guess.free else None)
    log_lapse = lapse.log(next(free) if lapse.free else None)
    return theta[:2], log_guess, log_lapse


def _nll(theta, data, guess, lapse):
    """Negative log-likelihood of the counts, without binomial coefficients."""
    a, log_guess, log_lapse = _unpack(theta, guess, lapse)
    eta = a[0] + a[1] * data.z
    log_scale = jnp.log1p(-jnp.exp(log_guess) - jnp.exp(log_lapse))
    log_p = jnp.logaddexp(log_guess, log_scale + log_ndtr(eta))
    log_q = jnp.logaddexp(log_lapse, log_scale + log_ndtr(-eta))
    return -jnp.sum(data.k * log_p + (data.n - data.k) * log_q)


def _objective(theta, data, guess, lapse):
    """``_nll`` plus the weak priors: on the standardised intercept and slope
    when the MLE does not exist, and always on the free rate parameters ``u``
    (which keeps a rate at its bound finite and the Hessian invertible)."""
    a, u = theta[:2], theta[2:]
    a_prior = jnp.where(data.flags & NO_MLE, jnp.sum(a**2), 0.0)
    prior = 0.5 * (a_prior + jnp.sum(u**2)) / PRIOR_SD**2
    return _nll(theta, data, guess, lapse) + prior


def _start(data):
    """One IRLS step from glmfit's start, ``mu = (k + 1/2) / (n + 1)``."""
    mu = (data.k + 0.5) / (data.n + 1.0)
    eta = jax.scipy.special.ndtri(mu)
    w = data.n * jnp.exp(2 * jax.scipy.stats.norm.logpdf(eta)) / (mu * (1 - mu))
    w = w / jnp.maximum(jnp.sum(w), jnp.finfo(w.dtype).tiny)
    z_mean, eta_mean = jnp.sum(w * data.z), jnp.sum(w * eta)
    var = jnp.sum(w * (data.z - z_mean) ** 2)
    cov = jnp.sum(w * (data.z - z_mean) * (eta - eta_mean))
    a1 = jnp.where(var > 0, cov / jnp.where(var > 0, var, 1.0), 0.0)
    return jnp.stack([eta_mean - a1 * z_mean, a1])


def _se(var):
    """Standard error, ``inf`` where the variance is not a finite non-negative
    number."""
    ok = jnp.isfinite(var) & (var >= 0)
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, var, 0.0)), jnp.inf)


class _Backtracking(optx.AbstractSearch):
    """Backtracking Armijo line search that also accepts a step whose
    predicted decrease is below the rounding error of ``f``.

    ``optimistix.BacktrackingArmijo`` halves the step until ``f`` decreases by
    a tenth of the predicted amount. Within about ``sqrt(eps)`` of the minimum
    the decrease of ``f`` is lost in rounding, that test fails for every step
    size, and the solver loops to ``max_steps`` (and, under ``vmap``, makes
    the whole batch do so). The gradient is still accurate there, so such a
    step is a sound quasi-Newton step: accepting it lets BFGS converge to
    machine precision in the parameters.
    """

    def init(self, y, f_info_struct):
        return jnp.ones((), y.dtype)

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        predicted = f_info.compute_grad_dot(y_eval - y)
        decrease = f_eval_info.f - f_info.f
        descent = predicted <= 0
        armijo = (decrease <= 0.1 * predicted) & descent
        negligible = descent & (-predicted <= jnp.finfo(y.dtype).eps * jnp.abs(f_info.f))
        accept = first_step | ((armijo | negligible) & jnp.isfinite(f_eval_info.f))
        step_size = jnp.where(accept, 1.0, 0.5 * state).astype(y.dtype)
        return step_size, accept, optx.RESULTS.successful, step_size


def _quiet(**kwargs):
    del kwargs


class _BFGS(optx.AbstractBFGS):
    """``optimistix.BFGS`` with the :class:`_Backtracking` search, started
    from a given inverse Hessian instead of the identity, kept positive
    definite, and also stopped by the Newton decrement.

    optimistix updates the inverse Hessian whenever ``y' s`` exceeds ``eps``
    in absolute terms; in float32 the update of a short step can then lose
    positive definiteness to rounding (a fitted lapse rate's flat valley),
    after which the decrement below is negative, the solve stopped 0.27
    log-likelihood units short of the optimum and said it had converged.
    An update that is not positive definite (its Cholesky factor not
    finite) is not made: the estimate stays the last positive-definite one.

    The objective is the negative log-likelihood per trial; the solver also
    stops when ``trials * g' H^-1 g``, twice the gain in log-likelihood that
    a full quasi-Newton step predicts, is at most ``decrement_tol`` (Boyd and
    Vandenberghe 2004, §9.5.1). With fitted rates the likelihood can have a
    flat valley (the slope traded against a lapse rate) along which BFGS
    creeps by steps far below the standard errors yet above the parameter
    tolerance; this rule stops it there. BFGS's estimate of ``H^-1`` can be
    poor along such a valley, so :func:`_fit_one` checks the stop with the
    exact Hessian. The probit likelihood alone is strictly convex and uses
    ``decrement_tol = 0``.
    """

    rtol: float
    atol: float
    hessian_inv: jax.Array
    trials: jax.Array
    decrement_tol: float
    norm: Callable = optx.max_norm
    use_inverse: bool = True
    descent: optx.NewtonDescent = optx.NewtonDescent()
    search: _Backtracking = _Backtracking()
    verbose: Callable = _quiet

    def init_hessian(self, y, f, grad):
        structure = jax.eval_shape(lambda: y)
        inverse = lx.PyTreeLinearOperator(self.hessian_inv, structure, lx.positive_semidefinite_tag)
        return optx.FunctionInfo.EvalGradHessianInv(f, grad, inverse), None

    def update_hessian(self, y, y_eval, f_info, f_eval_info, hessian_update_state):
        new, state = super().update_hessian(y, y_eval, f_info, f_eval_info, hessian_update_state)
        matrix = new.hessian_inv.as_matrix()
        positive = jnp.all(jnp.isfinite(jnp.linalg.cholesky(matrix)))
        inverse = lx.PyTreeLinearOperator(
            jnp.where(positive, matrix, f_info.hessian_inv.as_matrix()),
            new.hessian_inv.out_structure(),
            lx.positive_semidefinite_tag,
        )
        return optx.FunctionInfo.EvalGradHessianInv(new.f, new.grad, inverse), state

    def terminate(self, fn, y, args, options, state, tags):
        done, result = super().terminate(fn, y, args, options, state, tags)
        info = state.f_info
        decrement = self.trials * jnp.dot(info.grad, info.hessian_inv.mv(info.grad))
        return done | ((state.num_accepted_steps > 0) & (decrement <= self.decrement_tol)), result


def _inverse_if_positive_definite(H):
    """``inv(H)`` by Cholesky, or the identity where ``H`` is not positive
    definite."""
    L = jnp.linalg.cholesky(H)
    eye = jnp.eye(H.shape[0], dtype=H.dtype)
    ok = jnp.all(jnp.isfinite(L))
    inverse = jax.scipy.linalg.cho_solve((jnp.where(ok, L, eye), True), eye)
    return jnp.where(ok, inverse, eye)


def _solve(data, guess, lapse, max_steps):
    """Minimise the objective per trial with BFGS, from the IRLS start and the
    exact inverse Hessian there (the identity if it is not positive definite,
    as can happen with fitted rates).

    Returns ``(theta, converged)``.
    """
    n_free = guess.free + lapse.free
    theta0 = jnp.concatenate([_start(data), jnp.zeros(n_free, data.z.dtype)])
    total = jnp.maximum(jnp.sum(data.n), 1.0)

    def per_trial(theta, _):
        return _objective(theta, data, guess, lapse) / total

    eps = float(jnp.finfo(data.z.dtype).eps)
    solver = _BFGS(
        rtol=eps**0.7,
        atol=eps**0.7,
        hessian_inv=_inverse_if_positive_definite(jax.hessian(per_trial)(theta0, None)),
        trials=total,
        decrement_tol=eps**0.5 if n_free else 0.0,
    )
    solution = optx.minimise(
        per_trial,
        solver,
        theta0,
        max_steps=max_steps,
        throw=False,
    )
    return solution.value, solution.result == optx.RESULTS.successful


def _fit_one(x, k, n, guess, lapse, max_steps):
    data = _prepare(x, k, n)
    dtype = x.dtype
    theta, converged = _solve(data, guess, lapse, max_steps)
    # Responses all the same: the slope's optimum is 0. The levels are
    # centred on their trial-weighted mean, so at a1 = 0 the likelihood's
    # derivative along a1, sum n_i z_i h'(a0), is 0, as is the prior's (and
    # with fixed rates the objective is convex: Phi and 1 - Phi are
    # log-concave). The solver stops within its tolerance of it, in float32
    # at |a1| up to 0.15, whose sign would put the PSE on either side of
    # the levels (module notes): set to 0.
    all_same = (data.flags & ALL_SAME) > 0
    theta = theta.at[1].set(jnp.where(all_same, 0.0, theta[1]))
    (a0, a1), log_guess, log_lapse = _unpack(theta, guess, lapse)
    inverse = jnp.linalg.inv(jax.hessian(_objective)(theta, data, guess, lapse))
    cov_a = inverse[:2, :2]
    # The solver's tolerances can be met short of the optimum in the flat
    # valley of fitted rates (_BFGS): converged only where a Newton step
    # would move the estimates by at most NEWTON_STEP standard errors, the
    # Newton decrement |g' H^-1 g| with the exact Hessian (its magnitude:
    # along a direction of numerically zero, negative curvature, where the
    # likelihood is flat, its sign is rounding).
    gradient = jax.grad(_objective)(theta, data, guess, lapse)
    converged = converged & (jnp.abs(gradient @ inverse @ gradient) <= NEWTON_STEP**2)

    flat = jnp.abs(a1) < MIN_SLOPE
    a1_safe = jnp.where(flat, MIN_SLOPE, a1)  # flat counts as increasing (module notes)
    pse = data.c - data.s * a0 / a1_safe
    sigma = data.s / a1_safe
    # b = J a with J = [[1, -c/s], [0, 1/s]]; the PSE's gradient in a-space.
    J = jnp.array([[1.0, -data.c / data.s], [0.0, 1.0 / data.s]], dtype)
    cov_b = J @ cov_a @ J.T
    g_pse = jnp.array([-data.s / a1_safe, data.s * a0 / a1_safe**2], dtype)

    nll = _nll(theta, data, guess, lapse)
    log_binom = gammaln(n + 1) - gammaln(k + 1) - gammaln(n - k + 1)
    loglik = jnp.sum(log_binom) - nll
    p_obs = k / jnp.where(n > 0, n, 1.0)
    loglik_sat = jnp.sum(log_binom + xlogy(k, p_obs) + xlogy(n - k, 1.0 - p_obs))
    extrapolated = (pse < data.lo) | (pse > data.hi)
    flags = data.flags + EXTRAPOLATED * extrapolated + FLAT * flat
    return Fit(
        b0=a0 - a1 * data.c / data.s,
        b1=a1 / data.s,
        pse=pse,
        sigma=sigma,
        guess=jnp.exp(log_guess),
        lapse=jnp.exp(log_lapse),
        se_b0=_se(cov_b[0, 0]),
        se_b1=_se(cov_b[1, 1]),
        se_pse=_se(g_pse @ cov_a @ g_pse),
        se_sigma=_se(cov_a[1, 1]) * data.s / a1_safe**2,
        loglik=loglik,
        deviance=jnp.maximum(2.0 * (loglik_sat - loglik), 0.0),  # >= 0 but for rounding
        converged=converged,
        flags=flags.astype(jnp.int32),
    )


# -- batches ------------------------------------------------------------------


def _inputs(levels, n_yes, n_total, guess, lapse):
    """Arrays in one float dtype, broadcast to ``(..., L)``; rates parsed and
    broadcast to the batch shape ``(...)``."""
    names = ("levels", "n_yes", "n_total")
    arrays = [jnp.asarray(a) for a in (levels, n_yes, n_total)]
    try:
        shape = jnp.broadcast_shapes(*(a.shape for a in arrays))
    except ValueError:
        got = ", ".join(f"{n} {a.shape}" for n, a in zip(names, arrays, strict=True))
        raise ValueError(
            f"levels, n_yes, n_total: expected broadcastable shapes, got {got}"
        ) from None
    if not shape or shape[-1] == 0:
        raise ValueError(
            "levels: expected an array with levels on the last axis, got "
            + ("a scalar" if not shape else f"shape {shape}, no levels")
        )
    # The arrays, not their dtypes: a Python number keeps JAX's weak type and
    # follows the arrays (n_total=30.0 made float32 data a float64 fit).
    dtype = jnp.result_type(*arrays, float)
    levels, n_yes, n_total = (jnp.broadcast_to(a.astype(dtype), shape) for a in arrays)
    guess, lapse = (
        _batch_rate(v, n, shape[:-1], dtype) for v, n in ((guess, "guess"), (lapse, "lapse"))
    )
    return levels, n_yes, n_total, guess, lapse


def _batch_rate(value, name, batch, dtype):
    """:func:`_rate` of ``value`` in ``dtype``, broadcast to the batch shape."""
    rate = _rate(value, name)
    try:
        fits = jnp.broadcast_shapes(rate.low.shape, batch) == batch
    except ValueError:
        fits = False
    if not fits:
        raise ValueError(
            f"{name}: expected a rate of the batch shape {batch} or one that "
            f"broadcasts to it, got shape {rate.low.shape}"
        )
    return jax.tree.map(lambda r: jnp.broadcast_to(r.astype(dtype), batch), rate)


def _check(levels, n_yes, n_total, guess, lapse):
    """Value checks inside jit (finite levels, valid counts and rates)."""
    levels = eqx.error_if(
        levels, ~jnp.all(jnp.isfinite(levels)), "levels: expected finite log10 levels"
    )
    bad = ~jnp.all(jnp.isfinite(n_total) & (n_total >= 0) & (n_yes >= 0) & (n_yes <= n_total))
    n_yes = eqx.error_if(n_yes, bad, "n_yes, n_total: expected finite 0 <= n_yes <= n_total")
    bad = jnp.any((guess.low < 0) | (lapse.low < 0) | (guess.high + lapse.high >= 1))
    guess = eqx.error_if(guess, bad, "guess, lapse: expected rates >= 0 with guess + lapse < 1")
    return levels, n_yes, n_total, guess, lapse


def _over_datasets(fn, levels, n_yes, n_total, guess, lapse, *batched):
    """``vmap`` a one-dataset function over the flattened batch ``(...)`` and
    restore that batch shape on its outputs."""
    batch, L = levels.shape[:-1], levels.shape[-1]
    flat = [a.reshape(-1, L) for a in (levels, n_yes, n_total)]
    flat += [jax.tree.map(lambda r: r.reshape(-1), r) for r in (guess, lapse)]
    flat += [jax.tree.map(lambda b: b.reshape((-1,) + b.shape[len(batch) :]), b) for b in batched]
    out = jax.vmap(fn)(*flat)
    return jax.tree.map(lambda a: a.reshape(batch + a.shape[1:]), out)


def _fit_batch(levels, n_yes, n_total, guess, lapse, max_steps):
    """Fit ``(..., L)`` arrays (already checked), one ``vmap`` over the
    datasets."""
    return _over_datasets(
        partial(_fit_one, max_steps=max_steps), levels, n_yes, n_total, guess, lapse
    )


#: The value checks as a program of their own, before the fit's: a program
#: that raises from inside does so through a host callback, and JAX's
#: persistent compilation cache keeps no such program
#: (:func:`jaxadapt.runtime.cache_compilations`).
_checked = eqx.filter_jit(_check)


def _checked_inputs(levels, n_yes, n_total, guess, lapse):
    """:func:`_inputs`, then their values :func:`_checked`."""
    return _checked(*_inputs(levels, n_yes, n_total, guess, lapse))


@eqx.filter_jit
def _fit(levels, n_yes, n_total, guess, lapse, max_steps):
    """:func:`_fit_batch` compiled, on inputs already :func:`_checked`."""
    if int(max_steps) < 1:  # static: checked once per value, when traced
        raise ValueError(f"max_steps: expected at least 1, got {max_steps}")
    return _fit_batch(levels, n_yes, n_total, guess, lapse, max_steps)


@plain_errors
def fit(levels, n_yes, n_total, *, guess=0.0, lapse=0.0, max_steps=MAX_STEPS):
    """Fit cumulative Gaussians to binomial counts, all datasets at once.

    Parameters
    ----------
    levels : array, shape (..., L)
        Test levels, log10 units relative to the standard (any finite unit
        works; the estimates are in it).
    n_yes : array, shape (..., L)
        Number of "test brighter" responses per level.
    n_total : array, shape (..., L)
        Number of trials per level; levels with 0 trials are padding and
        ignored. The three arrays broadcast against each other (e.g. levels of
        shape ``(L,)`` shared by all datasets). Counts need not be integers
        (they act as weights).
    guess, lapse : float, array or (low, high), optional
        A number or an array of the batch shape fixes the rate (default 0, the
        plain probit of glmfit); a pair ``(low, high)`` fits it within those
        bounds, as ``low + (high - low) sigmoid(u)`` with ``u`` free, as
        psignifit and psychofit allow.
    max_steps : int, optional
        Iteration cap of the optimiser; ``converged`` is false where reached.

    Returns
    -------
    Fit
        Fields of the batch shape ``(...)``, in the inputs' floating dtype.

    Raises
    ------
    ValueError
        Scalars, shapes that do not broadcast, malformed rate bounds.
    equinox.EquinoxRuntimeError
        Non-finite levels, counts with ``n_yes > n_total`` or negative, rates
        outside ``[0, 1)`` or summing to 1 or more.

    Notes
    -----
    Equivalent to ``glmfit(x, [k n], 'binomial', 'link', 'probit')``:
    ``b0, b1`` are its coefficients, ``pse = -b0/b1`` and ``sigma = 1/b1``.
    See the module notes for the optimiser, the flags and degenerate data.
    With fitted or non-zero rates the PSE is still ``-b0/b1``, the midpoint of
    the Gaussian, which is the 50% point only when ``guess == lapse``.

    Examples
    --------
    >>> x = jnp.log10(jnp.array([14.0, 19, 27, 35, 49]) / 27)
    >>> f = fit(x, jnp.array([3, 8, 15, 22, 27]), jnp.full(5, 30))
    >>> round(float(f.pse), 4), round(float(f.sigma), 4), bool(f.converged)
    (-0.0128, 0.2129, True)
    >>> fit(x, jnp.zeros((4, 7, 5)), 30).pse.shape  # 4 x 7 datasets
    (4, 7)
    """
    return _fit(*_checked_inputs(levels, n_yes, n_total, guess, lapse), max_steps)


# -- bootstrap ----------------------------------------------------------------

METHODS = ("parametric", "nonparametric")


class _Intervals(NamedTuple):
    pse_ci: jax.Array
    slope_ci: jax.Array
    pse_se: jax.Array
    slope_se: jax.Array
    flagged: jax.Array


#: Bytes that one resample's fit takes in a vmapped bootstrap call, its
#: solver state and temporaries: 1.84 KB in float64, measured as the growth
#: of peak memory from 8,000 to 1,024,000 fits in one call.
FIT_BYTES = 2048
#: Bytes of memory a :func:`bootstrap` call holds at once by default: 256 MiB.
BOOTSTRAP_BUDGET = 2**28


def _draws(x, k, n, guess, lapse, key, fit, parametric, first, count, max_steps):
    """Resamples ``first`` to ``first + count - 1`` of one dataset, refitted:
    their PSEs, slopes and whether each is flagged. Resample ``r`` draws its
    counts from ``fold_in(key, r)``, so a resample does not depend on the
    block it is drawn in."""
    p_fit = psychometric(x, fit.pse, fit.sigma, fit.guess, fit.lapse)
    p = jnp.where(parametric, p_fit, k / jnp.where(n > 0, n, 1.0))
    keys = jax.vmap(partial(jax.random.fold_in, key))(first + jnp.arange(count))
    counts = jax.vmap(lambda kr: sample_counts(kr, n, p))(keys)
    boot = jax.vmap(lambda c: _fit_one(x, c, n, guess, lapse, max_steps))(counts)
    flagged = ((boot.flags & NO_MLE) > 0) | ~boot.converged
    return boot.pse, boot.b1, flagged


@eqx.filter_jit
def _draw_block(levels, n_yes, n_total, guess, lapse, keys, fits, parametric, first, static):
    """:func:`_draws` of a batch of datasets ``(B, L)``: arrays ``(B, count)``."""
    one = partial(_draws, parametric=parametric, first=first, **static)
    return jax.vmap(one)(levels, n_yes, n_total, guess, lapse, keys, fits)


@jax.jit
def _summary(pse, b1, flagged, confidence):
    """Percentile intervals, standard deviations and the flagged fraction of
    resampled PSEs and slopes ``(B, R)``."""
    q = jnp.stack([(1 - confidence) / 2, (1 + confidence) / 2]).astype(pse.dtype)
    return _Intervals(
        pse_ci=jnp.moveaxis(jnp.quantile(pse, q, axis=-1), 0, -1),
        slope_ci=jnp.moveaxis(jnp.quantile(b1, q, axis=-1), 0, -1),
        pse_se=jnp.std(pse, axis=-1),
        slope_se=jnp.std(b1, axis=-1),
        flagged=jnp.mean(flagged.astype(pse.dtype), axis=-1),
    )


def bootstrap_blocks(n_datasets, n_resamples, budget=BOOTSTRAP_BUDGET):
    """Datasets and resamples per compiled call of :func:`bootstrap`, within
    ``budget`` bytes (:data:`FIT_BYTES` a resample): all resamples of as
    many datasets as fit, or blocks of one dataset's resamples where even
    one dataset's do not. The datasets are a power of two (at most the
    next one above ``n_datasets``), so that tables of nearby sizes share a
    compiled program.

    >>> bootstrap_blocks(10_000, 1000), bootstrap_blocks(6, 1_000_000), bootstrap_blocks(3, 100)
    ((128, 1000), (1, 131072), (4, 100))
    """
    fits = max(1, budget // FIT_BYTES)
    resamples = min(n_resamples, fits)
    datasets = 1 << max(0, (fits // resamples).bit_length() - 1)  # a power of two, <= fits
    return min(datasets, 1 << max(0, n_datasets - 1).bit_length()), resamples


def _rows(tree, rows):
    """The datasets ``rows`` of a pytree of batched arrays ``(D, ...)``."""
    return jax.tree.map(lambda a: a[rows], tree)


@plain_errors
def bootstrap(
    key,
    levels,
    n_yes,
    n_total,
    *,
    n_resamples=1000,
    method="parametric",
    confidence=0.95,
    guess=0.0,
    lapse=0.0,
    max_steps=MAX_STEPS,
    budget=BOOTSTRAP_BUDGET,
    progress=None,
):
    """Fit, and bootstrap confidence intervals for the PSE and the slope.

    Parameters
    ----------
    key : PRNG key
        Same key, same resamples.
    levels, n_yes, n_total, guess, lapse, max_steps
        As for :func:`fit`; each resample is fitted the same way.
    n_resamples : int, optional
        Resamples per dataset.
    method : {"parametric", "nonparametric"}, optional
        Parametric: counts drawn from the fitted function,
        ``Binomial(n_total, P_fit(x))``. Non-parametric: trials resampled with
        replacement within each level, which is ``Binomial(n_total, k/n)``.
    confidence : float, optional
        Coverage of the percentile intervals.
    budget : int, optional
        Bytes of memory the resampled fits hold at once
        (:func:`bootstrap_blocks`); the results do not depend on it.
    progress : callable, optional
        Called with the number of datasets done after each batch.

    Returns
    -------
    Bootstrap
        With the fit of the data, intervals of shape ``(..., 2)``.

    Notes
    -----
    Percentile intervals (Wichmann and Hill 2001b, §2). Resamples whose data
    are degenerate keep their finite, flagged estimates (see the module notes)
    and count in ``flagged``. The datasets are fitted and resampled in
    batches (:func:`bootstrap_blocks`), the last padded with copies of its
    first dataset, so that memory does not grow with the number of datasets
    or resamples and one program serves every batch.

    Examples
    --------
    >>> x = jnp.log10(jnp.array([14.0, 19, 27, 35, 49]) / 27)
    >>> b = bootstrap(jax.random.key(0), x, jnp.array([3, 8, 15, 22, 27]), 30,
    ...               n_resamples=200)
    >>> bool(b.pse_ci[0] < b.fit.pse < b.pse_ci[1])
    True
    """
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence: expected a number in (0, 1), got {confidence!r}")
    R = check_whole("n_resamples", n_resamples, least=2)
    budget = check_whole("budget", budget, least=1, unit="bytes")
    levels, n_yes, n_total, guess, lapse = _checked_inputs(levels, n_yes, n_total, guess, lapse)
    batch, L = levels.shape[:-1], levels.shape[-1]
    data = (
        levels.reshape(-1, L),
        n_yes.reshape(-1, L),
        n_total.reshape(-1, L),
        *(jax.tree.map(lambda r: r.reshape(-1), rate) for rate in (guess, lapse)),
    )
    D = data[0].shape[0]
    keys = jax.random.split(key, D)
    B, block = bootstrap_blocks(D, R, budget)
    parametric, confidence = jnp.asarray(method == "parametric"), jnp.asarray(confidence)
    static = dict(count=block, max_steps=int(max_steps))
    results = []
    for start in range(0, D, B):
        rows = np.minimum(np.arange(start, start + B), D - 1)  # padded with the last
        part = _rows(data, rows)
        fits = _fit(*part, max_steps)
        draws = [
            _draw_block(*part, keys[rows], fits, parametric, jnp.asarray(first), static)
            for first in range(0, R, block)
        ]
        pse, b1, flagged = (jnp.concatenate(d, axis=-1)[:, :R] for d in zip(*draws, strict=True))
        done = min(B, D - start)
        results.append(_rows((fits, *_summary(pse, b1, flagged, confidence)), slice(done)))
        if progress is not None:
            progress(done)
    out = jax.tree.map(lambda *a: jnp.concatenate(a).reshape(batch + a[0].shape[1:]), *results)
    return Bootstrap(*out)


# -- several devices ----------------------------------------------------------


@eqx.filter_jit
def _on_mesh(fn, sharding, args, options):
    return jax.lax.with_sharding_constraint(fn(*args, **options), sharding)


def map_sharded(fn, *args, mesh=None, **options):
    """Run a batched function with its batch axis split across devices.

    Parameters
    ----------
    fn : callable
        ``fn(*args, **options)`` maps arrays whose leading axis is a batch to
        outputs with the same leading axis, each batch element independently
        (e.g. a ``vmap``-ped fit of ``(B, L)`` counts). A module-level
        function, so that repeated calls reuse the compiled program.
    *args : pytrees of arrays
        Leading axis of the same length ``B`` on every leaf.
    mesh : jax.sharding.Mesh, optional
        Devices to use, its axes all along the batch (default: every device,
        one axis named ``"batch"``).
    **options
        Static keyword arguments of ``fn`` (Python numbers, strings).

    Returns
    -------
    pytree
        ``fn``'s output for the ``B`` elements.

    Notes
    -----
    The batch is padded to a multiple of the number of devices with copies
    of its last element, placed with ``NamedSharding(mesh, P(axes))``, and
    ``fn`` is compiled once for the mesh: XLA gives each device its slice of
    the batch (the only communication is the all-reduce of a ``while`` loop's
    stopping test). Each element is computed by the same operations as on
    one device; the results agree with the single-device ones to rounding
    (a different slice size can change how XLA vectorises the arithmetic).
    """
    if mesh is None:
        mesh = jax.make_mesh((jax.device_count(),), ("batch",), (AxisType.Auto,))
    leaves = jax.tree.leaves(args)
    B = leaves[0].shape[0]
    if any(leaf.shape[:1] != (B,) for leaf in leaves):
        raise ValueError(
            f"args: expected a common leading batch axis, got shapes {[a.shape for a in leaves]}"
        )
    index = jnp.minimum(jnp.arange(-(-B // mesh.size) * mesh.size), B - 1)
    sharding = NamedSharding(mesh, P(mesh.axis_names))
    padded = jax.device_put(jax.tree.map(lambda a: a[index], args), sharding)
    out = _on_mesh(fn, sharding, padded, options)
    return jax.tree.map(lambda a: a[:B], out)


def fit_sharded(levels, n_yes, n_total, *, mesh=None, guess=0.0, lapse=0.0, max_steps=MAX_STEPS):
    """:func:`fit` with the datasets split across the devices of ``mesh``.

    Takes the arguments of :func:`fit` (and ``mesh``, see
    :func:`map_sharded`) and returns the same :class:`Fit` (to rounding).

    Examples
    --------
    >>> x = jnp.linspace(-0.3, 0.3, 5)
    >>> fit_sharded(x, jnp.array([[2, 9, 15, 21, 28]] * 3), 30).pse.shape
    (3,)
    """
    levels, n_yes, n_total, guess, lapse = _checked_inputs(levels, n_yes, n_total, guess, lapse)
    batch, L = levels.shape[:-1], levels.shape[-1]
    flat = [a.reshape(-1, L) for a in (levels, n_yes, n_total)]
    rates = [jax.tree.map(lambda r: r.reshape(-1), r) for r in (guess, lapse)]
    out = map_sharded(_fit_batch, *flat, *rates, mesh=mesh, max_steps=max_steps)
    return jax.tree.map(lambda a: a.reshape(batch), out)
