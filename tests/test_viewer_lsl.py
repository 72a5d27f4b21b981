"""``jaxadapt view --gaze-lsl``: a simulated eye tracker's Lab Streaming
Layer stream, on loopback, drives the frames' gaze: its path at each
frame's time on its own clock, its blinks and losses as gaps; the page
says so; a stream not found is one line and status 2."""

import asyncio
import math
import subprocess
import sys
import time
import uuid
from pathlib import Path

import aiohttp
import numpy as np
import pytest

from jaxadapt.cli import main
from jaxadapt.viewer import Server, Session, _lsl
from jaxadapt.viewer._simulation import Simulation
from jaxadapt.viewer.simulated_tracker import SimulatedTracker

#: The viewer's frames: pattanaik2000 (the gaze path is the operators'
#: same; it compiles in a third of jacobs2015's time).
SPEC = {"scene": "flash", "size": [32, 24], "operator": "pattanaik2000"}
W, H = SPEC["size"]
#: The schedule of the tracker's losses over each CYCLE seconds.
CYCLE = 2.0
LOSSES = {"blink": (0.25, 0.45), "gap": (0.55, 0.9), "doubt": (1.0, 1.2), "zeros": (1.25, 1.45)}
#: Where the path leaves the frame (x beyond its right edge), s of the cycle.
OFF = (1.6, 1.75)
#: Longest a sample takes from its time to a frame here, s: the tracker's
#: wait for its time, LSL on loopback, the reader, the server's loop
#: (measured: 11 ms at most on an idle 2-core machine, 48 ms with both cores
#: busy with other work; the median 3 and 5 ms).
LATENCY = 0.06
#: The noise of the tracker's x, y, normalised (0.06 px of 32).
NOISE = 0.002


def _loss(t):
    phase = t % CYCLE
    return next((kind for kind, (a, b) in LOSSES.items() if a <= phase < b), None)


def _path(t):
    """Once round the frame's centre each CYCLE s (30 px/s on 32 px), off it in OFF."""
    phase = 2 * math.pi * t / CYCLE
    off = OFF[0] <= t % CYCLE < OFF[1]
    return (1.25 if off else 0.5 + 0.3 * math.cos(phase)), 0.5 + 0.3 * math.sin(phase)


def _pixels(x, y):
    """Normalised x, y as frame pixels, as the reader maps them (span 1x1)."""
    return x * W - 0.5, y * H - 0.5


@pytest.fixture(scope="module")
def session():
    session = Session(SPEC)
    session.warm()
    return session


@pytest.fixture
def name():
    """A stream name of the test's own (LSL's streams are the machine's)."""
    return f"jaxadapt-test-{uuid.uuid4().hex[:12]}"


@pytest.mark.parametrize("offset", [0.0, 0.5, -0.5])
def test_the_frames_take_the_tracker_s_sample_of_their_time(session, name, offset, monkeypatch):
    """Each frame's gaze is the sample the tracker took at the frame's time
    (its newest: a few ms old), on a tracker clock ``offset`` s behind
    this machine's (which LSL's ``time_correction`` then reports, stood in
    for here: on one machine it reports 0); blinks (NaN), ``(0, 0)``,
    a confidence under 0.6 and a silence longer than GAP make the frames'
    gaze NaN, a shorter silence holds the last sample; a sample off the
    frame is clipped, and the terminal warned once and cleared."""
    if offset:
        monkeypatch.setattr(_lsl.load_pylsl().StreamInlet, "time_correction", _corrects(offset))
    tracker = SimulatedTracker(name, 200.0, _path, _loss, NOISE, clock_offset=offset)
    with tracker:
        opened = _lsl.open_tracker(name, timeout=5.0)
        frames, lines, hello = asyncio.run(_view(session, opened, seconds=2 * CYCLE))
    assert hello["trackers"] == 1 and hello["lsl"] == name
    log = np.array(tracker.log)  # (t on this machine's LSL clock, x, y, confidence)
    sent_at, sent = log[:, 0] - tracker.start_time, np.stack(_pixels(log[:, 1], log[:, 2]), -1)
    start = tracker.start_time + _lsl.clock_offset(_lsl.load_pylsl().local_clock)  # (server's)
    zones = {"tracked": [], "held": [], "off": [], **{kind: [] for kind in LOSSES}}
    for now, gaze in frames:
        t = now - start  # the frame's time since the tracker started
        if t < 0.2:
            continue  # (before the reader opened the stream)
        recent = {_loss(t - d) for d in np.linspace(0, LATENCY, 9)}
        phase = t % CYCLE
        since_gap = phase - LOSSES["gap"][0]  # (the last sample came 5 ms before)
        if recent == {None} and not OFF[0] - LATENCY <= phase < OFF[1] + LATENCY:
            zones["tracked"].append((t, gaze))
        elif OFF[0] + LATENCY <= phase < OFF[1]:
            zones["off"].append(gaze)
        elif _loss(t) == "gap" and since_gap < _lsl.GAP - 0.02:
            zones["held"].append(gaze)
        elif _loss(t) == "gap" and since_gap > _lsl.GAP + 0.01:
            zones["gap"].append(gaze)
        elif len(recent) == 1 and (kind := recent.pop()) not in (None, "gap"):
            zones[kind].append(gaze)
    assert {k: len(v) >= 5 for k, v in zones.items()} == dict.fromkeys(zones, True), {
        k: len(v) for k, v in zones.items()
    }
    ages = []
    for t, gaze in zones["tracked"]:
        match = np.flatnonzero(np.all(np.abs(sent - gaze) < 1e-3, -1))
        assert len(match) == 1, f"frame at {t:.3f} s: gaze {gaze} is no sample sent"
        ages.append(t - sent_at[match[0]])
    ages = np.array(ages)
    assert np.all(ages >= -1e-3) and np.median(ages) < 0.02, np.percentile(ages, [0, 50, 100])
    error = [math.dist(g, _pixels(*_path(t))) for t, g in zones["tracked"]]
    assert np.median(error) < 0.5  # 30 px/s for half a sample interval and more, the noise
    for kind in ("blink", "doubt", "zeros", "gap"):
        assert all(math.isnan(x) and math.isnan(y) for x, y in zones[kind]), kind
    assert all(math.isfinite(x) for x, _ in zones["held"])
    assert all(x == W - 1 for x, _ in zones["off"])
    warnings = [line for line in lines if "off the 32x24 frame" in line]
    assert 1 <= len(warnings) <= 2 and all(
        line.startswith(f"gaze-lsl {name!r}: warning: x, y:") for line in warnings
    ), lines
    assert any(line.startswith(f"gaze-lsl {name!r}: x, y: on the frame again") for line in lines)


def _corrects(offset):
    def time_correction(self, timeout=None):
        return offset

    return time_correction


async def _view(session, tracker, seconds):
    """Serve ``session`` with ``tracker`` and watch it as a page does for
    ``seconds``, its pointer at (3, 3) (to be ignored); the frames'
    ``(time.monotonic() at the frame, gaze)``, the terminal's lines and the
    page's hello."""
    frames, lines = [], []
    advance = session.advance

    def timed(dt, gaze, scene_index=None):
        now = time.monotonic()
        frame = advance(dt, gaze, scene_index)
        frames.append((now, frame.gaze))
        return frame

    session.advance = timed
    server = Server(session, report=lines.append, tracker=tracker)
    try:
        url = await server.start()
        async with aiohttp.ClientSession() as http:
            async with http.ws_connect(url.replace("http", "ws") + "ws") as ws:
                hello = await ws.receive_json()
                end = time.monotonic() + seconds
                while time.monotonic() < end:
                    msg = await asyncio.wait_for(ws.receive(), 10)
                    if msg.type == aiohttp.WSMsgType.BINARY:
                        await ws.send_json({"type": "ack"})
                        await ws.send_json({"type": "gaze", "x": 3, "y": 3})
    finally:
        await server.close()
        del session.advance
    return frames, lines, hello


def test_a_sample_holds_for_its_hold_and_frames_take_the_one_of_their_time():
    """:meth:`Simulation.look`: a frame takes the newest sample at or before
    its time (one that came late, out of order, included), none once it is
    older than its ``hold``; a pointer's sample holds until the next."""
    sim = Simulation(session=None, publish=None)
    sim.look((1.0, 1.0), "a", at=10.0, hold=0.1)
    sim.look((3.0, 3.0), "c", at=10.2, hold=0.1)
    sim.look((2.0, 2.0), "b", at=10.1, hold=0.1)  # (came last)
    with sim.cond:
        taken = [sim.gaze_at(t)[1] for t in (9.9, 10.0, 10.05, 10.1, 10.15, 10.21, 10.31)]
    assert taken == [None, "a", "a", "b", "b", "c", None]
    sim.look((4.0, 4.0), "pointer", at=11.0)
    with sim.cond:
        assert sim.gaze_at(1e6) == ((4.0, 4.0), "pointer")


def test_channels_come_from_the_gaze_meta_data_or_the_options():
    pylsl = _lsl.load_pylsl()
    info = pylsl.StreamInfo("t", "Gaze", 4, 60, pylsl.cf_float32, "t")
    info.set_channel_labels(["conf", "gx", "gy", "pupil"])
    info.set_channel_types(["Confidence", "ScreenX", "ScreenY", "Diameter"])
    assert _lsl.choose_channels(info) == (1, 2, 0)
    assert _lsl.choose_channels(info, ["gy", "gx"]) == (2, 1, None)
    assert _lsl.choose_channels(info, ["3", "2", "conf"]) == (3, 2, 0)
    with pytest.raises(ValueError, match=r"^--gaze-lsl-channels: expected labels of 't'"):
        _lsl.choose_channels(info, ["gx", "4"])
    bare = pylsl.StreamInfo("b", "Gaze", 2, 60, pylsl.cf_float32, "b")
    assert _lsl.choose_channels(bare) == (0, 1, None)


def test_lost_samples_are_nan_and_the_rest_frame_pixels():
    """Screen pixels of 1280x720 (``--gaze-lsl-span``) onto a 32x24 frame:
    the screen's edges are the frame's outer edges, -0.5 to 31.5 and 23.5."""
    samples = np.array(
        [
            [0.0, 720.0, 0.9],  # the left edge, the bottom edge
            [0.0, 0.0, 0.9],  # "no data"
            [np.nan, 300.0, 0.9],
            [np.inf, 300.0, 0.9],
            [400.0, 300.0, np.nan],  # no confidence: none taken
            [400.0, 300.0, 0.59],
            [640.0, 360.0, 0.6],
        ]
    )
    points = _lsl.frame_points(samples, (0, 1, 2), (1280, 720), 0.6, (24, 32))
    lost = np.isnan(points).all(-1)
    assert lost.tolist() == [False, True, True, True, True, True, False]
    np.testing.assert_array_equal(points[[0, 6]], [[-0.5, 23.5], [15.5, 11.5]])
    overflow = _lsl.frame_points(np.array([[1e308, 0.5]]), (0, 1, None), (1, 1), 0.6, (24, 32))
    assert np.isnan(overflow).all()  # (beyond float64 once scaled)


def test_the_page_says_the_tracker_drives_the_gaze(session, name, tmp_path):
    from browsers import chromium
    from test_viewer import _serve, _until

    with SimulatedTracker(name):
        server, url, close = _serve(session, None, tracker=_lsl.open_tracker(name))
        driver = chromium(tmp_path)
        try:
            driver.get(url)
            status = driver.find_element("id", "status")
            said = f'the eye tracker of LSL stream "{name}" drives the gaze: the pointer is ignored'
            _until(lambda: status.text == said, lambda: f"the page told: {status.text!r}")
            _until(lambda: driver.execute_script("return window.jaxadapt.frames") > 3, "frames")
        finally:
            driver.quit()
            close()


@pytest.mark.parametrize(
    "argv, says",
    [
        (["--gaze-lsl-span", "2x2"], "--gaze-lsl-span: applies with --gaze-lsl NAME"),
        (["--gaze-lsl-confidence", "0.5"], "--gaze-lsl-confidence: applies with --gaze-lsl"),
        (["--gaze-lsl", "x", "--gaze-lsl-span", "0x1"], "argument --gaze-lsl-span: expected"),
        (["--gaze-lsl", "x", "--gaze-lsl-channels", "a"], "expected X,Y or X,Y,CONFIDENCE"),
        (["--gaze-lsl", "x", "--gaze-lsl-confidence", "2"], "expected a number from 0 to 1"),
    ],
)
def test_option_errors_are_one_line_and_status_2(argv, says, capsys):
    try:
        status = main(["view", "--no-browser", *argv])
    except SystemExit as exit:
        status = exit.code
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and says in err, err


def test_without_pylsl_the_option_says_what_installs_it(monkeypatch):
    monkeypatch.setattr(_lsl, "_pylsl", None)
    monkeypatch.setitem(sys.modules, "pylsl", None)  # (its import then fails)
    expected = r"^--gaze-lsl: expected pylsl, which the lsl extra installs \(pip install "
    with pytest.raises(ValueError, match=expected + r"'jaxadapt\[lsl\]'\), got \w+Error: "):
        _lsl.open_tracker("any")


def test_a_stream_not_found_is_one_line_status_2_and_nothing_written(tmp_path):
    """As a user runs it: only the one line on stderr (liblsl's own log of
    its start kept quiet), and no record."""
    record, name = tmp_path / "record", f"jaxadapt-test-missing-{uuid.uuid4().hex[:8]}"
    argv = ["view", "--no-browser", "--scene", "flash", "--size", "32x24", "--record", str(record)]
    result = subprocess.run(
        [sys.executable, "-m", "jaxadapt", *argv, "--gaze-lsl", name, "--gaze-lsl-timeout", "0.5"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert result.returncode == 2 and result.stdout == "", result
    assert result.stderr.startswith(
        f"jaxadapt: error: --gaze-lsl: expected an LSL stream named {name!r} (an eye "
        "tracker's), found none in 0.5 s; streams seen: "
    )
    assert result.stderr.count("\n") == 1, result.stderr
    assert not record.exists() and list(tmp_path.iterdir()) == []
    assert Path(_lsl.__file__).with_name("lsl_api.cfg").is_file()
