"""What the Jacobs et al. (2015) experiment scripts share: running a scene and
turning its display values into images to show."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt.operators import jacobs2015 as op


def run_scene(scene, params, seed=0):
    """Render a :class:`jaxadapt.scenes.Scene` with the 2015 operator, in float32,
    at the scene's resolution (``pixels_per_degree``) and along its gaze path;
    ``params.afterimage_blur`` is read as meant for the paper's display and
    frame rate (:func:`~jaxadapt.operators.jacobs2015.blur_for_display`).

    The viewer starts globally adapted to ``scene.adaptation`` (cd/m2,
    floored at ``params.adaptation_floor``) with the retinal maps at
    equilibrium with the first frame (:func:`~jaxadapt.operators.jacobs2015.init`);
    with ``scene.adaptation`` None, adapted to the first frame.

    Returns ``(display, diagnostics)``: display values ``(T, H, W, 3)`` as
    NumPy and the operator's per-frame record.
    """
    frames = jnp.asarray(scene.render(scene.times), jnp.float32)
    gaze = jnp.asarray(scene.gaze(scene.times), jnp.float32)
    ppd = scene.pixels_per_degree
    blur = op.blur_for_display(ppd, 1.0 / float(np.median(scene.dt)), params.afterimage_blur)
    params = dataclasses.replace(params, pixels_per_degree=ppd, afterimage_blur=blur)
    dt = jnp.asarray(scene.dt, jnp.float32)
    key = jax.random.key(seed)
    state = None
    if scene.adaptation is not None:
        state = op.init(params, frames[0], gaze=gaze[0], key=key, adaptation=scene.adaptation)
    out, diag = op.run(params, frames, dt, gaze=gaze, key=key, state=state)
    return np.asarray(out), diag


def linear(display, params):
    """Linear display values of the operator's display values, numpy
    (:func:`jaxadapt.operators.jacobs2015.decode`)."""
    return np.asarray(op.decode(params, display))


def encode(values, params):
    """Display values of linear ones, numpy
    (:func:`jaxadapt.operators.jacobs2015.encode`)."""
    return np.asarray(op.encode(params, values))


def scaled_to_max(display, params, axis=None):
    """Display values rescaled so that their linear maximum over ``axis``
    (None: all) is one; all black stays black."""
    lin = linear(display, params)
    return encode(lin / np.maximum(lin.max(axis=axis, keepdims=True), 1e-12), params)


def scaled_to_mean(display, params, mean):
    """Display values rescaled so that their linear mean is ``mean`` (in
    [0, 1]), clipped to the display's range."""
    lin = linear(display, params)
    return encode(lin * mean / lin.mean(), params)
