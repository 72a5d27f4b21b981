"""Adaptation over time: each frame's goals and the state they drive.

The goal ``G`` of rods and cones per frame (one value from the
``Params.goal`` finder, or a map of the local background), the fully
adapted state for goals held forever (``A = G``, ``B`` the static value of
Eq 6), and the exact steps of the kinetics: neural filters with ``t0``
(§4.1.2) and pigment bleaching with ``tau`` and ``c`` (Eq 7), for one frame
(:func:`advance`) or a whole sequence at once (:func:`advance_sequence`).
"""

from jaxadapt import background
from jaxadapt.color import photopic_luminance, scotopic_luminance
from jaxadapt.operators import goal as goals
from jaxadapt.operators.checks import saturate
from jaxadapt.operators.pattanaik2000._params import State
from jaxadapt.physiology import kinetics


def frame_goals(params, frame, gaze):
    """Adaptation goals ``(G_rod, G_cone)`` of a frame ``(H, W, 3)``, cd/m2.

    Scalars, or ``(H, W)`` maps of the local background when
    ``params.background`` is not ``"global"``. ``gaze`` ``(x, y)`` in
    pixels is used by the ``"foveal"`` goal.
    """

    def goal(L):
        if params.background != "global":
            return background.estimate_background(L, params.background, params.background_scale)
        if params.goal == "log_average":
            return goals.log_average(L)
        if params.goal == "white_fraction":
            return goals.white_fraction(L, params.goal_fraction, params.white_percentile)
        return goals.foveal_log_average(L, gaze, params.pixels_per_degree)

    # Two reductions of the frame's shape (not one of a stack): XLA fuses
    # them, and the frames' value check, into one read of the frames.
    frame = saturate(frame)
    return goal(scotopic_luminance(frame)), goal(photopic_luminance(frame))


def static_state(params, G_rod, G_cone):
    """Fully adapted state for goals held forever: ``A = G``, ``B = B_inf(G)``."""
    B_rod = kinetics.bleaching(G_rod, params.tau_rod, params.c_rod).target
    B_cone = kinetics.bleaching(G_cone, params.tau_cone, params.c_cone).target
    return State(G_rod, G_cone, B_rod, B_cone)


def relaxations(params, G_rod, G_cone):
    """The kinetics of each state field under goals ``G_rod``, ``G_cone``
    (cd/m2): a :class:`State` of :class:`~jaxadapt.physiology.kinetics.Relaxation`.

    Neural filters with ``t0_rod``, ``t0_cone`` (§4.1.2) and pigment
    bleaching with ``tau``, ``c`` (Eq 7).
    """
    return State(
        kinetics.neural(G_rod, params.t0_rod),
        kinetics.neural(G_cone, params.t0_cone),
        kinetics.bleaching(G_rod, params.tau_rod, params.c_rod),
        kinetics.bleaching(G_cone, params.tau_cone, params.c_cone),
    )


def advance(params, state, G_rod, G_cone, dt):
    """State after goals held for ``dt`` s: the exact steps of the kinetics."""
    steps = zip(state, relaxations(params, G_rod, G_cone), strict=True)
    return State(*(kinetics.relaxation_step(y, law, dt) for y, law in steps))


def advance_sequence(params, state, G_rod, G_cone, dt):
    """States a sequence of frames is seen with, and the state after it.

    Frame ``k``'s goals ``G_rod[k]``, ``G_cone[k]`` (cd/m2) are held for
    ``dt[k]`` s. The exact steps of the four fields over the whole
    sequence (:func:`~jaxadapt.physiology.kinetics.relaxation_sequences`:
    on a GPU all frames at once, by their associative form): equal to a
    loop of :func:`advance` up to rounding.

    Returns
    -------
    (State, State)
        Fields of shape ``(T, ...)``: the state at each frame's start; and
        the state after the last frame's ``dt``.
    """
    ys = kinetics.relaxation_sequences(state, relaxations(params, G_rod, G_cone), dt)
    return State(*(y[:-1] for y in ys)), State(*(y[-1] for y in ys))
