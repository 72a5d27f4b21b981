"""Trial tables in, fit tables out: the files of ``jaxadapt psychometric``.

A trial table is a CSV file with a header row and either one row per trial,

    participant,condition,level,response
    p01,control,-0.285,0
    p01,control,0.259,1

or one row per level with counts,

    participant,condition,level,n_yes,n_total
    p01,control,-0.285,3,30

``level`` is log10 units relative to the standard and ``response`` is 1 when
the test was judged brighter. ``participant`` and ``condition`` may be left
out (one group, named ``"all"``). :func:`read_trials` reads and validates
such a file, :func:`group_trials` gathers the counts of each (participant,
condition) into padded arrays for the vmapped fit, :func:`fit_groups` fits
them all in one call, and :func:`write_fits` writes ``fits.csv``;
:func:`fit_file` does all four, paths in, table out.

Every problem in the input raises ``ValueError`` with a message that names the
file and the row (rows are counted as a spreadsheet shows them, the header
being row 1) or the column.
"""

import codecs
import csv
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import ndtri
from scipy.optimize import brentq, minimize_scalar
from scipy.special import log_ndtr

from jaxadapt.io import atomic_path, csv_writer
from jaxadapt.psychophysics import psychometric

#: Columns of a trial table with one row per trial.
TRIAL_COLUMNS = ("participant", "condition", "level", "response")
#: Columns of a trial table with counts.
COUNT_COLUMNS = ("participant", "condition", "level", "n_yes", "n_total")
#: Group columns that may be left out.
OPTIONAL_COLUMNS = ("participant", "condition")
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


class TrialTable(NamedTuple):
    """The rows of a trial table, as counts (a trial is a count of 1).

    Attributes
    ----------
    participant, condition : numpy array of str
    level : numpy array of float
        log10 units relative to the standard.
    n_yes, n_total : numpy array of float
        "Test brighter" responses and trials.
    row : numpy array of int
        Row of the file (header = 1), for messages.
    source : str
        The file, for messages.
    """

    participant: np.ndarray
    condition: np.ndarray
    level: np.ndarray
    n_yes: np.ndarray
    n_total: np.ndarray
    row: np.ndarray
    source: str


class Groups(NamedTuple):
    """Counts per (participant, condition), padded to a common number of
    levels; padding has ``n_total = 0``, which the fit ignores.

    Attributes
    ----------
    participant, condition : tuple of str, length G
        In order of first appearance in the file.
    levels, n_yes, n_total : numpy array, shape (G, L)
        Distinct levels of each group in increasing order, and their counts.
    """

    participant: tuple
    condition: tuple
    levels: np.ndarray
    n_yes: np.ndarray
    n_total: np.ndarray


class FitTable(NamedTuple):
    """One row per group; the fields are the columns of ``fits.csv``
    (``FIT_COLUMNS``). ``ci_low, ci_high`` bound the PSE (see
    :func:`fit_groups`); ``flags`` are the integer flags of
    :mod:`jaxadapt.psychophysics.psychometric`. Where the data do not determine the
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


# -- reading ------------------------------------------------------------------


def _header(path, header):
    """Index of each used column; which table format the header announces."""
    columns = [name.strip().lower() for name in header]
    repeated = [c for c in dict.fromkeys(columns) if c and columns.count(c) > 1]
    if repeated:
        raise ValueError(f"{path}: expected each column once, got '{repeated[0]}' more than once")
    if "response" in columns and ("n_yes" in columns or "n_total" in columns):
        raise ValueError(
            f"{path}: expected either a 'response' column or 'n_yes' and 'n_total' "
            f"columns, got both"
        )
    required = TRIAL_COLUMNS if "response" in columns or "n_yes" not in columns else COUNT_COLUMNS
    missing = [c for c in required if c not in columns and c not in OPTIONAL_COLUMNS]
    if missing:
        formats = [
            [c for c in f if c not in OPTIONAL_COLUMNS] for f in (TRIAL_COLUMNS, COUNT_COLUMNS)
        ]
        expected = (
            f"{', or '.join(_listed(f) for f in formats)}, and optionally "
            f"{_listed(OPTIONAL_COLUMNS)}"
        )
        if any(_is_number(cell) for cell in header):  # data where the names belong
            raise ValueError(
                f"{path}: expected a header row naming the columns ({expected}), got the "
                f"row {', '.join(cell.strip() for cell in header)}"
            )
        raise ValueError(
            f"{path}: missing column '{missing[0]}' (expected the columns {expected}; "
            f"got {', '.join(cell.strip() for cell in header)})"
        )
    return {c: columns.index(c) for c in required if c in columns}


def _is_number(text):
    """Whether ``text`` reads as a number (``float`` takes it)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def _listed(names):
    """``a``, ``a and b``, ``a, b and c``."""
    return " and ".join([", ".join(names[:-1]), names[-1]] if len(names) > 1 else names)


def _fail(path, rows, bad, column, expected, values):
    i = int(np.argmax(bad))
    raise ValueError(
        f"{path}, row {rows[i]}: column '{column}': expected {expected}, got {values[i]!r}"
    )


def _is_number(text):
    try:
        float(text)
    except ValueError:
        return False
    return True


def _numbers(path, rows, column, values):
    """A column as floats; the first non-numeric or non-finite cell is named."""
    try:
        numbers = np.array(values, dtype=float)
    except ValueError:
        bad = ~np.array([_is_number(v) for v in values])
        _fail(path, rows, bad, column, "a number", values)
    if not np.all(np.isfinite(numbers)):
        _fail(path, rows, ~np.isfinite(numbers), column, "a finite number", values)
    return numbers


def _names(path, rows, column, values):
    names = np.array([v.strip() for v in values], dtype=object)
    if np.any(names == ""):
        _fail(path, rows, names == "", column, "a non-empty name", list(values))
    return names


def read_trials(path):
    """Read and validate a trial table.

    Parameters
    ----------
    path : str or Path
        CSV file, UTF-8, with a header row (see the module notes).

    Returns
    -------
    TrialTable

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ValueError
        A folder, an empty file, missing or repeated columns, rows with the
        wrong number of cells, blank names, non-numeric or non-finite
        numbers, responses other than 0 or 1, negative or fractional counts,
        ``n_yes > n_total``; the message names the file, the row and the
        column.
    """
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{path}: is a folder (expected a CSV trial table)")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file (expected a CSV trial table)")
    with open(path, newline="", encoding="utf-8-sig") as file:
        reader = csv.reader(file)
        try:
            header = next(reader, None)
            if header is None:
                raise ValueError(f"{path}: expected a header row, got an empty file")
            index = _header(path, header)
            cells, rows = [], []
            for cells_of_row in reader:
                if not any(c.strip() for c in cells_of_row):
                    continue
                if len(cells_of_row) != len(header):
                    raise ValueError(
                        f"{path}, row {reader.line_num}: expected {len(header)} cells, "
                        f"got {len(cells_of_row)}"
                    )
                cells.append(cells_of_row)
                rows.append(reader.line_num)
        except UnicodeDecodeError:
            raise ValueError(_not_utf8(path)) from None
    if not cells:
        raise ValueError(f"{path}: expected at least one data row, got none")
    column = {name: [c[i] for c in cells] for name, i in index.items()}
    rows = np.array(rows)
    names = {
        name: _names(path, rows, name, column[name])
        if name in column
        else np.full(len(rows), "all", dtype=object)
        for name in OPTIONAL_COLUMNS
    }
    level = _numbers(path, rows, "level", column["level"])
    if "response" in column:
        n_yes = _numbers(path, rows, "response", column["response"])
        bad = (n_yes != 0) & (n_yes != 1)
        if np.any(bad):
            _fail(path, rows, bad, "response", "0 or 1", column["response"])
        n_total = np.ones_like(n_yes)
    else:
        n_yes, n_total = (_numbers(path, rows, c, column[c]) for c in ("n_yes", "n_total"))
        for name, counts in (("n_yes", n_yes), ("n_total", n_total)):
            bad = (counts < 0) | (counts != np.round(counts))
            if np.any(bad):
                _fail(path, rows, bad, name, "a whole number >= 0", column[name])
        if np.any(n_yes > n_total):
            i = int(np.argmax(n_yes > n_total))
            raise ValueError(
                f"{path}, row {rows[i]}: column 'n_yes': expected at most n_total = "
                f"{column['n_total'][i]}, got {column['n_yes'][i]!r}"
            )
    return TrialTable(
        names["participant"], names["condition"], level, n_yes, n_total, rows, str(path)
    )


# -- grouping -----------------------------------------------------------------


def _not_utf8(path):
    """The message for a trial table that is not UTF-8: where, and whether it
    is UTF-16 or UTF-32 text (a spreadsheet's "Unicode text"), other binary
    data, or text in another encoding (a spreadsheet's export)."""
    raw = Path(path).read_bytes().removeprefix(codecs.BOM_UTF8)
    start = 0
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError as error:
        start = error.start
    if raw.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE, codecs.BOM_UTF32_BE)):
        what = "UTF-16 or UTF-32 text (e.g. a spreadsheet's Unicode text: save it as UTF-8)"
    elif b"\0" in raw:
        what = "binary data"
    else:
        what = "text in another encoding (e.g. a Windows-1252 export: save it as UTF-8)"
    line = raw.count(b"\n", 0, start) + 1
    return f"{path}, line {line}: expected a UTF-8 text CSV, got {what}"


def group_trials(table):
    """Counts per (participant, condition) and level, as padded arrays.

    Parameters
    ----------
    table : TrialTable

    Returns
    -------
    Groups

    Raises
    ------
    ValueError
        A group without trials (its ``n_total`` sum to 0), naming its first
        row.
    """
    first = {}
    keys = zip(table.participant, table.condition, strict=True)
    group = np.array([first.setdefault(key, i) for i, key in enumerate(keys)])
    starts = np.array(sorted(set(first.values())))
    group = np.searchsorted(starts, group)  # 0..G-1 in order of first appearance
    order = np.lexsort((table.level, group))
    g, x = group[order], table.level[order]
    new_cell = np.r_[True, (g[1:] != g[:-1]) | (x[1:] != x[:-1])]
    cell = np.cumsum(new_cell) - 1
    n_yes = np.bincount(cell, weights=table.n_yes[order])
    n_total = np.bincount(cell, weights=table.n_total[order])
    cell_group, cell_level = g[new_cell], x[new_cell]
    group_start = np.r_[True, cell_group[1:] != cell_group[:-1]]
    first_cell = np.maximum.accumulate(np.where(group_start, np.arange(cell.max() + 1), 0))
    position = np.arange(cell.max() + 1) - first_cell
    shape = (len(starts), position.max() + 1)
    arrays = [np.zeros(shape) for _ in range(3)]
    for array, values in zip(arrays, (cell_level, n_yes, n_total), strict=True):
        array[cell_group, position] = values
    empty = arrays[2].sum(axis=1) == 0
    if np.any(empty):
        i = starts[np.argmax(empty)]
        raise ValueError(
            f"{table.source}, row {table.row[i]}: participant {table.participant[i]!r}, condition "
            f"{table.condition[i]!r}: expected at least one trial, got n_total = 0"
        )
    return Groups(tuple(table.participant[starts]), tuple(table.condition[starts]), *arrays)


# -- fitting and writing ------------------------------------------------------


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
):
    """Fit every group, with confidence intervals for the PSE.

    The interval is the bootstrap's percentile interval (or the Wald
    interval), except where the data do not determine the fit
    (:data:`jaxadapt.psychophysics.psychometric.NO_MLE`). Under separation the data
    say only that the PSE lies between the highest level with a "no" and
    the lowest with a "yes" (for a rising function): every PSE in that
    gap fits them as well in the limit of a steep slope. The prior then
    picks one, and resamples of the fitted curve, nearly a step, separate
    again at the same levels: the percentile interval came out 0.04 log
    units wide in a gap of 0.15. So the interval written spans at least
    the gap. Where the data place no PSE at all
    (:data:`~jaxadapt.psychophysics.psychometric.NO_PSE`: every response the same,
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
        As for :func:`jaxadapt.psychophysics.psychometric.bootstrap` (``progress``
        is called with the number of groups done).
    keep_undetermined : bool, optional
        Keep the estimates of groups whose data do not determine the fit
        (:func:`undetermined`), which the fit's prior and least slope set,
        instead of NaN; ``converged`` is false for them either way.

    Returns
    -------
    FitTable
    """
    if n_resamples == 1:  # the bootstrap's own message asked for >= 2 only
        raise ValueError("n_resamples: expected 0 (Wald intervals) or at least 2, got 1")
    count = len(groups.participant)
    options = dict(guess=guess, lapse=lapse)
    if n_resamples:  # in batches of its own (psychometric.bootstrap_blocks)
        arrays = (jnp.asarray(a) for a in (groups.levels, groups.n_yes, groups.n_total))
        boot = psychometric.bootstrap(
            key,
            *arrays,
            n_resamples=n_resamples,
            method=method,
            confidence=confidence,
            progress=progress,
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
    unplaced = (fits.flags & psychometric.NO_PSE) > 0
    single = (fits.flags & psychometric.SINGLE_LEVEL) > 0
    pse_low = np.where(open_, np.where(single, -np.inf, gap_low), np.nan)
    pse_high = np.where(open_, np.where(single, np.inf, gap_high), np.nan)
    separated = ((fits.flags & psychometric.SEPARATION) > 0) & ~unplaced
    sigma_max = np.full(count, np.nan)
    for i in np.flatnonzero(separated):
        sigma_max[i] = sigma_bound(groups.levels[i], groups.n_yes[i], groups.n_total[i])
    values = {name: getattr(fits, name) for name in ("pse", "sigma", "b0", "b1", "se_pse")}
    if not keep_undetermined:
        no_mle = (fits.flags & psychometric.NO_MLE) > 0
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


def undetermined(flags):
    """Groups (by their fit's ``flags``) whose data do not determine the
    fit: no maximum-likelihood estimate exists (every response the same,
    separation, one level: :data:`~jaxadapt.psychophysics.psychometric.NO_MLE`), or
    the slope is zero (``FLAT``), which places no PSE."""
    return (np.asarray(flags) & (psychometric.NO_MLE | psychometric.FLAT)) > 0


#: Confidence of :func:`sigma_bound`, and the drop of the log-likelihood
#: that bounds it: half the chi-squared quantile of one degree of freedom.
SIGMA_BOUND_LEVEL = 0.95
_SIGMA_DROP = 0.5 * 3.841458820694124


def sigma_bound(levels, n_yes, n_total):
    """The largest spread ``sigma`` (log10 units) that data whose levels
    separate the responses do not reject at :data:`SIGMA_BOUND_LEVEL`: the
    profile likelihood's bound (the log-likelihood, maximised over the PSE,
    within ``chi2(1) / 2`` of its supremum, reached as sigma goes to 0);
    ``inf`` when no sigma is rejected (too few trials)."""
    x, k, n = (np.asarray(a, float) for a in (levels, n_yes, n_total))
    x, k, n = x[n > 0], k[n > 0], n[n > 0]
    if np.sum(k * x) / max(np.sum(k), 1e-300) < np.sum((n - k) * x) / max(np.sum(n - k), 1e-300):
        x = -x  # a falling function: its mirror image rises
    span = max(np.ptp(x), 1e-3)

    def profile(sigma):
        def nll(pse):
            z = (x - pse) / sigma
            return -np.sum(k * log_ndtr(z) + (n - k) * log_ndtr(-z))

        lo, hi = x.min() - 10 * sigma - span, x.max() + 10 * sigma + span
        return -minimize_scalar(nll, bounds=(lo, hi), method="bounded").fun

    target = profile(1e-9 * span) - _SIGMA_DROP
    largest = 1e3 * span
    if profile(largest) >= target:
        return np.inf
    log_sigma = brentq(
        lambda u: profile(np.exp(u)) - target, np.log(1e-9 * span), np.log(largest), xtol=1e-10
    )
    return float(np.exp(log_sigma))


def batch_size(count):
    """The number of datasets :func:`fit_groups` fits ``count`` groups as:
    the next power of two, the groups after the first ``count`` copies of
    the first (each dataset of the vmapped fit is fitted on its own, and a
    copy stops when the first does, so it adds no step).

    A compiled fit serves one batch size, and compiling the fit and its
    bootstrap takes about 15 s of a first ``jaxadapt psychometric fit``
    (28 s in all, against 12.5 s for the same table again, with the
    compilation cache of :func:`jaxadapt.runtime.cache_compilations`).
    With sizes rounded up, tables of 9 to 16 groups share one program: a
    later table of another size in the range loads it instead of compiling
    it again. At most twice the datasets are fitted, in a call that takes
    less time than its compilation.

    Examples
    --------
    >>> [batch_size(n) for n in (1, 2, 3, 12, 16, 17, 340)]
    [1, 2, 4, 16, 16, 32, 512]
    """
    return 1 << (count - 1).bit_length()


def separating_gap(groups):
    """Per group, the levels ``(low, high)`` between which the responses
    change: the highest level with a "no" and the lowest with a "yes" when
    every "no" lies at or below every "yes", the reverse for a falling
    function; where neither holds, ``(-inf, inf)``. Under separation
    (:data:`jaxadapt.psychophysics.psychometric.SEPARATION`) the PSE lies in it."""
    x, k, n = groups.levels, groups.n_yes, groups.n_total
    yes, no = (n > 0) & (k > 0), (n > 0) & (k < n)
    top = [np.max(np.where(m, x, -np.inf), axis=1) for m in (no, yes)]
    bottom = [np.min(np.where(m, x, np.inf), axis=1) for m in (yes, no)]
    rising, falling = top[0] <= bottom[0], top[1] <= bottom[1]
    low = np.where(rising, top[0], np.where(falling, top[1], -np.inf))
    high = np.where(rising, bottom[0], np.where(falling, bottom[1], np.inf))
    return low, high


def _at_least_the_data(groups, flags, low, high):
    """The PSE interval ``(low, high)`` widened to what the data leave
    open: the separating gap under separation, everything where they place
    no PSE (:func:`fit_groups`)."""
    low, high = np.asarray(low), np.asarray(high)
    gap_low, gap_high = (g.astype(low.dtype) for g in separating_gap(groups))
    separated = (flags & psychometric.SEPARATION) > 0
    unplaced = (flags & psychometric.NO_PSE) > 0
    low = np.where(separated, np.minimum(low, gap_low), low)
    high = np.where(separated, np.maximum(high, gap_high), high)
    return np.where(unplaced, -np.inf, low), np.where(unplaced, np.inf, high)


#: How ``write_fits`` formats the flags, a column of integers.
_FORMATS = {"flags": lambda value: "|".join(psychometric.flag_names(value))}


def csv_cell(value):
    """A CSV cell: a number as the shortest decimal that reads back to the
    same value in its dtype (not ``str``: colour-science, which jaxadapt
    imports, sets NumPy's printing to its 1.13 style, 6 significant digits in
    float32 and 12 in float64; nor ``repr`` of the float64 it converts to,
    which gives a float32 -0.1 as -0.10000000149011612), a boolean as
    ``true``/``false``, anything else as ``str``."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (float, np.floating)):
        return repr(float(np.format_float_positional(value, unique=True, trim="-")))
    return str(value)


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
