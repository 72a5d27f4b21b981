"""The laws of the visual system, as pure functions on arrays of any shape:
no images, no time loops.

- :mod:`~jaxadapt.physiology.response`: Naka-Rushton responses and their
  inverses, Hunt's semi-saturation and static bleaching (Pattanaik et al.
  2000, Eqs 1-5);
- :mod:`~jaxadapt.physiology.kinetics`: every adaptation ODE of the papers,
  each with its right-hand side, its exact step for an input held over a
  step, and :func:`~jaxadapt.physiology.kinetics.integrate` with diffrax;
- :mod:`~jaxadapt.physiology.threshold`: threshold-versus-intensity curves
  and the threshold a response curve implies (Reinhard et al., the HDR
  imaging chapter on the human visual system);
- :mod:`~jaxadapt.physiology.pupil`: pupil diameter and retinal illuminance.

Luminance in cd/m2, time in s, log units are log10.
"""

from jaxadapt.physiology import kinetics, pupil, response, threshold
from jaxadapt.physiology.kinetics import (
    LOG_ADAPTATION_BAND,
    SMALL_STATE,
    Relaxation,
    affine_step,
    bleaching,
    bleaching_rhs,
    bleaching_step,
    calcium,
    calcium_rhs,
    calcium_step,
    cone_bleaching,
    cone_bleaching_rhs,
    cone_bleaching_step,
    goal_path,
    integrate,
    log_adaptation_rhs,
    log_adaptation_step,
    neural,
    neural_rhs,
    neural_step,
    relaxation_rhs,
    relaxation_sequence,
    relaxation_sequences,
    relaxation_step,
)
from jaxadapt.physiology.pupil import (
    DE_GROOT_GEBHARD_DARK,
    DIAMETERS,
    area,
    diameter_de_groot_gebhard,
    diameter_moon_spencer,
)
from jaxadapt.physiology.response import (
    N_HUNT,
    bleach_cone,
    bleach_rod,
    forward_difference_slope,
    hunt_F_L,
    hunt_F_LS,
    log_naka_rushton_sum_inverse,
    naka_rushton,
    naka_rushton_inverse,
    naka_rushton_sum_inverse,
    power,
    response_slope,
    sigma_cone,
    sigma_rod,
)
from jaxadapt.physiology.threshold import (
    TVI_MODELS,
    increment_sensitivity,
    increment_threshold,
    relative_threshold,
    relative_threshold_small_delta,
    trolands,
    tvi_blackwell,
    tvi_cone,
    tvi_luminance,
    tvi_rod,
    tvi_rod_cone,
)

__all__ = [
    "DE_GROOT_GEBHARD_DARK",
    "DIAMETERS",
    "LOG_ADAPTATION_BAND",
    "N_HUNT",
    "Relaxation",
    "SMALL_STATE",
    "TVI_MODELS",
    "affine_step",
    "area",
    "bleach_cone",
    "bleach_rod",
    "bleaching",
    "bleaching_rhs",
    "bleaching_step",
    "calcium",
    "calcium_rhs",
    "calcium_step",
    "cone_bleaching",
    "cone_bleaching_rhs",
    "cone_bleaching_step",
    "diameter_de_groot_gebhard",
    "diameter_moon_spencer",
    "forward_difference_slope",
    "goal_path",
    "hunt_F_L",
    "hunt_F_LS",
    "increment_sensitivity",
    "increment_threshold",
    "integrate",
    "kinetics",
    "log_adaptation_rhs",
    "log_adaptation_step",
    "log_naka_rushton_sum_inverse",
    "naka_rushton",
    "naka_rushton_inverse",
    "naka_rushton_sum_inverse",
    "neural",
    "neural_rhs",
    "neural_step",
    "power",
    "pupil",
    "relative_threshold",
    "relative_threshold_small_delta",
    "relaxation_rhs",
    "relaxation_sequence",
    "relaxation_sequences",
    "relaxation_step",
    "response",
    "response_slope",
    "sigma_cone",
    "sigma_rod",
    "threshold",
    "trolands",
    "tvi_blackwell",
    "tvi_cone",
    "tvi_luminance",
    "tvi_rod",
    "tvi_rod_cone",
]
