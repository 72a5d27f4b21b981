"""Simulated observers: judgements of rendered stimuli.

Tolerances on simulated data come from the binomial sampling distribution:
the standard errors that the maximum-likelihood fit reports for pooled
counts (which are exactly binomial), or ``sqrt(p (1 - p) / n)`` for a
frequency, at four standard errors.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxadapt import io
from jaxadapt.psychophysics import design, trials
from jaxadapt.psychophysics import experiment as E  # noqa: N812
from jaxadapt.psychophysics import observer as O  # noqa: N812
from jaxadapt.psychophysics import population as Pop  # noqa: N812
from jaxadapt.psychophysics import psychometric as F  # noqa: N812

A, M = design.AFTERIMAGE, design.MESOPIC
AFTERIMAGE, DESATURATION, BLUR = range(3)


@pytest.fixture(scope="module")
def afterimage_stimuli():
    return O.render_stimuli(A, key=jax.random.key(0))


@pytest.fixture(scope="module")
def mesopic_stimuli():
    return O.render_stimuli(M, key=jax.random.key(0), width=48, height=32, fps=4.0)


#: Batch of the fits: that of test_psychophysics_psychometric.py, so that the test
#: suite compiles the fit once for both files.
FIT_BATCH = 64


def identical(observer, n):
    """``n`` copies of one observer, as a batch."""
    return jax.tree.map(lambda a: jnp.broadcast_to(a, (n,) + jnp.shape(a)), observer)


def padded_fit(levels, n_yes, n_total):
    """``F.fit`` of one dataset per condition, ``(2, L)``, padded with copies
    of the first to ``FIT_BATCH`` datasets (each is fitted on its own)."""
    n_yes, n_total = np.asarray(n_yes), np.asarray(n_total)
    levels = np.broadcast_to(np.asarray(levels, float), n_yes.shape)
    b = n_yes.shape[0]
    padded = [
        np.concatenate([a, np.repeat(a[:1], FIT_BATCH - b, axis=0)])
        for a in (levels, n_yes, n_total)
    ]
    return jax.tree.map(lambda a: a[:b], F.fit(*padded))


def pooled_fit(protocol, experiment):
    """One fit per condition of the counts of all observers together."""
    n_yes, n_total = design.counts(protocol, experiment.trials, experiment.responses)
    return padded_fit(protocol.levels, n_yes.sum(0), n_total.sum(0))


@pytest.mark.slow
def test_an_observer_without_cues_is_recovered_by_the_fit():
    # 400 copies of one observer: pooled, 60,000 trials per condition of
    # exactly binomial data with P(x) = Phi((x + bias) / noise).
    observer = O.Observer(noise=0.15, bias=0.05)
    experiment = E.simulate_observers(
        jax.random.key(1), A, O.plain_stimuli(A), identical(observer, 400)
    )
    f = pooled_fit(A, experiment)
    assert np.all(f.converged) and np.all(f.flags == 0)
    np.testing.assert_array_less(np.abs(f.pse - (-0.05)), 4 * f.se_pse)  # PSE = -bias
    np.testing.assert_array_less(np.abs(f.sigma - 0.15), 4 * f.se_sigma)  # sigma = noise
    assert np.all(f.se_pse < 0.003)  # the test has power: 4 se < 0.012 log units
    # and an observer with a different bias is told apart
    other = E.simulate_observers(
        jax.random.key(1), A, O.plain_stimuli(A), identical(O.Observer(noise=0.15), 400)
    )
    assert np.all(np.abs(pooled_fit(A, other).pse - f.pse) > 8 * f.se_pse)


def test_lapses_and_order_bias_give_the_expected_frequencies():
    observer = O.Observer(noise=0.1, bias=0.02, order_bias=0.08, lapse=0.1)
    stimuli = O.plain_stimuli(A)
    # 400 observers: the batch of the test above (one compilation)
    e = E.simulate_observers(jax.random.key(2), A, stimuli, identical(observer, 400))
    t = jax.tree.map(np.asarray, e.trials)
    r = np.asarray(e.responses)
    for first in (True, False):
        p = np.asarray(O.probability(stimuli, observer, test_first=first))
        for c in range(2):
            for level in range(5):
                cell = ~t.training & (t.condition == c) & (t.level_index == level)
                cell &= t.test_first == first
                n = cell.sum()
                assert n == 400 * 15  # 30 trials a level and condition, half each order
                freq = r[cell].mean()
                assert abs(freq - p[c, level]) < 4 * np.sqrt(p[c, level] * (1 - p[c, level]) / n)
    # the order bias is visible: at level 0 the first interval is favoured
    p_first = O.probability(stimuli, observer, test_first=True)[0, 2]
    p_second = O.probability(stimuli, observer, test_first=False)[0, 2]
    assert p_first - p_second > 0.25
    # the counter-balanced average keeps the 50% point at -bias, and lapses
    # pull the extremes towards 1/2 (lapse/2 and 1 - lapse/2 at most)
    pse = O.true_pse(stimuli, observer)
    np.testing.assert_allclose(pse, -0.02, atol=1e-12)
    shifted = stimuli._replace(
        test=stimuli.test._replace(log_luminance=stimuli.test.log_luminance - 0.02)
    )
    np.testing.assert_allclose(O.probability(shifted, observer)[:, 2], 0.5, atol=1e-12)
    far = stimuli._replace(
        test=stimuli.test._replace(log_luminance=stimuli.test.log_luminance * 100)
    )
    p = np.asarray(O.probability(far, observer))
    np.testing.assert_allclose(p[:, [0, -1]], [[0.05, 0.95]] * 2, atol=1e-9)


def test_population_draws_have_the_documented_distribution():
    pop = Pop.Population(
        noise=0.2,
        noise_spread=0.4,
        bias=0.01,
        bias_spread=0.03,
        lapse=0.03,
        lapse_spread=0.5,
        weights=(0.0, -0.1, 0.0),
        weight_spread=(0.0, 0.05, 0.0),
    )
    n = 4000
    o = jax.tree.map(np.asarray, Pop.draw_observers(jax.random.key(3), pop, n))
    half = 4 * np.sqrt(0.25 / n)  # binomial tolerance of a fraction of 1/2
    assert abs(np.mean(o.noise < 0.2) - 0.5) < half  # median noise
    assert abs(np.mean(o.lapse < 0.03) - 0.5) < half  # median lapse
    assert abs(np.std(np.log(o.noise)) - 0.4) < 4 * 0.4 / np.sqrt(2 * n)
    assert abs(np.mean(o.bias) - 0.01) < 4 * 0.03 / np.sqrt(n)
    assert abs(np.mean(o.weights[:, 1]) + 0.1) < 4 * 0.05 / np.sqrt(n)
    assert np.all(o.weights[:, [0, 2]] == 0) and np.all(o.order_bias == 0)
    assert np.all((o.lapse > 0) & (o.lapse < 1) & (o.noise > 0))
    # observer i does not depend on how many are drawn
    few = Pop.draw_observers(jax.random.key(3), pop, 3)
    for a, b in zip(jax.tree.leaves(few), jax.tree.leaves(o), strict=True):
        np.testing.assert_array_equal(a, b[:3])


def test_population_parameters_are_differentiable():
    z = jax.random.normal(jax.random.key(4), (50, Pop.N_NORMALS))
    stimuli = O.plain_stimuli(A)

    @jax.jit
    def mean_p(pop):
        observers = Pop.observers_from_normals(pop, z)
        return jnp.mean(jax.vmap(lambda o: O.probability(stimuli, o)[0, 3])(observers))

    pop = Pop.POPULATIONS["afterimage"]
    grad = jax.grad(mean_p)(pop)
    eps = 1e-6
    for name in ("noise", "bias", "lapse"):
        value = getattr(pop, name)
        up = dataclasses.replace(pop, **{name: value + eps})
        down = dataclasses.replace(pop, **{name: value - eps})
        fd = (mean_p(up) - mean_p(down)) / (2 * eps)
        np.testing.assert_allclose(getattr(grad, name), fd, rtol=1e-6, atol=1e-9)
    assert float(grad.bias) > 0  # a positive constant error makes "brighter" likelier


@pytest.mark.slow
def test_rendered_stimuli_differ_only_in_what_each_condition_manipulates(
    afterimage_stimuli, mesopic_stimuli
):
    for protocol, s in ((A, afterimage_stimuli), (M, mesopic_stimuli)):
        d_lum, d_cues = (np.asarray(a) for a in s.differences())
        # tests are scaled copies of the standard: log luminance differs by the level
        np.testing.assert_allclose(d_lum, np.broadcast_to(protocol.levels, (2, 5)), atol=1e-4)
        np.testing.assert_allclose(d_cues[0], 0.0, atol=1e-3)  # control: nothing else
    _, d = (np.asarray(a) for a in afterimage_stimuli.differences())
    # the strong afterimage (j1 = 1e-3 against 3e-4) is ~3.3 times as bright:
    # 0.3-0.52 log units of contrast, the same at every level (the blank is
    # not scaled); the flash itself is not blurred, and its rim only faintly
    # tinted by the maps' spread of 0.086 degree a second (-0.010; maps
    # blurred 1 pixel a frame at 3.2 pixels per degree spread 2 degrees: -0.11)
    assert np.all((d[1, :, AFTERIMAGE] > 0.3) & (d[1, :, AFTERIMAGE] < 0.53))
    assert np.ptp(d[1, :, AFTERIMAGE]) < 1e-6
    assert np.all(np.abs(d[1, :, BLUR]) < 1e-3) and np.all(np.abs(d[1, :, DESATURATION]) < 0.02)
    _, d = (np.asarray(a) for a in mesopic_stimuli.differences())
    # mesopic rendering: less colourful, less fine detail, no afterimage;
    # darker tests are more mesopic, so both cues grow as the level falls
    assert np.all(d[1, :, DESATURATION] > 0.5) and np.all(d[1, :, BLUR] > 0.2)
    assert np.all(np.diff(d[1, :, DESATURATION]) < 0) and np.all(np.diff(d[1, :, BLUR]) < 0)
    assert np.all(d[1, :, AFTERIMAGE] == 0)


@pytest.mark.slow
def test_a_cue_weight_moves_the_pse_the_way_its_sign_says(afterimage_stimuli, mesopic_stimuli):
    cases = [
        (M, mesopic_stimuli, DESATURATION, -0.1, +1),  # desaturated tests look darker
        (M, mesopic_stimuli, BLUR, 0.1, -1),
        (A, afterimage_stimuli, AFTERIMAGE, 0.1, -1),  # an afterimage makes it look brighter
    ]
    for protocol, s, cue, weight, sign in cases:
        observer = O.Observer(noise=0.1, weights=jnp.zeros(3).at[cue].set(weight))
        pse = np.asarray(O.true_pse(s, observer))
        assert abs(pse[0]) < 1e-3 and sign * pse[1] > 0.03, (protocol.name, cue, pse)
        # simulated, pooled and fitted: near the pseudo-true PSE, the fit of
        # the expected counts (cues that change with the level bend P(x)
        # away from a cumulative Gaussian), within the fit's sampling error;
        # 400 observers, as in the first test (one compilation for both)
        e = E.simulate_observers(jax.random.key(5), protocol, s, identical(observer, 400))
        f = pooled_fit(protocol, e)
        _, n_total = design.counts(protocol, e.trials, e.responses)
        n = n_total.sum(0)
        expected = padded_fit(protocol.levels, n * O.probability(s, observer), n)
        np.testing.assert_array_less(np.abs(f.pse - expected.pse), 4 * f.se_pse)
        assert sign * (f.pse[1] - f.pse[0]) > 0.03
        np.testing.assert_allclose(expected.pse, pse, atol=1e-3)  # measured: 1.4e-4 at most


def test_true_pse_has_the_implicit_gradient_and_weights_for_pse_inverts_it(mesopic_stimuli):
    s = mesopic_stimuli
    observer = O.Observer(noise=0.1, bias=0.01, weights=jnp.array([0.0, -0.08, -0.05]))

    def manipulated(weights):
        return O.true_pse(s, dataclasses.replace(observer, weights=weights))[1]

    grad = jax.grad(manipulated)(observer.weights)
    eps = 1e-6
    for k in range(3):
        step = jnp.zeros(3).at[k].set(eps)
        fd = (manipulated(observer.weights + step) - manipulated(observer.weights - step)) / (
            2 * eps
        )
        np.testing.assert_allclose(grad[k], fd, rtol=1e-5, atol=1e-9)
    assert grad[AFTERIMAGE] == 0 and grad[DESATURATION] < 0  # no afterimage; darker
    w = O.weights_for_pse(s, jnp.array([0.0, 2.0, 1.0]), 0.13, bias=0.01)
    found = O.true_pse(s, dataclasses.replace(observer, weights=w))
    np.testing.assert_allclose(found[1], 0.13, atol=1e-9)
    np.testing.assert_allclose(w[1], 2 * w[2])
    # Under jit too, where the check cannot take float() of a traced value.
    jitted = jax.jit(lambda p: O.weights_for_pse(s, jnp.array([0.0, 2.0, 1.0]), p, bias=0.01))
    np.testing.assert_allclose(jitted(0.13), w, rtol=1e-12)
    with pytest.raises(ValueError, match="direction"):
        O.weights_for_pse(s, jnp.array([1.0, 0.0, 0.0]), 0.13)  # no afterimage here


@pytest.mark.slow
def test_the_vmapped_experiment_equals_a_loop_of_observers():
    stimuli = O.plain_stimuli(A)
    observers = Pop.draw_observers(jax.random.key(6), Pop.POPULATIONS["afterimage"], 3)
    key = jax.random.key(7)
    batch = E.simulate_observers(key, A, stimuli, observers)
    for i in range(3):
        one = jax.tree.map(lambda a, i=i: a[i], observers)
        t, r = E.run_observer(jax.random.fold_in(key, i), A, stimuli, one)
        np.testing.assert_array_equal(r, batch.responses[i])
        for a, b in zip(t, batch.trials, strict=True):
            np.testing.assert_array_equal(a, b[i])
        accuracy = design.training_accuracy(t, r)
        assert bool(batch.excluded[i]) == bool(accuracy < A.exclusion)


@pytest.mark.slow
def test_same_key_same_experiment_and_observers_do_not_depend_on_their_number():
    # 12 observers, as the round trip below, and 4, as the doctest of
    # E.simulate: the test suite compiles each experiment once.
    stimuli, pop = O.plain_stimuli(A), Pop.POPULATIONS["afterimage"]
    a = E.simulate(jax.random.key(8), A, stimuli, pop, 12)
    b = E.simulate(jax.random.key(8), A, stimuli, pop, 12)
    few = E.simulate(jax.random.key(8), A, stimuli, pop, 4)
    other = E.simulate(jax.random.key(9), A, stimuli, pop, 12)
    for x, y, z in zip(jax.tree.leaves(a), jax.tree.leaves(b), jax.tree.leaves(few), strict=True):
        np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(x[:4], z)
    assert not np.array_equal(a.responses, other.responses)
    assert not np.array_equal(a.trials.level, other.trials.level)


def test_trial_tables_round_trip_through_the_reader(tmp_path):
    # noisy observers, so that some fail the training criterion
    pop = dataclasses.replace(Pop.POPULATIONS["afterimage"], noise=0.6)
    e = E.simulate(jax.random.key(10), A, O.plain_stimuli(A), pop, 12)
    excluded = np.asarray(e.excluded)
    assert 0 < excluded.sum() < 12
    path = tmp_path / "trials.csv"
    rows = E.write_trials(path, A, e)
    assert rows == 12 * 320  # training trials and excluded observers kept, as a session keeps them
    groups = trials.group_trials(trials.read_trials(path))
    expected = E.groups(A, e)
    assert groups.participant == expected.participant
    assert groups.condition == expected.condition
    names = E.participant_names(12)
    assert set(groups.participant) == {n for n, x in zip(names, excluded, strict=True) if not x}
    np.testing.assert_array_equal(groups.levels, expected.levels)
    np.testing.assert_array_equal(groups.n_yes, expected.n_yes)
    np.testing.assert_array_equal(groups.n_total, expected.n_total)


def test_an_experiment_in_blocks_equals_the_whole(tmp_path):
    # Blocks of observers (as `psychometric simulate` streams them, memory
    # flat in their number) give the whole experiment's observers, trials
    # and answers, and the same tables.
    pop = dataclasses.replace(Pop.POPULATIONS["afterimage"], noise=0.6)
    stimuli, key = O.plain_stimuli(A), jax.random.key(10)
    whole = E.simulate(key, A, stimuli, pop, 7)
    blocks = list(E.simulate_in_chunks(key, A, stimuli, pop, 7, chunk=3))
    assert [(first, len(b.excluded)) for first, b in blocks] == [(0, 3), (3, 3), (6, 1)]
    joined = jax.tree.map(lambda *a: np.concatenate(a), *(b for _, b in blocks))
    for x, y in zip(jax.tree.leaves(whole), jax.tree.leaves(joined), strict=True):
        np.testing.assert_array_equal(x, y)
    E.write_trials(tmp_path / "whole.csv", A, whole)
    with open(tmp_path / "blocks.csv", "w", newline="") as f:
        writer = io.csv_writer(f)
        writer.writerow(E.TRIAL_COLUMNS)
        for first, block in blocks:
            E.append_trials(writer, A, block, first, 7)
    assert (tmp_path / "blocks.csv").read_text() == (tmp_path / "whole.csv").read_text()
    names = [
        n for first, b in blocks for n in E.observer_table(A, stimuli, b, first, 7)["participant"]
    ]
    assert names == E.observer_table(A, stimuli, whole)["participant"] == E.participant_names(7)


@pytest.mark.slow
def test_bad_inputs_are_named():
    # A population of negative noise would draw observers of negative noise.
    for field, value in (("noise", -1.0), ("lapse", 1.0), ("noise_spread", -0.1)):
        with pytest.raises(ValueError, match=f"^Population.{field}: expected"):
            Pop.Population(**{field: value})
    # A display shows whole frames: 50 ms at 30 fps is 1.5 of them.
    for fps, lead, match in ((30.0, 0.25, "protocol.presentation_s"), (40.0, 0.26, "lead_s")):
        with pytest.raises(ValueError, match=f"^{match}: expected a whole number"):
            O.afterimage_displays(A, key=jax.random.key(0), width=8, height=8, fps=fps, lead_s=lead)
    # Within 1e-6 of a frame is a whole frame: 10 ns more lead split a frame
    # and counted a dark sliver as shown.
    d = O.afterimage_displays(A, key=jax.random.key(0), width=8, height=8, lead_s=0.25 + 1e-8)
    np.testing.assert_allclose(d.times[np.asarray(d.presented)], [0.25, 0.275])
    # Weights of another length are named, not left to fail in a matmul at
    # the first judgement.
    with pytest.raises(ValueError, match=r"^Observer.weights: expected one value per cue"):
        O.Observer(weights=jnp.ones(2))
    with pytest.raises(ValueError, match=r"^Population.weight_spread: expected one value per cue"):
        Pop.Population(weight_spread=0.1)
    with pytest.raises(ValueError, match="n_observers"):
        E.simulate(jax.random.key(0), A, O.plain_stimuli(A), Pop.Population(), 0)
    with pytest.raises(ValueError, match="protocol"):
        O.render_stimuli(dataclasses.replace(A, name="other"), key=jax.random.key(0))
    with pytest.raises(ValueError, match="observers"):
        E.simulate_observers(jax.random.key(0), A, O.plain_stimuli(A), O.Observer())
    for bad in (O.Observer(noise=0.0), O.Observer(lapse=1.0), O.Observer(noise=jnp.nan)):
        with pytest.raises(ValueError, match="^observers: expected noise > 0"):
            # 3 observers: the batch of the vmapped experiment above (one compilation)
            E.simulate_observers(jax.random.key(0), A, O.plain_stimuli(A), identical(bad, 3))
        # unchecked, probability itself would give 0/0 = NaN (noise 0) or
        # values beyond [0, 1].
        with pytest.raises(ValueError, match="^observer: expected noise > 0"):
            O.probability(O.plain_stimuli(A), bad)
