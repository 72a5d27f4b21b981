"""What the Jacobs et al. (2015) experiment scripts share: running a scene."""

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

    Returns ``(display, diagnostics)``: display values ``(T, H, W, 3)`` as
    NumPy and the operator's per-frame record.
    """
    frames = jnp.asarray(scene.render(scene.times), jnp.float32)
    gaze = jnp.asarray(scene.gaze(scene.times), jnp.float32)
    ppd = scene.pixels_per_degree
    blur = op.blur_for_display(ppd, 1.0 / float(np.median(scene.dt)), params.afterimage_blur)
    params = dataclasses.replace(params, pixels_per_degree=ppd, afterimage_blur=blur)
    dt = jnp.asarray(scene.dt, jnp.float32)
    out, diag = op.run(params, frames, dt, gaze=gaze, key=jax.random.key(seed))
    return np.asarray(out), diag


def linear(display, params):
    """Linear display values of gamma-encoded ones (``J^(1/gamma)``)."""
    return np.asarray(display) ** (1.0 / float(params.gamma))
