"""Mesopic loss of acuity (Eqs 13-15, Appendix A, §2.3.3).

The normalised local log luminance ``rho`` of Eq 13, the Gaussian bands
``sigma_i`` of Appendix A, the noise ``X`` and thresholds of Eq 15, and
:func:`acuity_loss`, Eq 14's sum of bands, computed as the finest blur a
pixel still resolves.

The choices where the paper is silent (the "module notes" cited below) are
listed in the package's docstring, :mod:`jaxadapt.operators.jacobs2015`.
"""

import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt.background import LUMINANCE_FLOOR
from jaxadapt.color import combine
from jaxadapt.operators.jacobs2015._planes import planes
from jaxadapt.spatial import gaussian_ladder

# -- mesopic vision (Eqs 13-15) -----------------------------------------------


def acuity_sigmas(params):
    """Standard deviations ``sigma_i = sigma_0 2^(i/4)``, pixels (Appendix A)."""
    return [params.acuity_sigma0 * 2.0 ** (i / 4.0) for i in range(params.acuity_bands)]


def normalised_log_luminance(params, L):
    """``rho = (log10 L - m2) / (m1 - m2)`` (Eq 13), unclamped; ``L`` in cd/m2."""
    return (jnp.log10(jnp.maximum(L, LUMINANCE_FLOOR)) - params.m2) / (params.m1 - params.m2)


def local_rho(params, frame):
    """rho (Eq 13) of the local photopic luminance: the frame's luminance
    blurred at the coarsest acuity scale (:func:`jaxadapt.spatial.gaussian_ladder`).
    ``frame (H, W, 3)`` -> ``(H, W)``."""
    L = combine(params.w_P, planes(frame))
    (local,) = gaussian_ladder(L, acuity_sigmas(params)[-1:])
    return normalised_log_luminance(params, local())


def _interpolation_matrix(n, cell):
    """Linear interpolation from a grid every ``cell`` pixels (any positive
    size) to ``n`` pixels, with each row scaled so that interpolated
    unit-variance white noise keeps unit variance: ``(n, floor(n / cell) +
    2)``, NumPy (static)."""
    pos = np.arange(n) / cell
    i, f = np.floor(pos).astype(int), pos - np.floor(pos)
    A = np.zeros((n, int(n // cell) + 2))
    A[np.arange(n), i] = 1.0 - f
    A[np.arange(n), i + 1] = f
    return A / np.sqrt((A**2).sum(axis=1, keepdims=True))


def acuity_noise(params, key, t, shape):
    """Noise ``X ~ N(0, 1)`` of Eq 15, smooth in space and time, ``(H, W)``.

    Independent normal samples on a grid every ``acuity_noise_cell`` pixels
    and ``acuity_noise_period`` seconds (the grid step ``j`` is folded into
    ``key``) are interpolated linearly in space and time, and rescaled so
    that every pixel's ``X`` is exactly standard normal: the loss of detail
    comes and goes in patches rather than per pixel (§2.3.3).
    """
    H, W = shape
    Ay = jnp.asarray(_interpolation_matrix(H, params.acuity_noise_cell), dtype=t.dtype)
    Ax = jnp.asarray(_interpolation_matrix(W, params.acuity_noise_cell), dtype=t.dtype)
    position = t / params.acuity_noise_period
    j = jnp.floor(position)
    f = position - j

    def grid(step):
        return jax.random.normal(
            jax.random.fold_in(key, step), (Ay.shape[1], Ax.shape[1]), dtype=t.dtype
        )

    before, after = jax.vmap(grid)(j.astype(jnp.int32) + jnp.arange(2))
    coarse = ((1.0 - f) * before + f * after) / jnp.sqrt((1.0 - f) ** 2 + f**2)
    # The two products in the order with fewer multiplications (static):
    # for a 1920x1080 frame, columns first, 1.6 ms against 2.7 (2 cores).
    rows, columns = coarse.shape
    if H * columns * (rows + W) <= W * rows * (columns + H):
        return (Ay @ coarse) @ Ax.T
    return Ay @ (coarse @ Ax.T)


def acuity_thresholds(params):
    """Normalised threshold of each band, finest first: ``rho_(K-1-f) / (m1 - m2)``.

    The finest band needs the most light (module notes); ``rho_i =
    rho_step i`` is in log10 units, hence the division by ``m1 - m2``.
    """
    K = params.acuity_bands
    return params.rho_step * jnp.arange(K - 1, -1, -1) / (params.m1 - params.m2)


def acuity_loss(params, frame, rho, X):
    """Stochastic loss of acuity (Eqs 14-15), finest detail first.

    Eq 14 keeps the difference-of-Gaussian band ``f`` (0 = finest,
    ``blur_(f-1) - blur_f`` with ``blur_(-1)`` the frame) where
    ``rho + g X > threshold_f`` (:func:`acuity_thresholds`) and adds the
    low-pass ``blur_(K-1)``. The thresholds fall with coarseness
    (``rho_step >= 0``), so a pixel drops its ``d`` finest bands, and what it
    keeps telescopes to ``blur_(d-1)``: the frame blurred at the finest
    scale it still resolves. We select that blur per pixel, which gives
    Eq 14's sum without forming the ``K`` band images, and compute a blur
    only where some pixel of the frame keeps it (a conditional on the
    frame's set of ``d``): in photopic light none. Blurs of a non-negative
    frame are non-negative, so nothing undershoots.

    Parameters
    ----------
    frame : array, (H, W, 3)
        Linear RGB, cd/m2.
    rho : array, (H, W)
        Local normalised log luminance (Eq 13, unclamped).
    X : array, (H, W)
        Standard normal noise (:func:`acuity_noise`).

    Returns
    -------
    array, (H, W, 3)
        The frame as resolved, cd/m2.
    """
    return resolve(params, frame, *dropped_bands(params, rho, X))


def dropped_bands(params, rho, X):
    """How many of its finest bands each pixel drops (Eq 15), ``(H, W)``
    int, and the set of those counts in the frame: bit ``d`` of the
    ``uint32`` is set where some pixel drops ``d`` (one reduction for all
    bands; counts past 31 set bit 31)."""
    visible = rho + params.g * X
    dropped = jnp.sum(visible[None] <= acuity_thresholds(params)[:, None, None], axis=0)
    bits = jnp.left_shift(jnp.uint32(1), jnp.minimum(dropped, 31).astype(jnp.uint32))
    present = jax.lax.reduce(bits, jnp.uint32(0), jax.lax.bitwise_or, tuple(range(bits.ndim)))
    return dropped, present


def resolve(params, frame, dropped, present):
    """The frame blurred per pixel at the finest scale it resolves
    (:func:`acuity_loss`), from :func:`dropped_bands`: the blurs of
    :func:`jaxadapt.spatial.gaussian_ladder`, each computed only where some
    pixel keeps it."""
    needed = [(present >> min(f + 1, 31)) & 1 == 1 for f in range(params.acuity_bands)]
    blurs = gaussian_ladder(frame, acuity_sigmas(params), needed)
    seen = frame
    for f, blurred in enumerate(blurs):
        keeps = dropped == f + 1  # the pixels that resolve blur f and no finer

        def select(seen, keeps=keeps, blurred=blurred):
            return jnp.where(keeps[..., None], blurred(), seen)

        seen = jax.lax.cond(needed[f], select, lambda seen: seen, seen)
    return seen
