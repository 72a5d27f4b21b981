"""The probit likelihood of one dataset, standardised, and its start.

The negative log-likelihood of the binomial counts under
``P(x) = gamma + (1 - gamma - lambda) Phi(a0 + a1 z)``, with the levels
standardised (``z = (x - c) / s``, ``c`` and ``s`` the trial-weighted mean
and standard deviation of the levels) so that the identity is a good first
Hessian whatever the units; the weak priors of
:mod:`jaxadapt.psychophysics.flags`; and glmfit's start refined by one
iteratively reweighted least-squares step. Internal to
:mod:`jaxadapt.psychophysics.psychometric`.
"""

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.scipy.special import log_ndtr

from jaxadapt.psychophysics.flags import ALL_SAME, NO_MLE, PRIOR_SD, SEPARATION, SINGLE_LEVEL

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
    """One IRLS step from glmfit's start, ``mu = (k + 1/2) / (n + 1)``, with
    the slope 0 where every response is the same (``ALL_SAME``): their
    optimum is at ``a1 = 0`` exactly (the levels are centred on their
    trial-weighted mean, so there the gradient along ``a1`` and the
    Hessian's cross terms with it vanish), and BFGS started on that plane
    stays on it, where from glmfit's slope, fitted to unequal trial counts,
    it crept back too slowly to converge."""
    mu = (data.k + 0.5) / (data.n + 1.0)
    eta = jax.scipy.special.ndtri(mu)
    w = data.n * jnp.exp(2 * jax.scipy.stats.norm.logpdf(eta)) / (mu * (1 - mu))
    w = w / jnp.maximum(jnp.sum(w), jnp.finfo(w.dtype).tiny)
    z_mean, eta_mean = jnp.sum(w * data.z), jnp.sum(w * eta)
    var = jnp.sum(w * (data.z - z_mean) ** 2)
    cov = jnp.sum(w * (data.z - z_mean) * (eta - eta_mean))
    a1 = jnp.where((var > 0) & ~(data.flags & ALL_SAME), cov / jnp.where(var > 0, var, 1.0), 0.0)
    return jnp.stack([eta_mean - a1 * z_mean, a1])


def _se(var):
    """Standard error, ``inf`` where the variance is not a finite non-negative
    number."""
    ok = jnp.isfinite(var) & (var >= 0)
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, var, 0.0)), jnp.inf)
