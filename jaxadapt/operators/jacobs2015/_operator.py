"""The operator contract: :func:`init`, :func:`step` and :func:`run`.

One frame (``_frame``) is the whole operator: the acuity loss (Eqs
13-15), the tone map (Eqs 1-2), the afterimages (Eqs 11-12), the display
encoding and temporal dithering (§2.4), then the state's advance by the
exact steps of :mod:`jaxadapt.physiology.kinetics` (Eqs 3, 4 and 8) and
the blur of the maps. ``run`` scans it over the frames, ``step`` applies
it once; all three check their inputs alike. The helpers here default and
check the gaze and round it to the whole pixels the maps move by.
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxadapt.background import LUMINANCE_CEILING
from jaxadapt.color import LMS_TO_RGB, RGB_TO_LMS
from jaxadapt.gaze import fixation, frame_centre
from jaxadapt.operators.checks import (
    as_dtype,
    check_adaptation,
    check_frames,
    check_frames_and_dt,
    check_one_parameter_set,
    check_state,
    frames_and_dt_messages,
    frames_messages,
    is_traced,
    raise_verdict,
    saturate,
)
from jaxadapt.operators.jacobs2015._acuity import (
    acuity_noise,
    dropped_bands,
    local_rho,
    resolve,
)
from jaxadapt.operators.jacobs2015._afterimage import (
    afterimage_planes,
    blur_map_planes,
    falloff,
    receptor_planes,
    shifted_planes,
)
from jaxadapt.operators.jacobs2015._params import (
    CHANNEL_FIELDS,
    Params,  # noqa: F401  (the examples)
)
from jaxadapt.operators.jacobs2015._planes import joined, mix, planar, stacked
from jaxadapt.operators.jacobs2015._state import Diagnostics, State
from jaxadapt.operators.jacobs2015._tone import (
    adaptation_target,
    dither_planes,
    encode,
    semi_saturation,
    tone_planes,
)
from jaxadapt.physiology import kinetics

# -- gaze ---------------------------------------------------------------------


def _pixel(gaze):
    """The pixel of a gaze point, rounding halves up (not to even), so that
    equal moves of the gaze give equal moves of the maps."""
    return jnp.floor(gaze + 0.5).astype(jnp.int32)


def _check_gaze(gaze, shape, dtype):
    gaze = jnp.asarray(gaze)
    if gaze.shape != shape:
        raise ValueError(f"gaze: expected shape {shape} in pixels (x, y), got shape {gaze.shape}")
    return gaze.astype(dtype)


def _default_gaze(gaze, frames, rank):
    """The checked gaze for a frame (rank 3) or sequence (rank 4); None means
    fixation at the centre. Left None for frames of the wrong rank, which
    the frame check then rejects."""
    if frames.ndim != rank:
        return None
    leading = frames.shape[:1] if rank == 4 else ()
    if gaze is None:
        gaze = jnp.broadcast_to(frame_centre(frames.shape[-3:-1], frames.dtype), leading + (2,))
    return _check_gaze(gaze, leading + (2,), frames.dtype)


def _as_frame_dtype(dt, frames):
    """``dt`` as an array of the frames' floating type, so that a Python
    float, a NumPy scalar and an array of the same shape share one trace."""
    floating = jnp.issubdtype(frames.dtype, jnp.floating)
    return jnp.asarray(dt, dtype=frames.dtype if floating else None)


def _check_key(params, key):
    if key is None:
        if params.stochastic:
            raise ValueError(
                "key: expected a PRNG key (jax.random.key(seed)) for the acuity loss and "
                "dithering, got None (or switch both off in Params)"
            )
        return jax.random.key(0)
    return key


# -- one frame ----------------------------------------------------------------


def _frame(params, state, frame, dt, sample):
    """Show ``frame`` to the viewer in ``state``; return the next state, the
    display frame and the frame's record (:class:`Diagnostics` without
    ``final_state``). The whole operator is this map.

    The per-pixel work is written on contiguous channel planes
    (:mod:`._planes`): the frame is transposed once, the maps are kept as
    planes. The maps are moved with the gaze only when it moved a whole
    pixel (:func:`shifted_planes`); where no pixel loses acuity the display
    is computed from the frame itself (a conditional on the whole frame),
    not from a copy of it. The display is composed in LMS, where Eq 12's
    gains act, and turned into RGB once.
    """
    shape = frame.shape[:2]
    frame = saturate(frame)
    rgb = planar(frame)
    gaze = fixation(sample, state.gaze, shape)
    sigma = semi_saturation(params, state.A)
    rec = receptor_planes(params, rgb, sigma)
    shift = _pixel(gaze) - _pixel(state.gaze)
    B = shifted_planes(state.B, shift, rec.B_inf)
    C = shifted_planes(state.C, shift, rec.C_inf)
    rho = local_rho(params, frame)
    visibility = falloff(params, shape, gaze)
    key_noise, key_dither = (jax.random.fold_in(state.key, i) for i in range(2))
    seed = jax.random.bits(jax.random.fold_in(key_dither, state.frame), (2,), jnp.uint32)

    def shown(scene, lms):
        response = tone_planes(params, scene, rho, sigma, lms)
        response = afterimage_planes(params, response, B, C, rec, visibility)
        J = [encode(params, x) for x in mix(LMS_TO_RGB, response)]
        if params.dithering:
            J = dither_planes(params, J, seed)
        return stacked(J)

    if params.acuity:
        X = acuity_noise(params, key_noise, state.t, shape)
        dropped, present = dropped_bands(params, rho, X)

        def resolved():
            scene = planar(resolve(params, frame, dropped, present))
            return shown(scene, mix(RGB_TO_LMS, scene))

        J = jax.lax.cond(present > 1, resolved, lambda: shown(rgb, rec.lms))
    else:
        J = shown(rgb, rec.lms)

    A_T = adaptation_target(params, frame, gaze)
    A = kinetics.log_adaptation_step(state.A, A_T, params.a1, params.a2, dt)
    B_step = [
        kinetics.cone_bleaching_step(b, I, params.b1[k], params.b2[k], dt)
        for k, (b, I) in enumerate(zip(B, rec.lms, strict=True))
    ]
    C_step = [
        kinetics.calcium_step(c, R, params.c1, params.c2, dt) for c, R in zip(C, rec.R, strict=True)
    ]
    B_next, C_next = map(joined, blur_map_planes(params, B_step, C_step, rec.B_inf, rec.C_inf))
    advanced = state._replace(
        A=A if params.global_adaptation else state.A,
        B=B_next,
        C=C_next,
        gaze=gaze,
        t=state.t + dt,
        frame=state.frame + 1,
    )
    gx, gy = _pixel(gaze)
    record = Diagnostics(
        state.t,
        state.A,
        A_T,
        sigma,
        gaze,
        jnp.stack([b[gy, gx] for b in B]),
        jnp.stack([c[gy, gx] for c in C]),
        rho[gy, gx],
        final_state=None,
    )
    return advanced, J, record


def _initial_state(params, frame, gaze, key, adaptation=None):
    shape = frame.shape[:2]
    frame = saturate(frame)
    gaze = fixation(gaze, frame_centre(shape, frame.dtype), shape)
    if adaptation is None:
        A = adaptation_target(params, frame, gaze)
    else:
        adaptation = jnp.clip(adaptation, params.adaptation_floor, LUMINANCE_CEILING)
        A = jnp.log10(adaptation).astype(frame.dtype)
    rec = receptor_planes(params, planar(frame), semi_saturation(params, A))
    zero = jnp.zeros((), frame.dtype)
    B, C = joined(rec.B_inf), joined(rec.C_inf)
    return State(A, B, C, gaze, zero, jnp.zeros((), jnp.int32), key)


# -- the contract -------------------------------------------------------------


def init(params, first_frame, *, gaze=None, key=None, adaptation=None):
    """State of a viewer fully adapted to ``first_frame`` while fixating ``gaze``.

    ``A`` is the frame's target, ``B`` and ``C`` their equilibria (Eqs 6
    and 10) for the frame.

    Parameters
    ----------
    params : Params
    first_frame : array, shape (H, W, 3)
        Linear BT.709 RGB, cd/m2.
    gaze : array, shape (2,), optional
        Fixation ``(x, y)``, pixels (default: the centre; clipped to the
        frame; NaN also means the centre).
    key : PRNG key, optional
        Key of the sequence; required when the acuity loss or dithering is on.
    adaptation : float, optional
        Global adaptation luminance (cd/m2) to start from instead of the
        frame's target, e.g. a dark-adapted viewer; floored at
        ``adaptation_floor`` like every target. The retinal maps still start
        at equilibrium with the frame.

    Returns
    -------
    State
    """
    first_frame = jnp.asarray(first_frame)
    gaze = _default_gaze(gaze, first_frame, rank=3)
    check_adaptation(adaptation)
    key = _check_key(params, key)
    on_host = not is_traced(params, first_frame, gaze, key, adaptation)
    state, verdict = _init(params, first_frame, gaze, key, adaptation, on_host)
    raise_verdict(verdict, frames_messages("first_frame"))
    return state


@eqx.filter_jit
def _init(params, first_frame, gaze, key, adaptation, on_host):
    guard, verdict = check_frames(first_frame, 3, "first_frame", on_host)
    check_one_parameter_set(params, CHANNEL_FIELDS)
    params = as_dtype(params, first_frame.dtype)
    state = _initial_state(params, first_frame, gaze, key, adaptation)
    return state._replace(A=state.A + guard), verdict


def step(params, state, frame, dt, *, gaze=None, key=None):
    """Show one frame, then advance the state over its duration.

    Parameters
    ----------
    params : Params
    state : State
        State at the time the frame is shown (from :func:`init` or a
        previous step).
    frame : array, shape (H, W, 3)
        Linear BT.709 RGB, cd/m2, the shape of the state's maps.
    dt : float
        How long the frame is held, s.
    gaze : array, shape (2,), optional
        Gaze sample ``(x, y)``, pixels (default: the centre; NaN: a blink,
        the last fixation is held; outside the frame: clipped).
    key : PRNG key, optional
        Replaces the sequence key held in the state; by default the state's
        key is used, so that a loop of steps equals :func:`run`.

    Returns
    -------
    (State, array)
        The state after ``dt`` and the display frame ``(H, W, 3)``: display
        values ``J`` in [0, 1] (gamma-encoded by ``gamma``; on the 8-bit grid
        when dithering).
    """
    frame = jnp.asarray(frame)
    gaze = _default_gaze(gaze, frame, rank=3)
    check_state(state, State, "jacobs2015")
    if key is not None:
        state = state._replace(key=key)
    dt = _as_frame_dtype(dt, frame)
    on_host = not is_traced(params, state, frame, dt, gaze)
    new_state, out, verdict = _step(params, state, frame, dt, gaze, on_host)
    raise_verdict(verdict, frames_and_dt_messages("frame"))
    return new_state, out


@eqx.filter_jit
def _step(params, state, frame, dt, gaze, on_host):
    guard, dt, verdict = check_frames_and_dt(frame, dt, 3, "frame", on_host)
    expected = state.B.shape[1:] + state.B.shape[:1]  # the maps are planes (3, H, W)
    if expected != frame.shape:
        raise ValueError(
            f"frame: expected the shape of the state's frames {expected}, got {frame.shape}"
        )
    check_one_parameter_set(params, CHANNEL_FIELDS)
    params, state, dt = as_dtype((params, state, dt[0]), frame.dtype)
    state = state._replace(A=state.A + guard)
    new_state, out, _ = _frame(params, state, frame, dt, gaze)
    return new_state, out, verdict


def run(params, frames, dt, *, gaze=None, key=None, state=None):
    """Render a sequence as the viewer following ``gaze`` would see it.

    Parameters
    ----------
    params : Params
    frames : array, shape (T, H, W, 3)
        Linear BT.709 RGB, cd/m2, finite and non-negative.
    dt : float or array, shape (T,)
        Duration of each frame, s.
    gaze : array, shape (T, 2), optional
        Gaze path ``(x, y)``, pixels (default: fixation at the centre). NaN
        samples are blinks (the last fixation is held); points outside the
        frame are clipped to its edge.
    key : PRNG key
        Key of the sequence, required when the acuity loss or dithering is
        on: the same key gives the same frames.
    state : State, optional
        State at the first frame; by default :func:`init` on the first frame
        and gaze sample, with ``key``.

    Returns
    -------
    (array, Diagnostics)
        Display values ``(T, H, W, 3)`` in [0, 1] (gamma-encoded, see
        :func:`step`) and the per-frame record. ``run`` gives the same frames
        as a loop of :func:`step` from the same state.

    Examples
    --------
    >>> frames = jnp.full((3, 8, 8, 3), 100.0)
    >>> out, diag = run(Params(), frames, 1 / 30, key=jax.random.key(0))
    >>> out.shape, diag.B_gaze.shape
    ((3, 8, 8, 3), (3, 3))
    >>> bool(jnp.all(out * 255 == jnp.round(out * 255)))  # dithered to 8 bits
    True
    """
    frames = jnp.asarray(frames)
    gaze = _default_gaze(gaze, frames, rank=4)
    if state is None:
        key = _check_key(params, key)
    else:
        check_state(state, State, "jacobs2015")
        state = state if key is None else state._replace(key=key)
    dt = _as_frame_dtype(dt, frames)
    on_host = not is_traced(params, frames, dt, gaze, key, state)
    out, diagnostics, verdict = _run(params, frames, dt, gaze, key, state, on_host)
    raise_verdict(verdict, frames_and_dt_messages("frames"))
    return out, diagnostics


@eqx.filter_jit
def _run(params, frames, dt, gaze, key, state, on_host):
    guard, dt, verdict = check_frames_and_dt(frames, dt, 4, on_host=on_host)
    check_one_parameter_set(params, CHANNEL_FIELDS)
    params, state, dt = as_dtype((params, state, dt), frames.dtype)
    if state is None:
        state = _initial_state(params, frames[0], gaze[0], key)
    state = state._replace(A=state.A + guard)

    def scan_step(s, inputs):
        s, out, record = _frame(params, s, *inputs)
        return s, (out, record)

    final_state, (out, record) = jax.lax.scan(scan_step, state, (frames, dt, gaze))
    return out, record._replace(final_state=final_state), verdict
