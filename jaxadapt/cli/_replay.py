"""``jaxadapt render --replay DIR``: the frames of a session recorded by
``jaxadapt view --record DIR``, exactly as the viewer showed them, written
as a render writes its outputs."""

import contextlib
import warnings

import numpy as np

from jaxadapt.cli._frames import FrameOutputs
from jaxadapt.cli._options import MP4_MIN_FPS, UsageError
from jaxadapt.cli._output import _report, _video_and_progress
from jaxadapt.cli._staging import RENDER_OUTPUTS, _staged

#: The formats of a replay: the viewer's frames are 8-bit display pixels.
REPLAY_FORMATS = ("png", "mp4")


#: The options of ``render`` that a replay takes (the others the record fixes).
TAKEN = ("replay", "out", "formats", "video_codec", "allow_large")


def check(args, options):
    """Refuse with ``--replay`` the options that the record fixes: those of
    ``options`` ((flags, keywords) pairs, as declared) not in :data:`TAKEN`
    and not at their default, and the formats other than
    :data:`REPLAY_FORMATS`."""
    for flags, kwargs in options:
        dest = kwargs.get("dest", flags[0].lstrip("-").replace("-", "_"))
        if dest in TAKEN:
            continue
        value = getattr(args, dest)
        if value != kwargs.get("default") and value != []:
            name = "FILE" if dest == "files" else flags[0]
            raise UsageError(
                f"{name}: does not apply with --replay, whose record fixes the input, size, "
                "operator, effects and seed"
            )
    other = [f for f in args.formats or () if f not in REPLAY_FORMATS]
    if other:
        raise UsageError(
            f"--format: a replay writes the viewer's 8-bit frames (png, mp4), not {other[0]}"
        )


def _record(path, console):
    """The spec, frame rows and frames (an iterator) of the record in
    ``path``, checked before anything is written: an error of the record
    names ``--replay`` and the file, row or field; its warnings are said."""
    from jaxadapt.viewer import read_record, replay

    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            spec, rows = read_record(path)
        frames = replay(path, (spec, rows))
    except FileNotFoundError as error:  # (read_record's: replay's are ValueErrors)
        raise UsageError(
            f"--replay: expected a folder recorded by jaxadapt view --record, got {path}: {error}"
        ) from None
    except ValueError as error:
        raise UsageError(f"--replay: {error}") from None
    for warning in caught:
        console.print(f"warning: --replay: {warning.message}", markup=False)
    if not rows:
        raise UsageError(f"--replay: the record in {path} holds no frames")
    return spec, rows, frames


def render(args, console):
    """Replay the record of ``args.replay`` into ``args.out``: its frames
    (png), a video (mp4) at the session's mean frame rate, a contact sheet,
    ``diagnostics.csv`` (each frame's time, ``dt``, gaze, input frame and
    adaptation luminance) and its plot. Each frame's digest is checked
    against the record's; a mismatch is warned, with the frames that differ.
    """
    from jaxadapt import figures, io, pipeline

    path = args.replay
    spec, rows, frames = _record(path, console)
    formats = args.formats or list(REPLAY_FORMATS)
    if not spec.get("complete", False):
        console.print(
            f"warning: --replay: the session in {path} did not end cleanly; replaying the "
            f"{len(rows)} frames it recorded",
            markup=False,
        )
    dt = np.array([r["dt"] for r in rows])
    fps = len(dt) / float(dt.sum())
    if "mp4" in formats and fps < MP4_MIN_FPS:
        raise UsageError(
            f"--replay: a video (--format mp4, a default) needs at least {MP4_MIN_FPS:g} "
            f"frames/s, the session ran at {fps:g}; choose --format png"
        )
    from jaxadapt.operators import OPERATORS
    from jaxadapt.viewer._session import DEFAULT_OPERATOR

    operator = spec.get("operator", DEFAULT_OPERATOR)
    encoding = "gamma" if OPERATORS.supports(operator).display_encoded else "srgb"
    times = np.concatenate([[0.0], np.cumsum(dt)[:-1]])  # each frame's session time, s
    table, differ = [], []
    with _staged(args.out, console, RENDER_OUTPUTS, keep=[path]) as staging:
        with contextlib.ExitStack() as stack:
            send_video, advance = _video_and_progress(
                stack,
                staging,
                formats,
                fps,
                encoding,
                console,
                (f"replaying {path}", len(rows)),
                codec=args.video_codec or "h264",
            )

            write = FrameOutputs(
                staging, formats, times, fps, (encoding, True), send_video, advance
            )
            submit = stack.enter_context(pipeline.behind(write))
            for frame, row, t in zip(frames, rows, times, strict=True):
                if frame.digest != row["digest"]:
                    differ.append(frame.index)
                table.append((t, frame.dt, *frame.gaze, frame.scene_index, frame.adaptation))
                submit((np.array([frame.index]), frame.pixels[None]))
        columns = ("t", "dt", "gaze_x", "gaze_y", "scene_index", "adaptation")
        table = dict(zip(columns, np.array(table, np.float64).T, strict=True))
        io.write_columns(staging / "diagnostics.csv", table)
        with np.errstate(divide="ignore", invalid="ignore"):
            write.contact_sheet(np.log10(table["adaptation"]))
        figures.plot_columns(
            staging / "adaptation.png",
            {k: table[k] for k in ("t", "adaptation", "gaze_x", "gaze_y")},
            title=f"replay of {path}: {operator}",
            units={"adaptation": "cd/m2", "gaze_x": "px", "gaze_y": "px"},
        )
        count = len(list(staging.iterdir()))
    if differ:
        console.print(
            f"warning: --replay: {len(differ)} of {len(rows)} frames differ from those the "
            f"viewer showed (the first: frame {differ[0]}); a record of another jaxadapt "
            f"version ({spec.get('jaxadapt', 'unknown')}) or machine can round a dithered "
            "pixel the other way",
            markup=False,
        )
    _report(
        f"wrote {count} files to {args.out}/ for the {len(rows)} frames of {path} "
        f"({'all' if not differ else len(rows) - len(differ)} as shown, at {fps:.3g} frames/s)"
    )
