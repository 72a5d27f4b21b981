"""Adaptation-goal finders: a luminance image ``(..., H, W)`` in cd/m2 to
one goal per image, shape ``(...)``, in cd/m2 (Pattanaik et al. 2000,
§4.1.2, the "Adaptation Goal Finder" of Fig. 4); :data:`GOALS` names them.
The background estimators, one background per pixel, are in
:mod:`jaxadapt.background`.
"""

import jax.numpy as jnp

from jaxadapt._checks import check_value
from jaxadapt.background import LUMINANCE_FLOOR, log_average
from jaxadapt.spatial import foveal_weights, plane_sum

__all__ = [
    "GOALS",
    "LUMINANCE_FLOOR",
    "foveal_average",
    "foveal_log_average",
    "log_average",
    "white_fraction",
]


def white_fraction(L, fraction=0.2, percentile=99.0, floor=LUMINANCE_FLOOR):
    """A fraction of the reference-white luminance (Hunt; Pattanaik 2000, §4.1.2).

    The paper sets the goal to one fifth of the luminance of the white patch
    of a Macbeth chart. Without a chart to point at, we take the scene's
    white to be the ``percentile``-th percentile of luminance (the 99th by
    default: robust to a few specular or hot pixels, and inside a white
    patch that covers more than 1 % of the frame).

    Parameters
    ----------
    L : array, shape (..., H, W)
        Luminance, cd/m2.
    fraction : float
        Goal as a fraction of white (1/5 after Hunt).
    percentile : float
        Percentile of luminance taken as white, in [0, 100].
    floor : float
        Smallest goal returned, cd/m2.

    Returns
    -------
    array, shape (...)
        Goal, cd/m2.
    """
    check_value("percentile", percentile, lambda v: (v >= 0) & (v <= 100), "a value in [0, 100]")
    flat = L.reshape(L.shape[:-2] + (-1,))
    white = jnp.percentile(flat, percentile, axis=-1)
    return jnp.maximum(fraction * white, floor)


def foveal_log_average(L, gaze, pixels_per_degree, floor=LUMINANCE_FLOOR):
    """Log average luminance weighted over a 1-degree fovea around ``gaze``.

    The foveal weighting of Ward-Larson et al. (1997), which Pattanaik et al.
    (2000) aimed at the road in the tunnel sequence: ``exp(sum w ln L)`` with
    the weights of :func:`jaxadapt.spatial.foveal_weights`.

    Parameters
    ----------
    L : array, shape (H, W)
        Luminance, cd/m2.
    gaze : array, shape (2,)
        Gaze point ``(x, y)``, pixels.
    pixels_per_degree : float
        Pixels per degree of visual angle.
    floor : float
        Luminance floor before the logarithm, cd/m2.

    Returns
    -------
    array, shape ()
        Goal, cd/m2.
    """
    w = foveal_weights(L.shape[-2:], gaze, pixels_per_degree, dtype=L.dtype)
    return jnp.exp(plane_sum(w * jnp.log(jnp.maximum(L, floor))))


def foveal_average(L, gaze, pixels_per_degree):
    """Average luminance (cd/m2) weighted over a 1-degree fovea around ``gaze``:
    ``sum w L`` with the weights of :func:`jaxadapt.spatial.foveal_weights`
    (the arithmetic counterpart of :func:`foveal_log_average`, in which a
    small bright source counts for its light, not its log)."""
    w = foveal_weights(L.shape[-2:], gaze, pixels_per_degree, dtype=L.dtype)
    return plane_sum(w * L)


#: Names accepted by the operators' ``goal`` option.
GOALS = ("log_average", "white_fraction", "foveal")
