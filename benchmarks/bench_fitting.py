"""Fitting t0 and tau of 1,000 observers: one vmapped call against a SciPy loop.

The model is the threshold time course of ``experiments/fit_time_constants.py``
(a uniform field: 1e6 cd/m2 pre-adaptation, then 30 min dark, 30 s at 0.03
cd/m2 and 5 min at 1000 cd/m2; log10 increment thresholds from the 2000
operator's state, ``pattanaik2000.run``, by the chapter's response-to-threshold
relation), 90 thresholds per observer. Each simulated observer has its own
t0_rod, t0_cone, tau_rod and tau_cone (the paper's values times log-normal
factors, 20 %) and Gaussian noise of 0.05 log units.

* jaxadapt: :func:`jaxadapt.fitting.fit` of the four constants (in log
  units) for all observers in one call: Levenberg-Marquardt (Nielsen's
  damping, each parameter's scaled by its Jacobian column as MINPACK
  scales it) with exact forward-mode
  Jacobians through ``run`` (the model linearised once a step, each
  constant's tangent pushed through that linearisation alone), in a
  queue of ``fitting.LANES`` (64) vmapped solver lanes: a lane whose fit
  stops takes the next observer, so that no fit waits for the slowest.
* peer: a loop of ``scipy.optimize.least_squares`` (``method="lm"``, MINPACK,
  Jacobians by two-point finite differences, its default tolerances) on the
  same residuals of the same model, evaluated by the same jitted JAX function
  one observer at a time, in the same log parameters from the same start.

* second peer: the same SciPy loop on the model as written, not jitted as
  a whole (``pattanaik2000.run`` compiles itself, the parameter glue around
  it runs eagerly): what a first SciPy wrapper of the model costs.
* jaxadapt in float32 (float64 switched off), the library's default
  precision, compared with the float64 estimates in standard errors.
* the ceiling: the speed-up a solver would reach that took jaxadapt's
  steps and cost nothing but the model and its Jacobian at each step's
  trial point (the least a lane of one took, over ``jax.jacfwd`` and the
  fit's linearise-and-push form, at 64 and 256 lanes).

Compilation is excluded (each compiled function is called once first; that
first call's time, compilation included, is recorded too) and JAX results
are ``block_until_ready``-ed. The seconds are wall time on a machine that
may be shared, whose speed drifts by 10 to 30 % from minute to minute: so
the two sides are timed in turns. The SciPy loop fits the first ``--peer``
observers (all 1,000 by default) in ``--pairs`` (10) consecutive groups,
and after each group both jaxadapt calls (float64, float32) are timed once:
each pair (a group, the calls after it) gives a speed-up measured within
the same few seconds. The record keeps the median of the jaxadapt times
(the speed-up is the SciPy total over it), the median and range of the
speed-ups of the pairs, and the load average before and after. The second
SciPy loop fits the first ``--eager-peer`` (20) observers once. A subset
scales linearly, recorded as such. The estimates are compared where both
fits converged. Both sides stop by MINPACK's ``ftol = 1e-8`` test
(jaxadapt's LevenbergMarquardt adds it, and MINPACK's ``xtol`` test, to
optimistix's own tests).

Usage::

    python benchmarks/bench_fitting.py [--observers 1000] [--peer 1000]
                                       [--eager-peer 20] [--pairs 10] [--label NAME]

Writes ``benchmarks/results/fitting.json`` (or ``fitting_<label>.json``).
"""

import argparse
import os
import time

import jax

jax.config.update("jax_enable_x64", True)  # the same float64 model on both sides

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy  # noqa: E402
from common import machine, median_seconds, write_result  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

from jaxadapt import fitting  # noqa: E402
from jaxadapt.operators import pattanaik2000 as op  # noqa: E402
from jaxadapt.physiology.response import sigma_cone, sigma_rod  # noqa: E402
from jaxadapt.physiology.threshold import increment_sensitivity  # noqa: E402

NAMES = ("t0_rod", "t0_cone", "tau_rod", "tau_cone")
#: (luminance cd/m2, duration s, thresholds) of each step, after 1e6 cd/m2.
STEPS = ((1e-6, 1800.0, 40), (0.03, 30.0, 20), (1e3, 300.0, 30))
PRE, DELTA, NOISE = 1e6, 0.01, 0.05


def protocol():
    L, dt = [], []
    for lum, duration, count in STEPS:
        starts = np.concatenate([[0.0], np.geomspace(0.01, duration, count)])
        L.append(np.full(count, lum))
        dt.append(np.diff(starts))
    return jnp.asarray(np.concatenate(L)), jnp.asarray(np.concatenate(dt)), jnp.asarray(PRE)


def log_threshold(params, args):
    """log10 threshold (cd/m2) at each frame, rods and cones pooled (as in the experiment)."""
    L, dt, pre = args
    frames = jnp.broadcast_to(L[:, None, None, None], (L.shape[0], 1, 1, 3))
    _, diag = op.run(params, frames, dt, state=op.static_state(params, pre, pre))
    s = diag.state
    rod = increment_sensitivity(L, sigma_rod(s.A_rod, params.n), DELTA, s.B_rod, params.n)
    cone = increment_sensitivity(L, sigma_cone(s.A_cone, params.n), DELTA, s.B_cone, params.n)
    return -0.25 * jnp.log10(jnp.maximum(rod**4 + cone**4, 1e-32))


def with_log(log_values):
    """The paper's Params with the four constants set to ``exp(log_values)``."""
    values = jnp.exp(log_values)
    return eqx.tree_at(lambda p: [getattr(p, n) for n in NAMES], op.Params(), list(values))


def simulate(observers, args, seed=0):
    rng = np.random.default_rng(seed)
    base = np.log([float(getattr(op.Params(), n)) for n in NAMES])
    truth = base + 0.2 * rng.standard_normal((observers, len(NAMES)))
    clean = jax.jit(jax.vmap(lambda v: log_threshold(with_log(v), args)))(jnp.asarray(truth))
    data = np.asarray(clean) + NOISE * rng.standard_normal(clean.shape)
    return np.exp(truth), data


def scipy_loop(data, args, jit=True, groups=1, between=None):
    """Fit each observer with MINPACK's LM and finite-difference Jacobians.

    ``jit``: the whole model (parameters to thresholds) compiled as one
    function, the fastest way to give SciPy the model; otherwise the model
    as written, called eagerly (``pattanaik2000.run`` compiles itself, the
    glue around it runs op by op), as a SciPy user might first wrap it.
    The rows are fitted in ``groups`` consecutive groups, each timed on its
    own, with ``between()`` called after each, outside the timing.

    Returns the estimates, success flags and final costs (one per row),
    the seconds of each group and the number of model evaluations.
    """

    fn = jax.jit(model(args)) if jit else model(args)
    x0 = np.log([float(getattr(op.Params(), n)) for n in NAMES])
    fn(jnp.asarray(x0)).block_until_ready()  # compile outside the timing
    estimates, ok, costs, evaluations = [], [], [], [0]

    def residuals(v, row):
        evaluations[0] += 1
        return np.asarray(fn(jnp.asarray(v))) - row

    seconds = []
    for rows in np.array_split(data, groups):
        start = time.perf_counter()
        for row in rows:
            result = least_squares(residuals, x0, jac="2-point", method="lm", args=(row,))
            estimates.append(np.exp(result.x))
            ok.append(result.success)
            costs.append(result.cost)
        seconds.append(time.perf_counter() - start)
        if between is not None:
            between()
    return np.array(estimates), np.array(ok), np.array(costs), np.array(seconds), evaluations[0]


def model(model_args):
    """The log thresholds as a function of the four constants' logs."""
    return lambda v: log_threshold(with_log(v), model_args)


def model_and_jacobian(model_args):
    """Forward-mode Jacobians of the model, its value included, in the two
    forms a fit can compute them: ``jax.jacfwd`` (the four tangents pushed
    through every operation at once) and the model linearised once with
    each constant's tangent pushed through the linearisation alone (as
    :func:`jaxadapt.fitting.fit` computes its Jacobian)."""
    fn = model(model_args)

    def linearised(v):
        f, tangent = jax.linearize(fn, v)
        return f, jnp.stack([tangent(e) for e in jnp.eye(v.size, dtype=v.dtype)], -1)

    return {"jacfwd": jax.jacfwd(fn), "linearised": linearised}


def seconds_per_lane(fn, lanes=fitting.LANES):
    """Seconds a lane of ``fn`` (of the four constants' logs) vmapped over
    ``lanes`` lanes, at the paper's constants, in the precision in force."""
    x0 = np.log([float(getattr(op.Params(), n)) for n in NAMES])
    X = jnp.tile(jnp.asarray(x0), (lanes, 1))
    batched = jax.jit(jax.vmap(fn))
    return median_seconds(lambda: jax.block_until_ready(batched(X)), repeats=21) / lanes


def jacobian_seconds_per_lane(model_args):
    """The least seconds a lane of one model evaluation with its Jacobian
    took: each form of :func:`model_and_jacobian` at 64 and 256 lanes
    (wider vmaps pay XLA's fixed cost per operation less often)."""
    forms = model_and_jacobian(model_args)
    times = {
        f"{name}_{lanes}_lanes": seconds_per_lane(fn, lanes)
        for name, fn in forms.items()
        for lanes in (fitting.LANES, 4 * fitting.LANES)
    }
    return min(times.values()), times


def timed(fn, times):
    """``fn()``, its wall time appended to ``times``."""
    start = time.perf_counter()
    out = fn()
    times.append(time.perf_counter() - start)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--observers", type=int, default=1000)
    parser.add_argument("--peer", type=int, default=1000, help="observers fitted by SciPy")
    parser.add_argument(
        "--eager-peer", type=int, default=20, help="observers fitted by SciPy on the eager model"
    )
    parser.add_argument(
        "--pairs", type=int, default=10, help="SciPy groups, each followed by a timed fit"
    )
    parser.add_argument("--label", default=None, help="machine label in the record and file name")
    args = parser.parse_args()

    load_before = os.getloadavg()[0]
    model_args = protocol()
    truth, data = simulate(args.observers, model_args)
    data = jnp.asarray(data)
    start = op.Params()

    def run():
        return jax.block_until_ready(
            fitting.fit(log_threshold, start, NAMES, data, args=model_args)
        )

    t = time.perf_counter()
    fits = run()
    first_s = time.perf_counter() - t
    ours = np.stack([np.asarray(fits.estimate[n]) for n in NAMES], -1)
    converged = np.asarray(fits.converged)

    # float32, the library's default precision (float64 switched off here).
    with jax.enable_x64(False):
        data32 = jnp.asarray(np.asarray(data), jnp.float32)
        args32 = jax.tree.map(lambda a: jnp.asarray(a, jnp.float32), model_args)

        def run32():
            return jax.block_until_ready(
                fitting.fit(log_threshold, op.Params(), NAMES, data32, args=args32)
            )

        fits32 = run32()
        model32_per_lane = seconds_per_lane(model(args32))
        jacobian32_per_lane, jacobian32_forms = jacobian_seconds_per_lane(args32)
        ours32 = np.stack([np.asarray(fits32.estimate[n], float) for n in NAMES], -1)
        se64 = np.stack([np.asarray(fits.se[n]) for n in NAMES], -1)
        f32_vs_f64 = np.abs(ours32 - ours) / se64

    def run32_as_float32():
        with jax.enable_x64(False):
            return run32()

    jax_times, f32_times = [], []
    peer = min(args.peer, args.observers)
    theirs, peer_ok, cost, groups_s, evaluations = scipy_loop(
        np.asarray(data[:peer]),
        model_args,
        groups=min(args.pairs, peer),
        between=lambda: (timed(run, jax_times), timed(run32_as_float32, f32_times)),
    )
    peer_s = float(groups_s.sum())
    peer_per_fit = peer_s / peer
    jax_s, f32_s = float(np.median(jax_times)), float(np.median(f32_times))
    group_sizes = np.array([len(g) for g in np.array_split(np.arange(peer), groups_s.size)])
    # Each pair's SciPy time for all observers over the jaxadapt call after it.
    pair_speedups = groups_s / group_sizes * args.observers / np.array(jax_times)
    pair_speedups32 = groups_s / group_sizes * args.observers / np.array(f32_times)
    model_per_lane = seconds_per_lane(model(model_args))
    jacobian_per_lane, jacobian_forms = jacobian_seconds_per_lane(model_args)
    # A Levenberg-Marquardt step needs the model and its Jacobian at its
    # trial point: a solver that cost nothing else, taking as many steps,
    # would reach this speed-up and no more.
    mean_steps = float(np.mean(np.asarray(fits.steps)))
    mean_steps32 = float(np.mean(np.asarray(fits32.steps)))
    ceiling = peer_per_fit / (mean_steps * jacobian_per_lane)
    ceiling32 = peer_per_fit / (mean_steps32 * jacobian32_per_lane)
    eager = min(args.eager_peer, args.observers)
    *_, eager_groups_s, eager_evaluations = scipy_loop(
        np.asarray(data[:eager]), model_args, jit=False
    )
    eager_s = float(eager_groups_s.sum())
    eager_per_fit = eager_s / eager
    both = converged[:peer] & peer_ok
    rel = np.abs(ours[:peer] / theirs - 1)[both]
    se = np.stack([np.asarray(fits.se[n]) for n in NAMES], -1)[:peer][both]
    in_se = np.abs(ours[:peer] - theirs)[both] / se
    recovered = np.abs(np.log(ours / truth))
    # Where the estimates differ by more than 0.01 standard errors the two
    # solvers ended in different minima: which found the lower sum of squares?
    apart = np.flatnonzero(both)[np.max(in_se, axis=-1) > 0.01]
    lower = np.asarray(fits.loss)[:peer][apart] < cost[apart] * (1 - 1e-9)
    record = {
        "benchmark": "least-squares fits of t0 and tau (rods, cones) to 90 log thresholds "
        "from pattanaik2000.run, one per simulated observer",
        "observers": args.observers,
        "pairs": len(jax_times),
        "jaxadapt": {
            "seconds": jax_s,
            "seconds_each_pair": jax_times,
            "first_call_seconds": first_s,
            "fits_per_second": args.observers / jax_s,
            "converged_fraction": float(converged.mean()),
            "median_steps": float(np.median(np.asarray(fits.steps))),
            "mean_steps": mean_steps,
            "max_steps": int(np.max(np.asarray(fits.steps))),
            "lanes": fitting.LANES,
            "seconds_per_step_and_fit": jax_s / float(np.sum(np.asarray(fits.steps))),
            "model_seconds_per_lane": model_per_lane,
            "jacobian_seconds_per_lane": jacobian_per_lane,
            "jacobian_seconds_per_lane_each_form": jacobian_forms,
            "method": "fitting.fit: optimistix LevenbergMarquardt with Nielsen's damping "
            "(and MINPACK's ftol and xtol tests), "
            "forward-mode Jacobians (one linearisation, one tangent per constant), log "
            "parameters, a queue of vmapped solver lanes over observers, float64",
        },
        "jaxadapt_float32": {
            "seconds": f32_s,
            "seconds_each_pair": f32_times,
            "fits_per_second": args.observers / f32_s,
            "converged_fraction": float(np.mean(np.asarray(fits32.converged))),
            "median_steps": float(np.median(np.asarray(fits32.steps))),
            "mean_steps": mean_steps32,
            "seconds_per_step_and_fit": f32_s / float(np.sum(np.asarray(fits32.steps))),
            "model_seconds_per_lane": model32_per_lane,
            "jacobian_seconds_per_lane": jacobian32_per_lane,
            "jacobian_seconds_per_lane_each_form": jacobian32_forms,
            "max_difference_from_float64_in_standard_errors": float(np.max(f32_vs_f64)),
            "method": "the same call on float32 data and model (float64 off)",
        },
        "scipy": {
            "version": scipy.__version__,
            "observers": peer,
            "seconds": peer_s,
            "seconds_each_group": groups_s.tolist(),
            "seconds_per_fit": peer_per_fit,
            "seconds_for_all_observers": peer_per_fit * args.observers,
            "scaled_from_subset": peer < args.observers,
            "fits_per_second": 1.0 / peer_per_fit,
            "model_evaluations_per_fit": evaluations / peer,
            "model_seconds_per_evaluation": peer_s / evaluations,
            "converged_fraction": float(peer_ok.mean()),
            "method": "least_squares(method='lm', jac='2-point'), default tolerances, "
            "one observer at a time, same jitted model and log parameters",
        },
        "scipy_eager_model": {
            "observers": eager,
            "seconds": eager_s,
            "seconds_per_fit": eager_per_fit,
            "seconds_for_all_observers": eager_per_fit * args.observers,
            "scaled_from_subset": eager < args.observers,
            "model_evaluations_per_fit": eager_evaluations / eager,
            "method": "as 'scipy', but the model function not jitted as a whole: "
            "pattanaik2000.run compiles itself, the glue around it runs eagerly",
        },
        "speedup": peer_per_fit * args.observers / jax_s,
        "speedup_float32": peer_per_fit * args.observers / f32_s,
        "speedup_ceiling": {
            "float64": ceiling,
            "float32": ceiling32,
            "method": "SciPy's seconds a fit over (jaxadapt's mean steps a fit x the least "
            "seconds a lane of one model evaluation with its forward-mode Jacobian): the "
            "speed-up of a solver that took the same steps and cost nothing but the "
            "Jacobians they need",
        },
        "speedup_of_the_pairs": {
            "float64": {
                "median": float(np.median(pair_speedups)),
                "min": float(np.min(pair_speedups)),
                "max": float(np.max(pair_speedups)),
            },
            "float32": {
                "median": float(np.median(pair_speedups32)),
                "min": float(np.min(pair_speedups32)),
                "max": float(np.max(pair_speedups32)),
            },
        },
        "speedup_vs_eager_model": eager_per_fit * args.observers / jax_s,
        "agreement": {
            "compared_observers": int(both.sum()),
            "median_relative_difference": float(np.median(rel)),
            "max_relative_difference": float(np.max(rel)),
            "max_difference_in_standard_errors": float(np.max(in_se)),
            "fraction_within_1e-4_relative": float(np.mean(np.all(rel < 1e-4, axis=-1))),
            "observers_apart_by_more_than_0.01_se": int(apart.size),
            "of_which_jaxadapt_has_the_lower_sum_of_squares": int(lower.sum()),
        },
        "recovery_median_abs_log_error": dict(
            zip(NAMES, np.median(recovered, axis=0).round(4).tolist(), strict=True)
        ),
        "machine": {
            **machine(args.label),
            "load_average_1min_before": load_before,
            "load_average_1min": os.getloadavg()[0],
        },
    }
    print(write_result("fitting", record, args.label))
    print(
        f"ceiling (a solver costing only its Jacobians): {ceiling:.1f}x float64, "
        f"{ceiling32:.1f}x float32; a Jacobian with the model, a lane: "
        f"{jacobian_per_lane * 1e6:.1f} us float64, {jacobian32_per_lane * 1e6:.1f} us float32"
    )
    print(
        f"float32: {args.observers} fits in {f32_s:.2f} s ({record['speedup_float32']:.1f}x); "
        f"scipy on the eager model: {eager_per_fit * 1e3:.0f} ms a fit "
        f"({record['speedup_vs_eager_model']:.0f}x)"
    )
    print(
        f"jaxadapt: {args.observers} fits in {jax_s:.2f} s ({args.observers / jax_s:,.0f} fits/s, "
        f"first call {first_s:.1f} s); scipy: {peer_per_fit * 1e3:.1f} ms a fit "
        f"({peer} fitted); speed-up {record['speedup']:.1f}x (pairs: median "
        f"{np.median(pair_speedups):.1f}x, {np.min(pair_speedups):.1f} to "
        f"{np.max(pair_speedups):.1f}x); estimates agree to "
        f"{record['agreement']['max_relative_difference']:.1e} relative (max), "
        f"{record['agreement']['max_difference_in_standard_errors']:.1e} standard errors"
    )


if __name__ == "__main__":
    main()
