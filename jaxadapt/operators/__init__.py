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

import importlib
from collections.abc import Iterator, Mapping
from types import ModuleType
from typing import Any, Protocol, runtime_checkable

__all__ = ["OPERATORS", "TONE_CURVE_NAMES", "Operator"]

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
    a JAX PRNG key for operators that draw noise.
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


class _Registry(Mapping):
    """Names to operator modules, each imported when first asked for."""

    def __init__(self, modules):
        self._modules = dict(modules)

    def __getitem__(self, name) -> ModuleType:
        return importlib.import_module(f"{__name__}.{self._modules[name]}")

    def __iter__(self) -> Iterator[str]:
        return iter(self._modules)

    def __len__(self) -> int:
        return len(self._modules)

    def __repr__(self):
        return f"OPERATORS({', '.join(self._modules)})"


#: The operators by name: the two time-dependent models and each tone curve
#: (whose module is :mod:`~jaxadapt.operators.classic`).
OPERATORS = _Registry(
    {
        "pattanaik2000": "pattanaik2000",
        "jacobs2015": "jacobs2015",
        **dict.fromkeys(TONE_CURVE_NAMES, "classic"),
    }
)
