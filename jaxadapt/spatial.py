"""Spatial weights and filters on images ``(..., H, W)``."""

import jax.numpy as jnp

#: Full width at half maximum of the foveal weighting, degrees of visual angle.
FOVEA_DEG = 1.0


def foveal_weights(shape, gaze, pixels_per_degree, fwhm_deg=FOVEA_DEG):
    """Normalised Gaussian weights of a foveal patch around a gaze point.

    The 1-degree foveal weighting of Ward-Larson, Rushmeier and Piatko (1997)
    averages over a one-degree patch; we use a Gaussian whose full width at
    half maximum is ``fwhm_deg`` degrees, which is smooth in the gaze point
    (differentiable, no empty patch when the gaze sits between pixels).

    Parameters
    ----------
    shape : (int, int)
        Image height and width, pixels.
    gaze : array, shape (2,)
        Gaze point ``(x, y)`` in pixels (column, row), origin at the centre of
        the top-left pixel.
    pixels_per_degree : float
        Display resolution at the viewer's eye, pixels per degree.
    fwhm_deg : float
        Full width at half maximum of the patch, degrees.

    Returns
    -------
    array, shape (H, W)
        Weights summing to one.
    """
    H, W = shape
    sigma = fwhm_deg * pixels_per_degree / (2.0 * jnp.sqrt(2.0 * jnp.log(2.0)))
    y = jnp.arange(H, dtype=jnp.result_type(float))[:, None]
    x = jnp.arange(W, dtype=jnp.result_type(float))[None, :]
    d2 = (x - gaze[0]) ** 2 + (y - gaze[1]) ** 2
    logw = -0.5 * d2 / sigma**2
    w = jnp.exp(logw - jnp.max(logw))
    return w / jnp.sum(w)
