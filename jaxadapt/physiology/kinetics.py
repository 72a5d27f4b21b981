"""Adaptation kinetics: the ODEs of the papers, their exact steps, and diffrax.

Every linear kinetics law of the papers has the form of a first-order
relaxation towards an input-dependent target::

    dy/dt = k(G) (y_inf(G) - y)

For an input ``G`` held constant over a step ``dt`` its exact solution is::

    y(t + dt) = y_inf + (y(t) - y_inf) exp(-k dt)

which is the linear recurrence ``y' = a y + b`` with ``a = exp(-k dt)`` and
``b = (1 - a) y_inf``. It can never leave the interval between ``y(t)`` and
``y_inf``, whatever ``dt`` and ``G``: unlike the explicit update printed as
Eq 7 of Pattanaik et al. (2000), it cannot diverge on bright steps.

Each law below is given three ways:

* its rate and target (:class:`Relaxation`), from which follow
* the right-hand side in diffrax's ``f(t, y, args)`` form, where the input
  ``G`` in ``args`` is either an array or a diffrax path (e.g.
  :func:`goal_path`, a linear interpolation through frame times), and
* the exact step for an input held over ``dt``, which the operators use,
  and :func:`relaxation_sequence`, the same steps over a whole sequence of
  held inputs at once.

:func:`integrate` solves any of the right-hand sides with diffrax; it is the
reference the exact steps are tested against and the path for inputs that
vary continuously. Times in seconds, luminance in cd/m2.
"""

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = [
    "Relaxation",
    "relaxation_rhs",
    "affine_step",
    "affine_sequence",
    "then",
    "composed",
    "relaxation_step",
    "relaxation_sequence",
    "SMALL_STATE",
    "relaxation_sequences",
    "neural",
    "neural_rhs",
    "neural_step",
    "bleaching",
    "bleaching_rhs",
    "bleaching_step",
    "goal_path",
    "integrate",
    "cone_bleaching",
    "cone_bleaching_rhs",
    "cone_bleaching_step",
    "calcium",
    "calcium_rhs",
    "calcium_step",
    "LOG_ADAPTATION_BAND",
    "log_adaptation_step",
    "log_adaptation_rhs",
]


class Relaxation(NamedTuple):
    """A first-order relaxation ``dy/dt = rate (target - y)``.

    Attributes
    ----------
    rate : array
        Rate constant ``k``, 1/s.
    target : array
        Fixed point ``y_inf`` reached under a constant input.
    """

    rate: jnp.ndarray
    target: jnp.ndarray


def relaxation_rhs(y, relaxation):
    """``dy/dt = k (y_inf - y)``."""
    return relaxation.rate * (relaxation.target - y)


def affine_step(relaxation, dt):
    """The exact step as the affine map ``y -> a y + b``: ``(a, b)``.

    ``a = exp(-k dt)`` and ``b = (1 - a) y_inf``, with ``1 - a`` as
    ``-expm1(-k dt)`` so that slow relaxations (``k dt`` near float
    epsilon) keep their digits in float32.
    """
    x = relaxation.rate * dt
    return jnp.exp(-x), -jnp.expm1(-x) * relaxation.target


def then(first, second):
    """The affine map of ``first`` and then ``second``, each ``(a, b)`` of
    ``y -> a y + b``: ``(a2 a1, a2 b1 + b2)``; associative, so steps compose
    in any grouping."""
    (a1, b1), (a2, b2) = first, second
    return a2 * a1, a2 * b1 + b2


def composed(a, b):
    """The one affine map ``y -> A y + B`` of the maps ``y -> a_k y + b_k``
    applied in turn (leading axis ``k``): what a stretch of steps does to
    any state, so that a sequence split in time is joined exactly (the
    state after the stretch is ``A y0 + B``). Folded in order, as
    :func:`affine_sequence` steps on the CPU."""

    dtype = jnp.result_type(a, b)
    shape = jnp.broadcast_shapes(jnp.shape(a), jnp.shape(b))
    a, b = (jnp.broadcast_to(jnp.asarray(x, dtype), shape) for x in (a, b))
    one = (jnp.ones(shape[1:], dtype), jnp.zeros(shape[1:], dtype))
    return jax.lax.scan(lambda AB, ab: (then(AB, ab), None), one, (a, b))[0]


def relaxation_step(y, relaxation, dt):
    """Exact solution after ``dt`` seconds: ``y_inf + (y - y_inf) exp(-k dt)``,
    evaluated as ``a y + b`` (:func:`affine_step`)."""
    a, b = affine_step(relaxation, dt)
    return a * y + b


def relaxation_sequence(y0, relaxation, dt):
    """The exact steps over a sequence of inputs, each held for its ``dt``.

    Step ``k`` is the affine map ``y -> a_k y + b_k`` of
    :func:`affine_step`.
    Affine maps compose associatively, ``(a2, b2) o (a1, b1) = (a2 a1, a2 b1
    + b2)``, so on a GPU every prefix of the sequence is found by
    ``jax.lax.associative_scan`` in ``log2 T`` vectorised rounds instead of
    a loop of ``T`` dependent steps; the states are then ``A_k y0 + B_k``.
    On the CPU the loop is the faster form (:func:`_prefix_states`).
    Equal to a loop of :func:`relaxation_step` up to rounding, and so are
    its derivatives (:func:`affine_sequence`).

    Parameters
    ----------
    y0 : array
        State before the first step; broadcasts against one step's fields.
    relaxation : Relaxation
        Rate (1/s) and target of each step, leading axis ``T``; a field of
        fewer axes than the other (one rate for a map of targets) broadcasts
        over the trailing ones.
    dt : array, shape (T,)
        Duration of each step, s.

    Returns
    -------
    array, shape (T + 1, ...)
        The state before each step, then the state after the last.
    """
    dt = jnp.asarray(dt)
    if dt.ndim != 1:
        raise ValueError(f"dt: expected shape (T,) in seconds, got shape {dt.shape}")
    ndim = max(jnp.ndim(relaxation.rate), jnp.ndim(relaxation.target))

    def steps_first(x):  # the step axis first, then the trailing axes to broadcast over
        x = jnp.asarray(x)
        return jnp.reshape(x, x.shape + (1,) * (ndim - x.ndim))

    a, b = affine_step(Relaxation(*map(steps_first, relaxation)), steps_first(dt))
    y0 = jnp.broadcast_to(y0, jnp.broadcast_shapes(a.shape, b.shape)[1:])
    return affine_sequence(y0, a, b)


#: Elements per step, of all the states together, up to which
#: :func:`relaxation_sequences` steps them as one stacked state.
SMALL_STATE = 4096


def relaxation_sequences(y0s, relaxations, dt):
    """:func:`relaxation_sequence` of several independent states that share
    the steps ``dt``.

    Small states (at most :data:`SMALL_STATE` elements a step, all
    together; the 2000 operator's global state is four scalars a frame) are
    stacked into one state and stepped by one sequence; larger ones each by
    its own. XLA's CPU runtime runs independent loops on separate threads,
    which is parallel work for maps but only per-step hand-over for
    scalars, so the stacked form evaluates several times faster on small
    states. Stacking copies every state's steps, though, so large maps are
    stepped separately to bound memory.

    Parameters
    ----------
    y0s : sequence of arrays
        Each state before the first step.
    relaxations : sequence of Relaxation
        Each state's rates and targets, leading axis ``T``.
    dt : array, shape (T,)
        Duration of each step, s.

    Returns
    -------
    list of arrays, shape (T + 1, ...)
        Each state's :func:`relaxation_sequence`; when stacked, all of one
        broadcast shape.
    """
    shape = jnp.broadcast_shapes(
        *(jnp.shape(x)[1:] for law in relaxations for x in law), *map(jnp.shape, y0s)
    )
    if len(y0s) * math.prod(shape) > SMALL_STATE:
        return [relaxation_sequence(y0, law, dt) for y0, law in zip(y0s, relaxations, strict=True)]

    def stacked(fields):  # (T, states, ...), each step's fields broadcast to ``shape``
        return jnp.stack(
            [jax.vmap(lambda x: jnp.broadcast_to(x, shape))(jnp.asarray(x)) for x in fields], axis=1
        )

    law = Relaxation(*map(stacked, zip(*relaxations, strict=True)))
    ys = relaxation_sequence(jnp.stack([jnp.broadcast_to(y, shape) for y in y0s]), law, dt)
    return [ys[:, i] for i in range(len(y0s))]


def _prefix_states(y0, a, b):
    """``y0`` and the states after each map ``y -> a_k y + b_k`` (leading
    axis ``k``).

    XLA's CPU and GPU backends want this written differently, and
    ``jax.lax.platform_dependent`` picks the form. On a GPU, all at once by
    the associative scan of the maps' compositions: ``log2 T`` rounds of
    vectorised work instead of ``T`` dependent steps, each of which would be
    a kernel launch. On the CPU, the steps in turn (``lax.scan``): the
    associative scan's interleaving of odd and even prefixes is a padding
    along the time axis that XLA's CPU backend does not vectorise, and it
    reads and writes every state several times, so the loop is several
    times faster there.
    """
    return jax.lax.platform_dependent(
        y0, a, b, cpu=_prefix_states_in_turn, default=_prefix_states_associative
    )


def _prefix_states_associative(y0, a, b):
    """:func:`_prefix_states` by the associative scan of the compositions
    (:func:`then`)."""
    A, B = jax.lax.associative_scan(then, (a, b))
    return jnp.concatenate([y0[None], A * y0 + B])


def _prefix_states_in_turn(y0, a, b):
    """:func:`_prefix_states` by a loop of the steps ``y -> a_k y + b_k``, in
    the dtype the three promote to (as the associative scan computes)."""

    def step(y, ab):
        y = ab[0] * y + ab[1]
        return y, y

    y0, a, b = (jnp.asarray(x, jnp.result_type(y0, a, b)) for x in (y0, a, b))
    return jnp.concatenate([y0[None], jax.lax.scan(step, y0, (a, b))[1]])


@jax.custom_jvp
def affine_sequence(y0, a, b):
    """``y0`` and the states after each map ``y -> a_k y + b_k`` (leading
    axis ``k``), shape ``(K + 1, ...)`` (:func:`_prefix_states`), with the
    derivative of the recurrence it solves.

    Differentiating ``y_(k+1) = a_k y_k + b_k`` gives ``dy_(k+1) = a_k dy_k +
    (da_k y_k + db_k)``: the same recurrence with new offsets, so the
    tangent is one more scan of the same kind, linear in the tangents.
    JAX's own derivative of the scan would also carry the tangents of every
    product of the ``a_k``, which makes Jacobians and fits slower.
    """
    return _prefix_states(y0, a, b)


@affine_sequence.defjvp
def _affine_sequence_jvp(primals, tangents):
    y0, a, b = primals
    dy0, da, db = tangents
    y = affine_sequence(y0, a, b)
    return y, _prefix_states(dy0, a, da * y[:-1] + db)


def _at(G, t):
    """The input at time ``t``: ``G`` itself, or ``G.evaluate(t)`` for a diffrax path."""
    import diffrax  # (here and below, not at import: it takes a quarter of a second)

    return G.evaluate(t) if isinstance(G, diffrax.AbstractPath) else G


# -- neural adaptation filter (Pattanaik 2000, §4.1.2) ------------------------


def neural(G, t0):
    """Neural adaptation ``dA/dt = (G - A) / t0``.

    Pattanaik et al. (2000), §4.1.2 and Fig. 6: the exponential filter with
    ``J(x) = K(x) = F x``, ``F = 1 - exp(-T / t0)``; ``t0 = 0.150`` s for
    rods and ``0.080`` s for cones.

    Parameters
    ----------
    G : array
        Adaptation goal, cd/m2.
    t0 : array
        Time constant, s.
    """
    return Relaxation(jnp.ones_like(G) / t0, G)


def neural_rhs(t, A, args):
    """Right-hand side of :func:`neural`; ``args = (G, t0)``."""
    G, t0 = args
    return relaxation_rhs(A, neural(_at(G, t), t0))


def neural_step(A, G, t0, dt):
    """Exact neural step: ``A' = G + (A - G) exp(-dt / t0)``."""
    return relaxation_step(A, neural(G, t0), dt)


# -- pigment bleaching and regeneration (Pattanaik 2000, Eq 7) ----------------


def bleaching(G, tau, c):
    """Pigment kinetics ``dB/dt = (1 - B) / tau - B G / c``.

    Pattanaik et al. (2000), Eq 7 and §4.1.2: regeneration with time
    constant ``tau`` (400 s rods, 110 s cones) against depletion at the rate
    ``G / c`` (c = 16 scotopic cd/m2 s for rods, 2.2e8 cd/m2 s for cones).
    As a relaxation::

        k = 1/tau + G/c,    B_inf = (1/tau) / k = 1 / (1 + G tau / c)

    ``B_inf`` is exactly Hunt's static bleaching of Eq 6: ``tau/c = 25`` for
    rods gives ``0.04 / (0.04 + G)`` and ``tau/c = 5e-7`` for cones gives
    ``2e6 / (2e6 + G)``.

    Parameters
    ----------
    G : array
        Adaptation goal, cd/m2 (scotopic cd/m2 for rods).
    tau : array
        Regeneration time constant, s.
    c : array
        Bleaching constant, cd/m2 s.
    """
    rate = 1.0 / tau + G / c
    return Relaxation(rate, (1.0 / tau) / rate)


def bleaching_rhs(t, B, args):
    """Right-hand side of :func:`bleaching`; ``args = (G, tau, c)``."""
    G, tau, c = args
    return relaxation_rhs(B, bleaching(_at(G, t), tau, c))


def bleaching_step(B, G, tau, c, dt):
    """Exact bleaching step for ``G`` held over ``dt``; stays in [0, 1]."""
    return relaxation_step(B, bleaching(G, tau, c), dt)


# -- continuous-time inputs ---------------------------------------------------


def goal_path(ts, values):
    """A continuous input through samples ``values`` at times ``ts`` (s).

    A :class:`diffrax.LinearInterpolation`, to pass as ``G`` in ``args``.
    """
    import diffrax

    return diffrax.LinearInterpolation(ts=jnp.asarray(ts), ys=jnp.asarray(values))


def integrate(rhs, y0, ts, args, *, rtol=None, atol=None, max_steps=65536):
    """Solve ``dy/dt = rhs(t, y, args)`` from ``ts[0]``, saving at ``ts``.

    Uses Kvaerno5, an L-stable implicit Runge-Kutta method, with a PID
    step-size controller: the rod bleaching ODE is stiff at daylight
    (``k = G/16`` is 625 /s at 1e4 cd/m2 against ``1/tau = 1/400`` /s).
    When ``args`` holds :func:`goal_path` paths, their knots are passed to
    the controller as jump times so that steps do not straddle a kink.

    Parameters
    ----------
    rhs : callable
        Right-hand side ``f(t, y, args)``, e.g. :func:`bleaching_rhs`.
    y0 : array
        State at ``ts[0]``.
    ts : array, shape (K,)
        Increasing times, s.
    args : tuple
        Arguments of ``rhs``.
    rtol, atol : float, optional
        Tolerances of the step-size controller. By default ``rtol = max(1e-8,
        1e4 eps)`` and ``atol`` 1/100 of that, for the machine epsilon ``eps``
        of ``ts``'s dtype: 1e-8 and 1e-10 in float64; 1.2e-3 and 1.2e-5 in
        float32, where the implicit stages meet no tighter ones and the
        solver runs out of steps.

    Returns
    -------
    array, shape (K, *y0.shape)
        The state at each of ``ts``.
    """
    import diffrax

    ts = jnp.asarray(ts)
    default = max(1e-8, 1e4 * float(jnp.finfo(ts.dtype).eps))
    rtol = default if rtol is None else rtol
    atol = default / 100 if atol is None else atol
    jumps = [a.ts for a in args if isinstance(a, diffrax.LinearInterpolation)]
    jump_ts = jnp.sort(jnp.concatenate(jumps)) if jumps else None
    controller = diffrax.PIDController(rtol=rtol, atol=atol, jump_ts=jump_ts)
    solution = diffrax.diffeqsolve(
        diffrax.ODETerm(rhs),
        diffrax.Kvaerno5(),
        t0=ts[0],
        t1=ts[-1],
        dt0=None,
        y0=jnp.asarray(y0, dtype=ts.dtype),
        args=args,
        saveat=diffrax.SaveAt(ts=ts),
        stepsize_controller=controller,
        max_steps=max_steps,
    )
    return solution.ys


# -- cone bleaching per L, M, S (Jacobs 2015, Eqs 4-6) ------------------------


def cone_bleaching(I, b1, b2):
    """Photopigment bleaching ``dB/dt = b1 (1 - B) I - b2 B`` (Jacobs 2015, Eq 4).

    ``B`` is the bleached fraction of a cone's pigment (Baylor et al. 1974).
    As a relaxation (Eqs 5-6)::

        k = b1 I + b2,    B_inf = b1 I / (b1 I + b2)

    so that the exact step is Eq 5. Pass ``I`` of shape ``(..., 3)`` and
    ``b1, b2`` of shape ``(3,)`` to treat the L, M and S cones at once
    (Appendix A: ``b1 = (1.2e-3, 1.4e-4, 5.5e-7)`` per cd/m2 s,
    ``b2 = (0.69, 1.4, 5.5)`` per s).

    Parameters
    ----------
    I : array
        Cone excitation, cd/m2 (equal to luminance for white light).
    b1 : array
        Bleaching sensitivity, 1/(cd/m2 s).
    b2 : array
        Regeneration rate, 1/s.

    Examples
    --------
    >>> relax = cone_bleaching(jnp.float32(1e7), 1.2e-3, 0.69)
    >>> round(float(relax.target), 4), float(relax.rate) > 1e4
    (0.9999, True)
    """
    rate = b1 * I + b2
    return Relaxation(rate, b1 * I / rate)


def cone_bleaching_rhs(t, B, args):
    """Right-hand side of :func:`cone_bleaching`; ``args = (I, b1, b2)``."""
    I, b1, b2 = args
    return relaxation_rhs(B, cone_bleaching(_at(I, t), b1, b2))


def cone_bleaching_step(B, I, b1, b2, dt):
    """Exact bleaching step of Eq 5 for ``I`` held over ``dt``; stays in [0, 1]."""
    return relaxation_step(B, cone_bleaching(I, b1, b2), dt)


# -- calcium (Jacobs 2015, Eqs 8-10) ------------------------------------------


def calcium(R, c1, c2):
    """Calcium ``dC/dt = c1 (1 - R) - c2 C`` (Jacobs 2015, Eq 8 with S = 1 - R).

    The fraction of open channels ``S`` is approximated by ``1 - R`` with
    ``R`` the Naka-Rushton response of Eq 1, as the paper does. As a
    relaxation: ``k = c2``, ``C_inf = c1 (1 - R) / c2`` (Eq 10), and the
    exact step is Eq 9. ``C`` lies in ``[0, C_max]``, ``C_max = c1 / c2``
    (total darkness).

    Parameters
    ----------
    R : array
        Photoreceptor response, in [0, 1].
    c1 : array
        Calcium influx rate, 1/s (1; Appendix A).
    c2 : array
        Calcium efflux rate, 1/s (1; Appendix A).

    Examples
    --------
    >>> relax = calcium(jnp.float32(0.25), 1.0, 1.0)
    >>> float(relax.rate), float(relax.target)
    (1.0, 0.75)
    """
    return Relaxation(c2 * jnp.ones_like(R), c1 * (1.0 - R) / c2)


def calcium_rhs(t, C, args):
    """Right-hand side of :func:`calcium`; ``args = (R, c1, c2)``."""
    R, c1, c2 = args
    return relaxation_rhs(C, calcium(_at(R, t), c1, c2))


def calcium_step(C, R, c1, c2, dt):
    """Exact calcium step of Eq 9 for ``R`` held over ``dt``."""
    return relaxation_step(C, calcium(R, c1, c2), dt)


# -- asymmetric log-rate adaptation (Jacobs 2015, Eq 3) ------------------------

#: Half-width (log10 units) of the band around the target inside which
#: :func:`log_adaptation_rhs` slows linearly to zero (see there).
LOG_ADAPTATION_BAND = 1e-6


def log_adaptation_step(A, A_T, a1, a2, dt):
    """Exact step of Eq 3 for a target held over ``dt``: a clamped linear move.

    ``A`` moves towards ``A_T`` at ``a1`` log units per second when it is
    below (adapting to brighter light) and at ``a2`` when above (to darker),
    and stops at the target instead of overshooting it::

        A' = A + clip(A_T - A, -a2 dt, a1 dt)

    This is not a relaxation (the rate does not scale with the distance), so
    it has no :class:`Relaxation`; its continuous-time form is
    :func:`log_adaptation_rhs`.

    Parameters
    ----------
    A : array
        Adaptation state, log10 cd/m2.
    A_T : array
        Target, log10 cd/m2.
    a1, a2 : array
        Rates towards brighter and darker targets, log10 units per s
        (0.75 and 0.2; Appendix A).
    dt : array
        Step, s.

    Examples
    --------
    >>> float(log_adaptation_step(0.0, 2.0, 0.75, 0.2, 1.0))
    0.75
    >>> float(log_adaptation_step(0.0, 0.5, 0.75, 0.2, 1.0))  # no overshoot
    0.5
    >>> round(float(log_adaptation_step(2.0, 0.0, 0.75, 0.2, 1.0)), 6)
    1.8
    """
    return A + jnp.clip(A_T - A, -a2 * dt, a1 * dt)


def log_adaptation_rhs(t, A, args):
    """Right-hand side of Eq 3 for diffrax; ``args = (A_T, a1, a2)`` or
    ``(A_T, a1, a2, band)``.

    Eq 3 is ``dA/dt = a1`` below the target, ``-a2`` above it and 0 at it: a
    discontinuous field on which an ODE solver would chatter. We integrate
    the Lipschitz regularisation::

        dA/dt = a1 clip((A_T - A) / band, 0, 1) - a2 clip((A - A_T) / band, 0, 1)

    equal to Eq 3 more than ``band`` log units from the target; inside, ``A``
    relaxes to the target at the rate ``a / band`` instead of stopping dead,
    so the solution differs from Eq 3 by less than ``band`` (1e-6 log units
    by default). The implicit solver of :func:`integrate` copes with the
    stiff band, but narrower bands need many more steps (raise
    ``max_steps``). ``A_T`` may be a :func:`goal_path`.
    """
    A_T, a1, a2 = args[:3]
    band = args[3] if len(args) > 3 else LOG_ADAPTATION_BAND
    gap = _at(A_T, t) - A
    return a1 * jnp.clip(gap / band, 0.0, 1.0) - a2 * jnp.clip(-gap / band, 0.0, 1.0)
