"""Where simulated observers come from: a population of
:class:`~jaxadapt.psychophysics.observer.Observer`, and draws from it.

Observers are drawn through standard normals (:func:`observers_from_normals`),
so that fixed normals make a population differentiable (the
reparameterisation trick) and observer ``i`` of a draw depends only on the
key and ``i`` (:func:`draw_observers`).

References
----------
Jacobs et al. (2015), §4.1-4.2. Wichmann, Hill (2001), *The psychometric
function I*, Perception & Psychophysics 63 (lapses).
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxadapt._checks import check_value, float_array
from jaxadapt.psychophysics.observer import Observer, _check_cue_axis, _zeros
from jaxadapt.psychophysics.stimuli import CUES

__all__ = ["Population", "POPULATIONS", "N_NORMALS", "observers_from_normals", "draw_observers"]


class Population(eqx.Module):
    """Where observers come from: the distribution of
    :class:`~jaxadapt.psychophysics.observer.Observer` fields.

    Per observer, with independent standard normals ``z``::

        noise      = noise * exp(noise_spread z1)          (log-normal; median noise)
        bias       = bias + bias_spread z2
        order_bias = order_bias + order_bias_spread z3
        lapse      = sigmoid(logit(lapse) + lapse_spread z4)   (median lapse)
        weights    = weights + weight_spread z5..             (one z per cue)

    Every field is an array, so a population can be differentiated through
    :func:`observers_from_normals` (fixed ``z``: the reparameterisation
    trick) and batched.

    Attributes
    ----------
    noise, noise_spread : float
        Median decision noise, log10 units (0.15), and the standard
        deviation of its natural log (0.4: one observer in six is 1.5 times
        noisier than the median).
    bias, bias_spread : float
        Mean and spread of the constant error, log10 units (0, 0.02: the
        paper's control PSEs lie close to zero, Fig. 14).
    order_bias, order_bias_spread : float
        Mean and spread of the time-order error, log10 units (0, 0: the
        paper reports none).
    lapse, lapse_spread : float
        Median lapse rate (0.02) and the standard deviation of its logit
        (0.5); Wichmann and Hill (2001) report lapse rates of 0-5%.
    weights, weight_spread : array, (K,)
        Mean and spread of the cue weights (0: observers who judge
        luminance only).
    """

    noise: jax.Array = eqx.field(default=0.15, converter=float_array)
    noise_spread: jax.Array = eqx.field(default=0.4, converter=float_array)
    bias: jax.Array = eqx.field(default=0.0, converter=float_array)
    bias_spread: jax.Array = eqx.field(default=0.02, converter=float_array)
    order_bias: jax.Array = eqx.field(default=0.0, converter=float_array)
    order_bias_spread: jax.Array = eqx.field(default=0.0, converter=float_array)
    lapse: jax.Array = eqx.field(default=0.02, converter=float_array)
    lapse_spread: jax.Array = eqx.field(default=0.5, converter=float_array)
    weights: jax.Array = eqx.field(default_factory=_zeros, converter=float_array)
    weight_spread: jax.Array = eqx.field(default_factory=_zeros, converter=float_array)

    def __check_init__(self):
        for name in ("weights", "weight_spread"):
            _check_cue_axis(f"Population.{name}", getattr(self, name))
        check_value("Population.noise", self.noise, lambda v: v > 0, "a positive median noise")
        check_value(
            "Population.lapse", self.lapse, lambda v: (v >= 0) & (v < 1), "a median in [0, 1)"
        )
        for name in ("noise_spread", "bias_spread", "order_bias_spread", "lapse_spread"):
            check_value(
                f"Population.{name}", getattr(self, name), lambda v: v >= 0, "a spread >= 0"
            )


#: Default populations of the two presets. The paper chose the afterimage
#: tests (+-0.29 log units) so that "performance rates are mostly between
#: 10-90%", which puts the median noise near 0.29 / 1.28 = 0.22; the mesopic
#: tests span +-0.13 and gave "steeper slopes" (an easier task): 0.1.
#: Few simulated observers then fail the 70% training criterion, in line
#: with the 2 of 13 participants the paper excluded (§4.1.1).
POPULATIONS = {"afterimage": Population(noise=0.2), "mesopic": Population(noise=0.1)}

#: Number of standard normals behind one observer.
N_NORMALS = 4 + len(CUES)


def observers_from_normals(population, z):
    """Observers of a population from standard normals ``z (..., N_NORMALS)``.

    Differentiable with respect to the population (see :class:`Population`
    for the transforms).
    """
    z = jnp.asarray(z)
    p = population
    logit = jnp.log(p.lapse) - jnp.log1p(-p.lapse)
    return Observer(
        noise=p.noise * jnp.exp(p.noise_spread * z[..., 0]),
        bias=p.bias + p.bias_spread * z[..., 1],
        order_bias=p.order_bias + p.order_bias_spread * z[..., 2],
        lapse=jax.nn.sigmoid(logit + p.lapse_spread * z[..., 3]),
        weights=p.weights + p.weight_spread * z[..., 4:],
    )


def _observer_key(key, i):
    return jax.random.fold_in(key, i)


def draw_observers(key, population, n, first=0):
    """``n`` observers of a population, those numbered ``first`` to
    ``first + n - 1``; observer ``i`` depends only on ``key`` and ``i`` (not
    on ``n``), so consecutive blocks of observers join into one draw."""
    keys = jax.vmap(_observer_key, (None, 0))(key, first + jnp.arange(n))
    dtype = jnp.result_type(population.noise)
    z = jax.vmap(lambda k: jax.random.normal(k, (N_NORMALS,), dtype))(keys)
    return observers_from_normals(population, z)
