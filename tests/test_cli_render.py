"""``jaxadapt render``, end to end, on small inputs: its outputs, its
options and their errors, and its figures."""

import csv
import shutil
import threading
from pathlib import Path

import equinox as eqx
import imageio_ffmpeg
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from cli_runs import SMALL, assert_one_line_error, run

from jaxadapt import io, pipeline, runtime
from jaxadapt.cli import main
from jaxadapt.cli._output import _message
from jaxadapt.operators import pattanaik2000 as op


@pytest.mark.slow
def test_builtin_scene_writes_frames_video_sheet_plot_and_diagnostics(tmp_path, capsys):
    out = tmp_path / "out"
    status, _ = run(capsys, "render", "--scene", "title-step", *SMALL, "--out", str(out))
    assert status == 0
    assert b"\r" not in (out / "diagnostics.csv").read_bytes()  # LF line ends
    names = {p.name for p in out.iterdir()}
    assert {"video.mp4", "contact_sheet.png", "adaptation.png", "diagnostics.csv"} <= names
    assert len([n for n in names if n.startswith("frame_")]) == 10
    assert imageio_ffmpeg.count_frames_and_secs(str(out / "video.mp4"))[0] == 10
    rows = list(csv.DictReader(open(out / "diagnostics.csv")))
    assert len(rows) == 10 and list(rows[0]) == [
        "t",
        "G_rod",
        "G_cone",
        "A_rod",
        "A_cone",
        "B_rod",
        "B_cone",
        "sigma_rod",
        "sigma_cone",
        "rule",
    ]
    assert float(rows[1]["G_cone"]) == pytest.approx(1000, rel=0.01)
    assert [p.name for p in out.iterdir() if p.name.startswith(".")] == [".jaxadapt-render"]


@pytest.mark.slow
def test_hdr_files_in_and_linear_files_out(tmp_path, capsys):
    frames = [np.full((6, 8, 3), v, np.float32) for v in (0.01, 100.0, 100.0)]
    paths = []
    for i, (f, ext) in enumerate(zip(frames, (".exr", ".pfm", ".hdr"), strict=False)):
        paths.append(tmp_path / f"in_{i}{ext}")
        io.write_image(paths[-1], f)
    out = tmp_path / "out"
    status, err = run(
        capsys,
        "render",
        *map(str, paths),
        "--format",
        "pfm",
        "--fps",
        "10",
        "--multiplier",
        "2",
        "--out",
        str(out),
    )
    assert status == 0, err
    result = [io.read_hdr(out / f"frame_{k:05d}.pfm") for k in range(3)]
    assert all(np.all((r >= 0) & (r <= 1)) for r in result)
    rows = list(csv.DictReader(open(out / "diagnostics.csv")))
    assert float(rows[1]["G_cone"]) == pytest.approx(200.0, rel=1e-3)  # multiplier applied
    assert float(rows[2]["t"]) == pytest.approx(0.2)


@pytest.mark.slow
def test_a_video_ffmpeg_cannot_write_fails_the_run(tmp_path, capsys):
    # libx264 encodes at most 16,384 pixels a side: the encoder refuses to
    # open, and the run says so in one line, with nothing written.
    out = tmp_path / "out"
    size = ("--size", "20000x4", "--duration", "0.1", "--format", "mp4")
    status, err = run(capsys, "render", "--scene", "title-step", *size, "--out", str(out))
    assert_one_line_error(status, err, "video.mp4: libx264 cannot encode frames of 20000x4 (")
    assert not out.exists()


def test_missing_file(tmp_path, capsys, monkeypatch):
    calls = []
    monkeypatch.setattr(runtime, "retain_freed_memory", lambda: calls.append(1))
    status, err = run(capsys, "render", str(tmp_path / "nope.exr"), "--out", str(tmp_path / "o"))
    assert calls == [1]  # the command line keeps freed memory for reuse
    assert_one_line_error(status, err, "nope.exr", "no such file")
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_non_hdr_and_unreadable_files(tmp_path, capsys):
    png = tmp_path / "ldr.png"
    io.write_image(png, np.zeros((4, 4, 3), np.uint8))
    status, err = run(capsys, "render", str(png), "--out", str(tmp_path / "o"))
    assert_one_line_error(status, err, "ldr.png", "expected HDR")
    junk = tmp_path / "junk.exr"
    junk.write_bytes(b"not an image")
    status, err = run(capsys, "render", str(junk), "--out", str(tmp_path / "o"))
    assert_one_line_error(status, err, "junk.exr")


@pytest.mark.parametrize(
    "argv, words",
    [
        # argparse would take -64x36 for an option: "expected one argument"
        (["--size", "-64x36"], ("--size", "at least 2x2", "'-64x36'")),
        (["--size", "64x-36"], ("--size", "at least 2x2", "'64x-36'")),
        (["--fps", "-5"], ("--fps",)),
    ],
)
def test_negative_values_get_the_options_own_message(tmp_path, capsys, argv, words):
    with pytest.raises(SystemExit) as exit:
        main(["render", *argv, "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert_one_line_error(exit.value.code, err, *words)
    assert "expected one argument" not in err


@pytest.mark.slow
def test_a_render_larger_than_the_limit_or_the_disk_is_refused(tmp_path, capsys, monkeypatch):
    # 20 million frames at --fps 1e6 would take hours and about 80 GB.
    out = tmp_path / "o"
    args = ["render", "--size", "64x36", "--fps", "1e6", "--out", str(out)]
    status, err = run(capsys, *args)
    assert_one_line_error(status, err, "--fps, --duration", "20,000,000 frames", "--allow-large")
    assert not out.exists()
    # Frames that fit the limit but not the disk: the estimate and the free space.
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage._replace(free=10**4))
    args = ["render", "--scene", "flash", *SMALL, "--format", "pfm", "--out", str(out)]
    status, err = run(capsys, *args)
    assert_one_line_error(status, err, "--out", "more than the 10 kB free", "--allow-large")
    assert not out.exists()
    status, err = run(capsys, *args, "--allow-large")
    assert status == 0, err


def test_frames_of_different_sizes(tmp_path, capsys):
    a, b = tmp_path / "a.exr", tmp_path / "b.exr"
    io.write_image(a, np.ones((4, 4, 3), np.float32))
    io.write_image(b, np.ones((5, 4, 3), np.float32))
    status, err = run(capsys, "render", str(a), str(b), "--out", str(tmp_path / "o"))
    assert_one_line_error(status, err, "b.exr", "expected 4x4", "got 4x5")


def test_a_bad_file_late_in_a_sequence_is_found_before_rendering(tmp_path):
    # Sizes and readability come from the headers, up front: otherwise a
    # wrong last frame would be found only when its chunk is read, after the
    # render of all the frames before it.
    from jaxadapt import pipeline

    paths = [tmp_path / f"f{k}.exr" for k in range(4)]
    for path in paths[:3]:
        io.write_image(path, np.ones((4, 6, 3), np.float32))
    io.write_image(paths[3], np.ones((4, 5, 3), np.float32))
    with pytest.raises(ValueError, match=r"f3\.exr: expected 6x4 like .*f0\.exr, got 5x4"):
        pipeline.from_files(paths, 30.0)
    paths[3].write_bytes(b"not an image")
    with pytest.raises(ValueError, match=r"f3\.exr: cannot read as an image"):
        pipeline.from_files(paths, 30.0)


def test_a_sequence_shorter_than_one_frame_is_refused(tmp_path, capsys):
    out = tmp_path / "new" / "out"
    status, err = run(capsys, "render", "--duration", "0.01", "--out", str(out))
    assert_one_line_error(status, err, "--duration: expected from 1 to 1e+08 frames")
    assert not (tmp_path / "new").exists()  # a failed run leaves no folder behind


def test_bad_values_are_counted_and_located(tmp_path, capsys):
    # Each kind of bad value is counted and its first pixel located, not
    # one count of "negative, NaN or infinite values" and no place to look.
    frame = np.ones((4, 5, 3), np.float32)
    frame[1, 3, 0], frame[2, 0] = -1e-4, np.nan
    bad = tmp_path / "bad.exr"
    io.write_image(bad, frame)
    status, err = run(capsys, "render", str(bad), "--out", str(tmp_path / "o"))
    assert_one_line_error(
        status,
        err,
        "1 pixel with negative values, 1 pixel with NaN",
        "row 1, column 3",
        "--fixnan black --clamp:min=0 -o OUT",
    )
    # The repair offered is that of what the frame holds, and only that: no
    # clipping of negative values where there are none.
    frame[1, 3, 0], frame[3, 4, 1] = 1.0, np.inf
    io.write_image(bad, frame)
    status, err = run(capsys, "render", str(bad), "--out", str(tmp_path / "o"))
    assert_one_line_error(
        status,
        err,
        "1 pixel with NaN values, 1 pixel with infinite values",
        "row 2, column 0",
        "--fixnan black -o OUT sets NaN and infinite pixels to black",
    )
    assert "clamp" not in err


@pytest.mark.slow
def test_fps_takes_a_fraction(tmp_path, capsys):
    # 24000/1001, as video rates are written.
    image = tmp_path / "in.exr"
    io.write_image(image, np.ones((4, 4, 3), np.float32))
    out = tmp_path / "o"
    args = ["render", str(image), str(image), "--fps", "24000/1001", "--format", "exr"]
    assert run(capsys, *args, "--out", str(out))[0] == 0
    rows = list(csv.DictReader(open(out / "diagnostics.csv")))
    assert float(rows[1]["t"]) == pytest.approx(1001 / 24000)


@pytest.mark.slow
def test_pixels_per_degree_is_taken_within_its_range(tmp_path, capsys):
    # Beyond the range jacobs2015's blurs, sized in pixels, outgrow any
    # frame (minutes on 3 frames of 64x48 at 1e6); at its low end the
    # foveal goal still gives finite frames.
    for value in ("1e-4", "2e4"):
        with pytest.raises(SystemExit) as exit:
            main(["render", "--pixels-per-degree", value])
        assert_one_line_error(
            exit.value.code, capsys.readouterr().err, "--pixels-per-degree", "0.001 to 10000", value
        )
    out = tmp_path / "o"
    args = ["render", *SMALL, "--pixels-per-degree", "1e-3", "--format", "exr", "--out", str(out)]
    status, err = run(capsys, *args)
    assert status == 0, err
    assert np.isfinite(io.read_hdr(out / "frame_00000.exr")).all()


@pytest.mark.slow
def test_a_background_scale_beyond_the_frame_is_refused_before_the_render(tmp_path, capsys):
    # A scale beyond the frame costs memory for nothing: 1e9 on a 1x1 frame
    # would take 24 GB, 1e5 on 64x48 677 MB.
    out = tmp_path / "o"
    args = ["render", "--scene", "flash", "--size", "48x32", "--duration", "0.3"]
    status, err = run(capsys, *args, "--background", "box", "--background-scale", "1000",
                       "--out", str(out))  # fmt: skip
    assert_one_line_error(status, err, "--background-scale: expected at most 48 pixels", "1000")
    assert not out.exists()
    status, _ = run(capsys, *args, "--background", "gaussian", "--background-scale", "48",
                     "--out", str(out))  # fmt: skip
    assert status == 0


@pytest.mark.slow
def test_a_frame_rate_too_low_for_a_video_is_refused_before_the_render(tmp_path, capsys):
    # ffmpeg would fail to write it, after the whole render.
    image = tmp_path / "in.exr"
    io.write_image(image, np.ones((8, 8, 3), np.float32))
    out = tmp_path / "o"
    status, err = run(capsys, "render", str(image), "--fps", "1e-5", "--out", str(out))
    assert_one_line_error(status, err, "--fps", "at least 0.0001 frames/s", "got 1e-05")
    assert not out.exists()
    status, _ = run(capsys, "render", str(image), "--fps", "1e-5", "--format", "exr",
                     "--out", str(out))  # fmt: skip
    assert status == 0


def test_overflow_after_the_multiplier_is_named(tmp_path, capsys):
    bright = tmp_path / "bright.exr"
    io.write_image(bright, np.full((4, 4, 3), 1e8, np.float32))
    args = ["render", str(bright), "--multiplier", "1e32"]
    status, err = run(capsys, *args, "--out", str(tmp_path / "o"))
    assert_one_line_error(status, err, "bright.exr", "multiplier")


@pytest.mark.slow
def test_a_render_whose_cone_pigment_is_all_but_bleached_says_so(tmp_path, capsys):
    # Frames of 1e12 cd/m2 (or frames in other units, 1e28) render as the
    # display's black: the model's prediction (the cones' responses scale
    # with the unbleached pigment), which pfstmo's operator shares, but one
    # that looks like a failed render, so it is said.
    for luminance, warned in ((1e8, False), (1e12, True), (1e28, True)):
        path = tmp_path / "bright.exr"
        io.write_image(path, np.full((4, 4, 3), luminance, np.float32))
        out = tmp_path / f"o{luminance:g}"
        status, err = run(capsys, "render", str(path), "--format", "exr", "--out", str(out))
        assert status == 0, err
        said = " ".join(err.split())
        assert ("warning: at 1 of 1 frames" in said) == warned, said
        if warned:
            assert "over 99% bleached" in said and "display's black" in said
            assert "--multiplier" in said
            assert io.read_hdr(out / "frame_00000.exr").max() < 0.05  # near black, finite


@pytest.mark.slow
def test_a_check_inside_the_operator_gives_its_own_message(tmp_path, capsys):
    args = ["render", "--scene", "title-step", *SMALL, "--multiplier", "1e38"]
    status, err = run(capsys, *args, "--out", str(tmp_path / "o"))
    assert_one_line_error(status, err, "scene title-step", "multiplier")
    # A value check compiled into an operator called inside jit raises an
    # error whose text starts with the stack; the command line prints its message.
    with pytest.raises(eqx.EquinoxRuntimeError) as error:
        eqx.filter_jit(lambda f: op.run(op.Params(), f, 0.1)[0])(jnp.full((2, 4, 4, 3), jnp.inf))
    assert _message(error.value) == "frames: expected finite, non-negative luminance (cd/m2)"


@pytest.mark.parametrize(
    "args, option",
    [
        (["--operator", "jacobs2015", "--background", "box"], "--background"),
        (["--operator", "jacobs2015", "--encoding", "gamma"], "--encoding"),
        (["--operator", "ward-jnd", "--adaptation-goal", "foveal"], "--adaptation-goal"),
        (["--background-scale", "4"], "--background-scale"),
        (["--background", "gaussian", "--adaptation-goal", "white_fraction"], "--adaptation-goal"),
        (["FILE", "--gaze", "GAZE"], "--gaze"),  # pattanaik2000, goal log_average, global
        (["--background", "arithmetic", "--background-scale", "4"], "--background-scale"),
        (["--background", "adaptive", "--background-scale", "0.5"], "--background-scale"),
        (["--seed", "4"], "--seed"),
        (["--operator", "schlick1994", "--pixels-per-degree", "20"], "--pixels-per-degree"),
        (["FILE", "--pixels-per-degree", "60"], "--pixels-per-degree"),  # log-average goal
        (["FILE", "--size", "8x8"], "--size"),
        (["FILE", "--scene", "flash"], "--scene"),
    ],
)
def test_options_that_would_be_ignored_are_refused(tmp_path, capsys, args, option):
    image = tmp_path / "in.exr"
    io.write_image(image, np.ones((4, 4, 3), np.float32))
    gaze = tmp_path / "gaze.csv"
    gaze.write_text("t,x,y\n0,1,1\n")
    builtin = "FILE" not in args
    args = [{"FILE": str(image), "GAZE": str(gaze)}.get(a, a) for a in args]
    status, err = run(capsys, "render", *SMALL * builtin, *args, "--out", "o")
    assert_one_line_error(status, err, option)


@pytest.mark.slow
def test_fps_sets_the_frame_rate_of_a_builtin_scene(tmp_path, capsys):
    out = tmp_path / "out"
    args = ["render", "--scene", "flash", "--size", "16x16", "--duration", "0.5", "--fps", "10"]
    assert run(capsys, *args, "--format", "exr", "--format", "mp4", "--out", str(out))[0] == 0
    rows = list(csv.DictReader(open(out / "diagnostics.csv")))
    # and the flash (0.25 to 0.375 s) begins and ends on frames of its own,
    times = [0.0, 0.1, 0.2, 0.25, 0.3, 0.375, 0.4]
    assert [float(r["t"]) for r in rows] == pytest.approx(times)
    # which the video shows at the rate asked for, not the median frame's (75 ms: 13.3 fps).
    frames, seconds = imageio_ffmpeg.count_frames_and_secs(str(out / "video.mp4"))
    assert frames == 7 and seconds == pytest.approx(0.7, abs=0.01)


def test_help_explains_every_option(capsys):
    with pytest.raises(SystemExit):
        main(["render", "--help"])
    text = capsys.readouterr().out
    for option in ("--scene", "--fps", "--multiplier", "--adaptation-goal", "--out", "--format"):
        assert option in text


@pytest.mark.slow
@pytest.mark.parametrize(
    "operator, background",
    [("photographic", "global"), ("ward-jnd", "adaptive"), ("pattanaik2000", "bilateral")],
)
def test_operators_and_backgrounds(tmp_path, capsys, operator, background):
    out = tmp_path / "out"
    args = ["render", "--scene", "tunnel", "--size", "32x18", "--duration", "0.2"]
    args += ["--operator", operator, "--background", background]
    args += [] if background == "global" else ["--background-scale", "2"]
    status, err = run(capsys, *args, "--format", "exr", "--out", str(out))
    assert status == 0, err
    frame = io.read_hdr(out / "frame_00005.exr")
    assert np.all((frame >= 0) & (frame <= 1)) and frame.max() > 0.05
    rows = list(csv.DictReader(open(out / "diagnostics.csv")))
    assert len(rows) == 6
    assert ("background" in rows[0]) == (operator != "pattanaik2000")


@pytest.mark.slow
def test_jacobs2015_follows_a_recorded_gaze(tmp_path, capsys):
    gaze = tmp_path / "gaze.csv"
    gaze.write_text("t,x,y\n0,5,4\n0.1,nan,nan\n0.15,25,12\n")
    out = tmp_path / "out"
    args = ["render", "--operator", "jacobs2015", "--scene", "checkerboard", "--size", "32x18"]
    status, err = run(
        capsys, *args, "--duration", "0.2", "--gaze", str(gaze), "--seed", "3", "--out", str(out)
    )
    assert status == 0, err
    rows = list(csv.DictReader(open(out / "diagnostics.csv")))
    xs = [float(r["gaze_x"]) for r in rows]
    assert xs[0] == 5 and xs[3] == 5 and xs[5] == 25  # the blink holds the fixation
    assert {"B_L", "C_S", "A"} <= set(rows[0])
    assert "warning" not in err
    # A gaze off the frame (here in a larger screen's pixels) is said: the
    # operator takes the frame's nearest point.
    gaze.write_text("t,x,y\n0,5,4\n0.1,640,12\n")
    status, err = run(capsys, *args, "--duration", "0.2", "--gaze", str(gaze), "--out", str(out))
    assert status == 0, err
    said = " ".join(err.split())
    assert f"warning: --gaze: {gaze} leaves the 32x18 frame at 3 of 6 frames" in said, said
    assert "first (640, 12) pixels at 0.1 s" in said
    rows = list(csv.DictReader(open(out / "diagnostics.csv")))
    assert [float(r["gaze_x"]) for r in rows] == [5, 5, 5, 31, 31, 31]


@pytest.mark.slow
def test_a_blink_in_the_gaze_holds_the_fixation_for_pattanaik2000(tmp_path, capsys):
    # The foveal goal during a blink is the one at the fixation before it
    # (the recorded path holds it), not NaN and not black frames after it.
    gaze = tmp_path / "gaze.csv"
    gaze.write_text("t,x,y\n0,5,4\n0.1,nan,nan\n0.2,25,12\n")
    out = tmp_path / "out"
    args = ["render", "--scene", "tunnel", "--size", "32x18", "--duration", "0.3"]
    args += ["--adaptation-goal", "foveal", "--format", "exr", "--chunk", "4"]
    status, err = run(capsys, *args, "--gaze", str(gaze), "--out", str(out))
    assert status == 0, err
    rows = list(csv.DictReader(open(out / "diagnostics.csv")))
    values = np.array([[float(v) for v in r.values()] for r in rows])
    assert np.all(np.isfinite(values))
    frames = [io.read_hdr(out / f"frame_{k:05d}.exr") for k in range(len(rows))]
    assert min(float(f.max()) for f in frames) > 0.05
    held = tmp_path / "held.csv"  # the same path with the fixation written out
    held.write_text("t,x,y\n0,5,4\n0.1,5,4\n0.2,25,12\n")
    status, err = run(capsys, *args, "--gaze", str(held), "--out", str(tmp_path / "held"))
    assert status == 0, err
    for k in range(len(rows)):
        np.testing.assert_array_equal(
            frames[k], io.read_hdr(tmp_path / "held" / f"frame_{k:05d}.exr")
        )


@pytest.mark.slow
def test_a_gaze_file_of_blinks_alone_is_warned_about(tmp_path, capsys):
    # Every sample a blink: the frame's centre is used, and that is said.
    gaze = tmp_path / "gaze.csv"
    gaze.write_text("t,x,y\n0,nan,nan\n")
    args = ["render", "--scene", "tunnel", "--size", "32x18", "--duration", "0.2"]
    args += ["--adaptation-goal", "foveal", "--format", "pfm"]
    status, err = run(capsys, *args, "--gaze", str(gaze), "--out", str(tmp_path / "o"))
    assert status == 0, err
    said = " ".join(err.split())
    assert "warning: --gaze:" in said and "holds no fixation" in said, said
    gaze.write_text("t,x,y\n0,nan,nan\n0.1,5,4\n")  # one fixation: no warning
    status, err = run(capsys, *args, "--gaze", str(gaze), "--out", str(tmp_path / "o"))
    assert status == 0 and "fixation" not in err, err


def test_bad_gaze_file_is_named(tmp_path, capsys):
    gaze = tmp_path / "gaze.csv"
    gaze.write_text("t,x,y\n0,5\n")
    status, err = run(
        capsys,
        "render",
        "--operator",
        "jacobs2015",
        "--scene",
        "flash",
        *SMALL,
        "--gaze",
        str(gaze),
        "--out",
        str(tmp_path / "o"),
    )
    assert_one_line_error(status, err, "gaze.csv")


def test_a_memory_error_is_one_line_too(tmp_path, capsys, monkeypatch):
    # NumPy's MemoryError (a filter's index arrays) is one line too, not a traceback.
    def exhausted(*args, **kwargs):
        raise MemoryError("Unable to allocate 2.02 GiB")

    monkeypatch.setattr(pipeline, "chunks", exhausted)
    out = tmp_path / "o"
    status, err = run(capsys, "render", "--scene", "flash", *SMALL, "--out", str(out))
    assert_one_line_error(status, err, "out of memory", "--chunk, --size or --background-scale")
    assert not out.exists()


def test_contact_sheet_labels_each_frame():
    from jaxadapt import figures

    strip = figures.LABEL_HEIGHT
    sheet = figures.contact_sheet(np.zeros((3, 20, 60, 3), np.uint8), 2, ["0 s", "1.5 s", "3 s"])
    assert sheet.shape == (2 * (20 + strip + 4) + 4, 2 * 64 + 4, 3)
    for top, left in ((24, 4), (24, 68), (24 + strip + 24, 4)):  # each frame's strip
        assert (sheet[top : top + strip, left : left + 60] < 128).any()  # text is drawn
    assert (sheet[24 + strip + 24 :, 68:] == 255).all()  # no fourth frame, no label
    with pytest.raises(ValueError, match="labels: expected one for each of the 3 frames, got 2"):
        figures.contact_sheet(np.zeros((3, 20, 60, 3), np.uint8), labels=["a", "b"])


@pytest.mark.slow
def test_the_contact_sheet_spans_the_sequence(tmp_path, capsys, monkeypatch):
    # The tunnel's 12 tiles span the drive, from its first to its last
    # frame, few in its first second and one on the exit.
    from jaxadapt import figures

    sheets = []
    contact_sheet = figures.contact_sheet
    monkeypatch.setattr(
        figures, "contact_sheet", lambda f, **k: sheets.append(k["labels"]) or contact_sheet(f, **k)
    )
    args = ["render", "--size", "48x32", "--duration", "20", "--fps", "5", "--format", "png"]
    assert run(capsys, *args, "--out", str(tmp_path / "o"))[0] == 0
    (labels,) = sheets
    times = [float(label.removesuffix(" s")) for label in labels]
    assert len(times) == 12 and times[0] == 0 and times[-1] == pytest.approx(19.8)
    assert sum(t < 1 for t in times) <= 2, times
    assert any(12 < t < 15 for t in times), times  # the tunnel's exit


@pytest.mark.slow
def test_the_2015_diagnostics_plot_has_units_and_says_why_a_is_flat(tmp_path):
    # A and A_T can sit at the 100 cd/m2 floor and rho run to 2.7: the plot
    # says why, and its y axes have units.
    from jaxadapt import figures
    from jaxadapt.operators import jacobs2015

    table = {"t": np.arange(3.0), "A": np.full(3, 2.0), "rho": np.array([-0.17, 0.5, 2.7])}
    notes = jacobs2015.diagnostics_notes(jacobs2015.Params())
    fig = figures.plot_columns(
        tmp_path / "a.png", table, "t", units=jacobs2015.DIAGNOSTIC_UNITS, notes=notes
    )
    assert [ax.get_ylabel() for ax in fig.axes[:2]] == ["log10 cd/m2", "Eq 13, unclamped"]
    said = " ".join(text.get_text() for text in fig.texts)
    assert "floored at 100 cd/m2" in said and "clamped to [0, 1]" in said
    assert set(table) - {"t"} <= set(jacobs2015.DIAGNOSTIC_UNITS)
    frames, dt = jnp.full((2, 8, 8, 3), 1.0), jnp.full(2, 0.1)
    diag = jacobs2015.run(jacobs2015.Params(), frames, dt, key=jax.random.key(0))[1]
    columns = jacobs2015.diagnostics_table(diag)
    assert set(columns) - {"t"} == set(jacobs2015.DIAGNOSTIC_UNITS)


@pytest.mark.parametrize(
    "argv, message",
    [
        # a 20 s tunnel at 1e-5 frames/s has no frame: --fps is named, not --duration
        (["--fps", "1e-5"], "--fps: expected from 1 to 1e+08 frames"),
        (["--scene", "flash", "--duration", "0.2"], "--duration: expected more"),
        (["--duration", "1e308", "--fps", "10"], "--duration, --fps: expected"),  # OverflowError
    ],
)
def test_a_scenes_error_names_the_options_given(tmp_path, capsys, argv, message):
    status, err = run(capsys, "render", *argv, "--out", str(tmp_path / "o"))
    assert_one_line_error(status, err, message)
    assert not (tmp_path / "o").exists()


def test_curves_are_drawn_where_adaptation_changes():
    from jaxadapt import figures

    # The title-page step: A jumps within 0.3 s of a 4 s sequence; frames
    # evenly spaced in time would draw none of the transient (0, 0.57, 1.14 s ...).
    t = np.arange(134) * 0.03
    A = np.where(t < 0.03, 0.01, 1000 - 999.99 * np.exp(-(t - 0.03) / 0.08))
    picks = t[figures.curve_frames({"t": t, "A_rod": A, "A_cone": A})]
    assert picks[0] == 0 and picks[-1] == t[-1] and np.sum((picks > 0) & (picks < 0.3)) >= 1
    steady = figures.curve_frames({"t": t, "A_rod": np.ones(134), "A_cone": np.ones(134)})
    np.testing.assert_array_equal(steady, np.linspace(0, 133, 8).round())
    one = {"t": t[:1], "A_rod": A[:1], "A_cone": A[:1]}
    np.testing.assert_array_equal(figures.curve_frames(one), [0])


@pytest.mark.parametrize(
    "name, args, message",
    [
        ("contact_sheet", (np.full((2, 4, 4, 3), 0.8),), "frames: expected uint8"),
        ("contact_sheet", (np.zeros((2, 4, 4), np.uint8),), "frames: expected uint8"),
        ("contact_sheet", (np.zeros((2, 4, 4, 3), np.uint8), 0), "columns: expected"),
        ("curve_frames", ({"t": [], "A_rod": [], "A_cone": []},), "diag: expected"),
        ("plot_columns", ("x.png", {"t": np.zeros(3)}, ""), "table: expected"),
    ],
)
def test_figures_name_what_they_cannot_draw(name, args, message):
    # Unchecked, floats in [0, 1] would be drawn black, a 3-axis stack would
    # fail to unpack, and no frame or no column would fail with an
    # IndexError or a division by 0.
    from jaxadapt import figures

    with pytest.raises(ValueError, match=message):
        getattr(figures, name)(*args)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("numbers", "warned"),
    [
        ((1, 10, 11, 2, 3), ("f11.exr", "f2.exr")),  # a shell's glob of f1 ... f11
        ((1, 1, 10, 2), ("f10.exr", "f2.exr")),
        ((1, 2, 3, 10), None),
        ((10, 3, 2, 1), None),  # reversed on purpose
    ],
)
def test_frame_numbers_out_of_order_are_warned_of(tmp_path, capsys, numbers, warned):
    paths = [str(tmp_path / f"f{n}.exr") for n in numbers]
    for p in set(paths):
        io.write_image(p, np.ones((4, 6, 3), np.float32))
    out = tmp_path / "out"
    status, err = run(capsys, "render", *paths, "--format", "exr", "--out", str(out))
    assert status == 0, err
    if warned is None:
        assert "warning" not in err
    else:
        before, after = (str(tmp_path / name) for name in warned)
        assert f"warning: FILE: {before} comes before {after}: " in " ".join(err.split())


def _exr_at_rate(path, rate):
    """A small grey EXR whose header gives the frame rate ``rate`` (num, den),
    whatever it is (:func:`jaxadapt.io.write_image` writes only good ones)."""
    import OpenImageIO as oiio

    spec = oiio.ImageSpec(6, 4, 3, "float")
    spec.attribute("FramesPerSecond", oiio.TypeDesc("rational2i"), rate)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(np.full((4, 6, 3), 50.0, np.float32))
    out.close()


@pytest.mark.slow
def test_files_play_at_the_rate_their_header_gives(tmp_path, capsys):
    # The first file's FramesPerSecond is the default rate: a 23.976 fps EXR
    # sequence simulated at 30 fps would adapt 25 % fast.
    paths = [str(tmp_path / f"f{k}.exr") for k in range(3)]
    for p in paths:
        io.write_image(p, np.full((4, 6, 3), 50.0, np.float32), fps=24000 / 1001)
    for options, dt in (((), 1001 / 24000), (("--fps", "10"), 0.1)):
        out = tmp_path / f"out{len(options)}"
        status, err = run(capsys, "render", *paths, *options, "--format", "exr", "--out", str(out))
        assert status == 0, err
        t = [float(row["t"]) for row in csv.DictReader(open(out / "diagnostics.csv"))]
        np.testing.assert_allclose(np.diff(t), dt, rtol=1e-5)  # t written to 6 digits
        assert io.frame_rate(out / "frame_00002.exr") == pytest.approx(1 / dt, rel=1e-12)
    bad = tmp_path / "bad.exr"
    _exr_at_rate(bad, (30, 0))
    status, err = run(capsys, "render", str(bad), "--out", str(tmp_path / "o"))
    assert_one_line_error(status, err, "bad.exr", "FramesPerSecond, got 30/0")
    _exr_at_rate(bad, (1, 1_000_000))
    status, err = run(capsys, "render", str(bad), "--out", str(tmp_path / "o"))
    assert_one_line_error(status, err, "bad.exr", "FramesPerSecond, 1e-06, is outside", "--fps")


def test_size_help_gives_each_scenes_default_size(capsys):
    # Every scene's, as the scene renders its frames.
    from jaxadapt.scenes import SCENES

    with pytest.raises(SystemExit):
        main(["render", "--help"])
    said = " ".join(capsys.readouterr().out.split())
    for name, scene in SCENES.items():
        frame = pipeline.from_scene(scene()).frames(np.arange(1))[0]
        assert f"{frame.shape[1]}x{frame.shape[0]} {name}" in said, name


def _stream_threads():
    return [t for t in threading.enumerate() if t.name.startswith("jaxadapt-")]


@pytest.mark.slow
def test_a_streamed_render_gives_the_frames_and_diagnostics_of_a_plain_loop(tmp_path, capsys):
    # Reading ahead and writing behind in threads change nothing: the frames
    # and diagnostics are those of the operator called chunk after chunk.
    frames = _gradient_frames(7)
    paths = []
    for i, frame in enumerate(frames):
        paths.append(tmp_path / f"in_{i}.pfm")
        io.write_image(paths[-1], frame)
    out = tmp_path / "out"
    status, err = run(
        capsys, "render", *map(str, paths), "--format", "pfm", "--chunk", "3", "--out", str(out)
    )
    assert status == 0, err
    params, state, expected, tables = op.Params(), None, [], []
    for start in range(0, 7, 3):
        chunk = jnp.asarray(frames[start : start + 3])
        state = op.init(params, chunk[0]) if state is None else state
        shown, diag = op.run(params, chunk, jnp.full(len(chunk), 1 / 30, jnp.float32), state=state)
        state = diag.final_state
        expected.append(np.asarray(shown))
        tables.append(op.diagnostics_table(diag))
    expected = np.concatenate(expected)
    for i in range(7):
        np.testing.assert_array_equal(io.read_hdr(out / f"frame_{i:05d}.pfm"), expected[i])
    with open(out / "diagnostics.csv") as f:
        rows = list(csv.DictReader(f))
    column = np.concatenate([t["G_cone"] for t in tables])
    assert [row["G_cone"] for row in rows] == [f"{v:.6g}" for v in column]
    assert _stream_threads() == []


def _gradient_frames(T, H=12, W=20):
    rng = np.random.default_rng(1)
    level = np.geomspace(0.01, 1e4, T)[:, None, None, None]
    return (rng.uniform(0.5, 2.0, (T, H, W, 3)) * level).astype(np.float32)


@pytest.mark.slow
@pytest.mark.parametrize("stage", ["read", "write"])
def test_an_error_mid_stream_stops_the_render_and_joins_its_threads(
    tmp_path, capsys, monkeypatch, stage
):
    # A bad frame read ahead, or a frame the writer cannot write, in the
    # middle of a sequence: one line, exit 2, no file in --out and no
    # thread left running.
    frames = _gradient_frames(9)
    if stage == "read":
        frames[5, 2, 3, 1] = -1.0
    paths = []
    for i, frame in enumerate(frames):
        paths.append(tmp_path / f"in_{i}.pfm")
        io.write_image(paths[-1], frame)
    if stage == "write":
        write_image = io.write_image

        def failing(path, pixels, *args, **kwargs):
            if Path(path).name == "frame_00005.pfm":
                raise OSError(f"{path}: cannot write (a broken disk)")
            return write_image(path, pixels, *args, **kwargs)

        monkeypatch.setattr(io, "write_image", failing)
    out = tmp_path / "out"
    status, err = run(
        capsys, "render", *map(str, paths), "--format", "pfm", "--chunk", "2", "--out", str(out)
    )
    assert_one_line_error(status, err, "in_5.pfm" if stage == "read" else "frame_00005.pfm")
    assert not out.exists()
    assert _stream_threads() == []
