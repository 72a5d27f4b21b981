"""The kernels of Jacobs et al. (2015): exact steps against diffrax, bounds."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jaxadapt.physiology import kinetics as k

# Appendix A of Jacobs et al. (2015): L, M, S bleaching and regeneration rates.
B1 = jnp.array([1.2e-3, 1.4e-4, 5.5e-7])
B2 = jnp.array([6.9e-1, 1.4, 5.5])
TS = jnp.array([0.0, 0.01, 0.125, 0.5, 1.0, 3.0, 8.0])


@pytest.mark.slow
@pytest.mark.parametrize("I", [0.0, 1e3, 1e5, 1e7])
def test_cone_bleaching_exact_step_matches_diffrax(I):
    B0 = jnp.array([0.2, 0.5, 0.9])
    I3 = jnp.full(3, I)
    reference = k.integrate(k.cone_bleaching_rhs, B0, TS, (I3, B1, B2), rtol=1e-10, atol=1e-12)
    exact = k.cone_bleaching_step(B0, I3, B1, B2, TS[:, None])
    np.testing.assert_allclose(exact, reference, rtol=1e-6, atol=1e-9)


def test_cone_bleaching_fixed_point_is_eq6():
    I = jnp.logspace(-3, 9, 25)[:, None]
    relax = k.cone_bleaching(I, B1, B2)
    np.testing.assert_allclose(relax.target, B1 * I / (B1 * I + B2), rtol=1e-12)
    np.testing.assert_allclose(k.cone_bleaching_rhs(0.0, relax.target, (I, B1, B2)), 0.0, atol=1e-9)


@given(
    B=st.floats(0, 1),
    I=st.floats(0, 1e9),
    dt=st.floats(1e-6, 1e4),
    cone=st.integers(0, 2),
)
def test_cone_bleaching_stays_in_unit_interval_up_to_1e9(B, I, dt, cone):
    for dtype in (jnp.float32, jnp.float64):
        B1_ = float(
            k.cone_bleaching_step(
                dtype(B), dtype(I), B1[cone].astype(dtype), B2[cone].astype(dtype), dtype(dt)
            )
        )
        assert 0.0 <= B1_ <= 1.0


@pytest.mark.slow
def test_cone_bleaching_with_a_flash_path_matches_stepping():
    # A 1/8 s, 1e7 cd/m2 white flash (Fig. 4 of the paper) as a continuous
    # input: diffrax through the piecewise-linear path against exact steps at
    # the path's knots, where the input is constant between knots.
    knots = jnp.array([0.0, 0.125, 0.125 + 1e-9, 3.0])
    I = k.goal_path(knots, jnp.array([1e7, 1e7, 0.0, 0.0])[:, None] * jnp.ones(3))
    ts = jnp.array([0.0, 0.125, 1.0, 2.0, 3.0])
    reference = k.integrate(k.cone_bleaching_rhs, jnp.zeros(3), ts, (I, B1, B2), rtol=1e-10)
    flash = k.cone_bleaching_step(jnp.zeros(3), jnp.full(3, 1e7), B1, B2, 0.125)
    after = k.cone_bleaching_step(flash, 0.0, B1, B2, (ts[1:] - 0.125)[:, None])
    np.testing.assert_allclose(reference[1:], after, rtol=1e-5, atol=1e-7)
    # L and M saturate during the flash, S is about a third bleached (Fig. 4).
    assert flash[0] > 0.999 and flash[1] > 0.998 and 0.3 < flash[2] < 0.45


@pytest.mark.parametrize("R", [0.0, 0.3, 0.99])
def test_calcium_exact_step_matches_diffrax(R):
    c1, c2 = 1.0, 1.0  # Appendix A
    C0 = jnp.array([0.0, 0.4, 1.0])
    reference = k.integrate(k.calcium_rhs, C0, TS, (jnp.full(3, R), c1, c2), rtol=1e-10)
    exact = k.calcium_step(C0, R, c1, c2, TS[:, None])
    np.testing.assert_allclose(exact, reference, rtol=1e-6, atol=1e-9)


def test_calcium_reaches_c_max_in_darkness():
    # Eq 10: C_inf = c1 (1 - R) / c2, equal to C_max = c1 / c2 when R = 0.
    c1, c2 = 2.0, 0.5
    assert float(k.calcium(0.0, c1, c2).target) == pytest.approx(c1 / c2)
    assert float(k.calcium_step(0.0, 0.0, c1, c2, 100.0)) == pytest.approx(c1 / c2)


@pytest.mark.slow
@pytest.mark.parametrize(("A0", "A_T"), [(0.0, 3.0), (3.0, 0.0), (1.0, 1.2), (2.0, 2.0)])
def test_log_adaptation_exact_step_matches_diffrax(A0, A_T):
    a1, a2 = 0.75, 0.2  # Appendix A
    ts = jnp.linspace(0.0, 20.0, 21)
    # The target as an array (not a Python float, which diffrax's filter_jit
    # treats as static): the four cases share one compiled solver.
    args = (jnp.float64(A_T), a1, a2)
    reference = k.integrate(k.log_adaptation_rhs, A0, ts, args, rtol=1e-10, atol=1e-12)
    exact = k.log_adaptation_step(A0, A_T, a1, a2, ts)
    np.testing.assert_allclose(exact, reference, atol=1e-6)


def test_log_adaptation_rates_are_asymmetric_and_do_not_overshoot():
    # Eq 3: 0.75 log units/s up, 0.2 down; the step stops at the target.
    up = k.log_adaptation_step(0.0, 10.0, 0.75, 0.2, jnp.array([1.0, 2.0]))
    down = k.log_adaptation_step(10.0, 0.0, 0.75, 0.2, jnp.array([1.0, 2.0]))
    np.testing.assert_allclose(up, [0.75, 1.5])
    np.testing.assert_allclose(down, [9.8, 9.6])
    assert float(k.log_adaptation_step(0.0, 1.0, 0.75, 0.2, 100.0)) == 1.0
    assert float(k.log_adaptation_step(1.0, 0.0, 0.75, 0.2, 100.0)) == 0.0


@pytest.mark.slow
def test_log_adaptation_steps_converge_to_a_moving_target():
    # A target ramping from 0 to 4 log units over 4 s (at first faster than
    # a1 = 0.75 allows, then held): exact steps with the target held over
    # each frame converge to the diffrax solution of the continuous target.
    knots, values = jnp.array([0.0, 4.0, 10.0]), jnp.array([0.0, 4.0, 4.0])
    ts = jnp.linspace(0.0, 10.0, 11)
    path = k.goal_path(knots, values)
    reference = k.integrate(k.log_adaptation_rhs, 0.0, ts, (path, 0.75, 0.2), rtol=1e-10)

    def held(n):
        dt = 10.0 / n
        targets = jnp.interp(jnp.arange(n) * dt, knots, values)

        def step(A, target):
            A = k.log_adaptation_step(A, target, 0.75, 0.2, dt)
            return A, A

        _, A = jax.lax.scan(step, jnp.float64(0.0), targets)
        return jnp.concatenate([jnp.zeros(1), A])[:: n // 10]

    errors = [float(jnp.max(jnp.abs(held(n) - reference))) for n in (100, 1000)]
    assert errors[1] < errors[0] / 5 and errors[1] < 1e-2
