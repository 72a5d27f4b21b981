"""The entry point :func:`fit`: its checks of the arguments, and the choice
between one vmapped solve and the queue of solver lanes."""

import warnings
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from jaxadapt.fitting._bounds import _spec
from jaxadapt.fitting._problem import _Problem, _solver_linearisation
from jaxadapt.fitting._queue import _queue
from jaxadapt.fitting._solver import LevenbergMarquardt
from jaxadapt.operators.checks import plain_errors

#: What a weight must be, said for bad ones on the host and under ``jit``.
WEIGHTS_MESSAGE = (
    "weights: expected finite, non-negative weights (1/sd^2; 0 leaves a measurement out)"
)
#: Default iteration cap of the optimiser.
MAX_STEPS = 256
#: Solver lanes of a batch: a batch of at most this many datasets is fitted
#: in one vmapped solve, a larger one through a queue of this many lanes
#: (:mod:`~jaxadapt.fitting._queue`). Wider vmaps of the model leave the
#: cache, narrower ones pay XLA's fixed cost per operation more often, and
#: the last fits of a queue leave lanes idle; 64 balances these on a CPU.
LANES = 64


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
        each result that of its own uninterrupted solve). NaN or infinite
        values are left out (a warning says how many), and so are those of
        weight 0, silently; each fit reports both in ``n_masked``. The fit
        computes in the model's floating dtype, to which the data are cast.
    args : pytree, optional
        Passed to ``model`` unchanged (shared by all datasets; to vary it per
        dataset, ``jax.vmap`` this function over it).
    weights : array, optional
        Broadcast against ``data``: ``1/sd^2`` of each measurement (least
        squares) or the multiplicity of its ``nll`` (e.g. the number of
        trials); 0 leaves a measurement out. Default 1.
    bounds : dict, optional
        ``name -> (low, high)`` (infinite ends allowed) or ``None`` for an
        unbounded field; fields not given are positive. Each field is
        fitted through the map of its bounds (see the notes).
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

    Notes
    -----
    The optimiser works on unconstrained values ``u``, one per element of
    each fitted field, mapped to the parameter by its bounds ``(low, high)``:

    | bounds | parameter | start ``u`` |
    | --- | --- | --- |
    | ``(0, inf)`` (default) | ``exp(u)`` | ``log(p)`` |
    | ``(low, inf)`` | ``low + exp(u)`` | ``log(p - low)`` |
    | ``(-inf, high)`` | ``high - exp(u)`` | ``log(high - p)`` |
    | ``(low, high)`` | ``low + (high - low) s(u)`` | ``logit((p - low) / (high - low))`` |
    | ``None`` | ``u`` | ``p`` |

    with ``s`` the logistic sigmoid. Standard errors are those of ``u``
    mapped back by the delta method; :meth:`Fit.interval` maps ``u``'s
    interval through the table instead.

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
    _check_options(max_steps, jac, nll)
    out = _output_struct(model, params, args)
    if not isinstance(out, jax.ShapeDtypeStruct):
        raise ValueError(
            f"model: expected a function returning one array, got {type(out).__name__}"
        )
    given = jnp.asarray(data)
    data = _in_model_precision(given, out)
    weights = _broadcast_weights(weights, data)
    traced = _under_transformation(data, weights, params, args)
    if not traced:
        _check_on_host(given, data, weights)
    problem = _Problem(
        model,
        params,
        args,
        spec,
        nll,
        _default_solver(data.dtype, nll) if solver is None else solver,
        jac,
        jnp.asarray(bool(absolute_sigma)),  # traced: one compilation for both
        int(max_steps),
        data.dtype,
    )
    event = out.shape
    batch = data.shape[: data.ndim - len(event)]
    data = data.reshape((-1,) + event)
    weights = weights.reshape((-1,) + event)
    fits = _solve(problem, data, weights, traced)
    return jax.tree.map(lambda a: jnp.asarray(a.reshape(batch + a.shape[1:])), fits)


def _check_options(max_steps, jac, nll):
    """Raise on a ``max_steps``, ``jac`` or ``nll`` that :func:`fit` cannot take."""
    if int(max_steps) < 1:
        raise ValueError(f"max_steps: expected at least 1, got {max_steps}")
    if jac not in ("fwd", "bwd"):
        raise ValueError(f"jac: expected 'fwd' or 'bwd', got {jac!r}")
    if nll is not None and not callable(nll):
        raise ValueError(
            f"nll: expected a function nll(prediction, data) giving the negative "
            f"log-likelihood of each measurement, or None for least squares, got {nll!r}"
        )


def _in_model_precision(given, out):
    """The data ``given`` in the floating dtype of the model's output ``out``
    (a ``jax.ShapeDtypeStruct``), checked to end in its shape.

    Float32 data of a float64 model are fitted in float64, and float64 data
    of a float32 model (a float32 operator's thresholds against NumPy's
    measurements) in float32, which is all the model resolves (and a
    float32 prediction cannot take float64 derivatives).
    """
    data = given.astype(jnp.result_type(out.dtype, float))
    event = out.shape
    if data.ndim < len(event) or data.shape[data.ndim - len(event) :] != event:
        raise ValueError(
            f"data: expected shape (..., {', '.join(map(str, event))}) ending in the "
            f"model's output shape {event}, got shape {data.shape}"
        )
    return data


def _broadcast_weights(weights, data):
    """``weights`` (default 1) in the dtype of ``data``, broadcast to its shape."""
    weights = jnp.ones((), data.dtype) if weights is None else jnp.asarray(weights, data.dtype)
    try:
        return jnp.broadcast_to(weights, data.shape)
    except ValueError:
        raise ValueError(
            f"weights: expected a shape that broadcasts to data's {data.shape}, got {weights.shape}"
        ) from None


def _check_on_host(given, data, weights):
    """Raise on bad weights or on data beyond the model's dtype, and warn of
    measurements that are not finite (outside a JAX transformation, where
    the values are known)."""
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
            stacklevel=3,  # the caller of fit, through plain_errors
        )


def _default_solver(dtype, nll):
    """:class:`LevenbergMarquardt` for least squares, ``optimistix.BFGS`` for a
    likelihood, with tolerances for ``dtype``."""
    eps = float(np.finfo(dtype).eps)
    tol = float(np.sqrt(eps))
    if nll is None:
        return LevenbergMarquardt(tol, tol, ftol=max(1e-8, 10 * eps))
    return optx.BFGS(tol, tol)


def _solve(problem, data, weights, traced):
    """The :class:`Fit` of every dataset (leading axis): one vmapped solve
    for at most :data:`LANES` of them or under a JAX transformation, a
    queue of :data:`LANES` lanes otherwise."""
    try:
        if traced or data.shape[0] <= LANES:
            return _vmapped(problem, data, weights)
        return _queue(problem, data, weights, LANES)
    except NotImplementedError as e:  # JAX's own says "Differentiation rule for 'custom_lin'"
        if problem.jac != "fwd":
            raise
        raise NotImplementedError(
            f"model: no forward-mode derivative ({e}); fit a model that supports reverse "
            "mode only, such as one through diffrax, with jac='bwd'"
        ) from e


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
def _vmapped(problem, data, weights):
    """Every dataset (leading axis) at once: one vmapped solve."""
    bad = ~jnp.all(jnp.isfinite(weights) & (weights >= 0))
    weights = eqx.error_if(weights, bad, WEIGHTS_MESSAGE)
    return jax.vmap(lambda d, w: _fit_one(problem, d, w))(data, weights)


_OUTPUT_STRUCTS = {}


def _output_struct(model, params, args):
    """``eqx.filter_eval_shape(model, params, args)``, remembered for the same
    model, structure, shapes and dtypes: tracing the model anew at every
    call would cost a large part of a fit's time."""
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
