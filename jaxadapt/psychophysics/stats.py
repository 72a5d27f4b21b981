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

The p-value of the rank-sum test comes from the exact null distribution of
the statistic or from its normal approximation, as SciPy's ``mannwhitneyu``
does (``method="auto"``, ``"exact"``, ``"asymptotic"``; see
:func:`ranksum`). The paper's mesopic p = 2.84e-6 is an exact one:
2 / C(22, 11) = 2.835e-6, the two-sided p of 11 manipulated PSEs that all
lie above 11 control ones, which ``ranksum(..., method="exact")`` gives (no
other outcome with groups of at most 11 gives 2.84e-6, although §4.2.1
excludes one more of the 11 participants from this analysis, which would
leave 10). The normal approximation cannot go below 8.15e-5 for two groups
of 11 (7.11e-5 without the continuity correction), and it is what both
SciPy's automatic choice and MATLAB's default pick at that size (SciPy:
exact only when a group has at most 8 values; MATLAB: when
``min(n_x, n_y) < 10`` and ``n_x + n_y < 20``): the paper's value needs the
exact test asked for.

References
----------
Jacobs et al. (2015), ACM TOG 34(3), §4.1.2, §4.2.2. Hollander, Wolfe, Chicken (2014),
*Nonparametric Statistical Methods*, 3rd ed., §4.1 (rank-sum test, ties) and
§4.2 (Hodges-Lehmann shift). Mann and Whitney (1947), *Ann. Math. Statist.*
18, 50-60 (the recursion of the exact null distribution).
"""

import functools
from functools import partial
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import ndtr

from jaxadapt.operators.checks import plain_errors

__all__ = [
    "AUTO_EXACT_MAX",
    "RankSum",
    "Comparison",
    "median",
    "exact_too_large",
    "ranksum",
    "hodges_lehmann",
    "compare",
    "GROUP_TEST_COLUMNS",
    "group_tests",
    "untested",
]

#: ``method="auto"`` uses the exact null distribution when the smaller group
#: has at most this many values and there are no ties (SciPy's rule).
AUTO_EXACT_MAX = 8
#: Limits of a table of exact tail probabilities: entries stored, and
#: multiply-adds to build it.
_MAX_TABLE = 2**22
_MAX_WORK = 2**29


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
        Two-sided p-value. NaN, as ``statistic``, ``u`` and ``z``, where a
        group has no valid entry: there is no test.
    n_x, n_y : array
        Group sizes (valid entries).
    exact : array of bool
        Whether ``p`` comes from the exact null distribution (else from the
        normal approximation, or there is no ``p``).
    """

    statistic: jax.Array
    u: jax.Array
    z: jax.Array
    p: jax.Array
    n_x: jax.Array
    n_y: jax.Array
    exact: jax.Array


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
    if mask is None:
        return jnp.ones(jnp.shape(x), bool)
    return jnp.broadcast_to(jnp.asarray(mask, bool), jnp.shape(x))


def _checked_mask(x, mask, name):
    """:func:`_mask`, with an error naming ``name_mask`` when it does not
    broadcast to ``name``'s shape."""
    try:
        return _mask(x, mask)
    except ValueError:
        raise ValueError(
            f"{name}_mask: expected a shape that broadcasts to {name}'s {x.shape}, "
            f"got {jnp.shape(mask)}"
        ) from None


def median(x, mask=None):
    """Median over the last axis of the entries where ``mask`` is true.

    NaN for a group without valid entries.

    Examples
    --------
    >>> float(median(jnp.array([3.0, 1.0, 2.0, 100.0]), jnp.array([1, 1, 1, 0], bool)))
    2.0
    """
    x = jnp.asarray(x)
    if x.shape[-1] == 0:  # no entries at all (nanmedian would index into none)
        return jnp.full(x.shape[:-1], jnp.nan, jnp.result_type(x, float))
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


def _table_cost(s_lo, s_hi, l_lo, l_hi):
    """Entries :func:`_tail_table` holds (the larger of its result and its
    working array) and multiply-adds to build it."""
    working = (s_hi + 1) * (s_hi * l_hi + 1)
    work = s_hi * (s_hi + 1) * l_hi * (l_hi + 1) // 4
    if working > _MAX_TABLE or s_lo > s_hi:  # too large anyway, or empty
        return working, work
    small = np.arange(s_lo, s_hi + 1)[:, None]
    large = np.arange(l_lo, l_hi + 1)[None, :]
    product = small * large
    entries = np.where(small <= large, product - product // 2 + 1, 0).sum()
    return max(int(entries), working), work


def _exact_bounds(n, m, masked=(False, False), method="exact"):
    """Bounds ``(s_lo, s_hi, l_lo, l_hi)`` of the smaller and the larger
    group's sizes for which exact p are tabulated, groups of up to ``n`` and
    ``m`` values: static, fixed where a group has no mask (``masked``), and
    the smaller at most :data:`AUTO_EXACT_MAX` for ``method="auto"``."""
    low_x, low_y = (0 if mask else k for mask, k in zip(masked, (n, m), strict=True))
    s_hi = min(n, m) if method == "exact" else min(n, m, AUTO_EXACT_MAX)
    return min(low_x, low_y), s_hi, max(low_x, low_y), max(n, m)


def exact_too_large(n, m, masked=(False, False), method="exact"):
    """Why exact p for groups of up to ``n`` and ``m`` values (with masks
    where ``masked``) are not computed by ``method``: the table they need,
    or the work to build it, over its limit (said in words); ``None`` when
    they are.

    Examples
    --------
    >>> exact_too_large(11, 11) is None
    True
    >>> exact_too_large(170, 170).partition(", ")[0]
    'groups of 170 and 170 values need a table of 4942071 exact tail probabilities'
    """
    entries, work = _table_cost(*_exact_bounds(n, m, masked, method))
    sizes = f"groups of {'up to ' if any(masked) else ''}{n} and {m} values"
    if entries > _MAX_TABLE:
        return f"{sizes} need a table of {entries} exact tail probabilities, more than {_MAX_TABLE}"
    if work > _MAX_WORK:
        return f"{sizes} need {work} operations to tabulate their exact p, more than {_MAX_WORK}"
    return None


@functools.lru_cache(maxsize=16)
def _tail_table(s_lo, s_hi, l_lo, l_hi):
    """Upper tails of the exact null distribution of the rank-sum statistic.

    For groups of ``s <= l`` values without ties (``s_lo <= s <= s_hi``,
    ``l_lo <= l <= l_hi``), ``U`` counts the pairs in which the value of the
    group of ``s`` is the larger. Returns ``(tails, offsets)``, NumPy float64
    and int32, with

        P(U >= u) = tails[offsets[s - s_lo, l - l_lo] + u - s l // 2]

    for ``s l // 2 <= u <= s l`` (the upper half; the distribution is
    symmetric about ``s l / 2``). Pairs with ``s > l`` are not stored (their
    offset is 0).

    ``f(i, j)``, the distribution for ``i`` and ``j`` values, follows from the
    largest of the ``i + j`` values, which is in the first group with
    probability ``i / (i + j)`` (and beats all ``j`` others):

        f(i, j)[u] = i / (i + j) f(i - 1, j)[u - j] + j / (i + j) f(i, j - 1)[u],

    ``f(i, 0) = f(0, j) = [1]`` (Mann and Whitney 1947, in probabilities:
    every term is positive, so no precision is lost to cancellation, and the
    tails are summed from the top).
    """
    f = np.zeros((s_hi + 1, s_hi * l_hi + 1))
    f[:, 0] = 1.0
    offsets = np.zeros((s_hi - s_lo + 1, l_hi - l_lo + 1), np.int32)
    tails, size = [], 0

    def store(j):
        nonlocal size
        for i in range(s_lo, min(s_hi, j) + 1):
            m = i * j
            tail = np.cumsum(f[i, m::-1])[::-1][m // 2 :]
            offsets[i - s_lo, j - l_lo] = size
            tails.append(tail)
            size += tail.size

    if l_lo == 0:
        store(0)
    for j in range(1, l_hi + 1):
        for i in range(1, s_hi + 1):
            m = i * j
            new = j / (i + j) * f[i, : m + 1]
            new[j:] += i / (i + j) * f[i - 1, : m + 1 - j]
            f[i, : m + 1] = new
        if j >= l_lo:
            store(j)
    return np.concatenate(tails), offsets


def _exact_p(u, n_x, n_y, s_lo, s_hi, l_lo, l_hi, dtype):
    """Two-sided exact p of ``U`` for groups of ``n_x`` and ``n_y`` in the
    table's ranges (``min(n_x, n_y) > s_hi`` gives an unused value)."""
    tails, offsets = _tail_table(s_lo, s_hi, l_lo, l_hi)
    small = jnp.minimum(n_x, n_y).astype(jnp.int32)
    large = jnp.maximum(n_x, n_y).astype(jnp.int32)
    product = small * large
    # SciPy's exact method: U = max(U_x, U_y) (>= s l / 2), rounded down when
    # ties make it a half-integer.
    upper = jnp.floor(jnp.maximum(u, n_x * n_y - u)).astype(jnp.int32)
    start = jnp.asarray(offsets)[
        jnp.clip(small, s_lo, s_hi) - s_lo, jnp.clip(large, l_lo, l_hi) - l_lo
    ]
    index = start + jnp.clip(upper - product // 2, 0, product - product // 2)
    tail = jnp.asarray(tails, dtype)[index]
    return jnp.minimum(2 * tail, 1.0)


@plain_errors
def ranksum(x, y, *, x_mask=None, y_mask=None, continuity=True, method="auto"):
    """Two-sided Wilcoxon rank-sum (Mann-Whitney) test.

    Parameters
    ----------
    x, y : array, shapes (..., n) and (..., m)
        The two samples on the last axis (e.g. manipulated and control PSEs,
        log10 units); the valid entries must be finite.
    x_mask, y_mask : array of bool, optional
        Valid entries (default: all).
    continuity : bool, optional
        Continuity correction of 1/2 in the normal approximation (default,
        as MATLAB's ``ranksum`` and SciPy's ``mannwhitneyu``).
    method : {"auto", "exact", "asymptotic"}, optional
        Where ``p`` comes from, as in ``scipy.stats.mannwhitneyu``:
        ``"exact"``, the exact null distribution of ``U``; ``"asymptotic"``,
        the normal approximation; ``"auto"`` (default), SciPy's rule, for
        each batch element on its valid entries: exact when the smaller group
        has at most :data:`AUTO_EXACT_MAX` (8) values and no two valid values
        are tied, else asymptotic (so two groups of 11, the paper's, get the
        normal approximation: ask for ``"exact"`` to get its p = 2.84e-6).

    Returns
    -------
    RankSum
        ``exact`` says, per batch element, which method gave ``p``.

    Raises
    ------
    ValueError
        An unknown ``method``, or ``method="exact"`` for groups too large for
        a table of the exact distribution (see Notes).

    Notes
    -----
    Ranks are mid-ranks in the pooled valid sample, ``W`` the sum of those of
    ``x``, ``U = W - n_x (n_x + 1) / 2``.

    Asymptotic:

        z = sign(d) max(|d| - c/2, 0) / sqrt(n_x n_y / 12 (N + 1 - T / (N (N - 1)))),
        d = U - n_x n_y / 2,   T = sum over tie groups of (t^3 - t),

    ``N = n_x + n_y``, ``c = 1`` with the continuity correction, and
    ``p = 2 Phi(-|z|)``. This is ``scipy.stats.mannwhitneyu(x, y,
    method="asymptotic")`` (with ``use_continuity=continuity``) and MATLAB's
    ``ranksum(x, y, 'method', 'approximate')``; without ties and without the
    correction it is ``scipy.stats.ranksums``. ``z`` is this statistic
    whichever method gives ``p``.

    Exact: ``p = min(1, 2 P(U' >= max(U, n_x n_y - U)))`` with ``U'`` the
    statistic of two groups of these sizes under the null hypothesis, all
    ``C(N, n_x)`` arrangements of the ranks equally likely; this is
    ``scipy.stats.mannwhitneyu(x, y, method="exact")`` and MATLAB's
    ``ranksum(x, y, 'method', 'exact')`` without ties. Like SciPy's, it
    makes no correction for ties (``U`` is rounded down when they make it a
    half-integer); ``"auto"`` sends tied data to the approximation.

    The exact distribution comes from a table of tail probabilities,
    computed in NumPy once per range of group sizes (and cached), then
    gathered from as a constant: cheap under ``jit`` and ``vmap`` over
    thousands of experiments. The range follows the array shapes: without
    masks the sizes are the static ``n`` and ``m`` and one distribution is
    stored (about ``n m / 2`` entries); with a mask every size up to the
    padded one is. A table is not built beyond 2**22 entries or 2**29
    operations: two unmasked groups of more than about 160 values each, or
    masked ones padded to more than about 90; for ``"auto"``, where only a
    smaller group of at most 8 needs it, masked groups padded to more than
    about 680 or an unmasked larger group of more than about 5,400. There
    ``"exact"`` raises, and ``"auto"`` uses the normal approximation for
    every element, as ``exact`` reports.

    A group without valid entries leaves nothing to test: ``W``, ``U``,
    ``z`` and ``p`` are NaN and ``exact`` is false, as SciPy's
    ``mannwhitneyu`` and ``ranksums`` give NaN for an empty sample. Where
    there is no variation (every valid value tied), ``z = 0`` and ``p = 1``
    (SciPy's too); one value against one gets ``p = 1`` as well, the least
    p that two values can reach.

    Examples
    --------
    Four against four, all of ``x`` above all of ``y`` but one: exact (SciPy's
    automatic choice), ``p = 2 P(U >= 15) = 2 (2 / 70)``.

    >>> x, y = jnp.array([0.10, 0.21, 0.15, 0.30]), jnp.array([0.0, -0.05, 0.02, 0.12])
    >>> r = ranksum(x, y)
    >>> float(r.statistic), float(r.u), round(float(r.p), 4), bool(r.exact)
    (25.0, 15.0, 0.0571, True)
    >>> round(float(ranksum(x, y, method="asymptotic").p), 4)
    0.0606
    """
    if method not in ("auto", "exact", "asymptotic"):
        raise ValueError(f"method: expected 'auto', 'exact' or 'asymptotic', got {method!r}")
    x, y = jnp.asarray(x), jnp.asarray(y)
    for name, a in (("x", x), ("y", y)):
        if a.ndim == 0:
            raise ValueError(f"{name}: expected a group on the last axis, got a scalar")
    dtype = jnp.result_type(x, y, float)
    x, y = x.astype(dtype), y.astype(dtype)
    x_valid, y_valid = _checked_mask(x, x_mask, "x"), _checked_mask(y, y_mask, "y")
    missing = ~jnp.all(jnp.isfinite(x) | ~x_valid) | ~jnp.all(jnp.isfinite(y) | ~y_valid)
    x = eqx.error_if(x, missing, "x, y: expected finite values where valid (mask out the others)")
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
    p = 2 * ndtr(-jnp.abs(z))
    tested = (n_x > 0) & (n_y > 0)
    exact = jnp.zeros(batch, bool)
    if method != "asymptotic":
        masked = (x_mask is not None, y_mask is not None)
        bounds = _exact_bounds(x.shape[-1], y.shape[-1], masked, method)
        too_large = exact_too_large(x.shape[-1], y.shape[-1], masked, method)
        if method == "exact" and too_large:
            raise ValueError(
                f"method='exact': {too_large}; use method='asymptotic' (at these sizes the "
                "normal approximation is close)"
            )
        if bounds[0] <= bounds[1] and not too_large:
            s_lo, s_hi, l_lo, l_hi = bounds
            exact = jnp.minimum(n_x, n_y) <= s_hi
            if method == "auto":
                exact &= ~jnp.any(valid & (tied > 1), axis=-1)
            p_exact = _exact_p(U, n_x, n_y, s_lo, s_hi, l_lo, l_hi, dtype)
            p = jnp.where(exact, p_exact, p)
    W, U, z, p = (jnp.where(tested, a, jnp.nan) for a in (W, U, z, p))
    return RankSum(W, U, z, p, n_x, n_y, exact & tested)


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


def compare(x, y, *, x_mask=None, y_mask=None, continuity=True, method="auto"):
    """Medians, the rank-sum test and effect sizes of ``x`` against ``y``.

    Parameters
    ----------
    x, y, x_mask, y_mask, continuity, method
        As for :func:`ranksum`; e.g. ``x`` the manipulated and ``y`` the
        control PSEs of every participant.

    Returns
    -------
    Comparison
        ``shift`` and ``rank_biserial`` are positive when ``x`` tends to be
        larger (for PSEs: the manipulated test needs more luminance to match
        the standard, i.e. it looks darker). Like the test's ``p``,
        ``rank_biserial`` and ``shift`` are NaN when a group is empty.

    Examples
    --------
    >>> c = compare(jnp.array([0.10, 0.21, 0.15, 0.30]), jnp.array([0.0, -0.05, 0.02, 0.12]))
    >>> round(float(c.shift), 3), float(c.rank_biserial), round(float(c.median_x), 2)
    (0.165, 0.875, 0.18)
    """
    test = ranksum(x, y, x_mask=x_mask, y_mask=y_mask, continuity=continuity, method=method)
    r = 2 * test.u / jnp.maximum(test.n_x * test.n_y, 1.0) - 1  # NaN with U where untested
    return Comparison(
        median_x=median(x, x_mask),
        median_y=median(y, y_mask),
        shift=hodges_lehmann(x, y, x_mask=x_mask, y_mask=y_mask),
        rank_biserial=r,
        test=test,
    )


#: Columns of ``group_test.csv``: each condition against the control.
GROUP_TEST_COLUMNS = (
    "condition",
    "control",
    "median",
    "median_control",
    "shift",
    "rank_biserial",
    "W",
    "z",
    "p",
    "p_exact",
    "n",
    "n_control",
)


def group_tests(table, control, method="auto"):
    """Each condition's PSEs against the ``control``'s (:func:`compare`), as
    the rows of ``group_test.csv`` (:data:`GROUP_TEST_COLUMNS`); none when
    the table has no such condition.

    ``table`` has a ``condition`` and a ``pse`` per group (a fit table of
    :mod:`~jaxadapt.psychophysics.trials`); PSEs that are NaN (the data
    place none) are left out. ``method`` is :func:`ranksum`'s. A condition
    (or the control) left without PSEs has no test: its row's ``W``, ``z``,
    ``p`` and ``rank_biserial`` are NaN, ``p_exact`` false, and
    :func:`untested` says why.
    """
    condition = np.asarray(table.condition)
    placed = np.isfinite(table.pse)  # NaN: the data place no PSE (separation.undetermined)
    pse = np.where(placed, table.pse, 0.0)
    rows = []
    for other in dict.fromkeys(table.condition):
        if other == control or control not in condition:
            continue
        x, y = condition == other, condition == control
        c = compare(
            jnp.asarray(pse[x]),
            jnp.asarray(pse[y]),
            x_mask=jnp.asarray(placed[x]),
            y_mask=jnp.asarray(placed[y]),
            method=method,
        )
        rows.append(
            {
                "condition": other,
                "control": control,
                "median": float(c.median_x),
                "median_control": float(c.median_y),
                "shift": float(c.shift),
                "rank_biserial": float(c.rank_biserial),
                "W": float(c.test.statistic),
                "z": float(c.test.z),
                "p": float(c.test.p),
                "p_exact": "true" if bool(c.test.exact) else "false",
                "n": int(c.test.n_x),
                "n_control": int(c.test.n_y),
            }
        )
    return rows


def untested(row):
    """Why a row of :func:`group_tests` has no test (a group without a PSE
    to rank), in words for the command line and ``pse.png``; ``None`` when
    it has one.

    Examples
    --------
    >>> untested({"condition": "manip", "control": "control", "n": 0, "n_control": 3})
    'manip has no determined PSE'
    """
    empty = [
        str(row[name]) for name, n in (("condition", "n"), ("control", "n_control")) if not row[n]
    ]
    if len(empty) == 2:
        return f"neither {empty[0]} nor {empty[1]} has a determined PSE"
    return f"{empty[0]} has no determined PSE" if empty else None
