"""A render split in time on a Dask cluster (``render --scheduler``,
``--workers``): each shard of frames rendered by a worker into the staging
folder, from the state the viewer is in at its first frame; the video's
parts joined at the end (:mod:`jaxadapt.cluster` cuts and sends the work)."""

import contextlib
from typing import Any, NamedTuple

from jaxadapt.cli._frames import FrameOutputs

#: The folder, in the staging folder, of a video's parts rendered on a cluster.
VIDEO_PARTS = "video_parts"


class Work(NamedTuple):
    """What every shard of a render on a cluster shares: the render's
    :class:`~jaxadapt.cli.render.Plan`, the staging folder (on storage the
    workers reach), the sequence's key, the chunk and memory options, the
    frame times of a video input (None for frames counted at the plan's
    rate) and the video codec."""

    plan: Any
    staging: Any
    key: Any
    chunk: Any
    budget: int
    times: Any
    codec: str


class Shard(NamedTuple):
    """What a shard hands back: its diagnostics columns, the frames it kept
    for the contact sheet (:class:`~jaxadapt.cli._frames.FrameOutputs`)
    and the operator's state after its last frame."""

    table: dict
    kept: dict
    state: Any


def in_shards(client, work, bounds, name, option):
    """The :class:`Shard` results of a render split in time into ``bounds``
    (``(start, stop)`` each) over the cluster of ``client``, in order: each
    shard started from its exact state (:func:`jaxadapt.cluster.shard_states`)
    where operator ``name`` composes, independent shards for one without
    state, else the state handed from shard to shard
    (:func:`jaxadapt.cluster.handed_on`). Errors name ``option``."""
    from jaxadapt import cluster
    from jaxadapt.operators import OPERATORS

    plan, supports = work.plan, OPERATORS.supports(name)
    if supports.time_dependent and not supports.composable:
        return cluster.handed_on(client, _render_handed, (work,), bounds, option)
    if supports.time_dependent:
        args = (plan.op, plan.params, plan.source, bounds, work.key, work.budget, option)
        states = cluster.shard_states(client, *args)
    else:
        states = [None] * len(bounds)
    items = [(bounds_k, state) for bounds_k, state in zip(bounds, states, strict=True)]
    return cluster.in_order(client, _render_from, (work,), items, option)


def _ignored(*_):
    """What a shard does not do: send frames to the command's video, say
    its progress (the command says it as each shard comes back), hand its
    state on (a shard whose state was found before it started)."""


def _render_from(work, item):
    """A shard ``((start, stop), state)`` rendered from ``state``."""
    bounds, state = item
    return _render_shard(work, bounds, state)


def _render_handed(work, bounds, baton):
    """A shard rendered from the state the shard before hands on
    (:class:`jaxadapt.cluster.Baton`), its own handed on as soon as its
    last frame is computed, while its last frames are still being written."""
    return _render_shard(work, bounds, baton.taken, baton.hand_on)


def _render_shard(work, bounds, state, hand_on=_ignored):
    """A task on a worker: frames ``start`` to ``stop - 1`` of the plan of
    ``work`` rendered from ``state`` (the operator's ``init`` for None; or
    a function that returns it, called once the first frames are read),
    its frame files and its part of the video written into the staging
    folder; its :class:`Shard` (its state's arrays on the host, so that the
    table's columns keep their order). ``hand_on`` takes the state after
    the last frame as soon as it is computed."""
    from jaxadapt import cluster, io, pipeline

    (start, stop), plan = bounds, work.plan
    source = pipeline.part(plan.source, start, stop)
    tables = []
    with _shard_folder(work.staging) as staging, contextlib.ExitStack() as stack:
        send_video = _ignored
        if "mp4" in plan.formats:
            (staging / VIDEO_PARTS).mkdir(exist_ok=True)
            path = staging / VIDEO_PARTS / _part_name(start)
            coding = (plan.fps, plan.encoding, work.times, None, work.codec)
            send_video = stack.enter_context(io.video_writer(path, *coding, first=start))
        coding = (plan.encoding, plan.encoded)
        write = FrameOutputs(
            staging, plan.formats, plan.source.times, plan.fps, coding, send_video, _ignored
        )
        stream = pipeline.chunks(
            plan.op, plan.params, source, work.chunk, work.key, budget=work.budget, state=state
        )
        with contextlib.closing(stream), pipeline.behind(write) as submit:
            while True:
                try:
                    idx, linear, table = next(stream)
                except StopIteration as end:
                    state = end.value
                    hand_on(state)
                    break
                submit((idx + start, linear))
                tables.append(table)
    return Shard(pipeline.concatenate(tables), write.kept, cluster.on_host(state))


@contextlib.contextmanager
def _shard_folder(staging):
    """The folder a shard writes its files into: the staging folder (on a
    file system the workers share); for one at a URL (``--out`` in object
    storage), a temporary folder of the worker's whose files are put there
    once the shard has succeeded (a shard lost half-way puts nothing)."""
    import tempfile
    from pathlib import Path

    from jaxadapt import io

    if not io.is_url(staging):
        yield staging
        return
    fs, shared = io.filesystem(staging)
    with tempfile.TemporaryDirectory(prefix="jaxadapt-shard-") as folder:
        yield Path(folder)
        with io.url_errors(staging):
            fs.put(f"{folder}/", f"{shared}/", recursive=True)


def tidied(staging):
    """Remove from the staging folder what the tasks of killed workers left
    half-written: the temporary files of the atomic writers
    (:func:`jaxadapt.io.atomic_path`, hidden names), whose shards Dask ran
    again in full elsewhere."""
    for path in staging.glob(".*"):
        if path.is_file():
            path.unlink()


def _part_name(start):
    """The name of the video's part whose first frame is ``start``."""
    return f"{start:010d}.mp4"


def joined_parts(staging, shared, starts, fps, video):
    """``video.mp4`` in ``staging`` of the parts the shards starting at
    frames ``starts`` wrote into ``shared`` (:data:`VIDEO_PARTS`; a
    folder, or a URL) at ``fps``, with the frame times, audio and
    subtitles of ``video`` (``(times, path)`` of a video input, or None);
    the parts of a shared folder then removed (those at a URL go with its
    staging folder)."""
    import shutil

    from jaxadapt import io

    parts = [(start, f"{shared}/{VIDEO_PARTS}/{_part_name(start)}") for start in starts]
    times, copy_from = video or (None, None)
    io.joined_video(staging / "video.mp4", parts, fps, times, copy_from)
    if not io.is_url(shared):
        shutil.rmtree(shared / VIDEO_PARTS)
