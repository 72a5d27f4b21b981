"""A pilot session of each 2015 study, run by a scripted participant in
Debian's headless Chromium, killed and continued on the way.

For each study: ``jaxadapt experiment STUDY --training 5 --repetitions 1``
on the paper's display (64 pixels a degree, 60 Hz), with a scripted
participant (:mod:`jaxadapt.experiment.scripted`) that answers with the
brighter image 90 % of the time, and 10 s of darkness before the mesopic
study's trials (not the paper's 300); the server is killed with SIGKILL in
the middle of the session, the same command started again and the page
reloaded. Then ``jaxadapt psychometric fit`` reads the table.

Writes, per study: ``<study>/trials.csv`` and ``session.json`` (the
session), ``<study>_<phase>.png`` (a screenshot of each phase, and a copy
brightened 30 times where the page is too dark to see in print) and
``summary.json``: rows, trials answered once, flagged rows, the page's
measured durations (median, min, max) and what the fit said.
``--smoke`` runs 2 training trials on a display of 8.7 pixels a degree.
"""

import base64
import csv
import json
import re
import signal
import socket
import subprocess
import sys

import numpy as np
from common import setup

from jaxadapt.experiment.scripted import ScriptedParticipant

#: The standard's flash, as the page fetches it (a data URL's base64).
FLASH = """
const done = arguments[arguments.length - 1];
fetch("/image/f-s-0" + location.search).then((r) => r.arrayBuffer()).then((buffer) => {
  let s = "";
  for (const x of new Uint8Array(buffer)) s += String.fromCharCode(x);
  done(btoa(s));
});
"""
PHASES = ("instructions", "dark", "fixation", "interval1", "blank1", "respond", "break", "done")


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(argv):
    process = subprocess.Popen(
        [sys.executable, "-m", "jaxadapt", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    for line in process.stdout:
        print("   ", line, end="")
        found = re.search(r"serving (http://\S+)", line)
        if found:
            return process, found[1]
    raise RuntimeError(f"jaxadapt experiment ended with status {process.wait()}")


def _chromium(profile):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--no-first-run"):
        options.add_argument(flag)
    options.add_argument("--window-size=1920,1080")
    options.add_argument("--screen-info={1920x1080}")  # (the page asks for full screen)
    options.add_argument(f"--user-data-dir={profile}")
    return webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)


def _screenshot(driver, path):
    """The page as PNG, and a copy brightened 30 times (display codes, not light)."""
    from io import BytesIO

    from PIL import Image

    png = driver.get_screenshot_as_png()
    path.write_bytes(png)
    pixels = np.asarray(Image.open(BytesIO(png)).convert("RGB"), np.float32)
    bright = np.clip(pixels * 30, 0, 255).astype(np.uint8)
    Image.fromarray(bright).save(path.with_name(path.stem + "_x30.png"))


def pilot(study, folder, smoke):
    out = folder / study
    argv = ["experiment", study, "--participant", "pilot", "--out", str(out)]
    argv += ["--training", "2" if smoke else "5", "--repetitions", "0" if smoke else "1"]
    argv += ["--seed", "1", "--no-browser", "--port", str(_free_port())]
    if study == "mesopic":
        argv += ["--dark-seconds", "10"]  # (the paper's 300 s, shortened for a rehearsal)
    if smoke:
        display = folder / "small_display.json"
        display.write_text(json.dumps({"distance_m": 0.5, "pixel_pitch_mm": 1.0}))
        argv += ["--display", str(display)]
    print(f"{study}: jaxadapt {' '.join(argv)}")
    server, url = _start(argv)
    driver = _chromium(folder / f"chromium_{study}")
    shot = set()

    def screenshots(phase):
        if phase in PHASES and phase not in shot:
            shot.add(phase)
            _screenshot(driver, folder / f"{study}_{phase}.png")
            if phase == "interval1" and study == "afterimage":  # (50 ms: too short to catch)
                flash = driver.execute_async_script(FLASH)
                (folder / "afterimage_flash.png").write_bytes(base64.b64decode(flash))

    try:
        driver.get(url)
        participant = ScriptedParticipant(driver, error_rate=0.1, seed=1)
        participant.watch()
        planned = len(json.loads((out / "session.json").read_text())["trials"])
        half = planned // 2

        def answered():
            with open(out / "trials.csv") as f:
                return sum(1 for _ in f) - 1

        participant.until(lambda p: answered() >= half and p == "blank1", 900, screenshots)
        server.send_signal(signal.SIGKILL)
        server.wait()
        killed_at = answered()
        print(f"    SIGKILL with {killed_at} of {planned} answered, a trial in flight")
        server, url = _start(argv)
        driver.refresh()
        participant.watch()
        end = participant.until(lambda p: p in ("done", "excluded"), 900, screenshots)
        screenshots(end)
        status = server.wait(60)
    finally:
        driver.quit()
        if server.poll() is None:
            server.kill()
    with open(out / "trials.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    fit = subprocess.run(
        [sys.executable, "-m", "jaxadapt", "psychometric", "fit", str(out / "trials.csv")]
        + ["--out", str(folder / f"{study}_fit"), "--resamples", "0"],
        capture_output=True,
        text=True,
    )

    def spread(column):
        values = [float(r[column]) for r in rows if r["flagged"] == "false"]
        return {"median": float(np.median(values)), "min": min(values), "max": max(values)}

    summary = {
        "end": end,
        "status": status,
        "planned": planned,
        "rows": len(rows),
        "killed_at": killed_at,
        "answered_once": sorted(int(r["trial"]) for r in rows if r["flagged"] == "false")
        == list(range(planned)),
        "flagged": sum(r["flagged"] == "true" for r in rows),
        **{c: spread(c) for c in ("image1_ms", "image2_ms", "blank1_ms", "blank2_ms", "rt_ms")},
        "fit_status": fit.returncode,
        "fit_said": (fit.stdout + fit.stderr).strip().splitlines(),
    }
    print(json.dumps(summary, indent=1))
    return summary


def main():
    args, folder = setup("experiment_pilot", __doc__.splitlines()[0])
    summary = {study: pilot(study, folder, args.smoke) for study in ("afterimage", "mesopic")}
    (folder / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")


if __name__ == "__main__":
    main()
