"""HDR file input and output (OpenImageIO) against the formats' own layout."""

import re
import zlib

import colour
import numpy as np
import OpenImageIO as oiio
import pytest

from jaxadapt import io, pipeline
from jaxadapt.color import BT709_CHROMATICITIES


def _gradient(height=4, width=3):
    """A frame whose rows and channels differ: any flip or swap shows."""
    rows = np.arange(1, height + 1, dtype=np.float32)[:, None, None]
    cols = np.arange(1, width + 1, dtype=np.float32)[None, :, None]
    return rows * 10.0 + cols * np.array([1.0, 2.0, 3.0], np.float32)


@pytest.mark.parametrize("scale", [1.0, 2.0])
def test_pfm_written_by_hand_is_read_the_right_way_up(tmp_path, scale):
    # The PFM format stores rows bottom to top, little endian for a negative
    # scale (https://www.pauldebevec.com/Research/HDR/PFM/); written here
    # byte by byte, not by OpenImageIO. OpenImageIO multiplies the pixels by
    # the scale's magnitude (as read_hdr says).
    image = _gradient()
    path = tmp_path / "hand.pfm"
    H, W = image.shape[:2]
    header = b"PF\n%d %d\n%g\n" % (W, H, -scale)
    path.write_bytes(header + image[::-1].astype("<f4").tobytes())
    np.testing.assert_array_equal(io.read_hdr(path), image * np.float32(scale))


def test_radiance_exposure_lines_divide_the_pixels(tmp_path):
    # A Radiance picture written byte by byte: flat RGBE pixels of 40
    # (mantissa 0.625 * 256 = 160, exponent 6 + 128), after an exposure of 4
    # and then one of 0.5 (pfilt writes one EXPOSURE line each time). The
    # radiance is 40 / (4 * 0.5) = 20. OpenImageIO reports only the last
    # line and applies none.
    pixels = bytes([160, 160, 160, 134]) * 12
    header = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=4\nEXPOSURE=0.5\n\n-Y 3 +X 4\n"
    path = tmp_path / "exposed.hdr"
    path.write_bytes(header + pixels)
    np.testing.assert_array_equal(io.read_hdr(path), np.full((3, 4, 3), 20.0, np.float32))
    path.write_bytes(header.replace(b"\nEXPOSURE=4\nEXPOSURE=0.5", b"") + pixels)
    np.testing.assert_array_equal(io.read_hdr(path), np.full((3, 4, 3), 40.0, np.float32))
    path.write_bytes(header.replace(b"EXPOSURE=4", b"EXPOSURE=-4") + pixels)
    with pytest.raises(ValueError, match="exposed.hdr: expected a positive number.*EXPOSURE=-4"):
        io.read_hdr(path)


@pytest.mark.parametrize("suffix", [".exr", ".pfm", ".tif", ".hdr"])
def test_hdr_formats_round_trip(tmp_path, suffix):
    image = _gradient()
    path = tmp_path / f"image{suffix}"
    io.write_image(path, image)
    rtol = 1e-2 if suffix == ".hdr" else 0  # RGBE keeps 8 bits of mantissa
    np.testing.assert_allclose(io.read_hdr(path), image, rtol=rtol)


@pytest.mark.parametrize(
    "name, pixels, match",
    [
        # A linear float frame written to PNG unencoded would be too dark (0.5 as 128).
        ("f.png", np.full((4, 4, 3), 0.5, np.float32), r"f.png: expected uint8 .* got float32"),
        ("f.png", np.zeros((4, 4, 3), np.uint16), "pixels: expected uint8 or floating"),
        ("f.exr", np.zeros((4, 4, 3), np.uint8), "f.exr: expected floating-point pixels"),
        # A TIFF takes both: uint16 would be written as floats, 1000 as 1000/65535.
        ("f.tif", np.full((4, 4, 3), 1000, np.uint16), "pixels: expected uint8 or floating"),
        # Two axes: an IndexError of the header's third.
        ("f.exr", np.ones((4, 5), np.float32), r"pixels: expected shape \(H, W, C\)"),
    ],
)
def test_pixels_a_format_cannot_hold_as_they_are_are_refused(tmp_path, name, pixels, match):
    with pytest.raises(ValueError, match=match):
        io.write_image(tmp_path / name, pixels)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("encoding, chunk", [("srgb", b"sRGB"), ("gamma", b"gAMA")])
def test_png_is_tagged_with_its_encoding(tmp_path, encoding, chunk):
    # PNG (ISO/IEC 15948): an sRGB chunk, or a gAMA chunk holding 1/2.2 x 1e5
    # and no sRGB chunk, which would override it in a colour-managed viewer.
    path = tmp_path / "frame.png"
    io.write_image(path, np.zeros((4, 4, 3), np.uint8), encoding=encoding)
    data = path.read_bytes()
    assert chunk in data
    if encoding == "gamma":
        assert b"sRGB" not in data
        at = data.index(b"gAMA") + 4
        assert int.from_bytes(data[at : at + 4], "big") == round(1e5 / 2.2)


def test_png_frames_are_deflated_fast_with_one_filter_losslessly(tmp_path):
    # A zlib stream (RFC 1950) begins with CMF and FLG; FLG's two top bits,
    # FLEVEL, say how hard the compressor worked: 0 is its fastest
    # algorithm (zlib writes 0 for levels 0 and 1, 2 for its default 6).
    # Inflated, each row begins with its filter type (ISO/IEC 15948): 4 for
    # Paeth, on every row.
    pixels = np.random.default_rng(0).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    path = tmp_path / "frame.png"
    io.write_image(path, pixels)
    data, stream, at = path.read_bytes(), b"", 8
    while at < len(data):
        length, kind = int.from_bytes(data[at : at + 4], "big"), data[at + 4 : at + 8]
        if kind == b"IDAT":
            stream += data[at + 8 : at + 8 + length]
        at += 12 + length
    cmf, flg = stream[0], stream[1]
    assert cmf & 0x0F == 8 and (cmf * 256 + flg) % 31 == 0  # deflate, a valid header
    assert flg >> 6 == 0
    rows = np.frombuffer(zlib.decompress(stream), np.uint8).reshape(48, 1 + 64 * 3)
    assert set(rows[:, 0]) == {4}
    np.testing.assert_array_equal(oiio.ImageBuf(str(path)).get_pixels(oiio.UINT8), pixels)


def test_exr_frames_are_compressed_losslessly(tmp_path):
    # Display values with every bit of a float32 set by noise come back bit
    # for bit; a flat frame shrinks to a small fraction of its 4 bytes a value.
    noisy = np.random.default_rng(0).random((32, 40, 3), dtype=np.float32)
    flat = np.full((256, 256, 3), 0.25, np.float32)
    for name, pixels in (("noisy.exr", noisy), ("flat.exr", flat)):
        io.write_image(tmp_path / name, pixels)
        source = oiio.ImageInput.open(str(tmp_path / name))
        assert source.spec().get_string_attribute("compression") == "zip"
        np.testing.assert_array_equal(source.read_image("float"), pixels)
        source.close()
    assert (tmp_path / "flat.exr").stat().st_size < flat.nbytes / 50


@pytest.mark.parametrize(
    "names, expected",
    [
        (("B", "G", "R", "A"), [3.0, 2.0, 1.0]),  # stored B G R A: read as R G B
        (("A", "Y"), [2.0, 2.0, 2.0]),  # grey with alpha
        (("Y", "RY", "BY"), [1.0, 1.0, 1.0]),  # luminance-chroma: the luminance
    ],
)
def test_colour_channels_are_found_by_name(tmp_path, names, expected):
    path = tmp_path / "channels.exr"
    spec = oiio.ImageSpec(4, 3, len(names), "float")
    spec.channelnames = names
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    # Channel i holds i + 1, in the order the names were given.
    out.write_image(
        np.broadcast_to(np.arange(1.0, len(names) + 1, dtype=np.float32), (3, 4, len(names)))
    )
    out.close()
    np.testing.assert_array_equal(io.read_hdr(path), np.broadcast_to(expected, (3, 4, 3)))


def _write_parts(path, *parts):
    """An EXR with a part (subimage) of each ``(channel names, value)``."""
    specs = []
    for names, _ in parts:
        spec = oiio.ImageSpec(4, 3, len(names), "float")
        spec.channelnames = names
        specs.append(spec)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), tuple(specs)) if len(specs) > 1 else out.open(str(path), specs[0])
    for k, (spec, (names, value)) in enumerate(zip(specs, parts, strict=True)):
        if k:
            assert out.open(str(path), spec, "AppendSubimage")
        out.write_image(np.full((3, 4, len(names)), value, np.float32))
    out.close()


@pytest.mark.parametrize(
    "names, match",
    [
        (("R", "G"), "got channels R, G$"),
        (("Z",), "got channels Z$"),  # a depth pass is not a grey picture
        (("N.x", "N.y", "N.z"), r"got channels N\.x, N\.y, N\.z$"),
        (
            ("diffuse.R", "diffuse.G", "diffuse.B", "beauty.R", "beauty.G", "beauty.B"),
            r"layers with R, G and B are beauty, diffuse: .*--ch R=beauty\.R,G=beauty\.G,B=",
        ),
    ],
)
def test_channels_that_are_not_colour_are_refused(tmp_path, names, match):
    # Taken by position (the first three, or a single one as grey), they
    # would be tone-mapped as if they were the picture.
    path = tmp_path / "passes.exr"
    _write_parts(path, (names, 5000.0))
    with pytest.raises(ValueError, match=r"passes\.exr: expected R, G and B channels .*" + match):
        io.read_hdr(path)


def test_the_first_part_with_colour_is_read(tmp_path):
    # A multi-part EXR whose first part is a depth pass: read from part 0,
    # its depth (5000) would render as luminance.
    path = tmp_path / "parts.exr"
    _write_parts(path, (("Z",), 5000.0), (("R", "G", "B", "A"), 2.0))
    np.testing.assert_array_equal(io.read_hdr(path), np.full((3, 4, 3), 2.0))


@pytest.mark.parametrize(
    "x, y, w, h", [(8, 8, 8, 8), (-4, -2, 24, 20), (3, 0, 5, 16), (20, 20, 4, 4)]
)
def test_exr_data_window_is_placed_in_the_display_window(tmp_path, x, y, w, h):
    # An EXR stores its data window, which may be part of the image (a render
    # cropped to its non-black pixels) or reach beyond it (overscan). Read as
    # the data window, a moving patch in a black frame would come out as a
    # still patch, of the patch's size. The reference: OpenImageIO's own crop of
    # the file to its display window (zeros where no data are stored).
    spec = oiio.ImageSpec(w, h, 3, "float")
    spec.x, spec.y = x, y
    spec.full_x, spec.full_y, spec.full_width, spec.full_height = 0, 0, 16, 12
    path = str(tmp_path / "window.exr")
    out = oiio.ImageOutput.create(path)
    out.open(path, spec)
    out.write_image(np.random.default_rng(0).uniform(1, 1000, (h, w, 3)).astype(np.float32))
    out.close()
    buf = oiio.ImageBuf(path)
    expected = oiio.ImageBufAlgo.crop(buf, buf.roi_full).get_pixels(oiio.FLOAT)
    image = io.read_hdr(path)
    assert image.shape == (12, 16, 3)
    np.testing.assert_array_equal(image, expected)


@pytest.mark.parametrize(
    "encoding, transfer, codec",
    [
        ("srgb", "iec61966-2-1", "h264"),
        ("gamma", "bt470m", "h264"),
        ("srgb", "iec61966-2-1", "hevc"),
    ],
)
def test_video_is_bt709_and_says_so(tmp_path, encoding, transfer, codec):
    # ffmpeg's default converts RGB with BT.601's matrix and tags nothing:
    # pure red gets luma 81 where a BT.709 player expects 63 (16 + 219 * 0.2126).
    import subprocess

    import imageio_ffmpeg

    path = tmp_path / "red.mp4"
    with io.video_writer(path, 30, encoding, codec=codec) as send:
        send(np.broadcast_to(np.array([255, 0, 0], np.uint8), (2, 16, 16, 3)))
    ffmpeg = imageio_ffmpeg.get_ffmpeg_exe()
    luma = subprocess.run(
        [ffmpeg, "-v", "error", "-i", str(path), "-f", "rawvideo", "-pix_fmt", "yuv420p", "-"],
        capture_output=True,
        check=True,
    ).stdout
    assert abs(int(np.frombuffer(luma, np.uint8)[8 * 16 + 8]) - 63) <= 1
    info = subprocess.run([ffmpeg, "-i", str(path)], capture_output=True, text=True).stderr
    assert f"yuv420p(tv, bt709/bt709/{transfer}" in info
    assert {"h264": "Video: h264 (High) (avc1", "hevc": "Video: hevc (Main) (hvc1"}[codec] in info


def _write(path, image, **attributes):
    """Write ``image`` (H, W, C) float32 with OpenImageIO, with header ``attributes``."""
    spec = oiio.ImageSpec(image.shape[1], image.shape[0], image.shape[2], "float")
    if image.shape[2] == 1:
        spec.channelnames = ("Y",)
    for name, value in attributes.items():
        if name == "chromaticities":
            spec.attribute(name, oiio.TypeDesc("float[8]"), tuple(map(float, value)))
        else:
            spec.attribute(name, value)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(np.ascontiguousarray(image, np.float32))
    out.close()


#: The displayed image of one stored as ``image`` with each EXIF orientation
#: that has its own branch (EXIF 2.3, tag 274: where the stored row 0 and
#: column 0 are seen).
_DISPLAYED = {
    1: lambda image: image,
    4: lambda image: image[::-1],  # row 0 at the bottom
    5: lambda image: image.transpose(1, 0, 2),  # row 0 on the left, column 0 at the top
    6: lambda image: np.rot90(image, -1),  # row 0 on the right, column 0 at the top
    8: lambda image: np.rot90(image, 1),  # row 0 on the left, column 0 at the bottom
}


@pytest.mark.parametrize("suffix", [".exr", ".tif"])
@pytest.mark.parametrize("orientation", range(1, 9))
def test_orientation_turns_the_image_as_displayed(tmp_path, suffix, orientation):
    # Files with an Orientation other than 1, read as stored, would be upside
    # down for 4, and with width and height swapped by hdr_size's and
    # read_hdr's callers for 5 to 8. The reference: the displayed image where written
    # out above, else OpenImageIO's own reorient (oiiotool --reorient).
    stored = _gradient(4, 3)
    path = tmp_path / f"turned{suffix}"
    _write(path, stored, Orientation=orientation)
    if orientation in _DISPLAYED:
        expected = _DISPLAYED[orientation](stored)
    else:
        expected = oiio.ImageBufAlgo.reorient(oiio.ImageBuf(str(path))).get_pixels(oiio.FLOAT)
    np.testing.assert_array_equal(io.read_hdr(path), expected)
    assert io.hdr_size(path) == (expected.shape[1], expected.shape[0])


def _rgbe(image):
    """Radiance RGBE bytes of pixels that are whole numbers below 256 (exponent 136:
    a value is its mantissa byte)."""
    pixels = np.concatenate([image, np.full(image.shape[:-1] + (1,), 136)], axis=-1)
    return pixels.astype(np.uint8).tobytes()


@pytest.mark.parametrize(
    "resolution, stored",
    [
        (b"+Y 3 +X 4", lambda image: image[::-1]),  # rows from the bottom up
        (b"+X 4 -Y 3", lambda image: image.transpose(1, 0, 2)),  # columns from the left
    ],
)
def test_radiance_resolution_line_orients_the_image(tmp_path, resolution, stored):
    # The resolution line gives the order of the stored pixels (Radiance's
    # resolu.c; the standard is -Y H +X W, rows from the top, each from the
    # left): a +Y file read as the standard order would be upside down.
    image = _gradient(3, 4)
    path = tmp_path / "turned.hdr"
    header = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + resolution + b"\n"
    path.write_bytes(header + _rgbe(stored(image)))
    np.testing.assert_array_equal(io.read_hdr(path), image)
    assert io.hdr_size(path) == (4, 3)


#: Chromaticities (red, green, blue, white x y) of OpenColorIO colour spaces.
_PRIMARIES = {
    "ACES2065-1": (0.7347, 0.2653, 0.0, 1.0, 0.0001, -0.077, 0.32168, 0.33767),
    "ACEScg": (0.713, 0.293, 0.165, 0.83, 0.128, 0.044, 0.32168, 0.33767),
    "lin_rec2020_scene": (0.708, 0.292, 0.170, 0.797, 0.131, 0.046, 0.3127, 0.3290),
}


def _colours():
    """Saturated, grey and dark pixels in cd/m2, (2, 4, 3)."""
    return np.array(
        [
            [[100.0, 0.0, 0.0], [0.0, 100.0, 0.0], [0.0, 0.0, 100.0], [50.0, 50.0, 50.0]],
            [[80.0, 40.0, 5.0], [3.0, 20.0, 60.0], [1e4, 1e4, 1e4], [1e-3, 2e-3, 1e-3]],
        ],
        np.float32,
    )


@pytest.mark.parametrize("space", _PRIMARIES)
def test_exr_primaries_are_converted_to_bt709(tmp_path, space):
    # An EXR's chromaticities are applied: ACES AP0 red (100, 0, 0) is not
    # BT.709 red. The reference: OpenImageIO's colorconvert with
    # OpenColorIO's built-in configuration (Bradford adaptation to D65),
    # its negative channels (colours outside BT.709's gamut) clipped to 0.
    path = tmp_path / "wide.exr"
    _write(path, _colours(), chromaticities=_PRIMARIES[space])
    expected = oiio.ImageBufAlgo.colorconvert(oiio.ImageBuf(str(path)), space, "lin_rec709_scene")
    expected = expected.get_pixels(oiio.FLOAT)
    assert (expected < -1e-3).any()  # the saturated colours are outside BT.709
    np.testing.assert_allclose(io.read_hdr(path), np.maximum(expected, 0), rtol=2e-4, atol=1e-6)


def test_colours_outside_bt709_render(tmp_path):
    # ACEScg red (100, 0, 0) is BT.709 (170.5, -13.0, -2.4): the negative
    # channels, out of BT.709's gamut, are clipped to 0, not refused as
    # negative values in the file.
    path = tmp_path / "acescg.exr"
    _write(path, _colours(), chromaticities=_PRIMARIES["ACEScg"])
    frames = pipeline.from_files([path], fps=30).frames(np.arange(1))
    assert frames.min() == 0 and np.isfinite(frames).all()
    np.testing.assert_allclose(frames[0, 0, 0], (170.505, 0, 0), rtol=1e-4)


def _luminance(rgb, chromaticities):
    """Y (cd/m2) of linear RGB of the given primaries (white Y = 1), by colour-science."""
    xy = np.reshape(chromaticities, (4, 2))
    return rgb @ colour.normalised_primary_matrix(xy[:3], xy[3])[1]


@pytest.mark.parametrize("space", _PRIMARIES)
def test_primaries_conversion_keeps_luminance(tmp_path, space):
    # With a D65 white every pixel keeps its Y; with another (ACES: D60) the
    # adaptation to D65 keeps the Y of greys, which stay grey.
    colours = _colours()
    path = tmp_path / "wide.exr"
    _write(path, colours, chromaticities=_PRIMARIES[space])
    image = io.read_hdr(path)
    luminance = _luminance(image, BT709_CHROMATICITIES)
    expected = _luminance(colours, _PRIMARIES[space])
    greys = (colours == colours[..., :1]).all(axis=-1)
    d65 = _PRIMARIES[space][6:] == (0.3127, 0.3290)
    kept = greys | (d65 & (image > 0).all(axis=-1))  # colours of no clipped channel
    assert (kept & ~greys).any() == d65
    np.testing.assert_allclose(luminance[kept], expected[kept], rtol=1e-5)
    np.testing.assert_allclose(image[greys], np.repeat(image[greys][:, 1:2], 3, -1), rtol=1e-5)


def test_grey_and_bt709_files_are_not_converted(tmp_path):
    # A luminance (Y) image is grey in any primaries; BT.709's chromaticities
    # as stored (float32) are BT.709's.
    grey = tmp_path / "grey.exr"
    _write(grey, _colours()[..., :1], chromaticities=_PRIMARIES["ACES2065-1"])
    np.testing.assert_array_equal(io.read_hdr(grey), np.repeat(_colours()[..., :1], 3, -1))
    bt709 = tmp_path / "bt709.exr"
    _write(bt709, _colours(), chromaticities=np.float32(BT709_CHROMATICITIES))
    np.testing.assert_array_equal(io.read_hdr(bt709), _colours())


def test_radiance_primaries_line_is_converted_to_bt709(tmp_path):
    # Radiance records its primaries as PRIMARIES= rx ry gx gy bx by wx wy,
    # which OpenImageIO does not report (so the pixels would pass as
    # BT.709). The reference: OpenImageIO's colorconvert (OpenColorIO) of
    # the pixels.
    primaries = _PRIMARIES["lin_rec2020_scene"]
    path = tmp_path / "wide.hdr"
    line = b"PRIMARIES= " + b" ".join(b"%g" % v for v in primaries)
    header = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n" + line + b"\n\n-Y 3 +X 4\n"
    path.write_bytes(header + _rgbe(_gradient(3, 4)))
    expected = oiio.ImageBufAlgo.colorconvert(
        oiio.ImageBuf(str(path)), "lin_rec2020_scene", "lin_rec709_scene"
    )
    expected = np.maximum(expected.get_pixels(oiio.FLOAT), 0)
    np.testing.assert_allclose(io.read_hdr(path), expected, rtol=1e-5, atol=1e-7)


def _bad_radiance(path, line):
    """A Radiance file at ``path`` with the header ``line``."""
    path.write_bytes(
        b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n" + line + b"\n\n-Y 3 +X 4\n" + _rgbe(_gradient(3, 4))
    )


@pytest.mark.parametrize(
    "name, write, match",
    [
        (
            "bad.hdr",
            lambda p: _bad_radiance(p, b"EXPOSURE=abc"),
            "expected 1 number .*'EXPOSURE=abc'",
        ),
        (
            "bad.hdr",
            lambda p: _bad_radiance(p, b"EXPOSURE=0"),
            "expected a positive number .*'EXPOSURE=0'",
        ),
        (
            "bad.hdr",
            lambda p: _bad_radiance(p, b"PRIMARIES= 0.64 0.33"),
            "expected 8 numbers .*PRIMARIES",
        ),
        (
            "bad.hdr",
            lambda p: _bad_radiance(p, b"PRIMARIES= 0 0 0 0 0 0 0.3127 0.329"),
            r"expected chromaticities of three primaries .*got 0, 0, 0, 0, 0, 0, 0\.3127, 0\.329",
        ),
        (
            "bad.exr",
            lambda p: _write(
                p, _colours(), chromaticities=(0.64, 0.33, 0.3, 0.6, 0.15, 0.06, 0.3, 0)
            ),
            r"expected chromaticities .* white y > 0",
        ),
        (
            "bad.exr",
            lambda p: _write(p, _colours(), Orientation=9),
            "expected an Orientation of 1 to 8 .*got 9",
        ),
    ],
    ids=["exposure-nan", "exposure-0", "primaries-2", "primaries-flat", "white-y0", "turn-9"],
)
def test_hdr_size_refuses_the_headers_read_hdr_refuses(tmp_path, name, write, match):
    # hdr_size checks a sequence's frames before any is rendered: a header
    # it passed but read_hdr refused would stop the render only when that
    # frame's turn came.
    path = tmp_path / name
    write(path)
    for function in (io.hdr_size, io.read_hdr):
        with pytest.raises(ValueError, match=re.escape(name) + ": " + match):
            function(path)


@pytest.mark.slow
def test_no_module_keeps_openimageio_alive_at_exit():
    # `jaxadapt psychometric simulate` ended every run with some 140 lines of
    # "nanobind: leaked ..." about OpenImageIO on stderr: the observer's
    # classes, which JAX keeps until exit, held io.atomic_path and through
    # it io's globals past the interpreter's clean-up of modules.
    import pkgutil
    import subprocess
    import sys

    import jaxadapt

    found = pkgutil.walk_packages(jaxadapt.__path__, "jaxadapt.")
    names = [m.name for m in found if m.name != "jaxadapt.__main__"]  # that one runs the CLI
    code = f"import importlib\nfor name in {names!r}: importlib.import_module(name)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "jaxadapt.psychophysics.observer" in names
    assert "leaked" not in done.stderr, done.stderr[:400]


@pytest.mark.parametrize("fps", [24000 / 1001, 30.0, 29.97, 1e-5, 0.3, 123456.789, 1e6])
def test_a_frame_rate_written_is_read_back(tmp_path, fps):
    path = tmp_path / "f.exr"
    io.write_image(path, np.ones((2, 3, 3), np.float32), fps=fps)
    assert io.frame_rate(path) == pytest.approx(fps, rel=1e-12)
    io.write_image(path, np.ones((2, 3, 3), np.float32))
    assert io.frame_rate(path) is None


@pytest.mark.parametrize("channels", [1, 3])
def test_pfm_files_match_openimageio_both_ways(tmp_path, channels):
    # PFM frames are written and read with NumPy (OpenImageIO's PFM writer
    # and reader move a value or a few kB per call): OpenImageIO reads what
    # is written, and read_hdr reads what OpenImageIO writes, to the bit.
    import OpenImageIO as oiio

    image = _gradient()[..., :channels] * np.float32(0.37)
    ours = tmp_path / "ours.pfm"
    io.write_image(ours, image)
    config = oiio.ImageSpec()
    config.attribute("pnm:pfmflip", 1)  # rows the right way up (io._hdr_image)
    theirs = oiio.ImageInput.open(str(ours), config)
    np.testing.assert_array_equal(theirs.read_image(format="float"), image)
    theirs.close()
    written = tmp_path / "theirs.pfm"
    out = oiio.ImageOutput.create(str(written))
    out.open(str(written), oiio.ImageSpec(image.shape[1], image.shape[0], channels, "float"))
    out.write_image(image)
    out.close()
    expected = np.repeat(image, 3, axis=-1) if channels == 1 else image  # a grey's Y as RGB
    np.testing.assert_array_equal(io.read_hdr(written), expected)


def test_a_truncated_pfm_is_refused_in_one_line(tmp_path):
    path = tmp_path / "cut.pfm"
    io.write_image(path, _gradient())
    path.write_bytes(path.read_bytes()[:-4])
    with pytest.raises(ValueError, match=r"cut.pfm: cannot read pixels \(expected \d+ bytes"):
        io.read_hdr(path)


@pytest.mark.parametrize("keep", [40, 200])
def test_a_truncated_exr_header_is_said_once(tmp_path, keep):
    # OpenImageIO reported the cut header three times, joined into one line.
    path = tmp_path / "cut.exr"
    io.write_image(path, _gradient())
    path.write_bytes(path.read_bytes()[:keep])
    with pytest.raises(ValueError, match=r"cut.exr: ") as caught:
        io.read_hdr(path)
    parts = str(caught.value).split("; ")
    assert len(parts) == len(set(parts)), str(caught.value)
    assert "\n" not in str(caught.value)


def _double_tiff(path, pixels):
    """A TIFF of 64-bit floats, written by OpenImageIO."""
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(pixels.shape[1], pixels.shape[0], 3, oiio.DOUBLE))
    out.write_image(pixels)
    out.close()


def test_doubles_beyond_float32_are_refused_as_out_of_range(tmp_path):
    # Cast to float32 they would turn infinite, and be refused as if the
    # file held infinities, with the advice to set them to black.
    path = tmp_path / "big.tif"
    _double_tiff(path, np.full((2, 3, 3), 1e50))
    with pytest.raises(ValueError, match=r"big.tif: expected values within float32's range "):
        io.read_hdr(path)


def test_doubles_within_float32_read_as_their_nearest_float32(tmp_path):
    pixels = np.array([[[1e-40, 0.1, 3e38], [0.0, 1e8, np.pi], [1.0, 2.0, 1e-3]]] * 2)
    path = tmp_path / "fine.tif"
    _double_tiff(path, pixels)
    read = io.read_hdr(path)
    assert read.dtype == np.float32
    np.testing.assert_array_equal(read, pixels.astype(np.float32))


@pytest.mark.parametrize(
    "codec, refused, taken",
    [("h264", (2, 16386), (2, 16384)), ("hevc", (8, 8), (16, 16))],
)
def test_a_frame_size_the_encoder_refuses_is_said(tmp_path, codec, refused, taken):
    # libx264 takes up to 16384 pixels a side, libx265 at least 16.
    path = tmp_path / "v.mp4"
    H, W = refused
    encoder = {"h264": "libx264", "hevc": "libx265"}[codec]
    says = rf"v.mp4: {encoder} cannot encode frames of {W}x{H} \("
    with pytest.raises(ValueError, match=says), io.video_writer(path, 30, codec=codec) as send:
        send(np.zeros((1, H, W, 3), np.uint8))
    assert list(tmp_path.iterdir()) == []
    with io.video_writer(path, 30, codec=codec) as send:
        send(np.zeros((1, *taken, 3), np.uint8))
    assert path.exists()


@pytest.mark.parametrize("count", [1, 2, 3])
def test_hevc_clips_of_a_few_frames_are_written(tmp_path, count):
    # libx265 stamped a clip of 1 or 2 frames with a garbage DTS (35 of 40
    # two-frame clips here), which the MP4 muxer refused.
    for attempt in range(8):
        path = tmp_path / f"{attempt}.mp4"
        with io.video_writer(path, 30, codec="hevc") as send:
            send(np.zeros((count, 64, 64, 3), np.uint8))
        import av

        with av.open(str(path)) as video:
            assert sum(1 for _ in video.decode(video=0)) == count
