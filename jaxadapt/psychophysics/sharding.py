"""Psychometric fits with their datasets split across devices.

Each dataset of a batched fit is independent of the others, so the batch
axis can be laid out over a mesh of devices and the same compiled program
run on each slice (:func:`map_sharded`); :func:`fit_sharded` is
:func:`jaxadapt.psychophysics.psychometric.fit` that way.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.sharding import AxisType, NamedSharding
from jax.sharding import PartitionSpec as P

from jaxadapt.psychophysics._inputs import _checked_inputs
from jaxadapt.psychophysics.psychometric import MAX_STEPS, _fit_batch

__all__ = ["map_sharded", "fit_sharded"]


@eqx.filter_jit
def _on_mesh(fn, sharding, args, options):
    return jax.lax.with_sharding_constraint(fn(*args, **options), sharding)


def map_sharded(fn, *args, mesh=None, **options):
    """Run a batched function with its batch axis split across devices.

    Parameters
    ----------
    fn : callable
        ``fn(*args, **options)`` maps arrays whose leading axis is a batch to
        outputs with the same leading axis, each batch element independently
        (e.g. a ``vmap``-ped fit of ``(B, L)`` counts). A module-level
        function, so that repeated calls reuse the compiled program.
    *args : pytrees of arrays
        Leading axis of the same length ``B`` on every leaf.
    mesh : jax.sharding.Mesh, optional
        Devices to use, its axes all along the batch (default: every device,
        one axis named ``"batch"``).
    **options
        Static keyword arguments of ``fn`` (Python numbers, strings).

    Returns
    -------
    pytree
        ``fn``'s output for the ``B`` elements.

    Notes
    -----
    The batch is padded to a multiple of the number of devices with copies
    of its last element, placed with ``NamedSharding(mesh, P(axes))``, and
    ``fn`` is compiled once for the mesh: XLA gives each device its slice of
    the batch (the only communication is the all-reduce of a ``while`` loop's
    stopping test). Each element is computed by the same operations as on
    one device; the results agree with the single-device ones to rounding
    (a different slice size can change how XLA vectorises the arithmetic).
    """
    if mesh is None:
        mesh = jax.make_mesh((jax.device_count(),), ("batch",), (AxisType.Auto,))
    leaves = jax.tree.leaves(args)
    B = leaves[0].shape[0]
    if any(leaf.shape[:1] != (B,) for leaf in leaves):
        raise ValueError(
            f"args: expected a common leading batch axis, got shapes {[a.shape for a in leaves]}"
        )
    index = jnp.minimum(jnp.arange(-(-B // mesh.size) * mesh.size), B - 1)
    sharding = NamedSharding(mesh, P(mesh.axis_names))
    padded = jax.device_put(jax.tree.map(lambda a: a[index], args), sharding)
    out = _on_mesh(fn, sharding, padded, options)
    return jax.tree.map(lambda a: a[:B], out)


def fit_sharded(levels, n_yes, n_total, *, mesh=None, guess=0.0, lapse=0.0, max_steps=MAX_STEPS):
    """:func:`fit` with the datasets split across the devices of ``mesh``.

    Takes the arguments of :func:`fit` (and ``mesh``, see
    :func:`map_sharded`) and returns the same :class:`Fit` (to rounding).

    Examples
    --------
    >>> x = jnp.linspace(-0.3, 0.3, 5)
    >>> fit_sharded(x, jnp.array([[2, 9, 15, 21, 28]] * 3), 30).pse.shape
    (3,)
    """
    levels, n_yes, n_total, guess, lapse = _checked_inputs(levels, n_yes, n_total, guess, lapse)
    batch, L = levels.shape[:-1], levels.shape[-1]
    flat = [a.reshape(-1, L) for a in (levels, n_yes, n_total)]
    rates = [jax.tree.map(lambda r: r.reshape(-1), r) for r in (guess, lapse)]
    out = map_sharded(_fit_batch, *flat, *rates, mesh=mesh, max_steps=max_steps)
    return jax.tree.map(lambda a: a.reshape(batch), out)
