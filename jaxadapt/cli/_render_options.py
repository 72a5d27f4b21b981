"""The options of ``jaxadapt render``, as data in the order ``--help`` lists
them, and the checks of their combinations that argparse cannot make."""

import shutil
from pathlib import Path

from jaxadapt.cli._options import (
    UsageError,
    _default_sizes,
    _folder_or_url,
    _frame_rate,
    _memory,
    _pixels_per_degree,
    _positive,
    _seed,
    _size,
)

# The options as (flags, add_argument keywords), in the order --help lists them.
# Those naming a registry's entries import it when the parser is built, so that
# the program's start-up imports stay light.


def _input_options():
    """The options of the input: FILEs or a built-in scene, its rate and calibration."""
    from jaxadapt.scenes import SCENES

    return (
        (
            ("files",),
            dict(
                nargs="*",
                metavar="FILE",
                help="HDR input (EXR, Radiance HDR, PFM, float TIFF): one image, or the frames "
                "of a sequence in order (e.g. a shell glob of a numbered sequence); or one "
                "video (HDR10, HLG or SDR; MP4, MKV, MOV, ...), its frames timed by their stamps; "
                "local paths or URLs (s3://bucket/f_*.exr, read through fsspec)",
            ),
        ),
        (
            ("--replay",),
            dict(
                type=Path,
                default=None,
                metavar="DIR",
                help="instead of FILE or a scene, a session recorded by jaxadapt view --record "
                "DIR: its frames exactly as the viewer showed them (png, mp4), a contact sheet, "
                "diagnostics.csv (time, dt, gaze, adaptation) and its plot; the record fixes "
                "the input, size, operator, effects and seed",
            ),
        ),
        (
            ("--scene",),
            dict(
                choices=sorted(SCENES),
                default=None,
                help="built-in scene when no FILE is given (default: tunnel)",
            ),
        ),
        (
            ("--size",),
            dict(
                type=_size,
                default=None,
                metavar="WxH",
                help=f"frame size of the built-in scene (default: {_default_sizes(SCENES)}; "
                "files keep their own)",
            ),
        ),
        (
            ("--duration",),
            dict(
                type=_positive,
                default=None,
                metavar="S",
                help="length of the built-in scene in seconds (default: the scene's own)",
            ),
        ),
        (
            ("--fps",),
            dict(
                type=_frame_rate,
                default=None,
                help="frames per second, 1e-5 to 1e6 (default: for FILEs the first file's "
                "FramesPerSecond (an EXR's framesPerSecond), else 30; the scene's own "
                "for a built-in scene: 30, or one frame per 30 ms for title-step; the flash "
                "scene adds a frame where the flash starts or ends between two, so that the "
                "simulation holds it for exactly 1/8 s: the outputs show these frames too, at "
                "the same rate)",
            ),
        ),
        (
            ("--multiplier",),
            dict(
                type=_positive,
                default=1.0,
                help="multiply input values by this to calibrate them to cd/m2 (default: 1; "
                "SDR video is read at a white of 100 cd/m2 before it)",
            ),
        ),
        (
            ("--video-transfer",),
            dict(
                choices=("pq", "hlg", "bt709"),
                default=None,
                help="a video's transfer, where its tags are missing or wrong (default: its tags)",
            ),
        ),
        (
            ("--video-primaries",),
            dict(
                choices=("bt709", "bt2020"),
                default=None,
                help="a video's primaries, where its tags are missing or wrong (default: its "
                "tags; untagged: bt2020 for PQ and HLG, bt709 for SDR)",
            ),
        ),
        (
            ("--hlg-peak",),
            dict(
                type=_positive,
                default=None,
                metavar="CD",
                help="the display peak an HLG video is shown at, cd/m2 (default: 1000, "
                "ITU-R BT.2100's reference)",
            ),
        ),
    )


def _operator_options():
    """The options of the operator, its gaze input and its random draws."""
    from jaxadapt.operators import OPERATORS, TONE_CURVE_NAMES

    return (
        (
            ("--operator",),
            dict(
                choices=list(OPERATORS),
                default="pattanaik2000",
                help="the operator: pattanaik2000 (time-dependent adaptation, the default), "
                "jacobs2015 (gaze-driven adaptation with afterimages, Purkinje shift, mesopic "
                "colour and acuity loss; its frames are display-encoded and dithered, so "
                "--encoding does not apply), or a static tone curve of the HDR-imaging chapter "
                f"({', '.join(TONE_CURVE_NAMES)})",
            ),
        ),
        (
            ("--gaze",),
            dict(
                type=Path,
                default=None,
                metavar="CSV",
                help="gaze recording: rows t,x,y (s, pixels), each held until the next; x,y "
                "empty or nan during a blink, which holds the fixation before it; default: the "
                "scene's own path, the centre of the frame for files",
            ),
        ),
        (
            ("--seed",),
            dict(
                type=_seed,
                default=None,
                help="seed of the random draws of jacobs2015 (acuity noise, dithering); default 0",
            ),
        ),
    )


def _adaptation_options():
    """The options of the adapting background and the adaptation goal."""
    from jaxadapt.background import BACKGROUNDS
    from jaxadapt.operators.goal import GOALS

    return (
        (
            ("--background",),
            dict(
                choices=tuple(BACKGROUNDS),
                default="global",
                help="background (adapting) luminance: one per frame, global (the log "
                "average, the default) or arithmetic (the mean), or a local estimate per pixel "
                "(box, gaussian, bilateral, adaptive, multiscale; bilateral's time grows with "
                "the square of --background-scale); with pattanaik2000 a local background "
                "gives per-pixel, time-dependent adaptation",
            ),
        ),
        (
            ("--background-scale",),
            dict(
                type=_positive,
                default=None,
                metavar="PX",
                help="size s of the local background estimator, pixels (default: 8): the box "
                "||p - i|| < s of box (half-width ceil(s) - 1, the largest whole offset below "
                "s) and the finest box of adaptive and multiscale, a Gaussian exp(-d^2/s^2) "
                "for gaussian and bilateral",
            ),
        ),
        (
            ("--adaptation-goal",),
            dict(
                choices=GOALS,
                default=None,
                help="how pattanaik2000 finds the adaptation goal of each frame (default: the "
                "scene's own; log_average for files)",
            ),
        ),
        (
            ("--pixels-per-degree",),
            dict(
                type=_pixels_per_degree,
                default=None,
                help="resolution of the frames at the eye, 1e-3 to 1e4: for the foveal goal, "
                "and for jacobs2015's fovea, acuity loss and afterimage blur (default: the "
                "scene's own; 30 for files)",
            ),
        ),
    )


FORMATS = ("png", "mp4", "exr", "pfm")


#: The most frames a render writes without --allow-large: 55 minutes at 30 frames/s.
MAX_FRAMES = 100_000


_OUTPUT_OPTIONS = (
    (
        ("--out",),
        dict(
            type=_folder_or_url,
            default=Path("out"),
            help="output folder (default: ./out), or a URL of one (s3://bucket/run, written "
            "through fsspec); what an earlier render wrote there (listed "
            "in its .jaxadapt-render) is replaced, and so is a file with the name of an output "
            "of this one; other files and the inputs are left alone",
        ),
    ),
    (
        ("--format",),
        dict(
            action="append",
            choices=FORMATS,
            default=None,
            dest="formats",
            help="output format, repeatable: png (frames, as --encoding), mp4 (H.264 video, "
            "BT.709, tagged with its encoding; an odd width or height is padded by one edge "
            "pixel, as 4:2:0 needs), exr or pfm (linear display values in [0, 1], one file "
            "per frame; for jacobs2015 its display-encoded J); default: png and mp4",
        ),
    ),
    (
        ("--encoding",),
        dict(
            choices=("srgb", "gamma"),
            default=None,
            help="display encoding of png and mp4 output (default: srgb; gamma is 2.2); not "
            "for jacobs2015, whose display values are its own gamma encoding",
        ),
    ),
    (
        ("--video-codec",),
        dict(
            choices=("h264", "hevc"),
            default=None,
            help="codec of the mp4 output (default: h264; hevc is smaller at the same "
            "quality, for players that decode it)",
        ),
    ),
    (
        ("--chunk",),
        dict(
            type=int,
            default=None,
            help="frames computed per call (default: as many as --memory allows, at most 32)",
        ),
    ),
    (
        ("--allow-large",),
        dict(
            action="store_true",
            help=f"render even more than {MAX_FRAMES:,} frames, or more than the free space "
            "of --out may hold (refused by default, with the estimate)",
        ),
    ),
    (
        ("--memory",),
        dict(
            type=_memory,
            default=None,
            metavar="SIZE",
            help="memory for frames in flight (read ahead, computed, written behind), e.g. "
            "500M or 2G (default: 1G); it sets the frames per call, which --chunk overrides",
        ),
    ),
)


def _check_options(args):
    """Reject options that the chosen input or operator would ignore."""
    if args.files:
        for option in ("scene", "size", "duration"):
            if getattr(args, option) is not None:
                raise UsageError(f"--{option}: applies to a built-in scene, not to FILE input")
    from jaxadapt.operators import OPERATORS

    name, supports = args.operator, OPERATORS.supports(args.operator)
    # (option, whether given, the capability that takes it), in the order checked
    for option, given, capability in (
        ("adaptation_goal", args.adaptation_goal is not None, "adaptation_goal"),
        ("background", args.background != "global", "local_background"),
        ("encoding", args.encoding is not None, "encoding"),
        ("seed", args.seed is not None, "seed"),
        ("gaze", args.gaze is not None, "gaze"),
        ("pixels_per_degree", args.pixels_per_degree is not None, "time_dependent"),
    ):
        if not given or getattr(supports, capability):
            continue
        flag = f"--{option.replace('_', '-')}"
        if not supports.time_dependent and option in ("gaze", "pixels_per_degree"):
            raise UsageError(f"{flag}: does not apply to the static tone curve {name}")
        if option in supports.why_not:
            raise UsageError(
                f"{flag}: does not apply to --operator {name}, {supports.why_not[option]}"
            )
        having = ", ".join(OPERATORS.having(capability))
        raise UsageError(f"{flag}: applies to --operator {having}, not {name}")
    if args.background_scale is not None and args.background in ("global", "arithmetic"):
        raise UsageError(
            f"--background-scale: applies to a local --background, not {args.background}"
        )
    if args.background_scale is not None:
        from jaxadapt.background import check_background

        try:
            check_background(
                args.background, args.background_scale, ("--background", "--background-scale")
            )
        except ValueError as error:
            raise UsageError(str(error)) from None
    if args.chunk is not None and args.chunk < 1:
        raise UsageError(f"--chunk: expected a positive number of frames, got {args.chunk}")
    if args.video_codec is not None and args.formats and "mp4" not in args.formats:
        raise UsageError(
            f"--video-codec: applies to mp4 output, not --format {', '.join(args.formats)}"
        )


#: Bytes a pixel of a frame takes at most in each output format (PNG: 8 bits a
#: channel before compression; EXR and PFM: float32; MP4: a generous bound
#: of H.264 at the quality written).
BYTES_PER_PIXEL = {"png": 3, "exr": 12, "pfm": 12, "mp4": 0.1}


def _check_work(frames, shape, formats, out, frames_from):
    """Refuse a render of more than :data:`MAX_FRAMES` frames, or whose
    outputs could outgrow the free space of ``out``'s device (an upper bound
    from :data:`BYTES_PER_PIXEL`): a UsageError with the estimate and the
    option that goes ahead, so that a mistaken rate or length fails at once
    instead of filling the disk."""
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
    time grow with the scale, not the frame, up to exhausting the machine's
    memory."""
    if scale > max(size):
        raise UsageError(
            f"--background-scale: expected at most {max(size)} pixels, the frames' larger "
            f"side, got {scale:g}"
        )
