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

import pytest
from cli_runs import assert_one_line_error, run

distributed = pytest.importorskip("distributed")

DASK = shutil.which("dask", path=str(Path(sys.executable).parent))
SIMULATE = ["psychometric", "simulate", "--protocol", "afterimage", "--observers", "12"]
#: The vector width of this process's XLA (256 bits unless XLA_FLAGS chose
#: when it started): an in-process run's runtime.use_wide_vectors() changes
#: XLA_FLAGS for the processes it starts, not for this one, and results in
#: 256- and 512-bit vectors differ in the last bit.
THIS_PROCESS_XLA_FLAGS = os.environ.get("XLA_FLAGS") or "--xla_cpu_prefer_vector_width=256"


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def _cluster(logs, nanny=True):
    """``(address, processes)`` of a scheduler and two single-threaded
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
    for i in range(2):
        start(f"worker{i}", "worker", address, "--nthreads", "1", "--no-dashboard",
              "--name", f"w{i}", *([] if nanny else ["--no-nanny"]))  # fmt: skip
    try:
        with distributed.Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=120)
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
    # Each killed once the first block's result is in, the others in flight.
    from jaxadapt import cluster

    status, err = run(capsys, *SIMULATE, "--out", str(tmp_path / "one"))
    assert status == 0, err
    original, victim = cluster.in_order, []

    def killing(*args, **kwargs):
        for i, result in enumerate(original(*args, **kwargs)):
            if i == 0:
                victim[0].send_signal(signal.SIGKILL)
            yield result

    monkeypatch.setattr(cluster, "in_order", killing)
    with _cluster(tmp_path / "logs", nanny=False) as (address, (scheduler_, worker, _)):
        victim.append(worker)
        status, err = run(capsys, *SIMULATE, "--scheduler", address, "--out", str(tmp_path / "k"))
        assert status == 0, err
        for name in ("trials.csv", "observers.csv"):
            assert (tmp_path / "k" / name).read_bytes() == (tmp_path / "one" / name).read_bytes()
        victim[0] = scheduler_
        out = tmp_path / "lost"
        status, err = run(capsys, *SIMULATE, "--scheduler", address, "--out", str(out))
        assert_one_line_error(status, err, f"--scheduler {address}: the Dask scheduler was lost")
        assert not out.exists()
