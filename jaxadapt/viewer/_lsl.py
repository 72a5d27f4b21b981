"""An eye tracker's Lab Streaming Layer (LSL) stream as the viewer's gaze
(``jaxadapt view --gaze-lsl NAME``), read through pylsl, whose wheel ships
liblsl (``pip install 'jaxadapt[lsl]'``).

Coordinates: a sample's ``x, y`` map linearly onto the frame, ``(0, 0)``
at its top-left corner and ``span`` at its bottom-right one. The default
span, ``(1, 1)``, reads normalised coordinates, as LSL's gaze meta-data
(unit "normalized"), Tobii's display-area points and most trackers' LSL
relays give them; a screen's size in pixels reads screen pixels, the page
shown full screen; the frame's own size, frame pixels.

Time: a sample's time stamp is on the tracker machine's LSL clock. LSL's
clock offset (``time_correction``) maps it onto this machine's LSL clock
(``local_clock``), and the difference of that clock and
:func:`time.monotonic` onto the server's, so that a frame takes the sample
of its own time (:meth:`~jaxadapt.viewer._simulation.Simulation.look`).

Lost samples are blinks to the viewer (NaN, as on ``/gaze``): ``x`` or
``y`` not finite, both 0 (the "no data" of several trackers), a
confidence below the threshold, and any time more than ``gap`` s after
the last sample (the tracker sent none).
"""

import importlib.resources
import os
import threading
import time
from pathlib import Path

import numpy as np

#: Longest wait for the stream at start, s (``--gaze-lsl-timeout``).
TIMEOUT = 5.0
#: Lowest confidence of a sample taken (``--gaze-lsl-confidence``): Pupil
#: Labs' advice for its 0-1 confidence.
MIN_CONFIDENCE = 0.6
#: Longest a sample stands for the eye, s: a frame later than this after
#: the last sample has none (lost). Three intervals of a 30 Hz tracker (the
#: paper's); at least three of the stream's nominal rate where that is slower.
GAP = 0.1
#: Silence after which the terminal is told that no samples come, s.
SILENCE = 1.0
#: Longest wait for samples in one pull, s (how soon the reader stops).
POLL = 0.05
#: The channel types of LSL's gaze meta-data (XDF's "Gaze Meta-Data") read.
GAZE_TYPES = ("screenx", "screeny", "confidence")
#: Where liblsl looks for a configuration of the user's own, in its order.
LSL_CONFIGS = ("lsl_api.cfg", "~/lsl_api/lsl_api.cfg", "/etc/lsl_api/lsl_api.cfg")

_pylsl = None


def load_pylsl():
    """pylsl, its liblsl configured on first use: with no configuration of
    the user's own (``$LSLAPICFG`` or a file of :data:`LSL_CONFIGS`), liblsl's
    defaults, but its log on stderr kept to errors (by default it prints
    two lines of start-up information, which would bury a one-line error).
    ValueError where pylsl is missing or cannot load liblsl."""
    global _pylsl
    if _pylsl is None:
        try:
            import pylsl
        except (ImportError, OSError, RuntimeError) as error:
            raise ValueError(
                "expected pylsl, which the lsl extra installs (pip install 'jaxadapt[lsl]'), "
                f"got {type(error).__name__}: {error}"
            ) from None
        if not os.environ.get("LSLAPICFG") and not any(
            Path(p).expanduser().is_file() for p in LSL_CONFIGS
        ):
            config = importlib.resources.files(__package__).joinpath("lsl_api.cfg")
            pylsl.set_config_filename(str(config))
        _pylsl = pylsl
    return _pylsl


def find_stream(name, timeout=TIMEOUT):
    """The ``StreamInfo`` of the LSL stream named ``name``, looked for on
    the network for up to ``timeout`` s; a one-line ValueError naming the
    streams seen where none has that name."""
    pylsl = load_pylsl()
    resolver = pylsl.ContinuousResolver(forget_after=timeout + 1.0)
    end = time.monotonic() + timeout
    while True:
        streams = resolver.results()
        found = [s for s in streams if s.name() == name]
        if found:
            return found[0]
        if time.monotonic() >= end:
            break
        time.sleep(0.05)
    seen = sorted(f"{s.name()!r} of type {s.type()!r}" for s in streams)
    raise ValueError(
        f"--gaze-lsl: expected an LSL stream named {name!r} (an eye tracker's), found none "
        f"in {timeout:g} s; streams seen: {', '.join(seen) or 'none'}"
    )


def choose_channels(info, names=None):
    """The indices ``(x, y, confidence)`` (confidence None: none) of the
    stream's channels: ``names`` (labels or 0-based indices, 2 or 3), else
    those LSL's gaze meta-data types ScreenX, ScreenY and Confidence, else
    channels 0 and 1 without a confidence."""
    count = info.channel_count()
    labels = info.get_channel_labels() or [None] * count
    if names:
        return tuple(_channel(info, labels, n) for n in names) + (None,) * (3 - len(names))
    types = [(t or "").lower() for t in info.get_channel_types() or [None] * count]
    if "screenx" in types and "screeny" in types:
        return tuple(types.index(t) if t in types else None for t in GAZE_TYPES)
    if count < 2:
        raise ValueError(
            f"--gaze-lsl: expected a stream of x and y channels, got {info.name()!r} with "
            f"{count} channel"
        )
    return 0, 1, None


def _channel(info, labels, name):
    if name in labels:
        return labels.index(name)
    if name.isdigit() and int(name) < info.channel_count():
        return int(name)
    known = ", ".join(repr(label) for label in labels if label) or "none"
    raise ValueError(
        f"--gaze-lsl-channels: expected labels of {info.name()!r}'s channels ({known}) or "
        f"indices from 0 to {info.channel_count() - 1}, got {name!r}"
    )


def frame_points(values, channels, span, min_confidence, shape):
    """The frame pixels ``(N, 2)`` of a chunk of samples ``values (N, C)``
    (:func:`choose_channels`' ``channels``): ``(0, 0)`` to ``span`` mapped
    onto the frame's edges, -0.5 to ``W - 0.5`` and ``H - 0.5`` (pixel
    centres at whole numbers, as on ``/gaze``); NaN where the eye is lost.

    Examples
    --------
    >>> samples = np.array([[0.5, 0.25, 0.9], [0.0, 0.0, 1.0], [0.5, 0.5, 0.1]])
    >>> frame_points(samples, (0, 1, 2), (1, 1), 0.6, (10, 20)).tolist()
    [[9.5, 2.0], [nan, nan], [nan, nan]]
    """
    x, y, confidence = channels
    H, W = shape
    values = np.asarray(values, np.float64)
    with np.errstate(over="ignore", invalid="ignore"):  # (not finite: lost)
        points = np.stack([values[:, x] / span[0] * W, values[:, y] / span[1] * H], -1) - 0.5
    lost = ~np.all(np.isfinite(points), -1) | np.all(values[:, [x, y]] == 0, -1)
    if confidence is not None:
        lost |= ~(values[:, confidence] >= min_confidence)
    return np.where(lost[:, None], np.nan, points)


def clock_offset(local_clock):
    """``time.monotonic()`` less LSL's ``local_clock()``, s: both this
    machine's monotonic clock (the same one on Linux), read in pairs, the
    closest pair of five kept."""
    pairs = []
    for _ in range(5):
        before = time.monotonic()
        lsl = local_clock()
        after = time.monotonic()
        pairs.append((after - before, (before + after) / 2 - lsl))
    return min(pairs)[1]


def open_tracker(name, timeout=None, channels=None, span=None, min_confidence=None):
    """The :class:`Tracker` of the LSL stream ``name``: found, opened and its
    clock offset known within ``timeout`` s (None: :data:`TIMEOUT`).
    ``channels``, ``span`` and ``min_confidence`` (None:
    :data:`MIN_CONFIDENCE`) as ``--gaze-lsl-channels``, ``-span`` and
    ``-confidence`` take them; ``span`` None is 1x1, unless the stream's
    meta-data gives x in pixels, when the screen's size is needed. A
    one-line ValueError naming the option for what cannot be read."""
    timeout = TIMEOUT if timeout is None else timeout
    min_confidence = MIN_CONFIDENCE if min_confidence is None else min_confidence
    try:
        pylsl = load_pylsl()
    except ValueError as error:
        raise ValueError(f"--gaze-lsl: {error}") from None
    found = find_stream(name, timeout)
    if found.channel_format() == pylsl.cf_string:
        raise ValueError(f"--gaze-lsl: expected numeric channels, got text in {name!r}")
    inlet = pylsl.StreamInlet(found, max_buflen=1, recover=True)
    try:
        info = inlet.info(timeout)  # (with its meta-data: the channels' labels, types and units)
        inlet.open_stream(timeout)
        inlet.time_correction(timeout)  # the first estimate: several exchanges
    except (pylsl.util.TimeoutError, pylsl.util.LostError) as error:
        raise ValueError(
            f"--gaze-lsl: expected the stream {name!r} to open within {timeout:g} s, got: {error}"
        ) from None
    chosen = choose_channels(info, channels)
    if span is None:
        units = info.get_channel_units() or [None] * info.channel_count()
        if (units[chosen[0]] or "").lower() in ("pixels", "pixel", "px"):
            raise ValueError(
                f"--gaze-lsl-span: {name!r} gives x, y in pixels (its meta-data's unit); "
                "expected the size they span, the screen's with the page full screen "
                "(e.g. --gaze-lsl-span 1920x1080)"
            )
        span = (1.0, 1.0)
    rate = info.nominal_srate()
    gap = max(GAP, 3 / rate) if rate > 0 else GAP
    return Tracker(pylsl, inlet, info, chosen, span, min_confidence, gap)


class Tracker:
    """An opened eye tracker's stream (:func:`open_tracker`): :meth:`start`
    reads it in a thread of its own and hands the samples, in frame pixels
    and on the server's clock, to ``deliver(points (N, 2), at (N,), hold)``
    (``hold``: its gap, s); ``say(line)`` gets news for the terminal."""

    def __init__(self, pylsl, inlet, info, channels, span, min_confidence, gap):
        self.pylsl, self.inlet, self.info = pylsl, inlet, info
        self.name = info.name()
        self.channels, self.span = channels, tuple(float(v) for v in span)
        self.min_confidence, self.gap = min_confidence, gap
        self._stopping, self._thread = threading.Event(), None

    def describe(self):
        """What is read, in a line: the stream, its channels and their mapping."""
        labels = self.info.get_channel_labels() or [None] * self.info.channel_count()
        x, y, confidence = (None if i is None else labels[i] or f"#{i}" for i in self.channels)
        rate = self.info.nominal_srate()
        line = (
            f"gaze: LSL stream {self.name!r} (type {self.info.type()!r}, "
            f"{f'{rate:g} Hz' if rate > 0 else 'irregular rate'}, from "
            f"{self.info.hostname() or 'an unnamed host'}): x, y from channels {x!r}, {y!r}, "
            f"0,0 to {self.span[0]:g},{self.span[1]:g} across the frame"
        )
        if confidence is not None:
            line += f", confidence from {confidence!r} (at least {self.min_confidence:g})"
        return line + f"; lost after a gap of {self.gap:g} s"

    def start(self, shape, deliver, say):
        """Read the stream for frames of ``shape (H, W)`` until :meth:`stop`."""
        self._thread = threading.Thread(
            target=self._run, args=(shape, deliver, say), name="jaxadapt-gaze-lsl", daemon=True
        )
        self._thread.start()

    def stop(self):
        self._stopping.set()
        if self._thread is not None:
            self._thread.join(10)
        self.inlet.close_stream()

    def _run(self, shape, deliver, say):
        last, silent = time.monotonic(), False
        try:
            offset = clock_offset(self.pylsl.local_clock)
            correction = self.inlet.time_correction(0.0)
            while not self._stopping.is_set():
                values, stamps = self.inlet.pull_chunk(POLL, min_samples=1, as_numpy=True)
                now = time.monotonic()
                if len(stamps) == 0:
                    if not silent and now - last > SILENCE:
                        say(f"no samples for {SILENCE:g} s: the eye is lost until they come")
                        silent = True
                    continue
                if silent:
                    say("samples again")
                    silent = False
                last = now
                try:  # (liblsl updates it every few seconds)
                    correction = self.inlet.time_correction(0.0)
                except (self.pylsl.util.TimeoutError, self.pylsl.util.LostError):
                    pass
                at = stamps + correction + offset
                points = frame_points(values, self.channels, self.span, self.min_confidence, shape)
                deliver(points, at, self.gap)
        except Exception as error:  # (said; the frames then have no gaze)
            say(f"stopped reading the stream: {type(error).__name__}: {error}")
