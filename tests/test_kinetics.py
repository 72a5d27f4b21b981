"""Exact kinetics steps against diffrax, fixed points, and bounds."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxadapt.physiology import kinetics as k
from jaxadapt.physiology.response import bleach_cone, bleach_rod

ROD = (400.0, 16.0)  # tau (s), c (cd/m2 s): Pattanaik 2000, Eq 7
CONE = (110.0, 2.2e8)


@pytest.mark.slow
@pytest.mark.parametrize("G", [0.0, 1e-4, 1.0, 1e3, 1e5, 1e8])
@pytest.mark.parametrize("receptor", [ROD, CONE])
def test_bleaching_exact_step_matches_diffrax(G, receptor):
    ts = jnp.array([0.0, 0.01, 0.1, 1.0, 10.0, 100.0])
    B0 = 0.3
    reference = k.integrate(k.bleaching_rhs, B0, ts, (G, *receptor), rtol=1e-11, atol=1e-13)
    exact = k.bleaching_step(B0, G, *receptor, ts)
    np.testing.assert_allclose(exact, reference, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("t0", [0.150, 0.080])
def test_neural_exact_step_matches_diffrax(t0):
    ts = jnp.linspace(0.0, 1.0, 11)
    reference = k.integrate(k.neural_rhs, 0.01, ts, (1000.0, t0), rtol=1e-11, atol=1e-11)
    np.testing.assert_allclose(k.neural_step(0.01, 1000.0, t0, ts), reference, rtol=1e-6)


def test_bleaching_fixed_point_is_hunts_static_bleaching():
    G = np.logspace(-6, 8, 29)
    np.testing.assert_allclose(k.bleaching(G, *ROD).target, bleach_rod(G), rtol=1e-12)
    np.testing.assert_allclose(k.bleaching(G, *CONE).target, bleach_cone(G), rtol=1e-12)
    for tau_c, static in ((ROD, bleach_rod), (CONE, bleach_cone)):
        assert float(k.bleaching_rhs(0.0, static(G), (G, *tau_c)).max()) == pytest.approx(
            0, abs=1e-15
        )


@settings(max_examples=100)
@given(B=st.floats(0, 1), G=st.floats(0, 1e8), dt=st.floats(1e-6, 1e4))
def test_bleaching_stays_in_unit_interval(B, G, dt):
    for receptor in (ROD, CONE):
        B1 = float(k.bleaching_step(jnp.float32(B), jnp.float32(G), *receptor, jnp.float32(dt)))
        assert 0.0 <= B1 <= 1.0


def _literal_eq7(B, G, tau, c, T, n):
    """The explicit update printed as Eq 7 (and used by pfstmo_pattanaik00)."""
    out = []
    for _ in range(n):
        B = B + T * (1 - B) / tau - T * B * G / c
        out.append(B)
    return np.array(out)


@pytest.mark.parametrize("G", [1000.0, 5000.0])
def test_literal_eq7_update_fails_where_the_exact_step_does_not(G):
    # Rods adapted to 0.01 cd/m2, then a goal of 1000 cd/m2 (the title-page
    # step) or 5000 cd/m2 (the sunlit road of the tunnel), frames 30 ms apart.
    # The explicit update multiplies B by (1 - T G / c) < 0 each frame: at 1000
    # cd/m2 the pigment goes negative, above 2 c / T = 1067 cd/m2 it diverges.
    tau, c = ROD
    B0 = float(bleach_rod(0.01))
    euler = _literal_eq7(B0, G, tau, c, 0.03, 20)
    assert euler.min() < 0
    if G > 2 * c / 0.03:
        assert abs(euler[-1]) > 1e6
    exact = np.array([float(k.bleaching_step(B0, G, tau, c, 0.03 * (i + 1))) for i in range(20)])
    assert np.all((exact >= 0) & (exact <= 1))
    assert exact[-1] == pytest.approx(float(bleach_rod(G)), rel=1e-3)


@pytest.mark.slow
def test_exact_steps_converge_to_the_continuous_solution():
    # A goal ramping from 1 to 1e4 cd/m2 over 2 s: holding it constant over
    # frames of dt converges to the diffrax solution with a linear input, at
    # first order in dt.
    ts = jnp.array([0.0, 2.0])
    path = k.goal_path(ts, jnp.array([1.0, 1e4]))
    B0 = float(bleach_rod(1.0))
    reference = float(
        k.integrate(k.bleaching_rhs, B0, ts, (path, *ROD), rtol=1e-11, atol=1e-14)[-1]
    )
    errors = []
    for n in (10, 100, 1000):
        dt = 2.0 / n
        midpoints = jax.vmap(path.evaluate)((jnp.arange(n) + 0.5) * dt)
        B = jax.lax.fori_loop(
            0, n, lambda i, B, dt=dt, G=midpoints: k.bleaching_step(B, G[i], *ROD, dt), B0
        )
        errors.append(abs(float(B) - reference))
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 1e-3 * reference


@pytest.mark.parametrize("dtype, rtol", [(jnp.float64, 1e-12), (jnp.float32, 1e-5)])
def test_relaxation_sequence_equals_a_loop_of_steps(dtype, rtol):
    """The sequence gives the states of T dependent exact steps,
    for goals over 12 decades (bright steps included) and per-pixel maps:
    to rounding in float64, and in float32 to the float64 loop."""
    rng = np.random.default_rng(3)
    G = jnp.asarray(10.0 ** rng.uniform(-4, 8, (37, 2, 3)), dtype)
    dt = jnp.asarray(rng.uniform(0.001, 5.0, 37), dtype)
    B0 = jnp.asarray(0.7, dtype)
    law = k.bleaching(G, *(jnp.asarray(v, dtype) for v in ROD))
    states = k.relaxation_sequence(B0, law, dt)
    law64 = jax.tree.map(lambda x: x.astype(jnp.float64), law)
    B, loop = jnp.broadcast_to(B0, G.shape[1:]).astype(jnp.float64), [B0]
    for i in range(G.shape[0]):
        B = k.relaxation_step(B, k.Relaxation(law64.rate[i], law64.target[i]), float(dt[i]))
        loop.append(B)
    loop = jnp.stack([jnp.broadcast_to(b, G.shape[1:]) for b in loop])
    assert states.shape == (38, 2, 3) and states.dtype == dtype
    np.testing.assert_allclose(states, loop, rtol=rtol, atol=10 * float(jnp.finfo(dtype).tiny))
    assert bool(jnp.all((states >= 0) & (states <= 1)))


def test_a_rate_per_step_broadcasts_over_a_map_of_targets():
    # With one rate per step and a map of targets, each step's duration
    # goes with its step, not with the map's last axis (of the same length
    # T here), as the rate's axes alone would pair them.
    rng = np.random.default_rng(8)
    rate = jnp.asarray(rng.uniform(0.1, 3.0, 3))
    target = jnp.asarray(rng.uniform(0.0, 1.0, (3, 2, 3)))
    dt = jnp.asarray([0.1, 0.7, 2.0])
    states = k.relaxation_sequence(0.5, k.Relaxation(rate, target), dt)
    y, loop = jnp.full((2, 3), 0.5), [jnp.full((2, 3), 0.5)]
    for i in range(3):
        y = k.relaxation_step(y, k.Relaxation(rate[i], target[i]), dt[i])
        loop.append(y)
    np.testing.assert_allclose(states, jnp.stack(loop), rtol=1e-13)
    with pytest.raises(ValueError, match=r"dt: expected shape \(T,\)"):
        k.relaxation_sequence(0.5, k.Relaxation(rate, target), 0.1)


@pytest.mark.slow
def test_integrate_meets_its_default_tolerances_in_float32():
    # The float64 defaults (1e-8, 1e-10) cannot be met in float32: the
    # solver would run out of steps. Float32 times get tolerances it can meet.
    ts = jnp.asarray([0.0, 0.01, 0.1, 1.0, 10.0, 100.0], jnp.float32)
    G = jnp.asarray([0.0, 1.0, 1e5, 1e8], jnp.float32)  # one solve of four states
    y0 = jnp.full(4, 0.3, jnp.float32)
    laws = (
        (k.neural_rhs, (G, 0.15), k.neural_step(y0, G, 0.15, ts[:, None])),
        (k.bleaching_rhs, (G, *ROD), k.bleaching_step(y0, G, *ROD, ts[:, None])),
        (k.bleaching_rhs, (G, *CONE), k.bleaching_step(y0, G, *CONE, ts[:, None])),
    )
    for rhs, args, exact in laws:
        solved = k.integrate(rhs, y0, ts, args)
        assert solved.dtype == jnp.float32
        np.testing.assert_allclose(solved, exact, rtol=1e-2, atol=1e-4)


def test_integrate_steps_to_the_knots_of_every_path():
    # dy/dt = p(t) + q(t) for two piecewise-linear inputs whose kinks are at
    # different times: the integral of their sum, exactly, with a step
    # ending on every kink of either.
    p = k.goal_path([0.0, 0.3, 1.0], [0.0, 3.0, 0.0])
    q = k.goal_path([0.0, 0.71, 1.0], [1.0, -2.0, 5.0])
    solved = k.integrate(
        lambda t, y, args: args[0].evaluate(t) + args[1].evaluate(t),
        0.0,
        jnp.asarray([0.0, 1.0]),
        (p, q),
        rtol=1e-12,
        atol=1e-14,
    )
    exact = 0.5 * 3.0 * 1.0 + (0.5 * (1.0 - 2.0) * 0.71 + 0.5 * (-2.0 + 5.0) * 0.29)
    # (to the tolerances asked of the solver: only rounding is left)
    np.testing.assert_allclose(float(solved[-1]), exact, rtol=1e-12, atol=1e-14)


def test_both_forms_of_the_prefix_states_agree():
    # The CPU runs the steps in turn, other platforms the associative scan
    # (_prefix_states' notes): the same states, for one step and for many,
    # scalars and maps per step.
    rng = np.random.default_rng(5)
    for shape in ((1,), (1, 2, 3), (37,), (64, 4, 5)):
        a = jnp.asarray(rng.uniform(0.0, 1.0, shape))
        b = jnp.asarray(rng.uniform(0.0, 2.0, shape))
        y0 = jnp.asarray(rng.uniform(0.0, 1.0, shape[1:]))
        in_turn, associative = (
            jax.jit(f)(y0, a, b) for f in (k._prefix_states_in_turn, k._prefix_states_associative)
        )
        assert in_turn.shape == (shape[0] + 1, *shape[1:])
        np.testing.assert_allclose(in_turn, associative, rtol=1e-13)
    # A float32 start with float64 steps promotes, in both forms.
    y0, a, b = jnp.float32(0.5), jnp.full(3, 0.5), jnp.ones(3)
    for form in (k._prefix_states_in_turn, k._prefix_states_associative):
        assert form(y0, a, b).dtype == jnp.float64
    law = k.Relaxation(jnp.ones(3), jnp.ones(3))
    assert k.relaxation_sequence(jnp.float32(0.5), law, np.full(3, 0.1)).dtype == jnp.float64


@pytest.mark.slow
@pytest.mark.parametrize("size", [(), (3, 2), (40, 40)])
def test_several_sequences_at_once_equal_each_on_its_own(size):
    """relaxation_sequences gives each state's relaxation_sequence, and the
    same derivatives: stacked (scalars and small maps, the 2000 operator's
    global state) and one by one (maps above SMALL_STATE), with scalar and
    map goals side by side."""
    rng = np.random.default_rng(6)
    assert (4 * math.prod(size) > k.SMALL_STATE) == (size == (40, 40))
    dt = jnp.asarray(rng.uniform(0.01, 2.0, 19))
    G = jnp.asarray(10.0 ** rng.uniform(-4, 6, (19, *size)))
    y0s = [jnp.asarray(0.2), jnp.asarray(rng.uniform(0, 1, size)), jnp.asarray(0.9), 0.5]

    def laws(t0):
        return [
            k.neural(G.reshape(19, -1)[:, 0], t0),
            k.neural(G, 2 * t0),
            k.bleaching(G, *ROD),
            k.bleaching(G.reshape(19, -1)[:, 0], *CONE),
        ]

    def together(t0):
        return k.relaxation_sequences(y0s, laws(t0), dt)

    def apart(t0):
        return [k.relaxation_sequence(y, law, dt) for y, law in zip(y0s, laws(t0), strict=True)]

    def like(x, y):  # a state of scalars next to the stacked maps' shape
        return jnp.broadcast_to(x.reshape(x.shape + (1,) * (y.ndim - x.ndim)), y.shape)

    for y, y_apart in zip(together(0.15), apart(0.15), strict=True):
        np.testing.assert_allclose(y, like(y_apart, y), rtol=1e-13)
    for dy, dy_apart in zip(jax.jacfwd(together)(0.15), jax.jacfwd(apart)(0.15), strict=True):
        np.testing.assert_allclose(dy, like(dy_apart, dy), rtol=1e-12)


@pytest.mark.slow
def test_relaxation_sequence_derivatives_equal_those_of_a_loop_of_steps():
    """The scan's own derivative rule (forward and reverse mode) against
    JAX's derivative of a loop of exact steps, with respect to the start,
    the rates, the targets and the durations (float64)."""
    rng = np.random.default_rng(4)
    rate, target = (jnp.asarray(rng.uniform(0.01, 3.0, (9, 2))) for _ in range(2))
    dt = jnp.asarray(rng.uniform(0.01, 2.0, 9))
    y0 = jnp.asarray([0.3, 1.5])

    def scan(y0, rate, target, dt):
        return k.relaxation_sequence(y0, k.Relaxation(rate, target), dt)

    def loop(y0, rate, target, dt):
        ys = [y0]
        for i in range(dt.shape[0]):
            ys.append(k.relaxation_step(ys[-1], k.Relaxation(rate[i], target[i]), dt[i]))
        return jnp.stack(ys)

    # Each derivative compiled as a whole: run op by op, the loop's
    # derivatives would take 50 s of dispatch (for the same numbers).
    inputs = (y0, rate, target, dt)
    for derivative in (jax.jacfwd, jax.jacrev):
        ours = jax.jit(derivative(scan, argnums=(0, 1, 2, 3)))(*inputs)
        theirs = jax.jit(derivative(loop, argnums=(0, 1, 2, 3)))(*inputs)
        for a, b in zip(ours, theirs, strict=True):
            assert float(jnp.max(jnp.abs(b))) > 0
            np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-13)
    second = jax.jit(jax.hessian(lambda r: jnp.sum(scan(y0, r, target, dt) ** 2)))(rate)
    expected = jax.jit(jax.hessian(lambda r: jnp.sum(loop(y0, r, target, dt) ** 2)))(rate)
    np.testing.assert_allclose(second, expected, rtol=1e-9, atol=1e-12)
