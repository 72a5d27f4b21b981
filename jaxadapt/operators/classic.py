"""The photoreceptor family of tone curves, and Ward's JND mapping (chapter 6, §6.3).

Each classic global tone curve turns out to be Eq 6.2, the Naka-Rushton
response ``R / R_max = I^n / (I^n + sigma_b^n)``, with a particular
semi-saturation ``sigma_b``. For each curve this module gives its published
("original") form and the chapter's rewritten form, and evaluates the
rewritten one; ``tests/test_classic.py`` checks that the two agree.

Every curve is an ``equinox.Module`` of parameters with a method
``curve(I, I_b)`` from luminance ``I`` and background luminance ``I_b`` (both
cd/m2, shape ``(..., H, W)``) to display luminance relative to display white.
:func:`tone_map` applies any of them to linear RGB frames ``(..., H, W, 3)``
with a global background (the log average, by default) or any local one,
e.g. a :data:`jaxadapt.background.BACKGROUNDS` estimator.
:data:`TONE_CURVES` names them.

References
----------
Reinhard, Ward, Pattanaik, Debevec (2005), *High Dynamic Range Imaging*,
chapter 6, §6.3.1-6.3.2 and Eq 6.2-6.3.
"""

from functools import partial
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt._checks import check_value, float_array
from jaxadapt.background import (
    LUMINANCE_FLOOR,
    check_background,
    estimate_background,
    global_background,
)
from jaxadapt.color import photopic_luminance
from jaxadapt.operators import TONE_CURVE_NAMES
from jaxadapt.operators.checks import (
    as_dtype,
    check_frames_and_dt,
    check_rgb,
    frames_and_dt_messages,
    is_traced,
    plain_errors,
    raise_verdict,
    saturate,
)
from jaxadapt.physiology.response import naka_rushton, power
from jaxadapt.physiology.threshold import TVI_MODELS

__all__ = [
    "schlick_original",
    "schlick_sigma",
    "tumblin_original",
    "tumblin_sigma",
    "tumblin_rewritten",
    "reinhard_devlin_sigma",
    "photographic_original",
    "photographic_sigma",
    "jnd_count",
    "ward_display_luminance",
    "Schlick1994",
    "Tumblin1999",
    "ReinhardDevlin",
    "Photographic",
    "WardJND",
    "TONE_CURVES",
    "tone_map",
    "Params",
    "Diagnostics",
    "init",
    "step",
    "run",
    "DIAGNOSTIC_UNITS",
    "diagnostics_table",
    "log_adaptation",
    "configure",
    "describe",
    "plot_diagnostics",
]


def _positive(name, value):
    check_value(name, value, lambda v: np.isfinite(v) & (v > 0), "a positive finite value")


# -- the curves in their two forms --------------------------------------------


def schlick_original(I, I_max, p):
    """Schlick's rational quantisation: ``F = p I / (p I - I + I_max)`` [original form].

    Parameters
    ----------
    I : array
        Luminance, ``0 <= I <= I_max``.
    I_max : array
        Largest luminance of the image.
    p : array
        Rational parameter, ``>= 1``.

    Returns
    -------
    array
        Display value in ``[0, 1]``.
    """
    return p * I / (p * I - I + I_max)


def schlick_sigma(I, I_max, p):
    """Semi-saturation of Schlick's curve as Eq 6.2 (``n = 1``): ``sigma_b = (I_max - I) / p``.

    ``F = I / (I + (I_max - I) / p)`` [rewritten form]: every pixel is its
    own background.
    """
    return (I_max - I) / p


def tumblin_original(I, I_b, k, n, D):
    """Tumblin's S-curve: ``F = D ((I/I_b)^n + 1/k) / ((I/I_b)^n + k)`` [original form].

    Parameters
    ----------
    I : array
        Luminance.
    I_b : array
        Background (adaptation) luminance, in the unit of ``I``.
    k : array
        Shape parameter, ``> 1``: the background maps to ``D / k``, black to
        ``D / k^2``.
    n : array
        Exponent, ``> 0``.
    D : array
        Display white.

    Returns
    -------
    array
        Display value in ``[D / k^2, D)``.
    """
    x = power(I / I_b, n)
    return D * (x + 1.0 / k) / (x + k)


def tumblin_sigma(I_b, k, n):
    """Semi-saturation of the first part of Tumblin's rewritten curve: ``sigma_b = k^(1/n) I_b``."""
    return power(k, 1.0 / n) * I_b


def tumblin_rewritten(I, I_b, k, n, D):
    """Tumblin's S-curve as Eq 6.2 plus a second part [rewritten form].

    ``F = D [I^n / (I^n + k I_b^n) + I_b^n / (k (I^n + k I_b^n))]``: the first
    part is Eq 6.2 with ``sigma_b = k^(1/n) I_b`` (:func:`tumblin_sigma`);
    the second is ``(1 - R) / k^2``, so ``F = D (1/k^2 + (1 - 1/k^2) R)``:
    Eq 6.2 raised to the display's black level ``D / k^2``.
    """
    R = naka_rushton(I, tumblin_sigma(I_b, k, n), 1.0, n)
    return D * (R + (1.0 - R) / k**2)


def reinhard_devlin_sigma(I_b, f, m):
    """Reinhard and Devlin's semi-saturation ``sigma_b = (f I_b)^m`` (Eq 6.2 with ``n = 1``)."""
    return power(f * I_b, m)


def photographic_original(I, I_b, a):
    """Reinhard et al.'s photographic curve: ``F = (a I/I_b) / (1 + a I/I_b)`` [original form].

    Parameters
    ----------
    I : array
        Luminance.
    I_b : array
        Background luminance (the log average for the global operator).
    a : array
        Key, ``> 0``: the display value of the background is ``a / (1 + a)``.
    """
    x = a * I / I_b
    return x / (1.0 + x)


def photographic_sigma(I_b, a):
    """Semi-saturation of the photographic curve: ``F = I / (I + I_b / a)`` [rewritten form]."""
    return I_b / a


def jnd_count(I, I_b, tvi):
    """Number of just-noticeable differences between ``I`` and its background: ``(I - I_b) / dI_b``.

    Parameters
    ----------
    I, I_b : array
        Luminance and background luminance, cd/m2.
    tvi : callable
        Threshold (cd/m2) as a function of background luminance (cd/m2):
        one of :data:`jaxadapt.physiology.threshold.TVI_MODELS`.
    """
    return (I - I_b) / tvi(I_b)


def ward_display_luminance(jnds, I_bd, tvi):
    """Eq 6.3: ``I_display = JNDs dI_b,display + I_b,display``.

    Parameters
    ----------
    jnds : array
        JNDs above the background (:func:`jnd_count`).
    I_bd : array
        Display background (adaptation) luminance, cd/m2.
    tvi : callable
        TVI model, cd/m2 to cd/m2.

    Returns
    -------
    array
        Display luminance, cd/m2.
    """
    return jnds * tvi(I_bd) + I_bd


# -- parameters of each curve --------------------------------------------------


class Schlick1994(eqx.Module):
    """Schlick's rational quantisation as Eq 6.2 with ``sigma_b = (I_max - I) / p``.

    The curve is relative to the frame's brightest pixel, which is display
    white: a uniform frame, a black one (at the floor) included, is white.

    Attributes
    ----------
    p : float
        Rational parameter, ``>= 1`` (``1`` is linear scaling by ``I_max``).
    k : float
        Weight of the background, in ``[0, 1]``: Schlick's non-uniform
        quantisation replaces ``p`` by ``p (1 - k + k I_b / sqrt(I_min
        I_max))``, so that the curve is steeper where the background is
        bright. ``0`` (the default) is the uniform curve, which does not
        depend on the background. ``I_min`` is the darkest pixel above the
        luminance floor: a black pixel anywhere would otherwise make it the
        floor, 1e-6 cd/m2, and multiply ``p`` by hundreds (a 1 to 1,000
        cd/m2 ramp: 10 cd/m2 shown at 0.955 instead of 0.092).
    """

    p: jax.Array = eqx.field(default=100.0, converter=float_array)
    k: jax.Array = eqx.field(default=0.0, converter=float_array)

    def __check_init__(self):
        check_value("Schlick1994.p", self.p, lambda v: np.isfinite(v) & (v >= 1), "a finite p >= 1")
        check_value("Schlick1994.k", self.k, lambda v: (v >= 0) & (v <= 1), "k in [0, 1]")

    def curve(self, I, I_b):
        I_max = jnp.max(I, axis=(-2, -1), keepdims=True)
        lit = I > LUMINANCE_FLOOR  # black pixels come at the floor (tone_map)
        I_min = jnp.min(jnp.where(lit, I, I_max), axis=(-2, -1), keepdims=True)
        p = self.p * (1.0 - self.k + self.k * I_b / jnp.sqrt(I_min * I_max))
        sigma = schlick_sigma(I, I_max, p)
        # sigma = 0 at the brightest pixel: Eq 6.2 is then 1.
        positive = sigma > 0
        return jnp.where(positive, naka_rushton(I, jnp.where(positive, sigma, 1.0), 1.0, 1.0), 1.0)


class Tumblin1999(eqx.Module):
    """Tumblin's S-curve: ``D (1/k^2 + (1 - 1/k^2) R)``, ``R`` Eq 6.2, ``sigma_b = k^(1/n) I_b``.

    Attributes
    ----------
    k : float
        ``> 1``; ``k^2`` is the display contrast (black at ``D / k^2``) and
        the background maps to ``D / k``. Default 10 (100:1).
    n : float
        Exponent, ``> 0``.
    D : float
        Display white, relative to the display's maximum, ``> 0``.
    """

    k: jax.Array = eqx.field(default=10.0, converter=float_array)
    n: jax.Array = eqx.field(default=1.0, converter=float_array)
    D: jax.Array = eqx.field(default=1.0, converter=float_array)

    def __check_init__(self):
        check_value("Tumblin1999.k", self.k, lambda v: v > 1, "k > 1")
        _positive("Tumblin1999.n", self.n)
        _positive("Tumblin1999.D", self.D)

    def curve(self, I, I_b):
        return tumblin_rewritten(I, I_b, self.k, self.n, self.D)


class ReinhardDevlin(eqx.Module):
    """Reinhard and Devlin's curve: Eq 6.2 with ``n = 1`` and ``sigma_b = (f I_b)^m``.

    Attributes
    ----------
    f : float
        Intensity, ``> 0`` (colour-hdri's and the paper's ``f'`` is
        ``-ln f``).
    m : float
        Contrast, ``> 0``.
    """

    f: jax.Array = eqx.field(default=1.0, converter=float_array)
    m: jax.Array = eqx.field(default=0.6, converter=float_array)

    def __check_init__(self):
        _positive("ReinhardDevlin.f", self.f)
        _positive("ReinhardDevlin.m", self.m)

    def curve(self, I, I_b):
        return naka_rushton(I, reinhard_devlin_sigma(I_b, self.f, self.m), 1.0, 1.0)


class Photographic(eqx.Module):
    """Reinhard et al.'s photographic curve: Eq 6.2 with ``n = 1``, ``sigma_b = I_b / a``.

    With the global background (the log average) it is the global
    photographic operator; with
    :func:`jaxadapt.background.adaptive_background` it is the chapter's
    local version with a variable-size neighbourhood. (Reinhard et al.'s own
    local operator, ``L / (1 + V_1)``, keeps the log average in the scaling
    ``L = a I / I_w`` and puts the local average only in the denominator:
    a different curve, not the chapter's Eq 6.2 form, and not provided.)

    Attributes
    ----------
    a : float
        Key, ``> 0`` (0.18, middle grey).
    """

    a: jax.Array = eqx.field(default=0.18, converter=float_array)

    def __check_init__(self):
        _positive("Photographic.a", self.a)

    def curve(self, I, I_b):
        return naka_rushton(I, photographic_sigma(I_b, self.a), 1.0, 1.0)


class WardJND(eqx.Module):
    """Ward's JND mapping (Eq 6.3) from a TVI model.

    ``I_d = I_bd + (I - I_b) dI(I_bd) / dI(I_b)``: the pixel's JNDs above
    its background, counted with the scene's threshold ``dI(I_b)``, are
    reproduced above the display background ``I_bd`` in display JNDs. The
    result is relative to display white ``L_dmax``. With a global
    background its slope is Ward's (1994) contrast-based scale factor, but
    Eq 6.3 adds an offset that Ward's operator (``I_d = m I``) does not
    have: where the display's Weber fraction exceeds the scene's, every
    pixel below ``I_b - I_bd dI(I_b) / dI(I_bd)`` maps below zero and clips
    to black (Blackwell's TVI, ``I_bd`` = 50 cd/m2 and a 4200 cd/m2
    background: 0.37 of the background; Rushton-MacLeod's: 0.03). With a
    local background, the use §6.3.2 presents it for, each pixel stays near
    its own background and the log-linear TVI compresses the range.

    Attributes
    ----------
    L_da : float
        Display background (adaptation) luminance, cd/m2, ``> 0`` (Ward:
        half the display's maximum).
    L_dmax : float
        Display white, cd/m2, ``> 0``.
    tvi : str
        TVI model (static): ``"blackwell"`` (Ward 1994) or
        ``"rushton-macleod"`` (§6.2.2, through the natural pupil); see
        :data:`jaxadapt.physiology.threshold.TVI_MODELS`.
    """

    L_da: jax.Array = eqx.field(default=50.0, converter=float_array)
    L_dmax: jax.Array = eqx.field(default=100.0, converter=float_array)
    tvi: str = eqx.field(default="blackwell", static=True)

    def __check_init__(self):
        _positive("WardJND.L_da", self.L_da)
        _positive("WardJND.L_dmax", self.L_dmax)
        if self.tvi not in TVI_MODELS:
            raise ValueError(f"WardJND.tvi: expected one of {tuple(TVI_MODELS)}, got {self.tvi!r}")

    def curve(self, I, I_b):
        tvi = TVI_MODELS[self.tvi]
        return ward_display_luminance(jnd_count(I, I_b, tvi), self.L_da, tvi) / self.L_dmax


#: The tone curves by name (:data:`jaxadapt.operators.TONE_CURVE_NAMES`, in
#: that order): their parameter classes.
TONE_CURVES = dict(
    zip(
        TONE_CURVE_NAMES,
        (Schlick1994, Tumblin1999, ReinhardDevlin, Photographic, WardJND),
        strict=True,
    )
)


# -- applying a curve to frames --------------------------------------------------


def _background(L, background):
    """The background luminance of ``L`` that ``tone_map``'s argument asks for."""
    if background is None:
        return global_background(L)
    if callable(background):
        I_b = background(L)
    else:
        try:
            I_b = jnp.asarray(background, L.dtype)
        except (TypeError, ValueError):
            raise ValueError(
                "background: expected None, a luminance array (cd/m2) or a function of the "
                f"luminance image, got {background!r}"
            ) from None
        bad = ~jnp.all(jnp.isfinite(I_b) & (I_b >= 0))
        I_b = eqx.error_if(I_b, bad, "background: expected finite, non-negative luminance (cd/m2)")
        I_b = saturate(I_b)  # as the frame's luminance
    try:
        fits = jnp.broadcast_shapes(I_b.shape, L.shape) == L.shape
    except ValueError:
        fits = False
    if not fits:
        raise ValueError(
            f"background: expected a luminance broadcastable to {L.shape} (cd/m2), "
            f"got shape {I_b.shape}"
        )
    return I_b


@plain_errors
@eqx.filter_jit
def tone_map(params, frame, background=None):
    """Tone-map linear RGB frames with one of the curves.

    The curve maps the luminance ``Y`` of each pixel to a display value
    ``F(Y, I_b)``; the pixel's RGB is scaled by ``F / Y`` (its chromaticity
    is kept) and clipped to ``[0, 1]``.

    Parameters
    ----------
    params : Schlick1994, Tumblin1999, ReinhardDevlin, Photographic or WardJND
        The curve and its parameters (:data:`TONE_CURVES`).
    frame : array, shape (..., H, W, 3)
        Linear BT.709 RGB, cd/m2, finite; leading axes are frames or batches.
        A pixel whose luminance is below
        :data:`~jaxadapt.background.LUMINANCE_FLOOR` (zero, negative)
        counts as a grey of the floor's luminance and is shown as the curve
        shows that luminance, not at 0: beside brighter pixels, near the
        curve's black level; a black frame, or a black region wider than a
        local background, as a grey at its own background (Photographic ``a
        / (1 + a)``, Tumblin ``D / k``, Ward 0.5; Schlick's white). A
        channel above :data:`~jaxadapt.background.LUMINANCE_CEILING` (1e10
        cd/m2) counts as the ceiling
        (:func:`~jaxadapt.operators.checks.saturate`), and so does a given
        background above it.
    background : None, array or callable
        Background luminance ``I_b``, cd/m2: ``None`` for the log average
        of each image (global), an array broadcastable to ``(..., H, W)``,
        or a function from the luminance image ``(..., H, W)`` to one, e.g.
        ``functools.partial(background.BACKGROUNDS["bilateral"], scale=8)``,
        evaluated inside this jitted function.

    Returns
    -------
    array, shape (..., H, W, 3)
        Display-relative linear RGB in ``[0, 1]``, in the frame's dtype.

    Examples
    --------
    >>> frame = jnp.full((2, 2, 3), 10.0)  # a grey 10 cd/m2 frame
    >>> round(float(tone_map(Photographic(a=0.18), frame)[0, 0, 0]), 4)  # a / (1 + a)
    0.1525
    """
    frame = check_rgb(frame, "frame", "(..., H, W, 3)", min_ndim=3)
    frame = eqx.error_if(frame, ~jnp.all(jnp.isfinite(frame)), "frame: expected finite values")
    return _tone_map_checked(params, frame, background)[0]


def _tone_map_checked(params, frame, background):
    """:func:`tone_map` of a checked frame; returns the display frame and ``I_b``."""
    params = as_dtype(params, frame.dtype)
    # Luminance between the floor and the ceiling, where every curve, ratio
    # and background stays finite in float32 (saturate).
    frame = saturate(frame)
    # A grey of the floor's luminance has that luminance: L needs no second pass.
    L = photopic_luminance(frame)
    dark = L < LUMINANCE_FLOOR
    frame = jnp.where(dark[..., None], jnp.asarray(LUMINANCE_FLOOR, frame.dtype), frame)
    L = jnp.where(dark, LUMINANCE_FLOOR, L)
    I_b = jnp.maximum(_background(L, background), LUMINANCE_FLOOR)
    Y = params.curve(L, I_b)
    return jnp.clip(frame * (Y / L)[..., None], 0.0, 1.0), I_b


# -- the operator contract -------------------------------------------------------


class Params(eqx.Module):
    """A tone curve with its background: the operator contract's parameters.

    With :func:`init`, :func:`step`, :func:`run` and
    :func:`diagnostics_table`, any curve of :data:`TONE_CURVES` runs where
    the time-dependent operators do (the command line, the pipeline). The
    curves are static: they have no adaptation state.

    Attributes
    ----------
    curve : Schlick1994, Tumblin1999, ReinhardDevlin, Photographic or WardJND
        The curve and its parameters.
    background : str
        Background estimator, a name of
        :data:`jaxadapt.background.BACKGROUNDS` (static).
    background_scale : float
        Its size in pixels, for the local estimators (static).
    """

    curve: eqx.Module = eqx.field(default_factory=Photographic)
    background: str = eqx.field(default="global", static=True)
    background_scale: float = eqx.field(default=8.0, static=True)

    def __check_init__(self):
        curves = tuple(TONE_CURVES.values())
        if not isinstance(self.curve, curves):
            raise ValueError(
                f"curve: expected an instance of one of {', '.join(c.__name__ for c in curves)}, "
                f"got {self.curve!r}"
            )
        check_background(self.background, self.background_scale)


class Diagnostics(NamedTuple):
    """Per-frame record of :func:`run`.

    Attributes
    ----------
    t : array, (T,)
        Time of each frame, s, from 0.
    background : array, (T,)
        Geometric mean of the frame's background luminance, cd/m2.
    final_state : None
        The curves have no state.
    """

    t: jax.Array
    background: jax.Array
    final_state: None = None


def init(params, first_frame, *, gaze=None, key=None, adaptation=None):
    """No state: the curves are static. Returns None."""
    return None


def _frame_background(params):
    return partial(estimate_background, name=params.background, scale=params.background_scale)


def step(params, state, frame, dt, *, gaze=None, key=None):
    """Tone-map one frame ``(H, W, 3)``; returns ``(None, display frame)``.

    ``frame`` and ``dt`` are checked as the other operators check them
    (:func:`~jaxadapt.operators.checks.check_frames_and_dt`).
    """
    frame, dt = jnp.asarray(frame), jnp.asarray(dt)
    out, verdict = _step(params, frame, dt, not is_traced(params, frame, dt))
    raise_verdict(verdict, frames_and_dt_messages("frame"))
    return None, out


@eqx.filter_jit
def _step(params, frame, dt, on_host):
    guard, _, verdict = check_frames_and_dt(frame, dt, 3, "frame", on_host)
    return tone_map(params.curve, frame + guard, _frame_background(params)), verdict


def run(params, frames, dt, *, gaze=None, key=None, state=None):
    """Tone-map frames ``(T, H, W, 3)`` (cd/m2) one by one with ``params.curve``.

    ``dt`` (s, scalar or ``(T,)``) only dates the diagnostics; ``gaze``,
    ``key`` and ``state`` are accepted for the shared contract and unused.
    Returns display frames ``(T, H, W, 3)`` in [0, 1] and :class:`Diagnostics`.
    ``frames`` and ``dt`` are checked as the other operators check them
    (:func:`~jaxadapt.operators.checks.check_frames_and_dt`: finite,
    non-negative luminance, positive durations).
    """
    frames = jnp.asarray(frames)
    dt = jnp.asarray(dt, frames.dtype)
    out, diagnostics, verdict = _run(params, frames, dt, not is_traced(params, frames, dt))
    raise_verdict(verdict, frames_and_dt_messages("frames"))
    return out, diagnostics


@eqx.filter_jit
def _run(params, frames, dt, on_host):
    guard, dt, verdict = check_frames_and_dt(frames, dt, 4, on_host=on_host)
    background = _frame_background(params)
    out, I_b = jax.lax.map(lambda f: _tone_map_checked(params.curve, f + guard, background), frames)
    mean_background = jnp.exp(jnp.mean(jnp.log(I_b), axis=(-2, -1)))
    return out, Diagnostics(jnp.cumsum(dt) - dt, mean_background), verdict


#: Units of the columns of :func:`diagnostics_table` (``t`` is in s).
DIAGNOSTIC_UNITS = {"background": "cd/m2"}


def diagnostics_table(diag):
    """Per-frame columns of a :class:`Diagnostics` (``t``, ``background``: the
    frame's geometric-mean background, cd/m2), numpy."""
    return {"t": np.asarray(diag.t), "background": np.asarray(diag.background)}


def log_adaptation(table):
    """Each frame's adaptation, log10 cd/m2: its background (the column
    ``background`` of :func:`diagnostics_table`); -inf for a black frame."""
    with np.errstate(divide="ignore"):
        return np.log10(table["background"])


def configure(settings):
    """The :class:`Params` of ``settings``: the tone curve named
    ``settings.name`` (:data:`TONE_CURVES`, its published parameters) and
    its background."""
    return Params(TONE_CURVES[settings.name](), settings.background, settings.background_scale)


def describe(settings):
    """The curve's name and its background."""
    return f"{settings.name}, {settings.background} background"


def plot_diagnostics(path, table, params, title):
    """The background over time (:func:`jaxadapt.figures.plot_columns`)."""
    from jaxadapt import figures

    return figures.plot_columns(path, table, title, units=DIAGNOSTIC_UNITS)
