"""Shared helpers of the benchmark scripts: timing and the machine record."""

import datetime
import json
import os
import platform
import statistics
import subprocess
import time
from pathlib import Path

import jax

RESULTS = Path(__file__).parent / "results"


def median_seconds(fn, repeats=5, warmup=1):
    """Median wall time of ``fn()`` over ``repeats`` calls after ``warmup`` calls.

    ``fn`` must block until its work is done (``jax.block_until_ready``), so
    that compilation (in the warm-up) and asynchronous dispatch are excluded.
    """
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def copy_bandwidth(megabytes=1024, repeats=20):
    """Memory bandwidth of the default device, bytes read plus written per second.

    Times a jitted ``x + 1`` over ``megabytes`` of random float32 (one read
    and one write of every element), the ceiling a memory-bound kernel on the
    same device can reach, measured in the same run as the kernel it bounds.
    """
    x = jax.random.uniform(jax.random.key(0), (megabytes * 2**20 // 4,))
    add = jax.jit(lambda x: x + 1)
    seconds = median_seconds(lambda: jax.block_until_ready(add(x)), repeats=repeats, warmup=2)
    return 2 * x.nbytes / seconds


def _cpuinfo():
    """The first processor's fields in ``/proc/cpuinfo`` (empty elsewhere)."""
    fields = {}
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if not line.strip():
                    break
                key, _, value = line.partition(":")
                fields[key.strip()] = value.strip()
    except OSError:
        pass
    return fields


def machine(label=None):
    """What the numbers were measured on: CPU, cores, accelerator, versions.

    The CPU's family, model and clock are kept beside its name: a virtual
    machine's name ("AMD EPYC") stays the same when the host under it
    changes, and with it the speed of the same code (SciPy's loop in
    ``bench_fitting.py`` took 2.6 ms a fit on one day and 5.4 to 6.3 on
    another).
    """
    info = _cpuinfo()
    device = jax.devices()[0]
    return {
        "label": label or platform.node(),
        "cpu": info.get("model name", platform.processor()),
        "cpu_family_model": f"{info.get('cpu family', '?')}/{info.get('model', '?')}",
        "cpu_mhz": float(info.get("cpu MHz", "nan")),
        "cores": os.cpu_count(),
        "backend": jax.default_backend(),
        "device": getattr(device, "device_kind", str(device)),
        "jax": jax.__version__,
        "python": platform.python_version(),
    }


def _commit():
    """The checked-out commit, with ``+changes`` if the tree differs from it."""
    try:
        git = ["git", "-C", str(Path(__file__).parent)]
        head = [*git, "rev-parse", "--short", "HEAD"]
        head = subprocess.run(head, capture_output=True, text=True)
        changed = [*git, "status", "--porcelain", "--", "..", ":(exclude)results"]
        dirty = subprocess.run(changed, capture_output=True)
    except OSError:
        return None
    if head.returncode != 0:
        return None
    return head.stdout.strip() + ("+changes" if dirty.stdout.strip() else "")


def write_result(name, record, label=None):
    """Write ``record`` to ``benchmarks/results/<name>.json`` (``<name>_<label>.json``
    with a ``label``), with when it was recorded (UTC) and the code's commit,
    and return the path."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / (f"{name}.json" if label is None else f"{name}_{label}.json")
    stamp = {
        "recorded": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "commit": _commit(),
    }
    path.write_text(json.dumps({**record, **stamp}, indent=2) + "\n")
    return path
