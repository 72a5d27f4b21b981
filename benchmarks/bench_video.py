"""``jaxadapt render clip.mp4`` on an HDR10 clip, against ffmpeg's static tone map.

The clip: the built-in tunnel drive (frames made once, in cd/m2), encoded
to HDR10 by the ffmpeg that imageio-ffmpeg ships (zscale to PQ, BT.2020,
10-bit 4:2:0; libx265), with an AAC audio track. Timed as whole processes,
each the median of ``--repeats`` runs after one untimed run, with the
sum of peak resident memory:

- ``jaxadapt render CLIP --format mp4`` (the 2000 operator, the default):
  decode with PyAV, adapt, encode H.264 with the clip's timing and audio;
- the peer, ffmpeg's static tone map of the same clip to SDR H.264:
  ``zscale`` to linear light (``npl=100``), ``tonemap=hable``, ``zscale``
  to BT.709, libx264 at the same CRF 25, the audio copied.

Then the stages of the render, each alone in this process (compile
excluded, the median of three passes): seconds a frame to decode and
convert to cd/m2 (the whole clip, from the file's opening, chunk by
chunk as the render reads it), to compute the operator and to encode
into H.264 (over the first chunk).

``--sizes 1920x1080:60`` (default) and others; the record goes to
``results/video_<label>.json``.
"""

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))
from bench_render import run_processes, time_jaxadapt  # noqa: E402

#: ffmpeg's filters of the peer: PQ to linear light (100 cd/m2 = 1.0), the
#: Hable curve, then BT.709 primaries, transfer and matrix, 8-bit 4:2:0.
PEER_FILTERS = (
    "zscale=t=linear:npl=100,format=gbrpf32le,zscale=p=bt709,tonemap=tonemap=hable:desat=0,"
    "zscale=t=bt709:m=bt709:r=tv,format=yuv420p"
)


def ffmpeg():
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


def make_clip(folder, width, height, count):
    """An HDR10 clip of ``count`` tunnel frames (kept between runs: made once)."""
    path = folder / f"tunnel_{width}x{height}_{count}.mp4"
    if path.exists():
        return path
    folder.mkdir(parents=True, exist_ok=True)
    code = (
        f"import sys; sys.path.insert(0, {str(HERE)!r}); import bench_video; "
        f"bench_video.write_clip({str(path)!r}, {width}, {height}, {count})"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
    return path


def write_clip(path, width, height, count, **tunnel):
    """Render the tunnel's frames (``tunnel``: more arguments of
    :func:`jaxadapt.scenes.tunnel_drive`), PQ-encode them in float (R'G'B'
    planes) and let ffmpeg convert them to 10-bit BT.2020 Y'CbCr and
    encode them, at 30 frames/s, with a sine's audio track."""
    import colour

    from jaxadapt.scenes import tunnel_drive

    scene = tunnel_drive(width=width, height=height, duration=count / 30.0, fps=30.0, **tunnel)
    to2020 = colour.matrix_RGB_to_RGB(
        colour.RGB_COLOURSPACES["ITU-R BT.709"], colour.RGB_COLOURSPACES["ITU-R BT.2020"]
    )
    command = [
        ffmpeg(), "-v", "error", "-y",
        "-f", "rawvideo", "-pix_fmt", "gbrpf32le", "-s", f"{width}x{height}", "-r", "30",
        "-i", "-", "-f", "lavfi", "-i", f"sine=d={count / 30.0}",
        "-vf", "zscale=m=2020_ncl:r=limited:rin=full:min=gbr:t=smpte2084:tin=smpte2084:"
        "p=2020:pin=2020,format=yuv420p10le",
        "-c:v", "libx265", "-x265-params", "log-level=error:crf=18",
        "-color_primaries", "bt2020", "-color_trc", "smpte2084", "-colorspace", "bt2020nc",
        "-color_range", "tv", "-c:a", "aac", "-shortest", str(path),
    ]  # fmt: skip
    process = subprocess.Popen(command, stdin=subprocess.PIPE)
    for i in range(count):
        light = np.asarray(scene.render(scene.times[i : i + 1]), np.float64)[0] @ to2020.T
        signal = colour.models.eotf_inverse_ST2084(np.clip(light, 0, 10000)).astype(np.float32)
        process.stdin.write(np.ascontiguousarray(signal[..., [1, 2, 0]].transpose(2, 0, 1)))
    process.stdin.close()
    if process.wait():
        raise RuntimeError("ffmpeg could not make the clip")


def time_peer(clip, out, repeats):
    """Median wall time and peak memory of ffmpeg's static tone map."""
    command = [ffmpeg(), "-v", "error", "-y", "-i", str(clip), "-vf", PEER_FILTERS]
    command += ["-c:v", "libx264", "-crf", "25", "-c:a", "copy", str(out)]
    run_processes([command])  # (untimed, as jaxadapt's first run)
    runs = [run_processes([command]) for _ in range(repeats)]
    return statistics.median(w for w, _ in runs), max(p for _, p in runs)


def stages(clip, scratch):
    """Seconds a frame of each stage of ``jaxadapt render CLIP --format mp4``,
    each alone (compile excluded, the median of three passes): the decoding
    of the whole clip, chunk by chunk from the file's opening, as the
    render reads it; the operator and the encoding over one chunk."""
    import jax.numpy as jnp
    from common import median_seconds

    from jaxadapt import display, io, pipeline, runtime
    from jaxadapt.operators import pattanaik2000 as op

    runtime.retain_freed_memory()
    source = pipeline.from_video(clip)
    idx = np.arange(min(pipeline.chunk_size(source.shape), len(source.times)))

    def median(fn):
        return median_seconds(fn, repeats=3) / len(idx)

    frames = source.frames(idx)
    params = op.Params()
    state = op.init(params, jnp.asarray(frames[0]))
    dt = jnp.asarray(source.dt[idx], jnp.float32)
    out = np.asarray(op.run(params, jnp.asarray(frames), dt, state=state)[0])
    shown = display.to_uint8(display.encode_srgb(out))

    def encode():
        with io.video_writer(scratch / "stage.mp4", 30.0) as send:
            send(shown)

    def decode():  # (the whole clip in order, chunk by chunk, as a render reads it)
        whole = pipeline.from_video(clip)
        for start in range(0, len(whole.times), len(idx)):
            whole.frames(np.arange(start, min(start + len(idx), len(whole.times))))

    return {
        "frames_per_chunk": len(idx),
        "decode_s_per_frame": median_seconds(decode, repeats=3) / len(source.times),
        "compute_s_per_frame": median(
            lambda: np.asarray(op.run(params, jnp.asarray(frames), dt, state=state)[0])
        ),
        "encode_s_per_frame": median(encode),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["1920x1080:60"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--data", type=Path, default=Path(tempfile.gettempdir()) / "jaxadapt-bench")
    parser.add_argument("--label", default="cpu-2core")
    args = parser.parse_args()

    record = {"repeats": args.repeats, "peer": f"ffmpeg -vf {PEER_FILTERS}", "sizes": {}}
    scratch = args.data / "video_out"
    for item in args.sizes:
        size, count = item.split(":")
        width, height = map(int, size.split("x"))
        clip = make_clip(args.data, width, height, int(count))
        first, wall, peak = time_jaxadapt([clip, "--format", "mp4"], scratch, args.repeats)
        scratch.mkdir(parents=True, exist_ok=True)
        peer_wall, peer_peak = time_peer(clip, scratch / "peer.mp4", args.repeats)
        record["sizes"][size] = row = {
            "frames": int(count),
            "jaxadapt_first_run_s": first[0],
            "jaxadapt_s": wall,
            "jaxadapt_peak_rss_bytes": peak,
            "ffmpeg_tonemap_s": peer_wall,
            "ffmpeg_tonemap_peak_rss_bytes": peer_peak,
            "speedup": peer_wall / wall,
        }
        print(size, row, flush=True)
    for size, row in record["sizes"].items():  # (last: this process imports JAX)
        width, height = map(int, size.split("x"))
        clip = make_clip(args.data, width, height, row["frames"])
        row["stages"] = stages(clip, scratch)
        print(size, row["stages"], flush=True)
    from common import machine, write_result

    record["machine"] = machine(args.label)
    shutil.rmtree(scratch, ignore_errors=True)
    print(write_result("video", record, args.label))


if __name__ == "__main__":
    main()
