"""The live viewer's simulation: an operator's state advanced frame by frame
by measured time, its frames as 8-bit pixels, and its record.

A :class:`Session` is built from a *spec* (a dict of the command's choices:
scene or files, size, operator, seed, ...), so that a recorded session
(``session.json``) rebuilds the same one and :func:`replay` gives the same
frames from the recorded ``dt`` and gaze of each frame.
"""

import csv
import hashlib
import json
import math
import re
import warnings
from collections import OrderedDict
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxadapt.operators import OPERATORS, Settings

#: Frame size ``(W, H)`` of a session whose spec gives none, pixels: the
#: smallest size of the ladder on which the command line measures its
#: default (:data:`jaxadapt.viewer.LADDER`, :func:`~jaxadapt.viewer.fitting_size`).
DEFAULT_SIZE = (384, 216)
#: Longest time a frame may advance the simulation, s: a browser tab that
#: sleeps (and stops asking for frames) resumes where it left, not after
#: the minutes it slept.
MAX_DT = 0.25
#: The first frame's duration, and that after a pause, s (no frame before it to time).
FIRST_DT = 1 / 30
#: The scene shown when neither FILE nor ``--scene`` is given.
DEFAULT_SCENE = "patches"
#: Bytes of input frames kept decoded (a looped sequence is read once).
FRAME_CACHE_BYTES = 256 * 2**20
#: The columns of ``frames.csv`` in a record.
FRAME_COLUMNS = ("frame", "t", "dt", "x", "y", "scene_index", "effects", "reset", "digest")
#: The operators the viewer runs: those with a per-frame ``step`` that takes the gaze.
VIEW_OPERATORS = tuple(sorted(OPERATORS.having("live")))
#: The operator of a session whose spec names none.
DEFAULT_OPERATOR = "jacobs2015"
#: Every effect a viewed operator can switch (a record's rows name them).
EFFECTS = tuple(dict.fromkeys(e for n in VIEW_OPERATORS for e in OPERATORS.supports(n).effects))


class Frame(NamedTuple):
    """One frame the viewer showed.

    Attributes
    ----------
    index : int
        Frame number since the session started.
    t : float
        Session time at which the frame is shown, s (the sum of the ``dt`` before it).
    dt : float
        How long the frame advanced the state, s.
    gaze : (float, float)
        Gaze sample used ``(x, y)``, frame pixels (NaN: a blink).
    scene_index : int
        Index of the input frame (the scene or files loop).
    effects : str
        Effects on, joined by ``+`` (``-`` for none; ``""`` for pattanaik2000).
    reset : bool
        Whether the state was re-initialised before this frame.
    pixels : numpy array, (H, W, 3) uint8
        The display frame.
    adaptation : float
        Adaptation luminance after the frame, cd/m2.
    """

    index: int
    t: float
    dt: float
    gaze: tuple
    scene_index: int
    effects: str
    reset: bool
    pixels: np.ndarray
    adaptation: float

    @property
    def digest(self):
        """First 16 hex digits of the SHA-256 of the frame's pixels."""
        return hashlib.sha256(self.pixels.tobytes()).hexdigest()[:16]


def check_spec(spec):
    """Refuse a :class:`Session` spec that it cannot run: a ValueError naming
    the field, what was expected and what came (a record's ``session.json``
    may have been edited by hand). The names come from the registries of
    scenes, operators and effects."""
    from jaxadapt._checks import check_value, check_whole
    from jaxadapt.scenes import SCENES

    _check_choice("operator", spec.get("operator", DEFAULT_OPERATOR), VIEW_OPERATORS)
    size = spec.get("size")
    if not (isinstance(size, (list, tuple)) and len(size) == 2):
        raise ValueError(f"size: expected [width, height] in pixels, got {size!r}")
    for value in size:
        check_whole("size", value, 2, "pixels")
    files = spec.get("files") or []
    if not (isinstance(files, (list, tuple)) and all(isinstance(f, (str, Path)) for f in files)):
        raise ValueError(f"files: expected a list of HDR file paths, got {files!r}")
    if not files:
        _check_choice("scene", spec.get("scene") or DEFAULT_SCENE, sorted(SCENES))
    for name in ("multiplier", "fps", "pixels_per_degree"):
        if spec.get(name) is not None:
            check_value(name, spec[name], _number(lambda v: np.isfinite(v) & (v > 0)), "> 0")
    seed = check_whole("seed", spec.get("seed", 0))
    check_value("seed", seed, lambda s: s <= np.iinfo(np.int64).max, "at most 2**63 - 1")
    effects = spec.get("effects", [])
    if not (isinstance(effects, (list, tuple)) and all(e in EFFECTS for e in effects)):
        raise ValueError(f"effects: expected a list of {', '.join(EFFECTS)}, got {effects!r}")


def _check_choice(name, value, choices):
    if not (isinstance(value, str) and value in choices):
        raise ValueError(f"{name}: expected one of {', '.join(choices)}, got {value!r}")


def _number(ok):
    """``ok`` for :func:`jaxadapt._checks.check_value` that first refuses
    what is not one real number (text, a bool, a list, null)."""
    return lambda v: v.ndim == 0 and v.dtype.kind in "iuf" and bool(ok(v))


def open_source(spec):
    """The :class:`jaxadapt.pipeline.Source` of ``spec`` at its size, and its
    pixels per degree: a built-in scene made at ``spec["size"]``, or files
    shrunk to fit in it (aspect kept)."""
    from jaxadapt import pipeline
    from jaxadapt.scenes import SCENES

    W, H = spec["size"]
    if not spec.get("files"):
        scene = SCENES[spec.get("scene") or DEFAULT_SCENE](width=W, height=H)
        source = pipeline.from_scene(scene, spec.get("multiplier", 1.0))
        return source, source.pixels_per_degree
    files = spec["files"]
    source = pipeline.from_files(files, spec.get("fps"), spec.get("multiplier", 1.0))
    h, w = source.shape
    scale = min(1.0, W / w, H / h)
    size = (max(2, round(h * scale)), max(2, round(w * scale)))
    if size != (h, w):
        source = source._replace(frames=_shrunk(source.frames, size), shape=size)
    return source, source.pixels_per_degree * size[1] / w


def _shrunk(frames, size):
    """``frames(idx)`` shrunk to ``size (H, W)`` in linear light (antialiased)."""
    import jax
    import jax.numpy as jnp

    resize = jax.jit(
        lambda f: jax.image.resize(f, (len(f), *size, 3), "linear", antialias=True),
    )
    return lambda idx: np.maximum(np.asarray(resize(jnp.asarray(frames(idx)))), 0.0)


class Session:
    """A viewer's simulation, advanced one frame at a time by :meth:`advance`.

    Parameters
    ----------
    spec : dict
        ``scene`` (a name of :data:`jaxadapt.scenes.SCENES`) or ``files``
        (HDR paths; ``fps``, frames/s, optional), ``size`` ``(W, H)``
        pixels, and optionally ``multiplier``, ``operator`` (jacobs2015 or
        pattanaik2000), ``seed``, ``pixels_per_degree`` and ``effects``
        (names of :data:`jaxadapt.operators.jacobs2015.EFFECTS` on);
        checked (:func:`check_spec`).
    """

    def __init__(self, spec):
        import jax

        check_spec(spec)
        self.spec = dict(spec)
        self.operator = self.spec.setdefault("operator", DEFAULT_OPERATOR)
        self.op, self.supports = OPERATORS[self.operator], OPERATORS.supports(self.operator)
        self.source, ppd = open_source(self.spec)
        self._cache = OrderedDict()
        self.spec.setdefault("pixels_per_degree", ppd)
        self.spec.setdefault("seed", 0)
        self.shape = tuple(self._input(0).shape[:2])
        self.period = float(self.source.times[-1] + self.source.dt[-1])
        self.key = jax.random.key(self.spec["seed"])
        self._params = {}
        if self.available_effects:
            self.effects = set(self.spec.setdefault("effects", list(self.available_effects)))
        else:
            self.effects = set()
            self.spec["effects"] = []
        self.index, self.t = 0, 0.0
        self._reset_pending = True
        self.state = None

    @property
    def available_effects(self):
        """The effects this operator can switch (none for pattanaik2000)."""
        return self.supports.effects

    def params(self):
        """The operator's :class:`Params` for the effects now on, from the
        registry's contract (:meth:`~jaxadapt.operators.Operator.configure`;
        cached: each combination compiles once)."""
        key = self.effects_name()
        if key not in self._params:
            settings = Settings(
                self.operator,
                fps=1 / FIRST_DT,
                pixels_per_degree=float(self.spec["pixels_per_degree"]),
                goal="foveal",
                effects=tuple(sorted(self.effects)),
            )
            self._params[key] = self.op.configure(settings)
        return self._params[key]

    def effects_name(self):
        """The effects on, as recorded: names joined by ``+``, ``-`` for none."""
        if not self.available_effects:
            return ""
        return "+".join(e for e in self.available_effects if e in self.effects) or "-"

    def set_effects(self, name):
        """Switch the effects to those of an :meth:`effects_name` string."""
        if self.available_effects:
            self.effects = set() if name == "-" else set(name.split("+"))

    def toggle(self, effect, on):
        """Switch ``effect`` (a name of :attr:`available_effects`) on or off."""
        if effect not in self.available_effects:
            raise ValueError(
                f"effect: expected one of {', '.join(self.available_effects) or 'none'} "
                f"for {self.operator}, got {effect!r}"
            )
        (self.effects.add if on else self.effects.discard)(effect)

    def reset(self):
        """Restart the scene and the viewer's adaptation, from the next frame."""
        self._reset_pending = True

    def scene_index(self, t):
        """Index of the input frame at session time ``t`` (s): the input loops."""
        loop = math.fmod(t, self.period)
        return int(np.searchsorted(self.source.times, loop, side="right") - 1)

    def _input(self, i):
        cache = self._cache
        if i not in cache:
            cache[i] = self.source.frames(np.array([i]))[0]
            while len(cache) > 1 and len(cache) * cache[i].nbytes > FRAME_CACHE_BYTES:
                cache.popitem(last=False)
        cache.move_to_end(i)
        return cache[i]

    def advance(self, dt, gaze, scene_index=None):
        """Show the next frame with gaze sample ``gaze`` (x, y pixels; NaN a
        blink) and advance the state by ``dt`` seconds; return its :class:`Frame`.

        ``scene_index`` (a replay's) overrides the input frame that the
        session time gives."""
        import jax.numpy as jnp

        reset = self._reset_pending
        if reset:
            self.t, self._reset_pending = 0.0, False
        i = self.scene_index(self.t) if scene_index is None else scene_index
        frame = jnp.asarray(self._input(i))
        g = jnp.asarray(np.asarray(gaze, np.float32))
        params = self.params()
        if reset:
            self.state = self.op.init(
                params, frame, gaze=g, key=self.key, adaptation=self.source.adaptation
            )
        self.state, out = self.op.step(params, self.state, frame, dt, gaze=g)
        record = Frame(
            self.index,
            self.t,
            float(dt),
            tuple(float(v) for v in np.asarray(g)),
            i,
            self.effects_name(),
            reset,
            self._pixels(out),
            self.adaptation(),
        )
        self.index, self.t = self.index + 1, self.t + float(dt)
        return record

    def warm(self):
        """Compile the step for the effects now on (a step on the first
        input frame from a fresh state; the session is left as it was)."""
        import jax.numpy as jnp

        params, frame = self.params(), jnp.asarray(self._input(0))
        gaze = jnp.asarray(np.full(2, np.nan, np.float32))
        state = self.op.init(params, frame, gaze=gaze, key=self.key)
        self._pixels(self.op.step(params, state, frame, FIRST_DT, gaze=gaze)[1])

    def _pixels(self, out):
        from jaxadapt import display

        if self.supports.display_encoded:  # (jacobs2015: its J, dithered)
            return display.to_uint8(out)
        return display.encode_uint8(out, "srgb")

    def adaptation(self):
        """The viewer's adaptation luminance now, cd/m2 (jacobs2015: ``10^A``;
        pattanaik2000: the cones' ``A_cone``)."""
        if self.state is None:
            return math.nan
        if self.available_effects:
            return float(10.0**self.state.A)
        return float(self.state.A_cone)


class Recorder:
    """Writes a session's record into folder ``path``: ``session.json`` (the
    spec, then the frame count and ``complete``), ``frames.csv`` (one row
    per frame, :data:`FRAME_COLUMNS`; ``t`` restarts at a reset) and
    ``gaze.csv`` (``t,x,y`` rows: the gaze used by each frame against the
    time since the session started, which ``jaxadapt render --gaze`` reads)."""

    def __init__(self, path, spec):
        from jaxadapt.io import csv_writer

        self.check(path)
        self.path = Path(path)
        self.path.mkdir(parents=True, exist_ok=True)
        self.spec = {**spec, "files": [str(f) for f in spec.get("files") or []]}
        self.count, self.clock = 0, 0.0
        self._write_session(complete=False)
        self._frames = open(self.path / "frames.csv", "w", newline="")
        self._rows = csv_writer(self._frames)
        self._rows.writerow(FRAME_COLUMNS)
        self._gaze = []  # (time since the start, x, y) of each frame

    @staticmethod
    def check(path):
        """Refuse ``path`` for a record before anything is computed (a
        ValueError naming ``--record``): a file, a path under a file, or a
        folder that holds a recorded session already."""
        path = Path(path)
        wrong = _not_a_folder(path)
        if wrong:
            raise ValueError(f"--record: {wrong}")
        if (path / "session.json").exists():
            raise ValueError(
                f"--record: expected a folder without a recorded session, got {path}, "
                "which holds one (session.json); choose another folder"
            )

    def _write_session(self, complete):
        from jaxadapt import __version__

        text = json.dumps(
            {**self.spec, "jaxadapt": __version__, "frames": self.count, "complete": complete},
            indent=2,
        )
        partial = self.path / "session.json.partial"
        partial.write_text(text + "\n")
        partial.replace(self.path / "session.json")

    def write(self, frame):
        """Append one :class:`Frame`."""
        x, y = (repr(v) if math.isfinite(v) else "" for v in frame.gaze)  # "": a blink
        row = [frame.index, repr(frame.t), repr(frame.dt), x, y, frame.scene_index]
        self._rows.writerow([*row, frame.effects, int(frame.reset), frame.digest])
        self._gaze.append((self.clock, *frame.gaze))
        self.count, self.clock = self.count + 1, self.clock + frame.dt
        if self.count % 30 == 0:
            self._frames.flush()

    def close(self):
        """Close ``frames.csv``, write ``gaze.csv``; mark the record complete."""
        from jaxadapt.gaze import write_gaze_csv

        self._frames.close()
        gaze = np.reshape(np.asarray(self._gaze, np.float64), (-1, 3))
        write_gaze_csv(self.path / "gaze.csv", gaze[:, 0], gaze[:, 1:])
        self._write_session(complete=True)


def _not_a_folder(path):
    """What is wrong with ``path`` as a folder (a file, or under one), or None."""
    path = Path(path)
    found = next(p for p in (path, *path.parents) if p.exists() or p == p.parent)
    if found.exists() and not found.is_dir():
        if found == path:
            return f"expected a folder, got the file {path}"
        return f"expected a folder, got {path}, under the file {found}"
    return None


def read_record(path):
    """The spec (``session.json``) and frame rows (``frames.csv``: dicts of
    :data:`FRAME_COLUMNS`, numbers, ``x`` and ``y`` NaN in a blink, and
    strings) of a record written by ``jaxadapt view --record``, checked.

    Raises FileNotFoundError where a file is missing, and ValueError that
    names the file, its row (counted as a spreadsheet shows them, the
    header being row 1) or field, what was expected and what came. A last
    row cut short, as a view stopped while writing it leaves it, is left
    out with a warning.
    """
    path = Path(path)
    wrong = _not_a_folder(path)
    if wrong:
        raise ValueError(wrong)
    json_path, csv_path = path / "session.json", path / "frames.csv"
    try:
        spec_text, text = json_path.read_text("utf-8"), csv_path.read_text("utf-8")
    except FileNotFoundError as error:
        raise FileNotFoundError(f"{error.filename}: no such file") from None
    except UnicodeDecodeError as error:
        raise ValueError(f"{path}: expected UTF-8 text files, got {error.reason}") from None
    try:
        try:
            spec = json.loads(spec_text)
        except json.JSONDecodeError as error:
            raise ValueError(
                f"expected a JSON object, got text that is not JSON ({error})"
            ) from None
        if not isinstance(spec, dict):
            raise ValueError(f"expected a JSON object, got {spec_text[:40]!r}")
        check_spec(spec)
    except ValueError as error:
        raise ValueError(f"{json_path}: {error}") from None
    lines = text.splitlines()
    header, *cells = csv.reader(lines) if lines else [[]]
    if header != list(FRAME_COLUMNS):
        raise ValueError(
            f"{csv_path}, row 1: expected the columns {','.join(FRAME_COLUMNS)}, "
            f"got {','.join(header) or 'an empty file'}"
        )
    rows = []
    for n, row in enumerate(cells, 2):
        try:
            rows.append(_frame_row(row))
        except ValueError as error:
            if n == len(lines) and not text.endswith(("\n", "\r")):
                warnings.warn(
                    f"{csv_path}, row {n}: cut short, as a view stopped while writing it "
                    f"leaves its last row ({error}); left out",
                    stacklevel=2,
                )
                break
            raise ValueError(f"{csv_path}, row {n}: {error}") from None
    for n, row in enumerate(rows):  # a frame's state follows from all before it
        if row["frame"] != n:
            raise ValueError(
                f"{csv_path}, row {n + 2}: frame: expected frame {n}, the one after "
                f"{'the header' if n == 0 else f'frame {n - 1}'}, got {row['frame']} "
                "(rows removed or reordered: a replay needs every frame in order)"
            )
    return spec, rows


def _frame_row(cells):
    """A row of ``frames.csv`` (its cells) as a dict of values, checked."""
    from jaxadapt._checks import check_value, check_whole

    if len(cells) != len(FRAME_COLUMNS):
        raise ValueError(f"expected {len(FRAME_COLUMNS)} cells, got {len(cells)}")
    row = dict(zip(FRAME_COLUMNS, cells, strict=True))
    number = {k: _read_number(v) for k, v in row.items()}
    for name in ("frame", "scene_index"):
        row[name] = check_whole(name, number[name])
    check_value("t", number["t"], _number(np.isfinite), "a time in seconds")
    check_value("dt", number["dt"], _number(lambda v: np.isfinite(v) & (v > 0)), "seconds > 0")
    if row["x"] or row["y"]:  # (both empty: a blink)
        for name in ("x", "y"):
            check_value(name, number[name], _number(np.isfinite), "pixels (empty in a blink)")
    effects = [] if row["effects"] in ("", "-") else row["effects"].split("+")
    if not all(e in EFFECTS for e in effects):
        raise ValueError(
            f"effects: expected names of {', '.join(EFFECTS)} joined by +, or - for none, "
            f"got {row['effects']!r}"
        )
    if row["reset"] not in ("0", "1"):
        raise ValueError(f"reset: expected 0 or 1, got {row['reset']!r}")
    if not re.fullmatch("[0-9a-f]{16}", row["digest"]):
        raise ValueError(f"digest: expected 16 hex digits, got {row['digest']!r}")
    x, y = (float(row[k] or "nan") for k in ("x", "y"))
    times = {"t": float(number["t"]), "dt": float(number["dt"])}
    return {**row, **times, "x": x, "y": y, "reset": row["reset"] == "1"}


def _read_number(text):
    """A cell as the number it reads as, else as it is (which the checks of
    numbers refuse, naming it)."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def replay(path, record=None):
    """Replay a recorded session: its :class:`Frame` s as the viewer showed
    them, from the record's spec, ``dt``, gaze, input frame, effects and
    resets of each frame (exactly: each frame's ``digest`` matches the
    recorded one, in a process with JAX's precision as recorded: float64
    off, as the command line runs; with it on, a dithered pixel can round
    the other way).

    The record (``record``: what :func:`read_record` gave, where read
    already) and its input are checked before the first frame, with the
    errors of :func:`read_record`; an iterator of the frames is returned.

    Examples
    --------
    ``[f.digest for f in replay("session")]`` equals the ``digest`` column of
    ``session/frames.csv``.
    """
    path = Path(path)
    spec, rows = read_record(path) if record is None else record
    spec = {k: v for k, v in spec.items() if k not in ("jaxadapt", "frames", "complete")}
    try:
        session = Session(spec)
    except (ValueError, OSError) as error:  # the input files
        raise ValueError(f"{path / 'session.json'}: {error}") from None
    count = len(session.source.times)
    for n, row in enumerate(rows, 2):
        if row["scene_index"] >= count:
            raise ValueError(
                f"{path / 'frames.csv'}, row {n}: scene_index: expected an input frame from 0 "
                f"to {count - 1}, got {row['scene_index']}"
            )
    return _replayed(session, rows)


def _replayed(session, rows):
    for row in rows:
        if row["reset"]:
            session.reset()
        session.set_effects(row["effects"])
        yield session.advance(row["dt"], (row["x"], row["y"]), row["scene_index"])
