"""Every script in ``experiments/`` imports and has a ``main``; the measures
and helpers the scripts share do what they say.

Running them all is too slow for the suite (the fitting ones take 15 to 40 s
even with ``--smoke``); importing them catches a script left behind by a
change to what it imports, such as a function moved to another module.
"""

import importlib
from pathlib import Path

import pytest

#: End-to-end or long: left out of the quick run (pytest -m "not slow").
pytestmark = pytest.mark.slow

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"
SHARED = ("common", "jacobs_common")  # helpers the scripts import
SCRIPTS = sorted(p.stem for p in EXPERIMENTS.glob("*.py") if p.stem not in SHARED)


@pytest.mark.parametrize("name", SCRIPTS)
def test_experiment_imports_and_has_a_main(name, monkeypatch):
    monkeypatch.syspath_prepend(str(EXPERIMENTS))
    assert callable(importlib.import_module(name).main)


def test_halo_measure_tells_edge_preserving_backgrounds_from_local_averages(monkeypatch):
    """``hdr_halos.halo``: the edge-preserving backgrounds score near 0 on both
    sides of the window's edge, though the regions have texture (the median
    of a region scored 0.26 and 0.33 for I_b = L itself), and a box average's
    room side more than 1 log unit."""
    import jax.numpy as jnp
    import numpy as np

    from jaxadapt.color import photopic_luminance
    from jaxadapt.scenes import OUTSIDE, ROOM, interior_with_window

    monkeypatch.syspath_prepend(str(EXPERIMENTS))
    hdr_halos = importlib.import_module("hdr_halos")
    rgb, labels = interior_with_window(120, 80)
    L = np.asarray(photopic_luminance(rgb))
    estimators = hdr_halos.estimators(0.25)
    room, outside = hdr_halos.edge_bands(labels, 3)

    def score(name, region, band):
        estimate = estimators[name]
        alone = jnp.asarray(hdr_halos.region_alone(L, region))
        return hdr_halos.halo(
            np.asarray(estimate(jnp.asarray(L))), np.asarray(estimate(alone)), band
        )

    for region, band in ((labels == ROOM, room), (labels == OUTSIDE, outside)):
        assert hdr_halos.halo(L, hdr_halos.region_alone(L, region), band) == 0.0
        for name in ("bilateral (Pattanaik-Yee)", "adaptive"):
            assert score(name, region, band) < 0.02
    assert score("box", labels == ROOM, room) > 1.0


def test_run_scene_starts_from_the_scenes_prior_adaptation(monkeypatch):
    """A viewer adapted to 1e4 cd/m2 before a dark scene starts at log10 A = 4;
    without a prior adaptation, at the dark frame's floor (100 cd/m2)."""
    from jaxadapt import scenes
    from jaxadapt.operators import jacobs2015 as op

    monkeypatch.syspath_prepend(str(EXPERIMENTS))
    run_scene = importlib.import_module("jacobs_common").run_scene
    scene = scenes.flash(8, 8, duration=0.3, fps=10)
    params = op.Params(acuity=False, dithering=False)
    for adaptation, log_A in ((None, 2.0), (1e4, 4.0)):
        _, diag = run_scene(scene._replace(adaptation=adaptation), params)
        assert float(diag.A[0]) == pytest.approx(log_A)


@pytest.mark.parametrize("smoke", [True, False])
def test_a_smoke_run_says_its_numbers_are_not_the_full_runs(smoke, monkeypatch, tmp_path, capsys):
    monkeypatch.syspath_prepend(str(EXPERIMENTS))
    common = importlib.import_module("common")
    argv = ["script", "--out", str(tmp_path / "out")] + (["--smoke"] if smoke else [])
    monkeypatch.setattr("sys.argv", argv)
    args, out = common.setup("fit_tvi", "A script.")
    assert args.smoke == smoke and out.is_dir()
    said = capsys.readouterr().out
    assert ("fit_tvi: smoke run" in said and "not the full run's" in said) == smoke
    assert (said == "") != smoke, said  # a full run says nothing of its own
