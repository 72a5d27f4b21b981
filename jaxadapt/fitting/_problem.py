"""One fit's problem: the objective the solver works on, and the :class:`Fit`
of a dataset from the solver's end (estimates, standard errors, flags).

Objectives
----------
*Least squares* (the default, ``nll=None``): minimise ``1/2 sum w (f - y)^2``
over the measurements ``y`` with weights ``w`` (``1/sd^2``), with
:class:`~jaxadapt.fitting.LevenbergMarquardt` (or any optimistix
least-squares solver passed as ``solver``, e.g. ``optimistix.GaussNewton``).
The residuals are handed to the solver with their Jacobian computed in one
pass per step, so that a step costs one Jacobian of the model and not a
model replay per product with it: forward mode (the default) linearises
the model once and pushes each fitted field's tangent through the
linearisation alone (:meth:`_Problem.jacobian`), ``jac="bwd"`` takes
``jax.jacrev``.

*Maximum likelihood* (``nll`` given): minimise ``sum w nll(f, y)``, with
``nll`` the negative log-likelihood of one measurement given its prediction,
elementwise (e.g. ``-(y log f + (1 - y) log(1 - f))`` for a proportion ``y``
of ``w`` binomial trials), by optimistix's BFGS on the mean per unit weight.

:func:`~jaxadapt.fitting.fit` is not itself differentiable with respect to
``data``, ``args`` or the fixed fields of ``params``: the residuals' custom
derivative treats everything but the fitted values as constants (JAX then
fails with "No constant handler for type: ...Tracer"). The sensitivity of
a least-squares estimate to the data follows from the minimum's condition
``J' W (f - y) = 0``: ``d theta / d y = (J' W J)^-1 J' W`` (Gauss-Newton).

Uncertainty
-----------
Standard errors come from the information matrix of ``u`` (the free values,
:mod:`~jaxadapt.fitting._bounds`) at the estimate: the Gauss-Newton ``J' W
J`` for least squares (scaled by the residual variance ``2 loss / (m - k)``
unless ``absolute_sigma``, as SciPy's ``curve_fit`` does; ``J`` and the
returned prediction are the solver's last Jacobian and model evaluation
where optimistix's Gauss-Newton family keeps them, computed otherwise), the
Hessian of the negative log-likelihood otherwise; then the delta method
back to natural units, ``cov_p = D cov_u D`` with ``D`` the derivative of
the map. ``cov`` is over the fitted elements in the order of ``names``
(each field raveled).

The information matrix is inverted on its unit-diagonal scaling
(:func:`_information_inverse`). A parameter is *not identified* when its
sensitivity (the square root of its diagonal) is below ``eps`` of the
largest one, or when it has weight in a direction whose singular value
(least squares) or eigenvalue (likelihood) is below ``sqrt(eps)`` of the
largest (a combination of parameters the data do not pin down, e.g. two
that only enter as a product). Its standard error is then ``inf``, its
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
:data:`NEWTON_STEP`: the estimate is within a tenth of a standard error of
the minimum the linearisation there points to. A likelihood whose maximum
lies at infinity (responses all the same, or perfectly separated, in a
psychometric model) can be flat to rounding at the point the solver
reaches, with a short Newton step: there only the standard errors' size
tells (:mod:`jaxadapt.psychophysics.psychometric` flags such data).

Nocedal and Wright (2006), *Numerical Optimization*, ch. 6 (BFGS) and 10
(least squares); Bates and Watts (1988), *Nonlinear Regression Analysis*,
§2.3 (Gauss-Newton standard errors).
"""

from collections import OrderedDict
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jax.flatten_util import ravel_pytree

from jaxadapt.fitting._bounds import _derivative, _replace, _to_free, _to_natural
from jaxadapt.fitting._result import Fit
from jaxadapt.fitting._solver import _felt

#: Largest full (Gauss-)Newton step from the estimate, in standard errors,
#: of a fit called converged (``Fit.newton_step``).
NEWTON_STEP = 0.1
#: A Jacobian column (weighted) shorter than this many roundings of the
#: weighted prediction, ``ROUNDINGS eps |f|``, is rounding and is set to 0
#: (:meth:`_Problem.linearised`).
ROUNDINGS = 64


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
    ``1 - sqrt(eps)/2``: in float32, a straight line fitted over x from 500
    to 510 (intercept and slope correlated at -0.99998) keeps its standard
    errors.

    Returns ``(cov, identified)``, ``cov`` finite with 0 in the rows and
    columns of parameters not identified (see "Uncertainty" above).
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
        (:class:`~jaxadapt.fitting.LevenbergMarquardt`), which compares the residuals' change
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
        tangents pushed through every operation at once (``jax.jacfwd``).
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
        where ``A = G`` throughout), which would
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
