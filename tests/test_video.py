"""Video in: HDR10 (PQ), HLG and SDR clips made with the ffmpeg the project
ships (imageio-ffmpeg), from known signal values, decoded by
jaxadapt.io.read_video to cd/m2 and compared with colour-science's
transfer functions and Y'CbCr definitions; their timing; ``jaxadapt
render clip.mp4``; and what is refused."""

import subprocess

import colour
import imageio_ffmpeg
import numpy as np
import pytest
from cli_runs import assert_one_line_error, run

from jaxadapt import io, pipeline
from jaxadapt.cli import main
from jaxadapt.io._video_read import eotf_hlg, eotf_pq

FFMPEG = imageio_ffmpeg.get_ffmpeg_exe()
W, H = 96, 64
#: Signal values (R'G'B', non-linear): frame i of a clip is ``PATCHES[i %
#: 6]`` times a ramp from 0.7 at the left edge to 1 at the right (smooth:
#: 4:2:0 chroma mixes across a sharp colour edge as the encoder filters it,
#: and a clip of smooth frames measures the decoding, not the codec).
PATCHES = np.array(
    [(0.6, 0.2, 0.1), (0.2, 0.6, 0.3), (0.1, 0.2, 0.7), (0.5, 0.5, 0.5), (0.75, 0.75, 0.75),
     (0.3, 0.3, 0.3)]
)  # fmt: skip
#: ffmpeg's names of each transfer, and zscale's.
TAGS = {"pq": ("smpte2084", "smpte2084"), "hlg": ("arib-std-b67", "arib-std-b67"),
        "bt709": ("bt709", "709")}  # fmt: skip
BT2020_TO_709 = colour.matrix_RGB_to_RGB(
    colour.RGB_COLOURSPACES["ITU-R BT.2020"], colour.RGB_COLOURSPACES["ITU-R BT.709"]
)


def _signal(i):
    """Frame ``i``'s R'G'B' signal ``(H, W, 3)``."""
    ramp = np.linspace(0.7, 1.0, W)[None, :, None]
    return np.broadcast_to(PATCHES[i % len(PATCHES)] * ramp, (H, W, 3)).astype(np.float32)


#: x265's HDR10 static metadata of a clip: a P3-D65 mastering display of
#: 0.005 to 1000 cd/m2 (xy in 0.00002, luminance in 0.0001 cd/m2), and
#: MaxCLL, MaxFALL.
MASTERING = "master-display=G(13250,34500)B(7500,3000)R(34000,16000)WP(15635,16450)" \
    "L(10000000,50):max-cll=1000,400"  # fmt: skip


#: The encoders of a clip's codecs (lossless but ProRes, whose 422 HQ
#: profile is visually lossless), and the 10-bit pixel format each gets.
CODECS = {
    "hevc": (["-c:v", "libx265"], "yuv420p10le"),
    "av1": (["-c:v", "libaom-av1", "-aom-params", "lossless=1", "-cpu-used", "8"], "yuv420p10le"),
    "prores": (["-c:v", "prores_ks", "-profile:v", "3"], "yuv422p10le"),
}


def _clip(
    path, transfer, frames=6, audio=False, tag=True, faststart=False, hdr10=False, codec="hevc"
):
    """An HEVC (10-bit) or H.264 (SDR, 8-bit) clip of :func:`_signal` frames
    at 24 frames/s, converted by zscale (zimg) and losslessly encoded; with
    a sine's audio track; without colour tags; the index (moov) first;
    with :data:`MASTERING`'s metadata; in another of :data:`CODECS` (the
    container by the suffix of ``path``)."""
    raw = b"".join(
        np.ascontiguousarray(_signal(i)[..., [1, 2, 0]].transpose(2, 0, 1)).tobytes()
        for i in range(frames)
    )
    hd = transfer != "bt709"
    trc, z = TAGS[transfer]
    prim, matrix = ("bt2020", "2020_ncl") if hd else ("bt709", "709")
    vf = f"zscale=m={matrix}:r=limited:rin=full:min=gbr:t={z}:tin={z}:p={prim.replace('bt', '')}"
    encoder, pixels = CODECS[codec] if hd else (["-c:v", "libx264", "-qp", "0"], "yuv420p")
    vf += f":pin={prim.replace('bt', '')},format={pixels}"
    if not tag:  # (zscale tags the frames it converts; the encoder writes the tags it gets)
        vf += ",setparams=color_primaries=unknown:color_trc=unknown:colorspace=unknown"
    args = [FFMPEG, "-hide_banner", "-loglevel", "error", "-y", "-f", "rawvideo"]
    args += ["-pix_fmt", "gbrpf32le", "-s", f"{W}x{H}", "-r", "24", "-i", "-"]
    if audio:
        args += ["-f", "lavfi", "-i", f"sine=d={frames / 24}"]
    args += ["-vf", vf]
    args += encoder
    if hd and codec == "hevc":
        params = "log-level=error:lossless=1" + (":hdr10=1:" + MASTERING if hdr10 else "")
        args += ["-x265-params", params]
    if tag:
        space = "bt2020nc" if hd else "bt709"
        args += ["-color_primaries", prim, "-color_trc", trc, "-colorspace", space]
        args += ["-color_range", "tv"]
    if audio:
        args += ["-c:a", "aac", "-shortest"]
    if faststart:
        args += ["-movflags", "+faststart"]
    subprocess.run([*args, str(path)], input=raw, check=True)
    return path


def _truth(transfer, signal, peak=io.HLG_PEAK):
    """Linear BT.709 cd/m2 of ``signal`` (..., 3) by colour-science."""
    if transfer == "pq":
        light = colour.models.eotf_ST2084(signal)
    elif transfer == "hlg":
        light = colour.models.eotf_BT2100_HLG(signal, L_W=peak)
    else:
        return io.SDR_WHITE * colour.models.eotf_BT1886(signal, L_B=0, L_W=1)
    return np.maximum(light @ BT2020_TO_709.T, 0)


def test_transfer_functions_equal_colour_science():
    E = np.linspace(0, 1, 101)
    np.testing.assert_allclose(eotf_pq(E), colour.models.eotf_ST2084(E), rtol=1e-4, atol=1e-6)
    rgb = np.random.default_rng(0).uniform(0, 1, (200, 3))
    for peak in (1000.0, 400.0, 2000.0):
        truth = colour.models.eotf_BT2100_HLG(rgb, L_W=peak)
        np.testing.assert_allclose(eotf_hlg(rgb, peak), truth, rtol=1e-4, atol=1e-4 * peak)


@pytest.mark.parametrize("transfer", ["pq", "hlg", "bt709"])
def test_a_clip_decodes_to_its_light(tmp_path, transfer):
    path = _clip(tmp_path / f"{transfer}.mp4", transfer)
    info = io.probe_video(path)
    assert (info.transfer, info.width, info.height, info.frames) == (transfer, W, H, 6)
    assert info.primaries == ("bt709" if transfer == "bt709" else "bt2020")
    times, frames = next(io.read_video(info, chunk=6))
    np.testing.assert_allclose(times, np.arange(6) / 24)
    weights = [0.2126, 0.7152, 0.0722]
    for i, frame in enumerate(frames):
        truth = _truth(transfer, _signal(i))
        # each pixel within the quantisation (10-bit; 8-bit for SDR) and the
        # saturated primaries' BT.709 channels clipped: a few per cent
        rtol = 0.07 if transfer == "bt709" else 0.03  # (one code value of 8 bits, of 10)
        np.testing.assert_allclose(frame, truth, rtol=rtol, atol=0.003 * truth.max())
        # the log-average luminance within 1 % (the target for PQ)
        log_average = np.mean(np.log(frame @ weights)) - np.mean(np.log(truth @ weights))
        assert abs(np.expm1(log_average)) < 0.01


@pytest.mark.parametrize(
    "name, codec, pixel_format",
    [("clip.mkv", "hevc", "yuv420p10le"), ("clip.mkv", "av1", "yuv420p10le"),
     ("clip.mov", "prores", "yuv422p10le")],
)  # fmt: skip
def test_containers_and_codecs_decode_alike(tmp_path, name, codec, pixel_format):
    # The PQ clip in MKV (HEVC; AV1, lossless) and MOV (ProRes 422 HQ):
    # the same light, each frame's log-average within 1 %.
    info = io.probe_video(_clip(tmp_path / name, "pq", codec=codec))
    assert (info.codec, info.pixel_format, info.transfer, info.primaries) == (
        codec, pixel_format, "pq", "bt2020"
    )  # fmt: skip
    times, frames = next(io.read_video(info, chunk=6))
    np.testing.assert_allclose(times, np.arange(6) / 24, atol=1e-3)
    weights = [0.2126, 0.7152, 0.0722]
    for i, frame in enumerate(frames):
        truth = _truth("pq", _signal(i))
        np.testing.assert_allclose(frame, truth, rtol=0.03, atol=0.003 * truth.max())
        log_average = np.mean(np.log(frame @ weights)) - np.mean(np.log(truth @ weights))
        assert abs(np.expm1(log_average)) < 0.01


def test_variable_frame_rate_keeps_each_frame_s_time(tmp_path):
    # A phone's variable frame rate: frames stamped at 0, 40, 50, 110 and
    # 200 ms (encoded by PyAV, which sets each frame's stamp as given).
    import fractions

    import av

    stamps = [0, 40, 50, 110, 200]
    path = tmp_path / "vfr.mp4"
    with av.open(str(path), "w") as out:
        stream = out.add_stream("libx264", rate=24)
        stream.width, stream.height, stream.pix_fmt = W, H, "yuv420p"
        stream.codec_context.time_base = fractions.Fraction(1, 1000)
        for i, t in enumerate(stamps):
            frame = av.VideoFrame.from_ndarray(np.full((H, W, 3), 40 * i, np.uint8), "rgb24")
            frame.pts, frame.time_base = t, fractions.Fraction(1, 1000)
            out.mux(stream.encode(frame))
        out.mux(stream.encode())
    seconds = np.asarray(stamps) / 1000
    times, dt, whole = io.video_times(path)
    assert whole
    np.testing.assert_allclose(times, seconds)
    np.testing.assert_allclose(dt[:-1], np.diff(seconds))
    source = pipeline.from_video(path, transfer="bt709")  # (untagged)
    np.testing.assert_allclose(source.dt[:-1], np.diff(seconds))
    info = io.probe_video(path, transfer="bt709")
    decoded = np.concatenate([t for t, _ in io.read_video(info, chunk=2)])
    np.testing.assert_allclose(decoded, seconds)
    frames = source.frames(np.arange(5))  # the frames in order: brighter each time
    assert np.all(np.diff(frames.mean(axis=(1, 2, 3))) > 0)
    # The render's video keeps the stamps.
    out = tmp_path / "out"
    assert main(["render", str(path), "--video-transfer", "bt709", "--out", str(out)]) == 0
    with av.open(str(out / "video.mp4")) as rendered:
        shown = [float(f.time) for f in rendered.decode(video=0)]
    np.testing.assert_allclose(shown, seconds, atol=1e-4)


def test_frames_from_the_middle_are_those_of_the_whole(tmp_path):
    # An H.264 clip with a key frame every 8 frames and B-frames between
    # (frames reordered): read from frame k (seeking to the key frame
    # before it), or asked for by a source out of order, the frames are
    # those of the whole file, at the same times.
    import fractions

    import av

    path = tmp_path / "gop.mp4"
    with av.open(str(path), "w") as out:
        stream = out.add_stream("libx264", rate=24)
        stream.width, stream.height, stream.pix_fmt = W, H, "yuv420p"
        stream.codec_context.gop_size = 8
        stream.codec_context.options = {"bf": "2", "crf": "30"}
        for i in range(30):
            frame = av.VideoFrame.from_ndarray(np.full((H, W, 3), 8 * i, np.uint8), "rgb24")
            frame.pts, frame.time_base = i, fractions.Fraction(1, 24)
            out.mux(stream.encode(frame))
        out.mux(stream.encode())
    with av.open(str(path)) as container:
        keys = [p.pts for p in container.demux(video=0) if p.is_keyframe]
        assert len(keys) > 3
    info = io.probe_video(path, transfer="bt709")

    def read(first):
        chunks = list(io.read_video(info, chunk=4, first=first))
        return np.concatenate([t for t, _ in chunks]), np.concatenate([f for _, f in chunks])

    times, frames = read(0)
    for k in (1, 8, 13, 29):
        t, f = read(k)
        np.testing.assert_array_equal(t, times[k:])
        np.testing.assert_array_equal(f, frames[k:])
    source = pipeline.from_video(path, transfer="bt709")
    np.testing.assert_array_equal(source.frames(np.arange(20, 23)), frames[20:23])
    np.testing.assert_array_equal(source.frames(np.arange(5, 7)), frames[5:7])


@pytest.mark.parametrize("timed", [False, True], ids=["at-a-rate", "stamped"])
def test_a_video_written_in_parts_and_joined_is_the_whole(tmp_path, timed):
    # Frames counted at 24/s, or stamped at irregular times (a video
    # input's), written as three parts and joined, with a clip's audio:
    # each frame at the whole's stamp, the whole's audio, the pictures as
    # the whole's but for the key frames at the joins (not encoded again).
    import av

    rng = np.random.default_rng(0)
    ramp = np.linspace(30, 200, 40)[:, None, None, None]
    frames = np.clip(ramp + rng.normal(0, 2, (40, H, W, 3)), 0, 255).astype(np.uint8)
    times = np.cumsum(rng.uniform(0.03, 0.05, 40)) if timed else None
    clip = _clip(tmp_path / "clip.mp4", "bt709", frames=40, audio=True)
    whole = tmp_path / "whole.mp4"
    with io.video_writer(whole, 24, times=times, copy_from=clip) as send:
        send(frames)
    parts = []
    for first, stop in ((0, 13), (13, 14), (14, 40)):
        parts.append((first, tmp_path / f"part{first}.mp4"))
        with io.video_writer(parts[-1][1], 24, times=times, first=first) as send:
            send(frames[first:stop])
    joined = tmp_path / "joined.mp4"
    io.joined_video(joined, parts, 24, times, copy_from=clip)

    def read(path):
        with av.open(str(path)) as video:
            shown = [
                (f.pts, f.to_ndarray(format="rgb24").astype(int)) for f in video.decode(video=0)
            ]
            video.seek(0)
            audio = [bytes(p) for p in video.demux(video.streams.audio[0]) if p.size]
            return [t for t, _ in shown], np.stack([f for _, f in shown]), audio

    (stamps, pictures, audio), (stamps2, pictures2, audio2) = read(whole), read(joined)
    assert stamps2 == stamps and audio2 == audio and len(audio) > 0
    assert np.abs(pictures2 - pictures).mean() < 1.5
    assert np.abs(pictures2 - frames).mean() < 1.2 * np.abs(pictures - frames).mean() + 0.1


def test_render_a_video_and_what_is_refused(tmp_path, capsys):
    clip = _clip(tmp_path / "clip.mp4", "pq", audio=True)
    assert io.probe_video(clip).audio == 1
    status, err = run(capsys, "render", str(clip), "--out", str(tmp_path / "out"))
    assert status == 0, err
    assert len(list((tmp_path / "out").glob("frame_*.png"))) == 6
    # The video: H.264 tagged BT.709 (sRGB's transfer), the audio copied as it was.
    import av

    with av.open(str(clip)) as source, av.open(str(tmp_path / "out" / "video.mp4")) as video:
        assert [s.type for s in video.streams] == ["video", "audio"]
        cc = video.streams.video[0].codec_context
        assert (cc.name, cc.color_primaries, cc.color_trc, cc.colorspace) == ("h264", 1, 13, 1)
        copied = [bytes(p) for p in video.demux(video.streams.audio[0]) if p.size]
        original = [bytes(p) for p in source.demux(source.streams.audio[0]) if p.size]
        assert copied == original
    bad = tmp_path / "text.mp4"
    bad.write_text("not a video")
    untagged = _clip(tmp_path / "untagged.mp4", "pq", tag=False)
    for argv, words in (
        ([str(bad)], "expected a video file, got one FFmpeg cannot read"),
        ([str(untagged)], "transfer is not tagged; say which it is (--video-transfer"),
        ([str(clip), "--fps", "30"], "--fps: a video's frames are timed by their own stamps"),
        (["--hlg-peak", "400"], "--hlg-peak: applies to a video FILE"),
        ([str(clip), str(clip)], "FILE: expected one video, or HDR images"),
        (
            [str(clip), "--format", "png", "--video-codec", "hevc"],
            "--video-codec: applies to mp4 output, not --format png",
        ),
    ):
        out = tmp_path / "refused"
        status, err = run(capsys, "render", *argv, "--out", str(out))
        assert_one_line_error(status, err, words)
        assert not out.exists()
    # The tag given: the untagged clip reads as PQ.
    status, err = run(
        capsys, "render", str(untagged), "--video-transfer", "pq", "--out", str(tmp_path / "o2")
    )
    assert status == 0, err


def test_a_truncated_video_and_rgb_video_are_refused(tmp_path, capsys):
    # A download cut short with its index last: no index, not a video.
    data = _clip(tmp_path / "whole.mp4", "pq", frames=24).read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[: len(data) * 3 // 4])
    out = tmp_path / "out"
    status, err = run(capsys, "render", str(cut), "--out", str(out))
    assert_one_line_error(status, err, "expected a video file, got one FFmpeg cannot read")
    assert not out.exists()
    rgb = tmp_path / "rgb.mp4"
    subprocess.run(
        [FFMPEG, "-v", "error", "-f", "lavfi", "-i", "testsrc2=s=64x48:d=0.2", "-c:v",
         "libx264rgb", "-color_trc", "bt709", str(rgb)],
        check=True,
    )  # fmt: skip
    status, err = run(capsys, "render", str(rgb), "--out", str(out))
    assert_one_line_error(status, err, "expected Y'CbCr video of 8 to 12 bits", "gbrp")


def test_streams_an_mp4_cannot_hold_are_left_out_with_a_warning(tmp_path, capsys):
    # Text subtitles: MP4 holds them as mov_text, not as SubRip (an MKV's).
    clip = _clip(tmp_path / "clip.mp4", "pq", audio=True)
    srt = tmp_path / "subtitles.srt"
    srt.write_text("1\n00:00:00,000 --> 00:00:00,200\nhello\n")
    import av

    for name, codec, kept in (("subs.mp4", "mov_text", True), ("subs.mkv", "srt", False)):
        muxed = tmp_path / name
        subprocess.run(
            [FFMPEG, "-v", "error", "-i", str(clip), "-i", str(srt), "-map", "0", "-map", "1",
             "-c", "copy", "-c:s", codec, str(muxed)],
            check=True,
        )  # fmt: skip
        out = tmp_path / f"out_{codec}"
        status, err = run(capsys, "render", str(muxed), "--out", str(out))
        assert status == 0, err
        with av.open(str(out / "video.mp4")) as video:
            kinds = [s.type for s in video.streams]
        assert kinds == ["video", "audio", *(["subtitle"] if kept else [])]
        warning = f"warning: {name}: its subtitle stream 2 (srt) cannot go into an MP4; left out"
        assert (warning in err.splitlines()) != kept, err


def _decoded_by_ffmpeg(path):
    """How many frames the ffmpeg program decodes of ``path``."""
    said = subprocess.run(
        [FFMPEG, "-v", "error", "-i", str(path), "-map", "0:v", "-f", "framemd5", "-"],
        capture_output=True, text=True,
    ).stdout  # fmt: skip
    return sum(1 for line in said.splitlines() if line and not line.startswith("#"))


def test_a_video_cut_short_renders_the_frames_that_decode(tmp_path, capsys):
    # With its index first (as for streaming), a download cut short
    # announces 24 frames and holds fewer: those that decode (as many as
    # the ffmpeg program decodes) are rendered, as they are in the whole
    # clip's render, with a warning and status 3.
    whole = _clip(tmp_path / "whole.mp4", "pq", frames=24, audio=True, faststart=True)
    cut = tmp_path / "cut.mp4"
    data = whole.read_bytes()
    cut.write_bytes(data[: len(data) * 3 // 4])
    n = _decoded_by_ffmpeg(cut)
    assert 0 < n < 24
    status, err = run(capsys, "render", str(whole), "--out", str(tmp_path / "all"))
    assert status == 0, err
    status, err = run(capsys, "render", str(cut), "--out", str(tmp_path / "cut"))
    assert status == 3, err
    assert err.splitlines()[0] == (
        f"warning: cut.mp4: the file is cut short; its first {n} frames of the 24 its index "
        "announces decode and are rendered"
    ), err
    rendered = sorted((tmp_path / "cut").glob("frame_*.png"))
    assert len(rendered) == n
    for path in rendered:
        assert path.read_bytes() == (tmp_path / "all" / path.name).read_bytes(), path.name
    import av

    with av.open(str(tmp_path / "cut" / "video.mp4")) as video:
        assert [s.type for s in video.streams] == ["video", "audio"]
        assert sum(1 for _ in video.decode(video=0)) == n


def test_the_source_record_says_what_the_video_holds(tmp_path, capsys):
    # Its tags and HDR10 metadata as FFmpeg's showinfo filter prints them.
    # (and HEVC out, on request)
    clip = _clip(tmp_path / "clip.mp4", "pq", audio=True, hdr10=True)
    argv = ["render", str(clip), "--format", "mp4", "--video-codec", "hevc"]
    status, err = run(capsys, *argv, "--out", str(tmp_path / "o"))
    assert status == 0, err
    import av

    with av.open(str(tmp_path / "o" / "video.mp4")) as video:
        assert [(s.type, s.codec_context.name) for s in video.streams] == [
            ("video", "hevc"), ("audio", "aac")
        ]  # fmt: skip
        assert sum(1 for _ in video.decode(video=0)) == 6
    import json
    import re

    record = json.loads((tmp_path / "o" / "source.json").read_text())
    said = subprocess.run(
        [FFMPEG, "-hide_banner", "-i", str(clip), "-vf", "showinfo", "-frames:v", "1", "-f",
         "null", "-"],
        capture_output=True, text=True, check=True,
    ).stderr  # fmt: skip
    number = r"([\d.]+)"
    display = re.search(
        rf"r\({number},{number}\) g\({number},{number}\) b\({number} {number}\) "
        rf"wp\({number}, {number}\) min_luminance={number}, max_luminance={number}",
        said,
    )
    light = re.search(r"MaxCLL=(\d+), MaxFALL=(\d+)", said)
    r, g, b, wp = (list(map(float, display.groups()[i : i + 2])) for i in range(0, 8, 2))
    assert record["hdr_metadata"] == {
        "display_primaries_xy": {"red": r, "green": g, "blue": b},
        "display_white_xy": wp,
        "display_min_luminance": float(display[9]),
        "display_max_luminance": float(display[10]),
        "max_cll": int(light[1]),
        "max_fall": int(light[2]),
    }
    assert record["tags"] == {"color_trc": 16, "color_primaries": 9, "colorspace": 9,
                              "color_range": 1}  # fmt: skip
    assert (record["transfer"], record["primaries"], record["bits"]) == ("pq", "bt2020", 10)
    assert (record["codec"], record["audio"], record["frames"]) == ("hevc", 1, 6)
    assert record["decoded_to"] == {"units": "cd/m2, linear BT.709 RGB", "multiplier": 1.0}
    # A clip without the metadata has none; SDR says its white.
    sdr = _clip(tmp_path / "sdr.mp4", "bt709")
    status, err = run(capsys, "render", str(sdr), "--format", "mp4", "--out", str(tmp_path / "s"))
    record = json.loads((tmp_path / "s" / "source.json").read_text())
    assert record["hdr_metadata"] == {} and record["decoded_to"]["sdr_white"] == 100.0


def test_dolby_vision_without_a_base_layer_is_refused(tmp_path, capsys):
    # Profile 5 is stored in a dvhe (or dvh1) sample entry: the HDR10
    # clip's hev1 entry renamed, as FFmpeg then reports it.
    clip = _clip(tmp_path / "hdr10.mp4", "pq").read_bytes()
    assert clip.count(b"hev1") == 1
    dv = tmp_path / "dv.mp4"
    dv.write_bytes(clip.replace(b"hev1", b"dvhe"))
    said = subprocess.run([FFMPEG, "-hide_banner", "-i", str(dv)], capture_output=True, text=True)
    assert "Video: hevc (Main 10) (dvhe / " in said.stderr
    for given in ([], ["--video-transfer", "pq"]):
        out = tmp_path / "out"
        status, err = run(capsys, "render", str(dv), *given, "--out", str(out))
        assert_one_line_error(
            status, err, "dv.mp4: expected HDR10, HLG or SDR video, got Dolby Vision with no "
            "standard base layer (sample entry dvhe"
        )  # fmt: skip
        assert not out.exists()
