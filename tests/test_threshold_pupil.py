"""Thresholds and the pupil: chapter 6 of Reinhard et al., HDR Imaging, §6.2."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jaxadapt.physiology import pupil, threshold
from jaxadapt.physiology.response import naka_rushton, naka_rushton_inverse

LUMINANCES = np.logspace(-6, 8, 57)


# -- Rushton and MacLeod's TVI curves (Fig 6.7) -------------------------------


def test_tvi_curves_published_constants():
    # Chapter §6.2.2: dI = 0.1 (I + 0.015) (rods), 0.02 (I + 8) (cones), in td.
    assert float(threshold.tvi_rod(0.0)) == pytest.approx(0.0015)
    assert float(threshold.tvi_cone(0.0)) == pytest.approx(0.16)
    bright = 1e8
    assert float(threshold.tvi_rod(bright)) / bright == pytest.approx(0.1, rel=1e-9)
    assert float(threshold.tvi_cone(bright)) / bright == pytest.approx(0.02, rel=1e-6)


def test_rods_below_the_crossing_cones_above():
    crossing = 0.1585 / 0.08  # 0.1 (I + 0.015) = 0.02 (I + 8)
    assert float(threshold.tvi_rod(crossing)) == pytest.approx(float(threshold.tvi_cone(crossing)))
    below, above = crossing / 10, crossing * 10
    assert float(threshold.tvi_rod_cone(below)) == float(threshold.tvi_rod(below))
    assert float(threshold.tvi_rod_cone(above)) == float(threshold.tvi_cone(above))


def test_troland_definition():
    # 1 td: 1 cd/m2 through a pupil of 1 mm2.
    d_one_mm2 = 2.0 / np.sqrt(np.pi)
    assert float(threshold.trolands(1.0, d_one_mm2)) == pytest.approx(1.0)
    assert float(pupil.area(d_one_mm2)) == pytest.approx(1.0)


def test_tvi_luminance_is_weber_for_cones_and_uses_the_pupil():
    L = jnp.asarray([1e3, 1e5])
    np.testing.assert_allclose(threshold.tvi_luminance(L) / L, 0.02, rtol=5e-3)
    # In the dark, the rod threshold through the dark-adapted pupil.
    A = float(pupil.area(4.9 + 3 * np.tanh(2.0)))  # Moon and Spencer at 1e-6 cd/m2
    dark = float(threshold.tvi_luminance(1e-6))
    assert dark == pytest.approx(0.1 * (1e-6 * A + 0.015) / A, rel=1e-9)


def test_blackwell_tvi_of_ward_1994():
    # Ward (1994): dL = 0.0594 (1.219 + L^0.4)^2.5.
    assert float(threshold.tvi_blackwell(0.0)) == pytest.approx(0.0594 * 1.219**2.5)
    assert float(threshold.tvi_blackwell(100.0)) == pytest.approx(
        0.0594 * (1.219 + 100**0.4) ** 2.5
    )


def test_tvi_models_are_increasing_and_finite():
    for name, tvi in threshold.TVI_MODELS.items():
        t = np.asarray(tvi(jnp.asarray(LUMINANCES)))
        assert np.all(np.isfinite(t)) and np.all(t > 0), name
        assert np.all(np.diff(t) > 0), name


# -- pupil (§6.2.2) --------------------------------------------------------------


def test_moon_spencer_range_and_midpoint():
    # The chapter: "from a minimum of about 2 mm in bright light to a
    # maximum of about 8 mm in darkness"; the tanh is centred at 0.1 cd/m2.
    assert float(pupil.diameter_moon_spencer(0.1)) == pytest.approx(4.9)
    assert float(pupil.diameter_moon_spencer(1e30)) == pytest.approx(1.9, abs=1e-6)
    assert float(pupil.diameter_moon_spencer(0.0)) == pytest.approx(7.9)
    # Psychtoolbox's PupilDiameterFromLum('MoonSpencer'), worked by hand:
    # 4.9 - 3 tanh(0.4 * 3) at 100 cd/m2.
    assert float(pupil.diameter_moon_spencer(100.0)) == pytest.approx(4.9 - 3 * np.tanh(1.2))


def test_de_groot_gebhard_against_watson_yellott_form():
    # Watson and Yellott (2012) write de Groot and Gebhard's formula as
    # 7.175 exp(-0.00092 (x)^3): the same curve with natural exponentials
    # (10^0.8558 = 7.175, 4.01e-4 ln 10 = 0.000923, which they round to
    # 0.00092: 0.6 % apart at 1e4 cd/m2) -- a check of our constants.
    L = np.logspace(-6, 4, 41)
    x = np.log10(L) + 8.6
    expected = 7.175 * np.exp(-0.00092 * x**3)
    np.testing.assert_allclose(pupil.diameter_de_groot_gebhard(jnp.asarray(L)), expected, rtol=1e-2)


def test_de_groot_gebhard_held_at_its_maximum_in_the_dark():
    top = 10**0.8558
    for L in (0.0, 1e-12, pupil.DE_GROOT_GEBHARD_DARK):
        assert float(pupil.diameter_de_groot_gebhard(L)) == pytest.approx(top)


@pytest.mark.parametrize("name", sorted(pupil.DIAMETERS))
def test_pupil_in_the_dark_has_a_finite_derivative(name):
    # Moon and Spencer's log10(0) = -inf would make the derivative at L = 0 NaN.
    for dtype in (jnp.float32, jnp.float64):
        L = jnp.asarray(0.0, dtype)
        assert float(jax.grad(pupil.DIAMETERS[name])(L)) == 0.0
        assert np.isfinite(float(pupil.DIAMETERS[name](L)))


@pytest.mark.parametrize("name", sorted(pupil.DIAMETERS))
def test_pupil_diameters_shrink_with_luminance(name):
    d = np.asarray(pupil.DIAMETERS[name](jnp.asarray(LUMINANCES)))
    assert np.all(np.isfinite(d)) and np.all(d > 0)
    assert np.all(np.diff(d) < 0)
    assert d[0] < 8.0


@given(st.floats(1e-6, 1e8))
def test_pupil_and_trolands_finite_everywhere(L):
    for diameter in pupil.DIAMETERS.values():
        T = threshold.trolands(L, diameter(L))
        assert np.isfinite(float(T)) and float(T) > 0


def test_float32_in_float32_out():
    L = jnp.asarray([0.0, 1.0, 1e4], dtype=jnp.float32)
    for f in (
        pupil.diameter_moon_spencer,
        pupil.diameter_de_groot_gebhard,
        threshold.tvi_luminance,
        threshold.tvi_blackwell,
        threshold.tvi_rod_cone,
    ):
        assert f(L).dtype == jnp.float32, f.__name__
    args = jnp.float32(10.0), jnp.float32(10.0), jnp.float32(0.01)
    assert threshold.increment_threshold(*args).dtype == jnp.float32


# -- the response-threshold relation (§6.2.4) ------------------------------------


@given(
    I_b=st.floats(0.0, 1e4),
    sigma_b=st.floats(1e-2, 1e4),
    n=st.floats(0.5, 1.0),
    delta=st.floats(1e-3, 0.05),
)
def test_threshold_is_delta_over_the_slope_of_the_response(I_b, sigma_b, n, delta):
    """The chapter's dI = delta dI/dR at R = R_b + delta: check against a central
    finite difference of the Naka-Rushton response itself at that point."""
    R_b = float(naka_rushton(I_b, sigma_b, 1.0, n))
    if R_b + delta >= 0.95:
        return  # near saturation the criterion has no room
    I = float(naka_rushton_inverse(R_b + delta, sigma_b, 1.0, n))
    h = 1e-6 * I
    slope = (naka_rushton(I + h, sigma_b, 1.0, n) - naka_rushton(I - h, sigma_b, 1.0, n)) / (2 * h)
    expected = delta / float(slope)
    got = float(threshold.increment_threshold(I_b, sigma_b, delta, 1.0, n))
    assert got == pytest.approx(expected, rel=1e-6)


def test_threshold_converges_to_the_exact_increment_as_delta_shrinks():
    """The exact increment I(R_b + delta) - I_b agrees with the first-order
    formula to O(delta)."""
    I_b, sigma_b, n = 30.0, 100.0, 0.73
    R_b = naka_rushton(I_b, sigma_b, 1.0, n)
    errors = []
    for delta in (1e-2, 1e-3, 1e-4):
        exact = naka_rushton_inverse(R_b + delta, sigma_b, 1.0, n) - I_b
        approx = threshold.increment_threshold(I_b, sigma_b, delta, 1.0, n)
        errors.append(abs(float(approx / exact) - 1.0))
    assert errors[0] < 0.05
    assert errors[1] == pytest.approx(errors[0] / 10, rel=0.2)
    assert errors[2] == pytest.approx(errors[1] / 10, rel=0.2)


def test_weber_law_for_n_one_and_sigma_equal_background():
    """The chapter: for n = 1 and I_b = sigma_b, dI / dI_dark is proportional
    to I_b (Weber's law)."""
    I_b = jnp.logspace(-3, 6, 19)
    sigma_dark, delta = 0.5, 0.01
    relative = threshold.relative_threshold(I_b, I_b, sigma_dark, delta, 1.0, 1.0)
    ratio = np.asarray(relative / I_b)
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-10)
    # the exact first line: (I_b / sigma_dark) ((1 - delta) / (1/2 - delta))^2
    np.testing.assert_allclose(ratio[0], ((1 - delta) / (0.5 - delta)) ** 2 / sigma_dark)
    # the closed form of the last line: 4 I_b / sigma_dark
    small = threshold.relative_threshold_small_delta(I_b, I_b, sigma_dark, delta, 1.0, 1.0)
    np.testing.assert_allclose(small, 4 * I_b / sigma_dark, rtol=1e-12)
    # and the Weber fraction dI / I_b is constant
    weber = np.asarray(threshold.increment_threshold(I_b, I_b, delta, 1.0, 1.0) / I_b)
    np.testing.assert_allclose(weber, weber[0], rtol=1e-10)


def test_small_delta_form_matches_the_exact_ratio_when_delta_is_small():
    I_b = jnp.logspace(0, 4, 9)
    sigma_b, sigma_dark, n = I_b**0.8, 3.0, 0.73
    delta = 1e-5
    exact = threshold.relative_threshold(I_b, sigma_b, sigma_dark, delta, 1.0, n)
    small = threshold.relative_threshold_small_delta(I_b, sigma_b, sigma_dark, delta, 1.0, n)
    np.testing.assert_allclose(small, exact, rtol=1e-3)


def test_dark_adapted_relative_threshold_is_one():
    assert float(threshold.relative_threshold(0.0, 2.0, 2.0, 0.01)) == pytest.approx(1.0)


def test_thresholds_jit_and_vmap_equal_eager():
    I_b = jnp.logspace(-2, 4, 7)
    sigma = 1.0 + I_b
    eager = threshold.relative_threshold(I_b, sigma, 1.0, 0.01)
    jitted = jax.jit(threshold.relative_threshold)(I_b, sigma, 1.0, 0.01)
    mapped = jax.vmap(threshold.relative_threshold, in_axes=(0, 0, None, None))(
        I_b, sigma, 1.0, 0.01
    )
    np.testing.assert_allclose(jitted, eager, rtol=1e-12)
    np.testing.assert_allclose(mapped, eager, rtol=1e-12)
