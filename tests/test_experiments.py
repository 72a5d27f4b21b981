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


def test_halo_measure_is_zero_without_a_halo_and_large_for_a_box(monkeypatch):
    """``hdr_halos.halo`` scores I_b = L 0 on both sides of the window's edge,
    though the regions have texture, and a box average's raised room side > 1."""
    import jax.numpy as jnp
    import numpy as np

    from jaxadapt.color import photopic_luminance
    from jaxadapt.scenes import OUTSIDE, ROOM, interior_with_window

    monkeypatch.syspath_prepend(str(EXPERIMENTS))
    hdr_halos = importlib.import_module("hdr_halos")
    rgb, labels = interior_with_window(120, 80)
    L = np.asarray(photopic_luminance(rgb))
    room, outside = hdr_halos.edge_bands(labels, 3)
    for region, band in ((labels == ROOM, room), (labels == OUTSIDE, outside)):
        assert hdr_halos.halo(L, hdr_halos.region_alone(L, region), band) == 0.0
    box = hdr_halos.estimators(0.25)["box"]
    alone = jnp.asarray(hdr_halos.region_alone(L, labels == ROOM))
    assert hdr_halos.halo(np.asarray(box(jnp.asarray(L))), np.asarray(box(alone)), room) > 1.0
