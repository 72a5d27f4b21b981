"""Signals, one mechanism from the program's first instruction to its exit:
which signals interrupt a command, the record of those received, and the
rules that make them interrupts where a run can clean up.

The program (:mod:`jaxadapt._program`) takes the signals before it imports
anything heavy; while a command runs, :func:`interruptible` raises them as
``KeyboardInterrupt(signum)``, :func:`signals_deferred` holds them back
while outputs move into place, and once the outputs are all in place
(:data:`WRITTEN`) they are dropped. Every signal received is appended to
:data:`SIGNALLED`, the one record that each stage checks: Python drops an
exception raised inside a garbage-collector callback (as JAX's is), so a
signal can arrive without its interrupt.
"""

import contextlib
import signal
import sys
import threading

#: The signals that interrupt a command: Ctrl-C, a scheduler's SIGTERM, a
#: closed terminal's SIGHUP (where the platform has it).
SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)
#: What an interrupted command says on stderr, where it wrote nothing.
INTERRUPTED = "jaxadapt: interrupted; nothing was written to --out"

#: Signals received, in order, since the command began (:func:`interruptible`
#: clears it); before that, those received while the program imported.
SIGNALLED = []
#: Set while signals are held back (:func:`signals_deferred`).
DEFERRING = threading.Event()
#: Set once a command's outputs are all in ``--out``.
WRITTEN = threading.Event()


def named_command(argv):
    """The command the program's arguments ``argv`` name: their first word
    that is not an option (the program's own options, ``--help`` and
    ``--version``, take no value); None where there is none."""
    return next((a for a in argv if not a.startswith("-")), None)


def interrupted_message(argv):
    """What the command of ``argv`` (the program's arguments) says on stderr
    when interrupted, having written nothing: :data:`INTERRUPTED`, except
    for ``view``, which has no ``--out`` and is interrupted only while it
    starts (once serving, a signal stops it), before it records anything
    into ``--record``, and ``experiment``, whose answers are on the disk as
    they are given. Read from the words alone: an interrupt can come
    before the parser is imported."""
    command = named_command(argv)
    if command == "experiment":
        return (
            "jaxadapt: interrupted; every answer given is kept in --out's trials.csv, and the "
            "same command continues the session"
        )
    if command != "view":
        return INTERRUPTED
    recording = any(a == "--record" or a.startswith("--record=") for a in argv)
    return "jaxadapt: interrupted while starting" + (
        "; nothing was written to --record" if recording else ""
    )


def take_signals(handler):
    """Handle the :data:`SIGNALS` with ``handler``, except those the process
    was started ignoring (``nohup`` ignores SIGHUP), which stay ignored;
    returns the handlers they had, by signal."""
    return {
        s: signal.signal(s, handler) for s in SIGNALS if signal.getsignal(s) is not signal.SIG_IGN
    }


def remember(signum, frame):
    """A handler that only records the signal in :data:`SIGNALLED`."""
    SIGNALLED.append(signum)


def raise_interrupt(signum, frame):
    """A handler that records the signal and raises it as an interrupt."""
    SIGNALLED.append(signum)
    raise KeyboardInterrupt(signum)


def raise_swallowed():
    """Raise the first signal of :data:`SIGNALLED` as an interrupt, where one
    came whose interrupt Python dropped (in a garbage-collector callback)."""
    if SIGNALLED:
        raise KeyboardInterrupt(SIGNALLED[0])


def ignore_unraisable_interrupts():
    """Python's hook for an error it cannot raise, as an interrupt that comes
    while a garbage-collector callback runs (JAX has one): such an interrupt
    is already in :data:`SIGNALLED` and acted on where it is checked, not
    printed as a traceback. Other errors go to Python's own hook."""

    def hook(info):
        if not isinstance(info.exc_value, KeyboardInterrupt):
            sys.__unraisablehook__(info)

    sys.unraisablehook = hook


def interrupt_behind(error):
    """The interrupt that ``error`` was raised from, or None. Python wraps an
    exception raised while a class is being made (``__set_name__``, as in
    matplotlib's import) in a RuntimeError: a signal there must still end
    the run as interrupted, not as a crash."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


@contextlib.contextmanager
def signals_deferred():
    """Hold back the signals of :func:`interruptible` while the body runs:
    a signal is remembered, and raised as ``KeyboardInterrupt(signum)`` when
    the body has completed (an error of the body goes first), so that an
    interrupt while a render's files move into ``--out`` cannot leave the
    new run's outputs mixed with the old one's, nor a staging folder half
    removed. Once the outputs are all in place (:data:`WRITTEN`) the run
    has succeeded, and a signal held back is dropped."""
    before = len(SIGNALLED)
    DEFERRING.set()
    try:
        yield
    finally:
        DEFERRING.clear()
    if len(SIGNALLED) > before and not WRITTEN.is_set():
        raise KeyboardInterrupt(SIGNALLED[before])


@contextlib.contextmanager
def interruptible():
    """While the body runs, the :data:`SIGNALS` raise
    ``KeyboardInterrupt(signum)`` (unless deferred, :func:`signals_deferred`,
    or once the outputs are all in place, :data:`WRITTEN`: the run has
    succeeded) and are remembered in :data:`SIGNALLED`.

    By default SIGTERM and SIGHUP end Python at once, leaving the staging
    folder in ``--out``; raised as an interrupt, the run cleans up as a
    failed one. Only the main thread can set signal handlers; elsewhere the
    signals keep their own. A signal the process was started ignoring
    (``nohup`` ignores SIGHUP) stays ignored.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        SIGNALLED.append(signum)
        if not (DEFERRING.is_set() or WRITTEN.is_set()):
            raise KeyboardInterrupt(signum)

    SIGNALLED.clear()
    WRITTEN.clear()
    previous = take_signals(interrupt)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
