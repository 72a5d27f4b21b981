"""The whole ``jaxadapt render`` process on real-size footage, against pfstmo's pipe.

What a user runs, timed from the shell's point of view: the process starts,
imports, reads PFM frames, tone-maps them (the 2000 operator, global
adaptation, default options) and writes PFM frames, the contact sheet, the
plot and the diagnostics. The peer, in the same run and on the same files:
``pfsinpfm FILES | pfstmo_pattanaik00 -t --fps 30 | pfsoutpfm OUT/%04d.pfm``
(Debian's ``pfstools`` and ``pfstmo``), whose three processes run at once.

For each size the script records the median wall time of ``--repeats``
runs of each (the first jaxadapt run, which fills the compilation cache,
is recorded apart), the peak resident memory of each process (``wait4``;
for the pipe, the sum of its three processes' peaks) and the stages of a
render measured alone in this process (seconds a frame to read, compute
and write). ``--formats png exr`` also times renders that write those
formats from the same files (the peer writes PFM). ``--long`` also renders
60 and 600 frames of the built-in tunnel at 1920x1080 with the default
outputs (PNG and MP4), whose peak memory must not grow with the length.

    python benchmarks/bench_render.py [--sizes 1920x1080:60 3840x2160:40]
                                      [--repeats 3] [--data DIR] [--long]
                                      [--formats png exr]
"""

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent

PFSTMO = ("pfsinpfm", "pfstmo_pattanaik00", "pfsoutpfm")


def make_frames(folder, width, height, count):
    """``count`` frames of the built-in tunnel drive at ``width x height`` as
    PFM files in ``folder`` (kept between runs: made once), made in a
    process of their own (:func:`run_processes`)."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"f{i:04d}.pfm" for i in range(count)]
    if not all(p.exists() for p in paths):
        code = (
            f"import sys; sys.path.insert(0, {str(HERE)!r}); import bench_render; "
            f"bench_render.write_frames({str(folder)!r}, {width}, {height}, {count})"
        )
        subprocess.run([sys.executable, "-c", code], check=True)
    return paths


def write_frames(folder, width, height, count):
    from jaxadapt import io
    from jaxadapt.scenes import tunnel_drive

    paths = [Path(folder) / f"f{i:04d}.pfm" for i in range(count)]
    scene = tunnel_drive(width=width, height=height, duration=count / 30.0, fps=30.0)
    for i, path in enumerate(paths):
        io.write_image(path, np.asarray(scene.render(scene.times[i : i + 1]), np.float32)[0])
    return paths


def run_processes(commands):
    """Run ``commands`` as a pipe (each one's output the next one's input);
    return (wall seconds, sum of the processes' peak resident memory, bytes).

    Linux counts in a process's peak the memory of the process it was
    forked from, up to its ``exec``: this one must stay small until the
    timings are done (no JAX imported; the frames are made in a process of
    their own, the stages measured last)."""
    start, processes, previous, logs = time.perf_counter(), [], None, []
    for i, command in enumerate(commands):
        last = i == len(commands) - 1
        logs.append(tempfile.TemporaryFile())  # a pipe read only at the end could fill
        process = subprocess.Popen(
            command,
            stdin=previous,
            stdout=subprocess.DEVNULL if last else subprocess.PIPE,
            stderr=logs[-1],
        )
        if previous is not None:
            previous.close()  # the next process holds it
        previous = process.stdout
        processes.append(process)
    peak = 0
    for process in processes:
        _, status, usage = os.wait4(process.pid, 0)
        process.returncode = os.waitstatus_to_exitcode(status)
        peak += usage.ru_maxrss * 1024  # kB on Linux
    wall = time.perf_counter() - start
    for command, process, log in zip(commands, processes, logs, strict=True):
        log.seek(0)
        said = log.read().decode(errors="replace")
        log.close()
        if process.returncode != 0:
            raise RuntimeError(f"{command[0]} failed: {said[-500:]}")
    return wall, peak


def jaxadapt_command(args, out):
    return [sys.executable, "-m", "jaxadapt", "render", *map(str, args), "--out", str(out)]


def time_jaxadapt(args, out, repeats):
    """(first run, median of the later runs, their peak memory) of a render."""
    shutil.rmtree(out, ignore_errors=True)
    first = run_processes([jaxadapt_command(args, out)])
    runs = []
    for _ in range(repeats):
        shutil.rmtree(out, ignore_errors=True)
        runs.append(run_processes([jaxadapt_command(args, out)]))
    return first, statistics.median(w for w, _ in runs), max(p for _, p in runs)


def time_pfstmo(paths, out, repeats):
    """Median wall time and the largest peak memory of pfstmo's pipe."""
    if not all(shutil.which(tool) for tool in PFSTMO):
        return None, None
    runs = []
    for _ in range(repeats):
        shutil.rmtree(out, ignore_errors=True)
        out.mkdir(parents=True)
        runs.append(
            run_processes(
                [
                    ["pfsinpfm", *map(str, paths)],
                    ["pfstmo_pattanaik00", "-t", "--fps", "30"],
                    ["pfsoutpfm", str(out / "%04d.pfm")],
                ]
            )
        )
    return statistics.median(w for w, _ in runs), max(p for _, p in runs)


def stages(paths, scratch):
    """Seconds a frame of each stage of a render, each alone in this process
    (compile excluded, the median of three passes over the first frames)."""
    import jax.numpy as jnp

    from jaxadapt import io, pipeline, runtime
    from jaxadapt.operators import pattanaik2000 as op

    runtime.retain_freed_memory()
    source = pipeline.from_files(paths, 30.0)
    size = pipeline.chunk_size(source.shape)
    idx = np.arange(min(size, len(paths)))

    def median(fn):
        fn()
        times = []
        for _ in range(3):
            start = time.perf_counter()
            fn()
            times.append(time.perf_counter() - start)
        return statistics.median(times) / len(idx)

    frames = source.frames(idx)
    params = op.Params()
    state = op.init(params, jnp.asarray(frames[0]))
    dt = jnp.full(len(idx), 1 / 30, jnp.float32)
    out = np.asarray(op.run(params, jnp.asarray(frames), dt, state=state)[0])

    def write():
        for k in range(len(idx)):
            io.write_image(scratch / f"{k}.pfm", out[k])

    return {
        "frames_per_chunk": int(size),
        "read_s_per_frame": median(lambda: source.frames(idx)),
        "compute_s_per_frame": median(
            lambda: np.asarray(op.run(params, jnp.asarray(frames), dt, state=state)[0])
        ),
        "write_pfm_s_per_frame": median(write),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["1920x1080:60", "3840x2160:40"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--data", type=Path, default=Path(tempfile.gettempdir()) / "jaxadapt-bench")
    parser.add_argument("--long", action="store_true", help="also 60 and 600 tunnel frames")
    parser.add_argument("--label", default="cpu-2core")
    parser.add_argument("--formats", nargs="*", default=[], choices=["png", "exr", "mp4"])
    args = parser.parse_args()

    record = {"repeats": args.repeats, "sizes": {}}
    scratch = args.data / "out"
    for item in args.sizes:
        size, count = item.split(":")
        width, height = map(int, size.split("x"))
        paths = make_frames(args.data / f"{size}_{count}", width, height, int(count))
        first, wall, peak = time_jaxadapt([*paths, "--format", "pfm"], scratch, args.repeats)
        pf_wall, pf_peak = time_pfstmo(paths, scratch, args.repeats)
        row = {
            "frames": int(count),
            "jaxadapt_first_run_s": first[0],
            "jaxadapt_s": wall,
            "jaxadapt_peak_rss_bytes": peak,
            "pfstmo_s": pf_wall,
            "pfstmo_peak_rss_bytes": pf_peak,
            "speedup": pf_wall / wall if pf_wall else None,
            "paths": paths,
        }
        for fmt in args.formats:
            _, fmt_wall, fmt_peak = time_jaxadapt([*paths, "--format", fmt], scratch, args.repeats)
            row[f"jaxadapt_{fmt}_out"] = {"s": fmt_wall, "peak_rss_bytes": fmt_peak}
        record["sizes"][size] = row
        print(size, {k: v for k, v in row.items() if k != "paths"}, flush=True)
    if args.long:
        long = {}
        for seconds in (2, 20):
            command = ["--scene", "tunnel", "--size", "1920x1080", "--duration", seconds]
            _, wall, peak = time_jaxadapt(command, scratch, 1)
            long[f"{seconds * 30}_frames"] = {"s": wall, "peak_rss_bytes": peak}
            print(seconds * 30, "frames:", long[f"{seconds * 30}_frames"], flush=True)
        record["tunnel_1920x1080_png_mp4"] = long
    sys.path.insert(0, str(HERE))
    from common import machine, write_result

    for size, row in record["sizes"].items():  # now that nothing more is forked
        row["stages"] = stages(row.pop("paths"), scratch)
        print(size, row["stages"], flush=True)
    record["machine"] = machine(args.label)
    shutil.rmtree(scratch, ignore_errors=True)
    print(write_result("render", record, args.label))


if __name__ == "__main__":
    main()
