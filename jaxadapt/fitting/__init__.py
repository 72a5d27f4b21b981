"""Fit any subset of a model's parameters to data, by gradient, through the simulator.

One entry point, :func:`fit`. The user writes the forward model as a function
``model(params, args) -> prediction`` of a parameter module (an operator's or
an observer's ``Params``, any ``equinox.Module`` whose numeric fields are
arrays) and names the fields to fit; the other fields stay as they are in the
``params`` given, whose values of the named fields are also the start. The
fit differentiates through whatever ``model`` calls: ``pattanaik2000.run``
(the exact kernels), the diffrax path of :mod:`jaxadapt.physiology.kinetics`
(pass ``jac="bwd"``: diffrax's adjoint supports reverse mode only), or any
other pure JAX function. Least squares runs optimistix's Gauss-Newton loop
with :class:`LevenbergMarquardt` (MINPACK's scaling and stopping tests,
Nielsen's damping), a likelihood optimistix's BFGS; bounded fields are
fitted through a reparameterisation, so that the optimiser is
unconstrained; a large batch of datasets runs in a queue of :data:`LANES`
vmapped solver lanes, so that no fit waits for the slowest.

Modules:

- :mod:`~jaxadapt.fitting._fit`: :func:`fit`, its argument checks and the
  choice between one vmapped solve and the queue;
- :mod:`~jaxadapt.fitting._result`: the :class:`Fit` it returns;
- :mod:`~jaxadapt.fitting._problem`: the objective of one dataset, and its
  standard errors and convergence flags at the solver's end;
- :mod:`~jaxadapt.fitting._solver`: Levenberg-Marquardt (Nielsen's damping,
  the scaled damped Newton step, MINPACK's stopping tests);
- :mod:`~jaxadapt.fitting._bounds`: the fitted fields, their bounds and the
  map to the unconstrained values;
- :mod:`~jaxadapt.fitting._queue`: a large batch through a queue of solver
  lanes.
"""

from jaxadapt.fitting._bounds import POSITIVE
from jaxadapt.fitting._fit import LANES, MAX_STEPS, WEIGHTS_MESSAGE, fit
from jaxadapt.fitting._problem import NEWTON_STEP, ROUNDINGS
from jaxadapt.fitting._result import Fit
from jaxadapt.fitting._solver import (
    LevenbergMarquardt,
    NielsenDamping,
    ScaledDampedNewtonDescent,
    nielsen_update,
)

__all__ = [
    "LANES",
    "MAX_STEPS",
    "NEWTON_STEP",
    "POSITIVE",
    "ROUNDINGS",
    "WEIGHTS_MESSAGE",
    "Fit",
    "LevenbergMarquardt",
    "NielsenDamping",
    "ScaledDampedNewtonDescent",
    "fit",
    "nielsen_update",
]
