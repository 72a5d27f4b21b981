"""Group statistics of points of subjective equality.

§4.1.2 and §4.2.2 of the 2015 paper compare the PSEs of the control and the
manipulated condition across participants with their medians and MATLAB's
``ranksum`` (the Wilcoxon rank-sum test): p = 0.449 for afterimages,
p = 2.84e-6 for mesopic effects. This module gives that test, its effect
sizes, and the medians, as pure JAX functions of the last axis: leading axes
are batches (e.g. thousands of simulated experiments at once, under ``jit``
and ``vmap``), and optional masks mark the valid entries, so that groups of
different sizes (participants excluded in some simulated experiments) share
one array shape.

References
----------
Jacobs et al. (2015), ACM TOG 34(3), §4.1.2, §4.2.2
(``shared/seeds/004_*.txt``). Hollander, Wolfe, Chicken (2014),
*Nonparametric Statistical Methods*, 3rd ed., §4.1 (rank-sum test, ties) and
§4.2 (Hodges-Lehmann shift).
"""

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.scipy.special import ndtr


class RankSum(NamedTuple):
    """The Wilcoxon rank-sum (Mann-Whitney) test of ``x`` against ``y``.

    Attributes
    ----------
    statistic : array
        ``W``, the sum of the ranks of ``x`` in the pooled sample (MATLAB's
        ``stats.ranksum``).
    u : array
        ``U = W - n_x (n_x + 1) / 2`` (SciPy's ``mannwhitneyu`` statistic).
    z : array
        Standardised statistic, signed as ``U - n_x n_y / 2``.
    p : array
        Two-sided p-value.
    n_x, n_y : array
        Group sizes (valid entries).
    """

    statistic: jax.Array
    u: jax.Array
    z: jax.Array
    p: jax.Array
    n_x: jax.Array
    n_y: jax.Array


class Comparison(NamedTuple):
    """Two groups compared: medians, the rank-sum test, effect sizes.

    Attributes
    ----------
    median_x, median_y : array
        Group medians.
    shift : array
        Hodges-Lehmann estimate of the shift of ``x`` relative to ``y``.
    rank_biserial : array
        ``2 U / (n_x n_y) - 1`` in [-1, 1]: the probability that a value of
        ``x`` exceeds one of ``y``, minus the converse.
    test : RankSum
    """

    median_x: jax.Array
    median_y: jax.Array
    shift: jax.Array
    rank_biserial: jax.Array
    test: RankSum


def _mask(x, mask):
    return jnp.ones(jnp.shape(x), bool) if mask is None else jnp.broadcast_to(mask, jnp.shape(x))


def median(x, mask=None):
    """Median over the last axis of the entries where ``mask`` is true.

    NaN for a group without valid entries.

    Examples
    --------
    >>> float(median(jnp.array([3.0, 1.0, 2.0, 100.0]), jnp.array([1, 1, 1, 0], bool)))
    2.0
    """
    x = jnp.asarray(x)
    return jnp.nanmedian(jnp.where(_mask(x, mask), x, jnp.nan), axis=-1)


@partial(jnp.vectorize, signature="(n),(n)->(n),(n)")
def _ranks(values, valid):
    """Mid-ranks (1-based, ties averaged) among the valid entries, and each
    entry's tie count. Invalid entries sort last, as ``+inf``."""
    v = jnp.where(valid, values, jnp.inf)
    s = jnp.sort(v)
    below = jnp.searchsorted(s, v, side="left")
    tied = jnp.searchsorted(s, v, side="right") - below
    return (below + (tied + 1) / 2).astype(values.dtype), tied


def ranksum(x, y, *, x_mask=None, y_mask=None, continuity=True):
    """Two-sided Wilcoxon rank-sum test, normal approximation.

    Parameters
    ----------
    x, y : array, shapes (..., n) and (..., m)
        The two samples on the last axis (e.g. manipulated and control PSEs,
        log10 units); the valid entries must be finite.
    x_mask, y_mask : array of bool, optional
        Valid entries (default: all).
    continuity : bool, optional
        Continuity correction of 1/2 (default, as MATLAB's ``ranksum`` and
        SciPy's ``mannwhitneyu``).

    Returns
    -------
    RankSum

    Notes
    -----
    Ranks are mid-ranks in the pooled valid sample, ``U = W - n(n+1)/2`` with
    ``n = n_x``, and

        z = sign(d) max(|d| - c/2, 0) / sqrt(n_x n_y / 12 (N + 1 - T / (N (N - 1)))),
        d = U - n_x n_y / 2,   T = sum over tie groups of (t^3 - t),

    ``N = n_x + n_y``, ``c = 1`` with the continuity correction, and
    ``p = 2 Phi(-|z|)``. This is ``scipy.stats.mannwhitneyu(x, y,
    method="asymptotic")`` (with ``use_continuity=continuity``) and MATLAB's
    ``ranksum(x, y, 'method', 'approximate')``; without ties and without the
    correction it is ``scipy.stats.ranksums``.

    Small samples: the normal approximation is always used. MATLAB's
    ``ranksum`` switches to its exact test when ``min(n_x, n_y) < 10`` and
    ``n_x + n_y < 20``; for such sizes compute the exact p-value with SciPy
    (``method="exact"``) for a report, while this function keeps one smooth,
    vectorised rule for simulated experiments. The paper's groups (11
    participants each) are in the approximate regime of both. When there is
    no variation (every valid value tied) or a group is empty, ``z = 0`` and
    ``p = 1``.

    Examples
    --------
    >>> r = ranksum(jnp.array([0.10, 0.21, 0.15, 0.30]), jnp.array([0.0, -0.05, 0.02, 0.12]))
    >>> float(r.statistic), float(r.u), round(float(r.p), 4)
    (25.0, 15.0, 0.0606)
    """
    dtype = jnp.result_type(x, y, float)
    x, y = jnp.asarray(x, dtype), jnp.asarray(y, dtype)
    x_valid, y_valid = _mask(x, x_mask), _mask(y, y_mask)
    batch = jnp.broadcast_shapes(x.shape[:-1], y.shape[:-1])
    x, x_valid = (jnp.broadcast_to(a, batch + x.shape[-1:]) for a in (x, x_valid))
    y, y_valid = (jnp.broadcast_to(a, batch + y.shape[-1:]) for a in (y, y_valid))
    valid = jnp.concatenate([x_valid, y_valid], axis=-1)
    ranks, tied = _ranks(jnp.concatenate([x, y], axis=-1), valid)
    n_x = jnp.sum(x_valid, axis=-1).astype(dtype)
    n_y = jnp.sum(y_valid, axis=-1).astype(dtype)
    N = n_x + n_y
    W = jnp.sum(jnp.where(valid, ranks, 0.0)[..., : x.shape[-1]], axis=-1)
    U = W - n_x * (n_x + 1) / 2
    ties = jnp.sum(jnp.where(valid, tied.astype(dtype) ** 2 - 1, 0.0), axis=-1)
    var = n_x * n_y / 12 * (N + 1 - ties / jnp.maximum(N * (N - 1), 1.0))
    d = U - n_x * n_y / 2
    informative = var > 0
    z = jnp.sign(d) * jnp.maximum(jnp.abs(d) - 0.5 * continuity, 0.0)
    z = jnp.where(informative, z / jnp.sqrt(jnp.where(informative, var, 1.0)), 0.0)
    return RankSum(W, U, z, 2 * ndtr(-jnp.abs(z)), n_x, n_y)


def hodges_lehmann(x, y, *, x_mask=None, y_mask=None):
    """Hodges-Lehmann shift of ``x`` relative to ``y``: the median of all
    pairwise differences ``x_i - y_j`` between valid entries.

    NaN when a group has no valid entry. Uses ``n x m`` memory per batch
    element.

    Examples
    --------
    >>> float(hodges_lehmann(jnp.array([1.0, 2.0, 3.0]), jnp.array([0.0, 0.5])))
    1.75
    """
    x, y = jnp.asarray(x), jnp.asarray(y)
    diff = x[..., :, None] - y[..., None, :]
    valid = _mask(x, x_mask)[..., :, None] & _mask(y, y_mask)[..., None, :]
    flat = diff.shape[:-2] + (-1,)
    return median(diff.reshape(flat), valid.reshape(flat))


def compare(x, y, *, x_mask=None, y_mask=None, continuity=True):
    """Medians, the rank-sum test and effect sizes of ``x`` against ``y``.

    Parameters
    ----------
    x, y, x_mask, y_mask, continuity
        As for :func:`ranksum`; e.g. ``x`` the manipulated and ``y`` the
        control PSEs of every participant.

    Returns
    -------
    Comparison
        ``shift`` and ``rank_biserial`` are positive when ``x`` tends to be
        larger (for PSEs: the manipulated test needs more luminance to match
        the standard, i.e. it looks darker). ``rank_biserial`` is 0 when a
        group is empty.

    Examples
    --------
    >>> c = compare(jnp.array([0.10, 0.21, 0.15, 0.30]), jnp.array([0.0, -0.05, 0.02, 0.12]))
    >>> round(float(c.shift), 3), float(c.rank_biserial), round(float(c.median_x), 2)
    (0.165, 0.875, 0.18)
    """
    test = ranksum(x, y, x_mask=x_mask, y_mask=y_mask, continuity=continuity)
    pairs = test.n_x * test.n_y
    r = jnp.where(pairs > 0, 2 * test.u / jnp.maximum(pairs, 1.0) - 1, 0.0)
    return Comparison(
        median_x=median(x, x_mask),
        median_y=median(y, y_mask),
        shift=hodges_lehmann(x, y, x_mask=x_mask, y_mask=y_mask),
        rank_biserial=r,
        test=test,
    )
