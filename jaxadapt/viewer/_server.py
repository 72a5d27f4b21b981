"""The live viewer's server: one page, its frames over a WebSocket, the gaze
from the page's pointer or an external tracker, and ``/state``.

The simulation runs in a thread of its own (:class:`Simulation`) and
computes a frame only when a page has room for one (at most
:data:`WINDOW` frames unacknowledged): a page that falls behind skips
frames rather than queueing them, and the gaze a frame uses is never older
than the frames in flight.
"""

import asyncio
import collections
import contextlib
import hmac
import importlib.resources
import io
import ipaddress
import json
import logging
import math
import socket
import struct
import threading
import time

from jaxadapt.viewer._session import FIRST_DT, MAX_DT

#: Frames a page may hold unacknowledged (sent, not yet drawn).
WINDOW = 2
#: Most pages served at once; more are refused with a message.
MAX_CLIENTS = 8
#: Largest message a client may send, bytes.
MAX_MESSAGE = 2**16
#: Largest message a socket takes at all, bytes: one over :data:`MAX_MESSAGE`
#: and up to this is answered with an error, a larger one closes the socket (1009).
MAX_SOCKET_MESSAGE = 2**20
#: Highest frame rate computed, frames/s.
MAX_FPS = 60.0
#: Shortest time between two warnings to one client, s (those between are counted).
WARNING_INTERVAL = 1.0
#: JPEG quality of the frames sent (Pillow's scale, 1-95).
JPEG_QUALITY = 85
#: The page and its script, served from the package (never from a request's path).
ASSETS = {"/": ("index.html", "text/html"), "/viewer.js": ("viewer.js", "text/javascript")}
#: Paths served without the token: the page's script, the same for everyone
#: and holding no secret (the page loads it by a plain ``<script src>``).
PUBLIC = frozenset({"/viewer.js"})


def encode_jpeg(pixels, quality=JPEG_QUALITY):
    """JPEG bytes of 8-bit RGB ``pixels (H, W, 3)`` (Pillow)."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, "JPEG", quality=quality)
    return buffer.getvalue()


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
        raise ValueError(f'expected an object {{"t": s, "x": px, "y": px}}, got {_short(sample)}')
    gaze_id = sample.get("id")
    if not (gaze_id is None or _is_number(gaze_id) or isinstance(gaze_id, str)) or (
        isinstance(gaze_id, str) and len(gaze_id) > 64
    ):
        raise ValueError(
            f"id: expected a number or a string of at most 64 characters, got {_short(gaze_id)}"
        )
    x, y = sample["x"], sample["y"]
    if x is None and y is None:
        return (math.nan, math.nan), None
    if not (_is_number(x) and _is_number(y)):
        raise ValueError(
            f"x, y: expected numbers (pixels) or both null, got {_short(x, 30)}, {_short(y, 30)}"
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


def _is_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _short(value, length=80):
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
    flood of bad samples is not answered sample by sample."""

    def __init__(self, ws):
        self.ws, self.sent, self.suppressed, self.active = ws, -math.inf, 0, False

    async def warn(self, message):
        now = time.monotonic()
        self.active = True
        if now - self.sent < WARNING_INTERVAL:
            self.suppressed += 1
            return
        if self.suppressed:
            message += f" ({self.suppressed} more left unsaid in the last {now - self.sent:.1f} s)"
        self.sent, self.suppressed = now, 0
        await _error(self.ws, message, "warning")

    async def clear(self, message):
        """The samples are good again: say so, once, where a warning was due."""
        if self.active:
            if self.suppressed:
                message += f" ({self.suppressed} more warnings left unsaid before)"
            self.active, self.suppressed = False, 0
            await _error(self.ws, message, "clear")


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
        self.gaze, self.gaze_id = (math.nan, math.nan), None
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

    def look(self, gaze, gaze_id=None):
        """Take ``gaze`` (x, y pixels; NaN a blink) as the gaze of the next frame."""
        with self.cond:
            self.gaze, self.gaze_id = gaze, gaze_id

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
            gaze, gaze_id, last = self.gaze, self.gaze_id, self.last
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


class Client:
    """A page connected to ``/ws``: its socket, frames in flight and warnings."""

    def __init__(self, ws):
        self.ws, self.unacked, self.warnings = ws, 0, Warnings(ws)


class Server:
    """The viewer's web application around a :class:`Simulation`.

    Parameters
    ----------
    session : Session
    host : str
        Address to bind; a non-loopback one requires ``token`` in every URL.
    port : int
        Port (0: any free one).
    token : str or None
        Secret every request must carry as ``?token=``; None on loopback.
    report : callable or None
        Takes a line for the terminal: when simulated time starts to fall
        behind the wall clock, and when it keeps up again.
    """

    def __init__(self, session, host="127.0.0.1", port=0, token=None, report=None):
        self.session, self.host, self.port, self.token = session, host, port, token
        self.report, self.slow = report, None
        self.clients, self.trackers = set(), set()
        # What every page shows, kept here (the simulation applies the
        # commands between frames, and none while paused)
        self.effects, self.resets, self.last_frame = set(session.effects), 0, None
        self.sim = Simulation(session, self._publish_threadsafe)
        self.loop = self.runner = None
        self.assets = {
            route: (importlib.resources.files(__package__).joinpath("static", name).read_bytes(), t)
            for route, (name, t) in ASSETS.items()
        }

    def app(self):
        from aiohttp import web  # (imported when served: `import jaxadapt` stays light)

        guard = web.middleware(lambda request, handler: self._guard(request, handler))
        app = web.Application(middlewares=[guard], client_max_size=MAX_MESSAGE)
        app.router.add_get("/", self._asset)
        app.router.add_get("/viewer.js", self._asset)
        app.router.add_get("/state", self._state)
        app.router.add_get("/ws", self._page_socket)
        app.router.add_get("/gaze", self._gaze_socket)
        return app

    async def start(self, record=None, prepare=None):
        """Bind, run ``prepare()`` (in a thread: e.g. compiling the step),
        then start simulating; return the page's URL. ``record()``, once
        bound, makes the :class:`Recorder` of the frames."""
        from aiohttp import web

        self.loop = asyncio.get_running_loop()
        self.runner = web.AppRunner(
            self.app(), access_log=None, handle_signals=False, logger=_http_logger()
        )
        await self.runner.setup()
        try:
            await web.TCPSite(self.runner, self.host, self.port).start()
            self.port = self.runner.addresses[0][1]
            if prepare is not None:
                await asyncio.to_thread(prepare)
            self.sim.recorder = None if record is None else record()
        except BaseException:
            await self.runner.cleanup()
            raise
        self.sim.start()
        return self.urls()[0]

    def urls(self):
        """The page's URLs, the first to print: bound to a wildcard address
        (``0.0.0.0``, ``::``, ``""``), the machine's name and its addresses
        (a wildcard address is no place a browser can go), then loopback's;
        otherwise the one address bound."""
        query = f"?token={self.token}" if self.token else ""
        hosts = machine_names(self.host) if is_wildcard(self.host) else [self.host]
        return [f"http://{_bracketed(h)}:{self.port}/{query}" for h in hosts]

    async def close(self):
        """Close the sockets, stop the simulation (its record completed) and unbind."""
        for ws in [c.ws for c in self.clients] + list(self.trackers):
            await ws.close(code=1001, message=b"server stopped")
        self.sim.stop()
        await asyncio.to_thread(self.sim.join)
        await self.runner.cleanup()

    # -- requests ---------------------------------------------------------

    async def _guard(self, request, handler):
        """Refuse requests without the token, for another host (DNS
        rebinding) or from another origin's page."""
        from aiohttp import web

        given = request.query.get("token", "").encode()
        public = request.path in PUBLIC
        if self.token and not public and not hmac.compare_digest(given, self.token.encode()):
            return web.Response(status=403, text="jaxadapt view: missing or wrong token\n")
        host = request.headers.get("Host", "")
        if not self.token and not self._is_own(host):
            expected = " or ".join(f"{n}:{self.port}" for n in self._names())
            return web.Response(
                status=403,
                text=f"jaxadapt view: Host: expected {expected}, got {host!r}\n",
            )
        origin = request.headers.get("Origin")
        if origin is not None and not (
            origin.startswith("http://") and self._is_own(origin[7:], host)
        ):
            return web.Response(status=403, text=f"jaxadapt view: refused Origin {origin!r}\n")
        return await handler(request)

    def _names(self):
        """The names of this server without a token: loopback's and its address."""
        return list(dict.fromkeys(["127.0.0.1", "localhost", "[::1]", _bracketed(self.host)]))

    def _is_own(self, authority, host=None):
        """Whether ``authority`` (a Host header, or an Origin's ``host[:port]``)
        names this server: one of :meth:`_names` (with a token, also the
        request's ``host``: any name of the machine, the token guards) and
        its port, which a browser leaves out for port 80."""
        names = self._names()
        if self.token and host:
            names.append(_split_authority(host)[0])
        name, port = _split_authority(authority)
        return name is not None and name in names and port == self.port

    async def _asset(self, request):
        from aiohttp import web

        body, content_type = self.assets[request.path]
        return web.Response(body=body, content_type=content_type)

    async def _state(self, request):
        from aiohttp import web

        sim = self.sim
        with sim.cond:
            gaze = sim.gaze
        H, W = self.session.shape
        return web.json_response(
            {
                "frame": self.session.index,
                "fps": sim.fps(),
                "gaze": [None if math.isnan(v) else v for v in gaze],
                "adaptation": _number(self.session.adaptation()),
                "size": [W, H],
                "t": self.session.t,
                "operator": self.session.operator,
                "available_effects": list(self.session.available_effects),
                "clients": len(self.clients),
                "lag": sim.lag,
                "slow": sim.slow is not None,
                **self.view_state(),
            }
        )

    def view_state(self):
        """What every page shows alike: ``paused``, ``effects`` (those on,
        or switched on for the next frame), ``resets`` (how many so far) and
        ``trackers`` (connected to ``/gaze``: the pointers are then ignored)."""
        with self.sim.cond:
            paused = self.sim.paused
        return {
            "paused": paused,
            "effects": sorted(self.effects),
            "resets": self.resets,
            "trackers": len(self.trackers),
        }

    async def _tell_pages(self, change):
        """Send every page the view's state after ``change`` (pause, effect,
        reset, trackers), so that all pages agree."""
        message = {"type": "state", "change": change, **self.view_state()}
        for client in list(self.clients):
            await _tell(client.ws, message)

    async def _page_socket(self, request):
        from aiohttp import WSMsgType, web

        ws = web.WebSocketResponse(compress=False, max_msg_size=MAX_SOCKET_MESSAGE, heartbeat=20)
        await ws.prepare(request)
        if len(self.clients) >= MAX_CLIENTS:
            await ws.send_json({"type": "error", "message": f"at most {MAX_CLIENTS} pages"})
            await ws.close(code=1013, message=b"too many pages")
            return ws
        client = Client(ws)
        self.clients.add(client)
        H, W = self.session.shape
        await ws.send_json(
            {
                "type": "hello",
                "size": [W, H],
                "operator": self.session.operator,
                "available_effects": list(self.session.available_effects),
                **self.view_state(),
            }
        )
        if self.last_frame is not None:  # its first picture (while paused, its only one)
            client.unacked += 1
            await _send(ws, self.last_frame)
        self.sim.want()
        try:
            async for msg in ws:
                if _too_long(msg):
                    await _error(ws, _too_long(msg))
                elif msg.type == WSMsgType.TEXT:
                    await self._page_message(client, msg.data)
                elif msg.type == WSMsgType.BINARY:
                    await _error(ws, "expected JSON text messages, got binary data")
        finally:
            self.clients.discard(client)
        return ws

    async def _page_message(self, client, text):
        """Act on one message of a page: ``ack``, ``gaze``, ``pause``,
        ``reset`` or ``effect``; an error message for anything else."""
        try:
            message = _json(text)
            kind = message.get("type") if isinstance(message, dict) else None
            if kind == "ack":
                client.unacked = max(0, client.unacked - 1)
                self.sim.want()
            elif kind == "gaze":
                if self.trackers:  # an external tracker drives the gaze
                    return
                gaze, warning = parse_gaze(message, self.session.shape)
                self.sim.look(gaze, message.get("id"))
                await _warn(client.warnings, warning)
            elif kind == "pause":
                self.sim.command("pause", _flag(message, "paused", True))
                self.sim.want()
                await self._tell_pages("pause")
            elif kind == "reset":
                self.sim.command("reset")
                self.resets += 1
                await self._tell_pages("reset")
            elif kind == "effect":
                name, on = message.get("name"), _flag(message, "on")
                if name not in self.session.available_effects:
                    raise ValueError(
                        f"effect: expected one of {list(self.session.available_effects)}, "
                        f"got {_short(name, 40)}"
                    )
                self.sim.command("effect", name, on)
                (self.effects.add if on else self.effects.discard)(name)
                await self._tell_pages("effect")
            else:
                raise ValueError(
                    "expected a message of type ack, gaze, pause, reset or effect, "
                    f"got {text!r:.80}"
                )
        except Exception as error:  # a bad message (ValueError; any other: said as such)
            await _error(client.ws, _reason(error))

    async def _gaze_socket(self, request):
        """``/gaze``: JSON lines ``{"t": s, "x": px, "y": px}`` from a tracker."""
        from aiohttp import WSMsgType, web

        ws = web.WebSocketResponse(compress=False, max_msg_size=MAX_SOCKET_MESSAGE, heartbeat=20)
        await ws.prepare(request)
        self.trackers.add(ws)
        await self._tell_pages("trackers")
        warnings = Warnings(ws)
        try:
            async for msg in ws:
                if _too_long(msg):
                    await _error(ws, _too_long(msg))
                    continue
                if msg.type != WSMsgType.TEXT:
                    if msg.type == WSMsgType.BINARY:
                        await _error(ws, "expected JSON lines of text, got binary data")
                    continue
                for line in filter(str.strip, msg.data.splitlines()):
                    await self._tracker_line(ws, warnings, line)
        finally:
            self.trackers.discard(ws)
            await self._tell_pages("trackers")
        return ws

    async def _tracker_line(self, ws, warnings, line):
        """Take one line of a tracker: its gaze, or an error naming the line."""
        try:
            sample = _json(line)
            gaze, warning = parse_gaze(sample, self.session.shape)
            t = sample.get("t")
            if t is not None and not (_is_number(t) and math.isfinite(t)):
                raise ValueError(f"t: expected a time in seconds, got {_short(t, 30)}")
        except Exception as error:  # a bad line (ValueError; any other: said as such)
            await _error(ws, f"{_reason(error)} (line {_short(line)})")
            return
        self.sim.look(gaze, sample.get("id"))
        await _warn(warnings, warning)

    # -- frames -----------------------------------------------------------

    def _publish_threadsafe(self, header, jpeg):
        message = frame_message(header, jpeg)
        self.loop.call_soon_threadsafe(self._publish, message, header)

    def _publish(self, message, header=None):
        """Send a frame to every page with room for it; the others skip it.
        The last is kept for a page that opens while the simulation is paused."""
        self.last_frame = message
        if header is not None and (header["slow"] is None) != (self.slow is None):
            self.slow = header["slow"]
            if self.report is not None:
                self.report(lag_message(header["slow"], header["lag"]))
        for client in list(self.clients):
            if client.unacked < WINDOW and not client.ws.closed:
                client.unacked += 1
                self.loop.create_task(_send(client.ws, message))
        if any(c.unacked < WINDOW for c in self.clients):
            self.sim.want()


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


async def _send(ws, message):
    try:
        await ws.send_bytes(message)
    except (ConnectionError, RuntimeError):  # the page went away mid-frame
        pass


async def _tell(ws, message):
    """Send ``message`` (JSON) to a client, unless it has gone."""
    if not ws.closed:
        try:
            await ws.send_json(message)
        except (ConnectionError, RuntimeError):
            pass


async def _error(ws, message, kind="error"):
    """Tell a client what was wrong with its message (the socket stays open)."""
    await _tell(ws, {"type": kind, "message": message})


def _too_long(msg):
    """What is wrong with a socket's message over :data:`MAX_MESSAGE`, or None."""
    if not isinstance(msg.data, (str, bytes)):  # (not text or data: an error, a close)
        return None
    size = len(msg.data.encode() if isinstance(msg.data, str) else msg.data)
    if size > MAX_MESSAGE:
        return f"expected messages of at most {MAX_MESSAGE} bytes, got {size}; left unread"
    return None


def _flag(message, name, default=None):
    """``message[name]``, true or false (``default`` where left out, if any)."""
    value = message.get(name, default)
    if not isinstance(value, bool):
        raise ValueError(f"{name}: expected true or false, got {_short(value, 30)}")
    return value


async def _warn(warnings, warning):
    """Pass a sample's ``warning`` (None: the sample was on the frame) to ``warnings``."""
    if warning:
        await warnings.warn(warning)
    else:
        await warnings.clear("x, y: on the frame again")


def _reason(error):
    """The message of a client's bad message or line: a ValueError's own
    (it names the field), anything else's with its kind."""
    if isinstance(error, ValueError):
        return str(error)
    return f"could not read it: {type(error).__name__}: {_short(str(error))}"


def _json(text):
    """The JSON value of ``text``; a one-line ValueError where it is not JSON."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(f"expected a JSON object, got {_short(text)} ({error})") from None
    except RecursionError:
        raise ValueError(
            f"expected a JSON object, got {_short(text, 30)}, nested too deeply to read"
        ) from None


def _number(value):
    """``value`` for JSON: None for NaN (no frame yet)."""
    return None if math.isnan(value) else value


def _split_authority(text):
    """``(name, port)`` of ``host[:port]`` (port 80, HTTP's, when left out;
    names lower case); ``(None, None)`` where it is no such thing."""
    name, colon, port = text.rpartition(":")
    if not colon or name.startswith("[") and not name.endswith("]"):  # no port; IPv6 [::1]
        name, port = text, "80"
    if not name or not port.isdigit() or not port.isascii():
        return None, None
    return name.lower(), int(port)


class _ClientErrors(logging.Filter):
    """Drops aiohttp's report of a request it could not parse (no Host, a
    bad header line): the client gets a 400 saying so, and the terminal
    no traceback."""

    def filter(self, record):
        from aiohttp.http_exceptions import HttpProcessingError

        error = record.exc_info[1] if record.exc_info else None
        return not isinstance(error, HttpProcessingError)


def _http_logger():
    logger = logging.getLogger("jaxadapt.viewer.http")
    if not logger.filters:
        logger.addFilter(_ClientErrors())
    return logger


def _bracketed(host):
    return f"[{host}]" if ":" in host else host


def is_wildcard(host):
    """Whether ``host`` means every address of the machine (``0.0.0.0``, ``::``, ``""``)."""
    if host in ("", None):
        return True
    try:
        return ipaddress.ip_address(host).is_unspecified
    except ValueError:
        return False


def machine_names(wildcard="0.0.0.0"):
    """Names a browser can reach a server bound to ``wildcard`` by: the
    machine's host name, its addresses (those of its name and that of its
    default route; IPv4 for ``0.0.0.0``, IPv6 for ``::``, both for ``""``),
    then loopback's address."""
    families = {"0.0.0.0": [socket.AF_INET], "::": [socket.AF_INET6]}.get(
        str(ipaddress.ip_address(wildcard)) if wildcard else "",
        [socket.AF_INET, socket.AF_INET6],
    )
    names = [socket.gethostname()]
    for family in families:
        found = []
        try:
            found += [a[4][0] for a in socket.getaddrinfo(names[0], None, family)]
        except OSError:  # a name that does not resolve
            pass
        with contextlib.suppress(OSError), socket.socket(family, socket.SOCK_DGRAM) as probe:
            probe.connect(("192.0.2.1" if family == socket.AF_INET else "2001:db8::1", 9))
            found.append(probe.getsockname()[0])  # (a datagram socket sends nothing on connect)
        names += [a for a in found if not ipaddress.ip_address(a.split("%")[0]).is_loopback]
    names += ["127.0.0.1" if socket.AF_INET in families else "::1"]
    return list(dict.fromkeys(names))


def is_loopback(host):
    """Whether ``host`` (an address or ``localhost``) is this machine only."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
