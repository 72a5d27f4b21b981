"""Spatial weights and filters on images ``(..., H, W)``."""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt._checks import check_value, check_whole
from jaxadapt.fused import stored

__all__ = [
    "FOVEA_DEG",
    "plane_sum",
    "foveal_weights",
    "gaussian_kernel",
    "discrete_gaussian_kernel",
    "separable_filter",
    "channels_last_filter",
    "LONG_KERNEL",
    "gaussian_blur",
    "DECIMATE_AT",
    "EXPAND_SIGMA",
    "ladder_levels",
    "gaussian_ladder",
    "as_image",
    "sum_headroom",
    "box_filter",
    "iterated_box_filter",
    "lowpass_stack",
    "RANGE_KERNELS",
    "gaussian_window",
    "disc_window",
    "SPATIAL_WINDOWS",
    "bilateral_filter",
]

#: Full width at half maximum of the foveal weighting, degrees of visual angle.
FOVEA_DEG = 1.0


def plane_sum(x):
    """Sum of ``x (..., H, W)`` over its last two axes, shape ``(...)``.

    On the CPU, as two products with vectors of ones: XLA's CPU backend
    hands a plain sum to YNNPACK, which is several times slower when the
    summed values are computed from slices of an array, as a luminance is
    from the channels of an RGB frame. On other platforms, a plain sum,
    which a GPU fuses with the computation of its input and with sibling
    sums of the same frames into one read.
    """

    def products(x):
        return (x @ jnp.ones(x.shape[-1], x.dtype)) @ jnp.ones(x.shape[-2], x.dtype)

    return jax.lax.platform_dependent(x, cpu=products, default=lambda x: jnp.sum(x, axis=(-2, -1)))


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
    # exp(-d2 / 2 sigma^2) over its largest value, from each pixel's squared
    # distance beyond the nearest one's: 0 there exactly, so that the weight
    # there is 1 however narrow the patch (sigma^2 kept from underflowing to
    # 0). Written as the difference of the two exponents, it can be inf - inf
    # once compiled, at tiny pixels per degree.
    excess = d2 - jnp.min(d2)
    w = jnp.exp(-0.5 * excess / jnp.maximum(sigma**2, jnp.finfo(dtype).tiny))
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
    _check_sigma(sigma)
    if not (np.isfinite(truncate) and truncate >= 0):
        raise ValueError(f"truncate: expected a finite number >= 0 of widths, got {truncate!r}")
    r = int(np.ceil(truncate * sigma))
    x = np.arange(-r, r + 1, dtype=np.float64)
    taps = np.exp(-0.5 * (x / sigma) ** 2)
    return taps / taps.sum()


def _check_sigma(sigma):
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma: expected a positive width in pixels, got {sigma!r}")


def discrete_gaussian_kernel(sigma):
    """Lindeberg's discrete Gaussian: taps ``T(x) = exp(-t) I_x(t)``, ``t =
    sigma^2`` (``I_x`` the modified Bessel function), out to the smallest
    ``|x|`` beyond which the taps left out weigh less than 1e-4 (as a
    sampled Gaussian cut at 4 sigma leaves out 6e-5; the discrete one's
    tails are heavier when ``sigma`` is small), normalised.

    Its variance is ``sigma^2`` at any ``sigma`` (up to the truncation),
    and repeated blurs compose as the continuous ones do:
    ``n`` blurs of ``sigma`` are one of ``sigma sqrt(n)``. A sampled
    Gaussian (:func:`gaussian_kernel`) has neither property below about one
    pixel: at ``sigma = 0.4`` its variance is half of ``sigma^2``, at 0.2
    nearly nothing.

    Parameters
    ----------
    sigma : float
        Standard deviation, pixels, ``> 0`` (static, as for :func:`gaussian_kernel`).

    Returns
    -------
    numpy array, shape (2 r + 1,)
        Taps summing to one.

    Examples
    --------
    >>> taps = discrete_gaussian_kernel(0.4)
    >>> x = np.arange(taps.size) - taps.size // 2
    >>> round(float(np.sum(taps * x**2)), 3)  # the variance, pixels^2
    0.16
    """
    from scipy.special import ive

    _check_sigma(sigma)
    r = 1
    while (taps := ive(np.arange(-r, r + 1), sigma**2)).sum() < 1.0 - 1e-4:
        r += 1
    return taps / taps.sum()


def separable_filter(image, taps):
    """Convolve the last two axes of ``image (..., H, W)`` with ``taps`` along each.

    The edges are extended by mirror reflection about the edge pixels
    (``jnp.pad`` mode ``"reflect"``, repeated for kernels longer than the
    image), so that a constant image stays constant. Each pass is a weighted
    sum of shifted slices, which XLA fuses into one loop: on the CPU it is
    tens of times faster than a convolution op for these one-channel images.

    XLA's CPU and GPU backends want the two passes written differently
    (``jax.lax.platform_dependent`` picks): on the CPU each axis is padded
    just before its own pass, because padding both at once lets XLA fuse
    the passes into one slower loop of ``(2r + 1)^2`` products a pixel; on
    a GPU that fused loop is the fast form.

    Kernels of more than :data:`LONG_KERNEL` taps go through matrix
    products on every platform (:func:`_filter_by_products`), because XLA
    compiles one slice a tap and wide kernels take minutes to compile.
    """
    return _separable_filter(as_image(image), tuple(float(w) for w in np.asarray(taps)))


#: Taps above which :func:`separable_filter` filters by matrix products
#: (:func:`_filter_by_products`), where XLA's fusion of one slice a tap
#: stops being efficient. The products win on the CPU from somewhat fewer
#: taps, but the GPU's form has not been compared with them, so the
#: threshold stays where the slices fail.
LONG_KERNEL = 225


@functools.partial(jax.jit, static_argnames="taps")
def _separable_filter(image, taps):
    """:func:`separable_filter` compiled as one function per image shape and
    ``taps`` (a tuple, static): called eagerly, each tap's slice and product
    would otherwise be dispatched, and compiled, one op at a time."""
    taps = np.asarray(taps)
    if taps.shape[0] > LONG_KERNEL:
        return _filter_by_products(image, taps).astype(image.dtype)
    out = jax.lax.platform_dependent(
        image,
        cpu=lambda image: _filter_per_axis(image, taps),
        default=lambda image: _filter_both_axes(image, taps),
    )
    return out.astype(image.dtype)


def channels_last_filter(image, taps, when=None):
    """:func:`separable_filter` of the first two axes of ``image (H, W, ...)``:
    the same mirror-extended edges and taps along each axis, with the
    channels (any trailing axes) left where a frame keeps them.

    Each pass reads the mirror extension only at the ends
    (:func:`_mirrored_pass`: no padded copy). The first pass is
    :func:`jaxadapt.fused.stored` on the CPU: fused into the second, XLA's
    CPU backend evaluates it once per tap of the second, ``(2r + 1)^2``
    products a value (a 1920x1080 RGB frame at 11 taps: 147 ms fused, 29
    ms apart, 2 cores). The second pass fuses with what the caller does
    with its result. ``when`` (a traced bool, by default true) false skips
    the first pass on the CPU, for a caller that then discards the result.
    """
    taps = np.asarray(taps)
    rows = stored(lambda: _mirrored_pass(image, taps, 1), when)
    return _mirrored_pass(rows, taps, 0)


def _mirrored_pass(x, taps, axis):
    """One pass of ``taps`` along ``axis`` of ``x`` over its mirror extension:
    the inside from slices of ``x`` itself, the ``r`` samples at each end
    from the mirror indices of their neighbourhoods, joined. XLA's CPU
    backend fuses the join into one loop; a gather over the whole axis
    (or a padded copy) took 19.5 ms (11.6) for a pass along the rows of a
    1090x1920 RGB strip at 11 taps, the joined pass 3.2 ms."""
    r = (taps.shape[0] - 1) // 2
    n = x.shape[axis]
    taps = taps.astype(x.dtype)
    index = _reflect_indices(n, r)
    if n <= 4 * r:
        return _shifted_sum(jnp.take(x, index, axis=axis), taps, axis)
    first, last = (
        _shifted_sum(jnp.take(x, ends, axis=axis), taps, axis)
        for ends in (index[: 3 * r], index[-3 * r :])
    )
    return jnp.concatenate([first, _shifted_sum(x, taps, axis), last], axis=axis)


def _filter_by_products(image, taps):
    """:func:`separable_filter` one axis at a time, each pass a matrix product.

    A pass over a mirror-extended axis of length ``n`` is linear: the
    ``n x n`` matrix ``M_kj`` of :func:`_folded_matrix`. When the axis is
    longer than the kernel reaches (``n > 4 r``, ``2 r + 1`` taps), most of
    that matrix is zero, and the pass goes by blocks instead
    (:func:`_pass_by_blocks`): ``4 r + 1`` products a sample against ``n``,
    whichever is fewer (blocks alone would build a band far larger than a
    short axis). Every output is the sum of its own window's terms (the
    matrix is exactly 0 outside it), so float32 rounding stays relative to
    what the window holds; an FFT would spread the rounding of a line's
    brightest value over the whole line, wrecking the dark side of an HDR
    edge. ``precision="highest"``: full float32 products on a GPU too, whose
    default for a float32 matrix product may round its inputs (TF32).
    """
    r = (taps.shape[0] - 1) // 2
    for axis in (-2, -1):
        line = jnp.moveaxis(image, axis, -1)
        n = line.shape[-1]
        if n > 4 * r:
            out = _pass_by_blocks(line, taps)
        else:
            M = _folded_matrix(n, taps).astype(line.dtype)
            out = jnp.einsum("...k,kj->...j", line, M, precision="highest")
        image = jnp.moveaxis(out, -1, axis)
    return image


def _folded_matrix(n, taps):
    """The ``n x n`` matrix of one pass of ``taps`` over a mirror-extended
    axis of length ``n``: ``out_j = sum_k x_k M_kj``, ``M_kj`` the sum of
    the taps ``h_i`` whose extended sample ``j + i - r`` mirrors to ``k``
    (:func:`_reflect_indices`)."""
    r = (taps.shape[0] - 1) // 2
    source = _reflect_indices(n, r)[np.arange(n)[:, None] + np.arange(2 * r + 1)]
    M = np.zeros((n, n))
    np.add.at(M, (source, np.arange(n)[:, None]), taps)
    return M


def _pass_by_blocks(line, taps):
    """One pass of ``taps`` along the last axis of ``line``, as products of
    blocks of the mirror-extended axis with one banded matrix of the taps.

    With ``2 r + 1`` taps ``h``, output samples ``b s ... b s + s - 1``
    (``s = 2 r + 1``) read the ``s + 2 r`` extended samples from ``b s``
    on: they are that window times the ``(s + 2 r) x s`` matrix ``T_kj =
    h_(k - j)`` (0 off the band), one matrix product for all blocks, ``4 r
    + 1`` products a sample whatever the axis' length.
    """
    r = (taps.shape[0] - 1) // 2
    s = 2 * r + 1
    k = np.arange(s + 2 * r)[:, None] - np.arange(s)[None, :]
    band = np.where((k >= 0) & (k <= 2 * r), taps[np.clip(k, 0, 2 * r)], 0.0)
    n = line.shape[-1]
    blocks = -(-n // s)
    extended = _reflect_indices(n, r)  # n + 2 r samples
    extended = np.concatenate([extended, np.full(blocks * s - n, extended[-1])])
    windows = np.arange(blocks)[:, None] * s + np.arange(s + 2 * r)[None, :]
    out = jnp.einsum(
        "...bk,kj->...bj",
        jnp.take(line, extended[windows], axis=-1),
        band.astype(line.dtype),
        precision="highest",
    )
    return out.reshape(out.shape[:-2] + (blocks * s,))[..., :n]


def _filter_per_axis(image, taps):
    """:func:`separable_filter` one axis at a time, each padded just before its pass (CPU).

    The padding is ``jnp.pad``'s, not the index gather of :func:`_reflect_pad`
    taken one axis at a time: XLA fuses such a gather into the pass as well,
    which is several times slower."""
    r = (taps.shape[0] - 1) // 2
    for axis in (-2, -1):
        widths = [(0, 0)] * image.ndim
        widths[axis] = (r, r)
        image = _shifted_sum(jnp.pad(image, widths, mode="reflect"), taps, axis)
    return image


def _filter_both_axes(image, taps):
    """:func:`separable_filter` from the image padded on both axes at once (GPU)."""
    padded = _reflect_pad(image, (taps.shape[0] - 1) // 2)
    return _shifted_sum(_shifted_sum(padded, taps, -2), taps, -1)


def _shifted_sum(padded, taps, axis):
    """``sum_i taps[i] padded[i : i + n]`` along ``axis``, ``n`` the length
    before padding: one pass of a filter over a mirror-extended axis."""
    n = padded.shape[axis] - (taps.shape[0] - 1)
    return sum(w * jax.lax.slice_in_dim(padded, i, i + n, axis=axis) for i, w in enumerate(taps))


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
    >>> img = jnp.zeros((11, 11)).at[5, 5].set(1.0)
    >>> round(float(gaussian_blur(img, 1.0).sum()), 6)
    1.0
    """
    return separable_filter(image, gaussian_kernel(sigma, truncate))


def as_image(image, name="image"):
    """``image`` as a floating-point array, after checking its shape ``(..., H,
    W)`` (``H, W >= 1``; ``ValueError`` naming it otherwise). An integer image
    is promoted: a filter computing in its dtype would truncate the averages."""
    image = jnp.asarray(image)
    if image.ndim < 2 or 0 in image.shape[-2:]:
        raise ValueError(
            f"{name}: expected an array of shape (..., H, W), H, W >= 1, got shape {image.shape}"
        )
    return image.astype(jnp.result_type(image.dtype, float))


# -- box filters and low-pass stacks ------------------------------------------------


def _reflect_indices(n, r):
    """Indices of an axis of length ``n`` mirror-extended by ``r`` on each side.

    The same extension as ``jnp.pad(..., mode="reflect")`` (about the edge
    samples, repeated with period ``2 (n - 1)`` when ``r >= n``), as one
    gather instead of a chain of concatenations.
    """
    period = max(2 * (n - 1), 1)
    k = np.abs(np.arange(-r, n + r)) % period
    return np.where(k >= n, period - k, k)


def _reflect_pad(image, r):
    """Mirror-extend the last two axes by ``r`` pixels, as :func:`separable_filter` does."""
    H, W = image.shape[-2:]
    rows = jnp.take(image, _reflect_indices(H, r), axis=-2)
    return jnp.take(rows, _reflect_indices(W, r), axis=-1)


def _window_sums(x, w, axis):
    """Sums of ``w`` consecutive samples along ``axis``, one per window start (``n - w + 1``).

    The window is split as ``w = a b + c`` with ``a = floor(sqrt(w))``: sums of
    ``a`` samples, sums of ``b`` of those taken ``a`` apart (a dilated
    window), plus the ``c`` samples left over. That is ``O(sqrt(w))``
    additions per sample instead of ``w``, and every partial sum covers
    samples of the window only, so float32 rounding stays relative to the
    window's own content. (A running summed-area table would make the error
    grow with the sum of everything before the window: fatal for the dark
    side of an HDR edge.)
    """
    n = x.shape[axis]
    a = int(np.sqrt(w))
    b, c = divmod(w, a)
    count = n - w + 1
    zero = np.zeros((), x.dtype)  # concrete: the monoid reduce_window_sum, which JAX transposes

    def sums(y, size, dilation=1):
        window, dilations = [1] * y.ndim, [1] * y.ndim
        window[axis], dilations[axis] = size, dilation
        return jax.lax.reduce_window(
            y, zero, jax.lax.add, window, (1,) * y.ndim, "VALID", window_dilation=dilations
        )

    runs = sums(x, b) if a == 1 else sums(sums(x, a), b, a)
    total = jax.lax.slice_in_dim(runs, 0, count, axis=axis)
    if c:
        rest = sums(jax.lax.slice_in_dim(x, a * b, n, axis=axis), c)
        total = total + jax.lax.slice_in_dim(rest, 0, count, axis=axis)
    return total


def box_filter(image, radius):
    """Mean over the ``(2 radius + 1)^2`` square around each pixel (box weights of Eq 6.4).

    Parameters
    ----------
    image : array, shape (..., H, W)
        Any quantity per pixel; leading axes are batch axes.
    radius : int
        Half-width of the square, pixels (static). ``0`` returns the image.
        Radii larger than the image are allowed: the image is mirror-extended
        as often as needed (as in :func:`separable_filter`), so a constant
        image stays constant and a very large box tends to the mean of the
        mirrored image.

    Returns
    -------
    array, shape (..., H, W)

    Notes
    -----
    The chapter's box weight is a disc, ``||p - i|| < s``; we use the square
    of half-width ``s``, which is separable and costs ``O(sqrt(radius))``
    additions per pixel whatever the radius (see :func:`disc_window` and
    :func:`bilateral_filter` for disc weights).

    Examples
    --------
    >>> float(box_filter(jnp.arange(9.0).reshape(3, 3), 1)[1, 1])
    4.0
    """
    image = as_image(image)
    r = check_whole("radius", radius, unit="pixels")
    w = 2 * r + 1
    down, up = sum_headroom(w * w, image.dtype)
    image = image * down
    for axis in (image.ndim - 2, image.ndim - 1):  # one axis extended at a time
        extended = jnp.take(image, _reflect_indices(image.shape[axis], r), axis=axis)
        image = _window_sums(extended, w, axis)
    return image / jnp.asarray(w * w, image.dtype) * up


def sum_headroom(count, dtype):
    """``(2^-k, 2^k)`` with ``2^k >= count``: the factors by which a sum of
    ``count`` values is taken and its mean given back, so that the sum of
    values near the dtype's largest (float32's 3.4e38) does not overflow.
    A power of two scales exactly (down to values of 2^k times the
    smallest normal, 1e-38 in float32), so the mean is the unscaled one's,
    bit for bit."""
    k = max(int(count) - 1, 0).bit_length()
    return jnp.asarray(2.0**-k, dtype), jnp.asarray(2.0**k, dtype)


def iterated_box_filter(image, radius, passes=3):
    """``passes`` successive :func:`box_filter` s: a smooth, almost Gaussian low-pass.

    The kernel is a box convolved with itself ``passes`` times (a B-spline
    of degree ``passes - 1``), of support ``2 passes radius + 1`` and
    variance ``passes r (r + 1) / 3`` pixels^2; three passes approximate a
    Gaussian of standard deviation ``sqrt(r (r + 1))`` (Wells 1986) to
    within 6-8 % of its peak, at a cost independent of the radius.

    Parameters
    ----------
    image : array, shape (..., H, W)
    radius : int
        Half-width of each box, pixels (static).
    passes : int
        Number of boxes (static), ``>= 1``.

    Returns
    -------
    array, shape (..., H, W)

    Examples
    --------
    >>> impulse = jnp.zeros((1, 9)).at[0, 4].set(1.0)
    >>> [round(float(v) * 9, 6) for v in iterated_box_filter(impulse, 1, passes=2)[0, 2:7]]
    [1.0, 2.0, 3.0, 2.0, 1.0]
    """
    check_whole("passes", passes, least=1)
    for _ in range(passes):
        image = box_filter(image, radius)
    return image


def lowpass_stack(image, radii, passes=3):
    """Low-pass images of ``image`` at several scales, stacked on a new axis ``-3``.

    Level ``i`` is :func:`iterated_box_filter` with radius ``radii[i]``: the
    average local luminance at that scale (Peli's low-pass images, §6.4.3).

    Parameters
    ----------
    image : array, shape (..., H, W)
    radii : sequence of int
        Box half-widths, pixels (static), usually increasing.
    passes : int
        Boxes per level (static).

    Returns
    -------
    array, shape (..., len(radii), H, W)
    """
    if len(radii) == 0:
        raise ValueError("radii: expected at least one box half-width (pixels), got none")
    return jnp.stack([iterated_box_filter(image, r, passes) for r in radii], axis=-3)


# -- bilateral filter (Eq 6.5) --------------------------------------------------

#: Intensity weights ``g`` of Eq 6.5 as functions of ``t = (guide_i - guide_p) / sigma_r``:
#: Gaussian (Durand and Dorsey 2002) and exponential (Pattanaik and Yee 2002).
RANGE_KERNELS = {
    "gaussian": lambda t: jnp.exp(-0.5 * t * t),
    "exponential": lambda t: jnp.exp(-jnp.abs(t)),
}


def gaussian_window(s, truncate=2.0):
    """Spatial weights ``w = exp(-||p - i||^2 / s^2)`` of Eq 6.4 on a disc.

    The chapter's Gaussian, a standard deviation of ``s / sqrt(2)``,
    truncated to the disc ``||p - i|| <= R``, ``R = ceil(truncate s / sqrt(2))``.

    Parameters
    ----------
    s : float
        Size parameter of Eq 6.4, pixels (static), ``> 0``.
    truncate : float
        Radius of the disc in standard deviations.

    Returns
    -------
    numpy array, shape (2 R + 1, 2 R + 1)
    """
    if not (np.isfinite(s) and s > 0):
        raise ValueError(f"scale: expected a positive size in pixels, got {s!r}")
    R = int(np.ceil(truncate * s / np.sqrt(2.0)))
    d2 = np.add.outer(np.arange(-R, R + 1) ** 2, np.arange(-R, R + 1) ** 2)
    return np.where(d2 <= R * R, np.exp(-d2 / s**2), 0.0)


def disc_window(s):
    """Circular box weights of Eq 6.4: 1 for ``||p - i|| < s``, 0 elsewhere
    (Pattanaik and Yee's spatial weight). ``s <= 1`` is the pixel itself.

    Parameters
    ----------
    s : float
        Radius, pixels (static), ``> 0``.

    Returns
    -------
    numpy array, shape (2 R + 1, 2 R + 1)
        With ``R = ceil(s) - 1``.
    """
    if not (np.isfinite(s) and s > 0):
        raise ValueError(f"scale: expected a positive radius in pixels, got {s!r}")
    R = int(np.ceil(s)) - 1
    d2 = np.add.outer(np.arange(-R, R + 1) ** 2, np.arange(-R, R + 1) ** 2)
    return (d2 < s * s).astype(np.float64)


#: Spatial weights ``w`` of Eq 6.5 by name: functions of the size parameter ``s``.
SPATIAL_WINDOWS = {"gaussian": gaussian_window, "disc": disc_window}


def bilateral_filter(
    image, scale, sigma_r, spatial="gaussian", range_kernel="gaussian", guide=None
):
    """Bilateral average of Eq 6.5: ``sum w g I / sum w g`` over a window.

    ``I_p' = sum_i w(p, i) g(G_p, G_i) I_i / sum_i w(p, i) g(G_p, G_i)``, with
    ``w`` a spatial weight of size ``scale`` and ``g`` a weight on the
    difference of the guide ``G`` (the image itself by default, or e.g. its
    log luminance) in units of ``sigma_r``.

    Parameters
    ----------
    image : array, shape (..., H, W)
        Values averaged; leading axes are batch axes.
    scale : float
        Size parameter ``s`` of the spatial weight, pixels (static): see
        :func:`gaussian_window` and :func:`disc_window`.
    sigma_r : float or array
        Width of the intensity weight, in units of the guide, ``> 0``: one,
        or an array that broadcasts to the image's shape (e.g. one a frame,
        ``(T, 1, 1)``).
    spatial : str
        ``"gaussian"`` (Durand and Dorsey) or ``"disc"`` (Pattanaik and Yee).
    range_kernel : str
        ``"gaussian"`` (Durand and Dorsey) or ``"exponential"`` (Pattanaik
        and Yee): see :data:`RANGE_KERNELS`.
    guide : array, shape (..., H, W), optional
        Quantity whose differences set ``g``; defaults to ``image``.

    Returns
    -------
    array, shape (..., H, W)

    Notes
    -----
    Exact, windowed and vectorised: one pass over the whole image per window
    offset (``lax.scan`` over the offsets), so the cost grows with the
    window's area (about ``pi R^2`` offsets). The edges are mirror-extended
    as in :func:`box_filter`. With ``spatial="gaussian"`` and
    ``range_kernel="gaussian"`` it is OpenCV's ``cv2.bilateralFilter`` with
    ``d = 2 R + 1``, ``sigmaSpace = scale / sqrt(2)``, ``sigmaColor =
    sigma_r`` and ``BORDER_REFLECT_101``.

    Examples
    --------
    >>> step = jnp.concatenate([jnp.zeros((4, 4)), jnp.ones((4, 4))], axis=1)
    >>> out = bilateral_filter(step, 2.0, 0.1)
    >>> round(float(out[0, 3]), 6), round(float(out[0, 4]), 6)
    (0.0, 1.0)
    """
    image = as_image(image)
    for name, value, options in (
        ("spatial", spatial, SPATIAL_WINDOWS),
        ("range_kernel", range_kernel, RANGE_KERNELS),
    ):
        if value not in options:
            raise ValueError(f"{name}: expected one of {tuple(options)}, got {value!r}")
    check_value("sigma_r", sigma_r, lambda v: v > 0, "a positive width")
    guide = image if guide is None else as_image(guide, "guide")
    if guide.shape != image.shape:
        raise ValueError(f"guide: expected the shape of image {image.shape}, got {guide.shape}")
    shape = image.shape
    try:
        sigma_r = jnp.broadcast_to(jnp.asarray(sigma_r, image.dtype), shape)
    except ValueError:
        raise ValueError(
            f"sigma_r: expected a shape that broadcasts to {shape}, got {np.shape(sigma_r)}"
        ) from None
    window = SPATIAL_WINDOWS[spatial](scale)
    g = RANGE_KERNELS[range_kernel]
    R = window.shape[0] // 2
    values = image.reshape((-1,) + shape[-2:])
    guide = guide.reshape(values.shape).astype(image.dtype)
    sigma_r = sigma_r.reshape(values.shape)
    padded_values, padded_guide = _reflect_pad(values, R), _reflect_pad(guide, R)
    rows, cols = np.nonzero(window)
    taps = (jnp.asarray(rows), jnp.asarray(cols), jnp.asarray(window[rows, cols], image.dtype))
    down, up = sum_headroom(rows.size, image.dtype)  # the sum of every tap's value
    padded_values = padded_values * down

    def accumulate(carry, tap):
        num, den = carry
        dy, dx, w = tap
        start = (0, dy, dx)
        v = jax.lax.dynamic_slice(padded_values, start, values.shape)
        weight = w * g((jax.lax.dynamic_slice(padded_guide, start, values.shape) - guide) / sigma_r)
        return (num + weight * v, den + weight), None

    zeros = jnp.zeros_like(values)
    (num, den), _ = jax.lax.scan(accumulate, (zeros, zeros), taps)
    return (num / den * up).reshape(shape)


# -- Gaussian ladder: blurs at rising widths, each at a cost bounded whatever its width --

#: Width at which a level of :func:`gaussian_ladder` is decimated, pixels of
#: that level: a Gaussian of 2 pixels passes 0.7 % of a sinusoid at the
#: decimated level's Nyquist frequency, the most that can alias.
DECIMATE_AT = 2.0

#: Width of the Gaussian that interpolates a level onto the next finer one,
#: pixels of the finer level: its images of the coarse level's spectrum, at
#: half the finer level's sampling rate and above, pass at most 0.08 %.
EXPAND_SIGMA = 1.2


def ladder_levels(sigmas):
    """The pyramid level (0 = full resolution) at which :func:`gaussian_ladder`
    blurs each of ``sigmas`` (pixels): the coarsest whose decimation width
    (:data:`DECIMATE_AT`) and interpolations back up (:data:`EXPAND_SIGMA`)
    still fit in the blur's variance."""
    added = EXPAND_SIGMA**2 / 3  # expanding from level l adds added (4^l - 1) pixels^2
    levels = []
    for s in sigmas:
        _check_sigma(s)
        level = 0
        while s**2 >= 4 ** (level + 1) * (added + DECIMATE_AT**2 / 4) - added:
            level += 1
        levels.append(level)
    return levels


def gaussian_ladder(image, sigmas, needed=None):
    """Gaussian blurs of the first two axes of ``image (H, W, ...)`` at each
    of the rising ``sigmas``, each at a cost per pixel bounded whatever its
    width.

    A pyramid: level 0 is the image; once a level holds a blur of at least
    :data:`DECIMATE_AT` of its pixels, every other sample of that blur
    starts the next level, a quarter the size. Each requested blur is made
    on the coarsest level it fits (:func:`ladder_levels`), from that level's
    start by the sampled Gaussian (:func:`gaussian_kernel`) that makes up
    its variance (Gaussians compose: a blur of ``s`` blurred by ``sqrt(t^2
    - s^2)`` is one of ``t``), then interpolated back up to full size by
    Gaussians of :data:`EXPAND_SIGMA` (:func:`_expand`), whose variance is
    counted in it. A blur on level 0 is exactly :func:`channels_last_filter`
    with :func:`gaussian_kernel`; its kernel stays under 2.4 pixels of its
    level, so a blur costs at most 21 taps a pass on level 0, or a quarter
    of that and an interpolation on a coarser level, where a direct blur
    takes ``8 sigma + 1`` taps a pass. Every weight is positive, so a
    non-negative image gives non-negative blurs. Edges are mirror-extended
    on every level, as :func:`channels_last_filter` does.

    Parameters
    ----------
    image : array, shape (H, W, ...)
    sigmas : sequence of float
        Standard deviations, pixels, rising (static).
    needed : sequence of traced bool, optional
        Whether each blur is used; one not needed, and a level only it
        needs, is skipped on the CPU (zeros instead), as in
        :func:`jaxadapt.fused.stored`. By default all are computed.

    Returns
    -------
    list of functions
        Each gives its blur ``(H, W, ...)`` when called: called where the
        blur is used (under the caller's conditional, say), its last pass
        fuses with that use, as :func:`channels_last_filter`'s does.
    """
    sigmas = [float(s) for s in sigmas]
    if np.any(np.diff(sigmas) <= 0):
        raise ValueError(f"sigmas: expected rising widths in pixels, got {sigmas!r}")
    levels = ladder_levels(sigmas)
    needed = [None] * len(sigmas) if needed is None else list(needed)

    def any_of(flags):
        flags = list(flags)
        if any(f is None for f in flags):
            return None
        return functools.reduce(jnp.logical_or, flags, jnp.bool_(False))

    depth = max(levels)
    shapes = [image.shape[:2]]
    for _ in range(depth):
        shapes.append(tuple(-(-n // 2) for n in shapes[-1]))
    # Each blur's variance on its level before the interpolations, full pixels^2.
    held = [s**2 - EXPAND_SIGMA**2 * (4**l - 1) / 3 for s, l in zip(sigmas, levels, strict=True)]

    out = [None] * len(sigmas)
    start, start_variance = image, 0.0
    for level in range(depth + 1):

        def blur(variance, when, start=start, start_variance=start_variance, level=level):
            if variance <= start_variance:
                return start
            width = np.sqrt(variance - start_variance) / 2**level  # pixels of the level
            taps = gaussian_kernel(width) if level == 0 else _kernel_of_variance(width**2)
            return channels_last_filter(start, taps, when)

        mine = [i for i, l in enumerate(levels) if l == level]
        source = None
        if level < depth:
            # The next level starts from a blur of this one of at least
            # DECIMATE_AT of its pixels and at most what the next level's
            # blurs hold: the widest such blur made here, else one made for it.
            least = (DECIMATE_AT * 2**level) ** 2
            most = min(held[i] for i, l in enumerate(levels) if l > level)
            source = max((held[i] for i in mine if least <= held[i] <= most), default=least)
            when = any_of(needed[i] for i, l in enumerate(levels) if l > level or held[i] == source)
            made = stored(lambda source=source, when=when: blur(source, when), when)
        for i in mine:
            if held[i] == source:
                coarse = made
            elif level == 0:
                out[i] = functools.partial(blur, held[i], needed[i])
                continue
            else:
                coarse = stored(functools.partial(blur, held[i], needed[i]), needed[i])
            out[i] = functools.partial(_expanded, coarse, shapes[:level], needed[i])
        if source is not None:
            start, start_variance = made[::2, ::2], source
    return out


def _expanded(x, shapes, when):
    """``x`` interpolated (:func:`_expand`) level by level onto ``shapes[0]``
    from the level of ``shapes[-1]``, each level stored but the last, so
    that the last fuses with what the caller does with it (none: ``x``)."""
    for k, shape in enumerate(reversed(shapes)):
        x = _expand(x, shape, when)
        if k < len(shapes) - 1:
            x = stored(lambda x=x: x, when)
    return x


def _kernel_of_variance(variance):
    """The sampled Gaussian (:func:`gaussian_kernel`) whose taps' variance is
    ``variance`` (pixels^2): below about one pixel a sampled Gaussian's
    taps hold less variance than its width's square."""
    from scipy.optimize import brentq

    def held(sigma):
        taps = gaussian_kernel(sigma)
        x = np.arange(taps.size) - taps.size // 2
        return np.sum(taps * x**2) - variance

    return gaussian_kernel(brentq(held, np.sqrt(variance), np.sqrt(variance) + 1.0, xtol=1e-12))


def _expand(x, shape, when):
    """``x (h, w, ...)`` interpolated onto the level twice as fine, cut to
    ``shape (H, W)``: each finer sample a Gaussian (:data:`EXPAND_SIGMA`)
    weighting of the coarse samples, normalised per phase. The first pass
    is stored (:func:`jaxadapt.fused.stored`, skipped unless ``when``), the
    second fuses with its use."""
    r = int(np.ceil(4 * EXPAND_SIGMA / 2)) + 1
    j = np.arange(-r, r + 1)
    phases = []
    for offset in (0, 1):  # finer samples on a coarse one, between two
        taps = np.exp(-0.5 * ((2 * j - offset) / EXPAND_SIGMA) ** 2)
        phases.append(taps / taps.sum())

    def interpolated(x, axis, n):
        even, odd = (_mirrored_pass(x, taps, axis) for taps in phases)
        both = jnp.stack([even, odd], axis=axis + 1)
        x = both.reshape(x.shape[:axis] + (2 * x.shape[axis],) + x.shape[axis + 1 :])
        return jax.lax.slice_in_dim(x, 0, n, axis=axis)

    rows = stored(lambda: interpolated(x, 0, shape[0]), when)
    return interpolated(rows, 1, shape[1])
