"""Adaptation-goal finders: the luminance an observer would adapt to.

Each maps a luminance image ``(..., H, W)`` in cd/m2 to a goal ``(...)`` in
cd/m2 (Pattanaik et al. 2000, §4.1.2, the "Adaptation Goal Finder" of
Fig. 4).
"""

import jax.numpy as jnp

from jaxadapt.spatial import foveal_weights

#: Floor applied before taking logarithms, cd/m2: the bottom of the range of
#: human vision (1e-6 cd/m2, Pattanaik et al. 2000, §1). Black pixels and
#: all-black frames count as this luminance, so their goal is finite.
LUMINANCE_FLOOR = 1e-6


def log_average(L, floor=LUMINANCE_FLOOR):
    """Geometric mean luminance ``exp(mean(ln max(L, floor)))`` over ``(H, W)``.

    Parameters
    ----------
    L : array, shape (..., H, W)
        Luminance, cd/m2.
    floor : float
        Luminance below which pixels count as ``floor``, cd/m2.

    Returns
    -------
    array, shape (...)
        Goal, cd/m2.

    Examples
    --------
    >>> float(log_average(jnp.array([[1.0, 100.0]])))  # doctest: +ELLIPSIS
    10.0...
    """
    return jnp.exp(jnp.mean(jnp.log(jnp.maximum(L, floor)), axis=(-2, -1)))


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
    return jnp.exp(jnp.sum(w * jnp.log(jnp.maximum(L, floor)), axis=(-2, -1)))


#: Names accepted by the operators' ``goal`` option.
GOALS = ("log_average", "white_fraction", "foveal")
