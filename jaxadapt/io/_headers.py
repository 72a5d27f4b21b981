"""What an HDR file's header says: its channels, orientation, display
window, chromaticities and (Radiance) exposure, as OpenImageIO reads them."""

import contextlib
import math
from typing import NamedTuple

import numpy as np
import OpenImageIO as oiio

from jaxadapt.color import BT709_CHROMATICITIES

_FLOAT_FORMATS = ("float", "half", "double")


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
