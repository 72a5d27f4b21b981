"""``jaxadapt psychometric fit`` and ``simulate``, end to end, on small
tables."""

import csv

import jax
import matplotlib.image
import numpy as np
import pytest
import statsmodels.api as sm
from cli_runs import assert_one_line_error, run
from scipy.stats import mannwhitneyu

from jaxadapt.cli import main


def _fit_rows(capsys, rows, folder, *options):
    """``psychometric fit`` of a table of ``rows`` (lines), written to
    ``folder/trials.csv``, into ``folder``: ``(status, stderr)``."""
    folder.mkdir(parents=True, exist_ok=True)
    trials = folder / "trials.csv"
    trials.write_text("\n".join(rows) + "\n")
    return run(capsys, "psychometric", "fit", str(trials), *options, "--out", str(folder))


def _simulated_rows(participants, shifts, levels, sigma, seed):
    """Count rows ``p,condition,level,n_yes,20`` of simulated observers: for
    each participant and ``(condition, shift)``, 20 trials a level of a
    cumulative Gaussian of that PSE and ``sigma``."""
    rng = np.random.default_rng(seed)
    rows = []
    for p in participants:
        for condition, shift in shifts:
            k = rng.binomial(20, norm_cdf((levels - shift) / sigma))
            rows += [f"p{p},{condition},{x:.4f},{y},20" for x, y in zip(levels, k, strict=True)]
    return rows


@pytest.mark.slow
def test_psychometric_fit_writes_fits_group_test_and_figures(tmp_path, capsys):
    levels = np.log10(np.array([14, 19, 27, 35, 49]) / 27)  # the afterimage protocol
    rows = ["participant,condition,level,n_yes,n_total"]
    rows += _simulated_rows(range(6), (("control", 0.0), ("manipulated", 0.15)), levels, 0.1, 0)
    out = tmp_path / "out"
    status, err = _fit_rows(capsys, rows, out, "--resamples", "0")
    assert status == 0, err
    trials = out / "trials.csv"
    fits = list(csv.DictReader(open(out / "fits.csv")))
    assert len(fits) == 12
    # p1's and p5's control answers change at one level (quasi-complete
    # separation): the data do not fix their slopes
    undetermined = [f["participant"] + f["condition"] for f in fits if f["converged"] != "true"]
    assert undetermined == ["p1control", "p5control"]
    (test,) = list(csv.DictReader(open(out / "group_test.csv")))
    assert float(test["shift"]) == pytest.approx(0.15, abs=0.06) and float(test["p"]) < 0.01
    pses = {
        c: [float(f["pse"]) for f in fits if f["condition"] == c and f["pse"] != "nan"]
        for c in ("manipulated", "control")
    }
    assert (test["n"], test["n_control"]) == ("6", "4")  # without p1's and p5's
    # Groups of 6 and 4: "auto" is exact (SciPy's rule); --ranksum asymptotic
    # asks for the normal approximation. Both as SciPy gives them.
    for method, exact in (("auto", "true"), ("asymptotic", "false")):
        if method != "auto":
            status, err = _fit_rows(capsys, rows, out, "--resamples", "0", "--ranksum", method)
            assert status == 0, err
            (test,) = list(csv.DictReader(open(out / "group_test.csv")))
        scipy_method = "exact" if exact == "true" else "asymptotic"
        expected = mannwhitneyu(pses["manipulated"], pses["control"], method=scipy_method).pvalue
        assert test["p_exact"] == exact and float(test["p"]) == pytest.approx(expected, rel=1e-5)
    assert (out / "psychometric.png").stat().st_size > 0 and (out / "pse.png").exists()
    status, err = run(capsys, "psychometric", "fit", str(trials), "--control", "Control")
    assert_one_line_error(status, err, "--control", "control, manipulated", "'Control'")
    # Without a control condition and no --control: fits, and no comparison.
    trials.write_text(trials.read_text().replace(",control,", ",dark,"))
    status, err = run(
        capsys, "psychometric", "fit", str(trials), "--resamples", "0", "--out", str(out)
    )
    assert status == 0, err
    assert not (out / "group_test.csv").exists()  # the last run's, removed
    said = " ".join(err.split())  # the console wraps its lines
    assert "no group test" in said and "dark, manipulated" in said and "--control" in said
    # With one condition no --control can help, so none is suggested.
    one = tmp_path / "one.csv"
    one.write_text("".join(r for r in trials.open() if ",manipulated," not in r))
    status, err = run(
        capsys, "psychometric", "fit", str(one), "--resamples", "0", "--out", str(out)
    )
    assert status == 0, err
    said = " ".join(err.split())
    assert "has one condition, 'dark'; a group test compares two" in said, said
    assert "--control" not in said
    # A participant whose responses are all "yes", and one whose are half
    # "yes" at every level (no slope), have no PSE of their own: said.
    rows = trials.read_text().splitlines()
    for first, n_yes in (("p0,dark,", "20"), ("p1,dark,", "10")):
        rows = [
            r if not r.startswith(first) else ",".join(r.split(",")[:3] + [n_yes, "20"])
            for r in rows
        ]
    trials.write_text("\n".join(rows) + "\n")
    status, err = run(
        capsys, "psychometric", "fit", str(trials), "--resamples", "0", "--out", str(out)
    )
    assert status == 0, err
    said = " ".join(err.split())
    assert "p0, condition dark: the data place the PSE only below -0.285 log units (all_" in said
    assert "warning: participant p1, condition dark: the data place no PSE (flat)" in said
    # p5's responses change at one level (quasi-complete separation): said too.
    assert "p5, condition dark: the responses change at one level" in said
    assert said.count("warning") == 3, said
    assert "its PSE and slope in fits.csv are NaN" in said


@pytest.mark.slow
def test_many_undetermined_groups_are_counted_not_listed(tmp_path, capsys):
    # A warning line for each group the data do not determine would be
    # thousands of lines for 10,000 groups of simulated data: 10 are named,
    # and all are counted.
    rows = ["participant,condition,level,n_yes,n_total"]
    rows += [f"p{i},control,{x},{k},10" for i in range(12) for x, k in ((0.0, 10), (0.1, 10))]
    status, err = _fit_rows(capsys, rows, tmp_path / "o", "--resamples", "0")
    assert status == 0, err
    lines = err.splitlines()
    assert any(line.startswith("warning: the data of 12 groups do not determine") for line in lines)
    assert sum(line.startswith("warning: participant") for line in lines) == 10


@pytest.mark.slow
def test_results_on_stdout_warnings_on_stderr_csvs_with_lf(tmp_path, capsys):
    # The summaries go to stdout, the warnings to stderr, unwrapped (the
    # console would wrap at 80 columns, inside numbers: "p = \\n0.371");
    # CSVs end their lines with LF, not CRLF.
    levels = np.linspace(-0.3, 0.3, 5)
    rows = ["participant,condition,level,n_yes,n_total", "p0,control,0.0,10,10"]
    rows += _simulated_rows(range(1, 5), (("control", 0.0), ("bright", 0.1)), levels, 0.1, 3)
    folder = tmp_path / "a-folder-with-a-long-name-that-pushes-the-summary-past-eighty-columns"
    folder.mkdir()
    (folder / "trials.csv").write_text("\n".join(rows) + "\n")
    argv = ["psychometric", "fit", str(folder / "trials.csv"), "--resamples", "0"]
    status = main([*argv, "--out", str(folder)])
    said = capsys.readouterr()
    assert status == 0
    lines = said.out.splitlines()
    assert lines[0].startswith("bright vs control: median PSE") and "rank-sum p = " in lines[0]
    assert lines[1].startswith("wrote fits.csv") and str(folder) in lines[1]
    assert len(lines) == 2 and len(lines[1]) > 80  # not wrapped
    assert said.err.startswith("warning: participant p0, condition control")
    assert len(said.err.splitlines()) == 2  # the warning and the note, one line each
    for name in ("fits.csv", "group_test.csv"):
        assert b"\r" not in (folder / name).read_bytes(), name


def test_psychometric_fit_names_the_bad_row(tmp_path, capsys):
    trials = tmp_path / "trials.csv"
    trials.write_text("participant,condition,level,response\np1,control,0.1,1\np1,control,x,0\n")
    status, err = run(capsys, "psychometric", "fit", str(trials), "--out", str(tmp_path / "o"))
    assert_one_line_error(status, err, "trials.csv", "3")
    assert not (tmp_path / "o").exists()
    trials.write_text("level,level,n_yes,n_total\n0,0,1,1\n")
    status, err = run(capsys, "psychometric", "fit", str(trials), "--out", str(tmp_path / "o"))
    assert_one_line_error(status, err, "trials.csv", "'level' more than once")
    status, err = run(capsys, "psychometric", "fit", str(tmp_path), "--out", str(tmp_path / "o"))
    assert_one_line_error(status, err, "is a folder")
    assert not (tmp_path / "o").exists()
    trials.write_text("level,n_yes,n_total\n0,1,2\n0.1,2,2\n")
    for resamples in ("-1", "1"):
        args = ("psychometric", "fit", str(trials), "--resamples", resamples)
        status, err = run(capsys, *args, "--out", str(tmp_path / "o"))
        assert_one_line_error(status, err, "--resamples: expected 0", f"got {resamples}")
    assert not (tmp_path / "o").exists()


def test_psychometric_fit_refuses_its_options_before_fitting(tmp_path, capsys, monkeypatch):
    # Each is refused before any fit: --out a file, and --ranksum exact on
    # groups too large for its table, would otherwise be found after the
    # whole fit (28 s on a simulated experiment), and --seed without a
    # bootstrap, or --ranksum without a group test, would be ignored.
    from jaxadapt.psychophysics import fit_table

    def no_fit(*args, **kwargs):
        raise AssertionError("fitted before refusing")

    monkeypatch.setattr(fit_table, "fit_groups", no_fit)
    rows = ["participant,condition,level,n_yes,n_total"]
    rows += [f"p{i},{c},{x},1,2" for i in range(170) for c in ("control", "m") for x in (0, 1)]
    table = tmp_path / "trials.csv"
    table.write_text("\n".join(rows) + "\n")
    (tmp_path / "file").touch()
    for options, expected in (
        (["--out", str(tmp_path / "file")], ("--out: expected a folder",)),
        (["--resamples", "0", "--seed", "7"], ("--seed:", "--resamples 0")),
        (["--ranksum", "exact"], ("--ranksum exact:", "4942071", "use --ranksum asymptotic")),
        (["--control", "m", "--ranksum", "auto"], ("--ranksum: applies to the group test",)),
    ):
        if "--control" in options:  # a table with the control condition alone
            table.write_text("\n".join(r for r in rows if ",control," not in r) + "\n")
        status, err = run(capsys, "psychometric", "fit", str(table), *options)
        assert_one_line_error(status, err, *expected)


def test_out_of_memory_names_what_to_make_smaller(tmp_path, capsys, monkeypatch):
    # The advice is the command's own, not render's "try a smaller --chunk or --size".
    from jaxadapt.psychophysics import fit_table

    def exhausted(*args, **kwargs):
        raise jax.errors.JaxRuntimeError("RESOURCE_EXHAUSTED: Out of memory allocating 9 bytes.")

    monkeypatch.setattr(fit_table, "fit_groups", exhausted)
    table = tmp_path / "trials.csv"
    table.write_text("condition,level,n_yes,n_total\ncontrol,0,1,2\ncontrol,1,2,2\nm,0,1,2\n")
    status, err = run(capsys, "psychometric", "fit", str(table), "--out", str(tmp_path / "o"))
    assert_one_line_error(status, err, "out of memory", "try fewer --resamples")
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_separated_responses_get_an_interval_of_their_gap(tmp_path, capsys):
    # "no" up to 0, "yes" from 0.15: any PSE between fits, so the interval
    # spans the gap, with a warning (a bootstrap of the prior's near-step
    # curve would give (0.055, 0.094)); data without a PSE get an unbounded
    # interval, not one of zero width at the prior's PSE.
    rows = ["participant,condition,level,n_yes,n_total"]
    for x, k in zip((-0.3, -0.15, 0.0, 0.15, 0.3), (0, 0, 0, 30, 30), strict=True):
        rows += [f"p1,control,{x},{k},30", f"p2,control,{x},30,30"]
    out = tmp_path / "o"
    status, err = _fit_rows(capsys, rows, out, "--resamples", "50")
    assert status == 0, err
    separated, unplaced = list(csv.DictReader(open(out / "fits.csv")))
    assert float(separated["ci_low"]) <= 0.0 and float(separated["ci_high"]) >= 0.15
    assert (unplaced["ci_low"], unplaced["ci_high"]) == ("-inf", "inf")
    said = " ".join(err.split())
    assert "p1, condition control: the levels separate" in said and "+0 and +0.15" in said


@pytest.mark.slow
def test_undetermined_fits_are_nan_and_left_out_of_the_group_test(tmp_path, capsys):
    # p0's control answers are all "yes" at one level, and p1's control is
    # separated (0 to 5 to 10 of 10 "yes"), where the likelihood grows
    # without end as sigma goes to 0: the fits' numbers there (pse -503161
    # and sigma 141421; sigma 0.0307) are not the data's. Both are NaN, not
    # converged, with what the data determine in columns of their own, and
    # left out of the group test unless --keep-undetermined.
    levels = np.linspace(-0.4, 0.4, 9)
    rows = ["participant,condition,level,n_yes,n_total", "p0,control,-0.2,10,10"]
    for x, k in zip(levels, (0, 0, 0, 0, 0, 0, 5, 10, 10), strict=True):
        rows.append(f"p1,control,{x:.2f},{k},10")
    rows += _simulated_rows(range(2, 7), (("control", 0.0), ("bright", 0.1)), levels, 0.2, 2)
    out = tmp_path / "o"
    status, err = _fit_rows(capsys, rows, out, "--resamples", "0")
    assert status == 0, err
    fits = {f["participant"] + f["condition"]: f for f in csv.DictReader(open(out / "fits.csv"))}
    same, separated = fits["p0control"], fits["p1control"]
    for row in (same, separated):
        assert [row[c] for c in ("pse", "sigma", "b0", "b1", "se_pse")] == ["nan"] * 5, row
        assert row["converged"] == "false"
    assert "all_same" in same["flags"] and "separation" in separated["flags"]
    assert (same["pse_low"], same["pse_high"]) == ("-inf", "inf")  # one level: no side
    assert float(separated["pse_low"]) == float(separated["pse_high"]) == 0.2
    assert 0.01 < float(separated["sigma_max"]) < 0.2
    determined = fits["p2control"]
    assert determined["converged"] == "true" and determined["pse_low"] == "nan"
    (test,) = list(csv.DictReader(open(out / "group_test.csv")))
    assert (test["n"], test["n_control"]) == ("5", "5")
    said = " ".join(err.split())
    assert "the group test leaves out the 2 groups whose data place no PSE" in said
    status, err = _fit_rows(capsys, rows, out, "--resamples", "0", "--keep-undetermined")
    assert status == 0, err
    fits = {f["participant"] + f["condition"]: f for f in csv.DictReader(open(out / "fits.csv"))}
    assert (
        np.isfinite(float(fits["p0control"]["pse"])) and fits["p0control"]["converged"] == "false"
    )
    (test,) = list(csv.DictReader(open(out / "group_test.csv")))
    assert (test["n"], test["n_control"]) == ("5", "7")
    assert "leaves out" not in err


def _fit_in_float32(capsys, rows, folder):
    """:func:`_fit_rows` with ``--resamples 0`` and float64 off, as for a
    user (the tests switch it on)."""
    with jax.enable_x64(False):
        status, err = _fit_rows(capsys, rows, folder, "--resamples", "0")
    assert status == 0, err


@pytest.mark.slow
def test_psychometric_fit_is_float64_as_statsmodels(tmp_path, capsys):
    # 3,000 trials a level: in float32 (JAX's default) the log-likelihood
    # would be 0.01 off statsmodels' (binomial terms of 2e4 that cancel),
    # and an all-"no" PSE could fall below the levels. (The tests run with
    # float64 on: here it is off, as for a user.)
    levels, n = np.linspace(-0.3, 0.3, 5), 3000
    k = np.array([300, 900, 1500, 2100, 2700])
    rows = ["level,n_yes,n_total"] + [f"{x},{y},{n}" for x, y in zip(levels, k, strict=True)]
    _fit_in_float32(capsys, rows, tmp_path)
    (row,) = list(csv.DictReader(open(tmp_path / "fits.csv")))
    glm = sm.GLM(
        np.c_[k, n - k],
        sm.add_constant(levels),
        family=sm.families.Binomial(link=sm.families.links.Probit()),
    ).fit(tol=1e-14)
    assert float(row["loglik"]) == pytest.approx(glm.llf, abs=1e-7)
    assert float(row["b1"]) == pytest.approx(glm.params[1], rel=1e-8)


@pytest.mark.slow
def test_psychometric_group_test_p_is_float64(tmp_path, capsys):
    # 170 participants whose PSEs separate the conditions completely: z =
    # 15.9, p = 7.6e-57 (SciPy's mannwhitneyu), which a group test in
    # float32 after the float64 fits would write as 0.
    from scipy.stats import mannwhitneyu

    levels, n = np.linspace(-0.3, 0.3, 5), 40
    rows = ["participant,condition,level,n_yes,n_total"]
    for i in range(170):
        for condition, pse in (("control", -0.1), ("test", 0.1)):
            p = norm_cdf((levels - pse - 0.001 * i) / 0.1)
            rows += [
                f"p{i},{condition},{x},{round(n * q)},{n}" for x, q in zip(levels, p, strict=True)
            ]
    _fit_in_float32(capsys, rows, tmp_path)
    fits = list(csv.DictReader(open(tmp_path / "fits.csv")))
    pse = {c: [float(r["pse"]) for r in fits if r["condition"] == c] for c in ("control", "test")}
    (row,) = list(csv.DictReader(open(tmp_path / "group_test.csv")))
    expected = mannwhitneyu(pse["test"], pse["control"], method="asymptotic", use_continuity=False)
    assert float(row["p"]) == pytest.approx(expected.pvalue, rel=1e-6)
    assert 0 < float(row["p"]) < 1e-50
    # Fig. 13 draws the first 24 participants (6 rows): 170 panels would
    # take a minute to lay out, for a figure 11,200 pixels high.
    assert matplotlib.image.imread(tmp_path / "psychometric.png").shape[0] < 2000


def test_pse_figure_spans_the_placed_pses(tmp_path):
    # An all-"yes" participant's PSE, set by the prior at -7.3e5, would make
    # the axis run to -7e5 and flatten every other PSE onto 0.
    from jaxadapt import figures
    from jaxadapt.psychophysics import psychometric
    from jaxadapt.psychophysics.fit_table import FitTable

    pse = np.array([-7.3e5, 0.02, -0.05, 0.12, 0.08, 0.1])
    flags = np.array([psychometric.ALL_SAME, 0, 0, 0, 0, 0])
    table = FitTable(
        tuple(f"p{i}" for i in range(3)) * 2,
        ("control",) * 3 + ("test",) * 3,
        pse,
        *[np.zeros(6)] * 10,
        np.ones(6, bool),
        flags,
    )
    low, high = figures.plot_pse(tmp_path / "pse.png", table).axes[0].get_ylim()
    assert -0.11 < low < -0.05 and 0.12 < high < 0.2
    assert (tmp_path / "pse.png").stat().st_size > 0


@pytest.mark.slow
def test_figures_draw_any_condition_name_without_warnings(tmp_path, capsys):
    # Unicode names are drawn in fonts that have them, without matplotlib's
    # "Glyph ... missing" warnings or empty boxes. A character no installed
    # font has is written as its code point (U+1F9A9 here, on most machines).
    import warnings

    from jaxadapt import figures

    dark, other = "暗い条件 ☾", "contrôle \U0001f9a9"
    levels = np.linspace(-0.3, 0.3, 5)
    rows = ["participant,condition,level,n_yes,n_total"]
    rows += _simulated_rows(range(4), ((other, 0.0), (dark, 0.1)), levels, 0.15, 4)
    folder = tmp_path / "o"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        status, err = _fit_rows(capsys, rows, folder, "--resamples", "0", "--control", other)
    assert status == 0, err
    assert [str(w.message) for w in caught if "Glyph" in str(w.message)] == []
    assert "Glyph" not in err
    families, missing = figures._fonts_for([dark, other])
    with figures._drawing([dark, other]) as drawable:
        assert drawable(dark + other) == "".join(
            f"U+{ord(c):04X}" if ord(c) in missing else c for c in dark + other
        )
    assert families[0] == "DejaVu Sans" and not any("Last Resort" in f for f in families)


def norm_cdf(z):
    from scipy.special import ndtr

    return ndtr(z)


def test_psychometric_simulate_checks_out_before_simulating(tmp_path, capsys, monkeypatch):
    # An --out that is a file is refused before the simulation (11 s), not after it.
    from jaxadapt.psychophysics import observer

    def simulated(*args, **kwargs):
        pytest.fail("simulated before --out was checked")

    monkeypatch.setattr(observer, "render_stimuli", simulated)
    target = tmp_path / "a-file"
    target.write_text("kept")
    args = ["psychometric", "simulate", "--protocol", "afterimage", "--observers", "2"]
    status, err = run(capsys, *args, "--out", str(target))
    assert_one_line_error(status, err, "--out", "a-file")
    assert target.read_text() == "kept"


@pytest.mark.slow
def test_psychometric_simulate_writes_a_table_that_fit_reads(tmp_path, capsys):
    sim, out = tmp_path / "sim", tmp_path / "fit"
    args = ["psychometric", "simulate", "--protocol", "afterimage", "--observers", "6"]
    status, err = run(capsys, *args, "--weight", "afterimage=0.3", "--seed", "1", "--out", str(sim))
    assert status == 0, err
    for name in ("trials.csv", "observers.csv", "stimuli.csv"):
        assert b"\r" not in (sim / name).read_bytes(), name  # LF line ends
    observers = list(csv.DictReader(open(sim / "observers.csv")))
    assert len(observers) == 6 and all(float(o["weight_afterimage"]) == 0.3 for o in observers)
    included = [o["participant"] for o in observers if o["excluded"] == "false"]
    # a strong afterimage with a positive weight: the observer's own PSE moves left
    assert all(float(o["pse_manipulated"]) < float(o["pse_control"]) for o in observers)
    stimuli = list(csv.DictReader(open(sim / "stimuli.csv")))
    assert len(stimuli) == 10 and {s["condition"] for s in stimuli} == {"control", "manipulated"}
    status, err = run(
        capsys,
        "psychometric",
        "fit",
        str(sim / "trials.csv"),
        "--resamples",
        "0",
        "--out",
        str(out),
    )
    assert status == 0, err
    fits = list(csv.DictReader(open(out / "fits.csv")))
    assert [f["participant"] for f in fits] == [p for p in included for _ in range(2)]
    assert all(f["converged"] == "true" for f in fits)
    assert not [p for p in sim.iterdir() if p.name.startswith(".")]  # no staging left


@pytest.mark.slow
def test_psychometric_simulate_streams_observers_in_blocks(tmp_path, capsys, monkeypatch):
    # The observers go in blocks, each written before the next is
    # simulated (memory flat in their number), and the files are the same.
    from jaxadapt.psychophysics import experiment

    args = ["psychometric", "simulate", "--protocol", "afterimage", "--observers", "5"]
    assert run(capsys, *args, "--out", str(tmp_path / "whole"))[0] == 0
    blocks, simulate_in_chunks = [], experiment.simulate_in_chunks

    def counted(*args, **kwargs):
        for first, block in simulate_in_chunks(*args, **kwargs):
            blocks.append(first)
            yield first, block

    monkeypatch.setattr(experiment, "CHUNK", 2)
    monkeypatch.setattr(experiment, "simulate_in_chunks", counted)
    assert run(capsys, *args, "--out", str(tmp_path / "blocks"))[0] == 0
    assert blocks == [0, 2, 4]
    for name in ("trials.csv", "observers.csv", "stimuli.csv"):
        whole, parts = (tmp_path / d / name for d in ("whole", "blocks"))
        assert parts.read_bytes() == whole.read_bytes(), name


@pytest.mark.parametrize(
    "args, words",
    [
        (["--protocol", "glare", "--observers", "3"], ["--protocol", "glare", "afterimage"]),
        (["--protocol", "mesopic", "--observers", "0"], ["--observers", "0"]),
        (["--protocol", "mesopic", "--observers", "3", "--weight", "glow=1"], ["--weight"]),
        (["--protocol", "mesopic", "--observers", "3", "--weight", "blur=x"], ["--weight"]),
        (
            [
                "--protocol",
                "mesopic",
                "--observers",
                "3",
                "--weight",
                "blur=1",
                "--weight",
                "blur=2",
            ],
            ["--weight", "blur again"],
        ),
    ],
)
def test_psychometric_simulate_bad_input(tmp_path, capsys, args, words):
    out = tmp_path / "o"
    status, err = run(capsys, "psychometric", "simulate", *args, "--out", str(out))
    assert_one_line_error(status, err, *words)
    assert not out.exists()
