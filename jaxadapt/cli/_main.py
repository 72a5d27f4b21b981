"""The program's entry: parse, run the command, turn its errors into one
line and its outcome into the exit status."""

import contextlib
import importlib
import os
import signal
import sys
import warnings

from jaxadapt import _signals, runtime
from jaxadapt._signals import interrupt_behind, interrupted_message, named_command
from jaxadapt.cli._options import COMMANDS, UsageError, _Parser, _version
from jaxadapt.cli._output import _message

#: The exit status of a run that read an input only in part (a video file
#: cut short) and rendered what it could read.
INCOMPLETE = 3


def build_parser(command=None):
    """The program's parser: its options, and the options of ``command``
    (declared by the command's module). The other commands are named with
    their line of help only, so that ``jaxadapt --help`` and ``--version``
    do not import the registries that a command's options list (JAX)."""

    parser = _Parser(
        prog="jaxadapt",
        description="Simulate time-dependent visual adaptation to HDR scenes "
        "and render what a viewer would see on an ordinary display.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, line in COMMANDS.items():
        if name == command:
            importlib.import_module(f"{__package__}.{name}").add_parser(sub)
        else:
            sub.add_parser(name, help=line)
    return parser


def main(argv=None):
    """Run the command of ``argv`` (by default the command line's); return its
    exit status. Signals interrupt it from the parsing of its arguments to
    its last line (:func:`~jaxadapt._signals.interruptible`): the one line of
    :func:`~jaxadapt._signals.interrupted_message` and the shell's status,
    128 + the signal; 0 once the outputs are all in place."""
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        with _signals.interruptible():
            return _command(argv)
    except Exception as e:
        interrupt = interrupt_behind(e)
        if interrupt is None:
            raise
        return _interrupted(interrupt, argv)
    except KeyboardInterrupt as e:
        return _interrupted(e, argv)


def _interrupted(e, argv):
    """The status of a run of ``argv`` interrupted by ``e`` (after its one line)."""
    if _signals.WRITTEN.is_set():  # only a handler restored after the run can raise here
        return 0
    with contextlib.suppress(OSError):  # a terminal closed (SIGHUP) cannot be written to
        print(interrupted_message(argv), file=sys.stderr)
    return 128 + (e.args[0] if e.args else signal.SIGINT)


def _command(argv):
    """Parse ``argv`` and run its command; its errors as one line and status 2,
    its warnings as lines (status 3 after an input read only in part)."""
    from rich.console import Console

    # A signal while a command's module imports JAX is raised once the import
    # is done: raised inside the initialisation of JAX's compiled extension
    # (nanobind), it aborts the process instead of ending the run.
    with _signals.signals_deferred():
        parser = build_parser(named_command(argv))
    args = parser.parse_args(argv)
    runtime.use_wide_vectors()  # AVX-512's full width for XLA (jaxadapt.runtime)
    runtime.retain_freed_memory()  # buffers of later chunks reuse pages (jaxadapt.runtime)
    runtime.cache_compilations()  # later runs reuse this one's compiled programs
    # Warnings and progress on stderr, never wrapped inside a number or a path
    console = Console(stderr=True, soft_wrap=True)
    import equinox as eqx
    import jax

    from jaxadapt._checks import IncompleteInputWarning

    _signals.raise_swallowed()  # an interrupt that a garbage-collector callback dropped
    incomplete = []  # (an input read in part: said, and the status says so)

    def show(message, category, *_):
        console.print(f"warning: {message}", markup=False)
        incomplete.append(issubclass(category, IncompleteInputWarning))

    try:
        with warnings.catch_warnings():  # the library's warnings as the command's own lines
            warnings.simplefilter("always", IncompleteInputWarning)
            warnings.showwarning = show
            args.run(args, console)
    except MemoryError:
        print(f"jaxadapt: error: out of memory; try {_smaller(args)}", file=sys.stderr)
        return 2
    except (UsageError, ValueError, FileNotFoundError, OSError, eqx.EquinoxRuntimeError) as e:
        print(f"jaxadapt: error: {_message(e)}", file=sys.stderr)
        return 2
    except jax.errors.JaxRuntimeError as e:
        if "RESOURCE_EXHAUSTED" not in str(e):
            raise
        print(
            f"jaxadapt: error: out of memory ({_message(e)}); try {_smaller(args)}",
            file=sys.stderr,
        )
        return 2
    return INCOMPLETE if any(incomplete) else 0


def run():
    """The command line's program: :func:`main` on its arguments, then exit
    with its status (see :func:`jaxadapt._program.run`, which calls it).

    Signals that come after :func:`main` has returned are remembered and
    dropped: its status stands (one that reached Python's exit handlers
    printed an "Exception ignored in atexit callback" traceback). An
    interrupted run leaves through ``os._exit``, once :func:`main` has
    cleaned up and said so: the computation it interrupted may still be
    running on XLA's threads, and Python's finalisation, which frees what
    they use, crashed 3 of 8 runs sent SIGTERM during a bootstrap ("pure
    virtual method called", "corrupted size vs. prev_size", a segmentation
    fault: status 134 or 139 instead of 143).
    """
    _signals.take_signals(_signals.remember)  # main's restore these
    status = main()
    sys.stdout.flush()
    sys.stderr.flush()
    if _signals.SIGNALLED:
        os._exit(status)
    sys.exit(status)


def _smaller(args):
    """What to make smaller when the command of ``args`` runs out of memory."""
    if args.command == "render":
        return "a smaller --chunk, --size or --background-scale"
    if args.command == "experiment":
        return "a display of fewer pixels per degree (--display)"
    return {"fit": "fewer --resamples", "simulate": "fewer --observers"}[args.action]
