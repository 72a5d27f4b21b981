"""``jaxadapt view``: the live, gaze-contingent viewer in the browser
(:mod:`jaxadapt.viewer`)."""

import argparse
import math
from pathlib import Path

from jaxadapt.cli._options import (
    COMMANDS,
    UsageError,
    _folder,
    _frame_rate,
    _pixels_per_degree,
    _port,
    _positive,
    _seed,
    _size,
)
from jaxadapt.cli._output import _report

__all__ = ["add_parser", "view"]


def _span(text):
    try:
        w, h = (float(v) for v in text.lower().split("x"))
    except ValueError:
        w = h = math.nan
    if not (0 < w < math.inf and 0 < h < math.inf):
        raise argparse.ArgumentTypeError(
            f"expected WIDTHxHEIGHT, two positive numbers (1x1, 1920x1080), got {text!r}"
        )
    return w, h


def _channels(text):
    names = [n.strip() for n in text.split(",")]
    if len(names) not in (2, 3) or not all(names):
        raise argparse.ArgumentTypeError(
            f"expected X,Y or X,Y,CONFIDENCE, channel labels or indices, got {text!r}"
        )
    return names


def _fraction(text):
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"expected a number from 0 to 1, got {text!r}")
    return value


def add_parser(sub):
    """Declare ``jaxadapt view`` and its options on the subparsers ``sub``."""
    parser = sub.add_parser(
        "view",
        help=COMMANDS["view"],
        description="Serve a page that shows the operator's frames live and takes the "
        "pointer over them (or an eye tracker's samples, sent to /gaze or read from an "
        "LSL stream) as the gaze. The "
        "simulation advances by the wall-clock time between frames, so adaptation and "
        "afterimages keep their real time course. Ctrl-C stops it.",
    )
    for flags, kwargs in (*_input_options(), *_server_options(), *_tracker_options()):
        parser.add_argument(*flags, **kwargs)
    parser.set_defaults(run=view)


# The options as (flags, add_argument keywords), in the order --help lists them.


def _input_options():
    """The options of the input, the operator and its effects."""
    from jaxadapt.scenes import SCENES
    from jaxadapt.viewer import DEFAULT_SCENE
    from jaxadapt.viewer._session import DEFAULT_OPERATOR, EFFECTS, VIEW_OPERATORS
    from jaxadapt.viewer._sizing import LADDER, TARGET_FPS

    return (
        (("files",), dict(nargs="*", metavar="FILE", help="HDR input (EXR, HDR, PFM, float "
            "TIFF): one image, or a sequence played in a loop")),
        (("--scene",), dict(choices=sorted(SCENES), default=None, help="built-in scene when "
            f"no FILE is given (default: {DEFAULT_SCENE})")),
        (("--operator",), dict(choices=VIEW_OPERATORS, default=DEFAULT_OPERATOR,
            help=f"the operator (default: {DEFAULT_OPERATOR})")),
        (("--size",), dict(type=_size, default=None, metavar="WxH", help="largest frame "
            "size rendered (default: the largest of {} that keeps {:g} frames/s on this "
            "machine, measured at start-up); FILEs are shrunk to fit, aspect kept".format(
                ", ".join(f"{w}x{h}" for w, h in LADDER), TARGET_FPS))),
        (("--multiplier",), dict(type=_positive, default=1.0, help="multiply input values by "
            "this to calibrate them to cd/m2 (default: 1)")),
        (("--fps",), dict(type=_frame_rate, default=None, help="frame rate of a FILE sequence "
            "(default: the first file's, else 30)")),
        (("--pixels-per-degree",), dict(type=_pixels_per_degree, default=None,
            help="resolution of the frames at the eye (default: the scene's own at --size; "
            "for FILEs 30 at their own size)")),
        (("--seed",), dict(type=_seed, default=None, help="seed of jacobs2015's random draws "
            "(acuity noise, dithering); default 0")),
        (("--off",), dict(action="append", choices=EFFECTS, default=[], metavar="EFFECT",
            help="start with this jacobs2015 effect off, repeatable "
            f"({', '.join(EFFECTS)}); the page switches them")),
    )  # fmt: skip


def _server_options():
    """The options of the server and the record."""
    return (
        (("--host",), dict(default="127.0.0.1", help="address to listen on (default: "
            "127.0.0.1, this machine only; 0.0.0.0: every IPv4 address); any other requires "
            "the token in the URLs printed at start")),
        (("--port",), dict(type=_port, default=8765, help="port (default: 8765; 0: any free "
            "one)")),
        (("--no-browser",), dict(action="store_true", help="do not open the page in a browser")),
        (("--record",), dict(type=_folder, default=None, metavar="DIR", help="record the "
            "session into DIR: session.json, frames.csv (t, dt and gaze of every frame) and "
            "gaze.csv (what render --gaze reads)")),
    )  # fmt: skip


def _tracker_options():
    """The options of an eye tracker's Lab Streaming Layer stream."""
    from jaxadapt.viewer._lsl import MIN_CONFIDENCE, TIMEOUT

    return (
        (("--gaze-lsl",), dict(default=None, metavar="NAME", help="take the gaze from the eye "
            "tracker's Lab Streaming Layer stream NAME (pip install 'jaxadapt[lsl]'); the "
            "pointer is then ignored")),
        (("--gaze-lsl-channels",), dict(type=_channels, default=None,
            metavar="X,Y[,CONFIDENCE]", help="its channels of x, y and confidence, by label "
            "or 0-based index (default: those its meta-data types ScreenX, ScreenY and "
            "Confidence, else 0 and 1)")),
        (("--gaze-lsl-span",), dict(type=_span, default=None, metavar="WxH", help="its x, y "
            "at the frame's bottom-right corner, 0,0 being the top-left one (default: 1x1, "
            "normalised; a screen's size, e.g. 1920x1080, for its pixels, the page full "
            "screen)")),
        (("--gaze-lsl-confidence",), dict(type=_fraction, default=None,
            help="a sample of lower confidence is a lost eye, as a blink (default: "
            f"{MIN_CONFIDENCE:g})")),
        (("--gaze-lsl-timeout",), dict(type=_positive, default=None, metavar="S",
            help=f"seconds to wait for the stream at start (default: {TIMEOUT:g})")),
    )  # fmt: skip


def _tracker(args):
    """The opened :class:`~jaxadapt.viewer._lsl.Tracker` of ``--gaze-lsl``, or None."""
    options = {
        "timeout": args.gaze_lsl_timeout,
        "channels": args.gaze_lsl_channels,
        "span": args.gaze_lsl_span,
        "min_confidence": args.gaze_lsl_confidence,
    }
    if args.gaze_lsl is None:
        given = next((name for name, value in options.items() if value is not None), None)
        if given is not None:
            option = "--gaze-lsl-" + {"min_confidence": "confidence"}.get(given, given)
            raise UsageError(f"{option}: applies with --gaze-lsl NAME")
        return None
    from jaxadapt.viewer._lsl import open_tracker

    return open_tracker(args.gaze_lsl, **options)


def _spec(args):
    """The session's spec (:class:`jaxadapt.viewer.Session`) of the checked options."""
    if args.files and args.scene is not None:
        raise UsageError("--scene: applies when no FILE is given")
    if not args.files and args.fps is not None:
        raise UsageError("--fps: applies to FILE input, not to a built-in scene")
    from jaxadapt.operators import OPERATORS
    from jaxadapt.viewer._session import DEFAULT_SIZE, VIEW_OPERATORS

    supports = OPERATORS.supports(args.operator)
    for option, value, capability in (
        ("--seed", args.seed, "seed"),
        ("--off", args.off, "effects"),
    ):
        if value and not getattr(supports, capability):
            having = ", ".join(n for n in OPERATORS.having(capability) if n in VIEW_OPERATORS)
            raise UsageError(f"{option}: applies to --operator {having}, not {args.operator}")

    spec = {
        "operator": args.operator,
        "size": list(args.size or DEFAULT_SIZE),
        "multiplier": args.multiplier,
        "seed": args.seed or 0,
    }
    if args.files:
        missing = [f for f in args.files if not Path(f).is_file()]
        if missing:
            raise FileNotFoundError(f"FILE: {missing[0]}: no such file")
        spec |= {"files": [str(Path(f).resolve()) for f in args.files], "fps": args.fps}
    else:
        from jaxadapt.viewer import DEFAULT_SCENE

        spec["scene"] = args.scene or DEFAULT_SCENE
    if args.pixels_per_degree is not None:
        spec["pixels_per_degree"] = args.pixels_per_degree
    if supports.effects:
        spec["effects"] = [e for e in supports.effects if e not in args.off]
    return spec


def view(args, console):
    """``jaxadapt view``: build the session, compile its step, then serve
    until a signal (Ctrl-C) stops it; the record is complete on return."""
    import asyncio
    import secrets

    from jaxadapt.viewer import Recorder, Session
    from jaxadapt.viewer._addresses import is_loopback

    spec = _spec(args)
    if args.record is not None:
        Recorder.check(args.record)
    tracker = _tracker(args)  # (a stream not found: said before anything is written)
    try:
        if args.size is None:
            spec["size"] = _fitting_size(spec, console)
        session = Session(spec)
    except MemoryError:
        raise UsageError("out of memory; try a smaller --size") from None
    token = None if is_loopback(args.host) else secrets.token_urlsafe(16)
    record = None if args.record is None else (lambda: Recorder(args.record, session.spec))
    asyncio.run(_serve(session, args, token, record, console, tracker))


def _fitting_size(spec, console):
    """The default ``--size``, measured here (:func:`jaxadapt.viewer.fitting_size`), said."""
    from jaxadapt.viewer import TARGET_FPS, fitting_size

    console.print(f"measuring the largest --size that keeps {TARGET_FPS:g} frames/s here")
    (W, H), seconds = fitting_size(spec)
    console.print(
        f"--size {W}x{H}: a frame takes {1e3 * seconds:.0f} ms here"
        + ("" if seconds <= 1 / TARGET_FPS else ", slower than asked, at the smallest size"),
        markup=False,
        highlight=False,
    )
    return [W, H]


async def _serve(session, args, token, record, console, tracker=None):
    """Start the server (compile, then record), serve until a signal, stop.

    A signal while it starts ends the run as interrupted once the compile
    is done, before anything is recorded; once serving, it stops the server
    and the run succeeds (status 0, the record complete), and a signal
    after that is dropped."""
    import asyncio
    import signal
    import webbrowser

    from jaxadapt._signals import SIGNALS, WRITTEN
    from jaxadapt.viewer import Server

    loop = asyncio.get_running_loop()
    stop, signalled = asyncio.Event(), []
    # (those the process was started ignoring stay ignored: nohup's SIGHUP)
    previous = {s: signal.getsignal(s) for s in SIGNALS if signal.getsignal(s) != signal.SIG_IGN}
    for signum in previous:  # from here a signal stops the server cleanly
        loop.add_signal_handler(signum, lambda s=signum: (signalled.append(s), stop.set()))

    def restore():
        for signum, handler in previous.items():
            loop.remove_signal_handler(signum)  # (which sets Python's default)
            signal.signal(signum, handler)

    def recorder():
        if signalled:  # while compiling: nothing recorded, no serving
            raise KeyboardInterrupt(signalled[0])
        return None if record is None else record()

    def report(line):  # (simulated time falling behind, or keeping up again)
        console.print(line, markup=False, highlight=False)

    server = Server(session, args.host, args.port, token, report, tracker)
    if tracker is not None:
        report(tracker.describe())
    W, H = session.shape[1], session.shape[0]
    console.print(f"compiling {args.operator} for {W}x{H} frames")
    try:
        url = await server.start(recorder, prepare=session.warm)
    except OSError as error:
        if error.filename is not None:  # the record's folder, not the address
            raise
        raise UsageError(
            f"--host, --port: cannot listen on {args.host} port {args.port}: "
            f"{error.strerror or error}"
        ) from None
    finally:
        if server.sim.ident is None:  # not started: the handlers go with the error
            restore()
    urls = server.urls()  # (bound to every address: the machine's names, loopback's last)
    _report(f"jaxadapt view: serving {url} (Ctrl-C stops)")
    if len(urls) > 1:
        _report(f"  also at {', '.join(urls[1:])}")
    if not args.no_browser:
        loop.run_in_executor(None, webbrowser.open, urls[-1])
    try:
        while not stop.is_set() and server.sim.is_alive():
            try:
                await asyncio.wait_for(stop.wait(), 0.5)
            except asyncio.TimeoutError:
                pass
    finally:
        await server.close()
        WRITTEN.set()  # the record complete: the run has succeeded
        restore()
    if isinstance(server.sim.error, MemoryError):
        raise UsageError("out of memory; try a smaller --size")
    if server.sim.error is not None:
        raise server.sim.error
    if args.record is not None:
        _report(f"recorded {server.sim.recorder.count} frames in {args.record}/")
