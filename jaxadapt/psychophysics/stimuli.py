"""What a simulated observer takes from a displayed stimulus: its log
luminance and a few cue strengths.

The brightness signal of a displayed stimulus ``s`` (Jacobs et al. (2015),
§4.1-4.2, as modelled in :mod:`jaxadapt.psychophysics.observer`) is its log
luminance plus weighted cue terms measured on the rendered stimulus, with
the cues ``c = (afterimage, desaturation, blur)`` of :data:`CUES`
(:func:`stimulus_features`). Stimuli are rendered once per condition and
level (:func:`render_stimuli`, with the displays of
:mod:`jaxadapt.psychophysics.displays`) and reduced to those few numbers
(:class:`Features`); simulations of any number of observers then use only
those numbers (:class:`Stimuli`).

Choices where the paper is silent
---------------------------------
* **Cues, one number per stimulus** (:func:`stimulus_features`): the
  afterimage's mean luminance over the blank, as log contrast against the
  dark room; the spread of chromaticities over the image (desaturation); the
  contrast of the finest spatial scale (blur). Each is a log10 quantity that
  grows with the strength of the effect; the observer's weight says how
  many log10 units of brightness one unit of cue is worth (afterimage
  expected >= 0, desaturation and blur <= 0).
* **Stimuli.** See :func:`~jaxadapt.psychophysics.displays.afterimage_displays`
  and :func:`~jaxadapt.psychophysics.displays.mesopic_displays`: in both, test
  images are scaled copies on the display, as the paper describes, so that
  the log-luminance difference is exactly the level.
"""

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxadapt.background import LUMINANCE_FLOOR
from jaxadapt.color import photopic_luminance
from jaxadapt.psychophysics.displays import DISPLAYS
from jaxadapt.spatial import gaussian_blur

__all__ = [
    "CUES",
    "SHARPNESS_SIGMA",
    "CUE_FLOOR",
    "Features",
    "Stimuli",
    "stimulus_features",
    "stimuli_from_displays",
    "render_stimuli",
    "plain_stimuli",
]

#: The cue terms of the brightness signal, in the order of ``weights``.
CUES = ("afterimage", "desaturation", "blur")
#: Standard deviation of the blur whose residual is the "finest scale" of
#: the blur cue, pixels (about the finest band of the 2015 acuity model,
#: ``sigma_0 = 0.75``).
SHARPNESS_SIGMA = 1.0
#: Added to the colour spread and to the fine-scale contrast before their
#: logarithm: about a discrimination threshold (1% contrast, and a
#: chromaticity spread far below a colour chart's), so that differences
#: far below it (a neutral flash with a faintly coloured rim) count for
#: little, and a neutral or uniform image has a finite cue.
CUE_FLOOR = 0.01


class Features(NamedTuple):
    """What the observer takes from one displayed stimulus (leading axes:
    stimuli).

    Attributes
    ----------
    log_luminance : array, (...)
        log10 of the mean photopic luminance while the image is shown,
        cd/m2.
    cues : array, (..., K)
        The cue strengths of :data:`CUES`, log10 units each
        (:func:`stimulus_features`).
    """

    log_luminance: jax.Array
    cues: jax.Array


class Stimuli(NamedTuple):
    """The features of every test and its standard, per condition and level.

    Attributes
    ----------
    levels : array, (L,)
        Test levels, log10(test / standard).
    test, standard : Features
        Fields of shape ``(C, L)`` and ``(C, L, K)``: condition ``c`` (index
        into ``protocol.conditions``) and level ``l``. The standard is
        broadcast to every cell (it is the same image in both presets).
    """

    levels: jax.Array
    test: Features
    standard: Features

    def differences(self):
        """``(Delta log10 L, Delta c)``: test minus standard, ``(C, L)`` and
        ``(C, L, K)``."""
        return (
            self.test.log_luminance - self.standard.log_luminance,
            self.test.cues - self.standard.cues,
        )


def _features_one(display, presented, blank, ambient):
    """Features of one displayed stimulus ``(T, H, W, 3)``."""
    Y = photopic_luminance(display)
    shown = presented.astype(Y.dtype)[:, None, None]
    n_shown = jnp.maximum(jnp.sum(presented), 1)
    mean_Y = jnp.sum(Y * shown) / (n_shown * Y[0].size)
    log_luminance = jnp.log10(jnp.maximum(mean_Y, LUMINANCE_FLOOR))

    # Afterimage: the brightest pixel of the blank's mean luminance, as log
    # contrast against the dark room.
    n_blank = jnp.maximum(jnp.sum(blank), 1)
    after = jnp.sum(Y * blank.astype(Y.dtype)[:, None, None], axis=0) / n_blank
    afterimage = jnp.log10(1.0 + jnp.max(after) / ambient)

    # Desaturation: luminance-weighted spread of the chromaticities q = rgb / Y
    # in opponent coordinates (red-green, yellow-blue).
    q = display / jnp.maximum(Y, jnp.finfo(Y.dtype).tiny)[..., None]
    opponent = jnp.stack([q[..., 0] - q[..., 1], 0.5 * (q[..., 0] + q[..., 1]) - q[..., 2]], -1)
    w = Y * shown
    w = w / jnp.maximum(jnp.sum(w), jnp.finfo(Y.dtype).tiny)
    centre = jnp.sum(w[..., None] * opponent, axis=(0, 1, 2))
    spread = jnp.sqrt(jnp.sum(w[..., None] * (opponent - centre) ** 2))
    desaturation = -jnp.log10(spread + CUE_FLOOR)

    # Blur: RMS contrast of the finest scale (Y minus its blur) while shown.
    fine = Y - gaussian_blur(Y, SHARPNESS_SIGMA)
    rms = jnp.sqrt(jnp.sum(fine**2 * shown) / (n_shown * Y[0].size))
    blur = -jnp.log10(rms / jnp.maximum(mean_Y, LUMINANCE_FLOOR) + CUE_FLOOR)
    return Features(log_luminance, jnp.stack([afterimage, desaturation, blur]))


@eqx.filter_jit
def stimulus_features(display, presented, blank, ambient):
    """The log luminance and cue strengths of displayed stimuli.

    Parameters
    ----------
    display : array, (..., T, H, W, 3)
        Linear BT.709 RGB on the display, cd/m2; leading axes are stimuli.
    presented, blank : array of bool, (T,)
        Frames on which the image is shown, and the black frames after it.
    ambient : float
        Luminance of the dark room (black screen), cd/m2.

    Returns
    -------
    Features
        Fields of the leading shape ``(...)``, cues ``(..., 3)``:

        * ``log_luminance = log10 mean Y`` over the shown frames and all
          pixels (``Y`` photopic luminance, cd/m2);
        * ``afterimage = log10(1 + max_pixels mean_blank Y / ambient)``: the
          afterimage where it is brightest, averaged over the blank (so that
          both its strength and its duration count), as log contrast
          against the room;
        * ``desaturation = -log10(s + CUE_FLOOR)``, ``s`` the luminance-weighted
          standard deviation over pixels and shown frames of the opponent
          chromaticities ``(r - g, (r + g)/2 - b)`` of ``(r, g, b) = RGB / Y``:
          how different the colours of the image are, independent of its
          luminance;
        * ``blur = -log10(rms(Y - G * Y) / mean Y + CUE_FLOOR)``, ``G`` a Gaussian
          of :data:`SHARPNESS_SIGMA` pixels: the contrast of the finest
          detail, independent of luminance.

        desaturation and blur do not change when a display is scaled, so
        between scaled copies only ``log_luminance`` differs, by the log of
        the scale.

    Examples
    --------
    A grey frame of 10 cd/m2, then a black one:

    >>> frames = jnp.ones((2, 8, 8, 3)) * jnp.array([[10.0], [0.0]])[:, None, None]
    >>> f = stimulus_features(frames, jnp.array([True, False]), jnp.array([False, True]), 1e-3)
    >>> round(float(f.log_luminance), 6), float(f.cues[0])  # no afterimage
    (1.0, 0.0)
    """
    display = jnp.asarray(display)
    batch = display.shape[:-4]
    flat = display.reshape((-1,) + display.shape[-4:])
    out = jax.vmap(lambda d: _features_one(d, presented, blank, ambient))(flat)
    return jax.tree.map(lambda a: a.reshape(batch + a.shape[1:]), out)


def stimuli_from_displays(protocol, displays):
    """:class:`Stimuli` of rendered displays (:func:`stimulus_features` of
    every test and of the standard)."""
    args = (displays.presented, displays.blank, displays.ambient)
    test = stimulus_features(displays.test, *args)
    standard = stimulus_features(displays.standard, *args)
    standard = jax.tree.map(
        lambda s, t: jnp.broadcast_to(s, t.shape).astype(t.dtype), standard, test
    )
    return Stimuli(jnp.asarray(protocol.levels, test.log_luminance.dtype), test, standard)


def render_stimuli(protocol, *, key, **options):
    """Render a preset's stimuli with the 2015 operator and extract their features.

    Parameters
    ----------
    protocol : design.Protocol
        ``design.AFTERIMAGE`` or ``design.MESOPIC`` (or a protocol named
        like them), with conditions ``("control", "manipulated")``.
    key : PRNG key
        For the stochastic parts of the rendering (the mesopic acuity noise).
    **options
        Size and frame rate of the renders, passed to
        :func:`~jaxadapt.psychophysics.displays.afterimage_displays` or
        :func:`~jaxadapt.psychophysics.displays.mesopic_displays`.

    Returns
    -------
    Stimuli
        Computed once; simulations of any number of observers reuse it.

    Raises
    ------
    ValueError
        A protocol with no stimulus model (a name not in
        :data:`~jaxadapt.psychophysics.displays.DISPLAYS`),
        or other conditions.
    """
    if protocol.name not in DISPLAYS:
        raise ValueError(
            f"protocol: expected one of {', '.join(DISPLAYS)} (the stimuli we can render), "
            f"got {protocol.name!r}"
        )
    return stimuli_from_displays(protocol, DISPLAYS[protocol.name](protocol, key=key, **options))


def plain_stimuli(protocol):
    """Stimuli that differ in luminance only: ``Delta log10 L = level``, no
    cue differences, in every condition (no rendering).

    Examples
    --------
    >>> from jaxadapt.psychophysics import design
    >>> s = plain_stimuli(design.AFTERIMAGE)
    >>> s.test.cues.shape, [round(float(v), 3) for v in s.differences()[0][1]]
    ((2, 5, 3), [-0.285, -0.153, 0.0, 0.113, 0.259])
    """
    levels = jnp.asarray(protocol.levels, jnp.result_type(float))
    shape = (len(protocol.conditions), levels.shape[0])
    test = Features(jnp.broadcast_to(levels, shape), jnp.zeros(shape + (len(CUES),)))
    standard = Features(jnp.zeros(shape), jnp.zeros(shape + (len(CUES),)))
    return Stimuli(levels, test, standard)
