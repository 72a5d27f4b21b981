"""Process settings: freed memory kept for reuse, compiled programs kept on
disk (jaxadapt.runtime)."""

import os
import platform
import subprocess
import sys

import numpy as np
import pytest

from jaxadapt import runtime

#: End-to-end or long: left out of the quick run (pytest -m "not slow").
pytestmark = pytest.mark.slow

# Calls of the operator on a batch (output 50 MB, and its temporaries):
# prints the page faults of each call after the first.
PROGRAM = """
import resource, sys
from jaxadapt import runtime
if sys.argv[1] == "retain":
    assert runtime.retain_freed_memory()
import jax, jax.numpy as jnp
from jaxadapt.operators import pattanaik2000
frames = jnp.full((8, 540, 960, 3), 100.0)
for call in range(int(sys.argv[2]) + 1):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    out = jax.block_until_ready(pattanaik2000.run(pattanaik2000.Params(), frames, 1 / 30))
    del out
    if call:
        print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(mode, calls):
    """Page faults of each of ``calls`` repeated calls, in a fresh process
    compiled as the command line compiles (not at the test run's
    optimisation level, tests/conftest.py: the buffers of the programs a
    user runs)."""
    flags = [f for f in os.environ.get("XLA_FLAGS", "").split() if "optimization_level" not in f]
    done = subprocess.run(
        [sys.executable, "-c", PROGRAM, mode, str(calls)],
        capture_output=True,
        text=True,
        check=True,
        env=dict(os.environ, XLA_FLAGS=" ".join(flags)),
    )
    return [int(line) for line in done.stdout.split()]


@pytest.mark.skipif(
    platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="needs glibc"
)
def test_retained_memory_spares_the_page_faults_of_a_repeated_call():
    # The output alone is 12,150 pages of 4 KB: the default process maps them
    # afresh at every call; with the freed memory retained a repeated call
    # reuses the last call's pages. Not every time: XLA's CPU thread pool
    # runs independent work in an order that varies with the machine's load,
    # and now and then a temporary takes part of the freed block first, so
    # that the heap grows by one to three outputs. The heap's growth is
    # bounded, not its timing: three processes side by side see one to three
    # such calls among 24 each, and a CI run three among its first five.
    # Hence the median of 24 calls: most calls reuse the pages.
    assert min(_faults("default", 8)) > 12_000
    assert np.median(_faults("retain", 24)) < 1_000


def test_retain_freed_memory_reports_what_it_did(monkeypatch):
    monkeypatch.setattr(platform, "system", lambda: "Darwin")
    assert runtime.retain_freed_memory() is False
    assert runtime.release_freed_memory() is False


# With freed memory retained, a block of 400 MB written and freed stays
# resident until it is released; prints the resident MB at each point.
RELEASED = """
import os
import numpy as np
from jaxadapt import runtime
assert runtime.retain_freed_memory()
def resident():
    return int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE") >> 20
block = np.ones(50_000_000)  # 400 MB, from the heap (no mapping of its own)
keep = np.ones(1000)  # a live block above it: the heap's top cannot shrink
written = resident()
del block
freed = resident()
released = runtime.release_freed_memory()
print(written, freed, resident(), released)
"""


@pytest.mark.skipif(
    platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="needs glibc"
)
def test_released_memory_leaves_the_process():
    done = subprocess.run(
        [sys.executable, "-c", RELEASED], capture_output=True, text=True, check=True
    )
    written, freed, released, said = done.stdout.split()
    assert int(freed) > int(written) - 50  # retained: the freed block stays resident
    assert int(released) < int(freed) - 350  # released: its pages are handed back
    assert said == "True"


# A process that turns the cache on (with the folder from the environment)
# and compiles one program; prints the folder in use.
CACHED = """
from jaxadapt import runtime
folder = runtime.cache_compilations()
import jax
jax.block_until_ready(jax.jit(lambda x: x * 3 + 1)(2.0))
print(folder)
"""


def _cached_run(env):
    done = subprocess.run([sys.executable, "-c", CACHED], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_compilations_are_kept_for_the_next_process(tmp_path, own_cache_env):
    folder = tmp_path / "jaxadapt" / "xla"
    assert _cached_run(own_cache_env) == str(folder)
    kept = sorted(p.name for p in folder.iterdir())
    assert kept  # even a program that compiles in milliseconds
    assert _cached_run(own_cache_env) == str(folder)
    assert sorted(p.name for p in folder.iterdir()) == kept  # read back, not compiled again


def test_the_environment_chooses_the_compilation_cache(tmp_path, own_cache_env):
    # "" turns JAX's cache off: left so
    assert _cached_run(dict(own_cache_env, JAX_COMPILATION_CACHE_DIR="")) == "None"
    assert not (tmp_path / "jaxadapt").exists()
    unwritable = tmp_path / "file"
    unwritable.write_text("")
    # a file: no folder can be made in it
    assert _cached_run(dict(own_cache_env, XDG_CACHE_HOME=str(unwritable))) == "None"


def test_wide_vectors_are_asked_for_on_avx512_only(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/tmp/x")
    monkeypatch.setattr(runtime, "_has_avx512", lambda: False)
    assert runtime.use_wide_vectors() is False
    assert runtime.WIDE_VECTORS not in runtime.os.environ["XLA_FLAGS"]
    monkeypatch.setattr(runtime, "_has_avx512", lambda: True)
    assert runtime.use_wide_vectors() is True
    assert runtime.os.environ["XLA_FLAGS"] == f"--xla_dump_to=/tmp/x {runtime.WIDE_VECTORS}"
    # A width the user chose stays, and the flag is not added twice.
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_prefer_vector_width=128")
    assert runtime.use_wide_vectors() is False
    assert runtime.os.environ["XLA_FLAGS"] == "--xla_cpu_prefer_vector_width=128"


def test_xla_accepts_the_wide_vectors_flag():
    # XLA ends the process on a flag it does not know: the JAX installed
    # here must know this one, set after JAX is imported, as the command
    # line sets it, and compute the same values with it.
    program = (
        "import jax, jax.numpy as jnp\n"
        "from jaxadapt import runtime\n"
        "runtime._has_avx512 = lambda: True\n"
        "assert runtime.use_wide_vectors()\n"
        "x = jnp.linspace(0.01, 1.0, 4096)\n"
        "print(float(jnp.sum(jnp.exp(0.455 * jnp.log(x)))))\n"
    )
    env = {k: v for k, v in runtime.os.environ.items() if k != "XLA_FLAGS"}
    run = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, env=env)
    assert run.returncode == 0, run.stderr
    expected = np.sum(np.linspace(0.01, 1.0, 4096) ** 0.455)
    assert abs(float(run.stdout) - expected) < 1e-3 * expected
