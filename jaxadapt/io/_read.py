"""Reading HDR frames in cd/m2: OpenEXR, Radiance HDR, PFM and float TIFF,
rotated upright and converted to BT.709 primaries."""

import math
import re

import numpy as np

from jaxadapt.io._headers import _hdr_image, _one_line, display_window, reorient
from jaxadapt.io._remote import local_copy


def read_hdr(path):
    """Read a linear HDR image as a float32 ``(H, W, 3)`` array of linear
    BT.709 RGB (D65 white), top row first, left column first.

    Parameters
    ----------
    path : str or Path
        An OpenEXR, Radiance HDR, PFM or floating-point TIFF file. Its
        colour channels are found by name (:func:`rgb_channels`): R, G and
        B, or a luminance Y taken as grey; alpha and other channels are
        dropped. Of a multi-part EXR, the first part that has them is read.
        The pixel values are taken as they are: cd/m2 once the caller's
        calibration (``--multiplier``) is applied. An EXR's
        ``whiteLuminance`` attribute is not used; OpenImageIO multiplies a
        PFM's pixels by the magnitude of its header's scale. A Radiance
        file's pixels are divided by its exposure
        (:func:`radiance_exposure`).

    Returns
    -------
    numpy array, float32, (H, W, 3)
        The image's display window (:func:`display_window`), turned as its
        ``Orientation`` says (:func:`reorient`; a Radiance file's is its
        resolution line, ``+Y H +X W`` for rows stored bottom to top). Its
        RGB is converted to BT.709 (:func:`bt709_matrix`) from the primaries
        of an EXR's ``chromaticities`` attribute or a Radiance file's
        ``PRIMARIES=`` line; without them, as for PFM and TIFF, it is taken
        as BT.709. A grey (Y) image is not converted: its Y is the
        luminance in any primaries.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ValueError
        The file cannot be read, does not hold floating-point data, holds
        finite values beyond float32's range (a TIFF of doubles can), or its
        header is invalid (channels, orientation, primaries, exposure).
    """
    with local_copy(path) as local, _hdr_image(local) as (image, header):
        pixels = _read_pfm(local) if image.format_name() == "pnm" else None
        if pixels is None:  # doubles as they are, so that _as_float32 sees them
            pixels = image.read_image(format="double" if _doubles(header) else "float")
        if pixels is None:
            raise ValueError(f"{path}: cannot read pixels ({_one_line(image.geterror())})")
    spec = header.spec
    pixels = _as_float32(pixels, path).reshape(spec.height, spec.width, -1)
    if header.channels != list(range(pixels.shape[-1])):  # (a copy: only where needed)
        pixels = pixels[..., header.channels]
    pixels = display_window(pixels, spec)
    if header.exposure != 1:
        pixels = _within_float32(pixels, lambda x: x / np.float32(header.exposure))
    if header.to_bt709 is not None:
        pixels = to_bt709_gamut(pixels, header.to_bt709)
    return np.ascontiguousarray(reorient(pixels, header.orientation))


def _doubles(header):
    """Whether the file stores 64-bit floating-point pixels (TIFF can)."""
    return str(header.spec.format) == "double"


def _as_float32(pixels, path):
    """``pixels`` as float32, refusing finite values beyond its range: they
    would turn infinite, and be reported as if the file held infinities."""
    pixels = np.asarray(pixels)
    largest = float(np.finfo(np.float32).max)
    if pixels.dtype == np.float64:
        big = np.abs(np.nan_to_num(pixels, nan=0, posinf=0, neginf=0)).max(initial=0)
        if big > largest:
            raise ValueError(
                f"{path}: expected values within float32's range (up to {largest:.3g}), "
                f"got {big:.3g}; scale the file down (oiiotool {path} --mulc FACTOR -o OUT)"
            )
    return pixels.astype(np.float32, copy=False)


#: A PFM file's header: its kind (``PF`` colour, ``Pf`` grey), width,
#: height and scale (negative: little-endian), each followed by one blank.
_PFM_HEADER = re.compile(rb"(P[Ff])\s(\d+)\s(\d+)\s(\S+)\s")


def _read_pfm(path):
    """The pixels ``(H, W, C)`` of a PFM file whose header OpenImageIO has
    read, top row first and times the scale's magnitude, as OpenImageIO
    gives them; None for a header this does not parse (OpenImageIO then
    reads it). OpenImageIO reads the data in calls of a few kB, several
    times slower than one read of the whole. A file whose size is not its
    header's plus the pixels' is refused."""
    with open(path, "rb") as f:
        match = _PFM_HEADER.match(f.read(128))
    if match is None:
        return None
    kind, width, height, scale = match.groups()
    try:
        scale = float(scale)
    except ValueError:
        return None
    C, W, H = 3 if kind == b"PF" else 1, int(width), int(height)
    if path.stat().st_size != match.end() + H * W * C * 4 or not math.isfinite(scale):
        raise ValueError(
            f"{path}: cannot read pixels (expected {H * W * C * 4} bytes of data after the "
            f"header, got {path.stat().st_size - match.end()})"
        )
    dtype = "<f4" if scale < 0 else ">f4"
    rows = np.fromfile(path, dtype, count=H * W * C, offset=match.end()).reshape(H, W, C)
    pixels = rows[::-1].astype(np.float32)  # top row first, native byte order
    return (
        pixels if abs(scale) == 1 else _within_float32(pixels, lambda x: x * np.float32(abs(scale)))
    )


def to_bt709_gamut(rgb, matrix):
    """``rgb (..., 3)`` of a file's primaries as linear BT.709, ``matrix @
    rgb`` (:func:`bt709_matrix`), with the negative channels of colours
    outside BT.709's gamut clipped to 0.

    A saturated colour of a wider gamut (ACES, Rec.2020) has negative BT.709
    channels, which no display shows and which the operators, whose
    responses and colour ratios need light, refuse. Clipping keeps the hue
    roughly and adds a little light: ACEScg (100, 0, 0) is BT.709 (170.5,
    -13.0, -2.4), clipped (170.5, 0, 0). A pixel the file itself holds
    negative or NaN is left as converted, for the caller's check to refuse.
    A finite colour that converts beyond float32's range is clipped to its
    largest value (:func:`_within_float32`).
    """
    converted = _within_float32(rgb, lambda x: x @ matrix.T.astype(x.dtype), per_pixel=True)
    valid = np.all(rgb >= 0, axis=-1, keepdims=True)
    return np.where(valid, np.maximum(converted, 0), converted)


def _within_float32(values, fn, per_pixel=False):
    """``fn(values)`` (a scaling or a colour matrix), with the finite values
    it takes beyond float32's range (a legal 3.4e38 converted from ACES
    primaries, or divided by an exposure below 1) clipped to float32's
    largest, where the operators' luminance ceiling has long saturated
    them, instead of a NumPy overflow warning and an infinity that would be
    refused as if the file held one. What ``fn`` gives of a non-finite
    input (per value, or with ``per_pixel`` per pixel ``(..., 3)``) is kept
    as it is, for the caller's check to refuse."""
    with np.errstate(over="ignore", invalid="ignore"):
        out = fn(values)
    finite = np.isfinite(values)
    if per_pixel:
        finite = np.all(finite, axis=-1, keepdims=True)
    largest = np.finfo(np.float32).max
    if np.isfinite(out).all() or not finite.any():
        return out
    return np.where(finite, np.clip(out, -largest, largest), out)


def hdr_size(path):
    """``(width, height)`` of the image :func:`read_hdr` would read (turned
    as its orientation says), from the file's header alone.

    It runs :func:`read_hdr`'s checks of the header (channels, data type,
    orientation, primaries, Radiance exposure) and raises the same errors;
    pixel data that are truncated or corrupt are found only by reading them.
    """
    with local_copy(path) as local, _hdr_image(local) as (_, header):
        width, height = header.spec.full_width, header.spec.full_height
        return (height, width) if header.orientation > 4 else (width, height)


def frame_rate(path):
    """The frame rate a file's header gives, frames/s; None without one.

    OpenEXR's ``framesPerSecond`` (a rational, such as 24000/1001), which
    OpenImageIO reports as ``FramesPerSecond`` for any format that has it.
    Runs :func:`read_hdr`'s checks of the header and raises its errors, and
    ``ValueError`` naming the file for a rate that is not positive and
    finite (0/0, 30/0).
    """
    with local_copy(path) as local, _hdr_image(local) as (_, header):
        rate = header.spec.getattribute("FramesPerSecond")
    if rate is None:
        return None
    numerator, denominator = rate if isinstance(rate, tuple) else (rate, 1)
    value = numerator / denominator if denominator else math.inf
    if not (math.isfinite(value) and value > 0):
        raise ValueError(
            f"{path}: expected a positive, finite FramesPerSecond, got {numerator}/{denominator}"
        )
    return value
