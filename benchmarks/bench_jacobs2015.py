"""Frames per second of the full Jacobs 2015 pipeline (gaze-aware afterimages and mesopic cues).

Renders ``--frames`` float32 frames of the coloured-patch afterimage
stimulus around its saccade (so that the retinal maps move) at each
``--sizes``, then times, with every effect on (compile excluded,
``block_until_ready``, median of ``--repeats``):

* ``stepped``: one jitted :func:`jaxadapt.operators.jacobs2015.step` a
  frame, each call waiting for its frame, as the live viewer renders;
* ``run``: one :func:`~jaxadapt.operators.jacobs2015.run` over the frames;
* ``dark``: stepped, on the same frames dimmed 10,000 times (0.02 to 0.03
  cd/m2, mesopic): the acuity loss then blurs (in photopic light it has
  nothing to do and costs nothing).

At the largest size, ``acuity`` repeats ``dark`` with the display's pixels
per degree times each of ``--acuity-scales`` (a denser display or a
farther viewer: the acuity bands widen with it), and times the eight
bands' blurs and their per-pixel choice alone, every band needed: by
:func:`jaxadapt.spatial.gaussian_ladder` as the operator makes them
(``ladder_ms``), and by direct blurs, each fused into its choice as the
operator made them before (``direct_ms``, the peer).

The process keeps freed memory (:func:`jaxadapt.runtime.retain_freed_memory`)
and lets XLA use AVX-512's full width (:func:`jaxadapt.runtime.use_wide_vectors`)
as every ``jaxadapt`` command, the live viewer's included, does.

The per-pixel state read and written each frame is the frame (3 floats),
the L, M, S bleaching and calcium maps (6 floats, read and written) and the
display frame (3 floats): 18 floats per pixel, the ``bytes_per_frame``
that a frame rate turns into a bandwidth, against the copy bandwidth of
the same device measured in the same run (``copy_GB_per_s``, the peer).

Usage::

    python benchmarks/bench_jacobs2015.py [--sizes 384x216 960x540 1920x1080]
                                          [--frames 8] [--repeats 5] [--label NAME]
                                          [--acuity-scales 1 2 4]

Writes ``benchmarks/results/jacobs2015_<label>.json`` (label by default the
JAX backend).
"""

import argparse
import os

from jaxadapt import runtime

runtime.use_wide_vectors()  # before the first JAX computation, as the CLI does
runtime.retain_freed_memory()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from common import copy_bandwidth, machine, median_seconds, write_result  # noqa: E402

from jaxadapt import scenes  # noqa: E402
from jaxadapt.operators import jacobs2015 as op  # noqa: E402
from jaxadapt.spatial import channels_last_filter, gaussian_kernel, gaussian_ladder  # noqa: E402

FPS = 30.0
#: Dimming of the ``dark`` frames: 200-300 cd/m2 to 0.02-0.03, mesopic.
DARK = 1e-4


def patch_frames(width, height, count):
    """``count`` frames of the coloured patches, centred on the saccade (5 s)."""
    scene = scenes.patches(width, height, duration=5.0 + count / FPS, fps=FPS)
    times = scene.times[-count:] - count // 2 / FPS
    return np.asarray(scene.render(times)), np.asarray(scene.gaze(times)), scene


def time_stepped(params, frames, gaze, repeats):
    """Median seconds a frame, one jitted ``step`` a call, waiting for each."""
    dt = jnp.float32(1 / FPS)
    start = op.init(params, frames[0], gaze=gaze[0], key=jax.random.key(0))

    # One array a frame, as the viewer hands them over (slicing a stacked
    # array in the loop would add a dispatched slice to each frame's time).
    frames, gaze = list(frames), list(gaze)

    def go():
        state = start
        for frame, sample in zip(frames, gaze, strict=True):
            state, out = op.step(params, state, frame, dt, gaze=sample)
            jax.block_until_ready(out)

    return median_seconds(go, repeats=repeats) / len(frames)


def time_run(params, frames, gaze, repeats):
    """Median seconds a frame of one ``run`` over ``frames``."""
    dt = jnp.float32(1 / FPS)
    key = jax.random.key(0)

    def go():
        jax.block_until_ready(op.run(params, frames, dt, gaze=gaze, key=key))

    return median_seconds(go, repeats=repeats) / frames.shape[0]


def measure(width, height, count, repeats, bandwidth):
    """The record of one size: frames per second and bandwidth fractions."""
    frames, gaze, scene = patch_frames(width, height, count)
    frames = jax.device_put(jnp.asarray(frames, jnp.float32))
    gaze = jax.device_put(jnp.asarray(gaze, jnp.float32))
    params = op.Params(pixels_per_degree=scene.pixels_per_degree)
    seconds = {
        "stepped": time_stepped(params, frames, gaze, repeats),
        "run": time_run(params, frames, gaze, repeats),
        "dark": time_stepped(params, frames * DARK, gaze, repeats),
    }
    bytes_per_frame = 18 * 4 * width * height
    record = {"size": [width, height], "bytes_per_frame": bytes_per_frame}
    for name, s in seconds.items():
        record[f"{name}_ms"] = 1e3 * s
        record[f"{name}_fps"] = 1 / s
        record[f"{name}_bandwidth_fraction"] = bytes_per_frame / s / bandwidth
    return record


def time_blurs(sigmas, frame, repeats):
    """Median seconds of the acuity bands' blurs and per-pixel choice, every
    band needed, by the ladder and by direct blurs: ``(ladder, direct)``."""
    dropped = jnp.asarray(np.arange(frame.shape[0] * frame.shape[1]) % (len(sigmas) + 1))
    dropped = dropped.reshape(frame.shape[:2])

    def chosen(blurs, frame, dropped):
        seen = frame
        for f, blurred in enumerate(blurs):
            keeps = dropped == f + 1

            def select(seen, keeps=keeps, blurred=blurred):
                return jnp.where(keeps[..., None], blurred(), seen)

            seen = jax.lax.cond(jnp.any(keeps), select, lambda seen: seen, seen)
        return seen

    ladder = jax.jit(lambda x, d: chosen(gaussian_ladder(x, sigmas), x, d))
    direct = jax.jit(
        lambda x, d: chosen(
            [lambda s=s: channels_last_filter(x, gaussian_kernel(s)) for s in sigmas], x, d
        )
    )
    return tuple(
        median_seconds(lambda f=f: jax.block_until_ready(f(frame, dropped)), repeats=repeats)
        for f in (ladder, direct)
    )


def measure_acuity(width, height, count, repeats, scales):
    """The mesopic step and the acuity blurs at each scale of the display's
    pixels per degree."""
    frames, gaze, scene = patch_frames(width, height, count)
    frames = jax.device_put(jnp.asarray(frames * DARK, jnp.float32))
    gaze = jax.device_put(jnp.asarray(gaze, jnp.float32))
    records = []
    for scale in scales:
        params = op.Params(pixels_per_degree=scene.pixels_per_degree * scale)
        ladder, direct = time_blurs(op.acuity_sigmas(params), frames[0], repeats)
        dark = time_stepped(params, frames, gaze, repeats)
        records.append(
            {
                "pixels_per_degree": scene.pixels_per_degree * scale,
                "sigmas_px": [float(s) for s in op.acuity_sigmas(params)],
                "dark_ms": 1e3 * dark,
                "ladder_ms": 1e3 * ladder,
                "direct_ms": 1e3 * direct,
            }
        )
        print(
            f"acuity x{scale}: dark {records[-1]['dark_ms']:.0f} ms a frame; blurs "
            f"{records[-1]['ladder_ms']:.0f} ms, direct {records[-1]['direct_ms']:.0f}",
            flush=True,
        )
    return {"size": [width, height], "scales": records}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--sizes",
        "--size",
        nargs="+",
        default=["384x216", "960x540", "1920x1080"],
        help="WIDTHxHEIGHT, pixels",
    )
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--label", default=None, help="machine label in the record and file name")
    parser.add_argument(
        "--acuity-scales",
        nargs="*",
        type=float,
        default=[1.0, 2.0, 4.0],
        help="factors of the pixels per degree for the acuity rows, at the largest size",
    )
    args = parser.parse_args()

    load_before = os.getloadavg()[0]  # other work sharing the machine
    bandwidth = copy_bandwidth()
    sizes = []
    for size in args.sizes:
        width, height = (int(v) for v in size.split("x"))
        sizes.append(measure(width, height, args.frames, args.repeats, bandwidth))
        print(
            f"{size}: stepped {sizes[-1]['stepped_fps']:.2f} frames/s, "
            f"run {sizes[-1]['run_fps']:.2f}, dark {sizes[-1]['dark_fps']:.2f}",
            flush=True,
        )
    record = {
        "machine": machine(args.label),
        "load_average_1min": [load_before, os.getloadavg()[0]],  # before, after
        "frames": args.frames,
        "repeats": args.repeats,
        "retained_freed_memory": True,
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "copy_GB_per_s": bandwidth / 1e9,
        "sizes": sizes,
    }
    if args.acuity_scales:
        width, height = max(sizes, key=lambda r: r["size"][0] * r["size"][1])["size"]
        record["acuity"] = measure_acuity(
            width, height, args.frames, args.repeats, args.acuity_scales
        )
    label = args.label or record["machine"]["backend"]
    print(f"wrote {write_result(f'jacobs2015_{label}', record)}")


if __name__ == "__main__":
    main()
