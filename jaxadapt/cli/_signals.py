"""Signals while a command runs: raised as an interrupt where the run can
clean up, held back while outputs move into place, dropped once they are."""

import contextlib
import signal
import threading

from jaxadapt._program import take_signals

#: Signals received while a command ran (:func:`_interruptible`).
_SIGNALLED = []


#: Set while signals are held back (:func:`_signals_deferred`).
_DEFERRING = threading.Event()


#: Set once a command's outputs are all in ``--out`` (:func:`_staged`).
_WRITTEN = threading.Event()


@contextlib.contextmanager
def _signals_deferred():
    """Hold back the signals of :func:`_interruptible` while the body runs:
    a signal is remembered, and raised as ``KeyboardInterrupt(signum)`` when
    the body has completed (an error of the body goes first), so that an
    interrupt while a render's files move into ``--out`` cannot leave the
    new run's outputs mixed with the old one's, nor a staging folder half
    removed. Once the outputs are all in place (:data:`_WRITTEN`) the run
    has succeeded, and a signal held back is dropped."""
    before = len(_SIGNALLED)
    _DEFERRING.set()
    try:
        yield
    finally:
        _DEFERRING.clear()
    if len(_SIGNALLED) > before and not _WRITTEN.is_set():
        raise KeyboardInterrupt(_SIGNALLED[before])


@contextlib.contextmanager
def _interruptible():
    """While the body runs, the signals of :data:`jaxadapt._program.SIGNALS`
    raise ``KeyboardInterrupt(signum)`` (unless deferred,
    :func:`_signals_deferred`, or once the outputs are all in place,
    :data:`_WRITTEN`: the run has succeeded) and are remembered in
    :data:`_SIGNALLED`.

    By default SIGTERM and SIGHUP end Python at once, leaving the staging
    folder in ``--out``; raised as an interrupt, the run cleans up as a
    failed one. Python drops an exception raised inside a garbage-collector
    callback (as JAX's is), so :func:`_staged` also checks
    :data:`_SIGNALLED` before it moves anything into place. Only the main
    thread can set signal handlers; elsewhere the signals keep their own. A
    signal the process was started ignoring (``nohup`` ignores SIGHUP)
    stays ignored.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        _SIGNALLED.append(signum)
        if not (_DEFERRING.is_set() or _WRITTEN.is_set()):
            raise KeyboardInterrupt(signum)

    _SIGNALLED.clear()
    _WRITTEN.clear()
    previous = take_signals(interrupt)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
