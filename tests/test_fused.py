"""The fused per-pixel map, run in Pallas' interpreter, against the map it fuses."""

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxadapt import fused
from jaxadapt.operators import pattanaik2000 as op
from jaxadapt.operators.checks import as_dtype


def _frames(T, H, W, seed=0):
    rng = np.random.default_rng(seed)
    frames = 10 ** rng.uniform(-3, 5, (T, H, W, 3))
    frames[0, 0, 0] = 0.0  # a black pixel
    frames[-1, -1, -1, 1] = 0.0  # a zero channel
    return jnp.asarray(frames)


def _observers(params, frames):
    """Per-frame observers of a run over ``frames`` (fields (T,) or (T, H, W))."""
    gaze = jnp.zeros((frames.shape[0], 2), frames.dtype)
    G_rod, G_cone = jax.vmap(op.frame_goals, (None, 0, 0))(params, frames, gaze)
    state = op.static_state(params, G_rod[0], G_cone[0])
    states, _ = op.advance_sequence(params, state, G_rod, G_cone, jnp.full(G_rod.shape[:1], 0.1))
    return jax.vmap(op.observer, (None, 0))(params, states)


def _tone_map(frames, args):
    return jax.vmap(op.tone_map, (None, 0, 0))(*args, frames)


def _fused(frames, args):
    def planes(args, channels):
        return op.tone_map_planes(*args, channels)

    return fused.map_pixels(planes, frames, args, default=_tone_map, interpret=True)


# Both dtypes, and both kinds of argument: per frame (a global background)
# and per pixel (a local one).
@pytest.mark.slow
@pytest.mark.parametrize(
    ("dtype", "background"), [(jnp.float32, "global"), (jnp.float64, "gaussian")]
)
def test_kernel_equals_the_map_it_fuses(dtype, background):
    # 3 x 23 x 29 pixels: the last block of each frame is partly outside it.
    params, frames = as_dtype((op.Params(background=background), _frames(3, 23, 29)), dtype)
    args = (params, _observers(params, frames))
    expected = _tone_map(frames, args)
    got = _fused(frames, args)
    assert got.dtype == dtype and got.shape == frames.shape
    # exp(e ln c + s) turns an absolute rounding error in its argument (|s|
    # is up to about 30) into a relative one: a few ulps of float32 become 1e-6.
    tol = 1e-5 if dtype == jnp.float32 else 1e-12
    np.testing.assert_allclose(got, expected, rtol=tol, atol=tol)
    assert got[0, 0, 0].tolist() == [0.0, 0.0, 0.0]


def _brightening(T=3, H=4, W=5):
    """Frames that brighten 100-fold after the first: from the third on,
    the display depends on the cone time constant (frame ``k`` is seen with
    the state after frames ``0 .. k-1``, and the first state is adapted to
    the first frame)."""
    return _frames(T, H, W).at[1:].multiply(100.0)


@pytest.mark.slow
def test_kernel_derivative_is_that_of_the_map():
    # Frames that brighten: with two frames of one level the display would
    # not depend on t0 at all, and the derivative compared would be
    # rounding, 2e-15.
    frames = _brightening()

    def loss(t0, fn):
        params = op.Params(t0_cone=t0)
        return jnp.sum(fn(frames, (params, _observers(params, frames))) ** 2)

    got = float(jax.jit(jax.grad(loss), static_argnums=1)(0.08, _fused))
    assert got == pytest.approx(
        float(jax.jit(jax.grad(loss), static_argnums=1)(0.08, _tone_map)), rel=1e-12
    )
    h, value = 1e-6, jax.jit(loss, static_argnums=1)
    assert got == pytest.approx(
        float(value(0.08 + h, _tone_map) - value(0.08 - h, _tone_map)) / (2 * h), rel=1e-6
    )


@pytest.mark.slow
def test_kernel_under_vmap_over_parameters():
    frames = _brightening()

    def both(t0):
        params = op.Params(t0_cone=t0)
        args = (params, _observers(params, frames))
        return _fused(frames, args), _tone_map(frames, args)

    got, expected = jax.jit(jax.vmap(both))(jnp.array([0.05, 0.08, 0.2]))
    np.testing.assert_allclose(got, expected, rtol=1e-13)
    assert float(jnp.max(jnp.abs(got[0] - got[2]))) > 1e-3  # the time constant matters


@pytest.mark.parametrize("shape", [(3,), (2, 5, 4)])
def test_a_leaf_of_another_shape_is_refused(shape):
    frames = _frames(2, 4, 5)
    expected = r"args: expected leaves of shape \(\), \(2,\) or \(2, H, W\), got "
    with pytest.raises(ValueError, match=expected + re.escape(str(shape))):
        _fused(frames, jnp.ones(shape))
