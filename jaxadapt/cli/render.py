"""``jaxadapt render``: HDR frames or a built-in scene through an operator,
streamed to display frames, a video, a contact sheet, a plot and
``diagnostics.csv``."""

import contextlib
import re
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from jaxadapt.cli import _replay
from jaxadapt.cli._frames import FrameOutputs
from jaxadapt.cli._options import (
    CLUSTER_OPTIONS,
    COMMANDS,
    FPS_RANGE,
    MP4_MIN_FPS,
    UsageError,
    check_cluster_options,
)
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
from jaxadapt.cli._shards import Work, in_shards, joined_parts, tidied
from jaxadapt.cli._staging import RENDER_OUTPUTS, _staged_shared, shared_names

__all__ = [
    "add_parser",
    "Plan",
    "SETTING_OPTIONS",
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
        *CLUSTER_OPTIONS,
    ):
        parser.add_argument(*flags, **kwargs)
    parser.set_defaults(run=render)


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


def _is_video(files):
    """Whether the FILEs are a video."""
    from jaxadapt import io

    return any(io.is_video(f) for f in files)


def _write_video_record(path, args):
    """``source.json``: what the video FILE says of itself (its stream's
    codec, size, rate, colour tags as FFmpeg's codes and as read, HDR10's
    mastering metadata; :class:`~jaxadapt.io.VideoInfo`) and the light its
    signal was decoded to."""
    import dataclasses
    import json

    from jaxadapt import io

    info = io.probe_video(args.files[0], args.video_transfer, args.video_primaries)
    decoded = {"units": "cd/m2, linear BT.709 RGB", "multiplier": args.multiplier}
    if info.transfer == "hlg":
        decoded["hlg_peak"] = args.hlg_peak or io.HLG_PEAK
    elif info.transfer == "bt709":
        decoded["sdr_white"] = io.SDR_WHITE
    record = {**dataclasses.asdict(info), "decoded_to": decoded}
    path.write_text(json.dumps(record, indent=2) + "\n")


def _source(args):
    """The :class:`~jaxadapt.pipeline.Source` of FILEs (their headers read,
    no pixel) or of the built-in scene the options describe."""
    from jaxadapt import io, pipeline
    from jaxadapt.scenes import SCENES

    video = [f for f in args.files if io.is_video(f)]  # (more than one is refused below)
    options = {"--video-transfer": args.video_transfer, "--video-primaries": args.video_primaries}
    given = [o for o, v in (*options.items(), ("--hlg-peak", args.hlg_peak)) if v is not None]
    if given and not video:
        raise UsageError(f"{given[0]}: applies to a video FILE")
    if video:
        if len(args.files) > 1:
            raise UsageError(f"FILE: expected one video, or HDR images, got {video[0]} and more")
        if args.fps is not None:
            raise UsageError("--fps: a video's frames are timed by their own stamps")
        return pipeline.from_video(
            video[0], args.video_transfer, args.video_primaries, args.hlg_peak, args.multiplier
        )
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


#: The settings an operator may refuse (:meth:`jaxadapt.operators.Operator.configure`)
#: and the options that give them.
SETTING_OPTIONS = {
    "goal": "--adaptation-goal",
    "gaze": "--gaze",
    "pixels_per_degree": "--pixels-per-degree",
    "background": "--background",
    "background_scale": "--background-scale",
}


class Plan(NamedTuple):
    """A render, resolved and checked before any frame is read: its source
    (with ``--gaze``), operator module and parameters, plot title, output
    formats, nominal frame rate (frames/s) and display ``encoding``, with
    whether the operator's frames come ``encoded`` already."""

    source: Any
    op: Any
    params: Any
    title: str
    formats: list
    fps: float
    encoding: str
    encoded: bool


def _planned(args, console):
    """The :class:`Plan` of ``args``: the options checked, the source opened
    (the files' headers only), the operator configured from the registry's
    contract, each check once and in that order, with the warnings said."""
    from jaxadapt import pipeline
    from jaxadapt.operators import BACKGROUND_SCALE, OPERATORS, Settings

    _check_options(args)
    formats = args.formats or ["png", "mp4"]
    source = _source(args)
    _warn_numbers_out_of_order(args.files, console)
    if args.background_scale is not None:
        _check_scale_fits(args.background_scale, source.shape)
    if args.gaze is not None:
        source = pipeline.with_gaze(source, args.gaze)
        _warn_gaze_off_frame(source, source.shape, args.gaze, console)
    # The nominal rate: frames split at a flash's edges are shorter, none longer.
    fps = 1.0 / float(np.max(source.dt))
    if "mp4" in formats and fps < MP4_MIN_FPS:
        raise UsageError(
            f"--fps: a video (--format mp4, a default) needs at least {MP4_MIN_FPS:g} frames/s, "
            f"got {fps:g}; choose --format png, exr or pfm"
        )
    chosen = {
        "goal": args.adaptation_goal,
        "gaze": args.gaze,
        "pixels_per_degree": args.pixels_per_degree,
        "background_scale": args.background_scale,
    }
    settings = Settings(
        args.operator,
        fps,
        args.pixels_per_degree or source.pixels_per_degree,
        args.adaptation_goal or source.goal,
        args.background,
        args.background_scale or BACKGROUND_SCALE,
        given=frozenset(name for name, value in chosen.items() if value is not None),
    )
    op = OPERATORS[args.operator]
    try:
        params = op.configure(settings)
    except ValueError as error:  # named by the setting: name the option
        name, _, rest = str(error).partition(": ")
        raise UsageError(f"{SETTING_OPTIONS.get(name, name)}: {rest}") from None
    encoded = OPERATORS.supports(args.operator).display_encoded
    # The 2015 operator's display values J = R^0.455 are a gamma-2.2 encoding.
    encoding = "gamma" if encoded else args.encoding or "srgb"
    title = f"{source.name}: {op.describe(settings)}"
    return Plan(source, op, params, title, formats, fps, encoding, encoded)


def render(args, console):
    """``jaxadapt render``: plan and check everything (:func:`_planned`), then
    stream the frames through the operator with their outputs written
    behind, then the diagnostics, sheet and plot."""
    import jax

    from jaxadapt import cluster, io, pipeline

    check_cluster_options(args)
    if args.replay is not None:
        if args.scheduler is not None or args.workers is not None:
            option = "--scheduler" if args.scheduler is not None else "--workers"
            raise UsageError(
                f"{option}: a replay writes the frames it recorded; nothing to compute"
            )
        options = (*_input_options(), *_operator_options(), *_adaptation_options())
        _replay.check(args, (*options, *_OUTPUT_OPTIONS))
        _replay.render(args, console)
        return
    args.files = io.expanded(args.files)  # (a URL's glob: no shell expands it)
    if args.scheduler is not None or args.workers is not None:
        # (the workers open the files themselves, from another working folder)
        args.files = [f if io.is_url(f) else Path(f).absolute() for f in args.files]
    plan = _planned(args, console)
    source, formats, fps = plan.source, plan.formats, plan.fps
    out, T, tables = args.out, len(source.times), []
    inputs = [*args.files, *([args.gaze] if args.gaze else [])]
    with _staged_shared(out, console, RENDER_OUTPUTS, keep=inputs) as (staging, shared):
        if not args.allow_large:  # once --out is known to be writable
            frames_from = "FILE" if args.files else "--fps, --duration"
            # (an --out URL's files are written here first, then put there)
            space = staging if io.is_url(out) else out
            _check_work(T, source.shape, formats, space, frames_from)
        video = (source.times, args.files[0]) if _is_video(args.files) else None
        codec = args.video_codec or "h264"
        with (
            contextlib.ExitStack() as stack,
            cluster.connected(args.scheduler, args.workers) as client,
        ):
            send_video, advance = _video_and_progress(
                stack,
                staging,
                formats if client is None else [f for f in formats if f != "mp4"],
                fps,
                plan.encoding,
                console,
                (f"rendering {source.name}", T),
                video=video,
                codec=codec,
            )
            write = FrameOutputs(
                staging,
                formats,
                source.times,
                fps,
                (plan.encoding, plan.encoded),
                send_video,
                advance,
            )
            key = jax.random.key(args.seed or 0)
            budget = args.memory or pipeline.MEMORY_BUDGET
            if client is None:
                stream = pipeline.chunks(
                    plan.op, plan.params, source, args.chunk, key, budget=budget
                )
                with contextlib.closing(stream), pipeline.behind(write) as submit:
                    for idx, linear, table in stream:
                        submit((idx, linear))
                        tables.append(table)
            else:
                times = video[0] if video else None
                work = Work(plan, shared, key, args.chunk, budget, times, codec)
                option = "--scheduler" if args.scheduler is not None else "--workers"
                bounds = cluster.shard_bounds(T, cluster.workers_of(client))
                for shard in in_shards(client, work, bounds, args.operator, option):
                    tables.append(shard.table)
                    write.kept.update(shard.kept)
                    advance(len(shard.table["t"]))
        if client is not None:
            if not io.is_url(shared):
                tidied(shared)
            if "mp4" in formats:
                joined_parts(staging, shared, [start for start, _ in bounds], fps, video)
        table = pipeline.concatenate(tables)
        _warn_bleached(table, console)
        io.write_columns(staging / "diagnostics.csv", table)
        if _is_video(args.files):
            _write_video_record(staging / "source.json", args)
        write.contact_sheet(plan.op.log_adaptation(table))
        plan.op.plot_diagnostics(staging / "adaptation.png", table, plan.params, plan.title)
        names = sorted(path.name for path in staging.iterdir())
        if shared is not staging:  # (the files the workers put at an --out URL)
            names = sorted({*names, *shared_names(*io.filesystem(shared))})
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
