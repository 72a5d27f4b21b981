"""Parameters of the renderer: :class:`Params`, with Appendix A's defaults
where the paper gives them, and the constants they derive from (the
afterimage colour matrix ``H`` of Appendix A, the scotopic colour of
mesopic vision, the paper's display of §2.3.3 and the acuity sizes in
degrees); the field groups that the checks use; :func:`only` to switch
effects on by name.

The bottom layer of the package: every other module reads ``Params``, and
this one imports none of them. The choices where the paper is silent (the
"module notes" cited below) are listed in the package's docstring,
:mod:`jaxadapt.operators.jacobs2015`.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt._checks import check_value, float_array
from jaxadapt.color import W_PHOTOPIC, W_SCOTOPIC
from jaxadapt.operators import OPERATORS
from jaxadapt.operators.checks import check_fields

#: Appendix A: LMS bleaching deviations to RGB afterimage colour.
H_AFTERIMAGE = np.array([[1.14, -1.18, 0.36], [-0.08, 1.02, 0.18], [0.30, -0.11, 1.25]])

#: Colour ratio (linear BT.709 RGB with photopic luminance 1) towards which
#: mesopic colours drift: a dull purple, the scotopic appearance of a
#: neutral chip described by Shin et al. (2004). The paper does not give
#: it; this one has hue 286 degrees and saturation 0.32 (HSV of the linear
#: ratio; 0.16 once gamma-encoded for display): red and blue above green, as
#: in "dull purple".
SCOTOPIC_COLOUR = np.array([1.25, 0.92, 1.35]) / (np.array([1.25, 0.92, 1.35]) @ W_PHOTOPIC)

#: Resolution of the paper's display at the viewer (§2.3.3: a 0.6 m diagonal
#: 1920x1080 monitor 1 m away): 64 pixels per degree.
PAPER_PIXELS_PER_DEGREE = 64.0


#: ``sigma_0`` of the acuity bands, degrees: Appendix A's 0.75 pixels on the
#: paper's display (64 pixels per degree).
ACUITY_SIGMA0_DEG = 0.75 / PAPER_PIXELS_PER_DEGREE
#: Spacing of the acuity noise, degrees: 16 pixels on the paper's display.
ACUITY_NOISE_CELL_DEG = 16 / PAPER_PIXELS_PER_DEGREE


def _concrete_ppd(ppd):
    """``pixels_per_degree`` as one Python float, for the static acuity
    sizes; a ValueError where it is traced or a batch of different values."""
    try:
        values = np.unique(np.asarray(ppd, dtype=np.float64))
    except (jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError):
        values = None
    if values is None or values.size != 1:
        raise ValueError(
            "acuity_sigma0, acuity_noise_cell: their defaults follow pixels_per_degree, which "
            "must then be one concrete value; give both in pixels for a traced or batched "
            "pixels_per_degree"
        )
    return float(values[0])


class Params(eqx.Module):
    """Parameters of the renderer; numeric fields are arrays so that a batch of
    parameter sets can be ``vmap``-ped. Defaults are Appendix A of the paper
    where it gives them.

    Attributes
    ----------
    gamma : float
        Display gamma compensation, ``J = R^gamma`` (0.455).
    n : float
        Naka-Rushton exponent of Eq 1 (0.7).
    a1, a2 : float
        Adaptation rates to brighter and darker targets, log10 units/s
        (0.75, 0.2; Eq 3).
    b1 : array, (3,)
        L, M, S bleaching rates, 1/(cd/m2 s) (1.2e-3, 1.4e-4, 5.5e-7; Eq 4).
    b2 : array, (3,)
        L, M, S regeneration rates, 1/s (0.69, 1.4, 5.5; Eq 4).
    c1, c2 : float
        Calcium influx and efflux rates, 1/s (1, 1; Eq 8).
    j1, j2 : float
        Bleaching and adaptation afterimage strengths (0.03, 0.15; Eq 12).
    m1, m2 : float
        Upper and lower ends of the mesopic range, log10 cd/m2 (0, -2; Eq 13).
    w_P : array, (3,)
        Photopic luminance weights of RGB (0.2126, 0.7152, 0.0722).
    w_S : array, (3,)
        Scotopic luminance weights, Appendix A's (0, 0.8451, 0.1459) scaled to
        sum to one (:data:`jaxadapt.color.W_SCOTOPIC`), so that the Purkinje
        shift leaves neutral pixels alone.
    rho_step : float
        Acuity thresholds ``rho_i = rho_step i``, log10 units (0.286; Eq 15).
    g : float
        Standard deviation of the stochastic acuity threshold (0.25; Eq 15).
    H : array, (3, 3)
        LMS bleaching to RGB afterimage colour (Appendix A).
    adaptation_floor : float
        Lowest luminance the viewer adapts to, cd/m2 (100; §2.4).
    plateau_max, plateau_sigma, plateau_n : float
        Plateau ``M(I) = plateau_max I^q / (I^q + plateau_sigma^q)``,
        ``q = plateau_n``, of Eq 2 (0.8, 1e4 cd/m2, 0.25; our choice);
        ``plateau_max`` in (0, 1).
    calcium_epsilon : float
        Regularisation of Eq 11 as a fraction of ``C_max``, positive (1e-3;
        see module notes).
    scotopic_colour : array, (3,)
        Colour ratio of mesopic desaturation (:data:`SCOTOPIC_COLOUR`).
    pixels_per_degree : float
        Resolution at the eye (64, the paper's display).
    afterimage_falloff_deg : float
        Standard deviation of the Gaussian visibility of afterimages around
        the fovea, degrees (5; §2.4, our choice).
    acuity_noise_period : float
        Spacing in time of the acuity noise ``X``, s (0.25; our choice).
    levels : float
        Top code value of the dithered display (255: 8 bits; §2.4).
    acuity_sigma0 : float
        ``sigma_0`` of the acuity bands, pixels; ``sigma_i = sigma_0
        2^(i/4)``. Default: :data:`ACUITY_SIGMA0_DEG` times
        ``pixels_per_degree`` (0.75 pixels on the paper's display, Appendix
        A), so that the bands are the same angles on any display. Static (it
        sets kernel lengths): resolved when the Params are made, from a
        concrete ``pixels_per_degree``.
    acuity_bands : int
        Number of Gaussian kernels (8: ``i = 0..7``). Static.
    acuity_noise_cell : float
        Spacing in space of the acuity noise, pixels. Default:
        :data:`ACUITY_NOISE_CELL_DEG` times ``pixels_per_degree`` (16 pixels
        on the paper's display), at least 1 pixel (finer noise is per-pixel
        noise). Static, resolved like ``acuity_sigma0``.
    afterimage_blur : float
        Standard deviation of the blur of the ``B`` and ``C`` maps between
        frames, pixels (1; 0 for none; §2.4). Static. As in the paper it is
        applied "between each displayed frame", so the spread it causes
        grows with the frame rate: 1 pixel suits 30 frames per second at
        the paper's 64 pixels per degree (0.086 degree after 1 s);
        :func:`blur_for_display` gives the same spread on other displays.
    global_adaptation, bleaching, local_adaptation, purkinje, mesopic_colour,
    acuity, dithering : bool
        Switch each effect on or off. Static. Off, global adaptation stays
        at its initial state; local adaptation off uses Eq 7 instead of 12.
    """

    gamma: jax.Array = eqx.field(default=0.455, converter=float_array)
    n: jax.Array = eqx.field(default=0.7, converter=float_array)
    a1: jax.Array = eqx.field(default=0.75, converter=float_array)
    a2: jax.Array = eqx.field(default=0.2, converter=float_array)
    b1: jax.Array = eqx.field(default=(1.2e-3, 1.4e-4, 5.5e-7), converter=float_array)
    b2: jax.Array = eqx.field(default=(6.9e-1, 1.4, 5.5), converter=float_array)
    c1: jax.Array = eqx.field(default=1.0, converter=float_array)
    c2: jax.Array = eqx.field(default=1.0, converter=float_array)
    j1: jax.Array = eqx.field(default=0.03, converter=float_array)
    j2: jax.Array = eqx.field(default=0.15, converter=float_array)
    m1: jax.Array = eqx.field(default=0.0, converter=float_array)
    m2: jax.Array = eqx.field(default=-2.0, converter=float_array)
    w_P: jax.Array = eqx.field(default=tuple(W_PHOTOPIC), converter=float_array)
    w_S: jax.Array = eqx.field(default=tuple(W_SCOTOPIC), converter=float_array)
    rho_step: jax.Array = eqx.field(default=0.286, converter=float_array)
    g: jax.Array = eqx.field(default=0.25, converter=float_array)
    H: jax.Array = eqx.field(default=tuple(map(tuple, H_AFTERIMAGE)), converter=float_array)
    adaptation_floor: jax.Array = eqx.field(default=100.0, converter=float_array)
    plateau_max: jax.Array = eqx.field(default=0.8, converter=float_array)
    plateau_sigma: jax.Array = eqx.field(default=1e4, converter=float_array)
    plateau_n: jax.Array = eqx.field(default=0.25, converter=float_array)
    calcium_epsilon: jax.Array = eqx.field(default=1e-3, converter=float_array)
    scotopic_colour: jax.Array = eqx.field(default=tuple(SCOTOPIC_COLOUR), converter=float_array)
    pixels_per_degree: jax.Array = eqx.field(default=PAPER_PIXELS_PER_DEGREE, converter=float_array)
    afterimage_falloff_deg: jax.Array = eqx.field(default=5.0, converter=float_array)
    acuity_noise_period: jax.Array = eqx.field(default=0.25, converter=float_array)
    levels: jax.Array = eqx.field(default=255.0, converter=float_array)
    acuity_sigma0: float = eqx.field(default=None, static=True)
    acuity_bands: int = eqx.field(default=8, static=True)
    acuity_noise_cell: float = eqx.field(default=None, static=True)
    afterimage_blur: float = eqx.field(default=1.0, static=True)
    global_adaptation: bool = eqx.field(default=True, static=True)
    bleaching: bool = eqx.field(default=True, static=True)
    local_adaptation: bool = eqx.field(default=True, static=True)
    purkinje: bool = eqx.field(default=True, static=True)
    mesopic_colour: bool = eqx.field(default=True, static=True)
    acuity: bool = eqx.field(default=True, static=True)
    dithering: bool = eqx.field(default=True, static=True)

    def __post_init__(self):
        # The acuity sizes in pixels, from their angles (static: kernel lengths).
        if self.acuity_sigma0 is None or self.acuity_noise_cell is None:
            ppd = _concrete_ppd(self.pixels_per_degree)
            if self.acuity_sigma0 is None:
                self.acuity_sigma0 = ACUITY_SIGMA0_DEG * ppd
            if self.acuity_noise_cell is None:
                self.acuity_noise_cell = max(1.0, ACUITY_NOISE_CELL_DEG * ppd)

    def __check_init__(self):
        if not (self.acuity_sigma0 > 0):
            raise ValueError(f"acuity_sigma0: expected > 0 pixels, got {self.acuity_sigma0!r}")
        if not (isinstance(self.acuity_bands, int) and self.acuity_bands >= 1):
            raise ValueError(f"acuity_bands: expected an int >= 1, got {self.acuity_bands!r}")
        if not (self.acuity_noise_cell > 0 and math.isfinite(self.acuity_noise_cell)):
            raise ValueError(
                f"acuity_noise_cell: expected > 0 pixels, got {self.acuity_noise_cell!r}"
            )
        for name, shape in CHANNEL_FIELDS.items():
            value = getattr(self, name)
            if jnp.shape(value)[-len(shape) :] != shape:
                raise ValueError(
                    f"{name}: expected shape {shape} (leading axes may batch), got shape "
                    f"{jnp.shape(value)}"
                )
        check_value("rho_step", self.rho_step, lambda v: v >= 0, ">= 0 log10 units")
        # m1 = m2 divided by 0 in Eq 13 (rho infinite), m1 < m2 turned rho around.
        check_value(
            "m1 - m2",
            self.m1 - self.m2,
            lambda v: v > 0,
            "the mesopic range's upper end m1 above its lower end m2 (log10 cd/m2)",
        )
        # M >= 1 makes sigma of Eq 2 NaN (and M = 0 infinite): a black frame.
        check_value("plateau_max", self.plateau_max, lambda v: (v > 0) & (v < 1), "in (0, 1)")
        check_fields(self, positive=POSITIVE_FIELDS, non_negative=NON_NEGATIVE_FIELDS)
        if not (self.afterimage_blur >= 0):
            raise ValueError(f"afterimage_blur: expected >= 0 pixels, got {self.afterimage_blur!r}")

    @property
    def stochastic(self):
        """Whether the rendering draws random numbers (acuity loss, dithering)."""
        return self.acuity or self.dithering


#: The fields of :class:`Params` with one value per cone or channel, and
#: their shapes (leading axes may batch them).
CHANNEL_FIELDS = {
    "b1": (3,),
    "b2": (3,),
    "w_P": (3,),
    "w_S": (3,),
    "H": (3, 3),
    "scotopic_colour": (3,),
}
#: The fields of :class:`Params` that must be positive and finite (rates,
#: exponents, scales and the display's levels).
POSITIVE_FIELDS = (
    "gamma",
    "n",
    "a1",
    "a2",
    "b1",
    "b2",
    "c1",
    "c2",
    "plateau_sigma",
    "plateau_n",
    "calcium_epsilon",
    "pixels_per_degree",
    "afterimage_falloff_deg",
    "acuity_noise_period",
    "levels",
)

#: The fields of :class:`Params` that must be finite and at least 0 (the
#: afterimage strengths and the acuity noise's spread).
NON_NEGATIVE_FIELDS = ("j1", "j2", "g")

#: The effects that :class:`Params` can switch off, in the pipeline's order
#: (the registry's, :data:`jaxadapt.operators.OPERATORS`).
EFFECTS = OPERATORS.supports("jacobs2015").effects


def only(*effects, **fields):
    """:class:`Params` with only ``effects`` (names from :data:`EFFECTS`)
    switched on and the other ``fields`` as given.

    Global adaptation is not one of the effects: it stays on unless
    ``global_adaptation=False`` is given.

    Examples
    --------
    >>> p = only("purkinje")
    >>> p.purkinje, p.bleaching, p.global_adaptation
    (True, False, True)
    """
    unknown = sorted(set(effects) - set(EFFECTS))
    if unknown:
        raise ValueError(f"effects: expected names from {EFFECTS}, got {unknown}")
    return Params(**{name: name in effects for name in EFFECTS}, **fields)
