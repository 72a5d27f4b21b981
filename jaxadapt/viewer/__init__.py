"""The live, gaze-contingent viewer behind ``jaxadapt view``.

A local web server shows an operator's frames in the browser and takes the
pointer (or an external eye tracker's samples) as the gaze, as the display
system of Jacobs et al. (2015), §3, does with its 30 Hz tracker. The
simulation advances by the wall-clock time between frames
(:class:`Session`), so adaptation and afterimages keep their real time
course at any frame rate; a recorded session replays exactly
(:func:`replay`).
"""

from jaxadapt.viewer._messages import parse_gaze
from jaxadapt.viewer._server import Server
from jaxadapt.viewer._session import (
    DEFAULT_SCENE,
    DEFAULT_SIZE,
    FIRST_DT,
    MAX_DT,
    Frame,
    Recorder,
    Session,
    read_record,
    replay,
)
from jaxadapt.viewer._sizing import LADDER, TARGET_FPS, fitting_size, frame_seconds

__all__ = [
    "LADDER",
    "TARGET_FPS",
    "fitting_size",
    "frame_seconds",
    "DEFAULT_SCENE",
    "DEFAULT_SIZE",
    "FIRST_DT",
    "MAX_DT",
    "Frame",
    "Recorder",
    "Server",
    "Session",
    "parse_gaze",
    "read_record",
    "replay",
]
