"""Afterimages of bleaching and local adaptation (Eqs 4-12, §2.4).

The photoreceptor inputs of a frame (Eq 1 per cone, equilibria of Eqs 6
and 10), the Gaussian visibility of afterimages around the fovea, the
local gain ``alpha`` of Eq 11, the afterimage terms of Eq 12 (Eq 7
without local adaptation), and the retina-locked maps' shift with the
gaze and blur between frames, with :func:`blur_for_display` to carry the
paper's blur to other displays.

The choices where the paper is silent (the "module notes" cited below) are
listed in the package's docstring, :mod:`jaxadapt.operators.jacobs2015`.
"""

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxadapt.color import LMS_TO_RGB, RGB_TO_LMS
from jaxadapt.fused import skipped_unless, stored
from jaxadapt.operators.jacobs2015._params import (
    PAPER_PIXELS_PER_DEGREE,
    Params,  # noqa: F401  (the examples)
)
from jaxadapt.operators.jacobs2015._planes import mix, planes, split, stacked
from jaxadapt.physiology import kinetics
from jaxadapt.physiology.response import naka_rushton, power
from jaxadapt.spatial import channels_last_filter, discrete_gaussian_kernel

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
    return Receptors(*map(stacked, receptor_planes(params, planes(frame), sigma)))


def receptor_planes(params, rgb, sigma):
    """:func:`receptors` on channel planes: ``rgb`` and each field a list of
    three ``(H, W)`` planes (:mod:`._planes`)."""
    lms = mix(RGB_TO_LMS, rgb)
    R = [naka_rushton(I, sigma, 1.0, params.n) for I in lms]
    return Receptors(
        lms,
        [kinetics.cone_bleaching(I, params.b1[k], params.b2[k]).target for k, I in enumerate(lms)],
        R,
        [kinetics.calcium(r, params.c1, params.c2).target for r in R],
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
        The frame's photoreceptor inputs, ``(H, W, 3)`` (:func:`receptors`).
    visibility : array, (H, W)

    Returns
    -------
    array, (H, W, 3)
        Linear RGB.
    """
    lms = afterimage_planes(
        params,
        mix(RGB_TO_LMS, planes(response)),
        split(state.B),
        split(state.C),
        map(planes, rec),
        visibility,
    )
    return stacked(mix(LMS_TO_RGB, lms))


def afterimage_planes(params, response, B, C, rec, v):
    """:func:`afterimages` on channel planes (:mod:`._planes`), in LMS:
    ``response`` (the tone-mapped frame's cone responses), ``B``, ``C``,
    each field of ``rec`` and the result lists of three ``(H, W)`` planes,
    ``v`` the visibility ``(H, W)``. The afterimage colours ``H`` (LMS
    bleaching to RGB) enter as ``RGB_TO_LMS H``, so that the caller turns
    the sum into RGB once."""
    rec = Receptors(*rec)
    if params.local_adaptation:
        gain = stored(
            lambda: [
                power(local_gain(params, c, c_inf), params.j2 * v)
                for c, c_inf in zip(C, rec.C_inf, strict=True)
            ]
        )
        response = [x * g for x, g in zip(response, gain, strict=True)]
    if params.bleaching:
        excess = [jnp.maximum(b - b_inf, 0.0) for b, b_inf in zip(B, rec.B_inf, strict=True)]
        if params.local_adaptation:
            excess = [e * c * (params.c2 / params.c1) for e, c in zip(excess, C, strict=True)]
        colours = jnp.asarray(RGB_TO_LMS, params.H.dtype) @ params.H
        response = [
            r + params.j1 * v * h for r, h in zip(response, mix(colours, excess), strict=True)
        ]
    return response


def shifted_planes(maps, shift, fills):
    """The planes of :func:`retinal_shift` of ``maps (3, H, W)`` by
    ``shift``, the uncovered pixels of plane ``k`` from ``fills[k]``. The
    gathers run only when the gaze has moved a whole pixel
    (:func:`jaxadapt.fused.skipped_unless`), and their results are stored
    once: fused into the step's loops, they cost a prototype of the
    1920x1080 step 135 ms a frame, against 77 ms. ``maps`` is taken whole:
    a conditional copies each slice of an array it is given."""
    return skipped_unless(
        jnp.any(shift != 0),
        lambda: [retinal_shift(m, shift, f) for m, f in zip(split(maps), fills, strict=True)],
        lambda: split(maps),
    )


def retinal_shift(maps, shift, fill):
    """Move retina-locked maps ``(H, W, ...)`` by ``shift`` (dx, dy) whole pixels.

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
    return jnp.where(inside.reshape(inside.shape + (1,) * (maps.ndim - 2)), moved, fill)


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
    B_inf, C_inf = jnp.broadcast_to(B_inf, B.shape), jnp.broadcast_to(C_inf, C.shape)
    maps = blur_map_planes(params, *map(planes, (B, C, B_inf, C_inf)))
    return tuple(map(stacked, maps))


def blur_map_planes(params, B, C, B_inf, C_inf):
    """:func:`blur_maps` on channel planes (:mod:`._planes`): each argument
    and each result a list of three ``(H, W)`` planes."""
    if params.afterimage_blur == 0:
        return B, C
    taps = discrete_gaussian_kernel(params.afterimage_blur)
    C_max = params.c1 / params.c2

    def blurred(maps, equilibria, top):
        return [
            jnp.clip(e + channels_last_filter(m - e, taps), 0.0, top)
            for m, e in zip(maps, equilibria, strict=True)
        ]

    return blurred(B, B_inf, 1.0), blurred(C, C_inf, C_max)


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
