"""The 2015 renderer's fused step against the unfused computation it replaced.

``reference_frame`` below is the operator's frame as it was computed before
the step was rendered in strips of channel planes (commit 223785f): every
stage on whole ``(H, W, 3)`` frames, one after another, with the blurs of
:func:`jaxadapt.spatial.gaussian_ladder` (the acuity loss's, tested against
SciPy's in test_goal_color_display.py) and :func:`separable_filter` and
the dithering of :func:`jaxadapt.display.dither`. The operator must give
its frames and states within :data:`TOLERANCE` (docs/choices.md, "The 2015
renderer's fused step"), for every effect switched on alone and all
together, and a change the size of a small parameter's must not pass.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxadapt import display
from jaxadapt.color import LMS_TO_RGB, RGB_TO_LMS, transform
from jaxadapt.gaze import fixation
from jaxadapt.operators import jacobs2015 as op
from jaxadapt.operators.checks import as_dtype, saturate
from jaxadapt.operators.jacobs2015 import _operator
from jaxadapt.operators.jacobs2015._tone import dither
from jaxadapt.physiology import kinetics
from jaxadapt.physiology.response import naka_rushton, power
from jaxadapt.spatial import (
    channels_last_filter,
    discrete_gaussian_kernel,
    gaussian_kernel,
    gaussian_ladder,
    separable_filter,
)

#: Largest difference allowed between the fused step's display values and
#: the reference's, in float32 (and its maps'): a twentieth of an 8-bit
#: display step (1/255), the bound that float32 rounding already sets
#: between float32 and float64 runs of the same code (test_jacobs2015.py).
TOLERANCE = 2e-4

T, H, W, FPS = 6, 48, 40, 30.0
KEY = jax.random.key(0)


def reference_frame(params, state, frame, dt, sample):
    """One frame as the operator computed it before fusion: ``(state, J)``."""
    shape = frame.shape[:2]
    frame = saturate(frame)
    gaze = fixation(sample, state.gaze, shape)
    sigma = op.semi_saturation(params, state.A)
    lms = transform(frame, RGB_TO_LMS)
    R = naka_rushton(lms, sigma, 1.0, params.n)
    B_inf = kinetics.cone_bleaching(lms, params.b1, params.b2).target
    C_inf = kinetics.calcium(R, params.c1, params.c2).target
    pixel = _operator._pixel
    shift = pixel(gaze) - pixel(state.gaze)
    B = op.retinal_shift(jnp.moveaxis(state.B, 0, -1), shift, B_inf)  # maps kept as planes
    C = op.retinal_shift(jnp.moveaxis(state.C, 0, -1), shift, C_inf)
    sigmas = op.acuity_sigmas(params)
    (L_local,) = gaussian_ladder(transform(frame, params.w_P), sigmas[-1:])
    rho = op.normalised_log_luminance(params, L_local())
    key_noise, key_dither = (jax.random.fold_in(state.key, i) for i in range(2))
    scene = frame
    if params.acuity:
        X = op.acuity_noise(params, key_noise, state.t, shape)
        thresholds = op.acuity_thresholds(params)[:, None, None]
        dropped = jnp.sum((rho + params.g * X)[None] <= thresholds, axis=0)
        for f, blurred in enumerate(gaussian_ladder(frame, sigmas)):
            scene = jnp.where((dropped > f)[..., None], blurred(), scene)
    r = jnp.clip(rho, 0.0, 1.0)
    L_P = transform(scene, params.w_P)
    L = r * L_P + (1.0 - r) * transform(scene, params.w_S) if params.purkinje else L_P
    R_tone = naka_rushton(L, sigma, 1.0, params.n)
    positive = (L_P > 0)[..., None]
    ratio = jnp.where(positive, scene / jnp.where(positive, L_P[..., None], 1.0), 1.0)
    if params.mesopic_colour:
        ratio = r[..., None] * ratio + (1.0 - r[..., None]) * params.scotopic_colour
    response = ratio * R_tone[..., None]
    v = op.falloff(params, shape, gaze)[..., None]
    if params.local_adaptation:
        gain = power(op.local_gain(params, C, C_inf), params.j2 * v)
        response = transform(transform(response, RGB_TO_LMS) * gain, LMS_TO_RGB)
    if params.bleaching:
        excess = jnp.maximum(B - B_inf, 0.0)
        if params.local_adaptation:
            excess = excess * C * (params.c2 / params.c1)
        response = response + params.j1 * v * transform(excess, params.H)
    J = op.encode(params, response)
    if params.dithering:
        J = display.dither(J, jax.random.fold_in(key_dither, state.frame), params.levels)
    A_T = op.adaptation_target(params, frame, gaze)
    A = kinetics.log_adaptation_step(state.A, A_T, params.a1, params.a2, dt)
    B_next = kinetics.cone_bleaching_step(B, lms, params.b1, params.b2, dt)
    C_next = kinetics.calcium_step(C, R, params.c1, params.c2, dt)
    if params.afterimage_blur:
        both = jnp.concatenate([B_next - B_inf, C_next - C_inf], axis=-1)
        taps = discrete_gaussian_kernel(params.afterimage_blur)
        blurred = jnp.moveaxis(separable_filter(jnp.moveaxis(both, -1, 0), taps), 0, -1)
        B_next = jnp.clip(B_inf + blurred[..., :3], 0.0, 1.0)
        C_next = jnp.clip(C_inf + blurred[..., 3:], 0.0, params.c1 / params.c2)
    state = state._replace(
        A=A if params.global_adaptation else state.A,
        B=jnp.moveaxis(B_next, -1, 0),
        C=jnp.moveaxis(C_next, -1, 0),
        gaze=gaze,
        t=state.t + dt,
        frame=state.frame + 1,
    )
    return state, J, None


def scene_frames(dtype):
    """A dark coloured texture with a bright flash and a saccade: every
    effect has work, acuity varies across the frame (a luminance ramp
    through the mesopic range) and the maps move with the gaze."""
    rng = np.random.default_rng(1)
    ramp = np.logspace(-3, 1, W)[None, :, None]
    texture = rng.uniform(0.2, 1.8, size=(H, W, 3)) * ramp
    frames = np.broadcast_to(texture, (T, H, W, 3)).copy()
    frames[1:3, 10:20, 8:16] = 1e6
    gaze = np.tile([W / 2, H / 2], (T, 1))
    gaze[3:] += [7.0, -4.0]
    return jnp.asarray(frames, dtype), jnp.asarray(gaze, dtype)


def both(params, dtype):
    """The operator's and the reference's display frames and final states,
    from the operator's frame map (``_operator._frame``, which ``step`` and
    ``run`` apply)."""
    frames, gaze = scene_frames(dtype)
    state = op.init(params, frames[0], gaze=gaze[0], key=KEY)
    params = as_dtype(params, dtype)
    dt = jnp.asarray(1 / FPS, dtype)

    def scan(frame_map):
        def one(s, inputs):
            s, J, *_ = frame_map(params, s, inputs[0], dt, inputs[1])
            return s, J

        return jax.jit(lambda s: jax.lax.scan(one, s, (frames, gaze)))(state)

    final, out = scan(_operator._frame)
    reference, expected = scan(reference_frame)
    return out, expected, final, reference


NO_DITHER = op.Params(dithering=False)
COMBINATIONS = {
    "bare": op.only(global_adaptation=False),
    **{e: op.only(e) for e in op.EFFECTS if e != "dithering"},
    "all": NO_DITHER,
}


@pytest.mark.parametrize("name", COMBINATIONS)
def test_fused_step_equals_the_unfused_frame_in_float32(name):
    params = COMBINATIONS[name]
    out, expected, final, reference = both(params, jnp.float32)
    if params.acuity:
        # The acuity loss picks a blur per pixel by comparing rho + g X with
        # thresholds: float32 rounding may move a pixel across one. Those
        # pixels (a few in a thousand) differ by a band's detail; the rest
        # must meet the tolerance.
        close = jnp.abs(out - expected).max(axis=-1) <= TOLERANCE
        assert float(close.mean()) > 0.99, name
    else:
        np.testing.assert_allclose(out, expected, rtol=0, atol=TOLERANCE, err_msg=name)
    np.testing.assert_allclose(final.B, reference.B, rtol=0, atol=TOLERANCE)
    np.testing.assert_allclose(final.C, reference.C, rtol=0, atol=TOLERANCE)


@pytest.mark.slow
def test_fused_step_equals_the_unfused_frame_in_float64_with_acuity():
    # In float64 no pixel sits within rounding of a threshold: all equal.
    out, expected, final, reference = both(NO_DITHER, jnp.float64)
    np.testing.assert_allclose(out, expected, rtol=0, atol=1e-10)
    np.testing.assert_allclose(final.B, reference.B, rtol=0, atol=1e-10)


def test_the_tolerance_can_fail():
    # A change of a tenth in the afterimage strength j1 (0.03) moves the
    # display by more than the tolerance: the comparison has teeth.
    out, _, _, _ = both(NO_DITHER, jnp.float32)
    changed = dataclasses.replace(NO_DITHER, j1=NO_DITHER.j1 * 1.1)
    _, expected, _, _ = both(changed, jnp.float32)
    assert float(jnp.abs(out - expected).max()) > 10 * TOLERANCE


def test_dithering_differs_from_the_reference_by_at_most_one_step():
    # Dithering draws from a hash, not from jax.random.uniform: each value
    # rounds to one of the same two 8-bit steps, unbiased over frames.
    out, expected, _, _ = both(op.Params(acuity=False), jnp.float32)
    assert float(jnp.abs(out - expected).max()) <= 1 / 255 + TOLERANCE
    assert float(jnp.abs(out * 255 - jnp.round(out * 255)).max()) < 1e-3  # on the 8-bit grid
    J = jnp.full((64, 64, 3), 100.3 / 255)
    q = dither(op.Params(), J, jax.random.key(3))
    assert set(np.unique(np.round(np.asarray(q) * 255))) == {100.0, 101.0}
    assert float(q.mean() * 255) == pytest.approx(100.3, abs=0.02)


@pytest.mark.parametrize("shape", [(37, 29, 3), (6, 50, 2), (40, 5), (1, 1, 3)])
@pytest.mark.parametrize("sigma", [0.75, 2.52])
def test_channels_last_filter_is_the_separable_filter_of_each_channel(shape, sigma):
    # The same mirror edges as separable_filter, also where an axis is
    # shorter than the kernel (the gather over the whole axis) and for
    # planes without a channel axis; when=False leaves out the first pass.
    x = jnp.asarray(np.random.default_rng(0).uniform(size=shape))
    taps = gaussian_kernel(sigma)
    expected = jnp.moveaxis(
        separable_filter(jnp.moveaxis(x, (0, 1), (-2, -1)), taps), (-2, -1), (0, 1)
    )
    np.testing.assert_allclose(channels_last_filter(x, taps), expected, rtol=1e-12, atol=1e-15)
    skipped = channels_last_filter(x, taps, jnp.bool_(False))
    assert skipped.shape == x.shape
