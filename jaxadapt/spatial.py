"""Spatial weights and filters on images ``(..., H, W)``."""

import jax
import jax.numpy as jnp
import numpy as np

#: Full width at half maximum of the foveal weighting, degrees of visual angle.
FOVEA_DEG = 1.0


def foveal_weights(shape, gaze, pixels_per_degree, fwhm_deg=FOVEA_DEG, dtype=float):
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
    dtype : dtype
        Floating-point type of the weights.

    Returns
    -------
    array, shape (H, W)
        Weights summing to one.
    """
    H, W = shape
    sigma = fwhm_deg * pixels_per_degree / (2.0 * jnp.sqrt(2.0 * jnp.log(2.0)))
    y = jnp.arange(H, dtype=dtype)[:, None]
    x = jnp.arange(W, dtype=dtype)[None, :]
    d2 = (x - gaze[0]) ** 2 + (y - gaze[1]) ** 2
    logw = -0.5 * d2 / sigma**2
    w = jnp.exp(logw - jnp.max(logw))
    return (w / jnp.sum(w)).astype(dtype)


def gaussian_kernel(sigma, truncate=4.0):
    """Normalised 1-D Gaussian taps ``exp(-x^2 / 2 sigma^2)``, ``|x| <= truncate sigma``.

    Parameters
    ----------
    sigma : float
        Standard deviation, pixels, ``> 0``. A Python number: it sets the
        kernel's length, so it is static under ``jit``.
    truncate : float
        Half-width of the kernel in standard deviations.

    Returns
    -------
    numpy array, shape (2 r + 1,)
        Taps summing to one, ``r = ceil(truncate sigma)``.
    """
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma: expected a positive width in pixels, got {sigma!r}")
    r = int(np.ceil(truncate * sigma))
    x = np.arange(-r, r + 1, dtype=np.float64)
    taps = np.exp(-0.5 * (x / sigma) ** 2)
    return taps / taps.sum()


def separable_filter(image, taps):
    """Convolve the last two axes of ``image (..., H, W)`` with ``taps`` along each.

    The edges are extended by mirror reflection about the edge pixels
    (``jnp.pad`` mode ``"reflect"``, repeated for kernels longer than the
    image), so that a constant image stays constant.
    """
    taps = jnp.asarray(taps, dtype=image.dtype)
    r = (taps.shape[0] - 1) // 2
    lead, (H, W) = image.shape[:-2], image.shape[-2:]
    flat = image.reshape((-1, 1, H, W))
    padded = jnp.pad(flat, ((0, 0), (0, 0), (r, r), (r, r)), mode="reflect")
    dims = ("NCHW", "OIHW", "NCHW")
    rows = jax.lax.conv_general_dilated(
        padded, taps[None, None, :, None], (1, 1), "VALID", dimension_numbers=dims
    )
    both = jax.lax.conv_general_dilated(
        rows, taps[None, None, None, :], (1, 1), "VALID", dimension_numbers=dims
    )
    return both.reshape(lead + (H, W))


def gaussian_blur(image, sigma, truncate=4.0):
    """Gaussian blur of the last two axes of ``image (..., H, W)``.

    Parameters
    ----------
    image : array, shape (..., H, W)
        Any quantity per pixel; leading axes are batch axes.
    sigma : float
        Standard deviation, pixels (static).
    truncate : float
        Kernel half-width in standard deviations.

    Returns
    -------
    array, shape (..., H, W)

    Examples
    --------
    >>> img = jnp.zeros((9, 9)).at[4, 4].set(1.0)
    >>> round(float(gaussian_blur(img, 1.0).sum()), 6)
    1.0
    """
    return separable_filter(image, gaussian_kernel(sigma, truncate))
