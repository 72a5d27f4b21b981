"""Leaving a tunnel in an HDR10 video: jaxadapt's adaptation against FFmpeg's static tone map.

An HDR10 clip (PQ, BT.2020, 10-bit HEVC, with audio) of the tunnel drive
of Pattanaik et al. (2000), Fig. 7, from 150 m inside the unlit tunnel
(road 5 cd/m2) out into the sun (road 5000, sky 8000 cd/m2) at 90 km/h:
the car leaves at 4.0 s; the clip lasts 6 s. Rendered as a user would, by ``jaxadapt render
clip.mp4`` (the 2000 operator, foveal goal on the road 40 m ahead) and by
FFmpeg's static tone map (``zscale`` to linear light, ``tonemap=hable``,
the benchmark's peer). The top rows are frames of each video; the plot
under them is the adaptation (``diagnostics.csv``): the cones' adaptation
lags the goal, so the exit glares and then darkens as the eye adapts,
where the static curve shows every frame at the same exposure.

Writes ``video_tunnel_exit.png``, the clip and both renders.
"""

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
from common import setup
from matplotlib.figure import Figure

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "benchmarks"))
from bench_video import PEER_FILTERS, ffmpeg, write_clip  # noqa: E402

#: Frame times shown, s: inside; the opening filling the fovea (the cones'
#: adaptation lags the goal most, by 2.5 times, from 3.6 to 3.8 s); at the
#: exit; out and adapted (full-size run's ``diagnostics.csv``).
SHOWN_TIMES = (1.0, 3.3, 3.6, 3.8, 4.0, 5.5)
#: How far inside the tunnel the clip starts, m (it is 250 m long), and
#: when the car leaves it, s (at 25 m/s).
INSIDE = 150.0
EXIT = (250.0 - INSIDE) / 25.0


def frames_at(path, indices):
    """The frames ``indices`` of the video ``path``, RGB uint8, decoded by PyAV."""
    import av

    wanted, out = set(indices), {}
    with av.open(str(path)) as video:
        for i, frame in enumerate(video.decode(video=0)):
            if i in wanted:
                out[i] = frame.to_ndarray(format="rgb24")
    return [out[i] for i in indices]


def main():
    args, out = setup("video_tunnel_exit", __doc__.splitlines()[0])
    width, height, seconds = (96, 54, 6.0) if args.smoke else (480, 270, 6.0)
    clip = out / "tunnel_exit_hdr10.mp4"
    write_clip(clip, width, height, int(seconds * 30), entrance=-INSIDE)
    rendered = out / "jaxadapt"
    subprocess.run(
        [sys.executable, "-m", "jaxadapt", "render", str(clip), "--format", "mp4",
         "--out", str(rendered)],
        check=True,
    )  # fmt: skip
    peer = out / "ffmpeg_tonemap_hable.mp4"
    subprocess.run(
        [ffmpeg(), "-v", "error", "-y", "-i", str(clip), "-vf", PEER_FILTERS, "-c:v", "libx264",
         "-crf", "25", "-c:a", "copy", str(peer)],
        check=True,
    )  # fmt: skip
    with open(rendered / "diagnostics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    t = np.array([float(r["t"]) for r in rows])
    goal = np.array([float(r["G_cone"]) for r in rows])
    adapted = np.array([float(r["A_cone"]) for r in rows])
    indices = [int(np.argmin(np.abs(t - s))) for s in SHOWN_TIMES]
    videos = {
        "FFmpeg tonemap=hable\n(static)": frames_at(peer, indices),
        "jaxadapt render\n(pattanaik2000)": frames_at(rendered / "video.mp4", indices),
    }

    fig = Figure(figsize=(2.2 * len(indices), 6.2))
    grid = fig.add_gridspec(3, len(indices), height_ratios=(1, 1, 1.3))
    for row, (name, frames) in enumerate(videos.items()):
        for col, (i, frame) in enumerate(zip(indices, frames, strict=True)):
            ax = fig.add_subplot(grid[row, col])
            ax.imshow(frame)
            ax.set_xticks([])
            ax.set_yticks([])
            if row == 0:
                ax.set_title(f"t = {t[i]:.1f} s", fontsize=8)
            if col == 0:
                ax.set_ylabel(name, fontsize=8)
    plot = fig.add_subplot(grid[2, :])
    plot.semilogy(t, goal, label="goal G (foveal road luminance)", color="C0")
    plot.semilogy(t, adapted, label="cone adaptation A", color="C1")
    plot.axvline(EXIT, color="0.5", lw=0.8, ls="--")
    plot.text(EXIT, goal.max(), " the car leaves", fontsize=7, va="top", color="0.4")
    for i in indices:
        plot.axvline(t[i], color="0.8", lw=0.6, zorder=0)
    plot.set(xlabel="time, s", ylabel="cd/m$^2$", xlim=(0, t[-1]))
    plot.legend(fontsize=7, loc="center left")
    fig.suptitle(
        "Leaving a tunnel, HDR10 in, SDR out: a static tone map against the adapting eye",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(out / "video_tunnel_exit.png", dpi=110)
    print(out / "video_tunnel_exit.png")


if __name__ == "__main__":
    main()
