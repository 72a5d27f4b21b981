"""Debian's headless Chromium driven through selenium (never a browser
downloaded at run time), for the tests of the pages jaxadapt serves."""

from pathlib import Path

import pytest

CHROMIUM, CHROMEDRIVER = Path("/usr/bin/chromium"), Path("/usr/bin/chromedriver")


def chromium(profile, size=(800, 600), screen=None):
    """A headless Chromium of its own ``profile`` folder, its window ``size``
    on a screen of ``screen`` (default: the window's; the size a page made
    full screen takes); skips the test where Debian's chromium and
    chromium-driver are not installed."""
    if not CHROMIUM.exists() or not CHROMEDRIVER.exists():
        pytest.skip("needs Debian's chromium and chromium-driver (/usr/bin/chromium)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    for flag in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        f"--window-size={size[0]},{size[1]}",
        "--screen-info={{{}x{}}}".format(*(screen or size)),
        f"--user-data-dir={profile}",
    ):
        options.add_argument(flag)
    return webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=options)
