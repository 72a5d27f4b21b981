"""The viewer's default size: the largest of a ladder whose frames keep the
frame rate asked, predicted from the smallest size and then measured."""

import pytest

from jaxadapt.viewer import LADDER, fitting_size


def _measure(costs, asked):
    """A ``measure`` whose frames cost ``costs(size)`` s, noting each size asked."""

    def measure(spec, size):
        asked.append(size)
        return costs(size)

    return measure


def _pixels(size):
    return size[0] * size[1]


@pytest.mark.parametrize(
    ("per_pixel_us", "expected"),
    # at 30 frames/s, 33 ms a frame: 384x216 is 82,944 pixels, 960x540 518,400,
    # 1280x720 921,600, 1920x1080 2,073,600
    [(0.3, (384, 216)), (0.05, (960, 540)), (0.01, (1920, 1080))],
)
def test_the_largest_size_whose_frames_keep_the_rate_is_taken(per_pixel_us, expected):
    asked = []
    costs = lambda s: per_pixel_us * 1e-6 * _pixels(s)  # noqa: E731
    size, seconds = fitting_size({}, 30.0, _measure(costs, asked))
    assert (size, seconds) == (expected, costs(expected))
    # the smallest is timed, then the size predicted, which keeps up as predicted
    assert asked == list(dict.fromkeys([LADDER[0], expected]))


def test_a_cost_that_outgrows_the_pixels_steps_down_to_a_size_that_keeps_up():
    # 0.01 us a pixel at 384x216 predicts 1920x1080; a cost a pixel that grows
    # with the width (a blur sized in degrees) makes the larger sizes slower,
    # and sizes are measured from the prediction down until one keeps up.
    asked = []

    def costs(size):
        return 0.01e-6 * _pixels(size) * (size[0] / 384) ** 2

    size, seconds = fitting_size({}, 30.0, _measure(costs, asked))
    assert seconds == costs(size) <= 1 / 30
    larger = [s for s in LADDER if _pixels(s) > _pixels(size)]
    assert costs(larger[0]) > 1 / 30  # the next size up would not keep up
    assert asked[:2] == [LADDER[0], (1920, 1080)] and asked[-1] == size


def test_a_frames_fixed_cost_is_outgrown_by_climbing_from_a_size_that_keeps_up():
    # 3 ms a frame whatever its size, plus 0.01 us a pixel: 384x216's cost a
    # pixel predicts 960x540 at most; 960x540's, measured, predicts 1920x1080,
    # which keeps up (24 ms).
    asked = []
    costs = lambda s: 3e-3 + 0.01e-6 * _pixels(s)  # noqa: E731
    size, seconds = fitting_size({}, 30.0, _measure(costs, asked))
    assert (size, seconds) == ((1920, 1080), costs((1920, 1080)))
    assert asked == [LADDER[0], (960, 540), (1920, 1080)]


def test_even_the_smallest_too_slow_gives_the_smallest():
    size, seconds = fitting_size({}, 30.0, lambda spec, s: 1.0)
    assert (size, seconds) == (LADDER[0], 1.0)


@pytest.mark.slow
def test_a_real_session_is_measured():
    spec = {"scene": "patches", "operator": "pattanaik2000"}
    size, seconds = fitting_size(spec, 1.0, ladder=((32, 18), (64, 36)))
    assert size in ((32, 18), (64, 36)) and seconds > 0
