"""Per-pixel maps of frames in one pass over memory on a GPU (Pallas).

A tone-mapping operator's pixel map computes a chain of functions of a
pixel's luminance once and then uses it for each of the pixel's three
channels. XLA's GPU backend computes one output element per thread, so it
either repeats the chain for each channel or (what it chooses) splits the
map in two kernels, writing the chain's results to memory and reading them
and the frames back. :func:`map_pixels` runs such a map as a Pallas kernel
in which each program loads a block of pixels as three channel vectors,
computes the chain once per pixel and stores the three results, so the
frames are read and written once. On other platforms, and for frames that
are not float32, it runs the map given for them (XLA's CPU backend fuses
the broadcasting form well). Float64 frames stay with XLA on a GPU too:
Triton's lowering can give a weakly typed literal of a 64-bit kernel 32
bits (``jnp.log(10.0)`` in
:func:`~jaxadapt.physiology.response.response_slope`), and a GPU's float64
is for checking, not for speed.
"""

import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl

__all__ = ["BLOCK", "map_pixels", "stored", "skipped_unless"]

#: Pixels per program of the kernel: a power of two, as Triton requires;
#: the fastest of the sizes tried.
BLOCK = 512


def map_pixels(planes_fn, frames, args, *, default, interpret=False):
    """Apply a per-pixel map to ``frames (T, H, W, C)``, fused into one pass on a GPU.

    Parameters
    ----------
    planes_fn : callable
        ``planes_fn(args_t, channels) -> channels``: the map written on
        channel planes (lists of ``C`` arrays of one shape), elementwise.
        ``args_t`` is ``args`` with each leaf taken at one frame.
    frames : array, shape (T, H, W, C)
    args : pytree of arrays
        Leaves of shape ``()`` (the same for every frame), ``(T,)`` (one
        value per frame) or ``(T, H, W)`` (one per pixel).
    default : callable
        ``default(frames, args) -> (T, H, W, C)``, the same map for
        platforms other than CUDA and frames other than float32, and the
        reference of the derivatives (the kernel's derivative is that of
        ``default``).
    interpret : bool
        Run the kernel in Pallas' interpreter, on any platform (for tests).

    Returns
    -------
    array, shape (T, H, W, C)
    """
    kernel = jax.custom_jvp(lambda frames, args: _pallas_map(planes_fn, frames, args, interpret))
    kernel.defjvp(lambda primals, tangents: jax.jvp(default, primals, tangents))
    if interpret:
        return kernel(frames, args)
    if frames.dtype != jnp.float32:
        return default(frames, args)
    return jax.lax.platform_dependent(frames, args, cuda=kernel, default=default)


def _leaf_layout(leaf, T, H, W):
    """A leaf as a 2-D array indexed by frame, and whether it varies per pixel."""
    if leaf.ndim == 0:
        return leaf.reshape(1, 1), False
    if leaf.shape == (T,):
        return leaf.reshape(T, 1), False
    if leaf.shape == (T, H, W):
        return leaf.reshape(T, H * W), True
    raise ValueError(f"args: expected leaves of shape (), ({T},) or ({T}, H, W), got {leaf.shape}")


def _pallas_map(planes_fn, frames, args, interpret):
    T, H, W, C = frames.shape
    N = H * W
    leaves, treedef = jax.tree.flatten(args)
    layouts = [_leaf_layout(jnp.asarray(leaf), T, H, W) for leaf in leaves]
    arrays, per_pixel = [a for a, _ in layouts], [p for _, p in layouts]
    wide = jnp.dtype(frames.dtype).itemsize > 4

    def kernel(x_ref, *refs):
        *arg_refs, out_ref = refs
        t = pl.program_id(0)
        # The last block's surplus lanes repeat the last pixel: they compute
        # and store the same values as its own lane, so no mask is needed.
        pixel = jnp.minimum(pl.program_id(1) * BLOCK + jnp.arange(BLOCK), N - 1)

        def leaf(ref, varies):
            return ref[t, pixel] if varies else ref[t if ref.shape[0] > 1 else 0, 0]

        values = [leaf(ref, varies) for ref, varies in zip(arg_refs, per_pixel, strict=True)]
        planes = [x_ref[t, C * pixel + c] for c in range(C)]
        # Triton's lowering cannot mix float widths, which the literals of
        # planes_fn (weakly typed, 64-bit when x64 is on) would bring to
        # 32-bit frames: trace them at the frames' width.
        with jax.enable_x64(wide):
            out = planes_fn(jax.tree.unflatten(treedef, values), planes)
        for c, plane in enumerate(out):
            out_ref[t, C * pixel + c] = plane.astype(out_ref.dtype)

    flat = frames.reshape(T, N * C)
    out = pl.pallas_call(
        kernel,
        out_shape=jax.ShapeDtypeStruct(flat.shape, frames.dtype),
        grid=(T, pl.cdiv(N, BLOCK)),
        interpret=interpret,
    )(flat, *arrays)
    return out.reshape(frames.shape)


def stored(fn, when=None):
    """``fn()`` (a pytree of arrays), written to memory on the CPU before
    the loops that read it run.

    XLA's CPU backend fuses a producer into each loop that reads it, and
    evaluates it again there: a colour matrix's three outputs each redo
    the chain behind its inputs (the powers of Jacobs et al. 2015, Eq 11),
    a blur's second pass redoes its first pass once per tap. Computed
    under a conditional, whose result that backend stores, it is
    evaluated once. ``when`` (a traced bool; by default true, but not a
    constant XLA could fold the conditional away on) false gives zeros
    instead, for a caller that discards them. Other platforms compute
    ``fn()`` as it is: a GPU's conditional waits for its predicate.
    """
    if when is None:
        when = jax.lax.optimization_barrier(jnp.bool_(True))
    zeros = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), jax.eval_shape(fn))
    return skipped_unless(when, fn, lambda: zeros)


def skipped_unless(needed, fn, otherwise):
    """``fn()`` where ``needed`` (a traced bool) holds, else ``otherwise()``,
    both pytrees of one structure; ``fn()`` must equal ``otherwise()`` when
    ``needed`` is false (or the caller discards it then, as :func:`stored`'s do).

    On the CPU a conditional, so that work that rarely changes anything
    (the gathers that move the retinal maps, when the gaze has not moved a
    whole pixel) is skipped, and its result is stored once rather than
    evaluated again in every loop that reads it. Other platforms compute
    ``fn()``: a GPU's conditional waits for its predicate.
    """
    return jax.lax.platform_dependent(cpu=lambda: jax.lax.cond(needed, fn, otherwise), default=fn)
