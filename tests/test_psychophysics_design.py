"""Experiment designs (§4.1.1, §4.2.1 of the 2015 paper) and trial tables."""

import csv
import itertools
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats
from hypothesis import given
from hypothesis import strategies as st

from jaxadapt.psychophysics import design, fit_table, separation, trials
from jaxadapt.psychophysics import psychometric as F  # noqa: N812

A, M = design.AFTERIMAGE, design.MESOPIC
many_trial_lists = jax.jit(jax.vmap(lambda key: design.trial_list(A, key)))


def test_presets_are_the_papers_protocols():
    # §4.1.1: standard 27 cd/m2, tests 14, 19, 27, 35, 49 cd/m2, 50 ms + 2.5 s.
    assert A.standard == 27.0 and A.tests == (14.0, 19.0, 27.0, 35.0, 49.0)
    assert (A.presentation_s, A.blank_s, A.exclusion) == (0.05, 2.5, 0.7)
    # §4.2.1: 5.5e-2 cd/m2 at the white tile, tests 4.1e-2 ... 7.5e-2 cd/m2,
    # 1.25 s + 0.75 s, after five minutes in darkness.
    assert M.standard == 5.5e-2 and M.tests == (4.1e-2, 4.8e-2, 5.5e-2, 6.8e-2, 7.5e-2)
    assert (M.presentation_s, M.blank_s, M.dark_adaptation_s) == (1.25, 0.75, 300.0)
    np.testing.assert_allclose(A.levels, np.log10(np.array(A.tests) / 27.0))
    assert A.levels[2] == 0.0 and np.all(np.diff(A.levels) > 0)
    assert design.PROTOCOLS == {"afterimage": A, "mesopic": M}


@pytest.mark.parametrize("protocol", [A, M])
def test_blocks_hold_the_papers_counts(protocol):
    t = jax.tree.map(np.asarray, design.trial_list(protocol, jax.random.key(0)))
    # 20 training trials, then "each test image was paired with the standard
    # 20 times", then "30 repetitions of each manipulated test condition and
    # 10 additional repetitions of each control test condition".
    assert protocol.n_trials == len(t.block) == 20 + 5 * 20 + 5 * (30 + 10)
    assert np.all(np.diff(t.block) >= 0)  # blocks in order
    assert t.training.sum() == 20 and np.all(t.training == (t.block == 0))
    training_levels = protocol.levels[t.level_index[t.training]]
    assert np.all(training_levels != 0)  # every training answer is right or wrong
    for block, condition, per_level in [(1, 0, 20), (2, 1, 30), (2, 0, 10)]:
        cell = (t.block == block) & (t.condition == condition)
        np.testing.assert_array_equal(np.bincount(t.level_index[cell], minlength=5), per_level)
        for i in range(5):  # counter-balanced: half with the test first
            assert t.test_first[cell & (t.level_index == i)].sum() == per_level // 2
    np.testing.assert_allclose(t.level, protocol.levels[t.level_index])
    np.testing.assert_allclose(t.luminance, np.array(protocol.tests)[t.level_index])


def test_same_key_same_sequence_and_vmap_equals_a_loop():
    keys = jax.random.split(jax.random.key(3), 4)
    batch = many_trial_lists(keys)
    for i, key in enumerate(keys):
        single = design.trial_list(A, key)
        for a, b in zip(single, batch, strict=True):
            np.testing.assert_array_equal(a, b[i])
    again = many_trial_lists(keys)
    np.testing.assert_array_equal(again.level, batch.level)
    assert not np.array_equal(batch.level[0], batch.level[1])


def test_order_within_blocks_is_uniformly_random():
    # Over 2000 sequences, the first control-block trial is each of the 100
    # control-block cells' trials about equally often: every level 1/5.
    t = many_trial_lists(jax.random.split(jax.random.key(4), 2000))
    first = np.asarray(t.level_index[:, 20])
    counts = np.bincount(first, minlength=5)
    assert np.all(np.abs(counts - 400) < 4 * np.sqrt(2000 * 0.2 * 0.8))
    # and the test comes first in about half of the trials at any position
    assert abs(np.asarray(t.test_first[:, 100]).mean() - 0.5) < 0.05


def test_every_order_of_a_block_is_equally_likely():
    # A block of 5 trials (5 levels, one repetition): its 120 orders over
    # 24,000 sequences, against the uniform distribution.
    five = design.Protocol(
        name="five", standard=27.0, tests=A.tests, blocks=(design.Block("b", (("control", 1),)),)
    )
    t = jax.jit(jax.vmap(lambda k: design.trial_list(five, k)))(
        jax.random.split(jax.random.key(6), 24_000)
    )
    index = {order: i for i, order in enumerate(itertools.permutations(range(5)))}
    seen = np.bincount([index[tuple(row)] for row in np.asarray(t.level_index)], minlength=120)
    assert scipy.stats.chisquare(seen).pvalue > 1e-3
    # A block of 200 (the paper's main block): any entry lands at each
    # position equally often, and two entries come in either order equally
    # often, over 4000 shuffles.
    n = 200
    words = jax.random.bits(jax.random.key(7), (4000, design._rounds(n), n), jnp.uint32)
    order = np.asarray(jax.jit(jax.vmap(lambda w: design._shuffle(w, n)))(words))
    assert np.all(np.sort(order, axis=1) == np.arange(n))
    for entry in (0, 137, 199):
        position = np.argmax(order == entry, axis=1)
        assert scipy.stats.chisquare(np.bincount(position // 10, minlength=20)).pvalue > 1e-3
    before = np.argmax(order == 0, axis=1) < np.argmax(order == 1, axis=1)
    assert abs(before.mean() - 0.5) < 4 * np.sqrt(0.25 / 4000)


def test_coin_tosses_are_fair_and_do_not_depend_on_the_order():
    # Odd cells: the extra trial's order is a fair coin, whatever position
    # it lands at (the coin and the shuffle share one draw of random words).
    odd = design.Protocol(
        name="odd",
        standard=1.0,
        tests=(0.5, 2.0),
        blocks=(design.Block("only", (("control", 3),)),),
    )
    t = jax.jit(jax.vmap(lambda k: design.trial_list(odd, k)))(
        jax.random.split(jax.random.key(8), 8000)
    )
    first = np.asarray(t.test_first)[:, :, None] == [True, False]
    level = np.asarray(t.level_index)
    # per level: 1 or 2 of 3 trials show the test first; the count is 2 with
    # probability 1/2 whatever the order of the trials
    twos = np.stack([first[..., 0][level == i].reshape(-1, 3).sum(1) == 2 for i in range(2)])
    assert np.all(np.abs(twos.mean(1) - 0.5) < 4 * np.sqrt(0.25 / 8000))
    early = level[:, 0] == 0  # level 0 shown first
    for i in range(2):
        for group in (early, ~early):
            assert abs(twos[i][group].mean() - 0.5) < 4 * np.sqrt(0.25 / group.sum())


def test_odd_repetitions_are_balanced_up_to_one_trial():
    odd = design.Protocol(
        name="odd",
        standard=1.0,
        tests=(0.5, 2.0),
        blocks=(design.Block("only", (("control", 3),)),),
    )
    firsts = []
    for seed in range(40):
        t = design.trial_list(odd, jax.random.key(seed))
        per_level = [int(t.test_first[t.level_index == i].sum()) for i in range(2)]
        assert all(f in (1, 2) for f in per_level)
        firsts.append(per_level[0])
    assert 1 in firsts and 2 in firsts  # the extra trial's order is a coin toss


def test_training_accuracy_exclusion_and_counts():
    t = design.trial_list(A, jax.random.key(5))
    correct = (t.level > 0).astype(float)
    assert float(design.training_accuracy(t, correct)) == 1.0
    # Flip some training answers: 14/20 correct is kept, 13/20 excluded
    # ("less than 70% of the time").
    training = np.flatnonzero(np.asarray(t.training))
    responses = jnp.stack(
        [
            correct.at[training[:6]].set(1 - correct[training[:6]]),
            correct.at[training[:7]].set(1 - correct[training[:7]]),
        ]
    )
    np.testing.assert_allclose(design.training_accuracy(t, responses), [0.7, 0.65])
    np.testing.assert_array_equal(design.excluded(A, t, responses), [False, True])
    # Without training trials no one is excluded (0 of 0 correct excluded everyone).
    untrained = design.Protocol(
        name="untrained",
        standard=1.0,
        tests=(0.5, 0.8, 1.25, 2.0),
        blocks=(design.Block("main", (("control", 20),)),),
        conditions=("control",),
    )
    u = design.trial_list(untrained, jax.random.key(5))
    assert not np.any(np.asarray(u.training))
    np.testing.assert_array_equal(
        design.excluded(untrained, u, jnp.zeros((2, u.level.size))), False
    )
    n_yes, n_total = design.counts(A, t, responses)
    assert n_yes.shape == n_total.shape == (2, 2, 5)
    np.testing.assert_array_equal(n_total[0], np.full((2, 5), 30))
    # Training trials are left out, so flipping them does not change counts.
    np.testing.assert_array_equal(n_yes[0], n_yes[1])
    np.testing.assert_array_equal(n_yes[0], [[0, 0, 0, 30, 30]] * 2)
    # One answer short is named, not left to JAX's own shape errors.
    for fn in (design.training_accuracy, partial(design.counts, A)):
        with pytest.raises(ValueError, match=r"^responses: expected shape \(\.\.\., 320\)"):
            fn(t, responses[:, 1:])
        # Coded 1/2, or NaN: counted as 60 "yes" of 30, or a correct "no".
        for coded, got in ((responses + 1, "got 2"), (responses * np.nan, "got nan")):
            with pytest.raises(ValueError, match=f"^responses: expected 0 or 1 .*{got}"):
                fn(t, coded)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(standard=0.0), "standard, tests: expected positive"),
        (dict(exclusion=1.5), r"exclusion: expected a fraction in \(0, 1\]"),
        (dict(tests=(float("nan"), 27.0)), "standard, tests: expected positive, finite"),
        (dict(presentation_s=-1.0), "presentation_s: expected a positive duration"),
        (dict(ambient=-1.0), "ambient: expected a finite value >= 0"),
        (dict(conditions=("control", "control")), "conditions: expected distinct names"),
        (
            dict(blocks=(design.Block("b", (("control", 0),)),)),
            "blocks: expected at least one trial",
        ),
        (dict(blocks=(design.Block("b", (("placebo", 2),)),)), "expected conditions from"),
        (dict(blocks=(design.Block("b", (("control", -1),)),)), "expected counts >= 0"),
        (dict(blocks=(design.Block("b", (("control", 1),), levels=(7,)),)), "levels: expected"),
        (
            dict(blocks=(design.Block("t", (("control", 1),), training=True),)),
            "training trials need tests that differ from the standard",
        ),
    ],
)
def test_bad_protocols_are_named(kwargs, match):
    base = dict(name="x", standard=27.0, tests=A.tests, blocks=A.blocks)
    with pytest.raises(ValueError, match=match):
        design.Protocol(**{**base, **kwargs})


# -- trial tables ---------------------------------------------------------------


def _write(path, rows):
    with open(path, "w", newline="") as file:
        csv.writer(file).writerows(rows)
    return path


HEADER = ["participant", "condition", "level", "response"]


def test_trial_rows_and_count_rows_give_the_same_groups(tmp_path):
    rng = np.random.default_rng(0)
    rows, counts = [], {}
    for p in ("p1", "p2"):
        for c in ("control", "manipulated"):
            for x in (-0.2, 0.0, 0.2):
                responses = rng.integers(0, 2, 10)
                rows += [[p, c, x, r] for r in responses]
                counts[p, c, x] = responses.sum()
    order = rng.permutation(len(rows))
    by_trial = trials.read_trials(_write(tmp_path / "t.csv", [HEADER] + [rows[i] for i in order]))
    by_count = trials.read_trials(
        _write(
            tmp_path / "c.csv",
            [["participant", "condition", "level", "n_yes", "n_total"]]
            + [[p, c, x, k, 10] for (p, c, x), k in counts.items()],
        )
    )
    a, b = trials.group_trials(by_trial), trials.group_trials(by_count)
    assert len(a.participant) == 4
    keys = list(zip(b.participant, b.condition, strict=True))
    index = [keys.index(key) for key in zip(a.participant, a.condition, strict=True)]
    for name in ("levels", "n_yes", "n_total"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name)[index])
    np.testing.assert_array_equal(a.levels[0], [-0.2, 0.0, 0.2])
    np.testing.assert_array_equal(a.n_total, 10)


def test_padding_groups_and_optional_group_columns(tmp_path):
    table = trials.read_trials(
        _write(tmp_path / "t.csv", [["level", "n_yes", "n_total"], [0.1, 3, 5], [0.3, 4, 5]])
    )
    g = trials.group_trials(table)
    assert g.participant == ("all",) and g.condition == ("all",)
    uneven = trials.TrialTable(
        np.array(["a", "a", "b"], object),
        np.array(["c", "c", "c"], object),
        np.array([0.1, 0.2, 0.1]),
        np.array([1.0, 0.0, 1.0]),
        np.ones(3),
        np.array([2, 3, 4]),
        "uneven.csv",
    )
    g = trials.group_trials(uneven)
    np.testing.assert_array_equal(g.n_total, [[1, 1], [1, 0]])  # b is padded


@pytest.mark.parametrize(
    "rows, match",
    [
        ([], "expected a header row, got an empty file"),
        ([HEADER], "expected at least one data row"),
        # the formats it accepts, the plain one of counts among them, rather
        # than every column listed as required
        (
            [["participant", "condition", "response"], ["p", "c", 1]],
            "missing column 'level' .expected the columns level and response, or level, n_yes "
            "and n_total, and optionally participant and condition; got participant, condition",
        ),
        (
            [["participant", "condition", "level", "n_yes"], ["p", "c", 0, 1]],
            "missing column 'n_total'",
        ),
        # no header: said so, not its first row's data, lower-cased, as column names
        (
            [["P1", "control", -0.2, 1], ["P1", "control", 0.2, 0]],
            "expected a header row naming the columns .* got the row P1, control, -0.2, 1$",
        ),
        # a spreadsheet's semicolon-separated export: one cell a row
        (
            [["participant;condition;level;response"], ["p;c;0.1;1"]],
            "expected columns separated by commas, got a header separated by semicolons",
        ),
        ([HEADER + ["n_yes"], ["p", "c", 0, 1, 1]], "either a 'response' column"),
        ([HEADER + ["n_total"], ["p", "c", 0, 1, 9]], "either a 'response' column"),
        (
            [HEADER, ["p", "c", 0.1, 1], ["p", "c", "bright", 1]],
            r"row 3: column 'level': .*a number",
        ),
        ([HEADER, ["p", "c", "nan", 1]], r"row 2: column 'level': expected a finite number"),
        (
            [HEADER, ["p", "c", 0.1, 1], ["p", "c", 0.1, 2]],
            r"row 3: column 'response': expected 0 or 1, got '2'",
        ),
        ([HEADER, ["p", "c", 0.1, "yes"]], r"row 2: column 'response': expected a number"),
        ([HEADER, ["p", "c", 0.1]], r"row 2: expected 4 cells, got 3"),
        ([HEADER, [" ", "c", 0.1, 1]], r"row 2: column 'participant': expected a non-empty name"),
        (
            [["level", "n_yes", "n_total"], [0.1, 1, 5], [0.2, -1, 5]],
            r"row 3: column 'n_yes': expected a whole number >= 0, got '-1'",
        ),
        ([["level", "n_yes", "n_total"], [0.1, 1, 2.5]], r"column 'n_total': expected a whole"),
        ([["level", "n_yes", "n_total"], [0.1, 6, 5]], r"row 2: column 'n_yes': expected at most"),
        (
            [["participant", "level", "n_yes", "n_total"], ["a", 0.1, 1, 5], ["b", 0.1, 0, 0]],
            r"row 3: participant 'b', condition 'all': expected at least one trial",
        ),
    ],
)
def test_bad_trial_tables_are_named(tmp_path, rows, match):
    path = _write(tmp_path / "bad.csv", rows)
    with pytest.raises(ValueError, match=match) as error:
        trials.group_trials(trials.read_trials(path))
    assert "bad.csv" in str(error.value)


def test_missing_file_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothere.csv"):
        trials.read_trials(tmp_path / "nothere.csv")


@given(st.lists(st.tuples(st.sampled_from("abc"), st.integers(-3, 3), st.booleans()), min_size=1))
def test_grouping_keeps_every_trial(rows):
    table = trials.TrialTable(
        np.array([r[0] for r in rows], object),
        np.full(len(rows), "c", object),
        np.array([r[1] / 10 for r in rows]),
        np.array([float(r[2]) for r in rows]),
        np.ones(len(rows)),
        np.arange(2, len(rows) + 2),
        "rows.csv",
    )
    g = trials.group_trials(table)
    assert g.n_total.sum() == len(rows) and g.n_yes.sum() == sum(r[2] for r in rows)
    for p, levels, n in zip(g.participant, g.levels, g.n_total, strict=True):
        mine = sorted({r[1] / 10 for r in rows if r[0] == p})
        np.testing.assert_array_equal(levels[: len(mine)], mine)
        assert np.all(n[len(mine) :] == 0)


def test_fits_csv_numbers_read_back_exactly_whatever_numpy_printing():
    # colour-science sets NumPy's printing to its 1.13 style, and str() of a
    # number then keeps 6 significant digits in float32, 12 in float64.
    import colour  # noqa: F401

    for value in (np.float32(-0.012810701), np.float64(-0.012810690977614829), np.float64(1e-300)):
        assert type(value)(trials.csv_cell(value)) == value
    assert trials.csv_cell(np.float32(-0.012810701)) == "-0.012810701"
    assert trials.csv_cell("p1") == "p1" and trials.csv_cell(np.int64(7)) == "7"
    # Nor repr of the float64 it converts to, which would write a float32
    # weight of -0.1 to observers.csv as -0.10000000149011612.
    assert trials.csv_cell(np.float32(-0.1)) == "-0.1"
    assert (trials.csv_cell(np.bool_(True)), trials.csv_cell(False)) == ("true", "false")
    assert trials.csv_cell(np.float64(-np.inf)) == "-inf"


@pytest.mark.slow
def test_fit_groups_writes_fits_csv(tmp_path):
    # Simulated responses of 32 participants in the afterimage protocol: 64
    # groups, bootstrapped 200 times, the batch that test_psychophysics_psychometric.py
    # fits and bootstraps (so that the test suite compiles both only once).
    n_participants = 32
    t = design.trial_list(A, jax.random.key(7))
    p = F.psychometric(t.level, jnp.where(t.condition == 1, 0.05, 0.0), 0.1)
    responses = jax.random.bernoulli(jax.random.key(8), p, (n_participants, p.shape[0]))
    responses = np.asarray(responses).astype(int)
    condition, level = np.asarray(t.condition), np.asarray(t.level)
    rows = [HEADER]
    for i in range(n_participants):
        for trial in range(20, p.shape[0]):  # the analysed trials
            rows.append(
                [
                    f"p{i}",
                    A.conditions[int(condition[trial])],
                    float(level[trial]),
                    int(responses[i, trial]),
                ]
            )
    source, out = _write(tmp_path / "t.csv", rows), tmp_path / "fits.csv"
    fit_table.fit_file(source, out, key=jax.random.key(9), n_resamples=200)
    groups = trials.group_trials(trials.read_trials(source))
    with open(out, newline="") as file:
        written = list(csv.DictReader(file))
    assert list(written[0]) == list(fit_table.FIT_COLUMNS)
    assert [(r["participant"], r["condition"]) for r in written] == list(
        zip(groups.participant, groups.condition, strict=True)
    )
    n_yes, n_total = design.counts(A, t, responses)
    shape = (2 * n_participants, 5)
    np.testing.assert_array_equal(groups.n_yes, np.asarray(n_yes).reshape(shape))
    np.testing.assert_array_equal(groups.n_total, np.asarray(n_total).reshape(shape))
    np.testing.assert_allclose(groups.levels, np.broadcast_to(A.levels, shape), atol=1e-12)
    wald = fit_table.fit_groups(groups, key=None, n_resamples=0)
    np.testing.assert_allclose(wald.ci_high - wald.pse, 1.959964 * wald.se_pse, rtol=1e-6)
    with pytest.raises(
        ValueError, match=r"^n_resamples: expected 0 \(Wald intervals\) or at least 2"
    ):
        fit_table.fit_groups(groups, key=jax.random.key(0), n_resamples=1)
    for r, pse in zip(written, wald.pse, strict=True):
        assert float(r["pse"]) == float(pse)  # not str's 12 digits (colour's printing)
        assert float(r["ci_low"]) < float(r["pse"]) < float(r["ci_high"])
        assert r["converged"] == "true" and r["flags"] == ""
    assert not list(tmp_path.glob("*.tmp"))


@pytest.mark.slow
def test_tables_of_sizes_in_one_batch_size_share_one_compiled_fit(count_calls):
    # Groups are fitted in batches of a power of two (copies of the first
    # after them), each group as on its own, so that the fit is not
    # compiled for every number of groups: a first `jaxadapt psychometric
    # fit` of 14 groups would take 27 s after one of 12, against 12.5 s for
    # the 12 again.
    rng = np.random.default_rng(3)
    x = np.linspace(-0.3, 0.3, 6)  # 6 levels: no other test compiles these shapes
    pse = rng.normal(0.0, 0.1, 7)
    k = rng.binomial(30, scipy.stats.norm.cdf((x - pse[:, None]) / 0.1)).astype(float)

    def groups(count):
        names = tuple(f"p{i}" for i in range(count))
        return trials.Groups(
            names, ("c",) * count, np.tile(x, (count, 1)), k[:count], 30.0 + 0 * k[:count]
        )

    traces = count_calls(F, "_fit_batch")
    first = fit_table.fit_groups(groups(5), key=None, n_resamples=0)
    before = len(traces)
    tables = [fit_table.fit_groups(groups(count), key=None, n_resamples=0) for count in (6, 7)]
    assert len(traces) == before  # 5, 6 and 7 groups: one batch of 8
    for table in (first, *tables):
        count = table.pse.size
        assert table.participant == groups(count).participant
        alone = [F.fit(x, k[i], 30.0) for i in range(count)]
        np.testing.assert_allclose(table.pse, [float(f.pse) for f in alone], rtol=1e-9)
        np.testing.assert_allclose(table.loglik, [float(f.loglik) for f in alone], rtol=1e-12)


@pytest.mark.slow
def test_fit_groups_keeps_the_intervals_in_the_fits_dtype():
    # Widened to a separating gap (float64 levels), float32 intervals stay
    # float32: as float64, fits.csv would write them with 16 digits.
    groups = trials.Groups(
        ("p1", "p2"),
        ("c", "c"),
        np.array([[-0.3, 0.0, 0.3]] * 2),
        np.array([[0.0, 0.0, 30.0], [5.0, 15.0, 25.0]]),
        np.full((2, 3), 30.0),
    )
    with jax.enable_x64(False):
        table = fit_table.fit_groups(groups, key=None, n_resamples=0)
    assert table.pse.dtype == table.ci_low.dtype == table.ci_high.dtype == np.float32
    assert table.ci_low[0] <= 0.0 and table.ci_high[0] >= 0.3  # the gap of p1's separation


def test_the_sigma_bound_drops_the_profile_likelihood_by_the_chi2_quantile():
    # Checked against the profile log-likelihood maximised over a dense grid
    # of PSEs (not the bound's own optimiser): at the bound it lies 1.92
    # (chi2(1, 0.95) / 2) below its supremum, reached as sigma goes to 0;
    # a falling function's mirror image has the same bound.
    from scipy.special import log_ndtr

    x = np.linspace(-0.4, 0.4, 9)
    k = np.array([0, 0, 0, 0, 0, 0, 5, 10, 10])
    n = np.full(9, 10)

    def profile(sigma):
        pse = np.linspace(-1.0, 1.0, 200_001)[:, None]
        z = (x - pse) / sigma
        return np.max(np.sum(k * log_ndtr(z) + (n - k) * log_ndtr(-z), axis=1))

    bound = separation.sigma_bound(x, k, n)
    assert profile(1e-6) - profile(bound) == pytest.approx(3.841458820694124 / 2, abs=1e-4)
    assert separation.sigma_bound(-x, k, n) == pytest.approx(bound, rel=1e-6)
    # Complete separation on one trial a level rejects no sigma.
    assert separation.sigma_bound(x[:2], [0, 1], [1, 1]) == np.inf
