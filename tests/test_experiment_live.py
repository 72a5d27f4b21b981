"""``jaxadapt experiment`` run whole in Debian's headless Chromium with a
scripted participant: the page's phases and timing, every answer written
once through a SIGKILL of the server and a resume, and the table read by
``psychometric fit``."""

import csv
import json
import re
import signal
import socket
import subprocess
import threading
import time

import processes
from browsers import chromium

from jaxadapt.cli import main
from jaxadapt.experiment.scripted import ScriptedParticipant

#: Big pixels close by: images of a few tens of pixels.
SMALL = {"distance_m": 0.5, "pixel_pitch_mm": 1.0}


#: The brightest code on the page's canvas.
BRIGHTEST = """
const c = document.getElementById("screen");
const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
let m = 0;
for (let i = 0; i < d.length; i += 4) m = Math.max(m, d[i], d[i + 1], d[i + 2]);
return m;
"""


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(argv):
    """The command in a process of its own; it and its page's URL once serving."""
    process = processes.python(
        ["-m", "jaxadapt", *argv], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    lines = []
    for line in process.stdout:
        lines.append(line)
        found = re.search(r"serving (http://\S+)", line)
        if found:
            threading.Thread(target=lambda: lines.extend(process.stdout), daemon=True).start()
            return process, found[1], lines
    process.wait()
    raise AssertionError("".join(lines))


def _command(tmp_path, study, participant, *options):
    """``jaxadapt experiment`` of a 2-training-trial session on a small
    display into ``tmp_path / participant``: its arguments and folder."""
    display = tmp_path / "display.json"
    display.write_text(json.dumps(SMALL))
    out = tmp_path / participant
    argv = ["experiment", study, "--participant", participant, "--out", str(out), "--display"]
    argv += [str(display), "--training", "2", "--repetitions", "0", "--no-browser", *options]
    return argv, out


def _said(lines, words, timeout=10.0):
    """Wait until the command's output (read by a thread) holds ``words``."""
    end = time.monotonic() + timeout
    while words not in "".join(lines):
        assert time.monotonic() < end, "".join(lines)
        time.sleep(0.05)


def _rows(folder):
    with open(folder / "trials.csv", newline="") as f:
        return list(csv.DictReader(f))


def test_a_session_in_chromium_survives_sigkill_and_resumes(tmp_path, capsys):
    options = ("--break-every", "1", "--seed", "5", "--port", str(_free_port()))
    argv, out = _command(tmp_path, "afterimage", "p07", *options)
    server, url, said = _start(argv)
    # (a screen larger than the window: the page made full screen grows)
    driver = chromium(tmp_path / "chromium", screen=(1024, 768))
    try:
        driver.get(url)
        p = ScriptedParticipant(driver)
        p.watch()
        # The first trial, answered; the second up to its first blank (2.5 s
        # long: a poll of a loaded machine cannot miss it). The cross, seen
        # at a poll in a fixation (the page grew to full screen).
        brightest = []

        def look(phase):
            if phase == "fixation":
                brightest.append(driver.execute_script(BRIGHTEST))

        p.until(lambda phase: len(_rows(out)) == 1 and phase == "blank1", each=look)
        assert brightest and max(brightest) > 0
        assert driver.find_element("id", "text").text == ""  # (no words in a trial)
        assert not server.poll()
        server.send_signal(signal.SIGKILL)
        server.wait(30)
        assert len(_rows(out)) == 1  # the answer given is on the disk, the trial in flight not
        # The same command continues; the page, reloaded, shows the trial in flight again.
        server, url, said = _start(argv)
        assert "1 of 2 answered" in "".join(said)
        driver.refresh()
        p.watch()
        assert p.until(lambda phase: phase in ("done", "excluded")) == "done"
        assert server.wait(30) == 0
    finally:
        driver.quit()
        if server.poll() is None:
            server.kill()
    _said(said, "session complete: 2 trials answered")
    # Every phase, and what each image was.
    for phase in ("fixation", "interval1", "blank1", "interval2", "blank2", "respond", "break"):
        assert phase in p.phases
    assert p.images and set(p.images) <= {("standard", 27.0), ("test", 14.0), ("test", 49.0)}
    # Each trial answered once, correctly, its images timed by the page:
    # 50 ms (3 frames at 60 Hz) and 2.5 s of blank.
    rows = _rows(out)
    assert sorted(r["trial"] for r in rows) == ["0", "1"]
    for r in rows:
        assert r["flagged"] == "false" and r["correct"] == "true"
        for image in ("image1_ms", "image2_ms"):
            assert 45 < float(r[image]) < 55, r
        for blank in ("blank1_ms", "blank2_ms"):
            assert 2480 < float(r[blank]) < 2520, r
    session = json.loads((out / "session.json").read_text())
    assert session["seed"] == 5 and len(session["trials"]) == 2
    # A finished session is not run again; the fit reads its table (all of
    # it training here: nothing left to fit, and it says so).
    assert main(argv) == 2
    assert "finished afterimage session" in capsys.readouterr().err
    assert main(["psychometric", "fit", str(out / "trials.csv"), "--out", str(tmp_path / "f")]) == 2
    assert "got none (2 training, 0 flagged" in capsys.readouterr().err


def test_the_mesopic_session_starts_with_darkness(tmp_path):
    argv, out = _command(tmp_path, "mesopic", "p08", "--dark-seconds", "2", "--port", "0")
    server, url, said = _start(argv)
    driver = chromium(tmp_path / "chromium")
    try:
        driver.get(url)
        p = ScriptedParticipant(driver)
        p.watch()
        p.until(lambda phase: phase == "dark")
        started = time.monotonic()
        p.until(lambda phase: phase == "fixation")
        assert time.monotonic() - started > 1.5  # the countdown ran
        assert p.until(lambda phase: phase in ("done", "excluded")) == "done"
        assert server.wait(30) == 0
    finally:
        driver.quit()
        if server.poll() is None:
            server.kill()
    # Both trials kept once; a trial whose frames came late on a busy
    # machine is flagged and shown again, as designed (seen once in CI).
    rows = _rows(out)
    kept = [r for r in rows if r["flagged"] == "false"]
    assert sorted(r["trial"] for r in kept) == ["0", "1"], rows
    assert all(r["trial"] in ("0", "1") for r in rows) and len(rows) <= 4, rows
    for r in kept:  # 1.25 s images, 0.75 s black
        for image in ("image1_ms", "image2_ms"):
            assert 1230 < float(r[image]) < 1270, r
        assert 730 < float(r["blank1_ms"]) < 770, r


#: Holds the page's main thread for 100 ms (6 frames at 60 Hz) when the
#: first trial's second image comes up: its frames come late.
STALL = """
let stalled = false;
new MutationObserver(() => {
  if (!stalled && document.body.dataset.phase === "interval2") {
    stalled = true;
    const end = performance.now() + 100;
    while (performance.now() < end) {}
  }
}).observe(document.body, {attributes: true});
"""


def test_a_dropped_frame_and_ctrl_c(tmp_path):
    # The first trial's second image is kept from being drawn for 100 ms:
    # the trial is flagged, and shown again after the block's last. Then
    # Ctrl-C: status 130, the answers kept; the page left open waits for
    # the server and, once the same command serves again, carries on.
    argv, out = _command(tmp_path, "afterimage", "p10", "--seed", "5")
    argv += ["--port", str(_free_port())]
    server, url, said = _start(argv)
    driver = chromium(tmp_path / "chromium")
    try:
        driver.get(url)
        driver.execute_script(STALL)
        p = ScriptedParticipant(driver)
        p.watch()
        p.until(lambda phase: len(_rows(out)) == 1 and phase == "blank1")  # (2.5 s long)
        server.send_signal(signal.SIGINT)
        assert server.wait(30) == 128 + signal.SIGINT
        _said(said, "stopped at 0 of 2 trials answered")  # (the one row: flagged)
        _said(said, "jaxadapt: interrupted; every answer given is kept")
        server, url, said = _start(argv)
        assert p.until(lambda phase: phase == "done") == "done"  # (no reload)
        assert server.wait(30) == 0
    finally:
        driver.quit()
        if server.poll() is None:
            server.kill()
    rows = _rows(out)
    assert [(r["trial"], r["flagged"]) for r in rows] == [
        ("0", "true"),
        ("1", "false"),
        ("0", "false"),
    ]
    assert int(rows[0]["dropped_frames"]) >= 1 and float(rows[0]["image2_ms"]) > 100
