"""Fit tables out: every group of a trial table fitted, with an interval
for its PSE, and written as ``fits.csv`` (``jaxadapt psychometric fit``).

:func:`fit_groups` fits the groups of
:func:`jaxadapt.psychophysics.trials.group_trials` in one batched call,
:func:`write_fits` writes ``fits.csv``, and :func:`fit_file` does it all,
paths in, table out.
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import ndtri

from jaxadapt.io import atomic_path, csv_writer
from jaxadapt.psychophysics import psychometric
from jaxadapt.psychophysics.bootstrap import BOOTSTRAP_BUDGET, bootstrap
from jaxadapt.psychophysics.flags import NO_MLE, NO_PSE, SEPARATION, SINGLE_LEVEL, flag_names
from jaxadapt.psychophysics.separation import (
    _at_least_the_data,
    separating_gap,
    sigma_bound,
    undetermined,
)
from jaxadapt.psychophysics.trials import csv_cell, group_trials, read_trials

__all__ = [
    "FIT_COLUMNS",
    "FitTable",
    "fit_groups",
    "fit_rows",
    "concatenated",
    "batch_size",
    "write_fits",
    "fit_file",
]

#: Columns of ``fits.csv``.
FIT_COLUMNS = (
    "participant",
    "condition",
    "pse",
    "sigma",
    "b0",
    "b1",
    "se_pse",
    "ci_low",
    "ci_high",
    "pse_low",
    "pse_high",
    "sigma_max",
    "loglik",
    "converged",
    "flags",
)


class FitTable(NamedTuple):
    """One row per group; the fields are the columns of ``fits.csv``
    (``FIT_COLUMNS``). ``ci_low, ci_high`` bound the PSE (see
    :func:`fit_groups`); ``flags`` are the integer flags of
    :mod:`jaxadapt.psychophysics.flags`. Where the data do not determine the
    fit (:func:`undetermined`), what they leave open is NaN and
    ``converged`` false, and ``pse_low, pse_high`` (the levels the PSE lies
    between) and ``sigma_max`` (a 95% bound on sigma, for separated data)
    say what they do determine; elsewhere those three are NaN."""

    participant: tuple
    condition: tuple
    pse: np.ndarray
    sigma: np.ndarray
    b0: np.ndarray
    b1: np.ndarray
    se_pse: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    pse_low: np.ndarray
    pse_high: np.ndarray
    sigma_max: np.ndarray
    loglik: np.ndarray
    converged: np.ndarray
    flags: np.ndarray


def fit_groups(
    groups,
    *,
    key,
    n_resamples=1000,
    method="parametric",
    confidence=0.95,
    guess=0.0,
    lapse=0.0,
    progress=None,
    keep_undetermined=False,
    budget=BOOTSTRAP_BUDGET,
    first=0,
    total=None,
):
    """Fit every group, with confidence intervals for the PSE.

    The interval is the bootstrap's percentile interval (or the Wald
    interval), except where the data do not determine the fit
    (:data:`jaxadapt.psychophysics.flags.NO_MLE`). Under separation the data
    say only that the PSE lies between the highest level with a "no" and
    the lowest with a "yes" (for a rising function): every PSE in that
    gap fits them as well in the limit of a steep slope. The prior then
    picks one, and resamples of the fitted curve, nearly a step, separate
    again at the same levels, so that the percentile interval can be
    narrower than the gap. So the interval written spans at least the
    gap. Where the data place no PSE at all
    (:data:`~jaxadapt.psychophysics.flags.NO_PSE`: every response the same,
    one level, no slope) it is ``(-inf, inf)``.

    Parameters
    ----------
    groups : Groups
    key : PRNG key
        For the bootstrap; same key, same intervals.
    n_resamples : int, optional
        Bootstrap resamples per group; 0 gives Wald intervals
        ``pse +- z se_pse`` from the observed information instead.
    method, confidence, guess, lapse, progress
        As for :func:`jaxadapt.psychophysics.bootstrap.bootstrap` (``progress``
        is called with the number of groups done).
    keep_undetermined : bool, optional
        Keep the estimates of groups whose data do not determine the fit
        (:func:`undetermined`), which the fit's prior and least slope set,
        instead of NaN; ``converged`` is false for them either way.
    budget : int, optional
        Bytes the bootstrap's fits hold at once
        (:func:`~jaxadapt.psychophysics.bootstrap.bootstrap_blocks`).
    first, total : int, optional
        ``groups`` are those from ``first`` of a table of ``total``: as
        for :func:`~jaxadapt.psychophysics.bootstrap.bootstrap`, the
        intervals are then the whole table's (:func:`fit_rows`).

    Returns
    -------
    FitTable
    """
    if n_resamples == 1:  # said here: the bootstrap's message names only >= 2
        raise ValueError("n_resamples: expected 0 (Wald intervals) or at least 2, got 1")
    count = len(groups.participant)
    options = dict(guess=guess, lapse=lapse)
    if n_resamples:  # in batches of its own (bootstrap_blocks)
        arrays = (jnp.asarray(a) for a in (groups.levels, groups.n_yes, groups.n_total))
        boot = bootstrap(
            key,
            *arrays,
            n_resamples=n_resamples,
            method=method,
            confidence=confidence,
            progress=progress,
            budget=budget,
            first=first,
            total=total,
            **options,
        )
        fits, low, high = boot.fit, boot.pse_ci[:, 0], boot.pse_ci[:, 1]
    else:
        rows = np.concatenate([np.arange(count), np.zeros(batch_size(count) - count, int)])
        arrays = (jnp.asarray(a[rows]) for a in (groups.levels, groups.n_yes, groups.n_total))
        fits = psychometric.fit(*arrays, **options)
        half = ndtri((1 + confidence) / 2) * fits.se_pse
        low, high = fits.pse - half, fits.pse + half
        if progress is not None:
            progress(count)
    fits, low, high = (jax.tree.map(lambda a: np.asarray(a)[:count], x) for x in (fits, low, high))
    low, high = _at_least_the_data(groups, fits.flags, low, high)
    open_ = undetermined(fits.flags)
    gap_low, gap_high = separating_gap(groups)
    unplaced = (fits.flags & NO_PSE) > 0
    single = (fits.flags & SINGLE_LEVEL) > 0
    pse_low = np.where(open_, np.where(single, -np.inf, gap_low), np.nan)
    pse_high = np.where(open_, np.where(single, np.inf, gap_high), np.nan)
    separated = ((fits.flags & SEPARATION) > 0) & ~unplaced
    sigma_max = np.full(count, np.nan)
    for i in np.flatnonzero(separated):
        sigma_max[i] = sigma_bound(groups.levels[i], groups.n_yes[i], groups.n_total[i])
    values = {name: getattr(fits, name) for name in ("pse", "sigma", "b0", "b1", "se_pse")}
    if not keep_undetermined:
        no_mle = (fits.flags & NO_MLE) > 0
        for name, column in values.items():
            # a flat slope's b0 and b1 are the data's; its PSE and sigma are not
            blank = open_ if name in ("pse", "sigma", "se_pse") else no_mle
            values[name] = np.where(blank, np.nan, column)
    return FitTable(
        groups.participant,
        groups.condition,
        *values.values(),
        low,
        high,
        pse_low.astype(low.dtype),
        pse_high.astype(low.dtype),
        sigma_max.astype(low.dtype),
        fits.loglik,
        fits.converged & ~open_,
        fits.flags,
    )


def fit_rows(key, options, total, part):
    """:func:`fit_groups` of ``part = (first, groups)``, the groups from
    ``first`` of a table of ``total``, with ``options``, as in the whole
    table's fit: a task of its own, which a cluster's worker computes
    (:mod:`jaxadapt.cluster`), sent only its own groups."""
    first, groups = part
    return fit_groups(groups, key=key, first=first, total=total, **options)


def concatenated(tables):
    """One :class:`FitTable` of the consecutive ``tables``."""
    return FitTable(
        *(
            tuple(c for t in columns for c in t) if isinstance(columns[0], tuple)
            else np.concatenate(columns)
            for columns in zip(*tables, strict=True)
        )
    )  # fmt: skip


def batch_size(count):
    """The number of datasets :func:`fit_groups` fits ``count`` groups as:
    the next power of two, the groups after the first ``count`` copies of
    the first (each dataset of the vmapped fit is fitted on its own, and a
    copy stops when the first does, so it adds no step).

    A compiled fit serves one batch size, and compiling the fit and its
    bootstrap is a large part of a first ``jaxadapt psychometric fit``.
    With sizes rounded up, tables of 9 to 16 groups share one program: a
    later table of another size in the range loads it from the compilation
    cache (:func:`jaxadapt.runtime.cache_compilations`) instead of
    compiling it again. At most twice the datasets are fitted, which costs
    less than a compilation.

    Examples
    --------
    >>> [batch_size(n) for n in (1, 2, 3, 12, 16, 17, 340)]
    [1, 2, 4, 16, 16, 32, 512]
    """
    return 1 << (count - 1).bit_length()


#: How ``write_fits`` formats the flags, a column of integers.
_FORMATS = {"flags": lambda value: "|".join(flag_names(value))}


def write_fits(path, table):
    """Write ``fits.csv``: a header of ``FIT_COLUMNS`` and one row per group.

    Numbers are written as the shortest decimal that reads back to the same
    value in their dtype (:func:`csv_cell`), ``converged`` as ``true``/``false``
    and ``flags`` as flag names joined by ``|`` (empty when none). The file
    appears only once complete (:func:`jaxadapt.io.atomic_path`).
    """
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as file:
        writer = csv_writer(file)
        writer.writerow(FIT_COLUMNS)
        for row in zip(*table, strict=True):
            cells = zip(FIT_COLUMNS, row, strict=True)
            writer.writerow([_FORMATS.get(c, csv_cell)(v) for c, v in cells])


def fit_file(trials_path, fits_path, *, key, **options):
    """Read a trial table, fit every group and write ``fits.csv``.

    Parameters
    ----------
    trials_path, fits_path : str or Path
        The trial table to read and the fit table to write.
    key : PRNG key
        For the bootstrap.
    **options
        ``n_resamples``, ``method``, ``confidence``, ``guess``, ``lapse`` of
        :func:`fit_groups`.

    Returns
    -------
    FitTable
        What was written, e.g. for the group test between conditions
        (:func:`jaxadapt.psychophysics.stats.compare` on the PSEs).
    """
    table = fit_groups(group_trials(read_trials(trials_path)), key=key, **options)
    write_fits(fits_path, table)
    return table
