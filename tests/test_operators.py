"""Every operator of the registry keeps the contract written in
:class:`jaxadapt.operators.Operator`, and runs as the pipeline calls it."""

import inspect
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxadapt import operators
from jaxadapt.operators import OPERATORS, TONE_CURVE_NAMES, Operator, classic


def _signature(function, method=False):
    parameters = list(inspect.signature(function).parameters.values())
    return [(p.name, p.kind, p.default) for p in parameters[1 if method else 0 :]]


@pytest.mark.parametrize("name", list(OPERATORS))
def test_each_operator_module_keeps_the_contract(name):
    op = OPERATORS[name]
    assert isinstance(op, Operator)
    for function in ("init", "step", "run", "diagnostics_table"):
        assert _signature(getattr(op, function)) == _signature(
            getattr(Operator, function), method=True
        ), (name, function)


def test_a_module_without_a_function_of_the_contract_is_not_an_operator():
    from jaxadapt.operators import goal

    assert not isinstance(goal, Operator)


def test_the_tone_curves_are_named_once():
    assert tuple(classic.TONE_CURVES) == TONE_CURVE_NAMES
    assert [n for n in OPERATORS if OPERATORS[n] is classic] == list(TONE_CURVE_NAMES)
    with pytest.raises(KeyError):
        OPERATORS["pattanaik"]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["pattanaik2000", "jacobs2015", "photographic"])
def test_each_operator_runs_a_sequence_as_the_pipeline_does(name):
    # init, run over the frames, diagnostics as columns of one value per
    # frame: the calls of jaxadapt.pipeline, for any operator.
    op = OPERATORS[name]
    params = op.Params(classic.TONE_CURVES[name]()) if op is classic else op.Params()
    rng = np.random.default_rng(0)
    frames = jnp.asarray(rng.uniform(1.0, 100.0, (3, 8, 12, 3)), jnp.float32)
    dt = jnp.full(3, 1 / 30, jnp.float32)
    state = op.init(params, frames[0], key=jax.random.key(0))
    out, diag = op.run(params, frames, dt, state=state)
    assert out.shape == frames.shape and bool(jnp.all(jnp.isfinite(out)))
    assert isinstance(diag, op.Diagnostics)
    table = op.diagnostics_table(diag)
    np.testing.assert_allclose(table["t"], [0.0, 1 / 30, 2 / 30], rtol=1e-6)
    assert all(len(column) == 3 for column in table.values())


def test_the_registry_imports_an_operator_only_when_asked_for():
    # The command line lists the names at start-up; the import of an
    # operator (JAX, its compiled functions' modules) waits for its run.
    code = (
        "import sys; from jaxadapt.operators import OPERATORS; names = list(OPERATORS); "
        "assert not any(m.startswith('jaxadapt.operators.') for m in sys.modules), sys.modules; "
        "OPERATORS['jacobs2015']; assert 'jaxadapt.operators.jacobs2015' in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
    assert set(operators.__all__) == {"OPERATORS", "TONE_CURVE_NAMES", "Operator"}
