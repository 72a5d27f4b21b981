"""Other implementations, run on our frames for comparison.

:func:`pfstmo_pattanaik00` pipes frames through pfstools' implementation of
the 2000 operator (Debian packages ``pfstmo`` and ``pfstools``), as the
tests, the benchmarks and the experiments compare with it.
"""

import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from jaxadapt.io import read_hdr, write_image

__all__ = ["pfstmo_available", "pfstmo_pattanaik00"]


def pfstmo_available():
    """Whether ``pfsin``, ``pfsout`` and ``pfstmo_pattanaik00`` are on the PATH."""
    return all(shutil.which(c) for c in ("pfsin", "pfsout", "pfstmo_pattanaik00"))


def pfstmo_pattanaik00(frames, *options):
    """Run ``pfsin | pfstmo_pattanaik00 --verbose OPTIONS | pfsout`` on frames.

    Parameters
    ----------
    frames : array, shape (T, H, W, 3)
        Linear RGB, cd/m2.
    *options : str
        Options of ``pfstmo_pattanaik00``, e.g. ``"-t", "--fps", "30"``.

    Returns
    -------
    (numpy array, str)
        Its output frames ``(T, H, W, 3)`` (linear, relative to display
        white) and its ``--verbose`` report.
    """
    frames = np.asarray(frames, np.float32)
    # OpenEXR both ways: a PFM round trip through pfstools comes back upside down
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for k, frame in enumerate(frames):
            write_image(tmp / f"in_{k:05d}.exr", frame)
        # The report goes to a file: read from a pipe only at the end, a long
        # report would fill the pipe and the three processes would deadlock.
        with open(tmp / "report.txt", "w+b") as report_file:
            read = subprocess.Popen(
                ["pfsin", str(tmp / "in_%05d.exr"), "--frames", f"0:{len(frames) - 1}"],
                stdout=subprocess.PIPE,
            )
            tmo = subprocess.Popen(
                ["pfstmo_pattanaik00", "--verbose", *options],
                stdin=read.stdout,
                stdout=subprocess.PIPE,
                stderr=report_file,
            )
            read.stdout.close()
            write = subprocess.run(
                ["pfsout", str(tmp / "out_%05d.exr")], stdin=tmo.stdout, capture_output=True
            )
            tmo.stdout.close()
            failed = [tmo.wait(), read.wait(), write.returncode]
            report_file.seek(0)
            report = report_file.read().decode()
        if any(failed):
            raise RuntimeError(f"pfstmo_pattanaik00 failed: {report or write.stderr.decode()}")
        out = np.stack([read_hdr(tmp / f"out_{k:05d}.exr") for k in range(len(frames))])
    return out, report
