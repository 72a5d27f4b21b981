"""The live viewer (jaxadapt.viewer) driven in a real browser: Debian's
headless Chromium through selenium, one browser and one server for the
module. The server records the session, and the last test replays it."""

import asyncio
import base64
import contextlib
import hashlib
import io
import json
import math
import os
import queue
import socket
import threading
import time
import urllib.error
import urllib.request
from types import SimpleNamespace

import aiohttp
import numpy as np
import pytest
from browsers import chromium
from PIL import Image

from jaxadapt.cli import main
from jaxadapt.gaze import read_gaze_csv
from jaxadapt.viewer import Recorder, Server, Session, read_record, replay
from jaxadapt.viewer._server import WINDOW

#: The flash scene, small: a 1e7 cd/m2 disk of 1.5 degrees at the centre, 12.8 px/deg.
W, H = 128, 96


def _serve(session, record, **options):
    """A :class:`Server` of ``session`` (``options``: its host, token) in a
    thread of its own; returns it, its URL and a function that stops it
    (its record, where one is made, then complete)."""
    ready, stop = queue.Queue(), threading.Event()

    async def main():
        server = Server(session, **options)
        url = await server.start(record and (lambda: Recorder(record, session.spec)))
        ready.put((server, url))
        while not stop.is_set():
            await asyncio.sleep(0.05)
        await server.close()

    thread = threading.Thread(target=asyncio.run, args=(main(),), daemon=True)
    thread.start()
    server, url = ready.get(timeout=120)

    def close():
        stop.set()
        thread.join(60)

    return server, url, close


@pytest.fixture(scope="module")
def viewer(tmp_path_factory):
    session = Session({"scene": "flash", "size": [W, H]})
    session.warm()
    record = tmp_path_factory.mktemp("viewer") / "record"
    server, url, close = _serve(session, record)
    yield SimpleNamespace(server=server, url=url, record=record, close=close)
    close()


@pytest.fixture(scope="module")
def browser(viewer, tmp_path_factory):
    driver = chromium(tmp_path_factory.mktemp("chromium"))
    driver.get(viewer.url)
    _until(lambda: driver.execute_script("return window.jaxadapt.frames") > 3, "frames")
    yield driver
    driver.quit()


@pytest.fixture(scope="module")
def remote(browser):
    """A second server, as ``--host 0.0.0.0`` serves it (a token in its URLs),
    of pattanaik2000, whose page switches no effects."""
    session = Session({"scene": "patches", "size": [64, 36], "operator": "pattanaik2000"})
    server, url, close = _serve(session, None, host="0.0.0.0", token="s3cret-t0ken")
    yield SimpleNamespace(server=server, url=url)
    close()


@contextlib.contextmanager
def _new_window(browser, url):
    """Open ``url`` in a second window of ``browser`` (the first one's page
    stays open and visible) until the block ends."""
    first = browser.current_window_handle
    browser.switch_to.new_window("window")
    try:
        browser.get(url)
        yield
    finally:
        browser.close()
        browser.switch_to.window(first)


def _until(condition, what, timeout=20.0):
    """Wait until ``condition()`` holds; its last value."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = condition()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what() if callable(what) else what}")


def _state(viewer):
    with urllib.request.urlopen(viewer.url + "state", timeout=5) as response:
        return json.load(response)


def _point(browser, x, y):
    """Move the pointer to frame pixel ``(x, y)`` of the canvas."""
    _point_scaled(browser, x, y, W, H)


def _point_scaled(browser, x, y, W, H):
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    canvas = browser.find_element(By.ID, "view")
    scale = canvas.size["width"] / W
    dx, dy = (x + 0.5 - W / 2) * scale, (y + 0.5 - H / 2) * scale  # from the centre
    ActionChains(browser, duration=0).move_to_element_with_offset(
        canvas, round(dx), round(dy)
    ).perform()


def _canvas(browser):
    """The canvas's pixels, ``(H, W, 3)`` uint8."""
    from PIL import Image

    url = browser.execute_script("return document.getElementById('view').toDataURL()")
    png = base64.b64decode(url.split(",", 1)[1])
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def test_page_draws_frames_and_overlay(viewer, browser):
    start = browser.execute_script("return window.jaxadapt.frames")
    _until(lambda: browser.execute_script("return window.jaxadapt.frames") > start + 5, "frames")
    overlay = browser.find_element("id", "overlay").text
    assert "frames/s" in overlay and "cd/m2" in overlay and "t = " in overlay
    state = _state(viewer)
    assert state["size"] == [W, H] and state["frame"] > 5 and state["fps"] > 0
    assert state["adaptation"] >= 100.0  # jacobs2015's adaptation floor, cd/m2 (§2.4)


def test_gaze_in_state_follows_the_pointer(viewer, browser):
    for x, y in ((20, 30), (100, 70), (64, 10)):
        _point(browser, x, y)
        assert _until(lambda p=(x, y): _near(_state(viewer)["gaze"], p, 1.5), f"gaze at {x}, {y}")
        frame = _until(lambda: browser.execute_script("return window.jaxadapt.header"), "header")
        assert frame["size"] == [W, H]


def test_the_page_measures_gaze_to_frame_latency_and_shows_it(viewer, browser):
    # a frame that used this page's last sample takes with it every sample sent before
    _point(browser, 10, 10)
    last = "const j = window.jaxadapt; return j.header !== null && j.header.gaze_id === j.gazeId"
    _until(lambda: browser.execute_script(last), "a frame of the last sample")
    time.sleep(0.2)  # (its latency is taken at the next animation frame)
    browser.execute_script("window.jaxadapt.latencies.length = 0")
    first = browser.execute_script("return window.jaxadapt.gazeId")
    for k in range(12):  # a pointer moving over the canvas, a sample a frame or so
        _point(browser, 20 + 7 * k, 30 + 3 * k)
        time.sleep(0.03)
    latencies = _until(
        lambda: browser.execute_script("return window.jaxadapt.latencies.slice()"), "latencies"
    )
    # each sample measured once, from its sending to a painted frame that used it or a newer one
    sent = browser.execute_script("return window.jaxadapt.gazeId") - first
    assert 1 <= len(latencies) <= sent
    assert all(0 < ms < 10_000 for ms in latencies), latencies
    _until(lambda: "gaze to frame" in browser.find_element("id", "overlay").text, "the overlay")


def test_the_pointer_on_the_canvas_s_edge_pixels_is_on_the_frame(viewer, browser):
    """The canvas's outermost CSS pixels map to the frame's edge pixels, with
    no warning: the page maps its whole area into the frame."""
    from selenium.webdriver.common.action_chains import ActionChains

    canvas = browser.find_element("id", "view")
    w, h = canvas.size["width"], canvas.size["height"]
    errors = len(browser.execute_script("return window.jaxadapt.errors"))
    # (offsets from the pixel at the centre, at (w // 2, h // 2))
    for offset, corner in (
        (((w - 1) // 2, (h - 1) // 2), (W - 1, H - 1)),
        ((-(w // 2), -(h // 2)), (0, 0)),
    ):
        ActionChains(browser, duration=0).move_to_element_with_offset(canvas, *offset).perform()
        _until(lambda c=corner: _near(_state(viewer)["gaze"], c, 0.01), f"gaze at {corner}")
    time.sleep(0.2)  # (a warning would be on its way)
    assert len(browser.execute_script("return window.jaxadapt.errors")) == errors
    assert browser.find_element("id", "message").text == ""


def _near(gaze, point, tolerance):
    return gaze[0] is not None and math.dist(gaze, point) <= tolerance


def _afterimage_centre(pixels):
    """Centroid ``(x, y)`` of the pixels brighter than the dark field."""
    bright = pixels.max(axis=-1) > 10  # the afterimage peaks near 40
    if bright.sum() < 10:
        return None
    y, x = np.nonzero(bright)
    return float(x.mean()), float(y.mean())


def test_a_page_off_loopback_works_with_its_token(remote, browser):
    """Bound to every address, the server prints URLs of the machine (no
    0.0.0.0), each with the token; the page opened from one of them gets
    its script, its socket and frames, while a request without the token
    is refused."""
    urls = remote.server.urls()
    assert all("0.0.0.0" not in u and u.endswith("/?token=s3cret-t0ken") for u in urls)
    assert urls[0].startswith(f"http://{socket.gethostname()}:") and "127.0.0.1" in urls[-1]
    address = next((u for u in urls[1:-1]), urls[-1])  # an address other machines can use
    with _new_window(browser, address):
        _until(lambda: browser.execute_script("return window.jaxadapt.frames") > 3, "frames")
        assert "frames/s" in browser.find_element("id", "overlay").text
        assert _canvas(browser).max() > 100  # the patches drawn
    bare = address.split("?")[0]
    with pytest.raises(urllib.error.HTTPError, match="403"):
        urllib.request.urlopen(bare + "state", timeout=5)
    with urllib.request.urlopen(bare + "viewer.js", timeout=5) as response:  # no secret in it
        assert b"WebSocket" in response.read()


def test_without_effects_the_page_offers_none(remote, browser, viewer):
    """pattanaik2000 switches no effects: no check boxes and no keys for
    them on its page; jacobs2015's page lists its six."""
    assert browser.find_element("id", "effects-help").is_displayed()
    assert browser.find_element("id", "effects-last").text == "6"
    with _new_window(browser, remote.url):
        _until(lambda: browser.execute_script("return window.jaxadapt.frames") > 0, "a frame")
        assert not browser.find_element("id", "effects-help").is_displayed()
        assert browser.find_elements("css selector", "#effects input") == []
        assert "effects" not in browser.find_element("class name", "help").text


def test_afterimage_of_a_flash_moves_with_the_gaze(viewer, browser):
    """The flash (1/8 s of 1e7 cd/m2 at 0.25 s, fixated at the centre)
    leaves a bleaching afterimage on the retina (Jacobs 2015, Fig. 4): where
    the gaze goes, it goes."""
    cx, cy = (W - 1) / 2, (H - 1) / 2
    _point(browser, cx, cy)
    _until(lambda: _near(_state(viewer)["gaze"], (cx, cy), 1.0), "gaze at the centre")
    browser.find_element("id", "reset").click()  # the scene from 0 s, the flash to come
    _until(lambda: _state(viewer)["t"] < 0.25, "the reset")
    _until(lambda: 0.6 < _state(viewer)["t"] < 2.0, "the flash to pass", timeout=10)
    before = _afterimage_centre(_canvas(browser))
    assert before is not None and math.dist(before, (cx, cy)) < 4
    _point(browser, cx + 30, cy - 15)
    _until(lambda: _near(_state(viewer)["gaze"], (cx + 30, cy - 15), 1.0), "gaze moved")
    time.sleep(0.3)  # frames with the new gaze drawn
    after = _afterimage_centre(_canvas(browser))
    assert after is not None and math.dist(after, (cx + 30, cy - 15)) < 5


def test_bad_messages_get_a_message_and_the_server_runs_on(viewer, browser):
    replies = asyncio.run(_misbehave(viewer.url))
    assert "expected a JSON object" in replies["malformed"]
    assert "expected a message of type" in replies["unknown"]
    assert "off the 128x96 frame" in replies["off frame"]
    assert "expected numbers" in replies["strings"]
    assert "expected JSON text" in replies["binary"]
    assert "line" in replies["tracker garbage"] and "off the" in replies["tracker off"]
    assert replies["other origin"] == 403
    frames = browser.execute_script("return window.jaxadapt.frames")
    _until(lambda: browser.execute_script("return window.jaxadapt.frames") > frames + 3, "frames")
    _until(lambda: _state(viewer)["clients"] == 1, "the others gone")  # the page stays


async def _misbehave(url):
    """Send a page socket and a tracker socket garbage; their replies by case."""
    ws_url = url.replace("http", "ws")
    replies = {}
    async with aiohttp.ClientSession() as http:
        async with http.ws_connect(ws_url + "ws") as ws:
            await ws.receive_json()  # hello
            for case, text in (
                ("malformed", "{nope"),
                ("unknown", '{"type": "jump"}'),
                ("off frame", '{"type": "gaze", "x": 500, "y": 3}'),
                ("strings", '{"type": "gaze", "x": "1", "y": 2}'),
            ):
                await ws.send_str(text)
                replies[case] = await _reply(ws)
            await ws.send_bytes(b"\x00\x01")
            replies["binary"] = await _reply(ws)
        # a page that goes away mid-frame
        ws = await http.ws_connect(ws_url + "ws")
        await ws.receive()
        await ws.close()
        async with http.ws_connect(ws_url + "gaze") as ws:
            await ws.send_str('{"t": 0, "x": 1}\n')
            replies["tracker garbage"] = await _reply(ws)
            await ws.send_str('{"t": 0.1, "x": -5, "y": 3}')
            replies["tracker off"] = await _reply(ws)
        async with http.get(url + "state", headers={"Origin": "http://evil.example"}) as r:
            replies["other origin"] = r.status
    return replies


async def _reply(ws):
    """The next error or warning message on ``ws`` (frames skipped)."""
    while True:
        msg = await asyncio.wait_for(ws.receive(), 10)
        if msg.type == aiohttp.WSMsgType.TEXT:
            return json.loads(msg.data)["message"]


def test_an_external_tracker_drives_the_gaze(viewer, browser):
    """Samples sent to /gaze as JSON lines move the gaze; a null sample is a blink."""

    async def track():
        async with aiohttp.ClientSession() as http:
            async with http.ws_connect(viewer.url.replace("http", "ws") + "gaze") as ws:
                await ws.send_str('{"t": 0.0, "x": 12.5, "y": 80}\n')
                await asyncio.to_thread(
                    _until, lambda: _near(_state(viewer)["gaze"], (12.5, 80), 0.01), "tracked"
                )
                status = browser.find_element("id", "status")
                await asyncio.to_thread(
                    _until, lambda: "pointer is ignored" in status.text, "the page told"
                )
                _point(browser, 90, 20)  # ignored while a tracker drives the gaze
                await asyncio.sleep(0.2)
                assert _near(_state(viewer)["gaze"], (12.5, 80), 0.01)
                await ws.send_str('{"t": 0.1, "x": null, "y": null}')
                await asyncio.to_thread(
                    _until, lambda: _state(viewer)["gaze"] == [None, None], "a blink"
                )

    asyncio.run(track())
    _until(lambda: browser.find_element("id", "status").text == "", "the page told: gone")


def test_effects_pause_and_a_page_that_falls_behind(viewer, browser):
    """A checkbox switches an effect; space pauses the simulation; a page
    that acknowledges nothing gets :data:`WINDOW` frames and no more, while
    the others go on (frames dropped for it, not queued)."""
    from selenium.webdriver.common.keys import Keys

    browser.find_element("id", "effect-dithering").click()
    _until(lambda: "dithering" not in _state(viewer)["effects"], "dithering off", timeout=60)
    _until(
        lambda: "dithering" not in browser.execute_script("return window.jaxadapt.header.effects"),
        "frames without dithering",
        timeout=60,
    )

    async def lagging():
        async with aiohttp.ClientSession() as http:
            async with http.ws_connect(viewer.url.replace("http", "ws") + "ws") as ws:
                start = browser.execute_script("return window.jaxadapt.frames")
                await asyncio.sleep(1.0)
                frames = 0
                while True:
                    try:
                        msg = await asyncio.wait_for(ws.receive(), 0.2)
                    except asyncio.TimeoutError:
                        break
                    frames += msg.type == aiohttp.WSMsgType.BINARY
                return frames, browser.execute_script("return window.jaxadapt.frames") - start

    lagged, drawn = asyncio.run(lagging())
    assert lagged == WINDOW and drawn > 10
    browser.find_element("tag name", "body").send_keys(Keys.SPACE)
    _until(lambda: _state(viewer)["paused"], "paused")
    frame = _state(viewer)["frame"]
    time.sleep(0.3)
    assert _state(viewer)["frame"] <= frame + WINDOW
    browser.find_element("tag name", "body").send_keys(Keys.SPACE)
    _until(lambda: _state(viewer)["frame"] > frame + 5, "resumed")
    browser.find_element("id", "effect-dithering").click()


def test_pages_agree_on_pause_effects_and_resets(viewer, browser):
    """A page opened while the server is paused shows the last frame and
    says it is paused, and one press of space resumes; an effect switched
    or a reset on one page is told to every page."""
    from selenium.webdriver.common.keys import Keys

    def script(expression):
        return browser.execute_script("return " + expression)

    browser.find_element("tag name", "body").send_keys(Keys.SPACE)
    try:
        _pages_agree(viewer, browser, script)
    finally:  # (the tests after want frames)
        asyncio.run(_page_says(viewer, {"type": "pause", "paused": False}))
    _until(lambda: browser.find_element("id", "pause").text == "pause", "told: resumed")
    _until(lambda: not browser.find_element("id", "effect-acuity").is_selected(), "told: acuity")
    browser.find_element("id", "effect-acuity").click()
    _until(lambda: "acuity" in _state(viewer)["effects"], "acuity on again")


async def _page_says(viewer, message):
    async with aiohttp.ClientSession() as http:
        async with http.ws_connect(viewer.url.replace("http", "ws") + "ws") as ws:
            await ws.send_json(message)


def _pages_agree(viewer, browser, script):
    from selenium.webdriver.common.keys import Keys

    _until(lambda: _state(viewer)["paused"], "paused")

    def settled():
        # A frame being computed when the pause came is still published (and
        # becomes the one a new page gets): the frame count must stay put.
        frame = _state(viewer)["frame"]
        time.sleep(0.5)
        return frame == _state(viewer)["frame"] == script("window.jaxadapt.header.frame") + 1

    _until(
        settled,
        lambda: f"the last frame drawn: {script('window.jaxadapt.header.frame')}, {_state(viewer)}",
    )
    last, pixels, resets = (
        script("window.jaxadapt.header"),
        _canvas(browser),
        script("window.jaxadapt.resets"),
    )
    with _new_window(browser, viewer.url):
        _until(lambda: script("window.jaxadapt.frames") == 1, "the last frame")
        assert script("window.jaxadapt.header.digest") == last["digest"]
        np.testing.assert_array_equal(_canvas(browser), pixels)
        assert browser.find_element("id", "pause").text == "resume"
        overlay = browser.find_element("id", "overlay").text
        assert overlay.startswith(f"paused  frame {last['frame']}") and "frames/s" not in overlay
        browser.find_element("tag name", "body").send_keys(Keys.SPACE)  # once
        _until(lambda: not _state(viewer)["paused"], "resumed")
        browser.find_element("id", "effect-acuity").click()
        _until(lambda: "acuity" not in _state(viewer)["effects"], "acuity off")
        browser.find_element("id", "reset").click()
        _until(lambda: _state(viewer)["resets"] == resets + 1, "a reset")
    _until(lambda: script("window.jaxadapt.resets") == resets + 1, "told: a reset")


def test_the_page_says_when_simulated_time_falls_behind(viewer, browser, monkeypatch):
    """Frames that take longer than MAX_DT to compute: the page says how
    slow simulated time runs and how far behind, and stops saying it once
    frames keep up again."""
    from jaxadapt.viewer import _simulation

    monkeypatch.setattr(_simulation, "MAX_DT", 0.1)
    session, advance = viewer.server.session, viewer.server.session.advance

    def slow_advance(*args):
        time.sleep(0.15)
        return advance(*args)

    status = browser.find_element("id", "status")
    session.advance = slow_advance
    try:
        text = _until(lambda: status.text, "the page told")
        assert text.startswith("simulated time runs at ") and "% of real time (" in text
        assert "s behind): a frame takes 0." in text and "advances it at most 0.1 s" in text
        assert _state(viewer)["slow"] and _state(viewer)["lag"] > 0.1
    finally:
        del session.advance
    _until(lambda: status.text == "", "the page told: in time again")


def test_recorded_session_replays_to_the_frames_shown(viewer, browser, tmp_path):
    """The frames the browser drew (their digests) are those that
    :func:`replay`, and ``jaxadapt render --replay`` in its PNGs, make
    offline from the record."""
    seen = browser.execute_script("return window.jaxadapt.seen")
    viewer.close()
    spec, rows = read_record(viewer.record)
    assert json.loads((viewer.record / "session.json").read_text())["complete"]
    assert spec["frames"] == len(rows) > 50
    replayed = {f.index: f.digest for f in replay(viewer.record)}
    assert [replayed[int(r["frame"])] for r in rows] == [r["digest"] for r in rows]
    assert all(replayed[frame] == digest for frame, digest in seen)
    out = tmp_path / "replay"
    assert main(["render", "--replay", str(viewer.record), "--out", str(out)]) == 0
    written = {
        int(png.stem.removeprefix("frame_")): Image.open(png).tobytes()
        for png in out.glob("frame_*.png")
    }
    assert len(written) == len(rows) and (out / "video.mp4").stat().st_size > 0
    digests = {k: hashlib.sha256(pixels).hexdigest()[:16] for k, pixels in written.items()}
    assert all(digests[frame] == digest for frame, digest in seen)
    times, points = read_gaze_csv(viewer.record / "gaze.csv")  # what render --gaze reads
    assert len(times) == len(rows) and np.isnan(points).any()  # the tracker's blink


def test_the_page_says_when_the_server_stopped(viewer, browser):
    """Stopped (as Ctrl-C stops it), the server closes the page's socket:
    the page says so, shows no frame rate, and dims the last picture."""
    viewer.close()
    status = browser.find_element("id", "status")
    _until(lambda: "the server stopped" in status.text, "the page told")
    assert "frames/s" not in browser.find_element("id", "overlay").text
    assert "the server stopped" in browser.find_element("id", "overlay").text
    opacity = browser.execute_script(
        "return getComputedStyle(document.getElementById('view')).opacity"
    )
    assert float(opacity) < 0.5


@pytest.mark.skipif(not os.environ.get("JAXADAPT_SCREENSHOT"), reason="JAXADAPT_SCREENSHOT unset")
def test_screenshot(browser, tmp_path):
    """Save the page as JAXADAPT_SCREENSHOT (docs/viewer.png): the
    checkerboard of Fig. 3 b fixated, then the gaze on the field beside it,
    where the board's adaptation afterimage shows."""
    size = (384, 216)  # the default
    session = Session({"scene": "checkerboard", "size": list(size)})
    session.warm()
    server, url, close = _serve(session, tmp_path / "record")
    try:
        browser.set_window_size(900, 560)
        browser.get(url)
        _until(lambda: browser.execute_script("return window.jaxadapt.frames") > 3, "frames")
        _point_scaled(browser, 95.5, 107.5, *size)  # the board's centre
        time.sleep(5.0)
        _point_scaled(browser, 287.5, 107.5, *size)  # the field's
        time.sleep(0.5)
        browser.save_screenshot(os.environ["JAXADAPT_SCREENSHOT"])
        shown = _canvas(browser).astype(float).mean(axis=-1)
    finally:
        close()
    # The field shows the board's negative where the board's image fell on
    # the retina (shifted with the gaze by the board's width): light where a
    # square was dark, a faint modulation (the fixation mark left out).
    board, field = shown[:, : size[0] // 2], shown[:, size[0] // 2 :]
    on_field = (field > 50) & (field < 150)
    assert np.corrcoef(board[on_field], field[on_field])[0, 1] < -0.5
    assert 1.0 < field[on_field].std() < 20.0
