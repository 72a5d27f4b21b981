"""Bootstrap confidence intervals for psychometric fits.

Each dataset is fitted (:func:`jaxadapt.psychophysics.psychometric.fit`),
resampled ``n_resamples`` times (parametric: counts drawn from the fitted
function; non-parametric: trials resampled within each level) and every
resample refitted the same way; the percentile intervals of the resampled
PSEs and slopes are the confidence intervals (Wichmann and Hill 2001b, §2).
Datasets and resamples are processed in blocks whose memory stays within a
budget, so that neither the number of datasets nor of resamples limits a
call.

References
----------
Wichmann, Hill (2001), *The psychometric function II: bootstrap-based
confidence intervals and sampling*, Perception & Psychophysics 63.
"""

from functools import partial
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt._checks import check_whole
from jaxadapt.operators.checks import plain_errors
from jaxadapt.psychophysics._inputs import _checked_inputs
from jaxadapt.psychophysics.flags import NO_MLE
from jaxadapt.psychophysics.psychometric import (
    MAX_STEPS,
    Fit,
    _fit,
    _fit_one,
    psychometric,
    sample_counts,
)

__all__ = ["METHODS", "Bootstrap", "FIT_BYTES", "BOOTSTRAP_BUDGET", "bootstrap_blocks", "bootstrap"]

METHODS = ("parametric", "nonparametric")


class _Intervals(NamedTuple):
    pse_ci: jax.Array
    slope_ci: jax.Array
    pse_se: jax.Array
    slope_se: jax.Array
    flagged: jax.Array


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


#: Bytes that one resample's fit takes in a vmapped bootstrap call, its
#: solver state and temporaries: a bound, in float64, on how peak memory
#: grows with the number of fits in one call (``benchmarks/bench_psychometric.py``
#: records the whole command's).
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
    first=0,
    total=None,
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
    first, total : int, optional
        The datasets are those from ``first`` of a table of ``total`` (by
        default these alone): each resamples with the key it has in that
        table, in blocks of the table's size (:func:`bootstrap_blocks`), so
        that a table cut into parts of whole blocks (a cluster's tasks)
        gives the whole table's intervals, bit for bit.

    Returns
    -------
    Bootstrap
        With the fit of the data, intervals of shape ``(..., 2)``.

    Notes
    -----
    Percentile intervals (Wichmann and Hill 2001b, §2). Resamples whose data
    are degenerate keep their finite, flagged estimates (:mod:`jaxadapt.psychophysics.flags`)
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
    total = D if total is None else check_whole("total", total, least=first + D)
    keys = jax.random.split(key, total)[first : first + D]
    B, block = bootstrap_blocks(total, R, budget)  # (the whole table's blocks)
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
