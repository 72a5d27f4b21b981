"""The fitted fields and their bounds: which fields can be fitted, and the
map between each one and the unconstrained value ``u`` the optimiser works
on (the table in the notes of :func:`~jaxadapt.fitting.fit`).

Every field is positive unless ``bounds`` says otherwise (time constants,
bleaching constants and semi-saturations are). Working in ``log p`` also
puts parameters of very different scales (``t0 = 0.08`` s, ``tau = 400``
s) on one footing for the optimiser.
"""

import dataclasses
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

#: Default bounds of a fitted field: positive.
POSITIVE = (0.0, math.inf)


class _Free(NamedTuple):
    """One fitted field and its bounds (static)."""

    name: str
    low: float
    high: float


def _to_natural(u, free):
    """The parameter at the free value ``u``."""
    low, high = free.low, free.high
    if math.isinf(low) and math.isinf(high):
        return u
    if math.isinf(high):
        return low + jnp.exp(u)
    if math.isinf(low):
        return high - jnp.exp(u)
    return low + (high - low) * jax.nn.sigmoid(u)


def _derivative(u, free):
    """``dp/du`` of :func:`_to_natural`."""
    low, high = free.low, free.high
    if math.isinf(low) and math.isinf(high):
        return jnp.ones_like(u)
    if math.isinf(high):
        return jnp.exp(u)
    if math.isinf(low):
        return -jnp.exp(u)
    s = jax.nn.sigmoid(u)
    return (high - low) * s * (1.0 - s)


def _to_free(p, free):
    """The free value of the parameter ``p``: the inverse of :func:`_to_natural`."""
    low, high = free.low, free.high
    if math.isinf(low) and math.isinf(high):
        return p
    if math.isinf(high):
        return jnp.log(p - low)
    if math.isinf(low):
        return jnp.log(high - p)
    x = (p - low) / (high - low)
    return jnp.log(x) - jnp.log1p(-x)


def _replace(params, spec, values):
    """``params`` with the fields of ``spec`` set to ``values`` (by name)."""
    fields = [f.name for f in spec]
    return eqx.tree_at(
        lambda p: [getattr(p, n) for n in fields], params, [values[n] for n in fields]
    )


def _numeric_fields(params):
    """Names of the fields of ``params`` that can be fitted (floating arrays)."""
    if not dataclasses.is_dataclass(params):
        raise ValueError(
            f"params: expected a parameter module (an equinox.Module such as an operator's "
            f"Params), got {type(params).__name__}"
        )
    return tuple(
        f.name
        for f in dataclasses.fields(params)
        if not f.metadata.get("static", False) and eqx.is_inexact_array(getattr(params, f.name))
    )


def _not_fittable(params, name):
    """Why the field ``name`` of ``params`` cannot be fitted, or ``""`` if
    it is not a field."""
    field = next((f for f in dataclasses.fields(params) if f.name == name), None)
    value = getattr(params, name, None)
    if field is None:
        return ""
    if not eqx.is_array_like(value):  # a field, though not a number: say so
        return f"holds {value!r}, not a number"
    if field.metadata.get("static", False):
        why = "is a static field"
    elif isinstance(value, jax.Array | np.ndarray | np.generic):
        why = f"holds {value.dtype} values"
    else:
        why = f"holds a Python {type(value).__name__}"
    return (
        f"{why}; a fitted field must hold a JAX floating-point array "
        "(e.g. eqx.field(converter=jnp.asarray) and 1.0, not 1)"
    )


def _spec(params, names, bounds):
    """Validate ``names`` and ``bounds``; return the static spec, one
    :class:`_Free` per name."""
    names = _names(params, names)
    bounds = dict(bounds or {})
    extra = [n for n in bounds if n not in names]
    if extra:
        raise ValueError(f"bounds: {extra} are not among the fitted names {names}")
    return tuple(_free(params, name, bounds.get(name, POSITIVE)) for name in names)


def _names(params, names):
    """``names`` (one name or a sequence) as a tuple of fittable fields of
    ``params``, each once."""
    valid = _numeric_fields(params)
    names = (names,) if isinstance(names, str) else tuple(names)
    if not names:
        raise ValueError(f"names: expected at least one of {valid}, got none")
    unknown = [n for n in names if n not in valid]
    for name in unknown:
        why = _not_fittable(params, name)
        if why:
            raise ValueError(
                f"names: {name!r} of {type(params).__name__} {why}; valid names: {', '.join(valid)}"
            )
    if unknown:
        raise ValueError(
            f"names: {', '.join(map(repr, unknown))} "
            f"{'is not a parameter' if len(unknown) == 1 else 'are not parameters'} "
            f"of {type(params).__name__}; valid names: {', '.join(valid)}"
        )
    if len(set(names)) != len(names):
        raise ValueError(f"names: expected each parameter once, got {names}")
    return names


def _free(params, name, b):
    """The :class:`_Free` of the field ``name`` with bounds ``b`` (``(low,
    high)`` or ``None``), checked to contain the start (where it is known)."""
    if b is not None and not (isinstance(b, tuple | list) and len(b) == 2):
        raise ValueError(f"bounds[{name!r}]: expected (low, high) or None, got {b!r}")
    try:
        low, high = (-math.inf, math.inf) if b is None else (float(b[0]), float(b[1]))
    except (TypeError, ValueError):
        raise ValueError(f"bounds[{name!r}]: expected (low, high) or None, got {b!r}") from None
    if not low < high or math.isnan(low) or math.isnan(high):
        raise ValueError(f"bounds[{name!r}]: expected (low, high) with low < high, got {b!r}")
    value = getattr(params, name)
    if not isinstance(value, jax.core.Tracer):
        v = np.asarray(value, dtype=float)
        if not (np.all(np.isfinite(v)) and np.all(v > low) and np.all(v < high)):
            raise ValueError(
                f"params.{name}: the start must lie strictly inside its bounds "
                f"({low}, {high}), got {v.tolist()}"
            )
    return _Free(name, low, high)
