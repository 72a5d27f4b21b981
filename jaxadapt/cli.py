"""Command line: ``jaxadapt render``.

Every error that comes from the user's input (arguments, files, values)
prints one line on stderr and exits with status 2. Outputs are written into
a staging folder inside ``--out`` and moved into place only when the whole
run has succeeded, so a failed run leaves nothing half-written and
overwrites nothing.
"""

import argparse
import contextlib
import csv
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

FORMATS = ("png", "mp4", "exr", "pfm")
CONTACT_FRAMES = 12


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


def build_parser():
    from jaxadapt.operators.goal import GOALS
    from jaxadapt.scenes import SCENES

    parser = argparse.ArgumentParser(
        prog="jaxadapt",
        description="Simulate time-dependent visual adaptation to HDR scenes "
        "and render what a viewer would see on an ordinary display.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    render = sub.add_parser(
        "render",
        help="tone-map an HDR sequence with time-dependent adaptation (Pattanaik et al. 2000)",
        description="Tone-map an HDR frame sequence (absolute cd/m2) the way an observer "
        "whose eyes adapt over time would see it on an ordinary display (Pattanaik et al. "
        "2000). With no FILE, renders a built-in scene. Writes display frames, a contact "
        "sheet, a plot of the adaptation state and diagnostics.csv into --out.",
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
        default="tunnel",
        help="built-in scene when no FILE is given (default: tunnel)",
    )
    render.add_argument(
        "--size",
        type=_size,
        default=None,
        metavar="WxH",
        help="frame size of the built-in scene (default: 480x270 tunnel, 384x256 title-step)",
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
        type=_positive,
        default=30.0,
        help="frame rate of FILE sequences, frames per second (default: 30)",
    )
    render.add_argument(
        "--multiplier",
        type=_positive,
        default=1.0,
        help="multiply input values by this to calibrate them to cd/m2 (default: 1)",
    )
    render.add_argument(
        "--adaptation-goal",
        choices=GOALS,
        default=None,
        help="how the adaptation goal of each frame is found (default: the scene's own; "
        "log_average for files)",
    )
    render.add_argument(
        "--pixels-per-degree",
        type=_positive,
        default=None,
        help="resolution of the frames at the eye, for the foveal goal (default: the "
        "scene's own; 30 for files)",
    )
    render.add_argument(
        "--out", type=Path, default=Path("out"), help="output folder (default: ./out)"
    )
    render.add_argument(
        "--format",
        action="append",
        choices=FORMATS,
        default=None,
        dest="formats",
        help="output format, repeatable: png (sRGB frames), mp4 (video), exr or pfm "
        "(linear display values in [0, 1], one file per frame); default: png and mp4",
    )
    render.add_argument(
        "--encoding",
        choices=("srgb", "gamma"),
        default="srgb",
        help="display encoding of png and mp4 output (default: srgb; gamma is 2.2)",
    )
    render.add_argument(
        "--chunk", type=int, default=32, help="frames processed per call (default: 32)"
    )
    return parser


# -- sources ------------------------------------------------------------------


class Source:
    """Frames to render, produced chunk by chunk."""

    def __init__(self, times, dt, render, gaze, goal, adaptation, name, pixels_per_degree):
        self.times, self.dt, self.render, self.gaze = times, dt, render, gaze
        self.goal, self.adaptation, self.name = goal, adaptation, name
        self.pixels_per_degree = pixels_per_degree


def scene_source(args):
    from jaxadapt.scenes import SCENES

    kwargs = {}
    if args.size is not None:
        kwargs["width"], kwargs["height"] = args.size
    if args.duration is not None:
        kwargs["duration"] = args.duration
    scene = SCENES[args.scene](**kwargs)

    def render(idx):
        return np.asarray(scene.render(scene.times[idx])) * args.multiplier

    return Source(
        scene.times,
        scene.dt,
        render,
        lambda idx: scene.gaze(scene.times[idx]),
        scene.goal,
        scene.adaptation,
        scene.name,
        scene.pixels_per_degree,
    )


def file_source(args):
    from jaxadapt.io import read_hdr

    paths = [Path(p) for p in args.files]
    first = read_hdr(paths[0])
    for p in paths[1:]:
        if not p.is_file():
            raise FileNotFoundError(f"{p}: no such file")

    def render(idx):
        frames = []
        for i in idx:
            frame = first if i == 0 else read_hdr(paths[i])
            if frame.shape != first.shape:
                raise UsageError(
                    f"{paths[i]}: expected {first.shape[1]}x{first.shape[0]} like {paths[0]}, "
                    f"got {frame.shape[1]}x{frame.shape[0]}"
                )
            bad = ~(np.isfinite(frame) & (frame >= 0))
            if bad.any():
                raise UsageError(
                    f"{paths[i]}: expected finite, non-negative values, got {int(bad.sum())} "
                    "negative, NaN or infinite values"
                )
            frames.append(frame * np.float32(args.multiplier))
        return np.stack(frames)

    T = len(paths)
    centre = np.array([(first.shape[1] - 1) / 2.0, (first.shape[0] - 1) / 2.0])
    return Source(
        np.arange(T) / args.fps,
        np.full(T, 1.0 / args.fps),
        render,
        lambda idx: np.tile(centre, (len(idx), 1)),
        "log_average",
        None,
        "files",
        30.0,
    )


# -- outputs ------------------------------------------------------------------

DIAGNOSTIC_COLUMNS = (
    "t",
    "G_rod",
    "G_cone",
    "A_rod",
    "A_cone",
    "B_rod",
    "B_cone",
    "sigma_rod",
    "sigma_cone",
    "rule",
)


def write_diagnostics(path, diag):
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(DIAGNOSTIC_COLUMNS)
        for i in range(len(diag["t"])):
            writer.writerow([f"{diag[c][i]:.6g}" for c in DIAGNOSTIC_COLUMNS])


def plot_adaptation(path, diag, title):
    """Adaptation state over time and the scene-to-display curve at a few times."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxadapt.operators.pattanaik2000 import CURVE_LOG10_LUMINANCE

    t = diag["t"]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    ax = axes[0]
    for name, style in (("G_cone", "C1:"), ("A_cone", "C1-"), ("G_rod", "C0:"), ("A_rod", "C0-")):
        ax.semilogy(t, diag[name], style, label=name)
    ax.set(xlabel="time (s)", ylabel="cd/m$^2$", title="goal G and neural adaptation A")
    ax.legend()
    ax = axes[1]
    ax.semilogy(t, diag["B_cone"], "C1", label="B_cone")
    ax.semilogy(t, diag["B_rod"], "C0", label="B_rod")
    ax.set(xlabel="time (s)", ylabel="unbleached fraction", title="pigment B")
    ax.legend()
    ax = axes[2]
    picks = np.unique(np.linspace(0, len(t) - 1, 8).round().astype(int))
    colors = plt.cm.viridis(np.linspace(0, 1, len(picks)))
    for c, i in zip(colors, picks, strict=False):
        ax.plot(
            np.asarray(CURVE_LOG10_LUMINANCE), diag["curve"][i], color=c, label=f"t={t[i]:.2f} s"
        )
    ax.set(
        xlabel="scene luminance (log$_{10}$ cd/m$^2$)",
        ylabel="display value (linear)",
        title="scene-to-display curve",
    )
    ax.legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def contact_sheet(frames, columns=4):
    """Tile uint8 frames ``(K, H, W, 3)`` into one image, with white gutters."""
    K, H, W, _ = frames.shape
    rows = -(-K // columns)
    sheet = np.full((rows * (H + 4) + 4, columns * (W + 4) + 4, 3), 255, np.uint8)
    for k in range(K):
        r, c = divmod(k, columns)
        sheet[4 + r * (H + 4) : 4 + r * (H + 4) + H, 4 + c * (W + 4) : 4 + c * (W + 4) + W] = (
            frames[k]
        )
    return sheet


# -- the render command -------------------------------------------------------


def render(args, console):
    import jax.numpy as jnp
    from rich.progress import Progress

    from jaxadapt import display, io
    from jaxadapt.operators import pattanaik2000 as op

    if args.chunk < 1:
        raise UsageError(f"--chunk: expected a positive number of frames, got {args.chunk}")
    formats = args.formats or ["png", "mp4"]
    source = file_source(args) if args.files else scene_source(args)
    goal = args.adaptation_goal or source.goal
    params = op.Params(
        goal=goal, pixels_per_degree=args.pixels_per_degree or source.pixels_per_degree
    )
    encode = display.ENCODINGS[args.encoding]

    out = args.out
    try:
        out.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=".jaxadapt-", dir=out))
    except OSError as e:
        raise UsageError(f"--out: cannot write to {out} ({e.strerror or e})") from None

    T = len(source.times)
    fps = 1.0 / float(np.median(source.dt))
    contact_idx = set(range(min(4, T))) | set(
        np.linspace(4, T - 1, CONTACT_FRAMES - 4).round().astype(int) if T > 4 else []
    )
    contact, diag_chunks = [], []
    try:
        with contextlib.ExitStack() as stack:
            send_video = (
                stack.enter_context(io.video_writer(staging / "video.mp4", fps))
                if "mp4" in formats
                else (lambda frames: None)
            )
            progress = stack.enter_context(Progress(console=console, transient=True))
            task = progress.add_task(f"rendering {source.name}", total=T)
            state = None
            for start in range(0, T, args.chunk):
                idx = np.arange(start, min(start + args.chunk, T))
                padded = (
                    np.pad(idx, (0, args.chunk - len(idx)), mode="edge") if T > args.chunk else idx
                )
                frames = jnp.asarray(source.render(padded), dtype=jnp.float32)
                if state is None and source.adaptation is not None:
                    state = op.init(params, None, adaptation=source.adaptation)
                out_frames, diag = op.run(
                    params,
                    frames,
                    jnp.asarray(source.dt[padded], jnp.float32),
                    gaze=jnp.asarray(source.gaze(padded), jnp.float32),
                    state=state,
                )
                n = len(idx)
                # the state after the last real frame of a padded chunk
                pairs = zip(diag.state, diag.final_state, strict=True)
                state = op.State(*(s[n] if n < len(padded) else f for s, f in pairs))
                linear = np.asarray(out_frames[:n])
                coded = display.to_uint8(encode(linear))
                for k, i in enumerate(idx):
                    if "png" in formats:
                        io.write_image(staging / f"frame_{i:05d}.png", coded[k])
                    if "exr" in formats:
                        io.write_image(staging / f"frame_{i:05d}.exr", linear[k])
                    if "pfm" in formats:
                        io.write_image(staging / f"frame_{i:05d}.pfm", linear[k])
                    if i in contact_idx:
                        contact.append(coded[k])
                send_video(coded)
                diag_chunks.append(_diag_table(diag, n))
                progress.advance(task, n)
        table = {k: np.concatenate([d[k] for d in diag_chunks]) for k in diag_chunks[0]}
        table["t"] = source.times
        write_diagnostics(staging / "diagnostics.csv", table)
        io.write_image(staging / "contact_sheet.png", contact_sheet(np.stack(contact)))
        plot_adaptation(
            staging / "adaptation.png", table, f"{source.name}: Pattanaik et al. 2000, goal {goal}"
        )
        written = sorted(p.name for p in staging.iterdir())
        for name in written:
            (staging / name).replace(out / name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    console.print(
        f"wrote {len(written)} files to {out}/ (diagnostics.csv, contact_sheet.png, "
        f"adaptation.png, {T} frames)"
    )


def _diag_table(diag, n):
    s = diag.state
    cols = {
        "G_rod": diag.G_rod,
        "G_cone": diag.G_cone,
        "A_rod": s.A_rod,
        "A_cone": s.A_cone,
        "B_rod": s.B_rod,
        "B_cone": s.B_cone,
        "sigma_rod": diag.sigma_rod,
        "sigma_cone": diag.sigma_cone,
        "rule": diag.rule,
        "curve": diag.curve,
    }
    return {k: np.asarray(v)[:n] for k, v in cols.items()}


def main(argv=None):
    from rich.console import Console

    parser = build_parser()
    args = parser.parse_args(argv)
    console = Console(stderr=True)
    import equinox as eqx

    try:
        if args.command == "render":
            render(args, console)
    except (UsageError, ValueError, FileNotFoundError, OSError, eqx.EquinoxRuntimeError) as e:
        message = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        print(f"jaxadapt: error: {message}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
