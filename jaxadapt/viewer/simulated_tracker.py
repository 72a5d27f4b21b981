"""A simulated eye tracker on Lab Streaming Layer: a known gaze path with
noise and blinks, published as trackers' LSL relays publish theirs, to try
``jaxadapt view --gaze-lsl`` without a tracker (and to test it).

Run ``python -m jaxadapt.viewer.simulated_tracker``, then
``jaxadapt view --gaze-lsl jaxadapt-simulated-gaze``. The stream is of
type Gaze, with channels ``x``, ``y`` and ``confidence`` typed ScreenX,
ScreenY and Confidence as LSL's gaze meta-data has them: ``x, y``
normalised (0 to 1 across the screen, from its top-left corner),
confidence 0 to 1. Needs pylsl (``pip install 'jaxadapt[lsl]'``).
"""

import argparse
import math
import threading
import time

import numpy as np

__all__ = ["DOUBT", "NAME", "NOISE", "RATE", "SimulatedTracker", "blinks", "circle", "main"]

#: The stream's default name.
NAME = "jaxadapt-simulated-gaze"
#: Samples a second (Pupil Core's and many screen trackers' rate).
RATE = 120.0
#: Standard deviation of the noise of x and y, normalised (about 0.1 degree
#: of a screen 40 degrees wide: a good tracker's precision).
NOISE = 0.003
#: The confidence of a doubtful sample (below jaxadapt view's threshold, 0.6).
DOUBT = 0.2


def circle(t, period=8.0, radius=0.3):
    """The default path: around the screen's centre once each ``period``
    s, ``radius`` of its width and height, at time ``t`` (s); ``(x, y)``
    normalised."""
    phase = 2 * math.pi * t / period
    return 0.5 + radius * math.cos(phase), 0.5 + radius * math.sin(phase)


def blinks(t, every=3.0, length=0.15):
    """The default losses: a blink of ``length`` s each ``every`` s (people
    blink about every 3 to 4 s, for 0.1 to 0.4 s); the kind of loss at time
    ``t`` (s) or None (:meth:`SimulatedTracker.sample`)."""
    return "blink" if t % every >= every - length else None


class SimulatedTracker:
    """Publishes ``path(t)`` (normalised ``(x, y)`` at ``t``, s on LSL's
    clock from the start) as the LSL stream ``name`` at ``rate`` Hz, with
    Gaussian ``noise`` (its ``seed``) and the losses ``loss(t)`` gives
    (:func:`blinks`), from :meth:`start` (or ``with``) to :meth:`stop`.

    Each sample is stamped with its time, less ``clock_offset`` s: as a
    tracker on another machine whose clock is that much behind, which
    LSL's ``time_correction`` then reports (on one machine it reports 0, so
    a test stands in for it). ``log`` keeps ``(t, x, y, confidence)`` of
    every sample sent, ``t`` on this machine's LSL clock."""

    def __init__(
        self,
        name=NAME,
        rate=RATE,
        path=circle,
        loss=blinks,
        noise=NOISE,
        seed=0,
        clock_offset=0.0,
    ):
        self.name, self.rate, self.path, self.loss = name, rate, path, loss
        self.noise, self.clock_offset = noise, clock_offset
        self.rng = np.random.default_rng(seed)
        self.log, self.start_time = [], None
        self._stopping, self._thread = threading.Event(), None

    def start(self):
        """Open the stream (visible on the network from now) and publish."""
        from jaxadapt.viewer._lsl import load_pylsl

        pylsl = load_pylsl()
        info = pylsl.StreamInfo(self.name, "Gaze", 3, self.rate, pylsl.cf_double64, self.name)
        info.set_channel_labels(["x", "y", "confidence"])
        info.set_channel_types(["ScreenX", "ScreenY", "Confidence"])
        info.set_channel_units(["normalized", "normalized", "normalized"])
        self._outlet = pylsl.StreamOutlet(info)
        self.start_time = pylsl.local_clock()
        self._thread = threading.Thread(
            target=self._run, args=(pylsl.local_clock,), name="simulated-tracker", daemon=True
        )
        self._thread.start()
        return self

    def stop(self):
        """Stop publishing and close the stream."""
        self._stopping.set()
        if self._thread is not None:
            self._thread.join(10)
        self._outlet = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    def sample(self, t):
        """The sample ``[x, y, confidence]`` at ``t`` s from the start, by
        the kind of loss then: None, the path with noise; "blink", NaN;
        "zeros", ``(0, 0)`` (as several trackers say "no data"); "doubt",
        the path with :data:`DOUBT` confidence; "gap", no sample (None)."""
        kind = self.loss(t)
        if kind == "gap":
            return None
        if kind == "blink":
            return [math.nan, math.nan, 0.0]
        if kind == "zeros":
            return [0.0, 0.0, 1.0]
        x, y = np.asarray(self.path(t)) + self.rng.normal(0.0, self.noise, 2)
        return [float(x), float(y), DOUBT if kind == "doubt" else 1.0]

    def _run(self, local_clock):
        k = 0
        while not self._stopping.is_set():
            t = self.start_time + k / self.rate
            wait = t - local_clock()
            if wait > 0:
                time.sleep(wait)
            values = self.sample(t - self.start_time)
            if values is not None:
                self._outlet.push_sample(values, t - self.clock_offset)
                self.log.append((t, *values))
            k += 1


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog="python -m jaxadapt.viewer.simulated_tracker",
        description="Publish a simulated eye tracker's gaze on Lab Streaming Layer: a circle "
        "around the screen's centre every 8 s, with noise and a blink every 3 s, normalised "
        "x, y (0 to 1 from the top-left corner) and a confidence. Ctrl-C stops it.",
    )
    parser.add_argument("--name", default=NAME, help=f"the stream's name (default: {NAME})")
    parser.add_argument("--rate", type=float, default=RATE, help="samples a second (default: 120)")
    parser.add_argument("--seconds", type=float, default=0, help="stop after (default: never)")
    args = parser.parse_args(argv)
    with SimulatedTracker(args.name, args.rate):
        print(f"publishing the LSL stream {args.name!r}: jaxadapt view --gaze-lsl {args.name}")
        try:
            threading.Event().wait(args.seconds or None)
        except KeyboardInterrupt:
            pass


if __name__ == "__main__":
    main()
