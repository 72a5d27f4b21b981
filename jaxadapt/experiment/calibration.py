"""A calibrated display: which luminance each 8-bit code value shows, and
the codes that show a given luminance on average.

A :class:`Display` is the model of the monitor a live experiment runs on:
its peak white and black (cd/m2, measured with a photometer), its transfer
(sRGB, a power law, or SMPTE ST 2084 PQ), the viewing distance and pixel
pitch (pixels per degree) and its refresh rate. :meth:`Display.emitted`
is the luminance a channel's code value shows; :func:`dithered_codes`
chooses, for each channel of each pixel, between the two codes around the
luminance asked with the probability that makes their mean that luminance.

Choice: the dithering is in linear light. The 2015 operator's temporal
dithering (Jacobs et al. 2015, §2.4; :func:`jaxadapt.display.dither`)
rounds the encoded value up with the probability of its fraction, so that
the mean *code* is right; a few codes above black, where one code step is
a large ratio of luminance (on a gamma 2.2 display code 1 shows 0.0005 %
of white and code 2 4.6 times that), the mean *luminance* of such
rounding is off: by 15 % at 1.2e-3 cd/m2 on a 100 cd/m2 display, the
darkest tile of the mesopic study's chart. A psychophysical stimulus must have
the luminance asked, so here the probability is taken between the two
codes' emitted luminances.
"""

import dataclasses
import json
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["TRANSFERS", "CODES", "Display", "PAPER_DISPLAY", "read_display", "dithered_codes"]

#: Transfers a display file may name: the code value to relative (sRGB,
#: gamma) or absolute (PQ) light.
TRANSFERS = ("srgb", "gamma", "pq")

#: Code values per channel.
CODES = 256


@dataclasses.dataclass(frozen=True)
class Display:
    """A monitor as a photometer measures it, and where the viewer sits.

    Attributes
    ----------
    white, black : float
        Luminance of code 255 and of code 0 on every channel, cd/m2.
    transfer : str
        ``"srgb"``, ``"gamma"`` (``gamma``) or ``"pq"``: code to light. For
        sRGB and gamma the light is ``black + (white - black) EOTF(code)``;
        for PQ ``black + min(EOTF(code), white)``, EOTF in cd/m2.
    gamma : float
        Exponent of the ``"gamma"`` transfer.
    distance_m : float
        Viewing distance, m.
    pixel_pitch_mm : float
        Size of a pixel on the screen, mm.
    refresh_hz : float
        Frames per second the display shows.
    """

    white: float = 100.0
    black: float = 0.0
    transfer: str = "srgb"
    gamma: float = 2.2
    distance_m: float = 1.0
    pixel_pitch_mm: float = 0.6e3 * 16 / math.hypot(16, 9) / 1920
    refresh_hz: float = 60.0

    def __post_init__(self):
        def positive(name, value):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: expected a positive number, got {value!r}")

        for name in ("white", "gamma", "distance_m", "pixel_pitch_mm", "refresh_hz"):
            positive(name, getattr(self, name))
        if not (isinstance(self.black, (int, float)) and 0 <= self.black < self.white):
            raise ValueError(
                f"black: expected a luminance from 0 up to white ({self.white} cd/m2), "
                f"got {self.black!r}"
            )
        if self.transfer not in TRANSFERS:
            raise ValueError(
                f"transfer: expected one of {', '.join(TRANSFERS)}, got {self.transfer!r}"
            )

    @property
    def pixels_per_degree(self):
        """Pixels in one degree of visual angle at the centre of the screen."""
        degree = 2 * self.distance_m * 1e3 * math.tan(math.radians(0.5))  # mm
        return degree / self.pixel_pitch_mm

    def emitted(self, codes):
        """Luminance a channel shows at 8-bit ``codes`` (any shape), cd/m2."""
        from colour.models import eotf_sRGB, eotf_ST2084

        v = np.asarray(codes, float) / (CODES - 1)
        if self.transfer == "pq":
            return self.black + np.minimum(eotf_ST2084(v), self.white)
        relative = eotf_sRGB(v) if self.transfer == "srgb" else v**self.gamma
        return self.black + (self.white - self.black) * relative

    def to_json(self):
        """The fields as a dict (what :func:`read_display` reads back)."""
        return dataclasses.asdict(self)


#: The display the 2015 paper assumes (Appendix A): a 0.6 m diagonal
#: 1920x1080 monitor 1 m away (64 pixels a degree), here an OLED (black 0,
#: as the paper's Sony PVM-2541) of 100 cd/m2 white, sRGB, 60 Hz.
PAPER_DISPLAY = Display()


def read_display(path):
    """A :class:`Display` from a JSON file of its fields (any left out take
    :data:`PAPER_DISPLAY`'s values).

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Not a JSON object, an unknown key, or a value out of range; the
        message names the file and the key.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file (expected a display's JSON file)")
    try:
        fields = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"{path}: expected a display's JSON object, got {error}") from None
    if not isinstance(fields, dict):
        raise ValueError(f"{path}: expected a JSON object of display fields, got {fields!r:.60}")
    known = [f.name for f in dataclasses.fields(Display)]
    unknown = [k for k in fields if k not in known]
    if unknown:
        raise ValueError(f"{path}: unknown key {unknown[0]!r} (expected {', '.join(known)})")
    try:
        return Display(**fields)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None


def dithered_codes(display, luminance, key):
    """8-bit codes that show ``luminance`` on ``display`` on average.

    Each channel of each pixel takes the code ``c`` whose light is at or
    below the luminance asked, or ``c + 1`` with probability
    ``(L - E(c)) / (E(c + 1) - E(c))`` (``E``: :meth:`Display.emitted`), one
    uniform draw each from ``key`` (change it every frame: the pattern then
    varies in space and time): the expected light is ``L`` exactly for
    ``L`` from black to white. Below black, code 0; above white, 255.

    Parameters
    ----------
    display : Display
    luminance : array, (..., 3)
        Linear RGB in cd/m2 per channel (white: ``(w, w, w)``).
    key : PRNG key

    Returns
    -------
    numpy array of uint8, the shape of ``luminance``.
    """
    table = jnp.asarray(display.emitted(np.arange(CODES)), jnp.float32)
    return np.asarray(_dithered(table, jnp.asarray(luminance, jnp.float32), key))


@jax.jit
def _dithered(table, L, key):
    c = jnp.clip(jnp.searchsorted(table, L, side="right") - 1, 0, CODES - 2)
    low, high = table[c], table[c + 1]
    p = jnp.clip((L - low) / jnp.maximum(high - low, 1e-30), 0.0, 1.0)
    u = jax.random.uniform(key, L.shape, L.dtype)
    return (c + (u < p)).astype(jnp.uint8)
