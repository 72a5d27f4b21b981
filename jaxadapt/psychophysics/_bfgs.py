"""BFGS for the psychometric likelihood: robust in a batch where nobody
looks at the individual fits.

Internal to :mod:`jaxadapt.psychophysics.psychometric` (the module notes
there say why each piece is needed).
"""

from collections.abc import Callable

import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx

from jaxadapt.psychophysics._likelihood import _objective, _start


class _Backtracking(optx.AbstractSearch):
    """Backtracking Armijo line search that also accepts a step whose
    predicted decrease is below the rounding error of ``f``.

    ``optimistix.BacktrackingArmijo`` halves the step until ``f`` decreases by
    a tenth of the predicted amount. Within about ``sqrt(eps)`` of the minimum
    the decrease of ``f`` is lost in rounding, that test fails for every step
    size, and the solver loops to ``max_steps`` (and, under ``vmap``, makes
    the whole batch do so). The gradient is still accurate there, so such a
    step is a sound quasi-Newton step: accepting it lets BFGS converge to
    machine precision in the parameters.
    """

    def init(self, y, f_info_struct):
        return jnp.ones((), y.dtype)

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        predicted = f_info.compute_grad_dot(y_eval - y)
        decrease = f_eval_info.f - f_info.f
        descent = predicted <= 0
        armijo = (decrease <= 0.1 * predicted) & descent
        negligible = descent & (-predicted <= jnp.finfo(y.dtype).eps * jnp.abs(f_info.f))
        accept = first_step | ((armijo | negligible) & jnp.isfinite(f_eval_info.f))
        step_size = jnp.where(accept, 1.0, 0.5 * state).astype(y.dtype)
        return step_size, accept, optx.RESULTS.successful, step_size


def _quiet(**kwargs):
    del kwargs


class _BFGS(optx.AbstractBFGS):
    """``optimistix.BFGS`` with the :class:`_Backtracking` search, started
    from a given inverse Hessian instead of the identity, kept positive
    definite, and also stopped by the Newton decrement.

    optimistix updates the inverse Hessian whenever ``y' s`` exceeds ``eps``
    in absolute terms; in float32 the update of a short step can then lose
    positive definiteness to rounding (a fitted lapse rate's flat valley),
    after which the decrement below can be negative and the solver stop
    short of the optimum while reporting convergence.
    An update that is not positive definite (its Cholesky factor not
    finite) is not made: the estimate stays the last positive-definite one.

    The objective is the negative log-likelihood per trial; the solver also
    stops when ``trials * g' H^-1 g``, twice the gain in log-likelihood that
    a full quasi-Newton step predicts, is at most ``decrement_tol`` (Boyd and
    Vandenberghe 2004, §9.5.1). With fitted rates the likelihood can have a
    flat valley (the slope traded against a lapse rate) along which BFGS
    creeps by steps far below the standard errors yet above the parameter
    tolerance; this rule stops it there. BFGS's estimate of ``H^-1`` can be
    poor along such a valley, so :func:`_fit_one` checks the stop with the
    exact Hessian. The probit likelihood alone is strictly convex and uses
    ``decrement_tol = 0``.
    """

    rtol: float
    atol: float
    hessian_inv: jax.Array
    trials: jax.Array
    decrement_tol: float
    norm: Callable = optx.max_norm
    use_inverse: bool = True
    descent: optx.NewtonDescent = optx.NewtonDescent()
    search: _Backtracking = _Backtracking()
    verbose: Callable = _quiet

    def init_hessian(self, y, f, grad):
        structure = jax.eval_shape(lambda: y)
        inverse = lx.PyTreeLinearOperator(self.hessian_inv, structure, lx.positive_semidefinite_tag)
        return optx.FunctionInfo.EvalGradHessianInv(f, grad, inverse), None

    def update_hessian(self, y, y_eval, f_info, f_eval_info, hessian_update_state):
        new, state = super().update_hessian(y, y_eval, f_info, f_eval_info, hessian_update_state)
        matrix = new.hessian_inv.as_matrix()
        positive = jnp.all(jnp.isfinite(jnp.linalg.cholesky(matrix)))
        inverse = lx.PyTreeLinearOperator(
            jnp.where(positive, matrix, f_info.hessian_inv.as_matrix()),
            new.hessian_inv.out_structure(),
            lx.positive_semidefinite_tag,
        )
        return optx.FunctionInfo.EvalGradHessianInv(new.f, new.grad, inverse), state

    def terminate(self, fn, y, args, options, state, tags):
        done, result = super().terminate(fn, y, args, options, state, tags)
        info = state.f_info
        decrement = self.trials * jnp.dot(info.grad, info.hessian_inv.mv(info.grad))
        return done | ((state.num_accepted_steps > 0) & (decrement <= self.decrement_tol)), result


def _inverse_if_positive_definite(H):
    """``inv(H)`` by Cholesky, or the identity where ``H`` is not positive
    definite."""
    L = jnp.linalg.cholesky(H)
    eye = jnp.eye(H.shape[0], dtype=H.dtype)
    ok = jnp.all(jnp.isfinite(L))
    inverse = jax.scipy.linalg.cho_solve((jnp.where(ok, L, eye), True), eye)
    return jnp.where(ok, inverse, eye)


def _solve(data, guess, lapse, max_steps):
    """Minimise the objective per trial with BFGS, from the IRLS start and the
    exact inverse Hessian there (the identity if it is not positive definite,
    as can happen with fitted rates).

    Returns ``(theta, converged)``.
    """
    n_free = guess.free + lapse.free
    theta0 = jnp.concatenate([_start(data), jnp.zeros(n_free, data.z.dtype)])
    total = jnp.maximum(jnp.sum(data.n), 1.0)

    def per_trial(theta, _):
        return _objective(theta, data, guess, lapse) / total

    eps = float(jnp.finfo(data.z.dtype).eps)
    solver = _BFGS(
        rtol=eps**0.7,
        atol=eps**0.7,
        hessian_inv=_inverse_if_positive_definite(jax.hessian(per_trial)(theta0, None)),
        trials=total,
        decrement_tol=eps**0.5 if n_free else 0.0,
    )
    solution = optx.minimise(
        per_trial,
        solver,
        theta0,
        max_steps=max_steps,
        throw=False,
    )
    return solution.value, solution.result == optx.RESULTS.successful
