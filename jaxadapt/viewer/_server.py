"""The live viewer's server: one page, its frames over a WebSocket, the gaze
from the page's pointer or an external tracker (on ``/gaze``, or an LSL
stream: :mod:`~jaxadapt.viewer._lsl`), and ``/state``.

The simulation runs in a thread of its own
(:class:`~jaxadapt.viewer._simulation.Simulation`) and computes a frame
only when a page has room for one (at most :data:`WINDOW` frames
unacknowledged): a page that falls behind skips frames rather than
queueing them, and the gaze a frame uses is never older than the frames in
flight. What clients send is read in :mod:`~jaxadapt.viewer._messages`;
the machine's names in :mod:`~jaxadapt.viewer._addresses`.
"""

import asyncio
import math
import time

from jaxadapt.viewer._messages import (
    MAX_MESSAGE,
    MAX_SOCKET_MESSAGE,
    Warnings,
    flag,
    frame_message,
    is_number,
    json_number,
    lag_message,
    parse_gaze,
    read_json,
    reason,
    send_error,
    send_frame,
    short,
    socket_teller,
    tell,
    too_long,
    warn_or_clear,
)
from jaxadapt.viewer._simulation import Simulation
from jaxadapt.viewer._site import Site

#: Frames a page may hold unacknowledged (sent, not yet drawn).
WINDOW = 2
#: Most pages served at once; more are refused with a message.
MAX_CLIENTS = 8
#: The page and its script, served from the package (never from a request's path).
ASSETS = {"/": ("index.html", "text/html"), "/viewer.js": ("viewer.js", "text/javascript")}
#: Paths served without the token: the page's script, the same for everyone
#: and holding no secret (the page loads it by a plain ``<script src>``).
PUBLIC = frozenset({"/viewer.js"})


class Client:
    """A page connected to ``/ws``: its socket, frames in flight and warnings."""

    def __init__(self, ws):
        self.ws, self.unacked, self.warnings = ws, 0, Warnings(socket_teller(ws))


class Server(Site):
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
        behind the wall clock, and when it keeps up again; news of ``tracker``.
    tracker : :class:`~jaxadapt.viewer._lsl.Tracker` or None
        An eye tracker's LSL stream, opened: the gaze from the start (the
        pointers ignored), its samples taken as those of ``/gaze``.
    """

    def __init__(self, session, host="127.0.0.1", port=0, token=None, report=None, tracker=None):
        super().__init__("jaxadapt view", host, port, token, __package__, ASSETS, PUBLIC)
        self.session = session
        self.report, self.slow, self.tracker = report, None, tracker
        self.clients, self.trackers = set(), set()
        self.tracker_warnings = Warnings(self._say_of_tracker)
        # What every page shows, kept here (the simulation applies the
        # commands between frames, and none while paused)
        self.effects, self.resets, self.last_frame = set(session.effects), 0, None
        self.sim = Simulation(session, self._publish_threadsafe)

    def app(self):
        app = self.web_app(MAX_MESSAGE)
        app.router.add_get("/state", self._state)
        app.router.add_get("/ws", self._page_socket)
        app.router.add_get("/gaze", self._gaze_socket)
        return app

    async def start(self, record=None, prepare=None):
        """Bind, run ``prepare()`` (in a thread: e.g. compiling the step),
        then start simulating; return the page's URL. ``record()``, once
        bound, makes the :class:`Recorder` of the frames."""
        await self.bind(self.app())
        try:
            if prepare is not None:
                await asyncio.to_thread(prepare)
            self.sim.recorder = None if record is None else record()
        except BaseException:
            await self.runner.cleanup()
            raise
        self.sim.start()
        if self.tracker is not None:
            self.tracker.start(self.session.shape, self._tracked_threadsafe, self._say_threadsafe)
        return self.urls()[0]

    async def close(self):
        """Close the sockets, stop the simulation (its record completed) and unbind."""
        for ws in [c.ws for c in self.clients] + list(self.trackers):
            await ws.close(code=1001, message=b"server stopped")
        if self.tracker is not None:
            await asyncio.to_thread(self.tracker.stop)
        self.sim.stop()
        await asyncio.to_thread(self.sim.join)
        await self.runner.cleanup()

    # -- requests ---------------------------------------------------------

    async def _state(self, request):
        from aiohttp import web

        sim = self.sim
        with sim.cond:
            gaze = sim.gaze_at(time.monotonic())[0]
        H, W = self.session.shape
        return web.json_response(
            {
                "frame": self.session.index,
                "fps": sim.fps(),
                "gaze": [None if math.isnan(v) else v for v in gaze],
                "adaptation": json_number(self.session.adaptation()),
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
        or switched on for the next frame), ``resets`` (how many so far),
        ``trackers`` (connected to ``/gaze``, or the LSL stream: the
        pointers are then ignored) and ``lsl`` (that stream's name, or None)."""
        with self.sim.cond:
            paused = self.sim.paused
        return {
            "paused": paused,
            "effects": sorted(self.effects),
            "resets": self.resets,
            "trackers": len(self.trackers) + (self.tracker is not None),
            "lsl": None if self.tracker is None else self.tracker.name,
        }

    async def _tell_pages(self, change):
        """Send every page the view's state after ``change`` (pause, effect,
        reset, trackers), so that all pages agree."""
        message = {"type": "state", "change": change, **self.view_state()}
        for client in list(self.clients):
            await tell(client.ws, message)

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
            await send_frame(ws, self.last_frame)
        self.sim.want()
        try:
            async for msg in ws:
                if too_long(msg):
                    await send_error(ws, too_long(msg))
                elif msg.type == WSMsgType.TEXT:
                    await self._page_message(client, msg.data)
                elif msg.type == WSMsgType.BINARY:
                    await send_error(ws, "expected JSON text messages, got binary data")
        finally:
            self.clients.discard(client)
        return ws

    async def _page_message(self, client, text):
        """Act on one message of a page: ``ack``, ``gaze``, ``pause``,
        ``reset`` or ``effect``; an error message for anything else."""
        try:
            message = read_json(text)
            kind = message.get("type") if isinstance(message, dict) else None
            if kind == "ack":
                client.unacked = max(0, client.unacked - 1)
                self.sim.want()
            elif kind == "gaze":
                if self.trackers or self.tracker is not None:  # a tracker drives the gaze
                    return
                await self._take(message, client.warnings)
            elif kind == "pause":
                self.sim.command("pause", flag(message, "paused", True))
                self.sim.want()
                await self._tell_pages("pause")
            elif kind == "reset":
                self.sim.command("reset")
                self.resets += 1
                await self._tell_pages("reset")
            elif kind == "effect":
                name, on = message.get("name"), flag(message, "on")
                if name not in self.session.available_effects:
                    raise ValueError(
                        f"effect: expected one of {list(self.session.available_effects)}, "
                        f"got {short(name, 40)}"
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
            await send_error(client.ws, reason(error))

    async def _gaze_socket(self, request):
        """``/gaze``: JSON lines ``{"t": s, "x": px, "y": px}`` from a tracker."""
        from aiohttp import WSMsgType, web

        ws = web.WebSocketResponse(compress=False, max_msg_size=MAX_SOCKET_MESSAGE, heartbeat=20)
        await ws.prepare(request)
        self.trackers.add(ws)
        await self._tell_pages("trackers")
        warnings = Warnings(socket_teller(ws))
        try:
            async for msg in ws:
                if too_long(msg):
                    await send_error(ws, too_long(msg))
                    continue
                if msg.type != WSMsgType.TEXT:
                    if msg.type == WSMsgType.BINARY:
                        await send_error(ws, "expected JSON lines of text, got binary data")
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
            sample = read_json(line)
            if isinstance(sample, dict):
                t = sample.get("t")
                if t is not None and not (is_number(t) and math.isfinite(t)):
                    raise ValueError(f"t: expected a time in seconds, got {short(t, 30)}")
            await self._take(sample, warnings)
        except Exception as error:  # a bad line (ValueError; any other: said as such)
            await send_error(ws, f"{reason(error)} (line {short(line)})")

    async def _take(self, sample, warnings, at=None, hold=math.inf):
        """Take a gaze sample ``{"x": px, "y": px}`` (of a page, ``/gaze`` or
        the LSL stream) for the frames from ``at`` for ``hold`` s
        (:meth:`Simulation.look`); its warning, if any, to ``warnings``. A
        ValueError, before anything is taken, for a sample that is none."""
        gaze, warning = parse_gaze(sample, self.session.shape)
        self.sim.look(gaze, sample.get("id"), at, hold)
        await warn_or_clear(warnings, warning)

    # -- the LSL stream (its thread hands its samples and news to the loop) --

    def _tracked_threadsafe(self, points, at, hold):
        asyncio.run_coroutine_threadsafe(self._tracked(points, at, hold), self.loop)

    async def _tracked(self, points, at, hold):
        for (x, y), t in zip(points.tolist(), at.tolist(), strict=True):
            await self._take({"x": x, "y": y}, self.tracker_warnings, t, hold)

    def _say_threadsafe(self, line):
        asyncio.run_coroutine_threadsafe(self._say_of_tracker(line), self.loop)

    async def _say_of_tracker(self, message, kind=None):
        """Tell the terminal ``message`` about the LSL stream (``kind``:
        "warning" or "clear" from its :class:`Warnings`)."""
        if self.report is not None:
            warning = "warning: " if kind == "warning" else ""
            self.report(f"gaze-lsl {self.tracker.name!r}: {warning}{message}")

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
                self.loop.create_task(send_frame(client.ws, message))
        if any(c.unacked < WINDOW for c in self.clients):
            self.sim.want()
