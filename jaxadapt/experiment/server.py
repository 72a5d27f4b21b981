"""The experiment's web server: one page that runs the trials, its images,
and the answers it posts, written to the session's table before the page
moves on.

The page (``static/experiment.html``, ``experiment.js``) asks ``/next``
what comes next, fetches the trial's images (``/image/KEY``) before it
shows the fixation target, shows each image for its whole number of
display frames (counted with ``requestAnimationFrame``, timed by the
page), takes the answer from the keyboard and posts it to ``/answer``.
It is served as :mod:`jaxadapt.viewer` serves its page (a
:class:`~jaxadapt.viewer._site.Site`: loopback by default, a token
otherwise).
"""

import asyncio

from jaxadapt.viewer._site import Site

__all__ = ["ExperimentServer", "ASSETS", "MAX_MESSAGE", "INSTRUCTIONS", "KEYS"]

#: The page and its script.
ASSETS = {
    "/": ("experiment.html", "text/html"),
    "/experiment.js": ("experiment.js", "text/javascript"),
}
#: Largest request body taken (an answer is a few hundred bytes).
MAX_MESSAGE = 4096

#: What the page shows before the first trial: the cover story of each
#: study as the paper tells it (Jacobs et al. 2015, §4.1.1 and §4.2.1),
#: then the keys.
INSTRUCTIONS = {
    "afterimage": (
        "You will see videos of a camera flash firing on a special monitor that can get "
        "brighter than a normal display. The power of the flash has been adjusted in each "
        "video. In each trial you see two flashes, one after the other: keep your eyes on the "
        "cross, and say which flash was set to be brighter."
    ),
    "mesopic": (
        "You will see images of a very dark scene on a special monitor. The brightness of a "
        "lamp outside the picture has been adjusted in each image. In each trial you see two "
        "images, one after the other: say in which one the lamp was set to be brighter."
    ),
}
KEYS = "Press 1 or \u2190 for the first, 2 or \u2192 for the second. Space to begin."


class ExperimentServer(Site):
    """Serve a :class:`~jaxadapt.experiment.session.Session` with its
    :class:`~jaxadapt.experiment.stimuli.Stimuli`.

    Parameters
    ----------
    session : Session
    stimuli : Stimuli
    host, port, token
        As :class:`~jaxadapt.viewer._site.Site`.
    report : callable, optional
        Takes a line for the terminal (each answer's progress, the end).
    """

    def __init__(self, session, stimuli, host="127.0.0.1", port=0, token=None, report=None):
        super().__init__(
            "jaxadapt experiment",
            host,
            port,
            token,
            __package__,
            ASSETS,
            frozenset({"/experiment.js"}),
        )
        self.session, self.stimuli = session, stimuli
        self.report = report or (lambda line: None)
        self.finished = asyncio.Event()
        self.lock = asyncio.Lock()

    def app(self):
        app = self.web_app(MAX_MESSAGE)
        app.router.add_get("/session", self._setup)
        app.router.add_get("/next", self._next)
        app.router.add_get("/image/{key}", self._image)
        app.router.add_post("/answer", self._answer)
        return app

    async def start(self):
        """Bind; return the page's URL."""
        await self.bind(self.app())
        return self.urls()[0]

    async def close(self):
        await self.runner.cleanup()

    # -- requests -----------------------------------------------------------

    async def _setup(self, request):
        """What the page needs once: the study, the display's refresh, the
        images' size, the fixation target, the dark period, the words."""
        from aiohttp import web

        s, st = self.session, self.stimuli
        answered, planned = s.progress()
        return web.json_response(
            {
                "study": s.spec["study"],
                "participant": s.spec["participant"],
                "refresh_hz": st.display.refresh_hz,
                "size": list(st.size),
                "fixation": st.fixation,
                "text_code": st.text_code,
                "dark_seconds": s.spec["dark_seconds"],
                "instructions": INSTRUCTIONS[s.spec["study"]],
                "keys": KEYS,
                "progress": [answered, planned],
            }
        )

    def _state(self):
        """:meth:`Session.next`, with the trial's intervals when it is one."""
        s = self.session
        state = dict(s.next())
        state["progress"] = list(s.progress())
        if state["phase"] != "trial":
            return state
        t = s.plan[state["trial"]]
        condition = s.protocol.conditions.index(t["condition"])
        level = t["level_index"]
        test = {"stimulus": "test", "luminance": s.protocol.tests[level]}
        test |= self.stimuli.interval(condition, level)._asdict()
        standard = {"stimulus": "standard", "luminance": s.protocol.standard}
        standard |= self.stimuli.interval()._asdict()
        state["block"] = t["block"]
        state["intervals"] = [test, standard] if t["test_first"] else [standard, test]
        return state

    async def _next(self, request):
        from aiohttp import web

        return web.json_response(self._state())

    async def _image(self, request):
        from aiohttp import web

        body = self.stimuli.images.get(request.match_info["key"])
        if body is None:
            raise web.HTTPNotFound(text="no such image\n")
        return web.Response(
            body=body, content_type="image/png", headers={"Cache-Control": "max-age=86400"}
        )

    async def _answer(self, request):
        """Record an answer (JSON: ``trial``, ``answer``, ``rt_ms``,
        ``durations`` (4 ms values), ``dropped``); reply with what comes
        next. An answer to another trial than the one pending (a page
        posting twice) is not written."""
        from aiohttp import web

        try:
            body = await request.json()
            trial, answer = int(body["trial"]), int(body["answer"])
            rt, dropped = float(body["rt_ms"]), int(body["dropped"])
            durations = [float(v) for v in body["durations"]]
            if len(durations) != 4:
                raise ValueError
        except (ValueError, KeyError, TypeError):
            raise web.HTTPBadRequest(
                text="expected JSON with trial, answer, rt_ms, durations (4) and dropped\n"
            ) from None
        async with self.lock:
            written = await asyncio.to_thread(
                self.session.answer, trial, answer, rt, durations, dropped
            )
            state = self._state()
        if written:
            answered, planned = state["progress"]
            flag = f", flagged: {dropped} frame(s) dropped" if dropped else ""
            self.report(f"trial {trial}: answered {answer} ({answered}/{planned}){flag}")
        if state["phase"] in ("done", "excluded"):
            self.finished.set()
        return web.json_response({"written": written, "next": state})
