"""Simulated observers for the constant-stimuli experiments of the 2015 paper.

A model observer compares the internal brightness of the two images of a
trial. The brightness signal of a displayed stimulus ``s`` is its log
luminance plus weighted cue terms measured on the rendered stimulus::

    psi(s) = log10 L(s) + sum_k w_k c_k(s)                      (log10 units)

with the cues ``c = (afterimage, desaturation, blur)`` of :data:`CUES`
(:func:`stimulus_features`). On a trial the observer says "test brighter"
when the noisy difference of the two signals exceeds zero::

    D = psi(test) - psi(standard) + bias + order_bias (+1 test first, -1 second) + e,
    e ~ N(0, noise^2),

except on a lapse (probability ``lapse``), where the answer is a coin toss.
Averaged over the counter-balanced order, the probability of "test
brighter" at level ``x`` (log10 test/standard) in condition ``c`` is::

    P(x, c) = lapse / 2 + (1 - lapse) / 2 [Phi((m + order_bias) / noise)
                                          + Phi((m - order_bias) / noise)],
    m = Delta log10 L(x, c) + w . Delta c(x, c) + bias,

(:func:`probability`), so that an observer without cues, lapses or order bias
has the cumulative Gaussian of :mod:`jaxadapt.psychophysics.psychometric` with
``PSE = -bias`` and ``sigma = noise``; a cue that differs between the test
and the standard moves the PSE to the root of ``m`` (:func:`true_pse`).

Stimuli are rendered with the 2015 operator (:mod:`jaxadapt.operators.jacobs2015`,
through ``Params`` and ``run`` only) once per condition and level
(:func:`render_stimuli`), and reduced to a few numbers (:class:`Features`);
the simulation of thousands of observers then uses only those numbers
(:class:`Stimuli`), in one ``vmap``-ped call (:func:`simulate`).
Observers are drawn from a :class:`Population`; both are ``equinox``
modules (pytrees of arrays), so that :func:`probability` and
:func:`true_pse` can be differentiated with respect to cue weights and
population parameters (e.g. to calibrate them against the paper's PSEs).

Choices where the paper is silent
---------------------------------
* **The decision variable.** Log luminance plus linear cue terms, Gaussian
  noise on the difference (a Thurstonian observer, case V), lapses as
  random answers. ``noise`` is the standard deviation of the *difference*
  (``sqrt(2)`` times that of one interval's signal).
* **Constant error and order.** ``bias`` adds to the test's signal (a
  constant error, PSE = -bias); ``order_bias`` favours the first interval
  (a time-order error), which the paper's counter-balancing cancels in the
  PSE but which flattens the psychometric function.
* **Cues, one number per stimulus** (:func:`stimulus_features`): the
  afterimage's mean luminance over the blank, as log contrast against the
  dark room; the spread of chromaticities over the image (desaturation); the
  contrast of the finest spatial scale (blur). Each is a log10 quantity that
  grows with the strength of the effect; the observer's weight says how
  many log10 units of brightness one unit of cue is worth (afterimage
  expected >= 0, desaturation and blur <= 0).
* **Stimuli.** See :func:`afterimage_displays` and :func:`mesopic_displays`:
  in both, test images are scaled copies on the display, as the paper
  describes, so that the log-luminance difference is exactly the level.
* **Population defaults** (:data:`POPULATIONS`): see :class:`Population`.
  The cue weights default to zero (an observer who judges luminance only);
  the paper's effects are a calibration target, not a default.

References
----------
Jacobs, Gallo, Cooper, Pulli, Levoy (2015), *Simulating the Visual Experience
of Very Bright and Very Dark Scenes*, ACM TOG 34(3), §4.1-4.2.
Thurstone (1927), *A law of comparative
judgment*, Psychological Review 34. Wichmann, Hill (2001), *The
psychometric function I*, Perception & Psychophysics 63 (lapses).
"""

import dataclasses
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import ndtr

# io as a module, not ``from jaxadapt.io import atomic_path``: this module's
# classes live until the interpreter exits (JAX keeps its pytree types), and
# through them a bare function would keep io's globals, OpenImageIO among
# them, past the clean-up of modules at exit, where nanobind then lists
# OpenImageIO's objects as leaked on stderr after every run.
from jaxadapt import io, scenes
from jaxadapt._checks import check_value, check_whole, float_array
from jaxadapt.background import LUMINANCE_FLOOR
from jaxadapt.color import photopic_luminance
from jaxadapt.operators import jacobs2015
from jaxadapt.operators.checks import plain_errors
from jaxadapt.psychophysics import design
from jaxadapt.psychophysics import trials as trial_tables
from jaxadapt.spatial import gaussian_blur

#: The cue terms of the brightness signal, in the order of ``weights``.
CUES = ("afterimage", "desaturation", "blur")
#: Standard deviation of the blur whose residual is the "finest scale" of
#: the blur cue, pixels (about the finest band of the 2015 acuity model,
#: ``sigma_0 = 0.75``).
SHARPNESS_SIGMA = 1.0
#: Added to the colour spread and to the fine-scale contrast before their
#: logarithm: about a discrimination threshold (1% contrast; a chromaticity
#: spread of 0.01 where the ColorChecker's is 1.1), so that differences
#: far below it (a neutral flash with a faintly coloured rim) count for
#: little, and a neutral or uniform image has a finite cue.
CUE_FLOOR = 0.01


def _zeros():
    return jnp.zeros(len(CUES), dtype=jnp.result_type(float))


def _check_cue_axis(name, weights):
    """Raise unless ``weights`` has one entry per cue of :data:`CUES` on its last axis."""
    if jnp.shape(weights)[-1:] != (len(CUES),):
        raise ValueError(
            f"{name}: expected one value per cue {CUES} on the last axis, got shape "
            f"{jnp.shape(weights)}"
        )


# -- stimuli ------------------------------------------------------------------


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


class Displays(NamedTuple):
    """Rendered stimuli as they are shown on the display.

    Attributes
    ----------
    test : array, (C, L, T, H, W, 3)
        Each condition's test at each level: linear BT.709 RGB, cd/m2.
    standard : array, (T, H, W, 3)
        The standard, cd/m2.
    presented : array of bool, (T,)
        Frames on which the image is shown.
    blank : array of bool, (T,)
        Frames of the black screen that follows it (afterimages appear there).
    ambient : float
        Luminance of the room with the black screen shown, cd/m2.
    times : array, (T,)
        Time of each frame, s.
    """

    test: jax.Array
    standard: jax.Array
    presented: jax.Array
    blank: jax.Array
    ambient: float
    times: np.ndarray


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


def _check_conditions(protocol):
    if tuple(protocol.conditions) != ("control", "manipulated"):
        raise ValueError(
            f"protocol.conditions: expected ('control', 'manipulated'), got {protocol.conditions!r}"
        )


def _whole_frames(name, seconds, fps, least):
    """``seconds`` as a whole number (at least ``least``) of frames at ``fps``,
    ``n / fps`` exactly, so that the flash's edges fall on frame starts; a
    ValueError naming ``name`` when it is not within 1e-6 of a frame."""
    n = seconds * fps
    if abs(n - round(n)) > 1e-6 or round(n) < least:
        raise ValueError(
            f"{name}: expected a whole number (>= {least}) of frames at fps = {fps!r}, "
            f"got {seconds!r} s ({n:.4g} frames)"
        )
    return round(n) / fps


def afterimage_displays(
    protocol,
    *,
    key,
    width=32,
    height=32,
    fps=40.0,
    lead_s=0.25,
    flash_luminance=1e7,
    j1=(3e-4, 1e-3),
):
    """The stimuli of the afterimage experiment (§4.1.1), rendered.

    The camera-flash scene is :func:`jaxadapt.scenes.flash`: a white disk of
    ``flash_luminance`` cd/m2 (the flash of the paper's Fig. 4) at the
    fixation, shown for ``protocol.presentation_s`` (50 ms) after
    ``lead_s`` of darkness, then ``protocol.blank_s`` (2.5 s) of black on
    which the afterimage appears. It is rendered by the 2015 operator with
    the paper's weak synthetic afterimage (``j1 = 3e-4``: standard and
    control tests) and strong one (``j1 = 1e-3``: manipulated tests); the
    acuity loss (which leaves a photopic flash and a black screen unchanged)
    and the dithering are off, so that the rendering is deterministic.

    On the display, a linear value ``v`` is shown at ``k v`` cd/m2, ``k``
    chosen so that the standard's flash (its brightest point, averaged over
    the shown frames) measures ``protocol.standard`` (27 cd/m2). Tests are
    "identical to the standard, but scaled": their shown frames are
    multiplied by ``10^level``; the blank frames are not, so that the
    afterimage of each condition is the same at every level, as the paper
    gives one afterimage luminance per condition.

    With the defaults, the afterimage at its peak just after the flash
    measures 5.7e-3 cd/m2 (weak) and 1.9e-2 cd/m2 (strong), and 1.9e-3 and
    6.2e-3 cd/m2 averaged over the blank; the paper measured 2.2e-2 and
    6.5e-2 cd/m2 on its display (a ratio of 3.0 where ours, linear in
    ``j1``, is 3.3). The retinal maps are blurred between frames by the
    angle they spread on the paper's display
    (:func:`~jaxadapt.operators.jacobs2015.blur_for_display`: 0.27 pixel
    in a second at these 3.2 pixels per degree), so the strong
    afterimage's maps reach a little beyond the disk during the flash,
    which the desaturation cue registers as -0.010 (slightly more
    colourful; at 1 pixel a frame, 2 degrees a second, it was -0.11).

    Parameters
    ----------
    protocol : design.Protocol
        With conditions ``("control", "manipulated")``.
    key : PRNG key
        Unused (the rendering is deterministic); accepted for a common
        signature with :func:`mesopic_displays`.
    width, height : int
        Frame size, pixels (the scene spans 10 degrees).
    fps : float
        Frame rate, frames per second: a display shows whole frames, so
        ``presentation_s`` and ``lead_s`` must each last a whole number of
        them (the flash at least one).
    lead_s : float
        Darkness before the flash, s.
    flash_luminance : float
        Luminance of the flash in the depicted scene, cd/m2.
    j1 : (float, float)
        Bleaching-afterimage strengths of the control and manipulated tests.

    Returns
    -------
    Displays
    """
    del key
    _check_conditions(protocol)
    presentation = _whole_frames("protocol.presentation_s", protocol.presentation_s, fps, 1)
    lead_s = _whole_frames("lead_s", lead_s, fps, 0)
    blank_s = protocol.blank_s
    scene = scenes.flash(
        width,
        height,
        duration=lead_s + presentation + blank_s,
        fps=fps,
        luminance=flash_luminance,
        flash_duration=presentation,
        onset=lead_s,
    )
    times = scene.times
    half = 0.5 / fps
    presented = (times >= lead_s - half) & (times < lead_s + presentation - half)
    blank = times >= lead_s + presentation - half
    frames = jnp.asarray(scene.render(times), jnp.float32)
    gaze = jnp.asarray(scene.gaze(times), jnp.float32)
    ppd = scene.pixels_per_degree
    params = jacobs2015.Params(
        acuity=False,
        dithering=False,
        pixels_per_degree=ppd,
        afterimage_blur=jacobs2015.blur_for_display(ppd, fps),
    )

    def render(strength):
        version = dataclasses.replace(params, j1=strength)
        out, _ = jacobs2015.run(version, frames, scene.dt, gaze=gaze, key=jax.random.key(0))
        return jacobs2015.decode(version, out)

    weak, strong = jax.vmap(render)(jnp.asarray(j1, jnp.float32))
    shown = jnp.asarray(presented)
    flash = jnp.sum(photopic_luminance(weak) * shown[:, None, None], axis=0) / np.sum(presented)
    k = protocol.standard / jnp.max(flash)  # cd/m2 per unit of linear display value
    levels = jnp.asarray(protocol.levels, jnp.float32)
    scale = jnp.where(shown, 10.0 ** levels[:, None], 1.0)[..., None, None, None]  # (L, T, 1, 1, 1)
    standard = k * weak
    test = jnp.stack([standard * scale, k * strong * scale])
    return Displays(
        test, standard, jnp.asarray(presented), jnp.asarray(blank), protocol.ambient, times
    )


def mesopic_displays(protocol, *, key, width=96, height=64, fps=8.0):
    """The stimuli of the mesopic experiment (§4.2.1), rendered.

    The ColorChecker of :func:`jaxadapt.scenes.mesopic`, its white tile at
    the test's (or the standard's) luminance, shown for
    ``protocol.presentation_s`` (1.25 s). Every image goes through the 2015
    operator, so that the standard and the tests share its tone curve; the
    manipulated tests with the mesopic colour shift and the stochastic
    acuity loss on, the standard and the control tests with them off. The
    Purkinje shift is off in both, as in the paper; bleaching, local
    adaptation and dithering are off (a steady chart leaves no afterimage).
    The acuity noise uses the same ``key`` at every level (common random
    numbers: the features change smoothly with the level).

    The mesopic tests are "rendered with the color and acuity mesopic
    effects before intensity scaling": each rendered image is scaled on
    the display to the mean photopic luminance of the chart it depicts, so
    that the standard, control and manipulated tests at a level have the
    same mean luminance and differ only in colour and detail. The black
    screen after each image is not rendered (it shows nothing).

    Parameters
    ----------
    protocol : design.Protocol
        With conditions ``("control", "manipulated")``.
    key : PRNG key
        For the acuity noise.
    width, height : int
        Frame size, pixels (the chart spans 20 degrees).
    fps : float
        Frame rate, frames per second.

    Returns
    -------
    Displays
    """
    _check_conditions(protocol)
    whites = (*protocol.tests, protocol.standard)
    charts = [scenes.mesopic(width, height, protocol.presentation_s, fps, white=w) for w in whites]
    times = charts[0].times
    frames = jnp.stack([jnp.asarray(c.render(times), jnp.float32) for c in charts])
    gaze = jnp.asarray(charts[0].gaze(times), jnp.float32)
    ppd = charts[0].pixels_per_degree
    plain = jacobs2015.only(pixels_per_degree=ppd)
    effects = jacobs2015.only("mesopic_colour", "acuity", pixels_per_degree=ppd)

    def render(params, batch):
        def one(f):
            out, _ = jacobs2015.run(params, f, 1.0 / fps, gaze=gaze, key=key)
            lin = jacobs2015.decode(params, out)
            return lin * jnp.mean(photopic_luminance(f)) / jnp.mean(photopic_luminance(lin))

        return jax.vmap(one)(batch)

    control = render(plain, frames)
    manipulated = render(effects, frames[:-1])
    T = len(times)
    return Displays(
        jnp.stack([control[:-1], manipulated]),
        control[-1],
        jnp.ones(T, bool),
        jnp.zeros(T, bool),
        protocol.ambient,
        times,
    )


#: How each preset's stimuli are made, by protocol name.
DISPLAYS = {"afterimage": afterimage_displays, "mesopic": mesopic_displays}


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
        :func:`afterimage_displays` or :func:`mesopic_displays`.

    Returns
    -------
    Stimuli
        Computed once; simulations of any number of observers reuse it.

    Raises
    ------
    ValueError
        A protocol with no stimulus model (a name not in :data:`DISPLAYS`),
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
    >>> s = plain_stimuli(design.AFTERIMAGE)
    >>> s.test.cues.shape, [round(float(v), 3) for v in s.differences()[0][1]]
    ((2, 5, 3), [-0.285, -0.153, 0.0, 0.113, 0.259])
    """
    levels = jnp.asarray(protocol.levels, jnp.result_type(float))
    shape = (len(protocol.conditions), levels.shape[0])
    test = Features(jnp.broadcast_to(levels, shape), jnp.zeros(shape + (len(CUES),)))
    standard = Features(jnp.zeros(shape), jnp.zeros(shape + (len(CUES),)))
    return Stimuli(levels, test, standard)


# -- observers ----------------------------------------------------------------


class Observer(eqx.Module):
    """One model observer (or a batch: leading axes on every field).

    Attributes
    ----------
    noise : array
        Standard deviation of the decision variable (the difference of the
        two intervals' signals), log10 units; the fitted sigma of an
        observer without cues or lapses.
    bias : array
        Constant error added to the test's signal, log10 units (PSE = -bias).
    order_bias : array
        Added to the signal of the first interval, log10 units (time-order
        error).
    lapse : array
        Probability of a random answer, in [0, 1).
    weights : array, (..., K)
        Brightness per unit of each cue of :data:`CUES`, log10 units.
    """

    noise: jax.Array = eqx.field(default=0.15, converter=float_array)
    bias: jax.Array = eqx.field(default=0.0, converter=float_array)
    order_bias: jax.Array = eqx.field(default=0.0, converter=float_array)
    lapse: jax.Array = eqx.field(default=0.0, converter=float_array)
    weights: jax.Array = eqx.field(default_factory=_zeros, converter=float_array)

    def __check_init__(self):
        _check_cue_axis("Observer.weights", self.weights)


class Population(eqx.Module):
    """Where observers come from: the distribution of :class:`Observer` fields.

    Per observer, with independent standard normals ``z``::

        noise      = noise * exp(noise_spread z1)          (log-normal; median noise)
        bias       = bias + bias_spread z2
        order_bias = order_bias + order_bias_spread z3
        lapse      = sigmoid(logit(lapse) + lapse_spread z4)   (median lapse)
        weights    = weights + weight_spread z5..             (one z per cue)

    Every field is an array, so a population can be differentiated through
    :func:`observers_from_normals` (fixed ``z``: the reparameterisation
    trick) and batched.

    Attributes
    ----------
    noise, noise_spread : float
        Median decision noise, log10 units (0.15), and the standard
        deviation of its natural log (0.4: one observer in six is 1.5 times
        noisier than the median).
    bias, bias_spread : float
        Mean and spread of the constant error, log10 units (0, 0.02: the
        paper's control PSEs lie close to zero, Fig. 14).
    order_bias, order_bias_spread : float
        Mean and spread of the time-order error, log10 units (0, 0: the
        paper reports none).
    lapse, lapse_spread : float
        Median lapse rate (0.02) and the standard deviation of its logit
        (0.5); Wichmann and Hill (2001) report lapse rates of 0-5%.
    weights, weight_spread : array, (K,)
        Mean and spread of the cue weights (0: observers who judge
        luminance only).
    """

    noise: jax.Array = eqx.field(default=0.15, converter=float_array)
    noise_spread: jax.Array = eqx.field(default=0.4, converter=float_array)
    bias: jax.Array = eqx.field(default=0.0, converter=float_array)
    bias_spread: jax.Array = eqx.field(default=0.02, converter=float_array)
    order_bias: jax.Array = eqx.field(default=0.0, converter=float_array)
    order_bias_spread: jax.Array = eqx.field(default=0.0, converter=float_array)
    lapse: jax.Array = eqx.field(default=0.02, converter=float_array)
    lapse_spread: jax.Array = eqx.field(default=0.5, converter=float_array)
    weights: jax.Array = eqx.field(default_factory=_zeros, converter=float_array)
    weight_spread: jax.Array = eqx.field(default_factory=_zeros, converter=float_array)

    def __check_init__(self):
        for name in ("weights", "weight_spread"):
            _check_cue_axis(f"Population.{name}", getattr(self, name))
        check_value("Population.noise", self.noise, lambda v: v > 0, "a positive median noise")
        check_value(
            "Population.lapse", self.lapse, lambda v: (v >= 0) & (v < 1), "a median in [0, 1)"
        )
        for name in ("noise_spread", "bias_spread", "order_bias_spread", "lapse_spread"):
            check_value(
                f"Population.{name}", getattr(self, name), lambda v: v >= 0, "a spread >= 0"
            )


#: Default populations of the two presets. The paper chose the afterimage
#: tests (+-0.29 log units) so that "performance rates are mostly between
#: 10-90%", which puts the median noise near 0.29 / 1.28 = 0.22; the mesopic
#: tests span +-0.13 and gave "steeper slopes" (an easier task): 0.1.
#: With these, 3.5% (afterimage) and 4.1% (mesopic) of simulated observers
#: fail the 70% training criterion; the paper excluded 2 of 13 (15%, a 95%
#: interval of 2-45%).
POPULATIONS = {"afterimage": Population(noise=0.2), "mesopic": Population(noise=0.1)}

#: Number of standard normals behind one observer.
N_NORMALS = 4 + len(CUES)


def observers_from_normals(population, z):
    """Observers of a population from standard normals ``z (..., N_NORMALS)``.

    Differentiable with respect to the population (see :class:`Population`
    for the transforms).
    """
    z = jnp.asarray(z)
    p = population
    logit = jnp.log(p.lapse) - jnp.log1p(-p.lapse)
    return Observer(
        noise=p.noise * jnp.exp(p.noise_spread * z[..., 0]),
        bias=p.bias + p.bias_spread * z[..., 1],
        order_bias=p.order_bias + p.order_bias_spread * z[..., 2],
        lapse=jax.nn.sigmoid(logit + p.lapse_spread * z[..., 3]),
        weights=p.weights + p.weight_spread * z[..., 4:],
    )


def _observer_key(key, i):
    return jax.random.fold_in(key, i)


def draw_observers(key, population, n):
    """``n`` observers of a population; observer ``i`` depends only on ``key``
    and ``i`` (not on ``n``)."""
    keys = jax.vmap(_observer_key, (None, 0))(key, jnp.arange(n))
    dtype = jnp.result_type(population.noise)
    z = jax.vmap(lambda k: jax.random.normal(k, (N_NORMALS,), dtype))(keys)
    return observers_from_normals(population, z)


# -- judgements ---------------------------------------------------------------


def decision_mean(stimuli, observer):
    """``m = Delta log10 L + w . Delta c + bias`` per condition and level,
    ``(C, L)``: the mean of the decision variable before the order bias,
    log10 units."""
    d_lum, d_cues = stimuli.differences()
    return d_lum + d_cues @ observer.weights + observer.bias


def _p_yes(mean, observer, sign):
    z = (mean + sign * observer.order_bias) / observer.noise
    return 0.5 * observer.lapse + (1.0 - observer.lapse) * ndtr(z)


def _checked(observer, name="observer"):
    """``observer`` (or a batch), with a runtime error naming ``name``
    unless every noise is positive and every lapse in ``[0, 1)``."""
    bad = jnp.any(~(observer.noise > 0) | ~(observer.lapse >= 0) | ~(observer.lapse < 1))
    return eqx.error_if(observer, bad, f"{name}: expected noise > 0 and 0 <= lapse < 1")


@plain_errors
def probability(stimuli, observer, test_first=None):
    """Probability of "test brighter" per condition and level.

    Parameters
    ----------
    stimuli : Stimuli
    observer : Observer
        One observer (``vmap`` for a batch).
    test_first : bool or array, optional
        Order of the trial; by default the average of both orders (the
        counter-balanced design).

    Returns
    -------
    array, (C, L)
        ``lapse/2 + (1 - lapse) Phi((m +- order_bias) / noise)``, averaged
        over the order when ``test_first`` is None (module notes).
        Differentiable with respect to the observer and the stimuli.

    Examples
    --------
    >>> s = plain_stimuli(design.AFTERIMAGE)
    >>> p = probability(s, Observer(noise=0.2, bias=0.05))
    >>> p.shape, round(float(p[0, 2]), 4)  # level 0: Phi(0.05 / 0.2)
    ((2, 5), 0.5987)
    """
    observer = _checked(observer)
    mean = decision_mean(stimuli, observer)
    if test_first is None:
        return 0.5 * (_p_yes(mean, observer, 1.0) + _p_yes(mean, observer, -1.0))
    return _p_yes(mean, observer, jnp.where(test_first, 1.0, -1.0))


@plain_errors
def trial_probability(stimuli, observer, trials):
    """Probability of "test brighter" on each trial of a
    :class:`jaxadapt.psychophysics.design.Trials` (its condition, level and
    order), shape ``(n_trials,)``."""
    observer = _checked(observer)
    mean = decision_mean(stimuli, observer)[trials.condition, trials.level_index]
    return _p_yes(mean, observer, jnp.where(trials.test_first, 1.0, -1.0))


def respond(key, stimuli, observer, trials):
    """One observer's answers to a trial sequence: 1.0 for "test brighter".

    ``u < P`` with ``u`` uniform from ``key``: a lapse is a coin toss folded
    into ``P`` (:func:`trial_probability`).
    """
    p = trial_probability(stimuli, observer, trials)
    return (jax.random.uniform(key, p.shape, p.dtype) < p).astype(p.dtype)


class Experiment(NamedTuple):
    """A simulated experiment (leading axis: observers).

    Attributes
    ----------
    observers : Observer
        Fields of shape ``(N,)`` (weights ``(N, K)``).
    trials : design.Trials
        Each observer's trial sequence, ``(N, n_trials)``.
    responses : array, (N, n_trials)
        1 when the test was judged brighter.
    excluded : array of bool, (N,)
        Fewer than ``protocol.exclusion`` of the training trials correct.
    """

    observers: Observer
    trials: design.Trials
    responses: jax.Array
    excluded: jax.Array


def run_observer(key, protocol, stimuli, observer):
    """One observer through a protocol: ``(trials, responses)``.

    The trial order comes from ``split(key)[0]``
    (:func:`jaxadapt.psychophysics.design.trial_list`), the answers from
    ``split(key)[1]`` (:func:`respond`).
    """
    order_key, answer_key = jax.random.split(key)
    trials = design.trial_list(protocol, order_key)
    return trials, respond(answer_key, stimuli, observer, trials)


@eqx.filter_jit
def _simulate_observers(key, protocol, stimuli, observers):
    observers = _checked(observers, "observers")
    n = observers.noise.shape[0]
    keys = jax.vmap(_observer_key, (None, 0))(key, jnp.arange(n))
    trials, responses = jax.vmap(lambda k, o: run_observer(k, protocol, stimuli, o))(
        keys, observers
    )
    excluded = design.excluded(protocol, trials, responses)
    return Experiment(observers, trials, responses, excluded)


@plain_errors
def simulate_observers(key, protocol, stimuli, observers):
    """Given observers through a protocol, all in one ``vmap``-ped call.

    Parameters
    ----------
    key : PRNG key
        Observer ``i`` runs :func:`run_observer` with ``fold_in(key, i)``, so
        the result equals that loop and observer ``i``'s trials do not
        depend on how many observers there are.
    protocol : design.Protocol
    stimuli : Stimuli
    observers : Observer
        A batch: fields with a leading axis ``N``.

    Returns
    -------
    Experiment

    Raises
    ------
    ValueError
        Observers without one leading batch axis.
    equinox.EquinoxRuntimeError
        A noise that is not positive, or a lapse rate outside [0, 1).
    """
    if jnp.ndim(observers.noise) != 1:
        raise ValueError(
            f"observers: expected a batch with one leading axis, got noise of shape "
            f"{jnp.shape(observers.noise)}"
        )
    return _simulate_observers(key, protocol, stimuli, observers)


def simulate(key, protocol, stimuli, population, n_observers):
    """A whole experiment: ``n_observers`` drawn from a population, each
    through every trial of the protocol, in one compiled, ``vmap``-ped call.

    Parameters
    ----------
    key : PRNG key
        Same key, same experiment. ``split(key)[0]`` draws the observers
        (:func:`draw_observers`), ``split(key)[1]`` their trials
        (:func:`simulate_observers`).
    protocol : design.Protocol
    stimuli : Stimuli
        From :func:`render_stimuli` (or :func:`plain_stimuli`).
    population : Population
    n_observers : int

    Returns
    -------
    Experiment

    Examples
    --------
    >>> s = plain_stimuli(design.AFTERIMAGE)
    >>> e = simulate(jax.random.key(0), design.AFTERIMAGE, s, POPULATIONS["afterimage"], 4)
    >>> e.responses.shape, e.excluded.shape
    ((4, 320), (4,))
    """
    n = check_whole("n_observers", n_observers, least=1)
    draw_key, trial_key = jax.random.split(key)
    return _simulate_draws(draw_key, trial_key, protocol, stimuli, population, n)


@eqx.filter_jit
def _simulate_draws(draw_key, trial_key, protocol, stimuli, population, n):
    observers = draw_observers(draw_key, population, n)
    return _simulate_observers(trial_key, protocol, stimuli, observers)


# -- points of subjective equality --------------------------------------------


def _interp(x, xp, fp):
    """Piecewise-linear interpolation of ``fp (..., L)`` at ``x``, extended
    linearly beyond the end points."""
    i = jnp.clip(jnp.searchsorted(xp, x) - 1, 0, xp.shape[0] - 2)
    t = (x - xp[i]) / (xp[i + 1] - xp[i])
    return fp[..., i] + t * (fp[..., i + 1] - fp[..., i])


def _mean_at(stimuli, observer, x):
    """``m`` of every condition at level ``x`` (interpolated), ``(C,)``."""
    d_lum, d_cues = stimuli.differences()
    m = d_lum + d_cues @ observer.weights
    return _interp(x, stimuli.levels, m) + observer.bias


@eqx.filter_jit
def true_pse(stimuli, observer, *, steps=60):
    """The observer's own PSE in each condition: the level where ``m = 0``.

    ``m(x)`` (:func:`decision_mean`) is interpolated linearly between the
    levels and extended linearly beyond them. Lapses and a symmetric order
    bias leave the 50% point at ``m = 0``, so this is what a fit of
    infinitely many trials would give (where ``m`` is linear in ``x``, as
    without cues; with level-dependent cues, the point where the
    cumulative Gaussian fitted to the levels crosses 50% can differ a
    little).

    Parameters
    ----------
    stimuli : Stimuli
    observer : Observer
        One observer (``vmap`` for a batch).
    steps : int
        Bisection steps over the tested range widened by 2 log units on
        each side (the result is clipped to that bracket when ``m`` has no
        root in it).

    Returns
    -------
    array, (C,)
        log10 units. Differentiable: a final Newton step carries the
        implicit-function gradient ``-dm/dtheta / (dm/dx)``.

    Examples
    --------
    >>> s = plain_stimuli(design.AFTERIMAGE)
    >>> [round(float(v), 6) for v in true_pse(s, Observer(bias=0.05))]
    [-0.05, -0.05]
    """
    lo = jnp.broadcast_to(stimuli.levels[0] - 2.0, stimuli.test.log_luminance.shape[:1])
    hi = jnp.broadcast_to(stimuli.levels[-1] + 2.0, lo.shape)
    fixed = jax.lax.stop_gradient((stimuli, observer))
    increasing = _mean_at(*fixed, hi[0]) > _mean_at(*fixed, lo[0])

    def bisect(_, bracket):
        lo, hi = bracket
        mid = 0.5 * (lo + hi)
        m = jax.vmap(lambda c, x: _mean_at(*fixed, x)[c])(jnp.arange(mid.shape[0]), mid)
        above = (m > 0) == increasing
        return jnp.where(above, lo, mid), jnp.where(above, mid, hi)

    lo, hi = jax.lax.fori_loop(0, steps, bisect, (lo, hi))
    x = jax.lax.stop_gradient(0.5 * (lo + hi))

    def m_of(c, x):
        return _mean_at(stimuli, observer, x)[c]

    conditions = jnp.arange(x.shape[0])
    m = jax.vmap(m_of)(conditions, x)
    slope = jax.vmap(jax.grad(lambda x, c: _mean_at(*fixed, x)[c]))(x, conditions)
    slope = jnp.where(slope == 0, 1.0, slope)
    return x - m / jax.lax.stop_gradient(slope)


def weights_for_pse(stimuli, direction, pse, condition=1, bias=0.0):
    """Cue weights along ``direction`` that put an observer's PSE at ``pse``.

    Solves ``m(pse) = 0`` (:func:`true_pse`) for ``w = s direction`` in
    closed form, ``s = -(Delta log10 L(pse) + bias) / (direction . Delta
    c(pse))``, with the differences interpolated at ``pse`` as in
    :func:`true_pse`.

    Parameters
    ----------
    stimuli : Stimuli
    direction : array, (K,)
        Relative weights of the cues (e.g. ``(0, 2, 1)``: desaturation
        counts twice as much as blur).
    pse : float
        Target PSE of ``condition``, log10 units.
    condition : int
        Index into the protocol's conditions (default 1, manipulated).
    bias : float
        The observer's constant error.

    Returns
    -------
    array, (K,)
        Weights, log10 units per unit of cue.

    Raises
    ------
    ValueError
        When the cues along ``direction`` do not differ there (no weight
        can move the PSE); under ``jit`` (traced values) that is not
        checked, and the weights are then infinite or NaN.

    Examples
    --------
    >>> s = plain_stimuli(design.AFTERIMAGE)
    >>> s = s._replace(test=s.test._replace(cues=s.test.cues.at[1, :, 0].set(0.5)))
    >>> w = weights_for_pse(s, jnp.array([1.0, 0, 0]), -0.02)
    >>> round(float(w[0]), 4), round(float(true_pse(s, Observer(weights=w))[1]), 6)
    (0.04, -0.02)
    """
    direction = jnp.asarray(direction, jnp.result_type(float))
    d_lum, d_cues = stimuli.differences()
    lum = _interp(jnp.asarray(pse), stimuli.levels, d_lum[condition])
    cue = _interp(jnp.asarray(pse), stimuli.levels, jnp.moveaxis(d_cues[condition], -1, 0))
    along = jnp.dot(direction, cue)
    if not isinstance(along, jax.core.Tracer) and not abs(float(along)) > 0:
        raise ValueError(
            f"direction: expected cues that differ between test and standard at {pse}, "
            f"got a difference of {float(along)}"
        )
    return -(lum + bias) / along * direction


# -- tables -------------------------------------------------------------------


def participant_names(n):
    """``s01, s02, ...``, zero-padded to the width of ``n``."""
    width = max(2, len(str(n)))
    return [f"s{i + 1:0{width}d}" for i in range(n)]


def trial_table(protocol, experiment):
    """The analysed trials of the included observers, as columns.

    Returns
    -------
    dict of numpy arrays
        ``participant`` (:func:`participant_names`), ``condition`` (its
        name), ``level`` (log10 test/standard, the protocol's exact
        values), ``response`` (0/1), ``block`` (its name) and
        ``test_first`` (0/1), one row per trial in presentation order,
        observer after observer. Training trials and excluded observers
        are left out, as in the paper's analysis.
    """
    trials = jax.tree.map(np.asarray, experiment.trials)
    keep = ~trials.training & ~np.asarray(experiment.excluded)[:, None]
    names = np.array(participant_names(keep.shape[0]), dtype=object)
    who = np.broadcast_to(np.arange(keep.shape[0])[:, None], keep.shape)[keep]
    return {
        "participant": names[who],
        "condition": np.array(protocol.conditions, dtype=object)[trials.condition[keep]],
        "level": np.asarray(protocol.levels)[trials.level_index[keep]],
        "response": np.asarray(experiment.responses)[keep].astype(int),
        "block": np.array([b.name for b in protocol.blocks], dtype=object)[trials.block[keep]],
        "test_first": trials.test_first[keep].astype(int),
    }


def write_trials(path, protocol, experiment):
    """Write :func:`trial_table` as a CSV trial table (read back by
    :func:`jaxadapt.psychophysics.trials.read_trials`; the extra columns
    ``block`` and ``test_first`` are ignored there). Levels are written
    exactly (:func:`~jaxadapt.psychophysics.trials.csv_cell`). The file
    appears only once complete. Returns the number of rows."""
    table = trial_table(protocol, experiment)
    with io.atomic_path(path) as tmp, open(tmp, "w", newline="") as file:
        writer = io.csv_writer(file)
        writer.writerow(table)
        for row in zip(*table.values(), strict=True):
            writer.writerow([trial_tables.csv_cell(v) for v in row])
    return len(table["response"])


def groups(protocol, experiment):
    """Counts of the included observers per condition and level, as the
    :class:`jaxadapt.psychophysics.trials.Groups` that
    :func:`jaxadapt.psychophysics.trials.fit_groups` and the figures take
    (participant-major, conditions in the protocol's order)."""
    n_yes, n_total = design.counts(protocol, experiment.trials, experiment.responses)
    keep = ~np.asarray(experiment.excluded)
    names = np.array(participant_names(keep.shape[0]), dtype=object)[keep]
    C, L = len(protocol.conditions), len(protocol.tests)
    n_yes, n_total = (np.asarray(a, float)[keep].reshape(-1, L) for a in (n_yes, n_total))
    return trial_tables.Groups(
        tuple(np.repeat(names, C)),
        tuple(protocol.conditions) * int(keep.sum()),
        np.broadcast_to(np.asarray(protocol.levels), n_yes.shape).copy(),
        n_yes,
        n_total,
    )
