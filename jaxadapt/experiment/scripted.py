"""A scripted participant: drives the experiment's page in a browser as a
careful observer would, for tests and for a lab's rehearsal of a session
(``selenium``, from the test extra).

It reads the page's state from ``<body>``'s data attributes, as any
automation may (``data-phase``, and while an image is up
``data-stimulus`` and ``data-luminance``), presses space at the
instructions and breaks, and answers with the interval whose image was
brighter (the first where they are equal), or the other one with
probability ``error_rate``.
"""

import random
import time

__all__ = ["ScriptedParticipant"]

#: Records every change of <body>'s data attributes in ``window.seen``.
_OBSERVE = """
window.seen = window.seen || [];
new MutationObserver(() => {
  const d = document.body.dataset;
  window.seen.push([d.phase, d.stimulus || null, d.luminance || null]);
}).observe(document.body, {attributes: true});
"""


class ScriptedParticipant:
    """Drive a page of ``jaxadapt experiment`` open in ``driver`` (a
    selenium WebDriver).

    Attributes
    ----------
    phases : list of str
        Every phase the page entered, in order.
    images : list of (str, float)
        ``(stimulus, luminance)`` of every image shown.
    """

    def __init__(self, driver, error_rate=0.0, seed=0):
        self.driver, self.error_rate = driver, error_rate
        self.random = random.Random(seed)
        self.phases, self.images = [], []

    def watch(self):
        """Start recording the page's phases (again after a reload)."""
        self.driver.execute_script(_OBSERVE)

    def _collect(self):
        seen = self.driver.execute_script("const s = window.seen || []; window.seen = []; return s")
        self.phases += [s[0] for s in seen]
        self.images += [(s[1], float(s[2])) for s in seen if s[0] in ("interval1", "interval2")]

    def _press(self, key):
        from selenium.webdriver.common.action_chains import ActionChains

        ActionChains(self.driver).send_keys(key).perform()

    def step(self, before=None):
        """Act on the page's phase once; return the phase. ``before(phase)``,
        if given, is called first (e.g. to take a screenshot of it)."""
        self._collect()
        phase = self.driver.execute_script("return document.body.dataset.phase")
        if before is not None:
            before(phase)
        if phase in ("instructions", "break"):
            time.sleep(0.2)
            self._press(" ")
            time.sleep(0.3)
        elif phase == "respond":
            (_, first), (_, second) = self.images[-2:]
            answer = 1 if first >= second else 2
            if self.random.random() < self.error_rate:
                answer = 3 - answer
            self._press(str(answer))
            time.sleep(0.3)
        return phase

    def until(self, condition, timeout=60.0, each=None):
        """Act until ``condition(phase)`` holds; return that phase.
        ``each(phase)``, if given, is called at every step, before acting."""
        end = time.monotonic() + timeout
        phase = None
        while time.monotonic() < end:
            phase = self.step(each)
            if condition(phase):
                return phase
            time.sleep(0.03)
        raise TimeoutError(f"timed out in phase {phase!r}")
