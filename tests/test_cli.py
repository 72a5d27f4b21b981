"""The command line, end to end, on small inputs."""

import csv
import errno
import importlib.metadata
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import equinox as eqx
import imageio_ffmpeg
import jax
import jax.numpy as jnp
import matplotlib.image
import numpy as np
import processes
import pytest
import statsmodels.api as sm
from scipy.stats import mannwhitneyu

from jaxadapt import _signals, io, pipeline, runtime
from jaxadapt.cli import _staging, main
from jaxadapt.cli._output import _message
from jaxadapt.operators import pattanaik2000 as op

#: End-to-end or long: left out of the quick run (pytest -m "not slow").
pytestmark = pytest.mark.slow

SMALL = ["--size", "48x32", "--duration", "0.3"]


def _run(capsys, *argv):
    status = main(list(argv))
    return status, capsys.readouterr().err


def _start(*argv, ignored=()):
    """``python -m jaxadapt ARGV`` started in a process of its own with the
    default signal dispositions but ``ignored``, its stderr piped (text),
    its stdout discarded."""
    return processes.python(
        ["-m", "jaxadapt", *argv],
        ignored,
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
    )


@pytest.fixture
def interruptible():
    """Ctrl-C handled in this process for one test, as in a shell's
    foreground (a suite started in the background ignores it), then as
    before."""
    saved = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, saved)


def _fit_rows(capsys, rows, folder, *options):
    """``psychometric fit`` of a table of ``rows`` (lines), written to
    ``folder/trials.csv``, into ``folder``: ``(status, stderr)``."""
    folder.mkdir(parents=True, exist_ok=True)
    trials = folder / "trials.csv"
    trials.write_text("\n".join(rows) + "\n")
    return _run(capsys, "psychometric", "fit", str(trials), *options, "--out", str(folder))


def test_builtin_scene_writes_frames_video_sheet_plot_and_diagnostics(tmp_path, capsys):
    out = tmp_path / "out"
    status, _ = _run(capsys, "render", "--scene", "title-step", *SMALL, "--out", str(out))
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


def test_tunnel_scene_chunks_give_the_same_as_one_call(tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    args = ["render", "--scene", "tunnel", "--size", "32x18", "--duration", "1", "--format", "exr"]
    assert _run(capsys, *args, "--out", str(a), "--chunk", "7")[0] == 0
    assert _run(capsys, *args, "--out", str(b), "--chunk", "64")[0] == 0
    for k in (0, 13, 29):
        np.testing.assert_allclose(
            io.read_hdr(a / f"frame_{k:05d}.exr"), io.read_hdr(b / f"frame_{k:05d}.exr"), atol=1e-6
        )


def test_hdr_files_in_and_linear_files_out(tmp_path, capsys):
    frames = [np.full((6, 8, 3), v, np.float32) for v in (0.01, 100.0, 100.0)]
    paths = []
    for i, (f, ext) in enumerate(zip(frames, (".exr", ".pfm", ".hdr"), strict=False)):
        paths.append(tmp_path / f"in_{i}{ext}")
        io.write_image(paths[-1], f)
    out = tmp_path / "out"
    status, err = _run(
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


def _assert_one_line_error(status, err, *words):
    assert status == 2
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("jaxadapt: error:"), err
    for w in words:
        assert w in lines[0]


def test_a_video_ffmpeg_cannot_write_fails_the_run(tmp_path, capsys):
    # H.264 is at most 16,384 pixels wide. imageio-ffmpeg's writer does not
    # check ffmpeg's exit status: the run said it had written video.mp4, of
    # 0 bytes, with ffmpeg's ten lines of errors on the terminal.
    out = tmp_path / "out"
    size = ("--size", "20000x4", "--duration", "0.1", "--format", "mp4")
    status, err = _run(capsys, "render", "--scene", "title-step", *size, "--out", str(out))
    _assert_one_line_error(status, err, "video.mp4", "invalid width x height (20000x4)")
    assert not out.exists()


def test_missing_file(tmp_path, capsys, monkeypatch):
    calls = []
    monkeypatch.setattr(runtime, "retain_freed_memory", lambda: calls.append(1))
    status, err = _run(capsys, "render", str(tmp_path / "nope.exr"), "--out", str(tmp_path / "o"))
    assert calls == [1]  # the command line keeps freed memory for reuse
    _assert_one_line_error(status, err, "nope.exr", "no such file")
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_non_hdr_and_unreadable_files(tmp_path, capsys):
    png = tmp_path / "ldr.png"
    io.write_image(png, np.zeros((4, 4, 3), np.uint8))
    status, err = _run(capsys, "render", str(png), "--out", str(tmp_path / "o"))
    _assert_one_line_error(status, err, "ldr.png", "expected HDR")
    junk = tmp_path / "junk.exr"
    junk.write_bytes(b"not an image")
    status, err = _run(capsys, "render", str(junk), "--out", str(tmp_path / "o"))
    _assert_one_line_error(status, err, "junk.exr")


def test_bad_values_leave_earlier_output_untouched(tmp_path, capsys):
    good, bad = tmp_path / "a.exr", tmp_path / "b.exr"
    io.write_image(good, np.ones((4, 4, 3), np.float32))
    io.write_image(bad, np.full((4, 4, 3), -1.0, np.float32))
    out = tmp_path / "out"
    out.mkdir()
    (out / "frame_00000.png").write_bytes(b"earlier result")
    status, err = _run(capsys, "render", str(good), str(bad), "--out", str(out))
    _assert_one_line_error(status, err, "b.exr", "non-negative")
    assert [p.name for p in out.iterdir()] == ["frame_00000.png"]
    assert (out / "frame_00000.png").read_bytes() == b"earlier result"


@pytest.mark.parametrize(
    "argv, words",
    [
        # argparse took -64x36 for an option: "expected one argument"
        (["--size", "-64x36"], ("--size", "at least 2x2", "'-64x36'")),
        (["--size", "64x-36"], ("--size", "at least 2x2", "'64x-36'")),
        (["--fps", "-5"], ("--fps",)),
    ],
)
def test_negative_values_get_the_options_own_message(tmp_path, capsys, argv, words):
    with pytest.raises(SystemExit) as exit:
        main(["render", *argv, "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    _assert_one_line_error(exit.value.code, err, *words)
    assert "expected one argument" not in err


def test_a_render_larger_than_the_limit_or_the_disk_is_refused(tmp_path, capsys, monkeypatch):
    # 20 million frames at --fps 1e6 were accepted: hours and about 80 GB.
    out = tmp_path / "o"
    args = ["render", "--size", "64x36", "--fps", "1e6", "--out", str(out)]
    status, err = _run(capsys, *args)
    _assert_one_line_error(status, err, "--fps, --duration", "20,000,000 frames", "--allow-large")
    assert not out.exists()
    # Frames that fit the limit but not the disk: the estimate and the free space.
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage._replace(free=10**4))
    args = ["render", "--scene", "flash", *SMALL, "--format", "pfm", "--out", str(out)]
    status, err = _run(capsys, *args)
    _assert_one_line_error(status, err, "--out", "more than the 10 kB free", "--allow-large")
    assert not out.exists()
    status, err = _run(capsys, *args, "--allow-large")
    assert status == 0, err


def test_frames_of_different_sizes(tmp_path, capsys):
    a, b = tmp_path / "a.exr", tmp_path / "b.exr"
    io.write_image(a, np.ones((4, 4, 3), np.float32))
    io.write_image(b, np.ones((5, 4, 3), np.float32))
    status, err = _run(capsys, "render", str(a), str(b), "--out", str(tmp_path / "o"))
    _assert_one_line_error(status, err, "b.exr", "expected 4x4", "got 4x5")


def test_a_bad_file_late_in_a_sequence_is_found_before_rendering(tmp_path):
    # Sizes and readability come from the headers, up front: a wrong last
    # frame was found only when its chunk was read, after the render of all
    # the frames before it.
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


def test_unwritable_output(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    status, err = _run(capsys, "render", "--scene", "title-step", *SMALL, "--out", str(blocker))
    _assert_one_line_error(status, err, "--out: expected a folder, got the file", str(blocker))
    status, err = _run(
        capsys, "render", "--scene", "title-step", *SMALL, "--out", str(blocker / "x")
    )
    _assert_one_line_error(status, err, "--out: cannot write to", str(blocker / "x"))
    with pytest.raises(SystemExit) as exit:  # an empty path would be the current folder
        main(["render", "--out", ""])
    _assert_one_line_error(exit.value.code, capsys.readouterr().err, "--out", "empty path")


def test_a_sequence_shorter_than_one_frame_is_refused(tmp_path, capsys):
    out = tmp_path / "new" / "out"
    status, err = _run(capsys, "render", "--duration", "0.01", "--out", str(out))
    _assert_one_line_error(status, err, "--duration: expected from 1 to 1e+08 frames")
    assert not (tmp_path / "new").exists()  # a failed run leaves no folder behind


def test_bad_values_are_counted_and_located(tmp_path, capsys):
    # The message gave one count of "negative, NaN or infinite values" and
    # no place to look.
    frame = np.ones((4, 5, 3), np.float32)
    frame[1, 3, 0], frame[2, 0] = -1e-4, np.nan
    bad = tmp_path / "bad.exr"
    io.write_image(bad, frame)
    status, err = _run(capsys, "render", str(bad), "--out", str(tmp_path / "o"))
    _assert_one_line_error(
        status,
        err,
        "1 pixel with negative values, 1 pixel with NaN",
        "row 1, column 3",
        "--fixnan black --clamp:min=0 -o OUT",
    )
    # NaN and infinite values were told to clip negative ones: now the
    # repair of what the frame holds, and only that.
    frame[1, 3, 0], frame[3, 4, 1] = 1.0, np.inf
    io.write_image(bad, frame)
    status, err = _run(capsys, "render", str(bad), "--out", str(tmp_path / "o"))
    _assert_one_line_error(
        status,
        err,
        "1 pixel with NaN values, 1 pixel with infinite values",
        "row 2, column 0",
        "--fixnan black -o OUT sets NaN and infinite pixels to black",
    )
    assert "clamp" not in err


def test_fps_takes_a_fraction(tmp_path, capsys):
    # 24000/1001, as video rates are written, was refused.
    image = tmp_path / "in.exr"
    io.write_image(image, np.ones((4, 4, 3), np.float32))
    out = tmp_path / "o"
    args = ["render", str(image), str(image), "--fps", "24000/1001", "--format", "exr"]
    assert _run(capsys, *args, "--out", str(out))[0] == 0
    rows = list(csv.DictReader(open(out / "diagnostics.csv")))
    assert float(rows[1]["t"]) == pytest.approx(1001 / 24000)


def test_pixels_per_degree_is_taken_within_its_range(tmp_path, capsys):
    # 1e-6 stopped the tunnel's render with a traceback (non-finite display
    # frames: the foveal weights, now fixed), and jacobs2015 ran for minutes
    # on 3 frames of 64x48 at 1e6.
    for value in ("1e-4", "2e4"):
        with pytest.raises(SystemExit) as exit:
            main(["render", "--pixels-per-degree", value])
        _assert_one_line_error(
            exit.value.code, capsys.readouterr().err, "--pixels-per-degree", "0.001 to 10000", value
        )
    out = tmp_path / "o"
    args = ["render", *SMALL, "--pixels-per-degree", "1e-3", "--format", "exr", "--out", str(out)]
    status, err = _run(capsys, *args)
    assert status == 0, err
    assert np.isfinite(io.read_hdr(out / "frame_00000.exr")).all()


def test_a_failed_run_leaves_no_new_folder(tmp_path, capsys):
    bad = tmp_path / "bad.exr"
    io.write_image(bad, np.full((4, 4, 3), np.nan, np.float32))
    status, err = _run(capsys, "render", str(bad), "--out", str(tmp_path / "o"))
    _assert_one_line_error(status, err, "bad.exr", "non-negative")
    assert not (tmp_path / "o").exists()
    # Through a folder that does not exist and back (new/../o), the folders
    # made were new and o, and only new was removed; a good run left new.
    status, err = _run(capsys, "render", str(bad), "--out", str(tmp_path / "new" / ".." / "o"))
    _assert_one_line_error(status, err, "bad.exr", "non-negative")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.exr"]
    good = tmp_path / "good.exr"
    io.write_image(good, np.full((4, 4, 3), 1.0, np.float32))
    out = str(tmp_path / "new" / ".." / "o")
    assert _run(capsys, "render", str(good), "--out", out, "--format", "exr")[0] == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.exr", "good.exr", "o"]


def test_a_new_render_replaces_the_earlier_ones_outputs(tmp_path, capsys):
    out = tmp_path / "out"
    args = ["render", "--scene", "title-step", "--size", "24x16", "--out", str(out)]
    assert _run(capsys, *args, "--duration", "0.3")[0] == 0
    (out / "notes.txt").write_text("mine")
    assert _run(capsys, *args, "--duration", "0.09", "--format", "exr")[0] == 0
    names = sorted(p.name for p in out.iterdir())
    frames = [f"frame_{k:05d}.exr" for k in range(3)]
    files = ["adaptation.png", "contact_sheet.png", "diagnostics.csv", *frames, "notes.txt"]
    assert names == [".jaxadapt-render", *files]


def test_a_folder_where_an_output_goes_fails_the_run_before_anything_moves(tmp_path, capsys):
    # The moves into --out stopped at the folder: the outputs before it in
    # order were the new run's, those after it the old run's, and the
    # message named the removed staging folder.
    out = tmp_path / "out"
    args = ["render", "--scene", "title-step", "--size", "24x16", "--out", str(out)]
    assert _run(capsys, *args, "--duration", "0.3")[0] == 0
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    (out / "diagnostics.csv").unlink()
    (out / "diagnostics.csv").mkdir()
    del before["diagnostics.csv"]
    status, err = _run(capsys, *args, "--duration", "0.2")
    _assert_one_line_error(status, err, "--out", str(out / "diagnostics.csv"), "is a folder")
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == ["diagnostics.csv"]


def test_a_folder_named_as_an_output_is_refused_before_the_render(tmp_path, capsys, monkeypatch):
    # It was found only when the rendered files were moved into place.
    def rendered(*args, **kwargs):
        raise AssertionError("rendered")

    monkeypatch.setattr(pipeline, "chunks", rendered)
    out = tmp_path / "out"
    (out / "video.mp4").mkdir(parents=True)
    status, err = _run(capsys, "render", "--scene", "flash", *SMALL, "--out", str(out))
    _assert_one_line_error(status, err, "--out", str(out / "video.mp4"), "is a folder")
    assert [p.name for p in out.iterdir()] == ["video.mp4"]


def test_a_signal_while_the_outputs_move_waits_and_the_run_succeeds(
    tmp_path, monkeypatch, interruptible
):
    # A SIGINT after the first of the moves into --out left the new run's
    # first files beside the rest of the earlier run's, and the message said
    # that nothing was written.
    out = tmp_path / "out"
    out.mkdir()
    (out / "b.csv").write_text("old")
    replace = Path.replace

    def interrupted_replace(self, target):
        if not interrupted_replace.sent:
            interrupted_replace.sent = True
            os.kill(os.getpid(), signal.SIGINT)
        return replace(self, target)

    interrupted_replace.sent = False
    monkeypatch.setattr(Path, "replace", interrupted_replace)
    with _signals.interruptible(), _staging._staged(out, None) as staging:
        for name in ("a.csv", "b.csv", "c.csv"):
            (staging / name).write_text("new")
    # Once all are in place the run has succeeded: the signal is dropped
    # (it raised after the move, and the run said it was interrupted).
    assert _signals.WRITTEN.is_set() and _signals.SIGNALLED == [signal.SIGINT]
    assert {p.name: p.read_text() for p in out.iterdir()} == dict.fromkeys(
        ("a.csv", "b.csv", "c.csv"), "new"
    )


@pytest.mark.parametrize("existing", [False, True])
def test_a_signal_as_the_staging_folder_is_made_leaves_nothing(tmp_path, monkeypatch, existing):
    # A SIGTERM just after the staging folder was made (a test sends it as
    # soon as the folder is seen) came before the clean-up was armed: the
    # staging folder, and the --out it made, stayed.
    out = tmp_path / "new" / "out"
    if existing:
        out.mkdir(parents=True)
    mkdtemp = tempfile.mkdtemp

    def signalled_mkdtemp(*args, **kwargs):
        folder = mkdtemp(*args, **kwargs)
        os.kill(os.getpid(), signal.SIGTERM)
        return folder

    monkeypatch.setattr(tempfile, "mkdtemp", signalled_mkdtemp)
    with pytest.raises(KeyboardInterrupt) as caught:
        with _signals.interruptible(), _staging._staged(out, None) as staging:
            (staging / "a.csv").write_text("new")
    assert caught.value.args == (signal.SIGTERM,)
    assert not _signals.WRITTEN.is_set()
    if existing:
        assert list(out.iterdir()) == []
    else:
        assert not (tmp_path / "new").exists()


def test_staging_folders_of_killed_runs_are_removed_by_the_next(tmp_path, capsys):
    # A run killed outright (SIGKILL, the OOM killer) leaves its staging
    # folder; the next run into --out removes it, and only such folders.
    out = tmp_path / "out"
    out.mkdir()
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    killed = _staging._owner(child.pid)
    child.kill()
    child.wait()
    running = _staging._owner(os.getpid())  # this process: a run still going
    names = {
        f".jaxadapt-{killed}-abc123": False,
        f".jaxadapt-{os.getpid()}.1-xyz789": False,  # its id, another start: gone
        f".jaxadapt-{running}-q1w2e3": True,
        ".jaxadapt-older": True,  # not named by a process: only named in a warning
    }
    for name in names:
        (out / name).mkdir()
    status, err = _run(capsys, "render", "--scene", "flash", *SMALL, "--out", str(out))
    assert status == 0
    left = sorted(p.name for p in out.glob(".jaxadapt-*") if p.is_dir())
    assert left == sorted(name for name, kept in names.items() if kept)
    assert ".jaxadapt-older" in err and killed not in err


def test_staging_folders_left_by_killed_runs_are_named(tmp_path, capsys):
    out = tmp_path / "out"
    (out / ".jaxadapt-killed").mkdir(parents=True)
    status, err = _run(capsys, "render", "--scene", "flash", *SMALL, "--out", str(out))
    assert status == 0
    assert "warning:" in err and ".jaxadapt-killed" in err and "runs that were killed" in err


def test_a_full_device_is_said_naming_out(tmp_path, capsys, monkeypatch):
    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(io, "write_columns", full)
    out = tmp_path / "out"
    status, err = _run(capsys, "render", "--scene", "flash", *SMALL, "--out", str(out))
    _assert_one_line_error(status, err, "--out: no space left on the device of", str(out))
    assert not out.exists()


def test_a_full_device_is_said_when_the_writer_gives_no_errno(tmp_path, capsys, monkeypatch):
    # OpenImageIO and ffmpeg say "cannot write (Write error ...)", naming
    # the removed staging folder: the device's free space tells.
    def cannot_write(path, *args, **kwargs):
        raise OSError(f"{path}: cannot write (Write error at position 20477)")

    monkeypatch.setattr(io, "write_image", cannot_write)
    usage = shutil.disk_usage
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(path)._replace(free=0))
    out = tmp_path / "out"
    # (--allow-large: the writer, not the estimate up front, meets the full device)
    status, err = _run(
        capsys, "render", "--scene", "flash", *SMALL, "--allow-large", "--out", str(out)
    )
    _assert_one_line_error(status, err, "--out: no space left on the device of", str(out))


def test_an_out_that_cannot_be_written_is_said_so_on_a_device_without_space(
    tmp_path, capsys, monkeypatch
):
    # A read-only mount reports no free space: "cannot write to --out
    # (Read-only file system)" was said as a full device.
    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(tempfile, "mkdtemp", read_only)
    usage = shutil.disk_usage
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(path)._replace(free=0))
    out = tmp_path / "out"
    status, err = _run(capsys, "render", "--scene", "flash", *SMALL, "--out", str(out))
    _assert_one_line_error(status, err, f"--out: cannot write to {out} (Read-only file system)")
    assert not out.exists()


def test_a_background_scale_beyond_the_frame_is_refused_before_the_render(tmp_path, capsys):
    # 1e9 on a 1x1 frame took the machine's 24 GB; 1e5 on 64x48, 677 MB.
    out = tmp_path / "o"
    args = ["render", "--scene", "flash", "--size", "48x32", "--duration", "0.3"]
    status, err = _run(capsys, *args, "--background", "box", "--background-scale", "1000",
                       "--out", str(out))  # fmt: skip
    _assert_one_line_error(status, err, "--background-scale: expected at most 48 pixels", "1000")
    assert not out.exists()
    status, _ = _run(capsys, *args, "--background", "gaussian", "--background-scale", "48",
                     "--out", str(out))  # fmt: skip
    assert status == 0


def test_a_frame_rate_too_low_for_a_video_is_refused_before_the_render(tmp_path, capsys):
    # ffmpeg failed to write it after the whole render.
    image = tmp_path / "in.exr"
    io.write_image(image, np.ones((8, 8, 3), np.float32))
    out = tmp_path / "o"
    status, err = _run(capsys, "render", str(image), "--fps", "1e-5", "--out", str(out))
    _assert_one_line_error(status, err, "--fps", "at least 0.0001 frames/s", "got 1e-05")
    assert not out.exists()
    status, _ = _run(capsys, "render", str(image), "--fps", "1e-5", "--format", "exr",
                     "--out", str(out))  # fmt: skip
    assert status == 0


def test_frame_files_beyond_99999_are_outputs_too():
    # frame_100000.png did not match, so a later run never removed it.
    assert _staging.RENDER_OUTPUTS.fullmatch("frame_100000.png")
    assert not _staging.RENDER_OUTPUTS.fullmatch("frame_0001.png")


def test_a_render_never_writes_over_its_inputs_nor_removes_what_it_did_not_write(
    tmp_path, capsys, monkeypatch
):
    # Input frames named as the render's output frames, in --out: refused
    # before anything is written (they used to be overwritten by the display
    # frames). Renamed, they render into the same folder, and a file of the
    # user's with an output name (their own video) stays.
    monkeypatch.chdir(tmp_path)
    for k in range(3):
        io.write_image(tmp_path / f"frame_{k:05d}.exr", np.full((4, 6, 3), 10.0 + k, np.float32))
    (tmp_path / "video.mp4").write_bytes(b"the user's")
    inputs = [f"frame_{k:05d}.exr" for k in range(3)]
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    status, err = _run(capsys, "render", *inputs, "--out", ".", "--format", "exr")
    _assert_one_line_error(status, err, "frame_00000.exr", "may write over")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    renamed = [f"scene_{k}.exr" for k in range(3)]
    for old, new in zip(inputs, renamed, strict=True):
        (tmp_path / old).rename(tmp_path / new)
    assert _run(capsys, "render", *renamed, "--out", ".", "--format", "exr")[0] == 0
    assert (tmp_path / "video.mp4").read_bytes() == b"the user's"
    for name in renamed:
        assert (tmp_path / name).read_bytes() == before[inputs[renamed.index(name)]]
    # An input in --out that is a link, with an output's name: the link was
    # replaced by the display frame (its target untouched).
    (tmp_path / "frame_00000.exr").unlink()  # the last run's output
    (tmp_path / "frame_00000.exr").symlink_to(tmp_path / renamed[0])
    status, err = _run(capsys, "render", "frame_00000.exr", "--out", ".", "--format", "exr")
    _assert_one_line_error(status, err, "frame_00000.exr", "may write over")
    assert (tmp_path / "frame_00000.exr").is_symlink()


def test_overflow_after_the_multiplier_is_named(tmp_path, capsys):
    bright = tmp_path / "bright.exr"
    io.write_image(bright, np.full((4, 4, 3), 1e8, np.float32))
    args = ["render", str(bright), "--multiplier", "1e32"]
    status, err = _run(capsys, *args, "--out", str(tmp_path / "o"))
    _assert_one_line_error(status, err, "bright.exr", "multiplier")


def test_a_render_whose_cone_pigment_is_all_but_bleached_says_so(tmp_path, capsys):
    # Frames of 1e12 cd/m2 (or frames in other units, 1e28) rendered a frame
    # of the display's black without a word: the model's prediction (the
    # cones' responses scale with the unbleached pigment), which pfstmo's
    # operator shares, but one that looks like a failed render.
    for luminance, warned in ((1e8, False), (1e12, True), (1e28, True)):
        path = tmp_path / "bright.exr"
        io.write_image(path, np.full((4, 4, 3), luminance, np.float32))
        out = tmp_path / f"o{luminance:g}"
        status, err = _run(capsys, "render", str(path), "--format", "exr", "--out", str(out))
        assert status == 0, err
        said = " ".join(err.split())
        assert ("warning: at 1 of 1 frames" in said) == warned, said
        if warned:
            assert "over 99% bleached" in said and "display's black" in said
            assert "--multiplier" in said
            assert io.read_hdr(out / "frame_00000.exr").max() < 0.05  # near black, finite


def test_a_check_inside_the_operator_gives_its_own_message(tmp_path, capsys):
    args = ["render", "--scene", "title-step", *SMALL, "--multiplier", "1e38"]
    status, err = _run(capsys, *args, "--out", str(tmp_path / "o"))
    _assert_one_line_error(status, err, "scene title-step", "multiplier")
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
    status, err = _run(capsys, "render", *SMALL * builtin, *args, "--out", "o")
    _assert_one_line_error(status, err, option)


def test_fps_sets_the_frame_rate_of_a_builtin_scene(tmp_path, capsys):
    out = tmp_path / "out"
    args = ["render", "--scene", "flash", "--size", "16x16", "--duration", "0.5", "--fps", "10"]
    assert _run(capsys, *args, "--format", "exr", "--format", "mp4", "--out", str(out))[0] == 0
    rows = list(csv.DictReader(open(out / "diagnostics.csv")))
    # and the flash (0.25 to 0.375 s) begins and ends on frames of its own,
    times = [0.0, 0.1, 0.2, 0.25, 0.3, 0.375, 0.4]
    assert [float(r["t"]) for r in rows] == pytest.approx(times)
    # which the video shows at the rate asked for (the median frame, 75 ms, made it 13.3 fps).
    frames, seconds = imageio_ffmpeg.count_frames_and_secs(str(out / "video.mp4"))
    assert frames == 7 and seconds == pytest.approx(0.7, abs=0.01)


def test_gaze_and_trial_files_that_are_not_text_are_named(tmp_path, capsys):
    binary = tmp_path / "binary.csv"
    binary.write_bytes(b"\xff\xfe\x00bin")
    status, err = _run(capsys, "render", *SMALL, "--gaze", str(binary), "--out", "o")
    _assert_one_line_error(status, err, "binary.csv", "binary")
    status, err = _run(capsys, "psychometric", "fit", str(binary), "--out", str(tmp_path / "f"))
    _assert_one_line_error(status, err, "binary.csv", "binary")
    # A spreadsheet's Windows-1252 export is text, not binary data: where, and what to do.
    latin = tmp_path / "latin.csv"
    latin.write_bytes("participant,level,response\nJürgen,0.1,1\n".encode("cp1252"))
    status, err = _run(capsys, "psychometric", "fit", str(latin), "--out", str(tmp_path / "f"))
    _assert_one_line_error(status, err, "latin.csv, line 2", "another encoding", "save it as UTF-8")
    latin.write_bytes("participant,level,response\nJurgen,0.1,1\n".encode("utf-16"))
    status, err = _run(capsys, "psychometric", "fit", str(latin), "--out", str(tmp_path / "f"))
    _assert_one_line_error(status, err, "latin.csv, line 1", "UTF-16", "save it as UTF-8")
    status, err = _run(capsys, "render", str(tmp_path), "--out", str(tmp_path / "o"))
    _assert_one_line_error(status, err, str(tmp_path), "folder")


def test_help_explains_every_option(capsys):
    with pytest.raises(SystemExit):
        main(["render", "--help"])
    text = capsys.readouterr().out
    for option in ("--scene", "--fps", "--multiplier", "--adaptation-goal", "--out", "--format"):
        assert option in text


@pytest.mark.parametrize(
    "operator, background",
    [("photographic", "global"), ("ward-jnd", "adaptive"), ("pattanaik2000", "bilateral")],
)
def test_operators_and_backgrounds(tmp_path, capsys, operator, background):
    out = tmp_path / "out"
    args = ["render", "--scene", "tunnel", "--size", "32x18", "--duration", "0.2"]
    args += ["--operator", operator, "--background", background]
    args += [] if background == "global" else ["--background-scale", "2"]
    status, err = _run(capsys, *args, "--format", "exr", "--out", str(out))
    assert status == 0, err
    frame = io.read_hdr(out / "frame_00005.exr")
    assert np.all((frame >= 0) & (frame <= 1)) and frame.max() > 0.05
    rows = list(csv.DictReader(open(out / "diagnostics.csv")))
    assert len(rows) == 6
    assert ("background" in rows[0]) == (operator != "pattanaik2000")


def test_jacobs2015_follows_a_recorded_gaze(tmp_path, capsys):
    gaze = tmp_path / "gaze.csv"
    gaze.write_text("t,x,y\n0,5,4\n0.1,nan,nan\n0.15,25,12\n")
    out = tmp_path / "out"
    args = ["render", "--operator", "jacobs2015", "--scene", "checkerboard", "--size", "32x18"]
    status, err = _run(
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
    status, err = _run(capsys, *args, "--duration", "0.2", "--gaze", str(gaze), "--out", str(out))
    assert status == 0, err
    said = " ".join(err.split())
    assert f"warning: --gaze: {gaze} leaves the 32x18 frame at 3 of 6 frames" in said, said
    assert "first (640, 12) pixels at 0.1 s" in said
    rows = list(csv.DictReader(open(out / "diagnostics.csv")))
    assert [float(r["gaze_x"]) for r in rows] == [5, 5, 5, 31, 31, 31]


def test_a_blink_in_the_gaze_holds_the_fixation_for_pattanaik2000(tmp_path, capsys):
    # The foveal goal during a blink is the one at the fixation before it
    # (the recorded path holds it), not NaN and not black frames after it.
    gaze = tmp_path / "gaze.csv"
    gaze.write_text("t,x,y\n0,5,4\n0.1,nan,nan\n0.2,25,12\n")
    out = tmp_path / "out"
    args = ["render", "--scene", "tunnel", "--size", "32x18", "--duration", "0.3"]
    args += ["--adaptation-goal", "foveal", "--format", "exr", "--chunk", "4"]
    status, err = _run(capsys, *args, "--gaze", str(gaze), "--out", str(out))
    assert status == 0, err
    rows = list(csv.DictReader(open(out / "diagnostics.csv")))
    values = np.array([[float(v) for v in r.values()] for r in rows])
    assert np.all(np.isfinite(values))
    frames = [io.read_hdr(out / f"frame_{k:05d}.exr") for k in range(len(rows))]
    assert min(float(f.max()) for f in frames) > 0.05
    held = tmp_path / "held.csv"  # the same path with the fixation written out
    held.write_text("t,x,y\n0,5,4\n0.1,5,4\n0.2,25,12\n")
    status, err = _run(capsys, *args, "--gaze", str(held), "--out", str(tmp_path / "held"))
    assert status == 0, err
    for k in range(len(rows)):
        np.testing.assert_array_equal(
            frames[k], io.read_hdr(tmp_path / "held" / f"frame_{k:05d}.exr")
        )


def test_a_gaze_file_of_blinks_alone_is_warned_about(tmp_path, capsys):
    # Every sample a blink: the frame's centre was used without a word.
    gaze = tmp_path / "gaze.csv"
    gaze.write_text("t,x,y\n0,nan,nan\n")
    args = ["render", "--scene", "tunnel", "--size", "32x18", "--duration", "0.2"]
    args += ["--adaptation-goal", "foveal", "--format", "pfm"]
    status, err = _run(capsys, *args, "--gaze", str(gaze), "--out", str(tmp_path / "o"))
    assert status == 0, err
    said = " ".join(err.split())
    assert "warning: --gaze:" in said and "holds no fixation" in said, said
    gaze.write_text("t,x,y\n0,nan,nan\n0.1,5,4\n")  # one fixation: no warning
    status, err = _run(capsys, *args, "--gaze", str(gaze), "--out", str(tmp_path / "o"))
    assert status == 0 and "fixation" not in err, err


def test_bad_gaze_file_is_named(tmp_path, capsys):
    gaze = tmp_path / "gaze.csv"
    gaze.write_text("t,x,y\n0,5\n")
    status, err = _run(
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
    _assert_one_line_error(status, err, "gaze.csv")


def _simulated_rows(participants, shifts, levels, sigma, seed):
    """Count rows ``p,condition,level,n_yes,20`` of simulated observers: for
    each participant and ``(condition, shift)``, 20 trials a level of a
    cumulative Gaussian of that PSE and ``sigma``."""
    rng = np.random.default_rng(seed)
    rows = []
    for p in participants:
        for condition, shift in shifts:
            k = rng.binomial(20, norm_cdf((levels - shift) / sigma))
            rows += [f"p{p},{condition},{x:.4f},{y},20" for x, y in zip(levels, k, strict=True)]
    return rows


def test_psychometric_fit_writes_fits_group_test_and_figures(tmp_path, capsys):
    levels = np.log10(np.array([14, 19, 27, 35, 49]) / 27)  # the afterimage protocol
    rows = ["participant,condition,level,n_yes,n_total"]
    rows += _simulated_rows(range(6), (("control", 0.0), ("manipulated", 0.15)), levels, 0.1, 0)
    out = tmp_path / "out"
    status, err = _fit_rows(capsys, rows, out, "--resamples", "0")
    assert status == 0, err
    trials = out / "trials.csv"
    fits = list(csv.DictReader(open(out / "fits.csv")))
    assert len(fits) == 12
    # p1's and p5's control answers change at one level (quasi-complete
    # separation): the data do not fix their slopes
    undetermined = [f["participant"] + f["condition"] for f in fits if f["converged"] != "true"]
    assert undetermined == ["p1control", "p5control"]
    (test,) = list(csv.DictReader(open(out / "group_test.csv")))
    assert float(test["shift"]) == pytest.approx(0.15, abs=0.06) and float(test["p"]) < 0.01
    pses = {
        c: [float(f["pse"]) for f in fits if f["condition"] == c and f["pse"] != "nan"]
        for c in ("manipulated", "control")
    }
    assert (test["n"], test["n_control"]) == ("6", "4")  # without p1's and p5's
    # Groups of 6 and 4: "auto" is exact (SciPy's rule); --ranksum asymptotic
    # asks for the normal approximation. Both as SciPy gives them.
    for method, exact in (("auto", "true"), ("asymptotic", "false")):
        if method != "auto":
            status, err = _fit_rows(capsys, rows, out, "--resamples", "0", "--ranksum", method)
            assert status == 0, err
            (test,) = list(csv.DictReader(open(out / "group_test.csv")))
        scipy_method = "exact" if exact == "true" else "asymptotic"
        expected = mannwhitneyu(pses["manipulated"], pses["control"], method=scipy_method).pvalue
        assert test["p_exact"] == exact and float(test["p"]) == pytest.approx(expected, rel=1e-5)
    assert (out / "psychometric.png").stat().st_size > 0 and (out / "pse.png").exists()
    status, err = _run(capsys, "psychometric", "fit", str(trials), "--control", "Control")
    _assert_one_line_error(status, err, "--control", "control, manipulated", "'Control'")
    # Without a control condition and no --control: fits, and no comparison.
    trials.write_text(trials.read_text().replace(",control,", ",dark,"))
    status, err = _run(
        capsys, "psychometric", "fit", str(trials), "--resamples", "0", "--out", str(out)
    )
    assert status == 0, err
    assert not (out / "group_test.csv").exists()  # the last run's, removed
    said = " ".join(err.split())  # the console wraps its lines
    assert "no group test" in said and "dark, manipulated" in said and "--control" in said
    # With one condition no --control can help (it was suggested).
    one = tmp_path / "one.csv"
    one.write_text("".join(r for r in trials.open() if ",manipulated," not in r))
    status, err = _run(
        capsys, "psychometric", "fit", str(one), "--resamples", "0", "--out", str(out)
    )
    assert status == 0, err
    said = " ".join(err.split())
    assert "has one condition, 'dark'; a group test compares two" in said, said
    assert "--control" not in said
    # A participant whose responses are all "yes", and one whose are half
    # "yes" at every level (no slope), have no PSE of their own: said.
    rows = trials.read_text().splitlines()
    for first, n_yes in (("p0,dark,", "20"), ("p1,dark,", "10")):
        rows = [
            r if not r.startswith(first) else ",".join(r.split(",")[:3] + [n_yes, "20"])
            for r in rows
        ]
    trials.write_text("\n".join(rows) + "\n")
    status, err = _run(
        capsys, "psychometric", "fit", str(trials), "--resamples", "0", "--out", str(out)
    )
    assert status == 0, err
    said = " ".join(err.split())
    assert "p0, condition dark: the data place the PSE only below -0.285 log units (all_" in said
    assert "warning: participant p1, condition dark: the data place no PSE (flat)" in said
    # p5's responses change at one level (quasi-complete separation): said too.
    assert "p5, condition dark: the responses change at one level" in said
    assert said.count("warning") == 3, said
    assert "its PSE and slope in fits.csv are NaN" in said


def test_many_undetermined_groups_are_counted_not_listed(tmp_path, capsys):
    # 10,000 groups of simulated data wrote a warning line for each that
    # the data did not determine: thousands of lines.
    rows = ["participant,condition,level,n_yes,n_total"]
    rows += [f"p{i},control,{x},{k},10" for i in range(12) for x, k in ((0.0, 10), (0.1, 10))]
    status, err = _fit_rows(capsys, rows, tmp_path / "o", "--resamples", "0")
    assert status == 0, err
    lines = err.splitlines()
    assert any(line.startswith("warning: the data of 12 groups do not determine") for line in lines)
    assert sum(line.startswith("warning: participant") for line in lines) == 10


def test_results_on_stdout_warnings_on_stderr_csvs_with_lf(tmp_path, capsys):
    # Every summary went to stderr with the warnings; the console wrapped
    # lines at 80 columns, inside numbers ("p = \\n0.371"); CSVs had CRLF ends.
    levels = np.linspace(-0.3, 0.3, 5)
    rows = ["participant,condition,level,n_yes,n_total", "p0,control,0.0,10,10"]
    rows += _simulated_rows(range(1, 5), (("control", 0.0), ("bright", 0.1)), levels, 0.1, 3)
    folder = tmp_path / "a-folder-with-a-long-name-that-pushes-the-summary-past-eighty-columns"
    folder.mkdir()
    (folder / "trials.csv").write_text("\n".join(rows) + "\n")
    argv = ["psychometric", "fit", str(folder / "trials.csv"), "--resamples", "0"]
    status = main([*argv, "--out", str(folder)])
    said = capsys.readouterr()
    assert status == 0
    lines = said.out.splitlines()
    assert lines[0].startswith("bright vs control: median PSE") and "rank-sum p = " in lines[0]
    assert lines[1].startswith("wrote fits.csv") and str(folder) in lines[1]
    assert len(lines) == 2 and len(lines[1]) > 80  # not wrapped
    assert said.err.startswith("warning: participant p0, condition control")
    assert len(said.err.splitlines()) == 2  # the warning and the note, one line each
    for name in ("fits.csv", "group_test.csv"):
        assert b"\r" not in (folder / name).read_bytes(), name


def test_psychometric_fit_names_the_bad_row(tmp_path, capsys):
    trials = tmp_path / "trials.csv"
    trials.write_text("participant,condition,level,response\np1,control,0.1,1\np1,control,x,0\n")
    status, err = _run(capsys, "psychometric", "fit", str(trials), "--out", str(tmp_path / "o"))
    _assert_one_line_error(status, err, "trials.csv", "3")
    assert not (tmp_path / "o").exists()
    trials.write_text("level,level,n_yes,n_total\n0,0,1,1\n")
    status, err = _run(capsys, "psychometric", "fit", str(trials), "--out", str(tmp_path / "o"))
    _assert_one_line_error(status, err, "trials.csv", "'level' more than once")
    status, err = _run(capsys, "psychometric", "fit", str(tmp_path), "--out", str(tmp_path / "o"))
    _assert_one_line_error(status, err, "is a folder")
    assert not (tmp_path / "o").exists()
    trials.write_text("level,n_yes,n_total\n0,1,2\n0.1,2,2\n")
    for resamples in ("-1", "1"):
        args = ("psychometric", "fit", str(trials), "--resamples", resamples)
        status, err = _run(capsys, *args, "--out", str(tmp_path / "o"))
        _assert_one_line_error(status, err, "--resamples: expected 0", f"got {resamples}")
    assert not (tmp_path / "o").exists()


def test_psychometric_fit_refuses_its_options_before_fitting(tmp_path, capsys, monkeypatch):
    # --out a file, and --ranksum exact on groups too large for its table,
    # were found after the whole fit (28 s on a simulated experiment);
    # --seed without a bootstrap, and --ranksum without a group test, were
    # ignored. Now each is refused before any fit.
    from jaxadapt.psychophysics import fit_table

    def no_fit(*args, **kwargs):
        raise AssertionError("fitted before refusing")

    monkeypatch.setattr(fit_table, "fit_groups", no_fit)
    rows = ["participant,condition,level,n_yes,n_total"]
    rows += [f"p{i},{c},{x},1,2" for i in range(170) for c in ("control", "m") for x in (0, 1)]
    table = tmp_path / "trials.csv"
    table.write_text("\n".join(rows) + "\n")
    (tmp_path / "file").touch()
    for options, expected in (
        (["--out", str(tmp_path / "file")], ("--out: expected a folder",)),
        (["--resamples", "0", "--seed", "7"], ("--seed:", "--resamples 0")),
        (["--ranksum", "exact"], ("--ranksum exact:", "4942071", "use --ranksum asymptotic")),
        (["--control", "m", "--ranksum", "auto"], ("--ranksum: applies to the group test",)),
    ):
        if "--control" in options:  # a table with the control condition alone
            table.write_text("\n".join(r for r in rows if ",control," not in r) + "\n")
        status, err = _run(capsys, "psychometric", "fit", str(table), *options)
        _assert_one_line_error(status, err, *expected)


def test_out_of_memory_names_what_to_make_smaller(tmp_path, capsys, monkeypatch):
    # It said "try a smaller --chunk or --size" to psychometric fit too.
    from jaxadapt.psychophysics import fit_table

    def exhausted(*args, **kwargs):
        raise jax.errors.JaxRuntimeError("RESOURCE_EXHAUSTED: Out of memory allocating 9 bytes.")

    monkeypatch.setattr(fit_table, "fit_groups", exhausted)
    table = tmp_path / "trials.csv"
    table.write_text("condition,level,n_yes,n_total\ncontrol,0,1,2\ncontrol,1,2,2\nm,0,1,2\n")
    status, err = _run(capsys, "psychometric", "fit", str(table), "--out", str(tmp_path / "o"))
    _assert_one_line_error(status, err, "out of memory", "try fewer --resamples")
    assert not (tmp_path / "o").exists()


def test_a_memory_error_is_one_line_too(tmp_path, capsys, monkeypatch):
    # NumPy's MemoryError (a filter's index arrays) printed a traceback.
    def exhausted(*args, **kwargs):
        raise MemoryError("Unable to allocate 2.02 GiB")

    monkeypatch.setattr(pipeline, "chunks", exhausted)
    out = tmp_path / "o"
    status, err = _run(capsys, "render", "--scene", "flash", *SMALL, "--out", str(out))
    _assert_one_line_error(status, err, "out of memory", "--chunk, --size or --background-scale")
    assert not out.exists()


def test_separated_responses_get_an_interval_of_their_gap(tmp_path, capsys):
    # "no" up to 0, "yes" from 0.15: any PSE between fits. The bootstrap of
    # the prior's near-step curve gave (0.055, 0.094) and no warning; data
    # without a PSE gave an interval of zero width at the prior's PSE.
    rows = ["participant,condition,level,n_yes,n_total"]
    for x, k in zip((-0.3, -0.15, 0.0, 0.15, 0.3), (0, 0, 0, 30, 30), strict=True):
        rows += [f"p1,control,{x},{k},30", f"p2,control,{x},30,30"]
    out = tmp_path / "o"
    status, err = _fit_rows(capsys, rows, out, "--resamples", "50")
    assert status == 0, err
    separated, unplaced = list(csv.DictReader(open(out / "fits.csv")))
    assert float(separated["ci_low"]) <= 0.0 and float(separated["ci_high"]) >= 0.15
    assert (unplaced["ci_low"], unplaced["ci_high"]) == ("-inf", "inf")
    said = " ".join(err.split())
    assert "p1, condition control: the levels separate" in said and "+0 and +0.15" in said


def test_undetermined_fits_are_nan_and_left_out_of_the_group_test(tmp_path, capsys):
    # p0's control answers are all "yes" at one level: written as pse
    # -503161, sigma 141421, b1 0, converged true. p1's control is
    # separated (0 to 5 to 10 of 10 "yes"): sigma 0.0307, converged true,
    # where the likelihood grows without end as sigma goes to 0. Both
    # entered the group test. Now: NaN, not converged, what the data
    # determine in columns of their own, and left out of the test unless
    # --keep-undetermined.
    levels = np.linspace(-0.4, 0.4, 9)
    rows = ["participant,condition,level,n_yes,n_total", "p0,control,-0.2,10,10"]
    for x, k in zip(levels, (0, 0, 0, 0, 0, 0, 5, 10, 10), strict=True):
        rows.append(f"p1,control,{x:.2f},{k},10")
    rows += _simulated_rows(range(2, 7), (("control", 0.0), ("bright", 0.1)), levels, 0.2, 2)
    out = tmp_path / "o"
    status, err = _fit_rows(capsys, rows, out, "--resamples", "0")
    assert status == 0, err
    fits = {f["participant"] + f["condition"]: f for f in csv.DictReader(open(out / "fits.csv"))}
    same, separated = fits["p0control"], fits["p1control"]
    for row in (same, separated):
        assert [row[c] for c in ("pse", "sigma", "b0", "b1", "se_pse")] == ["nan"] * 5, row
        assert row["converged"] == "false"
    assert "all_same" in same["flags"] and "separation" in separated["flags"]
    assert (same["pse_low"], same["pse_high"]) == ("-inf", "inf")  # one level: no side
    assert float(separated["pse_low"]) == float(separated["pse_high"]) == 0.2
    assert 0.01 < float(separated["sigma_max"]) < 0.2
    determined = fits["p2control"]
    assert determined["converged"] == "true" and determined["pse_low"] == "nan"
    (test,) = list(csv.DictReader(open(out / "group_test.csv")))
    assert (test["n"], test["n_control"]) == ("5", "5")
    said = " ".join(err.split())
    assert "the group test leaves out the 2 groups whose data place no PSE" in said
    status, err = _fit_rows(capsys, rows, out, "--resamples", "0", "--keep-undetermined")
    assert status == 0, err
    fits = {f["participant"] + f["condition"]: f for f in csv.DictReader(open(out / "fits.csv"))}
    assert (
        np.isfinite(float(fits["p0control"]["pse"])) and fits["p0control"]["converged"] == "false"
    )
    (test,) = list(csv.DictReader(open(out / "group_test.csv")))
    assert (test["n"], test["n_control"]) == ("5", "7")
    assert "leaves out" not in err


def _fit_in_float32(capsys, rows, folder):
    """:func:`_fit_rows` with ``--resamples 0`` and float64 off, as for a
    user (the tests switch it on)."""
    with jax.enable_x64(False):
        status, err = _fit_rows(capsys, rows, folder, "--resamples", "0")
    assert status == 0, err


def test_psychometric_fit_is_float64_as_statsmodels(tmp_path, capsys):
    # 3,000 trials a level: in float32 (the command's precision before, as
    # JAX's default) the log-likelihood was 0.01 off statsmodels' (binomial
    # terms of 2e4 that cancel), and an all-"no" PSE could fall below the
    # levels. (The tests run with float64 on: here it is off, as for a user.)
    levels, n = np.linspace(-0.3, 0.3, 5), 3000
    k = np.array([300, 900, 1500, 2100, 2700])
    rows = ["level,n_yes,n_total"] + [f"{x},{y},{n}" for x, y in zip(levels, k, strict=True)]
    _fit_in_float32(capsys, rows, tmp_path)
    (row,) = list(csv.DictReader(open(tmp_path / "fits.csv")))
    glm = sm.GLM(
        np.c_[k, n - k],
        sm.add_constant(levels),
        family=sm.families.Binomial(link=sm.families.links.Probit()),
    ).fit(tol=1e-14)
    assert float(row["loglik"]) == pytest.approx(glm.llf, abs=1e-7)
    assert float(row["b1"]) == pytest.approx(glm.params[1], rel=1e-8)


def test_psychometric_group_test_p_is_float64(tmp_path, capsys):
    # 170 participants whose PSEs separate the conditions completely: z =
    # 15.9, p = 7.6e-57 (SciPy's mannwhitneyu), which the group test, run in
    # float32 after the float64 fits, wrote as 0.
    from scipy.stats import mannwhitneyu

    levels, n = np.linspace(-0.3, 0.3, 5), 40
    rows = ["participant,condition,level,n_yes,n_total"]
    for i in range(170):
        for condition, pse in (("control", -0.1), ("test", 0.1)):
            p = norm_cdf((levels - pse - 0.001 * i) / 0.1)
            rows += [
                f"p{i},{condition},{x},{round(n * q)},{n}" for x, q in zip(levels, p, strict=True)
            ]
    _fit_in_float32(capsys, rows, tmp_path)
    fits = list(csv.DictReader(open(tmp_path / "fits.csv")))
    pse = {c: [float(r["pse"]) for r in fits if r["condition"] == c] for c in ("control", "test")}
    (row,) = list(csv.DictReader(open(tmp_path / "group_test.csv")))
    expected = mannwhitneyu(pse["test"], pse["control"], method="asymptotic", use_continuity=False)
    assert float(row["p"]) == pytest.approx(expected.pvalue, rel=1e-6)
    assert 0 < float(row["p"]) < 1e-50
    # Fig. 13 draws the first 24 participants (6 rows): 170 panels took a
    # minute to lay out, for a figure 11,200 pixels high.
    assert matplotlib.image.imread(tmp_path / "psychometric.png").shape[0] < 2000


def test_pse_figure_spans_the_placed_pses(tmp_path):
    # An all-"yes" participant's PSE, set by the prior at -7.3e5, made the
    # axis run to -7e5 and flattened every other PSE onto 0.
    from jaxadapt import figures
    from jaxadapt.psychophysics import psychometric
    from jaxadapt.psychophysics.fit_table import FitTable

    pse = np.array([-7.3e5, 0.02, -0.05, 0.12, 0.08, 0.1])
    flags = np.array([psychometric.ALL_SAME, 0, 0, 0, 0, 0])
    table = FitTable(
        tuple(f"p{i}" for i in range(3)) * 2,
        ("control",) * 3 + ("test",) * 3,
        pse,
        *[np.zeros(6)] * 10,
        np.ones(6, bool),
        flags,
    )
    low, high = figures.plot_pse(tmp_path / "pse.png", table).axes[0].get_ylim()
    assert -0.11 < low < -0.05 and 0.12 < high < 0.2
    assert (tmp_path / "pse.png").stat().st_size > 0


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
    assert _run(capsys, *args, "--out", str(tmp_path / "o"))[0] == 0
    (labels,) = sheets
    times = [float(label.removesuffix(" s")) for label in labels]
    assert len(times) == 12 and times[0] == 0 and times[-1] == pytest.approx(19.8)
    assert sum(t < 1 for t in times) <= 2, times
    assert any(12 < t < 15 for t in times), times  # the tunnel's exit


def test_the_2015_diagnostics_plot_has_units_and_says_why_a_is_flat(tmp_path):
    # A and A_T sat at the 100 cd/m2 floor and rho ran to 2.7 with nothing
    # on the plot saying why; its y axes had no units.
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


def test_figures_draw_any_condition_name_without_warnings(tmp_path, capsys):
    # Unicode names fitted right but printed 26 lines of matplotlib's
    # "Glyph ... missing" and drew empty boxes. A character no installed
    # font has is written as its code point (U+1F9A9 here, on most machines).
    import warnings

    from jaxadapt import figures

    dark, other = "暗い条件 ☾", "contrôle \U0001f9a9"
    levels = np.linspace(-0.3, 0.3, 5)
    rows = ["participant,condition,level,n_yes,n_total"]
    rows += _simulated_rows(range(4), ((other, 0.0), (dark, 0.1)), levels, 0.15, 4)
    folder = tmp_path / "o"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        status, err = _fit_rows(capsys, rows, folder, "--resamples", "0", "--control", other)
    assert status == 0, err
    assert [str(w.message) for w in caught if "Glyph" in str(w.message)] == []
    assert "Glyph" not in err
    families, missing = figures._fonts_for([dark, other])
    with figures._drawing([dark, other]) as drawable:
        assert drawable(dark + other) == "".join(
            f"U+{ord(c):04X}" if ord(c) in missing else c for c in dark + other
        )
    assert families[0] == "DejaVu Sans" and not any("Last Resort" in f for f in families)


def norm_cdf(z):
    from scipy.special import ndtr

    return ndtr(z)


def test_psychometric_simulate_checks_out_before_simulating(tmp_path, capsys, monkeypatch):
    # An --out that is a file was refused after 11 s of simulating.
    from jaxadapt.psychophysics import observer

    def simulated(*args, **kwargs):
        pytest.fail("simulated before --out was checked")

    monkeypatch.setattr(observer, "render_stimuli", simulated)
    target = tmp_path / "a-file"
    target.write_text("kept")
    args = ["psychometric", "simulate", "--protocol", "afterimage", "--observers", "2"]
    status, err = _run(capsys, *args, "--out", str(target))
    _assert_one_line_error(status, err, "--out", "a-file")
    assert target.read_text() == "kept"


def test_psychometric_simulate_writes_a_table_that_fit_reads(tmp_path, capsys):
    sim, out = tmp_path / "sim", tmp_path / "fit"
    args = ["psychometric", "simulate", "--protocol", "afterimage", "--observers", "6"]
    status, err = _run(
        capsys, *args, "--weight", "afterimage=0.3", "--seed", "1", "--out", str(sim)
    )
    assert status == 0, err
    for name in ("trials.csv", "observers.csv", "stimuli.csv"):
        assert b"\r" not in (sim / name).read_bytes(), name  # LF line ends
    observers = list(csv.DictReader(open(sim / "observers.csv")))
    assert len(observers) == 6 and all(float(o["weight_afterimage"]) == 0.3 for o in observers)
    included = [o["participant"] for o in observers if o["excluded"] == "false"]
    # a strong afterimage with a positive weight: the observer's own PSE moves left
    assert all(float(o["pse_manipulated"]) < float(o["pse_control"]) for o in observers)
    stimuli = list(csv.DictReader(open(sim / "stimuli.csv")))
    assert len(stimuli) == 10 and {s["condition"] for s in stimuli} == {"control", "manipulated"}
    status, err = _run(
        capsys,
        "psychometric",
        "fit",
        str(sim / "trials.csv"),
        "--resamples",
        "0",
        "--out",
        str(out),
    )
    assert status == 0, err
    fits = list(csv.DictReader(open(out / "fits.csv")))
    assert [f["participant"] for f in fits] == [p for p in included for _ in range(2)]
    assert all(f["converged"] == "true" for f in fits)
    assert not [p for p in sim.iterdir() if p.name.startswith(".")]  # no staging left


def test_psychometric_simulate_streams_observers_in_blocks(tmp_path, capsys, monkeypatch):
    # The observers go in blocks, each written before the next is
    # simulated (memory flat in their number), and the files are the same.
    from jaxadapt.psychophysics import experiment

    args = ["psychometric", "simulate", "--protocol", "afterimage", "--observers", "5"]
    assert _run(capsys, *args, "--out", str(tmp_path / "whole"))[0] == 0
    blocks, simulate_in_chunks = [], experiment.simulate_in_chunks

    def counted(*args, **kwargs):
        for first, block in simulate_in_chunks(*args, **kwargs):
            blocks.append(first)
            yield first, block

    monkeypatch.setattr(experiment, "CHUNK", 2)
    monkeypatch.setattr(experiment, "simulate_in_chunks", counted)
    assert _run(capsys, *args, "--out", str(tmp_path / "blocks"))[0] == 0
    assert blocks == [0, 2, 4]
    for name in ("trials.csv", "observers.csv", "stimuli.csv"):
        whole, parts = (tmp_path / d / name for d in ("whole", "blocks"))
        assert parts.read_bytes() == whole.read_bytes(), name


@pytest.mark.parametrize(
    "args, words",
    [
        (["--protocol", "glare", "--observers", "3"], ["--protocol", "glare", "afterimage"]),
        (["--protocol", "mesopic", "--observers", "0"], ["--observers", "0"]),
        (["--protocol", "mesopic", "--observers", "3", "--weight", "glow=1"], ["--weight"]),
        (["--protocol", "mesopic", "--observers", "3", "--weight", "blur=x"], ["--weight"]),
        (
            [
                "--protocol",
                "mesopic",
                "--observers",
                "3",
                "--weight",
                "blur=1",
                "--weight",
                "blur=2",
            ],
            ["--weight", "blur again"],
        ),
    ],
)
def test_psychometric_simulate_bad_input(tmp_path, capsys, args, words):
    out = tmp_path / "o"
    status, err = _run(capsys, "psychometric", "simulate", *args, "--out", str(out))
    _assert_one_line_error(status, err, *words)
    assert not out.exists()


@pytest.mark.parametrize(
    "signum, command",
    [
        (signal.SIGINT, ["render", "--scene", "tunnel", "--size", "320x180"]),
        (signal.SIGTERM, ["render", "--scene", "tunnel", "--size", "320x180"]),
        (signal.SIGHUP, ["render", "--scene", "tunnel", "--size", "320x180"]),
        (signal.SIGTERM, ["psychometric", "fit", "TRIALS", "--resamples", "3000"]),
    ],
)
def test_an_interrupted_run_leaves_nothing_and_says_so(tmp_path, signum, command):
    # Ctrl-C (SIGINT), a scheduler's SIGTERM and a closed terminal's SIGHUP
    # (which left the staging folder behind), sent once the run has made
    # its staging folder: one line, the shell's status 128 + signal, and
    # neither the staging folder nor the --out it made remain. A fit makes
    # its staging folder before fitting (it checked --out after the fit);
    # killed here it is still compiling. (Killed 8 to 16 s in, in its
    # bootstrap, 3 of 8 runs crashed as Python finalised under XLA's running
    # threads, status 134 or 139, before cli.run: not reproduced in a test.)
    trials = tmp_path / "trials.csv"
    rows = [
        f"p{p},{c},{x},{k},20"
        for p in range(11)
        for c in ("control", "m")
        for x, k in ((-0.2, 3), (0.0, 10), (0.2, 17))
    ]
    trials.write_text("participant,condition,level,n_yes,n_total\n" + "\n".join(rows) + "\n")
    out = tmp_path / "new" / "out"
    command = [str(trials) if c == "TRIALS" else c for c in command]
    process = _start(*command, "--out", str(out))
    deadline = time.monotonic() + 120
    while not (out.exists() and any(out.iterdir())) and process.poll() is None:
        assert time.monotonic() < deadline, "the run made no staging folder in 120 s"
        time.sleep(0.05)
    process.send_signal(signum)
    err = process.communicate(timeout=120)[1]
    assert process.returncode == 128 + signum, err
    assert err.strip().splitlines()[-1] == "jaxadapt: interrupted; nothing was written to --out"
    assert "Traceback" not in err
    assert not (tmp_path / "new").exists()


def test_ctrl_c_mid_stream_joins_the_threads_and_leaves_nothing(tmp_path):
    # Sent once frames are being written behind while later chunks are
    # read ahead and computed: the interrupt reaches the main thread, the
    # reader and writer threads stop and are joined, the staging folder
    # with its frames goes, and the process ends with the shell's status.
    out = tmp_path / "new" / "out"
    args = ["render", "--scene", "tunnel", "--size", "320x180", "--format", "pfm", "--chunk", "4"]
    process = _start(*args, "--out", str(out))
    deadline = time.monotonic() + 120
    while len(list(out.glob("*/frame_*.pfm"))) < 8 and process.poll() is None:
        assert time.monotonic() < deadline, "the run wrote no 8 frames in 120 s"
        time.sleep(0.02)
    process.send_signal(signal.SIGINT)
    err = process.communicate(timeout=120)[1]
    assert process.returncode == 128 + signal.SIGINT, err
    assert err.strip().splitlines()[-1] == "jaxadapt: interrupted; nothing was written to --out"
    assert "Traceback" not in err
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize("delay", [0.5, 1.2])
def test_ctrl_c_during_start_up_is_one_line(tmp_path, delay):
    # Sent while the program imports JAX and parses its arguments, before
    # any command runs: a 30-line traceback, where the line and the status
    # of an interrupted run are due.
    out = tmp_path / "o"
    process = _start("render", "--scene", "flash", *SMALL, "--out", str(out))
    time.sleep(delay)
    process.send_signal(signal.SIGINT)
    err = process.communicate(timeout=120)[1]
    assert process.returncode == 128 + signal.SIGINT, err
    assert err.splitlines() == ["jaxadapt: interrupted; nothing was written to --out"]
    assert not out.exists()


def test_an_interrupt_wrapped_by_python_is_still_an_interrupt(monkeypatch, capsys):
    # A signal while matplotlib imports lands inside a class's __set_name__,
    # which Python 3.11 re-raises as a RuntimeError: it printed a traceback
    # and status 1 where the one line and 130 were due.
    from jaxadapt.cli import _main

    class Interrupted:
        def __set_name__(self, owner, name):
            raise KeyboardInterrupt(signal.SIGINT)

    def command(argv):
        type("Formatter", (), {"locs": Interrupted()})

    monkeypatch.setattr(_main, "_command", command)
    assert _main.main([]) == 128 + signal.SIGINT
    assert capsys.readouterr().err.splitlines() == [
        "jaxadapt: interrupted; nothing was written to --out"
    ]

    def crash(argv):
        raise RuntimeError("not an interrupt")

    monkeypatch.setattr(_main, "_command", crash)
    with pytest.raises(RuntimeError, match="not an interrupt"):
        _main.main([])


def test_a_signal_after_the_command_leaves_its_status(tmp_path):
    # A signal as the program exits (here: as its command returns) reached
    # Python's exit handlers: 'Exception ignored in atexit callback' and a
    # traceback, or status 130 after a run that had written everything.
    code = (
        "import os, signal; from jaxadapt.cli import _main as cli\n"
        "def main():\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    os.kill(os.getpid(), signal.SIGTERM)\n"
        "    return 0\n"
        "cli.main = main\n"
        "cli.run()\n"
    )
    process = processes.python(
        ["-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    stderr = process.communicate(timeout=120)[1]
    assert (process.returncode, stderr) == (0, "")


def test_a_signal_after_the_outputs_are_in_place_is_a_success(tmp_path, capsys, monkeypatch):
    # The outputs all moved into --out, then a SIGTERM: exit status 0 and
    # the run's own summary (it said "interrupted" with status 143).
    move = _staging._move_into_place

    def move_then_signal(*args):
        move(*args)
        os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(_staging, "_move_into_place", move_then_signal)
    out = tmp_path / "o"
    status = main(["render", "--scene", "flash", *SMALL, "--format", "pfm", "--out", str(out)])
    said = capsys.readouterr()
    assert status == 0, said.err
    assert said.out.startswith("wrote") and "interrupted" not in said.err
    assert (out / "diagnostics.csv").is_file()


def test_a_signal_ignored_by_nohup_stays_ignored(tmp_path):
    # Handled as an interrupt, SIGHUP ended a `nohup jaxadapt render` when
    # its terminal closed.
    out = tmp_path / "o"
    process = _start(
        "render", "--scene", "flash", *SMALL, "--out", str(out), ignored=[signal.SIGHUP]
    )
    deadline = time.monotonic() + 120
    while not (out.exists() and any(out.iterdir())) and process.poll() is None:
        assert time.monotonic() < deadline, "the run made no staging folder in 120 s"
        time.sleep(0.05)
    process.send_signal(signal.SIGHUP)
    err = process.communicate(timeout=120)[1]
    assert process.returncode == 0, err
    assert (out / "video.mp4").is_file()


@pytest.mark.parametrize(
    "argv, message",
    [
        # a 20 s tunnel at 1e-5 frames/s has no frame: it named --duration, not given
        (["--fps", "1e-5"], "--fps: expected from 1 to 1e+08 frames"),
        (["--scene", "flash", "--duration", "0.2"], "--duration: expected more"),
        (["--duration", "1e308", "--fps", "10"], "--duration, --fps: expected"),  # OverflowError
    ],
)
def test_a_scenes_error_names_the_options_given(tmp_path, capsys, argv, message):
    status, err = _run(capsys, "render", *argv, "--out", str(tmp_path / "o"))
    _assert_one_line_error(status, err, message)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "argv, option",
    [
        (["render", "--seed", "99999999999999999999999"], "--seed"),  # was an OverflowError
        (["psychometric", "simulate", "--observers", "2", "--seed", "-1"], "--seed"),
        (["render", "--multiplier", "0"], "--multiplier"),
        (["render", "--format", "gif"], "--format"),
        # A rate whose video rounded to 0 frames/s (after the whole render)
        # or whose frame time left float32 (black frames, or "dt").
        (["render", "--fps", "1e-7"], "from 1e-05 to 1e+06"),
        (["render", "--fps", "1e300"], "from 1e-05 to 1e+06"),
        (["render", "--fps", "24000/0"], "(30, 29.97, 24000/1001)"),
        (["render", "--fps", "24000/-1001"], "(30, 29.97, 24000/1001)"),
    ],
)
def test_argument_errors_are_one_line(capsys, argv, option):
    with pytest.raises(SystemExit) as exit:
        main(argv)
    _assert_one_line_error(exit.value.code, capsys.readouterr().err, option, "--help")


@pytest.mark.parametrize(
    "argv, command",
    [
        (["render", "--sise"], "jaxadapt render"),
        (["psychometric", "fit", "t.csv", "--sise"], "jaxadapt psychometric fit"),
        (
            ["psychometric", "simulate", "--protocol", "mesopic", "--observers", "2", "extra"],
            "jaxadapt psychometric simulate",
        ),
        # Before the command: the help of what it was given to.
        (["--sise", "render"], "jaxadapt"),
        (["psychometric", "--sise", "fit", "t.csv"], "jaxadapt psychometric"),
    ],
)
def test_an_unknown_argument_points_to_its_commands_help(capsys, argv, command):
    # It pointed to `jaxadapt --help`, which lists only the commands.
    with pytest.raises(SystemExit) as exit:
        main(argv)
    err = capsys.readouterr().err
    stray = next(a for a in argv if a in ("--sise", "extra"))
    _assert_one_line_error(exit.value.code, err, "unrecognized arguments", stray)
    assert err.strip().endswith(f"(see {command} --help)"), err


def test_version_is_the_installed_packages(capsys):
    with pytest.raises(SystemExit) as exit:
        main(["--version"])
    assert exit.value.code == 0
    assert capsys.readouterr().out == f"jaxadapt {importlib.metadata.version('jaxadapt')}\n"


def test_curves_are_drawn_where_adaptation_changes():
    from jaxadapt import figures

    # The title-page step: A jumps within 0.3 s of a 4 s sequence; frames
    # evenly spaced in time drew none of the transient (0, 0.57, 1.14 s ...).
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
    # Floats in [0, 1] were drawn black, a 3-axis stack failed to unpack,
    # and no frame or no column failed with an IndexError or a division by 0.
    from jaxadapt import figures

    with pytest.raises(ValueError, match=message):
        getattr(figures, name)(*args)


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
    status, err = _run(capsys, "render", *paths, "--format", "exr", "--out", str(out))
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


def test_files_play_at_the_rate_their_header_gives(tmp_path, capsys):
    # A 23.976 fps EXR sequence was simulated at 30 fps: the adaptation ran
    # 25 % fast. The first file's FramesPerSecond is now the default.
    paths = [str(tmp_path / f"f{k}.exr") for k in range(3)]
    for p in paths:
        io.write_image(p, np.full((4, 6, 3), 50.0, np.float32), fps=24000 / 1001)
    for options, dt in (((), 1001 / 24000), (("--fps", "10"), 0.1)):
        out = tmp_path / f"out{len(options)}"
        status, err = _run(capsys, "render", *paths, *options, "--format", "exr", "--out", str(out))
        assert status == 0, err
        t = [float(row["t"]) for row in csv.DictReader(open(out / "diagnostics.csv"))]
        np.testing.assert_allclose(np.diff(t), dt, rtol=1e-5)  # t written to 6 digits
        assert io.frame_rate(out / "frame_00002.exr") == pytest.approx(1 / dt, rel=1e-12)
    bad = tmp_path / "bad.exr"
    _exr_at_rate(bad, (30, 0))
    status, err = _run(capsys, "render", str(bad), "--out", str(tmp_path / "o"))
    _assert_one_line_error(status, err, "bad.exr", "FramesPerSecond, got 30/0")
    _exr_at_rate(bad, (1, 1_000_000))
    status, err = _run(capsys, "render", str(bad), "--out", str(tmp_path / "o"))
    _assert_one_line_error(status, err, "bad.exr", "FramesPerSecond, 1e-06, is outside", "--fps")


def test_size_help_gives_each_scenes_default_size(capsys):
    # It gave the default sizes of two scenes of six.
    from jaxadapt.scenes import SCENES

    with pytest.raises(SystemExit):
        main(["render", "--help"])
    said = " ".join(capsys.readouterr().out.split())
    for name, scene in SCENES.items():
        frame = pipeline.from_scene(scene()).frames(np.arange(1))[0]
        assert f"{frame.shape[1]}x{frame.shape[0]} {name}" in said, name


def _stream_threads():
    return [t for t in threading.enumerate() if t.name.startswith("jaxadapt-")]


def test_a_streamed_render_gives_the_frames_and_diagnostics_of_a_plain_loop(tmp_path, capsys):
    # Reading ahead and writing behind in threads change nothing: the frames
    # and diagnostics are those of the operator called chunk after chunk.
    frames = _gradient_frames(7)
    paths = []
    for i, frame in enumerate(frames):
        paths.append(tmp_path / f"in_{i}.pfm")
        io.write_image(paths[-1], frame)
    out = tmp_path / "out"
    status, err = _run(
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
    status, err = _run(
        capsys, "render", *map(str, paths), "--format", "pfm", "--chunk", "2", "--out", str(out)
    )
    _assert_one_line_error(status, err, "in_5.pfm" if stage == "read" else "frame_00005.pfm")
    assert not out.exists()
    assert _stream_threads() == []
