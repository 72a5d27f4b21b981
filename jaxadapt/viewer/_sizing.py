"""The viewer's default frame size: the largest that keeps a frame rate on
the machine it runs on, measured at start-up.

A frame's cost (the operator's step, its 8-bit pixels and the JPEG) grows
with its pixels and depends on the machine: 960x540 keeps jacobs2015 at 30
frames/s on a 2-core CPU, a GPU keeps the paper's 1920x1080. The frames of
the smallest size of :data:`LADDER` are timed, the largest size whose
frames would take at most ``1 / fps`` at the same cost a pixel is timed,
and a size down is taken while it is slower; from a size that keeps up
the prediction is made again, upwards (:func:`fitting_size`). A cost that
grows faster than the pixels (blurs sized in degrees, which span more
pixels in a larger frame) is measured rather than assumed.
"""

import statistics
import time

from jaxadapt.viewer._session import FIRST_DT, Session
from jaxadapt.viewer._simulation import encode_jpeg

__all__ = ["LADDER", "TARGET_FPS", "fitting_size", "frame_seconds"]

#: Frame rate the default size keeps, frames/s.
TARGET_FPS = 30.0
#: The sizes tried for the default, 16:9, smallest first.
LADDER = ((384, 216), (640, 360), (960, 540), (1280, 720), (1600, 900), (1920, 1080))


def frame_seconds(spec, size, frames=8):
    """Median wall time of a frame of a :class:`Session` of ``spec`` at
    ``size`` (W, H), s: its step, 8-bit pixels and JPEG, after a compile
    (which the session served at that size then reuses)."""
    session = Session({**spec, "size": list(size)})
    session.warm()
    W, H = size
    seconds = []
    for k in range(frames):
        start = time.perf_counter()
        frame = session.advance(FIRST_DT, (W / 2 + k % 5, H / 2))
        encode_jpeg(frame.pixels)
        seconds.append(time.perf_counter() - start)
    return statistics.median(seconds)


def fitting_size(spec, fps=TARGET_FPS, measure=frame_seconds, ladder=LADDER):
    """``(size, seconds)``: the largest size of ``ladder`` (smallest first)
    whose frame of a session of ``spec`` takes at most ``1 / fps`` s as
    measured by ``measure(spec, size)``, and that time; the smallest size
    when even its frames are slower.

    From the largest size known to keep up (first the smallest), the
    sizes above it that its cost a pixel predicts to keep up are measured,
    largest first, down to one that does; from that one the prediction is
    made again. A frame's fixed costs make a small size's cost a pixel too
    high (on 2 CPU cores 384x216 predicted 640x360, whose frames took 11
    ms of 33), so the climb goes on while a measured size predicts a larger
    one; a cost that grows faster than the pixels is measured, not
    assumed."""
    budget = 1.0 / fps
    seconds = {}

    def timed(size):
        if size not in seconds:
            seconds[size] = measure(spec, size)
        return seconds[size]

    fitting = ladder[0]
    timed(fitting)
    while seconds[fitting] <= budget:
        per_pixel = seconds[fitting] / _pixels(fitting)
        above = [
            s
            for s in ladder
            if _pixels(s) > _pixels(fitting)
            and s not in seconds
            and per_pixel * _pixels(s) <= budget
        ]
        keeping_up = next((s for s in reversed(above) if timed(s) <= budget), None)
        if keeping_up is None:
            break
        fitting = keeping_up
    return fitting, seconds[fitting]


def _pixels(size):
    return size[0] * size[1]
