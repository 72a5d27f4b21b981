"""Seconds to write one 1920x1080 frame as PNG and EXR, by compression setting.

The writers of a render (:func:`jaxadapt.io.write_image`, OpenImageIO) at
the settings it uses, against OpenImageIO's defaults (zlib level 6 for PNG,
with libpng choosing a filter for each row; ``zip`` at OpenEXR's level for
EXR), no compression, and NumPy writing the
same bytes raw (the floor: what the disk and the page cache cost). Two
frames: one with the statistics of natural scenes (log luminance with an
amplitude spectrum falling as 1/f, Field 1987, and a little colour), whose
float values use every bit, and the built-in tunnel at its middle frame,
smooth and synthetic. The file size of each is recorded beside its time.

    python benchmarks/bench_writers.py [--repeats 7]
"""

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

HERE = Path(__file__).parent
WIDTH, HEIGHT = 1920, 1080

#: Settings by format: header attributes, None for OpenImageIO's defaults.
SETTINGS = {
    "png": {
        "jaxadapt": "chosen",
        "level 6, best filter a row (default)": {},
        "level 1, best filter a row": {"png:compressionLevel": 1},
        "level 0": {"png:compressionLevel": 0},
    },
    "exr": {
        "jaxadapt": "chosen",
        "zip (default)": {},
        "piz": {"compression": "piz"},
        "rle": {"compression": "rle"},
        "none": {"compression": "none"},
    },
}


def natural_display(rng):
    """Display values in [0, 1] of a frame with natural-scene statistics."""

    def one_over_f(rng):
        spectrum = np.fft.rfft2(rng.standard_normal((HEIGHT, WIDTH)))
        radius = np.hypot(np.fft.fftfreq(HEIGHT)[:, None], np.fft.rfftfreq(WIDTH)[None, :])
        radius[0, 0] = 1.0
        field = np.fft.irfft2(spectrum / radius, s=(HEIGHT, WIDTH))
        return (field - field.mean()) / field.std()

    luminance = 10.0 ** (1.0 + 1.2 * one_over_f(rng))
    colour = np.exp(0.1 * np.stack([one_over_f(rng) for _ in range(3)], axis=-1))
    hdr = luminance[..., None] * colour
    return (hdr / (1.0 + hdr)).astype(np.float32)


def tunnel_display():
    """The middle frame of the built-in tunnel, tone-mapped to [0, 1]."""
    from jaxadapt.scenes import tunnel_drive

    scene = tunnel_drive(width=WIDTH, height=HEIGHT, duration=2.0, fps=30.0)
    hdr = np.asarray(scene.render(scene.times[30:31]), np.float32)[0]
    return (hdr / (1.0 + hdr)).astype(np.float32)


def write_oiio(path, pixels, attributes):
    out = oiio.ImageOutput.create(str(path))
    spec = oiio.ImageSpec(
        pixels.shape[1], pixels.shape[0], 3, "uint8" if pixels.dtype == np.uint8 else "float"
    )
    for name, value in attributes.items():
        spec.attribute(name, value)
    if not (out.open(str(path), spec) and out.write_image(pixels)):
        raise OSError(out.geterror())
    out.close()


def timed(write, path, repeats):
    """(median seconds of ``write()``, size of the file it wrote, bytes)."""
    times = []
    for _ in range(repeats + 1):
        start = time.perf_counter()
        write()
        times.append(time.perf_counter() - start)
    return statistics.median(times[1:]), os.path.getsize(path)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--label", default="cpu-2core")
    args = parser.parse_args()

    from jaxadapt import display, io

    frames = {"natural": natural_display(np.random.default_rng(0)), "tunnel": tunnel_display()}
    record = {"repeats": args.repeats, "size": [WIDTH, HEIGHT], "frames": {}}
    with tempfile.TemporaryDirectory() as scratch:
        for name, linear in frames.items():
            pixels = {"png": np.asarray(display.encode_uint8(linear)), "exr": linear}
            rows = {}
            for fmt, settings in SETTINGS.items():
                path = Path(scratch) / f"frame.{fmt}"
                for setting, attributes in settings.items():
                    if attributes == "chosen":
                        write = lambda p=path, x=pixels[fmt]: io.write_image(p, x)  # noqa: E731
                    else:
                        write = lambda p=path, x=pixels[fmt], a=attributes: write_oiio(p, x, a)  # noqa: E731
                    seconds, size = timed(write, path, args.repeats)
                    rows[f"{fmt} {setting}"] = {"s": seconds, "bytes": size}
                raw = Path(scratch) / "frame.raw"
                seconds, size = timed(lambda p=raw, x=pixels[fmt]: x.tofile(p), raw, args.repeats)
                rows[f"{fmt} raw bytes (numpy)"] = {"s": seconds, "bytes": size}
            record["frames"][name] = rows
            for row, value in rows.items():
                print(
                    f"{name:8} {row:28} {value['s'] * 1e3:7.1f} ms {value['bytes'] / 1e6:7.2f} MB"
                )
    sys.path.insert(0, str(HERE))
    from common import machine, write_result

    record["machine"] = machine(args.label)
    print(write_result("writers", record, args.label))


if __name__ == "__main__":
    main()
