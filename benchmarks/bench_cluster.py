"""``psychometric simulate``, ``fit`` and ``render`` on a Dask cluster, against one process.

Whole processes, as a user runs them (each the median of ``--repeats``
runs after one untimed run that fills the compilation cache; the peak
memory is the command's own process's, its workers' not counted):

- ``jaxadapt psychometric simulate --protocol afterimage --observers N``
  in one process, and with ``--workers 1, 2, 4`` (an embedded LocalCluster
  of that many worker processes, started and ended inside the run);
- ``jaxadapt psychometric fit`` of its table (``--resamples R``), the same
  ways;
- ``jaxadapt render --duration D`` (the tunnel drive at its default size,
  30 frames/s, PNG frames and the video), the same ways: split in time
  into shards of at least 16 frames, four a worker;
- the same with ``--operator jacobs2015``, whose shards hand their state
  on (they start at once, each reading its first frames and opening its
  video while it waits for the state of the one before, and writing its
  last while the next computes).

Then, in this process, the cost of a task on a LocalCluster of two
workers (the median round trip of an empty task, as ``in_order`` sends
them), and a model of a simulation's time on H hosts of one worker each
from the measured parts: ``T(H) = 2 start + work / H + tasks x
overhead``, where ``start`` (imports and compilation, in the command and
then in each worker) is measured as the one-process run of one observer,
``work`` is the one process's time less its start, and there are two
tasks a worker. This machine has 2 cores: more workers
than cores only share them, and the numbers say what a cluster costs,
not what it gains.

    python benchmarks/bench_cluster.py [--observers 2000] [--resamples 200] [--seconds 10]
        [--repeats 3]

(recorded with ``--observers 500 --resamples 100 --seconds 10 --repeats 2``: 16 minutes)
"""

import argparse
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))
from bench_render import run_processes  # noqa: E402

WORKERS = (1, 2, 4)


def command(*argv):
    return [sys.executable, "-m", "jaxadapt", *map(str, argv)]


def timed(argv, out, repeats):
    """Median wall time and peak memory of ``argv`` (one untimed run first)."""
    runs = []
    for i in range(repeats + 1):
        shutil.rmtree(out, ignore_errors=True)
        result = run_processes([command(*argv, "--out", out)])
        if i:
            runs.append(result)
    return statistics.median(w for w, _ in runs), max(p for _, p in runs)


def task_overhead(samples=200):
    """Median seconds of an empty task's round trip on two local workers."""
    import distributed

    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as c,
        distributed.Client(c) as client,
    ):
        client.submit(int, 0).result()
        times = []
        for i in range(samples):
            start = time.perf_counter()
            client.submit(int, i, pure=False).result()
            times.append(time.perf_counter() - start)
    return statistics.median(times)


#: The film of the render's model: two hours at 24 frames/s.
FILM_FRAMES = 2 * 3600 * 24


def models(record):
    """Add to ``record`` the modelled times on 16 and 64 hosts (one worker
    each) of its simulation, ``2 start + work / H + 2 H overhead`` (two
    tasks a worker), and of a film of :data:`FILM_FRAMES` frames of the
    render's size, ``2 start + frames x per-frame work / H + 4 H overhead``
    (four shards a worker), the per-frame work the one-process render's
    time less its start over its frames."""
    sim, render, overhead = record["simulate"], record["render"], record["task_overhead_s"]
    per_frame = (render["one_process_s"] - render["start_s"]) / render["frames"]
    record["simulate_model_s"], record["render_model_s"] = {}, {"film_frames": FILM_FRAMES}
    for hosts in (16, 64):
        record["simulate_model_s"][f"{hosts}_hosts"] = (
            2 * sim["start_s"]
            + (sim["one_process_s"] - sim["start_s"]) / hosts
            + 2 * hosts * overhead
        )
        record["render_model_s"][f"{hosts}_hosts"] = (
            2 * render["start_s"] + FILM_FRAMES * per_frame / hosts + 4 * hosts * overhead
        )
    record["render_model_s"]["1_host"] = render["start_s"] + FILM_FRAMES * per_frame


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--observers", type=int, default=2000)
    parser.add_argument("--resamples", type=int, default=200)
    parser.add_argument("--seconds", type=float, default=10.0, help="the render's duration")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--label", default="cpu-2core")
    args = parser.parse_args()
    scratch = Path(tempfile.mkdtemp(prefix="jaxadapt-bench-cluster-"))
    simulate = ["psychometric", "simulate", "--protocol", "afterimage", "--observers"]
    table = scratch / "table"
    run_processes([command(*simulate, args.observers, "--out", table)])
    fit = ["psychometric", "fit", table / "trials.csv", "--resamples", args.resamples]
    render = ["render", "--duration"]
    handed_on = ["render", "--operator", "jacobs2015", "--duration"]
    record = {
        "observers": args.observers,
        "resamples": args.resamples,
        "render_seconds": args.seconds,
        "repeats": args.repeats,
    }
    for name, argv, start in (
        ("simulate", [*simulate, args.observers], [*simulate, 1]),
        ("fit", fit, None),
        ("render", [*render, args.seconds], [*render, 0.1]),
        ("render_handed_on", [*handed_on, args.seconds], [*handed_on, 0.1]),
    ):
        row = record[name] = {}
        row["one_process_s"], row["one_process_peak_rss_bytes"] = timed(
            argv, scratch / "out", args.repeats
        )
        if start is not None:
            row["start_s"] = timed(start, scratch / "out", args.repeats)[0]
        for n in WORKERS:
            wall, peak = timed([*argv, "--workers", n], scratch / "out", args.repeats)
            row[f"workers_{n}_s"], row[f"workers_{n}_peak_rss_bytes"] = wall, peak
        print(name, row, flush=True)
    record["task_overhead_s"] = task_overhead()
    frames = round(args.seconds * 30)
    for name in ("render", "render_handed_on"):
        record[name]["frames"] = frames
        record[name]["one_process_ms_per_frame"] = 1e3 * record[name]["one_process_s"] / frames
    models(record)
    print(record["simulate_model_s"], record["render_model_s"])
    from common import machine, write_result

    record["machine"] = machine(args.label)
    shutil.rmtree(scratch, ignore_errors=True)
    print(write_result("cluster", record, args.label))


if __name__ == "__main__":
    main()
