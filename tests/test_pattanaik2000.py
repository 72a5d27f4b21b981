"""The 2000 operator: the paper's rules, the contract, and robustness."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxadapt import scenes
from jaxadapt.color import photopic_luminance, scotopic_luminance
from jaxadapt.operators import pattanaik2000 as op
from jaxadapt.operators.pattanaik2000 import _appearance, _operator
from jaxadapt.physiology import kinetics
from jaxadapt.physiology.response import bleach_cone, bleach_rod, response_slope

P = op.Params()


def _sequence(T=6, H=5, W=7, seed=0):
    rng = np.random.default_rng(seed)
    levels = np.array([1e-3, 1e-3, 1e3, 1e3, 5.0, 5e4])[:T]
    texture = rng.uniform(0.05, 1.5, size=(H, W, 3))
    return jnp.asarray(levels[:, None, None, None] * texture[None])


def display_state(params):
    A = params.display_adaptation
    return op.State(A, A, bleach_rod(A), params.display_B_cone)


@pytest.mark.slow
def test_rule_1_is_an_identity_for_luminance():
    # A scene viewer in exactly the display observer's state sees the display
    # frame as the scene: neutral pixels keep their luminance (display value x
    # 125 cd/m2 = scene luminance) across the display's reference range.
    obs = op.observer(P, display_state(P))
    assert int(obs.rule) == 1
    L = jnp.geomspace(125 / 32, 125.0, 20)
    out = op.tone_map(P, obs, jnp.repeat(L[:, None], 3, axis=-1))
    np.testing.assert_allclose(out * 125.0, jnp.repeat(L[:, None], 3, axis=-1), rtol=1e-9)


def test_rule_1_colour_follows_the_papers_exponent():
    # Colour ratios are raised to S_color(L) / S_d (Eq 3 per log10 unit over
    # the display's forward-difference slope): unchanged where the local slope
    # equals S_d, desaturated below and saturated above (docs/choices.md).
    obs = op.observer(P, display_state(P))
    S_d = float(op.display_slope(P))
    L = jnp.geomspace(1.0, 500.0, 200)
    slope = response_slope(L, obs.sigma_cone, obs.B_cone, P.n)
    L_match = float(L[jnp.argmin(jnp.abs(slope - S_d))])
    rgb = jnp.array([1.4, 0.9, 0.6]) / float(photopic_luminance(jnp.array([1.4, 0.9, 0.6])))
    out = op.tone_map(P, obs, L_match * rgb)
    ratio_out = out / photopic_luminance(out)
    np.testing.assert_allclose(ratio_out, rgb, rtol=0.02)


def test_each_rule_occurs_as_the_cone_pigment_bleaches():
    # Adapted to 1000 cd/m2, the scene's reference range narrows as the cone
    # pigment bleaches (B_cone from 1 to 0.1): wider than the display's
    # (rule 2, compress), then the span fits but sits above the display's
    # (rule 3), then inside it (rule 1), then below (rule 4), each in turn.
    A = 1e3
    B_cone = jnp.linspace(1.0, 0.1, 91)
    state = op.State(A, A, bleach_rod(A), B_cone)
    rules = np.asarray(op.observer(P, state).rule)
    runs = [int(r) for k, r in enumerate(rules) if k == 0 or r != rules[k - 1]]
    assert runs == [2, 3, 1, 4]
    # Steady states: a bright scene's range is wider than the display's, a
    # dim one's sits below it.
    for A, rule in ((1e6, 2), (1e-4, 4)):
        assert int(op.observer(P, op.State(A, A, bleach_rod(A), bleach_cone(A))).rule) == rule


@pytest.mark.slow
@pytest.mark.parametrize("goal", ["log_average", "white_fraction", "foveal"])
def test_run_equals_a_loop_of_step(goal):
    params = op.Params(goal=goal)
    frames = _sequence()
    dt = jnp.array([0.03, 0.05, 0.03, 0.5, 0.03, 2.0])
    out, diag = op.run(params, frames, dt)
    state = op.init(params, frames[0])
    for k in range(frames.shape[0]):
        state, frame_out = op.step(params, state, frames[k], dt[k])
        np.testing.assert_allclose(frame_out, out[k], rtol=1e-10, atol=1e-12)
    for a, b in zip(state, diag.final_state, strict=False):
        np.testing.assert_allclose(a, b, rtol=1e-12)


@pytest.mark.slow
def test_blinks_and_gaze_outside_the_frame_read_the_centre_and_the_edge():
    # A NaN sample (a blink) reads the frame's centre and a point outside
    # the frame its edge, in run as in step: finite output, never NaN.
    params = op.Params(goal="foveal", pixels_per_degree=2.0)
    frames = _sequence()
    dt = jnp.full(6, 0.05)
    centre, corner = [3.0, 2.0], [6.0, 0.0]
    given = jnp.array([[1.0, 1.0], [np.nan, np.nan], [np.nan, 2.0], [60.0, -9.0], centre, corner])
    meant = jnp.array([[1.0, 1.0], centre, centre, corner, centre, corner])
    out, diag = op.run(params, frames, dt, gaze=given)
    expected, expected_diag = op.run(params, frames, dt, gaze=meant)
    assert bool(jnp.all(jnp.isfinite(out)))
    np.testing.assert_allclose(out, expected, rtol=1e-12)
    np.testing.assert_allclose(diag.G_cone, expected_diag.G_cone, rtol=1e-12)
    state = op.init(params, frames[0], gaze=given[0])
    for k in range(frames.shape[0]):
        state, frame_out = op.step(params, state, frames[k], dt[k], gaze=given[k])
        np.testing.assert_allclose(frame_out, out[k], rtol=1e-10, atol=1e-12)


def test_steady_state_of_a_long_constant_scene_is_the_static_model():
    frames = jnp.full((40, 3, 3, 3), 300.0)
    start = op.init(P, None, adaptation=1e-3)
    _, diag = op.run(P, frames, 60.0, state=start)  # 40 minutes
    A = float(diag.G_cone[0])
    s = diag.final_state
    assert float(s.A_cone) == pytest.approx(A, rel=1e-9)
    assert float(s.B_cone) == pytest.approx(float(bleach_cone(A)), rel=1e-9)
    assert float(s.B_rod) == pytest.approx(float(bleach_rod(float(diag.G_rod[0]))), rel=1e-6)


def test_a_viewer_adapted_to_darkness_is_adapted_to_the_floor():
    # adaptation=0 (fully dark-adapted): sigma of Eqs 4-5 is 0/0 there,
    # which would show the first frame of a 10 cd/m2 field as display black
    # instead of a dazzle. It counts as the luminance floor, as the goals of
    # frames do.
    frames = jnp.full((2, 3, 3, 3), 10.0)
    dark, floor = (op.init(P, None, adaptation=a) for a in (0.0, 1e-6))
    out_dark, diag = op.run(P, frames, 0.03, state=dark)
    out_floor, _ = op.run(P, frames, 0.03, state=floor)
    np.testing.assert_array_equal(out_dark, out_floor)
    assert np.all(np.isfinite(np.asarray(diag.sigma_cone))) and float(out_dark[0].min()) > 0.99
    for bad in (-1.0, np.nan):
        with pytest.raises(ValueError, match="adaptation: expected a finite luminance >= 0"):
            op.init(P, None, adaptation=bad)


@pytest.mark.slow
def test_title_step_whites_out_then_recovers():
    scene = scenes.title_step(48, 32, duration=1.5)
    params = op.Params(goal=scene.goal)
    out, diag = op.run(
        params,
        scene.render(scene.times),
        jnp.asarray(scene.dt),
        state=op.init(params, None, adaptation=scene.adaptation),
    )
    mean = jnp.mean(out, axis=(1, 2, 3))
    assert float(diag.G_cone[1]) == pytest.approx(1000.0, rel=0.01)  # the paper's goal
    assert float(mean[1]) > 0.9  # "almost entirely white" at T = 30 ms
    assert float(mean[-1]) < 0.6 and float(mean[-1]) < float(mean[3])  # recovered
    assert jnp.all((diag.state.B_rod >= 0) & (diag.state.B_rod <= 1))


@pytest.mark.slow
def test_vmap_over_a_batch_of_params_equals_separate_runs():
    frames = _sequence()
    t0s = jnp.array([0.05, 0.08, 0.2])
    batch = eqx.tree_at(lambda p: p.t0_cone, P, t0s)
    batch = jax.tree.map(lambda x: jnp.broadcast_to(x, (3,) + jnp.shape(x)), batch)
    batch = eqx.tree_at(lambda p: p.t0_cone, batch, t0s)
    outs, _ = jax.vmap(lambda p: op.run(p, frames, 0.03))(batch)
    for i, t0 in enumerate(t0s):
        single, _ = op.run(op.Params(t0_cone=t0), frames, 0.03)
        np.testing.assert_allclose(outs[i], single, rtol=1e-10)
    # The batch passed as it is is named: otherwise a t0_cone per frame
    # without a word (3 of them, 3 frames), or JAX's broadcasting errors
    # naming no field.
    for field in (t0s, t0s[:2]):
        for call in (
            lambda p: op.run(p, frames[:3], 0.03),
            lambda p: op.step(p, op.init(P, frames[0]), frames[0], 0.03),
            lambda p: op.init(p, frames[0]),
        ):
            with pytest.raises(ValueError, match=r"^t0_cone: expected shape \(\) .* jax.vmap"):
                call(op.Params(t0_cone=field))


@pytest.mark.slow
def test_no_retrace_for_new_values_or_more_steps(count_calls):
    # tone_map as the pixel map (_operator) and the curve (_appearance) call it
    calls = [count_calls(module, "tone_map") for module in (_operator, _appearance)]

    def traces():
        return sum(map(len, calls))

    frames = _sequence(H=11, W=13)  # a shape no other test uses
    op.run(P, frames, 0.03)
    n = traces()
    op.run(P, frames * 2.0, 0.04)
    assert traces() == n
    state = op.init(P, frames[0])
    for k in range(frames.shape[0]):
        state, _ = op.step(P, state, frames[k], 0.03)
    m = traces()
    for k in range(frames.shape[0]):
        state, _ = op.step(P, state, frames[k] * 3.0, 0.05)
    assert traces() == m


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_black_darkness_and_1e8_are_finite(dtype):
    frames = jnp.stack(
        [
            jnp.zeros((4, 4, 3)),  # total darkness
            jnp.full((4, 4, 3), 1e8),  # 1e8 cd/m2
            jnp.zeros((4, 4, 3)).at[0, 0].set(1e8),  # a sun in the dark
            jnp.zeros((4, 4, 3)).at[1:, :].set(1e-6),  # black pixels, starlight
        ]
    ).astype(dtype)
    out, diag = op.run(P, frames, jnp.array(1 / 30, dtype))
    assert out.dtype == dtype
    assert jnp.all(jnp.isfinite(out)) and jnp.all((out >= 0) & (out <= 1))
    for leaf in jax.tree.leaves(diag):
        assert jnp.all(jnp.isfinite(leaf))


@pytest.mark.slow
@pytest.mark.parametrize("background", ["gaussian", "box", "bilateral", "arithmetic"])
def test_a_local_background_after_total_darkness_is_finite_and_whites_out(background):
    # Two black frames, then a ramp from 1e-2 to 1e4 cd/m2. A blur of black
    # is 0; unfloored, the state would go to 0, sigma to 0/0 (NaN in the
    # diagnostics) and the ramp would be erased to a flat grey. Floored as the
    # global goal is, the dark-adapted viewer sees it white, as globally.
    ramp = jnp.logspace(-2.0, 4.0, 24)[None, :, None] * jnp.ones((16, 24, 3))
    frames = jnp.zeros((3, 16, 24, 3)).at[2].set(ramp)
    globally, _ = op.run(P, frames, 1 / 30)
    out, diag = op.run(op.Params(background=background), frames, 1 / 30)
    for leaf in jax.tree.leaves(diag):
        assert jnp.all(jnp.isfinite(leaf))
    assert float(jnp.min(globally[2])) > 0.999
    np.testing.assert_allclose(out, globally, atol=1e-5)


def test_tone_map_refuses_what_is_not_floating_point_rgb():
    # Integer pixels would give integer arithmetic, a black frame, and no
    # error; float16 ones powers and semi-saturations off by up to 0.97 of
    # display white (10,000 cd/m2 shown at 0.03 instead of 0.29).
    obs = op.observer(P, op.static_state(P, jnp.array(100.0), jnp.array(100.0)))
    for bad, what in (
        (jnp.array([[10, 50, 200]]), "int"),
        (jnp.ones((4, 2)), "of shape (4, 2)"),
        (jnp.ones((4, 3), jnp.float16), "float16"),
    ):
        with pytest.raises(
            ValueError, match=r"rgb: expected float32 or float64 .*\(\.\.\., 3\)"
        ) as e:
            op.tone_map(P, obs, bad)
        assert what in str(e.value)
    frames = jnp.full((3, 4, 4, 3), 1e4, jnp.float16)
    with pytest.raises(ValueError, match=r"^frames: expected float32 or float64 .* got float16"):
        op.run(P, frames, 0.1)
    pixel = jnp.array([[10.0, 50.0, 200.0]])
    assert float(jnp.min(op.tone_map(P, obs, pixel))) > 0


@pytest.mark.slow
def test_tone_map_is_the_colour_ratio_power_and_differentiable_at_black():
    # tone_map evaluates (rgb / L_cone)^e L_d / L_white as one exponential
    # per channel; compare with the formula as written, on pixels that are
    # black, miss a channel, lie below display black or saturate.
    obs = op.observer(P, op.static_state(P, jnp.array(300.0), jnp.array(300.0)))
    rgb = jnp.array(
        [[0, 0, 0], [5, 0, 0], [0, 2, 7], [1e-3] * 3, [80, 60, 30], [300, 200, 900], [1e7] * 3],
        dtype=float,
    )
    L_cone = photopic_luminance(rgb)
    R = op.luminance_response(
        P, scotopic_luminance(rgb), L_cone, obs.sigma_rod, obs.sigma_cone, obs.B_rod, obs.B_cone
    )
    L_d = op.display_luminance(P, obs.scale * R + obs.offset)
    e = response_slope(L_cone, obs.sigma_cone, obs.B_cone, P.n) / op.display_slope(P)
    ratio = np.where(L_cone[:, None] > 0, rgb / np.maximum(L_cone, 1e-300)[:, None], 1.0)
    expected = np.clip(
        ratio ** e[:, None] * (L_d / (P.white_factor * P.display_adaptation))[:, None], 0, 1
    )
    assert float(L_d[3]) == 0.0  # below display black
    np.testing.assert_allclose(op.tone_map(P, obs, rgb), expected, rtol=1e-12, atol=1e-30)
    grad = jax.grad(lambda x: jnp.sum(op.tone_map(P, obs, x)))(rgb)
    assert jnp.all(jnp.isfinite(grad))


@pytest.mark.slow
def test_gradient_is_finite_where_pixels_fall_below_display_black():
    # A tunnel frame seen by an eye still adapted to daylight: most pixels
    # map below display black, where the display luminance is 0 and its log
    # is floored. Their gradient must be 0, not NaN (float32, compiled).
    frames = jnp.concatenate([jnp.full((2, 4, 4, 3), 5e3), jnp.full((3, 4, 4, 3), 5.0)])
    frames = frames.at[:, 0, 0].set(0.0).astype(jnp.float32)

    def out(t0_cone):
        return op.run(op.Params(t0_cone=t0_cone), frames, jnp.float32(1 / 30))[0]

    below = out(jnp.float32(0.08))[2:] == 0
    assert jnp.sum(below) > 10
    tangent = jax.jit(jax.jacfwd(out))(jnp.float32(0.08))
    assert jnp.all(jnp.isfinite(tangent))


@pytest.mark.slow
def test_float32_matches_float64():
    frames = _sequence()
    out64, _ = op.run(P, frames, 0.03)
    out32, _ = op.run(P, frames.astype(jnp.float32), jnp.float32(0.03))
    assert out32.dtype == jnp.float32
    np.testing.assert_allclose(out32, out64, atol=2e-4)


def test_display_inverse_matches_bisection():
    R = jnp.linspace(0.0, float(op.display_references(P)[0]), 50)
    L = op.display_luminance(P, R)
    sigma_r, sigma_c, B_rod, B_cone = op.display(P)[:4]  # the display observer
    lo, hi = jnp.zeros_like(R), jnp.full_like(R, 1e4)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        above = op.luminance_response(P, mid, mid, sigma_r, sigma_c, B_rod, B_cone) > R
        lo, hi = jnp.where(above, lo, mid), jnp.where(above, mid, hi)
    np.testing.assert_allclose(L, 0.5 * (lo + hi), rtol=1e-7, atol=1e-12)


@pytest.mark.slow
def test_gradient_through_run_matches_finite_differences():
    frames = _sequence()[:4]

    def loss(t0_cone):
        out, _ = op.run(op.Params(t0_cone=t0_cone), frames, 0.03)
        return jnp.mean(out)

    g = float(jax.grad(loss)(0.08))
    h = 1e-6
    fd = (float(loss(0.08 + h)) - float(loss(0.08 - h))) / (2 * h)
    assert g == pytest.approx(fd, rel=1e-5)
    assert abs(g) > 1e-4


def test_diagnostic_curve_is_monotone_and_matches_pixels():
    frames = _sequence()
    out, diag = op.run(P, frames, 0.03)
    assert jnp.all(jnp.diff(diag.curve, axis=-1) >= -1e-12)
    grey = jnp.full((1, 1, 3), 10.0 ** float(op.CURVE_LOG10_LUMINANCE[70]))
    obs = op.observer(P, jax.tree.map(lambda x: x[2], diag.state))
    assert float(op.tone_map(P, obs, grey)[0, 0, 1]) == pytest.approx(float(diag.curve[2, 70]))


# -- bad input ----------------------------------------------------------------


@pytest.mark.parametrize(
    "frames, match",
    [
        (
            jnp.ones((4, 4, 3)),
            r"frames: expected .*\(T, H, W, 3\).* got float64 of shape \(4, 4, 3\)",
        ),
        (jnp.ones((2, 4, 4, 4)), r"frames: expected .* of shape \(2, 4, 4, 4\)"),
        (jnp.ones((0, 4, 4, 3)), r"frames: expected .*no axis of length 0.* \(0, 4, 4, 3\)"),
    ],
)
def test_wrong_shapes_are_named(frames, match):
    with pytest.raises(ValueError, match=match):
        op.run(P, frames, 0.03)


@pytest.mark.parametrize("bad", [-1.0, jnp.nan, jnp.inf])
def test_bad_values_are_named(bad):
    frames = jnp.ones((2, 3, 3, 3)).at[1, 1, 1, 0].set(bad)
    with pytest.raises(ValueError, match="^frames: expected finite, non-negative"):
        op.run(P, frames, 0.03)
    with pytest.raises(eqx.EquinoxRuntimeError, match="frames: expected finite, non-negative"):
        eqx.filter_jit(lambda f: op.run(P, f, 0.03)[0])(frames)  # inside the caller's jit


def test_bad_dt_is_named():
    frames = jnp.ones((3, 2, 2, 3))
    with pytest.raises(ValueError, match=r"dt: expected a scalar or shape \(3,\)"):
        op.run(P, frames, jnp.ones(4))
    with pytest.raises(ValueError, match="^dt: expected positive"):
        op.run(P, frames, jnp.array([0.1, 0.0, 0.1]))
    # One verdict checks both: bad frames are named first.
    with pytest.raises(ValueError, match="^frames: expected finite"):
        op.run(P, frames.at[0, 0, 0, 0].set(jnp.nan), jnp.array([0.1, 0.0, 0.1]))
    state = op.init(P, frames[0])
    with pytest.raises(ValueError, match="^dt: expected positive"):
        op.step(P, state, frames[0], -0.1)
    with pytest.raises(ValueError, match="^first_frame: expected finite"):
        op.init(P, frames[0].at[0, 0, 0].set(-1.0))
    with pytest.raises(ValueError, match=r"dt: expected a scalar or shape \(1,\)"):
        op.step(P, state, frames[0], jnp.ones(2))


def test_a_state_of_the_wrong_kind_or_shape_is_named():
    # A local background's state maps of the wrong shape are named, not
    # left to JAX's broadcasting error.
    frames = jnp.full((3, 4, 5, 3), 100.0)
    local = op.Params(background="gaussian")
    state = op.init(local, frames[0])
    with pytest.raises(ValueError, match=r"^state: .* \(4, 5\) .* got A_rod of shape \(5, 4\)"):
        op.run(local, frames, 0.1, state=state._replace(A_rod=jnp.ones((5, 4))))
    with pytest.raises(ValueError, match=r"^state: expected a pattanaik2000.State .* got tuple"):
        op.run(P, frames, 0.1, state=(1.0, 1.0, 0.5, 0.5))
    with pytest.raises(ValueError, match=r"^state: expected a pattanaik2000.State .* got NoneType"):
        op.step(P, None, frames[0], 0.1)  # JAX's "vmap must have at least one non-None"
    with pytest.raises(ValueError, match=r"^state: expected fields of shape \(\), got A_rod"):
        op.run(P, frames, 0.1, state=op.init(P, frames[0])._replace(A_rod=jnp.ones(3)))


def test_unknown_goal_is_named():
    with pytest.raises(ValueError, match="goal: expected one of"):
        op.Params(goal="median")


# -- local time-dependent adaptation (HDR chapter) ----------------------------


def _half_lit(T=4, H=6, W=10, dark=5.0, bright=5000.0):
    frame = jnp.full((H, W, 3), dark).at[:, W // 2 :].set(bright)
    return jnp.broadcast_to(frame, (T, H, W, 3))


@pytest.mark.slow
def test_local_background_on_a_uniform_scene_is_the_global_operator():
    levels = jnp.array([1e-3, 1e-3, 1e3, 1e3, 5.0, 5e4])
    frames = jnp.broadcast_to(levels[:, None, None, None], (6, 5, 7, 3))
    dt = 0.05
    out_global, diag_global = op.run(P, frames, dt)
    for background in ("gaussian", "bilateral", "adaptive"):
        local = op.Params(background=background, background_scale=2.0)
        out_local, diag_local = op.run(local, frames, dt)
        np.testing.assert_allclose(out_local, out_global, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(diag_local.state.A_cone, diag_global.state.A_cone, rtol=1e-9)


@pytest.mark.slow
def test_local_state_adapts_per_pixel_with_the_exact_kinetics():
    # Adapted to 5 cd/m2 everywhere, then half the field jumps to 5000: the
    # bright half's cone adaptation follows the neural filter towards its
    # local background, the dark half stays; rules and curves differ.
    params = op.Params(background="gaussian", background_scale=1.0)
    frames = _half_lit(T=3, W=40)
    start = op.init(params, None, adaptation=5.0)
    _, diag = op.run(params, frames, 0.05, state=start)
    A = diag.final_state.A_cone
    assert A.shape == (6, 40)
    G = op.frame_goals(params, frames[0], None)[1]
    expected = kinetics.neural_step(5.0, G, params.t0_cone, 0.15)
    np.testing.assert_allclose(A, expected, rtol=1e-9)
    assert float(A[:, -1].mean()) > 1000 and float(A[:, 0].mean()) == pytest.approx(5.0, rel=1e-3)


@pytest.mark.slow
def test_local_run_equals_a_loop_of_step():
    params = op.Params(background="bilateral", background_scale=2.0)
    frames = _sequence(W=12)
    out, diag = op.run(params, frames, 0.04)
    state = op.init(params, frames[0])
    for k in range(frames.shape[0]):
        state, frame_out = op.step(params, state, frames[k], 0.04)
        np.testing.assert_allclose(frame_out, out[k], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(state.B_rod, diag.final_state.B_rod, rtol=1e-12)


@pytest.mark.parametrize(
    "field, value",
    [("t0_cone", -0.08), ("tau_rod", jnp.nan), ("n", -1.0), ("c_cone", jnp.inf)],
)
def test_a_parameter_out_of_its_range_is_named(field, value):
    # A negative t0 would drive the adaptation state below zero and a NaN
    # one make it NaN, while the display frames stay finite: nothing would
    # say so.
    with pytest.raises(ValueError, match=f"{field}: expected a positive, finite number"):
        op.Params(**{field: value})
    with pytest.raises(ValueError, match=r"goal_fraction: expected in \(0, 1\]"):
        op.Params(goal_fraction=0.0)
    # Traced values are not checked (a Params built under vmap or jit).
    t0 = jax.vmap(lambda t: op.Params(t0_cone=t).t0_cone)(jnp.array([-1.0, 0.1]))
    np.testing.assert_allclose(t0, [-1.0, 0.1])


@pytest.mark.parametrize("ratio", [1.0, 0.5])
def test_reference_black_must_lie_below_white(ratio):
    # At black_ratio = 1 the display's colour exponent S_d is 0/0 and every
    # pixel NaN; at 0.5 the tone curve is a step from 0 to 1.
    with pytest.raises(ValueError, match="black_ratio: expected a number above 1"):
        op.Params(black_ratio=ratio)


def test_unknown_background_and_bad_scale_are_named():
    with pytest.raises(ValueError, match="background: expected one of"):
        op.Params(background="median")
    with pytest.raises(ValueError, match="background_scale: expected a positive"):
        op.Params(background="gaussian", background_scale=0.0)


@pytest.mark.parametrize("name", ["pattanaik2000", "jacobs2015", "classic"])
def test_programs_called_as_they_are_hold_no_host_callback(name):
    # JAX's persistent compilation cache keeps no program with a host
    # callback (equinox's error_if is one): with one inside, a render would
    # compile its operator anew at every run. Called outside jit, the
    # operators check on the host.
    import importlib

    module = importlib.import_module(f"jaxadapt.operators.{name}")
    frames, dt = jnp.ones((2, 4, 4, 3)), jnp.full(2, 0.1)
    params = module.Params()
    key = jax.random.key(0)
    args = {
        "pattanaik2000": (params, frames, dt, None, None),
        "jacobs2015": (params, frames, dt, jnp.full((2, 2), 1.5), key, None),
        "classic": (params, frames, dt),
    }[name]
    programs = getattr(module, "_operator", module)  # a package's are in its _operator
    for on_host, has_callback in ((True, False), (False, True)):
        text = programs._run.lower(*args, on_host).as_text()
        assert ("callback" in text) == has_callback
