"""Reading HDR frames and writing display frames, with OpenImageIO.

Every writer writes to a temporary file beside its target and renames it
into place, so an interrupted or failed run never leaves a half-written
file.
"""

import contextlib
import csv
import math
import os
import re
import tempfile
import warnings
from fractions import Fraction
from pathlib import Path
from typing import NamedTuple

import numpy as np
import OpenImageIO as oiio

from jaxadapt.color import BT709_CHROMATICITIES

_FLOAT_FORMATS = ("float", "half", "double")
#: The largest term of a header's rational (OpenEXR's ``Rational``: int, unsigned int).
_INT32_MAX = 2**31 - 1


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
        The file cannot be read, does not hold floating-point data, or its
        header is invalid (channels, orientation, primaries, exposure).
    """
    path = Path(path)
    with _hdr_image(path) as (image, header):
        pixels = _read_pfm(path) if image.format_name() == "pnm" else None
        if pixels is None:
            pixels = image.read_image(format="float")
        if pixels is None:
            raise ValueError(f"{path}: cannot read pixels ({_one_line(image.geterror())})")
    spec = header.spec
    pixels = np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, -1)
    if header.channels != list(range(pixels.shape[-1])):  # (a copy: only where needed)
        pixels = pixels[..., header.channels]
    pixels = display_window(pixels, spec)
    if header.exposure != 1:
        pixels = pixels / np.float32(header.exposure)
    if header.to_bt709 is not None:
        pixels = to_bt709_gamut(pixels, header.to_bt709)
    return np.ascontiguousarray(reorient(pixels, header.orientation))


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
    return pixels if abs(scale) == 1 else pixels * np.float32(abs(scale))


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
    """
    converted = rgb @ matrix.T.astype(rgb.dtype)
    valid = np.all(rgb >= 0, axis=-1, keepdims=True)
    return np.where(valid, np.maximum(converted, 0), converted)


def hdr_size(path):
    """``(width, height)`` of the image :func:`read_hdr` would read (turned
    as its orientation says), from the file's header alone.

    It runs :func:`read_hdr`'s checks of the header (channels, data type,
    orientation, primaries, Radiance exposure) and raises the same errors;
    pixel data that are truncated or corrupt are found only by reading them.
    """
    with _hdr_image(Path(path)) as (_, header):
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
    with _hdr_image(Path(path)) as (_, header):
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


class _Header(NamedTuple):
    """What :func:`read_hdr` takes from an HDR file's header (:func:`_header`)."""

    spec: oiio.ImageSpec  # of the part read
    channels: list  # indices of its R, G and B (:func:`rgb_channels`)
    orientation: int  # EXIF, 1 to 8 (:func:`reorient`)
    exposure: float  # the pixels' divisor (:func:`radiance_exposure`)
    to_bt709: np.ndarray | None  # RGB to BT.709 (:func:`bt709_matrix`), None if BT.709


@contextlib.contextmanager
def _hdr_image(path):
    """The open OpenImageIO input of an HDR file at its colour part and the
    file's :class:`_Header` (:func:`_header`); closed after the block."""
    if path.is_dir():
        raise ValueError(f"{path}: expected an HDR image file, got a folder")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    # PFM stores its rows bottom to top. OpenImageIO turns them the right way
    # up only when opened with a configuration (``pnm:pfmflip``, default 1);
    # opened without one it can return them upside down, while its writer
    # stores them as the format says.
    config = oiio.ImageSpec()
    config.attribute("pnm:pfmflip", 1)
    image = oiio.ImageInput.open(str(path), config)
    if image is None:
        raise ValueError(f"{path}: cannot read as an image ({_one_line(oiio.geterror())})")
    try:
        yield image, _header(image, path)
    finally:
        image.close()


def _header(image, path):
    """The checked :class:`_Header` of an open HDR file ``image``, left at
    its colour part (:func:`_colour_part`): the one check of a file's header
    that :func:`read_hdr` and :func:`hdr_size` share."""
    spec, channels = _colour_part(image, path)
    kind, is_rgbe = str(spec.format), image.format_name() == "hdr"
    if kind not in _FLOAT_FORMATS and not is_rgbe:
        raise ValueError(
            f"{path}: expected HDR data (float EXR, Radiance HDR, PFM or float TIFF), "
            f"got {kind} {image.format_name()}"
        )
    lines = _radiance_header(path) if is_rgbe else []
    chromaticities = (
        radiance_primaries(lines, path) if is_rgbe else spec.getattribute("chromaticities")
    )
    is_grey = len(set(channels)) == 1
    return _Header(
        spec,
        channels,
        _orientation(spec, path),
        radiance_exposure(lines, path),
        None if is_grey else bt709_matrix(chromaticities, path),
    )


def _orientation(spec, path):
    """The EXIF orientation (1 to 8) of an image's ``spec``, 1 when it has none."""
    orientation = spec.get_int_attribute("Orientation", 1)
    if not 1 <= orientation <= 8:
        raise ValueError(f"{path}: expected an Orientation of 1 to 8 (EXIF), got {orientation}")
    return orientation


#: Whether rows and columns are reversed (after the transposition of 5 to 8)
#: to display orientations 1 to 4 and 5 to 8 (EXIF 2.3, tag 274).
_FLIPS = ((False, False), (False, True), (True, True), (True, False))


def reorient(pixels, orientation):
    """The displayed image of ``pixels`` ``(H, W, C)`` stored with an EXIF
    ``orientation`` (1 to 8), turned as ``oiiotool --reorient`` turns it.

    1 is the displayed image; 2 mirrored left to right; 3 turned 180
    degrees; 4 upside down; 5 transposed (rows stored as columns); 6 to be
    turned 90 degrees clockwise; 7 transposed and turned 180; 8 to be
    turned 90 degrees counterclockwise. Orientations 5 to 8 swap width and
    height.
    """
    if orientation > 4:
        pixels = pixels.swapaxes(0, 1)
    rows, cols = _FLIPS[(orientation - 1) % 4]
    return pixels[:: -1 if rows else 1, :: -1 if cols else 1]


def bt709_matrix(chromaticities, path):
    """The matrix ``M`` that takes linear RGB of a file's primaries to
    linear BT.709 RGB, ``rgb709 = M @ rgb``; None when they are BT.709's.

    ``chromaticities`` are 8 numbers: the CIE 1931 x, y of the red, green
    and blue primaries and of the white (an EXR's ``chromaticities``
    attribute, a Radiance ``PRIMARIES=`` line), or None (BT.709). Within
    1e-4 of BT.709's (D65 white) they are BT.709's. The matrix is the file's
    RGB to XYZ (white normalised to Y = 1, SMPTE RP 177), a Bradford
    chromatic adaptation from the file's white to D65 where they differ (as
    OpenColorIO's ACES configuration converts ACES2065-1 to BT.709), then
    XYZ to BT.709, computed by colour-science. A D65 white keeps every
    pixel's luminance Y; another keeps that of greys and changes that of
    colours slightly.
    """
    if chromaticities is None:
        return None
    xy = np.ravel(np.asarray(chromaticities, dtype=np.float64))
    if xy.size == 8 and np.allclose(xy, BT709_CHROMATICITIES, rtol=0, atol=1e-4):
        return None
    if not (
        xy.size == 8
        and np.isfinite(xy).all()
        and xy[7] > 0
        and abs(np.linalg.det(np.c_[xy[:6].reshape(3, 2), np.ones(3)])) > 1e-6
    ):
        raise ValueError(
            f"{path}: expected chromaticities of three primaries that span a triangle and a "
            f"white (8 numbers: x, y of red, green, blue, white; white y > 0), got "
            f"{', '.join(f'{v:g}' for v in xy)}"
        )
    import colour  # not at import: it takes seconds (jaxadapt.color)

    space = colour.RGB_Colourspace(str(path), xy[:6].reshape(3, 2), xy[6:])
    bt709 = colour.RGB_COLOURSPACES["ITU-R BT.709"]
    return np.asarray(colour.matrix_RGB_to_RGB(space, bt709, "Bradford"))


def display_window(pixels, spec):
    """The pixels ``(h, w, C)`` of an image's data window placed in its
    display window (``spec``: an OpenImageIO ``ImageSpec``).

    An OpenEXR file stores only its data window, which may be a part of
    the image (a render cropped to its non-black pixels, as VFX renderers
    write them) or reach beyond it (overscan). The image is the display
    window: black (0 cd/m2) where no data are stored, and data outside it
    dropped. Other formats have the two windows equal.
    """
    h, w = spec.full_height, spec.full_width
    x, y = spec.x - spec.full_x, spec.y - spec.full_y  # data origin in the display window
    if (x, y, pixels.shape[:2]) == (0, 0, (h, w)):
        return pixels
    image = np.zeros((h, w, pixels.shape[-1]), pixels.dtype)
    rows = slice(max(y, 0), min(y + pixels.shape[0], h))
    cols = slice(max(x, 0), min(x + pixels.shape[1], w))
    if rows.start < rows.stop and cols.start < cols.stop:
        image[rows, cols] = pixels[rows.start - y : rows.stop - y, cols.start - x : cols.stop - x]
    return image


def rgb_channels(names):
    """Indices of the red, green and blue channels among ``names``, or None.

    By name: ``R``, ``G``, ``B``; else a luminance ``Y`` three times (a grey
    image; of a luminance-chroma EXR, ``Y RY BY``, the luminance alone).
    OpenImageIO names the channels of formats that do not (PFM, TIFF,
    Radiance) ``R G B`` or ``Y``. Channels named otherwise are not taken by
    position: a depth ``Z``, normals ``N.x N.y N.z`` or a render pass
    ``diffuse.R`` would be tone-mapped as if they were the picture.
    """
    names = list(names)
    if {"R", "G", "B"} <= set(names):
        return [names.index(c) for c in "RGB"]
    if "Y" in names:
        return [names.index("Y")] * 3
    return None


def _colour_part(image, path):
    """``(spec, channels)`` of the first part (subimage) of an open ``image``
    that has colour channels (:func:`rgb_channels`), the image left at that
    part; ``ValueError`` naming the file, each part's channels and, for an
    EXR whose colour is in layers (``beauty.R``, ...), how to pick one."""
    parts = []
    while image.seek_subimage(len(parts), 0):
        spec = image.spec()
        channels = rgb_channels(spec.channelnames)
        if channels is not None:
            return spec, channels
        parts.append(list(spec.channelnames))
    names = [name for part in parts for name in part]
    layers = sorted(
        {n[:-2] for n in names if n.endswith(".R") and {n[:-1] + "G", n[:-1] + "B"} <= set(names)}
    )
    hint = (
        f"; its layers with R, G and B are {', '.join(layers)}: make one the plain R, G, B "
        f"(e.g. oiiotool {path} --ch R={layers[0]}.R,G={layers[0]}.G,B={layers[0]}.B -o rgb.exr)"
        if layers
        else ""
    )
    got = "; ".join(", ".join(part) for part in parts)
    raise ValueError(
        f"{path}: expected R, G and B channels or a luminance Y, got channels {got}{hint}"
    )


def _one_line(message):
    """An OpenImageIO error message, whose lines may be several, as one line,
    each line once (OpenImageIO may repeat one)."""
    lines = (line.strip() for line in message.splitlines())
    return "; ".join(dict.fromkeys(line for line in lines if line))


def _radiance_header(path):
    """The lines of a Radiance HDR file's header (bytes, stripped), up to
    the empty line that ends it."""
    lines = []
    with open(path, "rb") as f:
        for line in iter(f.readline, b""):
            line = line.strip()
            if not line:
                break
            lines.append(line)
    return lines


def _header_numbers(line, count, path):
    """The ``count`` numbers after the ``=`` of a Radiance header ``line``."""
    try:
        numbers = [float(word) for word in line.partition(b"=")[2].split()]
    except ValueError:
        numbers = []
    if len(numbers) != count or not all(map(math.isfinite, numbers)):
        raise ValueError(
            f"{path}: expected {count} number{'s' * (count > 1)} in the header line "
            f"{line.decode(errors='replace')!r}"
        )
    return numbers


def radiance_exposure(lines, path):
    """The product of the ``EXPOSURE`` lines among a Radiance HDR file's
    header ``lines`` (:func:`_radiance_header`; 1 without any).

    A Radiance picture's pixel values are the radiance times every exposure
    applied to it since it was made (``pfilt``, ``pcomb``), each recorded as
    an ``EXPOSURE=`` line; the radiance is the pixel value over their
    product (Ward, *The RADIANCE Lighting Simulation and Rendering System*,
    file formats). OpenImageIO reports only the last line
    (``hdr:exposure``), and does not apply it. ``path`` names the file in
    errors.
    """
    exposure = 1.0
    for line in lines:
        if line.startswith(b"EXPOSURE="):
            (value,) = _header_numbers(line, 1, path)
            if value <= 0:
                raise ValueError(
                    f"{path}: expected a positive number in the header line "
                    f"{line.decode(errors='replace')!r}"
                )
            exposure *= value
    return exposure


def radiance_primaries(lines, path):
    """The chromaticities of the last ``PRIMARIES=`` line among a Radiance
    HDR file's header ``lines`` (8 numbers: x, y of red, green, blue and
    white, as :func:`bt709_matrix` takes them), or None without one.

    OpenImageIO does not report them. A file without the line is taken as
    BT.709, as OpenImageIO and most tools take it, though Radiance's own
    default primaries (green x 0.29, white E) differ: the same line written
    out is converted as it says, which keeps greys grey but adapts the white
    E to D65 (a saturated red gains about 16 %). ``path`` names the file in
    errors.
    """
    primaries = None
    for line in lines:
        if line.startswith(b"PRIMARIES="):
            primaries = _header_numbers(line, 8, path)
    return primaries


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

#: ffmpeg's name of each encoding's transfer function, for a video's tag
#: (BT.470 M is a pure gamma of 2.2).
VIDEO_TRANSFERS = {"srgb": "iec61966-2-1", "gamma": "bt470m"}


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


@contextlib.contextmanager
def video_writer(path, fps, encoding="srgb"):
    """Stream uint8 frames into an H.264 MP4 (the ffmpeg of imageio-ffmpeg).

    Yields ``send(frames)`` taking ``(K, H, W, 3)`` uint8 chunks of BT.709
    RGB encoded with ``encoding`` (``"srgb"`` or ``"gamma"``, 2.2); frames
    of odd size are padded by one edge pixel (4:2:0 video needs even
    sizes). The file appears under ``path`` only when the block completes
    and ffmpeg has exited with success.

    The RGB is converted to YCbCr with the BT.709 matrix, and the stream is
    tagged with BT.709 primaries and matrix and the encoding's transfer
    function, so that a player decodes the colours that were sent. (By
    default ffmpeg converts with BT.601's matrix and tags nothing, and
    players that assume BT.709 for HD video then shift the colours.)

    ffmpeg is run here, not through ``imageio_ffmpeg.write_frames``, whose
    end does not check ffmpeg's exit status: a size that H.264 cannot
    encode (wider than 16,384 pixels) or a frame rate that ffmpeg cannot
    parse would leave an empty video reported as written.
    ffmpeg's messages go to a temporary file (not a pipe: one that filled
    would stall it) and the first of them, the cause, is raised.

    Raises
    ------
    OSError
        ffmpeg failed: the message names ``path`` and says what ffmpeg said.
    """
    import subprocess
    from fractions import Fraction

    import imageio_ffmpeg

    with atomic_path(path) as tmp, tempfile.TemporaryFile() as log:
        process = None

        def fail():
            with contextlib.suppress(BrokenPipeError):  # its buffer, flushed to no reader
                process.stdin.close()
            process.wait()
            log.seek(0)
            said = log.read().decode(errors="replace").strip().splitlines()
            # The first message is the cause, the rest its consequences;
            # without ffmpeg's "[libx264 @ 0x...]" prefixes.
            cause = re.sub(r"^(\[[^\]]*\]\s*)+", "", said[0]) if said else "no message"
            raise OSError(
                f"{Path(path).name}: ffmpeg could not write the video (exit status "
                f"{process.returncode}): {cause}"
            )

        def send(frames):
            nonlocal process
            frames = np.asarray(frames)
            H, W = frames.shape[1:3]
            frames = np.pad(frames, ((0, 0), (0, H % 2), (0, W % 2), (0, 0)), mode="edge")
            if process is None:
                # As imageio-ffmpeg calls it (quality 5: crf 25), the rate a
                # fraction so that 24000/1001 is not rounded.
                rate = Fraction(fps).limit_denominator()
                command = [
                    imageio_ffmpeg.get_ffmpeg_exe(),
                    "-y", "-v", "error",
                    "-f", "rawvideo", "-pix_fmt", "rgb24",
                    "-s", f"{W + W % 2}x{H + H % 2}", "-r", str(rate), "-i", "-",
                    "-an", "-vcodec", "libx264",
                    "-vf", "scale=out_color_matrix=bt709:out_range=tv,setparams="
                    f"colorspace=bt709:color_primaries=bt709:color_trc={VIDEO_TRANSFERS[encoding]}",
                    "-pix_fmt", "yuv420p", "-crf", "25", "-f", "mp4", tmp,
                ]  # fmt: skip
                with warnings.catch_warnings():
                    # ffmpeg is started with fork+exec, which is safe under JAX's threads
                    warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
                    process = subprocess.Popen(
                        command, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=log
                    )
            try:
                process.stdin.write(np.ascontiguousarray(frames).tobytes())
            except BrokenPipeError:
                fail()

        try:
            yield send
        except BaseException:
            if process is not None:
                process.kill()
                process.wait()
            raise
        if process is not None:
            with contextlib.suppress(BrokenPipeError):
                process.stdin.close()
            if process.wait() != 0:
                fail()


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
