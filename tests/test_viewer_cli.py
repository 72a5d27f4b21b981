"""``jaxadapt view`` without a browser: its option errors, Ctrl-C, the
simulation's clock, the record and its replay, and the server's guards."""

import asyncio
import contextlib
import json
import math
import signal
import socket
import subprocess
import time
import warnings
from pathlib import Path

import aiohttp
import jax
import numpy as np
import processes
import pytest
from PIL import Image

from jaxadapt._signals import interrupted_message
from jaxadapt.cli import main
from jaxadapt.gaze import read_gaze_csv, write_gaze_csv
from jaxadapt.viewer import (
    FIRST_DT,
    MAX_DT,
    Recorder,
    Server,
    Session,
    _messages,
    _server,
    _simulation,
    read_record,
    replay,
)
from jaxadapt.viewer._session import FRAME_COLUMNS, open_source
from jaxadapt.viewer._simulation import Simulation

SMALL = {"scene": "flash", "size": [32, 24]}
SMALL_ARGS = ["--scene", "flash", "--size", "32x24"]


@pytest.mark.parametrize(
    "argv, says",
    [
        (["--port", "70000"], "argument --port: expected a port from 0 to 65535"),
        (["--size", "1x5"], "argument --size: expected a size of at least 2x2"),
        (["--operator", "reinhard"], "argument --operator: invalid choice"),
        (["x.exr", "--scene", "flash"], "--scene: applies when no FILE is given"),
        (["--fps", "30"], "--fps: applies to FILE input"),
        (["--operator", "pattanaik2000", "--seed", "3"], "--seed: applies to --operator jacobs"),
        (["--operator", "pattanaik2000", "--off", "acuity"], "--off: applies to --operator"),
        (["--off", "blur"], "argument --off: invalid choice"),
        (["missing.exr"], "FILE: missing.exr: no such file"),
        (["--multiplier", "-1"], "argument --multiplier: expected a positive number"),
    ],
)
def test_option_errors_are_one_line_and_status_2(argv, says, capsys):
    assert _status(["view", "--no-browser", *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and says in err, err


def _status(argv):
    """The exit status of ``jaxadapt ARGV`` run here (the parser's errors exit)."""
    try:
        return main(argv)
    except SystemExit as exit:
        return exit.code


def test_a_recorded_folder_is_not_overwritten(tmp_path, capsys):
    (tmp_path / "session.json").write_text("{}")
    assert main(["view", "--no-browser", "--record", str(tmp_path)]) == 2
    assert "--record:" in capsys.readouterr().err
    assert (tmp_path / "session.json").read_text() == "{}"


@pytest.mark.parametrize("given", ["afile", "afile/x"])
def test_a_record_or_replay_in_a_file_is_one_line(given, tmp_path, capsys):
    """A file where --record or --replay wants a folder is said before
    anything is compiled, not left to the OS's error after compiling."""
    (tmp_path / "afile").write_text("kept")
    path = tmp_path / given
    assert _status(["view", "--no-browser", *SMALL_ARGS, "--record", str(path)]) == 2
    assert _status(["render", "--replay", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.splitlines()
    wrong = (
        f"expected a folder, got the file {path}"
        if given == "afile"
        else (f"expected a folder, got {path}, under the file {tmp_path / 'afile'}")
    )
    assert err == [f"jaxadapt: error: --record: {wrong}", f"jaxadapt: error: --replay: {wrong}"]
    assert (tmp_path / "afile").read_text() == "kept" and not (tmp_path / "o").exists()


def test_a_port_in_use_is_one_line(capsys):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        argv = ["view", "--no-browser", "--scene", "flash", "--size", "32x24", "--port", str(port)]
        assert main(argv) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[-1].startswith("jaxadapt: error: --host, --port: cannot listen on 127.0.0.1")


def test_write_gaze_csv_round_trips_through_read_gaze_csv(tmp_path):
    times = np.array([0.0, 1 / 3, 0.7000000000000001])
    points = np.array([[1 / 7, 2.5], [np.nan, np.nan], [3.0, 1e-9]])
    write_gaze_csv(tmp_path / "g.csv", times, points)
    t, p = read_gaze_csv(tmp_path / "g.csv")
    assert t.tolist() == times.tolist()
    np.testing.assert_array_equal(p, points)  # NaN where NaN, the rest bit for bit


@pytest.mark.parametrize("operator", ["jacobs2015", "pattanaik2000"])
def test_replay_gives_the_recorded_frames_exactly(operator, tmp_path):
    """Frames of varying ``dt`` and gaze, a blink, an effect switched and a
    reset: :func:`replay` makes every one again, bit for bit."""
    session = Session({**SMALL, "operator": operator})
    record = tmp_path / "record"
    recorder = Recorder(record, session.spec)
    rng = np.random.default_rng(0)
    shown = []
    for k in range(14):
        if k == 5 and session.available_effects:
            session.toggle("acuity", False)
        if k == 9:
            session.reset()
        gaze = (math.nan, math.nan) if k == 3 else tuple(rng.uniform(0, 30, 2))
        frame = session.advance(float(rng.uniform(0.005, MAX_DT)), gaze)
        recorder.write(frame)
        shown.append(frame.pixels)
    recorder.close()
    again = list(replay(record))
    assert len(again) == len(shown)
    for live, replayed in zip(shown, again, strict=True):
        np.testing.assert_array_equal(replayed.pixels, live)
    spec, rows = read_record(record)
    assert spec["complete"] and spec["frames"] == 14 and rows[9]["reset"]
    times, points = read_gaze_csv(record / "gaze.csv")
    assert np.all(np.diff(times) > 0) and np.isnan(points[3]).all()
    # The command line's replay writes the same frames, read back from its PNGs
    out = tmp_path / "out"
    assert main(["render", "--replay", str(record), "--out", str(out), "--format", "png"]) == 0
    written = [np.asarray(Image.open(out / f"frame_{k:05d}.png")) for k in range(len(shown))]
    for live, png in zip(shown, written, strict=True):
        np.testing.assert_array_equal(png, live)
    diagnostics = np.genfromtxt(out / "diagnostics.csv", delimiter=",", names=True)
    np.testing.assert_allclose(diagnostics["dt"], [r["dt"] for r in rows], rtol=1e-5)
    assert np.isnan(diagnostics["gaze_x"][3]) and np.all(diagnostics["adaptation"] > 0)
    assert {p.name for p in out.iterdir()} >= {"contact_sheet.png", "adaptation.png"}


@pytest.mark.parametrize(
    "argv, says",
    [
        (["--scene", "flash"], "--scene: does not apply with --replay"),
        (["x.exr"], "FILE: does not apply with --replay"),
        (["--operator", "jacobs2015"], "--operator: does not apply with --replay"),
        (["--chunk", "4"], "--chunk: does not apply with --replay"),
        (["--format", "exr"], "--format: a replay writes the viewer's 8-bit frames"),
    ],
)
def test_replay_options_the_record_fixes_are_refused(argv, says, tmp_path, capsys):
    session = Session(SMALL)
    with contextlib.closing(Recorder(tmp_path / "record", session.spec)) as recorder:
        recorder.write(session.advance(FIRST_DT, (5.0, 5.0)))
    out = tmp_path / "out"
    assert _status(["render", "--replay", str(tmp_path / "record"), *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and says in err, err
    assert not out.exists()


def test_replay_of_a_folder_without_a_record_is_one_line(tmp_path, capsys):
    assert _status(["render", "--replay", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxadapt: error: --replay: expected a folder recorded by jaxadapt view")
    assert err.count("\n") == 1 and "session.json: no such file" in err


@pytest.fixture
def recorded(tmp_path):
    """A record of SMALL's first 3 frames (the second a blink), in ``tmp_path/record``."""
    session = Session(SMALL)
    with contextlib.closing(Recorder(tmp_path / "record", session.spec)) as recorder:
        for gaze in ((5.0, 5.0), (math.nan, math.nan), (9.0, 4.0)):
            recorder.write(session.advance(FIRST_DT, gaze))
    return tmp_path / "record"


def _damage(path, file, change):
    """Edit the record in ``path``: set fields of ``session.json`` (a dict),
    write it (text), or set a cell of ``frames.csv`` ((row as a spreadsheet
    counts, column, value))."""
    if isinstance(change, dict):
        spec = json.loads((path / file).read_text())
        (path / file).write_text(json.dumps({**spec, **change}))
    elif isinstance(change, str):
        (path / file).write_text(change)
    else:
        row, column, value = change
        lines = (path / file).read_text().splitlines()
        cells = lines[row - 1].split(",")
        cells[FRAME_COLUMNS.index(column)] = value
        lines[row - 1] = ",".join(cells)
        (path / file).write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize(
    "file, change, says",
    [
        ("session.json", {"scene": "nope"}, "scene: expected one of checkerboard, flash, "),
        ("session.json", {"operator": "nope"}, "operator: expected one of jacobs2015, pattanaik"),
        ("session.json", {"seed": "x"}, "seed: expected a whole number >= 0, got 'x'"),
        ("session.json", {"size": "abc"}, "size: expected [width, height] in pixels, got 'abc'"),
        ("session.json", {"pixels_per_degree": -1}, "pixels_per_degree: expected > 0, got -1"),
        ("session.json", {"effects": ["blur"]}, "effects: expected a list of bleaching, "),
        ("session.json", "{", "expected a JSON object, got text that is not JSON (Expecting"),
        ("frames.csv", (3, "scene_index", "99999"), "row 3: scene_index: expected an input frame "
            "from 0 to 121, got 99999"),
        ("frames.csv", (2, "dt", "abc"), "row 2: dt: expected seconds > 0, got 'abc'"),
        ("frames.csv", (4, "x", "abc"), "row 4: x: expected pixels (empty in a blink), got 'abc'"),
        ("frames.csv", (2, "reset", "yes"), "row 2: reset: expected 0 or 1, got 'yes'"),
        ("frames.csv", (3, "effects", "blur"), "row 3: effects: expected names of bleaching, "),
        ("frames.csv", (2, "digest", "x,y"), "row 2: expected 9 cells, got 10"),
        ("frames.csv", (1, "frame", "n"), "row 1: expected the columns frame,t,dt,x,y,scene_index"),
        ("frames.csv", (3, "frame", "2"), "row 3: frame: expected frame 1, the one after frame 0, "
            "got 2 (rows removed or reordered"),
        ("frames.csv", (2, "frame", "1"), "row 2: frame: expected frame 0, the one after the "
            "header, got 1"),
    ],
)  # fmt: skip
def test_a_damaged_record_is_one_line(file, change, says, recorded, tmp_path, capsys):
    """A record edited by hand or damaged: one line that names --replay DIR,
    the file, its row or field, what was expected and what came; status 2,
    and no traceback or error that names none of them."""
    _damage(recorded, file, change)
    out = tmp_path / "out"
    assert _status(["render", "--replay", str(recorded), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert err.startswith(f"jaxadapt: error: --replay: {recorded / file}"), err
    assert says in err, err
    assert not out.exists()


def test_a_record_with_a_row_removed_names_the_first_gap(recorded, tmp_path, capsys):
    """Rows deleted from frames.csv: a replay of the rest could only give
    other frames, so it is refused, naming the first gap."""
    lines = (recorded / "frames.csv").read_text().splitlines(keepends=True)
    (recorded / "frames.csv").write_text("".join(lines[:2] + lines[3:]))
    assert _status(["render", "--replay", str(recorded), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"jaxadapt: error: --replay: {recorded / 'frames.csv'}, row 3: frame: expected frame 1, "
        "the one after frame 0, got 2 (rows removed or reordered: a replay needs every frame "
        "in order)\n"
    )
    assert not (tmp_path / "o").exists()


def test_a_last_row_cut_short_is_left_out_with_a_warning(recorded, tmp_path, capsys):
    """A view killed while writing a row leaves it cut short: the replay
    warns and leaves it out; a last row without its line end alone is kept;
    a row cut short before the last is an error. The rows end with LF."""
    text = (recorded / "frames.csv").read_bytes()
    assert b"\r" not in text and text.count(b"\n") == 4
    (recorded / "frames.csv").write_bytes(text[:-1])  # its line end only: kept
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(read_record(recorded)[1]) == 3
    (recorded / "frames.csv").write_bytes(text[:-30])
    with pytest.warns(UserWarning, match=r"frames.csv, row 4: cut short"):
        assert [row["frame"] for row in read_record(recorded)[1]] == [0, 1]
    out = tmp_path / "out"
    argv = ["render", "--replay", str(recorded), "--out", str(out), "--format", "png"]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert f"warning: --replay: {recorded}/frames.csv, row 4: cut short" in err, err
    assert sorted(p.name for p in out.glob("frame_*")) == ["frame_00000.png", "frame_00001.png"]
    (recorded / "frames.csv").write_bytes(text[:-30] + b"\n" + text[-30:])
    assert _status([*argv[:4], str(tmp_path / "o2")]) == 2
    assert "frames.csv, row 4: expected 9 cells, got " in capsys.readouterr().err


def test_an_interrupted_view_says_what_it_did_not_write():
    """view has no --out: interrupted while it starts, it says so, and that
    nothing is in --record where given."""
    assert interrupted_message(["view", "--port", "0"]) == "jaxadapt: interrupted while starting"
    assert interrupted_message(["view", "--record=r"]).endswith("; nothing was written to --record")
    assert interrupted_message(["render", "--out", "view"]).endswith("written to --out")


def _wait_for_signals_taken(pid, timeout=60.0):
    """Wait until process ``pid`` handles SIGTERM, as the program does from
    its first instruction (Python alone handles SIGINT only): a signal sent
    before would meet the interpreter's start, not the program. Without
    /proc, a fixed half second."""
    status = Path(f"/proc/{pid}/status")
    if not status.exists():
        time.sleep(0.5)
        return
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        caught = next(
            (
                int(line.split()[1], 16)
                for line in status.read_text().splitlines()
                if line.startswith("SigCgt:")
            ),
            0,
        )
        if caught >> (signal.SIGTERM - 1) & 1:
            return
        time.sleep(0.005)
    raise AssertionError(f"process {pid} took no signals in {timeout} s")


@pytest.mark.parametrize("when", ["importing", pytest.param("compiling", marks=pytest.mark.slow)])
def test_ctrl_c_while_the_view_starts_is_130_and_records_nothing(when, tmp_path):
    """Sent while the program imports JAX, or while it compiles (a signal
    then waits for the compile): one line that does not speak of --out
    (view has none), status 130, and no record."""
    record = tmp_path / "record"
    process = processes.python(
        ["-m", "jaxadapt", "view", "--no-browser", "--port", "0", *SMALL_ARGS]
        + ["--record", str(record)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        if when == "importing":
            _wait_for_signals_taken(process.pid)
        else:
            assert process.stderr.readline().startswith("compiling jacobs2015")
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=120)
    finally:
        process.kill()
    assert process.returncode == 128 + signal.SIGINT, err
    assert err.splitlines()[-1:] == [
        "jaxadapt: interrupted while starting; nothing was written to --record"
    ]
    assert "Traceback" not in err and not out and not record.exists()


def test_files_are_shrunk_to_fit_and_played_in_a_loop(tmp_path):
    """Two PFM frames of 64x48 at 2 frames/s, viewed at 32x32: shrunk to
    32x24 (aspect kept, in linear light: a uniform frame keeps its value),
    their 30 pixels per degree halved, the sequence repeated every 1 s."""
    from jaxadapt import io

    paths = [tmp_path / f"f{i}.pfm" for i in range(2)]
    for i, path in enumerate(paths):
        io.write_image(path, np.full((48, 64, 3), 10.0 * (i + 1), np.float32))
    spec = {"files": [str(p) for p in paths], "fps": 2.0, "size": [32, 32]}
    assert open_source(spec)[1] == 15.0
    session = Session({**spec, "pixels_per_degree": 3.2})  # SMALL's: its compiled step
    assert session.shape == (24, 32)
    assert [session.scene_index(t) for t in (0.0, 0.6, 1.2, 1.7)] == [0, 1, 0, 1]
    np.testing.assert_allclose(session._input(1), 20.0, rtol=1e-6)
    frame = session.advance(0.1, (5.0, 5.0))
    assert frame.pixels.shape == (24, 32, 3) and frame.adaptation >= 100.0


def test_each_frame_advances_by_the_time_measured_and_clamped():
    """dt is the wall-clock time since the last frame; the first one, and the
    first after a pause, last :data:`FIRST_DT`; a gap (a sleeping tab)
    counts at most :data:`MAX_DT`."""
    published = []
    session = Session(SMALL)
    session.warm()  # (a compile in the first frame would count in the second's dt)
    sim = Simulation(session, lambda header, jpeg: published.append(header))
    sim.start()

    def frame_after(gap):
        time.sleep(gap)
        count = len(published)
        sim.want()
        while len(published) == count:
            time.sleep(0.001)
        return published[-1]["dt"]

    try:
        assert frame_after(0) == FIRST_DT
        assert 0.1 <= frame_after(0.1) < 0.1 + 0.1  # + a frame's work and a wake-up
        assert frame_after(0.6) == MAX_DT
        sim.command("pause", True)
        sim.command("pause", False)
        assert frame_after(0.3) == FIRST_DT
    finally:
        sim.stop()
        sim.join(10)


def test_a_machine_too_slow_for_real_time_says_so_and_when_it_keeps_up(monkeypatch):
    """Frames whose work takes longer than MAX_DT advance the simulation by
    MAX_DT only: from the second in a row, the frames' headers and the
    terminal (once) say how slow and how far behind; two frames in time
    clear it, and the terminal says so (once)."""
    monkeypatch.setattr(_simulation, "MAX_DT", 0.1)
    session = Session(SMALL)
    session.warm()
    lines = []
    headers = asyncio.run(_slowed(session, lines.append))
    assert [h["dt"] for h in headers[1:6]] == [0.1] * 5  # the work of frames 0 to 4
    slow = [h for h in headers if h["slow"]]
    assert [h["frame"] for h in slow] == [2, 3, 4, 5, 6]  # the second late, to 2 in time
    assert 0.15 <= slow[0]["slow"]["frame_time"] < 0.6 and slow[0]["slow"]["max_dt"] == 0.1
    assert slow[-1]["lag"] > slow[0]["lag"] >= 0.1  # two frames, each 0.05 s or more behind
    assert headers[-1]["slow"] is None and headers[-1]["lag"] == slow[-1]["lag"]
    assert len(lines) == 2, lines
    assert lines[0].startswith("warning: simulated time runs slower than the wall clock: a frame")
    assert "MAX_DT = 0.1 s, so it runs at " in lines[0] and "s behind so far" in lines[0]
    assert lines[1].startswith("simulated time keeps up with the wall clock again (")


async def _slowed(session, report):
    """Watch frames as a page does: 5 frames whose work takes 0.15 s, then
    frames at the machine's pace until 3 after the slow flag is gone."""
    advance, slowed = session.advance, [5]

    def slow_advance(*args):
        if slowed[0] > 0:
            slowed[0] -= 1
            time.sleep(0.15)
        return advance(*args)

    session.advance = slow_advance
    server = Server(session, report=report)
    url = await server.start()
    headers = []
    try:
        async with aiohttp.ClientSession() as http:
            async with http.ws_connect(url.replace("http", "ws") + "ws") as ws:
                while len(headers) < 40 and sum(not h["slow"] for h in headers[5:]) < 3:
                    msg = await asyncio.wait_for(ws.receive(), 30)
                    if msg.type == aiohttp.WSMsgType.BINARY:
                        length = int.from_bytes(msg.data[:4], "big")
                        headers.append(json.loads(msg.data[4 : 4 + length]))
                        await ws.send_json({"type": "ack"})
    finally:
        await server.close()
    return headers


def test_guards_token_host_origin_paths_and_clients(monkeypatch):
    """With a token every request needs it; a foreign Host or Origin is
    refused; no path reaches the file system; pages beyond the limit are
    refused with a message."""
    monkeypatch.setattr(_server, "MAX_CLIENTS", 1)
    statuses = asyncio.run(_probe(Session(SMALL)))
    assert statuses == {
        "no token": 403,
        "token": 200,
        "script": 200,
        "script, foreign origin": 403,
        "state": 200,
        "traversal": 404,
        "foreign host": 403,
        "foreign origin": 403,
        "second page": "at most 1 pages",
    }


async def _probe(session):
    server = Server(session, token="s3cret")
    url = await server.start()
    base, statuses = url.split("?")[0], {}
    try:
        async with aiohttp.ClientSession() as http:
            for case, path, headers in (
                ("no token", "", {}),
                ("token", "?token=s3cret", {}),
                ("state", "state?token=s3cret", {}),
                ("script", "viewer.js", {}),  # the page's, loaded without the token
                ("script, foreign origin", "viewer.js", {"Origin": "http://evil.example"}),
                ("traversal", "..%2f..%2fetc%2fpasswd?token=s3cret", {}),
                ("foreign origin", "?token=s3cret", {"Origin": "http://evil.example"}),
            ):
                async with http.get(base + path, headers=headers) as response:
                    statuses[case] = response.status
            ws_url = url.replace("http", "ws").replace("/?", "/ws?")
            async with http.ws_connect(ws_url) as first:
                await first.receive_json()
                async with http.ws_connect(ws_url) as second:
                    statuses["second page"] = (await second.receive_json())["message"]
    finally:
        await server.close()
    plain = Server(session)
    url = await plain.start()
    try:
        async with aiohttp.ClientSession() as http:
            async with http.get(url, headers={"Host": f"evil.example:{plain.port}"}) as r:
                statuses["foreign host"] = r.status
    finally:
        await plain.close()
    return statuses


def test_a_request_without_host_is_a_400_and_port_80_takes_a_bare_host(caplog):
    """A request with no Host (curl -H 'Host:') is a 400 and no traceback on
    the terminal; an empty Host is refused naming what was expected; on port
    80 a browser's ``Host: localhost`` (no port) and its Origin are the
    server's own."""
    replies = asyncio.run(_hosts(Session(SMALL)))
    assert replies["no Host"].split()[1] == b"400" and b"Host" in replies["no Host"]
    assert not [r for r in caplog.records if r.exc_info], [r.getMessage() for r in caplog.records]
    empty = replies["empty Host"]
    assert empty.startswith(b"HTTP/1.1 403") and b"Host: expected 127.0.0.1:" in empty
    assert empty.endswith(b"got ''\n")
    assert replies["localhost, port 80"] == replies["origin, port 80"] == 200
    assert replies["localhost:8765, port 80"] == replies["evil.example, port 80"] == 403


async def _hosts(session):
    server = Server(session)
    await server.start()
    port, replies = server.port, {}
    try:
        for case, host in (("no Host", None), ("empty Host", "")):
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            line = "" if host is None else f"Host: {host}\r\n"
            writer.write(f"GET /state HTTP/1.1\r\n{line}Connection: close\r\n\r\n".encode())
            replies[case] = await asyncio.wait_for(reader.read(), 10)
            writer.close()
        server.port = 80  # (as bound to port 80, which a test cannot bind)
        async with aiohttp.ClientSession() as http:
            for case, headers in (
                ("localhost, port 80", {"Host": "localhost"}),
                ("origin, port 80", {"Host": "localhost", "Origin": "http://localhost"}),
                ("localhost:8765, port 80", {"Host": "localhost:8765"}),
                ("evil.example, port 80", {"Host": "evil.example"}),
            ):
                async with http.get(f"http://127.0.0.1:{port}/state", headers=headers) as r:
                    replies[case] = r.status
    finally:
        server.port = port
        await server.close()
    return replies


def test_a_tracker_s_bad_lines_get_errors_and_its_warnings_a_rate(monkeypatch):
    """On /gaze, every bad line gets a JSON error and the socket stays (one
    too long, one nested too deeply to parse, an id that is no id); a flood of samples
    off the frame gets one warning per interval, then one saying how many
    went unsaid, and a ``clear`` once the samples are on the frame again;
    the frame reaches the pixels' outer edges (-0.5 to W - 0.5)."""
    monkeypatch.setattr(_messages, "WARNING_INTERVAL", 0.3)
    replies = asyncio.run(_track(Session(SMALL)))
    too_long, nested, bad_id, first, flood_over, later, clear, edge = replies
    assert too_long == {
        "type": "error",
        "message": "expected messages of at most 65536 bytes, got 100000; left unread",
    }
    assert nested["type"] == "error" and "nested too deeply to read" in nested["message"]
    assert bad_id["type"] == "error" and bad_id["message"].startswith("id: expected a number")
    assert first["type"] == "warning" and "off the 32x24 frame (-0.5 to 31.5" in first["message"]
    assert flood_over == []  # the 1999 after the first, within the interval
    assert later["type"] == "warning" and "(1999 more left unsaid in the last" in later["message"]
    assert clear == {"type": "clear", "message": "x, y: on the frame again"}
    assert edge == {"gaze": [31.0, 0.0], "messages": []}


async def _track(session):
    server = Server(session)
    url = await server.start()
    replies = []

    async def received(ws, wait=0.1):
        found = []
        with contextlib.suppress(asyncio.TimeoutError):
            while True:
                found.append(await asyncio.wait_for(ws.receive_json(), wait))
        return found

    try:
        async with aiohttp.ClientSession() as http:
            async with http.ws_connect(url.replace("http", "ws") + "gaze") as ws:
                for line in ("[" * 100000, "[" * 50000, '{"x": 1, "y": 2, "id": [[1]]}'):
                    await ws.send_str(line)
                    replies.append(await asyncio.wait_for(ws.receive_json(), 10))
                off = '{"t": 0, "x": 40, "y": 3}\n'
                await ws.send_str(off * 2000)
                replies.append(await asyncio.wait_for(ws.receive_json(), 10))
                replies.append(await received(ws))
                await asyncio.sleep(0.3)
                await ws.send_str(off)
                replies.append(await asyncio.wait_for(ws.receive_json(), 10))
                await ws.send_str('{"t": 1, "x": 5, "y": 5}')
                replies.append(await asyncio.wait_for(ws.receive_json(), 10))
                await ws.send_str('{"t": 2, "x": 31.5, "y": -0.5}')
                messages = await received(ws, 0.3)
                async with http.get(url + "state") as response:
                    replies.append({"gaze": (await response.json())["gaze"], "messages": messages})
    finally:
        await server.close()
    return replies


def test_bound_to_every_address_the_urls_are_the_machine_s():
    """0.0.0.0 is no address a browser can open: the URLs are the machine's
    name, then its addresses, loopback's last, each with the token."""
    server = Server(Session(SMALL), host="0.0.0.0", token="s3cret")
    server.port = 8765
    urls = server.urls()
    hosts = [u.removeprefix("http://").removesuffix(":8765/?token=s3cret") for u in urls]
    assert hosts[0] == socket.gethostname() and hosts[-1] == "127.0.0.1"
    assert "0.0.0.0" not in hosts and len(set(hosts)) == len(hosts)
    assert [u.removeprefix("http://") for u in Server(Session(SMALL), host="::1").urls()] == [
        "[::1]:0/"
    ]


@pytest.mark.slow
def test_ctrl_c_stops_cleanly_with_the_record_complete(tmp_path):
    record = tmp_path / "record"
    process = processes.python(
        ["-m", "jaxadapt", "view", "--no-browser", "--port", "0"]
        + ["--scene", "flash", "--size", "48x32", "--record", str(record)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = process.stdout.readline()
        assert "serving http://127.0.0.1:" in line, process.stderr.read()
        url = line.split()[3]
        frames = asyncio.run(_watch(url, 1.0))
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=60)
    finally:
        process.kill()
    assert process.returncode == 0, err
    assert out.splitlines()[-1] == f"recorded {len(read_record(record)[1])} frames in {record}/"
    spec, rows = read_record(record)
    assert spec["complete"] and spec["frames"] == len(rows) >= frames > 5
    assert sorted(p.name for p in record.iterdir()) == ["frames.csv", "gaze.csv", "session.json"]
    assert len(read_gaze_csv(record / "gaze.csv")[0]) == len(rows)
    with jax.enable_x64(False):  # as the command line ran (tests/conftest.py enables it)
        assert [f.digest for f in replay(record)] == [r["digest"] for r in rows]


async def _watch(url, seconds):
    """Watch the page's stream for ``seconds`` as a page does (acknowledging
    each frame); the frames received."""
    frames = 0
    async with aiohttp.ClientSession() as http:
        async with http.ws_connect(url.replace("http", "ws") + "ws") as ws:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                msg = await asyncio.wait_for(ws.receive(), 30)
                if msg.type == aiohttp.WSMsgType.BINARY:
                    frames += 1
                    await ws.send_json({"type": "ack"})
                    await ws.send_json({"type": "gaze", "x": frames % 40, "y": 10, "id": frames})
    return frames


def test_frame_messages_carry_their_header():
    header = {"frame": 3, "gaze_id": 7}
    message = _messages.frame_message(header, b"\xff\xd8jpeg")
    length = int.from_bytes(message[:4], "big")
    assert (
        json.loads(message[4 : 4 + length]) == header and message[4 + length :] == b"\xff\xd8jpeg"
    )
