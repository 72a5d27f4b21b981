"""The gaze-aware renderer of very bright and very dark scenes of Jacobs et al. (2015).

A viewer looks around a calibrated HDR scene; a gaze path says where. Each
frame is rendered for an ordinary display with the epiphenomena of extreme
light levels::

    frame (cd/m2) --+-- local rho (Eq 13) --> acuity loss (Eqs 14-15) --> scene
                    |                                                       |
                    |     A (Eq 3) -> sigma (Eq 2) -> R (Eq 1), Purkinje,   |
                    |                                 mesopic colour  <-----+
                    |                                       |
                    +-- LMS -> B, C maps (Eqs 4-10) -> alpha^j2 R + j1 C/C_max (B - B_inf)
                                                            |
                                    J = clip(.)^gamma, temporal dithering (§2.4)

State: the log adaptation level ``A`` (a scalar, Eq 3) and, per pixel and
per cone (L, M, S), the bleached fraction ``B`` (Eqs 4-6) and the calcium
concentration ``C`` (Eqs 8-10). The maps are locked to the retina: they
are stored aligned with the current fixation and shifted with every gaze
movement (by whole pixels, between rounded gaze points, so that slow pursuit
does not drift), blurred between frames, and their visibility falls off as a
Gaussian around the fovea (§2.4). The per-pixel state advances by the exact
steps of :mod:`jaxadapt.physiology.kinetics` in a ``lax.scan`` over frames.

Timing: as in :mod:`jaxadapt.operators.pattanaik2000`, frame ``k`` is seen
with the state reached at its start; its input is then held for ``dt_k`` to
give the next state.

Choices where the paper is silent or garbled (each a :class:`Params` field
and tested in ``tests/test_jacobs2015.py``):

* **Plateau M** (Eq 2). The paper says only that M "has a form similar to
  Eq. (1)". We use ``M(I) = plateau_max I^q / (I^q + plateau_sigma^q)``
  (0.8, 1e4 cd/m2, q = 0.25): the adapted luminance is shown at 19 % of
  the display's linear range at 100 cd/m2 (the adaptation floor of §2.4,
  below which A does not go), 40 % at 1e4 cd/m2 and 68 % at 1e7 cd/m2, so
  brighter scenes look brighter, and M < 1 keeps sigma finite.
* **Adaptation target**: "the log of the average scene luminance in a
  small patch around the user's gaze" (§2.1), read as written: log10 of the
  foveally weighted mean of photopic luminance
  (:func:`jaxadapt.operators.goal.foveal_average`, a 1-degree patch), not
  the mean of its logs, floored at ``adaptation_floor`` (100 cd/m2, §2.4).
  A small bright source at the gaze then darkens the scene, as Fig. 2
  describes: a 1e6 cd/m2 lamp 12 pixels wide on a 20 cd/m2 field, fixated
  at 64 pixels per degree, gives 10^4.6 cd/m2 where the log average (31
  cd/m2) stayed at the floor.
* **rho** (Eq 13) is computed per pixel from the *local* photopic luminance,
  the scene blurred at the coarsest acuity scale ``sigma_7``: the paper ties
  acuity to "the local luminance level", and since the adaptation level
  never falls below the floor of §2.4, a rho from it would never be mesopic.
  Purkinje shift and mesopic colour use rho clamped to [0, 1].
* **Acuity thresholds**: Appendix A gives ``rho_i = 0.286 i`` "in
  log-luminance": 0 to 2 log units, the width ``m1 - m2`` of the mesopic
  range, so they are compared with the normalised rho after division by
  ``m1 - m2``. As printed, band ``i`` (``sigma_i`` growing with ``i``) would
  need the most light for the *coarsest* detail; the finest detail is lost
  first in the dark (Riggs 1965, the paper's Fig. 11 insets), so the band of
  fineness ``f`` (0 = finest) gets threshold ``rho_(7-f)``. rho is *not*
  clamped for acuity: clamped to 1, photopic scenes would keep flickering.
* **Total darkness**: Eq 11 is ``alpha = (C_max - C_inf) / (C_max - C)``,
  0/0 once calcium reaches ``C_max``. We use
  ``alpha = (C_max - C_inf + e) / (C_max - C + e)`` with
  ``e = calcium_epsilon C_max``: 1 (no gain) in the 0/0 limit, and bounded
  by about ``1/calcium_epsilon`` when light returns after long darkness (the
  brief boost of Fig. 1, frame 4). It departs from Eq 11 where the
  responses ``C_max - C`` and ``C_max - C_inf`` approach ``e``: at the
  adaptation floor (sigma = 778 cd/m2) within 2 % of Eq 11's gain
  ``alpha^j2`` from 10 cd/m2 up, and in mesopic light less: 1.35 against
  1.62 for a pixel adapted to 0.01 cd/m2 and shown 1 cd/m2, 0.74 against
  0.62 the other way. ``calcium_epsilon`` must be positive: at 0, after
  long darkness C rounds to C_max and ``alpha`` is infinite (the frame went
  black, its gradients NaN).
* **Colour**: cone excitations are Hunt-Pointer-Estevez LMS of the BT.709
  pixels, scaled so that white excites the three cones equally (Fig. 4:
  "white (stimulating all cone types equally)"). The local-adaptation gain
  multiplies the tone-mapped image in this LMS space; the bleaching term
  goes to RGB through the matrix ``H`` of Appendix A.
* **Acuity loss** changes only what is displayed; the photoreceptor state
  (``B``, ``C``) and the adaptation target are driven by the frame itself.
* **Gaze**: points outside the frame are clipped to its edge (an eye
  tracker reports the viewer looking just off screen; the nearest pixel is
  the best estimate of the fixation on it); samples that are not finite
  (NaN) are blinks and hold the last fixation.

References
----------
Jacobs, Gallo, Cooper, Pulli, Levoy (2015), *Simulating the Visual
Experience of Very Bright and Very Dark Scenes*, ACM TOG 34(3), §2, §2.4 and
Appendix A.
"""

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt._checks import check_value, float_array
from jaxadapt.background import LUMINANCE_FLOOR
from jaxadapt.color import LMS_TO_RGB, RGB_TO_LMS, W_PHOTOPIC, W_SCOTOPIC, transform
from jaxadapt.display import dither
from jaxadapt.gaze import fixation, frame_centre
from jaxadapt.operators.checks import (
    as_dtype,
    check_adaptation,
    check_fields,
    check_frames,
    check_frames_and_dt,
    check_one_parameter_set,
    check_state,
    frames_and_dt_messages,
    frames_messages,
    is_traced,
    raise_verdict,
)
from jaxadapt.operators.goal import foveal_average
from jaxadapt.physiology import kinetics
from jaxadapt.physiology.response import naka_rushton, power
from jaxadapt.spatial import (
    discrete_gaussian_kernel,
    gaussian_blur,
    separable_filter,
)

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

#: The effects that :class:`Params` can switch off, in the pipeline's order.
EFFECTS = ("bleaching", "local_adaptation", "purkinje", "mesopic_colour", "acuity", "dithering")


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


class State(NamedTuple):
    """State of the viewer.

    Attributes
    ----------
    A : array, ()
        Adaptation level, log10 cd/m2 (Eq 3).
    B : array, (H, W, 3)
        Bleached fraction of L, M, S pigment, in [0, 1], aligned with ``gaze``.
    C : array, (H, W, 3)
        Calcium concentration of L, M, S cones, in ``[0, c1/c2]``.
    gaze : array, (2,)
        Fixation ``(x, y)``, pixels, inside the frame; the maps are aligned
        with its rounded value.
    t : array, ()
        Time since the first frame, s.
    frame : array, () int
        Index of the next frame.
    key : PRNG key
        Key of the sequence (acuity noise and dithering).
    """

    A: jax.Array
    B: jax.Array
    C: jax.Array
    gaze: jax.Array
    t: jax.Array
    frame: jax.Array
    key: jax.Array


class Diagnostics(NamedTuple):
    """Per-frame record of a :func:`run` (leading axis: frames).

    Attributes
    ----------
    t : array, (T,)
        Time of each frame, s.
    A : array, (T,)
        Adaptation level the frame was seen with, log10 cd/m2.
    A_T : array, (T,)
        Adaptation target of the frame, log10 cd/m2 (floored).
    sigma : array, (T,)
        Semi-saturation luminance of Eq 2, cd/m2.
    gaze : array, (T, 2)
        Fixation used, pixels (clipped, blinks filled).
    B_gaze, C_gaze : array, (T, 3)
        L, M, S bleaching and calcium at the fixation.
    rho_gaze : array, (T,)
        Normalised local log luminance (Eq 13, unclamped) at the fixation.
    final_state : State
        State after the last frame, to continue a sequence.
    """

    t: jax.Array
    A: jax.Array
    A_T: jax.Array
    sigma: jax.Array
    gaze: jax.Array
    B_gaze: jax.Array
    C_gaze: jax.Array
    rho_gaze: jax.Array
    final_state: State


# -- global adaptation (Eqs 1-3) -----------------------------------------------


def plateau(params, I):
    """Plateau response ``M(I)`` to a steady luminance ``I`` (cd/m2), in (0, 1).

    The Naka-Rushton form the paper describes (Dowling 1987), with its own
    maximum, semi-saturation and exponent (module notes).
    """
    x = (I / params.plateau_sigma) ** params.plateau_n
    return params.plateau_max * x / (1.0 + x)


def semi_saturation(params, A):
    """sigma of Eq 2 for adaptation ``A`` (log10 cd/m2), cd/m2.

    ``sigma = (I^n / M(I) - I^n)^(1/n) = I (1/M(I) - 1)^(1/n)``, ``I = 10^A``:
    the response to the adapting luminance itself is the plateau ``M(I)``.

    Examples
    --------
    >>> p = Params()
    >>> s = semi_saturation(p, jnp.float32(2.0))
    >>> round(float(naka_rushton(100.0, s, 1.0, p.n) / plateau(p, 100.0)), 5)
    1.0
    """
    I = 10.0**A
    return I * (1.0 / plateau(params, I) - 1.0) ** (1.0 / params.n)


def adaptation_target(params, frame, gaze):
    """Target ``A_T`` of Eq 3: log10 of the foveal average photopic
    luminance around ``gaze``, floored at ``adaptation_floor`` (§2.4)."""
    L = transform(frame, params.w_P)
    mean = foveal_average(L, gaze, params.pixels_per_degree)
    return jnp.log10(jnp.maximum(mean, params.adaptation_floor))


# -- mesopic vision (Eqs 13-15) -----------------------------------------------


def acuity_sigmas(params):
    """Standard deviations ``sigma_i = sigma_0 2^(i/4)``, pixels (Appendix A)."""
    return [params.acuity_sigma0 * 2.0 ** (i / 4.0) for i in range(params.acuity_bands)]


def normalised_log_luminance(params, L):
    """``rho = (log10 L - m2) / (m1 - m2)`` (Eq 13), unclamped; ``L`` in cd/m2."""
    return (jnp.log10(jnp.maximum(L, LUMINANCE_FLOOR)) - params.m2) / (params.m1 - params.m2)


def local_rho(params, frame):
    """rho (Eq 13) of the local photopic luminance: the frame's luminance
    blurred at the coarsest acuity scale. ``frame (H, W, 3)`` -> ``(H, W)``."""
    L = gaussian_blur(transform(frame, params.w_P), acuity_sigmas(params)[-1])
    return normalised_log_luminance(params, L)


def _interpolation_matrix(n, cell):
    """Linear interpolation from a grid every ``cell`` pixels (any positive
    size) to ``n`` pixels, with each row scaled so that interpolated
    unit-variance white noise keeps unit variance: ``(n, floor(n / cell) +
    2)``, NumPy (static)."""
    pos = np.arange(n) / cell
    i, f = np.floor(pos).astype(int), pos - np.floor(pos)
    A = np.zeros((n, int(n // cell) + 2))
    A[np.arange(n), i] = 1.0 - f
    A[np.arange(n), i + 1] = f
    return A / np.sqrt((A**2).sum(axis=1, keepdims=True))


def acuity_noise(params, key, t, shape):
    """Noise ``X ~ N(0, 1)`` of Eq 15, smooth in space and time, ``(H, W)``.

    Independent normal samples on a grid every ``acuity_noise_cell`` pixels
    and ``acuity_noise_period`` seconds (the grid step ``j`` is folded into
    ``key``) are interpolated linearly in space and time, and rescaled so
    that every pixel's ``X`` is exactly standard normal: the loss of detail
    comes and goes in patches rather than per pixel (§2.3.3).
    """
    H, W = shape
    Ay = jnp.asarray(_interpolation_matrix(H, params.acuity_noise_cell), dtype=t.dtype)
    Ax = jnp.asarray(_interpolation_matrix(W, params.acuity_noise_cell), dtype=t.dtype)
    position = t / params.acuity_noise_period
    j = jnp.floor(position)
    f = position - j

    def grid(step):
        return jax.random.normal(
            jax.random.fold_in(key, step), (Ay.shape[1], Ax.shape[1]), dtype=t.dtype
        )

    before, after = jax.vmap(grid)(j.astype(jnp.int32) + jnp.arange(2))
    coarse = ((1.0 - f) * before + f * after) / jnp.sqrt((1.0 - f) ** 2 + f**2)
    return Ay @ coarse @ Ax.T


def acuity_thresholds(params):
    """Normalised threshold of each band, finest first: ``rho_(K-1-f) / (m1 - m2)``.

    The finest band needs the most light (module notes); ``rho_i =
    rho_step i`` is in log10 units, hence the division by ``m1 - m2``.
    """
    K = params.acuity_bands
    return params.rho_step * jnp.arange(K - 1, -1, -1) / (params.m1 - params.m2)


def acuity_loss(params, frame, rho, X):
    """Stochastic loss of acuity (Eqs 14-15), finest detail first.

    Eq 14 keeps the difference-of-Gaussian band ``f`` (0 = finest,
    ``blur_(f-1) - blur_f`` with ``blur_(-1)`` the frame) where
    ``rho + g X > threshold_f`` (:func:`acuity_thresholds`) and adds the
    low-pass ``blur_(K-1)``. The thresholds fall with coarseness
    (``rho_step >= 0``), so a pixel drops its ``d`` finest bands, and what it
    keeps telescopes to ``blur_(d-1)``: the frame blurred at the finest
    scale it still resolves. We select that blur per pixel, which gives
    Eq 14's sum without forming the ``K`` band images. Blurs of a
    non-negative frame are non-negative, so nothing undershoots.

    On the CPU the three colour planes are resolved one after another
    (``lax.map``), so that the resolved frame is stored once: as one
    vectorised expression, XLA's CPU backend fused the eight blurs (their
    horizontal passes) into each of the three fusions of the tone map that
    read the frame (luminance, colour ratios, colour) and computed them
    three times: the acuity loss took 0.34 s of a 1920x1080 frame's 0.75 s,
    and one plane at a time 0.12 s (the difference between the two frame
    rates of ``benchmarks/bench_jacobs2015.py``, 2 cores). Other platforms
    keep the vectorised form (the one measured on an H100).

    Parameters
    ----------
    frame : array, (H, W, 3)
        Linear RGB, cd/m2.
    rho : array, (H, W)
        Local normalised log luminance (Eq 13, unclamped).
    X : array, (H, W)
        Standard normal noise (:func:`acuity_noise`).

    Returns
    -------
    array, (H, W, 3)
        The frame as resolved, cd/m2.
    """
    visible = rho + params.g * X
    dropped = jnp.sum(visible[None] <= acuity_thresholds(params)[:, None, None], axis=0)

    def resolve(planes):
        seen = planes
        for f, sigma in enumerate(acuity_sigmas(params)):
            seen = jnp.where(dropped > f, gaussian_blur(planes, sigma), seen)
        return seen

    planes = jax.lax.platform_dependent(
        jnp.moveaxis(frame, -1, 0), cpu=lambda x: jax.lax.map(resolve, x), default=resolve
    )
    return jnp.moveaxis(planes, 0, -1)


def tone_map(params, scene, rho, sigma):
    """Global adaptation with the Purkinje shift and mesopic colour.

    The luminance fed to Eq 1 is photopic, blended towards scotopic by
    ``rho`` clamped to [0, 1] (Purkinje, Eq 13); colour is restored by the
    ratio ``rgb / L_photopic``, blended towards :data:`SCOTOPIC_COLOUR` by the
    same ``rho`` (mesopic hue shift and desaturation, §2.3.2).

    Parameters
    ----------
    scene : array, (H, W, 3)
        Linear RGB, cd/m2.
    rho : array, (H, W)
        Local normalised log luminance (unclamped).
    sigma : array, ()
        Semi-saturation luminance of Eq 2, cd/m2 (:func:`semi_saturation`).

    Returns
    -------
    array, (H, W, 3)
        Linear response ``ratio R(L)``: display-relative, 1 = white.
    """
    rho = jnp.clip(rho, 0.0, 1.0)
    L_P = transform(scene, params.w_P)
    L = rho * L_P + (1.0 - rho) * transform(scene, params.w_S) if params.purkinje else L_P
    R = naka_rushton(L, sigma, 1.0, params.n)
    positive = (L_P > 0)[..., None]
    ratio = jnp.where(positive, scene / jnp.where(positive, L_P[..., None], 1.0), 1.0)
    if params.mesopic_colour:
        ratio = rho[..., None] * ratio + (1.0 - rho[..., None]) * params.scotopic_colour
    return ratio * R[..., None]


# -- afterimages (Eqs 4-12, §2.4) ---------------------------------------------


class Receptors(NamedTuple):
    """Photoreceptor inputs of one frame, per pixel and cone (H, W, 3)."""

    lms: jax.Array
    B_inf: jax.Array
    R: jax.Array
    C_inf: jax.Array


def receptors(params, frame, sigma):
    """Cone excitations, equilibrium bleaching (Eq 6), responses (Eq 1) and
    equilibrium calcium (Eq 10) of a frame, for semi-saturation ``sigma``."""
    lms = transform(frame, RGB_TO_LMS)
    R = naka_rushton(lms, sigma, 1.0, params.n)
    return Receptors(
        lms,
        kinetics.cone_bleaching(lms, params.b1, params.b2).target,
        R,
        kinetics.calcium(R, params.c1, params.c2).target,
    )


def falloff(params, shape, gaze):
    """Visibility of afterimages: a Gaussian of ``afterimage_falloff_deg``
    around ``gaze`` (x, y pixels), ``(H, W)`` (§2.4)."""
    H, W = shape
    s = params.afterimage_falloff_deg * params.pixels_per_degree
    y = jnp.arange(H, dtype=gaze.dtype)[:, None]
    x = jnp.arange(W, dtype=gaze.dtype)[None, :]
    return jnp.exp(-0.5 * ((x - gaze[0]) ** 2 + (y - gaze[1]) ** 2) / s**2)


def local_gain(params, C, C_inf):
    """``alpha`` of Eq 11, regularised so that total darkness gives 1.

    ``(C_max - C_inf + e) / (C_max - C + e)``, ``e = calcium_epsilon C_max``
    (module notes).

    Examples
    --------
    >>> p = Params()
    >>> float(local_gain(p, jnp.float32(1.0), jnp.float32(1.0)))  # darkness: 0/0
    1.0
    """
    C_max = params.c1 / params.c2
    e = params.calcium_epsilon * C_max
    return (C_max - C_inf + e) / (C_max - C + e)


def afterimages(params, response, state, rec, visibility):
    """Add the afterimages of Eq 12 to a tone-mapped frame.

    ``J = alpha^(j2 v) R + j1 v H (C / C_max) max(B - B_inf, 0)``, with
    ``v`` the foveal visibility; ``alpha^(j2 v)`` acts on each cone's
    response (the tone-mapped frame in LMS). With local adaptation off it is
    Eq 7: ``J = R + j1 v H max(B - B_inf, 0)``.

    Parameters
    ----------
    response : array, (H, W, 3)
        Tone-mapped linear RGB (:func:`tone_map`).
    state : State
    rec : Receptors
        The frame's photoreceptor inputs.
    visibility : array, (H, W)
    """
    v = visibility[..., None]
    if params.local_adaptation:
        gain = power(local_gain(params, state.C, rec.C_inf), params.j2 * v)
        response = transform(transform(response, RGB_TO_LMS) * gain, LMS_TO_RGB)
    if params.bleaching:
        excess = jnp.maximum(state.B - rec.B_inf, 0.0)
        if params.local_adaptation:
            excess = excess * state.C * (params.c2 / params.c1)
        response = response + params.j1 * v * transform(excess, params.H)
    return response


def retinal_shift(maps, shift, fill):
    """Move retina-locked maps ``(H, W, 3)`` by ``shift`` (dx, dy) whole pixels.

    Pixel ``(y, x)`` takes the map's value at ``(y - dy, x - dx)``; pixels
    uncovered by the move (retina that was looking off screen) take their
    value from ``fill``. The map is read through clamped row and column
    indices (two gathers XLA fuses into the selection), not rolled: a
    dynamic ``jnp.roll`` concatenates the map with itself along each axis
    first, 25 ms against 5 ms for 1920x1080 maps on the CPU (2 cores).
    """
    H, W = maps.shape[:2]
    y = jnp.arange(H) - shift[1]
    x = jnp.arange(W) - shift[0]
    moved = jnp.take(jnp.take(maps, jnp.clip(y, 0, H - 1), axis=0), jnp.clip(x, 0, W - 1), axis=1)
    inside = ((y >= 0) & (y < H))[:, None] & ((x >= 0) & (x < W))[None, :]
    return jnp.where(inside[..., None], moved, fill)


def blur_maps(params, B, C, B_inf, C_inf):
    """Blur the bleaching and calcium maps between frames (§2.4), in one pass,
    by a discrete Gaussian of ``afterimage_blur`` pixels (exactly that
    variance at any width, so that :func:`blur_for_display` holds for the
    sub-pixel blurs of coarse displays).

    What is blurred is each map's departure from its equilibrium under the
    frame, ``B - B_inf`` and ``C - C_inf``: the afterimages (Eqs 7 and 11
    are written in them), which the paper blurs "to simulate the blurry
    nature of afterimages". Blurred whole, the maps of a steady scene seen
    with a steady gaze, which has no afterimage, left their equilibrium at
    every edge: a ring built up around a 1e6 cd/m2 lamp on a 20 cd/m2 field
    (display values moved by up to 0.029 in 2 s), where Eqs 4-12 have
    nothing change.

    A departure blurred onto a pixel whose equilibrium differs can carry
    it past the maps' bounds: beside a 1e8 cd/m2 sun just gone dark, the
    dark field's calcium (at its maximum ``C_max = c1 / c2``) got more,
    Eq 11's denominator ``C_max - C`` changed sign and the local gain was
    -0.015. The blurred maps are clipped to their ranges, ``B`` to [0, 1]
    and ``C`` to ``[0, C_max]``, as the kinetics keep them.
    """
    if params.afterimage_blur == 0:
        return B, C
    both = jnp.concatenate([B - B_inf, C - C_inf], axis=-1)
    blurred = separable_filter(
        jnp.moveaxis(both, -1, 0), discrete_gaussian_kernel(params.afterimage_blur)
    )
    blurred = jnp.moveaxis(blurred, 0, -1)
    C_max = params.c1 / params.c2
    return (
        jnp.clip(B_inf + blurred[..., :3], 0.0, 1.0),
        jnp.clip(C_inf + blurred[..., 3:], 0.0, C_max),
    )


#: Frame rate at which the default ``afterimage_blur`` (1 pixel a frame, at
#: the paper's 64 pixels per degree) is meant, frames per second.
PAPER_FPS = 30.0


def blur_for_display(pixels_per_degree, fps, blur=1.0):
    """The ``afterimage_blur`` (pixels a frame) that spreads the maps on a
    display of ``pixels_per_degree`` at ``fps`` as ``blur`` pixels a frame
    do on the paper's display (64 pixels per degree) at 30 fps.

    ``n`` Gaussian blurs of ``sigma`` compose to one of ``sigma sqrt(n)``,
    so after 1 s the maps have spread by ``sigma sqrt(fps) / ppd`` degrees;
    holding that angle gives ``sigma = blur (ppd / 64) sqrt(30 / fps)``.
    (Left at 1 pixel, the maps of the flash scene, 256 pixels over 10
    degrees at 30 fps, spread 0.21 degree in 1 s, where the paper's spread
    0.086.)

    Examples
    --------
    >>> blur_for_display(64.0, 30.0), round(blur_for_display(25.6, 120.0), 3)
    (1.0, 0.2)
    """
    return float(blur * pixels_per_degree / PAPER_PIXELS_PER_DEGREE * math.sqrt(PAPER_FPS / fps))


# -- gaze ---------------------------------------------------------------------


def encode(params, R):
    """Display values ``J = clip(R, 0, 1)^gamma`` of linear responses ``R``
    (§2.4, the display's gamma compensation, ``gamma = 0.455``)."""
    return power(jnp.clip(R, 0.0, 1.0), params.gamma)


def decode(params, J):
    """Linear display values ``J^(1/gamma)`` of display values ``J`` in [0, 1]:
    the inverse of :func:`encode` (before dithering), for measuring frames."""
    return power(J, 1.0 / params.gamma)


def _pixel(gaze):
    """The pixel of a gaze point, rounding halves up (not to even), so that
    equal moves of the gaze give equal moves of the maps."""
    return jnp.floor(gaze + 0.5).astype(jnp.int32)


def _check_gaze(gaze, shape, dtype):
    gaze = jnp.asarray(gaze)
    if gaze.shape != shape:
        raise ValueError(f"gaze: expected shape {shape} in pixels (x, y), got shape {gaze.shape}")
    return gaze.astype(dtype)


def _default_gaze(gaze, frames, rank):
    """The checked gaze for a frame (rank 3) or sequence (rank 4); None means
    fixation at the centre. Left None for frames of the wrong rank, which
    the frame check then rejects."""
    if frames.ndim != rank:
        return None
    leading = frames.shape[:1] if rank == 4 else ()
    if gaze is None:
        gaze = jnp.broadcast_to(frame_centre(frames.shape[-3:-1], frames.dtype), leading + (2,))
    return _check_gaze(gaze, leading + (2,), frames.dtype)


def _as_frame_dtype(dt, frames):
    """``dt`` as an array of the frames' floating type, so that a Python
    float, a NumPy scalar and an array of the same shape share one trace."""
    floating = jnp.issubdtype(frames.dtype, jnp.floating)
    return jnp.asarray(dt, dtype=frames.dtype if floating else None)


def _check_key(params, key):
    if key is None:
        if params.stochastic:
            raise ValueError(
                "key: expected a PRNG key (jax.random.key(seed)) for the acuity loss and "
                "dithering, got None (or switch both off in Params)"
            )
        return jax.random.key(0)
    return key


# -- one frame ----------------------------------------------------------------


def _frame(params, state, frame, dt, sample):
    """Show ``frame`` to the viewer in ``state``; return the next state, the
    display frame and the frame's record (:class:`Diagnostics` without
    ``final_state``). The whole operator is this map."""
    shape = frame.shape[:2]
    gaze = fixation(sample, state.gaze, shape)
    sigma = semi_saturation(params, state.A)
    rec = receptors(params, frame, sigma)
    shift = _pixel(gaze) - _pixel(state.gaze)
    B = retinal_shift(state.B, shift, rec.B_inf)
    C = retinal_shift(state.C, shift, rec.C_inf)
    seen = state._replace(B=B, C=C, gaze=gaze)

    rho = local_rho(params, frame)
    key_noise, key_dither = (jax.random.fold_in(seen.key, i) for i in range(2))
    scene = frame
    if params.acuity:
        X = acuity_noise(params, key_noise, seen.t, shape)
        scene = acuity_loss(params, frame, rho, X)
    response = tone_map(params, scene, rho, sigma)
    response = afterimages(params, response, seen, rec, falloff(params, shape, gaze))
    J = encode(params, response)
    if params.dithering:
        J = dither(J, jax.random.fold_in(key_dither, seen.frame), params.levels)

    A_T = adaptation_target(params, frame, gaze)
    A = kinetics.log_adaptation_step(seen.A, A_T, params.a1, params.a2, dt)
    B_next, C_next = blur_maps(
        params,
        kinetics.cone_bleaching_step(B, rec.lms, params.b1, params.b2, dt),
        kinetics.calcium_step(C, rec.R, params.c1, params.c2, dt),
        rec.B_inf,
        rec.C_inf,
    )
    advanced = seen._replace(
        A=A if params.global_adaptation else seen.A,
        B=B_next,
        C=C_next,
        t=seen.t + dt,
        frame=seen.frame + 1,
    )
    gx, gy = _pixel(gaze)
    record = Diagnostics(
        seen.t, seen.A, A_T, sigma, gaze, B[gy, gx], C[gy, gx], rho[gy, gx], final_state=None
    )
    return advanced, J, record


def _initial_state(params, frame, gaze, key, adaptation=None):
    shape = frame.shape[:2]
    gaze = fixation(gaze, frame_centre(shape, frame.dtype), shape)
    if adaptation is None:
        A = adaptation_target(params, frame, gaze)
    else:
        A = jnp.log10(jnp.maximum(adaptation, params.adaptation_floor)).astype(frame.dtype)
    rec = receptors(params, frame, semi_saturation(params, A))
    zero = jnp.zeros((), frame.dtype)
    return State(A, rec.B_inf, rec.C_inf, gaze, zero, jnp.zeros((), jnp.int32), key)


# -- the contract -------------------------------------------------------------


def init(params, first_frame, *, gaze=None, key=None, adaptation=None):
    """State of a viewer fully adapted to ``first_frame`` while fixating ``gaze``.

    ``A`` is the frame's target, ``B`` and ``C`` their equilibria (Eqs 6
    and 10) for the frame.

    Parameters
    ----------
    params : Params
    first_frame : array, shape (H, W, 3)
        Linear BT.709 RGB, cd/m2.
    gaze : array, shape (2,), optional
        Fixation ``(x, y)``, pixels (default: the centre; clipped to the
        frame; NaN also means the centre).
    key : PRNG key, optional
        Key of the sequence; required when the acuity loss or dithering is on.
    adaptation : float, optional
        Global adaptation luminance (cd/m2) to start from instead of the
        frame's target, e.g. a dark-adapted viewer; floored at
        ``adaptation_floor`` like every target. The retinal maps still start
        at equilibrium with the frame.

    Returns
    -------
    State
    """
    first_frame = jnp.asarray(first_frame)
    gaze = _default_gaze(gaze, first_frame, rank=3)
    check_adaptation(adaptation)
    key = _check_key(params, key)
    on_host = not is_traced(params, first_frame, gaze, key, adaptation)
    state, verdict = _init(params, first_frame, gaze, key, adaptation, on_host)
    raise_verdict(verdict, frames_messages("first_frame"))
    return state


@eqx.filter_jit
def _init(params, first_frame, gaze, key, adaptation, on_host):
    guard, verdict = check_frames(first_frame, 3, "first_frame", on_host)
    check_one_parameter_set(params, CHANNEL_FIELDS)
    params = as_dtype(params, first_frame.dtype)
    state = _initial_state(params, first_frame, gaze, key, adaptation)
    return state._replace(A=state.A + guard), verdict


#: Units of the columns of :func:`diagnostics_table` (``t`` is in s).
DIAGNOSTIC_UNITS = {
    "A": "log10 cd/m2",
    "A_T": "log10 cd/m2",
    "sigma": "cd/m2",
    "gaze_x": "pixels",
    "gaze_y": "pixels",
    **{f"B_{cone}": "bleached fraction" for cone in "LMS"},
    **{f"C_{cone}": "calcium (relative)" for cone in "LMS"},
    "rho": "Eq 13, unclamped",
}


def diagnostics_notes(params):
    """What a reader of the diagnostics needs to know of ``params`` (lines
    for a plot): ``A`` and ``A_T`` never fall below the adaptation floor of
    §2.4, and ``rho`` is Eq 13 before its clamp to [0, 1]."""
    floor = float(params.adaptation_floor)
    return (
        f"A and A_T are floored at {floor:g} cd/m2 (log10 {np.log10(floor):g}; §2.4): "
        "a darker fixation shows the floor",
        "rho is Eq 13 unclamped (below 0 scotopic, above 1 photopic); the Purkinje shift "
        "and the mesopic colour use it clamped to [0, 1]",
    )


def diagnostics_table(diag):
    """Per-frame columns of a :class:`Diagnostics`, as numpy arrays.

    ``t``; ``A`` and ``A_T`` (log10 cd/m2); ``sigma`` (cd/m2); the fixation
    ``gaze_x``, ``gaze_y`` (pixels); L, M, S bleaching ``B_L`` ... and
    calcium ``C_L`` ... at the fixation; and ``rho`` there (Eq 13,
    unclamped: :func:`diagnostics_notes`). Units: :data:`DIAGNOSTIC_UNITS`.
    """
    columns = {"t": diag.t, "A": diag.A, "A_T": diag.A_T, "sigma": diag.sigma}
    columns |= {"gaze_x": diag.gaze[:, 0], "gaze_y": diag.gaze[:, 1]}
    for i, cone in enumerate("LMS"):
        columns[f"B_{cone}"] = diag.B_gaze[:, i]
    for i, cone in enumerate("LMS"):
        columns[f"C_{cone}"] = diag.C_gaze[:, i]
    columns["rho"] = diag.rho_gaze
    return {name: np.asarray(column) for name, column in columns.items()}


def step(params, state, frame, dt, *, gaze=None, key=None):
    """Show one frame, then advance the state over its duration.

    Parameters
    ----------
    params : Params
    state : State
        State at the time the frame is shown (from :func:`init` or a
        previous step).
    frame : array, shape (H, W, 3)
        Linear BT.709 RGB, cd/m2, the shape of the state's maps.
    dt : float
        How long the frame is held, s.
    gaze : array, shape (2,), optional
        Gaze sample ``(x, y)``, pixels (default: the centre; NaN: a blink,
        the last fixation is held; outside the frame: clipped).
    key : PRNG key, optional
        Replaces the sequence key held in the state; by default the state's
        key is used, so that a loop of steps equals :func:`run`.

    Returns
    -------
    (State, array)
        The state after ``dt`` and the display frame ``(H, W, 3)``: display
        values ``J`` in [0, 1] (gamma-encoded by ``gamma``; on the 8-bit grid
        when dithering).
    """
    frame = jnp.asarray(frame)
    gaze = _default_gaze(gaze, frame, rank=3)
    check_state(state, State, "jacobs2015")
    if key is not None:
        state = state._replace(key=key)
    dt = _as_frame_dtype(dt, frame)
    on_host = not is_traced(params, state, frame, dt, gaze)
    new_state, out, verdict = _step(params, state, frame, dt, gaze, on_host)
    raise_verdict(verdict, frames_and_dt_messages("frame"))
    return new_state, out


@eqx.filter_jit
def _step(params, state, frame, dt, gaze, on_host):
    guard, dt, verdict = check_frames_and_dt(frame, dt, 3, "frame", on_host)
    if state.B.shape != frame.shape:
        raise ValueError(
            f"frame: expected the shape of the state's maps {state.B.shape}, got {frame.shape}"
        )
    check_one_parameter_set(params, CHANNEL_FIELDS)
    params, state, dt = as_dtype((params, state, dt[0]), frame.dtype)
    state = state._replace(A=state.A + guard)
    new_state, out, _ = _frame(params, state, frame, dt, gaze)
    return new_state, out, verdict


def run(params, frames, dt, *, gaze=None, key=None, state=None):
    """Render a sequence as the viewer following ``gaze`` would see it.

    Parameters
    ----------
    params : Params
    frames : array, shape (T, H, W, 3)
        Linear BT.709 RGB, cd/m2, finite and non-negative.
    dt : float or array, shape (T,)
        Duration of each frame, s.
    gaze : array, shape (T, 2), optional
        Gaze path ``(x, y)``, pixels (default: fixation at the centre). NaN
        samples are blinks (the last fixation is held); points outside the
        frame are clipped to its edge.
    key : PRNG key
        Key of the sequence, required when the acuity loss or dithering is
        on: the same key gives the same frames.
    state : State, optional
        State at the first frame; by default :func:`init` on the first frame
        and gaze sample, with ``key``.

    Returns
    -------
    (array, Diagnostics)
        Display values ``(T, H, W, 3)`` in [0, 1] (gamma-encoded, see
        :func:`step`) and the per-frame record. ``run`` gives the same frames
        as a loop of :func:`step` from the same state.

    Examples
    --------
    >>> frames = jnp.full((3, 8, 8, 3), 100.0)
    >>> out, diag = run(Params(), frames, 1 / 30, key=jax.random.key(0))
    >>> out.shape, diag.B_gaze.shape
    ((3, 8, 8, 3), (3, 3))
    >>> bool(jnp.all(out * 255 == jnp.round(out * 255)))  # dithered to 8 bits
    True
    """
    frames = jnp.asarray(frames)
    gaze = _default_gaze(gaze, frames, rank=4)
    if state is None:
        key = _check_key(params, key)
    else:
        check_state(state, State, "jacobs2015")
        state = state if key is None else state._replace(key=key)
    dt = _as_frame_dtype(dt, frames)
    on_host = not is_traced(params, frames, dt, gaze, key, state)
    out, diagnostics, verdict = _run(params, frames, dt, gaze, key, state, on_host)
    raise_verdict(verdict, frames_and_dt_messages("frames"))
    return out, diagnostics


@eqx.filter_jit
def _run(params, frames, dt, gaze, key, state, on_host):
    guard, dt, verdict = check_frames_and_dt(frames, dt, 4, on_host=on_host)
    check_one_parameter_set(params, CHANNEL_FIELDS)
    params, state, dt = as_dtype((params, state, dt), frames.dtype)
    if state is None:
        state = _initial_state(params, frames[0], gaze[0], key)
    state = state._replace(A=state.A + guard)

    def scan_step(s, inputs):
        s, out, record = _frame(params, s, *inputs)
        return s, (out, record)

    final_state, (out, record) = jax.lax.scan(scan_step, state, (frames, dt, gaze))
    return out, record._replace(final_state=final_state), verdict
