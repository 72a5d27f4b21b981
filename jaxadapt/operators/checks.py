"""Input checks and dtype handling shared by the operators.

Shapes, ranks and dtypes are checked before tracing and raise
``ValueError`` naming the argument, what was expected and what came;
values (finite, non-negative luminance, positive durations) are checked
inside the operators' compiled programs (:func:`value_check`): called as
they are, the operators raise ``ValueError`` after the call; inside the
caller's ``jit`` or ``vmap``, ``equinox.error_if`` raises
``equinox.EquinoxRuntimeError`` with the same message.
"""

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt._checks import check_value
from jaxadapt.background import LUMINANCE_CEILING

__all__ = [
    "check_frames",
    "saturate",
    "frames_messages",
    "frames_and_dt_messages",
    "check_frames_and_dt",
    "is_traced",
    "error_message",
    "plain_errors",
    "value_check",
    "raise_verdict",
    "check_rgb",
    "check_one_parameter_set",
    "check_state",
    "as_dtype",
    "check_fields",
    "check_adaptation",
]


def check_frames(frames, rank, name="frames", on_host=False):
    """Check frames of linear RGB in cd/m2; return their value check
    ``(guard, verdict)`` (:func:`value_check`).

    The shape must be ``(T, H, W, 3)`` (rank 4) or ``(H, W, 3)`` (rank 3)
    with no axis of length 0, and the dtype floating point (``ValueError``
    at once otherwise); the values must be finite and non-negative. The
    guard is an exact zero scalar of the frames' dtype: add it to the
    operator's scalar state, which every result depends on. (Raising on the
    frames themselves would route them through a conditional, and XLA would
    copy the whole sequence.) The bad pixels are counted by a sum over
    ``(H, W)``, the form of the operators' goal reductions, so that XLA
    reads the frames once for both.
    """
    dtype = _frames_dtype(frames, rank, name)
    return value_check(dtype, [_bad_frames(frames)], frames_messages(name), on_host)


def saturate(rgb):
    """Linear RGB ``(..., 3)`` (cd/m2), or any of its channels or
    luminances, with every value above
    :data:`~jaxadapt.background.LUMINANCE_CEILING` clipped to it: what the
    operators see of a frame.

    Frames may hold any finite value, up to float32's largest (3.4e38), and
    the models saturate far below the ceiling; above it, the luminance
    weights alone (a sum of three products) can overflow, and so can the
    operators' ratios, which XLA may reassociate (``(x / y) / L`` into ``x
    / (y L)``). Values at or below the ceiling are returned exactly. A
    clip per channel, as a sensor saturates, costs one operation a value;
    scaling the pixel to keep its colour would cost a division a pixel in
    every frame, for colours that only frames beyond any scene's luminance
    hold.
    """
    rgb = jnp.asarray(rgb)
    return jnp.minimum(rgb, jnp.asarray(LUMINANCE_CEILING, rgb.dtype))


def frames_messages(name="frames"):
    """The messages of :func:`check_frames`, one per condition."""
    return (f"{name}: expected finite, non-negative luminance (cd/m2)",)


def frames_and_dt_messages(name="frames"):
    """The messages of :func:`check_frames_and_dt`, one per condition."""
    return (*frames_messages(name), "dt: expected positive frame durations (s)")


def check_frames_and_dt(frames, dt, rank, name="frames", on_host=False):
    """:func:`check_frames`, and the frame durations ``dt`` (s): a scalar or
    one per frame, positive. Returns ``(guard, dt, verdict)``, ``dt`` of
    shape ``(T,)`` (``(1,)`` for a single frame, rank 3).

    Both value checks are one conditional on ``guard`` (or one verdict).
    Each conditional is a copy of its predicate to the host and a wait for
    it, and in a fit through ``run`` it is taken at every solver step.
    """
    dtype = _frames_dtype(frames, rank, name)
    T = frames.shape[0] if rank == 4 else 1
    if dt.ndim > 1 or (dt.ndim == 1 and dt.shape[0] != T):
        raise ValueError(f"dt: expected a scalar or shape ({T},) in seconds, got shape {dt.shape}")
    dt = jnp.broadcast_to(dt, (T,))
    bad = [_bad_frames(frames), ~jnp.all(dt > 0)]
    guard, verdict = value_check(dtype, bad, frames_and_dt_messages(name), on_host)
    return guard, dt, verdict


def is_traced(*trees):
    """Whether a leaf of ``trees`` is a tracer: the caller is inside
    ``jit``, ``vmap`` or a derivative, where no value can reach Python."""
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(trees))


def error_message(error):
    """The message of an ``equinox`` value check's ``EquinoxRuntimeError``,
    whose text starts with the stack outside and inside ``jit``: the text
    after its class name (the first line of any other error)."""
    lines = str(error).strip().splitlines()
    for line in lines:
        _, mark, message = line.partition("EquinoxRuntimeError: ")
        if mark:
            return message
    return lines[0] if lines else type(error).__name__


def plain_errors(fn):
    """``fn``, raising its value checks' errors (``equinox.error_if``) as a
    ``ValueError`` whose text is the message, where it is called outside
    ``jit``; inside a ``jit``, ``vmap`` or a derivative (:func:`is_traced`)
    ``fn`` is called as it is. The result is waited for: the check raises
    when the computation reaches it."""

    @functools.wraps(fn)
    def checked(*args, **kwargs):
        if is_traced(args, kwargs):
            return fn(*args, **kwargs)
        try:
            return jax.block_until_ready(fn(*args, **kwargs))
        except eqx.EquinoxRuntimeError as error:
            raise ValueError(error_message(error)) from None

    return checked


def value_check(dtype, bad, messages, on_host):
    """The check of the conditions ``bad`` (boolean scalars, True where
    ``messages[i]`` applies), inside compiled code: ``(guard, verdict)``.

    With ``on_host`` False, ``guard`` is an exact zero of ``dtype`` that
    raises ``equinox.EquinoxRuntimeError`` with the first message that
    applies when it is computed, and ``verdict`` is None. With ``on_host``
    True, ``guard`` is a plain zero and ``verdict`` an int32 scalar, 0 if
    no condition holds, else 1 plus the index of the first that does, for
    :func:`raise_verdict` to raise after the call. An operator called
    outside ``jit`` (:func:`is_traced`) checks on the host: its program
    then holds no host callback, which JAX's persistent compilation cache
    cannot keep, and its error is a ``ValueError`` whose text is the
    message.
    """
    zero = jnp.zeros((), dtype)
    which = jnp.argmax(jnp.stack(bad)).astype(jnp.int32)
    if on_host:
        return zero, jnp.where(jnp.any(jnp.stack(bad)), which + 1, 0)
    return eqx.branched_error_if(zero, jnp.any(jnp.stack(bad)), which, messages), None


def raise_verdict(verdict, messages):
    """Raise ``ValueError(messages[verdict - 1])`` for a verdict of
    :func:`value_check` other than 0 (it waits for the computation that
    gives it); nothing for 0 or None."""
    if verdict is not None and (code := int(verdict)):
        raise ValueError(messages[code - 1])


def _computable(dtype):
    """Whether the operators compute in ``dtype``: float32 or float64.

    Not float16 (nor bfloat16): it holds no luminance above 65,504 cd/m2,
    and the 2000 operator's powers and semi-saturations lose so much
    precision in it that display values come out grossly wrong, with no
    error.
    """
    return jnp.issubdtype(dtype, jnp.floating) and jnp.finfo(dtype).bits >= 32


def _frames_dtype(frames, rank, name):
    """The frames' dtype, after checking their rank, channels and dtype."""
    if (
        frames.ndim != rank
        or frames.shape[-1] != 3
        or 0 in frames.shape
        or not _computable(frames.dtype)
    ):
        expected = "(T, H, W, 3)" if rank == 4 else "(H, W, 3)"
        raise ValueError(
            f"{name}: expected float32 or float64 linear RGB of shape {expected} in cd/m2 "
            f"(no axis of length 0), got {frames.dtype} of shape {frames.shape}"
        )
    return frames.dtype


def check_rgb(rgb, name, expected="(..., 3)", min_ndim=1):
    """``rgb`` as an array, after checking that it is floating-point linear
    RGB of shape ``expected`` (at least ``min_ndim`` axes, 3 channels last);
    ``ValueError`` naming it otherwise. The per-pixel maps compute in their
    input's dtype, so integer input would give integer nonsense."""
    rgb = jnp.asarray(rgb)
    if rgb.ndim < min_ndim or rgb.shape[-1:] != (3,) or not _computable(rgb.dtype):
        raise ValueError(
            f"{name}: expected float32 or float64 linear RGB of shape {expected} in cd/m2, "
            f"got {rgb.dtype} of shape {rgb.shape}"
        )
    return rgb


def _bad_frames(frames):
    """Whether any pixel is not finite or negative (see :func:`check_frames`)."""
    ok = [jnp.isfinite(frames[..., c]) & (frames[..., c] >= 0) for c in range(3)]
    n_bad = jnp.sum(jnp.where(ok[0] & ok[1] & ok[2], 0.0, 1.0), axis=(-2, -1), dtype=frames.dtype)
    return jnp.any(n_bad > 0)


def check_one_parameter_set(params, shapes=None):
    """Refuse ``params`` whose numeric fields are not one parameter set's:
    scalars, or the shape ``shapes[name]`` gives a field (``ValueError``
    naming the field). Inside ``jax.vmap`` a batch of parameter sets has
    these shapes; passed to ``run`` as it is, ``t0_cone`` of shape ``(T,)``
    would silently give one time constant per frame, and other shapes
    JAX's broadcasting errors, naming no field."""
    shapes = shapes or {}
    for field in dataclasses.fields(params):
        value = getattr(params, field.name)
        shape = shapes.get(field.name, ())
        if eqx.is_array(value) and value.shape != shape:
            raise ValueError(
                f"{field.name}: expected shape {shape} in one parameter set (for several, "
                f"jax.vmap over a batch of Params), got shape {value.shape}"
            )


def check_state(state, kind, operator):
    """Refuse a ``state`` that is not an operator's ``kind`` of state (its
    ``State``, from its ``init``), which would otherwise fail with JAX's
    errors from inside the operator."""
    if not isinstance(state, kind):
        raise ValueError(
            f"state: expected a {operator}.State (from {operator}.init), got {type(state).__name__}"
        )


def as_dtype(tree, dtype):
    """Cast the floating-point arrays of a pytree (params, state) to ``dtype``,
    so that an operator computes in its input's precision."""

    def cast(x):
        return x.astype(dtype) if eqx.is_array(x) and jnp.issubdtype(x.dtype, jnp.floating) else x

    return jax.tree.map(cast, tree)


def check_fields(params, positive=(), non_negative=()):
    """Raise ``ValueError`` naming the first field of ``params`` among
    ``positive`` that is not positive and finite, or among ``non_negative``
    that is negative or not finite (every element; traced values are not
    checked, see :func:`jaxadapt._checks.check_value`). For an operator's
    ``Params.__check_init__``: a negative time constant or a NaN rate runs,
    and its results are wrong without a word."""
    for name in positive:
        value = getattr(params, name)
        check_value(name, value, lambda v: np.isfinite(v) & (v > 0), "a positive, finite number")
    for name in non_negative:
        value = getattr(params, name)
        check_value(name, value, lambda v: np.isfinite(v) & (v >= 0), "a finite number >= 0")


def check_adaptation(adaptation):
    """An ``init``'s ``adaptation`` luminance (cd/m2), when given: finite and
    ``>= 0``, ``ValueError`` naming it otherwise (NaN would fill the state
    with NaN, and every frame after it)."""
    if adaptation is not None:
        check_value(
            "adaptation",
            adaptation,
            lambda v: np.isfinite(v) & (v >= 0),
            "a finite luminance >= 0 (cd/m2)",
        )
