"""The ``jaxadapt`` program (and ``python -m jaxadapt``), signals handled from
its first instruction.

Importing the command line (JAX, NumPy) takes long enough to be
interrupted. :func:`run` takes the signals (:mod:`jaxadapt._signals`)
before it imports anything else, so that an interrupt at any point gives
the one line and the shell's status instead of a traceback, as
:mod:`jaxadapt.cli` does while a command runs.
"""

import os
import signal
import sys

from jaxadapt import _signals


def run():
    """Take the signals, import the command line and run it
    (:func:`jaxadapt.cli.run`, which exits with the command's status)."""
    _signals.ignore_unraisable_interrupts()
    taken = _signals.take_signals(_signals.raise_interrupt)
    try:
        try:
            from jaxadapt import cli

            _signals.raise_swallowed()  # an interrupt the import's garbage collection dropped
        except Exception as error:
            interrupt = _signals.interrupt_behind(error)
            if interrupt is None:
                raise
            raise interrupt from error
        cli.run()
    except KeyboardInterrupt as e:  # before the command line took the signals
        for s in taken:
            signal.signal(s, signal.SIG_IGN)
        print(_signals.interrupted_message(sys.argv[1:]), file=sys.stderr, flush=True)
        # Not through Python's finalisation: an import cut short (NumPy's,
        # JAX's) leaves its C extension half made, and finalising it can
        # crash the interpreter.
        os._exit(128 + (e.args[0] if e.args else signal.SIGINT))
