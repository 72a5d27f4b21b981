"""Frames per second of the Pattanaik 2000 operator, against pfstmo_pattanaik00.

Renders ``--frames`` frames of the built-in tunnel drive around the tunnel
mouth, then times:

* ``jaxadapt``: one jitted :func:`jaxadapt.operators.pattanaik2000.run` over
  all frames, resident on the device (compile excluded, median of repeats);
* ``pfstmo``: ``pfstmo_pattanaik00 -t --fps 30`` on the same frames as a
  pfs stream read from a file, minus the time of ``cat`` on the same stream
  (its core time, which still includes parsing and writing the pfs stream;
  Debian package ``pfstmo``). It runs on one core: jaxadapt uses them all.

With ``--background`` other than ``global`` the operator adapts per pixel
to a local background (a per-pixel state advanced by the exact kinetics),
and pfstmo runs with ``--local`` (its local mode, which keeps the
adaptation of its first frame: the nearest peer, doing less).

jaxadapt is timed twice: in this process, with glibc's default ``malloc``,
and in a child process that first calls
:func:`jaxadapt.runtime.retain_freed_memory` (as ``jaxadapt render`` does),
so that each call's buffers reuse the pages of the last call's instead of
new pages the kernel must map and zero (``getrusage`` page faults and system
time are recorded for both). The headline ``jaxadapt_fps`` is the second.
On a GPU, whose frames live in JAX's own pool of device memory, only the
first is timed.

Usage::

    python benchmarks/bench_pattanaik2000.py [--size 1920x1080] [--frames 60] [--repeats 5]
                                             [--background global] [--label NAME]
                                             [--no-pfstmo]

Writes ``benchmarks/results/pattanaik2000_<label>_<size>[_<background>].json``.
"""

import argparse
import json
import resource
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from common import copy_bandwidth, machine, median_seconds, write_result

from jaxadapt import io, scenes
from jaxadapt.operators import pattanaik2000 as op

FPS = 30.0


def tunnel_frames(width, height, count, start=3.0, chunk=8):
    """``count`` float32 frames of the tunnel drive from ``start`` s, as numpy."""
    scene = scenes.tunnel_drive(width, height, duration=start + count / FPS, fps=FPS)
    times = scene.times[int(round(start * FPS)) :][:count]
    return np.concatenate(
        [np.asarray(scene.render(times[i : i + chunk])) for i in range(0, count, chunk)]
    )


def time_jaxadapt(frames, repeats, background="global"):
    """Median seconds of one ``run`` over the frames, and the page faults and
    system seconds per call."""
    params = op.Params(background=background)
    device_frames = jax.device_put(jnp.asarray(frames))
    dt = jnp.float32(1 / FPS)

    def go():
        jax.block_until_ready(op.run(params, device_frames, dt))

    seconds = median_seconds(go, repeats=repeats)
    before = resource.getrusage(resource.RUSAGE_SELF)
    go()
    after = resource.getrusage(resource.RUSAGE_SELF)
    return {
        "seconds": seconds,
        "page_faults_per_call": after.ru_minflt - before.ru_minflt,
        "system_seconds_per_call": after.ru_stime - before.ru_stime,
    }


#: A child process that keeps freed memory from its start (before JAX starts
#: its threads), then runs this script with the arguments after ``-c``.
CHILD = (
    "import runpy, sys; from jaxadapt import runtime; runtime.retain_freed_memory(); "
    "sys.argv = sys.argv[1:]; runpy.run_path(sys.argv[0], run_name='__main__')"
)


def time_jaxadapt_retained(args):
    """:func:`time_jaxadapt` in a child process that keeps freed memory."""
    command = [sys.executable, "-c", CHILD, __file__, "--size", args.size]
    command += ["--frames", str(args.frames), "--repeats", str(args.repeats), "--timing-only"]
    command += ["--background", args.background]
    here = Path(__file__).parent  # where ``common`` is imported from
    done = subprocess.run(command, capture_output=True, text=True, check=True, cwd=here)
    return json.loads(done.stdout.splitlines()[-1])


def pfstmo_options(local):
    """The options given to ``pfstmo_pattanaik00``."""
    return ["-t", "--fps", str(FPS)] + (["--local"] if local else [])


def time_pfstmo(frames, repeats, local=False):
    """Core seconds of ``pfstmo_pattanaik00`` with :func:`pfstmo_options` on
    the frames, or None if absent."""
    if shutil.which("pfstmo_pattanaik00") is None or shutil.which("pfsin") is None:
        return None
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for k, frame in enumerate(frames):
            io.write_image(tmp / f"f{k:04d}.pfm", frame)
        stream = tmp / "frames.pfs"
        with open(stream, "wb") as f:
            pattern = str(tmp / "f%04d.pfm")
            subprocess.run(
                ["pfsin", pattern, "--frames", f"0:{len(frames) - 1}"], stdout=f, check=True
            )

        def pipe(*command):
            def go():
                with open(stream, "rb") as f:
                    subprocess.run(command, stdin=f, stdout=subprocess.DEVNULL, check=True)

            return go

        operator = median_seconds(
            pipe("pfstmo_pattanaik00", *pfstmo_options(local)), repeats=repeats
        )
        copy = median_seconds(pipe("cat"), repeats=repeats)
    return operator - copy


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="1920x1080")
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--label", default=None, help="machine label in the record and file name")
    parser.add_argument("--no-pfstmo", action="store_true", help="time jaxadapt only")
    parser.add_argument(
        "--background", default="global", help="global, or a local background (e.g. gaussian)"
    )
    parser.add_argument("--timing-only", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    if args.timing_only:  # the child of time_jaxadapt_retained
        frames = tunnel_frames(width, height, args.frames)
        timing = time_jaxadapt(frames, args.repeats, args.background)
        print(json.dumps({**timing, "copy_bytes_per_s": copy_bandwidth()}))
        return

    frames = tunnel_frames(width, height, args.frames)
    default = time_jaxadapt(frames, args.repeats, args.background)
    # On a GPU the frames live in JAX's own pool of device memory: no child.
    retained = time_jaxadapt_retained(args) if jax.default_backend() == "cpu" else None
    ours = (retained or default)["seconds"]
    local = args.background != "global"
    theirs = None if args.no_pfstmo else time_pfstmo(frames, args.repeats, local)
    bytes_moved = 2 * frames.nbytes  # read the frames, write the display frames
    bandwidth = (retained or {}).get("copy_bytes_per_s") or copy_bandwidth()
    record = {
        "machine": machine(args.label),
        "size": [width, height],
        "background": args.background,
        "pfstmo_options": " ".join(pfstmo_options(local)),
        "frames": args.frames,
        "repeats": args.repeats,
        "jaxadapt_seconds": ours,
        "jaxadapt_fps": args.frames / ours,
        "jaxadapt_retained_memory": retained,
        "jaxadapt_default_malloc": default,
        "jaxadapt_fps_default_malloc": args.frames / default["seconds"],
        "jaxadapt_GB_per_s": bytes_moved / ours / 1e9,
        "copy_GB_per_s": bandwidth / 1e9,
        "bandwidth_fraction": bytes_moved / ours / bandwidth,
        "pfstmo_core_seconds": theirs,
        "pfstmo_fps": None if theirs is None else args.frames / theirs,
        "speedup": None if theirs is None else theirs / ours,
        "speedup_default_malloc": None if theirs is None else theirs / default["seconds"],
    }
    label = record["machine"]["backend"] if args.label is None else args.label
    suffix = f"_{args.background}" if local else ""
    path = write_result(f"pattanaik2000_{label}_{width}x{height}{suffix}", record)
    for key, value in record.items():
        if key != "machine":
            print(f"{key:>20}: {value}")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
