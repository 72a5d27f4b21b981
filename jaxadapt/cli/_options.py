"""The command line's argument types and parser: each value checked as it
is parsed, each error one line."""

import argparse
import importlib.metadata
import inspect
import math
import re
import sys
from pathlib import Path


class UsageError(ValueError):
    """A problem with the command line or its inputs."""


#: The commands, in the order ``jaxadapt --help`` lists them, and what each
#: does in a line. The program imports a command's module (and with it the
#: registries its options name: JAX) only when that command is run.
COMMANDS = {
    "render": "tone-map an HDR sequence with time-dependent adaptation (Pattanaik et al. 2000)",
    "psychometric": "analyse constant-stimuli experiments (Jacobs et al. 2015, §4)",
    "view": "look around an HDR scene live in the browser, the pointer as the gaze",
    "experiment": "run the 2015 paper's brightness studies with a participant in the browser",
}


def _size(text):
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected WIDTHxHEIGHT, e.g. 480x270, got {text!r}"
        ) from None
    if w < 2 or h < 2:
        raise argparse.ArgumentTypeError(f"expected a size of at least 2x2, got {text!r}")
    return w, h


def _positive(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


#: The resolutions ``--pixels-per-degree`` takes: a pixel of 1000 degrees
#: (more than the visual field) to 10,000 pixels to a degree (100 times
#: the eye's resolution). Beyond that jacobs2015's blurs, sized in pixels,
#: outgrow any frame: a render becomes very slow, then gives non-finite
#: frames.
PPD_RANGE = (1e-3, 1e4)


def _pixels_per_degree(text):
    value = _positive(text)
    low, high = PPD_RANGE
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(
            f"expected pixels per degree from {low:g} to {high:g}, got {text!r}"
        )
    return value


#: The frame rates ``--fps`` takes, frames/s: a frame a day (27.8 h) to a
#: frame a microsecond. Outside them the video's rate rounds to 0 or ffmpeg
#: refuses it (after the whole render), and a frame time beyond float32's
#: range gives black frames or an error about ``dt`` that does not name
#: ``--fps``.
FPS_RANGE = (1e-5, 1e6)


#: The lowest frame rate of ``video.mp4``, frames/s (a frame every 2.8 h),
#: with a margin above the rates at which the ffmpeg of imageio-ffmpeg
#: fails to write MP4 (its muxer refuses, for some rates only once there
#: are enough frames).
MP4_MIN_FPS = 1e-4


def _frame_rate(text):
    """``--fps``: a number, or a fraction as video rates are written (``24000/1001``)."""
    numerator, slash, denominator = text.partition("/")
    try:
        value = float(numerator) / float(denominator) if slash else float(text)
    except (ValueError, ZeroDivisionError):
        value = math.nan
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(
            f"expected a positive number of frames per second (30, 29.97, 24000/1001), got {text!r}"
        )
    low, high = FPS_RANGE
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(
            f"expected frames per second from {low:g} to {high:g}, got {text!r}"
        )
    return value


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line, as every other error of
    the command line (the usage is one ``--help`` away)."""

    def error(self, message, command=None):
        self.exit(2, f"jaxadapt: error: {message} (see {command or self.prog} --help)\n")

    def parse_args(self, args=None, namespace=None):
        """The arguments parsed; arguments that no option takes are said with
        the help of the command they were given to (``jaxadapt render
        --help``), not the program's, which lists only the commands."""
        argv = _negative_values_joined(list(sys.argv[1:] if args is None else args))
        parsed, extras = self.parse_known_args(argv, namespace)
        if extras:
            before = argv[: argv.index(extras[0])] if extras[0] in argv else argv
            # the command words the first of them follows (none: the program's)
            words = [getattr(parsed, dest, None) for dest in ("command", "action")]
            command = " ".join([self.prog, *(w for w in words if w and w in before)])
            self.error(f"unrecognized arguments: {' '.join(extras)}", command)
        return parsed


def _negative_values_joined(argv):
    """``argv`` with ``--option -VALUE`` written ``--option=-VALUE`` where the
    value starts with a minus and a digit: argparse takes ``-64x36`` (not a
    plain number) for an option and says "expected one argument" for
    ``--size -64x36``; joined, the option's own check says what is wrong."""
    joined = []
    for arg in argv:
        if joined and re.match(r"--[^=]+$", joined[-1]) and re.match(r"-\d", arg):
            joined[-1] = f"{joined[-1]}={arg}"
        else:
            joined.append(arg)
    return joined


def _port(text):
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(
            f"expected a port from 0 to 65535 (0: any free one), got {text!r}"
        )
    return value


def _folder(text):
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a folder, got an empty path")
    return Path(text)


def _folder_or_url(text):
    """A folder, or a URL of one in object storage (``s3://bucket/run``: a
    str, which a Path would mangle)."""
    from jaxadapt.io import is_url

    return text if is_url(text) else _folder(text)


#: Factors of the suffixes ``--memory`` takes.
_UNITS = {"": 1, "k": 2**10, "m": 2**20, "g": 2**30, "t": 2**40}


def _memory(text):
    """``--memory``: bytes, with an optional suffix K, M, G or T (powers of 1024)."""
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([kmgt]?)i?b?\s*", text.lower())
    value = float(match[1]) * _UNITS[match[2]] if match else 0
    if not 2**20 <= value <= 2**50:
        raise argparse.ArgumentTypeError(
            f"expected a size from 1M to 1P, such as 500M or 2G, got {text!r}"
        )
    return int(value)


def _workers(text):
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive number of processes, got {text!r}")
    return value


#: The options that send a command's work to a Dask cluster (:mod:`jaxadapt.cluster`),
#: as (flags, add_argument keywords); at most one of them is given.
CLUSTER_OPTIONS = (
    (
        ("--scheduler",),
        dict(
            default=None,
            metavar="ADDRESS",
            help="run the work on the Dask cluster of this scheduler (e.g. tcp://host:8786; "
            "needs the cluster extra, and jaxadapt on the workers); the results equal one "
            "process's",
        ),
    ),
    (
        ("--workers",),
        dict(
            type=_workers,
            default=None,
            metavar="N",
            help="run the work on N worker processes of an embedded Dask cluster (the "
            "cluster extra)",
        ),
    ),
)


def check_cluster_options(args):
    """Refuse ``--scheduler`` with ``--workers``: one cluster or the other."""
    if args.scheduler is not None and args.workers is not None:
        raise UsageError("--workers: starts a cluster of its own; not with --scheduler")


#: Largest seed: JAX's keys take a 64-bit signed integer.
MAX_SEED = 2**63 - 1


def _seed(text):
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(
            f"expected a whole number from 0 to 2**63 - 1, got {text!r}"
        )
    return value


def _default_sizes(scenes):
    """``"480x270 tunnel, ..."``: each scene's default frame size, from the
    defaults of its function's ``width`` and ``height``."""
    sizes = []
    for name, scene in scenes.items():
        parameters = inspect.signature(scene).parameters
        sizes.append(f"{parameters['width'].default}x{parameters['height'].default} {name}")
    return ", ".join(sizes)


def _version():
    """The installed package's version; said as such when run from a source
    tree that is not installed, which has no package metadata."""
    try:
        return importlib.metadata.version("jaxadapt")
    except importlib.metadata.PackageNotFoundError:
        return "(not installed)"
