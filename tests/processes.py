"""Child processes for the tests of signals, started without forking the
test's process: a ``preexec_fn`` makes Python fork it (not vfork or
posix_spawn), and forking a process that runs JAX's threads can deadlock
the child, as JAX warns."""

import subprocess
import sys

from jaxadapt._signals import SIGNALS

# The child's first program: set the dispositions, then become ``python ARGS``
# (an ignored signal stays ignored across exec, a handled one becomes default).
_SETUP = (
    "import os, signal, sys\n"
    "for s, how in zip(map(int, sys.argv[1].split(',')), sys.argv[2]):\n"
    "    signal.signal(s, signal.SIG_IGN if how == 'i' else signal.SIG_DFL)\n"
    "os.execv(sys.executable, [sys.executable, *sys.argv[3:]])\n"
)


def python(args, ignored=(), **popen):
    """``subprocess.Popen`` of ``python ARGS`` with the default disposition
    of each signal the command line handles, but ``ignored`` ignored: a
    suite started in the background or under nohup ignores SIGINT or
    SIGHUP and passes that on to its children, where the command line
    rightly keeps them ignored."""
    signals = [*SIGNALS, *ignored]
    how = "".join("i" if s in ignored else "d" for s in signals)
    numbers = ",".join(str(int(s)) for s in signals)
    return subprocess.Popen([sys.executable, "-c", _SETUP, numbers, how, *args], **popen)
