"""The pipe to pfstools (:mod:`jaxadapt.peers`), with stand-ins for its tools."""

import os
import stat
import subprocess
import sys

import numpy as np
import pytest

STAND_INS = {
    # pfsin: name the input folder downstream; pfsout: copy the inputs as outputs
    "pfsin": 'dirname "$1"\n',
    "pfsout": 'd=$(cat)\nfor f in "$d"/in_*.exr; do cp "$f" "${f/in_/out_}"; done\n',
    # the operator: a report of REPORT_BYTES on stderr, and its input passed on
    "pfstmo_pattanaik00": 'head -c "$REPORT_BYTES" /dev/zero | tr "\\0" x >&2\ncat\n',
}


@pytest.fixture
def stand_ins(tmp_path, monkeypatch):
    for name, body in STAND_INS.items():
        tool = tmp_path / name
        tool.write_text("#!/bin/bash\n" + body)
        tool.chmod(tool.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("PATH", f"{tmp_path}{os.pathsep}{os.environ['PATH']}")


def test_a_long_report_does_not_block_the_pipe(stand_ins, monkeypatch, tmp_path):
    # The operator's report is read as it comes: read only once pfsout has
    # finished, a report past the pipe's 64 KiB would block the operator
    # writing it, and all three would wait for ever. Run in a child
    # process, so that a hang fails.
    monkeypatch.setenv("REPORT_BYTES", str(200_000))
    frames = np.random.default_rng(0).uniform(0, 100, (2, 4, 6, 3)).astype(np.float32)
    np.save(tmp_path / "frames.npy", frames)
    script = (
        "import sys, numpy as np; from jaxadapt import peers; "
        "out, report = peers.pfstmo_pattanaik00(np.load(sys.argv[1]), '-t'); "
        "np.save(sys.argv[2], out); print(len(report))"
    )
    done = subprocess.run(
        [sys.executable, "-c", script, tmp_path / "frames.npy", tmp_path / "out.npy"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["200000"]
    np.testing.assert_array_equal(np.load(tmp_path / "out.npy"), frames)
