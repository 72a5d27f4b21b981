"""The photoreceptor family of tone curves and Ward's JND mapping (chapter 6, §6.3)."""

import colour
import colour_hdri
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jaxadapt import background as bg
from jaxadapt.operators import classic
from jaxadapt.physiology.response import naka_rushton
from jaxadapt.physiology.threshold import TVI_MODELS, tvi_blackwell

positive = st.floats(1e-4, 1e6)


def hdr_frame(seed=0, shape=(6, 8), grey=False):
    """Linear RGB, cd/m2, log-uniform over 1e-2..1e4 cd/m2."""
    rng = np.random.default_rng(seed)
    rgb = 10.0 ** rng.uniform(-2, 4, shape + ((1,) if grey else (3,)))
    return np.repeat(rgb, 3, axis=-1) if grey else rgb


def luminance(rgb):
    """Photopic luminance with colour-science's BT.709 weights."""
    return np.asarray(rgb) @ colour.RGB_COLOURSPACES["ITU-R BT.709"].matrix_RGB_to_XYZ[1]


# -- original forms = rewritten (Eq 6.2) forms -----------------------------------


@given(I=positive, I_max_over_I=st.floats(1.0, 1e4), p=st.floats(1.0, 1e4))
def test_schlick_rewritten_is_original(I, I_max_over_I, p):
    """Eq 6.2 with ``sigma_b = (I_max - I) / p`` on a two-pixel image ``[I, I_max]``
    (the curve finds ``I_max`` itself; at ``I = I_max``, ``sigma_b = 0``)."""
    I_max = I * I_max_over_I
    image = jnp.asarray([[I, I_max]])
    rewritten = classic.Schlick1994(p=p).curve(image, image)
    original = classic.schlick_original(image, I_max, p)
    np.testing.assert_allclose(rewritten, original, rtol=1e-9)
    sigma = classic.schlick_sigma(I, I_max, p)
    if sigma > 0:
        assert float(naka_rushton(I, sigma, 1.0, 1.0)) == pytest.approx(float(original[0, 0]))


@given(I=positive, I_b=positive, k=st.floats(1.01, 100.0), n=st.floats(0.3, 2.0))
def test_tumblin_rewritten_is_original(I, I_b, k, n):
    D = 0.8
    original = classic.tumblin_original(I, I_b, k, n, D)
    # the chapter's two-part rewritten form, term by term
    two_parts = D * (I**n / (I**n + k * I_b**n) + I_b**n / (k * (I**n + k * I_b**n)))
    assert float(classic.tumblin_rewritten(I, I_b, k, n, D)) == pytest.approx(float(original))
    assert float(original) == pytest.approx(two_parts)


@given(I=positive, I_b=positive, a=st.floats(0.01, 10.0))
def test_photographic_rewritten_is_original(I, I_b, a):
    rewritten = naka_rushton(I, classic.photographic_sigma(I_b, a), 1.0, 1.0)
    assert float(rewritten) == pytest.approx(float(classic.photographic_original(I, I_b, a)))


@given(I=positive, I_b=positive, f=st.floats(0.1, 10.0), m=st.floats(0.2, 1.0))
def test_reinhard_devlin_is_eq_6_2_with_their_sigma(I, I_b, f, m):
    got = classic.ReinhardDevlin(f=f, m=m).curve(jnp.asarray(I), jnp.asarray(I_b))
    assert float(got) == pytest.approx(I / (I + (f * I_b) ** m))


def test_curves_map_the_background_where_the_papers_say():
    I_b = jnp.asarray(37.0)
    assert float(classic.Photographic(a=0.18).curve(I_b, I_b)) == pytest.approx(0.18 / 1.18)
    tumblin = classic.Tumblin1999(k=10.0, n=0.7, D=0.9)
    assert float(tumblin.curve(I_b, I_b)) == pytest.approx(0.09)  # D / k
    assert float(tumblin.curve(jnp.asarray(0.0), I_b)) == pytest.approx(0.009)  # D / k^2
    assert float(tumblin.curve(jnp.asarray(1e30), I_b)) == pytest.approx(0.9)  # D


# -- against colour-hdri ------------------------------------------------------------


@pytest.mark.parametrize("p", [1.0, 20.0, 500.0])
def test_schlick_matches_colour_hdri(p):
    rgb = hdr_frame()
    expected = np.clip(colour_hdri.tonemapping_operator_Schlick1994(rgb, p), 0, 1)
    got = classic.tone_map(classic.Schlick1994(p=p), jnp.asarray(rgb))
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize(("f", "m"), [(1.0, 0.3), (0.5, 0.7), (2.0, 1.0)])
def test_reinhard_devlin_matches_colour_hdri_on_grey(f, m):
    """colour-hdri's ``f`` is ``-ln f``; its light adaptation ``a = 0`` is the
    global background (the log average) and ``a = 1`` the pixel itself."""
    rgb = hdr_frame(grey=True)
    params = classic.ReinhardDevlin(f=f, m=m)
    for a, background in ((0.0, None), (1.0, luminance(rgb))):
        expected = colour_hdri.tonemapping_operator_Reinhard2004(rgb, f=-np.log(f), m=m, a=a)
        got = classic.tone_map(params, jnp.asarray(rgb), background)
        np.testing.assert_allclose(got, expected, rtol=1e-9)


def test_reinhard_devlin_colour_deliberately_differs_from_colour_hdri():
    """Where we differ: colour-hdri applies the curve to each channel (the
    paper's form, with chromatic adaptation ``c``), which desaturates bright
    colours; we apply every curve of the family to luminance and keep the
    pixel's chromaticity, as the chapter's curves are stated on intensity and
    so that all curves treat colour alike. The luminance of a grey pixel is
    the same either way (test above)."""
    rgb = hdr_frame(seed=1)
    ours = np.asarray(classic.tone_map(classic.ReinhardDevlin(m=0.5), jnp.asarray(rgb)))
    theirs = colour_hdri.tonemapping_operator_Reinhard2004(rgb, m=0.5)
    unclipped = np.all(ours < 1, axis=-1)
    np.testing.assert_allclose((ours / rgb)[unclipped].std(axis=-1), 0, atol=1e-12)
    assert np.max((theirs / rgb).std(axis=-1)) > 1e-3


def test_tumblin_deliberately_differs_from_colour_hdri():
    """Where we differ: colour-hdri's ``tonemapping_operator_Tumblin1999`` is
    the revised Tumblin-Rushmeier operator, a power law ``L_d = m L_da
    (L_w / L_wa)^(g_w / g_d)`` with one log-log slope, whereas the chapter's
    Tumblin curve (§6.3.1) is the S-shaped sigmoid of Tumblin, Hodgins and
    Guenter (1999), bounded by ``D / k^2`` and ``D``. We implement the
    chapter's curve."""
    L = np.logspace(-2, 4, 13)
    rgb = np.repeat(L[None, :, None], 3, axis=-1)
    theirs = luminance(colour_hdri.tonemapping_operator_Tumblin1999(rgb))[0]
    slopes = np.diff(np.log10(theirs)) / np.diff(np.log10(L))
    np.testing.assert_allclose(slopes, slopes[0], rtol=1e-9)  # a straight line in log-log
    ours = luminance(classic.tone_map(classic.Tumblin1999(k=10.0), jnp.asarray(rgb)))[0]
    slopes = np.diff(np.log10(ours)) / np.diff(np.log10(L))
    assert slopes[0] < 0.1 and slopes[-1] < 0.1 and slopes[len(slopes) // 2] > 0.5  # an S
    assert 0.01 <= ours.min() and ours.max() < 1.0


# -- Ward's JND mapping (Eq 6.3) ----------------------------------------------------


def test_ward_jnd_is_ward_1994_scale_factor_with_the_offset_of_eq_6_3():
    """With Blackwell's TVI and the global background, Eq 6.3 is Ward's (1994)
    contrast-based scale factor ``m = ((1.219 + L_da^0.4) / (1.219 +
    L_wa^0.4))^2.5`` applied to the pixel's difference from the background."""
    rgb = hdr_frame(grey=True) / 100.0  # a dim scene, mostly inside the display range
    L = luminance(rgb)
    L_wa = np.exp(np.mean(np.log(L)))
    L_da, L_dmax = 50.0, 100.0
    m = ((1.219 + L_da**0.4) / (1.219 + L_wa**0.4)) ** 2.5
    expected = np.clip((L_da + m * (L - L_wa)) / L_dmax, 0, 1)
    got = classic.tone_map(classic.WardJND(L_da=L_da, L_dmax=L_dmax), jnp.asarray(rgb))
    np.testing.assert_allclose(luminance(got), expected, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("tvi, cut", [("blackwell", 0.370), ("rushton-macleod", 0.0305)])
def test_ward_jnd_with_a_global_background_clips_below_its_cut(tvi, cut):
    # The offset of Eq 6.3 (the docstring's warning): below I_b - I_bd dI_b /
    # dI_bd the display luminance is negative and clips to black.
    I_b = 4200.0
    params = classic.WardJND(L_da=50.0, tvi=tvi)
    below, above = params.curve(jnp.asarray([0.99, 1.01]) * cut * I_b, jnp.asarray(I_b))
    assert float(below) < 0 < float(above)


@pytest.mark.parametrize("tvi", ["blackwell", "rushton-macleod"])
def test_ward_jnd_preserves_the_number_of_jnds(tvi):
    I, I_b, I_bd = jnp.asarray([5.0, 80.0, 300.0]), jnp.asarray(60.0), 50.0
    model = TVI_MODELS[tvi]
    jnds = classic.jnd_count(I, I_b, model)
    I_d = classic.ward_display_luminance(jnds, I_bd, model)
    np.testing.assert_allclose(classic.jnd_count(I_d, I_bd, model), jnds, rtol=1e-12)
    # with Blackwell's TVI at the background, one JND is dL = tvi(I_b)
    one = classic.jnd_count(I_b + tvi_blackwell(I_b), I_b, tvi_blackwell)
    assert float(one) == pytest.approx(1.0)


def test_local_background_compresses_an_hdr_scene():
    """§6.3.2: with a locally adapted background the JND mapping compresses a
    window 1e4 times brighter than the room into the display range."""
    H, W = 12, 24
    xx = np.arange(W)[None, :]
    yy = np.arange(H)[:, None]
    L = np.where(xx < W // 2, 1.0, 1e4) * (1 + 0.2 * np.sin(xx + yy))
    rgb = jnp.asarray(np.repeat(L[..., None], 3, axis=-1))
    params = classic.WardJND()
    global_out = luminance(classic.tone_map(params, rgb))
    local_out = luminance(classic.tone_map(params, rgb, bg.bilateral_background))
    assert np.mean(global_out[:, W // 2 :] > 1 - 1e-9) > 0.9  # the window burns out
    for side in (slice(None, W // 2), slice(W // 2, None)):
        assert 0.2 < local_out[:, side].mean() < 0.8  # both regions around L_da
        assert local_out[:, side].std() > 0.01  # with their texture


# -- tone_map ---------------------------------------------------------------------

CURVES = sorted(classic.TONE_CURVES)


@pytest.mark.parametrize("name", CURVES)
def test_global_background_default_explicit_and_as_array_agree(name):
    params = classic.TONE_CURVES[name]()
    rgb = jnp.asarray(hdr_frame())
    L = jnp.asarray(luminance(rgb))
    default = classic.tone_map(params, rgb)
    np.testing.assert_allclose(classic.tone_map(params, rgb, bg.global_background), default)
    np.testing.assert_allclose(classic.tone_map(params, rgb, bg.log_average(L)), default)


@pytest.mark.slow
@pytest.mark.parametrize("name", CURVES)
def test_local_backgrounds_on_a_constant_image_equal_global(name):
    params = classic.TONE_CURVES[name]()
    rgb = jnp.broadcast_to(jnp.asarray([30.0, 20.0, 10.0]), (9, 13, 3))
    L = jnp.asarray(luminance(rgb))
    for background in ("bilateral", "adaptive", "multiscale"):
        local = classic.tone_map(params, rgb, bg.BACKGROUNDS[background](L))
        np.testing.assert_allclose(local, classic.tone_map(params, rgb), rtol=1e-9)


@pytest.mark.parametrize("name", CURVES)
def test_monotone_bounded_and_finite_over_the_range_of_vision(name):
    L = np.logspace(-6, 8, 57)
    rgb = jnp.asarray(np.repeat(L[None, :, None], 3, axis=-1))
    params = classic.TONE_CURVES[name]()
    for background in (None, jnp.asarray(1e-3), jnp.asarray(1e5)):
        Y = luminance(classic.tone_map(params, rgb, background))[0]
        assert np.all(np.isfinite(Y)) and np.all((Y >= 0) & (Y <= 1)), background
        assert np.all(np.diff(Y) >= 0), background


def test_frames_batch_and_parameter_sets_vmap():
    frames = jnp.asarray(np.stack([hdr_frame(s) for s in range(3)]))
    params = classic.Photographic(a=0.3)
    looped = jnp.stack([classic.tone_map(params, f) for f in frames])
    np.testing.assert_allclose(classic.tone_map(params, frames), looped, rtol=1e-12)
    keys = jnp.asarray([0.09, 0.18, 0.36])
    batched = jax.vmap(lambda a: classic.tone_map(classic.Photographic(a=a), frames[0]))(keys)
    for a, out in zip(keys, batched, strict=True):
        np.testing.assert_allclose(out, classic.tone_map(classic.Photographic(a=a), frames[0]))


def test_more_frames_of_the_same_shape_do_not_retrace():
    traces = []

    def background(L):
        traces.append(L.shape)
        return bg.global_background(L)

    frames = jnp.asarray(np.stack([hdr_frame(s) for s in range(2)]))
    classic.tone_map(classic.Tumblin1999(), frames, background)
    classic.tone_map(classic.Tumblin1999(k=5.0, n=0.8), 2.0 * frames, background)
    assert len(traces) == 1


def test_step_does_not_retrace_for_new_frames(count_calls):
    # tone_map is jitted with step's background function as a static
    # argument: a function built afresh at each call would trace it again
    # for every frame.
    traces = count_calls(classic, "estimate_background")
    params = classic.Params(background="gaussian", background_scale=2.0)
    frame = hdr_frame(5, shape=(5, 11))  # a shape no other test uses
    for k in range(3):
        classic.step(params, None, frame * (k + 1.0), 0.03)
    assert len(traces) == 1


@pytest.mark.parametrize("name", CURVES)
def test_float32_in_float32_out(name):
    params = classic.TONE_CURVES[name]()
    rgb = jnp.asarray(hdr_frame(), dtype=jnp.float32)
    background = bg.adaptive_background(jnp.asarray(luminance(rgb), dtype=jnp.float32))
    out = classic.tone_map(params, rgb, background)
    assert out.dtype == jnp.float32 and np.all(np.isfinite(np.asarray(out)))
    reference = classic.tone_map(params, rgb.astype(jnp.float64), background.astype(jnp.float64))
    np.testing.assert_allclose(out, reference, rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("name", CURVES)
def test_zero_and_negative_pixels_count_as_the_floor(name):
    # As a grey pixel at the floor: at the curve's black level, which is not
    # 0 for Tumblin's (D/k^2) or Ward's, so a black pixel shown as 0 would
    # be darker than the floor's pixels beside it.
    floor = np.full(3, bg.LUMINANCE_FLOOR)
    rgb = jnp.asarray(hdr_frame()).at[0, 0].set(0.0).at[0, 1].set(-1.0).at[0, 2].set(floor)
    out = np.asarray(classic.tone_map(classic.TONE_CURVES[name](), rgb))
    assert np.all(np.isfinite(out))
    np.testing.assert_array_equal(out[0, 0], out[0, 2])
    np.testing.assert_array_equal(out[0, 1], out[0, 2])


# -- bad input ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("make", "name"),
    [
        (lambda: classic.Schlick1994(p=0.5), "Schlick1994.p"),
        (lambda: classic.Schlick1994(k=1.5), "Schlick1994.k"),
        (lambda: classic.Tumblin1999(k=1.0), "Tumblin1999.k"),
        (lambda: classic.Tumblin1999(n=0.0), "Tumblin1999.n"),
        (lambda: classic.Tumblin1999(D=-1.0), "Tumblin1999.D"),
        (lambda: classic.ReinhardDevlin(f=0.0), "ReinhardDevlin.f"),
        (lambda: classic.ReinhardDevlin(m=-0.3), "ReinhardDevlin.m"),
        (lambda: classic.Photographic(a=0.0), "Photographic.a"),
        (lambda: classic.WardJND(L_da=0.0), "WardJND.L_da"),
        (lambda: classic.WardJND(L_dmax=-100.0), "WardJND.L_dmax"),
        (lambda: classic.WardJND(tvi="ferwerda"), "WardJND.tvi"),
        (lambda: classic.Photographic(a=np.inf), "Photographic.a"),
        (lambda: classic.Schlick1994(p=np.inf), "Schlick1994.p"),
        (lambda: classic.ReinhardDevlin(m=np.inf), "ReinhardDevlin.m"),
        (lambda: classic.Params(curve="photographic"), "curve"),
        (lambda: classic.Params(curve=classic.Photographic), "curve"),
        (lambda: classic.Params(background="box", background_scale=0.5), "background_scale"),
        (lambda: classic.Params(background_scale=np.inf), "background_scale"),
        (lambda: classic.Params(background="blur"), "background"),
    ],
)
def test_bad_parameters_name_the_field(make, name):
    with pytest.raises(ValueError, match=f"^{name}: expected"):
        make()


def test_bad_frames_and_backgrounds_name_the_argument():
    params = classic.Photographic()
    with pytest.raises(ValueError, match="^frame: expected"):
        classic.tone_map(params, jnp.ones((4, 5)))
    with pytest.raises(ValueError, match="^frame: expected"):
        classic.tone_map(params, jnp.ones((4, 5, 3), dtype=jnp.int32))
    with pytest.raises(ValueError, match="^background: expected"):
        classic.tone_map(params, jnp.ones((4, 5, 3)), jnp.ones((5, 4)))
    # The value checks' message is the error's first line (an EquinoxRuntimeError
    # began with the stack); inside the caller's jit they stay equinox's.
    with pytest.raises(ValueError, match="^frame: expected finite"):
        classic.tone_map(params, jnp.ones((4, 5, 3)).at[0, 0, 0].set(jnp.nan))
    with pytest.raises(eqx.EquinoxRuntimeError, match="frame: expected finite"):
        eqx.filter_jit(lambda f: classic.tone_map(params, f))(jnp.full((4, 5, 3), jnp.nan))
    with pytest.raises(ValueError, match="^background: expected None, a luminance array"):
        classic.tone_map(params, jnp.ones((4, 5, 3)), "gaussian")
    for bad in (jnp.nan, -5.0):  # unchecked: a black frame, or a white one
        with pytest.raises(ValueError, match="^background: expected finite"):
            classic.tone_map(params, jnp.ones((4, 5, 3)), jnp.full((4, 5), bad))


def test_schlick_darkest_pixel_is_above_the_floor():
    # I_min is the darkest pixel above the floor: one black pixel taken as
    # I_min (1e-6 cd/m2) would make p hundreds of times larger, and 10 cd/m2
    # of a 1 to 1,000 cd/m2 ramp would go from 0.092 to 0.955.
    ramp = np.geomspace(1.0, 1000.0, 12).reshape(3, 4)
    curve = classic.Schlick1994(p=10.0, k=0.5)

    def shown(L):
        return classic.tone_map(curve, jnp.asarray(np.repeat(L[..., None], 3, -1)), L)

    lit = shown(np.concatenate([ramp, np.full((3, 1), 500.0)], 1))
    with_black = shown(np.concatenate([ramp, [[0.0], [500.0], [500.0]]], 1))
    np.testing.assert_allclose(with_black[:, :4], lit[:, :4], rtol=1e-12)


def test_run_and_step_check_frames_and_dt_as_the_other_operators():
    # Refused, as the other operators refuse them: negative pixels (an
    # all-negative frame would render mid-grey), NaN or negative durations
    # (diagnostics dated NaN, -1, -2) and a dt of the wrong shape (else
    # JAX's broadcasting error); frames of four channels are named as
    # frames, the argument given.
    p = classic.Params()
    frames = jnp.full((2, 4, 4, 3), 10.0)
    for bad, dt, match in (
        (-frames, 0.1, "frames: expected finite, non-negative"),
        (frames, jnp.nan, "dt: expected positive"),
        (frames, -1.0, "dt: expected positive"),
    ):
        with pytest.raises(ValueError, match=f"^{match}"):
            classic.run(p, bad, dt)
    with pytest.raises(ValueError, match=r"^dt: expected a scalar or shape \(2,\)"):
        classic.run(p, frames, jnp.ones(3))
    with pytest.raises(ValueError, match=r"^frames: .* got float\d+ of shape \(2, 4, 4, 4\)"):
        classic.run(p, jnp.ones((2, 4, 4, 4)), 0.1)
    with pytest.raises(ValueError, match="^frame: expected finite, non-negative"):
        classic.step(p, None, -frames[0], 0.1)
    np.testing.assert_array_equal(
        classic.step(p, None, frames[0], 0.1)[1], classic.run(p, frames, 0.1)[0][0]
    )
