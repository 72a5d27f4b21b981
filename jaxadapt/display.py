"""Display encodings: from display-relative linear values in [0, 1] to encoded
signals in [0, 1], and from those to 8-bit code values."""

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt._checks import check_value
from jaxadapt.physiology.response import power

__all__ = ["encode_srgb", "encode_gamma", "ENCODINGS", "to_uint8", "encode_uint8", "dither"]


def encode_srgb(v):
    """IEC 61966-2-1 sRGB encoding of linear values in [0, 1].

    ``12.92 v`` below 0.0031308, ``1.055 v^(1/2.4) - 0.055`` above.
    """
    v = jnp.clip(v, 0.0, 1.0)
    high = 1.055 * power(jnp.maximum(v, 0.0031308), 1.0 / 2.4) - 0.055
    return jnp.where(v <= 0.0031308, 12.92 * v, high)


def encode_gamma(v, gamma=2.2):
    """Pure power-law encoding ``v^(1/gamma)`` of linear values in [0, 1]."""
    check_value("gamma", gamma, lambda g: np.isfinite(g) & (g > 0), "a positive display gamma")
    return power(jnp.clip(v, 0.0, 1.0), 1.0 / gamma)


ENCODINGS = {"srgb": encode_srgb, "gamma": encode_gamma, "linear": lambda v: jnp.clip(v, 0, 1)}


def to_uint8(v):
    """Quantise encoded values in [0, 1] to 8-bit code values: the nearest,
    ties to even (``jnp.round``); a numpy array."""
    return np.asarray(_codes(jnp.asarray(v)))


@jax.jit
def _codes(v):
    return jnp.round(jnp.clip(v, 0.0, 1.0) * 255.0).astype(jnp.uint8)


@partial(jax.jit, static_argnames="encoding")
def _encoded_codes(v, encoding):
    return _codes(ENCODINGS[encoding](v))


def encode_uint8(v, encoding="srgb"):
    """8-bit code values of linear display values ``v`` in [0, 1] encoded
    with ``encoding`` (a name of :data:`ENCODINGS`): :func:`to_uint8` of
    the encoding, compiled as one pass over the frames (op by op, each step
    would write a whole chunk of frames to memory); a numpy array."""
    return np.asarray(_encoded_codes(jnp.asarray(v), encoding))


def dither(J, key, levels=255):
    """Temporal dithering of encoded values ``J`` in [0, 1] to ``levels`` steps.

    Jacobs et al. (2015), §2.4: ``J levels = J_I + J_F`` is rounded up to
    ``J_I + 1`` with probability ``J_F``, independently for every channel of
    every pixel (one uniform draw each from ``key``, which the caller
    changes every frame), so that the average over frames is ``J``.
    """
    u = jax.random.uniform(key, J.shape, dtype=J.dtype)
    return jnp.clip(jnp.floor(J * levels + u), 0.0, levels) / levels
