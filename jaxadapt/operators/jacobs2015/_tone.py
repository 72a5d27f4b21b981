"""Global adaptation and the display encoding (Eqs 1-3 and 13, §2.3.2, §2.4).

The plateau ``M`` and the semi-saturation ``sigma`` of Eq 2, the
adaptation target ``A_T`` of Eq 3 (floored as §2.4 asks), the tone map of
Eq 1 with the Purkinje shift and mesopic colour, and the display's gamma
(``encode``, ``decode``).

The choices where the paper is silent (the "module notes" cited below) are
listed in the package's docstring, :mod:`jaxadapt.operators.jacobs2015`.
"""

import jax.numpy as jnp

from jaxadapt.color import transform
from jaxadapt.operators.goal import foveal_average
from jaxadapt.operators.jacobs2015._params import Params  # noqa: F401  (the examples)
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
    rho = jnp.clip(rho, 0.0, 1.0)
    L_P = transform(scene, params.w_P)
    L = rho * L_P + (1.0 - rho) * transform(scene, params.w_S) if params.purkinje else L_P
    R = naka_rushton(L, sigma, 1.0, params.n)
    positive = (L_P > 0)[..., None]
    ratio = jnp.where(positive, scene / jnp.where(positive, L_P[..., None], 1.0), 1.0)
    if params.mesopic_colour:
        ratio = rho[..., None] * ratio + (1.0 - rho[..., None]) * params.scotopic_colour
    return ratio * R[..., None]


def encode(params, R):
    """Display values ``J = clip(R, 0, 1)^gamma`` of linear responses ``R``
    (§2.4, the display's gamma compensation, ``gamma = 0.455``)."""
    return power(jnp.clip(R, 0.0, 1.0), params.gamma)


def decode(params, J):
    """Linear display values ``J^(1/gamma)`` of display values ``J`` in [0, 1]:
    the inverse of :func:`encode` (before dithering), for measuring frames."""
    return power(J, 1.0 / params.gamma)
