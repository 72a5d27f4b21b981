"""The gaze-aware renderer of very bright and very dark scenes of Jacobs et al. (2015).

A viewer looks around a calibrated HDR scene; a gaze path says where. Each
frame is rendered for an ordinary display with the epiphenomena of extreme
light levels::

    frame (cd/m2) --+-- local rho (Eq 13) --> acuity loss (Eqs 14-15) --> scene
                    |                                                       |
                    |     A (Eq 3) -> sigma (Eq 2) -> R (Eq 1), Purkinje,   |
                    |                                 mesopic colour  <-----+
                    |                                       |
                    +-- LMS -> B, C maps (Eqs 4-10) -> alpha^j2 R + j1 C/C_max (B - B_inf)
                                                            |
                                    J = clip(.)^gamma, temporal dithering (§2.4)

State: the log adaptation level ``A`` (a scalar, Eq 3) and, per pixel and
per cone (L, M, S), the bleached fraction ``B`` (Eqs 4-6) and the calcium
concentration ``C`` (Eqs 8-10). The maps are locked to the retina: they
are stored aligned with the current fixation and shifted with every gaze
movement (by whole pixels, between rounded gaze points, so that slow pursuit
does not drift), blurred between frames, and their visibility falls off as a
Gaussian around the fovea (§2.4). The per-pixel state advances by the exact
steps of :mod:`jaxadapt.physiology.kinetics` in a ``lax.scan`` over frames.

Timing: as in :mod:`jaxadapt.operators.pattanaik2000`, frame ``k`` is seen
with the state reached at its start; its input is then held for ``dt_k`` to
give the next state.

Choices where the paper is silent or garbled (each a :class:`Params` field
and tested in ``tests/test_jacobs2015.py``):

* **Plateau M** (Eq 2). The paper says only that M "has a form similar to
  Eq. (1)". We use ``M(I) = plateau_max I^q / (I^q + plateau_sigma^q)``
  (0.8, 1e4 cd/m2, q = 0.25): the adapted luminance is shown at 19 % of
  the display's linear range at 100 cd/m2 (the adaptation floor of §2.4,
  below which A does not go), 40 % at 1e4 cd/m2 and 68 % at 1e7 cd/m2, so
  brighter scenes look brighter, and M < 1 keeps sigma finite.
* **Adaptation target**: "the log of the average scene luminance in a
  small patch around the user's gaze" (§2.1), read as written: log10 of the
  foveally weighted mean of photopic luminance
  (:func:`jaxadapt.operators.goal.foveal_average`, a 1-degree patch), not
  the mean of its logs, floored at ``adaptation_floor`` (100 cd/m2, §2.4).
  A small bright source at the gaze then darkens the scene, as Fig. 2
  describes: a 1e6 cd/m2 lamp 12 pixels wide on a 20 cd/m2 field, fixated
  at 64 pixels per degree, gives 10^4.6 cd/m2 where the log average (31
  cd/m2) stayed at the floor.
* **rho** (Eq 13) is computed per pixel from the *local* photopic luminance,
  the scene blurred at the coarsest acuity scale ``sigma_7``: the paper ties
  acuity to "the local luminance level", and since the adaptation level
  never falls below the floor of §2.4, a rho from it would never be mesopic.
  Purkinje shift and mesopic colour use rho clamped to [0, 1].
* **Acuity thresholds**: Appendix A gives ``rho_i = 0.286 i`` "in
  log-luminance": 0 to 2 log units, the width ``m1 - m2`` of the mesopic
  range, so they are compared with the normalised rho after division by
  ``m1 - m2``. As printed, band ``i`` (``sigma_i`` growing with ``i``) would
  need the most light for the *coarsest* detail; the finest detail is lost
  first in the dark (Riggs 1965, the paper's Fig. 11 insets), so the band of
  fineness ``f`` (0 = finest) gets threshold ``rho_(7-f)``. rho is *not*
  clamped for acuity: clamped to 1, photopic scenes would keep flickering.
* **Total darkness**: Eq 11 is ``alpha = (C_max - C_inf) / (C_max - C)``,
  0/0 once calcium reaches ``C_max``. We use
  ``alpha = (C_max - C_inf + e) / (C_max - C + e)`` with
  ``e = calcium_epsilon C_max``: 1 (no gain) in the 0/0 limit, and bounded
  by about ``1/calcium_epsilon`` when light returns after long darkness (the
  brief boost of Fig. 1, frame 4). It departs from Eq 11 where the
  responses ``C_max - C`` and ``C_max - C_inf`` approach ``e``: at the
  adaptation floor (sigma = 778 cd/m2) within 2 % of Eq 11's gain
  ``alpha^j2`` from 10 cd/m2 up, and in mesopic light less: 1.35 against
  1.62 for a pixel adapted to 0.01 cd/m2 and shown 1 cd/m2, 0.74 against
  0.62 the other way. ``calcium_epsilon`` must be positive: at 0, after
  long darkness C rounds to C_max and ``alpha`` is infinite (the frame went
  black, its gradients NaN).
* **Colour**: cone excitations are Hunt-Pointer-Estevez LMS of the BT.709
  pixels, scaled so that white excites the three cones equally (Fig. 4:
  "white (stimulating all cone types equally)"). The local-adaptation gain
  multiplies the tone-mapped image in this LMS space; the bleaching term
  goes to RGB through the matrix ``H`` of Appendix A.
* **Acuity loss** changes only what is displayed; the photoreceptor state
  (``B``, ``C``) and the adaptation target are driven by the frame itself.
* **Gaze**: points outside the frame are clipped to its edge (an eye
  tracker reports the viewer looking just off screen; the nearest pixel is
  the best estimate of the fixation on it); samples that are not finite
  (NaN) are blinks and hold the last fixation.
* **Luminance ceiling**: a channel brighter than
  :data:`jaxadapt.background.LUMINANCE_CEILING` (1e10 cd/m2) is seen at
  that level (:func:`jaxadapt.operators.checks.saturate`), and so is an
  ``init`` adaptation above it: the responses, bleaching and
  adaptation level have saturated there, and above it the foveal mean of
  frames near float32's largest value overflowed.

References
----------
Jacobs, Gallo, Cooper, Pulli, Levoy (2015), *Simulating the Visual
Experience of Very Bright and Very Dark Scenes*, ACM TOG 34(3), §2, §2.4 and
Appendix A.
"""

from jaxadapt.operators.jacobs2015._acuity import (
    acuity_loss,
    acuity_noise,
    acuity_sigmas,
    acuity_thresholds,
    local_rho,
    normalised_log_luminance,
)
from jaxadapt.operators.jacobs2015._afterimage import (
    PAPER_FPS,
    Receptors,
    afterimages,
    blur_for_display,
    blur_maps,
    falloff,
    local_gain,
    receptors,
    retinal_shift,
)
from jaxadapt.operators.jacobs2015._configure import configure, describe, plot_diagnostics
from jaxadapt.operators.jacobs2015._operator import init, run, step
from jaxadapt.operators.jacobs2015._params import (
    ACUITY_NOISE_CELL_DEG,
    ACUITY_SIGMA0_DEG,
    CHANNEL_FIELDS,
    EFFECTS,
    H_AFTERIMAGE,
    NON_NEGATIVE_FIELDS,
    PAPER_PIXELS_PER_DEGREE,
    POSITIVE_FIELDS,
    SCOTOPIC_COLOUR,
    Params,
    only,
)
from jaxadapt.operators.jacobs2015._state import (
    DIAGNOSTIC_UNITS,
    Diagnostics,
    State,
    diagnostics_notes,
    diagnostics_table,
    log_adaptation,
)
from jaxadapt.operators.jacobs2015._tone import (
    adaptation_target,
    decode,
    encode,
    plateau,
    semi_saturation,
    tone_map,
)

__all__ = [
    "H_AFTERIMAGE",
    "SCOTOPIC_COLOUR",
    "PAPER_PIXELS_PER_DEGREE",
    "ACUITY_SIGMA0_DEG",
    "ACUITY_NOISE_CELL_DEG",
    "Params",
    "CHANNEL_FIELDS",
    "POSITIVE_FIELDS",
    "NON_NEGATIVE_FIELDS",
    "EFFECTS",
    "only",
    "State",
    "Diagnostics",
    "plateau",
    "semi_saturation",
    "adaptation_target",
    "acuity_sigmas",
    "normalised_log_luminance",
    "local_rho",
    "acuity_noise",
    "acuity_thresholds",
    "acuity_loss",
    "tone_map",
    "Receptors",
    "receptors",
    "falloff",
    "local_gain",
    "afterimages",
    "retinal_shift",
    "blur_maps",
    "PAPER_FPS",
    "blur_for_display",
    "encode",
    "decode",
    "init",
    "DIAGNOSTIC_UNITS",
    "diagnostics_notes",
    "diagnostics_table",
    "log_adaptation",
    "step",
    "run",
    "configure",
    "describe",
    "plot_diagnostics",
]
