"""Frames as channel planes: the layout of the renderer's per-pixel work.

The per-pixel functions of the renderer take and return lists of three
``(H, W)`` planes (R, G, B or L, M, S), not ``(H, W, 3)`` arrays. Written
on ``(H, W, 3)`` arrays, a colour matrix's output (``x @ M.T``) reads
each of a pixel's three inputs for each of its three outputs, and XLA's
CPU backend, which fuses one output element at a time, evaluated the
whole chain behind ``x`` (powers of Eq 1, of Eq 11) once per output
channel, or stored it and read it back per channel. On planes the chain
is evaluated once per pixel and channel.

The planes are contiguous: the renderer transposes its input frame once
(:func:`planar`) and keeps its maps as ``(3, H, W)`` arrays
(:func:`split`, :func:`joined`). A plane read out of an interleaved
``(H, W, 3)`` frame steps over the other two channels in every loop that
reads it, which XLA's CPU backend does not vectorise: the receptor inputs
of a 1920x1080 frame took 27 ms from it, 15 ms from planes (2 cores).
The public functions on ``(H, W, 3)`` arrays are these functions between
:func:`planes` and :func:`stacked`.
"""

import jax.numpy as jnp

from jaxadapt.color import combine
from jaxadapt.fused import stored


def planes(x):
    """The channel planes ``[x[..., 0], x[..., 1], x[..., 2]]`` of ``x (..., 3)``."""
    return [x[..., c] for c in range(x.shape[-1])]


def stacked(channels):
    """The planes ``channels`` as one array, channels last."""
    return jnp.stack(channels, axis=-1)


def planar(frame):
    """The contiguous planes of ``frame (H, W, 3)``: one transposition,
    stored on the CPU (:func:`jaxadapt.fused.stored`) so that the loops
    that read the planes do not each read the interleaved frame; each plane
    its own array, which a conditional can take without a copy (a slice of
    one array is copied into an array of its own there)."""
    return stored(lambda: split(jnp.moveaxis(frame, -1, 0)))


def split(x):
    """The planes of a planar array ``x (3, H, W)``."""
    return [x[c] for c in range(x.shape[0])]


def joined(channels):
    """The planes ``channels`` as one planar array ``(3, H, W)``."""
    return jnp.stack(channels, axis=0)


def mix(M, channels):
    """The planes of ``x @ M.T`` for the planes of ``x``, ``M (3, 3)``."""
    return [combine(row, channels) for row in M]
