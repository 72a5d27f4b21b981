"""Frames as channel planes: the layout of the renderer's per-pixel work.

The per-pixel functions of the renderer take and return lists of three
``(H, W)`` planes (R, G, B or L, M, S), not ``(H, W, 3)`` arrays. Written
on ``(H, W, 3)`` arrays, a colour matrix's output (``x @ M.T``) reads
each of a pixel's three inputs for each of its three outputs, and XLA's
CPU backend, which fuses one output element at a time, evaluated the
whole chain behind ``x`` (powers of Eq 1, of Eq 11) once per output
channel, or stored it and read it back per channel. On planes the chain
is evaluated once per pixel and channel. The public functions on
``(H, W, 3)`` arrays are these functions between :func:`planes` and
:func:`stacked`, which XLA cancels where one's output is the other's input.
"""

import jax.numpy as jnp

from jaxadapt.color import combine


def planes(x):
    """The channel planes ``[x[..., 0], x[..., 1], x[..., 2]]`` of ``x (..., 3)``."""
    return [x[..., c] for c in range(x.shape[-1])]


def stacked(channels):
    """The planes ``channels`` as one array, channels last."""
    return jnp.stack(channels, axis=-1)


def mix(M, channels):
    """The planes of ``x @ M.T`` for the planes of ``x``, ``M (3, 3)``."""
    return [combine(row, channels) for row in M]
