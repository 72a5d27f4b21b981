"""The time-dependent tone reproduction operator of Pattanaik et al. (2000).

A viewer looks at a scene whose luminance changes over time; a display
observer, adapted to an ordinary display, looks at our output. The operator
finds display values that evoke in the display observer the appearance the
scene evokes in the scene viewer (Fig. 1 and Fig. 4 of the paper)::

    frame (cd/m2) -> goal G -> kinetics -> A, B -> sigma, references, rule
                                                      |
    pixels: L_rod, L_cone -> R_lum, S_color -> display response -> display RGB

The adaptation state is four scalars (``A_rod``, ``A_cone``, ``B_rod``,
``B_cone``). :func:`run` therefore finds the goals of every frame at once
(one batched reduction), advances the state through the whole sequence by
the exact kinetics (on a GPU by their associative form, with no loop over
frames), and only then maps the pixels of every frame in one vectorised
pass; :func:`step` does the same one frame at a time.

Timing: frame ``k``, shown at ``t_k``, is seen with the state reached at
``t_k``; its goal is then held for its duration ``dt_k`` to give the state
at ``t_{k+1}``. This is the reading of §5 (title page): the frame just after
the lights come on is seen with the adaptation of the dark frame before it
("the lighting has changed, but the scene viewer's adaptation state has
not"), and is almost entirely white.

Luminance: frames may hold any finite value; a channel above
:data:`jaxadapt.background.LUMINANCE_CEILING` (1e10 cd/m2, where the cone
pigment is 99.98 % bleached) is seen, by the goals and by the pixel map
alike, at the ceiling (:func:`jaxadapt.operators.checks.saturate`): above
it Hunt's ``F_L`` of the goal and the responses' ratios overflow float32.

References
----------
Pattanaik, Tumblin, Yee, Greenberg (2000), *Time-Dependent Visual Adaptation
for Fast Realistic Image Display*, SIGGRAPH 2000, §4-§5.
"""

from jaxadapt.operators.pattanaik2000._adaptation import (
    advance,
    advance_sequence,
    frame_goals,
    relaxations,
    static_state,
)
from jaxadapt.operators.pattanaik2000._appearance import (
    curve,
    display,
    display_log_luminance,
    display_luminance,
    display_references,
    display_slope,
    display_value,
    inverse_appearance,
    inverse_display,
    luminance_response,
    observer,
    pixel_terms,
    references,
    tone_map,
    tone_map_planes,
)
from jaxadapt.operators.pattanaik2000._configure import configure, describe, plot_diagnostics
from jaxadapt.operators.pattanaik2000._operator import init, run, step, transition
from jaxadapt.operators.pattanaik2000._params import (
    CURVE_LOG10_LUMINANCE,
    POSITIVE_FIELDS,
    Diagnostics,
    Display,
    Observer,
    Params,
    State,
    diagnostics_table,
    log_adaptation,
)

# The API, in the order of the single module it was (parameters,
# appearance, adaptation, contract).
__all__ = [
    "CURVE_LOG10_LUMINANCE",
    "Params",
    "POSITIVE_FIELDS",
    "State",
    "Display",
    "Observer",
    "Diagnostics",
    "diagnostics_table",
    "log_adaptation",
    "luminance_response",
    "references",
    "display_references",
    "display_slope",
    "display",
    "display_log_luminance",
    "inverse_display",
    "display_luminance",
    "inverse_appearance",
    "observer",
    "tone_map",
    "tone_map_planes",
    "pixel_terms",
    "display_value",
    "curve",
    "frame_goals",
    "static_state",
    "relaxations",
    "advance",
    "advance_sequence",
    "init",
    "step",
    "run",
    "transition",
    "configure",
    "describe",
    "plot_diagnostics",
]
