"""What the renderer carries from frame to frame and what it records.

:class:`State` holds the log adaptation level ``A`` (Eq 3) and the
retina-locked maps of bleaching ``B`` (Eqs 4-6) and calcium ``C`` (Eqs
8-10) with the fixation they are aligned to; :class:`Diagnostics` is the
per-frame record of ``run``, which :func:`diagnostics_table` turns into
columns (units in :data:`DIAGNOSTIC_UNITS`, caveats from
:func:`diagnostics_notes`, such as the adaptation floor of §2.4).
"""

from typing import NamedTuple

import jax
import numpy as np


class State(NamedTuple):
    """State of the viewer.

    Attributes
    ----------
    A : array, ()
        Adaptation level, log10 cd/m2 (Eq 3).
    B : array, (3, H, W)
        Bleached fraction of L, M, S pigment, in [0, 1], aligned with
        ``gaze``: one plane per cone, the layout the renderer works in.
    C : array, (3, H, W)
        Calcium concentration of L, M, S cones, in ``[0, c1/c2]``.
    gaze : array, (2,)
        Fixation ``(x, y)``, pixels, inside the frame; the maps are aligned
        with its rounded value.
    t : array, ()
        Time since the first frame, s.
    frame : array, () int
        Index of the next frame.
    key : PRNG key
        Key of the sequence (acuity noise and dithering).
    """

    A: jax.Array
    B: jax.Array
    C: jax.Array
    gaze: jax.Array
    t: jax.Array
    frame: jax.Array
    key: jax.Array


class Diagnostics(NamedTuple):
    """Per-frame record of a :func:`run` (leading axis: frames).

    Attributes
    ----------
    t : array, (T,)
        Time of each frame, s.
    A : array, (T,)
        Adaptation level the frame was seen with, log10 cd/m2.
    A_T : array, (T,)
        Adaptation target of the frame, log10 cd/m2 (floored).
    sigma : array, (T,)
        Semi-saturation luminance of Eq 2, cd/m2.
    gaze : array, (T, 2)
        Fixation used, pixels (clipped, blinks filled).
    B_gaze, C_gaze : array, (T, 3)
        L, M, S bleaching and calcium at the fixation.
    rho_gaze : array, (T,)
        Normalised local log luminance (Eq 13, unclamped) at the fixation.
    final_state : State
        State after the last frame, to continue a sequence.
    """

    t: jax.Array
    A: jax.Array
    A_T: jax.Array
    sigma: jax.Array
    gaze: jax.Array
    B_gaze: jax.Array
    C_gaze: jax.Array
    rho_gaze: jax.Array
    final_state: State


#: Units of the columns of :func:`diagnostics_table` (``t`` is in s).
DIAGNOSTIC_UNITS = {
    "A": "log10 cd/m2",
    "A_T": "log10 cd/m2",
    "sigma": "cd/m2",
    "gaze_x": "pixels",
    "gaze_y": "pixels",
    **{f"B_{cone}": "bleached fraction" for cone in "LMS"},
    **{f"C_{cone}": "calcium (relative)" for cone in "LMS"},
    "rho": "Eq 13, unclamped",
}


def diagnostics_notes(params):
    """What a reader of the diagnostics needs to know of ``params`` (lines
    for a plot): ``A`` and ``A_T`` never fall below the adaptation floor of
    §2.4, and ``rho`` is Eq 13 before its clamp to [0, 1]."""
    floor = float(params.adaptation_floor)
    return (
        f"A and A_T are floored at {floor:g} cd/m2 (log10 {np.log10(floor):g}; §2.4): "
        "a darker fixation shows the floor",
        "rho is Eq 13 unclamped (below 0 scotopic, above 1 photopic); the Purkinje shift "
        "and the mesopic colour use it clamped to [0, 1]",
    )


def diagnostics_table(diag):
    """Per-frame columns of a :class:`Diagnostics`, as numpy arrays.

    ``t``; ``A`` and ``A_T`` (log10 cd/m2); ``sigma`` (cd/m2); the fixation
    ``gaze_x``, ``gaze_y`` (pixels); L, M, S bleaching ``B_L`` ... and
    calcium ``C_L`` ... at the fixation; and ``rho`` there (Eq 13,
    unclamped: :func:`diagnostics_notes`). Units: :data:`DIAGNOSTIC_UNITS`.
    """
    columns = {"t": diag.t, "A": diag.A, "A_T": diag.A_T, "sigma": diag.sigma}
    columns |= {"gaze_x": diag.gaze[:, 0], "gaze_y": diag.gaze[:, 1]}
    for i, cone in enumerate("LMS"):
        columns[f"B_{cone}"] = diag.B_gaze[:, i]
    for i, cone in enumerate("LMS"):
        columns[f"C_{cone}"] = diag.C_gaze[:, i]
    columns["rho"] = diag.rho_gaze
    return {name: np.asarray(column) for name, column in columns.items()}


def log_adaptation(table):
    """Each frame's adaptation, log10 cd/m2: the column ``A`` (Eq 3) of
    :func:`diagnostics_table`."""
    return np.asarray(table["A"])
