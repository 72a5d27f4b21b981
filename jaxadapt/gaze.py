"""Gaze: where the viewer looks, in frame pixels ``(x, y)``.

Paths are functions ``gaze(times) -> (K, 2)`` of frame times in seconds:
built ones (:func:`fixate`, :func:`saccade`) and recorded ones
(:func:`read_gaze_csv`, :func:`recorded_gaze`), as the eye tracker of
Jacobs et al. (2015) reports them, about 30 samples a second. A sample that
is not finite (NaN) is a blink. :func:`fixation` is how the operators read a
sample: clipped to the frame, a blink replaced by a fallback.
"""

from pathlib import Path

import jax.numpy as jnp
import numpy as np

__all__ = [
    "frame_centre",
    "fixation",
    "fixate",
    "saccade",
    "read_gaze_csv",
    "write_gaze_csv",
    "recorded_gaze",
]


def frame_centre(shape, dtype=float):
    """The centre ``(x, y)``, pixels, of frames of shape ``(H, W)``: the default gaze."""
    H, W = shape
    return jnp.array([(W - 1) / 2.0, (H - 1) / 2.0], dtype=dtype)


def fixation(gaze, fallback, shape):
    """The fixation for gaze samples ``(..., 2)`` (``x, y`` pixels) on frames
    of shape ``(H, W)``: each sample clipped to the frame, or ``fallback``
    where it is not finite (NaN: a blink). The 2015 operator falls back on
    the fixation before the blink, kept in its state; the 2000 operator,
    which keeps no gaze, on the frame's centre."""
    H, W = shape
    clipped = jnp.clip(gaze, 0.0, jnp.array([W - 1, H - 1], dtype=gaze.dtype))
    return jnp.where(jnp.all(jnp.isfinite(gaze), axis=-1, keepdims=True), clipped, fallback)


def fixate(x, y):
    """A gaze path that rests on ``(x, y)`` pixels: ``gaze(times) -> (K, 2)``.

    Examples
    --------
    >>> fixate(3.0, 4.0)(np.arange(2)).tolist()
    [[3.0, 4.0], [3.0, 4.0]]
    """

    def gaze(times):
        return np.tile(np.array([x, y], dtype=np.float64), (len(np.atleast_1d(times)), 1))

    return gaze


def saccade(start, end, at):
    """A gaze path that fixates ``start`` (x, y pixels) until ``at`` seconds,
    then jumps to ``end`` (a saccade lasts tens of milliseconds, less than a
    frame of a 30 Hz eye tracker).

    Examples
    --------
    >>> saccade((0, 0), (5, 1), at=1.0)(np.array([0.5, 1.0])).tolist()
    [[0.0, 0.0], [5.0, 1.0]]
    """

    def gaze(times):
        after = np.atleast_1d(times)[:, None] >= at
        return np.where(after, np.asarray(end, np.float64), np.asarray(start, np.float64))

    return gaze


def read_gaze_csv(path):
    """Read a gaze recording: a CSV of ``t, x, y`` rows (s, pixels).

    A header line (a first line of three cells none of which is a number)
    names the columns, in any order and any case: ``t`` or ``time``, ``x``
    and ``y`` (a header of other names is refused); without one they are
    ``t,x,y``. A UTF-8 byte-order mark,
    which spreadsheets write, is skipped. ``x`` and ``y`` may both be empty or ``nan``
    where the tracker lost the eye (a blink); one of them alone missing, or
    an infinite coordinate (also one beyond float32's range, in which the
    operators compute), is an error. Times must increase.

    Returns
    -------
    (numpy array (N,), numpy array (N, 2))
        Sample times and gaze points.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If a row does not hold three numbers or the times do not increase,
        naming the file and line.
    """
    import csv

    path = Path(path)
    if path.is_dir():
        raise ValueError(f"gaze: expected a CSV file of t,x,y rows, got the folder {path}")
    if not path.is_file():
        raise FileNotFoundError(f"gaze: {path}: no such file")
    rows = []
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError(
            f"gaze: expected a text CSV of t,x,y rows, got binary data in {path}"
        ) from None

    def number(cell):
        try:
            float(cell)
        except ValueError:
            return False
        return True

    last = None  # line of the row before
    order = [0, 1, 2]  # the columns of t, x and y
    for line, row in enumerate(csv.reader(text.splitlines()), start=1):
        cells = [c.strip() for c in row]
        if line == 1 and len(cells) == 3 and all(c and not number(c) for c in cells):
            order = _gaze_columns(cells, path)
            continue
        if not any(cells):
            continue
        try:
            if len(cells) != 3:
                raise ValueError
            cells = [cells[i] for i in order]
            t = float(cells[0])
            xy = [float(c) if c else np.nan for c in cells[1:]]
            if np.isnan(xy[0]) != np.isnan(xy[1]) or np.any(np.abs(xy) > np.finfo(np.float32).max):
                raise ValueError
        except ValueError:
            raise ValueError(
                f"gaze: expected rows of three numbers t,x,y (s, pixels; x and y both "
                f"empty or nan for a blink) in {path}, got {','.join(row)!r} on line {line}"
            ) from None
        if not np.isfinite(t) or (rows and t <= rows[-1][0]):
            raise ValueError(
                f"gaze: expected finite times that increase in {path}, got {cells[0]} on "
                f"line {line}" + (f" after {rows[-1][0]:g} on line {last}" if rows else "")
            )
        rows.append([t, *xy])
        last = line
    if not rows:
        raise ValueError(f"gaze: expected at least one t,x,y row in {path}, got none")
    data = np.asarray(rows)
    return data[:, 0], data[:, 1:]


def _gaze_columns(header, path):
    """The columns of ``t``, ``x`` and ``y`` that the ``header`` cells of a
    gaze file name (:func:`read_gaze_csv`)."""
    names = {"t": ("t", "time"), "x": ("x",), "y": ("y",)}
    lower = [cell.lower() for cell in header]
    columns = [next((i for i, c in enumerate(lower) if c in n), None) for n in names.values()]
    if None in columns:
        raise ValueError(
            f"gaze: expected a header naming the columns t (or time), x and y, in any order, "
            f"in {path}, got {','.join(header)!r}"
        )
    return columns


def write_gaze_csv(path, times, points):
    """Write a gaze recording that :func:`read_gaze_csv` reads back exactly:
    a ``t,x,y`` header, then one row per sample (s, pixels; each number as
    Python's shortest round-tripping form; a blink, NaN, as empty cells).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "gaze.csv"
    >>> write_gaze_csv(path, [0.0, 0.5], [[1.5, 2.0], [np.nan, np.nan]])
    >>> path.read_text().splitlines()
    ['t,x,y', '0.0,1.5,2.0', '0.5,,']
    """
    times, points = np.asarray(times, dtype=np.float64), np.asarray(points, dtype=np.float64)
    if times.ndim != 1 or points.shape != (times.size, 2):
        raise ValueError(
            f"times, points: expected sample times (N,) and gaze points (N, 2), got shapes "
            f"{times.shape} and {points.shape}"
        )
    if not (np.all(np.isfinite(times)) and np.all(np.diff(times) > 0)):
        raise ValueError("times: expected finite sample times that increase")
    rows = ["t,x,y"]
    for t, (x, y) in zip(times.tolist(), points.tolist(), strict=True):
        xy = f"{x!r},{y!r}" if np.isfinite(x) and np.isfinite(y) else ","
        rows.append(f"{t!r},{xy}")
    Path(path).write_text("\n".join(rows) + "\n", encoding="utf-8")


def recorded_gaze(times, points):
    """A gaze path through recorded samples, held from each sample to the next.

    Eye trackers report fixations; holding (rather than interpolating)
    keeps saccades sharp. A blink (a sample that is not finite) holds the
    fixation before it, as the 2015 operator does with a blink in its own
    path, so that every operator, and every chunk of a long sequence, sees
    the same fixation; a recording that starts with a blink stays NaN until
    its first fixation (the operators then take the frame's centre). Before
    the first sample, the first one holds.

    Examples
    --------
    >>> points = np.array([[1.0, 2.0], [np.nan, np.nan], [5.0, 6.0]])  # a blink at 1 s
    >>> path = recorded_gaze(np.array([0.0, 1.0, 2.0]), points)
    >>> path(np.array([0.5, 1.0, 1.5, 9.0])).tolist()
    [[1.0, 2.0], [1.0, 2.0], [1.0, 2.0], [5.0, 6.0]]
    """
    times, points = np.asarray(times, dtype=np.float64), np.asarray(points, dtype=np.float64)
    if times.ndim != 1 or times.size == 0 or points.shape != (times.size, 2):
        raise ValueError(
            f"times, points: expected N >= 1 sample times (N,) and gaze points (N, 2), got "
            f"shapes {times.shape} and {points.shape}"
        )
    if not (np.all(np.isfinite(times)) and np.all(np.diff(times) > 0)):
        raise ValueError(f"times: expected finite sample times that increase, got {times}")
    finite = np.all(np.isfinite(points), axis=-1)
    last = np.maximum.accumulate(np.where(finite, np.arange(len(points)), -1))
    points = np.where((last >= 0)[:, None], points[np.maximum(last, 0)], np.nan)

    def gaze(t):
        i = np.searchsorted(times, np.atleast_1d(t), side="right") - 1
        return points[np.clip(i, 0, len(times) - 1)]

    return gaze
