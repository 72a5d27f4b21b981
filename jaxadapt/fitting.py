"""Fit any subset of a model's parameters to data, by gradient, through the simulator.

One entry point, :func:`fit`. The user writes the forward model as a function
``model(params, args) -> prediction`` of a parameter module (an operator's or
an observer's ``Params``, any ``equinox.Module`` whose numeric fields are
arrays) and names the fields to fit; the other fields stay as they are in the
``params`` given, whose values of the named fields are also the start. The
fit differentiates through whatever ``model`` calls: ``pattanaik2000.run``
(the exact kernels), the diffrax path of :mod:`jaxadapt.physiology.kinetics`
(pass ``jac="bwd"``: diffrax's adjoint supports reverse mode only), or any
other pure JAX function.

Reparameterisation
------------------
The optimiser works on unconstrained values ``u``, one per element of each
fitted field, mapped to the parameter by its bounds ``(low, high)``:

| bounds | parameter | start ``u`` |
| --- | --- | --- |
| ``(0, inf)`` (default) | ``exp(u)`` | ``log(p)`` |
| ``(low, inf)`` | ``low + exp(u)`` | ``log(p - low)`` |
| ``(-inf, high)`` | ``high - exp(u)`` | ``log(high - p)`` |
| ``(low, high)`` | ``low + (high - low) s(u)`` | ``logit((p - low) / (high - low))`` |
| ``None`` | ``u`` | ``p`` |

with ``s`` the logistic sigmoid. Every field is positive unless ``bounds``
says otherwise (time constants, bleaching constants and semi-saturations
are). Working in ``log p`` also puts parameters of very different scales
(``t0 = 0.08`` s, ``tau = 400`` s) on one footing for the optimiser.

Objectives
----------
*Least squares* (the default, ``nll=None``): minimise ``1/2 sum w (f - y)^2``
over the measurements ``y`` with weights ``w`` (``1/sd^2``), with
:class:`LevenbergMarquardt` (optimistix's, with each parameter damped in
its own units and stopped by MINPACK's tests, and Nielsen's update of the
damping; or any optimistix least-squares solver passed as ``solver``,
e.g. ``optimistix.GaussNewton``). The residuals are handed to the solver
with their Jacobian computed in one pass per step, so that a step costs one
Jacobian of the model and not a model replay per product with it: forward
mode (the default) linearises the model once and pushes each fitted
field's tangent through the linearisation alone (see
:meth:`_Problem.linearised`), ``jac="bwd"`` takes ``jax.jacrev``.

*Maximum likelihood* (``nll`` given): minimise ``sum w nll(f, y)``, with
``nll`` the negative log-likelihood of one measurement given its prediction,
elementwise (e.g. ``-(y log f + (1 - y) log(1 - f))`` for a proportion ``y``
of ``w`` binomial trials), by optimistix's BFGS on the mean per unit weight.

:func:`fit` is not itself differentiable, with respect to ``data``,
``args`` or the fixed fields of ``params`` (the residuals' custom
derivative treats everything but the fitted values as constants; JAX then
fails with "No constant handler for type: ...Tracer"). The sensitivity of
a least-squares estimate to the data follows from the minimum's condition
``J' W (f - y) = 0``: ``d theta / d y = (J' W J)^-1 J' W`` (Gauss-Newton).

Batches
-------
Datasets are fitted in *lanes*, one solve each, vmapped. A batch of at most
:data:`LANES` datasets is one vmapped solve (optimistix's own loop): it runs
until the slowest fit has stopped, the others frozen meanwhile. A larger
batch would make every fit wait for the slowest one, computing the model
and its Jacobian for all of them at every step (fits of the same model
often take from 5 to 50 steps), so it goes through a queue instead:
:data:`LANES` lanes, and a lane whose fit stops is written out and takes
the next dataset at once. The host hands the queue over in rounds of
:data:`LANES` datasets; between rounds each lane's whole solver state
(iterate, step count, Levenberg-Marquardt's damping and last Jacobian)
stays as it is, so that every fit takes the steps, and gives the numbers,
of an uninterrupted solve (to rounding, which XLA may give differently for
another batch width). The compiled functions see twice :data:`LANES`
datasets whatever the batch: a batch of any size compiles them once. Under
a JAX transformation (:func:`fit` called inside ``jit`` or ``vmap``, any of
``data``, ``weights``, ``params``, ``args`` traced) there is no host to keep
the queue, and the batch is one vmapped solve whatever its size.

The lanes take each step as one vmapped computation. (Stepping them in two
independent groups, which XLA's CPU runtime runs side by side, deadlocked
that runtime in jaxlib 0.10.2 once a group held about 90 lanes of this
benchmark's 90 residuals, or 32 lanes of 270, and it was no faster on a
2-core VM: 0.384 s for the 1,000 fits, against 0.379 s in one group.)

Uncertainty
-----------
Standard errors come from the information matrix of ``u`` at the estimate:
the Gauss-Newton ``J' W J`` for least squares (scaled by the residual
variance ``2 loss / (m - k)`` unless ``absolute_sigma``, as SciPy's
``curve_fit`` does; ``J`` and the returned prediction are the solver's
last Jacobian and model evaluation, at the estimate, for optimistix's
Gauss-Newton family, and are computed there otherwise), the
Hessian of the negative log-likelihood otherwise; then the delta method
back to natural units, ``cov_p = D cov_u D`` with ``D`` the derivative of
the map above. ``cov`` is over the fitted elements in the
order of ``names`` (each field raveled).

The information matrix is inverted on its unit-diagonal scaling, through
the singular values of the scaled Jacobian ``J`` for least squares (the
eigenvalues of ``J'J`` are their squares) and the eigen-decomposition of
the Hessian for a likelihood. A parameter is *not identified* when its
sensitivity (the square root of its diagonal) is below ``eps`` of the
largest one, or when it has weight in a direction whose singular value
(least squares) or eigenvalue (likelihood) is below ``sqrt(eps)`` of the
largest (a combination of parameters the data do not pin down, e.g.
two that only enter as a product). Its standard error is then ``inf``, its
off-diagonal covariances 0, and ``converged`` is False; every other number
stays finite. No output is NaN.

A solver's tests say that its steps have become small, not that it is at a
minimum: far from the data a step can be small because the model is far
from linear, or because the sum of squares cannot resolve a better point.
``Fit.newton_step`` measures what is left: the length, in standard errors,
of a full Gauss-Newton (Newton) step from the estimate, ``sqrt(g' C g)``
(with ``C`` in the units of the free values and, for least squares, the
residual variance at least ``eps mean(w y^2)``, so that a fit to rounding is
not judged by rounding). ``converged`` also requires it to be at most
:data:`NEWTON_STEP` (0.1): the estimate is within a tenth of a standard
error of the minimum the linearisation there points to. A likelihood
whose maximum lies at infinity (responses all the same, or perfectly
separated, in a psychometric model) can be flat to rounding at the point
the solver reaches, with a short Newton step: there only the standard
errors' size tells (:mod:`jaxadapt.psychophysics.psychometric` flags such data).

Data
----
``data`` has the model's output shape, with any leading axes a batch of
datasets fitted at once (one ``vmap``: one fit per participant, per
condition). Measurements that are not finite (NaN, inf) are left out, and a
warning says how many; so are those of weight 0, silently (that is how a
measurement is left out on purpose). Each fit reports both in ``n_masked``.

References
----------
Moré (1978), *The Levenberg-Marquardt algorithm: implementation and theory*;
Madsen, Nielsen and Tingleff (2004), *Methods for non-linear least squares
problems*, §3.2 (the damping's start and update);
Nocedal and Wright (2006), *Numerical Optimization*, ch. 6 (BFGS) and 10
(least squares); Bates and Watts (1988), *Nonlinear Regression Analysis*,
§2.3 (Gauss-Newton standard errors).
"""

import dataclasses
import math
import warnings
from collections import OrderedDict
from collections.abc import Callable
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree

from jaxadapt.operators.checks import plain_errors

#: What a weight must be, said for bad ones on the host and under ``jit``.
WEIGHTS_MESSAGE = (
    "weights: expected finite, non-negative weights (1/sd^2; 0 leaves a measurement out)"
)

#: Default bounds of a fitted field: positive.
POSITIVE = (0.0, math.inf)
#: Default iteration cap of the optimiser.
MAX_STEPS = 256
#: Largest full (Gauss-)Newton step from the estimate, in standard errors,
#: of a fit called converged (``Fit.newton_step``).
NEWTON_STEP = 0.1
#: A Jacobian column (weighted) shorter than this many roundings of the
#: weighted prediction, ``ROUNDINGS eps |f|``, is rounding and is set to 0
#: (:meth:`_Problem.linearised`).
ROUNDINGS = 64
#: Solver lanes of a batch (see "Batches" in the module notes): a batch of at
#: most this many datasets is fitted in one vmapped solve, a larger one
#: through a queue of this many lanes. On a 2-core CPU, 64 lanes fitted the
#: 1,000 datasets of ``benchmarks/bench_fitting.py`` faster than 32 or 128:
#: wider vmaps of the model leave the cache, narrower ones pay XLA's fixed
#: cost per operation more often, and the last fits of a queue leave lanes idle.
LANES = 64


class Fit(eqx.Module):
    """Result of :func:`fit`; every array has the datasets' batch shape in front.

    Attributes
    ----------
    params : Params
        The parameter module at the estimate (fitted fields replaced, the
        others as given; under a batch every field gains the batch axes).
    estimate : OrderedDict
        Fitted values by name, in natural units, in the order of ``names``.
    se : OrderedDict
        Standard errors by name (delta method, natural units), in the order
        of ``names``; ``inf`` for a parameter the data do not identify.
    cov : array, (..., k, k)
        Covariance of the ``k`` fitted elements (``names`` order, raveled).
    prediction : array
        The model at the estimate, the shape of ``data``.
    residuals : array
        ``prediction - data``, 0 where a measurement was left out.
    mask : array of bool
        Measurements used (finite, positive weight).
    n_masked : array of int
        Measurements left out, per dataset.
    loss : array
        ``1/2 sum w r^2`` (least squares) or ``sum w nll`` at the estimate.
    newton_step : array
        Length of a full Gauss-Newton (least squares) or Newton (likelihood)
        step from the estimate, in standard errors: ``sqrt(g' C g)``, with
        ``g`` the gradient of the loss and ``C`` the covariance of the free
        values (the identified ones). At a minimum it is 0; a solve that
        stopped short of one (a start far from the data, a loss flat to
        rounding before the minimum) leaves it large.
    converged : array of bool
        The solver met its tolerance within ``max_steps``, every parameter is
        identified (finite standard error) and ``newton_step`` is at most
        :data:`NEWTON_STEP`. It says the estimate is the minimum, not that
        the data determine it well: a parameter the data barely constrain
        has a finite standard error larger than its estimate (``se``
        against ``estimate`` tells), and its Wald interval, symmetric in
        natural units, can reach below 0 for a positive parameter and cover
        the truth less often than its level says (:meth:`interval` maps it
        through the reparameterisation instead).
    solved : array of bool
        The solver met its tolerance, identified or not.
    steps : array of int
        Iterations the solver took.
    names : tuple of str
        The fitted fields (static).
    bounds : tuple of (float, float)
        Each fitted field's ``(low, high)`` (static), as fitted.
    """

    params: Any
    estimate: dict
    se: dict
    cov: jax.Array
    prediction: jax.Array
    residuals: jax.Array
    mask: jax.Array
    n_masked: jax.Array
    loss: jax.Array
    newton_step: jax.Array
    converged: jax.Array
    solved: jax.Array
    steps: jax.Array
    names: tuple = eqx.field(static=True)
    bounds: tuple = eqx.field(static=True)

    def interval(self, level=0.95):
        """Confidence intervals by name, ``(lower, upper)`` in natural units,
        from the standard errors of the free values the fit worked on.

        ``u +- z se_u`` mapped back through each field's bounds (the table
        in the module notes), with ``se_u = se / |dp/du|`` (the delta method
        undone) and ``z`` the normal quantile of ``(1 + level) / 2``: a
        positive parameter gets ``p exp(+-z se / p)``, which stays above 0
        and is wider above the estimate than below it; an unbounded one the
        Wald interval ``p +- z se``. Where the log (or logit) of a parameter
        is closer to normal than the parameter itself, as for a time
        constant known to a factor, it covers better than the Wald
        interval. A parameter that is not identified (``se`` inf) gets its
        bounds.

        Examples
        --------
        >>> import equinox as eqx
        >>> class Line(eqx.Module):
        ...     b: jax.Array
        >>> x = jnp.linspace(1.0, 2.0, 5)
        >>> y = 2.0 * x + 0.01 * jnp.sin(9.0 * x)
        >>> f = fit(lambda p, x: p.b * x, Line(jnp.array(1.0)), ["b"], y, args=x)
        >>> low, high = f.interval()["b"]
        >>> bool(0 < low < f.estimate["b"] < high)
        True
        """
        if not 0 < level < 1:
            raise ValueError(f"level: expected a number between 0 and 1, got {level!r}")
        z = jax.scipy.special.ndtri((1.0 + level) / 2.0)
        out = OrderedDict()
        for name, (low, high) in zip(self.names, self.bounds, strict=True):
            free = _Free(name, low, high)
            p, se = jnp.asarray(self.estimate[name]), jnp.asarray(self.se[name])
            u = _to_free(p, free)
            se_u = se / jnp.abs(_derivative(u, free))
            # Each map is monotonic (``high - exp(u)`` falling): its ends in order.
            a, b = (_to_natural(u + sign * z * se_u, free) for sign in (-1.0, 1.0))
            identified = jnp.isfinite(se)
            out[name] = (
                jnp.where(identified, jnp.minimum(a, b), low).astype(p.dtype),
                jnp.where(identified, jnp.maximum(a, b), high).astype(p.dtype),
            )
        return out

    @property
    def correlation(self):
        """Correlation matrix of the fitted elements, ``(..., k, k)``; 0 off
        the diagonal for a parameter that is not identified."""
        var = jnp.diagonal(self.cov, axis1=-2, axis2=-1)
        ok = jnp.isfinite(var) & (var > 0)
        sd = jnp.where(ok, jnp.sqrt(jnp.where(ok, var, 1.0)), 1.0)
        both = ok[..., :, None] & ok[..., None, :]
        corr = jnp.where(both, self.cov / (sd[..., :, None] * sd[..., None, :]), 0.0)
        eye = jnp.eye(var.shape[-1], dtype=bool)
        return jnp.where(eye, 1.0, corr)


# -- the least-squares solver -------------------------------------------------


def _quiet(**kwargs):
    del kwargs


def _sum_squares(tree):
    return sum(jnp.sum(leaf**2) for leaf in jax.tree.leaves(tree))


def _predicted_reduction(y, y_new, f_info):
    """``(S, S - |r + J p|^2)``: the sum of squares ``S`` of the residuals
    ``r`` at ``y`` and its reduction at ``y_new = y + p`` predicted by the
    linearisation ``J`` at ``y`` (``f_info``: optimistix's residuals and
    Jacobian there).

    The reduction is computed as ``-(J p)'(2 r + J p)``, equal in exact
    arithmetic, not as the difference of the two sums: that difference
    keeps a rounding of ``S`` however short the step, so that at a float32
    minimum the shrinking steps of a growing damping still predicted 2
    roundings of ``S`` and never passed :class:`LevenbergMarquardt`'s
    stall test (256 steps for a fit that one lane stopped in 8).
    """
    Jp = f_info.jac.mv(jax.tree.map(jnp.subtract, y_new, y))
    terms = jax.tree.map(lambda r, d: d * (2.0 * r + d), f_info.residual, Jp)
    return _sum_squares(f_info.residual), -sum(jnp.sum(t) for t in jax.tree.leaves(terms))


def _reductions(y, y_new, f_info, f_new):
    """``(S, S - S_new, predicted)``: :func:`_predicted_reduction` and the
    actual reduction at ``y_new``, whose residuals are ``f_new``'s."""
    before, predicted = _predicted_reduction(y, y_new, f_info)
    return before, before - _sum_squares(f_new.residual), predicted


def nielsen_update(rho, step_size, nu):
    """Nielsen's update of the Levenberg-Marquardt damping after a trial step.

    ``rho`` is the gain ratio: the actual reduction of the sum of squares
    over the reduction predicted by the linearised model. With ``lambda =
    1 / step_size`` (optimistix's parameterisation of the damping), a step
    with ``rho > 0`` is accepted and ``lambda <- lambda max(1/3, 1 - (2 rho
    - 1)^3)``, ``nu <- 2``; otherwise it is rejected and ``lambda <- lambda
    nu``, ``nu <- 2 nu`` (Nielsen 1999, *Damping parameter in Marquardt's
    method*, IMM-REP-1999-05; Madsen, Nielsen and Tingleff 2004, *Methods
    for non-linear least squares problems*, §3.2).

    Returns ``(accept, step_size, nu)``.

    Examples
    --------
    >>> accept, step_size, nu = nielsen_update(1.0, 1.0, 2.0)  # lambda / 3
    >>> bool(accept), float(step_size), float(nu)
    (True, 3.0, 2.0)
    """
    accept = rho > 0
    grow = 1.0 / jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
    return (
        accept,
        jnp.where(accept, step_size * grow, step_size / nu),
        jnp.where(accept, 2.0, 2.0 * nu),
    )


class _DampingState(eqx.Module):
    step_size: jax.Array  # 1 / lambda
    nu: jax.Array  # the factor of lambda after the next rejected step


class NielsenDamping(optx.AbstractSearch):
    """The damping of Levenberg-Marquardt by Nielsen's rule.

    The first evaluation sets ``lambda_0 = tau`` (Madsen, Nielsen and
    Tingleff 2004, §3.2, ``tau max_j (J' J)_jj`` with their default ``tau =
    1e-3``, here in the units of :class:`ScaledDampedNewtonDescent`, in
    which every ``(J' J)_jj`` of the first Jacobian is 1); every later one
    updates it by :func:`nielsen_update` from the gain ratio of the step.
    The search of ``optimistix.LevenbergMarquardt`` (``ClassicalTrustRegion``)
    instead starts from ``lambda = 1`` and lowers it only after a step whose
    gain ratio exceeds 0.99: a fit that a Gauss-Newton step would nearly
    finish takes several damped steps first, and a fit in a curved valley
    (gain ratios of 0.5 to 0.9) keeps its damping and creeps. On the 1,000
    fits of ``benchmarks/bench_fitting.py`` this rule took 6.8 steps a fit
    on average instead of 8.8 (median 6 instead of 8, longest 34 instead
    of 45), and its estimates came closer to MINPACK's (at most 1.1
    standard errors apart instead of 20).

    The step size it returns is ``1 / lambda``, as optimistix's descents take it.
    """

    tau: float = 1e-3

    def init(self, y, f_info_struct):
        del f_info_struct
        dtype = jnp.result_type(*jax.tree.leaves(y))  # as the updates keep it
        return _DampingState(step_size=jnp.ones((), dtype), nu=jnp.full((), 2.0, dtype))

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        _, actual, predicted = _reductions(y, y_eval, f_info, f_eval_info)
        positive = predicted > 0
        rho = jnp.where(positive, actual / jnp.where(positive, predicted, 1.0), 0.0)
        # A point where the Jacobian is not finite cannot give the next step
        # (a parameter run to the end of its map, where ``dp/du = 0`` meets
        # an infinite derivative of the model): rejected, as a worse one is.
        usable = jnp.all(jnp.isfinite(f_eval_info.jac.as_matrix()))
        accept, step_size, nu = nielsen_update(
            jnp.where(usable, rho, 0.0), state.step_size, state.nu
        )
        step_size = jnp.where(first_step, 1.0 / self.tau, step_size).astype(state.step_size.dtype)
        nu = jnp.where(first_step, 2.0, nu).astype(state.nu.dtype)
        return step_size, accept | first_step, optx.RESULTS.successful, _DampingState(step_size, nu)


class _ScaledDescentState(eqx.Module):
    f_info: optx.FunctionInfo.ResidualJac
    scale: jax.Array  # D_j, the largest norm column j of J has had


class ScaledDampedNewtonDescent(optx.AbstractDescent):
    """The Levenberg-Marquardt step with each parameter damped in its own units.

    The step ``p`` minimises ``|r + J p|^2 + lambda |D p|^2``, that is
    ``(J' J + lambda D^2) p = -J' r``, with ``D_j`` the largest norm that
    column ``j`` of ``J`` has had so far (1 while every column is 0): MINPACK's
    scaling (``lmder``, ``mode = 1``; Moré 1978, §6). A column that the
    residuals do not feel (:func:`_felt`) counts as long as the longest:
    scaled to unit length, its rounding noise would drive the parameter.
    A parameter in units
    ``c`` times larger has a column, and a ``D_j``, ``c`` times smaller, so
    the steps, and the fit, do not depend on the units of the parameters.
    ``optimistix.DampedNewtonDescent`` damps every parameter by the same
    ``lambda``: one whose column is much shorter than the longest barely
    moves until ``lambda`` has fallen below its scale (a straight line
    ``a + b x`` with ``x`` up to 1,000 took 15 steps instead of 5, and a
    fit of data in units of ``1e8`` from a start of 1 stopped, its ``a``
    still at 15, 3,000 times the least sum of squares above it).

    ``p`` is found as the least-squares solution of ``[J; sqrt(lambda) D] p
    = [-r; 0]`` by QR, as optimistix solves its damped step. ``y`` is one
    vector (as :func:`fit` gives it) or a pytree, raveled.
    """

    def init(self, y, f_info_struct):
        flat, _ = ravel_pytree(y)
        f_info = jax.tree.map(
            lambda s: jnp.zeros(s.shape, s.dtype) if isinstance(s, jax.ShapeDtypeStruct) else s,
            f_info_struct,
            is_leaf=lambda s: isinstance(s, jax.ShapeDtypeStruct),
        )
        return _ScaledDescentState(f_info, jnp.zeros_like(flat))

    def query(self, y, f_info, state):
        del y
        norms = jnp.linalg.norm(f_info.jac.as_matrix(), axis=0)
        scale = jnp.maximum(state.scale, jnp.where(_felt(norms), norms, jnp.max(norms)))
        return _ScaledDescentState(f_info, scale)

    def step(self, step_size, state):
        J = state.f_info.jac.as_matrix()
        r, _ = ravel_pytree(state.f_info.residual)
        D = jnp.where(state.scale > 0, state.scale, 1.0)
        moves = step_size > 0  # lambda finite (it grows without bound on a stalled fit)
        sqrt_lambda = 1.0 / jnp.sqrt(jnp.where(moves, step_size, 1.0))
        damped = jnp.concatenate([J, jnp.diag(sqrt_lambda * D)])
        target = jnp.concatenate([r, jnp.zeros_like(D)])
        sol = lx.linear_solve(lx.MatrixLinearOperator(damped), target, lx.QR(), throw=False)
        structure = state.f_info.jac.in_structure()
        _, unravel = ravel_pytree(jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), structure))
        return unravel(jnp.where(moves, -sol.value, 0.0)), optx.RESULTS.promote(sol.result)


class LevenbergMarquardt(optx.AbstractGaussNewton):
    """Levenberg-Marquardt as MINPACK's ``lmder`` scales and stops it, on
    optimistix's Gauss-Newton loop, with Nielsen's damping.

    The step damps each parameter in its own units
    (:class:`ScaledDampedNewtonDescent`), the damping follows Nielsen's rule
    (:class:`NielsenDamping`), and the solve stops by the first of four tests:

    * optimistix's: the parameters and the residuals both changed by less
      than ``atol + rtol |.|`` (after the first step: before it, optimistix
      compares the residuals with the zeros its state starts from, and would
      stop at the start whenever every residual is below ``atol``);
    * MINPACK's ``ftol`` test (Moré 1978; SciPy's
      ``least_squares(method="lm")``): an accepted step whose actual and
      predicted relative reductions of the sum of squares are both at most
      ``ftol``, the actual one at most twice the predicted. With ``m - k``
      residual degrees of freedom such a step moves the parameters by at most
      about ``sqrt(ftol (m - k))`` standard errors. Without it, noisy data
      can take hundreds of steps when a parameter is weakly determined (the
      solver creeps by steps far below the standard errors), and under
      ``vmap`` every fit of a batch waits for the slowest. The ratio's bound
      (MINPACK's) keeps it from stopping a fit whose steps are small only
      because the model is far from linear there: far from the data, in the
      log of a parameter, a step does much more than its linearisation says;
    * a rejected step whose predicted relative reduction is at most ``eps``:
      at the rounding floor of the sum of squares (in float32, the last
      digits of a converged fit) no step lowers it, every step is rejected
      and the damping grows without end (MINPACK's ``xtol`` test, there on
      the trust region's radius);
    * a sum of squares of exactly 0: nothing is left to reduce (an exact
      fit, or a dataset with no measurements, whose residuals are all
      masked to 0). Every step has a gain ratio of 0/0 and is rejected, so
      no other test would stop it before ``max_steps``, with every fit of
      its vmapped batch waiting (256 steps, 14 times the batch's time, for
      one empty dataset among eight).

    Whether the fit stopped at a minimum is :func:`fit`'s test
    (``Fit.newton_step``), not the solver's.

    Attributes
    ----------
    rtol, atol : float
        Tolerances of optimistix's test.
    ftol : float
        Relative reduction of the sum of squares (``0`` disables the test).
    search, descent : optimistix search and descent
        Default :class:`NielsenDamping` and :class:`ScaledDampedNewtonDescent`.
    norm, verbose : callable
        As in ``optimistix.LevenbergMarquardt`` (max norm, silent).
    """

    rtol: float
    atol: float
    ftol: float
    norm: Callable = optx.max_norm
    descent: optx.AbstractDescent = ScaledDampedNewtonDescent()
    search: optx.AbstractSearch = NielsenDamping()
    verbose: Callable = _quiet

    def step(self, fn, y, args, options, state, tags):
        new_y, new_state, aux = super().step(fn, y, args, options, state, tags)
        before, actual, predicted = _reductions(y, new_y, state.f_info, new_state.f_info)
        scale = jnp.where(before > 0, before, 1.0)
        actual, predicted = actual / scale, predicted / scale
        accepted = new_state.num_accepted_steps > state.num_accepted_steps
        later = ~state.first_step & (before > 0)
        small = (
            accepted
            & later
            & (actual <= self.ftol)
            & (predicted <= self.ftol)
            & (actual <= 2.0 * predicted)
        )
        _, trial = _predicted_reduction(new_y, new_state.y_eval, new_state.f_info)
        eps = jnp.finfo(before.dtype).eps
        stalled = ~accepted & later & (trial <= eps * scale)
        exact = ~state.first_step & (before == 0)
        cauchy = new_state.terminate & ~state.first_step
        new_state = eqx.tree_at(lambda s: s.terminate, new_state, cauchy | small | stalled | exact)
        return new_y, new_state, aux


# -- the reparameterisation ---------------------------------------------------


class _Free(NamedTuple):
    """One fitted field and its bounds (static)."""

    name: str
    low: float
    high: float


def _to_natural(u, free):
    low, high = free.low, free.high
    if math.isinf(low) and math.isinf(high):
        return u
    if math.isinf(high):
        return low + jnp.exp(u)
    if math.isinf(low):
        return high - jnp.exp(u)
    return low + (high - low) * jax.nn.sigmoid(u)


def _derivative(u, free):
    """``dp/du`` of :func:`_to_natural`."""
    low, high = free.low, free.high
    if math.isinf(low) and math.isinf(high):
        return jnp.ones_like(u)
    if math.isinf(high):
        return jnp.exp(u)
    if math.isinf(low):
        return -jnp.exp(u)
    s = jax.nn.sigmoid(u)
    return (high - low) * s * (1.0 - s)


def _to_free(p, free):
    low, high = free.low, free.high
    if math.isinf(low) and math.isinf(high):
        return p
    if math.isinf(high):
        return jnp.log(p - low)
    if math.isinf(low):
        return jnp.log(high - p)
    x = (p - low) / (high - low)
    return jnp.log(x) - jnp.log1p(-x)


def _replace(params, spec, values):
    """``params`` with the fields of ``spec`` set to ``values`` (by name)."""
    fields = [f.name for f in spec]
    return eqx.tree_at(
        lambda p: [getattr(p, n) for n in fields], params, [values[n] for n in fields]
    )


# -- checks before tracing ----------------------------------------------------


def _numeric_fields(params):
    """Names of the fields of ``params`` that can be fitted (floating arrays)."""
    if not dataclasses.is_dataclass(params):
        raise ValueError(
            f"params: expected a parameter module (an equinox.Module such as an operator's "
            f"Params), got {type(params).__name__}"
        )
    return tuple(
        f.name
        for f in dataclasses.fields(params)
        if not f.metadata.get("static", False) and eqx.is_inexact_array(getattr(params, f.name))
    )


def _not_fittable(params, name):
    """Why the field ``name`` of ``params`` cannot be fitted, or ``""`` if
    it is not a field."""
    field = next((f for f in dataclasses.fields(params) if f.name == name), None)
    value = getattr(params, name, None)
    if field is None:
        return ""
    if not eqx.is_array_like(value):  # 'goal' "is not a parameter" misled
        return f"holds {value!r}, not a number"
    if field.metadata.get("static", False):
        why = "is a static field"
    elif isinstance(value, jax.Array | np.ndarray | np.generic):
        why = f"holds {value.dtype} values"
    else:
        why = f"holds a Python {type(value).__name__}"
    return (
        f"{why}; a fitted field must hold a JAX floating-point array "
        "(e.g. eqx.field(converter=jnp.asarray) and 1.0, not 1)"
    )


def _spec(params, names, bounds):
    """Validate ``names`` and ``bounds``; return the static spec."""
    valid = _numeric_fields(params)
    names = (names,) if isinstance(names, str) else tuple(names)
    if not names:
        raise ValueError(f"names: expected at least one of {valid}, got none")
    unknown = [n for n in names if n not in valid]
    for name in unknown:
        why = _not_fittable(params, name)
        if why:
            raise ValueError(
                f"names: {name!r} of {type(params).__name__} {why}; valid names: {', '.join(valid)}"
            )
    if unknown:
        raise ValueError(
            f"names: {', '.join(map(repr, unknown))} "
            f"{'is not a parameter' if len(unknown) == 1 else 'are not parameters'} "
            f"of {type(params).__name__}; valid names: {', '.join(valid)}"
        )
    if len(set(names)) != len(names):
        raise ValueError(f"names: expected each parameter once, got {names}")
    bounds = dict(bounds or {})
    extra = [n for n in bounds if n not in names]
    if extra:
        raise ValueError(f"bounds: {extra} are not among the fitted names {names}")
    spec = []
    for name in names:
        b = bounds.get(name, POSITIVE)
        if b is not None and not (isinstance(b, tuple | list) and len(b) == 2):
            raise ValueError(f"bounds[{name!r}]: expected (low, high) or None, got {b!r}")
        try:
            low, high = (-math.inf, math.inf) if b is None else (float(b[0]), float(b[1]))
        except (TypeError, ValueError):
            raise ValueError(f"bounds[{name!r}]: expected (low, high) or None, got {b!r}") from None
        if not low < high or math.isnan(low) or math.isnan(high):
            raise ValueError(f"bounds[{name!r}]: expected (low, high) with low < high, got {b!r}")
        value = getattr(params, name)
        if not isinstance(value, jax.core.Tracer):
            v = np.asarray(value, dtype=float)
            if not (np.all(np.isfinite(v)) and np.all(v > low) and np.all(v < high)):
                raise ValueError(
                    f"params.{name}: the start must lie strictly inside its bounds "
                    f"({low}, {high}), got {v.tolist()}"
                )
        spec.append(_Free(name, low, high))
    return tuple(spec)


# -- one dataset --------------------------------------------------------------


def _felt(norms):
    """Which parameters the residuals feel, from the norms of their Jacobian
    columns (or the square roots of an information matrix's diagonal): those
    longer than ``eps`` of the longest.

    A shorter column is at the rounding of the longest's effect (a derivative
    that is 0 in exact arithmetic, left by a rounding) and identifies
    nothing. Below that, the ratio of two columns does not matter: the
    information matrix scaled to a unit diagonal (:func:`_information_inverse`)
    is accurate to about ``m eps`` in every entry whatever the ratio, as
    is MINPACK's QR step. (Against ``sqrt(eps)`` of the longest, the columns
    of ``a`` and ``tau`` of ``a exp(-t / tau) + c`` with ``c = 1e8``, fitted
    in ``log c``, were 3e-8 of ``c``'s: the fit did not move them, and
    called them not identified.)
    """
    return norms > jnp.finfo(norms.dtype).eps * jnp.max(norms)


def _information_inverse(info=None, root=None):
    """Covariance from an information matrix, and which parameters it identifies.

    The information is ``info``, or ``root' root`` for a least-squares fit's
    weighted Jacobian ``root`` (one column per parameter). It is scaled to a
    unit diagonal, ``C = info / (d d')``, and inverted on the directions
    whose value exceeds ``sqrt(eps)`` of the largest: the eigenvalues of
    ``C``, or the singular values of ``root / d``, whose squares they are.
    Formed, ``J'J`` keeps its eigenvalues only down to about ``eps`` of the
    largest and the cut at ``sqrt(eps)`` must stay above that; ``J``'s own
    singular values are accurate to ``eps`` of the largest, so the cut on
    them lets through parameters correlated up to ``1 - eps/2``, not
    ``1 - sqrt(eps)/2``. In float32 that is the difference between a
    straight line fitted over x from 500 to 510 (its intercept and slope
    correlated at -0.99998, as in statsmodels) and no standard errors.

    Returns ``(cov, identified)``, ``cov`` finite with 0 in the rows and
    columns of parameters not identified (see the module notes).
    """
    a = info if root is None else root
    eps = jnp.finfo(a.dtype).eps
    # A parameter whose row is not finite (at a bound of its map, where
    # ``dp/du = 0`` meets an infinite derivative of the model: ``0 inf``) is
    # left out, not identified, and the others are judged without it.
    finite = jnp.all(jnp.isfinite(a), axis=0)
    if root is None:
        finite = finite & jnp.all(jnp.isfinite(info), axis=1)
        info = jnp.where(finite[:, None] & finite[None, :], 0.5 * (info + info.T), 0.0)
        d = jnp.sqrt(jnp.maximum(jnp.diagonal(info), 0.0))
    else:
        root = jnp.where(finite, root, 0.0)
        d = jnp.linalg.norm(root, axis=0)
    sensitive = _felt(d)
    d_safe = jnp.where(sensitive, d, 1.0)
    if root is None:
        scaled = sensitive[:, None] & sensitive[None, :]
        values, V = jnp.linalg.eigh(jnp.where(scaled, info / (d_safe[:, None] * d_safe), 0.0))
        eigenvalues = values
    else:
        scaled = jnp.where(sensitive, root / d_safe, 0.0)
        _, values, Vt = jnp.linalg.svd(scaled, full_matrices=False)
        V, eigenvalues = Vt.T, values**2
    keep = values > jnp.sqrt(eps) * jnp.maximum(jnp.max(values), jnp.finfo(a.dtype).tiny)
    inv = jnp.where(keep, 1.0 / jnp.where(keep, eigenvalues, 1.0), 0.0)
    null_weight = jnp.sum(jnp.where(keep, 0.0, V**2), axis=1)
    identified = sensitive & (null_weight < jnp.sqrt(eps)) & finite
    cov = (V * inv) @ V.T / (d_safe[:, None] * d_safe)
    return jnp.where(identified[:, None] & identified[None, :], cov, 0.0), identified


def _and_itself(x):
    """``(x, x)``: a value with itself as the aux."""
    return x, x


class _Problem(eqx.Module):
    """What every dataset of one call shares, and the fit of one dataset.

    The methods take one dataset's observations ``obs = (y, w, mask, c)``
    (:meth:`observations`) as an argument rather than closing over them, so
    that a solver lane can pass from one dataset to the next. Under
    ``eqx.filter_jit`` the arrays (``params``, ``args``, ``absolute_sigma``)
    are traced and the rest is static.
    """

    model: Callable
    params: Any
    args: Any
    spec: tuple
    nll: Callable | None
    solver: Any
    jac: str
    absolute_sigma: jax.Array
    max_steps: int
    dtype: Any

    def observations(self, data, weights):
        """``(y, w, mask, c)``: the measurements and weights, 0 where left
        out, and the root mean square ``c`` of the weighted residuals at the
        start (1 if that is 0 or not finite, and for a likelihood).

        The least-squares solver works on the residuals over ``c``, so that
        the units of the data and weights do not matter to optimistix's test
        (:class:`LevenbergMarquardt`), which compares the residuals' change
        with ``atol + rtol |r|``: on data in units of ``1e-9`` every change
        would pass it, and the parameters' change alone would decide.
        """
        mask = jnp.isfinite(data) & (weights > 0)
        w = jnp.where(mask, weights, 0.0).astype(self.dtype)
        y = jnp.where(mask, data, 0.0)
        if self.nll is not None:  # the likelihood has no residuals to scale
            return y, w, mask, jnp.ones((), self.dtype)
        start = jnp.where(mask, (self.predict(self.free()[0]) - y) * jnp.sqrt(w), 0.0)
        c = jnp.sqrt(jnp.sum(start**2) / jnp.maximum(jnp.sum(mask), 1))
        return y, w, mask, jnp.where(jnp.isfinite(c) & (c > 0), c, 1.0)

    def free(self):
        """The start ``u0``, one vector in the order of ``names`` (raveled, so
        that ``cov`` follows that order), and the map from such a vector back
        to the fitted fields' free values."""
        return ravel_pytree(
            tuple(
                _to_free(jnp.asarray(getattr(self.params, f.name), self.dtype), f)
                for f in self.spec
            )
        )

    def natural(self, fields):
        """The fitted fields' natural values by name, in the order of ``names``
        (an ``OrderedDict``: JAX keeps its order, and sorts a ``dict``'s keys)."""
        return OrderedDict(
            (f.name, _to_natural(v, f)) for v, f in zip(fields, self.spec, strict=True)
        )

    def prediction(self, fields):
        """The model with the fitted fields at the free values ``fields``."""
        return self.model(_replace(self.params, self.spec, self.natural(fields)), self.args)

    def predict(self, u):
        """The model at the free vector ``u``."""
        return self.prediction(self.free()[1](u))

    def weigh(self, df, obs):
        """``sqrt(w) df / c``, raveled, 0 where masked: the weighted residuals
        ``r = sqrt(w) (f - y) / c`` of the prediction ``f = y + df``, in
        units of their start (:meth:`observations`), and (being linear in
        ``df``) their change for a change ``df`` of ``f``."""
        _, w, mask, c = obs
        return jnp.where(mask, df * (jnp.sqrt(w) / c), 0.0).ravel()

    def jacobian(self, u):
        """``(F, f)``: the Jacobian ``F = df/du`` of the prediction (one row per
        element of ``f``, raveled, one column per element of ``u``) and the
        prediction ``f`` at ``u``.

        Forward mode (``jac="fwd"``): the model is linearised once
        (``jax.linearize``: one evaluation, which keeps what its derivative
        needs) and each fitted field's tangent is then pushed through that
        linear map alone, the other fields' tangents zero, so that it only
        passes the operations that depend on that field. A model whose
        fields act on separate parts of it (the time constants of rods and
        cones, each on its own state) then costs far less than with all ``k``
        tangents pushed through every operation at once (``jax.jacfwd``): the
        fits of ``benchmarks/bench_fitting.py`` took 1.5 times less CPU time.
        ``jac="bwd"``: one reverse-mode Jacobian.
        """
        if self.jac == "bwd":
            F, f = jax.jacrev(lambda u: _and_itself(self.predict(u)), has_aux=True)(u)
            return F.reshape(f.size, -1), f
        fields = self.free()[1](u)
        f, tangent = jax.linearize(lambda *fields: self.prediction(fields), *fields)
        zeros = [jnp.zeros_like(field) for field in fields]

        def column(i):
            def along(t):
                return tangent(*zeros[:i], t, *zeros[i + 1 :])

            return jax.jacfwd(along)(zeros[i]).reshape(f.size, -1)

        return jnp.concatenate([column(i) for i in range(len(fields))], axis=1), f

    def linearised(self, u, obs):
        """``(J, r, f, F)``: the Jacobian of the weighted residuals (``sqrt(w) F``,
        0 in masked rows), the residuals, the prediction and its Jacobian
        (:meth:`jacobian`) at ``u``.

        A column of ``J`` shorter than :data:`ROUNDINGS` roundings of the
        weighted prediction, ``|J_j| <= ROUNDINGS eps |sqrt(w) f|``, is set to
        0 (in ``J`` and ``F``): a parameter whose effect on the model is 0 in
        exact arithmetic leaves a column of its rounding (``t0`` on a field
        where ``A = G`` throughout: 0.07 roundings in float64), which would
        otherwise steer the solver and give a finite standard error. The
        prediction's scale, not the longest column's, is what a column's
        rounding is relative to: ``a`` of ``a exp(-t / b) + c`` on ``c =
        1e8`` has a column 3e-8 of ``c``'s and is well identified.
        """
        F, f = self.jacobian(u)
        J = jax.vmap(lambda column: self.weigh(column.reshape(f.shape), obs), 1, 1)(F)
        rounding = ROUNDINGS * jnp.finfo(f.dtype).eps * jnp.linalg.norm(self.weigh(f, obs))
        felt = jnp.linalg.norm(J, axis=0) > rounding
        return jnp.where(felt, J, 0.0), self.weigh(f - obs[0], obs), f, jnp.where(felt, F, 0.0)

    def residuals(self, u, obs):
        """``(r, f)``: the weighted residuals and the prediction, whose
        derivatives are the Jacobians of :meth:`linearised`, computed in one
        pass: the solver's linearisation then keeps a ``k``-column matrix
        instead of replaying the model for every product with it
        (materialising, trust-region predictions). The data are constants
        to it."""

        @jax.custom_jvp
        def residuals(u, obs):
            f = self.predict(u)
            return self.weigh(f - obs[0], obs), f

        @residuals.defjvp
        def residuals_jvp(primals, tangents):
            J, r, f, F = self.linearised(*primals)
            return (r, f), (J @ tangents[0], (F @ tangents[0]).reshape(f.shape))

        return residuals(u, obs)

    def total_nll(self, u, obs):
        y, w, mask, _ = obs
        f = self.predict(u)
        terms = self.nll(f, jnp.where(mask, y, jax.lax.stop_gradient(f)))
        return jnp.sum(jnp.where(mask, w * terms, 0.0))

    def objective(self, u, obs):
        """What the solver works on, and its aux: the residuals with the
        prediction as the aux (a least-squares solver, which keeps the aux
        of its last accepted iterate, so that the :class:`Fit` needs no
        model evaluation of its own), half their sum of squares (a
        minimiser given for least squares), or the negative log-likelihood
        per unit weight (both without aux)."""
        if self.nll is not None:
            total_w = jnp.maximum(jnp.sum(obs[1]), jnp.finfo(self.dtype).tiny)
            return self.total_nll(u, obs) / total_w, None
        r, f = self.residuals(u, obs)
        if isinstance(self.solver, optx.AbstractMinimiser):
            return 0.5 * jnp.sum(r**2), None
        return r, f

    def summarise(self, obs, u, solved, steps, linear=None):
        """The :class:`Fit` of one dataset at the solver's final ``u``, with
        ``linear = (J, r, f)`` there if the solver kept them
        (:func:`_solver_linearisation`)."""
        y, w, mask, c = obs
        u0, unravel = self.free()
        k = u0.size
        if self.nll is None:
            # J and r in the solver's units (residuals over c), in which the
            # numbers are near 1 whatever the units of the data and weights.
            J, r, prediction = self.linearised(u, obs)[:3] if linear is None else linear
            information, gradient = {"root": J}, J.T @ r
            loss = 0.5 * jnp.sum((r * c) ** 2)
            dof = jnp.sum(mask) - k
            per_dof = jnp.where(dof > 0, dof, 1)
            variance = jnp.where(dof > 0, jnp.sum(r**2) / per_dof, jnp.inf)
            scale = jnp.where(self.absolute_sigma, 1.0 / c**2, variance)
            # The Newton step of a fit to rounding (noiseless data) is rounding
            # over rounding: it is measured against a variance of at least
            # ``eps mean(w y^2)`` (residuals of half the digits of the data).
            floor = jnp.finfo(self.dtype).eps * jnp.sum(self.weigh(y, obs) ** 2) / per_dof
            step_scale = jnp.where(self.absolute_sigma, scale, jnp.maximum(variance, floor))
        else:
            hessian = jax.hessian if self.jac == "fwd" else lambda f: jax.jacrev(jax.grad(f))
            information = {"info": hessian(lambda u: self.total_nll(u, obs))(u)}
            loss, gradient = jax.value_and_grad(lambda u: self.total_nll(u, obs))(u)
            prediction = self.predict(u)
            scale = step_scale = 1.0
        cov_u, identified = _information_inverse(**information)
        gradient = jnp.where(identified, gradient, 0.0)  # cov_u is 0 there; no 0 NaN
        reduction = jnp.maximum(gradient @ cov_u @ gradient, 0.0)  # twice the step's, of the loss
        newton_step = jnp.sqrt(jnp.where(step_scale > 0, reduction / step_scale, 0.0))
        D, _ = ravel_pytree(
            tuple(_derivative(v, f) for v, f in zip(unravel(u), self.spec, strict=True))
        )
        ok = identified & jnp.isfinite(scale) & jnp.all(jnp.isfinite(D))
        cov = jnp.where(ok[:, None] & ok[None, :], D[:, None] * cov_u * D * scale, 0.0)
        cov = jnp.where(jnp.eye(k, dtype=bool) & ~ok[:, None], jnp.inf, cov)
        se = jnp.where(ok, jnp.sqrt(jnp.where(ok, jnp.diagonal(cov), 0.0)), jnp.inf)
        estimate = self.natural(unravel(u))
        finite = jnp.all(jnp.isfinite(u)) & jnp.isfinite(loss)
        return Fit(
            params=_replace(self.params, self.spec, estimate),
            estimate=estimate,
            se=OrderedDict(zip(estimate, unravel(se.astype(self.dtype)), strict=True)),
            cov=cov.astype(self.dtype),
            prediction=prediction,
            residuals=jnp.where(mask, prediction - y, 0.0),
            mask=mask,
            n_masked=jnp.sum(~mask).astype(jnp.int32),
            loss=loss,
            newton_step=newton_step.astype(self.dtype),
            converged=solved & jnp.all(ok) & finite & (newton_step <= NEWTON_STEP),
            solved=solved,
            steps=jnp.asarray(steps, jnp.int32),
            names=tuple(f.name for f in self.spec),
            bounds=tuple((f.low, f.high) for f in self.spec),
        )


# -- a batch in one vmapped solve ---------------------------------------------


def _solver_linearisation(state):
    """``(J, r, f)`` at the solver's last accepted iterate where its state
    keeps them (optimistix's Gauss-Newton family: Levenberg-Marquardt,
    Gauss-Newton, dogleg; ``f`` is the aux of :meth:`_Problem.objective`),
    so that the standard errors need no Jacobian of their own; else
    ``None``. (After at least one step: before the first, that state holds
    zeros.)"""
    f_info, f = getattr(state, "f_info", None), getattr(state, "aux", None)
    if isinstance(f_info, optx.FunctionInfo.ResidualJac) and f is not None:
        return f_info.jac.as_matrix(), f_info.residual, f
    return None


def _fit_one(problem, data, weights):
    """One dataset, solved by optimistix's own loop (``least_squares`` or
    ``minimise``)."""
    obs = problem.observations(data, weights)
    solve = (
        optx.minimise if isinstance(problem.solver, optx.AbstractMinimiser) else optx.least_squares
    )
    sol = solve(
        problem.objective,
        problem.solver,
        problem.free()[0],
        obs,
        has_aux=True,
        max_steps=problem.max_steps,
        throw=False,
    )
    solved = sol.result == optx.RESULTS.successful
    linear = _solver_linearisation(sol.state)
    return problem.summarise(obs, sol.value, solved, sol.stats["num_steps"], linear)


@eqx.filter_jit
def _fit(problem, data, weights):
    """Every dataset (leading axis) at once: one vmapped solve."""
    bad = ~jnp.all(jnp.isfinite(weights) & (weights >= 0))
    weights = eqx.error_if(weights, bad, WEIGHTS_MESSAGE)
    return jax.vmap(lambda d, w: _fit_one(problem, d, w))(data, weights)


# -- a batch through a queue of solver lanes ----------------------------------


class _Lane:
    """optimistix's ``iterative_solve`` (``optimistix/_iterate.py``) taken apart
    for one dataset: its start, one step, whether it goes on, and its end.

    The carry ``(y, num_steps, state, aux, terminate, result)`` is the one of
    optimistix's loop, with the solver's whole state (for Levenberg-Marquardt
    its damping, the last Jacobian, the trust region), so that a solve
    stopped after any step and carried on gives the same iterates as one
    uninterrupted solve.
    """

    def __init__(self, problem, obs):
        """``obs``: one dataset's observations, as an example of their shapes."""
        self.solver = problem.solver
        self.max_steps = problem.max_steps
        self.y0 = problem.free()[0]
        # As optimistix's least_squares and minimise prepare the function.
        self.fn = eqx.filter_closure_convert(problem.objective, self.y0, obs)
        self.structs = self.fn.out_struct
        self.options, self.tags = {}, frozenset()

    def _status(self, y, state, obs):
        terminate, result = self.solver.terminate(self.fn, y, obs, self.options, state, self.tags)
        return terminate, optx.RESULTS.where(
            jnp.all(jnp.isfinite(y)), result, optx.RESULTS.nonfinite
        )

    def start(self, obs):
        state = self.solver.init(self.fn, self.y0, obs, self.options, *self.structs, self.tags)
        aux = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), self.structs[1])
        return (self.y0, jnp.array(0), state, aux, *self._status(self.y0, state, obs))

    def step(self, carry, obs):
        y, num_steps, state, _, _, _ = carry
        new_y, state, aux = self.solver.step(self.fn, y, obs, self.options, state, self.tags)
        return (new_y, num_steps + 1, state, aux, *self._status(y, state, obs))

    def running(self, carry):
        _, num_steps, _, _, terminate, result = carry
        return ~terminate & (result == optx.RESULTS.successful) & (num_steps < self.max_steps)

    def end(self, carry, obs):
        """``(u, solved, steps, linear)`` of a solve that has stopped."""
        y, num_steps, state, aux, terminate, result = carry
        result = optx.RESULTS.where(
            (result == optx.RESULTS.successful) & ~terminate,
            optx.RESULTS.nonlinear_max_steps_reached,
            result,
        )
        y, _, _ = self.solver.postprocess(
            self.fn, y, aux, obs, self.options, state, self.tags, result
        )
        return y, result == optx.RESULTS.successful, num_steps, _solver_linearisation(state)


def _where(mask, new, old):
    """Per lane (leading axis): ``new`` where ``mask``, else ``old``."""
    return jax.tree.map(
        lambda a, b: jnp.where(mask.reshape(mask.shape + (1,) * (a.ndim - 1)), a, b), new, old
    )


def _lanes(problem, data, weights):
    """Observations of the datasets given (leading axis), the per-dataset
    functions, the start of each dataset's solve (its arrays) and the solver
    state's static part (the same for all)."""
    obs = jax.vmap(problem.observations)(data, weights)
    lane = _Lane(problem, jax.tree.map(lambda x: x[0], obs))
    start, static = eqx.partition(eqx.filter_vmap(lane.start)(obs), eqx.is_array)
    return obs, lane, start, static


def _rows(tree, index):
    """The rows ``index`` (leading axis) of every leaf."""
    return jax.tree.map(lambda x: x[index], tree)


@eqx.filter_jit
def _start(problem, data, weights):
    """A carry for lanes (one per dataset given): their solves' start."""
    return _lanes(problem, data, weights)[2]


@eqx.filter_jit
def _round(problem, carry, live, data, weights, waiting, final):
    """Solver steps in ``lanes`` lanes that take their datasets from a queue.

    ``data`` and ``weights`` have ``2 lanes`` rows: row ``i < lanes`` is the
    dataset lane ``i`` works on (where ``live``), the next ``waiting`` rows
    the datasets waiting, in order. Each iteration, idle lanes take the
    next waiting datasets (their solves' start), every running lane takes
    one solver step while the others stay as they are, and the lanes whose
    solve has stopped are written out and become idle. The round ends once
    every waiting dataset has been taken or, if ``final``, once every lane
    is idle. Returns the carry, each lane's row and whether it is live, and
    per row whether its solve is done and its end (:meth:`_Lane.end`).
    """
    lanes = live.shape[0]
    obs, lane, start, static = _lanes(problem, data, weights)

    def running(carry):
        return jax.vmap(lambda c: lane.running(eqx.combine(c, static)))(carry)

    def step(carry, obs):
        return eqx.partition(lane.step(eqx.combine(carry, static), obs), eqx.is_array)[0]

    def ends(carry, obs):
        return jax.vmap(lambda c, o: lane.end(eqx.combine(c, static), o))(carry, obs)

    def body(loop):
        carry, row, live, taken, out = loop
        idle = ~live
        rank = taken + jnp.cumsum(idle) - 1
        take = idle & (rank < waiting)
        row = jnp.where(take, lanes + rank, row)
        carry = _where(take, _rows(start, row), carry)
        live, taken = live | take, taken + jnp.sum(take, dtype=taken.dtype)
        here = _rows(obs, row)
        stepped = jax.vmap(step)(carry, here)
        carry = _where(live & running(carry), stepped, carry)
        stop = live & ~running(carry)
        out = jax.tree.map(
            lambda o, e: o.at[jnp.where(stop, row, 2 * lanes)].set(e, mode="drop"),
            out,
            (stop, *ends(carry, here)),
        )
        return carry, row, live & ~stop, taken, out

    shapes = jax.eval_shape(lambda: (live, *ends(carry, _rows(obs, jnp.arange(lanes)))))
    out = jax.tree.map(lambda x: jnp.zeros((2 * lanes,) + x.shape[1:], x.dtype), shapes)
    loop = (carry, jnp.arange(lanes), live, jnp.zeros((), int), out)
    carry, row, live, _, out = jax.lax.while_loop(
        lambda loop: (loop[3] < waiting) | (final & jnp.any(loop[2])), body, loop
    )
    return carry, row, live, out


@eqx.filter_jit
def _summaries(problem, data, weights, ends):
    """The :class:`Fit` of each dataset given (leading axis) from its solve's
    end ``(u, solved, steps, linear)``."""
    obs = jax.vmap(problem.observations)(data, weights)
    return jax.vmap(problem.summarise)(obs, *ends)


def _queue(problem, data, weights, lanes):
    """Every dataset (leading axis, more than ``lanes``) through ``lanes``
    solver lanes; see "Batches" in the module notes.

    The host keeps the queue and hands it to :func:`_round` ``lanes``
    datasets at a time; the compiled functions see ``2 lanes`` datasets
    whatever their number. The standard errors and the rest of each
    :class:`Fit` then come from :func:`_summaries`, ``2 lanes`` datasets at
    a time (half as many calls as ``lanes`` at a time: on the 1,000 fits of
    ``benchmarks/bench_fitting.py``, 7 ms instead of 11).
    """
    n = data.shape[0]
    data, weights = np.asarray(data), np.asarray(weights)
    ends = None  # each dataset's (u, solved, steps, linear)
    at = np.zeros(lanes, int)  # the dataset of each lane
    live = np.zeros(lanes, bool)
    carry = _start(problem, data[:lanes], weights[:lanes])
    queued = 0
    while queued < n or np.any(live):
        waiting = np.arange(queued, min(queued + lanes, n))
        queued += waiting.size
        rows = np.concatenate([at, waiting, np.zeros(lanes - waiting.size, int)])
        carry, row, live, (done, *out) = _round(
            problem,
            carry,
            live,
            data[rows],
            weights[rows],
            np.asarray(waiting.size),
            np.asarray(queued == n),
        )
        done = np.asarray(done)
        if ends is None:
            ends = jax.tree.map(lambda x: np.zeros((n,) + x.shape[1:], x.dtype), out)
        for end, x in zip(jax.tree.leaves(ends), jax.tree.leaves(out), strict=True):
            end[rows[done]] = np.asarray(x)[done]
        at, live = rows[np.asarray(row)], np.asarray(live)
    chunks = []
    for first in range(0, n, 2 * lanes):
        rows = np.minimum(np.arange(first, first + 2 * lanes), n - 1)
        chunks.append(_summaries(problem, data[rows], weights[rows], _rows(ends, rows)))
    return jax.tree.map(lambda *a: np.concatenate([np.asarray(x) for x in a])[:n], *chunks)


@plain_errors
def fit(
    model: Callable,
    params,
    names,
    data,
    *,
    args=None,
    weights=None,
    bounds=None,
    nll: Callable | None = None,
    solver=None,
    jac: str = "fwd",
    absolute_sigma: bool = False,
    max_steps: int = MAX_STEPS,
):
    """Fit the fields ``names`` of ``params`` to ``data``, one fit per dataset.

    Parameters
    ----------
    model : callable
        ``model(params, args) -> prediction``, pure and differentiable, with
        ``prediction`` an array of the shape of one dataset. Pass a
        module-level function and put the stimulus in ``args``: a new
        closure each call compiles the fit again.
    params : equinox.Module
        The parameter module (e.g. ``pattanaik2000.Params()``): the fixed
        values of the other fields and the start of the fitted ones.
    names : str or sequence of str
        Fields to fit. Each must be a numeric (array) field of ``params``.
    data : array, shape (..., *prediction.shape)
        Measurements; leading axes are a batch of datasets fitted at once
        (more than :data:`LANES` of them through a queue of solver lanes,
        see "Batches" in the module notes). NaN or infinite values are left
        out (a warning says how many). The fit computes in the model's
        floating dtype, to which the data are cast.
    args : pytree, optional
        Passed to ``model`` unchanged (shared by all datasets; to vary it per
        dataset, ``jax.vmap`` this function over it).
    weights : array, optional
        Broadcast against ``data``: ``1/sd^2`` of each measurement (least
        squares) or the multiplicity of its ``nll`` (e.g. the number of
        trials); 0 leaves a measurement out. Default 1.
    bounds : dict, optional
        ``name -> (low, high)`` (infinite ends allowed) or ``None`` for an
        unbounded field; fields not given are positive. See the module notes.
    nll : callable, optional
        Elementwise negative log-likelihood ``nll(prediction, data)``: fit
        by maximum likelihood (BFGS). Default: least squares.
    solver : optimistix solver, optional
        Default :class:`LevenbergMarquardt` (least squares; ``rtol = atol =
        sqrt(eps)`` of the data's dtype and ``ftol = max(1e-8, 10 eps)``,
        MINPACK's default in float64) or ``optimistix.BFGS`` (likelihood,
        ``rtol = atol = sqrt(eps)``).
    jac : {"fwd", "bwd"}
        Mode of the Jacobian (and Hessian): ``"bwd"`` for models that only
        support reverse mode, such as the diffrax path.
    absolute_sigma : bool
        Least squares: take ``weights`` as known ``1/sd^2`` (covariance
        ``(J' W J)^-1``) instead of scaling by the residual variance.
    max_steps : int
        Iteration cap (at least 1); ``converged`` is False where it is reached.

    Returns
    -------
    Fit
        Estimates, standard errors, covariance, residuals and flags, with the
        batch shape of ``data`` in front.

    Raises
    ------
    ValueError
        A name that is not a numeric field (the message lists the valid
        ones), bounds that do not contain the start, data whose trailing
        shape is not the model's output shape, weights that do not
        broadcast or are negative or not finite, an unknown ``jac``, data
        beyond the range of the model's dtype.
    NotImplementedError
        ``jac="fwd"`` for a model without forward-mode derivatives (one
        through diffrax): fit it with ``jac="bwd"``.

    Examples
    --------
    Recover the cone time constant from the adaptation after a step:

    >>> from jaxadapt.operators import pattanaik2000 as op
    >>> frames = jnp.ones((20, 1, 1, 3)).at[10:].set(100.0)  # 1 -> 100 cd/m2
    >>> def model(params, frames):
    ...     return jnp.log10(op.run(params, frames, 0.02)[1].state.A_cone)
    >>> data = model(op.Params(t0_cone=0.05), frames)
    >>> f = fit(model, op.Params(), "t0_cone", data, args=frames)
    >>> round(float(f.estimate["t0_cone"]), 4), bool(f.converged)
    (0.05, True)
    """
    spec = _spec(params, names, bounds)
    if int(max_steps) < 1:
        raise ValueError(f"max_steps: expected at least 1, got {max_steps}")
    if jac not in ("fwd", "bwd"):
        raise ValueError(f"jac: expected 'fwd' or 'bwd', got {jac!r}")
    if nll is not None and not callable(nll):
        raise ValueError(
            f"nll: expected a function nll(prediction, data) giving the negative "
            f"log-likelihood of each measurement, or None for least squares, got {nll!r}"
        )
    out = _output_struct(model, params, args)
    if not isinstance(out, jax.ShapeDtypeStruct):
        raise ValueError(
            f"model: expected a function returning one array, got {type(out).__name__}"
        )
    # In the precision the model computes in: float32 data of a float64
    # model are fitted in float64, and float64 data of a float32 model (a
    # float32 operator's thresholds against NumPy's measurements) in float32,
    # which is all the model resolves (in float64 its float32 prediction had
    # float64 derivatives, which JAX refused).
    given = jnp.asarray(data)
    data = given.astype(jnp.result_type(out.dtype, float))
    event = out.shape
    if data.ndim < len(event) or data.shape[data.ndim - len(event) :] != event:
        raise ValueError(
            f"data: expected shape (..., {', '.join(map(str, event))}) ending in the "
            f"model's output shape {event}, got shape {data.shape}"
        )
    weights = jnp.ones((), data.dtype) if weights is None else jnp.asarray(weights, data.dtype)
    try:
        weights = jnp.broadcast_to(weights, data.shape)
    except ValueError:
        raise ValueError(
            f"weights: expected a shape that broadcasts to data's {data.shape}, got {weights.shape}"
        ) from None
    traced = _under_transformation(data, weights, params, args)
    if not traced:
        w = np.asarray(weights)
        if not np.all(np.isfinite(w) & (w >= 0)):
            raise ValueError(WEIGHTS_MESSAGE)
        finite = np.isfinite(np.asarray(data))
        beyond = int(np.sum(np.isfinite(np.asarray(given)) & ~finite))
        if beyond:  # else said as measurements "not finite" that were
            raise ValueError(
                f"data: {beyond} measurements lie beyond the range of {data.dtype}, the "
                "model's precision"
            )
        missing = int(np.sum(~finite))
        if missing:
            warnings.warn(
                f"data: {missing} of {data.size} measurements are not finite and were left "
                "out of the fit (see Fit.n_masked and Fit.mask)",
                stacklevel=2,
            )
    if solver is None:
        eps = float(np.finfo(data.dtype).eps)
        tol = float(np.sqrt(eps))
        if nll is None:
            solver = LevenbergMarquardt(tol, tol, ftol=max(1e-8, 10 * eps))
        else:
            solver = optx.BFGS(tol, tol)
    problem = _Problem(
        model,
        params,
        args,
        spec,
        nll,
        solver,
        jac,
        jnp.asarray(bool(absolute_sigma)),  # traced: one compilation for both
        int(max_steps),
        data.dtype,
    )
    batch = data.shape[: data.ndim - len(event)]
    data = data.reshape((-1,) + event)
    weights = weights.reshape((-1,) + event)
    try:
        if traced or data.shape[0] <= LANES:
            fits = _fit(problem, data, weights)
        else:
            fits = _queue(problem, data, weights, LANES)
    except NotImplementedError as e:  # JAX's own says "Differentiation rule for 'custom_lin'"
        if jac != "fwd":
            raise
        raise NotImplementedError(
            f"model: no forward-mode derivative ({e}); fit a model that supports reverse "
            "mode only, such as one through diffrax, with jac='bwd'"
        ) from e
    return jax.tree.map(lambda a: jnp.asarray(a.reshape(batch + a.shape[1:])), fits)


_OUTPUT_STRUCTS = {}


def _output_struct(model, params, args):
    """``eqx.filter_eval_shape(model, params, args)``, remembered for the same
    model, structure, shapes and dtypes: tracing the model costs tens of
    milliseconds, a tenth of a fit of 1,000 datasets."""
    leaves, structure = jax.tree.flatten((params, args))
    key = (model, structure, *((x.shape, x.dtype) if eqx.is_array(x) else x for x in leaves))
    try:
        out = _OUTPUT_STRUCTS.get(key)
    except TypeError:  # an unhashable leaf: no memory
        return eqx.filter_eval_shape(model, params, args)
    if out is None:
        out = eqx.filter_eval_shape(model, params, args)
        if len(_OUTPUT_STRUCTS) > 64:
            _OUTPUT_STRUCTS.clear()
        _OUTPUT_STRUCTS[key] = out
    return out


def _under_transformation(*trees):
    """Whether :func:`fit` is called under a JAX transformation: an input is
    traced (``vmap``, ``grad``, ``jit``), or arrays made here are (``jit``)."""
    leaves = jax.tree.leaves(trees) + [jnp.zeros(()) + 0]
    return any(isinstance(leaf, jax.core.Tracer) for leaf in leaves)
