"""HDR file input and output (OpenImageIO) against the formats' own layout."""

import numpy as np
import OpenImageIO as oiio
import pytest

from jaxadapt import io


def _gradient(height=4, width=3):
    """A frame whose rows and channels differ: any flip or swap shows."""
    rows = np.arange(1, height + 1, dtype=np.float32)[:, None, None]
    cols = np.arange(1, width + 1, dtype=np.float32)[None, :, None]
    return rows * 10.0 + cols * np.array([1.0, 2.0, 3.0], np.float32)


def test_pfm_written_by_hand_is_read_the_right_way_up(tmp_path):
    # The PFM format stores rows bottom to top, little endian for a negative
    # scale (https://www.pauldebevec.com/Research/HDR/PFM/); written here
    # byte by byte, not by OpenImageIO.
    image = _gradient()
    path = tmp_path / "hand.pfm"
    H, W = image.shape[:2]
    path.write_bytes(b"PF\n%d %d\n-1.0\n" % (W, H) + image[::-1].astype("<f4").tobytes())
    np.testing.assert_array_equal(io.read_hdr(path), image)


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
    # They were taken by position (the first three, or a single one as grey)
    # and tone-mapped as if they were the picture.
    path = tmp_path / "passes.exr"
    _write_parts(path, (names, 5000.0))
    with pytest.raises(ValueError, match=r"passes\.exr: expected R, G and B channels .*" + match):
        io.read_hdr(path)


def test_the_first_part_with_colour_is_read(tmp_path):
    # A multi-part EXR whose first part is a depth pass: only part 0 was
    # read, and its depth (5000) rendered as luminance.
    path = tmp_path / "parts.exr"
    _write_parts(path, (("Z",), 5000.0), (("R", "G", "B", "A"), 2.0))
    np.testing.assert_array_equal(io.read_hdr(path), np.full((3, 4, 3), 2.0))


@pytest.mark.parametrize(
    "x, y, w, h", [(8, 8, 8, 8), (-4, -2, 24, 20), (3, 0, 5, 16), (20, 20, 4, 4)]
)
def test_exr_data_window_is_placed_in_the_display_window(tmp_path, x, y, w, h):
    # An EXR stores its data window, which may be part of the image (a render
    # cropped to its non-black pixels) or reach beyond it (overscan). Read as
    # the data window, a moving patch in a black frame came out as a still
    # patch, of the patch's size. The reference: OpenImageIO's own crop of
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


@pytest.mark.parametrize("encoding, transfer", [("srgb", "iec61966-2-1"), ("gamma", "bt470m")])
def test_video_is_bt709_and_says_so(tmp_path, encoding, transfer):
    # ffmpeg's default converted RGB with BT.601's matrix and tagged nothing:
    # pure red had luma 81 where a BT.709 player expects 63 (16 + 219 * 0.2126).
    import subprocess

    import imageio_ffmpeg

    path = tmp_path / "red.mp4"
    with io.video_writer(path, 30, encoding) as send:
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
