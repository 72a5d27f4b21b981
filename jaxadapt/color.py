"""Colour constants, derived once at import from colour-science, and luminances.

Frames are linear ITU-R BT.709 RGB in absolute units: each channel in cd/m2,
so that the photopic luminance ``Y`` of a pixel is in cd/m2.
"""

import colour
import jax
import jax.numpy as jnp
import numpy as np

#: Linear BT.709 RGB to CIE XYZ (D65), from colour-science.
RGB709_TO_XYZ = np.asarray(colour.RGB_COLOURSPACES["ITU-R BT.709"].matrix_RGB_to_XYZ)

#: Photopic luminance weights: the Y row of :data:`RGB709_TO_XYZ`
#: (0.2126, 0.7152, 0.0722).
W_PHOTOPIC = RGB709_TO_XYZ[1]

#: Scotopic luminance weights for BT.709 RGB.
#:
#: Jacobs et al. (2015), Appendix A, give ``w_S = (0, 0.8451, 0.1459)``
#: (adapted from Kirk and O'Brien 2011): no weight on red, most on green and
#: blue, as the CIE 1951 scotopic curve peaking at 507 nm implies. We scale
#: them to sum to one, so that a neutral (D65) pixel has equal scotopic and
#: photopic values. This is the convention of Pattanaik et al. (2000), whose
#: display observer has ``A_rod = A_cone = 25`` cd/m2 and whose Hunt-derived
#: rod constants (Eqs 4 and 6) are stated in the same units as the cone ones.
#: (In true scotopic cd/m2, D65 carries 2.46 times its photopic luminance by
#: colour-science's CIE 1951 and 1931 tables: see :data:`SP_RATIO_D65`.)
W_SCOTOPIC = np.array([0.0, 0.8451, 0.1459]) / (0.8451 + 0.1459)


def _sp_ratio_d65():
    """Scotopic-to-photopic luminance ratio of CIE D65 (1700 and 683 lm/W)."""
    shape = colour.SpectralShape(380, 780, 1)
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(shape).values
    v_scotopic = (
        colour.colorimetry.SDS_LEFS_SCOTOPIC["CIE 1951 Scotopic Standard Observer"]
        .copy()
        .align(shape)
        .values
    )
    v_photopic = (
        colour.colorimetry.SDS_LEFS_PHOTOPIC["CIE 1924 Photopic Standard Observer"]
        .copy()
        .align(shape)
        .values
    )
    return 1700.0 * np.dot(d65, v_scotopic) / (683.0 * np.dot(d65, v_photopic))


#: Scotopic-to-photopic luminance ratio of D65 in absolute units (about 2.46).
SP_RATIO_D65 = float(_sp_ratio_d65())


def _lms_matrix():
    """BT.709 RGB to Hunt-Pointer-Estevez LMS, rows scaled so that white
    ``(1, 1, 1)`` gives ``(1, 1, 1)``: cone excitations in cd/m2 of white."""
    M = np.asarray(colour.appearance.hunt.MATRIX_XYZ_TO_HPE) @ RGB709_TO_XYZ
    return M / M.sum(axis=1, keepdims=True)


#: Linear BT.709 RGB to cone excitations L, M, S (cd/m2 for white light).
RGB_TO_LMS = _lms_matrix()
#: Its inverse.
LMS_TO_RGB = np.linalg.inv(RGB_TO_LMS)


def transform(x, M):
    """Apply the colour matrix ``M`` to colour vectors ``x (..., 3)``: ``x @ M.T``.

    ``M`` is ``(k, 3)``, giving ``(..., k)``, or a weight vector ``(3,)``,
    giving ``(...)``. Each output is written out as a sum of three products
    rather than a dot: XLA then fuses it with the elementwise work around
    it, whereas a dot contracting three channels over a batch of frames
    becomes a matrix multiply of its own on a GPU (an extra pass over the
    frames: 78 us per 1080p frame on an H100 for the two luminances of
    :mod:`~jaxadapt.operators.pattanaik2000`). The exception is a matrix on
    the CPU: fused there, the sums of its ``k`` outputs make XLA evaluate
    whatever computes ``x`` ``k`` times (the 2015 operator's afterimage
    gain, an exponential per cone class, three times per channel: the whole
    operator a quarter slower). So on the CPU the ``k`` outputs are
    computed one after another (``lax.map`` over the rows of ``M``), which
    stores ``x`` once as the loop's input. That is also 4 times faster than
    the dot the CPU path was before, which XLA hands to YNNPACK as a matrix
    multiply with 3 columns: 8.3 ms against 35 ms for a 1920x1080 frame,
    51 against 70 ms after an expensive producer (float32, 2 cores).

    ``x`` of integers is promoted to floats (in its own dtype the weights
    would round to 0); a last axis other than 3 is a ``ValueError``.
    """
    x = jnp.asarray(x)
    if x.shape[-1:] != (3,):
        raise ValueError(f"rgb: expected colour vectors of shape (..., 3), got shape {x.shape}")
    x = x.astype(jnp.result_type(x.dtype, float))
    M = jnp.asarray(M, dtype=x.dtype)
    if M.ndim == 1:
        return combine(M, [x[..., j] for j in range(3)])
    return jax.lax.platform_dependent(
        x, cpu=lambda x: _rows_in_turn(x, M), default=lambda x: _rows_at_once(x, M)
    )


def _rows_at_once(x, M):
    """``x @ M.T`` as one expression of sums of products (GPU)."""
    channels = [x[..., j] for j in range(3)]
    return jnp.stack([combine(m, channels) for m in M], axis=-1)


def _rows_in_turn(x, M):
    """``x @ M.T`` one output channel after another, ``x`` stored once (CPU)."""
    channels = list(jnp.moveaxis(x, -1, 0))
    return jnp.moveaxis(jax.lax.map(lambda m: combine(m, channels), M), 0, -1)


def combine(weights, channels):
    """``sum_j w_j c_j``: weights ``(3,)`` applied to channel planes ``[c_0, c_1, c_2]``."""
    return sum(jnp.asarray(w, c.dtype) * c for w, c in zip(weights, channels, strict=True))


def photopic_luminance(rgb):
    """Photopic luminance ``Y = w_P . rgb`` (cd/m2) of ``(..., 3)`` linear BT.709 RGB."""
    return transform(rgb, W_PHOTOPIC)


def scotopic_luminance(rgb):
    """Scotopic luminance ``Y' = w_S . rgb`` of ``(..., 3)`` linear BT.709 RGB.

    In units where a neutral pixel's scotopic value equals its photopic
    luminance (see :data:`W_SCOTOPIC`).
    """
    return transform(rgb, W_SCOTOPIC)
