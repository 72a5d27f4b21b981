"""The whole ``jaxadapt psychometric fit`` process on tables of 10 to 10,000 groups.

What a user runs: the process starts, reads a trial table (one row per
trial, 100 trials a group over 5 levels), fits every group with the
default bootstrap (1,000 parametric resamples), runs the group test and
writes its tables and figures. Recorded for each size: the wall time and
the peak resident memory of the process (``wait4``), of its first run
(which fills the compilation cache) and the median of ``--repeats`` more
(one more for sizes of ``--one-run-from`` groups and up, whose programs
the smaller sizes compiled). Also the largest table with ``--resamples 0``
(Wald intervals, no bootstrap). No peer runs the same job; statsmodels'
fit rate is in ``bench_fit.py``.

    python benchmarks/bench_psychometric.py [--groups 10 1000 10000]
                                            [--repeats 3] [--one-run-from 10000]
"""

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np
from bench_render import run_processes

LEVELS = np.array([-0.3, -0.15, 0.0, 0.15, 0.3])
TRIALS_PER_LEVEL = 20


def write_table(path, groups, seed=0):
    """A trial table of ``groups`` groups (participants x 2 conditions), one
    row per trial, responses from cumulative Gaussians of random PSE and
    spread."""
    rng = np.random.default_rng(seed)
    participants = groups // 2
    pse = rng.normal(0.0, 0.08, (participants, 2, 1, 1))
    pse[:, 1] += 0.05  # the second condition's shift
    sigma = rng.uniform(0.05, 0.2, (participants, 1, 1, 1))
    p = 0.5 * (1 + np.tanh((LEVELS[:, None] - pse) / sigma * 0.8))  # a logistic stand-in
    shape = (participants, 2, LEVELS.size, TRIALS_PER_LEVEL)
    response = (rng.random(shape) < p).astype(int)
    with open(path, "w") as f:
        f.write("participant,condition,level,response\n")
        for i in range(participants):
            for c, condition in enumerate(("control", "bright")):
                for j, level in enumerate(LEVELS):
                    row = f"p{i:05d},{condition},{level:g},"
                    f.writelines(f"{row}{r}\n" for r in response[i, c, j])


def fit_command(table, out, *options):
    return [sys.executable, "-m", "jaxadapt", "psychometric", "fit", str(table)] + [
        *options,
        "--out",
        str(out),
    ]


def measure(table, folder, runs, *options):
    """Wall seconds and peak RSS bytes of ``runs`` runs of the command."""
    results = []
    for i in range(runs):
        results.append(run_processes([fit_command(table, Path(folder) / f"out{i}", *options)]))
    return results


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--groups", type=int, nargs="+", default=[10, 1000, 10000])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--one-run-from", type=int, default=10000)
    parser.add_argument("--label", default="cpu-2core")
    args = parser.parse_args()
    record = {"trials_per_group": LEVELS.size * TRIALS_PER_LEVEL, "resamples": 1000, "sizes": {}}
    with tempfile.TemporaryDirectory() as folder:
        for groups in sorted(args.groups):
            table = Path(folder) / f"trials_{groups}.csv"
            write_table(table, groups)
            runs = 1 + (groups < args.one_run_from) * args.repeats
            (s0, rss0), *rest = measure(table, folder, runs)
            entry = {"rows": groups * LEVELS.size * TRIALS_PER_LEVEL}
            entry |= {"first_run_s": s0, "first_run_peak_rss_bytes": rss0}
            if rest:
                entry["s"] = statistics.median(s for s, _ in rest)
                entry["peak_rss_bytes"] = max(rss for _, rss in rest)
            record["sizes"][str(groups)] = entry
            print(groups, entry, flush=True)
        largest = max(args.groups)
        table = Path(folder) / f"trials_{largest}.csv"
        (s, rss), *_ = measure(table, folder, 1, "--resamples", "0")
        record["wald"] = {"groups": largest, "s": s, "peak_rss_bytes": rss}
        print("wald", record["wald"], flush=True)

    sys.path.insert(0, str(Path(__file__).parent))
    from common import machine, write_result

    record["machine"] = machine(args.label)
    print(write_result("psychometric", record, args.label))


if __name__ == "__main__":
    main()
