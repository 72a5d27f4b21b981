"""``jaxadapt experiment``: one participant's session of a 2015 brightness
study, run in the browser (:mod:`jaxadapt.experiment`)."""

import argparse

from jaxadapt.cli._options import COMMANDS, UsageError, _folder, _port, _seed
from jaxadapt.cli._output import _report

__all__ = ["add_parser", "experiment"]


def _count(text):
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}")
    return value


def _positive_count(text):
    value = _count(text)
    if value == 0:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
    return value


def _seconds(text):
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0 <= value < 1e6:
        raise argparse.ArgumentTypeError(f"expected seconds >= 0, got {text!r}")
    return value


def _participant(text):
    name = text.strip()
    if not name or any(ch in name for ch in '\r\n,"/\\'):
        raise argparse.ArgumentTypeError(
            f"expected a name without commas, quotes, slashes or line breaks, got {text!r}"
        )
    return name


def add_parser(sub):
    """Declare ``jaxadapt experiment`` and its options on the subparsers ``sub``."""
    from jaxadapt.experiment.session import BREAK_EVERY

    parser = sub.add_parser(
        "experiment",
        help=COMMANDS["experiment"],
        description="Run one participant's session of the afterimage (§4.1) or mesopic "
        "(§4.2) study of Jacobs et al. (2015) in the browser: two intervals a trial, the "
        "answer by keyboard, every answer written to DIR/trials.csv as it is given. Run the "
        "same command again to continue a session that stopped; `jaxadapt psychometric fit "
        "DIR/trials.csv` analyses it.",
    )
    add = parser.add_argument
    add("study", choices=("afterimage", "mesopic"), help="the study")
    add(
        "--participant",
        type=_participant,
        required=True,
        metavar="ID",
        help="the participant's code, written in every row",
    )
    add(
        "--out",
        type=_folder,
        required=True,
        metavar="DIR",
        help="the session's folder: session.json and trials.csv (a new or empty folder, or "
        "this participant's unfinished session, which is continued)",
    )
    add(
        "--display",
        default=None,
        metavar="FILE",
        help="the monitor's calibration as JSON: white and black (cd/m2), transfer (srgb, "
        "gamma, pq), gamma, distance_m, pixel_pitch_mm, refresh_hz (default: the paper's "
        "display, an OLED of 100 cd/m2 white at 64 pixels a degree, 60 Hz)",
    )
    add(
        "--training",
        type=_count,
        default=20,
        metavar="N",
        help="training trials (default: 20, the paper's)",
    )
    add(
        "--repetitions",
        type=_count,
        default=20,
        metavar="N",
        help="times each test is shown in the control block; the main block shows each "
        "1.5 N times manipulated and 0.5 N control (default: 20, the paper's 20, 30 and 10)",
    )
    add(
        "--dark-seconds",
        type=_seconds,
        default=None,
        metavar="S",
        help="seconds of darkness before the first trial (default: 300 for mesopic, as the "
        "paper; 0 for afterimage)",
    )
    add(
        "--break-every",
        type=_positive_count,
        default=None,
        metavar="N",
        help="a break every N trials within a block, besides those between blocks "
        f"(default: {BREAK_EVERY})",
    )
    add(
        "--seed",
        type=_seed,
        default=None,
        help="seed of the trial order and the dither patterns (default: a random one, kept "
        "in session.json)",
    )
    add(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default: 127.0.0.1, this machine only); any other "
        "requires the token in the URL printed at start",
    )
    add("--port", type=_port, default=8765, help="port (default: 8765; 0: any free one)")
    add("--no-browser", action="store_true", help="do not open the page in a browser")
    parser.set_defaults(run=experiment)


def experiment(args, console):
    """Open (or continue) the session, render its stimuli, serve the page
    until the session is over or a signal stops it."""
    import asyncio

    import jax

    from jaxadapt.cli._options import _version
    from jaxadapt.experiment.calibration import PAPER_DISPLAY, read_display
    from jaxadapt.experiment.session import BREAK_EVERY, Session, SessionError, scaled_protocol
    from jaxadapt.experiment.stimuli import Stimuli
    from jaxadapt.psychophysics import design

    display = PAPER_DISPLAY if args.display is None else read_display(args.display)
    dark = args.dark_seconds
    if dark is None:
        dark = design.PROTOCOLS[args.study].dark_adaptation_s
    spec = {
        "participant": args.participant,
        "study": args.study,
        "training": args.training,
        "repetitions": args.repetitions,
        "dark_seconds": dark,
        "display": display.to_json(),
        "software": _version(),
        "seed": args.seed,
        "break_every": args.break_every or BREAK_EVERY,
    }
    try:
        scaled_protocol(design.PROTOCOLS[args.study], args.training, args.repetitions)
    except ValueError as error:
        raise UsageError(f"--{error}") from None
    folder = args.out
    session = None
    try:
        if (folder / "session.json").exists():
            session = Session(folder, spec)
            spec["seed"] = session.spec["seed"]
        elif folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
            raise UsageError(
                f"--out: expected a new or empty folder, or an unfinished session, got {folder} "
                "holding other files"
            )
    except SessionError as error:
        raise UsageError(f"--out: {error}") from None
    if spec["seed"] is None:
        import os

        spec["seed"] = int.from_bytes(os.urandom(4), "little") >> 1
    protocol = design.PROTOCOLS[args.study]
    console.print(f"preparing the {args.study} stimuli for the display", highlight=False)
    try:
        stimuli = Stimuli(
            protocol,
            display,
            jax.random.key(spec["seed"]),
            report=lambda line: console.print("  " + line, highlight=False),
        )
    except ValueError as error:
        where = "the paper's display" if args.display is None else args.display
        raise UsageError(f"--display: {where}: {str(error).removeprefix('display: ')}") from None
    if session is None:
        session = Session(folder, spec)
    asyncio.run(_serve(session, stimuli, args, console))


async def _serve(session, stimuli, args, console):
    """Serve until the session is over (status 0) or a signal stops it
    (the answers so far kept; status 128 + the signal)."""
    import asyncio
    import secrets
    import signal
    import webbrowser

    from jaxadapt._signals import SIGNALS, WRITTEN
    from jaxadapt.experiment.server import ExperimentServer
    from jaxadapt.viewer._addresses import is_loopback

    loop = asyncio.get_running_loop()
    stop, signalled = asyncio.Event(), []
    previous = {s: signal.getsignal(s) for s in SIGNALS if signal.getsignal(s) != signal.SIG_IGN}
    for signum in previous:
        loop.add_signal_handler(signum, lambda s=signum: (signalled.append(s), stop.set()))

    def report(line):
        console.print(line, markup=False, highlight=False)

    token = None if is_loopback(args.host) else secrets.token_urlsafe(16)
    server = ExperimentServer(session, stimuli, args.host, args.port, token, report)
    try:
        try:
            url = await server.start()
        except OSError as error:
            raise UsageError(
                f"--host, --port: cannot listen on {args.host} port {args.port}: "
                f"{error.strerror or error}"
            ) from None
        answered, planned = session.progress()
        begun = f", {answered} of {planned} answered" if answered else ""
        _report(f"jaxadapt experiment: serving {url} (Ctrl-C stops{begun})")
        if not args.no_browser:
            loop.run_in_executor(None, webbrowser.open, server.urls()[-1])
        finished = asyncio.ensure_future(server.finished.wait())
        stopped = asyncio.ensure_future(stop.wait())
        await asyncio.wait({finished, stopped}, return_when=asyncio.FIRST_COMPLETED)
        finished.cancel()
        stopped.cancel()
        if server.finished.is_set():
            await asyncio.sleep(0.5)  # (the page's last reply on its way)
    finally:
        if server.runner is not None:
            await server.close()
        for signum, handler in previous.items():
            loop.remove_signal_handler(signum)
            signal.signal(signum, handler)
    answered, planned = session.progress()
    state = session.next()["phase"]
    where = session.table
    if state == "excluded":
        accuracy = session.training_accuracy()
        WRITTEN.set()
        _report(
            f"participant {session.spec['participant']} excluded: {accuracy:.0%} of the training "
            f"trials correct (at least {session.protocol_exclusion:.0%} needed); {where}"
        )
    elif state == "done":
        WRITTEN.set()
        _report(f"session complete: {answered} trials answered in {where}")
    else:
        _report(f"stopped at {answered} of {planned} trials answered")
        raise KeyboardInterrupt(signalled[0] if signalled else signal.SIGINT)
