"""Cumulative-Gaussian psychometric functions fitted by maximum likelihood.

Jacobs et al. (2015), §4.1.2, fits, per participant and condition, the
fraction of trials on which the test was judged brighter than the standard
with a cumulative Gaussian, using MATLAB's ``glmfit(x, [k n], 'binomial',
'link', 'probit')``, and reads the point of subjective equality (PSE) at
50%. With levels ``x`` in log10 units relative to the standard, the model
here is::

    P(x) = gamma + (1 - gamma - lambda) Phi(b0 + b1 x)
         = gamma + (1 - gamma - lambda) Phi((x - mu) / sigma),
    mu = PSE = -b0 / b1,   sigma = 1 / b1,

with the guess rate ``gamma`` and the lapse rate ``lambda`` zero by default,
which is exactly the probit GLM of ``glmfit``. Every function takes arrays
whose last axis holds the levels of one dataset and whose leading axes are
datasets (participants x conditions x bootstrap resamples): one compiled call
fits them all. Bootstrap intervals are in
:mod:`~jaxadapt.psychophysics.bootstrap`, fits across devices in
:mod:`~jaxadapt.psychophysics.sharding`, and the flags of degenerate data
in :mod:`~jaxadapt.psychophysics.flags` (all of them also reachable from
this module).

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
  rounding error of the objective (``jaxadapt.psychophysics._bfgs``), so
  that BFGS converges to machine precision instead of stalling within
  ``sqrt(eps)``.

The tolerance follows the dtype (``eps**0.7``); with fitted rates the fit
also stops when the log-likelihood a further step could gain is below
``sqrt(eps)/2``.

Fitted rates are ``low + (high - low) sigmoid(u)`` with a weak Gaussian prior
(standard deviation ``PRIOR_SD`` = 10) on ``u``, which keeps a rate that wants
to leave its bounds finite (within about 1% of its range from the bound) and
the information matrix invertible. The estimate is then the posterior mode,
not the maximum of the likelihood, where the likelihood's maximum lies near
a bound: a fitted rate sits a little inside its bound, and the standard
errors are those of the posterior. Rates held fixed (the default, and the
command line's) are plain maximum likelihood.

References
----------
Jacobs, Gallo, Cooper, Pulli, Levoy (2015), *Simulating the Visual Experience
of Very Bright and Very Dark Scenes*, ACM TOG 34(3), §4.1.2.
Wichmann, Hill (2001), *The psychometric
function I and II*, Perception & Psychophysics 63 (lapse rates, bootstrap).
"""

from functools import partial
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.scipy.special import gammaln, ndtr, xlogy

from jaxadapt.fitting import NEWTON_STEP
from jaxadapt.operators.checks import plain_errors
from jaxadapt.psychophysics._bfgs import _solve
from jaxadapt.psychophysics._inputs import _checked_inputs, _over_datasets
from jaxadapt.psychophysics._likelihood import _nll, _objective, _prepare, _se, _unpack
from jaxadapt.psychophysics.flags import (  # noqa: F401  (the flags, as before their module)
    ALL_SAME,
    EXTRAPOLATED,
    FLAG_NAMES,
    FLAT,
    MIN_SLOPE,
    NO_MLE,
    NO_PSE,
    PRIOR_SD,
    SEPARATION,
    SINGLE_LEVEL,
    flag_names,
)

__all__ = ["MAX_STEPS", "Fit", "psychometric", "sample_counts", "fit"]

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
        cancel: its rounding is about ``eps n log n``, which float32 makes
        visible at thousands of trials a level (``jaxadapt psychometric
        fit`` fits in float64).
    deviance : array
        ``2 (loglik_saturated - loglik)``, rounded likewise, and set to 0
        where rounding makes it negative.
    converged : array of bool
        Whether the optimiser met its tolerance within ``max_steps`` and a
        Newton step from the estimate (exact Hessian) would move it by at
        most ``jaxadapt.fitting.NEWTON_STEP`` (0.1) standard errors.
    flags : array of int
        Bit flags, see :mod:`jaxadapt.psychophysics.flags`.
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


def _fit_one(x, k, n, guess, lapse, max_steps):
    data = _prepare(x, k, n)
    dtype = x.dtype
    theta, converged = _solve(data, guess, lapse, max_steps)
    # Responses all the same: the slope's optimum is 0. The levels are
    # centred on their trial-weighted mean, so at a1 = 0 the likelihood's
    # derivative along a1, sum n_i z_i h'(a0), is 0, as is the prior's (and
    # with fixed rates the objective is convex: Phi and 1 - Phi are
    # log-concave). The solver starts on a1 = 0 and stays there but for
    # rounding (_start), whose sign would put the PSE on either side of the
    # levels (jaxadapt.psychophysics.flags): set to 0. The test below is
    # then that of the problem constrained to a1 = 0, whose optimum is the
    # unconstrained one: there the gradient along a1 and the Hessian's cross
    # terms with a1 vanish, and what it measures is how far the other
    # parameters are from their optimum.
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
    a1_safe = jnp.where(flat, MIN_SLOPE, a1)  # flat counts as increasing (flags.py)
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


def _fit_batch(levels, n_yes, n_total, guess, lapse, max_steps):
    """Fit ``(..., L)`` arrays (already checked), one ``vmap`` over the
    datasets."""
    return _over_datasets(
        partial(_fit_one, max_steps=max_steps), levels, n_yes, n_total, guess, lapse
    )


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
    See the module notes for the optimiser, and
    :mod:`jaxadapt.psychophysics.flags` for the flags and degenerate data.
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
