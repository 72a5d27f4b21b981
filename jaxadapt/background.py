"""Background (adapting) luminance: estimators that map a luminance image
``(..., H, W)`` in cd/m2 to a background per pixel, shape ``(..., H, W)``,
in cd/m2: the ``I_b`` of the tone curves, estimated globally or locally in
the ways §6.4 of the HDR-imaging chapter (Reinhard et al.) compares.

:data:`BACKGROUNDS` names them; :func:`estimate_background` is how the
operators call one. Each is jitted (``equinox.filter_jit``): its
Python-number options, the sizes in pixels among them, are static.
:func:`log_average` and :data:`LUMINANCE_FLOOR` are here because the global
background is the log average, which is also the default adaptation goal
(:mod:`jaxadapt.operators.goal`).
"""

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from jaxadapt._checks import check_value, check_whole
from jaxadapt.spatial import (
    as_image,
    bilateral_filter,
    box_filter,
    gaussian_blur,
    lowpass_stack,
    plane_sum,
    sum_headroom,
)

__all__ = [
    "LUMINANCE_FLOOR",
    "LUMINANCE_CEILING",
    "log_average",
    "check_scale",
    "box_radius",
    "arithmetic_average",
    "global_background",
    "arithmetic_background",
    "box_background",
    "gaussian_background",
    "BILATERAL_KINDS",
    "bilateral_background",
    "octave_radii",
    "adaptive_background",
    "multiscale_background",
    "BACKGROUNDS",
    "BOX_SIZED",
    "check_background",
    "estimate_background",
]

#: Floor applied before taking logarithms, cd/m2: the bottom of the range of
#: human vision (1e-6 cd/m2, Pattanaik et al. 2000, §1). Black pixels and
#: all-black frames count as this luminance, so their goal is finite.
LUMINANCE_FLOOR = 1e-6

#: Ceiling of the luminance the operators see, cd/m2: a hundred times the top
#: of the range of vision the models are built for (1e8 cd/m2, Pattanaik et
#: al. 2000, §1), six times the sun's disc (1.6e9 cd/m2). A channel brighter
#: than it counts as this level
#: (:func:`jaxadapt.operators.checks.saturate`): the models have saturated
#: long before (the cone pigment is 99.98 % bleached, Eq 6), and below it
#: every product and sum of the operators stays far inside float32's range,
#: whatever order XLA evaluates them in.
LUMINANCE_CEILING = 1e10


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
    H, W = L.shape[-2:]
    return jnp.exp(plane_sum(jnp.log(jnp.maximum(L, floor))) / (H * W))


def check_scale(scale, least=0.0, name="scale"):
    """Refuse a size ``scale`` (pixels) that is not a finite number above
    0, or ``least`` (the boxes: at least 1 pixel)."""
    number = isinstance(scale, (int, float, np.integer, np.floating)) and not isinstance(
        scale, bool
    )
    if not (number and np.isfinite(scale) and scale > 0 and scale >= least):
        expected = f"a size of at least {least:g} pixel" if least else "a positive size in pixels"
        raise ValueError(f"{name}: expected {expected}, got {scale!r}")


def box_radius(scale):
    """Half-width of the chapter's box ``||p - i|| < s`` (§6.4.2) made
    square: ``ceil(s) - 1`` pixels, the largest whole offset below ``s``, so
    that ``s = 1`` is the pixel itself and ``s >= 1``.

    Examples
    --------
    >>> box_radius(1), box_radius(8.0), box_radius(4.2)
    (0, 7, 4)
    """
    check_scale(scale, least=1)
    return math.ceil(scale) - 1


def arithmetic_average(L):
    """Arithmetic mean luminance ``sum(I) / n`` over ``(H, W)`` (§6.4.1).

    Parameters
    ----------
    L : array, shape (..., H, W)
        Luminance, cd/m2.

    Returns
    -------
    array, shape (...)
        Mean, cd/m2.

    Notes
    -----
    A float32 sum of luminances near float32's largest value (3.4e38)
    overflows although their mean does not; there the mean is taken of
    the image scaled down by a power of two at least its pixel count
    (:func:`jaxadapt.spatial.sum_headroom`, as the box and bilateral sums
    take theirs), then scaled back. A division by
    the largest value would not do: XLA's CPU backend divides by
    multiplying with the reciprocal, a denormal that it flushes to 0
    above 8.5e37. Elsewhere it is the plain mean, bit for bit.

    Examples
    --------
    >>> float(arithmetic_average(jnp.array([[1.0, 100.0]])))
    50.5
    """
    mean = jnp.mean(L, axis=(-2, -1))
    down, up = sum_headroom(L.shape[-2] * L.shape[-1], mean.dtype)
    scaled = jnp.mean(L * down, axis=(-2, -1)) * up
    return jnp.where(jnp.isfinite(mean), mean, scaled)


@eqx.filter_jit
def global_background(L, floor=LUMINANCE_FLOOR):
    """The geometric (log) average of §6.4.1 as every pixel's background.

    The chapter's ``exp(mean(log(I + eps)))``; we floor instead of adding
    ``eps`` (:func:`log_average`): zero and negative luminances count as
    ``floor``, and pixels above it are not shifted.

    Parameters
    ----------
    L : array, shape (..., H, W)
        Luminance, cd/m2.
    floor : float
        Luminance floor before the logarithm, cd/m2.

    Returns
    -------
    array, shape (..., H, W)
        Background, cd/m2, constant over each image.

    Examples
    --------
    >>> global_background(jnp.array([[1.0, 100.0]])).tolist()  # doctest: +ELLIPSIS
    [[10.0..., 10.0...]]
    """
    L = as_image(L, "L")
    return jnp.broadcast_to(log_average(L, floor)[..., None, None], L.shape)


@eqx.filter_jit
def arithmetic_background(L):
    """The arithmetic average of §6.4.1 as every pixel's background.

    Parameters
    ----------
    L : array, shape (..., H, W)
        Luminance, cd/m2.

    Returns
    -------
    array, shape (..., H, W)
        Background, cd/m2, constant over each image.
    """
    L = as_image(L, "L")
    return jnp.broadcast_to(arithmetic_average(L)[..., None, None], L.shape)


@eqx.filter_jit
def box_background(L, scale=8.0):
    """Local box average, Eq 6.4 with box weights.

    Parameters
    ----------
    L : array, shape (..., H, W)
        Luminance, cd/m2.
    scale : float
        Size ``s``, pixels (static), ``>= 1``: the chapter's disc ``||p - i||
        < s`` made square, so that it is separable, of half-width
        :func:`box_radius` ``ceil(s) - 1`` (as each level of
        :func:`octave_radii`; see :func:`jaxadapt.spatial.box_filter`).

    Returns
    -------
    array, shape (..., H, W)
        Background, cd/m2.
    """
    return box_filter(as_image(L, "L"), box_radius(scale))


@eqx.filter_jit
def gaussian_background(L, scale=8.0):
    """Local Gaussian average, Eq 6.4 with ``w = exp(-||p - i||^2 / s^2)``.

    Parameters
    ----------
    L : array, shape (..., H, W)
        Luminance, cd/m2.
    scale : float
        Size ``s``, pixels (static): a Gaussian of standard deviation
        ``s / sqrt(2)`` (:func:`jaxadapt.spatial.gaussian_blur`).

    Returns
    -------
    array, shape (..., H, W)
        Background, cd/m2.
    """
    L = as_image(L, "L")
    check_scale(scale)
    return gaussian_blur(L, scale / np.sqrt(2.0))


#: The two bilateral backgrounds of §6.4.2: spatial weight, intensity weight
#: and default width of the intensity weight (log10 units).
BILATERAL_KINDS = {
    "durand-dorsey": ("gaussian", "gaussian", 0.4),
    "pattanaik-yee": ("disc", "exponential", 0.2),
}


@eqx.filter_jit
def bilateral_background(L, scale=4.0, sigma_r=None, kind="durand-dorsey", floor=LUMINANCE_FLOOR):
    """Bilateral local average, Eq 6.5, with intensity weights on log luminance.

    ``I_b = sum w g I / sum w g``, where ``g`` depends on the difference of
    ``log10 max(I, floor)`` between the two pixels: pixels across an HDR
    edge, orders of magnitude apart, get (almost) no weight.

    Parameters
    ----------
    L : array, shape (..., H, W)
        Luminance, cd/m2.
    scale : float
        Size ``s`` of the spatial weight, pixels (static).
    sigma_r : float, optional
        Width of the intensity weight, log10 units, ``> 0``; by default that
        of ``kind``.
    kind : str
        ``"durand-dorsey"``: Gaussian ``w = exp(-d^2 / s^2)`` (on a disc of
        radius ``ceil(sqrt(2) s)``) and Gaussian ``g`` of width 0.4 log10
        units, Durand and Dorsey's value. ``"pattanaik-yee"``: a circular
        box ``w`` of radius ``s`` and an exponential ``g = exp(-|dlog10 I| /
        sigma_r)``.
    floor : float
        Luminance floor before the logarithm, cd/m2.

    Returns
    -------
    array, shape (..., H, W)
        Background, cd/m2.

    Notes
    -----
    Eq 6.5 averages the luminance itself, so a pixel ``D`` log units
    brighter contributes in proportion to ``10^D g(D)``. The exponential
    weight must decay faster than ``10^D`` for the average not to cross an
    HDR edge, which needs ``sigma_r < 1 / ln(10) = 0.43``; we default to
    0.2 for Pattanaik and Yee's weight (a pixel ``D`` log units brighter
    then counts ``10^(-1.17 D)`` as much as a neighbour of equal luminance).
    The Gaussian weight decays faster than any exponential, so Durand and
    Dorsey's 0.4 is safe.
    """
    L = as_image(L, "L")
    if kind not in BILATERAL_KINDS:
        raise ValueError(f"kind: expected one of {tuple(BILATERAL_KINDS)}, got {kind!r}")
    spatial, range_kernel, default_sigma_r = BILATERAL_KINDS[kind]
    sigma_r = default_sigma_r if sigma_r is None else sigma_r
    guide = jnp.log10(jnp.maximum(L, floor))
    return bilateral_filter(L, scale, sigma_r, spatial, range_kernel, guide)


def octave_radii(scale, levels):
    """Box half-widths of a stack whose size parameter doubles: ``ceil(s 2^i) - 1``.

    Each level is the box of size ``s 2^i`` (:func:`box_radius`): ``s = 1``
    is the pixel itself.

    Parameters
    ----------
    scale : float
        Size ``s`` of the finest level, pixels, ``>= 1``.
    levels : int
        Number of levels, ``>= 2``.

    Returns
    -------
    tuple of int

    Examples
    --------
    >>> octave_radii(1, 5)
    (0, 1, 3, 7, 15)
    """
    check_scale(scale, least=1)
    check_whole("levels", levels, least=2)
    return tuple(box_radius(scale * 2.0**i) for i in range(levels))


@eqx.filter_jit
def adaptive_background(L, scale=1.0, levels=8, tolerance=0.05, floor=LUMINANCE_FLOOR):
    """Local average over a variable-size neighbourhood (§6.4.2, Reinhard et al.; Ashikhmin).

    Starting from ``s = scale``, double the size of the neighbourhood until
    the local average moves, relative to the previous one, by more than
    ``tolerance``: the larger neighbourhood has reached across an edge, so
    the previous average is the background. Pixels whose average never
    moves that much take the largest level.

    Parameters
    ----------
    L : array, shape (..., H, W)
        Luminance, cd/m2.
    scale : float
        Size ``s`` of the first neighbourhood, pixels (static); ``1`` is the
        pixel itself.
    levels : int
        Number of sizes tried, ``s 2^i`` for ``i < levels`` (static).
    tolerance : float
        Largest relative change ``|V_{i+1} - V_i| / V_i`` of an unbiased
        average, ``> 0``; 0.05 is Reinhard et al.'s ``epsilon``. Darker
        pixels flag a bright neighbour at once (it multiplies their
        average), but brighter ones see a dark neighbour only as a fall of
        at most 100 % spread over several doublings, so a loose tolerance
        (0.2) lets the bright side of an edge drift down to the mean.
    floor : float
        Luminance floor of the denominator, cd/m2.

    Returns
    -------
    array, shape (..., H, W)
        Background, cd/m2.

    Notes
    -----
    The averages are Eq 6.4 with the smooth weights of
    :func:`jaxadapt.spatial.iterated_box_filter` (three boxes of half-width
    ``r_i`` from :func:`octave_radii`, standard deviation ``sqrt(r_i (r_i +
    1))``), whose cost does not grow with the size. Reinhard et al. (2002)
    compare Gaussians 1.6 times apart and relax the test at small scales
    with a sharpening term; we keep the chapter's description: doubling
    sizes and a relative tolerance (a Weber-like criterion, since the
    visual system is log-linear).
    """
    L = as_image(L, "L")
    check_value("tolerance", tolerance, lambda v: v > 0, "a positive relative change")
    stack = jnp.maximum(lowpass_stack(L, octave_radii(scale, levels)), floor)
    change = jnp.abs(stack[..., 1:, :, :] - stack[..., :-1, :, :]) / stack[..., :-1, :, :]
    biased = change > tolerance
    stop = jnp.where(jnp.any(biased, axis=-3), jnp.argmax(biased, axis=-3), levels - 1)
    return jnp.take_along_axis(stack, stop[..., None, :, :], axis=-3)[..., 0, :, :]


@eqx.filter_jit
def multiscale_background(L, scale=1.0, levels=8, floor=LUMINANCE_FLOOR):
    """Background combining a multiscale stack of low-pass images (§6.4.3).

    The geometric mean over the levels of the stack of
    :func:`adaptive_background` (sizes ``s 2^i``): each band-pass mechanism
    adapts to the average at its own scale, and the background is their
    equal-weight average in log luminance, as in the multiscale retinex
    (Jobson, Rahman and Woodell 1997).

    Parameters
    ----------
    L : array, shape (..., H, W)
        Luminance, cd/m2.
    scale : float
        Size ``s`` of the finest level, pixels (static).
    levels : int
        Number of levels (static).
    floor : float
        Luminance floor before the logarithm, cd/m2.

    Returns
    -------
    array, shape (..., H, W)
        Background, cd/m2.
    """
    L = as_image(L, "L")
    stack = lowpass_stack(L, octave_radii(scale, levels))
    return jnp.exp(jnp.mean(jnp.log(jnp.maximum(stack, floor)), axis=-3))


#: Background estimators by name, each ``f(L, **size_options) -> (..., H, W)``.
#: ``GOALS`` keeps naming the global goals of the Pattanaik operator.
BACKGROUNDS = {
    "global": global_background,
    "arithmetic": arithmetic_background,
    "box": box_background,
    "gaussian": gaussian_background,
    "bilateral": bilateral_background,
    "adaptive": adaptive_background,
    "multiscale": multiscale_background,
}


#: The local estimators whose size is a box's (:func:`box_radius`): at least 1 pixel.
BOX_SIZED = ("box", "adaptive", "multiscale")


def check_background(name, scale, names=("background", "background_scale")):
    """Refuse an estimator ``name`` not in :data:`BACKGROUNDS`, or a size
    ``scale`` it cannot take (:func:`check_scale`); ``names`` name the two
    in the message (fields of a ``Params``, or options of the command line)."""
    if name not in BACKGROUNDS:
        raise ValueError(f"{names[0]}: expected one of {tuple(BACKGROUNDS)}, got {name!r}")
    check_scale(scale, least=1 if name in BOX_SIZED else 0, name=names[1])


def estimate_background(L, name, scale):
    """The background ``BACKGROUNDS[name]`` of ``L (..., H, W)``, cd/m2, as a map.

    ``scale`` (pixels) is passed to the local estimators; the global ones
    (``"global"``, ``"arithmetic"``) have no size and are broadcast to the
    image's shape. Every estimate is floored at :data:`LUMINANCE_FLOOR`, as
    the log averages are: a blur of a black region is 0, and its background
    is then, like a black pixel's luminance, the bottom of the range of
    vision.
    """
    estimator = BACKGROUNDS[name]
    I_b = estimator(L) if name in ("global", "arithmetic") else estimator(L, scale=scale)
    return jnp.broadcast_to(jnp.maximum(I_b, LUMINANCE_FLOOR), L.shape)
