"""The ``jaxadapt`` program (and ``python -m jaxadapt``), signals handled from
its first instruction.

Importing the command line (JAX, NumPy) takes long enough to be
interrupted. :func:`run` takes the signals before it imports anything else,
so that an interrupt at any point gives the one line and the shell's status
instead of a traceback, as :mod:`jaxadapt.cli` does while a command runs.
"""

import os
import signal
import sys

#: The signals that interrupt a command: Ctrl-C, a scheduler's SIGTERM, a
#: closed terminal's SIGHUP (where the platform has it).
SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)
#: What an interrupted command says on stderr, where it wrote nothing.
INTERRUPTED = "jaxadapt: interrupted; nothing was written to --out"


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
    into ``--record``. Read from the words alone: an interrupt can come
    before the parser is imported."""
    if named_command(argv) != "view":
        return INTERRUPTED
    recording = any(a == "--record" or a.startswith("--record=") for a in argv)
    return "jaxadapt: interrupted while starting" + (
        "; nothing was written to --record" if recording else ""
    )


#: Signals received before the command line took them over.
_SIGNALLED = []


def _interrupt(signum, frame):
    _SIGNALLED.append(signum)
    raise KeyboardInterrupt(signum)


def _unraisable(info):
    """Python's hook for an error it cannot raise, as an interrupt that comes
    while a garbage-collector callback runs (JAX has one): such an interrupt
    is remembered where it came (:data:`_SIGNALLED`, and the command line's
    own record) and acted on there, not printed as a traceback."""
    if not isinstance(info.exc_value, KeyboardInterrupt):
        sys.__unraisablehook__(info)


def take_signals(handler):
    """Handle the :data:`SIGNALS` with ``handler``, except those the process
    was started ignoring (``nohup`` ignores SIGHUP), which stay ignored;
    returns the handlers they had, by signal."""
    return {
        s: signal.signal(s, handler) for s in SIGNALS if signal.getsignal(s) is not signal.SIG_IGN
    }


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


def run():
    """Take the signals, import the command line and run it
    (:func:`jaxadapt.cli.run`, which exits with the command's status)."""
    sys.unraisablehook = _unraisable
    taken = take_signals(_interrupt)
    try:
        try:
            from jaxadapt import cli

            if _SIGNALLED:  # an interrupt the import's garbage collection swallowed
                raise KeyboardInterrupt(_SIGNALLED[0])
        except Exception as error:
            interrupt = interrupt_behind(error)
            if interrupt is None:
                raise
            raise interrupt from error
        cli.run()
    except KeyboardInterrupt as e:  # before the command line took the signals
        for s in taken:
            signal.signal(s, signal.SIG_IGN)
        print(interrupted_message(sys.argv[1:]), file=sys.stderr, flush=True)
        # Not through Python's finalisation: an import cut short (NumPy's,
        # JAX's) leaves its C extension half made, and finalising it can
        # crash the interpreter.
        os._exit(128 + (e.args[0] if e.args else signal.SIGINT))
