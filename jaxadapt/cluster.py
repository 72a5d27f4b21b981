"""Work spread over a Dask cluster (dask distributed: the ``cluster`` extra).

``--scheduler ADDRESS`` sends a command's tasks to a running cluster
(``tcp://host:8786``, from ``dask scheduler`` and ``dask worker``, SLURM
through dask-jobqueue, Kubernetes ...); ``--workers N`` starts an embedded
``LocalCluster`` of N worker processes for the command's length. Without
either, nothing here imports Dask and the command runs in its one process.

Dask schedules, moves the data and reruns the tasks of a worker that dies;
jaxadapt only cuts the work into tasks. Each task is a pure function of its
arguments, its random keys derived per observer or group (never per
worker), so that the results equal one process's whatever the number of
workers. A task computes in the precision of the process that sent it
(``jax_enable_x64``), and each worker keeps its own compilation cache
(:func:`jaxadapt.runtime.cache_compilations`).
"""

__all__ = ["CONNECT_TIMEOUT", "AHEAD_PER_WORKER", "connected", "in_order", "workers_of"]

import collections
import contextlib
import functools
import itertools
import logging

#: Seconds to wait for a scheduler to answer before the command gives up.
CONNECT_TIMEOUT = 10.0
#: Tasks in flight per worker: a worker starts the next as soon as it hands
#: back one, and the results held for the ordered output stay bounded.
AHEAD_PER_WORKER = 2


def _distributed(option):
    """dask.distributed, or the one line that says how to install it."""
    try:
        import distributed
    except ImportError:
        raise ValueError(
            f"{option}: needs Dask distributed, which is not installed: "
            "pip install 'jaxadapt[cluster]'"
        ) from None
    return distributed


@contextlib.contextmanager
def connected(scheduler=None, workers=None):
    """A Dask ``Client`` for the block: of the cluster at ``scheduler``, or
    of an embedded one of ``workers`` processes; None where neither is given.

    Raises
    ------
    ValueError
        Dask distributed is not installed, or ``workers`` is below 1.
    OSError
        No scheduler answers at ``scheduler`` (within
        :data:`CONNECT_TIMEOUT`); the message names it.
    """
    if scheduler is None and workers is None:
        yield None
        return
    option = f"--scheduler {scheduler}" if scheduler is not None else "--workers"
    distributed = _distributed(option)
    with contextlib.ExitStack() as stack:
        # Dask's own log (a lost scheduler's tracebacks) kept off stderr: the
        # command says what failed in its one line.
        for name in [
            n for n in logging.root.manager.loggerDict if n.split(".")[0] == "distributed"
        ]:
            logger = logging.getLogger(name)
            stack.callback(logger.setLevel, logger.level)
            logger.setLevel(logging.CRITICAL)
        if scheduler is None:
            if workers < 1:
                raise ValueError(f"--workers: expected a positive number, got {workers}")
            import jax

            cluster = distributed.LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,  # (spawned: each its own JAX and XLA threads)
                dashboard_address=None,
                silence_logs=logging.ERROR,
                # this process's default precision, set before the workers import JAX
                env={"JAX_ENABLE_X64": str(bool(jax.config.jax_enable_x64))},
            )
            client = stack.enter_context(distributed.Client(cluster))
            stack.callback(cluster.close)
        else:
            try:
                client = distributed.Client(scheduler, timeout=CONNECT_TIMEOUT)
            except (OSError, TimeoutError) as error:
                raise OSError(f"{option}: no Dask scheduler answers ({error})") from None
            stack.callback(client.close)
        yield client


def in_order(client, function, args, items, option):
    """``function(*args, item)`` of each of ``items`` on the cluster of
    ``client``, its arrays as NumPy's, yielded in the items' order, a few
    per worker in flight at once. The workers compute in this process's
    precision (``jax_enable_x64``).

    Raises
    ------
    OSError
        The scheduler was lost, or a task's workers kept dying; the message
        names ``option``.
    """
    import jax

    distributed = _distributed(option)
    task = functools.partial(_run, function, bool(jax.config.jax_enable_x64), args)
    lost = (
        OSError,
        TimeoutError,
        distributed.comm.CommClosedError,
        distributed.client.FutureCancelledError,  # ("scheduler-connection-lost")
    )
    try:
        workers = workers_of(client)
    except lost as error:
        raise OSError(f"{option}: the Dask scheduler was lost ({error})") from None
    items = iter(items)
    futures = collections.deque(
        client.submit(task, item, pure=False)
        for item in itertools.islice(items, AHEAD_PER_WORKER * workers)
    )
    try:
        while futures:
            result = futures.popleft().result()
            futures.extend(client.submit(task, i, pure=False) for i in itertools.islice(items, 1))
            yield result
    except lost as error:
        raise OSError(f"{option}: the Dask scheduler was lost ({type(error).__name__})") from None
    except distributed.KilledWorker:
        raise OSError(f"{option}: a task's workers kept dying; the cluster gave up on it") from None
    finally:
        for future in futures:
            future.cancel()


def workers_of(client):
    """How many workers the cluster of ``client`` has now (at least 1)."""
    return max(1, len(client.scheduler_info(n_workers=-1)["workers"]))


def _run(function, x64, args, item):
    """A task on a worker: ``function(*args, item)`` in the sender's
    precision, its JAX arrays brought to NumPy (small to send back)."""
    import jax
    import numpy as np

    _set_up()
    with jax.enable_x64(x64):
        result = function(*args, item)
    return jax.tree.map(lambda a: np.asarray(a) if isinstance(a, jax.Array) else a, result)


@functools.cache
def _set_up():
    """A worker process set up as the command line sets up its own
    (:mod:`jaxadapt.runtime`), once, before its first task."""
    from jaxadapt import runtime

    runtime.use_wide_vectors()
    runtime.retain_freed_memory()
    runtime.cache_compilations()
