"""Input checks and dtype handling shared by the operators.

Shapes, ranks and dtypes are checked before tracing and raise
``ValueError`` naming the argument, what was expected and what came;
values (finite, non-negative luminance, positive durations) are checked
inside ``jit`` with ``equinox.error_if``, which raises
``equinox.EquinoxRuntimeError`` with the same kind of message.
"""

import equinox as eqx
import jax
import jax.numpy as jnp


def check_frames(frames, rank, name="frames"):
    """Check frames of linear RGB in cd/m2 and return their value guard.

    The shape must be ``(T, H, W, 3)`` (rank 4) or ``(H, W, 3)`` (rank 3)
    and the dtype floating point (``ValueError`` at once otherwise); the
    values must be finite and non-negative. That value check is returned as
    ``guard``, an exact zero scalar of the frames' dtype that raises when it
    is computed on bad frames: add it to the operator's scalar state, which
    every result depends on. Raising on the frames themselves
    (``eqx.error_if(frames, ...)``) routes them through a conditional, and XLA
    then copies the whole sequence: on a GPU that copy cost more than the
    operator's own pixel work. The check counts the bad pixels of each frame
    by a floating-point sum over ``(H, W)``, the form of the operators'
    per-frame goal reductions, so that XLA reads the frames once for both.
    """
    if (
        frames.ndim != rank
        or frames.shape[-1] != 3
        or not jnp.issubdtype(frames.dtype, jnp.floating)
    ):
        expected = "(T, H, W, 3)" if rank == 4 else "(H, W, 3)"
        raise ValueError(
            f"{name}: expected floating-point linear RGB of shape {expected} in cd/m2, "
            f"got {frames.dtype} of shape {frames.shape}"
        )
    ok = [jnp.isfinite(frames[..., c]) & (frames[..., c] >= 0) for c in range(3)]
    n_bad = jnp.sum(jnp.where(ok[0] & ok[1] & ok[2], 0.0, 1.0), axis=(-2, -1), dtype=frames.dtype)
    bad = jnp.any(n_bad > 0)
    zero = jnp.zeros((), frames.dtype)
    return eqx.error_if(zero, bad, f"{name}: expected finite, non-negative luminance (cd/m2)")


def check_dt(dt, T):
    """Frame durations (s): a scalar or ``(T,)``, positive; returned as ``(T,)``."""
    if dt.ndim > 1 or (dt.ndim == 1 and dt.shape[0] != T):
        raise ValueError(f"dt: expected a scalar or shape ({T},) in seconds, got shape {dt.shape}")
    dt = jnp.broadcast_to(dt, (T,))
    return eqx.error_if(dt, ~jnp.all(dt > 0), "dt: expected positive frame durations (s)")


def as_dtype(tree, dtype):
    """Cast the floating-point arrays of a pytree (params, state) to ``dtype``,
    so that an operator computes in its input's precision."""

    def cast(x):
        return x.astype(dtype) if eqx.is_array(x) and jnp.issubdtype(x.dtype, jnp.floating) else x

    return jax.tree.map(cast, tree)
