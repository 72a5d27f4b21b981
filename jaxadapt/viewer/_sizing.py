"""The viewer's default frame size: the largest that keeps a frame rate on
the machine it runs on, measured at start-up.

A frame's cost (the operator's step, its 8-bit pixels and the JPEG) grows
with its pixels and depends on the machine: 384x216 keeps jacobs2015 at 30
frames/s on a 2-core CPU, a GPU keeps the paper's 1920x1080. The frames of
the smallest size of :data:`LADDER` are timed, the largest size whose
frames would take at most ``1 / fps`` at the same cost a pixel is chosen,
then timed itself, and a size down is taken while it is slower: a cost
that grows faster than the pixels (blurs sized in degrees, which span more
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
    when even its frames are slower."""
    budget = 1.0 / fps
    smallest = ladder[0]
    seconds = {smallest: measure(spec, smallest)}
    per_pixel = seconds[smallest] / (smallest[0] * smallest[1])
    fits = [s for s in ladder if per_pixel * s[0] * s[1] <= budget] or [smallest]
    for size in reversed(fits):
        if size not in seconds:
            seconds[size] = measure(spec, size)
        if seconds[size] <= budget or size == smallest:
            return size, seconds[size]
