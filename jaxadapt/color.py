"""Colour constants and luminances.

Frames are linear ITU-R BT.709 RGB in absolute units: each channel in cd/m2,
so that the photopic luminance ``Y`` of a pixel is in cd/m2.

The constants are colour-science's values written out to full float64
precision, because importing colour-science (with matplotlib, SciPy and
pandas) takes longer than a short render's work. The tests derive each one
from colour-science again and require equality to 1e-15.
"""

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "BT709_CHROMATICITIES",
    "RGB709_TO_XYZ",
    "W_PHOTOPIC",
    "W_SCOTOPIC",
    "SP_RATIO_D65",
    "XYZ_TO_HPE",
    "RGB_TO_LMS",
    "LMS_TO_RGB",
    "BT2020_TO_BT709",
    "YCBCR_WEIGHTS",
    "ycbcr_to_rgb",
    "transform",
    "combine",
    "photopic_luminance",
    "scotopic_luminance",
]

#: Chromaticities of ITU-R BT.709 (x, y of red, green, blue and the D65 white).
BT709_CHROMATICITIES = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)

#: Linear BT.709 RGB to CIE XYZ (D65): colour-science's
#: ``RGB_COLOURSPACES["ITU-R BT.709"].matrix_RGB_to_XYZ``.
RGB709_TO_XYZ = np.array(
    [
        [0.41239079926595934, 0.35758433938387796, 0.1804807884018343],
        [0.2126390058715103, 0.7151686787677559, 0.07219231536073371],
        [0.01933081871559182, 0.11919477979462595, 0.9505321522496606],
    ]
)

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

#: Scotopic-to-photopic luminance ratio of CIE D65 in absolute units:
#: ``1700 sum(D65 V') / (683 sum(D65 V))`` over 380-780 nm in 1 nm steps,
#: with colour-science's D65, CIE 1951 scotopic and CIE 1924 photopic tables.
SP_RATIO_D65 = 2.464501664248087

#: CIE XYZ to Hunt-Pointer-Estevez LMS (colour-science's
#: ``appearance.hunt.MATRIX_XYZ_TO_HPE``).
XYZ_TO_HPE = np.array(
    [
        [0.38971, 0.68898, -0.07868],
        [-0.22981, 1.18340, 0.04641],
        [0.0, 0.0, 1.0],
    ]
)


def _lms_matrix():
    """BT.709 RGB to Hunt-Pointer-Estevez LMS, rows scaled so that white
    ``(1, 1, 1)`` gives ``(1, 1, 1)``: cone excitations in cd/m2 of white."""
    M = XYZ_TO_HPE @ RGB709_TO_XYZ
    return M / M.sum(axis=1, keepdims=True)


#: Linear BT.709 RGB to cone excitations L, M, S (cd/m2 for white light).
RGB_TO_LMS = _lms_matrix()
#: Its inverse.
LMS_TO_RGB = np.linalg.inv(RGB_TO_LMS)


#: Linear BT.2020 RGB to linear BT.709 RGB (both D65): colour-science's
#: ``matrix_RGB_to_RGB`` of its ``"ITU-R BT.2020"`` and ``"ITU-R BT.709"``.
BT2020_TO_BT709 = np.array(
    [
        [1.6604910021084347, -0.5876411387885498, -0.07284986331988497],
        [-0.12455047452159082, 1.1328998971259605, -0.00834942260436943],
        [-0.01815076335490522, -0.10057889800800744, 1.1187296613629127],
    ]
)

#: Luma weights ``(Kr, Kb)`` of the Y'CbCr matrices, by colour-science's
#: names (its ``WEIGHTS_YCBCR``).
YCBCR_WEIGHTS = {
    "ITU-R BT.601": (0.299, 0.114),
    "ITU-R BT.709": (0.2126, 0.0722),
    "ITU-R BT.2020": (0.2627, 0.0593),
}


def ycbcr_to_rgb(weights, bits, legal):
    """The matrix and offsets that turn integer Y'CbCr codes into R'G'B'
    in [0, 1]: ``R'G'B' = matrix @ (codes - offsets)``.

    ITU-R BT.601, BT.709 and BT.2020's Y'CbCr for luma weights ``(Kr,
    Kb)`` (:data:`YCBCR_WEIGHTS`), as colour-science's ``matrix_YCbCr``
    and ``offset_YCbCr`` (integer codes) give them: legal ("video") range
    Y' 16 to 235 and Cb, Cr 16 to 240, times ``2^(bits - 8)``; full range
    0 to ``2^bits - 1``, chroma centred on ``2^(bits - 1)``.

    Parameters
    ----------
    weights : (float, float)
    bits : int
        Bits a code.
    legal : bool
        Legal (limited) range, or full range.

    Returns
    -------
    (numpy array (3, 3), numpy array (3,))
    """
    Kr, Kb = weights
    if legal:
        Y_min, Y_max, C_min, C_max = np.array([16.0, 235.0, 16.0, 240.0]) * 2.0 ** (bits - 8)
    else:
        Y_min, Y_max, C_min, C_max = 0.0, 2.0**bits - 1, 0.5, 2.0**bits - 0.5
    Y = np.array([Kr, 1.0 - Kr - Kb, Kb])
    Cb = 0.5 * (np.array([0.0, 0.0, 1.0]) - Y) / (1.0 - Kb) * (C_max - C_min)
    Cr = 0.5 * (np.array([1.0, 0.0, 0.0]) - Y) / (1.0 - Kr) * (C_max - C_min)
    matrix = np.linalg.inv(np.vstack([Y * (Y_max - Y_min), Cb, Cr]))
    centre = (C_min + C_max) / 2
    return matrix, np.array([Y_min, centre, centre])


def transform(x, M):
    """Apply the colour matrix ``M`` to colour vectors ``x (..., 3)``: ``x @ M.T``.

    ``M`` is ``(k, 3)``, giving ``(..., k)``, or a weight vector ``(3,)``,
    giving ``(...)``. Each output is written as a sum of three products, not
    a dot, so that on a GPU XLA fuses it with the elementwise work around it
    instead of adding a matrix multiply's pass over the frames. On the CPU a
    matrix's outputs are computed one after another (``lax.map`` over the
    rows of ``M``): there the fused sums would re-evaluate whatever computes
    ``x`` once per output, and a dot is slower too.

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
