"""Global adaptation and the display encoding (Eqs 1-3 and 13, §2.3.2, §2.4).

The plateau ``M`` and the semi-saturation ``sigma`` of Eq 2, the
adaptation target ``A_T`` of Eq 3 (floored as §2.4 asks), the tone map of
Eq 1 with the Purkinje shift and mesopic colour, and the display's gamma
(``encode``, ``decode``).

The choices where the paper is silent (the "module notes" cited below) are
listed in the package's docstring, :mod:`jaxadapt.operators.jacobs2015`.
"""

import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt.color import RGB_TO_LMS, combine, transform
from jaxadapt.operators.goal import foveal_average
from jaxadapt.operators.jacobs2015._params import Params  # noqa: F401  (the examples)
from jaxadapt.operators.jacobs2015._planes import planes, stacked
from jaxadapt.physiology.response import naka_rushton, power

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
    return stacked(tone_planes(params, planes(scene), rho, sigma))


def tone_planes(params, scene, rho, sigma, lms=None):
    """:func:`tone_map` on channel planes: ``scene`` and the result lists of
    three ``(H, W)`` planes (:mod:`._planes`).

    Given ``lms``, the scene's cone excitations (``RGB_TO_LMS`` applied to
    ``scene``), the response is returned in LMS instead of RGB: the colour
    ratios are linear in the scene, so the cones' ratios are the
    excitations over ``L_P`` (and the scotopic colour's excitations). The
    renderer, which has the excitations and wants the response in LMS
    (Eq 12), saves a colour matrix.
    """
    rho = jnp.clip(rho, 0.0, 1.0)
    L_P = combine(params.w_P, scene)
    L = rho * L_P + (1.0 - rho) * combine(params.w_S, scene) if params.purkinje else L_P
    R = naka_rushton(L, sigma, 1.0, params.n)
    grey, colour, channels = [1.0] * 3, params.scotopic_colour, scene
    if lms is not None:
        grey = [float(g) for g in RGB_TO_LMS.sum(axis=1)]
        colour = jnp.asarray(RGB_TO_LMS, colour.dtype) @ colour
        channels = lms
    positive = L_P > 0
    inverse = 1.0 / jnp.where(positive, L_P, 1.0)
    ratio = [jnp.where(positive, x * inverse, g) for x, g in zip(channels, grey, strict=True)]
    if params.mesopic_colour:
        ratio = [rho * r + (1.0 - rho) * colour[c] for c, r in enumerate(ratio)]
    return [r * R for r in ratio]


def encode(params, R):
    """Display values ``J = clip(R, 0, 1)^gamma`` of linear responses ``R``
    (§2.4, the display's gamma compensation, ``gamma = 0.455``)."""
    return power(jnp.clip(R, 0.0, 1.0), params.gamma)


def decode(params, J):
    """Linear display values ``J^(1/gamma)`` of display values ``J`` in [0, 1]:
    the inverse of :func:`encode` (before dithering), for measuring frames."""
    return power(J, 1.0 / params.gamma)


def dither(params, J, key):
    """Temporal dithering of §2.4 to ``levels`` steps, as
    :func:`jaxadapt.display.dither` (``floor(J levels + u) / levels``, one
    uniform ``u`` per channel of every pixel, new each frame through
    ``key``), with ``u`` from a counter-based hash of the value's index and
    two seeds drawn from ``key``, not from ``jax.random.uniform``: on the
    CPU the 6.2 million Threefry draws of a 1920x1080 frame took 145 ms;
    the hash is a few integer operations inside the pixel pass. ``u`` has
    24 random bits, far more than the dithering of 8-bit steps resolves.
    ``J (..., 3)``; :func:`dither_planes` on channel planes."""
    return stacked(dither_planes(params, planes(J), jax.random.bits(key, (2,), jnp.uint32)))


def dither_planes(params, J, seed):
    """:func:`dither` on channel planes (:mod:`._planes`), from the two
    ``uint32`` seeds ``seed`` drawn from the frame's key; the value of
    channel ``c`` of pixel ``p`` draws with index ``3 p + c``, as in
    ``(..., 3)``."""
    pixel = jnp.arange(J[0].size, dtype=jnp.uint32).reshape(J[0].shape) * np.uint32(len(J))
    out = []
    for c, plane in enumerate(J):
        bits = _mix(_mix((pixel + np.uint32(c)) ^ seed[0]) + seed[1])
        u = (bits >> 8).astype(plane.dtype) * (2.0**-24)
        steps = jnp.clip(jnp.floor(plane * params.levels + u), 0.0, params.levels)
        out.append(steps / params.levels)
    return out


def _mix(x):
    """A 32-bit integer hash (the "lowbias32" finaliser of C. Wellons, an
    avalanche of every input bit into every output bit), on ``uint32``."""
    x = x ^ (x >> 16)
    x = x * np.uint32(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * np.uint32(0x846CA68B)
    return x ^ (x >> 16)
