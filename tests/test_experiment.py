"""jaxadapt.experiment without a browser: the display model against the
transfer functions' published values, the dithering's mean luminance, the
stimuli against the protocol, and a session's table through answers,
crashes and resumes."""

import dataclasses
import json

import jax
import numpy as np
import pytest
from cli_runs import assert_one_line_error, run

from jaxadapt.display import dither
from jaxadapt.experiment.calibration import PAPER_DISPLAY, Display, dithered_codes, read_display
from jaxadapt.experiment.session import TRIAL_COLUMNS, Session, SessionError
from jaxadapt.experiment.stimuli import Stimuli
from jaxadapt.psychophysics import design, trials
from jaxadapt.psychophysics.displays import afterimage_renders, mesopic_render

#: A display of big pixels close by (8.7 pixels a degree): images of a few
#: tens of pixels, rendered in seconds.
SMALL = {"distance_m": 0.5, "pixel_pitch_mm": 1.0}


def test_display_model_against_published_values():
    # The paper's assumed display (Appendix A): 64 pixels a degree.
    assert PAPER_DISPLAY.pixels_per_degree == pytest.approx(64.0, rel=2e-3)
    # sRGB (IEC 61966-2-1): code 128 is 21.586 % of white; code 10 on the
    # linear segment, 10 / 255 / 12.92.
    d = Display(white=100.0)
    np.testing.assert_allclose(d.emitted([0, 10, 128, 255]), [0, 0.30353, 21.586, 100], rtol=1e-4)
    # A black level adds to every code: white stays white.
    lifted = Display(white=100.0, black=0.5)
    np.testing.assert_allclose(lifted.emitted([0, 255]), [0.5, 100.0])
    # SMPTE ST 2084: a signal of 0.508 is 100 cd/m2, 0.7518 is 1000; a PQ
    # display clips at its own white.
    pq = Display(white=1000.0, transfer="pq")
    codes = np.array([0.50808, 0.75183]) * 255
    np.testing.assert_allclose(pq.emitted(codes), [100.0, 1000.0], rtol=2e-3)
    assert pq.emitted(255) == 1000.0
    gamma = Display(white=80.0, transfer="gamma", gamma=2.4)
    assert gamma.emitted(128) == pytest.approx(80.0 * (128 / 255) ** 2.4)


@pytest.mark.parametrize(
    "display",
    [Display(), Display(transfer="gamma"), Display(white=1000.0, transfer="pq")],
    ids=["srgb", "gamma", "pq"],
)
@pytest.mark.parametrize("luminance", [1.2e-3, 4.1e-2, 5.5e-2, 2.2e-2, 27.0])
def test_dithered_codes_show_the_luminance_asked_on_average(display, luminance):
    # The darkest tile of the mesopic chart (1.2e-3 cd/m2) is a fraction of
    # one code step on every transfer; its mean over a 128x128 patch and 8
    # patterns is within 1 % of what is asked.
    L = np.full((128, 128, 3), luminance, np.float32)
    shown = [display.emitted(dithered_codes(display, L, jax.random.key(i))) for i in range(8)]
    assert np.mean(shown) == pytest.approx(luminance, rel=0.01)
    # Dithering the encoded value instead (the operator's temporal
    # dithering) keeps the mean code, not the mean light: between codes 1
    # and 2 of a power-law display it is off by far more than 1 %.
    if display.transfer == "gamma" and luminance < 2e-3:
        v = (luminance / display.white) ** (1 / display.gamma)
        codes = np.asarray(dither(jax.numpy.asarray(L[..., 0] * 0 + v), jax.random.key(0))) * 255
        assert np.mean(display.emitted(codes)) / luminance - 1 > 0.1


def test_display_files_are_checked(tmp_path):
    path = tmp_path / "display.json"
    path.write_text(json.dumps({"white": 250, "refresh_hz": 120}))
    d = read_display(path)
    assert (d.white, d.refresh_hz, d.black) == (250, 120, 0.0)
    for content, says in (
        ({"whit": 100}, "unknown key 'whit'"),
        ({"white": -1}, "white: expected a positive number"),
        ({"black": 200}, "black: expected a luminance from 0 up to white"),
        ({"transfer": "hlg"}, "transfer: expected one of srgb, gamma, pq"),
        ([1, 2], "expected a JSON object"),
    ):
        path.write_text(json.dumps(content))
        with pytest.raises(ValueError, match=says) as error:
            read_display(path)
        assert str(path) in str(error.value)
    path.write_text("{not json")
    with pytest.raises(ValueError, match="expected a display's JSON object"):
        read_display(path)


@pytest.fixture(scope="module")
def afterimage():
    return Stimuli(design.AFTERIMAGE, Display(**SMALL), jax.random.key(0))


def _codes(png):
    from io import BytesIO

    from PIL import Image

    return np.asarray(Image.open(BytesIO(png)).convert("RGB"))


def _luminance(display, png):
    return display.emitted(_codes(png)) @ np.array([0.2126, 0.7152, 0.0722])


def test_afterimage_stimuli_on_the_display(afterimage):
    d = afterimage.display
    # 50 ms and 2.5 s at 60 Hz: 3 and 150 display frames, images of 3 frames.
    standard = afterimage.interval()
    assert standard.shown == 1 and sum(standard.holds[:1]) == 3
    assert sum(standard.holds[1:]) == 150
    # The standard's flash measures 27 cd/m2 at its brightest (the centre
    # of the disk), each test 10^level times that, within the dithering.
    W = afterimage.size[0]
    centre = (slice(W // 2 - 2, W // 2 + 2),) * 2

    def flash(interval):
        return np.mean(_luminance(d, afterimage.images[interval.images[0]])[centre])

    assert flash(standard) == pytest.approx(27.0, rel=0.02)
    # The fixation cross 2.5 degrees below the flash's centre (the paper:
    # "just below the position of the flash unit"), 0.5 degrees wide.
    ppd = d.pixels_per_degree
    assert afterimage.fixation["y"] == round(2.5 * ppd)
    assert afterimage.fixation["size"] == max(5, round(0.5 * ppd))
    for j, test in enumerate(design.AFTERIMAGE.tests):
        assert flash(afterimage.interval(1, j)) == pytest.approx(test, rel=0.02)
    # The strong afterimage (manipulated tests) outshines the weak one.
    weak, strong = (
        max(
            np.max(_luminance(d, afterimage.images[k]))
            for k in afterimage.interval(c, 0).images[1:4]
        )
        for c in (0, 1)
    )
    assert strong > weak > 0


def test_mesopic_charts_measure_their_level_at_the_white_tile():
    # "5.5e-2 cd/m2 at the white tile" (§4.2.1): measured on the display
    # model, over the 25 dithered images of an interval; a manipulated
    # chart has its control's mean light.
    from jaxadapt.color import photopic_luminance
    from jaxadapt.experiment.stimuli import _white_tile

    d = Display(**SMALL)
    st = Stimuli(design.MESOPIC, d, jax.random.key(0))
    tile = _white_tile(*st.size)

    def shown(interval):
        images = interval.images[: interval.shown]
        light = [photopic_luminance(d.emitted(_codes(st.images[k]))) for k in images]
        return np.mean([y[tile].mean() for y in light]), np.mean(light)

    white, _ = shown(st.interval())
    assert white == pytest.approx(5.5e-2, rel=0.01)
    for j, level in enumerate(design.MESOPIC.tests):
        (white, mean), (_, manipulated) = shown(st.interval(0, j)), shown(st.interval(1, j))
        assert white == pytest.approx(level, rel=0.01)
        assert manipulated == pytest.approx(mean, rel=0.01)


def test_stepped_renders_equal_the_runs():
    # The experiment renders frame by frame (its images are large); the
    # simulations run whole sequences: the same frames.
    P = dataclasses.replace(design.MESOPIC, presentation_s=0.25)
    options = dict(key=jax.random.key(3), width=32, height=24, fps=20.0, effects=True)
    run = mesopic_render(P, [5.5e-2, 4.1e-2], **options)
    stepped = mesopic_render(P, [5.5e-2, 4.1e-2], stepped=True, **options)
    np.testing.assert_allclose(stepped, run, rtol=1e-5, atol=1e-5 * float(np.max(run)))
    A = dataclasses.replace(design.AFTERIMAGE, blank_s=0.5)
    run, stepped = (
        afterimage_renders(A, width=16, height=16, fps=20.0, lead_s=0.0, stepped=s)
        for s in (False, True)
    )
    for a, b in ((run.weak, stepped.weak), (run.strong, stepped.strong)):
        np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-5 * float(np.max(a)))
    assert float(run.scale) == pytest.approx(float(stepped.scale), rel=1e-6)


def test_stimuli_a_display_cannot_show_are_refused():
    with pytest.raises(ValueError, match="white 20 cd/m2 cannot show"):
        Stimuli(design.AFTERIMAGE, Display(white=20.0, **SMALL), jax.random.key(0))
    with pytest.raises(ValueError, match="black 0.05 cd/m2 is not below the dimmest level"):
        Stimuli(design.MESOPIC, Display(black=0.05, **SMALL), jax.random.key(0))


def _spec(**changes):
    spec = {
        "participant": "p01",
        "study": "afterimage",
        "training": 4,
        "repetitions": 1,
        "dark_seconds": 0.0,
        "display": Display(**SMALL).to_json(),
        "software": "test",
        "seed": 11,
    }
    return spec | changes


def _brighter(t):
    """The interval of the brighter image (the standard where they are equal)."""
    test_brighter = t["level_index"] > 2
    return 1 if t["test_first"] == test_brighter else 2


def _answer_all(session, chooser=_brighter, flag=()):
    """Answer every trial the session gives; ``flag``: trial indices whose
    first attempt drops a frame."""
    flagged = set()
    while (state := session.next())["phase"] == "trial":
        i = state["trial"]
        dropped = int(i in flag and i not in flagged)
        flagged.add(i)
        assert session.answer(i, chooser(session.plan[i]), 400.0, [50, 50, 2500, 2500], dropped)
    return state


def test_a_session_is_kept_and_continued(tmp_path):
    folder = tmp_path / "p01"
    s = Session(folder, _spec())
    assert (folder / "trials.csv").read_text() == ",".join(TRIAL_COLUMNS) + "\n"
    assert len(s.plan) == 4 + 5 + 15  # training, control, main (10 manipulated, 5 control)
    first = s.next()
    assert first == {"phase": "trial", "trial": 0, "break": False}
    # An answer to another trial than the one pending (a page posting
    # twice) is not written.
    assert not s.answer(1, 1, 300, [50] * 4, 0)
    assert s.answer(0, 2, 300, [50] * 4, 0)
    assert not s.answer(0, 2, 300, [50] * 4, 0)
    # A crash while the next row was written: its trial is shown again.
    with open(folder / "trials.csv", "a") as f:
        f.write("p01,afterimage,training,1,con")
    s = Session(folder, _spec(seed=None))
    assert s.spec["seed"] == 11 and len(s.rows) == 1
    assert s.next()["trial"] == 1
    # Another participant's options, or another seed, are refused.
    with pytest.raises(SessionError, match="participant 'p01', not 'p02'"):
        Session(folder, _spec(participant="p02"))
    with pytest.raises(SessionError, match="seed 11, not 12"):
        Session(folder, _spec(seed=12))
    # A break comes between blocks; a flagged trial comes back at the end
    # of its block.
    breaks = []
    while (state := s.next())["phase"] == "trial":
        breaks.append(state["break"])
        i = state["trial"]
        s.answer(i, 1, 300, [50] * 4, int(i == 5 and not any(r["trial"] == "5" for r in s.rows)))
    assert state["phase"] == "done"
    table = trials.read_trials(folder / "trials.csv")
    assert table.left_out == {"training": 4, "flagged": 1, "excluded": 0}
    assert sum(breaks) == 2  # control block, main block
    order = [int(r["trial"]) for r in s.rows]
    assert sorted(order) == sorted([*range(len(s.plan)), 5])
    control = [i for i, t in enumerate(s.plan) if t["block"] == "control"]
    assert order[order.index(control[-1]) + 1] == 5  # shown again after its block's last
    # A finished session is not overwritten, or continued.
    with pytest.raises(SessionError, match="finished afterimage session"):
        Session(folder, _spec())


def test_training_below_70_percent_ends_the_session_and_the_fit_excludes(tmp_path):
    good = Session(tmp_path / "a", _spec())
    assert _answer_all(good)["phase"] == "done"
    wrong = Session(tmp_path / "b", _spec(participant="p02"))
    state = _answer_all(wrong, chooser=lambda t: 3 - _brighter(t))
    assert state["phase"] == "excluded" and wrong.training_accuracy() == 0.0
    assert len(wrong.rows) == 4  # nothing after the training block
    # The fit reads both tables joined: p02 excluded, its training rows left out.
    rows = (tmp_path / "a" / "trials.csv").read_text().splitlines()
    rows += (tmp_path / "b" / "trials.csv").read_text().splitlines()[1:]
    (tmp_path / "both.csv").write_text("\n".join(rows) + "\n")
    table = trials.read_trials(tmp_path / "both.csv")
    assert table.excluded == {"p02": 0.0}
    assert set(table.participant) == {"p01"} and len(table.level) == 20
    # test_chosen is the response: the brighter image chosen here.
    np.testing.assert_array_equal(table.n_yes, table.level > 0)


def test_the_command_refuses_bad_input_in_one_line(tmp_path, capsys):
    base = ["experiment", "afterimage", "--participant", "p01", "--no-browser"]
    bad = tmp_path / "display.json"
    bad.write_text('{"white": "bright"}')
    out = tmp_path / "out"
    status, err = run(capsys, *base, "--out", str(out), "--display", str(bad))
    assert_one_line_error(status, err, "display.json", "white: expected a positive number")
    assert not out.exists()
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("keep me")
    status, err = run(capsys, *base, "--out", str(tmp_path / "other"))
    assert_one_line_error(status, err, "--out", "holding other files")
    status, err = run(capsys, *base, "--out", str(out), "--training", "0", "--repetitions", "0")
    assert_one_line_error(status, err, "--training, repetitions: expected some trials")
    dim = tmp_path / "dim.json"
    dim.write_text(json.dumps({"white": 20, **SMALL}))
    status, err = run(capsys, *base, "--out", str(out), "--display", str(dim))
    # (after the lines of progress: the stimuli are rendered to be measured)
    assert status == 2 and err.splitlines()[-1] == (
        f"jaxadapt: error: --display: {dim}: white 20 cd/m2 cannot show the standard, "
        "27 cd/m2 at its brightest"
    )
    assert not out.exists()  # refused before anything is written
    # A finished session: refused, and left as it is.
    display = tmp_path / "small.json"
    display.write_text(json.dumps(SMALL))
    spec = _spec(training=2, repetitions=0, display=read_display(display).to_json())
    _answer_all(Session(out, spec))
    before = (out / "trials.csv").read_bytes()
    argv = [*base, "--out", str(out), "--display", str(display), "--training", "2"]
    status, err = run(capsys, *argv, "--repetitions", "0")
    assert_one_line_error(status, err, "--out", "finished afterimage session")
    assert (out / "trials.csv").read_bytes() == before
