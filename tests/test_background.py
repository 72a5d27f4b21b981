"""Background-luminance estimators and the filters under them (chapter 6, §6.4)."""

import functools

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.ndimage as ndi
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from jaxadapt import background as bg
from jaxadapt import spatial
from jaxadapt.operators import goal

LOCAL = ("box", "gaussian", "bilateral", "adaptive", "multiscale")
#: One image shape for the estimator tests, so that their compilations are shared.
SHAPE = (2, 9, 13)


def hdr_edge(H=32, W=64, texture=0.1, bright=1e4):
    """A textured 1 cd/m2 left half beside a ``bright`` cd/m2 right half."""
    yy, xx = np.mgrid[:H, :W]
    pattern = 1.0 + texture * np.sin(1.3 * xx) * np.cos(0.7 * yy)
    return jnp.asarray(np.where(xx < W // 2, 1.0, bright) * pattern), pattern


# -- the filters ------------------------------------------------------------------


@pytest.mark.parametrize("radius", [0, 1, 3, 6])
def test_box_filter_equals_scipy_uniform_filter(radius):
    # SciPy's "mirror" extension is NumPy's "reflect": about the edge pixel.
    x = np.random.default_rng(radius).random((2, 17, 23))
    expected = ndi.uniform_filter(x, size=(1, 2 * radius + 1, 2 * radius + 1), mode="mirror")
    np.testing.assert_allclose(spatial.box_filter(jnp.asarray(x), radius), expected, rtol=1e-12)


def test_box_filter_larger_than_the_image():
    """Kernel sizes larger than the image: the mirror extension is repeated."""
    x = np.random.default_rng(1).random((5, 4))
    r = 11
    padded = np.pad(x, r, mode="reflect")
    expected = np.array(
        [[padded[i : i + 2 * r + 1, j : j + 2 * r + 1].mean() for j in range(4)] for i in range(5)]
    )
    np.testing.assert_allclose(spatial.box_filter(jnp.asarray(x), r), expected, rtol=1e-12)


def test_box_filter_keeps_dark_pixels_accurate_in_float32():
    """Partial sums cover the window only: a 1e5 cd/m2 region far away does not
    swamp a 1e-3 cd/m2 one in float32 (a summed-area table would)."""
    x = np.full((8, 4000), 1e-3, dtype=np.float32)
    x[:, :100] = 1e5
    out = np.asarray(spatial.box_filter(jnp.asarray(x), 20))
    np.testing.assert_allclose(out[:, 200:-200], 1e-3, rtol=1e-5)


def test_iterated_box_variance_and_shape():
    impulse = jnp.zeros((1, 101)).at[0, 50].set(1.0)
    for r in (1, 3, 7):
        kernel = np.asarray(jax.jit(spatial.iterated_box_filter, static_argnums=1)(impulse, r))[0]
        x = np.arange(101) - 50
        assert kernel.sum() == pytest.approx(1.0)
        assert (kernel * x * x).sum() == pytest.approx(r * (r + 1))
        gauss = np.exp(-(x**2) / (2 * r * (r + 1)))
        gauss /= gauss.sum()
        assert np.abs(kernel - gauss).max() < 0.09 * gauss.max()


def test_lowpass_stack_levels():
    x = jnp.asarray(np.random.default_rng(2).random((3, 20, 30)))
    stack = jax.jit(spatial.lowpass_stack, static_argnums=1)(x, (0, 1, 3, 7))
    assert stack.shape == (3, 4, 20, 30)
    np.testing.assert_allclose(stack[:, 0], x)  # radius 0 is the image itself
    assert np.all(np.diff(stack.std(axis=(-2, -1)), axis=-1) < 0)  # smoother at each level


def test_bilateral_equals_opencv():
    """Gaussian spatial and intensity weights on a disc: cv2.bilateralFilter
    with the same window (float32; OpenCV interpolates its range weights from
    a table, hence the tolerance)."""
    rng = np.random.default_rng(3)
    log_l = rng.normal(size=(40, 50)).astype(np.float32)
    s, sigma_r = 2.5, 0.6
    R = spatial.gaussian_window(s).shape[0] // 2  # ceil(2 s / sqrt(2)) = 4
    ours = spatial.bilateral_filter(jnp.asarray(log_l), s, sigma_r)
    theirs = cv2.bilateralFilter(
        log_l, 2 * R + 1, sigma_r, s / np.sqrt(2), borderType=cv2.BORDER_REFLECT_101
    )
    np.testing.assert_allclose(ours, theirs, atol=2e-5)


@pytest.mark.parametrize("spatial_kind", sorted(spatial.SPATIAL_WINDOWS))
def test_bilateral_with_flat_intensity_weight_is_the_windowed_average(spatial_kind):
    x = np.random.default_rng(4).random((15, 18))
    window = spatial.SPATIAL_WINDOWS[spatial_kind](3.0)
    expected = ndi.correlate(x, window / window.sum(), mode="mirror")
    got = spatial.bilateral_filter(jnp.asarray(x), 3.0, 1e9, spatial=spatial_kind)
    np.testing.assert_allclose(got, expected, rtol=1e-9)


def test_windows_follow_the_chapter():
    w = spatial.gaussian_window(2.0)
    assert w[w.shape[0] // 2, w.shape[0] // 2 + 1] == pytest.approx(np.exp(-1 / 4))
    disc = spatial.disc_window(2.0)
    assert disc.shape == (3, 3) and disc.sum() == 9  # ||p - i|| < 2
    assert spatial.disc_window(2.5).sum() == 21 and spatial.disc_window(1.0).sum() == 1


# -- the estimators ---------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(bg.BACKGROUNDS))
def test_constant_image_gives_its_luminance(name):
    """Every estimator reduces to the global mean on a constant image, also with
    neighbourhoods larger than the image."""
    L = jnp.asarray(np.full(SHAPE, 37.0))
    np.testing.assert_allclose(bg.BACKGROUNDS[name](L), 37.0, rtol=1e-12)


def test_box_sizes_follow_the_chapter_box_as_the_octaves_do():
    # ||p - i|| < s made square: half-width ceil(s) - 1, the largest whole
    # offset below s, as each level of octave_radii (round(s) would give a
    # box two pixels wider, and round(4.2) - 1 would leave offset 4 out).
    L = np.random.default_rng(7).lognormal(size=(9, 13))
    np.testing.assert_array_equal(bg.box_background(jnp.asarray(L), scale=1), L)
    expected = ndi.uniform_filter(L, size=2 * 4 + 1, mode="mirror")
    np.testing.assert_allclose(bg.box_background(jnp.asarray(L), scale=4.2), expected, rtol=1e-12)
    assert bg.octave_radii(4.2, 2)[0] == bg.box_radius(4.2) == 4
    assert bg.box_radius(4.0) == 3


@pytest.mark.slow
@pytest.mark.parametrize("name", LOCAL)
def test_backgrounds_differentiate_under_jit(name):
    # The box sums' reduce_window needs a constant initial value: with a
    # traced one JAX takes the generic reduce_window, which it cannot
    # transpose, and jax.grad fails for box, adaptive and multiscale (they
    # are jitted).
    rng = np.random.default_rng(8)
    L, v, w = (jnp.asarray(rng.lognormal(size=SHAPE)) for _ in range(3))

    def f(L):
        return jnp.sum(w * bg.estimate_background(L, name, 2.0))

    h = 1e-6
    expected = (f(L + h * v) - f(L - h * v)) / (2 * h)
    np.testing.assert_allclose(jnp.sum(jax.grad(f)(L) * v), expected, rtol=1e-6)


@pytest.mark.parametrize("name", LOCAL)
def test_integer_luminance_is_averaged_as_floats(name):
    # Averaged in the input's integer dtype, gaussian_background's averages
    # would be truncated and bilateral_background's loop would fail.
    L = np.random.default_rng(9).integers(0, 100, size=SHAPE)
    as_float = bg.estimate_background(jnp.asarray(L, float), name, 2.0)
    np.testing.assert_allclose(bg.estimate_background(jnp.asarray(L), name, 2.0), as_float)


def test_large_neighbourhoods_on_a_small_image():
    """Sizes beyond the 9 x 13 image; the adaptive default reaches radius 127."""
    L = jnp.asarray(np.full(SHAPE, 3.0))
    for background in (
        bg.box_background(L, scale=40),
        bg.gaussian_background(L, scale=40.0),
        bg.bilateral_background(L, scale=20.0),
        bg.bilateral_background(L, scale=20.0, kind="pattanaik-yee"),
        bg.adaptive_background(L),
    ):
        np.testing.assert_allclose(background, 3.0, rtol=1e-12)


def test_global_estimators():
    L = jnp.asarray([[1.0, 100.0], [10.0, 10.0]])
    np.testing.assert_allclose(bg.global_background(L), 10.0)
    np.testing.assert_allclose(bg.arithmetic_background(L), 30.25)
    assert bg.arithmetic_average(L).shape == ()


@pytest.mark.parametrize("name", list(bg.BACKGROUNDS))
def test_every_estimator_of_float32_s_largest_values_is_finite(name):
    # The box sums (box, adaptive, multiscale) and the bilateral sum of a
    # window of 3e38 luminances overflowed: infinite backgrounds.
    L = np.full((6, 8), 3.0e38, np.float32)
    L[2:4, 2:4] = 1.0
    estimate = np.asarray(bg.estimate_background(jnp.asarray(L), name, 2.0))
    assert estimate.dtype == np.float32 and np.isfinite(estimate).all()
    uniform = bg.estimate_background(jnp.full((6, 8), 3.0e38, jnp.float32), name, 2.0)
    np.testing.assert_allclose(uniform, 3.0e38, rtol=1e-5)


def test_arithmetic_average_of_float32_s_largest_values_is_finite():
    # The float32 sum of 3e38 and 3.4e38 overflowed: an infinite background.
    L = jnp.asarray([[3.0e38, 3.4e38], [0.0, 1.0]], jnp.float32)
    np.testing.assert_allclose(bg.arithmetic_average(L), (3.0e38 + 3.4e38) / 4, rtol=1e-6)
    assert bg.arithmetic_average(L).dtype == jnp.float32
    black = jnp.zeros((2, 2), jnp.float32)
    assert float(bg.arithmetic_average(black)) == 0.0
    grad = jax.grad(bg.arithmetic_average)(black)
    np.testing.assert_array_equal(grad, 0.25)


def test_zero_and_negative_luminance_use_the_documented_floor():
    L = jnp.asarray([[0.0, -5.0], [0.0, 0.0]])
    np.testing.assert_allclose(bg.global_background(L), bg.LUMINANCE_FLOOR)
    L = jnp.zeros(SHAPE).at[0, 0, 0].set(1.0)
    for name in ("global", "bilateral", "adaptive", "multiscale"):
        assert np.all(np.isfinite(np.asarray(bg.BACKGROUNDS[name](L)))), name


def assert_within_each_side(b, L, slack):
    """Each side's background stays inside the range of that side's own
    luminances (the texture, +-10 %), up to ``slack``: nothing leaks across."""
    for side in (slice(None, 32), slice(32, None)):
        lo, hi = float(L[:, side].min()), float(L[:, side].max())
        assert np.all(b[:, side] >= lo * (1 - slack)) and np.all(b[:, side] <= hi * (1 + slack))


@pytest.mark.parametrize("kind", sorted(bg.BILATERAL_KINDS))
def test_bilateral_does_not_cross_an_hdr_edge(kind):
    L, _ = hdr_edge()
    assert_within_each_side(np.asarray(bg.bilateral_background(L, kind=kind)), L, 0.01)


def test_adaptive_does_not_cross_an_hdr_edge():
    """Dark pixels stop growing their neighbourhood at the first bright pixel;
    bright ones may drift by about the tolerance before they stop."""
    L, _ = hdr_edge()
    assert_within_each_side(np.asarray(bg.adaptive_background(L)), L, 0.1)


def test_plain_local_averages_cross_it_the_halo():
    """Fig 6.14: box and Gaussian averages are biased on both sides of the edge."""
    L, _ = hdr_edge()
    for name in ("box", "gaussian"):
        b = np.asarray(bg.BACKGROUNDS[name](L))
        assert np.all(b[:, 28:32] > 100.0), name  # dark side: a bright halo of I_b
        assert np.all(b[:, 32:34] < 0.7e4), name  # bright side: a dark one


def test_adaptive_uses_large_neighbourhoods_away_from_edges():
    rng = np.random.default_rng(5)
    L = jnp.asarray(100.0 * (1.0 + 0.01 * rng.standard_normal(SHAPE)))
    b = np.asarray(bg.adaptive_background(L))
    # far from any edge the largest level averages the noise away
    assert np.std(b) < 0.2 * np.std(np.asarray(L))


@pytest.mark.parametrize("name", LOCAL)
def test_estimators_batch_over_leading_axes(name):
    """A batch gives what a loop over its images gives (the estimators are
    jitted, so this is also jit against the unbatched calls)."""
    L = hdr_edge(*SHAPE[1:])[0]
    batch = jnp.stack([L, 2.0 * L])
    f = bg.BACKGROUNDS[name]
    np.testing.assert_allclose(f(batch), jnp.stack([f(x) for x in batch]), rtol=1e-10)


@pytest.mark.parametrize("name", sorted(bg.BACKGROUNDS))
def test_float32_in_float32_out(name):
    L = jnp.asarray(hdr_edge(*SHAPE[1:])[0], dtype=jnp.float32)
    out = bg.BACKGROUNDS[name](L)
    assert out.dtype == jnp.float32 and out.shape == L.shape


@settings(max_examples=10)
@given(arrays(np.float64, SHAPE, elements=st.floats(-6, 8)))
def test_no_nan_across_the_range_of_vision(log_l):
    L = jnp.asarray(10.0**log_l)
    for name, f in bg.BACKGROUNDS.items():
        b = np.asarray(f(L))
        assert np.all(np.isfinite(b)) and np.all(b > 0), name


# -- bad input ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda L: bg.box_background(L, scale=0), "scale"),
        (lambda L: bg.gaussian_background(L, scale=-1.0), "scale"),
        (lambda L: bg.bilateral_background(L, scale=0.0), "scale"),
        (lambda L: bg.bilateral_background(L, sigma_r=0.0), "sigma_r"),
        (lambda L: bg.bilateral_background(L, kind="trilateral"), "kind"),
        (lambda L: bg.adaptive_background(L, tolerance=-0.1), "tolerance"),
        (lambda L: bg.adaptive_background(L, levels=1), "levels"),
        (lambda L: bg.adaptive_background(L, scale=0.5), "scale"),
        (lambda L: bg.box_background(L, scale=0.4), "scale"),
        (lambda L: goal.white_fraction(L, percentile=150.0), "percentile"),
        (lambda L: bg.gaussian_background(L, scale=float("inf")), "scale"),
        (lambda L: bg.box_background(L, scale="8"), "scale"),
        (lambda L: bg.multiscale_background(L, levels=2.5), "levels"),
        (lambda L: bg.global_background(L[0, 0]), "L"),
        (lambda L: spatial.box_filter(L, -1), "radius"),
        (lambda L: spatial.box_filter(L, 1.5), "radius"),
        (lambda L: spatial.iterated_box_filter(L, 1, passes=0), "passes"),
        (lambda L: spatial.bilateral_filter(L, 2.0, 0.1, spatial="square"), "spatial"),
        (lambda L: spatial.bilateral_filter(L, 2.0, 0.1, range_kernel="box"), "range_kernel"),
        (lambda L: spatial.bilateral_filter(L, 2.0, 0.1, guide=L[:2]), "guide"),
    ],
)
def test_bad_input_names_the_argument(call, name):
    L = jnp.ones((4, 5))
    with pytest.raises(ValueError, match=f"^{name}: expected"):
        call(L)


def test_traced_tolerance_is_accepted():
    L, _ = hdr_edge(8, 12)
    f = jax.jit(functools.partial(bg.adaptive_background, levels=2))
    np.testing.assert_allclose(f(L, tolerance=0.05), bg.adaptive_background(L, levels=2))
