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

=====================  ==============================  =====================
bounds                 parameter                       start ``u``
=====================  ==============================  =====================
``(0, inf)`` (default)  ``exp(u)``                      ``log(p)``
``(low, inf)``          ``low + exp(u)``                ``log(p - low)``
``(-inf, high)``        ``high - exp(u)``               ``log(high - p)``
``(low, high)``         ``low + (high - low) s(u)``     ``logit((p - low) / (high - low))``
``None``                ``u``                           ``p``
=====================  ==============================  =====================

with ``s`` the logistic sigmoid. Every field is positive unless ``bounds``
says otherwise (time constants, bleaching constants and semi-saturations
are). Working in ``log p`` also puts parameters of very different scales
(``t0 = 0.08`` s, ``tau = 400`` s) on one footing for the optimiser.

Objectives
----------
*Least squares* (the default, ``nll=None``): minimise ``1/2 sum w (f - y)^2``
over the measurements ``y`` with weights ``w`` (``1/sd^2``), with
:class:`LevenbergMarquardt` (optimistix's, which also stops by MINPACK's
``ftol`` test; or any optimistix least-squares solver passed as ``solver``,
e.g. ``optimistix.GaussNewton``). The residuals are handed to the solver
with their Jacobian computed in one pass per step (``jax.jacfwd``, all ``k``
tangents at once, or ``jax.jacrev`` with ``jac="bwd"``), so that a step
costs one Jacobian of the model and not a model replay per product with it.

*Maximum likelihood* (``nll`` given): minimise ``sum w nll(f, y)``, with
``nll`` the negative log-likelihood of one measurement given its prediction,
elementwise (e.g. ``-(y log f + (1 - y) log(1 - f))`` for a proportion ``y``
of ``w`` binomial trials), by optimistix's BFGS on the mean per unit weight.

Under ``vmap`` the solver's loop runs until the slowest fit of the batch has
stopped; the others are frozen meanwhile (their results equal those of
separate fits). :func:`fit` is not itself differentiable with respect to
``data`` (the residuals' custom derivative treats the data as constants).

Uncertainty
-----------
Standard errors come from the information matrix of ``u`` at the estimate:
the Gauss-Newton ``J' W J`` for least squares (scaled by the residual
variance ``2 loss / (m - k)`` unless ``absolute_sigma``, as SciPy's
``curve_fit`` does), the Hessian of the negative log-likelihood otherwise;
then the delta method back to natural units, ``cov_p = D cov_u D`` with ``D``
the derivative of the map above. ``cov`` is over the fitted elements in the
order of ``names`` (each field raveled).

The information matrix is inverted through the eigen-decomposition of its
unit-diagonal scaling. A parameter is *not identified* when its sensitivity
(the square root of its diagonal) is below ``sqrt(eps)`` of the largest one,
or when it has weight in a direction whose eigenvalue is below ``sqrt(eps)``
of the largest (a combination of parameters the data do not pin down, e.g.
two that only enter as a product). Its standard error is then ``inf``, its
off-diagonal covariances 0, and ``converged`` is False; every other number
stays finite. No output is NaN.

Data
----
``data`` has the model's output shape, with any leading axes a batch of
datasets fitted at once (one ``vmap``: one fit per participant, per
condition). Measurements that are not finite (NaN, inf) or have weight 0 are
left out; a warning says how many, and each fit reports ``n_masked``.

References
----------
Moré (1978), *The Levenberg-Marquardt algorithm: implementation and theory*;
Nocedal and Wright (2006), *Numerical Optimization*, ch. 6 (BFGS) and 10
(least squares); Bates and Watts (1988), *Nonlinear Regression Analysis*,
§2.3 (Gauss-Newton standard errors).
"""

import dataclasses
import math
import warnings
from collections.abc import Callable
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree

#: Default bounds of a fitted field: positive.
POSITIVE = (0.0, math.inf)
#: Default iteration cap of the optimiser.
MAX_STEPS = 256


class Fit(eqx.Module):
    """Result of :func:`fit`; every array has the datasets' batch shape in front.

    Attributes
    ----------
    params : Params
        The parameter module at the estimate (fitted fields replaced, the
        others as given; under a batch every field gains the batch axes).
    estimate : dict
        Fitted values by name, in natural units.
    se : dict
        Standard errors by name (delta method, natural units); ``inf`` for a
        parameter the data do not identify.
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
    converged : array of bool
        The solver met its tolerance within ``max_steps`` and every
        parameter is identified (finite standard error).
    solved : array of bool
        The solver met its tolerance, identified or not.
    steps : array of int
        Iterations the solver took.
    names : tuple of str
        The fitted fields (static).
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
    converged: jax.Array
    solved: jax.Array
    steps: jax.Array
    names: tuple = eqx.field(static=True)

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


class LevenbergMarquardt(optx.AbstractGaussNewton):
    """``optimistix.LevenbergMarquardt`` that also stops by MINPACK's ``ftol`` test.

    optimistix stops when both the parameters and the residuals change by
    less than ``atol + rtol |.|``. With noisy data that can take hundreds of
    steps when a parameter is weakly determined or the Gauss-Newton step
    overshoots (the solver then creeps or oscillates by steps far below the
    standard errors), and
    under ``vmap`` every fit of the batch waits for the slowest. This solver
    also stops after an accepted step whose actual and predicted relative
    reductions of the sum of squares are both at most ``ftol`` (Moré 1978,
    MINPACK's ``lmder``; SciPy's ``least_squares(method="lm")``): with
    ``m - k`` residual degrees of freedom, such a step moves the parameters
    by at most about ``sqrt(ftol (m - k))`` standard errors.

    Parameters
    ----------
    rtol, atol : float
        Tolerances of optimistix's test.
    ftol : float
        Relative reduction of the sum of squares (``0`` disables the test).
    descent, search, norm, verbose
        As in ``optimistix.LevenbergMarquardt`` (damped Newton step by QR,
        classical trust region, max norm, silent).
    """

    rtol: float
    atol: float
    ftol: float
    norm: Callable = optx.max_norm
    descent: optx.DampedNewtonDescent = optx.DampedNewtonDescent(linear_solver=lx.QR())
    search: optx.ClassicalTrustRegion = optx.ClassicalTrustRegion()
    verbose: Callable = _quiet

    def step(self, fn, y, args, options, state, tags):
        new_y, new_state, aux = super().step(fn, y, args, options, state, tags)
        before = _sum_squares(state.f_info.residual)
        after = _sum_squares(new_state.f_info.residual)
        step = jax.tree.map(lambda a, b: a - b, new_y, y)
        linear = jax.tree.map(jnp.add, state.f_info.residual, state.f_info.jac.mv(step))
        scale = jnp.where(before > 0, before, 1.0)
        actual = (before - after) / scale
        predicted = (before - _sum_squares(linear)) / scale
        accepted = new_state.num_accepted_steps > state.num_accepted_steps
        small = (
            accepted
            & ~state.first_step
            & (before > 0)
            & (actual <= self.ftol)
            & (predicted <= self.ftol)
        )
        new_state = eqx.tree_at(lambda s: s.terminate, new_state, new_state.terminate | small)
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


def _spec(params, names, bounds):
    """Validate ``names`` and ``bounds``; return the static spec."""
    valid = _numeric_fields(params)
    names = (names,) if isinstance(names, str) else tuple(names)
    if not names:
        raise ValueError(f"names: expected at least one of {valid}, got none")
    unknown = [n for n in names if n not in valid]
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
        low, high = (-math.inf, math.inf) if b is None else (float(b[0]), float(b[1]))
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


def _information_inverse(info):
    """Covariance from an information matrix, and which parameters it identifies.

    ``info`` is scaled to a unit diagonal, ``C = info / (d d')``, and inverted
    on its eigenvectors whose eigenvalue exceeds ``sqrt(eps)`` of the largest.
    Returns ``(cov, identified)``, ``cov`` finite with 0 in the rows and
    columns of parameters not identified (see the module notes).
    """
    eps = jnp.finfo(info.dtype).eps
    finite = jnp.all(jnp.isfinite(info))
    info = jnp.where(finite, 0.5 * (info + info.T), 0.0)
    d = jnp.sqrt(jnp.maximum(jnp.diagonal(info), 0.0))
    sensitive = d > jnp.sqrt(eps) * jnp.max(d)
    d_safe = jnp.where(sensitive, d, 1.0)
    C = jnp.where(sensitive[:, None] & sensitive[None, :], info / (d_safe[:, None] * d_safe), 0.0)
    lam, V = jnp.linalg.eigh(C)
    keep = lam > jnp.sqrt(eps) * jnp.maximum(jnp.max(lam), jnp.finfo(info.dtype).tiny)
    inv = jnp.where(keep, 1.0 / jnp.where(keep, lam, 1.0), 0.0)
    null_weight = jnp.sum(jnp.where(keep, 0.0, V**2), axis=1)
    identified = sensitive & (null_weight < jnp.sqrt(eps)) & finite
    cov = (V * inv) @ V.T / (d_safe[:, None] * d_safe)
    return jnp.where(identified[:, None] & identified[None, :], cov, 0.0), identified


def _fit_one(data, weights, model, params, args, spec, nll, solver, jac, absolute_sigma, steps):
    dtype = data.dtype
    mask = jnp.isfinite(data) & (weights > 0)
    w = jnp.where(mask, weights, 0.0).astype(dtype)
    y = jnp.where(mask, data, 0.0)
    root_w = jnp.sqrt(w)
    # The free values u, one vector in the order of ``names`` (raveled), so
    # that ``cov`` follows that order.
    u0, unravel = ravel_pytree(
        tuple(_to_free(jnp.asarray(getattr(params, f.name), dtype), f) for f in spec)
    )
    k = u0.size

    def natural(u):
        return {f.name: _to_natural(v, f) for v, f in zip(unravel(u), spec, strict=True)}

    def predict(u):
        return model(_replace(params, spec, natural(u)), args)

    def weighted(u):
        """Weighted residuals (raveled, 0 where masked), and the prediction."""
        f = predict(u)
        return jnp.where(mask, (f - y) * root_w, 0.0).ravel(), f

    def linearised(u):
        """``(J, r, f)``: the Jacobian of the weighted residuals (forward or
        reverse mode, as ``jac`` says), the residuals, the prediction."""
        jacobian = jax.jacfwd if jac == "fwd" else jax.jacrev
        J, (r, f) = jacobian(lambda u: (lambda rf: (rf[0], rf))(weighted(u)), has_aux=True)(u)
        return J, r, f

    def total_nll(u, _):
        f = predict(u)
        terms = nll(f, jnp.where(mask, data, jax.lax.stop_gradient(f)))
        return jnp.sum(jnp.where(mask, w * terms, 0.0))

    m = jnp.sum(mask)
    if nll is None:
        # Residuals whose derivative is the Jacobian computed in one pass
        # (jacfwd: the k tangents at once; or jacrev), so that the solver's
        # linearisation keeps a k-column matrix instead of replaying the model
        # for every product with it (materialising, trust-region predictions).
        @jax.custom_jvp
        def residuals(u):
            return weighted(u)[0]

        @residuals.defjvp
        def residuals_jvp(primals, tangents):
            J, r, _ = linearised(primals[0])
            return r, J @ tangents[0]

        sol = optx.least_squares(
            lambda u, _: residuals(u), solver, u0, max_steps=steps, throw=False
        )
        u = sol.value
        J, r, prediction = linearised(u)
        loss = 0.5 * jnp.sum(r**2)
        info = J.T @ J
        dof = m - k
        variance = jnp.where(dof > 0, 2.0 * loss / jnp.where(dof > 0, dof, 1), jnp.inf)
        scale = jnp.where(absolute_sigma, 1.0, variance)
    else:
        total_w = jnp.maximum(jnp.sum(w), jnp.finfo(dtype).tiny)
        sol = optx.minimise(
            lambda u, a: total_nll(u, a) / total_w, solver, u0, max_steps=steps, throw=False
        )
        u = sol.value
        hessian = jax.hessian if jac == "fwd" else lambda f: jax.jacrev(jax.grad(f))
        info = hessian(lambda u: total_nll(u, None))(u)
        loss = total_nll(u, None)
        prediction = predict(u)
        scale = 1.0
    cov_u, identified = _information_inverse(info)
    D, _ = ravel_pytree(tuple(_derivative(v, f) for v, f in zip(unravel(u), spec, strict=True)))
    ok = identified & jnp.isfinite(scale) & jnp.all(jnp.isfinite(D))
    cov = jnp.where(ok[:, None] & ok[None, :], D[:, None] * cov_u * D * scale, 0.0)
    cov = jnp.where(jnp.eye(k, dtype=bool) & ~ok[:, None], jnp.inf, cov)
    se = jnp.where(ok, jnp.sqrt(jnp.where(ok, jnp.diagonal(cov), 0.0)), jnp.inf)
    estimate = natural(u)
    solved = sol.result == optx.RESULTS.successful
    finite = jnp.all(jnp.isfinite(u)) & jnp.isfinite(loss)
    return Fit(
        params=_replace(params, spec, estimate),
        estimate=estimate,
        se=dict(zip(estimate, unravel(se.astype(dtype)), strict=True)),
        cov=cov.astype(dtype),
        prediction=prediction,
        residuals=jnp.where(mask, prediction - y, 0.0),
        mask=mask,
        n_masked=jnp.sum(~mask).astype(jnp.int32),
        loss=loss,
        converged=solved & jnp.all(ok) & finite,
        solved=solved,
        steps=jnp.asarray(sol.stats["num_steps"], jnp.int32),
        names=tuple(f.name for f in spec),
    )


@eqx.filter_jit
def _fit(data, weights, model, params, args, spec, nll, solver, jac, absolute_sigma, steps, ndim):
    batch = data.shape[: data.ndim - ndim]
    event = data.shape[data.ndim - ndim :]
    flat_data = data.reshape((-1,) + event)
    flat_w = weights.reshape((-1,) + event)
    bad = jnp.any(weights < 0) | jnp.any(jnp.isnan(weights))
    flat_w = eqx.error_if(flat_w, bad, "weights: expected non-negative weights (1/sd^2)")

    def one(d, w):
        return _fit_one(d, w, model, params, args, spec, nll, solver, jac, absolute_sigma, steps)

    out = jax.vmap(one)(flat_data, flat_w)
    return jax.tree.map(lambda a: a.reshape(batch + a.shape[1:]), out)


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
        Measurements; leading axes are a batch of datasets fitted at once.
        NaN or infinite values are left out (a warning says how many).
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
        Iteration cap; ``converged`` is False where it is reached.

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
        broadcast, an unknown ``jac``.

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
    if jac not in ("fwd", "bwd"):
        raise ValueError(f"jac: expected 'fwd' or 'bwd', got {jac!r}")
    out = eqx.filter_eval_shape(model, params, args)
    if not isinstance(out, jax.ShapeDtypeStruct):
        raise ValueError(
            f"model: expected a function returning one array, got {type(out).__name__}"
        )
    data = jnp.asarray(data)
    data = data.astype(jnp.result_type(data.dtype, float))
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
    if not isinstance(data, jax.core.Tracer):
        missing = int(np.sum(~np.isfinite(np.asarray(data))))
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
    return _fit(
        data,
        weights,
        model,
        params,
        args,
        spec,
        nll,
        solver,
        jac,
        jnp.asarray(bool(absolute_sigma)),  # traced: one compilation for both
        int(max_steps),
        len(event),
    )
