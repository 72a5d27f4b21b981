"""Simulated trials per second: the afterimage protocol with 10,000 observers.

The stimuli are rendered once with the 2015 operator (not timed); then one
call of :func:`jaxadapt.psychophysics.experiment.simulate` draws 10,000
observers from the protocol's default population, gives each a randomised,
counter-balanced trial order (320 trials: 20 training, 100 control, 200 in
the main block) and simulates every answer. Compile time is excluded,
results are ``block_until_ready``-ed and the median of the repeats is kept.
Also timed: the answers alone (trial orders given), and the analysis of the
experiment (counts and the 20,000 cumulative-Gaussian fits). In the same run,
a NumPy peer simulates the answers of the same observers, vectorised over
them: a random trial order per observer (``Generator.permuted`` of one
counter-balanced template, whose test-first assignment it keeps), then
``scipy.special.ndtr`` and uniform draws. It does less than the timed
``simulate``, which also draws the observers, counter-balances each
observer's list afresh and applies the exclusion rule.

Usage::

    python benchmarks/bench_observer.py [--observers 10000] [--repeats 5] [--label NAME]

Writes ``benchmarks/results/observer.json`` (or ``observer_<label>.json``).
"""

import argparse
import os
import time

import jax
import jax.numpy as jnp
import numpy as np
from common import machine, median_seconds, write_result
from scipy.special import ndtr

from jaxadapt.psychophysics import design, psychometric
from jaxadapt.psychophysics import experiment as experiments
from jaxadapt.psychophysics import observer as obs
from jaxadapt.psychophysics import population as populations

PROTOCOL = design.AFTERIMAGE


def numpy_peer(rng, stimuli, observers, schedule):
    """The same simulation in NumPy, vectorised over observers: answers ``(N, T)``."""
    block, condition, level_index, test_first = schedule
    N, T = len(observers.noise), len(block)
    # random order within blocks: permute, then stable-sort by block
    perm = rng.permuted(np.broadcast_to(np.arange(T), (N, T)), axis=1)
    order = np.take_along_axis(perm, np.argsort(block[perm], axis=1, kind="stable"), 1)
    c, i, first = condition[order], level_index[order], test_first[order]
    d_lum, d_cues = (np.asarray(a, np.float64) for a in stimuli.differences())
    weights = np.asarray(observers.weights, np.float64)
    m = d_lum[c, i] + np.einsum("ntk,nk->nt", d_cues[c, i], weights)
    m += np.asarray(observers.bias)[:, None]
    sign = np.where(first, 1.0, -1.0)
    z = (m + sign * np.asarray(observers.order_bias)[:, None]) / np.asarray(observers.noise)[
        :, None
    ]
    lapse = np.asarray(observers.lapse)[:, None]
    p = 0.5 * lapse + (1 - lapse) * ndtr(z)
    return (rng.random((N, T)) < p).astype(np.float32)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--observers", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--label", default=None, help="machine label in the record and file name")
    args = parser.parse_args()

    stimuli = obs.render_stimuli(PROTOCOL, key=jax.random.key(0))
    population = populations.POPULATIONS["afterimage"]
    N, T = args.observers, PROTOCOL.n_trials
    key = jax.random.key(1)

    def simulate():
        return jax.block_until_ready(experiments.simulate(key, PROTOCOL, stimuli, population, N))

    start = time.perf_counter()
    experiment = simulate()
    first_call = time.perf_counter() - start
    simulate_s = median_seconds(simulate, args.repeats)

    observers, trials = experiment.observers, experiment.trials
    answer = jax.jit(jax.vmap(lambda k, o, t: obs.respond(k, stimuli, o, t)))
    keys = jax.random.split(jax.random.key(2), N)
    answers_s = median_seconds(
        lambda: jax.block_until_ready(answer(keys, observers, trials)), args.repeats
    )

    @jax.jit
    def analyse(trials, responses):
        n_yes, n_total = design.counts(PROTOCOL, trials, responses)
        return psychometric.fit(jnp.asarray(PROTOCOL.levels, n_yes.dtype), n_yes, n_total)

    fits = jax.block_until_ready(analyse(trials, experiment.responses))
    analyse_s = median_seconds(
        lambda: jax.block_until_ready(analyse(trials, experiment.responses)), args.repeats
    )

    # one counter-balanced trial list as the template the peer permutes per observer
    template = design.trial_list(PROTOCOL, jax.random.key(3))
    schedule = tuple(
        np.asarray(a)
        for a in (template.block, template.condition, template.level_index, template.test_first)
    )
    rng = np.random.default_rng(0)
    numpy_s = median_seconds(
        lambda: numpy_peer(rng, stimuli, observers, schedule), repeats=3, warmup=1
    )
    peer_rate = float(numpy_peer(rng, stimuli, observers, schedule).mean())

    trials_total = N * T
    record = {
        "benchmark": "simulated trials of the afterimage protocol (observer.simulate)",
        "observers": N,
        "trials_per_observer": T,
        "repeats": args.repeats,
        "dtype": str(experiment.responses.dtype),
        "jaxadapt": {
            "simulate_seconds": simulate_s,
            "first_call_seconds": first_call,
            "trials_per_second": trials_total / simulate_s,
            "answers_only_seconds": answers_s,
            "answers_only_trials_per_second": trials_total / answers_s,
            "analysis_seconds": analyse_s,
            "analysis": f"counts and {2 * N} cumulative-Gaussian fits",
            "fits_converged_fraction": float(jnp.mean(fits.converged)),
            "excluded_fraction": float(jnp.mean(experiment.excluded)),
            "yes_fraction": float(jnp.mean(experiment.responses)),
        },
        "numpy_peer": {
            "seconds": numpy_s,
            "trials_per_second": trials_total / numpy_s,
            "yes_fraction": peer_rate,
            "method": "vectorised over observers: Generator.permuted, stable argsort by block, "
            "scipy.special.ndtr, Generator.random (float64)",
        },
        "machine": {**machine(args.label), "load_average_1min": os.getloadavg()[0]},
    }
    print(write_result("observer", record, args.label))
    j = record["jaxadapt"]
    print(
        f"{N} observers x {T} trials: {j['trials_per_second']:,.0f} trials/s "
        f"({simulate_s:.3f} s; answers alone {j['answers_only_trials_per_second']:,.0f}/s); "
        f"NumPy peer {record['numpy_peer']['trials_per_second']:,.0f} trials/s; analysis "
        f"(counts + {2 * N} fits) {analyse_s:.2f} s"
    )


if __name__ == "__main__":
    main()
