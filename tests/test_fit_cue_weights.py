"""The cue-weight calibration of ``experiments/fit_cue_weights.py``.

On synthetic stimuli whose cue differences do not change with the level
(no rendering), each observer's true PSE shift is ``-w . Delta c``, linear in
its weights; with antithetic normals (every group also drawn with ``-z``)
the model's mean median shift is then exactly ``-w_mean . Delta c``, so the
fitted weights and their standard errors have a closed form, which the
single-observer :func:`jaxadapt.psychophysics.observer.weights_for_pse`
also gives.
"""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxadapt.psychophysics import design
from jaxadapt.psychophysics import observer as O  # noqa: N812
from jaxadapt.psychophysics import population as Pop  # noqa: N812

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "experiments"))
import fit_cue_weights as F  # noqa: E402, N812

#: End-to-end or long: left out of the quick run (pytest -m "not slow").
pytestmark = pytest.mark.slow

AFTERIMAGE, DESATURATION, BLUR = range(3)
TARGETS = np.array([-0.02, 0.13])  # afterimage, mesopic (the order of F.PROTOCOLS)
SD = np.array([0.016, 0.021])


def synthetic(protocol, cues):
    """Plain stimuli whose manipulated tests differ by ``cues (K,)`` at every level."""
    s = O.plain_stimuli(protocol)
    return s._replace(test=s.test._replace(cues=s.test.cues.at[1].set(jnp.asarray(cues))))


#: The afterimage tests carry a faint colour difference too, so that the
#: mesopic scale moves both protocols: the joint fit must handle coupled
#: protocols (the real renders are coupled faintly, by -0.010).
STIMULI = {
    "afterimage": synthetic(design.AFTERIMAGE, [0.47, -0.11, 0.0]),
    "mesopic": synthetic(design.MESOPIC, [0.0, 1.0, 0.55]),
}


def antithetic(groups):
    """A calibration of ``2 groups`` groups: ``groups`` drawn, and their negatives."""
    cal = F.calibration(jax.random.key(0), STIMULI, groups=groups)
    return cal._replace(normals=jnp.concatenate([cal.normals, -cal.normals], axis=1))


def closed_form():
    """``(A, b)`` of the linear model ``shift = A (a, s)``: ``A[p, j] = -d_j . Delta c_p``."""
    D = np.stack([np.asarray(F.cue_direction(n)) for n in F.NAMES], -1)  # (K, 2)
    dc = np.stack([np.asarray(STIMULI[n].differences()[1][1, 0]) for n in F.PROTOCOLS])
    return -dc @ D


@pytest.fixture(scope="module")
def calibrated():
    cal = antithetic(20)
    return cal, F.calibrate(cal, TARGETS, SD, F.CueWeights(0.01, -0.01))


def test_the_fit_reproduces_the_medians_and_the_closed_form(calibrated):
    cal, result = calibrated
    assert bool(result.converged)
    np.testing.assert_allclose(F.predicted_shifts(result.params, cal), TARGETS, atol=1e-8)
    A = closed_form()
    expected = np.linalg.solve(A, TARGETS)
    got = np.array([float(result.estimate[n]) for n in F.NAMES])
    np.testing.assert_allclose(got, expected, rtol=1e-6)
    # The mesopic protocol alone fixes s: the single-observer closed form.
    direction = F.cue_direction("mesopic")
    w = O.weights_for_pse(STIMULI["mesopic"], direction, TARGETS[1])
    np.testing.assert_allclose(got[1], float(w[BLUR] / direction[BLUR]), rtol=1e-6)


def test_standard_errors_propagate_the_spread_of_one_experiment(calibrated):
    # absolute_sigma: cov = (A' W A)^-1 = A^-1 diag(sd^2) A^-T, although the
    # fit has no residual degrees of freedom.
    _, result = calibrated
    A_inv = np.linalg.inv(closed_form())
    cov = A_inv @ np.diag(SD**2) @ A_inv.T
    np.testing.assert_allclose(np.asarray(result.cov), cov, rtol=1e-5, atol=1e-12)
    assert abs(float(result.correlation[0, 1])) > 0.1  # the coupling correlates them


def test_known_weights_are_recovered_from_the_model():
    # Random (not antithetic) normals, as many groups as above (one
    # compilation): with them the model is not linear in the weights; data made
    # at known weights must give them back.
    cal = F.calibration(jax.random.key(1), STIMULI, groups=40)
    known = F.CueWeights(0.06, -0.05)
    data = F.predicted_shifts(known, cal)
    result = F.calibrate(cal, data, SD, F.CueWeights(0.01, -0.01))
    assert bool(result.converged)
    for name in F.NAMES:
        np.testing.assert_allclose(result.estimate[name], getattr(known, name), rtol=1e-6)


def test_whole_experiments_agree_with_the_model():
    # 200 simulated experiments (trials, exclusion, psychometric fits) at the
    # closed-form weights: their median shifts centre on the target within
    # four standard errors of the median of 200 (1.25 sd / sqrt(200)).
    a, s = np.linalg.solve(closed_form(), TARGETS)
    population = F.with_weights(Pop.POPULATIONS["afterimage"], F.CueWeights(a, s).vector())
    result = F.simulate_shifts(
        jax.random.key(2), design.AFTERIMAGE, STIMULI["afterimage"], population, 200
    )
    shift = result.shift
    assert shift.shape == result.p.shape == result.separated.shape == (200,)
    tolerance = 4 * 1.25 * np.std(shift, ddof=1) / np.sqrt(shift.size)
    assert abs(np.median(shift) - TARGETS[0]) < tolerance
