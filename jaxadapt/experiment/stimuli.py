"""The 2015 paper's stimuli on a calibrated display: each interval of a
trial as 8-bit PNG images and the display frames each is held for.

The images are the renders of :mod:`jaxadapt.psychophysics.displays` (the
2015 operator; the same code the model observers see), made at the
display's own pixels per degree and at a whole fraction of its refresh
rate, and turned into code values by
:func:`~jaxadapt.experiment.calibration.dithered_codes` with a new dither
pattern per image. Everything is rendered and encoded once, at start-up,
and checked against the display: a stimulus brighter than its white, or
a level not above its black, is refused there.

Choices where the paper is silent
---------------------------------
* **Image rate.** A new image (and dither pattern) every
  :func:`refreshes_per_image` display frames, about 20 per second: the
  afterimage's flash (50 ms) is then one image at the usual refresh
  rates, and the afterimage fades and the acuity noise moves at the rate
  the simulations render them.
* **The mesopic chart's level** is its white tile's: each chart is rendered
  as the simulations render it (scaled to the mean luminance of the chart
  it depicts, where the tone curve leaves the white tile about 30 %
  darker), then scaled so that the control chart's white tile measures
  the level on the display, "5.5e-2 cd/m2 at the white tile" (§4.2.1);
  the manipulated chart of a level takes its control's scale, so that the
  two have the same mean light and differ in colour and detail only.
* **Fixation target.** A cross of 0.5 degrees, 2.5 degrees below the
  centre of the flash (the flash has a 1.5-degree radius: "just below the
  position of the flash unit", §4.1.1), at the centre of the chart for the
  mesopic study, shown before each trial at a quarter of the standard's
  luminance (nearest code, at least 1).
"""

import dataclasses
import io as _bytes_io
from typing import NamedTuple

import jax
import numpy as np

from jaxadapt.color import photopic_luminance
from jaxadapt.experiment.calibration import dithered_codes

__all__ = [
    "IMAGE_RATE",
    "FLASH_FIELD_DEG",
    "CHART_FIELD_DEG",
    "CHART_ASPECT",
    "Interval",
    "Stimuli",
    "refreshes_per_image",
    "png",
]

#: Images per second, about (:func:`refreshes_per_image`).
IMAGE_RATE = 20.0
#: Width of the flash scene and of the colour chart, degrees of visual angle.
FLASH_FIELD_DEG = 10.0
CHART_FIELD_DEG = 20.0
#: Aspect of the chart (:func:`jaxadapt.scenes.mesopic`'s default 384x256).
CHART_ASPECT = 2.0 / 3.0


class Interval(NamedTuple):
    """One interval of a trial: the image, then the blank after it.

    Attributes
    ----------
    images : tuple of str
        Keys of :attr:`Stimuli.images`, in order.
    holds : tuple of int
        Display frames each image is held for.
    shown : int
        How many of the leading images are the stimulus (the rest: the
        blank, black or an afterimage on black).
    """

    images: tuple
    holds: tuple
    shown: int


def refreshes_per_image(refresh_hz):
    """Display frames each image is held: the whole number nearest to
    ``refresh_hz / IMAGE_RATE``, at least 1."""
    return max(1, round(refresh_hz / IMAGE_RATE))


def png(codes):
    """PNG bytes of 8-bit RGB ``codes`` (H, W, 3), fastest deflate."""
    from PIL import Image

    out = _bytes_io.BytesIO()
    Image.fromarray(np.ascontiguousarray(codes), "RGB").save(out, "PNG", compress_level=1)
    return out.getvalue()


def _frames(seconds, refresh_hz, k):
    """``(images, refreshes)``: ``seconds`` as whole display frames (at least
    one), then as images of ``k`` of them (the last may hold fewer)."""
    n = max(1, round(seconds * refresh_hz))
    return -(-n // k), n


def _holds(images, n, k):
    return tuple(min(k, n - i * k) for i in range(images))


class Stimuli:
    """Every image of a protocol's trials, encoded for ``display``.

    Parameters
    ----------
    protocol : jaxadapt.psychophysics.design.Protocol
        ``AFTERIMAGE`` or ``MESOPIC`` (by name), conditions control and
        manipulated.
    display : jaxadapt.experiment.calibration.Display
    key : PRNG key
        The dither patterns and the acuity noise.
    report : callable, optional
        Takes a line of progress.

    Raises
    ------
    ValueError
        A stimulus the display cannot show (see the module notes).

    Attributes
    ----------
    images : dict of str to bytes
        PNG of each image, by key.
    size : (int, int)
        Width and height of the images, pixels.
    presentation_s, blank_s : float
        What the display shows of each: whole display frames.
    fixation : dict
        ``x``, ``y`` (offset from the images' centre, pixels), ``size``
        (pixels) and ``code`` of the fixation cross.
    text_code : int
        Grey code of the page's words: about five times the standard's
        luminance, from 12 to 90 (dim after the dark period of the mesopic
        study, legible in the afterimage study).
    """

    def __init__(self, protocol, display, key, report=None):
        self.protocol, self.display = protocol, display
        self.k = k = refreshes_per_image(display.refresh_hz)
        self.shown, self.n_shown = _frames(protocol.presentation_s, display.refresh_hz, k)
        self.blanks, self.n_blank = _frames(protocol.blank_s, display.refresh_hz, k)
        self.presentation_s = self.n_shown / display.refresh_hz
        self.blank_s = self.n_blank / display.refresh_hz
        self.images, self._n = {}, 0
        render_key, self._dither_key = jax.random.split(key)
        report = report or (lambda line: None)
        _check_levels(protocol, display)
        ppd = display.pixels_per_degree
        if protocol.name == "afterimage":
            self._afterimage(ppd, report)
        elif protocol.name == "mesopic":
            self._mesopic(ppd, render_key, report)
        else:
            raise ValueError(f"protocol: expected afterimage or mesopic, got {protocol.name!r}")
        emitted = display.emitted(np.arange(256))
        code = np.argmin(np.abs(emitted - protocol.standard / 4))
        self.text_code = int(np.clip(np.argmin(np.abs(emitted - 5 * protocol.standard)), 12, 90))
        self.fixation = {
            "x": 0,
            "y": round(2.5 * ppd) if protocol.name == "afterimage" else 0,
            "size": max(5, round(0.5 * ppd)),
            "code": int(max(code, 1)),
        }

    # -- rendering --------------------------------------------------------

    def _add(self, key, luminance, what):
        """Encode one image (cd/m2, (H, W, 3)) under ``key``, with a dither
        pattern of its own; refuse one brighter than the display's white."""
        brightest = float(np.max(luminance))
        if brightest > self.display.white * 1.001:
            raise ValueError(
                f"display: white {self.display.white:g} cd/m2 cannot show the {what}, "
                f"{brightest:.3g} cd/m2 at its brightest"
            )
        pattern = jax.random.fold_in(self._dither_key, self._n)
        self._n += 1
        self.images[key] = png(dithered_codes(self.display, luminance, pattern))

    def _afterimage(self, ppd, report):
        from jaxadapt.psychophysics.displays import afterimage_renders

        protocol, k = self.protocol, self.k
        fps = self.display.refresh_hz / k
        width = _even(FLASH_FIELD_DEG * ppd)
        shown = dataclasses.replace(protocol, presentation_s=self.shown / fps)
        report(f"rendering the flash scene at {width}x{width}, {fps:.4g} images/s")
        # (the blank: what the renders hold after the flash, up to whole images)
        r = afterimage_renders(shown, width=width, height=width, fps=fps, lead_s=0.0, stepped=True)
        self.size = (width, width)
        presented, blank = np.flatnonzero(r.presented), np.flatnonzero(r.blank)
        renders = (np.asarray(r.weak), np.asarray(r.strong))
        scale = float(r.scale)
        faint = scale * np.max(renders[0][blank].mean(axis=0))
        if faint <= self.display.black:
            raise ValueError(
                f"display: black {self.display.black:g} cd/m2 hides the weak afterimage, "
                f"{faint:.3g} cd/m2 at its brightest"
            )
        levels = 10.0 ** np.asarray(protocol.levels)
        report(f"encoding {len(levels) * 2 + 1 + 2 * self.blanks} images")
        for i, t in enumerate(presented):
            self._add(f"f-s-{i}", scale * renders[0][t], "standard")
            for c, render in enumerate(renders):
                for j, level in enumerate(levels):
                    name = f"{protocol.conditions[c]} test at {protocol.tests[j]:g} cd/m2"
                    self._add(f"f-{c}-{j}-{i}", scale * level * render[t], name)
        for c, render in enumerate(renders):
            for i in range(self.blanks):
                t = blank[min(i, len(blank) - 1)]
                self._add(f"a-{c}-{i}", scale * render[t], "afterimage")

    def _mesopic(self, ppd, key, report):
        from jaxadapt.psychophysics.displays import mesopic_render

        protocol, k = self.protocol, self.k
        fps = self.display.refresh_hz / k
        width = _even(CHART_FIELD_DEG * ppd)
        height = _even(width * CHART_ASPECT)
        self.size = (width, height)
        shown = self.shown / fps
        protocol = dataclasses.replace(protocol, presentation_s=shown)
        options = dict(key=key, width=width, height=height, fps=fps, paper_pixels=False)
        options["stepped"] = True  # (frame by frame: the memory of one frame)
        tile = _white_tile(width, height)
        cells = [("s", None, protocol.standard)] + [
            (f"{c}-{j}", j, test) for c in (0, 1) for j, test in enumerate(protocol.tests)
        ]
        scales = {}
        for n, (name, level, white) in enumerate(cells):
            report(f"rendering chart {n + 1} of {len(cells)} at {width}x{height}")
            effects = name.startswith("1-")
            frames = np.asarray(mesopic_render(protocol, [white], effects=effects, **options)[0])
            if not effects:  # the white tile of the control chart measures the level
                scales[level] = white / np.mean(photopic_luminance(frames[:, tile]))
            frames *= scales[level]  # (a manipulated chart: its control's, same mean light)
            for i in range(self.shown):
                self._add(f"c-{name}-{i}", frames[min(i, len(frames) - 1)], "colour chart")
        self.images["black"] = png(np.zeros((height, width, 3), np.uint8))

    # -- trials -----------------------------------------------------------

    def interval(self, condition=None, level=None):
        """The :class:`Interval` of the standard (no arguments) or of the test
        of ``condition`` (index) at ``level`` (index into the tests)."""
        cell = "s" if condition is None else f"{condition}-{level}"
        k, shown_holds = self.k, _holds(self.shown, self.n_shown, self.k)
        if self.protocol.name == "afterimage":
            flash = tuple(f"f-{cell}-{i}" for i in range(self.shown))
            c = 0 if condition is None else condition
            after = tuple(f"a-{c}-{i}" for i in range(self.blanks))
            return Interval(
                flash + after, shown_holds + _holds(self.blanks, self.n_blank, k), self.shown
            )
        chart = tuple(f"c-{cell}-{i}" for i in range(self.shown))
        return Interval(chart + ("black",), shown_holds + (self.n_blank,), self.shown)


def _check_levels(protocol, display):
    """Refuse a protocol whose dimmest level is not above the display's black."""
    dimmest = min(protocol.standard, *protocol.tests)
    if dimmest <= display.black:
        raise ValueError(
            f"display: black {display.black:g} cd/m2 is not below the dimmest level of the "
            f"{protocol.name} study, {dimmest:g} cd/m2"
        )


def _white_tile(width, height):
    """Mask ``(H, W)`` of the chart's white tile (no. 19, its brightest) in
    :func:`jaxadapt.scenes.mesopic` at this size."""
    from jaxadapt import scenes

    chart = scenes.mesopic(width, height, 1.0, 1.0)
    Y = photopic_luminance(np.asarray(chart.render(chart.times[:1])[0]))
    return np.asarray(Y > 0.95 * np.max(Y))


def _even(pixels):
    """``pixels`` rounded to an even whole number (the image has a centre
    between pixels, as the scenes' fixation), at least 8."""
    return max(8, 2 * round(pixels / 2))
