"""Input files named by URL: an S3 bucket served on loopback by moto's
server (a stand-in for AWS that speaks its protocol), read through fsspec
and s3fs by the command and by the workers of an embedded Dask cluster;
the renders equal those of the same files on the local disk."""

import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from cli_runs import assert_one_line_error, run

s3fs = pytest.importorskip("s3fs")
MOTO = shutil.which("moto_server", path=str(Path(sys.executable).parent))
pytestmark = pytest.mark.skipif(MOTO is None, reason="moto's server is not installed")


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def bucket(tmp_path_factory):
    """An S3 filesystem on a moto server with an empty bucket ``frames``;
    the environment that points AWS's clients at it (set while the module
    runs, so that the workers a test starts inherit it)."""
    port = _free_port()
    log = open(tmp_path_factory.mktemp("moto") / "moto.log", "w")
    server = subprocess.Popen([MOTO, "-H", "127.0.0.1", "-p", str(port)], stdout=log, stderr=log)
    env = {
        "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}",
        "AWS_ACCESS_KEY_ID": "testing",
        "AWS_SECRET_ACCESS_KEY": "testing",
        "AWS_DEFAULT_REGION": "us-east-1",
    }
    saved = {name: os.environ.get(name) for name in env}
    os.environ.update(env)
    try:
        fs = s3fs.S3FileSystem(skip_instance_cache=True)
        deadline = time.monotonic() + 60
        while True:
            try:
                fs.mkdir("frames")
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        yield fs
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
        server.terminate()
        server.wait(timeout=30)


def _frames(folder, n):
    """``n`` EXR frames of a step from 100 to 1 cd/m2 (48x32), on the local disk."""
    from jaxadapt import io

    folder.mkdir()
    y = np.linspace(0.2, 1.0, 32, dtype=np.float32)[:, None, None]
    for i in range(n):
        level = 100.0 if i < n // 2 else 1.0
        io.write_image(folder / f"f_{i:04d}.exr", np.broadcast_to(level * y, (32, 48, 3)))
    return sorted(folder.iterdir())


def _same_outputs(one, other):
    """Two renders' files the same: EXR frames' pixels (their headers hold
    the time they were written), the other files byte for byte."""
    from jaxadapt import io

    names = sorted(p.name for p in one.iterdir())
    assert sorted(p.name for p in other.iterdir()) == names
    for name in names:
        if name.endswith(".exr"):
            np.testing.assert_array_equal(io.read_hdr(other / name), io.read_hdr(one / name))
        else:
            assert (one / name).read_bytes() == (other / name).read_bytes(), name


def test_frames_named_by_url_render_as_the_files_do(tmp_path, capsys, bucket, monkeypatch):
    # A sequence named by a glob of URLs (expanded by jaxadapt: no shell
    # does), rendered in this process and on an embedded cluster of two
    # workers that each read their own frames from the bucket.
    from test_cluster import THIS_PROCESS_XLA_FLAGS

    monkeypatch.setenv("XLA_FLAGS", THIS_PROCESS_XLA_FLAGS)
    files = _frames(tmp_path / "frames", 40)
    bucket.put([str(f) for f in files], "frames/shot/")
    formats = ["--format", "exr", "--format", "png"]
    argv = ["render", "--fps", "12", "--operator", "jacobs2015", *formats]
    status, err = run(capsys, *argv, *map(str, files), "--out", str(tmp_path / "local"))
    assert status == 0, err
    for option, out in (([], "remote"), (["--workers", "2"], "remote_cluster")):
        status, err = run(capsys, *argv, "s3://frames/shot/f_*.exr", *option,
                          "--out", str(tmp_path / out))  # fmt: skip
        assert status == 0, err
        _same_outputs(tmp_path / "local", tmp_path / out)


def test_a_video_named_by_url_renders_as_the_file_does(tmp_path, capsys, bucket):
    # Read by FFmpeg in blocks through s3fs (not copied whole), its audio
    # copied into the render's video.
    from test_cluster import _assert_renders_alike
    from test_video import _clip

    clip = _clip(tmp_path / "clip.mp4", "pq", frames=12, audio=True)
    bucket.put(str(clip), "frames/clip.mp4")
    formats = ["--format", "exr", "--format", "png", "--format", "mp4"]
    status, err = run(capsys, "render", str(clip), *formats, "--out", str(tmp_path / "local"))
    assert status == 0, err
    url = "s3://frames/clip.mp4"
    status, err = run(capsys, "render", url, *formats, "--out", str(tmp_path / "remote"))
    assert status == 0, err
    _assert_renders_alike(tmp_path / "local", tmp_path / "remote", exact=True)


def test_urls_that_name_nothing_are_one_line(tmp_path, capsys, bucket, monkeypatch):
    out = tmp_path / "out"
    for url, words in (
        ("s3://frames/none.exr", ["s3://frames/none.exr: no such file"]),
        ("s3://frames/none_*.exr", ["s3://frames/none_*.exr: no file matches"]),
        ("s3://frames/none.mp4", ["s3://frames/none.mp4: no such file"]),
        ("nosuchprotocol://x/f.exr", ["nosuchprotocol://x/f.exr: cannot be read here"]),
    ):
        status, err = run(capsys, "render", url, "--out", str(out))
        assert_one_line_error(status, err, *words)
        assert not out.exists()
    # A bucket read without credentials (an error of the filesystem
    # package's own), by a glob, a frame's name and a video's.
    with monkeypatch.context() as without:
        for name in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY"):
            without.delenv(name)
        without.setenv("AWS_SHARED_CREDENTIALS_FILE", str(tmp_path / "none"))
        s3fs.S3FileSystem.clear_instance_cache()
        for url in ("s3://frames/f_*.exr", "s3://frames/f.exr", "s3://frames/f.mp4"):
            status, err = run(capsys, "render", url, "--out", str(out))
            assert_one_line_error(status, err, f"{url}: cannot be read (", "credentials")
            assert not out.exists()
    s3fs.S3FileSystem.clear_instance_cache()
    # A bad frame in the bucket is named by its URL, not by a local copy's path.
    bucket.pipe("frames/bad.exr", b"not an image")
    status, err = run(capsys, "render", "s3://frames/bad.exr", "--out", str(out))
    assert_one_line_error(status, err, "s3://frames/bad.exr:")
    assert "jaxadapt-" not in err


def test_a_render_into_a_url_equals_one_into_a_folder(tmp_path, capsys, bucket, monkeypatch):
    # --out s3://frames/run: in this process (its files written here and
    # put there once the run has succeeded), then on an embedded cluster
    # (each shard's files put there by its worker once it is done; the
    # video's parts joined by the command). A later run there removes what
    # the earlier one wrote and it does not; a run that fails leaves the
    # folder as it was; no staging folder is left either way.
    from test_cluster import THIS_PROCESS_XLA_FLAGS, _assert_renders_alike

    from jaxadapt import io

    monkeypatch.setenv("XLA_FLAGS", THIS_PROCESS_XLA_FLAGS)
    files = [str(f) for f in _frames(tmp_path / "frames", 40)]
    formats = ["--format", "exr", "--format", "png", "--format", "mp4"]
    argv = ["render", *files, "--fps", "12", *formats]
    status, err = run(capsys, *argv, "--out", str(tmp_path / "local"))
    assert status == 0, err

    def listing(name):
        return sorted(p.rsplit("/", 1)[1] for p in bucket.ls(f"frames/{name}", refresh=True))

    for option, name in (([], "one"), (["--workers", "2"], "cluster")):
        status, err = run(capsys, *argv, *option, "--out", f"s3://frames/{name}")
        assert status == 0, err
        got = tmp_path / f"got_{name}"
        bucket.get(f"frames/{name}/", str(got), recursive=True)
        _assert_renders_alike(tmp_path / "local", got)
        assert [n for n in listing(name) if n.startswith(".jaxadapt-")] == [".jaxadapt-render"]
    status, err = run(capsys, *argv[:-4], "--out", "s3://frames/one")  # (EXR frames only)
    assert status == 0, err
    names = listing("one")
    assert not any(n.startswith("frame_") and n.endswith(".png") for n in names)
    assert "video.mp4" not in names and "contact_sheet.png" in names
    assert sum(n.endswith(".exr") for n in names) == 40
    io.write_image(tmp_path / "nan.exr", np.full((32, 48, 3), np.nan, np.float32))
    bad = ["render", *files, str(tmp_path / "nan.exr"), *argv[-8:]]
    status, err = run(capsys, *bad, "--out", "s3://frames/one")
    assert_one_line_error(status, err, "nan.exr")
    assert listing("one") == names
    # A staging folder that a failed run's worker wrote into after the run
    # removed it: named in a warning, left alone.
    bucket.pipe("frames/one/.jaxadapt-0123/frame_00000.exr", b"late")
    status, err = run(capsys, *argv[:-4], "--out", "s3://frames/one")
    assert status == 0, err
    assert "warning: s3://frames/one holds .jaxadapt-0123: the staging folders" in err
    assert ".jaxadapt-0123" in listing("one")
