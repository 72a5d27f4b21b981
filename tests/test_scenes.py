"""Built-in scenes: calibrated in the cd/m2 they document."""

import numpy as np
import pytest

from jaxadapt import scenes
from jaxadapt.color import photopic_luminance
from jaxadapt.gaze import recorded_gaze


@pytest.mark.parametrize("size", [(480, 320), (120, 80)])
def test_interior_with_window_is_calibrated_in_cd_m2(size):
    rgb, labels = scenes.interior_with_window(*size)
    assert rgb.shape == (size[1], size[0], 3) and rgb.dtype == np.float32
    assert labels.shape == rgb.shape[:2]
    L = np.asarray(photopic_luminance(rgb))
    fy = np.broadcast_to((np.arange(size[1]) / size[1])[:, None], labels.shape)
    fx = np.broadcast_to(np.arange(size[0]) / size[0], labels.shape)
    room, outside = L[labels == scenes.ROOM], L[labels == scenes.OUTSIDE]
    assert room.min() >= 1.6 and room.max() <= 53.0
    np.testing.assert_allclose(L[labels == scenes.FRAME], 15.0, rtol=1e-5)
    sky = (labels == scenes.OUTSIDE) & (fy < 0.3)
    assert L[sky].min() >= 4800.0 and L[sky].max() <= 5520.0
    shaded = (labels == scenes.OUTSIDE) & ~sky & (fx < 0.6)
    sunlit = (labels == scenes.OUTSIDE) & ~sky & (fx >= 0.6)
    np.testing.assert_allclose([L[shaded].min(), L[shaded].max()], [1200.0, 1500.0], rtol=1e-5)
    np.testing.assert_allclose([L[sunlit].min(), L[sunlit].max()], [1.6e4, 2e4], rtol=1e-5)
    assert outside.max() == pytest.approx(2e4, rel=1e-5)


def test_the_mesopic_chart_has_the_papers_luminance_at_its_white_tile():
    # Jacobs 2015 §4.2: 5.5e-2 cd/m2 "at the white tile", not on a perfect
    # white diffuser, which would leave the tile (reflecting 0.89 of it)
    # 11 % darker.
    frame = np.asarray(scenes.mesopic(width=96, height=64, duration=0.1).render(0.0))[0]
    assert float(photopic_luminance(frame).max()) == pytest.approx(5.5e-2, rel=1e-5)
    assert scenes.white_tile() == pytest.approx(0.887, abs=0.005)


@pytest.mark.parametrize("name", sorted(scenes.SCENES))
def test_every_scene_renders_one_time_as_a_batch_of_one(name):
    # Every scene takes a scalar time, as a batch of one.
    scene = scenes.SCENES[name](width=32, height=16, duration=0.5)
    frames = np.asarray(scene.render(scene.times[0]))
    assert frames.shape == (1, 16, 32, 3) and np.all(np.isfinite(frames))
    assert np.asarray(scene.gaze(scene.times[0])).shape == (1, 2)
    assert scene.shape == (16, 32)  # known before rendering: a render checks its size first


def test_a_scenes_size_is_known_without_rendering_a_frame():
    from jaxadapt import pipeline

    scene = scenes.tunnel_drive(width=40, height=24, duration=0.2)

    def unrendered(t):
        raise AssertionError("a frame was rendered to learn the size")

    source = pipeline.from_scene(scene._replace(render=unrendered))
    assert source.shape == (24, 40)


@pytest.mark.parametrize(
    "make, name",
    [
        (lambda: scenes.tunnel_drive(-4, 8), "width"),
        (lambda: scenes.flash(fps=0), "fps"),
        (lambda: scenes.title_step(duration=-1), "duration"),
        (lambda: scenes.title_step(duration=0.001), "duration, fps"),
        (lambda: scenes.title_step(duration=1e308), "duration, fps"),  # an OverflowError
        (lambda: scenes.flash(duration=0.2), "duration"),  # before the flash's onset
        (lambda: scenes.title_step(sunlight_goal=-5), "sunlight_goal"),
        (lambda: scenes.flash(luminance=float("nan")), "luminance"),
        (lambda: scenes.checkerboard(white=-1), "white"),
        (lambda: scenes.checkerboard(checks=0), "checks"),
        (lambda: scenes.mesopic(white=-1), "white"),
        (lambda: scenes.tunnel_drive(speed=float("nan")), "speed"),
        (lambda: recorded_gaze([2.0, 0.0, 1.0], np.zeros((3, 2))), "times"),
        (lambda: recorded_gaze([0.0, 1.0, 2.0], [1.0, 2.0, 3.0]), "times, points"),
        (lambda: recorded_gaze([], np.zeros((0, 2))), "times, points"),
    ],
)
def test_bad_scene_arguments_are_named(make, name):
    # Unchecked, each would run: NaN or negative frames, a plain board, a
    # frame of width 0, a ZeroDivisionError, or a gaze read from unsorted
    # samples.
    with pytest.raises(ValueError, match=f"^{name}: expected"):
        make()


def test_the_tunnel_fovea_is_a_degree_at_the_centre_of_the_view():
    # A pinhole of 60 degrees: pixels per degree at the centre are the focal
    # length per radian, not the width over the field (10 % more).
    width = 480
    scene = scenes.tunnel_drive(width, 270, duration=0.1)
    focal = 0.5 * width / np.tan(np.radians(30.0))
    assert scene.pixels_per_degree == pytest.approx(focal * np.tan(np.radians(0.5)) * 2, rel=1e-4)


def test_the_one_chart_patch_outside_bt709_is_clipped_as_documented():
    # colorchecker_rgb: cyan (no. 18) has red -0.033 in BT.709 under D65.
    rgb = scenes.colorchecker_rgb()
    assert np.all(rgb >= 0) and np.count_nonzero(rgb == 0) == 1 and rgb[2, 5, 0] == 0
    assert float(photopic_luminance(rgb[2, 5])) == pytest.approx(0.2058, abs=5e-4)


def test_integer_sizes_of_numpy_and_jax_are_sizes():
    # A 0-d integer array or a JAX integer is a whole number.
    import jax.numpy as jnp

    scene = scenes.mesopic(np.array(16), jnp.int32(12), np.float32(0.2), np.float32(10.0))
    assert np.asarray(scene.render(scene.times[:1])).shape == (1, 12, 16, 3)


def test_fixation_crosses_stay_on_their_side_of_a_small_frame():
    # A 6-pixel-wide frame: the left cross (at x = 1, arms of 2) reaches
    # past the edge, and its row sliced from -1, which indexes from the far
    # end, would give an empty arm.
    frame = np.asarray(scenes.checkerboard(width=6, height=8, duration=0.1).render(0.0))[0]
    assert np.all(frame[4] == 0)  # both crosses' horizontal arms: the whole row
    assert np.all(frame[2:7, 1] == 0) and np.all(frame[2:7, 4] == 0)  # their vertical arms
