"""Psychometric fits per second: one vmapped call against a statsmodels loop.

100,000 simulated datasets of the afterimage protocol (5 levels, 30 trials a
level, PSEs and spreads drawn at random) are fitted in one call of
:func:`jaxadapt.psychophysics.psychometric.fit`, in float32 and in float64; compile
time is excluded, results are ``block_until_ready``-ed, and the median of the
repeats is kept. In the same run a loop of statsmodels' probit GLM (the
counterpart of MATLAB's ``glmfit`` used by the paper) fits the first 500 of
the same datasets, and the PSEs are compared where the MLE exists.

Usage::

    python benchmarks/bench_fit.py [--datasets 100000] [--peer 500] [--repeats 5]
                                   [--label NAME]

Writes ``benchmarks/results/fit.json`` (or ``fit_<label>.json``; about a
minute on 2 cores).
"""

import argparse
import os
import time
import warnings

import jax

jax.config.update("jax_enable_x64", True)  # float64 available; each run picks its dtype

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import statsmodels  # noqa: E402
import statsmodels.api as sm  # noqa: E402
from common import machine, median_seconds, write_result  # noqa: E402
from scipy.stats import norm  # noqa: E402

from jaxadapt.psychophysics import design, psychometric  # noqa: E402


def simulate(datasets, seed=0):
    """The afterimage protocol's levels, 30 trials a level, random observers."""
    rng = np.random.default_rng(seed)
    levels = design.AFTERIMAGE.levels
    mu = rng.normal(0.0, 0.1, (datasets, 1))
    sigma = rng.uniform(0.05, 0.3, (datasets, 1))
    n = np.full((datasets, levels.size), 30)
    k = rng.binomial(n, norm.cdf((levels - mu) / sigma))
    return levels, k, n


def statsmodels_pse(levels, k, n):
    """PSEs from a loop of probit GLM fits with statsmodels' defaults."""
    exog = sm.add_constant(levels)
    family = sm.families.Binomial(link=sm.families.links.Probit())
    pse = np.empty(len(k))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # separation and convergence warnings
        for i in range(len(k)):
            b0, b1 = sm.GLM(np.c_[k[i], n[i] - k[i]], exog, family=family).fit().params
            pse[i] = -b0 / b1
    return pse


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=int, default=100_000)
    parser.add_argument("--peer", type=int, default=500, help="datasets fitted by statsmodels")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--label", default=None, help="machine label in the record and file name")
    args = parser.parse_args()

    levels, k, n = simulate(args.datasets)
    peer = slice(0, args.peer)
    peer_pse = statsmodels_pse(levels, k[peer], n[peer])
    peer_s = median_seconds(lambda: statsmodels_pse(levels, k[peer], n[peer]), 3, warmup=0)
    runs = {}
    for dtype in (jnp.float32, jnp.float64):
        arrays = [jnp.asarray(a, dtype) for a in (levels, k, n)]
        start = time.perf_counter()
        fits = jax.block_until_ready(psychometric.fit(*arrays))
        compile_s = time.perf_counter() - start
        run_s = median_seconds(
            lambda a=arrays: jax.block_until_ready(psychometric.fit(*a)), args.repeats
        )
        flags = np.asarray(fits.flags)
        exists = (flags[peer] & psychometric.NO_MLE) == 0
        runs[jnp.dtype(dtype).name] = {
            "seconds": run_s,
            "first_call_seconds": compile_s,
            "fits_per_second": args.datasets / run_s,
            "speedup_vs_statsmodels": (args.datasets / run_s) / (args.peer / peer_s),
            "converged_fraction": float(np.mean(fits.converged)),
            "no_mle_fraction": float(np.mean((flags & psychometric.NO_MLE) > 0)),
            "pse_max_abs_diff_vs_statsmodels": float(
                np.max(np.abs(np.asarray(fits.pse, float)[peer] - peer_pse)[exists])
            ),
            "compared_datasets": int(exists.sum()),
        }
    record = {
        "benchmark": "cumulative-Gaussian (probit) fits of 5-level datasets, 30 trials a level",
        "datasets": args.datasets,
        "repeats": args.repeats,
        "jaxadapt": runs,
        "statsmodels": {
            "version": statsmodels.__version__,
            "datasets": args.peer,
            "seconds": peer_s,
            "fits_per_second": args.peer / peer_s,
            "method": "GLM(Binomial(link=Probit())).fit() (IRLS, defaults), one dataset at a time",
            "note": "statsmodels stops its IRLS at a 1e-8 change of the deviance, so PSEs "
            "differ by up to ~1e-6 log units here; the tests, at tol=1e-14, agree to 1e-6 "
            "relative in b0 and b1",
        },
        "machine": {**machine(args.label), "load_average_1min": os.getloadavg()[0]},
    }
    print(write_result("fit", record, args.label))
    for dtype, run in runs.items():
        print(
            f"{dtype}: {run['fits_per_second']:,.0f} fits/s "
            f"({run['speedup_vs_statsmodels']:.0f}x statsmodels, "
            f"{args.peer / peer_s:,.0f} fits/s), max PSE difference "
            f"{run['pse_max_abs_diff_vs_statsmodels']:.1e}"
        )


if __name__ == "__main__":
    main()
