"""Edges of ``jaxadapt psychometric``: a group test without PSEs on one side,
and cue weights beyond float32's range."""

import csv
import warnings

import numpy as np
import pytest

from jaxadapt.cli import main


def _run(capsys, *argv):
    status = main(list(argv))
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def test_a_weight_beyond_float32_is_refused_up_front(tmp_path, capsys):
    # 1e300 would be cast to inf in the float32 simulation (NumPy's overflow
    # warning on stderr), then written as weight_blur=inf with NaN PSEs.
    for value in ("1e300", "-1e39", "nan", "inf"):
        out = tmp_path / value
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # no overflow warning either
            status, _, err = _run(
                capsys,
                *("psychometric", "simulate", "--protocol", "mesopic", "--observers", "2"),
                *("--weight", f"blur={value}", "--out", str(out)),
            )
        assert status == 2
        lines = err.splitlines()
        assert len(lines) == 1, err
        assert lines[0].startswith("jaxadapt: error: --weight: expected a finite number")
        assert "float32: -3.4e+38 to 3.4e+38" in lines[0] and f"blur={value}" in lines[0]
        assert not out.exists()


@pytest.mark.slow
def test_a_condition_without_determined_pses_has_no_group_test(tmp_path, capsys):
    # Every manipulated answer "yes": no manipulated PSE is determined, so
    # the test has nothing to rank on that side. No test is reported, not
    # one that found nothing ("rank-sum p = 1 (exact; n = 0, 3)", W = z =
    # rank_biserial = 0, p = 1, p_exact true).
    rng = np.random.default_rng(1)
    rows = ["participant,condition,level,response"]
    for participant in ("p1", "p2", "p3"):
        for level in np.linspace(-0.3, 0.3, 7):
            for _ in range(10):
                rows.append(f"{participant},control,{level:.2f},{int(rng.random() < 0.5 + level)}")
                rows.append(f"{participant},manip,{level:.2f},1")
    out = tmp_path / "out"
    out.mkdir()
    (out / "trials.csv").write_text("\n".join(rows) + "\n")
    status, stdout, err = _run(
        capsys,
        "psychometric",
        "fit",
        str(out / "trials.csv"),
        "--resamples",
        "0",
        "--out",
        str(out),
    )
    assert status == 0, err
    said = stdout.splitlines()[0]
    assert said.startswith("manip vs control: median PSE nan vs ")
    assert said.endswith("no rank-sum test: manip has no determined PSE (n = 0, 3)")
    (row,) = list(csv.DictReader(open(out / "group_test.csv")))
    for column in ("median", "shift", "rank_biserial", "W", "z", "p"):
        assert row[column] == "nan", (column, row)
    assert (row["p_exact"], row["n"], row["n_control"]) == ("false", "0", "3")


@pytest.mark.slow
def test_kept_undetermined_pses_are_said_as_the_priors(tmp_path, capsys):
    # With --keep-undetermined the medians of all-"yes" groups are PSEs the
    # fit's prior placed far off: the summary says they are the prior's.
    rows = ["participant,condition,level,response"]
    for participant in ("p1", "p2"):
        for condition in ("control", "manip"):
            rows += [f"{participant},{condition},{level},1" for level in (-0.2, 0.0, 0.2)]
    (tmp_path / "trials.csv").write_text("\n".join(rows) + "\n")
    argv = ["psychometric", "fit", str(tmp_path / "trials.csv"), "--resamples", "0"]
    status, stdout, err = _run(capsys, *argv, "--keep-undetermined", "--out", str(tmp_path / "k"))
    assert status == 0, err
    said = stdout.splitlines()[0]
    (row,) = list(csv.DictReader(open(tmp_path / "k" / "group_test.csv")))
    assert abs(float(row["median"])) > 1e3  # the prior's PSE, far off every level
    assert said.startswith(f"manip vs control: median PSE {float(row['median']):+.3g} vs "), said
    assert "(2 and 2 of these PSEs are the fit's prior's, not the data's)" in said, said


def test_pse_figure_says_why_a_row_has_no_test(tmp_path):
    from types import SimpleNamespace

    from jaxadapt import figures
    from jaxadapt.psychophysics import psychometric

    nan = np.full(2, np.nan)
    table = SimpleNamespace(
        condition=["control", "manip"],
        pse=np.array([0.01, np.nan]),
        ci_low=np.array([-0.05, np.nan]),
        ci_high=np.array([0.07, np.nan]),
        pse_low=np.array([np.nan, -np.inf]),
        pse_high=np.array([np.nan, -0.3]),
        flags=np.array([0, psychometric.NO_PSE]),
        sigma_max=nan,
    )
    row = {"condition": "manip", "control": "control", "p": np.nan, "n": 0, "n_control": 1}
    title = figures.plot_pse(tmp_path / "pse.png", table, [row]).axes[0].get_title()
    assert "manip vs control: no test (manip has no determined PSE)" in title
    assert "p = " not in title
