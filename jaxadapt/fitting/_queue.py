"""A large batch of datasets fitted through a queue of vmapped solver lanes.

A batch of at most :data:`~jaxadapt.fitting.LANES` datasets is one vmapped
solve (optimistix's own loop): it runs until the slowest fit has stopped,
the others frozen meanwhile. A larger batch would make every fit wait for
the slowest one, computing the model and its Jacobian for all of them at
every step (fits of the same model often take from 5 to 50 steps), so it
goes through a queue instead: ``lanes`` lanes, and a lane whose fit stops
is written out and takes the next dataset at once. The host hands the
queue over in rounds of ``lanes`` datasets; between rounds each lane's
whole solver state (iterate, step count, Levenberg-Marquardt's damping and
last Jacobian) stays as it is, so that every fit takes the steps, and gives
the numbers, of an uninterrupted solve (to rounding, which XLA may give
differently for another batch width). The compiled functions see twice
``lanes`` datasets whatever the batch: a batch of any size compiles them
once. Under a JAX transformation (:func:`~jaxadapt.fitting.fit` called
inside ``jit`` or ``vmap``) there is no host to keep the queue, and the
batch is one vmapped solve whatever its size.

The lanes take each step as one vmapped computation, not in independent
groups that XLA's CPU runtime would run side by side: that was no faster,
and such groups can deadlock that runtime.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from jaxadapt.fitting._problem import _solver_linearisation


class _Lane:
    """optimistix's ``iterative_solve`` (its loop of solver steps) taken apart
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
    """The :class:`~jaxadapt.fitting.Fit` of each dataset given (leading axis) from its solve's
    end ``(u, solved, steps, linear)``."""
    obs = jax.vmap(problem.observations)(data, weights)
    return jax.vmap(problem.summarise)(obs, *ends)


def _queue(problem, data, weights, lanes):
    """Every dataset (leading axis, more than ``lanes``) through ``lanes``
    solver lanes (see the module notes).

    The host keeps the queue and hands it to :func:`_round` ``lanes``
    datasets at a time; the compiled functions see ``2 lanes`` datasets
    whatever their number. The standard errors and the rest of each
    :class:`~jaxadapt.fitting.Fit` then come from :func:`_summaries`,
    ``2 lanes`` datasets at a time (half as many calls as ``lanes`` at a
    time).
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
