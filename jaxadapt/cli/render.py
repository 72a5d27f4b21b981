"""``jaxadapt render``: HDR frames or a built-in scene through an operator,
streamed to display frames, a video, a contact sheet, a plot and
``diagnostics.csv``."""

import contextlib
import re

import numpy as np

from jaxadapt.cli import _replay
from jaxadapt.cli._frames import FrameOutputs
from jaxadapt.cli._options import COMMANDS, FPS_RANGE, MP4_MIN_FPS, UsageError
from jaxadapt.cli._output import _report, _video_and_progress
from jaxadapt.cli._render_options import (
    _OUTPUT_OPTIONS,
    _adaptation_options,
    _check_options,
    _check_scale_fits,
    _check_work,
    _input_options,
    _operator_options,
)
from jaxadapt.cli._staging import RENDER_OUTPUTS, _staged

__all__ = [
    "add_parser",
    "BACKGROUND_SCALE",
    "render",
    "BLEACHED",
]


def add_parser(sub):
    """Declare ``jaxadapt render`` and its options on the subparsers ``sub``."""
    parser = sub.add_parser(
        "render",
        help=COMMANDS["render"],
        description="Tone-map an HDR frame sequence (absolute cd/m2) the way an observer "
        "whose eyes adapt over time would see it on an ordinary display (Pattanaik et al. "
        "2000), or with one of the classic tone curves (--operator). With no FILE, renders "
        "a built-in scene. Writes display frames, a contact sheet, a plot of the adaptation "
        "state and diagnostics.csv into --out.",
    )
    for flags, kwargs in (
        *_input_options(),
        *_operator_options(),
        *_adaptation_options(),
        *_OUTPUT_OPTIONS,
    ):
        parser.add_argument(*flags, **kwargs)
    parser.set_defaults(run=render)


#: Size of a local background estimator unless --background-scale says otherwise, pixels.
BACKGROUND_SCALE = 8.0


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
    (:func:`jaxadapt.gaze.fixation`), and a recording in other
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
    """The operator module, its parameters (for frames at ``fps``) and the
    plot of its diagnostics. Each module's parameters are made here from the
    options (the checks of which options an operator takes, from the
    registry, are :func:`_check_options`')."""
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
        return (
            op,
            params,
            partial(
                figures.plot_adaptation, title=title, curve_log10_luminance=op.CURVE_LOG10_LUMINANCE
            ),
        )
    if op is jacobs2015:
        title = f"{source.name}: Jacobs et al. 2015, at the gaze point"
        params = op.Params(pixels_per_degree=ppd, afterimage_blur=op.blur_for_display(ppd, fps))
        notes = op.diagnostics_notes(params)
        plot = partial(figures.plot_columns, title=title, units=op.DIAGNOSTIC_UNITS, notes=notes)
        return op, params, plot
    params = classic.Params(
        classic.TONE_CURVES[args.operator](),
        args.background,
        args.background_scale or BACKGROUND_SCALE,
    )
    title = f"{source.name}: {args.operator}, {args.background} background"
    plot = partial(figures.plot_columns, title=title, units=classic.DIAGNOSTIC_UNITS)
    return classic, params, plot


def render(args, console):
    """``jaxadapt render``: check, stream the frames through the operator with
    their outputs written behind, then the diagnostics, sheet and plot."""
    import jax

    from jaxadapt import io, pipeline

    if args.replay is not None:
        options = (*_input_options(), *_operator_options(), *_adaptation_options())
        _replay.check(args, (*options, *_OUTPUT_OPTIONS))
        _replay.render(args, console)
        return
    source, formats, fps = _prepared(args, console)
    from jaxadapt.operators import OPERATORS

    op, params, plot = _operator(args, source, fps)
    encoded = OPERATORS.supports(args.operator).display_encoded
    # The 2015 operator's display values J = R^0.455 are a gamma-2.2 encoding.
    encoding = "gamma" if encoded else args.encoding or "srgb"
    out, T, tables = args.out, len(source.times), []
    inputs = [*args.files, *([args.gaze] if args.gaze else [])]
    with _staged(out, console, RENDER_OUTPUTS, keep=inputs) as staging:
        if not args.allow_large:  # once --out is known to be writable
            frames_from = "FILE" if args.files else "--fps, --duration"
            _check_work(T, pipeline.frame_shape(source), formats, out, frames_from)
        with contextlib.ExitStack() as stack:
            send_video, advance = _video_and_progress(
                stack, staging, formats, fps, encoding, console, (f"rendering {source.name}", T)
            )
            write = FrameOutputs(
                staging, formats, source.times, fps, (encoding, encoded), send_video, advance
            )
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
        write.contact_sheet(op.log_adaptation(table))
        plot(staging / "adaptation.png", table)
        names = sorted(path.name for path in staging.iterdir())
    frame_files = [name for name in names if name.startswith("frame_")]
    others = [name for name in names if not name.startswith("frame_")]
    if frame_files:
        others.append(f"{len(frame_files)} frame file{'s' * (len(frame_files) > 1)}")
    _report(
        f"wrote {len(names)} files to {out}/ ({', '.join(others)}) for {T} frame{'s' * (T > 1)}"
    )


def _prepared(args, console):
    """The checked options' source of frames (with ``--gaze``), output formats
    and nominal frame rate (frames/s), with their warnings said."""
    from jaxadapt import pipeline

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
    return source, formats, fps


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
