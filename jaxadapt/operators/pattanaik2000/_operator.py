"""The operator contract: :func:`init`, :func:`step` and :func:`run`.

Each checks its inputs, finds the frames' goals and advances the state
(:mod:`._adaptation`), then maps the pixels of every frame with the
observer of the state it is seen with (:mod:`._appearance`), in one pass
over the frames; :func:`run` also records the per-frame
:class:`Diagnostics`, at the gaze point for a local background. Frame ``k``
is seen with the state reached at its start (§5, the package's "Timing").
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxadapt import fused
from jaxadapt.background import LUMINANCE_CEILING
from jaxadapt.gaze import fixation, frame_centre
from jaxadapt.operators import goal as goals
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
)
from jaxadapt.operators.pattanaik2000._adaptation import (
    advance,
    advance_sequence,
    frame_goals,
    relaxations,
    static_state,
)
from jaxadapt.operators.pattanaik2000._appearance import (
    curve,
    observer,
    tone_map,
    tone_map_planes,
)
from jaxadapt.operators.pattanaik2000._params import (
    Diagnostics,
    Params,  # noqa: F401  (run's example)
    State,
)
from jaxadapt.physiology import kinetics


def _fixation(frames, gaze):
    """The point ``(x, y)``, pixels, of frames ``(..., H, W, 3)`` that the
    foveal goal and the diagnostics are read at, one per frame.

    ``gaze`` clipped to the frame; the frame's centre where ``gaze`` is None
    or a sample is not finite (NaN: a blink; :func:`~jaxadapt.gaze.fixation`).
    This operator keeps no gaze in its state, so a blink cannot hold the
    fixation before it: :func:`jaxadapt.gaze.recorded_gaze` holds it in
    a recorded path (as the 2015 operator holds it in its state).
    """
    shape = frames.shape[-3:-1]
    centre = frame_centre(shape, frames.dtype)
    if gaze is None:
        return jnp.broadcast_to(centre, frames.shape[:-3] + (2,))
    return fixation(gaze, centre, shape)


def init(params, first_frame, *, gaze=None, key=None, adaptation=None):
    """State of a viewer fully adapted before the sequence starts.

    Parameters
    ----------
    params : Params
    first_frame : array, shape (H, W, 3)
        Linear RGB, cd/m2; the viewer is adapted to its goals.
    gaze : array, shape (2,), optional
        Gaze point ``(x, y)`` in pixels, for the ``"foveal"`` goal (default
        and during a blink, NaN: the centre; see :func:`_fixation`).
    key : ignored
        The operator is deterministic.
    adaptation : float, optional
        Adapt instead to this luminance (cd/m2) for rods and cones, e.g.
        0.01 for the moonlit start of the title-page sequence; at least
        ``goal.LUMINANCE_FLOOR`` (1e-6) counts, as for the goals of frames,
        so that 0 is a fully dark-adapted viewer, and at most
        ``background.LUMINANCE_CEILING`` (1e10). With a local background
        the state is then a uniform map, of ``first_frame``'s size.

    Returns
    -------
    State
        Scalars, or ``(H, W)`` maps with a local background, in the frame's
        dtype (the dtype :func:`run` returns its final state in, so that a
        sequence run in chunks compiles ``run`` once).
    """
    on_host = not is_traced(params, first_frame, gaze, adaptation)
    state, verdict = _init(params, first_frame, gaze, adaptation, on_host)
    raise_verdict(verdict, frames_messages("first_frame"))
    return state


@eqx.filter_jit
def _init(params, first_frame, gaze, adaptation, on_host):
    check_one_parameter_set(params)
    if adaptation is not None:
        floating = first_frame is not None and jnp.issubdtype(first_frame.dtype, jnp.floating)
        dtype = first_frame.dtype if floating else jnp.result_type(float)
        check_adaptation(adaptation)
        A = jnp.clip(jnp.asarray(adaptation, dtype=dtype), goals.LUMINANCE_FLOOR, LUMINANCE_CEILING)
        if params.background != "global" and first_frame is not None:
            A = jnp.broadcast_to(A, first_frame.shape[:2])  # as run() carries it
        return static_state(as_dtype(params, dtype), A, A), None
    guard, verdict = check_frames(first_frame, 3, "first_frame", on_host)
    params = as_dtype(params, first_frame.dtype)
    G_rod, G_cone = frame_goals(params, first_frame, _fixation(first_frame, gaze))
    return static_state(params, G_rod + guard, G_cone + guard), verdict


def _probe(x, gaze):
    """``x`` itself if a scalar, else its value at the pixel nearest ``gaze``."""
    if x.ndim == 0:
        return x
    H, W = x.shape
    col = jnp.clip(jnp.round(gaze[0]).astype(jnp.int32), 0, W - 1)
    row = jnp.clip(jnp.round(gaze[1]).astype(jnp.int32), 0, H - 1)
    return x[row, col]


def _display(params, G_rod, G_cone, states, frames, gaze):
    """Show frames ``(T, H, W, 3)`` with their goals to viewers in ``states``.

    All arguments but ``params`` have a leading frame axis. Returns the
    display frames and each frame's record at the gaze point ``(G_rod,
    G_cone, state, observer, curve)``. The pixel map is one pass over the
    frames on a GPU (:func:`jaxadapt.fused.map_pixels`).
    """
    obs = jax.vmap(observer, (None, 0))(params, states)
    seen = jax.vmap(lambda g, *x: jax.tree.map(lambda y: _probe(y, g), x))(
        gaze, G_rod, G_cone, states, obs
    )
    out = fused.map_pixels(
        lambda args, channels: tone_map_planes(*args, channels),
        frames,
        (params, obs),
        default=lambda frames, args: jax.vmap(tone_map, (None, 0, 0))(*args, frames),
    )
    return out, (*seen, jax.vmap(curve, (None, 0))(params, seen[-1]))


def step(params, state, frame, dt, *, gaze=None, key=None):
    """Show one frame, then advance the state over its duration.

    Parameters
    ----------
    params : Params
    state : State
        State at the time the frame is shown.
    frame : array, shape (H, W, 3)
        Linear RGB, cd/m2.
    dt : float
        How long the frame is held, s.
    gaze : array, shape (2,), optional
        Gaze point ``(x, y)``, pixels (``"foveal"`` goal; default and during
        a blink, NaN: the centre).
    key : ignored
        The operator is deterministic; accepted so that all operators share
        one signature.

    Returns
    -------
    (State, array)
        The state after ``dt`` and the display frame ``(H, W, 3)`` in [0, 1].
    """
    gaze = None if gaze is None else jnp.asarray(gaze)
    check_state(state, State, "pattanaik2000")
    frame, dt = jnp.asarray(frame), jnp.asarray(dt)
    on_host = not is_traced(params, state, frame, dt, gaze)
    state, out, verdict = _step(params, state, frame, dt, gaze, on_host)
    raise_verdict(verdict, frames_and_dt_messages("frame"))
    return state, out


@eqx.filter_jit
def _step(params, state, frame, dt, gaze, on_host):
    guard, dt, verdict = check_frames_and_dt(frame, dt, 3, "frame", on_host)
    check_one_parameter_set(params)
    params, state, dt, gaze = as_dtype((params, state, dt[0], gaze), frame.dtype)
    state = jax.tree.map(lambda s: s + guard, state)
    gaze = _fixation(frame, gaze)
    G_rod, G_cone = frame_goals(params, frame, gaze)
    one = jax.tree.map(lambda x: x[None], (G_rod, G_cone, state, frame, gaze))
    out, _ = _display(params, *one)
    return advance(params, state, G_rod, G_cone, dt), out[0], verdict


def run(params, frames, dt, *, gaze=None, key=None, state=None):
    """Tone-map a sequence with time-dependent adaptation.

    Parameters
    ----------
    params : Params
    frames : array, shape (T, H, W, 3)
        Linear BT.709 RGB, cd/m2, finite and non-negative.
    dt : float or array, shape (T,)
        Duration of each frame, s (``1/fps``).
    gaze : array, shape (T, 2), optional
        Gaze path ``(x, y)`` in pixels, for the ``"foveal"`` goal and for
        the point a local operator's diagnostics are read at, clipped to
        the frame (default, and for samples that are not finite, NaN
        during a blink: the image centre; see :func:`_fixation`).
    key : ignored
        The operator is deterministic.
    state : State, optional
        State at the first frame; by default the viewer is fully adapted to
        the first frame (:func:`init`).

    Returns
    -------
    (array, Diagnostics)
        Display frames ``(T, H, W, 3)``, linear, in [0, 1], and the per-frame
        record (at the gaze point, for a local background). ``run`` finds
        every frame's goals at once, advances the state through the whole
        sequence (:func:`advance_sequence`) and then maps the pixels of all
        frames in one vectorised pass; it gives the frames of a loop of
        :func:`step` up to rounding.

    Examples
    --------
    >>> frames = jnp.full((4, 2, 2, 3), 100.0)
    >>> out, diag = run(Params(), frames, 1 / 30)
    >>> out.shape, diag.G_cone.shape
    ((4, 2, 2, 3), (4,))
    """
    gaze = None if gaze is None else jnp.asarray(gaze)
    frames, dt = jnp.asarray(frames), jnp.asarray(dt)
    on_host = not is_traced(params, frames, dt, gaze, state)
    out, diagnostics, verdict = _run(params, frames, dt, gaze, state, on_host)
    raise_verdict(verdict, frames_and_dt_messages("frames"))
    return out, diagnostics


def _checked_state(state, shape, guard):
    """A given ``state`` broadcast to the goals' ``shape`` (``()``, or the
    frames' ``(H, W)`` with a local background), with the frames' check
    ``guard`` added, after checking that it is a :class:`State` whose
    fields are scalars or of ``shape`` (``ValueError`` naming the field; its
    values are not checked: a second conditional would cost every step of
    a fit through ``run``)."""
    check_state(state, State, "pattanaik2000")
    shapes = "()" if shape == () else f"() or {shape} (the goals' shape)"
    for name, field in zip(State._fields, state, strict=True):
        if jnp.shape(field) not in ((), shape):
            raise ValueError(
                f"state: expected fields of shape {shapes}, got {name} of shape {jnp.shape(field)}"
            )
    return State(*(jnp.broadcast_to(field + guard, shape) for field in state))


@eqx.filter_jit
def _run(params, frames, dt, gaze, state, on_host):
    guard, dt, verdict = check_frames_and_dt(frames, dt, 4, on_host=on_host)
    check_one_parameter_set(params)
    params, state, dt, gaze = as_dtype((params, state, dt, gaze), frames.dtype)
    T = frames.shape[0]
    if gaze is not None and gaze.shape != (T, 2):
        raise ValueError(f"gaze: expected shape ({T}, 2) in pixels, got shape {gaze.shape}")
    gaze = _fixation(frames, gaze)
    G_rod, G_cone = jax.vmap(frame_goals, (None, 0, 0))(params, frames, gaze)
    if state is None:
        state = static_state(params, G_rod[0], G_cone[0])
    state = _checked_state(state, G_cone.shape[1:], guard)
    states, final_state = advance_sequence(params, state, G_rod, G_cone, dt)
    out, record = _display(params, G_rod, G_cone, states, frames, gaze)
    G_rod, G_cone, states, obs, curves = record
    diagnostics = Diagnostics(
        t=jnp.cumsum(dt) - dt,
        G_rod=G_rod,
        G_cone=G_cone,
        state=states,
        sigma_rod=obs.sigma_rod,
        sigma_cone=obs.sigma_cone,
        rule=obs.rule,
        curve=curves,
        final_state=final_state,
    )
    return out, diagnostics, verdict


def transition(params, frames, dt, *, gaze=None):
    """What a stretch of frames does to the state: the affine map ``state ->
    a * state + b``, field by field, for any state at its start.

    The goals of this model depend on the frames alone, and the kinetics
    step the state by exact affine steps (§4.1.2 and Eq 7), so a stretch of
    frames composes into one map (:func:`~jaxadapt.physiology.kinetics.composed`):
    the contract's ``composable``. A sequence split in time is joined
    exactly with it: each piece starts from ``a * state + b`` of the pieces
    before it, which equals :func:`run`'s ``final_state`` up to rounding.

    Parameters
    ----------
    params, frames, dt, gaze
        As :func:`run`.

    Returns
    -------
    (State, State)
        ``a`` and ``b``: scalars, or ``(H, W)`` maps with a local background.
    """
    gaze = None if gaze is None else jnp.asarray(gaze)
    frames, dt = jnp.asarray(frames), jnp.asarray(dt)
    on_host = not is_traced(params, frames, dt, gaze)
    a, b, verdict = _transition(params, frames, dt, gaze, on_host)
    raise_verdict(verdict, frames_and_dt_messages("frames"))
    return a, b


@eqx.filter_jit
def _transition(params, frames, dt, gaze, on_host):
    guard, dt, verdict = check_frames_and_dt(frames, dt, 4, on_host=on_host)
    check_one_parameter_set(params)
    params, dt, gaze = as_dtype((params, dt, gaze), frames.dtype)
    G_rod, G_cone = jax.vmap(frame_goals, (None, 0, 0))(params, frames, _fixation(frames, gaze))
    dt = jnp.reshape(dt, dt.shape + (1,) * (G_cone.ndim - 1))  # (maps: over their pixels)
    maps = [
        kinetics.composed(*kinetics.affine_step(law, dt))
        for law in relaxations(params, G_rod + guard, G_cone + guard)
    ]
    return State(*(a for a, _ in maps)), State(*(b for _, b in maps)), verdict
