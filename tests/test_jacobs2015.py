"""The 2015 gaze-aware renderer: the paper's effects, the contract, and bad input."""

import colorsys
import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxadapt import color, display, scenes, spatial
from jaxadapt.gaze import read_gaze_csv, recorded_gaze
from jaxadapt.operators import jacobs2015 as op
from jaxadapt.physiology.response import naka_rushton
from jaxadapt.spatial import gaussian_blur

KEY = jax.random.key(0)
#: Everything off: the bare global tone curve of Eqs 1-2.
BARE = op.only(global_adaptation=False)
#: The deterministic pipeline (no acuity noise, no dithering).
SMOOTH = op.Params(acuity=False, dithering=False)
EFFECTS = op.EFFECTS


def only(*effects):
    """BARE with some effects switched back on."""
    return dataclasses.replace(BARE, **{e: True for e in effects})


# Most tests render sequences of one shape, T frames of 32 x 32 at 8 frames
# per second (a 1/8 s flash is one frame), with an explicit gaze path, so
# that each configuration of the operator is compiled once for the file.
T, H, W, FPS = 24, 32, 32, 8.0
CENTRE = np.tile([(W - 1) / 2, (H - 1) / 2], (T, 1))


def render(params, frames, gaze=CENTRE, dt=1 / FPS, key=KEY):
    """``op.run`` on a standard-shape sequence."""
    assert frames.shape[:3] == (T, H, W)
    return op.run(params, frames, dt, gaze=gaze, key=key)


def flash_frames(luminance=1e7):
    """The flash scene: dark, one frame of ``luminance`` at 0.25 s, dark."""
    scene = scenes.flash(width=W, height=H, duration=T / FPS, fps=FPS, luminance=luminance)
    return jnp.asarray(scene.render(scene.times), jnp.float64)


def sequence(image):
    return jnp.broadcast_to(jnp.asarray(image, jnp.float64), (T, H, W, 3))


def hue(rgb):
    """HSV hue, degrees, of an RGB triple."""
    return 360.0 * colorsys.rgb_to_hsv(*np.clip(np.asarray(rgb), 0, None))[0]


def texture(seed=0):
    """A coloured random texture of photopic luminance about 1 cd/m2."""
    rng = np.random.default_rng(seed)
    return jnp.asarray(rng.uniform(0.2, 1.8, size=(H, W, 3)))


# -- published values ---------------------------------------------------------


def test_defaults_are_appendix_a():
    # Jacobs et al. (2015), Appendix A.
    p = op.Params()
    expected = dict(gamma=0.455, n=0.7, a1=0.75, a2=0.2, c1=1, c2=1, j1=0.03, j2=0.15)
    for name, value in expected.items():
        assert float(getattr(p, name)) == pytest.approx(value)
    np.testing.assert_allclose(p.b1, [1.2e-3, 1.4e-4, 5.5e-7])
    np.testing.assert_allclose(p.b2, [0.69, 1.4, 5.5])
    assert (float(p.m1), float(p.m2), float(p.g), float(p.rho_step)) == (0, -2, 0.25, 0.286)
    np.testing.assert_allclose(p.w_P, [0.2126, 0.7152, 0.0722], atol=1e-4)
    np.testing.assert_allclose(p.w_S / p.w_S[1], np.array([0, 0.8451, 0.1459]) / 0.8451)
    np.testing.assert_allclose(p.H, [[1.14, -1.18, 0.36], [-0.08, 1.02, 0.18], [0.30, -0.11, 1.25]])
    np.testing.assert_allclose(op.acuity_sigmas(p), 0.75 * 2 ** (np.arange(8) / 4))
    assert float(p.adaptation_floor) == 100.0  # §2.4


def test_white_excites_the_three_cones_equally():
    # Fig. 4: a white flash "stimulating all cone types equally".
    np.testing.assert_allclose(color.RGB_TO_LMS @ np.ones(3), np.ones(3), rtol=1e-12)


# -- global adaptation --------------------------------------------------------


def test_sigma_puts_the_adapting_luminance_on_the_plateau():
    # Eq 2 solves R(I) = M(I): the response to the adapting luminance is M.
    p = op.Params()
    A = jnp.linspace(-1.0, 9.0, 21)
    I = 10.0**A
    R = naka_rushton(I, op.semi_saturation(p, A), 1.0, p.n)
    np.testing.assert_allclose(R, op.plateau(p, I), rtol=1e-10)
    assert jnp.all(jnp.diff(op.plateau(p, I)) > 0) and float(op.plateau(p, I).max()) < 1


def test_adaptation_follows_the_gaze_at_the_papers_rates():
    # Left half at 1e4 cd/m2, right half at 10: fixating the right half holds
    # A at the floor of 100 cd/m2 (§2.4); looking left raises it at a1 = 0.75
    # log units/s (Eq 3); the frame darkens as the viewer adapts.
    frame = jnp.ones((H, W, 3)).at[:, : W // 2].multiply(1e4).at[:, W // 2 :].multiply(10.0)
    gaze = np.where(np.arange(T)[:, None] < 8, [24.0, 15.5], [7.5, 15.5])
    params = dataclasses.replace(SMOOTH, pixels_per_degree=jnp.asarray(4.0))  # a 4 px fovea
    out, diag = render(params, sequence(frame), gaze=gaze)
    A = np.asarray(diag.A)
    assert A[0] == pytest.approx(2.0, abs=1e-6)
    np.testing.assert_allclose(np.diff(A[8:20]), 0.75 / FPS, rtol=1e-9)
    assert np.asarray(diag.A_T)[-1] == pytest.approx(4.0, abs=0.01)
    assert float(out[9, 15, 4].mean()) > float(out[-1, 15, 4].mean())  # darkens as it adapts


def test_a_small_bright_source_at_the_gaze_raises_the_target():
    # A_T is "the log of the average scene luminance in a small patch around
    # the user's gaze" (§2.1; Fig. 2: fixating a bright point darkens the
    # scene). A 1e6 cd/m2 lamp 12 pixels across on a 20 cd/m2 field: the
    # foveal mean's log, 4.6; the log average (31 cd/m2) stayed at the floor.
    y, x = np.mgrid[:64, :64]
    frame = np.where((np.hypot(y - 32, x - 32) < 6)[..., None], 1e6, 20.0) * np.ones(3)
    gaze = jnp.array([32.0, 32.0])
    w = spatial.foveal_weights((64, 64), gaze, 64.0)
    expected = np.log10(np.sum(np.asarray(w) * frame[..., 0]))
    A_T = op.adaptation_target(op.Params(), jnp.asarray(frame), gaze)
    assert float(A_T) == pytest.approx(expected, abs=1e-9) and 4.5 < expected < 4.7


def test_global_adaptation_off_keeps_the_initial_state():
    frames = sequence(texture()) * jnp.geomspace(10.0, 1e5, T)[:, None, None, None]
    out, diag = render(BARE, frames)
    assert float(jnp.ptp(diag.A)) == 0.0
    no_gaze, _ = op.run(BARE, frames, 1 / FPS)  # no gaze: fixation at the centre
    assert jnp.array_equal(out, no_gaze)


# -- afterimages --------------------------------------------------------------


def _gaze_colour(luminance, times):
    """Display values at the fixation ``times`` s after a flash ends."""
    out, _ = render(SMOOTH, flash_frames(luminance))
    end = 3  # the flash is frame 2, at 0.25 s
    return [np.asarray(out[end + int(round(t * FPS)), 16, 16]) for t in times]


def test_flash_afterimage_goes_from_cyan_to_magenta():
    # §2.2: a bright neutral flash gives "a strong cyan afterimage, fading to
    # green, and finally to magenta" (Weve 1925); Fig. 5's 1e7 cd/m2 line.
    first, later, late = _gaze_colour(1e7, [0.0, 0.25, 2.5])
    assert 150 <= hue(first) <= 200  # cyan
    assert 90 <= hue(later) < 150  # green
    assert 280 <= hue(late)  # magenta to pink
    assert late[0] > late[1] and late[2] > late[1]


def test_dim_flash_afterimage_starts_magenta():
    # Fig. 5: below about 1e4.5 cd/m2 no cyan or green phase, only magenta.
    (first,) = _gaze_colour(1e3, [0.0])
    assert hue(first) >= 280 and first[0] > first[1]


@pytest.mark.slow
def test_bleaching_off_leaves_darkness_black():
    frames = flash_frames()
    for params in (BARE, only("local_adaptation")):
        out, _ = render(params, frames)
        assert float(out[3:].max()) == 0.0
    out, _ = render(only("bleaching"), frames)
    assert float(out[3:].max()) > 0.1


def test_retinal_shift_moves_the_maps_and_fills_what_it_uncovers():
    # NumPy reference: out[y, x] = maps[y - dy, x - dx] where that lies in
    # the frame, else fill[y, x]; shifts past the frame's size fill it all.
    rng = np.random.default_rng(4)
    maps, fill = rng.uniform(size=(2, 7, 11, 3))
    shift_map = jax.jit(op.retinal_shift)
    for dx, dy in [(0, 0), (3, -2), (-5, 4), (11, 0), (-20, 30)]:
        expected = fill.copy()
        for y in range(7):
            for x in range(11):
                if 0 <= y - dy < 7 and 0 <= x - dx < 11:
                    expected[y, x] = maps[y - dy, x - dx]
        out = shift_map(jnp.asarray(maps), jnp.array([dx, dy]), jnp.asarray(fill))
        np.testing.assert_array_equal(out, expected)


def test_afterimages_move_with_the_gaze():
    # A flash at the centre, then darkness while the gaze moves 6 pixels
    # right and 3 down: the afterimage moves with it (retina-locked).
    gaze = CENTRE.copy()
    gaze[6:] += [6.0, 3.0]
    out, diag = render(SMOOTH, flash_frames(), gaze=gaze)

    def peak(image):
        """Centroid of the afterimage's core (above 80 % of its maximum)."""
        w = np.asarray(image).sum(-1)
        w = np.maximum(w - 0.8 * w.max(), 0.0)
        y, x = np.mgrid[: w.shape[0], : w.shape[1]]
        return np.array([(w * x).sum(), (w * y).sum()]) / w.sum()

    np.testing.assert_allclose(peak(out[5]), [15.5, 15.5], atol=0.3)
    np.testing.assert_allclose(peak(out[7]), [21.5, 18.5], atol=0.3)
    # the fixated point keeps its retina's bleaching through the saccade
    assert float(diag.B_gaze[6, 0]) == pytest.approx(float(diag.B_gaze[5, 0]), rel=0.2)


def _quadrants_after_saccade(scene, params):
    """Mean display value of the four quadrants of the uniform field 0.1 s
    after the saccade, away from the fixation cross: ``(2, 2, 3)``."""
    frames = jnp.asarray(scene.render(scene.times), jnp.float64)
    out, _ = op.run(params, frames, scene.dt[0], gaze=scene.gaze(scene.times), key=KEY)
    k = np.searchsorted(scene.times, 5.0) + 1
    field = np.asarray(out[k, :, frames.shape[2] // 2 :])
    h, w = field.shape[:2]
    rows = (slice(2, h // 2 - 3), slice(h // 2 + 3, h - 2))
    cols = (slice(2, w // 2 - 3), slice(w // 2 + 3, w - 2))
    return np.array([[field[r, c].mean((0, 1)) for c in cols] for r in rows])


@pytest.mark.slow
def test_checkerboard_leaves_a_reversed_afterimage_only_with_local_adaptation():
    # Fig. 3 b-c: after fixating the board, the uniform field shows the board
    # with its brightness relationships reversed.
    scene = scenes.checkerboard(width=64, height=32, duration=5.5, fps=FPS, checks=2, field_deg=8)
    q = _quadrants_after_saccade(scene, only("local_adaptation", "global_adaptation")).mean(-1)
    assert q[0, 0] < 0.97 * q[0, 1] and q[1, 1] < 0.97 * q[1, 0]  # top-left check was white
    q_off = _quadrants_after_saccade(scene, only("global_adaptation"))
    assert float(np.ptp(q_off)) < 1e-12


def test_coloured_patches_leave_opponent_afterimages():
    # Fig. 3 d and §2.2.3: a blue stimulus lowers the S-cones' gain, so the
    # grey field looks yellow where it was; red leaves cyan.
    scene = scenes.patches(width=64, height=32, duration=5.5, fps=FPS, field_deg=8)
    q = _quadrants_after_saccade(scene, only("local_adaptation", "global_adaptation"))
    red, blue = q[0, 0], q[1, 0]  # top-left was red, bottom-left blue
    assert blue[2] < 0.97 * min(blue[0], blue[1])  # yellow
    assert red[0] < 0.97 * min(red[1], red[2])  # cyan


@pytest.mark.slow
def test_total_darkness_is_finite_and_black():
    # I = 0 everywhere for a minute: C reaches C_max = c1 / c2 (to the last
    # bit in float64) and Eq 11 is 0/0; our limit alpha = 1 keeps the output
    # finite (and black). Light after the darkness is boosted but finite.
    frames = jnp.zeros((T, H, W, 3)).at[-1].set(50.0)
    for dtype in (jnp.float32, jnp.float64):
        out, diag = render(SMOOTH, frames.astype(dtype), dt=dtype(2.5), gaze=CENTRE.astype(dtype))
        assert float(diag.C_gaze[-2, 0]) == pytest.approx(1.0, abs=1e-7)
        assert jnp.all(jnp.isfinite(out)) and float(out[:-1].max()) == 0.0
        assert 0 < float(out[-1].mean()) <= 1


def test_local_gain_is_eq_11_away_from_darkness():
    p = op.Params(calcium_epsilon=1e-12)  # 0, Eq 11 as printed, is refused
    C, C_inf = jnp.array([0.2, 0.5, 0.9]), jnp.array([0.4, 0.5, 0.3])
    np.testing.assert_allclose(op.local_gain(p, C, C_inf), (1 - C_inf) / (1 - C), rtol=1e-10)
    assert float(op.local_gain(op.Params(), 1.0, 1.0)) == 1.0


def test_afterimages_fade_away_from_the_fovea():
    p = op.Params()
    v = op.falloff(p, (5, 400), jnp.array([0.0, 2.0]))
    assert float(v[2, 0]) == 1.0
    assert float(v[2, 320]) == pytest.approx(np.exp(-0.5), rel=1e-6)  # 5 deg at 64 px/deg


# -- mesopic vision -----------------------------------------------------------


def test_purkinje_darkens_red_and_brightens_blue_in_the_dark():
    # Eq 13 and Fig. 10: in the dark, luminance moves towards the scotopic
    # weights; a neutral pixel keeps its luminance; in daylight nothing moves.
    colours = jnp.array([[1.0, 0.05, 0.05], [0.05, 0.05, 1.0], [1.0, 1.0, 1.0], [1, 1, 1]])
    patches = jnp.repeat(jnp.repeat(colours[:, None], H, 1), W // 4, 0).transpose(1, 0, 2)
    scale = jnp.where(jnp.arange(T) < T // 2, 1e-2, 1e3)[:, None, None, None]
    frames = sequence(patches) * scale

    def luminance(params):
        out, _ = render(params, frames)
        return np.asarray((out ** (1 / params.gamma)) @ params.w_P)[:, 16, 4 :: W // 4]

    on, off = luminance(only("purkinje")), luminance(BARE)
    dark, bright = slice(0, T // 2), slice(T // 2, T)
    assert np.all(on[dark, 0] < 0.7 * off[dark, 0]) and np.all(on[dark, 1] > 1.3 * off[dark, 1])
    np.testing.assert_allclose(on[bright], off[bright], rtol=1e-9)
    np.testing.assert_allclose(on[:, 2], off[:, 2], rtol=1e-9)


def test_display_encoding_is_the_gamma_of_section_2_4_and_decode_undoes_it():
    R = jnp.array([-0.5, 0.0, 0.25, 1.0, 3.0])
    J = op.encode(BARE, R)
    np.testing.assert_allclose(J, np.clip(R, 0, 1) ** 0.455, rtol=1e-12)
    np.testing.assert_allclose(op.decode(BARE, J), np.clip(R, 0, 1), rtol=1e-12, atol=1e-300)


def test_mesopic_colour_turns_grey_dull_purple():
    # §2.3.2: in the dark colour ratios drift to a dull purple (Shin et al.
    # 2004); off, the output keeps the input's colour ratios.
    out, _ = render(only("mesopic_colour"), sequence(jnp.full((H, W, 3), 1e-2)))
    r, g, b = np.asarray(out[0, 4, 4]) ** (1 / float(BARE.gamma))
    assert r > g and b > g and 270 <= hue((r, g, b)) <= 300
    assert float(np.ptp([r, g, b]) / max(r, g, b)) < 0.4  # dull
    out, _ = render(BARE, sequence(jnp.ones((H, W, 3)) * jnp.array([1.0, 0.5, 0.2]) * 1e-2))
    linear = np.asarray(out[0, 4, 4]) ** (1 / float(BARE.gamma))
    np.testing.assert_allclose(linear / linear[0], [1.0, 0.5, 0.2], rtol=1e-9)


@jax.jit
def _highpass(image):
    chw = jnp.moveaxis(image, -1, 0)
    return jnp.mean((chw - gaussian_blur(chw, 1.0)) ** 2) / jnp.mean(chw) ** 2


def _highpass_energy(image):
    """Energy of the detail finer than 1 pixel, relative to the mean squared."""
    return float(_highpass(image))


def test_acuity_loss_drops_fine_detail_first():
    # §2.3.3 with the intended order: as luminance falls, the fine bands go
    # first; averaged over noise draws, fine-detail energy falls with luminance.
    p = op.Params()
    image = texture()

    @jax.jit
    def loss(scene, key, t):
        X = op.acuity_noise(p, key, t, (H, W))
        return op.acuity_loss(p, scene, op.local_rho(p, scene), X)

    levels = [1e-3, 1e-2, 3e-2, 1e-1, 3e-1, 1.0, 1e2]
    energy = []
    for L in levels:
        kept = [_highpass_energy(loss(image * L, jax.random.key(i), 0.3 * i)) for i in range(8)]
        energy.append(np.mean(kept))
    assert np.all(np.diff(energy) > 0)
    assert energy[-1] == pytest.approx(_highpass_energy(image), rel=1e-3)
    # the coarsest band is kept down to rho = 0 and dropped below it
    thresholds = np.asarray(op.acuity_thresholds(p))
    assert thresholds[0] == pytest.approx(1.001) and thresholds[-1] == 0.0


@pytest.mark.slow
def test_acuity_loss_is_eq14_band_sum():
    # Eq 14 written out: the low-pass plus each difference-of-Gaussian band
    # where rho + g X exceeds its threshold; acuity_loss selects a blur instead.
    p = op.Params()

    @jax.jit  # one compilation instead of one per operation and blur
    def reference_and_ours(image):
        rho = op.local_rho(p, image)
        X = op.acuity_noise(p, jax.random.key(3), jnp.float64(0.4), image.shape[:2])
        chw = jnp.moveaxis(image, -1, 0)
        stack = jnp.stack([chw] + [gaussian_blur(chw, s) for s in op.acuity_sigmas(p)])
        bands = stack[:-1] - stack[1:]
        keep = (rho + p.g * X)[None] > op.acuity_thresholds(p)[:, None, None]
        reference = stack[-1] + jnp.sum(jnp.where(keep[:, None], bands, 0.0), axis=0)
        return reference, keep, op.acuity_loss(p, image, rho, X)

    reference, keep, ours = reference_and_ours(texture() * 0.3)
    assert 0 < float(keep.mean()) < 1  # some bands kept, some dropped
    np.testing.assert_allclose(ours, jnp.moveaxis(reference, 0, -1), rtol=1e-10, atol=1e-14)
    with pytest.raises(ValueError, match="rho_step"):
        op.Params(rho_step=-0.1)


def test_acuity_noise_is_standard_normal_and_smooth():
    p = op.Params()
    noise = jax.jit(lambda key, t: op.acuity_noise(p, key, t, (64, 64)))
    X = np.stack([noise(jax.random.key(i), jnp.float64(0.37 * i)) for i in range(400)])
    assert abs(X.mean()) < 0.08 and abs(X.std() - 1) < 0.05
    neighbours = np.corrcoef(X[:, :, :-1].ravel(), X[:, :, 1:].ravel())[0, 1]
    assert neighbours > 0.9  # patches, not per-pixel noise


@pytest.mark.slow
def test_acuity_in_the_operator_flickers_in_the_dark_only():
    dark = sequence(texture() * 1e-1)
    a, _ = render(only("acuity"), dark, key=jax.random.key(1))
    b, _ = render(only("acuity"), dark, key=jax.random.key(2))
    assert float(jnp.abs(a - b).max()) > 1e-3
    bright = sequence(texture() * 1e4)
    c, _ = render(only("acuity"), bright, key=jax.random.key(1))
    d, _ = render(BARE, bright)
    np.testing.assert_allclose(c, d, rtol=1e-9)


# -- display ------------------------------------------------------------------


def test_dithering_is_unbiased_on_the_8_bit_grid():
    J = jnp.full((64, 64, 3), 100.3 / 255)
    q = display.dither(J, jax.random.key(3), 255)
    assert jnp.all(q * 255 == jnp.round(q * 255))
    assert set(np.unique(np.round(np.asarray(q) * 255))) == {100.0, 101.0}
    assert float(q.mean() * 255) == pytest.approx(100.3, abs=0.02)


def test_each_effect_off_leaves_the_frame_unchanged_by_it():
    # With everything off, the frame is the bare tone curve of Eqs 1-2,
    # computed here independently; switching any one effect on changes it,
    # on a dark coloured texture with a flash (so that every effect has work).
    frames = sequence(texture() * 3e-2).at[2:4, 12:20, 12:20].set(1e6)
    bare, diag = render(BARE, frames)
    I = 10.0 ** float(diag.A[0])
    M = 0.8 * (I / 1e4) ** 0.25 / (1 + (I / 1e4) ** 0.25)
    sigma = I * (1 / M - 1) ** (1 / 0.7)
    L = np.asarray(frames) @ np.asarray(BARE.w_P)
    R = L**0.7 / (L**0.7 + sigma**0.7)
    expected = np.clip(np.asarray(frames) / L[..., None] * R[..., None], 0, 1) ** 0.455
    np.testing.assert_allclose(bare, expected, rtol=1e-9)
    for effect in EFFECTS:
        out, _ = render(only(effect), frames)
        assert float(jnp.abs(out - bare).max()) > 1e-3, effect


# -- the contract -------------------------------------------------------------


@pytest.mark.slow
def test_same_key_same_frames():
    frames = sequence(texture() * 0.1)
    a, _ = render(op.Params(), frames, key=jax.random.key(7))
    b, _ = render(op.Params(), frames, key=jax.random.key(7))
    c, _ = render(op.Params(), frames, key=jax.random.key(8))
    assert jnp.array_equal(a, b) and not jnp.array_equal(a, c)


@pytest.mark.slow
def test_run_equals_a_loop_of_step():
    frames = flash_frames()
    gaze = CENTRE.copy()
    gaze[8:] += [4.0, -2.0]
    gaze[10:12] = np.nan  # a blink
    gaze[14:] = [100.0, -5.0]  # off the frame
    params = op.Params()
    out, diag = render(params, frames, gaze=gaze)
    state = op.init(params, frames[0], gaze=gaze[0], key=KEY)
    for k in range(T):
        state, frame = op.step(params, state, frames[k], 1 / FPS, gaze=gaze[k])
        np.testing.assert_allclose(frame, out[k], atol=1e-12)
    np.testing.assert_allclose(state.B, diag.final_state.B, atol=1e-12)
    np.testing.assert_allclose(diag.gaze[11], [19.5, 13.5])  # blink: held
    np.testing.assert_allclose(diag.gaze[-1], [W - 1, 0.0])  # clipped to the frame


@pytest.mark.slow
def test_vmap_over_a_batch_of_params_equals_separate_runs():
    frames = flash_frames()
    j1 = jnp.array([0.0, 0.03, 0.1])
    batch = jax.tree.map(lambda x: jnp.broadcast_to(x, (3,) + jnp.shape(x)), SMOOTH)
    batch = eqx.tree_at(lambda p: p.j1, batch, j1)
    outs, _ = jax.vmap(lambda p: render(p, frames))(batch)
    for i in range(3):
        single, _ = render(eqx.tree_at(lambda p: p.j1, SMOOTH, j1[i]), frames)
        np.testing.assert_allclose(outs[i], single, atol=1e-12)
    # The batch passed as it is is named, and a channel field keeps its shape.
    with pytest.raises(ValueError, match=r"^j1: expected shape \(\) .* jax.vmap"):
        render(eqx.tree_at(lambda p: p.j1, SMOOTH, j1), frames)
    with pytest.raises(ValueError, match=r"^b1: expected shape \(3,\) .* got shape \(2, 3\)"):
        render(eqx.tree_at(lambda p: p.b1, SMOOTH, batch.b1[:2]), frames)


@pytest.mark.slow
def test_no_retrace_for_new_values_or_more_frames(count_calls):
    traces = count_calls(op, "tone_map")
    frames = jnp.ones((4, 9, 11, 3))  # a shape no other test uses
    op.run(BARE, frames, 0.03)
    n = len(traces)
    op.run(BARE, frames * 5.0, np.float64(0.04), key=jax.random.key(5))
    assert len(traces) == n
    state = op.init(BARE, frames[0])
    state, _ = op.step(BARE, state, frames[0], 0.03)
    m = len(traces)
    for k in range(1, 4):  # more frames, new values
        state, _ = op.step(BARE, state, frames[k] * k, 0.01 * k, gaze=np.array([k, 2.0 * k]))
    assert len(traces) == m


@pytest.mark.slow
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_1e8_and_black_are_finite(dtype):
    frames = (
        jnp.zeros((T, H, W, 3))
        .at[1]
        .set(1e8)  # 1e8 cd/m2
        .at[2, 10:20, 10:20]
        .set(1e8)  # a sun in the dark
        .at[4]
        .set(1e-6)  # starlight
        .astype(dtype)
    )
    out, diag = render(op.Params(), frames, dt=dtype(1 / FPS), gaze=CENTRE.astype(dtype))
    assert out.dtype == dtype
    # checked in NumPy: no compilation per shape of the diagnostics
    out, diag = jax.tree.map(
        np.asarray, (out, diag._replace(final_state=diag.final_state._replace(key=0)))
    )
    assert np.all(np.isfinite(out)) and np.all((out >= 0) & (out <= 1))
    for leaf in jax.tree.leaves(diag):
        assert np.all(np.isfinite(leaf))
    assert np.all((diag.final_state.B >= 0) & (diag.final_state.B <= 1))


def test_float32_matches_float64():
    frames = flash_frames()
    out64, _ = render(SMOOTH, frames)
    out32, _ = render(
        SMOOTH, frames.astype(jnp.float32), dt=jnp.float32(1 / FPS), gaze=CENTRE.astype(jnp.float32)
    )
    np.testing.assert_allclose(out32, out64, atol=2e-4)


# -- bad input ----------------------------------------------------------------


@pytest.mark.parametrize("gaze", [np.zeros((T - 1, 2)), np.zeros(T), np.zeros((T, 3))])
def test_wrong_gaze_shape_is_named(gaze):
    with pytest.raises(ValueError, match=rf"gaze.*\({T}, 2\)"):
        render(op.Params(), flash_frames(), gaze=gaze)


@pytest.mark.parametrize("frames", [jnp.ones((4, 4, 3)), jnp.ones((2, 4, 4, 4))])
def test_wrong_frames_are_named(frames):
    with pytest.raises(ValueError, match="frames"):
        op.run(op.Params(), frames, 0.03, key=KEY)


@pytest.mark.parametrize("bad", [-1.0, np.nan, np.inf])
def test_bad_luminance_is_named(bad):
    with pytest.raises(Exception, match="frames"):
        render(op.Params(), flash_frames().at[5, 1, 1, 1].set(bad))


@pytest.mark.parametrize("bad", [-5.0, np.nan, np.inf])
def test_bad_adaptation_luminance_is_named(bad):
    # Unchecked, NaN would fill the state, and every frame after it, with
    # NaN (about 0 on the display), and -5 would run; the 2000 operator
    # refuses both too.
    with pytest.raises(ValueError, match=r"^adaptation: expected a finite luminance >= 0"):
        op.init(op.Params(), flash_frames()[0], key=KEY, adaptation=bad)


def test_bad_dt_and_missing_key_are_named():
    with pytest.raises(Exception, match="dt"):
        render(op.Params(), flash_frames(), dt=0.0)
    with pytest.raises(ValueError, match="key"):
        op.run(op.Params(), jnp.ones((2, 4, 4, 3)), 0.03)
    with pytest.raises(ValueError, match="acuity_bands"):
        op.Params(acuity_bands=0)


@pytest.mark.parametrize(
    "fields, match",
    [
        ({"a1": -1.0}, "a1: expected a positive, finite number"),
        ({"b1": (1.2e-3, -1.0, 5.5e-7)}, "b1: expected a positive, finite number"),
        ({"c2": jnp.nan}, "c2: expected a positive, finite number"),
        ({"j1": -0.1}, "j1: expected a finite number >= 0"),
        # Eq 13's range empty (rho infinite) or upside down (rho turned around).
        ({"m1": -2.0}, r"m1 - m2: expected the mesopic range's upper end .* got Array\(0"),
        ({"m1": -3.0}, "m1 - m2: expected the mesopic range's upper end"),
        ({"m2": jnp.nan}, "m1 - m2: expected the mesopic range's upper end"),
        # Two bleaching rates for three cones: named here, not left to JAX's
        # broadcasting error from inside run.
        ({"b1": (1e-3, 1e-4)}, r"b1: expected shape \(3,\) .* got shape \(2,\)"),
        ({"H": np.eye(2)}, r"H: expected shape \(3, 3\)"),
        # Eq 11 as printed: after long darkness C rounds to C_max, alpha is
        # infinite and the frame black, its gradients NaN.
        ({"calcium_epsilon": 0.0}, "calcium_epsilon: expected a positive, finite number"),
        # M >= 1 makes sigma NaN, M = 0 infinite: black frames.
        ({"plateau_max": 1.2}, r"plateau_max: expected in \(0, 1\)"),
        ({"plateau_max": 0.0}, r"plateau_max: expected in \(0, 1\)"),
    ],
)
def test_a_parameter_out_of_its_range_is_named(fields, match):
    # A negative adaptation rate or a NaN decay would run and give wrong
    # frames without a word.
    with pytest.raises(ValueError, match=match):
        op.Params(**fields)
    op.Params(j1=0.0, j2=0.0, g=0.0)


def test_step_rejects_a_frame_of_another_shape():
    state = op.init(BARE, jnp.ones((4, 4, 3)))
    with pytest.raises(ValueError, match="frame"):
        op.step(BARE, state, jnp.ones((4, 5, 3)), 0.03)
    # Not a state at all: an AttributeError of tuple's, or JAX's own.
    for wrong in (None, tuple(state)):
        with pytest.raises(ValueError, match=r"^state: expected a jacobs2015.State \(from"):
            op.step(BARE, wrong, jnp.ones((4, 4, 3)), 0.03)
    with pytest.raises(ValueError, match=r"^state: expected a jacobs2015.State \(from"):
        op.run(BARE, jnp.ones((2, 4, 4, 3)), 0.03, state=tuple(state), key=jax.random.key(0))


# -- scenes and gaze files ----------------------------------------------------


def test_gaze_csv_round_trip_blinks_and_errors(tmp_path):
    path = tmp_path / "gaze.csv"
    path.write_text("t,x,y\n0.0,10,20\n0.5,,\n1.0,30,40\n")
    t, xy = read_gaze_csv(path)
    np.testing.assert_allclose(t, [0.0, 0.5, 1.0])
    assert np.isnan(xy[1]).all()
    gaze = recorded_gaze(t, xy)(np.array([0.2, 0.7, 2.0]))
    assert gaze.tolist() == [[10.0, 20.0], [10.0, 20.0], [30.0, 40.0]]  # the blink holds
    starts_blinking = recorded_gaze(t[1:], xy[1:])(np.array([0.7, 1.2]))
    assert np.isnan(starts_blinking[0]).all() and starts_blinking[1].tolist() == [30.0, 40.0]
    with pytest.raises(FileNotFoundError, match="^gaze: .*missing.csv: no such file$"):
        read_gaze_csv(tmp_path / "missing.csv")
    with pytest.raises(ValueError, match="^gaze: expected a CSV file .* got the folder"):
        read_gaze_csv(tmp_path)
    path.write_text("0.0,10\n")
    with pytest.raises(ValueError, match="line 1"):
        read_gaze_csv(path)
    # Times that stop increasing are named by line, not printed (numpy cuts
    # a long array short with "...").
    path.write_text("".join(f"{t},2,2\n" for t in range(2000)) + "1.0,1,1\n")
    with pytest.raises(
        ValueError, match="increase .* got 1.0 on line 2001 after 1999 on line 2000"
    ):
        read_gaze_csv(path)
    # 1e39 pixels is finite in float64 but not in float32, where the
    # operators would take it for a blink.
    for row in ("0.5,inf,3", "0.5,nan,3", "0.5,,3", "0.5,1e39,3"):  # not a blink: one coordinate
        path.write_text(f"t,x,y\n0,1,1\n{row}\n")
        with pytest.raises(ValueError, match=f"got '{row}' on line 3"):
            read_gaze_csv(path)
    # A spreadsheet's "CSV UTF-8": a byte-order mark and CRLF line ends.
    path.write_bytes(b"\xef\xbb\xbft,x,y\r\n0,10,20\r\n")
    t, xy = read_gaze_csv(path)
    assert t.tolist() == [0.0] and xy.tolist() == [[10.0, 20.0]]
    # A header in any case, not taken for a bad row.
    path.write_text("Time,X,Y\n0,10,20\n")
    assert read_gaze_csv(path)[0].tolist() == [0.0]
    # The header names the columns: x,y,t is not read as t,x,y.
    path.write_text("x,y,T\n10,20,0\n30,40,1\n")
    t, xy = read_gaze_csv(path)
    assert t.tolist() == [0.0, 1.0] and xy.tolist() == [[10.0, 20.0], [30.0, 40.0]]
    path.write_text("time,gaze_x,gaze_y\n0,10,20\n")
    with pytest.raises(ValueError, match="naming the columns t .* got 'time,gaze_x,gaze_y'"):
        read_gaze_csv(path)


def test_jacobs_scenes_are_registered_and_calibrated():
    for name in ("flash", "checkerboard", "patches", "mesopic"):
        scene = scenes.SCENES[name](width=32, height=16, duration=0.5)
        frames = np.asarray(scene.render(scene.times))
        assert frames.shape == (len(scene.times), 16, 32, 3)
        assert scene.gaze(scene.times).shape == (len(scene.times), 2)
    flash = scenes.flash(width=16, height=16)
    frames = np.asarray(flash.render(flash.times))
    lit = frames.max(axis=(1, 2, 3)) > 0
    assert frames.max() == 1e7 and np.sum(flash.dt * lit) == pytest.approx(0.125, rel=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("length", [0.125, 0.001])
def test_a_flash_lasts_its_length_at_any_frame_rate(length):
    # At 30 fps a 1/8 s flash from 0.25 s ends inside a frame: lit for 4
    # whole frames (0.133 s) it would leave 3 % too much S-cone bleaching.
    # A flash of 1 ms, shorter than a frame, is taken too.
    params = op.Params(acuity=False, dithering=False, afterimage_blur=0.0)
    after = {}
    for fps in (30.0, 120.0):
        scene = scenes.flash(width=8, height=8, duration=0.5, fps=fps, flash_duration=length)
        assert scene.dt.sum() == pytest.approx(0.5) and np.all(scene.dt > 0)
        frames = jnp.asarray(scene.render(scene.times), jnp.float64)
        gaze = jnp.asarray(scene.gaze(scene.times), jnp.float64)
        _, diag = op.run(params, frames, scene.dt, gaze=gaze, key=KEY)
        after[fps] = np.asarray(diag.B_gaze)[np.argmin(np.abs(scene.times - 0.4))]
    assert after[30.0][2] > 1e-3
    np.testing.assert_allclose(after[30.0], after[120.0], rtol=1e-9)
    for onset, length, message in (
        (-0.1, 0.125, "onset: expected a finite time >= 0"),
        (4.0, 0.125, "duration: expected more than the flash's onset, 4.0 s, got 4.0"),
        (0.25, 1e-10, "flash_duration: expected at least 1e-6 s"),
        (0.25, np.nan, "flash_duration: expected at least 1e-6 s"),
    ):
        with pytest.raises(ValueError, match=f"^{message}"):
            scenes.flash(width=8, height=8, duration=4.0, onset=onset, flash_duration=length)
    # A flash ending with the scene leaves no last frame of rounding (5.6e-17 s).
    scene = scenes.flash(width=8, height=8, duration=0.3, fps=50, onset=0.05, flash_duration=0.25)
    assert len(scene.times) == 16 and scene.dt[-1] == pytest.approx(0.02)


def test_afterimage_maps_spread_the_same_angle_on_any_display():
    # 1 s of blurs between frames, at 30 and 120 fps, 25.6 to 128 pixels per
    # degree: the same spread in degrees (1 pixel a frame at 64 and 30 fps).
    # The sub-pixel blurs (0.4 and 0.2 pixels at 25.6) of a sampled Gaussian
    # spread 29 % and 99 % less.
    def spread_deg(ppd, fps):
        params = op.Params(afterimage_blur=op.blur_for_display(ppd, fps))
        point = jnp.zeros((160, 160, 3)).at[80, 80].set(1.0)
        blur = lambda _, m: op.blur_maps(params, m, m, 0.0, 0.0)[0]  # noqa: E731 (darkness)
        maps = jax.lax.fori_loop(0, int(fps), blur, point)
        profile = np.asarray(maps[80, :, 0] / maps[80, :, 0].sum())
        return np.sqrt(np.sum(profile * (np.arange(160) - 80) ** 2)) / ppd

    paper = spread_deg(64.0, 30.0)
    assert paper == pytest.approx(np.sqrt(30) / 64, rel=0.01)
    for ppd, fps in ((128.0, 30.0), (128.0, 120.0), (25.6, 30.0), (25.6, 120.0)):
        assert spread_deg(ppd, fps) == pytest.approx(paper, rel=0.01)


def test_blurred_maps_keep_their_ranges_where_the_equilibrium_changes():
    # A square just lit (its calcium at C_max, its equilibrium 0) inside a
    # dark field at C_max, and one just darkened (bleached, equilibrium 0)
    # inside a bleached bright field: the blurred departures must not take
    # the fields' calcium above C_max, bleaching above 1, or Eq 11's local
    # gain negative (it would reach -0.015 beside a 1e8 cd/m2 sun gone dark).
    params = op.Params(afterimage_blur=2.0)
    C_max = float(params.c1 / params.c2)
    square = jnp.zeros((24, 24, 3), bool).at[8:16, 8:16].set(True)
    C, C_inf = jnp.full((24, 24, 3), C_max), jnp.where(square, 0.0, C_max)
    B, B_inf = jnp.ones((24, 24, 3)), jnp.where(square, 0.0, 1.0)
    B_next, C_next = op.blur_maps(params, B, C, B_inf, C_inf)
    assert float(B_next.max()) <= 1.0 and float(B_next.min()) >= 0.0
    assert float(C_next.max()) <= C_max and float(C_next.min()) >= 0.0
    assert float(op.local_gain(params, C_next, C_inf).min()) > 0.0
    assert float(C_next[12, 12, 0]) < C_max  # the blur still moves the square's departure


@pytest.mark.slow
def test_a_steady_scene_seen_steadily_leaves_no_afterimage():
    # Started at equilibrium, with the scene and the gaze still, Eqs 4-12
    # change nothing. Blurring the whole maps (not their departures from
    # equilibrium) built a ring around a bright lamp: 0.029 in 2 s.
    y, x = np.mgrid[:48, :48]
    frame = np.where((np.hypot(y - 24, x - 24) < 6)[..., None], 1e6, 20.0) * np.ones(3)
    frames = jnp.asarray(np.stack([frame] * 60), jnp.float32)
    params = op.Params(acuity=False, dithering=False, afterimage_blur=1.0)
    out, _ = op.run(params, frames, 1 / 30, gaze=jnp.full((60, 2), 24.0))
    np.testing.assert_allclose(out[-1], out[0], atol=1e-6)


def test_only_switches_on_the_named_effects_and_names_unknown_ones():
    p = op.only("purkinje", "acuity", n=0.8)
    assert [getattr(p, e) for e in op.EFFECTS] == [e in ("purkinje", "acuity") for e in op.EFFECTS]
    assert p.global_adaptation and float(p.n) == 0.8
    with pytest.raises(ValueError, match="effects: expected names from"):
        op.only("purkinje", "glare")


# -- acuity in degrees ----------------------------------------------------------


def test_acuity_sizes_at_the_papers_display_are_appendix_a_pixels():
    """At 64 pixels per degree, the paper's display, the defaults are
    exactly Appendix A's pixel sizes (sigma_0 = 0.75 pixels, a 16-pixel
    noise cell)."""
    p = op.Params()
    assert (p.acuity_sigma0, p.acuity_noise_cell) == (0.75, 16.0)
    frames = _acuity_frames()
    explicit = op.Params(acuity_sigma0=0.75, acuity_noise_cell=16)
    np.testing.assert_array_equal(render(p, frames)[0], render(explicit, frames)[0])


def _acuity_frames():
    rng = np.random.default_rng(1)
    return jnp.asarray(rng.uniform(0.001, 0.1, (T, H, W, 3)))  # mesopic texture


@pytest.mark.parametrize("ppd", [1.0, 12.8, 30.0, 100.0, 640.0])
def test_acuity_bands_and_noise_cell_are_angles(ppd):
    """Scaled with pixels per degree: the same angles on any display."""
    p = op.Params(pixels_per_degree=ppd)
    paper = op.Params()
    scale = ppd / op.PAPER_PIXELS_PER_DEGREE
    np.testing.assert_allclose(op.acuity_sigmas(p), np.multiply(op.acuity_sigmas(paper), scale))
    assert p.acuity_noise_cell == pytest.approx(max(1.0, 16 * scale))


def test_acuity_noise_at_half_the_resolution_is_the_same_field():
    """The noise at 32 px/deg on a half-size frame is the 64 px/deg noise at
    every other pixel: the same field of the visual angle."""
    fine = op.acuity_noise(op.Params(), KEY, jnp.float64(0.3), (64, 96))
    coarse = op.acuity_noise(op.Params(pixels_per_degree=32.0), KEY, jnp.float64(0.3), (32, 48))
    np.testing.assert_allclose(coarse, fine[::2, ::2], rtol=1e-12, atol=1e-12)


def test_acuity_sizes_given_in_pixels_are_kept_and_batches_need_them():
    p = op.Params(pixels_per_degree=20.0, acuity_sigma0=0.5, acuity_noise_cell=4)
    assert (p.acuity_sigma0, p.acuity_noise_cell) == (0.5, 4)
    with pytest.raises(ValueError, match="acuity_sigma0, acuity_noise_cell"):
        op.Params(pixels_per_degree=jnp.array([20.0, 40.0]))
    batch = op.Params(pixels_per_degree=jnp.array([20.0, 20.0]))  # one value: resolved
    assert batch.acuity_sigma0 == 0.75 * 20 / 64
    with pytest.raises(ValueError, match="acuity_noise_cell: expected > 0"):
        op.Params(acuity_noise_cell=0.0)
