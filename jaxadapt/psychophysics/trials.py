"""Trial tables in: the input files of ``jaxadapt psychometric fit``.

A trial table is a CSV file with a header row and either one row per trial,

    participant,condition,level,response
    p01,control,-0.285,0
    p01,control,0.259,1

or one row per level with counts,

    participant,condition,level,n_yes,n_total
    p01,control,-0.285,3,30

``level`` is log10 units relative to the standard and ``response`` is 1 when
the test was judged brighter. ``participant`` and ``condition`` may be left
out (one group, named ``"all"``).

A session's table from ``jaxadapt experiment`` (or ``psychometric
simulate``) reads as it is: its ``test_chosen`` is the response; rows of
``block`` ``training`` are not analysed but score the participant, who is
excluded (listed, and left out) with fewer than :data:`EXCLUSION` of them
correct (Jacobs et al. 2015, §4.1.1); rows ``flagged`` ``true`` (a frame
dropped while an image was up, the trial shown again) are left out.

:func:`read_trials` reads and validates such a file and
:func:`group_trials` gathers the counts of each (participant, condition)
into padded arrays for the vmapped fit;
:mod:`~jaxadapt.psychophysics.fit_table` fits them and writes ``fits.csv``
(its names are also reachable from this module).

Every problem in the input raises ``ValueError`` with a message that names the
file and the row (rows are counted as a spreadsheet shows them, the header
being row 1) or the column.
"""

import codecs
import csv
from pathlib import Path
from typing import NamedTuple

import numpy as np

__all__ = [
    "TRIAL_COLUMNS",
    "COUNT_COLUMNS",
    "OPTIONAL_COLUMNS",
    "TEST_CHOSEN",
    "FILTER_COLUMNS",
    "SESSION_COLUMNS",
    "EXCLUSION",
    "TrialTable",
    "Groups",
    "OTHER_SEPARATORS",
    "read_trials",
    "group_trials",
    "csv_cell",
]

#: Columns of a trial table with one row per trial.
TRIAL_COLUMNS = ("participant", "condition", "level", "response")
#: Columns of a trial table with counts.
COUNT_COLUMNS = ("participant", "condition", "level", "n_yes", "n_total")
#: Group columns that may be left out.
OPTIONAL_COLUMNS = ("participant", "condition")
#: The name of the response in a session's table: whether the test was chosen.
TEST_CHOSEN = "test_chosen"
#: Columns of a session's table that say which rows are analysed.
FILTER_COLUMNS = ("block", "flagged")
#: The columns of a session's table, in order: ``jaxadapt experiment``
#: writes them, and ``psychometric simulate`` (leaving empty what a model
#: observer does not have: reaction times, measured durations, the time).
SESSION_COLUMNS = (
    "participant",
    "study",
    "block",
    "trial",
    "condition",
    "level",
    "test_luminance",
    "standard_luminance",
    "test_interval",
    "answer",
    TEST_CHOSEN,
    "correct",
    "rt_ms",
    "image1_ms",
    "image2_ms",
    "blank1_ms",
    "blank2_ms",
    "dropped_frames",
    "flagged",
    "answered_at",
)
#: Fewer training trials correct than this fraction exclude a participant
#: (the paper's 70 %, decided before its experiments).
EXCLUSION = 0.7


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
    excluded : dict of str to float
        Participants left out, by their fraction of training trials correct.
    left_out : dict of str to int
        Rows not analysed: ``training``, ``flagged``, ``excluded`` (the
        other rows of excluded participants).
    """

    participant: np.ndarray
    condition: np.ndarray
    level: np.ndarray
    n_yes: np.ndarray
    n_total: np.ndarray
    row: np.ndarray
    source: str
    excluded: dict = {}
    left_out: dict = {}


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


# -- reading ------------------------------------------------------------------


def _header(path, header):
    """Index of each used column; which table format the header announces."""
    columns = [name.strip().lower() for name in header]
    if TEST_CHOSEN in columns:
        if "response" in columns:
            raise ValueError(
                f"{path}: expected either a 'response' or a '{TEST_CHOSEN}' column, got both"
            )
        columns[columns.index(TEST_CHOSEN)] = "response"
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
        separator = _other_separator(header)
        if separator:
            raise ValueError(
                f"{path}: expected columns separated by commas, got a header separated by "
                f"{separator} ({header[0].strip()!r:.80}); save the table as comma-separated CSV"
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
    return {c: columns.index(c) for c in (*required, *FILTER_COLUMNS) if c in columns}


#: Separators of tables that are not comma-separated, as a spreadsheet in
#: a locale with a decimal comma saves them, and their names.
OTHER_SEPARATORS = {";": "semicolons", "\t": "tabs", "|": "vertical bars"}


def _other_separator(header):
    """The name of the separator a one-cell ``header`` row holds, as read
    from a table that is not comma-separated; None where it holds none."""
    if len(header) != 1:
        return None
    return next((name for sep, name in OTHER_SEPARATORS.items() if sep in header[0]), None)


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
        name = "response" if "response" in _lower(header) else TEST_CHOSEN
        n_yes = _numbers(path, rows, name, column["response"])
        bad = (n_yes != 0) & (n_yes != 1)
        if np.any(bad):
            _fail(path, rows, bad, name, "0 or 1", column["response"])
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
    table = TrialTable(
        names["participant"], names["condition"], level, n_yes, n_total, rows, str(path)
    )
    return _analysed(table, column)


def _lower(header):
    return [name.strip().lower() for name in header]


def _analysed(table, column):
    """The rows of ``table`` that are analysed (see the module notes), the
    excluded participants, and what was left out."""
    path, rows = table.source, table.row
    flagged = np.zeros(len(rows), bool)
    if "flagged" in column:
        values = np.array([v.strip().lower() for v in column["flagged"]])
        bad = ~np.isin(values, ("true", "false"))
        if np.any(bad):
            _fail(path, rows, bad, "flagged", "true or false", column["flagged"])
        flagged = values == "true"
    training = np.zeros(len(rows), bool)
    if "block" in column:
        training = np.array([v.strip() == "training" for v in column["block"]])
    scored = training & ~flagged
    excluded = {}
    for who in dict.fromkeys(table.participant[scored]):
        mine = scored & (table.participant == who)
        correct = (table.n_yes[mine] == 1) == (table.level[mine] > 0)
        if np.mean(correct) < EXCLUSION:
            excluded[who] = float(np.mean(correct))
    out = np.isin(table.participant, list(excluded)) & ~training & ~flagged
    keep = ~(training | flagged | out)
    left_out = {
        "training": int(training.sum()),
        "flagged": int((flagged & ~training).sum()),
        "excluded": int(out.sum()),
    }
    if not np.any(keep):
        raise ValueError(
            f"{path}: expected rows to analyse, got none ({left_out['training']} training, "
            f"{left_out['flagged']} flagged, {left_out['excluded']} of excluded participants)"
        )
    kept = TrialTable(*(a[keep] for a in table[:6]), table.source)
    return kept._replace(excluded=excluded, left_out=left_out)


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


def csv_cell(value):
    """A CSV cell: a number as the shortest decimal that reads back to the
    same value in its dtype (not ``str``, which follows NumPy's print
    options, and imported libraries change those; nor ``repr`` of the
    float64 it converts to, which spells out a float32's binary rounding),
    a boolean as ``true``/``false``, anything else as ``str``."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (float, np.floating)):
        return repr(float(np.format_float_positional(value, unique=True, trim="-")))
    return str(value)
