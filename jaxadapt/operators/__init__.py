"""Tone-reproduction operators, one module per published model, and the
contract they share.

- :mod:`~jaxadapt.operators.pattanaik2000`: time-dependent adaptation
  (Pattanaik, Tumblin, Yee and Greenberg 2000);
- :mod:`~jaxadapt.operators.jacobs2015`: gaze-driven adaptation with
  afterimages, Purkinje shift, mesopic colour and acuity loss (Jacobs,
  Gallo, Cooper, Pulli and Levoy 2015);
- :mod:`~jaxadapt.operators.classic`: the static tone curves of the
  HDR-imaging chapter (Reinhard et al.), one :data:`TONE_CURVES` entry each;
- :mod:`~jaxadapt.operators.goal`: adaptation goals and background
  estimators the operators share.

Every operator module keeps the :class:`Operator` contract, so that the
pipeline, the command line, the experiments and the benchmarks treat them
alike. :data:`OPERATORS` maps the operators' names to their modules,
importing a module only when it is asked for.
"""

import dataclasses
import importlib
from collections.abc import Iterator, Mapping
from types import ModuleType
from typing import Any, Protocol, runtime_checkable

__all__ = ["BACKGROUND_SCALE", "OPERATORS", "TONE_CURVE_NAMES", "Operator", "Settings", "Supports"]

#: Names of the static tone curves of :mod:`~jaxadapt.operators.classic`
#: (its ``TONE_CURVES``), each an operator of its own for the command line.
TONE_CURVE_NAMES = ("schlick1994", "tumblin1999", "reinhard-devlin", "photographic", "ward-jnd")


@runtime_checkable
class Operator(Protocol):
    """What an operator module provides (a module satisfies this protocol).

    ``Params`` is an ``equinox.Module`` of the parameters: numeric fields
    are arrays, so that a batch of parameter sets can be ``vmap``-ped;
    configuration that changes shapes is static. ``Diagnostics`` is the
    per-frame record of :meth:`run`, a ``NamedTuple`` with at least ``t``
    (s, from 0) and ``final_state``. Frames are ``(..., H, W, 3)`` linear
    BT.709 RGB in cd/m2; ``dt`` in s; ``gaze`` ``(x, y)`` in pixels; ``key``
    a JAX PRNG key for operators that draw noise. What an operator
    supports beyond this is data in the registry (:class:`Supports`).
    """

    Params: type
    Diagnostics: type

    def init(self, params, first_frame, *, gaze=None, key=None, adaptation=None) -> Any:
        """The state before the first frame: adapted to ``first_frame``, or
        to ``adaptation`` (cd/m2) where given."""

    def step(self, params, state, frame, dt, *, gaze=None, key=None) -> tuple[Any, Any]:
        """``(state, display frame)`` after one frame held for ``dt``."""

    def run(self, params, frames, dt, *, gaze=None, key=None, state=None) -> tuple[Any, Any]:
        """``(display frames, Diagnostics)`` of a sequence ``(T, H, W, 3)``."""

    def diagnostics_table(self, diag) -> dict:
        """Per-frame columns of a ``Diagnostics``, NumPy arrays by name."""

    def log_adaptation(self, table) -> Any:
        """Each frame's adaptation luminance (log10 cd/m2) from the columns
        of :meth:`diagnostics_table`: what a contact sheet follows."""

    def configure(self, settings) -> Any:
        """The ``Params`` that a render's :class:`Settings` ask for; a
        ``ValueError`` naming the setting (``gaze: ...``) for one given
        that this operator would ignore."""

    def describe(self, settings) -> str:
        """What :meth:`configure` makes of ``settings``, a few words for a
        title (``Pattanaik et al. 2000, goal foveal``)."""

    def plot_diagnostics(self, path, table, params, title) -> Any:
        """Draw the columns of :meth:`diagnostics_table` over time to
        ``path`` (a PNG), titled ``title``; returns the figure."""


#: Size of a local background estimator unless a render says otherwise, pixels.
BACKGROUND_SCALE = 8.0


@dataclasses.dataclass(frozen=True)
class Settings:
    """A render's choices, the same for every operator: each operator's
    ``configure`` makes its ``Params`` of those it reads, so that whatever
    drives an operator (the command line, the viewer, a study) says what it
    wants once and never by the operator's name.

    Attributes
    ----------
    name : str
        The operator's name in :data:`OPERATORS` (a tone curve's, for
        :mod:`~jaxadapt.operators.classic`).
    fps : float
        The frames' nominal rate, frames/s.
    pixels_per_degree : float
        Resolution of the frames at the viewer's eye.
    goal : str
        Adaptation goal (:mod:`~jaxadapt.operators.goal`), for an operator
        that takes one.
    background, background_scale : str, float
        Background estimator (:mod:`jaxadapt.background`) and its size,
        pixels.
    effects : tuple of str or None
        The effects (:attr:`Supports.effects`) switched on; None for all.
    given : frozenset of str
        The settings a user chose rather than took by default, by the
        names above plus ``gaze`` (a gaze path was given): those an operator
        refuses where it would ignore them.
    """

    name: str
    fps: float = 30.0
    pixels_per_degree: float = 30.0
    goal: str = "foveal"
    background: str = "global"
    background_scale: float = BACKGROUND_SCALE
    effects: tuple | None = None
    given: frozenset = frozenset()


@dataclasses.dataclass(frozen=True)
class Supports:
    """What an operator supports, as data: the command line, the viewer and
    whatever drives an operator read it here rather than test its name.

    Attributes
    ----------
    time_dependent : bool
        It adapts over time: a state carried from frame to frame (False for
        a static tone curve).
    gaze : bool
        It reads a gaze point per frame (``--gaze``, the viewer's pointer).
    adaptation_goal : bool
        It takes an adaptation goal (``--adaptation-goal``).
    local_background : bool
        It takes a background estimator other than the global one
        (``--background``).
    display_encoded : bool
        Its frames come display-encoded by its own transfer (a gamma 2.2
        encoding), so a display encoding (``--encoding``) does not apply.
    seed : bool
        It draws noise from a PRNG key (``--seed``).
    effects : tuple of str
        Parts that can be switched on and off (the viewer's toggles).
    live : bool
        It can be stepped frame by frame at the wall clock's ``dt`` with a
        gaze (``jaxadapt view``).
    composable : bool
        Its state update is affine in the state for a fixed input frame, so
        a sequence can be split in time and the pieces joined exactly: a
        time-dependent one has ``transition(params, frames, dt, *, gaze)``,
        the map ``state -> a * state + b`` of a stretch of frames, ``(a, b)``.
    why_not : dict
        For an option it does not take, why, where its name is not enough
        (the option's name without dashes to the reason, a clause).
    """

    time_dependent: bool = True
    gaze: bool = False
    adaptation_goal: bool = False
    local_background: bool = True
    display_encoded: bool = False
    seed: bool = False
    effects: tuple = ()
    live: bool = False
    composable: bool = True
    why_not: dict = dataclasses.field(default_factory=dict)

    @property
    def encoding(self) -> bool:
        """A display encoding (``--encoding``) applies to its frames: they
        are not display-encoded already."""
        return not self.display_encoded


class _Registry(Mapping):
    """Names to operator modules, each imported when first asked for, and
    what each supports (:meth:`supports`), known without importing it."""

    def __init__(self, entries):
        self._entries = dict(entries)

    def __getitem__(self, name) -> ModuleType:
        return importlib.import_module(f"{__name__}.{self._entries[name][0]}")

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self):
        return f"OPERATORS({', '.join(self._entries)})"

    def supports(self, name) -> Supports:
        """What the operator ``name`` supports."""
        return self._entries[name][1]

    def having(self, capability) -> list:
        """The names of the operators that support ``capability`` (a field
        or property of :class:`Supports`: true, or not empty), in the
        registry's order."""
        return [n for n, (_, s) in self._entries.items() if getattr(s, capability)]


#: The operators by name: the two time-dependent models and each tone curve
#: (whose module is :mod:`~jaxadapt.operators.classic`), with what each supports.
OPERATORS = _Registry(
    {
        # Time-dependent adaptation (Pattanaik et al. 2000): its four state
        # scalars advance by exact steps x' = a x + b, affine for a held frame.
        "pattanaik2000": (
            "pattanaik2000",
            Supports(gaze=True, adaptation_goal=True, live=True),
        ),
        # Gaze-driven adaptation with afterimages (Jacobs et al. 2015): its
        # adaptation level moves at a rate that depends on the sign of its
        # distance to the target (Eq 3), not affine in the state.
        "jacobs2015": (
            "jacobs2015",
            Supports(
                gaze=True,
                local_background=False,
                display_encoded=True,
                seed=True,
                effects=(
                    "bleaching",
                    "local_adaptation",
                    "purkinje",
                    "mesopic_colour",
                    "acuity",
                    "dithering",
                ),
                live=True,
                composable=False,
                why_not={
                    "background": "which adapts to the foveal luminance and finds local "
                    "luminance itself",
                    "encoding": "whose display values are its own gamma encoding",
                },
            ),
        ),
        # The static tone curves: no state, each frame mapped on its own.
        **dict.fromkeys(TONE_CURVE_NAMES, ("classic", Supports(time_dependent=False))),
    }
)
