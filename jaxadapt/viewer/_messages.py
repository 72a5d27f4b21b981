"""What the viewer's clients send and are told: gaze samples read and
checked, warnings of a flood said at most once a second, errors as JSON,
frames as one binary message. No part of a client's message reaches
anything but these checks."""

import json
import math
import struct
import time

#: Largest message a client may send, bytes.
MAX_MESSAGE = 2**16
#: Largest message a socket takes at all, bytes: one over :data:`MAX_MESSAGE`
#: and up to this is answered with an error, a larger one closes the socket (1009).
MAX_SOCKET_MESSAGE = 2**20
#: Shortest time between two warnings to one client, s (those between are counted).
WARNING_INTERVAL = 1.0


def frame_message(header, jpeg):
    """A frame as one binary message: the header's JSON length (4 bytes,
    big-endian), the header (UTF-8 JSON), then the JPEG."""
    text = json.dumps(header).encode()
    return struct.pack(">I", len(text)) + text + jpeg


def parse_gaze(sample, shape):
    """The gaze point ``(x, y)`` of a sample ``{"x": px, "y": px}`` on frames
    of ``shape (H, W)``, and a warning or None: ``x`` and ``y`` both null
    (or NaN) are a blink, ``(nan, nan)``. Pixel centres are whole numbers,
    so the frame spans -0.5 to ``W - 0.5``: a point on it is clipped to the
    nearest pixel centre (the operators' reading) silently, one beyond it
    with a warning. ValueError for anything else, naming what was expected."""
    if not isinstance(sample, dict) or not {"x", "y"} <= set(sample):
        raise ValueError(f'expected an object {{"t": s, "x": px, "y": px}}, got {short(sample)}')
    gaze_id = sample.get("id")
    if not (gaze_id is None or is_number(gaze_id) or isinstance(gaze_id, str)) or (
        isinstance(gaze_id, str) and len(gaze_id) > 64
    ):
        raise ValueError(
            f"id: expected a number or a string of at most 64 characters, got {short(gaze_id)}"
        )
    x, y = sample["x"], sample["y"]
    if x is None and y is None:
        return (math.nan, math.nan), None
    if not (is_number(x) and is_number(y)):
        raise ValueError(
            f"x, y: expected numbers (pixels) or both null, got {short(x, 30)}, {short(y, 30)}"
        )
    try:
        x, y = float(x), float(y)
    except OverflowError:  # an integer beyond float64
        x = y = math.inf
    if math.isnan(x) and math.isnan(y):
        return (math.nan, math.nan), None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ValueError(f"x, y: expected finite pixels or both NaN (a blink), got {x}, {y}")
    H, W = shape
    clipped = (min(max(x, 0.0), W - 1.0), min(max(y, 0.0), H - 1.0))
    if not (-0.5 <= x <= W - 0.5 and -0.5 <= y <= H - 0.5):
        return clipped, (
            f"x, y: ({x:g}, {y:g}) is off the {W}x{H} frame (-0.5 to {W - 0.5:g}, "
            f"-0.5 to {H - 0.5:g}); taken as its nearest point ({clipped[0]:g}, {clipped[1]:g})"
        )
    return clipped, None


def is_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def short(value, length=80):
    """``repr(value)``, cut to ``length`` characters (a client's value may be
    long, or nested too deeply to print)."""
    try:
        text = repr(value)
    except RecursionError:
        text = f"a {type(value).__name__} nested too deeply"
    return text if len(text) <= length else text[: length - 3] + "..."


class Warnings:
    """The warnings of one client's samples, at most one each
    :data:`WARNING_INTERVAL` (those between counted, and said with the
    next), and a ``clear`` message once its samples are good again: a
    flood of bad samples is not answered sample by sample.

    ``say(message, kind)``: a coroutine function that tells the client
    (``kind`` "warning" or "clear"), :func:`socket_teller` for a socket's."""

    def __init__(self, say):
        self.say = say
        self.sent, self.suppressed, self.active = -math.inf, 0, False

    async def warn(self, message):
        now = time.monotonic()
        self.active = True
        if now - self.sent < WARNING_INTERVAL:
            self.suppressed += 1
            return
        if self.suppressed:
            message += f" ({self.suppressed} more left unsaid in the last {now - self.sent:.1f} s)"
        self.sent, self.suppressed = now, 0
        await self.say(message, "warning")

    async def clear(self, message):
        """The samples are good again: say so, once, where a warning was due."""
        if self.active:
            if self.suppressed:
                message += f" ({self.suppressed} more warnings left unsaid before)"
            self.active, self.suppressed = False, 0
            await self.say(message, "clear")


def lag_message(slow, lag):
    """What to say when simulated time starts to fall behind the wall clock
    (``slow``: the :attr:`Simulation.slow` of the frame) or keeps up again
    (``slow`` None); ``lag``: seconds behind in all."""
    if slow is None:
        return f"simulated time keeps up with the wall clock again ({lag:.1f} s behind in all)"
    share = slow["max_dt"] / slow["frame_time"]
    return (
        f"warning: simulated time runs slower than the wall clock: a frame takes "
        f"{slow['frame_time']:.2f} s here and advances the simulation by at most "
        f"MAX_DT = {slow['max_dt']:g} s, so it runs at {share:.0%} of real time "
        f"({lag:.1f} s behind so far); a smaller --size keeps up"
    )


async def send_frame(ws, message):
    try:
        await ws.send_bytes(message)
    except (ConnectionError, RuntimeError):  # the page went away mid-frame
        pass


async def tell(ws, message):
    """Send ``message`` (JSON) to a client, unless it has gone."""
    if not ws.closed:
        try:
            await ws.send_json(message)
        except (ConnectionError, RuntimeError):
            pass


async def send_error(ws, message, kind="error"):
    """Tell a client what was wrong with its message (the socket stays open)."""
    await tell(ws, {"type": kind, "message": message})


def socket_teller(ws):
    """``say(message, kind)`` of :class:`Warnings` for a client's socket ``ws``."""
    return lambda message, kind: send_error(ws, message, kind)


def too_long(msg):
    """What is wrong with a socket's message over :data:`MAX_MESSAGE`, or None."""
    if not isinstance(msg.data, (str, bytes)):  # (not text or data: an error, a close)
        return None
    size = len(msg.data.encode() if isinstance(msg.data, str) else msg.data)
    if size > MAX_MESSAGE:
        return f"expected messages of at most {MAX_MESSAGE} bytes, got {size}; left unread"
    return None


def flag(message, name, default=None):
    """``message[name]``, true or false (``default`` where left out, if any)."""
    value = message.get(name, default)
    if not isinstance(value, bool):
        raise ValueError(f"{name}: expected true or false, got {short(value, 30)}")
    return value


async def warn_or_clear(warnings, warning):
    """Pass a sample's ``warning`` (None: the sample was on the frame) to ``warnings``."""
    if warning:
        await warnings.warn(warning)
    else:
        await warnings.clear("x, y: on the frame again")


def reason(error):
    """The message of a client's bad message or line: a ValueError's own
    (it names the field), anything else's with its kind."""
    if isinstance(error, ValueError):
        return str(error)
    return f"could not read it: {type(error).__name__}: {short(str(error))}"


def read_json(text):
    """The JSON value of ``text``; a one-line ValueError where it is not JSON."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(f"expected a JSON object, got {short(text)} ({error})") from None
    except RecursionError:
        raise ValueError(
            f"expected a JSON object, got {short(text, 30)}, nested too deeply to read"
        ) from None


def json_number(value):
    """``value`` for JSON: None for NaN (no frame yet)."""
    return None if math.isnan(value) else value
