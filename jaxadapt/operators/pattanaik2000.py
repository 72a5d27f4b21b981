"""The time-dependent tone reproduction operator of Pattanaik et al. (2000).

A viewer looks at a scene whose luminance changes over time; a display
observer, adapted to an ordinary display, looks at our output. The operator
finds display values that evoke in the display observer the appearance the
scene evokes in the scene viewer (Fig. 1 and Fig. 4 of the paper)::

    frame (cd/m2) -> goal G -> kinetics -> A, B -> sigma, references, rule
                                                      |
    pixels: L_rod, L_cone -> R_lum, S_color -> display response -> display RGB

The adaptation state is four scalars (``A_rod``, ``A_cone``, ``B_rod``,
``B_cone``). :func:`run` therefore finds the goals of every frame at once
(one batched reduction), advances the state through the whole sequence by
the exact kinetics (on a GPU by their associative form, with no loop over
frames), and only then maps the pixels of every frame in one vectorised
pass; :func:`step` does the same one frame at a time.

Timing: frame ``k``, shown at ``t_k``, is seen with the state reached at
``t_k``; its goal is then held for its duration ``dt_k`` to give the state
at ``t_{k+1}``. This is the reading of §5 (title page): the frame just after
the lights come on is seen with the adaptation of the dark frame before it
("the lighting has changed, but the scene viewer's adaptation state has
not"), and is almost entirely white.

References
----------
Pattanaik, Tumblin, Yee, Greenberg (2000), *Time-Dependent Visual Adaptation
for Fast Realistic Image Display*, SIGGRAPH 2000, §4-§5.
"""

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt import background, fused
from jaxadapt._checks import check_value, float_array
from jaxadapt.color import (
    W_PHOTOPIC,
    W_SCOTOPIC,
    combine,
    photopic_luminance,
    scotopic_luminance,
)
from jaxadapt.gaze import fixation, frame_centre
from jaxadapt.operators import goal as goals
from jaxadapt.operators.checks import (
    as_dtype,
    check_adaptation,
    check_fields,
    check_frames,
    check_frames_and_dt,
    check_one_parameter_set,
    check_rgb,
    check_state,
    frames_and_dt_messages,
    frames_messages,
    is_traced,
    raise_verdict,
)
from jaxadapt.physiology import kinetics
from jaxadapt.physiology.response import (
    forward_difference_slope,
    log_naka_rushton_sum_inverse,
    naka_rushton,
    response_slope,
    sigma_cone,
    sigma_rod,
)

#: Scene luminances (log10 cd/m2) at which the scene-to-display curve of the
#: diagnostics is sampled: 1e-6 to 1e8 cd/m2, ten samples a decade.
CURVE_LOG10_LUMINANCE = jnp.linspace(-6.0, 8.0, 141)


class Params(eqx.Module):
    """Parameters of the operator; numeric fields are arrays, so a batch of
    parameter sets can be ``vmap``-ped.

    Attributes
    ----------
    n : float
        Response exponent of Eq 2 (0.73, Hunt).
    t0_rod, t0_cone : float
        Neural adaptation time constants, s (0.150, 0.080; §4.1.2).
    tau_rod, tau_cone : float
        Pigment regeneration time constants, s (400, 110; Eq 7).
    c_rod, c_cone : float
        Bleaching constants, cd/m2 s (16, 2.2e8; Eq 7).
    white_factor : float
        Reference white as a multiple of adaptation (5; Eq 8).
    black_ratio : float
        Reference white over reference black (32; Eq 8), above 1: at 1 the
        display's colour exponent ``S_d`` is 0/0, below it black is
        brighter than white.
    display_adaptation : float
        Adaptation of the display observer, cd/m2 (25; §4.3). The display's
        white is ``white_factor`` times this (125 cd/m2) and maps to 1.0.
    display_B_cone : float
        Cone bleaching factor of the display observer (1; §4.3).
    goal_fraction : float
        Fraction of white used by the ``"white_fraction"`` goal (1/5).
    white_percentile : float
        Percentile of luminance taken as white by ``"white_fraction"``.
    pixels_per_degree : float
        Resolution at the eye, used by the ``"foveal"`` goal.
    goal : str
        Adaptation-goal finder: ``"log_average"``, ``"white_fraction"`` or
        ``"foveal"`` (see :mod:`jaxadapt.operators.goal`). Static.
    background : str
        ``"global"`` (the default): one goal per frame from ``goal``, the
        paper's operator. Any other name of
        :data:`jaxadapt.background.BACKGROUNDS` (``"gaussian"``,
        ``"bilateral"``, ``"adaptive"``, ...): a goal per pixel, the local
        background luminance, and a state per pixel advanced with the same
        exact kinetics, so that local adaptation stays time-dependent (unlike
        pfstmo's ``--local``, which drops time dependence). Static.
    background_scale : float
        Size of the local background estimator, pixels (its ``scale``). Static.
    """

    n: jax.Array = eqx.field(default=0.73, converter=float_array)
    t0_rod: jax.Array = eqx.field(default=0.150, converter=float_array)
    t0_cone: jax.Array = eqx.field(default=0.080, converter=float_array)
    tau_rod: jax.Array = eqx.field(default=400.0, converter=float_array)
    tau_cone: jax.Array = eqx.field(default=110.0, converter=float_array)
    c_rod: jax.Array = eqx.field(default=16.0, converter=float_array)
    c_cone: jax.Array = eqx.field(default=2.2e8, converter=float_array)
    white_factor: jax.Array = eqx.field(default=5.0, converter=float_array)
    black_ratio: jax.Array = eqx.field(default=32.0, converter=float_array)
    display_adaptation: jax.Array = eqx.field(default=25.0, converter=float_array)
    display_B_cone: jax.Array = eqx.field(default=1.0, converter=float_array)
    goal_fraction: jax.Array = eqx.field(default=0.2, converter=float_array)
    white_percentile: jax.Array = eqx.field(default=99.0, converter=float_array)
    pixels_per_degree: jax.Array = eqx.field(default=30.0, converter=float_array)
    goal: str = eqx.field(default="log_average", static=True)
    background: str = eqx.field(default="global", static=True)
    background_scale: float = eqx.field(default=8.0, static=True)

    def __check_init__(self):
        if self.goal not in goals.GOALS:
            raise ValueError(f"goal: expected one of {goals.GOALS}, got {self.goal!r}")
        background.check_background(self.background, self.background_scale)
        check_fields(self, positive=POSITIVE_FIELDS)
        check_value("black_ratio", self.black_ratio, lambda v: v > 1, "a number above 1")
        for name in ("display_B_cone", "goal_fraction"):
            check_value(name, getattr(self, name), lambda v: (v > 0) & (v <= 1), "in (0, 1]")
        check_value(
            "white_percentile", self.white_percentile, lambda v: (v > 0) & (v <= 100), "in (0, 100]"
        )


#: The fields of :class:`Params` that must be positive and finite (time and
#: bleaching constants, exponent, reference factors, display adaptation,
#: resolution): a negative ``t0`` would drive the adaptation state below
#: zero and a NaN one make it NaN, both silently.
POSITIVE_FIELDS = (
    "n",
    "t0_rod",
    "t0_cone",
    "tau_rod",
    "tau_cone",
    "c_rod",
    "c_cone",
    "white_factor",
    "black_ratio",
    "display_adaptation",
    "pixels_per_degree",
)


class State(NamedTuple):
    """Adaptation state of the scene viewer.

    Attributes
    ----------
    A_rod, A_cone : array
        Neural adaptation luminance, cd/m2.
    B_rod, B_cone : array
        Unbleached pigment fraction, in [0, 1].
    """

    A_rod: jax.Array
    A_cone: jax.Array
    B_rod: jax.Array
    B_cone: jax.Array


class Display(NamedTuple):
    """The display observer's constants (§4.3) that the pixel map uses:
    sigma and B of both receptors adapted to ``display_adaptation``, its
    response to display white ``REF_wht``, its colour exponent ``S_d`` and
    the natural log of display white, ``ln(white_factor A_d)`` (cd/m2)."""

    sigma_rod: jax.Array
    sigma_cone: jax.Array
    B_rod: jax.Array
    B_cone: jax.Array
    white: jax.Array
    slope: jax.Array
    log_white: jax.Array


class Observer(NamedTuple):
    """Everything the pixel map needs from one frame's adaptation: sigma and B
    of both receptors, the affine map of the inverse appearance model
    (display response = ``scale * R_lum + offset``) and the display
    observer's constants. Scalars computed once per frame, so that the
    pixel map does not repeat them per pixel."""

    sigma_rod: jax.Array
    sigma_cone: jax.Array
    B_rod: jax.Array
    B_cone: jax.Array
    scale: jax.Array
    offset: jax.Array
    rule: jax.Array
    display: Display


class Diagnostics(NamedTuple):
    """Per-frame record of a :func:`run` (leading axis: frames).

    With a local background, every per-frame value is the one at the gaze
    point (the pixel nearest it): what the fovea is adapted to.

    Attributes
    ----------
    t : array, (T,)
        Time of each frame, s, from 0.
    G_rod, G_cone : array, (T,)
        Adaptation goals, cd/m2.
    state : State
        State each frame was seen with, fields of shape (T,).
    sigma_rod, sigma_cone : array, (T,)
        Semi-saturation luminances, cd/m2.
    rule : array, (T,)
        Rule of §4.3 (1-4) that mapped the frame.
    curve : array, (T, 141)
        Display value (linear, [0, 1]) of a neutral scene luminance
        ``10**CURVE_LOG10_LUMINANCE`` cd/m2: the graphs under Fig. 7.
    final_state : State
        State after the last frame's ``dt``, to continue a sequence (maps
        ``(H, W)`` with a local background).
    """

    t: jax.Array
    G_rod: jax.Array
    G_cone: jax.Array
    state: State
    sigma_rod: jax.Array
    sigma_cone: jax.Array
    rule: jax.Array
    curve: jax.Array
    final_state: State


def diagnostics_table(diag):
    """Per-frame columns of a :class:`Diagnostics`, as numpy arrays.

    Scalars per frame (``t``, ``G_rod``, ``G_cone``, ``A_rod``, ``A_cone``,
    ``B_rod``, ``B_cone``, ``sigma_rod``, ``sigma_cone``, ``rule``) and the
    sampled scene-to-display ``curve`` ``(T, 141)``.
    """
    s = diag.state
    columns = {
        "t": diag.t,
        "G_rod": diag.G_rod,
        "G_cone": diag.G_cone,
        "A_rod": s.A_rod,
        "A_cone": s.A_cone,
        "B_rod": s.B_rod,
        "B_cone": s.B_cone,
        "sigma_rod": diag.sigma_rod,
        "sigma_cone": diag.sigma_cone,
        "rule": diag.rule,
        "curve": diag.curve,
    }
    return {name: np.asarray(column) for name, column in columns.items()}


# -- the observers ------------------------------------------------------------


def luminance_response(params, L_rod, L_cone, sigma_r, sigma_c, B_rod, B_cone):
    """``R_lum = R_rod + R_cone`` (Eq 2 and §4.2)."""
    return naka_rushton(L_rod, sigma_r, B_rod, params.n) + naka_rushton(
        L_cone, sigma_c, B_cone, params.n
    )


def _display_observer(params):
    """sigma and B of the display observer, adapted to ``display_adaptation``.

    sigma from Eqs 4-5 (722 cd/m2 for rods, 646 for cones at 25 cd/m2), ``B_rod`` the static
    value of Eq 6 (0.0016) and ``B_cone`` the paper's 1.
    """
    A = params.display_adaptation
    B_rod = kinetics.bleaching(A, params.tau_rod, params.c_rod).target
    return sigma_rod(A, params.n), sigma_cone(A, params.n), B_rod, params.display_B_cone


def references(params, sigma_r, sigma_c, B_rod, B_cone, A_rod, A_cone):
    """Responses to reference white and black, ``(REF_wht, REF_blk)`` (Eq 8).

    White is ``white_factor * A``, black is white over ``black_ratio``.
    """
    w, k = params.white_factor, params.black_ratio
    white = luminance_response(params, w * A_rod, w * A_cone, sigma_r, sigma_c, B_rod, B_cone)
    black = luminance_response(
        params, w * A_rod / k, w * A_cone / k, sigma_r, sigma_c, B_rod, B_cone
    )
    return white, black


def display_references(params):
    """``(REF_wht, REF_blk)`` of the display observer (§4.3)."""
    A = params.display_adaptation
    return references(params, *_display_observer(params), A, A)


def display_slope(params):
    """The display's colour exponent ``S_d`` (§4.3).

    The forward-difference slope per log10 unit of the display observer's
    cone response between display white and black: 0.1383 with the
    paper's constants.
    """
    A, w = params.display_adaptation, params.white_factor
    _, sigma_c, _, B_cone = _display_observer(params)
    return forward_difference_slope(w * A, w * A / params.black_ratio, sigma_c, B_cone, params.n)


def display(params):
    """The display observer's constants (:class:`Display`)."""
    A = params.display_adaptation
    receptors = _display_observer(params)
    white, _ = references(params, *receptors, A, A)
    log_white = jnp.log(params.white_factor * A)
    return Display(*receptors, white, display_slope(params), log_white)


def display_log_luminance(params, R):
    """Log of the luminance (cd/m2) of a neutral display pixel that evokes response ``R``:
    :func:`inverse_display` with the constants of ``params``."""
    return inverse_display(display(params), R, params.n)


def inverse_display(d, R, n):
    """Log of the luminance (cd/m2) at which the display observer ``d``
    (:class:`Display`) responds ``R``.

    The inverse of the display observer's ``R_lum(L) = R_rod(L) + R_cone(L)``
    (Eq 2 with the constants of §4.3), solved exactly
    (:func:`~jaxadapt.physiology.response.log_naka_rushton_sum_inverse`).
    ``R`` is first clipped to ``[0, REF_wht]``: the display cannot show more
    than its white.
    """
    R = jnp.clip(R, 0.0, d.white)
    return log_naka_rushton_sum_inverse(R, d.sigma_rod, d.B_rod, d.sigma_cone, d.B_cone, n)


def display_luminance(params, R):
    """Luminance (cd/m2) of a neutral display pixel that evokes response ``R``:
    ``exp`` of :func:`display_log_luminance` (0 for ``R <= 0``)."""
    return jnp.exp(display_log_luminance(params, R))


def inverse_appearance(params, ref_white, ref_black):
    """The four rules of §4.3 as an affine map of the scene response.

    Returns ``(scale, offset, rule)`` such that the display observer's
    response is ``scale * R_lum + offset``:

    1. the scene's reference range ``[REF_blk, REF_wht]`` lies within the
       display's: identity (the offset of the forward appearance model is
       cancelled exactly);
    2. else, if the scene's ``Q_span`` exceeds the display's: compress and
       offset so that scene white and black land on display white and black;
    3. else, if the scene's ``Q_mid`` exceeds the display's: offset down just
       enough that scene white lands on display white;
    4. else: offset up just enough that scene black lands on display black.

    When the span fits (rules 3-4) the range overflows on one side only, and
    ``Q_mid`` tells which, so the four cases cover every scene.
    """
    white_d, black_d = display_references(params)
    fits = (ref_white <= white_d) & (ref_black >= black_d)
    span, span_d = ref_white - ref_black, white_d - black_d
    mid, mid_d = 0.5 * (ref_white + ref_black), 0.5 * (white_d + black_d)
    rule = jnp.where(fits, 1, jnp.where(span > span_d, 2, jnp.where(mid > mid_d, 3, 4)))
    compress = span_d / span
    scale = jnp.where(rule == 2, compress, 1.0)
    offset = jnp.select(
        [rule == 1, rule == 2, rule == 3],
        [jnp.zeros_like(span), black_d - compress * ref_black, white_d - ref_white],
        black_d - ref_black,
    )
    return scale, offset, rule


def observer(params, state):
    """The scene viewer's response constants for a state (Eqs 4-5 and 8)."""
    sigma_r = sigma_rod(state.A_rod, params.n)
    sigma_c = sigma_cone(state.A_cone, params.n)
    ref_white, ref_black = references(
        params, sigma_r, sigma_c, state.B_rod, state.B_cone, state.A_rod, state.A_cone
    )
    scale, offset, rule = inverse_appearance(params, ref_white, ref_black)
    return Observer(
        sigma_r, sigma_c, state.B_rod, state.B_cone, scale, offset, rule, display(params)
    )


# -- the pixel map ------------------------------------------------------------


def tone_map(params, obs, rgb):
    """Map scene pixels to display-relative linear RGB in [0, 1].

    Parameters
    ----------
    params : Params
    obs : Observer
        The frame's adaptation (from :func:`observer`).
    rgb : array, shape (..., 3)
        Linear BT.709 RGB, cd/m2.

    Returns
    -------
    array, shape (..., 3)
        Display values, linear, 1.0 = display white.

    Notes
    -----
    Per pixel: ``L_rod`` (scotopic) and ``L_cone`` (photopic) luminance;
    ``R_lum = R_rod + R_cone`` (Eq 2); the display response
    ``scale * R_lum + offset`` (§4.3); its luminance ``L_d`` through the
    inverse display observer; and the colour ratios ``C = rgb / L_cone``
    raised to ``e = S_color / S_d`` (Eq 3 per log10 unit, over the display's
    ``S_d``): ``out = C^e L_d / L_white``, clipped to [0, 1]. Black pixels
    (``L_cone = 0``) have neutral colour ratios.

    Each channel costs one exponential: ``out = exp(e ln rgb + s)`` with the
    pixel's ``s = ln L_d - ln L_white - e ln L_cone``, and ``ln L_d`` comes
    from the display inverse in its log form (:func:`display_log_luminance`:
    a display luminance of 0 enters below 1e-49 cd/m2, an output of 0). Black
    pixels get their neutral ratio from adding 1 to ``rgb`` and ``L_cone``
    there, not from a select on a per-pixel test broadcast over the
    channels: XLA's CPU backend evaluates the exponentials after such a
    select unvectorised, several times slower.

    The clip is per channel, as in the paper: a saturated colour whose
    dominant channel is at 1 can come out darker as it brightens, its
    exponent (up to 3.04) pushing the other channels down (the
    documentation's choices, "Saturated colours at display white").
    Neutral pixels map monotonically.
    """
    rgb = check_rgb(rgb, "rgb")
    e, s, black = pixel_terms(params, obs, scotopic_luminance(rgb), photopic_luminance(rgb))
    return display_value(e[..., None], s[..., None], black[..., None], rgb)


def tone_map_planes(params, obs, channels):
    """:func:`tone_map` on channel planes ``[r, g, b]``, for a fused kernel
    (:func:`jaxadapt.fused.map_pixels`): the same terms, once per pixel."""
    L_rod, L_cone = (combine(w, channels) for w in (W_SCOTOPIC, W_PHOTOPIC))
    e, s, black = pixel_terms(params, obs, L_rod, L_cone)
    return [display_value(e, s, black, c) for c in channels]


def pixel_terms(params, obs, L_rod, L_cone):
    """What the pixel map needs of a pixel's luminances (cd/m2): ``(e, s, black)``.

    ``e = S_color / S_d`` is the colour exponent, ``s = ln L_d - ln L_white
    - e ln L_cone`` the log of the display value of a channel equal to
    ``L_cone``, and ``black`` is 1 where ``L_cone = 0``, else 0
    (:func:`tone_map`).
    """
    R_lum = luminance_response(
        params, L_rod, L_cone, obs.sigma_rod, obs.sigma_cone, obs.B_rod, obs.B_cone
    )
    d = obs.display
    ln_L_d = inverse_display(d, obs.scale * R_lum + obs.offset, params.n)
    e = response_slope(L_cone, obs.sigma_cone, obs.B_cone, params.n) / d.slope
    black = (L_cone <= 0).astype(L_cone.dtype)
    return e, ln_L_d - d.log_white - e * jnp.log(L_cone + black), black


def display_value(e, s, black, c):
    """Display value ``min(exp(e ln c + s), 1)`` of a channel ``c`` (cd/m2),
    0 where ``c = 0``; a black pixel's channels enter as 1 (neutral)."""
    c = c + black
    lit = c > 0
    out = jnp.exp(e * jnp.log(jnp.where(lit, c, 1.0)) + s)
    return jnp.minimum(jnp.where(lit, out, 0.0), 1.0)


def curve(params, obs):
    """Display value of neutral scene luminances ``10**CURVE_LOG10_LUMINANCE``."""
    L = 10.0 ** CURVE_LOG10_LUMINANCE.astype(obs.sigma_cone.dtype)
    return tone_map(params, obs, jnp.repeat(L[:, None], 3, axis=-1))[:, 1]


# -- goals and kinetics -------------------------------------------------------


def frame_goals(params, frame, gaze):
    """Adaptation goals ``(G_rod, G_cone)`` of a frame ``(H, W, 3)``, cd/m2.

    Scalars, or ``(H, W)`` maps of the local background when
    ``params.background`` is not ``"global"``. ``gaze`` ``(x, y)`` in
    pixels is used by the ``"foveal"`` goal.
    """

    def goal(L):
        if params.background != "global":
            return background.estimate_background(L, params.background, params.background_scale)
        if params.goal == "log_average":
            return goals.log_average(L)
        if params.goal == "white_fraction":
            return goals.white_fraction(L, params.goal_fraction, params.white_percentile)
        return goals.foveal_log_average(L, gaze, params.pixels_per_degree)

    # Two reductions of the frame's shape (not one of a stack): XLA fuses
    # them, and the frames' value check, into one read of the frames.
    return goal(scotopic_luminance(frame)), goal(photopic_luminance(frame))


def static_state(params, G_rod, G_cone):
    """Fully adapted state for goals held forever: ``A = G``, ``B = B_inf(G)``."""
    B_rod = kinetics.bleaching(G_rod, params.tau_rod, params.c_rod).target
    B_cone = kinetics.bleaching(G_cone, params.tau_cone, params.c_cone).target
    return State(G_rod, G_cone, B_rod, B_cone)


def relaxations(params, G_rod, G_cone):
    """The kinetics of each state field under goals ``G_rod``, ``G_cone``
    (cd/m2): a :class:`State` of :class:`~jaxadapt.physiology.kinetics.Relaxation`.

    Neural filters with ``t0_rod``, ``t0_cone`` (§4.1.2) and pigment
    bleaching with ``tau``, ``c`` (Eq 7).
    """
    return State(
        kinetics.neural(G_rod, params.t0_rod),
        kinetics.neural(G_cone, params.t0_cone),
        kinetics.bleaching(G_rod, params.tau_rod, params.c_rod),
        kinetics.bleaching(G_cone, params.tau_cone, params.c_cone),
    )


def advance(params, state, G_rod, G_cone, dt):
    """State after goals held for ``dt`` s: the exact steps of the kinetics."""
    steps = zip(state, relaxations(params, G_rod, G_cone), strict=True)
    return State(*(kinetics.relaxation_step(y, law, dt) for y, law in steps))


def advance_sequence(params, state, G_rod, G_cone, dt):
    """States a sequence of frames is seen with, and the state after it.

    Frame ``k``'s goals ``G_rod[k]``, ``G_cone[k]`` (cd/m2) are held for
    ``dt[k]`` s. The exact steps of the four fields over the whole
    sequence (:func:`~jaxadapt.physiology.kinetics.relaxation_sequences`:
    on a GPU all frames at once, by their associative form): equal to a
    loop of :func:`advance` up to rounding.

    Returns
    -------
    (State, State)
        Fields of shape ``(T, ...)``: the state at each frame's start; and
        the state after the last frame's ``dt``.
    """
    ys = kinetics.relaxation_sequences(state, relaxations(params, G_rod, G_cone), dt)
    return State(*(y[:-1] for y in ys)), State(*(y[-1] for y in ys))


# -- the contract -------------------------------------------------------------


def _fixation(frames, gaze):
    """The point ``(x, y)``, pixels, of frames ``(..., H, W, 3)`` that the
    foveal goal and the diagnostics are read at, one per frame.

    ``gaze`` clipped to the frame; the frame's centre where ``gaze`` is None
    or a sample is not finite (NaN: a blink; :func:`~jaxadapt.gaze.fixation`).
    This operator keeps no gaze in its state, so a blink cannot hold the
    fixation before it: :func:`jaxadapt.gaze.recorded_gaze` holds it in
    a recorded path (as the 2015 operator holds it in its state).
    """
    shape = frames.shape[-3:-1]
    centre = frame_centre(shape, frames.dtype)
    if gaze is None:
        return jnp.broadcast_to(centre, frames.shape[:-3] + (2,))
    return fixation(gaze, centre, shape)


def init(params, first_frame, *, gaze=None, key=None, adaptation=None):
    """State of a viewer fully adapted before the sequence starts.

    Parameters
    ----------
    params : Params
    first_frame : array, shape (H, W, 3)
        Linear RGB, cd/m2; the viewer is adapted to its goals.
    gaze : array, shape (2,), optional
        Gaze point ``(x, y)`` in pixels, for the ``"foveal"`` goal (default
        and during a blink, NaN: the centre; see :func:`_fixation`).
    key : ignored
        The operator is deterministic.
    adaptation : float, optional
        Adapt instead to this luminance (cd/m2) for rods and cones, e.g.
        0.01 for the moonlit start of the title-page sequence; at least
        ``goal.LUMINANCE_FLOOR`` (1e-6) counts, as for the goals of frames,
        so that 0 is a fully dark-adapted viewer. With a local background
        the state is then a uniform map, of ``first_frame``'s size.

    Returns
    -------
    State
        Scalars, or ``(H, W)`` maps with a local background, in the frame's
        dtype (the dtype :func:`run` returns its final state in, so that a
        sequence run in chunks compiles ``run`` once).
    """
    on_host = not is_traced(params, first_frame, gaze, adaptation)
    state, verdict = _init(params, first_frame, gaze, adaptation, on_host)
    raise_verdict(verdict, frames_messages("first_frame"))
    return state


@eqx.filter_jit
def _init(params, first_frame, gaze, adaptation, on_host):
    check_one_parameter_set(params)
    if adaptation is not None:
        floating = first_frame is not None and jnp.issubdtype(first_frame.dtype, jnp.floating)
        dtype = first_frame.dtype if floating else jnp.result_type(float)
        check_adaptation(adaptation)
        A = jnp.maximum(jnp.asarray(adaptation, dtype=dtype), goals.LUMINANCE_FLOOR)
        if params.background != "global" and first_frame is not None:
            A = jnp.broadcast_to(A, first_frame.shape[:2])  # as run() carries it
        return static_state(as_dtype(params, dtype), A, A), None
    guard, verdict = check_frames(first_frame, 3, "first_frame", on_host)
    params = as_dtype(params, first_frame.dtype)
    G_rod, G_cone = frame_goals(params, first_frame, _fixation(first_frame, gaze))
    return static_state(params, G_rod + guard, G_cone + guard), verdict


def _probe(x, gaze):
    """``x`` itself if a scalar, else its value at the pixel nearest ``gaze``."""
    if x.ndim == 0:
        return x
    H, W = x.shape
    col = jnp.clip(jnp.round(gaze[0]).astype(jnp.int32), 0, W - 1)
    row = jnp.clip(jnp.round(gaze[1]).astype(jnp.int32), 0, H - 1)
    return x[row, col]


def _display(params, G_rod, G_cone, states, frames, gaze):
    """Show frames ``(T, H, W, 3)`` with their goals to viewers in ``states``.

    All arguments but ``params`` have a leading frame axis. Returns the
    display frames and each frame's record at the gaze point ``(G_rod,
    G_cone, state, observer, curve)``. The pixel map is one pass over the
    frames on a GPU (:func:`jaxadapt.fused.map_pixels`).
    """
    obs = jax.vmap(observer, (None, 0))(params, states)
    seen = jax.vmap(lambda g, *x: jax.tree.map(lambda y: _probe(y, g), x))(
        gaze, G_rod, G_cone, states, obs
    )
    out = fused.map_pixels(
        lambda args, channels: tone_map_planes(*args, channels),
        frames,
        (params, obs),
        default=lambda frames, args: jax.vmap(tone_map, (None, 0, 0))(*args, frames),
    )
    return out, (*seen, jax.vmap(curve, (None, 0))(params, seen[-1]))


def step(params, state, frame, dt, *, gaze=None, key=None):
    """Show one frame, then advance the state over its duration.

    Parameters
    ----------
    params : Params
    state : State
        State at the time the frame is shown.
    frame : array, shape (H, W, 3)
        Linear RGB, cd/m2.
    dt : float
        How long the frame is held, s.
    gaze : array, shape (2,), optional
        Gaze point ``(x, y)``, pixels (``"foveal"`` goal; default and during
        a blink, NaN: the centre).
    key : ignored
        The operator is deterministic; accepted so that all operators share
        one signature.

    Returns
    -------
    (State, array)
        The state after ``dt`` and the display frame ``(H, W, 3)`` in [0, 1].
    """
    gaze = None if gaze is None else jnp.asarray(gaze)
    check_state(state, State, "pattanaik2000")
    frame, dt = jnp.asarray(frame), jnp.asarray(dt)
    on_host = not is_traced(params, state, frame, dt, gaze)
    state, out, verdict = _step(params, state, frame, dt, gaze, on_host)
    raise_verdict(verdict, frames_and_dt_messages("frame"))
    return state, out


@eqx.filter_jit
def _step(params, state, frame, dt, gaze, on_host):
    guard, dt, verdict = check_frames_and_dt(frame, dt, 3, "frame", on_host)
    check_one_parameter_set(params)
    params, state, dt, gaze = as_dtype((params, state, dt[0], gaze), frame.dtype)
    state = jax.tree.map(lambda s: s + guard, state)
    gaze = _fixation(frame, gaze)
    G_rod, G_cone = frame_goals(params, frame, gaze)
    one = jax.tree.map(lambda x: x[None], (G_rod, G_cone, state, frame, gaze))
    out, _ = _display(params, *one)
    return advance(params, state, G_rod, G_cone, dt), out[0], verdict


def run(params, frames, dt, *, gaze=None, key=None, state=None):
    """Tone-map a sequence with time-dependent adaptation.

    Parameters
    ----------
    params : Params
    frames : array, shape (T, H, W, 3)
        Linear BT.709 RGB, cd/m2, finite and non-negative.
    dt : float or array, shape (T,)
        Duration of each frame, s (``1/fps``).
    gaze : array, shape (T, 2), optional
        Gaze path ``(x, y)`` in pixels, for the ``"foveal"`` goal and for
        the point a local operator's diagnostics are read at, clipped to
        the frame (default, and for samples that are not finite, NaN
        during a blink: the image centre; see :func:`_fixation`).
    key : ignored
        The operator is deterministic.
    state : State, optional
        State at the first frame; by default the viewer is fully adapted to
        the first frame (:func:`init`).

    Returns
    -------
    (array, Diagnostics)
        Display frames ``(T, H, W, 3)``, linear, in [0, 1], and the per-frame
        record (at the gaze point, for a local background). ``run`` finds
        every frame's goals at once, advances the state through the whole
        sequence (:func:`advance_sequence`) and then maps the pixels of all
        frames in one vectorised pass; it gives the frames of a loop of
        :func:`step` up to rounding.

    Examples
    --------
    >>> frames = jnp.full((4, 2, 2, 3), 100.0)
    >>> out, diag = run(Params(), frames, 1 / 30)
    >>> out.shape, diag.G_cone.shape
    ((4, 2, 2, 3), (4,))
    """
    gaze = None if gaze is None else jnp.asarray(gaze)
    frames, dt = jnp.asarray(frames), jnp.asarray(dt)
    on_host = not is_traced(params, frames, dt, gaze, state)
    out, diagnostics, verdict = _run(params, frames, dt, gaze, state, on_host)
    raise_verdict(verdict, frames_and_dt_messages("frames"))
    return out, diagnostics


def _checked_state(state, shape, guard):
    """A given ``state`` broadcast to the goals' ``shape`` (``()``, or the
    frames' ``(H, W)`` with a local background), with the frames' check
    ``guard`` added, after checking that it is a :class:`State` whose
    fields are scalars or of ``shape`` (``ValueError`` naming the field; its
    values are not checked: a second conditional would cost every step of
    a fit through ``run``)."""
    check_state(state, State, "pattanaik2000")
    shapes = "()" if shape == () else f"() or {shape} (the goals' shape)"
    for name, field in zip(State._fields, state, strict=True):
        if jnp.shape(field) not in ((), shape):
            raise ValueError(
                f"state: expected fields of shape {shapes}, got {name} of shape {jnp.shape(field)}"
            )
    return State(*(jnp.broadcast_to(field + guard, shape) for field in state))


@eqx.filter_jit
def _run(params, frames, dt, gaze, state, on_host):
    guard, dt, verdict = check_frames_and_dt(frames, dt, 4, on_host=on_host)
    check_one_parameter_set(params)
    params, state, dt, gaze = as_dtype((params, state, dt, gaze), frames.dtype)
    T = frames.shape[0]
    if gaze is not None and gaze.shape != (T, 2):
        raise ValueError(f"gaze: expected shape ({T}, 2) in pixels, got shape {gaze.shape}")
    gaze = _fixation(frames, gaze)
    G_rod, G_cone = jax.vmap(frame_goals, (None, 0, 0))(params, frames, gaze)
    if state is None:
        state = static_state(params, G_rod[0], G_cone[0])
    state = _checked_state(state, G_cone.shape[1:], guard)
    states, final_state = advance_sequence(params, state, G_rod, G_cone, dt)
    out, record = _display(params, G_rod, G_cone, states, frames, gaze)
    G_rod, G_cone, states, obs, curves = record
    diagnostics = Diagnostics(
        t=jnp.cumsum(dt) - dt,
        G_rod=G_rod,
        G_cone=G_cone,
        state=states,
        sigma_rod=obs.sigma_rod,
        sigma_cone=obs.sigma_cone,
        rule=obs.rule,
        curve=curves,
        final_state=final_state,
    )
    return out, diagnostics, verdict
