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

__all__ = [
    "CONNECT_TIMEOUT",
    "AHEAD_PER_WORKER",
    "SHARDS_PER_WORKER",
    "SHARD_LEAST",
    "connected",
    "in_order",
    "handed_on",
    "Baton",
    "workers_of",
    "shard_bounds",
    "shard_states",
    "on_host",
]

import collections
import contextlib
import functools
import itertools
import logging
import time

#: Seconds to wait for a scheduler to answer before the command gives up.
CONNECT_TIMEOUT = 10.0
#: Tasks in flight per worker: a worker starts the next as soon as it hands
#: back one, and the results held for the ordered output stay bounded.
AHEAD_PER_WORKER = 2
#: Shards of a render split in time, per worker: more than one each, so
#: that a slow or lost worker holds back a small part of the sequence.
SHARDS_PER_WORKER = 4
#: The fewest frames of a shard: each shard reads, and compiles for, its
#: own chunks, and a short one would cost more than it renders.
SHARD_LEAST = 16


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

            cluster = stack.enter_context(
                distributed.LocalCluster(
                    n_workers=workers,
                    threads_per_worker=1,
                    processes=True,  # (spawned: each its own JAX and XLA threads)
                    # (its HTTP server on a free port: None still takes 8787, and a
                    # second run at once warned that the port was in use)
                    dashboard_address=":0",
                    # (a task's error is said by the command in its one line, not
                    # as the worker's log with its traceback)
                    silence_logs=logging.CRITICAL,
                    # this process's default precision, set before the workers import JAX
                    env={"JAX_ENABLE_X64": str(bool(jax.config.jax_enable_x64))},
                )
            )
            # (the client closed first: closed after its cluster, it keeps
            # Dask's IO loop thread alive until Python finalises)
            client = stack.enter_context(distributed.Client(cluster))
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
    task = functools.partial(_run, function, _x64(), args)
    yield from _gathered(client, lambda item: client.submit(task, item, pure=False), items, option)


def _x64():
    """Whether this process computes in 64 bits (``jax_enable_x64``)."""
    import jax

    return bool(jax.config.jax_enable_x64)


def _gathered(client, submit, items, option):
    """The results of ``submit(item)`` (a future) of each of ``items``, in
    order, a few per worker in flight; a lost scheduler or a task whose
    workers kept dying as an OSError naming ``option``, a task's own error
    (a file a worker cannot read) as it was raised there."""
    distributed = _distributed(option)
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
    futures = collections.deque(map(submit, itertools.islice(items, AHEAD_PER_WORKER * workers)))
    try:
        while futures:
            future = futures.popleft()
            try:
                result = future.result()
            except lost as error:
                if future.status == "error":  # (the task's own, a missing file: as it is)
                    raise
                raise OSError(
                    f"{option}: the Dask scheduler was lost ({type(error).__name__})"
                ) from None
            futures.extend(map(submit, itertools.islice(items, 1)))
            yield result
    except distributed.KilledWorker:
        raise OSError(f"{option}: a task's workers kept dying; the cluster gave up on it") from None
    finally:
        for future in futures:
            future.cancel()


def handed_on(client, function, args, items, option):
    """``function(*args, item, baton)`` of each of ``items`` on the cluster of
    ``client``, each taking what the one before it hands on with its
    :class:`Baton`: for work whose state flows from one item to the next
    (a render split in time whose operator does not compose). The tasks
    run at once, each waiting for the state where it needs it, so that an
    item's reading, decoding and writing overlap its neighbours' computing.
    The results yielded in order, as :func:`in_order`'s.

    Raises
    ------
    OSError
        As :func:`in_order`; or a state handed on was lost with both the
        workers that held it, after the task that handed it on had ended.
    """
    import uuid

    distributed = _distributed(option)
    items, run = list(items), uuid.uuid4().hex
    batons = [Baton(run, k, k == len(items) - 1) for k in range(len(items))]
    task = functools.partial(_run, function, _x64(), args)
    submitted = iter(batons)

    def submit(item):
        return client.submit(task, item, next(submitted), pure=False)

    def forget(baton):  # (a state no longer needed: the task after its own has ended)
        with contextlib.suppress(OSError, TimeoutError):  # (a lost scheduler: gone with it)
            for name in baton.names():
                distributed.Variable(name, client).delete()

    try:
        results = _gathered(client, submit, items, option)
        for k, result in enumerate(results):
            if k:
                forget(batons[k - 1])
            yield result
    finally:
        for baton in batons:
            forget(baton)


class Baton:
    """What a task of :func:`handed_on` hands to the next: its state, in a
    Dask ``Variable`` named for the run and the task that holds a future of
    it (Dask sends it worker to worker).

    The task takes the state of the one before with :meth:`taken` (None
    for the first), waiting without holding its worker's thread, and hands
    its own on with :meth:`hand_on` as soon as it has it, before it writes
    its outputs. The state is kept on two workers (two copies, each its
    own future): one lost, the next task (or its run again elsewhere)
    takes it from the other. A task lost before it ended is run again
    elsewhere, and hands the same state on.
    """

    #: Seconds between looks at a variable whose state was lost, until the
    #: task run again hands it on again.
    POLL = 0.1
    #: Seconds a state may take to come from the worker that holds it.
    TRANSFER = 60.0
    #: The workers that hold each state handed on.
    COPIES = 2

    def __init__(self, run, index, last):
        self.run, self.index, self.last = run, index, last

    def names(self):
        """The variables of this task's state's copies and of its end."""
        copies = [f"state{i}" for i in range(self.COPIES)]
        return tuple(f"{self.run}-{what}-{self.index}" for what in (*copies, "ended"))

    def taken(self):
        """The state the task before this one handed on (None for the first)."""
        import distributed

        if self.index == 0:
            return None
        *copies, ended = Baton(self.run, self.index - 1, False).names()
        with _seceded():
            while True:
                futures = [distributed.Variable(copies[0]).get()]  # (waits until it is set)
                for name in copies[1:]:
                    with contextlib.suppress(TimeoutError):  # (not yet, or only one worker)
                        futures.append(distributed.Variable(name).get(timeout=0))
                for future in futures:
                    if future.status != "lost":
                        with contextlib.suppress(
                            TimeoutError, distributed.client.FutureCancelledError
                        ):
                            return future.result(timeout=self.TRANSFER)
                with contextlib.suppress(TimeoutError):  # (lost: its task ended, or runs again)
                    distributed.Variable(ended).get(timeout=0)
                    raise OSError(
                        "a state handed on from task to task was lost with both "
                        "the workers that held it: run again"
                    )
                time.sleep(self.POLL)

    def hand_on(self, state):
        """Hand ``state`` to the next task (nothing for the last): kept on
        this worker, then copied to another (the next in address order)."""
        import distributed

        if self.last:
            return
        client, here = distributed.get_client(), distributed.get_worker().address
        workers = sorted(client.scheduler_info(n_workers=-1)["workers"])
        others = [w for w in workers if w > here] + [w for w in workers if w < here]
        for name, holder in zip(self.names(), [here, *others][: self.COPIES], strict=False):
            # (copies of their own, not replicas of one: Dask's memory manager
            # drops the replicas that no task needs; in a list: a tuple's items
            # would each be a future of their own)
            (future,) = client.scatter([state], workers=[holder], hash=False)
            distributed.Variable(name).set(future)

    def ended(self):
        """Say that this task has ended (a state lost since is not handed on again)."""
        import distributed

        if not self.last:
            distributed.Variable(self.names()[-1]).set(True)


@contextlib.contextmanager
def _seceded():
    """The block run outside the worker's pool of task threads, which may
    start another task meanwhile (a wait for another task's value)."""
    import distributed

    distributed.secede()
    try:
        yield
    finally:
        distributed.rejoin()


def workers_of(client):
    """How many workers the cluster of ``client`` has now (at least 1)."""
    return max(1, len(client.scheduler_info(n_workers=-1)["workers"]))


def _run(function, x64, args, *item):
    """A task on a worker: ``function(*args, *item)`` in the sender's
    precision, its results on the host (:func:`on_host`)."""
    import jax

    _set_up()
    with jax.enable_x64(x64):
        result = on_host(function(*args, *item))
    if item and isinstance(item[-1], Baton):
        item[-1].ended()
    return result


def on_host(tree):
    """``tree`` with its JAX arrays as NumPy's (small to send back), but for
    PRNG keys (which pickle as they are). A tree with none is returned as it
    is: ``jax.tree.map`` would sort its dicts' keys (a table's columns)."""
    import jax
    import numpy as np

    def host(a):
        is_key = isinstance(a, jax.Array) and jax.dtypes.issubdtype(a.dtype, jax.dtypes.prng_key)
        return np.asarray(a) if isinstance(a, jax.Array) and not is_key else a

    if all(host(leaf) is leaf for leaf in jax.tree.leaves(tree)):
        return tree
    return jax.tree.map(host, tree)


@functools.cache
def _set_up():
    """A worker process set up as the command line sets up its own
    (:mod:`jaxadapt.runtime`), once, before its first task."""
    from jaxadapt import runtime

    runtime.use_wide_vectors()
    runtime.retain_freed_memory()
    runtime.cache_compilations()


def shard_bounds(frames, workers):
    """``(start, stop)`` of the shards of a render of ``frames`` frames split
    in time for ``workers`` workers: :data:`SHARDS_PER_WORKER` each, none
    shorter than :data:`SHARD_LEAST` frames (but the only one), as even as
    whole frames allow."""
    import numpy as np

    n = max(1, min(SHARDS_PER_WORKER * workers, frames // SHARD_LEAST))
    edges = np.linspace(0, frames, n + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def shard_states(client, op, params, source, bounds, key, budget, option):
    """The state of operator module ``op`` at the first frame of each shard
    ``bounds`` of ``source``, exactly (up to rounding) as one process
    reaches it, for an operator that composes in time (``transition``:
    :attr:`~jaxadapt.operators.Supports.composable`).

    Each shard but the last is reduced on the cluster to the affine map it
    applies to the state (:func:`jaxadapt.pipeline.transition`); the
    viewer's state before the first frame (``op.init``, which reads that
    frame here) is carried through the maps in order by
    :func:`jaxadapt.physiology.kinetics.affine_sequence` (on a GPU an
    associative scan over the shards).
    """
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxadapt import pipeline
    from jaxadapt.physiology import kinetics

    first = jnp.asarray(source.frames(np.arange(1)))[0]
    gaze = jnp.asarray(source.gaze(np.arange(1)), jnp.float32)[0]
    state = op.init(params, first, gaze=gaze, key=key, adaptation=source.adaptation)
    if len(bounds) == 1:
        return [state]
    parts = [pipeline.part(source, a, b) for a, b in bounds[:-1]]
    transition = functools.partial(pipeline.transition, budget=budget)
    maps = list(in_order(client, transition, (op, params), parts, option))
    a, b = (jax.tree.map(lambda *x: jnp.stack(x), *m) for m in zip(*maps, strict=True))
    states = jax.tree.map(kinetics.affine_sequence, state, a, b)
    return [jax.tree.map(lambda x, k=k: x[k], states) for k in range(len(bounds))]
