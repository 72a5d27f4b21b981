"""Command line: ``jaxadapt render``.

Every error that comes from the user's input (arguments, files, values)
prints one line on stderr and exits with status 2. Outputs are written into
a staging folder inside ``--out`` and moved into place only when the whole
run has succeeded, so a failed run leaves nothing half-written and
overwrites nothing. An interrupted run (Ctrl-C, SIGTERM as a job
scheduler sends it, or SIGHUP as a closed terminal does) is a failed one: it
removes its staging folder, prints one line and exits with status 130 (143
for SIGTERM, 129 for SIGHUP), as a shell reports such a signal. A signal
that comes while the outputs are moved into place waits until they all are,
and the line says so.
"""

import argparse
import contextlib
import errno
import importlib.metadata
import inspect
import math
import os
import re
import shutil
import signal
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np

from jaxadapt import runtime
from jaxadapt._program import INTERRUPTED, take_signals

FORMATS = ("png", "mp4", "exr", "pfm")
CONTACT_FRAMES = 12
#: Size of a local background estimator unless --background-scale says otherwise, pixels.
BACKGROUND_SCALE = 8.0
#: Names of the files ``jaxadapt render`` writes.
RENDER_OUTPUTS = re.compile(
    r"frame_\d{5,}\.(png|exr|pfm)|video\.mp4|contact_sheet\.png|adaptation\.png|diagnostics\.csv"
)
#: Names of the files ``jaxadapt psychometric fit`` writes.
FIT_OUTPUTS = re.compile(r"fits\.csv|group_test\.csv|psychometric\.png|pse\.png")
#: A command's list, in its folder, of the files it wrote: the next run of
#: the command into the folder removes those of them it does not write again.
MANIFESTS = {RENDER_OUTPUTS: ".jaxadapt-render", FIT_OUTPUTS: ".jaxadapt-psychometric-fit"}


class UsageError(ValueError):
    """A problem with the command line or its inputs."""


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
    if not (value > 0 and np.isfinite(value)):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


#: The resolutions ``--pixels-per-degree`` takes: a pixel of 1000 degrees
#: (more than the visual field) to 10,000 pixels to a degree (100 times
#: the eye's resolution). Beyond that jacobs2015's blurs, sized in pixels,
#: outgrow any frame: 3 frames of 64x48 took 14 s at 1e4, minutes at 1e6,
#: and gave non-finite frames from 1e7.
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
#: frame a microsecond. Outside them the video's rate rounded to 0 (below
#: 5e-7, after the whole render) or ffmpeg refused it, and a frame time
#: beyond float32 (1e-300 s, 1e300 s) gave black frames or a message about
#: ``dt`` that did not name ``--fps``.
FPS_RANGE = (1e-5, 1e6)
#: The lowest frame rate of ``video.mp4``, frames/s (a frame every 2.8 h).
#: The ffmpeg of imageio-ffmpeg failed to write MP4 below about 2.6e-5
#: ("Error submitting a packet to the muxer: Not yet implemented"), for
#: some rates only with enough frames (2.5e-5 wrote 3 frames, not 300).
MP4_MIN_FPS = 1e-4


def _frame_rate(text):
    """``--fps``: a number, or a fraction as video rates are written (``24000/1001``)."""
    numerator, slash, denominator = text.partition("/")
    try:
        value = float(numerator) / float(denominator) if slash else float(text)
    except (ValueError, ZeroDivisionError):
        value = math.nan
    if not (value > 0 and np.isfinite(value)):
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
    plain number) for an option and said "expected one argument" for
    ``--size -64x36``; joined, the option's own check says what is wrong."""
    joined = []
    for arg in argv:
        if joined and re.match(r"--[^=]+$", joined[-1]) and re.match(r"-\d", arg):
            joined[-1] = f"{joined[-1]}={arg}"
        else:
            joined.append(arg)
    return joined


def _folder(text):
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a folder, got an empty path")
    return Path(text)


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
    tree that is not installed (every command failed there)."""
    try:
        return importlib.metadata.version("jaxadapt")
    except importlib.metadata.PackageNotFoundError:
        return "(not installed)"


def build_parser():
    from jaxadapt.operators import OPERATORS, TONE_CURVE_NAMES
    from jaxadapt.operators.goal import BACKGROUNDS, GOALS
    from jaxadapt.scenes import SCENES

    parser = _Parser(
        prog="jaxadapt",
        description="Simulate time-dependent visual adaptation to HDR scenes "
        "and render what a viewer would see on an ordinary display.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    render = sub.add_parser(
        "render",
        help="tone-map an HDR sequence with time-dependent adaptation (Pattanaik et al. 2000)",
        description="Tone-map an HDR frame sequence (absolute cd/m2) the way an observer "
        "whose eyes adapt over time would see it on an ordinary display (Pattanaik et al. "
        "2000), or with one of the classic tone curves (--operator). With no FILE, renders "
        "a built-in scene. Writes display frames, a contact sheet, a plot of the adaptation "
        "state and diagnostics.csv into --out.",
    )
    render.add_argument(
        "files",
        nargs="*",
        metavar="FILE",
        help="HDR input (EXR, Radiance HDR, PFM, float TIFF): one image, or the frames of "
        "a sequence in order (e.g. a shell glob of a numbered sequence)",
    )
    render.add_argument(
        "--scene",
        choices=sorted(SCENES),
        default=None,
        help="built-in scene when no FILE is given (default: tunnel)",
    )
    render.add_argument(
        "--size",
        type=_size,
        default=None,
        metavar="WxH",
        help=f"frame size of the built-in scene (default: {_default_sizes(SCENES)}; files keep "
        "their own)",
    )
    render.add_argument(
        "--duration",
        type=_positive,
        default=None,
        metavar="S",
        help="length of the built-in scene in seconds (default: the scene's own)",
    )
    render.add_argument(
        "--fps",
        type=_frame_rate,
        default=None,
        help="frames per second, 1e-5 to 1e6 (default: for FILEs the first file's "
        "FramesPerSecond (an EXR's framesPerSecond), else 30; the scene's own "
        "for a built-in scene: 30, or one frame per 30 ms for title-step; the flash scene adds a "
        "frame where the flash starts or ends between two, so that the simulation holds it for "
        "exactly 1/8 s: the outputs show these frames too, at the same rate)",
    )
    render.add_argument(
        "--multiplier",
        type=_positive,
        default=1.0,
        help="multiply input values by this to calibrate them to cd/m2 (default: 1)",
    )
    render.add_argument(
        "--operator",
        choices=list(OPERATORS),
        default="pattanaik2000",
        help="the operator: pattanaik2000 (time-dependent adaptation, the default), "
        "jacobs2015 (gaze-driven adaptation with afterimages, Purkinje shift, mesopic colour "
        "and acuity loss; its frames are display-encoded and dithered, so --encoding does "
        "not apply), or a static tone curve of the HDR-imaging chapter "
        f"({', '.join(TONE_CURVE_NAMES)})",
    )
    render.add_argument(
        "--gaze",
        type=Path,
        default=None,
        metavar="CSV",
        help="gaze recording: rows t,x,y (s, pixels), each held until the next; x,y empty "
        "or nan during a blink, which holds the fixation before it; default: the scene's "
        "own path, the centre of the frame for files",
    )
    render.add_argument(
        "--seed",
        type=_seed,
        default=None,
        help="seed of the random draws of jacobs2015 (acuity noise, dithering); default 0",
    )
    render.add_argument(
        "--background",
        choices=tuple(BACKGROUNDS),
        default="global",
        help="background (adapting) luminance: one per frame, global (the log average, the "
        "default) or arithmetic (the mean), or a local estimate per pixel (box, gaussian, "
        "bilateral, adaptive, multiscale; bilateral's time grows with the square of "
        "--background-scale); with pattanaik2000 a local background gives per-pixel, "
        "time-dependent adaptation",
    )
    render.add_argument(
        "--background-scale",
        type=_positive,
        default=None,
        metavar="PX",
        help="size s of the local background estimator, pixels (default: 8): the box "
        "||p - i|| < s of box (half-width round(s) - 1, so at least 1) and the finest box "
        "of adaptive and multiscale, a Gaussian exp(-d^2/s^2) for gaussian and bilateral",
    )
    render.add_argument(
        "--adaptation-goal",
        choices=GOALS,
        default=None,
        help="how pattanaik2000 finds the adaptation goal of each frame (default: the "
        "scene's own; log_average for files)",
    )
    render.add_argument(
        "--pixels-per-degree",
        type=_pixels_per_degree,
        default=None,
        help="resolution of the frames at the eye, 1e-3 to 1e4: for the foveal goal, and for "
        "jacobs2015's fovea, acuity loss and afterimage blur (default: the scene's own; 30 for "
        "files)",
    )
    render.add_argument(
        "--out",
        type=_folder,
        default=Path("out"),
        help="output folder (default: ./out); what an earlier render wrote there (listed in "
        "its .jaxadapt-render) is replaced, and so is a file with the name of an output of "
        "this one; other files and the inputs are left alone",
    )
    render.add_argument(
        "--format",
        action="append",
        choices=FORMATS,
        default=None,
        dest="formats",
        help="output format, repeatable: png (frames, as --encoding), mp4 (H.264 video, "
        "BT.709, tagged with its encoding; an odd width or height is padded by one edge "
        "pixel, as 4:2:0 needs), exr or pfm (linear display values in [0, 1], one file per "
        "frame; for jacobs2015 its display-encoded J); default: png and mp4",
    )
    render.add_argument(
        "--encoding",
        choices=("srgb", "gamma"),
        default=None,
        help="display encoding of png and mp4 output (default: srgb; gamma is 2.2); not for "
        "jacobs2015, whose display values are its own gamma encoding",
    )
    render.add_argument(
        "--chunk",
        type=int,
        default=None,
        help="frames computed per call (default: as many as --memory allows, at most 32)",
    )
    render.add_argument(
        "--allow-large",
        action="store_true",
        help=f"render even more than {MAX_FRAMES:,} frames, or more than the free space of "
        "--out may hold (refused by default, with the estimate)",
    )
    render.add_argument(
        "--memory",
        type=_memory,
        default=None,
        metavar="SIZE",
        help="memory for frames in flight (read ahead, computed, written behind), e.g. "
        "500M or 2G (default: 1G); it sets the frames per call, which --chunk overrides",
    )
    psychometric = sub.add_parser(
        "psychometric",
        help="analyse constant-stimuli experiments (Jacobs et al. 2015, §4)",
        description="Psychometric analysis of a method-of-constant-stimuli experiment.",
    )
    psy = psychometric.add_subparsers(dest="action", required=True, metavar="ACTION")
    fit = psy.add_parser(
        "fit",
        help="fit cumulative Gaussians per participant and condition, and compare conditions",
        description="Fit P(x) = Phi((x - PSE) / sigma) by maximum likelihood (a probit GLM, "
        "as MATLAB's glmfit in the paper) to every (participant, condition) of a trial "
        "table, with bootstrap intervals for the PSE; compare the conditions' PSEs with the "
        "Wilcoxon rank-sum test. Writes fits.csv, group_test.csv (when the table has the "
        "control condition and another), psychometric.png (Fig. 13) and pse.png (Fig. 14) "
        "into --out.",
    )
    fit.add_argument(
        "trials",
        type=Path,
        metavar="TRIALS.csv",
        help="columns participant, condition, level (log10 relative to the standard), "
        "response (1: test brighter); or level, n_yes, n_total",
    )
    fit.add_argument(
        "--out", type=_folder, default=Path("out"), help="output folder (default ./out)"
    )
    fit.add_argument(
        "--resamples",
        type=int,
        default=1000,
        help="bootstrap resamples per group for the PSE interval (0: Wald interval); default 1000",
    )
    fit.add_argument(
        "--control",
        default=None,
        help="condition the others are compared with (default: control, if the table has it)",
    )
    fit.add_argument("--seed", type=_seed, default=None, help="seed of the bootstrap (default 0)")
    fit.add_argument(
        "--keep-undetermined",
        action="store_true",
        help="write the estimates of groups whose data do not determine the fit (all "
        "answers the same, separation, one level, no slope), which the fit's prior sets, "
        "and enter them in the group test (default: NaN in fits.csv, left out of the test)",
    )
    fit.add_argument(
        "--ranksum",
        choices=("auto", "exact", "asymptotic"),
        default=None,
        help="where the rank-sum test's p comes from: the exact null distribution, the "
        "normal approximation, or auto (default: exact when the smaller group has at most "
        "8 PSEs and none are tied, as SciPy's mannwhitneyu; the paper's p of its two groups "
        "of 11 is the exact one)",
    )
    simulate = psy.add_parser(
        "simulate",
        help="simulate an experiment of the 2015 paper with model observers",
        description="Simulate the afterimage or mesopic experiment of Jacobs et al. (2015, "
        "§4) with model observers drawn from a population: the stimuli are rendered with "
        "the 2015 operator, each observer compares the brightness of test and standard "
        "(log luminance plus weighted cues, with noise, bias and lapses) on every trial of "
        "the paper's design, and observers below 70% correct in training are excluded. "
        "Writes trials.csv (readable by 'jaxadapt psychometric fit'), observers.csv and "
        "stimuli.csv into --out.",
    )
    simulate.add_argument(
        "--protocol",
        required=True,
        metavar="afterimage|mesopic",
        help="the experiment: afterimage (§4.1) or mesopic (§4.2)",
    )
    simulate.add_argument(
        "--observers", type=int, required=True, metavar="N", help="number of observers"
    )
    simulate.add_argument(
        "--weight",
        action="append",
        default=[],
        metavar="CUE=W",
        help="weight of a cue (afterimage, desaturation, blur) in log10 units of "
        "brightness per unit of cue, the same for every observer, repeatable (default: 0, "
        "observers who judge luminance only); e.g. --weight desaturation=-0.1 makes "
        "desaturated tests look darker",
    )
    simulate.add_argument(
        "--seed", type=_seed, default=0, help="seed of the simulation (default 0)"
    )
    simulate.add_argument(
        "--out", type=_folder, default=Path("out"), help="output folder (default ./out)"
    )
    return parser


# -- outputs ------------------------------------------------------------------


# -- the render command -------------------------------------------------------


#: Columns of ``group_test.csv``: each condition against the control.
GROUP_TEST_COLUMNS = (
    "condition",
    "control",
    "median",
    "median_control",
    "shift",
    "rank_biserial",
    "W",
    "z",
    "p",
    "p_exact",
    "n",
    "n_control",
)


@contextlib.contextmanager
def _staged(out, console, replaces=None, keep=()):
    """Yield a staging folder inside ``out``; move its files into ``out`` on success.

    With ``replaces`` (a command's pattern of output names), the names this
    run wrote are listed in its manifest in ``out`` (:data:`MANIFESTS`), and
    on success the files that an earlier run listed there, that match
    ``replaces`` and that this run did not write are removed, so that the
    folder holds one run's outputs; nothing else is, and never a path in
    ``keep`` (this run's inputs). An input in ``out`` with the name of an
    output is refused before anything is done: the run would write over it.
    On any error nothing reaches ``out`` (earlier results stay as they were)
    and the folders made for it are removed. The staging folder is removed
    either way. ``out`` is resolved first: through a ``..`` after a folder
    that does not exist (``new/../out``), the folders made would be other
    than the ones named, and a failed run left ``out`` behind.

    A folder in ``out`` with the name of an output is refused: with
    ``replaces``, before anything is done; otherwise when it is found, as
    the files are moved (before any is). Staging
    folders that runs killed outright (SIGKILL) left in ``out`` are named in
    a warning on ``console``: they may also be those of runs still going.
    A full device is said as such, naming ``out`` (:func:`_out_of_space`).
    Signals are deferred while the staging folder is made, while the files
    are moved and while the folders are removed (:func:`_signals_deferred`),
    so that a signal at any point leaves nothing behind; :data:`_WRITTEN`
    is set once the files are all in place.
    """
    out = out.resolve()
    given = [Path(p) for p in keep]
    keep = {p.resolve() for p in given}
    # An input is in out by its name there (a link in out would be replaced)
    # or by what it names (a link elsewhere to a file in out).
    named = sorted({*keep, *(p.parent.resolve() / p.name for p in given)})
    for path in named:
        if replaces is not None and path.parent == out and replaces.fullmatch(path.name):
            raise UsageError(
                f"{path}: an input in --out named as this command's outputs, which a run "
                "there may write over or remove; choose another --out"
            )
    made = next((p for p in [*reversed(out.parents), out] if not p.exists()), None)

    def unmake():
        if made is not None:
            shutil.rmtree(made, ignore_errors=True)

    if out.exists() and not out.is_dir():
        raise UsageError(f"--out: expected a folder, got the file {out}")
    if replaces is not None and out.is_dir():
        _refuse_folders(out, [p.name for p in out.iterdir() if replaces.fullmatch(p.name)])
    staging = None
    try:
        with _signals_deferred():  # a signal as it is made is raised where it is removed
            staging = _staging_folder(out)
            _remove_dead_staging(out)
        left = sorted(p.name for p in out.glob(f"{STAGING_PREFIX}*") if p.is_dir() and p != staging)
        if left:
            console.print(
                f"warning: {out} holds {', '.join(left)}: the staging folders of runs that were "
                "killed (remove them) or are still running",
                markup=False,
                soft_wrap=True,
            )
        yield staging
        with _signals_deferred():
            if _SIGNALLED:  # an interrupt that Python ignored (_interruptible)
                raise KeyboardInterrupt(_SIGNALLED[0])
            _move_into_place(staging, out, replaces, keep)
            _WRITTEN.set()
    except BaseException as e:
        full = not isinstance(e, UsageError) and _out_of_space(e, out)  # said already
        with _signals_deferred():
            if not _WRITTEN.is_set():
                unmake()
        if full:
            raise UsageError(f"--out: no space left on the device of {out}") from None
        raise
    finally:
        with _signals_deferred():
            if staging is not None:
                shutil.rmtree(staging, ignore_errors=True)


def _staging_folder(out):
    """Make ``out`` (and its parents) and a new staging folder in it, named
    after this process (:func:`_owner`); a UsageError naming ``out`` if it
    cannot be written to."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}{_owner(os.getpid())}-", dir=out))
    except OSError as e:
        raise UsageError(f"--out: cannot write to {out} ({e.strerror or e})") from None


def _owner(pid):
    """``PID.START`` of a running process, its id and the time it started in
    clock ticks since boot (Linux's ``/proc/PID/stat``; ``PID.0`` where there
    is none), so that a later process with the same id is told apart; None
    if no process has that id."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        return f"{pid}.{stat.rpartition(')')[2].split()[19]}"
    except (OSError, IndexError):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return None
        except OSError:
            pass  # it exists, owned by another user
        return f"{pid}.0"


def _remove_dead_staging(out):
    """Remove the staging folders in ``out`` whose run was killed before it
    could clean up (SIGKILL, the OOM killer, a power loss): those whose name
    says a process (:func:`_owner`) that no longer runs. Others, of runs
    still going or of another naming, are left alone."""
    for folder in out.glob(f"{STAGING_PREFIX}*"):
        match = re.fullmatch(rf"{re.escape(STAGING_PREFIX)}(\d+)\.(\d+)-\w+", folder.name)
        if match and folder.is_dir() and _owner(int(match[1])) != f"{match[1]}.{match[2]}":
            shutil.rmtree(folder, ignore_errors=True)


def _out_of_space(error, out):
    """Whether ``error``, raised while writing into ``out``, is a full device
    or quota: by its ``errno``, or, for the writers that give none
    (OpenImageIO, ffmpeg), by less than 1 MiB left on ``out``'s device."""
    if isinstance(error, OSError) and error.errno in (errno.ENOSPC, getattr(errno, "EDQUOT", 0)):
        return True
    if isinstance(error, (OSError, ValueError)):
        with contextlib.suppress(OSError):
            return shutil.disk_usage(out).free < 2**20
    return False


#: Prefix of the staging folders that :func:`_staged` makes in ``--out``.
STAGING_PREFIX = ".jaxadapt-"


def _refuse_folders(out, names):
    """A UsageError if a folder in ``out`` has one of ``names``: only a file
    can be replaced by a file, and a folder in the way would stop the moves
    half-way, the folder holding two runs' outputs."""
    for name in names:
        if (out / name).is_dir():
            raise UsageError(
                f"--out: {out / name} is a folder named as an output of this command; "
                "move it away, or choose another --out"
            )


def _move_into_place(staging, out, replaces, keep):
    """Move the files of ``staging`` into ``out``, with the manifest of
    ``replaces`` and the removal of an earlier run's files (:func:`_staged`)."""
    written = sorted(path.name for path in staging.iterdir())
    earlier = []
    if replaces is not None:
        manifest = MANIFESTS[replaces]
        with contextlib.suppress(OSError, UnicodeDecodeError):
            earlier = (out / manifest).read_text().splitlines()
        (staging / manifest).write_text("".join(f"{name}\n" for name in written))
    names = sorted(path.name for path in staging.iterdir())
    _refuse_folders(out, names)
    for name in names:
        (staging / name).replace(out / name)
    for name in set(earlier) - set(written):
        path = out / name
        if replaces.fullmatch(name) and path.is_file() and path.resolve() not in keep:
            path.unlink()


def _check_options(args):
    """Reject options that the chosen input or operator would ignore."""
    if args.files:
        for option in ("scene", "size", "duration"):
            if getattr(args, option) is not None:
                raise UsageError(f"--{option}: applies to a built-in scene, not to FILE input")
    if args.adaptation_goal is not None and args.operator != "pattanaik2000":
        raise UsageError(
            f"--adaptation-goal: applies to --operator pattanaik2000, not {args.operator}"
        )
    if args.operator == "jacobs2015" and args.background != "global":
        raise UsageError(
            "--background: does not apply to --operator jacobs2015, which adapts to the "
            "foveal luminance and finds local luminance itself"
        )
    if args.operator == "jacobs2015" and args.encoding is not None:
        raise UsageError(
            "--encoding: does not apply to --operator jacobs2015, whose display values are "
            "its own gamma encoding"
        )
    if args.seed is not None and args.operator != "jacobs2015":
        raise UsageError(f"--seed: applies to --operator jacobs2015, not {args.operator}")
    static = args.operator not in ("pattanaik2000", "jacobs2015")
    for option in ("gaze", "pixels_per_degree"):
        if static and getattr(args, option) is not None:
            raise UsageError(
                f"--{option.replace('_', '-')}: does not apply to the static tone curve "
                f"{args.operator}"
            )
    if args.background_scale is not None and args.background in ("global", "arithmetic"):
        raise UsageError(
            f"--background-scale: applies to a local --background, not {args.background}"
        )
    if args.background_scale is not None:
        from jaxadapt.operators.goal import check_background

        try:
            check_background(
                args.background, args.background_scale, ("--background", "--background-scale")
            )
        except ValueError as error:
            raise UsageError(str(error)) from None
    if args.chunk is not None and args.chunk < 1:
        raise UsageError(f"--chunk: expected a positive number of frames, got {args.chunk}")


#: The most frames a render writes without --allow-large: 55 minutes at 30 frames/s.
MAX_FRAMES = 100_000
#: Bytes a pixel of a frame takes at most in each output format (PNG: 8 bits a
#: channel before compression; EXR and PFM: float32; MP4: a generous bound
#: of H.264 at the quality written).
BYTES_PER_PIXEL = {"png": 3, "exr": 12, "pfm": 12, "mp4": 0.1}


def _check_work(frames, shape, formats, out, frames_from):
    """Refuse a render of more than :data:`MAX_FRAMES` frames, or whose
    outputs could outgrow the free space of ``out``'s device (an upper bound
    from :data:`BYTES_PER_PIXEL`): a UsageError with the estimate and the
    option that goes ahead. A render at 1e6 frames/s staged 840,000 files
    in 10 minutes on its way to 80 GB, more than the disk held."""
    H, W = shape
    size = frames * H * W * sum(BYTES_PER_PIXEL[f] for f in formats)
    existing = next(p for p in [out.resolve(), *out.resolve().parents] if p.exists())
    free = shutil.disk_usage(existing).free
    work = f"{frames:,} frames of {W}x{H} as {', '.join(formats)}, up to {_bytes(size)}"
    if frames > MAX_FRAMES:
        raise UsageError(
            f"{frames_from}: the render would write {work}, more than {MAX_FRAMES:,} "
            "frames; render fewer, or pass --allow-large to go ahead"
        )
    if size > free:
        raise UsageError(
            f"--out: the render would write {work}, more than the {_bytes(free)} free on "
            f"the device of {out}; free space, choose another --out or fewer frames, or "
            "pass --allow-large to go ahead"
        )


def _bytes(n):
    """``n`` bytes in the largest unit that keeps a number of at least 1."""
    for unit in ("bytes", "kB", "MB", "GB"):
        if n < 1000:
            return f"{n:.3g} {unit}"
        n /= 1000
    return f"{n:.3g} TB"


def _check_scale_fits(scale, size):
    """Refuse a ``--background-scale`` beyond the larger side of frames of
    ``size (H, W)``, pixels: a window larger than the frame covers the
    mirror-extended frame several times over, and the filters' memory and
    time grow with the scale, not the frame: a scale of 1e9 on a 1x1 frame
    took the machine's 24 GB and was killed, 1e5 on 64x48 took 677 MB and
    17 s."""
    if scale > max(size):
        raise UsageError(
            f"--background-scale: expected at most {max(size)} pixels, the frames' larger "
            f"side, got {scale:g}"
        )


def _files_rate(files):
    """The frame rate of FILEs without ``--fps``
    (:func:`jaxadapt.pipeline.files_rate`), refused outside ``--fps``'s range."""
    from jaxadapt import pipeline

    rate = pipeline.files_rate(files)
    if not FPS_RANGE[0] <= rate <= FPS_RANGE[1]:
        raise UsageError(
            f"{files[0]}: its FramesPerSecond, {rate:g}, is outside {FPS_RANGE[0]:g} to "
            f"{FPS_RANGE[1]:g} frames/s; give --fps"
        )
    return rate


def _source(args):
    from jaxadapt import pipeline
    from jaxadapt.scenes import SCENES

    if args.files:
        return pipeline.from_files(args.files, args.fps or _files_rate(args.files), args.multiplier)
    kwargs = {}
    if args.size is not None:
        kwargs["width"], kwargs["height"] = args.size
    if args.duration is not None:
        kwargs["duration"] = args.duration
    if args.fps is not None:
        kwargs["fps"] = args.fps
    try:
        scene = SCENES[args.scene or "tunnel"](**kwargs)
    except ValueError as error:  # named by the scene's arguments: name the options given
        name, _, rest = str(error).partition(": ")
        given = [o for o, v in (("--duration", args.duration), ("--fps", args.fps)) if v]
        options = {"duration": "--duration", "fps": "--fps", "duration, fps": ", ".join(given)}
        raise UsageError(f"{options.get(name, name)}: {rest}") from None
    return pipeline.from_scene(scene, args.multiplier)


def _warn_numbers_out_of_order(files, console):
    """Warn when the frame numbers in the names of ``files`` (the last run of
    digits, the rest of the names all alike) neither rise nor fall in the
    order given: the frames are rendered in that order, and a shell's glob
    of a sequence numbered without padding gives them sorted as text
    (``f1 f10 f11 f2 ...``). A sequence reversed on purpose goes one way and
    passes."""
    parts = [re.fullmatch(r"(.*?)(\d+)(\D*)", str(f)) for f in files]
    if len(files) < 3 or not all(parts) or len({(m[1], m[3]) for m in parts}) > 1:
        return
    numbers = [int(m[2]) for m in parts]
    steps = np.sign(np.diff(numbers))
    if np.all(steps >= 0) or np.all(steps <= 0):
        return
    i = int(np.argmax(steps == -steps[steps != 0][0]))  # the first step against the first
    console.print(
        f"warning: FILE: {files[i]} comes before {files[i + 1]}: the numbers in the names "
        "neither rise nor fall, and the frames are rendered in the order given (a shell's "
        "glob sorts names as text, 10 before 2: pad the numbers, or list them with ls -v)"
    )


def _warn_gaze_off_frame(source, shape, path, console):
    """Warn when the gaze of ``source`` (recorded in ``path``) leaves frames
    of ``shape`` (H, W): the operators take the nearest point of the frame
    (:func:`jaxadapt.operators.goal.fixation`), and a recording in other
    coordinates (normalised, or a larger screen's) would be held at the
    frame's edges without a word; and when it holds no fixation at all, for
    which the frame's centre is taken."""
    H, W = shape
    x, y = source.gaze(np.arange(len(source.times))).T
    if not np.isfinite(x).any():
        console.print(
            f"warning: --gaze: {path} holds no fixation during the sequence (every sample "
            "before its end is a blink, x and y empty or nan); the frame's centre is taken",
            markup=False,
            soft_wrap=True,
        )
    off = (x < 0) | (x > W - 1) | (y < 0) | (y > H - 1)  # False for a blink's NaN
    if off.any():
        i = int(np.argmax(off))
        console.print(
            f"warning: --gaze: {path} leaves the {W}x{H} frame at {off.sum()} of {off.size} "
            f"frames (first ({x[i]:g}, {y[i]:g}) pixels at {source.times[i]:g} s); there the "
            "nearest point of the frame is taken",
            markup=False,
            soft_wrap=True,
        )


def _operator(args, source, fps):
    """The operator module, its parameters (for frames at ``fps``), the plot of
    its diagnostics and whether its frames come display-encoded."""
    from functools import partial

    from jaxadapt import figures
    from jaxadapt.operators import OPERATORS, classic, jacobs2015, pattanaik2000

    ppd = args.pixels_per_degree or source.pixels_per_degree
    op = OPERATORS[args.operator]
    if op is pattanaik2000:
        goal = args.adaptation_goal or source.goal
        if args.adaptation_goal is not None and args.background != "global":
            raise UsageError(
                f"--adaptation-goal: applies to a global background, not {args.background}, "
                "whose local estimate is each pixel's goal"
            )
        if args.gaze is not None and args.background == "global" and goal != "foveal":
            raise UsageError(
                "--gaze: pattanaik2000 reads the gaze for the foveal adaptation goal or the "
                f"diagnostics of a local background, not for goal {goal} with a global background"
            )
        if args.pixels_per_degree is not None and (goal, args.background) != ("foveal", "global"):
            raise UsageError(
                "--pixels-per-degree: applies to the foveal adaptation goal "
                f"(--adaptation-goal foveal, global background), not goal {goal} "
                f"with a {args.background} background"
            )
        params = op.Params(
            goal=goal,
            pixels_per_degree=ppd,
            background=args.background,
            background_scale=args.background_scale or BACKGROUND_SCALE,
        )
        where = "goal " + goal if args.background == "global" else args.background + " background"
        title = f"{source.name}: Pattanaik et al. 2000, {where}"
        return op, params, partial(figures.plot_adaptation, title=title), False
    if op is jacobs2015:
        title = f"{source.name}: Jacobs et al. 2015, at the gaze point"
        params = op.Params(pixels_per_degree=ppd, afterimage_blur=op.blur_for_display(ppd, fps))
        notes = op.diagnostics_notes(params)
        plot = partial(figures.plot_columns, title=title, units=op.DIAGNOSTIC_UNITS, notes=notes)
        return op, params, plot, True
    params = classic.Params(
        classic.TONE_CURVES[args.operator](),
        args.background,
        args.background_scale or BACKGROUND_SCALE,
    )
    title = f"{source.name}: {args.operator}, {args.background} background"
    plot = partial(figures.plot_columns, title=title, units=classic.DIAGNOSTIC_UNITS)
    return classic, params, plot, False


def render(args, console):
    import jax
    from rich.progress import Progress

    from jaxadapt import display, figures, io, pipeline

    _check_options(args)
    formats = args.formats or ["png", "mp4"]
    source = _source(args)
    _warn_numbers_out_of_order(args.files, console)
    if args.background_scale is not None or args.gaze is not None:
        shape = pipeline.frame_shape(source)
    if args.background_scale is not None:
        _check_scale_fits(args.background_scale, shape)
    if args.gaze is not None:
        source = pipeline.with_gaze(source, args.gaze)
        _warn_gaze_off_frame(source, shape, args.gaze, console)
    # The nominal rate: frames split at a flash's edges are shorter, none longer.
    fps = 1.0 / float(np.max(source.dt))
    if "mp4" in formats and fps < MP4_MIN_FPS:
        raise UsageError(
            f"--fps: a video (--format mp4, a default) needs at least {MP4_MIN_FPS:g} frames/s, "
            f"got {fps:g}; choose --format png, exr or pfm"
        )
    op, params, plot, encoded = _operator(args, source, fps)
    # The 2015 operator's display values J = R^0.455 are a gamma-2.2 encoding.
    encoding = "gamma" if encoded else args.encoding or "srgb"
    code_as = "linear" if encoded else encoding  # (display.ENCODINGS)

    out = args.out
    T = len(source.times)
    digits = max(5, len(str(T - 1)))  # frame files sort in order
    contact_idx = set(range(min(4, T))) | set(
        np.linspace(4, T - 1, CONTACT_FRAMES - 4).round().astype(int) if T > 4 else []
    )
    contact, contact_labels, tables = [], [], []
    inputs = [*args.files, *([args.gaze] if args.gaze else [])]
    with _staged(out, console, RENDER_OUTPUTS, keep=inputs) as staging:
        if not args.allow_large:  # once --out is known to be writable
            frames_from = "FILE" if args.files else "--fps, --duration"
            _check_work(T, pipeline.frame_shape(source), formats, out, frames_from)
        with contextlib.ExitStack() as stack:
            send_video = (
                stack.enter_context(io.video_writer(staging / "video.mp4", fps, encoding))
                if "mp4" in formats
                else (lambda frames: None)
            )
            bar = Progress(console=console, transient=True, disable=not console.is_terminal)
            progress = stack.enter_context(bar)
            task = progress.add_task(f"rendering {source.name}", total=T)

            def write(chunk):
                """Write a chunk's frames (in the write-behind thread)."""
                idx, linear = chunk
                shown = [k for k, i in enumerate(idx) if i in contact_idx]
                coded = None
                if {"png", "mp4"} & set(formats):
                    coded = display.encode_uint8(linear, code_as)
                for k in shown:  # shrunk in linear light, then encoded
                    contact.append(display.encode_uint8(figures.shrink(linear[k]), code_as))
                    contact_labels.append(f"{source.times[idx[k]]:.3g} s")
                for k, i in enumerate(idx):
                    name = f"frame_{i:0{digits}d}"
                    if "png" in formats:
                        io.write_image(staging / f"{name}.png", coded[k], encoding)
                    if "exr" in formats:
                        io.write_image(staging / f"{name}.exr", linear[k], fps=fps)
                    if "pfm" in formats:
                        io.write_image(staging / f"{name}.pfm", linear[k])
                send_video(coded)  # (a no-op without mp4)
                progress.advance(task, len(idx))

            key = jax.random.key(args.seed or 0)
            budget = args.memory or pipeline.MEMORY_BUDGET
            stream = pipeline.chunks(op, params, source, args.chunk, key, budget=budget)
            with contextlib.closing(stream), pipeline.behind(write) as submit:
                for idx, linear, table in stream:
                    submit((idx, linear))
                    tables.append(table)
        table = pipeline.concatenate(tables)
        _warn_bleached(table, console)
        io.write_columns(staging / "diagnostics.csv", table)
        sheet = figures.contact_sheet(np.stack(contact), labels=contact_labels)
        io.write_image(staging / "contact_sheet.png", sheet, encoding)
        plot(staging / "adaptation.png", table)
        names = sorted(path.name for path in staging.iterdir())
    frame_files = [name for name in names if name.startswith("frame_")]
    others = [name for name in names if not name.startswith("frame_")]
    if frame_files:
        others.append(f"{len(frame_files)} frame file{'s' * (len(frame_files) > 1)}")
    _report(
        f"wrote {len(names)} files to {out}/ ({', '.join(others)}) for {T} frame{'s' * (T > 1)}"
    )


#: Unbleached fraction of the cone pigment below which a render warns (:func:`_warn_bleached`).
BLEACHED = 0.01


def _warn_bleached(table, console):
    """Warn when the 2000 operator's diagnostics ``table`` has the cone
    pigment all but bleached (``B_cone`` below :data:`BLEACHED`, adapted
    above about 2e8 cd/m2). Its responses, scaled by ``B_cone`` (Eq 2),
    then span almost nothing, and the appearance model puts the whole frame
    near the display's black (Eq 8; ``pfstmo_pattanaik00`` renders the
    same): the model's prediction, which looks like a failed render, and
    which luminance far above daylight's more often means frames not in
    cd/m2."""
    if "B_cone" not in table:
        return
    B = np.asarray(table["B_cone"])
    bleached = B < BLEACHED
    if bleached.any():
        i = int(np.argmin(B))
        console.print(
            f"warning: at {bleached.sum()} of {B.size} frames the viewer is adapted where the "
            f"cone pigment is over {1 - BLEACHED:.0%} bleached (the most at "
            f"{float(table['t'][i]):g} s, adapted to {float(table['A_cone'][i]):.3g} cd/m2): "
            "the 2000 model renders such frames near the display's black, as "
            "pfstmo_pattanaik00 does; frames not in cd/m2 take --multiplier",
            markup=False,
            soft_wrap=True,
        )


def _group_tests(table, control, method):
    """The rows of ``group_test.csv``: each condition's PSEs against the
    ``control``'s (:func:`jaxadapt.psychophysics.stats.compare`), none when
    the table has no such condition. PSEs that are NaN (the data place
    none) are left out."""
    import jax.numpy as jnp

    from jaxadapt.psychophysics import stats

    condition = np.asarray(table.condition)
    placed = np.isfinite(table.pse)  # NaN: the data place no PSE (trials.undetermined)
    pse = np.where(placed, table.pse, 0.0)
    rows = []
    for other in dict.fromkeys(table.condition):
        if other == control or control not in condition:
            continue
        x, y = condition == other, condition == control
        c = stats.compare(
            jnp.asarray(pse[x]),
            jnp.asarray(pse[y]),
            x_mask=jnp.asarray(placed[x]),
            y_mask=jnp.asarray(placed[y]),
            method=method,
        )
        rows.append(
            {
                "condition": other,
                "control": control,
                "median": float(c.median_x),
                "median_control": float(c.median_y),
                "shift": float(c.shift),
                "rank_biserial": float(c.rank_biserial),
                "W": float(c.test.statistic),
                "z": float(c.test.z),
                "p": float(c.test.p),
                "p_exact": "true" if bool(c.test.exact) else "false",
                "n": int(c.test.n_x),
                "n_control": int(c.test.n_y),
            }
        )
    return rows


def psychometric_fit(args, console):
    """``jaxadapt psychometric fit``: fits, group tests and figures into ``--out``."""
    import jax
    from rich.progress import Progress

    from jaxadapt import figures, io
    from jaxadapt.psychophysics import stats, trials

    if args.resamples < 0 or args.resamples == 1:
        raise UsageError(
            f"--resamples: expected 0 (a Wald interval) or at least 2, got {args.resamples}"
        )
    if args.seed is not None and args.resamples == 0:
        raise UsageError("--seed: seeds the bootstrap, which --resamples 0 leaves out")
    trial_table = trials.read_trials(args.trials)
    conditions = list(dict.fromkeys(trial_table.condition))
    if args.control is not None and args.control not in conditions:
        raise UsageError(
            f"--control: expected one of the conditions of {args.trials} "
            f"({', '.join(map(str, conditions))}), got {args.control!r}"
        )
    control = args.control or "control"
    groups = trials.group_trials(trial_table)
    tested = [c for c in conditions if c != control] if control in conditions else []
    if not tested:
        no_test = (
            f"no group test: {args.trials} has one condition, {conditions[0]!r}; "
            "a group test compares two"
            if len(conditions) == 1
            else f"no group test: {args.trials} has no condition {control!r} to compare with "
            f"(conditions: {', '.join(map(str, conditions))}); name one with --control"
        )
        if args.ranksum is not None:
            raise UsageError(f"--ranksum: applies to the group test, and there is none ({no_test})")
        console.print(no_test)
    method = args.ranksum or "auto"
    size = {c: groups.condition.count(c) for c in conditions}
    for c in tested if method == "exact" else ():
        too_large = stats.exact_too_large(size[c], size[control])
        if too_large:
            raise UsageError(
                f"--ranksum exact: {too_large}; use --ranksum asymptotic (at these sizes the "
                "normal approximation is close)"
            )
    out = args.out
    written = ["fits.csv", "group_test.csv", "psychometric.png", "pse.png"]
    if not tested:
        written.remove("group_test.csv")
    with _staged(out, console, FIT_OUTPUTS, keep=[args.trials]) as staging:
        # In float64, as statsmodels and MATLAB fit: in float32 the
        # log-likelihood of a few thousand trials a level is off by 0.01
        # (binomial terms that cancel), and its fits stop at slopes whose
        # rounding matters; the group test's normal tail 2 Phi(-|z|) is 0 in
        # float32 from z = 13.
        bar = Progress(console=console, transient=True, disable=not console.is_terminal)
        with jax.enable_x64(True), bar:
            count = len(groups.participant)
            task = bar.add_task(f"fitting {count} group{'s' * (count > 1)}", total=count)
            key = jax.random.key(args.seed or 0)
            table = trials.fit_groups(
                groups,
                key=key,
                n_resamples=args.resamples,
                progress=lambda done: bar.advance(task, done),
                keep_undetermined=args.keep_undetermined,
            )
            rows = _group_tests(table, control, method)
        _warn_undetermined(console, groups, table, args.keep_undetermined, bool(rows))
        trials.write_fits(staging / "fits.csv", table)
        if rows:
            with open(staging / "group_test.csv", "w", newline="") as f:
                writer = io.csv_writer(f, GROUP_TEST_COLUMNS)
                writer.writeheader()
                writer.writerows(rows)
        figures.plot_psychometric(staging / "psychometric.png", groups, table)
        figures.plot_pse(staging / "pse.png", table, rows)
    for row in rows:
        _report(
            f"{row['condition']} vs {row['control']}: median PSE {_signed(row['median'])} vs "
            f"{_signed(row['median_control'])} log units, rank-sum p = {row['p']:.3g} "
            f"({'exact' if row['p_exact'] == 'true' else 'normal approximation'}; "
            f"n = {row['n']}, {row['n_control']})"
        )
    _report(f"wrote {', '.join(written)} to {out}/")


def _signed(value, digits=3):
    """``value`` with its sign and ``digits`` decimals, 0 as ``+0.000`` (not ``-0.000``)."""
    return f"{round(value, digits) + 0.0:+.{digits}f}"


#: Groups named one by one in the warnings of :func:`_warn_undetermined`: a
#: table of 10,000 groups wrote thousands of lines.
MAX_GROUP_WARNINGS = 10


def _warn_undetermined(console, groups, table, kept, tested):
    """Say which groups' data do not determine their fit: those that place
    no PSE (every response the same, one level, or no slope) and those whose
    levels separate the responses, whose PSE lies somewhere between two
    levels (:func:`~jaxadapt.psychophysics.trials.fit_groups`); and whether
    the group test (``tested``) left them out or, with
    ``--keep-undetermined`` (``kept``), took the fit's prior-set PSEs."""
    from jaxadapt.psychophysics import fit as psyfit
    from jaxadapt.psychophysics.trials import undetermined

    flags = np.asarray(table.flags)
    written = "are its prior's, not the data's" if kept else "are NaN"
    groups_open = np.flatnonzero(undetermined(flags))
    if len(groups_open) > MAX_GROUP_WARNINGS:
        console.print(
            f"warning: the data of {len(groups_open)} groups do not determine their fit; "
            f"the first {MAX_GROUP_WARNINGS} follow, the flags of all are in fits.csv"
        )
    for i in groups_open[:MAX_GROUP_WARNINGS]:
        who = f"participant {table.participant[i]}, condition {table.condition[i]}"
        low, high = table.pse_low[i], table.pse_high[i]
        if flags[i] & psyfit.NO_PSE:
            why = ", ".join(psyfit.flag_names(int(flags[i])))
            if np.isinf(low) and np.isinf(high):
                said = f"the data place no PSE ({why})"
            else:
                side = f"below {high:+.3g}" if np.isinf(low) else f"above {low:+.3g}"
                said = f"the data place the PSE only {side} log units ({why})"
        elif low < high:
            said = (
                "the levels separate the 'no' from the 'yes' responses, so the data place "
                f"the PSE only between {low:+.3g} and {high:+.3g} log units and bound sigma "
                f"below {table.sigma_max[i]:.3g}"
            )
        else:
            said = (
                f"the responses change at one level, {low:+.3g} log units (one answer on "
                "either side of it: quasi-complete separation), and bound sigma below "
                f"{table.sigma_max[i]:.3g} without fixing it"
            )
        console.print(
            f"warning: {who}: {said}; its PSE and slope in fits.csv {written}", soft_wrap=True
        )
    left_out = int(np.sum(~np.isfinite(table.pse)))
    if tested and left_out:
        console.print(
            f"the group test leaves out the {left_out} group{'s' * (left_out > 1)} whose data "
            "place no PSE (--keep-undetermined enters their prior-set PSEs)",
            soft_wrap=True,
        )


def _weights(items, cues):
    """``--weight CUE=W`` options as a weight per cue (0 where not given)."""
    weights, given = dict.fromkeys(cues, 0.0), set()
    for item in items:
        name, _, value = item.partition("=")
        if name.strip() not in weights:
            raise UsageError(
                f"--weight: expected CUE=W with CUE one of {', '.join(cues)}, got {item!r}"
            )
        if name.strip() in given:
            raise UsageError(f"--weight: expected each cue once, got {name.strip()} again")
        given.add(name.strip())
        try:
            weights[name.strip()] = float(value)
        except ValueError:
            raise UsageError(f"--weight: expected a number after '=', got {item!r}") from None
        if not np.isfinite(weights[name.strip()]):
            raise UsageError(f"--weight: expected a finite number, got {item!r}")
    return list(weights.values())


def psychometric_simulate(args, console):
    """``jaxadapt psychometric simulate``: a simulated experiment into ``--out``."""
    import dataclasses

    import jax

    from jaxadapt import io
    from jaxadapt.psychophysics import design
    from jaxadapt.psychophysics import observer as obs
    from jaxadapt.psychophysics.trials import csv_cell

    if args.protocol not in design.PROTOCOLS:
        raise UsageError(
            f"--protocol: expected one of {', '.join(design.PROTOCOLS)}, got {args.protocol!r}"
        )
    if args.observers < 1:
        raise UsageError(f"--observers: expected a positive number, got {args.observers}")
    protocol = design.PROTOCOLS[args.protocol]
    population = dataclasses.replace(
        obs.POPULATIONS[args.protocol], weights=_weights(args.weight, obs.CUES)
    )
    # --out is checked (and staged) before the minutes of simulating
    with _staged(args.out, console) as staging:
        render_key, simulate_key = jax.random.split(jax.random.key(args.seed))
        stimuli = obs.render_stimuli(protocol, key=render_key)
        experiment = obs.simulate(simulate_key, protocol, stimuli, population, args.observers)
        pse = np.asarray(jax.vmap(lambda o: obs.true_pse(stimuli, o))(experiment.observers))
        observers = {
            "participant": obs.participant_names(args.observers),
            **{
                name: np.asarray(getattr(experiment.observers, name))
                for name in ("noise", "bias", "order_bias", "lapse")
            },
            **{
                f"weight_{cue}": np.asarray(experiment.observers.weights[:, i])
                for i, cue in enumerate(obs.CUES)
            },
            **{f"pse_{c}": pse[:, i] for i, c in enumerate(protocol.conditions)},
            "excluded": np.asarray(experiment.excluded),
        }
        d_lum, d_cues = (np.asarray(a) for a in stimuli.differences())
        n_rows = obs.write_trials(staging / "trials.csv", protocol, experiment)
        with open(staging / "observers.csv", "w", newline="") as f:
            writer = io.csv_writer(f)
            writer.writerow(observers)
            for row in zip(*observers.values(), strict=True):
                writer.writerow([csv_cell(v) for v in row])
        with open(staging / "stimuli.csv", "w", newline="") as f:
            writer = io.csv_writer(f)
            writer.writerow(
                ["condition", "level", "d_log_luminance", *(f"d_{c}" for c in obs.CUES)]
            )
            for c, condition in enumerate(protocol.conditions):
                for i, level in enumerate(protocol.levels):
                    cells = [level, d_lum[c, i], *d_cues[c, i]]
                    writer.writerow([condition, *(csv_cell(v) for v in cells)])
    excluded = int(np.sum(experiment.excluded))
    _report(
        f"{args.protocol}: {args.observers} observers, {excluded} excluded (training below "
        f"{protocol.exclusion:.0%} correct); wrote trials.csv ({n_rows} trials), "
        f"observers.csv, stimuli.csv to {args.out}/"
    )


def main(argv=None):
    """Run the command of ``argv`` (by default the command line's); return its
    exit status. Signals interrupt it from the parsing of its arguments to
    its last line (:func:`_interruptible`): the one line of
    :data:`~jaxadapt._program.INTERRUPTED` and the shell's status,
    128 + the signal; 0 once the outputs are all in place."""
    try:
        with _interruptible():
            return _command(argv)
    except KeyboardInterrupt as e:
        if _WRITTEN.is_set():  # only a handler restored after the run can raise here
            return 0
        with contextlib.suppress(OSError):  # a terminal closed (SIGHUP) cannot be written to
            print(INTERRUPTED, file=sys.stderr)
        return 128 + (e.args[0] if e.args else signal.SIGINT)


def _command(argv):
    """Parse ``argv`` and run its command; its errors as one line and status 2."""
    from rich.console import Console

    parser = build_parser()
    args = parser.parse_args(argv)
    runtime.retain_freed_memory()  # buffers of later chunks reuse pages (jaxadapt.runtime)
    runtime.cache_compilations()  # later runs reuse this one's compiled programs
    # Warnings and progress on stderr, never wrapped inside a number or a path
    console = Console(stderr=True, soft_wrap=True)
    import equinox as eqx
    import jax

    if _SIGNALLED:  # an interrupt that a garbage-collector callback swallowed
        raise KeyboardInterrupt(_SIGNALLED[0])
    try:
        if args.command == "render":
            render(args, console)
        elif args.command == "psychometric" and args.action == "simulate":
            psychometric_simulate(args, console)
        elif args.command == "psychometric":
            psychometric_fit(args, console)
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
    return 0


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
    take_signals(lambda signum, frame: _SIGNALLED.append(signum))  # main's restore these
    status = main()
    sys.stdout.flush()
    sys.stderr.flush()
    if _SIGNALLED:
        os._exit(status)
    sys.exit(status)


def _report(line):
    """Print a line of a command's result (what it wrote, the group test) on
    stdout, as Unix tools do: warnings, progress and errors go to stderr."""
    print(line, flush=True)


def _smaller(args):
    """What to make smaller when the command of ``args`` runs out of memory."""
    if args.command == "render":
        return "a smaller --chunk, --size or --background-scale"
    return {"fit": "fewer --resamples", "simulate": "fewer --observers"}[args.action]


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
    the body has completed (an error of the body goes first). Moving the
    files of a long render into ``--out`` takes a while, and an interrupt
    in it left some of the outputs of the new run beside the rest of the
    old one's; one in the removal of a staging folder left the folder. Once
    the outputs are all in place (:data:`_WRITTEN`) the run has succeeded,
    and a signal held back is dropped."""
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

    By default SIGTERM and SIGHUP end Python at once and the staging folder would stay
    in ``--out``; raised as an interrupt, the run cleans up as a failed one.
    Python ignores (and prints) an exception raised while it runs a
    garbage-collector callback, as JAX's is: a render went on to the end
    after such a SIGTERM. So :func:`_staged` also checks :data:`_SIGNALLED`
    before it moves anything into place. Only the main thread can set
    signal handlers; elsewhere the signals keep their own. A signal the
    process was started ignoring (``nohup`` ignores SIGHUP) stays ignored.
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


def _message(error):
    """The one line that says what went wrong (:func:`jaxadapt.operators.checks.error_message`)."""
    from jaxadapt.operators.checks import error_message

    return error_message(error)


if __name__ == "__main__":
    run()
