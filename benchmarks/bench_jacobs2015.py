"""Frames per second of the full Jacobs 2015 pipeline (gaze-aware afterimages and mesopic cues).

Renders ``--frames`` float32 frames of the coloured-patch afterimage
stimulus around its saccade (so that the retinal maps move), then times one
jitted :func:`jaxadapt.operators.jacobs2015.run` over them with every effect
on (compile excluded, ``block_until_ready``, median of repeats), and the
same without the acuity loss, its costliest stage.

The per-pixel state read and written each frame is the frame (3 floats),
the L, M, S bleaching and calcium maps (6 floats, read and written) and the
display frame (3 floats): 18 floats per pixel, the ``bytes_per_frame``
against which a GPU's memory bandwidth bounds the frame rate.

Usage::

    python benchmarks/bench_jacobs2015.py [--size 1920x1080] [--frames 4] [--repeats 3]
                                          [--label NAME]

Writes ``benchmarks/results/jacobs2015_<label>.json`` (label by default the
JAX backend).
"""

import argparse
import dataclasses
import os

import jax
import jax.numpy as jnp
import numpy as np
from common import copy_bandwidth, machine, median_seconds, write_result

from jaxadapt import scenes
from jaxadapt.operators import jacobs2015 as op

FPS = 30.0


def patch_frames(width, height, count):
    """``count`` frames of the coloured patches, centred on the saccade (5 s)."""
    scene = scenes.patches(width, height, duration=5.0 + count / FPS, fps=FPS)
    times = scene.times[-count:] - count // 2 / FPS
    return np.asarray(scene.render(times)), np.asarray(scene.gaze(times)), scene


def time_run(params, frames, gaze, repeats):
    dt = jnp.float32(1 / FPS)
    key = jax.random.key(0)

    def go():
        jax.block_until_ready(op.run(params, frames, dt, gaze=gaze, key=key))

    return median_seconds(go, repeats=repeats)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="1920x1080", help="WIDTHxHEIGHT, pixels")
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--label", default=None, help="machine label in the record and file name")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))

    frames, gaze, scene = patch_frames(width, height, args.frames)
    frames = jax.device_put(jnp.asarray(frames, jnp.float32))
    gaze = jax.device_put(jnp.asarray(gaze, jnp.float32))
    full = op.Params(pixels_per_degree=scene.pixels_per_degree)
    seconds = time_run(full, frames, gaze, args.repeats)
    no_acuity = time_run(dataclasses.replace(full, acuity=False), frames, gaze, args.repeats)
    bytes_per_frame = 18 * 4 * width * height
    bandwidth = copy_bandwidth()
    record = {
        "machine": machine(args.label),
        "load_average_1min": os.getloadavg()[0],  # other work sharing the machine
        "size": [width, height],
        "frames": args.frames,
        "repeats": args.repeats,
        "full_seconds": seconds,
        "full_fps": args.frames / seconds,
        "no_acuity_fps": args.frames / no_acuity,
        "bytes_per_frame": bytes_per_frame,
        "full_GB_per_s": bytes_per_frame * args.frames / seconds / 1e9,
        "copy_GB_per_s": bandwidth / 1e9,
        "bandwidth_fraction": bytes_per_frame * args.frames / seconds / bandwidth,
    }
    label = args.label or record["machine"]["backend"]
    path = write_result(f"jacobs2015_{label}", record)
    for key, value in record.items():
        if key != "machine":
            print(f"{key:>16}: {value}")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
