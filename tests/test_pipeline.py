"""A sequence through an operator a chunk at a time (:mod:`jaxadapt.pipeline`)."""

import os
import threading
import types
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxadapt import io, pipeline, runtime, scenes
from jaxadapt.operators import classic, jacobs2015, pattanaik2000


def _step_source(T=7, H=5, W=13, adaptation=None):
    """T frames of textured grey, 0.01 cd/m2 for two frames, then 1000."""
    rng = np.random.default_rng(0)
    level = np.where(np.arange(T) < 2, 0.01, 1000.0)[:, None, None, None]
    frames = (rng.uniform(0.5, 2.0, (T, H, W, 3)) * level).astype(np.float32)
    return pipeline.Source(
        "step",
        np.arange(T) / 30.0,
        np.full(T, 1 / 30.0),
        lambda idx: frames[idx],
        lambda idx: np.tile([(W - 1) / 2, (H - 1) / 2], (len(idx), 1)),
        "log_average",
        adaptation,
        30.0,
        (H, W),
    )


def _render(op, params, source, size):
    key = jax.random.key(3)
    chunks = list(pipeline.chunks(op, params, source, size, key=key))
    return np.concatenate([out for _, out, _ in chunks]), pipeline.concatenate(
        [table for _, _, table in chunks]
    )


def _tunnel():
    """The 2000 operator as ``jaxadapt render --scene tunnel`` runs it, on
    1 s of a 32x18 drive: a global state, and a foveal goal that follows
    the scene's gaze."""
    source = pipeline.from_scene(scenes.tunnel_drive(32, 18, duration=1.0))
    params = pattanaik2000.Params(goal=source.goal, pixels_per_degree=source.pixels_per_degree)
    return pattanaik2000, params, source


@pytest.mark.slow
@pytest.mark.parametrize(
    ("case", "size", "atol"),
    [
        pytest.param(
            lambda: (
                pattanaik2000,
                pattanaik2000.Params(background="gaussian", background_scale=2.0),
                _step_source(T=4, adaptation=0.01),
            ),
            2,
            1e-5,
            id="pattanaik2000-local-given-adaptation",
        ),
        pytest.param(
            lambda: (jacobs2015, jacobs2015.Params(), _step_source(T=4)), 2, 1e-5, id="jacobs2015"
        ),
        pytest.param(lambda: (classic, classic.Params(), _step_source(T=4)), 2, 1e-5, id="classic"),
        # 30 frames 7 at a time: four chunks and a shorter last one
        pytest.param(_tunnel, 7, 1e-6, id="pattanaik2000-foveal-tunnel"),
    ],
)
def test_chunks_give_the_frames_and_diagnostics_of_one_call(case, size, atol):
    """A sequence rendered ``size`` frames at a time, each chunk starting
    from the state the last one left, gives the frames and diagnostics of
    one call on the whole sequence."""
    op, params, source = case()
    whole, whole_table = _render(op, params, source, size=len(source.times))
    out, table = _render(op, params, source, size=size)
    np.testing.assert_allclose(out, whole, atol=atol)
    # the sequence changes across a chunk's boundary (the step; the tunnel's frame 14)
    assert any(not np.allclose(out[k - 1], out[k], atol=1e-3) for k in range(size, len(out), size))
    for name, column in whole_table.items():
        np.testing.assert_allclose(table[name], column, rtol=1e-5, atol=1e-7)


def _drained(stream):
    """The display frames of a stream of chunks, and the state it ended in."""
    outs = []
    while True:
        try:
            outs.append(next(stream)[1])
        except StopIteration as end:
            return np.concatenate(outs), end.value


@pytest.mark.parametrize("background", ["global", "gaussian"])
def test_parts_started_from_their_composed_maps_give_the_whole(background):
    """A sequence split in time, each part started from the state that the
    affine maps of the parts before it give (``transition``, composed over
    chunks of 2 frames), gives the frames and the final state of the whole;
    and a part's map is what its steps do to any state, one the sequence
    never reaches too."""
    op, params = pattanaik2000, pattanaik2000.Params(background=background, background_scale=2.0)
    source = _step_source(T=8, adaptation=0.01)
    whole, final = _drained(pipeline.chunks(op, params, source, 8))
    state = op.init(params, jnp.asarray(source.frames([0]))[0], adaptation=0.01)
    elsewhere = jax.tree.map(
        lambda x: jnp.full_like(state[0], x), pattanaik2000.State(5, 7, 0.5, 0.9)
    )
    outs = []
    for start, stop in ((0, 2), (2, 6), (6, 8)):  # (chunks of one length: one compilation)
        part = pipeline.part(source, start, stop)
        np.testing.assert_array_equal(part.times, source.times[start:stop])
        a, b = pipeline.transition(op, params, part, 2)
        for y0 in (state, elsewhere):
            out, end = _drained(pipeline.chunks(op, params, part, 2, state=y0))
            for x, y in zip(jax.tree.map(lambda a, b, y: a * y + b, a, b, y0), end, strict=True):
                np.testing.assert_allclose(x, y, rtol=2e-6)
        outs.append(_drained(pipeline.chunks(op, params, part, 2, state=state))[0])
        state = jax.tree.map(lambda a, b, y: a * y + b, a, b, state)
    np.testing.assert_allclose(np.concatenate(outs), whole, atol=1e-5)
    for x, y in zip(state, final, strict=True):
        np.testing.assert_allclose(x, y, rtol=2e-6)


@pytest.mark.slow
def test_a_local_background_from_a_given_adaptation_compiles_run_twice(count_calls):
    # init gives a given adaptation as the maps that run carries: as
    # scalars, the second chunk would compile run again, for three
    # compilations of two shapes.
    traces = count_calls(pattanaik2000._operator, "frame_goals")
    params = pattanaik2000.Params(background="gaussian", background_scale=2.0)
    source = _step_source(T=7, H=7, W=11, adaptation=0.5)  # a shape no other test uses
    assert len(list(pipeline.chunks(pattanaik2000, params, source, size=3))) == 3
    assert len(traces) == 2


def test_collected_frames_are_copies_not_views_of_their_chunk():
    kept, table = pipeline.collect(classic, classic.Params(), _step_source(), keep={0, 4}, size=7)
    assert sorted(kept) == [0, 4] and len(table["t"]) == 7
    for frame in kept.values():
        assert frame.shape == (5, 13, 3) and frame.base is None
    # An index past the end is named, not left out without a word.
    with pytest.raises(
        ValueError, match=r"^keep: expected frame indices from 0 to 6, got \[7, 9\]"
    ):
        pipeline.collect(classic, classic.Params(), _step_source(), keep={0, 7, 9})
    with pytest.raises(ValueError, match="^keep: expected a whole number"):
        pipeline.collect(classic, classic.Params(), _step_source(), keep={-1})


def test_a_non_finite_display_frame_is_refused_not_written_black():
    def run(params, frames, dt, *, gaze=None, state=None):  # NaN in the second chunk's last
        out = np.zeros(frames.shape, np.float32)
        out[-1, 0, 0, 1] = np.nan if state == 1 else 0.0
        return out, types.SimpleNamespace(final_state=state + 1)

    broken = types.SimpleNamespace(
        __name__="broken", init=lambda *a, **k: 0, run=run, diagnostics_table=lambda d: {}
    )
    with pytest.raises(FloatingPointError, match=r"^broken: display frame 5 holds non-finite"):
        list(pipeline.chunks(broken, None, _step_source(T=6), size=3))


def test_bad_arguments_are_named(tmp_path):
    path = tmp_path / "frame.exr"
    io.write_image(path, np.ones((4, 6, 3), np.float32))
    for kwargs, message in (
        ({"paths": []}, "paths: expected at least one HDR file"),
        ({"fps": 0.0}, "fps: expected a positive frame rate"),
        ({"fps": float("nan")}, "fps: expected a positive frame rate"),
        ({"multiplier": -1.0}, "multiplier: expected a positive finite factor"),
        ({"multiplier": float("nan")}, "multiplier: expected a positive finite factor"),
        ({"multiplier": 1e-50}, "multiplier: expected a positive finite factor"),
        # infinite in float32: the message, with no NumPy overflow warning before it
        ({"multiplier": 1e40}, "multiplier: expected a positive finite factor"),
    ):
        arguments = {"paths": [path], "fps": 30.0, "multiplier": 1.0} | kwargs
        with warnings.catch_warnings(), pytest.raises(ValueError, match=f"^{message}"):
            warnings.simplefilter("error")
            pipeline.from_files(**arguments)
    for size in (0, 2.5, "4"):
        with pytest.raises(ValueError, match="^size: expected a whole number of frames >= 1"):
            list(pipeline.chunks(classic, classic.Params(), _step_source(), size))


def test_files_are_timed_by_the_first_files_frame_rate(tmp_path):
    # The library, not only the command line, reads the header's rate: a
    # 23.976 frames/s EXR sequence is timed at its own rate unless fps is given.
    paths = [tmp_path / f"f{i}.exr" for i in range(3)]
    for path in paths:
        io.write_image(path, np.ones((2, 3, 3), np.float32), fps=24000 / 1001)
    np.testing.assert_allclose(pipeline.from_files(paths).dt, 1001 / 24000, rtol=1e-12)
    np.testing.assert_allclose(pipeline.from_files(paths).times[2], 2002 / 24000, rtol=1e-12)
    np.testing.assert_allclose(pipeline.from_files(paths, fps=10.0).dt, 0.1)  # given: it wins
    io.write_image(paths[0], np.ones((2, 3, 3), np.float32))  # no rate in the first file
    np.testing.assert_allclose(pipeline.from_files(paths).dt, 1 / pipeline.FILE_FPS)


def test_one_path_is_one_still_image(tmp_path, monkeypatch):
    # A string or a Path is one path, not a sequence of one-letter paths
    # ("i: no such file") nor a Path to iterate.
    monkeypatch.chdir(tmp_path)
    io.write_image(tmp_path / "still.exr", np.full((2, 3, 3), 7.0, np.float32))
    for path in ("still.exr", str(tmp_path / "still.exr"), tmp_path / "still.exr"):
        source = pipeline.from_files(path)
        assert len(source.times) == 1
        np.testing.assert_array_equal(source.frames(np.arange(1)), np.full((1, 2, 3, 3), 7.0))


def _resident_bytes():
    """This process's resident memory now (Linux), bytes; None elsewhere."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:
        return None


@pytest.mark.slow
def test_memory_stays_flat_over_a_long_sequence():
    # 1,200 frames of 128x128 (240 MB of input, as much of display frames)
    # streamed 4 at a time: what is resident after 50 chunks is what is
    # resident at the end, and no frames are left alive in JAX.
    T, H, W = 1200, 128, 128
    base = np.random.default_rng(0).uniform(1.0, 100.0, (H, W, 3)).astype(np.float32)
    source = pipeline.Source(
        "long",
        np.arange(T) / 30.0,
        np.full(T, 1 / 30.0),
        lambda idx: np.stack([base * (1 + (i % 50)) for i in idx]),
        lambda idx: np.tile([(W - 1) / 2, (H - 1) / 2], (len(idx), 1)),
        "log_average",
        None,
        30.0,
        (H, W),
    )
    resident, arrays = [], []
    for n, _ in enumerate(pipeline.chunks(pattanaik2000, pattanaik2000.Params(), source, 4)):
        if n in (50, T // 4 - 1):
            resident.append(_resident_bytes())
            arrays.append(len(jax.live_arrays()))
    assert arrays[1] <= arrays[0]
    if resident[0] is not None:
        assert resident[1] - resident[0] < 40e6  # kept display frames alone: 200 MB


def test_a_stage_that_fails_stops_the_stream_and_its_thread():
    def frames(idx):
        if idx[0] >= 6:
            raise ValueError("frame 6: unreadable")
        return np.ones((len(idx), 4, 4, 3), np.float32)

    source = _step_source(T=10)._replace(frames=frames)
    with pytest.raises(ValueError, match="^frame 6: unreadable"):
        for _ in pipeline.chunks(pattanaik2000, pattanaik2000.Params(), source, 3):
            pass
    consumed = []

    def consume(item):
        if item == 3:
            raise OSError("disk full")
        consumed.append(item)

    with pytest.raises(OSError, match="disk full"):
        with pipeline.behind(consume) as submit:
            for item in range(20):
                submit(item)
    assert consumed == [0, 1, 2]  # nothing after the failure
    assert not [t for t in threading.enumerate() if t.name.startswith("jaxadapt-")]


def test_chunk_size_follows_the_budget_and_the_frame_size():
    assert pipeline.chunk_size((1080, 1920)) == 7
    assert pipeline.chunk_size((2160, 3840)) == 1
    assert pipeline.chunk_size((10, 10)) == pipeline.MAX_CHUNK
    assert pipeline.chunk_size((1080, 1920), budget=2**32) == 28


def test_chunks_release_freed_memory_past_the_ceiling(monkeypatch):
    # the bound on a long render's memory: after each chunk, freed memory is
    # handed back when the process has grown by the budget past its size
    # after the first (benchmarks/README.md, "Memory of long renders")
    sizes = iter([100, 150, 1000, 120])  # bytes resident after each chunk
    released = []
    monkeypatch.setattr(runtime, "resident_bytes", lambda: next(sizes))
    monkeypatch.setattr(runtime, "release_freed_memory", lambda: released.append(1) or True)
    source = pipeline.from_scene(scenes.tunnel_drive(16, 9, duration=0.5))
    chunks = pipeline.chunks(pattanaik2000, pattanaik2000.Params(), source, size=4, budget=500)
    assert len(list(chunks)) == 4
    assert released == [1]  # at the third chunk only: 1000 > 100 + 500


def test_a_ceiling_outgrown_again_at_once_is_raised_not_released_again(monkeypatch):
    # pages handed back and faulted in again within one chunk are the
    # working set (a video's decoder and encoder): the ceiling moves up
    sizes = iter([100, 1000, 1000, 1200, 1600, 300])  # bytes resident at each call
    released = []
    monkeypatch.setattr(runtime, "resident_bytes", lambda: next(sizes))
    monkeypatch.setattr(runtime, "release_freed_memory", lambda: released.append(1) or True)
    ceiling = runtime.MemoryCeiling(500)
    assert [ceiling() for _ in range(6)] == [False, True, False, False, True, False]
    assert len(released) == 2 and ceiling.ceiling == 1500  # 1000 + 500, from the third call
