"""The live viewer as a user runs it: frame rate and gaze-to-frame latency.

A real ``jaxadapt view --no-browser`` process serves a scene; a client
behaves as the page does (it decodes each JPEG frame, then acknowledges
it) and sends gaze samples as a pointer does (``--gaze-rate`` a second,
each with an id). Each frame's header names the id of the gaze sample the
frame used, so the latency of a sample is the time from its sending to the
arrival of the first frame that used it (or a newer one): what a viewer
waits between moving the eyes and seeing the frame that follows them.
The sustained frame rate is the frames received over ``--seconds``, after
two seconds of warm-up. Each row also times a frame's step and JPEG alone,
in this process, which other work on the machine disturbs less, and with
``--browser`` a page in Debian's headless Chromium on the same machine
(which then shares its cores), its pointer moving: the frame rate it gets,
and the latency the page itself measures, from a pointer's sample sent to
the animation frame after the frame that used it is drawn (the browser's
decoding and painting included).

    python benchmarks/bench_viewer.py [--sizes 256x144 384x216 480x270]
                                      [--seconds 10] [--browser] [--label cpu-2core]
"""

import argparse
import asyncio
import io
import json
import os
import statistics
import struct
import subprocess
import sys
import time

import aiohttp
from common import machine, write_result
from PIL import Image


def start(size, operator, scene):
    """The server process and its page's URL."""
    command = [sys.executable, "-m", "jaxadapt", "view", "--no-browser", "--port", "0"]
    command += ["--size", size, "--operator", operator, "--scene", scene]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
    line = process.stdout.readline()
    if "serving" not in line:
        process.kill()
        raise RuntimeError(f"jaxadapt view did not start: {line!r}")
    return process, line.split()[3]


async def watch(url, seconds, gaze_rate, warmup=2.0):
    """Frames received per second and the latencies of gaze samples, s."""
    sent, latencies, frames = {}, [], 0
    async with aiohttp.ClientSession() as http:
        async with http.ws_connect(url.replace("http", "ws") + "ws") as ws:
            await ws.receive_json()  # hello
            start = time.perf_counter()
            measuring = start + warmup
            end = measuring + seconds

            async def look():
                k = 0
                while time.perf_counter() < end:
                    k += 1
                    sent[k] = time.perf_counter()
                    await ws.send_json({"type": "gaze", "x": 10 + k % 50, "y": 20, "id": k})
                    await asyncio.sleep(1 / gaze_rate)

            looking = asyncio.create_task(look())
            while time.perf_counter() < end:
                msg = await ws.receive()
                if msg.type != aiohttp.WSMsgType.BINARY:
                    continue
                arrived = time.perf_counter()
                length = struct.unpack(">I", msg.data[:4])[0]
                header = json.loads(msg.data[4 : 4 + length])
                Image.open(io.BytesIO(msg.data[4 + length :])).load()  # as the page decodes it
                await ws.send_json({"type": "ack"})
                frames += arrived >= measuring
                used = header["gaze_id"] or 0
                for k in sorted(k for k in sent if k <= used):
                    if sent[k] >= measuring:
                        latencies.append(arrived - sent[k])
                    del sent[k]
            await looking
    return frames / seconds, latencies


def measure(size, operator, scene, seconds, gaze_rate):
    process, url = start(size, operator, scene)
    try:
        fps, latencies = asyncio.run(watch(url, seconds, gaze_rate))
    finally:
        process.terminate()
        process.wait(30)
    latencies.sort()
    return {
        "size": size,
        "operator": operator,
        "scene": scene,
        "frames_per_s": fps,
        "latency_median_ms": 1e3 * statistics.median(latencies),
        "latency_p95_ms": 1e3 * latencies[int(0.95 * (len(latencies) - 1))],
        "latency_max_ms": 1e3 * latencies[-1],
        "gaze_samples": len(latencies),
    }


#: A pointer moving over the page's canvas, ``rate`` pointermove events a
#: second (dispatched in the page, as a mouse's reach its script).
POINTER = """
const canvas = document.getElementById("view");
let k = 0;
window.probe = setInterval(function () {
  const r = canvas.getBoundingClientRect();
  k += 1;
  canvas.dispatchEvent(new PointerEvent("pointermove", {
    clientX: r.left + r.width * (0.2 + 0.6 * ((k * 0.37) % 1)),
    clientY: r.top + r.height * (0.3 + 0.4 * ((k * 0.61) % 1)),
    bubbles: true,
  }));
}, 1000 / arguments[0]);
"""


def browser(size, operator, scene, seconds, gaze_rate, window="900,560"):
    """A page in Debian's headless Chromium (``/usr/bin/chromium``, through
    selenium) on the same machine, its pointer moving (:data:`POINTER`):
    the frames/s the server sustains for it (the mean of ``/state``'s
    ``fps`` each second, after three seconds) and the page's own
    gaze-to-frame latencies, ms (from a pointer's sample sent to the
    animation frame after the frame that used it is drawn: the page's
    ``latencies``)."""
    import tempfile
    import urllib.request

    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    process, url = start(size, operator, scene)
    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", f"--window-size={window}",
                 f"--user-data-dir={tempfile.mkdtemp()}"):  # fmt: skip
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
    try:
        driver.get(url)
        driver.execute_script(POINTER, gaze_rate)
        time.sleep(3.0)
        driver.execute_script("window.jaxadapt.latencies.length = 0")
        rates = []
        for _ in range(int(seconds)):
            time.sleep(1.0)
            with urllib.request.urlopen(url + "state") as response:
                rates.append(json.load(response)["fps"])
        latencies = sorted(driver.execute_script("return window.jaxadapt.latencies.slice()"))
    finally:
        driver.quit()
        process.terminate()
        process.wait(30)
    return {
        "chromium_frames_per_s": statistics.mean(rates),
        "chromium_latency_median_ms": statistics.median(latencies),
        "chromium_latency_p95_ms": latencies[int(0.95 * (len(latencies) - 1))],
        "chromium_gaze_samples": len(latencies),
    }


def stages(size, operator, scene, frames=30):
    """Milliseconds a frame takes in this process, alone: the session's step
    (with its 8-bit frame and digest) and the JPEG encoding (medians)."""
    from jaxadapt.viewer import Session
    from jaxadapt.viewer._simulation import encode_jpeg

    w, h = (int(v) for v in size.split("x"))
    session = Session({"scene": scene, "size": [w, h], "operator": operator})
    session.warm()
    step, jpeg = [], []
    for k in range(frames):
        start = time.perf_counter()
        frame = session.advance(1 / 30, (w / 2 + k % 7, h / 2))
        assert frame.digest  # (as the server computes it)
        middle = time.perf_counter()
        encode_jpeg(frame.pixels)
        step.append(middle - start)
        jpeg.append(time.perf_counter() - middle)
    return {"step_ms": 1e3 * statistics.median(step), "jpeg_ms": 1e3 * statistics.median(jpeg)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["256x144", "384x216", "480x270"])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--gaze-rate", type=float, default=60.0, help="gaze samples a second")
    parser.add_argument("--scene", default="patches")
    parser.add_argument("--label", default=None)
    parser.add_argument(
        "--browser",
        action="store_true",
        help="also the frame rate and the page's gaze-to-frame latency in Chromium",
    )
    args = parser.parse_args()
    from jaxadapt import runtime

    # The process settings of the server (every jaxadapt command), for the
    # stages timed here, before the first JAX computation.
    runtime.use_wide_vectors()
    runtime.retain_freed_memory()
    load = os.getloadavg()[0]  # other work on the machine slows every row
    runs = [measure(s, "jacobs2015", args.scene, args.seconds, args.gaze_rate) for s in args.sizes]
    runs.append(measure("384x216", "pattanaik2000", args.scene, args.seconds, args.gaze_rate))
    for run in runs:
        run["alone"] = stages(run["size"], run["operator"], args.scene)
        if args.browser:
            run.update(
                browser(run["size"], run["operator"], args.scene, args.seconds, args.gaze_rate)
            )
    for run in runs:
        print(
            f"{run['operator']:14s} {run['size']:>9s}: {run['frames_per_s']:5.1f} frames/s, "
            f"gaze to frame {run['latency_median_ms']:.0f} ms (95 % {run['latency_p95_ms']:.0f}, "
            f"max {run['latency_max_ms']:.0f}); alone a frame's step {run['alone']['step_ms']:.1f} "
            f"ms, its JPEG {run['alone']['jpeg_ms']:.1f} ms"
            + (
                f"; Chromium {run['chromium_frames_per_s']:.1f} frames/s, gaze to frame drawn "
                f"{run['chromium_latency_median_ms']:.0f} ms (95 % "
                f"{run['chromium_latency_p95_ms']:.0f})"
                if args.browser
                else ""
            )
        )
    record = {
        "machine": machine(args.label),
        "seconds": args.seconds,
        "gaze_rate": args.gaze_rate,
        "load_average_1min": {"before": load, "after": os.getloadavg()[0]},
        "client": "aiohttp, decodes each JPEG (Pillow) and acknowledges it, as the page",
        "runs": runs,
    }
    print(write_result("viewer", record, args.label))


if __name__ == "__main__":
    main()
