"""Numerical checks run in float64; the float32 paths are tested explicitly.

One XLA compilation cache serves the processes of a test run (the pytest-xdist
workers and the command lines the CLI tests start): a function that one of
them compiled, another loads instead of compiling it again. It lives in a
folder made for the run and removed after it, so no run loads what another
compiled.
"""

import os
import shutil
import tempfile

import pytest

#: XLA's backend (LLVM) optimisation level for the processes of a test run,
#: unless XLA_FLAGS chose one: 0, because compiling is most of what the
#: tests' small programs cost (tests/test_pattanaik2000.py: 66 s against
#: 86 to 95 s at XLA's default). The command line and the benchmarks keep
#: the default; an XLA_FLAGS with another --xla_backend_optimization_level
#: tests the code as the command line compiles it.
OPTIMISATION = "--xla_backend_optimization_level=0"
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {OPTIMISATION}".strip()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

from hypothesis import settings  # noqa: E402

# JAX dispatch makes the first example of each shape slow: no deadlines.
settings.register_profile("jaxadapt", deadline=None, max_examples=50)
settings.load_profile("jaxadapt")

CACHE_FOLDER = pytest.StashKey[str]()


class _FreeCompiledPrograms:
    """Free the programs a test file compiled once its last test is done.

    Each compiled XLA program keeps about three memory mappings while its
    function holds it, and a worker that kept every program of its files
    passed Linux's limit of 65530 mappings a process (``vm.max_map_count``)
    late in the run: XLA then crashed inside a compilation (a segmentation
    fault, an abort). A later file that needs a freed program loads it from
    the run's compilation cache. (A plugin, not this file's hook: it serves
    the doctests of ``jaxadapt/`` too.)
    """

    @staticmethod
    def pytest_runtest_teardown(item, nextitem):
        if nextitem is None or nextitem.path != item.path:
            jax.clear_caches()


def pytest_configure(config):
    config.pluginmanager.register(_FreeCompiledPrograms())
    if "PYTEST_XDIST_WORKER" in os.environ:  # a worker: the run's environment names the cache
        return
    folder = tempfile.mkdtemp(prefix="jaxadapt-tests-xla-")
    config.stash[CACHE_FOLDER] = folder
    # in the environment for the processes started from here, in the config for this one
    os.environ["JAX_COMPILATION_CACHE_DIR"] = folder
    os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0.5"
    jax.config.update("jax_compilation_cache_dir", folder)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


def pytest_unconfigure(config):
    folder = config.stash.get(CACHE_FOLDER, None)
    if folder is not None:
        shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture
def own_cache_env(tmp_path):
    """The environment of a process that chooses its own compilation cache
    (:func:`jaxadapt.runtime.cache_compilations`): without the test run's
    ``JAX_COMPILATION_CACHE_DIR``, with ``XDG_CACHE_HOME`` at ``tmp_path``."""
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    return dict(env, XDG_CACHE_HOME=str(tmp_path))


@pytest.fixture
def count_calls(monkeypatch):
    """``count_calls(owner, name)``: a list that gains an entry at each call
    of ``owner.name`` (a module's function, a class's method). Called while
    tracing, it counts traces: no new entry means nothing was traced anew."""

    def patch(owner, name):
        calls, original = [], getattr(owner, name)

        def counting(*args, **kwargs):
            calls.append(1)
            return original(*args, **kwargs)

        monkeypatch.setattr(owner, name, counting)
        return calls

    return patch


#: Doctests that compile whole fits: left out of the quick run
#: (``pytest -m "not slow"``), as the slow tests are.
SLOW_DOCTESTS = (
    "jaxadapt.fitting",
    "jaxadapt.psychophysics.bootstrap",
    "jaxadapt.psychophysics.psychometric",
    "jaxadapt.psychophysics.sharding",
)


def pytest_collection_modifyitems(items):
    for item in items:
        if isinstance(item, pytest.DoctestItem) and item.name.startswith(SLOW_DOCTESTS):
            item.add_marker(pytest.mark.slow)
