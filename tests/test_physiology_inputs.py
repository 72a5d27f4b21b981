"""What the physiology functions take: lists as arrays, and NaN outside their domain."""

import inspect

import jax.numpy as jnp
import numpy as np
import pytest

from jaxadapt.physiology import pupil, response, threshold


def _public(module):
    return [
        pytest.param(fn, id=f"{module.__name__.rsplit('.', 1)[1]}.{name}")
        for name, fn in inspect.getmembers(module, inspect.isfunction)
        if fn.__module__ == module.__name__ and not name.startswith("_")
    ]


PUBLIC = _public(pupil) + _public(response) + _public(threshold)


def _required(fn):
    signature = inspect.signature(fn)
    return [p for p in signature.parameters.values() if p.default is inspect.Parameter.empty]


@pytest.mark.parametrize("fn", PUBLIC)
@pytest.mark.parametrize("sequence", [list, tuple])
def test_a_list_or_tuple_is_taken_as_an_array(fn, sequence):
    # In every function's domain: a response of 0.2 or 0.5 below a maximum of
    # 0.5 + 0.5, a criterion of 0.5 or 0.4 below the headroom.
    values = [[0.2, 0.5]] + [[0.5, 0.4]] * (len(_required(fn)) - 1)
    expected = fn(*(jnp.asarray(v) for v in values))
    got = fn(*(sequence(v) for v in values))
    assert np.all(np.isfinite(expected))
    np.testing.assert_array_equal(got, expected)


def test_a_list_is_taken_as_a_keyword_argument_too():
    np.testing.assert_array_equal(
        threshold.trolands(L=[1.0, 100.0], d=[2.0, 3.0]),
        threshold.trolands(jnp.array([1.0, 100.0]), jnp.array([2.0, 3.0])),
    )


#: Functions of a luminance, a retinal illuminance or a diameter (first argument).
OF_LUMINANCE = [
    pupil.diameter_moon_spencer,
    pupil.diameter_de_groot_gebhard,
    pupil.area,
    response.bleach_cone,
    response.bleach_rod,
    response.hunt_F_L,
    response.hunt_F_LS,
    response.sigma_cone,
    response.sigma_rod,
    threshold.tvi_rod,
    threshold.tvi_cone,
    threshold.tvi_rod_cone,
    threshold.tvi_luminance,
    threshold.tvi_blackwell,
]


@pytest.mark.parametrize("fn", OF_LUMINANCE, ids=lambda fn: fn.__name__)
def test_a_negative_luminance_gives_nan_and_zero_a_number(fn):
    out = np.asarray(fn(jnp.array([-1.0, -1e-30, 0.0, 1.0])))
    assert np.all(np.isnan(out[:2])), out  # a pupil of 7.9 mm, a bleaching above 1: no
    assert np.all(np.isfinite(out[2:])), out


def test_trolands_of_a_negative_luminance_or_diameter_are_nan():
    out = np.asarray(threshold.trolands(jnp.array([-1.0, 1.0, 1.0]), jnp.array([2.0, -2.0, 2.0])))
    assert np.isnan(out[0]) and np.isnan(out[1]) and out[2] == pytest.approx(np.pi)
