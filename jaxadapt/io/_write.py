"""Writing display frames and tables, each to a temporary file beside its
target renamed into place, so that an interrupted run leaves no half file."""

import contextlib
import csv
import os
import tempfile
from fractions import Fraction
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from jaxadapt.io._headers import _one_line

#: The largest term of a header's rational (OpenEXR's ``Rational``: int, unsigned int).
_INT32_MAX = 2**31 - 1


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path beside ``path``; rename it to ``path`` on success."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp's 0600 would outlive the rename
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


#: OpenImageIO's names of the display encodings of :mod:`jaxadapt.display`,
#: with which 8-bit files are tagged (PNG: an sRGB chunk, or a gAMA of 1/2.2).
COLOUR_SPACES = {"srgb": "sRGB", "gamma": "Gamma2.2"}


#: Deflate level of PNG frames and of EXR's lossless ``zip``: the fastest, 1.
#: The frames of a render are the work its writer thread must keep up with,
#: and natural frames barely compress further at higher levels (EXR's
#: full-precision floats not at all); ``benchmarks/bench_writers.py``.
DEFLATE_LEVEL = 1


#: PNG's Paeth filter on every row (ISO/IEC 15948, filter type 4), where
#: libpng by default tries all five filters on each row and keeps the best.
PNG_PAETH = 0x80


#: Header attributes that set the compression of a written file, by suffix.
COMPRESSION = {
    ".png": {"png:compressionLevel": DEFLATE_LEVEL, "png:filter": PNG_PAETH},
    ".exr": {"compression": f"zip:{DEFLATE_LEVEL}"},
}


def write_image(path, pixels, encoding="srgb", fps=None):
    """Write ``(H, W, C)`` pixels: uint8 for PNG (and JPEG), floating point
    for EXR, Radiance HDR and PFM, either for TIFF; other pixels are refused
    before anything is written (:func:`_check_pixels`).

    ``encoding`` (``"srgb"`` or ``"gamma"``, see :mod:`jaxadapt.display`)
    tags 8-bit pixels with the transfer function they were encoded with, so
    that colour-managed viewers decode them with it. ``fps``, a frame of a
    sequence at that rate (frames/s), goes into the header where the format
    has a place for it (an EXR's ``framesPerSecond``, which
    :func:`frame_rate` reads back), as the nearest fraction of 32-bit terms
    with a denominator of at most 1e6 (24000/1001 for 23.976...). PNG and
    EXR are compressed losslessly, for speed (:data:`COMPRESSION`).
    """
    pixels = np.ascontiguousarray(pixels)
    _check_pixels(path, pixels)
    kind = "uint8" if pixels.dtype == np.uint8 else "float"
    suffix = Path(path).suffix.lower()
    if suffix == ".pfm":
        _write_pfm(path, pixels)
        return
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(path))
        if out is None:
            raise ValueError(f"{path}: no image writer for this format")
        spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], kind)
        if kind == "uint8":
            spec.attribute("oiio:ColorSpace", COLOUR_SPACES[encoding])
        for name, value in COMPRESSION.get(suffix, {}).items():
            spec.attribute(name, value)
        if fps is not None:
            most = min(10**6, int(_INT32_MAX // max(fps, 1.0)))  # the numerator fits too
            rate = Fraction(fps).limit_denominator(most)
            spec.attribute(
                "FramesPerSecond", oiio.TypeDesc("rational2i"), (rate.numerator, rate.denominator)
            )
        if not (out.open(tmp, spec) and out.write_image(pixels)):
            msg = _one_line(out.geterror())
            out.close()
            raise OSError(f"{path}: cannot write ({msg})")
        out.close()


def _write_pfm(path, pixels):
    """Write floating-point ``(H, W, C)`` pixels as a PFM file: the header
    (``PF`` for 3 channels, ``Pf`` for 1; the size; ``-1.0``, little-endian
    float32) and the rows bottom to top, as the format stores them.

    Written here because OpenImageIO's PFM writer passes each value to its
    output stream in a call of its own, many times slower than writing the
    rows at once. The file reads back through OpenImageIO
    (:func:`read_hdr`) to the same values.
    """
    C = pixels.shape[2]
    if C not in (1, 3):
        raise OSError(f"{path}: cannot write (PFM holds 1 or 3 channels, got {C})")
    header = f"P{'F' if C == 3 else 'f'}\n{pixels.shape[1]} {pixels.shape[0]}\n-1.0\n"
    rows = np.ascontiguousarray(pixels[::-1], dtype="<f4")
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(header.encode("ascii"))
        rows.tofile(f)


#: Formats of 8-bit display values and of floating-point values (TIFF holds either).
EIGHT_BIT_FORMATS = (".png", ".jpg", ".jpeg")


FLOAT_FORMATS = (".exr", ".hdr", ".pfm")


def _check_pixels(path, pixels):
    """Refuse pixels :func:`write_image` cannot write to ``path`` as they
    are: not ``(H, W, C)`` with 1 to 4 channels, neither uint8 nor floating
    point, floats for an 8-bit format (written unencoded, a linear 0.5 as
    128: too dark on any display) or integers for a floating-point one."""
    if pixels.ndim != 3 or not 1 <= pixels.shape[2] <= 4:
        raise ValueError(
            f"pixels: expected shape (H, W, C) with 1 to 4 channels, got shape {pixels.shape}"
        )
    if pixels.dtype != np.uint8 and not np.issubdtype(pixels.dtype, np.floating):
        # written as floats, uint16 1000 read back as 1000/65535
        raise ValueError(f"pixels: expected uint8 or floating-point values, got {pixels.dtype}")
    suffix = Path(path).suffix.lower()
    if suffix in EIGHT_BIT_FORMATS and pixels.dtype != np.uint8:
        raise ValueError(
            f"{path}: expected uint8 display-encoded pixels for a {suffix} file, got "
            f"{pixels.dtype} (encode linear values first: jaxadapt.display.to_uint8("
            "jaxadapt.display.encode_srgb(pixels)))"
        )
    if suffix in FLOAT_FORMATS and not np.issubdtype(pixels.dtype, np.floating):
        raise ValueError(
            f"{path}: expected floating-point pixels for a {suffix} file, got {pixels.dtype}"
        )


def csv_writer(file, fieldnames=None):
    """A ``csv`` writer on ``file`` (a ``DictWriter`` with ``fieldnames``)
    that ends its lines with LF: the csv module's default, CRLF, shows as a
    stray ``\\r`` in Unix tools (``cut``, ``awk``) and in diffs."""
    if fieldnames is None:
        return csv.writer(file, lineterminator="\n")
    return csv.DictWriter(file, fieldnames=fieldnames, lineterminator="\n")


def write_columns(path, table):
    """Write the 1-D columns of ``table`` (a dict of equal-length arrays) as CSV.

    One row per entry (per frame, for diagnostics), numbers to six
    significant digits; columns of other ranks (e.g. sampled curves) are
    left out. The file appears only once complete.
    """
    columns = [name for name, column in table.items() if np.ndim(column) == 1]
    rows = zip(*(table[name] for name in columns), strict=True)
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as f:
        writer = csv_writer(f)
        writer.writerow(columns)
        writer.writerows([f"{value:.6g}" for value in row] for row in rows)
