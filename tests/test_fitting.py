"""Fitting parameters through the simulator (jaxadapt.fitting).

Peers: float64 central finite differences for the gradients (through
``pattanaik2000.run`` and through the diffrax path), SciPy's ``curve_fit``
and a hand-written ``s^2 (J'J)^-1`` for least-squares estimates and their
covariance, and statsmodels' probit GLM (the paper's ``glmfit``) for maximum
likelihood. The time-course model is a small version of
``experiments/fit_time_constants.py``: increment thresholds during dark and
light adaptation from the 2000 operator's state. Shapes and static options
are kept few so that the file compiles each fit once.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import statsmodels.api as sm
from scipy.optimize import curve_fit
from scipy.special import gammaln
from scipy.stats import norm

from jaxadapt import fitting
from jaxadapt.fitting import _fit, _queue
from jaxadapt.operators import pattanaik2000 as op
from jaxadapt.physiology import kinetics
from jaxadapt.physiology.response import sigma_cone, sigma_rod
from jaxadapt.physiology.threshold import increment_sensitivity, increment_threshold

NAMES = ("t0_rod", "t0_cone", "tau_rod", "tau_cone")
DELTA = 0.01


# -- the threshold time course ------------------------------------------------


def _protocol(steps):
    """Luminance and frame durations of a stepped uniform field: frames start
    at 0 and then geometrically from 10 ms to the end of each step."""
    L, dt = [], []
    for lum, duration, count in steps:
        starts = np.concatenate([[0.0], np.geomspace(0.01, duration, count)])
        L.append(np.full(count, lum))
        dt.append(np.diff(starts))
    return jnp.asarray(np.concatenate(L)), jnp.asarray(np.concatenate(dt))


#: A viewer adapted to 1e6 cd/m2, 10 min in the dark, 10 s at 0.03 cd/m2
#: (rods), 60 s at 1000 cd/m2 (cones): 44 thresholds.
L_STEPS, DT_STEPS = _protocol([(1e-6, 600.0, 20), (0.03, 10.0, 12), (1e3, 60.0, 12)])
ARGS = (L_STEPS, DT_STEPS, jnp.asarray(1e6))
#: The same frames on a field that never changes: nothing adapts.
FLAT_ARGS = (jnp.full_like(L_STEPS, 1e3), DT_STEPS, jnp.asarray(1e3))


def states(params, G_rod, G_cone, dt, pre):
    """The 2000 operator's state over frames with goals ``G_rod, G_cone``
    (cd/m2) held for ``dt`` (s), from full adaptation to ``pre``: its exact
    kinetics (``pattanaik2000.advance``) scanned over the frames, which is
    what ``run`` computes (checked below) without its pixel map, so that the
    fits here compile quickly."""

    def body(state, frame):
        return op.advance(params, state, *frame), state

    return jax.lax.scan(body, op.static_state(params, pre, pre), (G_rod, G_cone, dt))[1]


def log_threshold(params, args):
    """log10 threshold (cd/m2) at each frame, rod and cone sensitivities pooled
    (Minkowski exponent 4, as in the experiment)."""
    L, dt, pre = args
    s, n = states(params, L, L, dt, pre), params.n
    rod = increment_sensitivity(L, sigma_rod(s.A_rod, n), DELTA, s.B_rod, n)
    cone = increment_sensitivity(L, sigma_cone(s.A_cone, n), DELTA, s.B_cone, n)
    return -0.25 * jnp.log10(jnp.maximum(rod**4 + cone**4, 1e-32))


TRUTH = op.Params()
START = op.Params(t0_rod=0.3, t0_cone=0.04, tau_rod=250.0, tau_cone=200.0)


def _log_params(params):
    return jnp.log(jnp.array([getattr(params, n) for n in NAMES]))


def _with_log(v):
    return eqx.tree_at(lambda p: [getattr(p, n) for n in NAMES], TRUTH, list(jnp.exp(v)))


def _check_gradient(f, x, h, forward=True, rtol=1e-6):
    """Reverse- (and forward-) mode derivatives of the scalar ``f`` (which
    returns ``(value, aux)``) at ``x`` against central differences of step
    ``h``, from one compiled function (compiling is the cost here). Returns
    the aux at ``x``."""

    @jax.jit
    def derivatives(x):
        (value, aux), rev = jax.value_and_grad(f, has_aux=True)(x)
        fwd = jax.jacfwd(lambda x: f(x)[0])(x) if forward else rev
        return value, rev, fwd, aux

    _, rev, fwd, aux = derivatives(x)
    steps = h * np.eye(x.size)
    fd = np.array([derivatives(x + e)[0] - derivatives(x - e)[0] for e in steps]) / (2 * h)
    assert np.all(np.abs(fd) > 1e-3)  # every parameter matters
    np.testing.assert_allclose(rev, fd, rtol=rtol)
    np.testing.assert_allclose(fwd, fd, rtol=rtol)
    return aux


# -- gradients ----------------------------------------------------------------


def test_sensitivity_is_the_reciprocal_of_the_chapters_threshold():
    L = jnp.array([0.0, 1e-3, 1.0, 100.0])
    sigma, B = jnp.array([1e-3, 2.0, 50.0, 300.0]), jnp.array([0.05, 0.5, 1.0, 0.9])
    np.testing.assert_allclose(
        1 / increment_sensitivity(L, sigma, DELTA, B, 0.73),
        increment_threshold(L, sigma, DELTA, B, 0.73),
        rtol=1e-12,
    )
    saturated = increment_sensitivity(jnp.asarray(1e4), 1.0, DELTA, 0.9, 0.73)
    assert float(saturated) == 0.0
    assert float(jax.grad(lambda s: increment_sensitivity(1e4, s, DELTA, 0.9, 0.73))(1.0)) == 0.0


@pytest.mark.slow
def test_gradient_through_run_matches_finite_differences():
    # Thresholds from the state ``run`` reports over the stepped field, in
    # forward and reverse mode (the display output's gradient is checked in
    # test_pattanaik2000.py); a random weighted sum is the scalar checked.
    frames = jnp.broadcast_to(L_STEPS[:, None, None, None], (L_STEPS.size, 1, 1, 3))
    weights = jax.random.normal(jax.random.key(0), L_STEPS.shape)

    def thresholds(v):
        params = _with_log(v)
        pre = jnp.asarray(1e6)
        _, diag = op.run(params, frames, DT_STEPS, state=op.static_state(params, pre, pre))
        s, n = diag.state, params.n
        rod = increment_sensitivity(diag.G_rod, sigma_rod(s.A_rod, n), DELTA, s.B_rod, n)
        cone = increment_sensitivity(diag.G_cone, sigma_cone(s.A_cone, n), DELTA, s.B_cone, n)
        return jnp.dot(weights, jnp.log10(rod**4 + cone**4)), diag.state

    v = _log_params(op.Params(t0_rod=0.17, t0_cone=0.07, tau_rod=380.0, tau_cone=120.0))
    seen = _check_gradient(thresholds, v, 1e-6)
    # The fits below use the operator's kinetics without its pixel map: run's own state.
    ours = states(_with_log(v), L_STEPS, L_STEPS, DT_STEPS, 1e6)
    for a, b in zip(ours, seen, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12)


@pytest.mark.slow
def test_gradient_through_the_diffrax_path_matches_finite_differences():
    # Rod pigment under a goal that rises from 0.01 to 5 cd/m2 in 2 s, solved
    # by diffrax (Kvaerno5; reverse mode only). The adaptive solution moves by
    # ~1e-10 when a parameter change alters the steps taken (its error is
    # ~3e-10 here even at rtol 1e-12), so the differences take a step of 1e-3,
    # where that noise is ~1e-7; with 1e-5 it would be ~1e-5 and swamp the
    # comparison. (The gradient also matches differences of SciPy's DOP853.)
    ts = jnp.linspace(0.0, 20.0, 16)
    goal = kinetics.goal_path(jnp.array([0.0, 2.0, 20.0]), jnp.array([1e-2, 5.0, 5.0]))
    weights = jax.random.normal(jax.random.key(1), ts.shape)

    def model(v):
        tau, c = jnp.exp(v)
        args = (goal, tau, c)
        B = kinetics.integrate(kinetics.bleaching_rhs, 0.5, ts, args, rtol=1e-12, atol=1e-14)
        return jnp.dot(weights, jnp.log(B)), None

    _check_gradient(model, jnp.log(jnp.array([40.0, 16.0])), 1e-3, forward=False, rtol=1e-5)


@pytest.mark.slow
def test_a_reverse_mode_only_model_fitted_forward_is_pointed_to_bwd():
    # JAX's "Differentiation rule for 'custom_lin' not implemented", alone.
    class Rates(eqx.Module):
        tau: jax.Array = eqx.field(default=40.0, converter=jnp.asarray)

    ts = jnp.linspace(0.0, 4.0, 5)
    goal = kinetics.goal_path(jnp.array([0.0, 4.0]), jnp.array([5.0, 5.0]))

    def model(params, ts):
        return kinetics.integrate(kinetics.bleaching_rhs, 0.5, ts, (goal, params.tau, 16.0))

    with pytest.raises(NotImplementedError, match=r"^model: no forward-mode .* jac='bwd'"):
        fitting.fit(model, Rates(), "tau", np.full(5, 0.5), args=ts)


# -- recovery, flags and masks on the threshold time course --------------------
#
# Every fit of the time course below has data of shape (4, 44) and the same
# names: one compilation serves them all.

HOLES = np.array([0, 7, 19, 30, 43])


@pytest.fixture(scope="module")
def course():
    """Rows: noiseless, two noisy (0.05 log units), noiseless with 5 NaNs."""
    rng = np.random.default_rng(3)
    clean = np.asarray(log_threshold(TRUTH, ARGS))
    data = np.stack([clean, *(clean + 0.05 * rng.standard_normal((2, clean.size))), clean])
    data[3, HOLES] = np.nan
    with pytest.warns(UserWarning, match="data: 5 of 176 measurements are not finite"):
        fit = fitting.fit(log_threshold, START, NAMES, data, args=ARGS)
    return data, fit


@pytest.mark.slow
def test_recovers_known_parameters_from_noiseless_data(course):
    _, f = course
    assert bool(f.converged[0]) and bool(f.solved[0]) and 0 < int(f.steps[0]) < 100
    for name in NAMES:
        assert float(f.estimate[name][0]) == pytest.approx(float(getattr(TRUTH, name)), rel=1e-6)
        assert float(f.se[name][0]) < 1e-6 * float(getattr(TRUTH, name))
    assert float(jnp.abs(f.residuals[0]).max()) < 1e-8
    assert float(f.params.t0_cone[0]) == pytest.approx(0.08, rel=1e-6)  # the full Params back
    assert float(f.params.c_rod[0]) == 16.0  # a field held fixed


@pytest.mark.slow
def test_noisy_recovery_lies_within_its_standard_errors(course):
    data, f = course
    rows = slice(1, 3)
    assert np.all(f.converged[rows])
    z = np.array([(f.estimate[n][rows] - getattr(TRUTH, n)) / f.se[n][rows] for n in NAMES])
    assert np.all(np.abs(z) < 4), z
    assert np.all(np.abs(z) > 1e-3)  # the noise did move the estimates
    # The residuals estimate the noise: 0.05 log units.
    sd = np.sqrt(2 * np.asarray(f.loss[rows]) / (data.shape[1] - len(NAMES)))
    np.testing.assert_allclose(sd, 0.05, rtol=0.35)
    np.testing.assert_allclose(f.residuals[rows], f.prediction[rows] - data[rows], atol=1e-12)
    corr = np.asarray(f.correlation)
    assert corr.shape == (4, 4, 4)
    np.testing.assert_allclose(corr, np.swapaxes(corr, -1, -2), atol=1e-12)
    assert np.all(np.abs(corr) <= 1 + 1e-12)
    se = np.sqrt(np.diagonal(np.asarray(f.cov[1])))
    np.testing.assert_allclose(se, [float(f.se[n][1]) for n in NAMES], rtol=1e-12)


def test_nan_measurements_are_masked_and_said(course):
    data, f = course  # the fixture checked the warning
    np.testing.assert_array_equal(f.n_masked, [0, 0, 0, 5])
    np.testing.assert_array_equal(~np.asarray(f.mask[3]), np.isin(np.arange(44), HOLES))
    assert np.all(np.asarray(f.residuals[3])[HOLES] == 0.0)
    assert bool(f.converged[3])
    for name in NAMES:
        assert float(f.estimate[name][3]) == pytest.approx(float(getattr(TRUTH, name)), rel=1e-6)
    for leaf in jax.tree.leaves(f):
        assert not np.any(np.isnan(np.asarray(leaf)))
    # The prediction (the solver's last evaluation) is the model at the
    # estimate, at the left-out measurements too.
    at_estimate = log_threshold(jax.tree.map(lambda x: x[3], f.params), ARGS)
    np.testing.assert_allclose(f.prediction[3], at_estimate, rtol=1e-12)
    # Weight 0 on arbitrary values is the same fit, and the other rows of the
    # batch do not change.
    weights = np.ones_like(data)
    weights[3, HOLES] = 0.0
    g = fitting.fit(
        log_threshold, START, NAMES, np.nan_to_num(data, nan=99.0), args=ARGS, weights=weights
    )
    np.testing.assert_array_equal(g.n_masked, f.n_masked)
    for name in NAMES:
        np.testing.assert_allclose(g.estimate[name], f.estimate[name], rtol=1e-12)


def test_flat_data_are_flagged_and_finite():
    # On a field that never changes A = G throughout, so t0 has no effect,
    # and the rods are saturated, so tau_rod has none either. Only tau_cone
    # acts, through the static cone bleach B = 1 / (1 + G tau / c).
    data = np.broadcast_to(np.asarray(log_threshold(TRUTH, FLAT_ARGS)), (4, 44))
    assert np.ptp(data) < 1e-12  # flat to rounding
    f = fitting.fit(log_threshold, START, NAMES, data, args=FLAT_ARGS)
    assert not np.any(f.converged)
    for name in ("t0_rod", "t0_cone", "tau_rod"):
        assert np.all(np.asarray(f.se[name]) == np.inf)
        np.testing.assert_allclose(f.estimate[name], getattr(START, name), rtol=1e-6)
    assert np.all(np.isfinite(f.se["tau_cone"]))
    np.testing.assert_allclose(f.estimate["tau_cone"], 110.0, rtol=1e-4)
    for leaf in jax.tree.leaves(f):
        assert not np.any(np.isnan(np.asarray(leaf)))
    assert np.all(np.isfinite(f.residuals)) and np.all(np.isfinite(f.loss))
    corr = np.asarray(f.correlation)
    assert np.all(np.isfinite(corr)) and np.all(corr[:, 0, 3] == 0.0)
    # Intervals: a parameter not identified gets its bounds (positive: 0 to inf).
    for name in ("t0_rod", "t0_cone", "tau_rod"):
        low, high = f.interval()[name]
        assert np.all(np.asarray(low) == 0.0) and np.all(np.asarray(high) == np.inf)


@pytest.mark.slow
def test_a_parameter_run_off_its_flat_direction_leaves_the_others_identified():
    # Dark adaptation alone barely depends on t0_rod (the rods are saturated
    # while it acts). Damped in its own units, its first steps can run it to
    # 1e-160, where dp/du = 0 meets the model's infinite derivative: a NaN
    # Jacobian. Such a trial point is rejected; the solve goes on, t0_rod is
    # flagged and the three other constants keep finite standard errors.
    # (Accepted, the NaN would stop the solve with every standard error inf,
    # in about one fit in ten of experiments/fit_time_constants.py.)
    # 32 observers, the paper's constants times log-normal factors (20 %),
    # as in the experiment: with such points accepted, 19 of the 32 would stop.
    L, dt = _protocol([(1e-6, 1800.0, 40)])
    args = (L, dt, jnp.asarray(1e6))
    rng = np.random.default_rng(0)
    paper = np.array([float(getattr(TRUTH, name)) for name in NAMES])
    truth = paper * np.exp(0.2 * rng.standard_normal((32, len(NAMES))))

    def model(values):
        return log_threshold(
            eqx.tree_at(lambda p: [getattr(p, n) for n in NAMES], TRUTH, values), args
        )

    clean = np.asarray(jax.vmap(lambda v: model(list(v)))(jnp.asarray(truth)))
    data = clean + 0.05 * rng.standard_normal(clean.shape)
    f = fitting.fit(log_threshold, op.Params(), NAMES, data, args=args)
    assert np.all(f.solved)
    for name in ("t0_cone", "tau_rod", "tau_cone"):
        assert np.all(np.isfinite(f.se[name])), name
    assert not np.all(np.isfinite(f.se["t0_rod"]))  # not identified in some fits
    assert np.all(f.converged == np.isfinite(f.se["t0_rod"]))


def test_bad_input_is_named():
    data = np.zeros(44)
    with pytest.raises(ValueError, match=r"data: expected shape \(\.\.\., 44\).*got shape \(43,\)"):
        fitting.fit(log_threshold, START, NAMES, np.zeros(43), args=ARGS)
    with pytest.raises(ValueError, match=r"got shape \(44, 2\)"):
        fitting.fit(log_threshold, START, NAMES, np.zeros((44, 2)), args=ARGS)
    with pytest.raises(ValueError, match="'t0_cones' is not a parameter of Params") as error:
        fitting.fit(log_threshold, START, ("t0_rod", "t0_cones"), data, args=ARGS)
    for name in NAMES + ("c_rod", "n", "white_factor"):
        assert name in str(error.value)  # the valid names are listed
    # A choice, not "not a parameter" (it is one).
    with pytest.raises(
        ValueError,
        match=r"'goal' of Params holds 'log_average', not a number; valid names: n, t0_rod",
    ):
        fitting.fit(log_threshold, START, "goal", data, args=ARGS)
    with pytest.raises(ValueError, match="names: expected each parameter once"):
        fitting.fit(log_threshold, START, ("t0_rod", "t0_rod"), data, args=ARGS)
    with pytest.raises(ValueError, match="names: expected at least one"):
        fitting.fit(log_threshold, START, (), data, args=ARGS)
    with pytest.raises(ValueError, match=r"params.t0_rod: the start must lie strictly inside"):
        fitting.fit(log_threshold, START, "t0_rod", data, args=ARGS, bounds={"t0_rod": (0, 0.2)})
    with pytest.raises(ValueError, match=r"bounds\['t0_rod'\]: expected \(low, high\)"):
        fitting.fit(log_threshold, START, "t0_rod", data, args=ARGS, bounds={"t0_rod": (1, 0)})
    with pytest.raises(ValueError, match=r"bounds: \['c_rod'\] are not among"):
        fitting.fit(log_threshold, START, "t0_rod", data, args=ARGS, bounds={"c_rod": None})
    with pytest.raises(ValueError, match="weights: expected a shape that broadcasts"):
        fitting.fit(log_threshold, START, NAMES, data, args=ARGS, weights=np.ones(3))
    with pytest.raises(ValueError, match="max_steps: expected at least 1"):
        fitting.fit(log_threshold, START, NAMES, data, args=ARGS, max_steps=0)
    for bad in (-np.ones(44), np.full(44, np.inf), np.full(44, np.nan)):
        with pytest.raises(ValueError, match="weights: expected finite, non-negative"):
            fitting.fit(log_threshold, START, NAMES, data, args=ARGS, weights=bad)
    for bad in (5, (0, 5, 7), ("x", 1)):
        with pytest.raises(ValueError, match=r"bounds\['t0_rod'\]: expected \(low, high\) or None"):
            fitting.fit(log_threshold, START, "t0_rod", data, args=ARGS, bounds={"t0_rod": bad})
    with pytest.raises(ValueError, match="jac: expected 'fwd' or 'bwd'"):
        fitting.fit(log_threshold, START, NAMES, data, args=ARGS, jac="central")
    with pytest.raises(ValueError, match="params: expected a parameter module"):
        fitting.fit(log_threshold, {"t0_rod": 0.1}, "t0_rod", data, args=ARGS)
    with pytest.raises(ValueError, match="model: expected a function returning one array"):
        fitting.fit(lambda p, a: (p.t0_rod, p.t0_cone), START, "t0_rod", data)
    with pytest.raises(ValueError, match="nll: expected a function nll.*got 'gauss'"):
        fitting.fit(log_threshold, START, NAMES, data, args=ARGS, nll="gauss")

    class Counts(eqx.Module):
        rate: jax.Array = eqx.field(default=1.0, converter=jnp.asarray)
        n: jax.Array = eqx.field(default=3, converter=jnp.asarray)
        plain: float = 1.0
        fixed: float = eqx.field(default=1.0, static=True)

    for name, why in (
        ("n", "holds int(32|64) values"),
        ("plain", "holds a Python float"),
        ("fixed", "is a static field"),
    ):
        with pytest.raises(ValueError, match=rf"names: '{name}' of Counts {why}; .*1\.0, not 1"):
            fitting.fit(lambda p, x: p.rate * x, Counts(), ("rate", name), np.ones(3), args=1.0)


# -- the mechanism on a small model -------------------------------------------


class Decay(eqx.Module):
    """``y = a exp(-t / b) + c``."""

    a: jax.Array = eqx.field(default=1.0, converter=jnp.asarray)
    b: jax.Array = eqx.field(default=1.0, converter=jnp.asarray)
    c: jax.Array = eqx.field(default=0.0, converter=jnp.asarray)


def decay(params, t):
    return params.a * jnp.exp(-t / params.b) + params.c


T = jnp.linspace(0.0, 4.0, 25)
ABC = ("a", "b", "c")
UNBOUNDED_C = {"c": None}
SD = 0.05


def test_nielsen_update_of_the_damping():
    # lambda = 1 / step_size. An accepted step (gain ratio rho > 0) lowers
    # lambda by up to 3 (rho = 1: the linear model was exact), keeps it at
    # rho = 1/2 and at most doubles it as rho -> 0; each rejection in a row
    # raises lambda by 2, 4, 8, ... (Madsen, Nielsen and Tingleff 2004, §3.2).
    lam = lambda step_size: 1.0 / float(step_size)  # noqa: E731
    for rho, factor in ((1.0, 1 / 3), (0.5, 1.0), (1e-9, 2.0), (0.25, 1 - (-0.5) ** 3)):
        accept, step_size, nu = fitting.nielsen_update(rho, 1.0, 8.0)
        assert bool(accept) and float(nu) == 2.0
        assert lam(step_size) == pytest.approx(factor, rel=1e-7)
    step_size, nu = 1.0, 2.0
    for expected in (2.0, 8.0, 64.0):
        accept, step_size, nu = fitting.nielsen_update(-0.5, step_size, nu)
        assert not bool(accept) and lam(step_size) == pytest.approx(expected)
    accept, step_size, nu = fitting.nielsen_update(0.0, 1.0, 2.0)
    assert not bool(accept)  # no reduction is no progress


def _scipy(data, **kw):
    return curve_fit(
        lambda t, a, b, c: a * np.exp(-t / b) + c, np.asarray(T), data, p0=(1, 1, 0), **kw
    )


@pytest.fixture(scope="module")
def decays():
    """Three noisy decays (a = 2, b = 0.7, c = 0.3, sd 0.05) and their fit."""
    rng = np.random.default_rng(0)
    data = 2.0 * np.exp(-np.asarray(T) / 0.7) + 0.3 + SD * rng.standard_normal((3, T.size))
    return data, fitting.fit(decay, Decay(), ABC, data, args=T, bounds=UNBOUNDED_C)


def test_least_squares_matches_scipy_curve_fit(decays):
    data, f = decays
    assert np.all(f.converged)
    for i in range(3):
        popt, pcov = _scipy(data[i])
        # Both stop by MINPACK's ftol (1e-8): the same estimates to far below
        # their standard errors.
        est = np.array([float(f.estimate[n][i]) for n in ABC])
        assert np.all(np.abs(est - popt) < 1e-3 * np.sqrt(np.diag(pcov)))
        # MINPACK's covariance comes from its last Jacobian, near the estimate.
        np.testing.assert_allclose(np.asarray(f.cov[i]), pcov, rtol=1e-4)
        # At the estimate itself: s^2 (J'J)^-1 with J by hand, in natural units.
        a, b, c = (float(f.estimate[n][i]) for n in ABC)
        t = np.asarray(T)
        J = np.stack([np.exp(-t / b), a * t / b**2 * np.exp(-t / b), np.ones_like(t)], -1)
        r = a * np.exp(-t / b) + c - data[i]
        cov = np.linalg.inv(J.T @ J) * (r @ r) / (t.size - 3)
        np.testing.assert_allclose(np.asarray(f.cov[i]), cov, rtol=1e-9)
        np.testing.assert_allclose([f.se[n][i] for n in ABC], np.sqrt(np.diag(cov)), rtol=1e-9)
    # Known noise: weights 1/sd^2 and absolute_sigma, forward and reverse mode.
    kw = dict(args=T, bounds=UNBOUNDED_C, weights=np.full(T.size, SD**-2), absolute_sigma=True)
    fwd = fitting.fit(decay, Decay(), ABC, data, **kw)
    bwd = fitting.fit(decay, Decay(), ABC, data, jac="bwd", **kw)
    _, pcov = _scipy(data[0], sigma=np.full(T.size, SD), absolute_sigma=True)
    np.testing.assert_allclose(np.asarray(fwd.cov[0]), pcov, rtol=1e-4)
    for name in ABC:
        assert np.all(np.abs(fwd.estimate[name] - f.estimate[name]) < 1e-3 * f.se[name])
        np.testing.assert_allclose(bwd.estimate[name], fwd.estimate[name], rtol=1e-7)
        np.testing.assert_allclose(bwd.se[name], fwd.se[name], rtol=1e-6)


@pytest.mark.slow
def test_intervals_follow_each_fields_bounds(decays):
    """``Fit.interval``: ``u +- z se_u`` mapped back through the bounds, by
    the formulas of each map written out here."""
    data, f = decays
    z = norm.ppf(0.975)
    got = f.interval()
    for name in ("a", "b"):  # positive: p exp(+-z se / p)
        p, se = np.asarray(f.estimate[name]), np.asarray(f.se[name])
        np.testing.assert_allclose(got[name][0], p * np.exp(-z * se / p), rtol=1e-12)
        np.testing.assert_allclose(got[name][1], p * np.exp(z * se / p), rtol=1e-12)
    p, se = np.asarray(f.estimate["c"]), np.asarray(f.se["c"])  # unbounded: Wald
    np.testing.assert_allclose(got["c"][0], p - z * se, rtol=1e-12)
    np.testing.assert_allclose(got["c"][1], p + z * se, rtol=1e-12)
    narrow = f.interval(0.5)["a"]
    assert np.all(narrow[0] > got["a"][0]) and np.all(narrow[1] < got["a"][1])

    # Both ends bounded (a logistic map) and only the upper one (p = 5 - exp(u)).
    bounded = fitting.fit(
        decay, Decay(), ABC, data, args=T, bounds={"a": (0.0, 10.0), "b": (-np.inf, 5.0), "c": None}
    )
    got = bounded.interval()
    p, se = np.asarray(bounded.estimate["a"]), np.asarray(bounded.se["a"])
    x = p / 10.0
    u, se_u = np.log(x / (1 - x)), se / (10.0 * x * (1 - x))
    np.testing.assert_allclose(got["a"][0], 10.0 / (1 + np.exp(-(u - z * se_u))), rtol=1e-10)
    np.testing.assert_allclose(got["a"][1], 10.0 / (1 + np.exp(-(u + z * se_u))), rtol=1e-10)
    p, se = np.asarray(bounded.estimate["b"]), np.asarray(bounded.se["b"])
    room = 5.0 - p
    np.testing.assert_allclose(got["b"][0], 5.0 - room * np.exp(z * se / room), rtol=1e-10)
    np.testing.assert_allclose(got["b"][1], 5.0 - room * np.exp(-z * se / room), rtol=1e-10)
    for name in ("a", "b"):
        assert np.all(got[name][0] < bounded.estimate[name])
        assert np.all(bounded.estimate[name] < got[name][1])
    with pytest.raises(ValueError, match="level: expected a number between 0 and 1, got 95"):
        f.interval(95)


def test_a_weakly_determined_positive_parameter_keeps_a_positive_interval():
    # a = 0.03 in noise of sd 0.05: its standard error is near its size and
    # the Wald interval reaches below 0; the interval through log(a) does not.
    rng = np.random.default_rng(1)
    data = 0.03 * np.exp(-np.asarray(T) / 0.7) + 0.3 + SD * rng.standard_normal(T.size)
    f = fitting.fit(decay, Decay(), ABC, data, args=T, bounds=UNBOUNDED_C)
    a, se = float(f.estimate["a"]), float(f.se["a"])
    assert bool(f.converged) and se > a / 2 and a - norm.ppf(0.975) * se < 0
    low, high = f.interval()["a"]
    assert 0 < float(low) < a < float(high)


@pytest.mark.slow
@pytest.mark.parametrize("dtype, scales", [("float64", (1e-9, 1e9)), ("float32", (1e-4, 1e5))])
def test_the_units_of_data_and_weights_do_not_change_the_fit(decays, dtype, scales):
    # The solver works on residuals in units of those at the start. In the
    # data's own units, data in small units would stop at the start
    # (optimistix's first test compares the residuals with zeros, below
    # atol) and data in large units would never move (the damping, 1e-3 max
    # diag(J'J), above optimistix's 1/eps cap), both reporting
    # converged=True. (Positive fields, fitted in
    # log units; an unbounded field is fitted in its own units.)
    data = np.asarray(decays[0][0], dtype)

    def fit(s, **kw):
        start = Decay(*(jnp.asarray(v, dtype) for v in (s, 1.0, 0.1 * s)))
        return fitting.fit(decay, start, ABC, s * data, args=jnp.asarray(T, dtype), **kw)

    with jax.enable_x64(dtype == "float64"):
        reference = fit(1.0)
        fits = [fit(s) for s in scales] + [fit(1.0, weights=w) for w in (1e-30, 1e30)]
    assert bool(reference.converged)
    rtol = 1e-9 if dtype == "float64" else 2e-5
    # In float32 the last steps are taken at the rounding floor of the sum
    # of squares, where the data's rounding in other units decides whether
    # one more step is accepted: 10 to 12 steps here.
    slack = 0 if dtype == "float64" else 2
    for f, s in zip(fits, (*scales, 1.0, 1.0), strict=True):
        assert bool(f.converged) and abs(int(f.steps) - int(reference.steps)) <= slack
        for name, unit in zip(ABC, (s, 1.0, s), strict=True):
            np.testing.assert_allclose(
                float(f.estimate[name]) / unit, float(reference.estimate[name]), rtol=rtol
            )
            np.testing.assert_allclose(
                float(f.se[name]) / unit, float(reference.se[name]), rtol=100 * rtol
            )


class Line(eqx.Module):
    """``y = a + b x``."""

    a: jax.Array = eqx.field(default=1.0, converter=jnp.asarray)
    b: jax.Array = eqx.field(default=1.0, converter=jnp.asarray)


def line(params, x):
    return params.a + params.b * x


def test_the_units_of_an_unbounded_parameter_do_not_change_the_fit():
    # Each parameter is damped by its own Jacobian column (MINPACK's
    # scaling): x in [0, 1] or in [0, 1e6] (b in units a million times
    # smaller) gives the same steps and the same line. Damped alike (the
    # same lambda for both), b's long column would leave a creep: 15 steps
    # for x up to 1,000.
    rng = np.random.default_rng(3)
    x = np.linspace(0.0, 1.0, 30)
    y = 2.0 + 0.5 * x + 0.01 * rng.standard_normal(x.size)
    with jax.enable_x64(True):
        kw = dict(bounds={"a": None, "b": None})
        unit = fitting.fit(line, Line(0.0, 0.0), ("a", "b"), y, args=jnp.asarray(x), **kw)
        mega = fitting.fit(line, Line(0.0, 0.0), ("a", "b"), y, args=jnp.asarray(1e6 * x), **kw)
    b, a = np.polyfit(x, y, 1)
    assert bool(unit.converged) and bool(mega.converged)
    assert int(mega.steps) == int(unit.steps) <= 6
    np.testing.assert_allclose([float(unit.estimate["a"]), float(unit.estimate["b"])], [a, b])
    np.testing.assert_allclose(float(mega.estimate["a"]), a, rtol=1e-9)
    np.testing.assert_allclose(float(mega.estimate["b"]), b * 1e-6, rtol=1e-9)
    np.testing.assert_allclose(float(mega.se["b"]), float(unit.se["b"]) * 1e-6, rtol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_strongly_correlated_parameters_keep_their_standard_errors(dtype):
    # A line over x from 500 to 510: intercept and slope correlated at
    # -0.99998, each well determined. Judged on the eigenvalues of J'J
    # formed in float32, the pair would be "not identified" (se inf); judged
    # on the singular values of J it matches statsmodels in both precisions.
    rng = np.random.default_rng(1)
    x = np.linspace(500.0, 510.0, 30)
    y = 3.0 + 0.02 * (x - 500.0) - 10.0 + 0.01 * rng.standard_normal(x.size)
    ols = sm.OLS(y, sm.add_constant(x)).fit()
    assert ols.cov_params()[0, 1] / np.prod(ols.bse) < -0.9999
    with jax.enable_x64(dtype == "float64"):
        fits = fitting.fit(
            line,
            Line(1.0, 1.0),
            ("a", "b"),
            y.astype(dtype),
            args=jnp.asarray(x, dtype),
            bounds={"a": None, "b": None},
        )
    assert bool(fits.converged)
    rtol = 1e-9 if dtype == "float64" else 1e-4
    np.testing.assert_allclose([float(fits.se[n]) for n in "ab"], ols.bse, rtol=rtol)
    np.testing.assert_allclose(
        [float(fits.estimate[n]) for n in "ab"],
        ols.params,
        rtol=1e-3 if dtype == "float32" else 1e-9,
    )


def test_a_parameter_small_beside_a_large_offset_is_fitted_and_identified(decays):
    # a and b of a exp(-t / b) + c on an offset c = 1e8, all three fitted in
    # log units: the columns of a and b are 3e-8 of c's. Judged against
    # sqrt(eps) of the longest column they would count as not felt: the
    # damping would hold them at the start (loss 2.9, three steps) with
    # standard errors of inf. Float64 resolves them: the fit is SciPy's curve_fit of
    # the same data less the offset. (curve_fit of the data themselves stops
    # at twice the least sum of squares: its finite differences in c,
    # steps of sqrt(eps) 1e8, do not resolve the decay.)
    data = decays[0][0]
    with jax.enable_x64(True):
        start = Decay(*(jnp.asarray(v, jnp.float64) for v in (3.0, 0.5, 1e8)))
        f = fitting.fit(decay, start, ABC, data + 1e8, args=jnp.asarray(T, jnp.float64))
    popt, pcov = _scipy(data)
    popt[2] += 1e8
    assert bool(f.converged)
    for name, value, se in zip(ABC, popt, np.sqrt(np.diag(pcov)), strict=True):
        assert float(f.estimate[name]) == pytest.approx(value, abs=1e-3 * se)
        assert float(f.se[name]) == pytest.approx(se, rel=1e-3)


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_converged_means_at_the_minimum_even_from_a_start_far_from_the_data(dtype):
    # Data in units of 1e8, positive parameters (fitted in log units)
    # started at 1. In float64 the fit walks the eight decades to the
    # least-squares line. (Without MINPACK's scaling it would stop with
    # a = 15, 3,000 times the least sum of squares, by the ftol test, and
    # report converged.) In float32 no step the sum of squares can resolve is
    # small enough to be accepted, and the solve stalls at the start:
    # solved, but a Gauss-Newton step from there is many standard errors
    # long, so not converged. Either way, converged is true exactly when
    # the fit is at the minimum.
    x = np.linspace(0.0, 5.0, 20)
    y = 1e8 * (2.0 + 0.3 * x) * (1.0 + 0.01 * np.sin(np.arange(20.0)))
    b, a = np.polyfit(x, y, 1)
    least = 0.5 * np.sum((y - a - b * x) ** 2)
    with jax.enable_x64(dtype == "float64"):
        f = fitting.fit(line, Line(), ("a", "b"), y.astype(dtype), args=jnp.asarray(x, dtype))
    at_minimum = float(f.loss) < least * (1 + 1e-3)
    assert bool(f.converged) == at_minimum == (dtype == "float64")
    assert (float(f.newton_step) <= fitting.NEWTON_STEP) == at_minimum
    if at_minimum:
        np.testing.assert_allclose([float(f.estimate["a"]), float(f.estimate["b"])], [a, b])


def test_estimates_and_standard_errors_follow_the_order_of_names(decays):
    data, _ = decays
    f = fitting.fit(decay, Decay(), ("c", "a", "b"), data[0], args=T, bounds=UNBOUNDED_C)
    assert list(f.estimate) == list(f.se) == ["c", "a", "b"]
    np.testing.assert_allclose(
        np.sqrt(np.diagonal(np.asarray(f.cov))), [float(v) for v in f.se.values()]
    )
    assert float(f.newton_step) < 1e-3  # at the minimum


def test_float32_data_of_a_float64_model_are_fitted_in_float64(decays):
    # jax_enable_x64 on (as in the experiments), data loaded as float32: the
    # model computes in float64, and so does the fit (otherwise lineax fails
    # with "pytree does not have a consistent input_structure").
    data, f64 = decays
    f = fitting.fit(decay, Decay(), ABC, data[0].astype(np.float32), args=T, bounds=UNBOUNDED_C)
    assert f.estimate["a"].dtype == jnp.float64 and bool(f.converged)
    np.testing.assert_allclose(float(f.estimate["b"]), float(f64.estimate["b"][0]), rtol=1e-6)


@pytest.mark.slow
def test_float64_data_of_a_float32_model_are_fitted_in_float32(decays):
    # NumPy's float64 measurements against a model that computes in float32
    # (as the operators do on float32 frames): the fit is in the model's
    # float32, in both modes of the Jacobian; in float64 JAX would refuse it
    # ("Custom JVP rule must produce primal and tangent outputs with
    # corresponding dtypes").
    data, f64 = decays

    def decay32(params, t):
        return decay(params, t).astype(jnp.float32)

    for jac in ("fwd", "bwd"):
        f = fitting.fit(decay32, Decay(), ABC, data[0], args=T, bounds=UNBOUNDED_C, jac=jac)
        assert f.estimate["a"].dtype == jnp.float32 and bool(f.converged)
        g = fitting.fit(
            decay32, Decay(), ABC, data[0].astype(np.float32), args=T, bounds=UNBOUNDED_C, jac=jac
        )
        for name in ABC:  # the fit of the data rounded to float32
            assert float(f.estimate[name]) == float(g.estimate[name])
        np.testing.assert_allclose(float(f.estimate["b"]), float(f64.estimate["b"][0]), rtol=1e-4)
    # Finite measurements the cast makes infinite are not "not finite" data.
    with pytest.raises(ValueError, match="^data: 1 measurements lie beyond the range of float32"):
        fitting.fit(
            decay32, Decay(), ABC, np.append(data[0][:-1], 1e39), args=T, bounds=UNBOUNDED_C
        )


@pytest.mark.parametrize("empty", ["nan", "weight 0"])
def test_a_dataset_without_measurements_stops_at_once(decays, empty):
    # Its residuals are all masked to 0, so every step's gain ratio is 0/0:
    # rejecting step after step, it would run to max_steps (256) while its
    # batch waits.
    data, f = decays
    data = np.concatenate([data, np.full((1, T.size), np.nan if empty == "nan" else 1.0)])
    weights = np.ones_like(data)
    weights[-1] = 0.0 if empty == "weight 0" else 1.0
    fits = fitting.fit(decay, Decay(), ABC, data, args=T, weights=weights, bounds=UNBOUNDED_C)
    assert int(fits.steps[-1]) <= 2 and int(fits.n_masked[-1]) == T.size
    assert not bool(fits.converged[-1]) and np.all(np.isinf([fits.se[n][-1] for n in ABC]))
    for name in ABC:
        assert float(fits.estimate[name][-1]) == float(getattr(Decay(), name))
        np.testing.assert_array_equal(fits.estimate[name][:-1], f.estimate[name])
    assert int(np.max(fits.steps)) == int(np.max(f.steps))


def test_vmapped_fits_equal_looped_fits(decays):
    data, batch = decays
    for i in range(3):
        single = fitting.fit(decay, Decay(), ABC, data[i], args=T, bounds=UNBOUNDED_C)
        assert single.estimate["a"].shape == ()
        for name in ABC:
            assert float(single.estimate[name]) == pytest.approx(
                float(batch.estimate[name][i]), rel=1e-9
            )
            assert float(single.se[name]) == pytest.approx(float(batch.se[name][i]), rel=1e-7)
        assert int(single.steps) == int(batch.steps[i])
        assert bool(single.converged) == bool(batch.converged[i])


@pytest.fixture(scope="module")
def uneven():
    """Six decays whose fits take from 6 to 97 steps, and their fit by one
    vmapped solve (six datasets fit in the default lanes). Rows: two badly
    conditioned ones (a weak decay, 12 steps, and a slow one, 15 steps; a
    and b correlated at 0.96 and 0.99), three noisy ones as in ``decays``,
    and a flat one, whose b the data do not determine (97 steps)."""
    t = np.asarray(T)
    rng = np.random.default_rng(1)
    weak = 0.05 * np.exp(-t / 1.5) + 0.3 + SD * rng.standard_normal(t.size)
    slow = 2.0 * np.exp(-t / 5.0) + 0.3
    noisy = (
        2.0 * np.exp(-t / 0.7) + 0.3 + SD * np.random.default_rng(0).standard_normal((3, t.size))
    )
    data = np.stack([weak, slow, *noisy, np.full(t.size, 0.4)])
    return data, fitting.fit(decay, Decay(), ABC, data, args=T, bounds=UNBOUNDED_C)


@pytest.mark.slow
def test_float32_fits_in_lanes_stop_at_their_minimum(monkeypatch):
    # t0_cone from 20 frames of the 2000 operator, float32, in a queue of 4
    # lanes. At the minimum every step is rejected and the damping grows;
    # taken as a difference of two sums, the predicted reduction would keep
    # 2 roundings of the sum of squares in the lanes' vectorised arithmetic
    # and never pass the stall test: 256 steps, solved False, where one
    # lane alone stops after 8.
    from jaxadapt.operators import pattanaik2000 as op

    def model(params, frames):
        return jnp.log10(op.run(params, frames, 0.02)[1].state.A_cone)

    monkeypatch.setattr(_fit, "LANES", 4)
    with jax.enable_x64(False):
        frames = jnp.ones((20, 1, 1, 3), jnp.float32).at[10:].set(100.0)
        clean = model(op.Params(t0_cone=np.linspace(0.04, 0.12, 70)[35]), frames)
        noise = np.random.default_rng(0).standard_normal((70, 20))[35].astype(np.float32)
        data = np.tile(np.asarray(clean) + 0.002 * noise, (5, 1))
        fits = fitting.fit(model, op.Params(), "t0_cone", data, args=frames)
    assert np.all(np.asarray(fits.solved)) and np.all(np.asarray(fits.converged))
    assert np.max(np.asarray(fits.steps)) <= 12


@pytest.mark.slow
def test_queued_fits_equal_one_vmapped_solve(uneven, monkeypatch, count_calls):
    # Two lanes for six datasets: each lane takes the next dataset when its
    # fit stops, and the host hands the queue over two datasets at a time,
    # so that the weak decay's solve (12 steps) is stopped at a round's end
    # and carried on with its whole solver state. Every number equals the
    # uninterrupted vmapped solve's, step counts included.
    data, plain = uneven
    steps = np.asarray(plain.steps)
    np.testing.assert_array_equal(steps, [12, 15, 8, 7, 6, 97])
    monkeypatch.setattr(_fit, "LANES", 2)
    traces = count_calls(_fit, "_fit_one")
    queued = fitting.fit(decay, Decay(), ABC, data, args=T, bounds=UNBOUNDED_C)
    assert traces == []  # the queue, not the vmapped solve
    np.testing.assert_array_equal(queued.steps, steps)
    for name in ("converged", "solved", "n_masked"):
        np.testing.assert_array_equal(getattr(queued, name), getattr(plain, name))
    for name in ABC:
        np.testing.assert_allclose(queued.estimate[name], plain.estimate[name], rtol=1e-12)
        np.testing.assert_allclose(queued.se[name], plain.se[name], rtol=1e-9)
    for a, b in zip(jax.tree.leaves(queued), jax.tree.leaves(plain), strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)


def test_queued_fits_that_do_not_converge_are_flagged_and_finite(uneven, monkeypatch, count_calls):
    # The flat row: a -> 0 leaves b undetermined. The solver stops once no
    # step lowers the sum of squares (it is at its rounding floor), but a
    # and b are not identified: not converged, their standard errors
    # infinite. The weak and slow rows are badly conditioned but converge.
    data, _ = uneven
    monkeypatch.setattr(_fit, "LANES", 2)
    f = fitting.fit(decay, Decay(), ABC, data[::-1], args=T, bounds=UNBOUNDED_C)
    np.testing.assert_array_equal(f.steps, [97, 6, 7, 8, 15, 12])
    np.testing.assert_array_equal(f.converged, [False, True, True, True, True, True])
    assert bool(f.solved[0]) and np.isinf(f.se["a"][0]) and np.isinf(f.se["b"][0])
    for leaf in jax.tree.leaves(f):
        assert not np.any(np.isnan(np.asarray(leaf)))
    assert np.all(np.isfinite(f.residuals)) and np.all(np.isfinite(f.loss))
    np.testing.assert_allclose(f.estimate["c"][0], 0.4, rtol=1e-4)
    # The compiled functions see the lanes, not the datasets: another number
    # of datasets traces nothing anew.
    traces = count_calls(_queue._Lane, "__init__")
    g = fitting.fit(decay, Decay(), ABC, data[1:4], args=T, bounds=UNBOUNDED_C)
    assert traces == []
    np.testing.assert_array_equal(g.steps, [15, 8, 7])


def test_a_queue_traces_its_round_once(uneven, monkeypatch, count_calls):
    # The carry that a round hands to the next (the solver's whole state,
    # the damping's included) keeps its dtypes and weak types, so that the
    # rounds after the first reuse its compilation (_lanes is called once
    # when _start is traced and once when _round is).
    data, _ = uneven
    monkeypatch.setattr(_fit, "LANES", 2)
    traces = count_calls(_queue, "_lanes")

    def model(params, t):  # a model of its own: nothing is compiled for it yet
        return decay(params, t)

    fitting.fit(model, Decay(), ABC, data, args=T, bounds=UNBOUNDED_C)
    assert len(traces) == 2


def test_a_traced_call_is_one_vmapped_solve(decays, monkeypatch):
    # Under jit (or vmap) there is no host to keep a queue: the batch is
    # fitted in one vmapped solve, whatever the lanes.
    data, f = decays
    monkeypatch.setattr(_fit, "LANES", 1)
    traced = jax.jit(lambda d: fitting.fit(decay, Decay(), ABC, d, args=T, bounds=UNBOUNDED_C))
    g = traced(data)
    np.testing.assert_array_equal(g.steps, f.steps)
    for name in ABC:
        np.testing.assert_allclose(g.estimate[name], f.estimate[name], rtol=1e-12)


def test_bounds_are_respected(decays):
    data, unbounded = decays
    # Rows 0-1 as before; row 2 decays with b = 5, above the upper bound 2:
    # its estimate presses against the bound from inside and stays finite.
    slow = 2.0 * np.exp(-np.asarray(T) / 5.0) + 0.3
    rows = np.stack([data[0], data[1], slow])
    f = fitting.fit(decay, Decay(), ABC, rows, args=T, bounds={"b": (0.1, 2.0), "c": None})
    b = np.asarray(f.estimate["b"])
    assert 1.99 < b[2] < 2.0
    for leaf in jax.tree.leaves(f):
        assert not np.any(np.isnan(np.asarray(leaf)))
    # Inside the bounds: the unbounded fit, standard errors through the
    # logistic map's derivative included.
    for name in ABC:
        gap = np.abs(f.estimate[name][:2] - unbounded.estimate[name][:2])
        assert np.all(gap < 1e-3 * unbounded.se[name][:2])
        np.testing.assert_allclose(f.se[name][:2], unbounded.se[name][:2], rtol=1e-3)


class Psychometric(eqx.Module):
    pse: jax.Array = eqx.field(default=0.0, converter=jnp.asarray)
    sigma: jax.Array = eqx.field(default=0.2, converter=jnp.asarray)


def _binomial_nll(p, y):
    """Negative log-likelihood of a proportion ``y`` of one trial."""
    p = jnp.clip(p, 1e-12, 1 - 1e-12)
    return -(y * jnp.log(p) + (1 - y) * jnp.log1p(-p))


def _cumulative_gaussian(params, x):
    return jax.scipy.stats.norm.cdf((x - params.pse) / params.sigma)


def test_maximum_likelihood_matches_statsmodels_probit():
    # The paper's glmfit probit, P(x) = Phi((x - pse) / sigma), fitted by
    # binomial maximum likelihood; statsmodels gives (b0, b1) = (-pse/sigma,
    # 1/sigma) and their observed-information covariance.
    levels = np.log10(np.array([14.0, 19, 27, 35, 49]) / 27)
    rng = np.random.default_rng(4)
    n = np.full((3, 5), 30)
    k = rng.binomial(n, norm.cdf((levels - 0.03) / 0.15))
    ours = fitting.fit(
        _cumulative_gaussian,
        Psychometric(),
        ("pse", "sigma"),
        k / n,
        args=jnp.asarray(levels),
        weights=n,
        nll=_binomial_nll,
        bounds={"pse": None},
    )
    assert np.all(ours.converged)
    family = sm.families.Binomial(link=sm.families.links.Probit())
    for i in range(3):
        glm = sm.GLM(np.c_[k[i], n[i] - k[i]], sm.add_constant(levels), family=family)
        ref = glm.fit(tol=1e-14, maxiter=1000)
        b0, b1 = ref.params
        cov = np.linalg.inv(-glm.hessian(ref.params, observed=True))
        # pse = -b0/b1 and sigma = 1/b1: the delta method by hand.
        G = np.array([[-1 / b1, b0 / b1**2], [0.0, -1 / b1**2]])
        se = np.sqrt(np.diag(G @ cov @ G.T))
        est = [float(ours.estimate["pse"][i]), float(ours.estimate["sigma"][i])]
        np.testing.assert_allclose(est, [-b0 / b1, 1 / b1], rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose([ours.se["pse"][i], ours.se["sigma"][i]], se, rtol=1e-5)
        log_binomial = np.sum(gammaln(n[i] + 1) - gammaln(k[i] + 1) - gammaln(n[i] - k[i] + 1))
        assert float(ours.loss[i]) == pytest.approx(log_binomial - ref.llf, rel=1e-9)


@pytest.mark.slow
def test_float32_follows_the_data_and_another_batch_does_not_retrace(
    decays, monkeypatch, count_calls
):
    data, f64 = decays
    # The library default: float64 off, everything in float32.
    with jax.enable_x64(False):
        kw = dict(args=jnp.asarray(T, jnp.float32), bounds=UNBOUNDED_C)
        f32 = fitting.fit(decay, Decay(), ABC, data.astype(np.float32), **kw)
        assert f32.estimate["b"].dtype == jnp.float32 and f32.se["b"].dtype == jnp.float32
        assert np.all(f32.converged)
        for name in ABC:
            np.testing.assert_allclose(f32.estimate[name], f64.estimate[name], rtol=1e-3)
            np.testing.assert_allclose(f32.se[name], f64.se[name], rtol=1e-2)
        traces = count_calls(_fit, "_fit_one")
        fitting.fit(decay, Decay(), ABC, data.astype(np.float32) + 0.01, **kw)
        assert traces == []
