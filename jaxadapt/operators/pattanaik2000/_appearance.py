"""The appearance model: what a viewer sees of a pixel, and the display
values that evoke it in the display observer.

The response ``R_lum = R_rod + R_cone`` (Eq 2, §4.2) with the
semi-saturations of Eqs 4-5; the responses to reference white and black
(Eq 8); the display observer adapted to an ordinary display and the four
rules of the inverse appearance model (§4.3); the colour exponent
``S_color / S_d`` (Eq 3); and the per-pixel map that applies them
(:func:`tone_map`, and its planes form for the fused kernel), with the
sampled scene-to-display curve of the diagnostics (Fig. 7).

It needs only an :class:`Observer` (one frame's adaptation), never the
kinetics: the time dependence is in :mod:`._adaptation`.
"""

import jax.numpy as jnp

from jaxadapt.color import (
    W_PHOTOPIC,
    W_SCOTOPIC,
    combine,
    photopic_luminance,
    scotopic_luminance,
)
from jaxadapt.operators.checks import check_rgb, saturate
from jaxadapt.operators.pattanaik2000._params import CURVE_LOG10_LUMINANCE, Display, Observer
from jaxadapt.physiology import kinetics
from jaxadapt.physiology.response import (
    forward_difference_slope,
    log_naka_rushton_sum_inverse,
    naka_rushton,
    response_slope,
    sigma_cone,
    sigma_rod,
)

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
    rgb = saturate(check_rgb(rgb, "rgb"))
    e, s, black = pixel_terms(params, obs, scotopic_luminance(rgb), photopic_luminance(rgb))
    return display_value(e[..., None], s[..., None], black[..., None], rgb)


def tone_map_planes(params, obs, channels):
    """:func:`tone_map` on channel planes ``[r, g, b]``, for a fused kernel
    (:func:`jaxadapt.fused.map_pixels`): the same terms, once per pixel."""
    channels = [saturate(c) for c in channels]
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
