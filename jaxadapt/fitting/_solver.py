"""Levenberg-Marquardt as MINPACK's ``lmder`` scales and stops it, on
optimistix's Gauss-Newton loop, with Nielsen's update of the damping.

Moré (1978), *The Levenberg-Marquardt algorithm: implementation and
theory*; Madsen, Nielsen and Tingleff (2004), *Methods for non-linear least
squares problems*, §3.2 (the damping's start and update).
"""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from jax.flatten_util import ravel_pytree


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
    minimum the shrinking steps of a growing damping would never pass
    :class:`LevenbergMarquardt`'s stall test.
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
    (gain ratios of 0.5 to 0.9) keeps its damping and creeps. Nielsen's
    rule takes fewer steps, and its estimates come closer to MINPACK's.

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


def _felt(norms):
    """Which parameters the residuals feel, from the norms of their Jacobian
    columns (or the square roots of an information matrix's diagonal): those
    longer than ``eps`` of the longest.

    A shorter column is at the rounding of the longest's effect (a derivative
    that is 0 in exact arithmetic, left by a rounding) and identifies
    nothing. Above that, the ratio of two columns does not matter: the
    information matrix scaled to a unit diagonal
    (:func:`~jaxadapt.fitting._problem._information_inverse`) is accurate
    to about ``m eps`` in every entry whatever the ratio, as is MINPACK's
    QR step. A higher cut, such as ``sqrt(eps)``, would leave unmoved and
    call not identified the well-determined parameters of a model with a
    large offset (``a`` and ``tau`` of ``a exp(-t / tau) + c`` with ``c =
    1e8``).
    """
    return norms > jnp.finfo(norms.dtype).eps * jnp.max(norms)


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
    moves until ``lambda`` has fallen below its scale, and a fit in badly
    matched units takes more steps or stops far from the minimum.

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
      its vmapped batch waiting.

    Whether the fit stopped at a minimum is :func:`~jaxadapt.fitting.fit`'s test
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
