"""Sequences of any length through an operator, streamed in bounded memory.

A :class:`Source` produces calibrated frames (cd/m2) on demand, from a
built-in scene or from HDR files, so that a long sequence is never held in
memory whole. :func:`chunks` runs an operator over it: each chunk is one
call of the operator's ``run``, started from the state the previous chunk
ended in, so the result equals one call over the whole sequence. The next
chunk is read in a background thread while the operator computes
(:func:`ahead`), and :func:`behind` writes a chunk's results in another
while the next is computed, so that a render runs at the speed of its
slowest stage rather than the sum of the three. The chunk's length follows
from a memory budget and the frame size (:func:`chunk_size`), so memory
does not grow with the sequence's length.
"""

import contextlib
import os
import queue
import threading
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt import io, runtime
from jaxadapt._checks import check_value, check_whole
from jaxadapt.io import frame_rate, hdr_size, is_url, read_hdr, url_name
from jaxadapt.physiology import kinetics

__all__ = [
    "FILE_PIXELS_PER_DEGREE",
    "FILE_FPS",
    "MEMORY_BUDGET",
    "CHUNK_COPIES",
    "MAX_CHUNK",
    "chunk_size",
    "Source",
    "from_scene",
    "files_rate",
    "from_files",
    "from_video",
    "part",
    "chunks",
    "transition",
    "ahead",
    "behind",
    "concatenate",
    "collect",
    "with_gaze",
]

#: Pixels per degree assumed for files, whose viewing geometry is unknown:
#: a 1920-pixel-wide frame seen across 64 degrees.
FILE_PIXELS_PER_DEGREE = 30.0
#: Frame rate of HDR files whose first file's header gives none, frames per second.
FILE_FPS = 30.0


#: Bytes of frames that :func:`chunks` holds at once by default, in all its
#: stages together (:func:`chunk_size`): 1 GiB.
MEMORY_BUDGET = 2**30
#: Chunks' worth of float32 frames alive at once while streaming: the chunk
#: read ahead, the chunk computed (its frames, the operator's display frames
#: and temporaries, and their copy on the host) and the chunk written
#: behind. Measured: ``benchmarks/bench_render.py`` records peak memory.
CHUNK_COPIES = 6
#: The longest chunk, frames: beyond it a call's fixed cost is already small.
MAX_CHUNK = 32


def chunk_size(shape, budget=MEMORY_BUDGET):
    """Frames per chunk for frames of ``shape`` ``(H, W)`` within ``budget``
    bytes: ``budget // (CHUNK_COPIES * H * W * 3 * 4)``, from 1 to
    :data:`MAX_CHUNK`. A 1920x1080 frame takes 24.9 MB, so the default
    budget gives 7 frames a chunk; a 3840x2160 frame 99.5 MB, 1 frame."""
    budget = check_whole("budget", budget, least=1, unit="bytes")
    H, W = shape
    return int(np.clip(budget // (CHUNK_COPIES * H * W * 3 * 4), 1, MAX_CHUNK))


class Source(NamedTuple):
    """Frames to render, produced chunk by chunk.

    Attributes
    ----------
    name : str
    times, dt : numpy array, (T,)
        Frame times and durations, s.
    frames : callable
        ``frames(idx) -> (K, H, W, 3)`` float32 numpy frames, cd/m2.
    gaze : callable
        ``gaze(idx) -> (K, 2)`` gaze points ``(x, y)``, pixels.
    goal : str
        Adaptation goal the source suggests.
    adaptation : float or None
        Luminance (cd/m2) the viewer is adapted to before the first frame;
        None to adapt to the first frame.
    pixels_per_degree : float
        Resolution of the frames at the viewer's eye.
    shape : tuple
        Frame size ``(H, W)``, pixels, known before a frame is made.
    """

    name: str
    times: np.ndarray
    dt: np.ndarray
    frames: Callable
    gaze: Callable
    goal: str
    adaptation: float | None
    pixels_per_degree: float
    shape: tuple


def _check_multiplier(multiplier):
    """Refuse a multiplier that is not positive and finite in float32: 1e-50
    is 0 there (every frame would be black), 1e40 infinite. Compared with
    float32's bounds rather than cast, which warns of the overflow before
    the message says it."""
    float32 = np.finfo(np.float32)
    check_value(
        "multiplier",
        multiplier,
        lambda m: (m >= float32.smallest_subnormal) & (m <= float32.max),
        "a positive finite factor (float32: 1.4e-45 to 3.4e+38)",
    )


def _calibrated(frames, multiplier, name):
    """``frames * multiplier`` in float32; a ValueError naming ``name`` (the
    frames' source) where that overflows."""
    if multiplier == 1:
        return frames  # (frames * 1 is frames: a pass over memory saved)
    with np.errstate(over="ignore"):
        calibrated = frames * np.float32(multiplier)
    if not np.all(np.isfinite(calibrated)):
        raise ValueError(
            f"{name}: times the multiplier {multiplier:g}, values exceed the float32 range "
            f"(largest value {float(frames.max()):g})"
        )
    return calibrated


def from_scene(scene, multiplier=1.0):
    """A :class:`Source` over a :class:`jaxadapt.scenes.Scene`, scaled by ``multiplier``."""
    _check_multiplier(multiplier)

    def frames(idx):
        rendered = np.asarray(scene.render(scene.times[idx]), np.float32)
        return _calibrated(rendered, multiplier, f"scene {scene.name}")

    def gaze(idx):
        return np.asarray(scene.gaze(scene.times[idx]))

    return Source(
        scene.name,
        scene.times,
        scene.dt,
        frames,
        gaze,
        scene.goal,
        scene.adaptation,
        scene.pixels_per_degree,
        scene.shape,
    )


def files_rate(paths):
    """The frame rate of a sequence of HDR files, frames/s: the first file's
    header's (:func:`jaxadapt.io.frame_rate`: an EXR's framesPerSecond),
    else :data:`FILE_FPS`."""
    rate = frame_rate(paths[0])
    return FILE_FPS if rate is None else rate


def from_files(paths, fps=None, multiplier=1.0):
    """A :class:`Source` over HDR files, one frame each, in the order given.

    Parameters
    ----------
    paths : str, Path or a sequence of them
        EXR, Radiance HDR, PFM or float TIFF files (:func:`jaxadapt.io.read_hdr`):
        one (a still image; a single ``str`` is one path) or the frames of a
        sequence; local paths, or URLs (:func:`jaxadapt.io.is_url`).
    fps : float, optional
        Frame rate, frames per second; by default the first file's
        (:func:`files_rate`: its header's, else :data:`FILE_FPS`).
    multiplier : float
        Factor that calibrates the values to cd/m2.

    Raises
    ------
    FileNotFoundError
        A file does not exist.
    ValueError
        No path, ``fps`` or ``multiplier`` not positive and finite, a file
        that cannot be read as an HDR image or whose size differs from the
        first's (all checked up front, from the files' headers alone: no
        pixel is read until a chunk asks for it); later, when its chunk is
        read, a frame whose pixel data are truncated or corrupt, or that
        holds negative, NaN or infinite values.
    """
    paths = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    paths = [p if is_url(p) else Path(p) for p in paths]
    if not paths:
        raise ValueError("paths: expected at least one HDR file, got none")
    fps = files_rate(paths) if fps is None else fps
    check_value("fps", fps, lambda f: np.isfinite(f) & (f > 0), "a positive frame rate")
    _check_multiplier(multiplier)
    W, H = hdr_size(paths[0])
    for p in paths[1:]:
        width, height = hdr_size(p)
        if (width, height) != (W, H):
            raise ValueError(f"{p}: expected {W}x{H} like {paths[0]}, got {width}x{height}")

    def read(i):
        frame = read_hdr(paths[i])
        _check_values(frame, paths[i])
        return _calibrated(frame, multiplier, paths[i])

    centre = np.array([(W - 1) / 2.0, (H - 1) / 2.0])
    T, first = len(paths), url_name(paths[0])
    return Source(
        first if T == 1 else f"{first} to {url_name(paths[-1])} ({T} files)",
        np.arange(T) / fps,
        np.full(T, 1.0 / fps),
        lambda idx: np.stack([read(i) for i in idx]),
        lambda idx: np.tile(centre, (len(idx), 1)),
        "log_average",
        None,
        FILE_PIXELS_PER_DEGREE,
        (H, W),
    )


def from_video(path, transfer=None, primaries=None, hlg_peak=None, multiplier=1.0):
    """A :class:`Source` over a video file's frames (:func:`jaxadapt.io.read_video`).

    Parameters
    ----------
    path : str or Path
        HDR10 (PQ), HLG or SDR video that FFmpeg reads (H.264, HEVC, AV1,
        ProRes ... in MP4, MKV, MOV).
    transfer, primaries : str, optional
        Overrides of the stream's tags (:func:`jaxadapt.io.probe_video`).
    hlg_peak : float, optional
        HLG's display peak, cd/m2 (default :data:`jaxadapt.io.HLG_PEAK`).
    multiplier : float
        Factor on the decoded cd/m2 (SDR video is decoded at a reference
        white of :data:`jaxadapt.io.SDR_WHITE`).

    The frames' times and durations are their presentation stamps' (a
    video of variable frame rate keeps its timing); the frames are decoded
    in order as the chunks ask for them. A file cut short (a download that
    stopped) gives the frames that decode, with an
    :class:`~jaxadapt.io.IncompleteInputWarning` that says how many.

    Raises
    ------
    FileNotFoundError, ValueError
        As :func:`jaxadapt.io.probe_video`, up front; when a chunk is read,
        a frame FFmpeg cannot decode inside the file (corrupt data).
    """
    info = io.probe_video(path, transfer, primaries)
    peak = io.HLG_PEAK if hlg_peak is None else hlg_peak
    check_value("hlg_peak", peak, lambda v: np.isfinite(v) & (v > 0), "a positive luminance")
    _check_multiplier(multiplier)
    times, dt, whole = io.video_times(path)
    if not whole:  # (which frames decode, only decoding tells)
        times, dt, _ = io.video_times(path, cut_short=True)
        announced = f" of the {info.frames} its index announces" if info.frames else ""
        warnings.warn(
            f"{Path(path).name}: the file is cut short; its first {len(times)} frames"
            f"{announced} decode and are rendered",
            io.IncompleteInputWarning,
            stacklevel=2,
        )
    frames = _VideoFrames(info, peak, whole, multiplier, len(times))
    centre = np.array([(info.width - 1) / 2.0, (info.height - 1) / 2.0])
    return Source(
        Path(path).name,
        times,
        dt,
        frames,
        lambda idx: np.tile(centre, (len(idx), 1)),
        "log_average",
        None,
        FILE_PIXELS_PER_DEGREE,
        (info.height, info.width),
    )


class _VideoFrames:
    """``frames(idx)`` of a video (:func:`from_video`): decoded in order from
    where the last call stopped, or from the key frame before ``idx[0]``
    (a render reads forwards; a shard of one split in time starts
    anywhere). Pickled without its decoder (a shard on a cluster's worker
    opens its own)."""

    def __init__(self, info, hlg_peak, whole, multiplier, total):
        self.info, self.hlg_peak, self.whole = info, hlg_peak, whole
        self.multiplier, self.total = multiplier, total
        self.decoder, self.at = None, 0

    def __getstate__(self):
        return {**self.__dict__, "decoder": None, "at": 0}

    def _decoded(self, first):
        chunks = io.read_video(
            self.info, hlg_peak=self.hlg_peak, cut_short=not self.whole, first=first
        )
        for _, chunk in chunks:
            yield from chunk

    def __call__(self, idx):
        idx = np.asarray(idx)
        if self.decoder is None or idx[0] != self.at:  # (first, or not in order)
            self.decoder, self.at = self._decoded(int(idx[0])), int(idx[0])
        out = []
        for i in idx:
            frame = next(self.decoder, None)
            if frame is None:
                raise ValueError(
                    f"{self.info.path}: frame {i} of {self.total} could not be decoded (the "
                    "file ends before the frames its packets announce: truncated?)"
                )
            out.append(frame)
        self.at = int(idx[-1]) + 1
        return _calibrated(np.stack(out), self.multiplier, self.info.path)


#: The ``oiiotool`` options that repair a frame's bad values, what each
#: does, and the kinds of bad value it repairs (:func:`_check_values`).
_REPAIRS = (
    ("--fixnan black", "sets NaN and infinite pixels to black", ("NaN", "infinite")),
    ("--clamp:min=0", "clips negative values", ("negative",)),
)


def _check_values(frame, path):
    """Refuse a frame ``(H, W, 3)`` read from ``path`` that holds negative,
    NaN or infinite values: a ValueError with the count of each and where
    the first is, and the ``oiiotool`` options that repair them. Small
    negative values are common in real EXRs (a renderer's filter ringing, a
    camera's black level); ``--clamp:min=0`` clips them, and ``--fixnan
    black`` sets NaN and infinite pixels to black."""
    # Two reductions for a good frame (NaN makes the least NaN, -inf it too).
    if not (frame.min() >= 0 and frame.max() < np.inf):
        bad = ~(np.isfinite(frame) & (frame >= 0))
        kinds = {
            "negative": (frame < 0) & np.isfinite(frame),  # -inf is counted as infinite
            "NaN": np.isnan(frame),
            "infinite": np.isinf(frame),
        }
        counts = {name: int(mask.any(axis=-1).sum()) for name, mask in kinds.items()}
        row, column = np.argwhere(bad.any(axis=-1))[0]
        found = ", ".join(
            f"{n} pixel{'s' * (n > 1)} with {name} values" for name, n in counts.items() if n
        )
        repairs = [
            (option, effect) for option, effect, kinds in _REPAIRS if any(counts[k] for k in kinds)
        ]
        raise ValueError(
            f"{path}: expected finite, non-negative values, got {found} "
            f"(the first at row {row}, column {column}); oiiotool {path} "
            f"{' '.join(o for o, _ in repairs)} -o OUT {' and '.join(e for _, e in repairs)}"
        )


def part(source, start, stop):
    """The frames ``start`` to ``stop - 1`` of ``source``, a :class:`Source`
    of their own (a shard of a render split in time): its times still
    count from the sequence's start."""
    times = source.times[start:stop]
    return source._replace(
        name=f"{source.name}, frames {start} to {stop - 1}",
        times=times,
        dt=source.dt[start:stop],
        frames=lambda idx: source.frames(np.asarray(idx) + start),
        gaze=lambda idx: source.gaze(np.asarray(idx) + start),
    )


def _read(source, size):
    """Chunks ``(idx, frames, gaze)`` of ``source``, ``size`` frames each,
    put on the device."""
    T = len(source.times)
    for start in range(0, T, size):
        idx = np.arange(start, min(start + size, T))
        frames = jnp.asarray(source.frames(idx))
        yield idx, frames, jnp.asarray(source.gaze(idx), jnp.float32)


def transition(op, params, source, size=None, *, budget=MEMORY_BUDGET):
    """What the frames of ``source`` do to the state of operator module
    ``op`` (a ``composable`` one, with ``transition``): the affine map
    ``(a, b)`` of the whole source, composed chunk by chunk in bounded
    memory, as :func:`chunks` reads them. A render split in time starts
    each shard from ``a * state + b`` of the shards before it."""
    if size is None:
        size = chunk_size(source.shape, budget)
    size = check_whole("size", size, least=1, unit="frames")
    ab = None
    with contextlib.closing(ahead(_read(source, size))) as frames_ahead:
        for idx, frames, gaze in frames_ahead:
            dt = jnp.asarray(source.dt[idx], jnp.float32)
            step = op.transition(params, frames, dt, gaze=gaze)
            ab = step if ab is None else _then(ab, step)
    return ab


def _then(first, second):
    """:func:`~jaxadapt.physiology.kinetics.then` of two maps ``(a, b)`` of
    an operator's state, field by field."""
    pairs = jax.tree.map(lambda *x: kinetics.then(x[:2], x[2:]), *first, *second)
    state, pair = jax.tree.structure(first[0]), jax.tree.structure((0, 0))
    return tuple(jax.tree.transpose(state, pair, pairs))


def chunks(op, params, source, size=None, key=None, *, budget=MEMORY_BUDGET, state=None):
    """Run operator module ``op`` over ``source``, a chunk of frames per call.

    The next chunk's frames are read (and put on the device) in a
    background thread while the operator computes this one (:func:`ahead`).

    Parameters
    ----------
    op : module
        An operator with the contract of :mod:`jaxadapt.operators`
        (``init``, ``run`` and ``diagnostics_table``).
    params : op.Params
    source : Source
    size : int, optional
        Frames per call; by default :func:`chunk_size` of the frames and
        ``budget``. Every chunk but the last has this length, so the
        operator compiles at most twice.
    key : PRNG key, optional
        Key of the sequence, for the stochastic operators.
    budget : int
        Bytes of frames held at once, for the default ``size``; also how
        far the process may grow past its size after the first chunk
        before freed memory is handed back (:class:`runtime.MemoryCeiling`).
    state : optional
        The operator's state at the first frame (a shard of a render split
        in time), or a function that returns it, called once the first
        chunk is read (a state that another process is still computing);
        by default its ``init`` of the first frame.

    Yields
    ------
    (numpy array, numpy array, dict)
        Frame indices ``(n,)``, display frames ``(n, H, W, 3)`` in [0, 1]
        and the chunk's diagnostics as columns of length ``n``.

    Returns
    -------
    The operator's state after the last frame, as the generator's return
    value (``StopIteration.value``): a shard of a render
    split in time hands it to the next.

    Raises
    ------
    ValueError
        ``size`` or ``budget`` is not a whole number, at least 1.
    FloatingPointError
        A display frame holds a non-finite value (:func:`_finite`).
    """
    if size is None:
        size = chunk_size(source.shape, budget)
    size = check_whole("size", size, least=1, unit="frames")
    ceiling = runtime.MemoryCeiling(budget)
    with contextlib.closing(ahead(_read(source, size))) as frames_ahead:
        for idx, frames, gaze in frames_ahead:
            if idx[0] == 0 and callable(state):
                state = state()
            if idx[0] == 0 and state is None:  # (None too for an operator without one)
                state = op.init(
                    params, frames[0], gaze=gaze[0], key=key, adaptation=source.adaptation
                )
            dt = jnp.asarray(source.dt[idx], jnp.float32)
            out, diag = op.run(params, frames, dt, gaze=gaze, state=state)
            del frames  # not held while the chunk is written
            state = diag.final_state
            table = op.diagnostics_table(diag)
            table["t"] = source.times[idx]
            yield idx, _finite(np.asarray(out), idx, op), table
            del out, diag
            ceiling()  # the retained heap bounded, however long the sequence
    return state


#: What a stage's queue holds after its last item.
_END = object()


def ahead(items, depth=1):
    """Iterate over ``items`` (an iterator), computed in a background thread
    at most ``depth`` items ahead of the caller: the thread starts on the
    next item when the caller takes one, so that one item is computed while
    the caller works on the one before, and no more are held.

    An error in the thread is raised here, at the item it stopped at. When
    the caller stops (its loop ends early, an error, ``close()``), the
    thread is told to stop, finishes the item it is computing and is
    joined: no thread outlives the iteration.
    """
    q, room, stop = queue.Queue(), threading.Semaphore(depth), threading.Event()

    def work():
        try:
            while _acquire(room, stop):
                item = next(items, _END)
                q.put((item, None))
                if item is _END:
                    return
        except BaseException as error:  # raised in the caller
            q.put((None, error))

    thread = threading.Thread(target=work, name="jaxadapt-read-ahead", daemon=True)
    thread.start()
    try:
        while True:
            item, error = q.get()
            if error is not None:
                raise error
            if item is _END:
                return
            room.release()  # the thread goes on to the next item
            box, item = [item], None
            yield box.pop()  # not held here while the caller works on it
    finally:
        stop.set()
        thread.join()


def _acquire(semaphore, stop):
    """Acquire ``semaphore`` unless ``stop`` is set first (then False)."""
    while not stop.is_set():
        if semaphore.acquire(timeout=0.05):
            return True
    return False


@contextlib.contextmanager
def behind(consume, depth=1):
    """Yield ``submit(item)``, which hands ``item`` to ``consume(item)`` in
    a background thread, at most ``depth`` items behind the caller.

    ``submit`` waits while ``depth`` items are not consumed yet (memory
    stays bounded), and raises the error of an earlier ``consume``, if any.
    When the block ends, the thread consumes what was submitted and is
    joined; then its error, if any, is raised. When the block raises, what
    was not consumed yet is dropped, the thread is joined and the block's
    error goes on.
    """
    q, slots, errors, drop = queue.Queue(), threading.Semaphore(depth), [], threading.Event()

    def work():
        while (item := q.get()) is not _END:
            if not (errors or drop.is_set()):
                try:
                    consume(item)
                except BaseException as error:  # raised in the caller
                    errors.append(error)
            item = None
            slots.release()

    def submit(item):
        if errors:
            raise errors[0]
        slots.acquire()
        q.put(item)

    thread = threading.Thread(target=work, name="jaxadapt-write-behind", daemon=True)
    thread.start()
    try:
        yield submit
    except BaseException:
        drop.set()
        raise
    finally:
        q.put(_END)
        thread.join()
    if errors:
        raise errors[0]


def _finite(out, idx, op):
    """The display frames ``out`` of frames ``idx``, after checking that they
    are finite: a non-finite display value is a defect of the operator, which
    quantising to 8 bits would write as black without a word."""
    bad = ~np.isfinite(out).reshape(len(idx), -1).all(axis=1)
    if bad.any():
        raise FloatingPointError(
            f"{op.__name__}: display frame {idx[np.argmax(bad)]} holds non-finite values "
            f"({int(bad.sum())} of frames {idx[0]} to {idx[-1]}); "
            "this is a defect, please report it"
        )
    return out


def concatenate(tables):
    """One diagnostics table from the chunks' tables (dicts of columns)."""
    return {name: np.concatenate([t[name] for t in tables]) for name in tables[0]}


def collect(op, params, source, keep, size=None, key=None):
    """Run ``op`` over ``source``; keep the display frames at indices ``keep``.

    Returns ``({index: frame (H, W, 3)}, table)``: the kept frames and the
    whole sequence's diagnostics (:func:`chunks`, :func:`concatenate`). An
    index that is not a frame's is refused before anything runs.
    """
    T = len(source.times)
    keep = {check_whole("keep", i) for i in keep}
    if outside := sorted(i for i in keep if i >= T):
        raise ValueError(f"keep: expected frame indices from 0 to {T - 1}, got {outside}")
    frames, tables = {}, []
    for idx, out, table in chunks(op, params, source, size, key):
        # copies: a view of ``out`` would hold the whole chunk in memory
        frames.update({i: out[k].copy() for k, i in enumerate(idx) if i in keep})
        tables.append(table)
    return frames, concatenate(tables)


def with_gaze(source, path):
    """``source`` with its gaze from a recording: a CSV of ``t, x, y`` rows.

    See :func:`jaxadapt.gaze.read_gaze_csv` (samples held until the next;
    NaN samples are blinks).
    """
    from jaxadapt.gaze import read_gaze_csv, recorded_gaze

    gaze = recorded_gaze(*read_gaze_csv(path))
    return source._replace(gaze=lambda idx: gaze(source.times[idx]))
