"""The result of a fit, :class:`Fit`, with its confidence intervals and
correlations."""

from collections import OrderedDict
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxadapt.fitting._bounds import _derivative, _Free, _to_free, _to_natural


class Fit(eqx.Module):
    """Result of :func:`~jaxadapt.fitting.fit`; every array has the datasets' batch shape in front.

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
        :data:`~jaxadapt.fitting.NEWTON_STEP`. It says the estimate is the minimum, not that
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
        in the notes of :func:`~jaxadapt.fitting.fit`), with ``se_u = se /
        |dp/du|`` (the delta method undone) and ``z`` the normal quantile of ``(1 + level) / 2``: a
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
        >>> from jaxadapt.fitting import fit
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
