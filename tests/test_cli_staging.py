"""``--out``: a run's outputs are staged in a hidden folder inside it and
moved into place only when the whole run has succeeded
(:mod:`jaxadapt.cli._staging`), here through ``jaxadapt render``."""

import errno
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from cli_runs import SMALL, assert_one_line_error, run

from jaxadapt import _signals, io, pipeline
from jaxadapt.cli import _staging, main


@pytest.fixture
def interruptible():
    """Ctrl-C handled in this process for one test, as in a shell's
    foreground (a suite started in the background ignores it), then as
    before."""
    saved = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, saved)


def test_bad_values_leave_earlier_output_untouched(tmp_path, capsys):
    good, bad = tmp_path / "a.exr", tmp_path / "b.exr"
    io.write_image(good, np.ones((4, 4, 3), np.float32))
    io.write_image(bad, np.full((4, 4, 3), -1.0, np.float32))
    out = tmp_path / "out"
    out.mkdir()
    (out / "frame_00000.png").write_bytes(b"earlier result")
    status, err = run(capsys, "render", str(good), str(bad), "--out", str(out))
    assert_one_line_error(status, err, "b.exr", "non-negative")
    assert [p.name for p in out.iterdir()] == ["frame_00000.png"]
    assert (out / "frame_00000.png").read_bytes() == b"earlier result"


def test_unwritable_output(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    status, err = run(capsys, "render", "--scene", "title-step", *SMALL, "--out", str(blocker))
    assert_one_line_error(status, err, "--out: expected a folder, got the file", str(blocker))
    status, err = run(
        capsys, "render", "--scene", "title-step", *SMALL, "--out", str(blocker / "x")
    )
    assert_one_line_error(status, err, "--out: cannot write to", str(blocker / "x"))
    with pytest.raises(SystemExit) as exit:  # an empty path would be the current folder
        main(["render", "--out", ""])
    assert_one_line_error(exit.value.code, capsys.readouterr().err, "--out", "empty path")


@pytest.mark.slow
def test_a_failed_run_leaves_no_new_folder(tmp_path, capsys):
    bad = tmp_path / "bad.exr"
    io.write_image(bad, np.full((4, 4, 3), np.nan, np.float32))
    status, err = run(capsys, "render", str(bad), "--out", str(tmp_path / "o"))
    assert_one_line_error(status, err, "bad.exr", "non-negative")
    assert not (tmp_path / "o").exists()
    # Through a folder that does not exist and back (new/../o), the run
    # makes new and o: a failed run removes both, a good run leaves no new.
    status, err = run(capsys, "render", str(bad), "--out", str(tmp_path / "new" / ".." / "o"))
    assert_one_line_error(status, err, "bad.exr", "non-negative")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.exr"]
    good = tmp_path / "good.exr"
    io.write_image(good, np.full((4, 4, 3), 1.0, np.float32))
    out = str(tmp_path / "new" / ".." / "o")
    assert run(capsys, "render", str(good), "--out", out, "--format", "exr")[0] == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.exr", "good.exr", "o"]


@pytest.mark.slow
def test_a_new_render_replaces_the_earlier_ones_outputs(tmp_path, capsys):
    out = tmp_path / "out"
    args = ["render", "--scene", "title-step", "--size", "24x16", "--out", str(out)]
    assert run(capsys, *args, "--duration", "0.3")[0] == 0
    (out / "notes.txt").write_text("mine")
    assert run(capsys, *args, "--duration", "0.09", "--format", "exr")[0] == 0
    names = sorted(p.name for p in out.iterdir())
    frames = [f"frame_{k:05d}.exr" for k in range(3)]
    files = ["adaptation.png", "contact_sheet.png", "diagnostics.csv", *frames, "notes.txt"]
    assert names == [".jaxadapt-render", *files]


@pytest.mark.slow
def test_a_folder_where_an_output_goes_fails_the_run_before_anything_moves(tmp_path, capsys):
    # Found before anything moves: moves that stop at the folder would
    # leave the outputs before it in order the new run's, those after it
    # the old run's, and a message naming the removed staging folder.
    out = tmp_path / "out"
    args = ["render", "--scene", "title-step", "--size", "24x16", "--out", str(out)]
    assert run(capsys, *args, "--duration", "0.3")[0] == 0
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    (out / "diagnostics.csv").unlink()
    (out / "diagnostics.csv").mkdir()
    del before["diagnostics.csv"]
    status, err = run(capsys, *args, "--duration", "0.2")
    assert_one_line_error(status, err, "--out", str(out / "diagnostics.csv"), "is a folder")
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == ["diagnostics.csv"]


def test_a_folder_named_as_an_output_is_refused_before_the_render(tmp_path, capsys, monkeypatch):
    # Found before the render, not when the rendered files move into place.
    def rendered(*args, **kwargs):
        raise AssertionError("rendered")

    monkeypatch.setattr(pipeline, "chunks", rendered)
    out = tmp_path / "out"
    (out / "video.mp4").mkdir(parents=True)
    status, err = run(capsys, "render", "--scene", "flash", *SMALL, "--out", str(out))
    assert_one_line_error(status, err, "--out", str(out / "video.mp4"), "is a folder")
    assert [p.name for p in out.iterdir()] == ["video.mp4"]


def test_a_signal_while_the_outputs_move_waits_and_the_run_succeeds(
    tmp_path, monkeypatch, interruptible
):
    # A SIGINT after the first of the moves into --out waits for the rest:
    # acted on there, it would leave the new run's first files beside the
    # rest of the earlier run's, with a message that nothing was written.
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
    # Once all are in place the run has succeeded: the signal is dropped,
    # not raised after the move to say that the run was interrupted.
    assert _signals.WRITTEN.is_set() and _signals.SIGNALLED == [signal.SIGINT]
    assert {p.name: p.read_text() for p in out.iterdir()} == dict.fromkeys(
        ("a.csv", "b.csv", "c.csv"), "new"
    )


@pytest.mark.parametrize("existing", [False, True])
def test_a_signal_as_the_staging_folder_is_made_leaves_nothing(tmp_path, monkeypatch, existing):
    # A SIGTERM just after the staging folder is made (as a test sends it
    # as soon as the folder is seen) finds the clean-up armed: neither the
    # staging folder nor the --out it made stays.
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


@pytest.mark.slow
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
    status, err = run(capsys, "render", "--scene", "flash", *SMALL, "--out", str(out))
    assert status == 0
    left = sorted(p.name for p in out.glob(".jaxadapt-*") if p.is_dir())
    assert left == sorted(name for name, kept in names.items() if kept)
    assert ".jaxadapt-older" in err and killed not in err


@pytest.mark.slow
def test_staging_folders_left_by_killed_runs_are_named(tmp_path, capsys):
    out = tmp_path / "out"
    (out / ".jaxadapt-killed").mkdir(parents=True)
    status, err = run(capsys, "render", "--scene", "flash", *SMALL, "--out", str(out))
    assert status == 0
    assert "warning:" in err and ".jaxadapt-killed" in err and "runs that were killed" in err


@pytest.mark.slow
def test_a_full_device_is_said_naming_out(tmp_path, capsys, monkeypatch):
    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(io, "write_columns", full)
    out = tmp_path / "out"
    status, err = run(capsys, "render", "--scene", "flash", *SMALL, "--out", str(out))
    assert_one_line_error(status, err, "--out: no space left on the device of", str(out))
    assert not out.exists()


@pytest.mark.slow
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
    status, err = run(
        capsys, "render", "--scene", "flash", *SMALL, "--allow-large", "--out", str(out)
    )
    assert_one_line_error(status, err, "--out: no space left on the device of", str(out))


def test_an_out_that_cannot_be_written_is_said_so_on_a_device_without_space(
    tmp_path, capsys, monkeypatch
):
    # A read-only mount reports no free space: its error, "cannot write to
    # --out (Read-only file system)", is said as it is, not as a full device.
    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(tempfile, "mkdtemp", read_only)
    usage = shutil.disk_usage
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(path)._replace(free=0))
    out = tmp_path / "out"
    status, err = run(capsys, "render", "--scene", "flash", *SMALL, "--out", str(out))
    assert_one_line_error(status, err, f"--out: cannot write to {out} (Read-only file system)")
    assert not out.exists()


def test_frame_files_beyond_99999_are_outputs_too():
    # frame_100000.png is an output too, or a later run would never remove it.
    assert _staging.RENDER_OUTPUTS.fullmatch("frame_100000.png")
    assert not _staging.RENDER_OUTPUTS.fullmatch("frame_0001.png")


@pytest.mark.slow
def test_a_render_never_writes_over_its_inputs_nor_removes_what_it_did_not_write(
    tmp_path, capsys, monkeypatch
):
    # Input frames named as the render's output frames, in --out: refused
    # before anything is written (the display frames would overwrite
    # them). Renamed, they render into the same folder, and a file of the
    # user's with an output name (their own video) stays.
    monkeypatch.chdir(tmp_path)
    for k in range(3):
        io.write_image(tmp_path / f"frame_{k:05d}.exr", np.full((4, 6, 3), 10.0 + k, np.float32))
    (tmp_path / "video.mp4").write_bytes(b"the user's")
    inputs = [f"frame_{k:05d}.exr" for k in range(3)]
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    status, err = run(capsys, "render", *inputs, "--out", ".", "--format", "exr")
    assert_one_line_error(status, err, "frame_00000.exr", "may write over")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    renamed = [f"scene_{k}.exr" for k in range(3)]
    for old, new in zip(inputs, renamed, strict=True):
        (tmp_path / old).rename(tmp_path / new)
    assert run(capsys, "render", *renamed, "--out", ".", "--format", "exr")[0] == 0
    assert (tmp_path / "video.mp4").read_bytes() == b"the user's"
    for name in renamed:
        assert (tmp_path / name).read_bytes() == before[inputs[renamed.index(name)]]
    # An input in --out that is a link, with an output's name, is refused
    # too: the display frame would replace the link (its target untouched).
    (tmp_path / "frame_00000.exr").unlink()  # the last run's output
    (tmp_path / "frame_00000.exr").symlink_to(tmp_path / renamed[0])
    status, err = run(capsys, "render", "frame_00000.exr", "--out", ".", "--format", "exr")
    assert_one_line_error(status, err, "frame_00000.exr", "may write over")
    assert (tmp_path / "frame_00000.exr").is_symlink()


@pytest.mark.slow
def test_a_signal_after_the_outputs_are_in_place_is_a_success(tmp_path, capsys, monkeypatch):
    # The outputs all moved into --out, then a SIGTERM: exit status 0 and
    # the run's own summary, not "interrupted" and status 143.
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
