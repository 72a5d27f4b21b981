"""What the physiology functions take: array-likes, and their domains."""

import functools

import jax.numpy as jnp


def array_like(fn):
    """``fn`` with each list or tuple argument made an array first.

    JAX's functions refuse lists (``jnp.log10([1, 10])`` is a TypeError,
    so that a loop does not convert one at every call). The physiology
    functions are also called by hand, on a list of luminances, and take
    one as NumPy and colour-science do; arrays, scalars and tracers pass
    as they are.
    """

    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        args = [_array(x) for x in args]
        return fn(*args, **{name: _array(x) for name, x in kwargs.items()})

    return wrapped


def _array(x):
    return jnp.asarray(x) if isinstance(x, list | tuple) else x


def nonnegative(x, y):
    """``y`` where ``x >= 0``, NaN where ``x < 0``.

    For functions of a luminance or a diameter, which is never negative:
    outside that domain they give NaN (as NaN itself does), not a number
    that could pass for an answer (a pupil of 7.9 mm, a bleaching factor
    above 1). Under ``jit`` there is no other way to say it.
    """
    return jnp.where(x < 0, jnp.nan, y)
