"""Every operator gives finite display values in [0, 1] for every finite,
non-negative frame in float32: darkness, denormals, ordinary scenes and
values up to float32's largest (3.4e38), alone or mixed in one frame.

Luminance above :data:`jaxadapt.background.LUMINANCE_CEILING` counts as
the ceiling (:func:`jaxadapt.operators.checks.saturate`), where the models
have saturated; below it nothing changes.
"""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from jaxadapt import io
from jaxadapt.background import BACKGROUNDS, LUMINANCE_CEILING
from jaxadapt.cli import main
from jaxadapt.operators import OPERATORS, checks, classic, jacobs2015, pattanaik2000

F32_MAX = float(np.finfo(np.float32).max)

#: Values that would break an operator without the ceiling: float32's
#: largest, the largest whose luminance sum stays finite, a value whose
#: reciprocal is a denormal, one whose Hunt adaptation factor (5 A)
#: overflows, darkness, denormals and the smallest normal.
SPECIAL = (F32_MAX, 3.4e38, 1e38, 7e37, 1e30, 1e10, 1e8, 1.0, 1e-30, 1.2e-38, 1e-40, 1e-45, 0.0)

channel = st.one_of(
    st.sampled_from(SPECIAL),
    st.floats(0.0, F32_MAX, width=32, allow_subnormal=True),
    st.floats(float(np.float32(1e-3)), float(np.float32(1e5)), width=32),
)


@st.composite
def frames(draw, shape=(2, 6, 8, 3)):
    """Float32 frames mixing the values above, or uniform at one of them."""
    if draw(st.booleans()):
        return np.full(shape, draw(st.sampled_from(SPECIAL)), np.float32)
    return draw(arrays(np.float32, shape, elements=channel))


def _configurations():
    """Each operator with its default background, each background with a
    tone curve, and the 2000 operator's local state and other goal (the
    ceiling comes before any background, so the rest are alike)."""
    for name in OPERATORS:
        if name == "pattanaik2000":
            yield name, pattanaik2000.Params()
        elif name == "jacobs2015":
            yield name, jacobs2015.Params()
        else:
            yield name, classic.Params(classic.TONE_CURVES[name]())
    for background in BACKGROUNDS:
        if background != "global":
            yield f"ward-jnd-{background}", classic.Params(classic.WardJND(), background, 2.0)
    for background in ("arithmetic", "bilateral"):
        params = pattanaik2000.Params(background=background, background_scale=2.0)
        yield f"pattanaik2000-{background}", params
    yield "pattanaik2000-white_fraction", pattanaik2000.Params(goal="white_fraction")


CONFIGURATIONS = dict(_configurations())


def _module(params):
    for module in (pattanaik2000, jacobs2015, classic):
        if isinstance(params, module.Params):
            return module
    raise AssertionError(params)


def _assert_display(out):
    out = np.asarray(out)
    assert out.dtype == np.float32
    assert np.isfinite(out).all(), np.argwhere(~np.isfinite(out))[:5]
    assert out.min() >= 0.0 and out.max() <= 1.0


@pytest.mark.filterwarnings("error::RuntimeWarning")
@pytest.mark.parametrize("name", list(CONFIGURATIONS))
@settings(max_examples=10)
@given(f=frames())
def test_every_operator_shows_any_finite_frame(name, f):
    params = CONFIGURATIONS[name]
    op = _module(params)
    out, _ = op.run(params, jnp.asarray(f), np.float32(1 / 30), key=jax.random.key(0))
    _assert_display(out)


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_a_step_and_an_init_at_the_extremes_are_finite():
    # The live viewer's calls: init (here adapted to float32's largest
    # value) and a step of a frame that mixes it with darkness.
    frame = np.full((6, 8, 3), F32_MAX, np.float32)
    frame[0, :2] = 0.0
    frame[1, :2] = 1e-45
    key = jax.random.key(0)
    state = jacobs2015.init(jacobs2015.Params(), frame, key=key, adaptation=F32_MAX)
    assert np.isfinite(state.A) and np.isfinite(state.B).all() and np.isfinite(state.C).all()
    params = pattanaik2000.Params()
    state = pattanaik2000.init(params, frame, adaptation=F32_MAX)
    assert all(np.isfinite(x) for x in state)
    _, out = pattanaik2000.step(params, state, frame, np.float32(1 / 30))
    _assert_display(out)


def test_the_ceiling_clips_channels_and_leaves_the_rest_alone():
    rgb = jnp.asarray([[F32_MAX, 3e10, 0.0], [1e10, 1.0, 1e-30]], jnp.float32)
    got = np.asarray(checks.saturate(rgb))
    np.testing.assert_array_equal(got[0], np.float32([LUMINANCE_CEILING, LUMINANCE_CEILING, 0]))
    assert (got[1] == np.asarray(rgb[1])).all()  # at the ceiling and below: exactly as given
    planes = [checks.saturate(c) for c in jnp.moveaxis(rgb, -1, 0)]  # (a fused kernel's form)
    np.testing.assert_array_equal(np.stack(planes, axis=-1), got)


def test_above_the_ceiling_a_frame_is_shown_as_at_it():
    # The models have saturated: a frame beyond the ceiling is the frame at it.
    at = np.full((2, 6, 8, 3), LUMINANCE_CEILING, np.float32)  # the shape compiled above
    for name in ("pattanaik2000", "photographic", "ward-jnd"):
        params = CONFIGURATIONS[name]
        op = _module(params)
        want, _ = op.run(params, jnp.asarray(at), np.float32(0.1))
        got, _ = op.run(params, jnp.asarray(at * 1e28), np.float32(0.1))
        np.testing.assert_array_equal(got, want)


@pytest.mark.filterwarnings("error::RuntimeWarning")
@pytest.mark.parametrize("operator", list(OPERATORS))
def test_render_of_extreme_frames_exits_0_with_finite_frames(operator, tmp_path, capsys):
    mixed = np.full((6, 8, 3), 1.0, np.float32)
    mixed[1:3, 1:3] = 3.0e38
    mixed[4, 4:7] = 1e-30
    mixed[5, 0] = 0.0
    mixed[5, 1] = (F32_MAX, 0.0, 1e-45)
    paths = []
    for i, frame in enumerate((np.full_like(mixed, F32_MAX), mixed)):
        paths.append(str(tmp_path / f"f{i}.exr"))
        io.write_image(paths[-1], frame)
    out = tmp_path / "out"
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        args = [*paths, "--operator", operator, "--format", "exr", "--out", str(out)]
        status = main(["render", *args])
    assert status == 0, capsys.readouterr().err
    for i in range(2):
        frame = io.read_hdr(out / f"frame_{i:05d}.exr")
        assert np.isfinite(frame).all() and frame.min() >= 0 and frame.max() <= 1


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_files_whose_values_leave_float32_when_read_are_clipped(tmp_path):
    # ACES primaries turn a legal 3e38 red into BT.709 5e38, and a PFM's
    # scale of 2 doubles 3e38. Clipped to float32's largest, such values
    # raise no NumPy overflow warning and do not become infinities that the
    # operators would refuse as if the file held one.
    import OpenImageIO as oiio

    img = np.full((4, 6, 3), 1.0, np.float32)
    img[0, 0] = (3.0e38, 0.0, 0.0)
    img[1, 1] = np.inf  # the file's own infinity stays one
    spec = oiio.ImageSpec(6, 4, 3, "float")
    aces = (0.7347, 0.2653, 0.0, 1.0, 0.0001, -0.077, 0.32168, 0.33767)
    spec.attribute("chromaticities", oiio.TypeDesc("float[8]"), aces)
    path = str(tmp_path / "aces.exr")
    out = oiio.ImageOutput.create(path)
    out.open(path, spec)
    out.write_image(img)
    out.close()
    got = io.read_hdr(path)
    np.testing.assert_array_equal(got[0, 0], [F32_MAX, 0.0, 0.0])
    assert (
        not np.isfinite(got[1, 1]).any() and np.isfinite(np.delete(got.reshape(-1, 3), 7, 0)).all()
    )
    pfm = tmp_path / "scaled.pfm"
    pfm.write_bytes(b"PF\n2 1\n-2.0\n" + np.array([[3e38] * 3, [1.0] * 3], "<f4").tobytes())
    np.testing.assert_array_equal(io.read_hdr(pfm)[0], [[F32_MAX] * 3, [2.0] * 3])
