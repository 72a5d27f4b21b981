"""Adaptation goals, colour constants and display encodings."""

import subprocess
import sys
from functools import partial

import colour
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxadapt import color, display, scenes, spatial
from jaxadapt.operators import goal, pattanaik2000


def test_log_average_floors_black_pixels():
    L = jnp.array([[0.0, 1e-6], [1.0, 1e6]])
    assert float(goal.log_average(L)) == pytest.approx(10 ** ((-6 - 6 + 0 + 6) / 4), rel=1e-9)
    assert float(goal.log_average(jnp.zeros((3, 3)))) == pytest.approx(goal.LUMINANCE_FLOOR)


def test_white_fraction_finds_the_chart_white():
    chart = scenes.colorchecker_image(120, 80, white_luminance=5000.0)
    L = color.photopic_luminance(jnp.asarray(chart))
    white_patch = float(scenes.colorchecker_rgb()[3, 0] @ color.W_PHOTOPIC) * 5000.0
    assert float(goal.white_fraction(L)) == pytest.approx(white_patch / 5, rel=1e-3)


def test_foveal_weights_are_normalised_and_centred():
    w = spatial.foveal_weights((41, 61), jnp.array([20.0, 10.0]), pixels_per_degree=10.0)
    assert float(w.sum()) == pytest.approx(1.0)
    assert np.unravel_index(int(jnp.argmax(w)), w.shape) == (10, 20)
    # half maximum at half a degree (5 px) from the gaze point
    assert float(w[10, 25] / w[10, 20]) == pytest.approx(0.5, rel=1e-6)
    far = spatial.foveal_weights((5, 5), jnp.array([1e4, 1e4]), pixels_per_degree=1.0)
    assert jnp.all(jnp.isfinite(far)) and float(far.sum()) == pytest.approx(1.0)


def test_a_foveal_patch_narrower_than_a_pixel_is_the_nearest_pixels():
    # At `--pixels-per-degree 1e-6` the Gaussian's weights are the
    # difference of two exponents of -1e12, NaN once compiled: the pixels
    # nearest the gaze share the weight instead, at any narrowness, so that
    # the display frames stay finite.
    weights = jax.jit(partial(spatial.foveal_weights, (48, 64), dtype=jnp.float32))
    for gaze, nearest in (([31.5, 25.2], [(25, 31), (25, 32)]), ([10.0, 5.0], [(5, 10)])):
        for ppd in (1e-6, 1e-30, 0.0):
            w = np.asarray(weights(jnp.array(gaze, jnp.float32), jnp.float32(ppd)))
            expected = np.zeros((48, 64), np.float32)
            expected[tuple(np.array(nearest).T)] = 1 / len(nearest)
            np.testing.assert_array_equal(w, expected)
    frame = jnp.full((48, 64, 3), 10.0, jnp.float32).at[:, :20].set(1e4)
    params = pattanaik2000.Params(goal="foveal", pixels_per_degree=1e-6)
    state = pattanaik2000.init(params, frame, gaze=jnp.array([31.5, 25.2]))
    assert float(state.A_cone) == pytest.approx(10.0, rel=1e-5)


def test_foveal_goal_sees_what_the_gaze_sees():
    L = jnp.full((40, 80), 5.0).at[:, 40:].set(5000.0)
    left = goal.foveal_log_average(L, jnp.array([10.0, 20.0]), 4.0)
    right = goal.foveal_log_average(L, jnp.array([70.0, 20.0]), 4.0)
    assert float(left) == pytest.approx(5.0, rel=1e-3)
    assert float(right) == pytest.approx(5000.0, rel=1e-3)


def test_photopic_weights_come_from_colour_science():
    bt709 = colour.RGB_COLOURSPACES["ITU-R BT.709"]
    np.testing.assert_allclose(color.RGB709_TO_XYZ, bt709.matrix_RGB_to_XYZ, rtol=1e-15)
    np.testing.assert_allclose(color.W_PHOTOPIC, bt709.matrix_RGB_to_XYZ[1], rtol=1e-15)
    assert color.W_PHOTOPIC.sum() == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_array_equal(
        color.BT709_CHROMATICITIES, [*np.ravel(bt709.primaries), *bt709.whitepoint]
    )


def test_frozen_constants_equal_colour_science():
    # jaxadapt.color writes colour-science's values out (its import takes seconds).
    shape = colour.SpectralShape(380, 780, 1)
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(shape).values
    lefs = colour.colorimetry
    v_scotopic = lefs.SDS_LEFS_SCOTOPIC["CIE 1951 Scotopic Standard Observer"].copy()
    v_photopic = lefs.SDS_LEFS_PHOTOPIC["CIE 1924 Photopic Standard Observer"].copy()
    ratio = (1700.0 * d65 @ v_scotopic.align(shape).values) / (
        683.0 * d65 @ v_photopic.align(shape).values
    )
    assert color.SP_RATIO_D65 == pytest.approx(ratio, rel=1e-15)
    np.testing.assert_array_equal(color.XYZ_TO_HPE, colour.appearance.hunt.MATRIX_XYZ_TO_HPE)
    bt2020, bt709 = (colour.RGB_COLOURSPACES[f"ITU-R BT.{n}"] for n in (2020, 709))
    # colour-science computes the gamut matrix with NumPy's products, whose
    # last bit varies with the CPU's vector units: equal to within 1e-14.
    np.testing.assert_allclose(
        color.BT2020_TO_BT709, colour.matrix_RGB_to_RGB(bt2020, bt709), rtol=1e-14, atol=1e-15
    )
    assert set(color.YCBCR_WEIGHTS) <= set(colour.WEIGHTS_YCBCR)
    for name, weights in color.YCBCR_WEIGHTS.items():
        np.testing.assert_array_equal(weights, colour.WEIGHTS_YCBCR[name])
        for bits in (8, 10, 12, 16):
            for legal in (True, False):
                matrix, offsets = color.ycbcr_to_rgb(weights, bits, legal)
                np.testing.assert_allclose(
                    matrix, colour.matrix_YCbCr(weights, bits, legal, True), rtol=1e-15, atol=1e-18
                )
                np.testing.assert_array_equal(offsets, colour.offset_YCbCr(bits, legal, True))


def test_importing_the_library_imports_neither_colour_science_nor_diffrax():
    # (each takes a large part of a second: only the code that needs one imports it)
    code = (
        "import sys, jaxadapt, jaxadapt.cli, jaxadapt.pipeline, jaxadapt.figures; "
        "from jaxadapt.operators import jacobs2015, classic, pattanaik2000; "
        "from jaxadapt import fitting, psychophysics, viewer; "
        "[jaxadapt.cli._main.build_parser(c) for c in jaxadapt.cli._options.COMMANDS]; "
        "print('colour' in sys.modules, 'diffrax' in sys.modules)"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.stdout.strip() == "False False", result.stderr


def test_scotopic_weights_follow_the_scotopic_curve():
    # Jacobs et al. 2015, Appendix A, normalised: neutral stays neutral, and
    # blue counts for more (red for less) than photopically (peak 507 nm).
    assert color.W_SCOTOPIC.sum() == pytest.approx(1.0)
    assert color.W_SCOTOPIC[0] == 0.0 and color.W_SCOTOPIC[2] > color.W_PHOTOPIC[2]
    assert color.SP_RATIO_D65 == pytest.approx(2.46, abs=0.02)


def test_srgb_encoding_matches_colour_science():
    v = np.linspace(0, 1, 101)
    np.testing.assert_allclose(display.encode_srgb(v), colour.cctf_encoding(v, "sRGB"), atol=1e-7)


def test_quantisation_rounds_and_clips():
    q = display.to_uint8(jnp.array([-0.1, 0.0, 0.6 / 255, 0.5, 1.0, 2.0]))
    assert q.tolist() == [0, 0, 1, 128, 255, 255]


def test_gaussian_blur_matches_scipy_and_keeps_constants():
    from scipy.ndimage import gaussian_filter

    x = np.random.default_rng(0).uniform(size=(2, 20, 30))
    expected = np.stack([gaussian_filter(a, 2.0, mode="mirror", truncate=4.0) for a in x])
    np.testing.assert_allclose(spatial.gaussian_blur(jnp.asarray(x), 2.0), expected, atol=1e-12)
    wide = spatial.gaussian_blur(jnp.full((5, 7), 3.0), 10.0)  # kernel longer than the image
    np.testing.assert_allclose(wide, 3.0, rtol=1e-12)
    with pytest.raises(ValueError, match="sigma: expected a positive width"):
        spatial.gaussian_kernel(0.0)


@pytest.mark.slow
def test_the_forms_of_the_separable_filter_agree():
    # The CPU runs the per-axis form, other platforms the both-axes form, and
    # kernels longer than LONG_KERNEL taps go by blocks
    # (separable_filter's notes): the same filter, kernels longer than the
    # image and one-pixel axes included.
    rng = np.random.default_rng(3)
    forms = (spatial._filter_per_axis, spatial._filter_both_axes, spatial._filter_by_products)
    for shape, sigma in (((3, 20, 30), 1.5), ((2, 5, 7), 10.0), ((1, 9), 0.75), ((4, 1, 6), 2.0)):
        x = jnp.asarray(rng.uniform(size=shape))
        taps = spatial.gaussian_kernel(sigma)
        per_axis, *others = (jax.jit(lambda x, f=f, t=taps: f(x, t))(x) for f in forms)
        for other in others:
            np.testing.assert_allclose(other, per_axis, rtol=1e-12)


@pytest.mark.parametrize(
    "shape, sigma",
    [
        ((2, 40, 1000), 60.0),  # 481 taps: blocks along 1,000 pixels, the folded matrix along 40
        ((8, 8), 600.0),  # 4,801 taps folded: by blocks, 9.7 s and 1.3 GB
    ],
)
def test_long_kernels_go_by_products_and_match_scipy(shape, sigma):
    # One slice a tap would take minutes to compile (_filter_by_products).
    from scipy.ndimage import gaussian_filter

    assert spatial.gaussian_kernel(sigma).size > spatial.LONG_KERNEL
    x = np.random.default_rng(4).lognormal(size=shape).reshape((-1, *shape[-2:]))
    expected = np.stack([gaussian_filter(a, sigma, mode="mirror", truncate=4.0) for a in x])
    expected = expected.reshape(shape)
    x = x.reshape(shape)
    np.testing.assert_allclose(spatial.gaussian_blur(jnp.asarray(x), sigma), expected, rtol=1e-12)
    blurred = spatial.gaussian_blur(jnp.asarray(x, jnp.float32), sigma)
    assert blurred.dtype == jnp.float32
    np.testing.assert_allclose(blurred, expected, rtol=1e-5)


def test_integer_images_are_filtered_as_numbers():
    # Computed in the image's dtype, a blur of uint8 would be truncated to
    # whole numbers, the bilateral filter would fail inside its scan, and a
    # luminance of integer RGB would be 0 (its weights rounded to 0).
    u = (np.arange(48) % 2 * 255).astype(np.uint8).reshape(6, 8)
    f = u.astype(float)
    for filt in (
        lambda x: spatial.gaussian_blur(x, 1.0),
        lambda x: spatial.box_filter(x, 1),
        lambda x: spatial.bilateral_filter(x, 2.0, 50.0),
    ):
        np.testing.assert_allclose(filt(u), filt(f), rtol=1e-12)
    rgb = np.array([200, 100, 50], np.uint8)
    np.testing.assert_allclose(color.photopic_luminance(rgb), rgb @ color.W_PHOTOPIC)


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: color.photopic_luminance(np.ones((4, 5))), "rgb: .* shape \\(4, 5\\)"),
        (lambda: color.transform(np.ones((2, 4)), color.RGB_TO_LMS), "rgb: .* shape \\(2, 4\\)"),
        (lambda: spatial.gaussian_blur(np.ones(5), 1.0), "image: .* shape \\(5,\\)"),
        (lambda: spatial.box_filter(np.ones((0, 5)), 1), "image: .*H, W >= 1.*\\(0, 5\\)"),
        (lambda: spatial.bilateral_filter(np.ones((3, 0)), 2.0, 1.0), "image: .*\\(3, 0\\)"),
        (lambda: spatial.gaussian_kernel(1.0, truncate=-1), "truncate: expected"),
        (lambda: spatial.lowpass_stack(np.ones((4, 4)), []), "radii: expected"),
        (
            lambda: spatial.bilateral_filter(np.ones((2, 3, 4, 4)), 2.0, np.ones(5)),
            "sigma_r: .*broadcasts to \\(2, 3, 4, 4\\), got \\(5,\\)",
        ),
    ],
)
def test_bad_images_and_filter_arguments_are_named(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_an_intensity_width_per_frame_filters_each_frame_with_its_own():
    # sigma_r of shape (3, 1, 1) against images (2, 3, H, W): it is
    # reshaped with the image's batch axes to broadcast.
    img = np.random.default_rng(8).random((2, 3, 7, 9))
    widths = np.array([0.1, 0.2, 0.3])
    got = spatial.bilateral_filter(jnp.asarray(img), 2.0, widths[:, None, None])
    for i, j in np.ndindex(2, 3):
        np.testing.assert_allclose(got[i, j], spatial.bilateral_filter(img[i, j], 2.0, widths[j]))


def test_long_kernels_keep_the_dark_side_of_an_hdr_edge_in_float32():
    # 1e8 | 1e-3 cd/m2: an FFT spread the rounding of 1e8 over the whole
    # line (the dark side off by up to 2e4 times its value); the blocks sum
    # each window's own terms (_filter_by_products).
    from scipy.ndimage import gaussian_filter

    x = np.where(np.arange(1200) < 200, 1e8, 1e-3) * np.ones((8, 1))
    expected = gaussian_filter(x, (0.0, 70.0), mode="mirror", truncate=4.0)
    taps = spatial.gaussian_kernel(70.0)
    assert taps.size > spatial.LONG_KERNEL
    with jax.enable_x64(False):
        blurred = spatial._separable_filter(
            jnp.asarray(x, jnp.float32), tuple(float(w) for w in taps)
        )
    np.testing.assert_allclose(blurred, expected, rtol=1e-4)


#: Largest difference allowed between a blur of spatial.gaussian_ladder made
#: on a coarser level and SciPy's sampled Gaussian, as a fraction of the
#: image's range (docs/choices.md, "The acuity loss's blurs"): measured up
#: to 0.30 %, for the blurs just past a decimation.
LADDER_TOLERANCE = 4e-3


def hdr_test_image(shape):
    """Noise on 0-1 cd/m2 with a 1e4 block and a bright pixel: HDR edges
    in both directions and near two image edges."""
    x = np.random.default_rng(9).uniform(0.0, 1.0, shape)
    x[5:40, 3:50] = 1e4
    x[shape[0] // 2, shape[1] // 2] = 1e4
    return x


@pytest.mark.parametrize("scale", [1, 4])
def test_the_gaussian_ladder_is_scipys_gaussian_filter(scale):
    # Eight quarter-octave widths from 0.75 pixels (the acuity bands at the
    # paper's display, on levels 0 and 1) and 4 times those (levels 1 to
    # 3), on a frame of odd sizes: all within LADDER_TOLERANCE of SciPy's sampled Gaussian
    # (mode "mirror"; SciPy rounds the kernel's half-width where we take
    # its ceiling) and non-negative, those on level 0 the direct blurs, and
    # a constant stays constant.
    from scipy.ndimage import gaussian_filter

    sigmas = [scale * 0.75 * 2 ** (i / 4) for i in range(8)]
    x = hdr_test_image((181, 243, 2))
    levels = spatial.ladder_levels(sigmas)
    assert levels == {1: [0] * 7 + [1], 4: [1, 1, 1, 2, 2, 2, 2, 3]}[scale]
    ladder = jax.jit(lambda x: [b() for b in spatial.gaussian_ladder(x, sigmas)])
    blurs = ladder(jnp.asarray(x))
    fine = [s for s, level in zip(sigmas, levels, strict=True) if level == 0]
    direct = jax.jit(
        lambda x: [spatial.channels_last_filter(x, spatial.gaussian_kernel(s)) for s in fine]
    )(jnp.asarray(x))
    for s, level, blur in zip(sigmas, levels, blurs, strict=True):
        expected = np.stack(
            [gaussian_filter(x[..., c], s, mode="mirror", truncate=4.0) for c in range(2)], -1
        )
        error = np.abs(np.asarray(blur) - expected).max() / x.max()
        assert error < LADDER_TOLERANCE, (s, error)
        assert float(blur.min()) >= 0.0
        if level == 0:
            np.testing.assert_allclose(blur, direct[fine.index(s)], rtol=1e-12)
    np.testing.assert_allclose(ladder(jnp.full(x.shape, 3.0)), 3.0, rtol=1e-12)


def test_a_blur_of_the_ladder_costs_the_same_at_any_width():
    # XLA's count of floating-point operations: a direct blur's grows with
    # its width (8 sigma + 1 taps a pass), the ladder's stays bounded.
    x = jnp.zeros((135, 240, 3), jnp.float32)

    def flops(f):
        analysis = jax.jit(f).lower(x).compile().cost_analysis()
        return (analysis[0] if isinstance(analysis, list) else analysis)["flops"]

    ladder, direct = [], []
    for s in (2.5, 20.0):
        ladder.append(flops(lambda x, s=s: spatial.gaussian_ladder(x, [s])[0]()))
        direct.append(
            flops(lambda x, s=s: spatial.channels_last_filter(x, spatial.gaussian_kernel(s)))
        )
    assert direct[1] > 5 * direct[0]
    assert ladder[1] < 1.5 * ladder[0], ladder


def test_blurs_of_the_ladder_not_needed_are_skipped():
    # On the CPU a blur not needed is zeros; a needed one past it is exact,
    # though the level it starts from was made for it alone.
    sigmas = [0.75, 1.5, 3.0, 6.0]
    x = jnp.asarray(hdr_test_image((60, 70)))
    full = jax.jit(lambda x: [b() for b in spatial.gaussian_ladder(x, sigmas)])(x)
    needed = [jnp.bool_(False), jnp.bool_(True), jnp.bool_(False), jnp.bool_(True)]
    some = jax.jit(lambda x: [b() for b in spatial.gaussian_ladder(x, sigmas, needed)])(x)
    for blur, all_of, need in zip(some, full, needed, strict=True):
        np.testing.assert_allclose(blur, all_of if need else 0.0, rtol=1e-12, atol=0)
    with pytest.raises(ValueError, match="sigmas: expected rising widths"):
        spatial.gaussian_ladder(x, [2.0, 1.0])


def test_both_forms_of_the_colour_transform_are_the_matrix_product():
    # The CPU computes the rows in turn, other platforms at once (transform's notes).
    x = np.random.default_rng(5).lognormal(size=(2, 5, 4, 3))
    M = np.asarray(color.RGB_TO_LMS)
    for form in (color._rows_in_turn, color._rows_at_once):
        np.testing.assert_allclose(form(jnp.asarray(x), jnp.asarray(M)), x @ M.T, rtol=1e-13)
    np.testing.assert_allclose(color.transform(jnp.asarray(x), M), x @ M.T, rtol=1e-13)
    np.testing.assert_allclose(color.transform(jnp.asarray(x), M[1]), x @ M[1], rtol=1e-13)


def test_plane_sum_is_the_sum_over_the_image_axes():
    # On the CPU plane_sum is two products with vectors of ones (module notes).
    x = np.random.default_rng(1).lognormal(size=(3, 2, 17, 23))
    np.testing.assert_allclose(spatial.plane_sum(jnp.asarray(x)), x.sum(axis=(-2, -1)), rtol=1e-13)
    grad = jax.grad(lambda a: spatial.plane_sum(a).sum())(jnp.asarray(x))
    np.testing.assert_array_equal(grad, np.ones_like(x))


def test_a_contact_frame_is_shrunk_by_whole_boxes_in_linear_light():
    from jaxadapt import figures

    frame = np.random.default_rng(0).uniform(0, 1, (10, 2000, 3)).astype(np.float32)
    small = figures.shrink(frame, width=960)  # 3 x 3 boxes: 666 wide, 3 rows
    assert small.shape == (3, 666, 3)
    np.testing.assert_allclose(small[1, 5], frame[3:6, 15:18].mean(axis=(0, 1)), rtol=1e-6)
    narrow = frame[:, :960]
    np.testing.assert_array_equal(figures.shrink(narrow, width=960), narrow)


def test_contact_frames_follow_the_clock_and_crowd_where_adaptation_changes():
    from jaxadapt import figures

    t = np.arange(100) / 30
    flat = np.zeros(100)
    evenly = figures.spread_frames(t, flat, 12)
    np.testing.assert_array_equal(evenly, np.linspace(0, 99, 12).round())
    # a 3 log unit change over frames 60 to 66 (a tunnel's exit): half the
    # path, so about half the tiles, where even spacing puts one
    step = np.clip((np.arange(100) - 60) / 6, 0, 1) * 3.0
    chosen = figures.spread_frames(t, step, 12)
    assert len(chosen) == 12 and chosen[0] == 0 and chosen[-1] == 99
    assert np.sum((chosen >= 60) & (chosen <= 66)) >= 4, chosen
    assert np.max(np.diff(chosen)) <= 25, chosen  # the rest still spread over the clock
    # only the frames kept can be shown; non-finite adaptation is no change
    kept = np.arange(0, 100, 7)
    with_black = np.where(np.arange(100) < 10, -np.inf, step)
    picked = figures.spread_frames(t, with_black, 12, among=kept)
    assert set(picked) <= set(kept) and len(picked) == 12
    np.testing.assert_array_equal(figures.spread_frames(t, step, 12, among=[5, 3]), [3, 5])
