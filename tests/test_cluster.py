"""Work on a Dask cluster: a real scheduler and two workers, started by
Dask's own commands (``dask scheduler``, ``dask worker``) on loopback, and
the embedded LocalCluster of ``--workers``; the results equal one
process's, and a cluster that cannot be reached is one line, status 2."""

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from cli_runs import assert_one_line_error, run

distributed = pytest.importorskip("distributed")

DASK = shutil.which("dask", path=str(Path(sys.executable).parent))
SIMULATE = ["psychometric", "simulate", "--protocol", "afterimage", "--observers", "12"]
#: The vector width of this process's XLA (256 bits unless XLA_FLAGS chose
#: when it started): an in-process run's runtime.use_wide_vectors() changes
#: XLA_FLAGS for the processes it starts, not for this one, and results in
#: 256- and 512-bit vectors differ in the last bit.
_FLAGS = os.environ.get("XLA_FLAGS", "")
THIS_PROCESS_XLA_FLAGS = (
    _FLAGS
    if "xla_cpu_prefer_vector_width" in _FLAGS
    else f"{_FLAGS} --xla_cpu_prefer_vector_width=256".strip()
)


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def _cluster(logs, nanny=True, workers=2):
    """``(address, processes)`` of a scheduler and ``workers`` single-threaded
    workers, the scheduler first (without nannies, a worker killed stays
    dead)."""
    address = f"tcp://127.0.0.1:{_free_port()}"
    logs.mkdir(parents=True, exist_ok=True)
    started = []

    # (the workers in this process's precision, x64: jaxadapt's constants take
    # the precision in force when it is imported; and with its vectors)
    env = dict(os.environ, JAX_ENABLE_X64="True", XLA_FLAGS=THIS_PROCESS_XLA_FLAGS)

    def start(name, *argv):
        log = open(logs / f"{name}.log", "w")
        started.append(subprocess.Popen([DASK, *argv], stdout=log, stderr=log, env=env))

    start("scheduler", "scheduler", "--host", "127.0.0.1", "--port", address.rsplit(":", 1)[1],
          "--no-dashboard")  # fmt: skip
    for i in range(workers):
        start(f"worker{i}", "worker", address, "--nthreads", "1", "--no-dashboard",
              "--name", f"w{i}", *([] if nanny else ["--no-nanny"]))  # fmt: skip
    try:
        with distributed.Client(address, timeout=60) as client:
            client.wait_for_workers(workers, timeout=120)
        yield address, started
    finally:
        for process in reversed(started):
            process.terminate()
        for process in started:
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()


def _spawned():
    """The process ids of this process's children that multiprocessing
    spawned (a LocalCluster's workers; not its resource tracker)."""
    children = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            command = (stat.parent / "cmdline").read_bytes()
        except OSError:  # (ended meanwhile)
            continue
        if int(fields[1]) == os.getpid() and b"spawn_main" in command:
            children.add(int(stat.parent.name))
    return children


@pytest.fixture(scope="module")
def scheduler(tmp_path_factory):
    """The address of a scheduler with two workers."""
    with _cluster(tmp_path_factory.mktemp("dask")) as (address, _):
        yield address


def test_simulate_and_fit_on_a_cluster_equal_one_process(tmp_path, capsys, scheduler, monkeypatch):
    # The simulation's observers in blocks of 3 (two tasks a worker), the
    # fit's 24 groups in parts of whole bootstrap blocks, each resampled
    # with its keys in the whole table: the same tables, byte for byte (the
    # embedded cluster's run by the same code once connected: simulate's).
    monkeypatch.setenv("XLA_FLAGS", THIS_PROCESS_XLA_FLAGS)  # (for --workers' processes)
    status, err = run(capsys, *SIMULATE, "--out", str(tmp_path / "one"))
    assert status == 0, err
    before = _spawned()
    for option in (["--scheduler", scheduler], ["--workers", "2"]):
        out = tmp_path / option[0].lstrip("-")
        status, err = run(capsys, *SIMULATE, *option, "--out", str(out))
        assert status == 0, err
        for name in ("trials.csv", "observers.csv", "stimuli.csv"):
            assert (out / name).read_bytes() == (tmp_path / "one" / name).read_bytes(), name
    # (--memory 1M: bootstrap blocks of 16 groups at 20 resamples; two parts)
    fit = ["psychometric", "fit", str(tmp_path / "one" / "trials.csv"), "--resamples", "20",
           "--memory", "1M"]  # fmt: skip
    for option, out in (([], "fit_one"), (["--scheduler", scheduler], "fit_cluster")):
        status, err = run(capsys, *fit, *option, "--out", str(tmp_path / out))
        assert status == 0, err
    for name in ("fits.csv", "group_test.csv"):
        one, cluster = (tmp_path / out / name for out in ("fit_one", "fit_cluster"))
        assert cluster.read_bytes() == one.read_bytes(), name
    # The embedded cluster's worker processes ended with the run.
    deadline = time.monotonic() + 30
    while _spawned() - before and time.monotonic() < deadline:
        time.sleep(0.2)
    assert _spawned() - before == set()


#: A render of 48 frames: three shards of 16 on a cluster of two workers.
FORMATS = ["--format", "exr", "--format", "png", "--format", "mp4"]
RENDER = ["render", "--size", "48x32", "--duration", "4", "--fps", "12", *FORMATS]


def _video(path):
    """Each frame's stamp (s) and pixels, the streams' types, the audio's packets."""
    import av

    with av.open(str(path)) as video:
        frames = [(f.time, f.to_ndarray(format="rgb24").astype(int)) for f in video.decode(video=0)]
        video.seek(0)
        audio = [bytes(p) for s in video.streams.audio for p in video.demux(s) if p.size]
        return frames, [s.type for s in video.streams], audio


def _png(path):
    """An 8-bit file's pixels, as ints."""
    import OpenImageIO as oiio

    return oiio.ImageBuf(str(path)).get_pixels(oiio.UINT8).astype(int)


def _assert_renders_alike(one, other, exact=False):
    """Two renders' outputs alike: the same files; EXR frames and the
    diagnostics equal (up to float32 rounding, unless ``exact``), PNG frames
    within a level; the video's frames at the same times, its pictures
    within a few levels (a video split in time has a key frame at each
    shard's start), the same audio."""
    from jaxadapt import io

    names = sorted(p.name for p in one.iterdir())
    assert sorted(p.name for p in other.iterdir()) == names
    tolerance = {"rtol": 0, "atol": 0} if exact else {"rtol": 1e-5, "atol": 1e-6}
    for name in names:
        if name.endswith(".exr"):
            np.testing.assert_allclose(
                io.read_hdr(other / name), io.read_hdr(one / name), **tolerance, err_msg=name
            )
        elif name.startswith("frame_") and name.endswith(".png"):
            a, b = (_png(d / name) for d in (one, other))
            assert np.abs(a - b).max() <= (0 if exact else 1), name
    lines = [(d / "diagnostics.csv").read_text().splitlines() for d in (one, other)]
    assert lines[0][0] == lines[1][0]  # (the columns in order)
    a, b = (np.array([r.split(",") for r in rows[1:]], float) for rows in lines)
    np.testing.assert_allclose(b, a, rtol=0 if exact else 1e-5)
    (times, streams, audio, errors), (times2, streams2, audio2, errors2) = (
        _video_and_errors(d) for d in (one, other)
    )
    assert (times2, streams2, audio2) == (times, streams, audio)
    # (the parts' pictures as faithful to the frames as the whole's)
    assert np.mean(errors2) < 1.2 * np.mean(errors) and max(errors2) < 1.2 * max(errors)


def _video_and_errors(folder):
    """The times, streams and audio of a render's video, and its pictures'
    mean absolute difference from the PNG frames, levels."""
    frames, streams, audio = _video(folder / "video.mp4")
    errors = [
        np.abs(f - _png(folder / f"frame_{i:05d}.png")).mean() for i, (_, f) in enumerate(frames)
    ]
    return [t for t, _ in frames], streams, audio, errors


def test_render_on_a_cluster_equals_one_process(tmp_path, capsys, scheduler, monkeypatch):
    # The 2000 operator composes in time: its shards start from the state
    # the maps of the shards before them give (a video's frames with a
    # global background, the tunnel's with a local one); the 2015 one's
    # state is handed from shard to shard (the same computation, bit for
    # bit); a tone curve's shards are independent. A video's parts are
    # joined with its stamps and its audio; its name, as given, is relative
    # to this process's folder, not the workers'.
    monkeypatch.setenv("XLA_FLAGS", THIS_PROCESS_XLA_FLAGS)
    from test_video import _clip

    clip = _clip(tmp_path / "clip.mp4", "pq", frames=40, audio=True)
    monkeypatch.chdir(tmp_path)
    for name, argv, exact in (
        ("local", [*RENDER, "--background", "gaussian"], False),
        ("jacobs", [*RENDER, "--operator", "jacobs2015"], True),
        ("curve", [*RENDER, "--operator", "photographic"], True),
        ("video", ["render", clip.name, *FORMATS], False),  # (named from here: not the workers')
    ):
        one, other = tmp_path / f"{name}_one", tmp_path / f"{name}_cluster"
        status, err = run(capsys, *argv, "--out", str(one))
        assert status == 0, err
        status, err = run(capsys, *argv, "--scheduler", scheduler, "--out", str(other))
        assert status == 0, err
        _assert_renders_alike(one, other, exact)


def test_what_killed_shards_left_half_written_is_removed(tmp_path):
    # A worker killed while it writes a frame leaves its atomic writer's
    # temporary file (this name, in one run of the test below): not an output.
    from jaxadapt.cli._shards import tidied

    (tmp_path / ".frame_00016.z738w4qp.png").write_bytes(b"half")
    (tmp_path / "frame_00015.png").write_bytes(b"whole")
    tidied(tmp_path)
    assert [p.name for p in tmp_path.iterdir()] == ["frame_00015.png"]


def test_a_task_s_error_is_the_command_s_one_line(tmp_path, capfd):
    # A frame a worker finds bad: its error as the command's one line, the
    # worker's own log of it (and its traceback) not on the terminal the
    # embedded cluster shares (capfd: the workers' stderr too).
    from jaxadapt import io

    frames = [tmp_path / f"f{i}.exr" for i in range(2)]
    for i, path in enumerate(frames):
        io.write_image(path, np.full((8, 8, 3), np.nan if i else 1.0, np.float32))
    out = tmp_path / "out"
    status, err = run(capfd, "render", *map(str, frames), "--workers", "1", "--out", str(out))
    assert_one_line_error(status, err, "f1.exr: expected finite, non-negative values")
    assert not out.exists()


def test_a_cluster_that_cannot_be_reached_is_one_line(tmp_path, capsys, monkeypatch):
    from jaxadapt import cluster

    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT", 2.0)
    nobody = f"tcp://127.0.0.1:{_free_port()}"
    out = tmp_path / "out"
    status, err = run(capsys, *SIMULATE, "--scheduler", nobody, "--out", str(out))
    assert_one_line_error(status, err, f"--scheduler {nobody}: no Dask scheduler answers")
    assert not out.exists()
    status, err = run(capsys, *SIMULATE, "--scheduler", nobody, "--workers", "2", "--out", str(out))
    assert_one_line_error(
        status, err, "--workers: starts a cluster of its own; not with --scheduler"
    )
    status, err = run(
        capsys, "render", "--replay", str(tmp_path), "--workers", "2", "--out", str(out)
    )
    assert_one_line_error(status, err, "--workers: a replay writes the frames it recorded")
    with pytest.raises(SystemExit) as exit_:
        run(capsys, *SIMULATE, "--workers", "0", "--out", str(out))
    assert exit_.value.code == 2
    assert "--workers: expected a positive number of processes, got '0'" in capsys.readouterr().err
    # Without Dask installed: how to install it.
    monkeypatch.setitem(sys.modules, "distributed", None)
    status, err = run(capsys, *SIMULATE, "--workers", "2", "--out", str(out))
    assert_one_line_error(status, err, "--workers: needs Dask distributed, which is not installed:",
                          "pip install 'jaxadapt[cluster]'")  # fmt: skip
    assert not out.exists()


def test_without_a_cluster_option_dask_is_not_needed(tmp_path, capsys, monkeypatch):
    # Dask made unimportable: a run without --scheduler or --workers works.
    monkeypatch.setitem(sys.modules, "distributed", None)
    monkeypatch.setitem(sys.modules, "dask", None)
    status, err = run(capsys, *SIMULATE, "--out", str(tmp_path / "o"))
    assert status == 0, err


def test_a_worker_killed_changes_nothing_a_scheduler_lost_is_one_line(
    tmp_path, capsys, monkeypatch
):
    # A worker killed once the first result is in, the others in flight: in
    # a simulation, then in a render (its shards' maps found; its frames
    # being rendered), then in a render whose shards hand their state on
    # (the next shards waiting for it, or rendering from it); then the
    # scheduler.
    from jaxadapt import cluster

    monkeypatch.setenv("XLA_FLAGS", THIS_PROCESS_XLA_FLAGS)
    handing = [*RENDER, "--operator", "jacobs2015"]
    for argv, out in ((SIMULATE, "one"), (RENDER, "render_one"), (handing, "handing_one")):
        status, err = run(capsys, *argv, "--out", str(tmp_path / out))
        assert status == 0, err
    victims, calls = [], []

    def killing(original):
        def sent(*args, **kwargs):
            calls.append(None)
            for i, result in enumerate(original(*args, **kwargs)):
                if i == 0 and len(calls) != 2:  # (not while the render's maps are found)
                    victims.pop(0).send_signal(signal.SIGKILL)
                yield result

        return sent

    for name in ("in_order", "handed_on"):
        monkeypatch.setattr(cluster, name, killing(getattr(cluster, name)))
    with _cluster(tmp_path / "logs", nanny=False, workers=4) as (address, (scheduler_, *workers)):
        victims.extend(workers[:3])
        status, err = run(capsys, *SIMULATE, "--scheduler", address, "--out", str(tmp_path / "k"))
        assert status == 0, err
        for name in ("trials.csv", "observers.csv"):
            assert (tmp_path / "k" / name).read_bytes() == (tmp_path / "one" / name).read_bytes()
        for argv, one in ((RENDER, "render_one"), (handing, "handing_one")):
            render = tmp_path / f"{one}_killed"
            status, err = run(capsys, *argv, "--scheduler", address, "--out", str(render))
            assert status == 0, err
            _assert_renders_alike(tmp_path / one, render)
        assert [w.poll() for w in workers] == [-signal.SIGKILL] * 3 + [None]
        victims.append(scheduler_)
        out = tmp_path / "lost"
        status, err = run(capsys, *SIMULATE, "--scheduler", address, "--out", str(out))
        assert_one_line_error(status, err, f"--scheduler {address}: the Dask scheduler was lost")
        assert not out.exists()
