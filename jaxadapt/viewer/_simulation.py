"""The viewer's simulation thread: it advances a
:class:`~jaxadapt.viewer.Session` by the wall-clock time between frames,
only when a page has room for a frame, and encodes each frame as JPEG."""

import bisect
import collections
import io
import math
import threading
import time
from typing import NamedTuple

from jaxadapt.viewer._session import FIRST_DT, MAX_DT

#: Highest frame rate computed, frames/s.
MAX_FPS = 60.0
#: JPEG quality of the frames sent (Pillow's scale, 1-95).
JPEG_QUALITY = 85
#: Most gaze samples kept for the frames to come (a tracker's samples, at up
#: to a few kHz, while the simulation is paused: the oldest go first).
MAX_SAMPLES = 4096


class Sample(NamedTuple):
    """A gaze sample for the frames from time ``at`` (the server's clock,
    :func:`time.monotonic`, s) until ``at + hold``: ``gaze`` ``(x, y)``
    pixels (NaN: a blink) and the ``gaze_id`` its sender gave it."""

    at: float
    gaze: tuple
    gaze_id: object
    hold: float


def encode_jpeg(pixels, quality=JPEG_QUALITY):
    """JPEG bytes of 8-bit RGB ``pixels (H, W, 3)`` (Pillow)."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, "JPEG", quality=quality)
    return buffer.getvalue()


class Simulation(threading.Thread):
    """The thread that advances a :class:`~jaxadapt.viewer.Session`: it
    waits until a page wants a frame, steps the session by the time since
    the last frame (clamped to :data:`MAX_DT`; :data:`FIRST_DT` for the
    first one and after a pause), encodes the frame and hands it to
    ``publish(header, jpeg)``; ``recorder`` (optional) writes each frame.

    A frame whose own work (not the wait for a page) takes longer than
    :data:`MAX_DT` loses the difference: simulated time falls behind the
    wall clock. ``lag`` totals what was lost; ``slow`` holds the last such
    frame's time from the second such frame in a row (a one-off, such as a
    compile, is not) until two in a row keep up again."""

    def __init__(self, session, publish, recorder=None, max_fps=MAX_FPS):
        super().__init__(name="jaxadapt-viewer-simulation", daemon=True)
        self.session, self.publish, self.recorder = session, publish, recorder
        self.min_interval = 1.0 / max_fps
        self.cond = threading.Condition()
        self.wanted = self.paused = self.stopping = False
        self.commands = []
        self.samples = collections.deque()  # by time: the last frame's, then newer ones
        self.times = collections.deque()
        self.last = None
        self.error = None
        self.lag, self.slow, self._run = 0.0, None, 0  # (_run: frames slow (> 0) or not in a row)

    def want(self):
        """A page has room for a frame."""
        with self.cond:
            self.wanted = True
            self.cond.notify()

    def command(self, *command):
        """Queue ``("reset",)``, ``("pause", bool)`` or ``("effect", name, on)``
        for the next frame (commands apply between frames, in order)."""
        with self.cond:
            if command[0] == "pause":
                self.paused = command[1]
                self.last = None
            else:
                self.commands.append(command)
            self.cond.notify()

    def look(self, gaze, gaze_id=None, at=None, hold=math.inf):
        """Take ``gaze`` (x, y pixels; NaN a blink) as the gaze from time ``at``
        (the server's clock, :func:`time.monotonic`, s; default: now) on.

        A frame takes the newest sample at or before its own time, so a
        tracker's time-stamped samples reach the frames of their time, not
        of their arrival; it has none (NaN, as in a blink) once that sample
        is more than ``hold`` s old: a tracker that lost the eye."""
        at = time.monotonic() if at is None else at
        sample = Sample(at, gaze, gaze_id, hold)
        with self.cond:
            if not self.samples or at >= self.samples[-1].at:
                self.samples.append(sample)
            else:
                self.samples.insert(bisect.bisect_right(self.samples, at, key=_at), sample)
            if len(self.samples) > MAX_SAMPLES:
                self.samples.popleft()

    def gaze_at(self, now):
        """The gaze ``(x, y)`` and its id for a frame at time ``now``
        (:meth:`look`); call with ``cond`` held."""
        taken = bisect.bisect_right(self.samples, now, key=_at) - 1
        sample = self.samples[taken] if taken >= 0 else None
        if sample is None or now - sample.at > sample.hold:
            return (math.nan, math.nan), None
        return sample.gaze, sample.gaze_id

    def stop(self):
        with self.cond:
            self.stopping = True
            self.cond.notify()

    def fps(self):
        """Frames computed over the last second."""
        now = time.monotonic()
        return sum(1 for t in list(self.times) if now - t <= 1.0)

    def run(self):
        try:
            while self._next():
                pass
        except Exception as error:  # said by the server, which stops
            self.error = error
        finally:
            if self.recorder is not None:
                self.recorder.close()

    def _next(self):
        with self.cond:
            start = time.monotonic()
            self.cond.wait_for(lambda: self.stopping or (self.wanted and not self.paused))
            waited = time.monotonic() - start
            if self.stopping:
                return False
            self.wanted = False
            commands, self.commands = self.commands, []
            last = self.last
        for command in commands:
            if command[0] == "reset":
                self.session.reset()
            else:
                self.session.toggle(*command[1:])
        now = time.monotonic()
        if last is not None and now - last < self.min_interval:
            time.sleep(self.min_interval - (now - last))
            now = time.monotonic()
        dt = FIRST_DT if last is None else min(now - last, MAX_DT)
        if last is not None:
            self._keep_time(now - last - waited)
        with self.cond:
            self.last = now
            gaze, gaze_id = self.gaze_at(now)
            while len(self.samples) > 1 and self.samples[1].at <= now:
                self.samples.popleft()  # (no later frame takes it)
        frame = self.session.advance(dt, gaze)
        if self.recorder is not None:
            self.recorder.write(frame)
        self.times.append(time.monotonic())
        while self.times and self.times[-1] - self.times[0] > 2.0:
            self.times.popleft()
        H, W = frame.pixels.shape[:2]
        header = {
            "frame": frame.index,
            "t": frame.t,
            "dt": frame.dt,
            "gaze": [None if math.isnan(v) else v for v in frame.gaze],
            "gaze_id": gaze_id,
            "adaptation": frame.adaptation,
            "fps": self.fps(),
            "size": [W, H],
            "effects": sorted(self.session.effects),
            "digest": frame.digest,
            "sent": time.time(),
            "lag": self.lag,
            "slow": self.slow,
        }
        self.publish(header, encode_jpeg(frame.pixels))
        return True

    def _keep_time(self, work):
        """Account a frame whose own work (since the last frame, less the
        wait for a page) took ``work`` seconds."""
        if work > MAX_DT:
            self.lag += work - MAX_DT
            self._run = max(self._run, 0) + 1
            if self._run >= 2:
                self.slow = {"frame_time": work, "max_dt": MAX_DT}
        else:
            self._run = min(self._run, 0) - 1
            if self._run <= -2:
                self.slow = None


def _at(sample):
    return sample.at
