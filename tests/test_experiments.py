"""Every script in ``experiments/`` imports and has a ``main``.

Running them all is too slow for the suite (the fitting ones take 15 to 40 s
even with ``--smoke``); importing them catches a script left behind by a
change to what it imports, as ``fit_tvi.py`` was when ``sensitivity`` moved
from ``fit_time_constants.py`` to ``threshold.increment_sensitivity``.
"""

import importlib
from pathlib import Path

import pytest

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"
SHARED = ("common", "jacobs_common")  # helpers the scripts import
SCRIPTS = sorted(p.stem for p in EXPERIMENTS.glob("*.py") if p.stem not in SHARED)


@pytest.mark.parametrize("name", SCRIPTS)
def test_experiment_imports_and_has_a_main(name, monkeypatch):
    monkeypatch.syspath_prepend(str(EXPERIMENTS))
    assert callable(importlib.import_module(name).main)
