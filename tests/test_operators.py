"""Every operator of the registry keeps the contract written in
:class:`jaxadapt.operators.Operator`, and runs as the pipeline calls it."""

import dataclasses
import inspect
import subprocess
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxadapt import operators
from jaxadapt.operators import OPERATORS, TONE_CURVE_NAMES, Operator, Settings, classic


def _signature(function, method=False):
    parameters = list(inspect.signature(function).parameters.values())
    return [(p.name, p.kind, p.default) for p in parameters[1 if method else 0 :]]


@pytest.mark.parametrize("name", list(OPERATORS))
def test_each_operator_module_keeps_the_contract(name):
    op = OPERATORS[name]
    assert isinstance(op, Operator)
    for function in ("init", "step", "run", "diagnostics_table", "log_adaptation"):
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


@pytest.mark.parametrize("name", list(OPERATORS))
def test_configure_makes_the_params_the_settings_ask_for(name):
    op, supports = OPERATORS[name], OPERATORS.supports(name)
    settings = Settings(name, fps=60.0, pixels_per_degree=45.0, background_scale=5.0)
    params = op.configure(settings)
    assert isinstance(params, op.Params)
    if supports.local_background:
        local = op.configure(dataclasses.replace(settings, background="gaussian"))
        assert (local.background, local.background_scale) == ("gaussian", 5.0)
    if supports.time_dependent:
        assert float(params.pixels_per_degree) == 45.0
    for effect in supports.effects:  # each effect on alone, as the viewer asks
        alone = op.configure(dataclasses.replace(settings, effects=(effect,)))
        assert {e for e in supports.effects if getattr(alone, e)} == {effect}
    assert op.describe(settings)


@pytest.mark.parametrize(
    ("settings", "refused"),
    [
        (Settings("pattanaik2000", background="gaussian", given=frozenset({"goal"})), "goal"),
        (Settings("pattanaik2000", goal="log_average", given=frozenset({"gaze"})), "gaze"),
        (
            Settings(
                "pattanaik2000", goal="white_fraction", given=frozenset({"pixels_per_degree"})
            ),
            "pixels_per_degree",
        ),
    ],
)
def test_configure_refuses_a_chosen_setting_the_model_would_ignore(settings, refused):
    with pytest.raises(ValueError, match=f"^{refused}: "):
        OPERATORS[settings.name].configure(settings)
    # the same values taken by default are not refused
    OPERATORS[settings.name].configure(dataclasses.replace(settings, given=frozenset()))


def test_the_registry_imports_an_operator_only_when_asked_for():
    # The command line lists the names at start-up; the import of an
    # operator (JAX, its compiled functions' modules) waits for its run.
    code = (
        "import sys; from jaxadapt.operators import OPERATORS; names = list(OPERATORS); "
        "assert not any(m.startswith('jaxadapt.operators.') for m in sys.modules), sys.modules; "
        "OPERATORS['jacobs2015']; assert 'jaxadapt.operators.jacobs2015' in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
    assert set(operators.__all__) == {
        "BACKGROUND_SCALE",
        "OPERATORS",
        "TONE_CURVE_NAMES",
        "Operator",
        "Settings",
        "Supports",
    }
    code = (
        "import sys; from jaxadapt.operators import OPERATORS; OPERATORS.having('live'); "
        "OPERATORS.supports('jacobs2015').effects; "
        "assert not any(m.startswith('jaxadapt.operators.') for m in sys.modules), sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize("name", OPERATORS.having("time_dependent"))
def test_composable_says_whether_the_state_update_is_affine(name):
    # For a held frame, the step of a mix of two states is the mix of their
    # steps exactly when the registry says the operator is composable (the
    # basis of splitting a sequence in time).
    op, params, key = OPERATORS[name], OPERATORS[name].Params(), jax.random.key(0)
    rng = np.random.default_rng(0)
    with jax.enable_x64(True):
        frames = [jnp.asarray(rng.lognormal(m, 2.0, (8, 12, 3))) for m in (0.0, 4.0, 2.0)]
        a, b = (op.init(params, f, key=key) for f in frames[:2])

        def step(state):
            return op.step(params, state, frames[2], 0.5, key=key)[0]

        def mix(x, y):  # (keys and other non-float leaves as in x)
            floating = eqx.is_inexact_array
            return jax.tree.map(lambda u, v: 0.3 * u + 0.7 * v if floating(u) else u, x, y)

        gaps = [
            float(jnp.max(jnp.abs(u - v)))
            for u, v in zip(
                jax.tree.leaves(eqx.filter(step(mix(a, b)), eqx.is_inexact_array)),
                jax.tree.leaves(eqx.filter(mix(step(a), step(b)), eqx.is_inexact_array)),
                strict=True,
            )
        ]
    assert (max(gaps) < 1e-9) == OPERATORS.supports(name).composable, gaps


def test_no_operator_is_told_apart_by_its_name_outside_the_registry():
    # What an operator supports is data (OPERATORS.supports): no module of
    # the package compares a name with an operator's.
    import ast
    from pathlib import Path

    package = Path(operators.__file__).resolve().parent.parent
    names = set(OPERATORS)
    compared = []
    for path in package.rglob("*.py"):
        if path == Path(operators.__file__).resolve():
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Compare):
                sides = [node.left, *node.comparators]
                literals = [
                    e.value
                    for side in sides
                    for e in ([side] + list(getattr(side, "elts", [])))
                    if isinstance(e, ast.Constant) and e.value in names
                ]
                if literals:
                    compared.append(f"{path.relative_to(package)}:{node.lineno} {literals}")
    assert not compared, compared
