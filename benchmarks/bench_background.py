"""Megapixels per second of the local background estimators, against cv2.bilateralFilter.

Times, on one float32 luminance image (default 1920x1080, log-normal over
about four decades):

* ``bilateral``: :func:`jaxadapt.background.bilateral_background`,
  Durand-Dorsey weights (Gaussian ``w`` with ``s = --scale``, i.e. a disc of
  radius ``ceil(sqrt(2) s)``, and a Gaussian of 0.4 log10 units on log
  luminance), the exact windowed Eq 6.5;
* ``bilateral_pattanaik_yee``: the same with the circular box and the
  exponential weight;
* ``adaptive``: :func:`jaxadapt.background.adaptive_background`
  (8 sizes, radii 0, 1, 3, ..., 127: 7 doublings);
* ``box`` and ``gaussian``: the plain local averages of Eq 6.4 (``s = 8``),
  for scale;
* ``cv2_bilateral``: OpenCV's ``cv2.bilateralFilter`` on log10 luminance
  with the same window, ``sigmaSpace`` and ``sigmaColor`` (the same
  weights: our Durand-Dorsey estimator averages luminance where OpenCV
  averages its input, which costs the same).

Each jaxadapt function is jitted and compiled first; timings block until
the result is ready; median of ``--repeats``. Writes
``benchmarks/results/background.json`` (or ``background_<label>.json``).

Usage::

    python benchmarks/bench_background.py [--size 1920x1080] [--repeats 5] [--scale 4]
                                          [--label NAME]
"""

import argparse
import functools
import os

import cv2
import jax
import jax.numpy as jnp
import numpy as np
from common import machine, median_seconds, write_result

from jaxadapt import background


def luminance_image(width, height, seed=0):
    """A float32 HDR luminance image, log-normal: median 50 cd/m2, 1 decade s.d."""
    rng = np.random.default_rng(seed)
    return (50.0 * 10.0 ** rng.normal(size=(height, width))).astype(np.float32)


def ours(scale):
    return {
        "bilateral": functools.partial(background.bilateral_background, scale=scale),
        "bilateral_pattanaik_yee": functools.partial(
            background.bilateral_background, scale=scale, kind="pattanaik-yee"
        ),
        "adaptive": background.adaptive_background,
        "box": functools.partial(background.box_background, scale=8.0),
        "gaussian": functools.partial(background.gaussian_background, scale=8.0),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="1920x1080")
    parser.add_argument("--scale", type=float, default=4.0, help="bilateral size s, pixels")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--label", default=None, help="machine label in the record and file name")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    megapixels = width * height / 1e6

    L = luminance_image(width, height)
    device_L = jax.device_put(jnp.asarray(L))
    record = {
        "machine": {
            **machine(args.label),
            "cv2": cv2.__version__,
            "cv2_threads": cv2.getNumThreads(),
            "load_average_1min": os.getloadavg()[0],
        },
        "size": [width, height],
        "repeats": args.repeats,
        "bilateral_scale_px": args.scale,
        "seconds": {},
        "megapixels_per_s": {},
    }
    for name, f in ours(args.scale).items():
        seconds = median_seconds(lambda f=f: jax.block_until_ready(f(device_L)), args.repeats)
        record["seconds"][name] = seconds

    R = int(np.ceil(np.sqrt(2.0) * args.scale))
    log_L = np.log10(L)
    record["cv2_window_diameter_px"] = 2 * R + 1
    record["seconds"]["cv2_bilateral"] = median_seconds(
        lambda: cv2.bilateralFilter(
            log_L, 2 * R + 1, 0.4, args.scale / np.sqrt(2.0), borderType=cv2.BORDER_REFLECT_101
        ),
        args.repeats,
    )
    record["megapixels_per_s"] = {k: megapixels / s for k, s in record["seconds"].items()}
    record["bilateral_vs_cv2"] = record["seconds"]["cv2_bilateral"] / record["seconds"]["bilateral"]
    path = write_result("background", record, args.label)
    for key, value in record["megapixels_per_s"].items():
        print(f"{key:>24}: {value:8.2f} MP/s  ({record['seconds'][key] * 1e3:.1f} ms)")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
