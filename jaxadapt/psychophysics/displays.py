"""The stimuli of the 2015 paper's two constant-stimuli experiments,
rendered with the 2015 operator as they are shown on the display.

:func:`afterimage_displays` renders the camera flash of §4.1.1 and
:func:`mesopic_displays` the colour checker of §4.2.1 of Jacobs et al.
(2015), through :mod:`jaxadapt.operators.jacobs2015` (``Params`` and ``run``
only), once per condition and level; :data:`DISPLAYS` picks one by protocol
name.
"""

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt import scenes
from jaxadapt.color import photopic_luminance
from jaxadapt.operators import jacobs2015

__all__ = [
    "Displays",
    "AfterimageRenders",
    "afterimage_displays",
    "afterimage_renders",
    "mesopic_displays",
    "mesopic_render",
    "DISPLAYS",
]


class Displays(NamedTuple):
    """Rendered stimuli as they are shown on the display.

    Attributes
    ----------
    test : array, (C, L, T, H, W, 3)
        Each condition's test at each level: linear BT.709 RGB, cd/m2.
    standard : array, (T, H, W, 3)
        The standard, cd/m2.
    presented : array of bool, (T,)
        Frames on which the image is shown.
    blank : array of bool, (T,)
        Frames of the black screen that follows it (afterimages appear there).
    ambient : float
        Luminance of the room with the black screen shown, cd/m2.
    times : array, (T,)
        Time of each frame, s.
    """

    test: jax.Array
    standard: jax.Array
    presented: jax.Array
    blank: jax.Array
    ambient: float
    times: np.ndarray


def _check_conditions(protocol):
    if tuple(protocol.conditions) != ("control", "manipulated"):
        raise ValueError(
            f"protocol.conditions: expected ('control', 'manipulated'), got {protocol.conditions!r}"
        )


def _whole_frames(name, seconds, fps, least):
    """``seconds`` as a whole number (at least ``least``) of frames at ``fps``,
    ``n / fps`` exactly, so that the flash's edges fall on frame starts; a
    ValueError naming ``name`` when it is not within 1e-6 of a frame."""
    n = seconds * fps
    if abs(n - round(n)) > 1e-6 or round(n) < least:
        raise ValueError(
            f"{name}: expected a whole number (>= {least}) of frames at fps = {fps!r}, "
            f"got {seconds!r} s ({n:.4g} frames)"
        )
    return round(n) / fps


def afterimage_displays(
    protocol,
    *,
    key,
    width=32,
    height=32,
    fps=40.0,
    lead_s=0.25,
    flash_luminance=1e7,
    j1=(3e-4, 1e-3),
):
    """The stimuli of the afterimage experiment (§4.1.1), rendered.

    The camera-flash scene is :func:`jaxadapt.scenes.flash`: a white disk of
    ``flash_luminance`` cd/m2 (the flash of the paper's Fig. 4) at the
    fixation, shown for ``protocol.presentation_s`` (50 ms) after
    ``lead_s`` of darkness, then ``protocol.blank_s`` (2.5 s) of black on
    which the afterimage appears. It is rendered by the 2015 operator with
    the paper's weak synthetic afterimage (``j1 = 3e-4``: standard and
    control tests) and strong one (``j1 = 1e-3``: manipulated tests); the
    acuity loss (which leaves a photopic flash and a black screen unchanged)
    and the dithering are off, so that the rendering is deterministic.

    On the display, a linear value ``v`` is shown at ``k v`` cd/m2, ``k``
    chosen so that the standard's flash (its brightest point, averaged over
    the shown frames) measures ``protocol.standard`` (27 cd/m2). Tests are
    "identical to the standard, but scaled": their shown frames are
    multiplied by ``10^level``; the blank frames are not, so that the
    afterimage of each condition is the same at every level, as the paper
    gives one afterimage luminance per condition.

    The afterimage is linear in ``j1``, so the strong one is ``j1``'s ratio
    times the weak one, close to the ratio of the afterimage luminances the
    paper measured on its display (§4.1.1; :data:`jaxadapt.psychophysics.design.AFTERIMAGE`).
    The retinal maps are blurred between frames by the angle they spread
    on the paper's display
    (:func:`~jaxadapt.operators.jacobs2015.blur_for_display`), so the
    strong afterimage's maps reach a little beyond the disk during the
    flash, which the desaturation cue registers as slightly more colour.

    Parameters
    ----------
    protocol : design.Protocol
        With conditions ``("control", "manipulated")``.
    key : PRNG key
        Unused (the rendering is deterministic); accepted for a common
        signature with :func:`mesopic_displays`.
    width, height : int
        Frame size, pixels (the scene spans 10 degrees).
    fps : float
        Frame rate, frames per second: a display shows whole frames, so
        ``presentation_s`` and ``lead_s`` must each last a whole number of
        them (the flash at least one).
    lead_s : float
        Darkness before the flash, s.
    flash_luminance : float
        Luminance of the flash in the depicted scene, cd/m2.
    j1 : (float, float)
        Bleaching-afterimage strengths of the control and manipulated tests.

    Returns
    -------
    Displays
    """
    del key
    _check_conditions(protocol)
    r = afterimage_renders(
        protocol, width=width, height=height, fps=fps, lead_s=lead_s,
        flash_luminance=flash_luminance, j1=j1,
    )  # fmt: skip
    levels = jnp.asarray(protocol.levels, jnp.float32)
    shown = jnp.asarray(r.presented)
    scale = jnp.where(shown, 10.0 ** levels[:, None], 1.0)[..., None, None, None]  # (L, T, 1, 1, 1)
    standard = r.scale * r.weak
    test = jnp.stack([standard * scale, r.scale * r.strong * scale])
    return Displays(test, standard, shown, jnp.asarray(r.blank), protocol.ambient, r.times)


class AfterimageRenders(NamedTuple):
    """The flash scene of §4.1.1 rendered with the weak and the strong
    afterimage, before it is scaled to the display (:func:`afterimage_renders`).

    Attributes
    ----------
    weak, strong : array, (T, H, W, 3)
        Linear display values (the operator's decoded output).
    scale : float
        cd/m2 per unit of linear display value: the standard's flash
        measures ``protocol.standard``.
    presented, blank : numpy array of bool, (T,)
        Frames of the flash, and of the black screen after it.
    times : numpy array, (T,)
        Time of each frame, s.
    """

    weak: jax.Array
    strong: jax.Array
    scale: jax.Array
    presented: np.ndarray
    blank: np.ndarray
    times: np.ndarray


def afterimage_renders(
    protocol,
    *,
    width=32,
    height=32,
    fps=40.0,
    lead_s=0.25,
    flash_luminance=1e7,
    j1=(3e-4, 1e-3),
    stepped=False,
):
    """The flash scene rendered with the weak and strong afterimages, and the
    display scale of the standard (see :func:`afterimage_displays`, which
    takes the same arguments and composes the stimuli from these: a
    stimulus is ``scale`` times a render, its flash frames times
    ``10^level``). ``stepped``: one frame at a time (:func:`_stepped`),
    the renders numpy arrays."""
    presentation = _whole_frames("protocol.presentation_s", protocol.presentation_s, fps, 1)
    lead_s = _whole_frames("lead_s", lead_s, fps, 0)
    scene = scenes.flash(
        width,
        height,
        duration=lead_s + presentation + protocol.blank_s,
        fps=fps,
        luminance=flash_luminance,
        flash_duration=presentation,
        onset=lead_s,
    )
    times = scene.times
    half = 0.5 / fps
    presented = (times >= lead_s - half) & (times < lead_s + presentation - half)
    blank = times >= lead_s + presentation - half
    gaze = jnp.asarray(scene.gaze(times), jnp.float32)
    ppd = scene.pixels_per_degree
    params = jacobs2015.Params(
        acuity=False,
        dithering=False,
        pixels_per_degree=ppd,
        afterimage_blur=jacobs2015.blur_for_display(ppd, fps),
    )
    key = jax.random.key(0)
    if stepped:
        dt = np.broadcast_to(scene.dt, times.shape)
        weak, strong = (
            _stepped(dataclasses.replace(params, j1=float(strength)),
                     lambda i: scene.render(times[i : i + 1])[0], dt, gaze, key)
            for strength in j1
        )  # fmt: skip
    else:
        frames = jnp.asarray(scene.render(times), jnp.float32)

        def render(strength):
            version = dataclasses.replace(params, j1=strength)
            out, _ = jacobs2015.run(version, frames, scene.dt, gaze=gaze, key=key)
            return jacobs2015.decode(version, out)

        weak, strong = jax.vmap(render)(jnp.asarray(j1, jnp.float32))
    shown = jnp.asarray(presented)
    flash = jnp.sum(photopic_luminance(weak) * shown[:, None, None], axis=0) / np.sum(presented)
    scale = protocol.standard / jnp.max(flash)  # cd/m2 per unit of linear display value
    return AfterimageRenders(weak, strong, scale, presented, blank, times)


def mesopic_displays(protocol, *, key, width=96, height=64, fps=8.0):
    """The stimuli of the mesopic experiment (§4.2.1), rendered.

    The ColorChecker of :func:`jaxadapt.scenes.mesopic`, its white tile at
    the test's (or the standard's) luminance, shown for
    ``protocol.presentation_s`` (1.25 s). Every image goes through the 2015
    operator, so that the standard and the tests share its tone curve; the
    manipulated tests with the mesopic colour shift and the stochastic
    acuity loss on, the standard and the control tests with them off. The
    Purkinje shift is off in both, as in the paper; bleaching, local
    adaptation and dithering are off (a steady chart leaves no afterimage).
    The acuity noise uses the same ``key`` at every level (common random
    numbers: the features change smoothly with the level).

    The mesopic tests are "rendered with the color and acuity mesopic
    effects before intensity scaling": each rendered image is scaled on
    the display to the mean photopic luminance of the chart it depicts, so
    that the standard, control and manipulated tests at a level have the
    same mean luminance and differ only in colour and detail. The black
    screen after each image is not rendered (it shows nothing).

    Parameters
    ----------
    protocol : design.Protocol
        With conditions ``("control", "manipulated")``.
    key : PRNG key
        For the acuity noise.
    width, height : int
        Frame size, pixels (the chart spans 20 degrees).
    fps : float
        Frame rate, frames per second.

    Returns
    -------
    Displays
    """
    _check_conditions(protocol)
    whites = (*protocol.tests, protocol.standard)
    options = dict(key=key, width=width, height=height, fps=fps)
    control = mesopic_render(protocol, whites, effects=False, **options)
    manipulated = mesopic_render(protocol, whites[:-1], effects=True, **options)
    T = control.shape[1]
    return Displays(
        jnp.stack([control[:-1], manipulated]),
        control[-1],
        jnp.ones(T, bool),
        jnp.zeros(T, bool),
        protocol.ambient,
        np.arange(T) / fps,
    )


def mesopic_render(
    protocol,
    whites,
    *,
    effects,
    key,
    width=96,
    height=64,
    fps=8.0,
    paper_pixels=True,
    stepped=False,
):
    """Charts of :func:`jaxadapt.scenes.mesopic` at the white-tile luminances
    ``whites`` (cd/m2), rendered as :func:`mesopic_displays` renders them:
    with the mesopic colour shift and acuity loss (``effects``) or without,
    each scaled to the mean luminance of the chart it depicts.

    ``paper_pixels``: the chart stands in for the paper's display at a
    reduced size, so the acuity loss keeps the paper's pixel sizes
    (Appendix A), at which the blur the paper's observers saw is kept; with
    False the chart is drawn at its true angle (20 degrees over ``width``
    pixels) and the acuity loss follows those pixels.

    ``stepped``: one chart and one frame at a time (:func:`_stepped`), a
    numpy array.

    Returns
    -------
    array, (len(whites), T, H, W, 3)
        cd/m2 on the display, ``T`` frames of ``protocol.presentation_s``.
    """
    charts = [scenes.mesopic(width, height, protocol.presentation_s, fps, white=w) for w in whites]
    times = charts[0].times
    gaze = jnp.asarray(charts[0].gaze(times), jnp.float32)
    ppd = charts[0].pixels_per_degree
    sizes = {}
    if paper_pixels:
        paper = jacobs2015.PAPER_PIXELS_PER_DEGREE
        sizes = {
            "acuity_sigma0": jacobs2015.ACUITY_SIGMA0_DEG * paper,
            "acuity_noise_cell": jacobs2015.ACUITY_NOISE_CELL_DEG * paper,
        }
    on = ("mesopic_colour", "acuity") if effects else ()
    params = jacobs2015.only(*on, pixels_per_degree=ppd, **sizes)

    def scaled(lin, frames):  # shown at the mean luminance of the chart
        return lin * jnp.mean(photopic_luminance(frames)) / jnp.mean(photopic_luminance(lin))

    if stepped:
        dt, rendered = np.full(len(times), 1.0 / fps), []
        for chart in charts:
            first = chart.render(times[:1])  # (a steady chart: every frame is its first)
            lin = _stepped(params, lambda i, f=first: f[0], dt, gaze, key)
            rendered.append(np.asarray(scaled(lin, first)))
        return np.stack(rendered)

    def one(f):
        out, _ = jacobs2015.run(params, f, 1.0 / fps, gaze=gaze, key=key)
        return scaled(jacobs2015.decode(params, out), f)

    frames = jnp.stack([jnp.asarray(c.render(times), jnp.float32) for c in charts])
    return jax.vmap(one)(frames)


def _stepped(params, frame_at, dt, gaze, key):
    """Decoded display frames ``(T, H, W, 3)`` of ``frame_at(i)`` (the scene's
    frame ``i``, cd/m2) held ``dt[i]`` s with the gaze at ``gaze[i]``, one
    :func:`jaxadapt.operators.jacobs2015.step` at a time, kept on the host:
    the frames of :func:`jaxadapt.operators.jacobs2015.run` in the memory
    of one (a run of 25 frames of 1282x854 took 3 GB)."""
    frame = jnp.asarray(frame_at(0), jnp.float32)
    state = jacobs2015.init(params, frame, gaze=gaze[0], key=key)
    lin = np.empty((len(dt), *frame.shape), np.float32)
    for i in range(len(dt)):
        if i:
            frame = jnp.asarray(frame_at(i), jnp.float32)
        state, out = jacobs2015.step(params, state, frame, float(dt[i]), gaze=gaze[i])
        lin[i] = np.asarray(jacobs2015.decode(params, out))
    return lin


#: How each preset's stimuli are made, by protocol name.
DISPLAYS = {"afterimage": afterimage_displays, "mesopic": mesopic_displays}
