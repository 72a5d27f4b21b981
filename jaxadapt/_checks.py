"""Checks and converters of arguments, shared by the whole library.

Each check raises ``ValueError`` with one line that names the argument,
what was expected and what came, so that the command line can print it as
it is. Values that are traced (inside ``jit`` or ``vmap``) are not known
and are not checked here; the operators check those inside their programs
(:mod:`jaxadapt.operators.checks`).
"""

import operator

import jax
import jax.numpy as jnp
import numpy as np


def float_array(x):
    """``x`` as a JAX array of the default floating-point dtype: the
    converter of the numeric fields of the operators' ``Params``, so that a
    Python number and an array of parameter sets are stored alike."""
    return jnp.asarray(x, dtype=jnp.result_type(float))


def check_value(name, value, ok, expected):
    """Raise ``ValueError`` naming ``name`` unless ``ok(value)`` holds everywhere.

    Values that are traced (inside ``jit`` or ``vmap``) are not checked: a
    traced value is not known before tracing.

    Parameters
    ----------
    name : str
        Argument name, for the message.
    value : number or array
    ok : callable
        Predicate on a NumPy array, elementwise.
    expected : str
        What was expected, for the message.
    """
    if isinstance(value, jax.core.Tracer):
        return
    if not np.all(ok(np.asarray(value))):
        raise ValueError(f"{name}: expected {expected}, got {value!r}")


def check_whole(name, value, least=0, unit=""):
    """``value`` as an ``int``, after checking that it is a whole number
    (anything with ``__index__``: Python, NumPy and JAX integers, not a bool
    nor a float) of at least ``least``; ``ValueError`` naming ``name``,
    with ``unit`` (e.g. ``"pixels"``) in the message, otherwise."""
    try:
        whole = not isinstance(value, bool) and operator.index(value) >= least
    except TypeError:
        whole = False
    if not whole:
        of = f" of {unit}" if unit else ""
        raise ValueError(f"{name}: expected a whole number{of} >= {least}, got {value!r}")
    return operator.index(value)


class IncompleteInputWarning(UserWarning):
    """An input was read only in part (a video file cut short): what could
    be read was used, and the command line exits with status 3 to say so."""
