"""Parameters, state and records of the operator: :class:`Params` with the
paper's constants as defaults, the fields the checks require positive, the
scene viewer's adaptation :class:`State` (``A`` and ``B`` of rods and cones,
§4.1-§4.2), the per-frame constants of the display observer
(:class:`Display`, §4.3) and of the scene viewer (:class:`Observer`), and
the per-frame :class:`Diagnostics` of :func:`run` with their columns
(:func:`diagnostics_table`), sampled at ``CURVE_LOG10_LUMINANCE``.

The bottom layer of the package: every other module reads these types, and
this one imports none of them.
"""

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt import background
from jaxadapt._checks import check_value, float_array
from jaxadapt.operators import goal as goals
from jaxadapt.operators.checks import check_fields

#: Scene luminances (log10 cd/m2) at which the scene-to-display curve of the
#: diagnostics is sampled: 1e-6 to 1e8 cd/m2, ten samples a decade.
CURVE_LOG10_LUMINANCE = jnp.linspace(-6.0, 8.0, 141)


class Params(eqx.Module):
    """Parameters of the operator; numeric fields are arrays, so a batch of
    parameter sets can be ``vmap``-ped.

    Attributes
    ----------
    n : float
        Response exponent of Eq 2 (0.73, Hunt).
    t0_rod, t0_cone : float
        Neural adaptation time constants, s (0.150, 0.080; §4.1.2).
    tau_rod, tau_cone : float
        Pigment regeneration time constants, s (400, 110; Eq 7).
    c_rod, c_cone : float
        Bleaching constants, cd/m2 s (16, 2.2e8; Eq 7).
    white_factor : float
        Reference white as a multiple of adaptation (5; Eq 8).
    black_ratio : float
        Reference white over reference black (32; Eq 8), above 1: at 1 the
        display's colour exponent ``S_d`` is 0/0, below it black is
        brighter than white.
    display_adaptation : float
        Adaptation of the display observer, cd/m2 (25; §4.3). The display's
        white is ``white_factor`` times this (125 cd/m2) and maps to 1.0.
    display_B_cone : float
        Cone bleaching factor of the display observer (1; §4.3).
    goal_fraction : float
        Fraction of white used by the ``"white_fraction"`` goal (1/5).
    white_percentile : float
        Percentile of luminance taken as white by ``"white_fraction"``.
    pixels_per_degree : float
        Resolution at the eye, used by the ``"foveal"`` goal.
    goal : str
        Adaptation-goal finder: ``"log_average"``, ``"white_fraction"`` or
        ``"foveal"`` (see :mod:`jaxadapt.operators.goal`). Static.
    background : str
        ``"global"`` (the default): one goal per frame from ``goal``, the
        paper's operator. Any other name of
        :data:`jaxadapt.background.BACKGROUNDS` (``"gaussian"``,
        ``"bilateral"``, ``"adaptive"``, ...): a goal per pixel, the local
        background luminance, and a state per pixel advanced with the same
        exact kinetics, so that local adaptation stays time-dependent (unlike
        pfstmo's ``--local``, which drops time dependence). Static.
    background_scale : float
        Size of the local background estimator, pixels (its ``scale``). Static.
    """

    n: jax.Array = eqx.field(default=0.73, converter=float_array)
    t0_rod: jax.Array = eqx.field(default=0.150, converter=float_array)
    t0_cone: jax.Array = eqx.field(default=0.080, converter=float_array)
    tau_rod: jax.Array = eqx.field(default=400.0, converter=float_array)
    tau_cone: jax.Array = eqx.field(default=110.0, converter=float_array)
    c_rod: jax.Array = eqx.field(default=16.0, converter=float_array)
    c_cone: jax.Array = eqx.field(default=2.2e8, converter=float_array)
    white_factor: jax.Array = eqx.field(default=5.0, converter=float_array)
    black_ratio: jax.Array = eqx.field(default=32.0, converter=float_array)
    display_adaptation: jax.Array = eqx.field(default=25.0, converter=float_array)
    display_B_cone: jax.Array = eqx.field(default=1.0, converter=float_array)
    goal_fraction: jax.Array = eqx.field(default=0.2, converter=float_array)
    white_percentile: jax.Array = eqx.field(default=99.0, converter=float_array)
    pixels_per_degree: jax.Array = eqx.field(default=30.0, converter=float_array)
    goal: str = eqx.field(default="log_average", static=True)
    background: str = eqx.field(default="global", static=True)
    background_scale: float = eqx.field(default=8.0, static=True)

    def __check_init__(self):
        if self.goal not in goals.GOALS:
            raise ValueError(f"goal: expected one of {goals.GOALS}, got {self.goal!r}")
        background.check_background(self.background, self.background_scale)
        check_fields(self, positive=POSITIVE_FIELDS)
        check_value("black_ratio", self.black_ratio, lambda v: v > 1, "a number above 1")
        for name in ("display_B_cone", "goal_fraction"):
            check_value(name, getattr(self, name), lambda v: (v > 0) & (v <= 1), "in (0, 1]")
        check_value(
            "white_percentile", self.white_percentile, lambda v: (v > 0) & (v <= 100), "in (0, 100]"
        )


#: The fields of :class:`Params` that must be positive and finite (time and
#: bleaching constants, exponent, reference factors, display adaptation,
#: resolution): a negative ``t0`` would drive the adaptation state below
#: zero and a NaN one make it NaN, both silently.
POSITIVE_FIELDS = (
    "n",
    "t0_rod",
    "t0_cone",
    "tau_rod",
    "tau_cone",
    "c_rod",
    "c_cone",
    "white_factor",
    "black_ratio",
    "display_adaptation",
    "pixels_per_degree",
)


class State(NamedTuple):
    """Adaptation state of the scene viewer.

    Attributes
    ----------
    A_rod, A_cone : array
        Neural adaptation luminance, cd/m2.
    B_rod, B_cone : array
        Unbleached pigment fraction, in [0, 1].
    """

    A_rod: jax.Array
    A_cone: jax.Array
    B_rod: jax.Array
    B_cone: jax.Array


class Display(NamedTuple):
    """The display observer's constants (§4.3) that the pixel map uses:
    sigma and B of both receptors adapted to ``display_adaptation``, its
    response to display white ``REF_wht``, its colour exponent ``S_d`` and
    the natural log of display white, ``ln(white_factor A_d)`` (cd/m2)."""

    sigma_rod: jax.Array
    sigma_cone: jax.Array
    B_rod: jax.Array
    B_cone: jax.Array
    white: jax.Array
    slope: jax.Array
    log_white: jax.Array


class Observer(NamedTuple):
    """Everything the pixel map needs from one frame's adaptation: sigma and B
    of both receptors, the affine map of the inverse appearance model
    (display response = ``scale * R_lum + offset``) and the display
    observer's constants. Scalars computed once per frame, so that the
    pixel map does not repeat them per pixel."""

    sigma_rod: jax.Array
    sigma_cone: jax.Array
    B_rod: jax.Array
    B_cone: jax.Array
    scale: jax.Array
    offset: jax.Array
    rule: jax.Array
    display: Display


class Diagnostics(NamedTuple):
    """Per-frame record of a :func:`run` (leading axis: frames).

    With a local background, every per-frame value is the one at the gaze
    point (the pixel nearest it): what the fovea is adapted to.

    Attributes
    ----------
    t : array, (T,)
        Time of each frame, s, from 0.
    G_rod, G_cone : array, (T,)
        Adaptation goals, cd/m2.
    state : State
        State each frame was seen with, fields of shape (T,).
    sigma_rod, sigma_cone : array, (T,)
        Semi-saturation luminances, cd/m2.
    rule : array, (T,)
        Rule of §4.3 (1-4) that mapped the frame.
    curve : array, (T, 141)
        Display value (linear, [0, 1]) of a neutral scene luminance
        ``10**CURVE_LOG10_LUMINANCE`` cd/m2: the graphs under Fig. 7.
    final_state : State
        State after the last frame's ``dt``, to continue a sequence (maps
        ``(H, W)`` with a local background).
    """

    t: jax.Array
    G_rod: jax.Array
    G_cone: jax.Array
    state: State
    sigma_rod: jax.Array
    sigma_cone: jax.Array
    rule: jax.Array
    curve: jax.Array
    final_state: State


def diagnostics_table(diag):
    """Per-frame columns of a :class:`Diagnostics`, as numpy arrays.

    Scalars per frame (``t``, ``G_rod``, ``G_cone``, ``A_rod``, ``A_cone``,
    ``B_rod``, ``B_cone``, ``sigma_rod``, ``sigma_cone``, ``rule``) and the
    sampled scene-to-display ``curve`` ``(T, 141)``.
    """
    s = diag.state
    columns = {
        "t": diag.t,
        "G_rod": diag.G_rod,
        "G_cone": diag.G_cone,
        "A_rod": s.A_rod,
        "A_cone": s.A_cone,
        "B_rod": s.B_rod,
        "B_cone": s.B_cone,
        "sigma_rod": diag.sigma_rod,
        "sigma_cone": diag.sigma_cone,
        "rule": diag.rule,
        "curve": diag.curve,
    }
    return {name: np.asarray(column) for name, column in columns.items()}


def log_adaptation(table):
    """Each frame's adaptation, log10 cd/m2: the mean of the rods' and the
    cones' log adaptation luminance (``A_rod``, ``A_cone`` of
    :func:`diagnostics_table`), so that the slow dark adaptation of the rods
    counts as the cones' does."""
    with np.errstate(divide="ignore"):
        return (np.log10(table["A_rod"]) + np.log10(table["A_cone"])) / 2
