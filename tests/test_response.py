"""Static response laws against the paper's published constants and colour-science."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from colour.appearance.hunt import luminance_level_adaptation_factor
from hypothesis import given
from hypothesis import strategies as st

from jaxadapt.physiology import response as r

LUMINANCE = st.floats(1e-6, 1e8)


def test_display_constants_of_the_paper():
    # Pattanaik et al. 2000, §4.3: the display observer adapted to 25 cd/m2.
    assert float(r.sigma_cone(25.0)) == pytest.approx(646, abs=0.5)
    assert float(r.sigma_rod(25.0)) == pytest.approx(722, abs=0.5)
    assert float(r.bleach_rod(25.0)) == pytest.approx(0.0016, abs=5e-6)
    S_d = r.forward_difference_slope(125.0, 125.0 / 32, r.sigma_cone(25.0), 1.0)
    assert float(S_d) == pytest.approx(0.1383, abs=5e-5)


def test_eq4_as_printed_differs_from_the_table_by_reference_white():
    # The printed numerator 2.5874 A gives 145 cd/m2 at 25 cd/m2, a fifth of the
    # table's 722: we follow the table (see sigma_rod's docstring).
    printed = 2.5874 * 25.0 / float(r.hunt_F_LS(25.0) / 5.0**0)  # 2.5874 A / (...)
    assert printed == pytest.approx(float(r.sigma_rod(25.0)) / 5.0, rel=2e-3)


def test_cone_sigma_matches_eq5_and_colour_science_F_L():
    A = np.logspace(-6, 8, 57)
    F_L = luminance_level_adaptation_factor(A)  # colour-science's Hunt model
    np.testing.assert_allclose(r.hunt_F_L(A), F_L, rtol=1e-12)
    k4 = (1 / (5 * A + 1)) ** 4
    eq5 = 12.9223 * A / (k4 * A + 0.171 * (1 - k4) ** 2 * A ** (1 / 3))
    np.testing.assert_allclose(r.sigma_cone(A), eq5, rtol=2e-4)


def test_rod_sigma_is_eq4_with_the_reference_white_numerator():
    A = np.logspace(-6, 8, 57)
    j2 = (1 / (5e5 * A + 1)) ** 2
    eq4_denominator = 19000 * j2 * A + 0.2615 * (1 - j2) ** 4 * A ** (1 / 6)
    np.testing.assert_allclose(r.sigma_rod(A), 12.9223 * A / eq4_denominator, rtol=2e-4)


def test_static_bleaching_eq6():
    A = np.logspace(-6, 8, 15)
    np.testing.assert_allclose(r.bleach_cone(A), 2e6 / (2e6 + A))
    np.testing.assert_allclose(r.bleach_rod(A), 0.04 / (0.04 + A))


@given(L=LUMINANCE, sigma=st.floats(1e-4, 1e6), B=st.floats(0.01, 1.0))
def test_inverse_undoes_the_response(L, sigma, B):
    R = r.naka_rushton(L, sigma, B)
    if float(R) < B * (1 - 1e-9):  # not saturated to machine precision
        assert float(r.naka_rushton_inverse(R, sigma, B)) == pytest.approx(L, rel=1e-6)


def test_inverses_outside_their_range_are_nan_not_black():
    # A response beyond saturation (or negative) has no luminance: NaN, not
    # the 0 cd/m2 of a power() that maps a negative base to 0. NaN goes in
    # and out of power.
    for R, expected in ((0.6, np.nan), (-0.1, np.nan), (0.5, np.inf), (0.0, 0.0)):
        np.testing.assert_equal(float(r.naka_rushton_inverse(R, 2.0, B=0.5)), expected)
    for R, expected in ((1.1, np.nan), (-0.1, np.nan), (1.0016, np.inf), (0.0, 0.0)):
        L = r.naka_rushton_sum_inverse(jnp.asarray(R), 722.0, 0.0016, 646.0, 1.0)
        np.testing.assert_equal(float(L), expected)
    for x, expected in ((np.nan, np.nan), (-1.0, np.nan), (0.0, 0.0), (8.0, 2.0)):
        np.testing.assert_allclose(float(r.power(x, 1 / 3)), expected, rtol=1e-12)
    assert np.isnan(float(r.naka_rushton(np.nan, 1.0)))


@given(L1=LUMINANCE, L2=LUMINANCE, A=LUMINANCE)
def test_response_is_monotone_and_bounded(L1, L2, A):
    lo, hi = sorted((L1, L2))
    R_lo = r.naka_rushton(lo, r.sigma_cone(A), r.bleach_cone(A))
    R_hi = r.naka_rushton(hi, r.sigma_cone(A), r.bleach_cone(A))
    assert 0 <= float(R_lo) <= float(R_hi) <= float(r.bleach_cone(A))


def test_slope_is_the_derivative_per_log10_unit():
    sigma, B = 40.0, 0.8

    def R_of_log10(u):
        return r.naka_rushton(10.0**u, sigma, B)

    for u in np.linspace(-3, 5, 9):
        assert float(r.response_slope(10.0**u, sigma, B)) == pytest.approx(
            float(jax.grad(R_of_log10)(u)), rel=1e-10
        )


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_semi_saturation_in_the_dark_is_its_limit(dtype):
    # 5A / F(A) is 0/0 at A = 0: the dark value is the limit, not NaN,
    # 2^(1/n) / 0.2 for cones and 2^(1/n) / 3800 for rods.
    A = jnp.array([0.0, 1e-15], dtype)
    for f, dark in ((r.sigma_cone, 12.9223), (r.sigma_rod, 12.9223 / 19000)):
        sigma = f(A)
        assert sigma.dtype == dtype
        np.testing.assert_allclose(sigma, dark, rtol=1e-4)
        assert jnp.isfinite(jax.grad(lambda a, f=f: f(a))(jnp.asarray(0.0, dtype)))


def test_extremes_are_finite_in_float32():
    L = jnp.array([0.0, 1e-6, 1.0, 1e8], dtype=jnp.float32)
    A = jnp.array([1e-6, 1e-2, 1e4, 1e8], dtype=jnp.float32)
    for f in (r.sigma_rod, r.sigma_cone, r.bleach_rod, r.bleach_cone):
        assert jnp.all(jnp.isfinite(f(A))) and f(A).dtype == jnp.float32
    R = r.naka_rushton(L[:, None], r.sigma_cone(A)[None], 1.0)
    assert R.dtype == jnp.float32 and jnp.all(jnp.isfinite(R))
