"""Input handling of the psychometric fits: shapes, dtypes, rates and the
value checks, and the ``vmap`` over the flattened datasets.

Internal to :mod:`jaxadapt.psychophysics.psychometric`,
:mod:`~jaxadapt.psychophysics.bootstrap` and
:mod:`~jaxadapt.psychophysics.sharding`.
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxadapt.psychophysics._likelihood import _rate


def _inputs(levels, n_yes, n_total, guess, lapse):
    """Arrays in one float dtype, broadcast to ``(..., L)``; rates parsed and
    broadcast to the batch shape ``(...)``."""
    names = ("levels", "n_yes", "n_total")
    arrays = [jnp.asarray(a) for a in (levels, n_yes, n_total)]
    try:
        shape = jnp.broadcast_shapes(*(a.shape for a in arrays))
    except ValueError:
        got = ", ".join(f"{n} {a.shape}" for n, a in zip(names, arrays, strict=True))
        raise ValueError(
            f"levels, n_yes, n_total: expected broadcastable shapes, got {got}"
        ) from None
    if not shape or shape[-1] == 0:
        raise ValueError(
            "levels: expected an array with levels on the last axis, got "
            + ("a scalar" if not shape else f"shape {shape}, no levels")
        )
    # The arrays, not their dtypes: a Python number keeps JAX's weak type and
    # follows the arrays, so that ``n_total=30.0`` leaves float32 data a
    # float32 fit.
    dtype = jnp.result_type(*arrays, float)
    levels, n_yes, n_total = (jnp.broadcast_to(a.astype(dtype), shape) for a in arrays)
    guess, lapse = (
        _batch_rate(v, n, shape[:-1], dtype) for v, n in ((guess, "guess"), (lapse, "lapse"))
    )
    return levels, n_yes, n_total, guess, lapse


def _batch_rate(value, name, batch, dtype):
    """:func:`_rate` of ``value`` in ``dtype``, broadcast to the batch shape."""
    rate = _rate(value, name)
    try:
        fits = jnp.broadcast_shapes(rate.low.shape, batch) == batch
    except ValueError:
        fits = False
    if not fits:
        raise ValueError(
            f"{name}: expected a rate of the batch shape {batch} or one that "
            f"broadcasts to it, got shape {rate.low.shape}"
        )
    return jax.tree.map(lambda r: jnp.broadcast_to(r.astype(dtype), batch), rate)


def _check(levels, n_yes, n_total, guess, lapse):
    """Value checks inside jit (finite levels, valid counts and rates)."""
    levels = eqx.error_if(
        levels, ~jnp.all(jnp.isfinite(levels)), "levels: expected finite log10 levels"
    )
    bad = ~jnp.all(jnp.isfinite(n_total) & (n_total >= 0) & (n_yes >= 0) & (n_yes <= n_total))
    n_yes = eqx.error_if(n_yes, bad, "n_yes, n_total: expected finite 0 <= n_yes <= n_total")
    bad = jnp.any((guess.low < 0) | (lapse.low < 0) | (guess.high + lapse.high >= 1))
    guess = eqx.error_if(guess, bad, "guess, lapse: expected rates >= 0 with guess + lapse < 1")
    return levels, n_yes, n_total, guess, lapse


def _over_datasets(fn, levels, n_yes, n_total, guess, lapse, *batched):
    """``vmap`` a one-dataset function over the flattened batch ``(...)`` and
    restore that batch shape on its outputs."""
    batch, L = levels.shape[:-1], levels.shape[-1]
    flat = [a.reshape(-1, L) for a in (levels, n_yes, n_total)]
    flat += [jax.tree.map(lambda r: r.reshape(-1), r) for r in (guess, lapse)]
    flat += [jax.tree.map(lambda b: b.reshape((-1,) + b.shape[len(batch) :]), b) for b in batched]
    out = jax.vmap(fn)(*flat)
    return jax.tree.map(lambda a: a.reshape(batch + a.shape[1:]), out)


#: The value checks as a program of their own, before the fit's: a program
#: that raises from inside does so through a host callback, and JAX's
#: persistent compilation cache keeps no such program
#: (:func:`jaxadapt.runtime.cache_compilations`).
_checked = eqx.filter_jit(_check)


def _checked_inputs(levels, n_yes, n_total, guess, lapse):
    """:func:`_inputs`, then their values :func:`_checked`."""
    return _checked(*_inputs(levels, n_yes, n_total, guess, lapse))
