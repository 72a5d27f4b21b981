"""Simulated observers for the constant-stimuli experiments of the 2015 paper.

A model observer compares the internal brightness of the two images of a
trial. The brightness signal of a displayed stimulus ``s`` is its log
luminance plus weighted cue terms measured on the rendered stimulus::

    psi(s) = log10 L(s) + sum_k w_k c_k(s)                      (log10 units)

with the cues ``c = (afterimage, desaturation, blur)`` of
:data:`~jaxadapt.psychophysics.stimuli.CUES`
(:func:`~jaxadapt.psychophysics.stimuli.stimulus_features`). On a trial the
observer says "test brighter" when the noisy difference of the two signals exceeds zero::

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

Stimuli are rendered with the 2015 operator once per condition and level,
and reduced to a few numbers (:mod:`~jaxadapt.psychophysics.stimuli`); the
simulation of thousands of observers then uses only those numbers, in one
``vmap``-ped call (:mod:`~jaxadapt.psychophysics.experiment`).
Observers are drawn from a :class:`~jaxadapt.psychophysics.population.Population`;
both are ``equinox`` modules (pytrees of arrays), so that :func:`probability`
and :func:`true_pse` can be differentiated with respect to cue weights and
population parameters (e.g. to calibrate them against the paper's PSEs).
The names of those modules, and of :mod:`~jaxadapt.psychophysics.displays`,
are also reachable from this one.

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
* **Population defaults**
  (:data:`~jaxadapt.psychophysics.population.POPULATIONS`): see
  :class:`~jaxadapt.psychophysics.population.Population`.
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

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.scipy.special import ndtr

from jaxadapt._checks import float_array
from jaxadapt.operators.checks import plain_errors
from jaxadapt.psychophysics import design  # noqa: F401  (the examples)
from jaxadapt.psychophysics.displays import (  # noqa: F401  (as before their module)
    DISPLAYS,
    Displays,
    afterimage_displays,
    mesopic_displays,
)
from jaxadapt.psychophysics.stimuli import (  # noqa: F401  (as before their module)
    CUE_FLOOR,
    CUES,
    SHARPNESS_SIGMA,
    Features,
    Stimuli,
    plain_stimuli,
    render_stimuli,
    stimuli_from_displays,
    stimulus_features,
)

__all__ = [
    "Observer",
    "decision_mean",
    "probability",
    "trial_probability",
    "respond",
    "true_pse",
    "weights_for_pse",
]


def _zeros():
    return jnp.zeros(len(CUES), dtype=jnp.result_type(float))


def _check_cue_axis(name, weights):
    """Raise unless ``weights`` has one entry per cue of :data:`CUES` on its last axis."""
    if jnp.shape(weights)[-1:] != (len(CUES),):
        raise ValueError(
            f"{name}: expected one value per cue {CUES} on the last axis, got shape "
            f"{jnp.shape(weights)}"
        )


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
