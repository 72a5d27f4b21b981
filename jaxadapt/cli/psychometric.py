"""``jaxadapt psychometric fit`` and ``simulate``: psychometric fits of a
trial table with their group test, and simulated experiments of the 2015
paper."""

from pathlib import Path

import numpy as np

from jaxadapt.cli._options import (
    CLUSTER_OPTIONS,
    COMMANDS,
    UsageError,
    _folder,
    _memory,
    _seed,
    check_cluster_options,
)
from jaxadapt.cli._output import _report
from jaxadapt.cli._staging import FIT_OUTPUTS, _staged

__all__ = ["add_parser", "fit", "MAX_GROUP_WARNINGS", "simulate"]


def add_parser(sub):
    """Declare ``jaxadapt psychometric fit`` and ``simulate`` on the subparsers ``sub``."""
    psychometric = sub.add_parser(
        "psychometric",
        help=COMMANDS["psychometric"],
        description="Psychometric analysis of a method-of-constant-stimuli experiment.",
    )
    psy = psychometric.add_subparsers(dest="action", required=True, metavar="ACTION")
    fit_parser = psy.add_parser(
        "fit",
        help="fit cumulative Gaussians per participant and condition, and compare conditions",
        description="Fit P(x) = Phi((x - PSE) / sigma) by maximum likelihood (a probit GLM, "
        "as MATLAB's glmfit in the paper) to every (participant, condition) of a trial "
        "table, with bootstrap intervals for the PSE; compare the conditions' PSEs with the "
        "Wilcoxon rank-sum test. Writes fits.csv, group_test.csv (when the table has the "
        "control condition and another), psychometric.png (Fig. 13) and pse.png (Fig. 14) "
        "into --out.",
    )
    for flags, kwargs in _FIT_OPTIONS:
        fit_parser.add_argument(*flags, **kwargs)
    fit_parser.set_defaults(run=fit)
    simulate_parser = psy.add_parser(
        "simulate",
        help="simulate an experiment of the 2015 paper with model observers",
        description="Simulate the afterimage or mesopic experiment of Jacobs et al. (2015, "
        "§4) with model observers drawn from a population: the stimuli are rendered with "
        "the 2015 operator, each observer compares the brightness of test and standard "
        "(log luminance plus weighted cues, with noise, bias and lapses) on every trial of "
        "the paper's design, and observers below 70% correct in training are excluded. "
        "Writes trials.csv (readable by 'jaxadapt psychometric fit'), observers.csv and "
        "stimuli.csv into --out.",
    )
    for flags, kwargs in _SIMULATE_OPTIONS:
        simulate_parser.add_argument(*flags, **kwargs)
    simulate_parser.set_defaults(run=simulate)


# The options of each action as (flags, add_argument keywords), in the order
# --help lists them.

_FIT_OPTIONS = (
    (
        ("trials",),
        dict(
            type=Path,
            metavar="TRIALS.csv",
            help="columns participant, condition, level (log10 relative to the standard), "
            "response (1: test brighter); or level, n_yes, n_total",
        ),
    ),
    (("--out",), dict(type=_folder, default=Path("out"), help="output folder (default ./out)")),
    (
        ("--resamples",),
        dict(
            type=int,
            default=1000,
            help="bootstrap resamples per group for the PSE interval (0: Wald interval); "
            "default 1000",
        ),
    ),
    (
        ("--control",),
        dict(
            default=None,
            help="condition the others are compared with (default: control, if the table has it)",
        ),
    ),
    (("--seed",), dict(type=_seed, default=None, help="seed of the bootstrap (default 0)")),
    (
        ("--keep-undetermined",),
        dict(
            action="store_true",
            help="write the estimates of groups whose data do not determine the fit (all "
            "answers the same, separation, one level, no slope), which the fit's prior sets, "
            "and enter them in the group test (default: NaN in fits.csv, left out of the test)",
        ),
    ),
    (
        ("--ranksum",),
        dict(
            choices=("auto", "exact", "asymptotic"),
            default=None,
            help="where the rank-sum test's p comes from: the exact null distribution, the "
            "normal approximation, or auto (default: exact when the smaller group has at most "
            "8 PSEs and none are tied, as SciPy's mannwhitneyu; the paper's p of its two "
            "groups of 11 is the exact one)",
        ),
    ),
    (
        ("--memory",),
        dict(
            type=_memory,
            default=None,
            metavar="SIZE",
            help="memory for the bootstrap's resampled fits held at once, e.g. 500M or 2G "
            "(default 256M; on a cluster, each worker's); the results do not depend on it",
        ),
    ),
    *CLUSTER_OPTIONS,
)

_SIMULATE_OPTIONS = (
    (
        ("--protocol",),
        dict(
            required=True,
            metavar="afterimage|mesopic",
            help="the experiment: afterimage (§4.1) or mesopic (§4.2)",
        ),
    ),
    (
        ("--observers",),
        dict(type=int, required=True, metavar="N", help="number of observers"),
    ),
    (
        ("--weight",),
        dict(
            action="append",
            default=[],
            metavar="CUE=W",
            help="weight of a cue (afterimage, desaturation, blur) in log10 units of "
            "brightness per unit of cue, the same for every observer, repeatable (default: 0, "
            "observers who judge luminance only); e.g. --weight desaturation=-0.1 makes "
            "desaturated tests look darker",
        ),
    ),
    (("--seed",), dict(type=_seed, default=0, help="seed of the simulation (default 0)")),
    (("--out",), dict(type=_folder, default=Path("out"), help="output folder (default ./out)")),
    *CLUSTER_OPTIONS,
)


def fit(args, console):
    """``jaxadapt psychometric fit``: fits, group tests and figures into ``--out``."""
    import jax
    from rich.progress import Progress

    from jaxadapt import cluster, figures, io
    from jaxadapt.psychophysics import bootstrap, fit_table, stats, trials

    if args.resamples < 0 or args.resamples == 1:
        raise UsageError(
            f"--resamples: expected 0 (a Wald interval) or at least 2, got {args.resamples}"
        )
    if args.seed is not None and args.resamples == 0:
        raise UsageError("--seed: seeds the bootstrap, which --resamples 0 leaves out")
    check_cluster_options(args)
    trial_table = trials.read_trials(args.trials)
    _say_left_out(console, trial_table)
    conditions = list(dict.fromkeys(trial_table.condition))
    if args.control is not None and args.control not in conditions:
        raise UsageError(
            f"--control: expected one of the conditions of {args.trials} "
            f"({', '.join(map(str, conditions))}), got {args.control!r}"
        )
    control = args.control or "control"
    groups = trials.group_trials(trial_table)
    tested = [c for c in conditions if c != control] if control in conditions else []
    if not tested:
        no_test = (
            f"no group test: {args.trials} has one condition, {conditions[0]!r}; "
            "a group test compares two"
            if len(conditions) == 1
            else f"no group test: {args.trials} has no condition {control!r} to compare with "
            f"(conditions: {', '.join(map(str, conditions))}); name one with --control"
        )
        if args.ranksum is not None:
            raise UsageError(f"--ranksum: applies to the group test, and there is none ({no_test})")
        console.print(no_test)
    method = args.ranksum or "auto"
    size = {c: groups.condition.count(c) for c in conditions}
    for c in tested if method == "exact" else ():
        too_large = stats.exact_too_large(size[c], size[control])
        if too_large:
            raise UsageError(
                f"--ranksum exact: {too_large}; use --ranksum asymptotic (at these sizes the "
                "normal approximation is close)"
            )
    out = args.out
    written = ["fits.csv", "group_test.csv", "psychometric.png", "pse.png"]
    if not tested:
        written.remove("group_test.csv")
    with (
        _staged(out, console, FIT_OUTPUTS, keep=[args.trials]) as staging,
        cluster.connected(args.scheduler, args.workers) as client,
    ):
        # In float64, as statsmodels and MATLAB fit: in float32 the
        # log-likelihood of thousands of trials a level loses precision to
        # binomial terms that cancel, so the fits stop at slopes whose
        # rounding matters; the group test's normal tail 2 Phi(-|z|) is 0 in
        # float32 from z = 13.
        bar = Progress(console=console, transient=True, disable=not console.is_terminal)
        with jax.enable_x64(True), bar:
            count = len(groups.participant)
            task = bar.add_task(f"fitting {count} group{'s' * (count > 1)}", total=count)
            key = jax.random.key(args.seed or 0)
            options = dict(
                n_resamples=args.resamples,
                keep_undetermined=args.keep_undetermined,
                budget=args.memory or bootstrap.BOOTSTRAP_BUDGET,
            )
            advance = lambda done: bar.advance(task, done)  # noqa: E731
            if client is None:
                table = fit_table.fit_groups(groups, key=key, progress=advance, **options)
            else:
                table = _fitted(client, _cluster_option(args), groups, key, options, advance)
            rows = stats.group_tests(table, control, method)
        _warn_undetermined(console, groups, table, args.keep_undetermined, bool(rows))
        fit_table.write_fits(staging / "fits.csv", table)
        if rows:
            with open(staging / "group_test.csv", "w", newline="") as f:
                writer = io.csv_writer(f, stats.GROUP_TEST_COLUMNS)
                writer.writeheader()
                writer.writerows(rows)
        figures.plot_psychometric(staging / "psychometric.png", groups, table)
        figures.plot_pse(staging / "pse.png", table, rows)
    for row in rows:
        sizes, why_not = f"n = {row['n']}, {row['n_control']}", stats.untested(row)
        how = "exact" if row["p_exact"] == "true" else "normal approximation"
        test = (
            f"no rank-sum test: {why_not} ({sizes})"
            if why_not
            else f"rank-sum p = {row['p']:.3g} ({how}; {sizes})"
        )
        _report(
            f"{row['condition']} vs {row['control']}: median PSE {_signed(row['median'])} vs "
            f"{_signed(row['median_control'])} log units"
            f"{_set_by_prior(table, row) if args.keep_undetermined else ''}, {test}"
        )
    _report(f"wrote {', '.join(written)} to {out}/")


def _say_left_out(console, table):
    """Say which participants were excluded and which rows not analysed."""
    from jaxadapt.psychophysics.trials import EXCLUSION

    for who, accuracy in table.excluded.items():
        console.print(
            f"participant {who} excluded: {accuracy:.0%} of the training trials correct "
            f"(fewer than {EXCLUSION:.0%})",
            markup=False,
            highlight=False,
        )
    said = [f"{n} {what}" for what, n in table.left_out.items() if n]
    if said:
        console.print(f"rows left out: {', '.join(said)}", markup=False, highlight=False)


def _set_by_prior(table, row):
    """How many of the PSEs behind a group test's ``row`` the fit's prior set
    (``--keep-undetermined``), said after its medians; empty where none."""
    from jaxadapt.psychophysics.separation import undetermined

    open_ = undetermined(np.asarray(table.flags))
    condition = np.asarray(table.condition)
    counts = [int(open_[condition == row[side]].sum()) for side in ("condition", "control")]
    if not any(counts):
        return ""
    return f" ({counts[0]} and {counts[1]} of these PSEs are the fit's prior's, not the data's)"


def _signed(value, digits=3):
    """``value`` with its sign and ``digits`` decimals, 0 as ``+0.000`` (not
    ``-0.000``), from 1000 log units in three significant digits (a PSE the
    fit's prior placed far off); NaN (no PSE to take the median of) as ``nan``."""
    if np.isnan(value):
        return "nan"
    if abs(value) >= 1e3:
        return f"{value:+.3g}"
    return f"{round(value, digits) + 0.0:+.{digits}f}"


#: Groups named one by one in the warnings of :func:`_warn_undetermined`, so
#: that a large table does not write thousands of lines.
MAX_GROUP_WARNINGS = 10


def _warn_undetermined(console, groups, table, kept, tested):
    """Say which groups' data do not determine their fit: those that place
    no PSE (every response the same, one level, or no slope) and those whose
    levels separate the responses, whose PSE lies somewhere between two
    levels (:func:`~jaxadapt.psychophysics.fit_table.fit_groups`); and whether
    the group test (``tested``) left them out or, with
    ``--keep-undetermined`` (``kept``), took the fit's prior-set PSEs."""
    from jaxadapt.psychophysics import psychometric
    from jaxadapt.psychophysics.separation import undetermined

    flags = np.asarray(table.flags)
    written = "are its prior's, not the data's" if kept else "are NaN"
    groups_open = np.flatnonzero(undetermined(flags))
    if len(groups_open) > MAX_GROUP_WARNINGS:
        console.print(
            f"warning: the data of {len(groups_open)} groups do not determine their fit; "
            f"the first {MAX_GROUP_WARNINGS} follow, the flags of all are in fits.csv"
        )
    for i in groups_open[:MAX_GROUP_WARNINGS]:
        who = f"participant {table.participant[i]}, condition {table.condition[i]}"
        low, high = table.pse_low[i], table.pse_high[i]
        if flags[i] & psychometric.NO_PSE:
            why = ", ".join(psychometric.flag_names(int(flags[i])))
            if np.isinf(low) and np.isinf(high):
                said = f"the data place no PSE ({why})"
            else:
                side = f"below {high:+.3g}" if np.isinf(low) else f"above {low:+.3g}"
                said = f"the data place the PSE only {side} log units ({why})"
        elif low < high:
            said = (
                "the levels separate the 'no' from the 'yes' responses, so the data place "
                f"the PSE only between {low:+.3g} and {high:+.3g} log units and bound sigma "
                f"below {table.sigma_max[i]:.3g}"
            )
        else:
            said = (
                f"the responses change at one level, {low:+.3g} log units (one answer on "
                "either side of it: quasi-complete separation), and bound sigma below "
                f"{table.sigma_max[i]:.3g} without fixing it"
            )
        console.print(
            f"warning: {who}: {said}; its PSE and slope in fits.csv {written}", soft_wrap=True
        )
    left_out = int(np.sum(~np.isfinite(table.pse)))
    if tested and left_out:
        console.print(
            f"the group test leaves out the {left_out} group{'s' * (left_out > 1)} whose data "
            "place no PSE (--keep-undetermined enters their prior-set PSEs)",
            soft_wrap=True,
        )


def _weights(items, cues):
    """``--weight CUE=W`` options as a weight per cue (0 where not given)."""
    weights, given = dict.fromkeys(cues, 0.0), set()
    for item in items:
        name, _, value = item.partition("=")
        if name.strip() not in weights:
            raise UsageError(
                f"--weight: expected CUE=W with CUE one of {', '.join(cues)}, got {item!r}"
            )
        if name.strip() in given:
            raise UsageError(f"--weight: expected each cue once, got {name.strip()} again")
        given.add(name.strip())
        try:
            weights[name.strip()] = float(value)
        except ValueError:
            raise UsageError(f"--weight: expected a number after '=', got {item!r}") from None
        # Finite in float32, the simulation's dtype: beyond its range the
        # weight would be cast to inf (with NumPy's overflow warning).
        largest = float(np.finfo(np.float32).max)
        if not abs(weights[name.strip()]) <= largest:
            raise UsageError(
                f"--weight: expected a finite number (float32: {-largest:.2g} to {largest:.2g}), "
                f"got {item!r}"
            )
    return list(weights.values())


def _write_stimuli(path, protocol, stimuli):
    """``stimuli.csv``: each condition and level's differences of test and
    standard, in log luminance and in each cue."""
    from jaxadapt import io
    from jaxadapt.psychophysics.observer import CUES
    from jaxadapt.psychophysics.trials import csv_cell

    d_lum, d_cues = (np.asarray(a) for a in stimuli.differences())
    with open(path, "w", newline="") as f:
        writer = io.csv_writer(f)
        writer.writerow(["condition", "level", "d_log_luminance", *(f"d_{c}" for c in CUES)])
        for c, condition in enumerate(protocol.conditions):
            for i, level in enumerate(protocol.levels):
                cells = [level, d_lum[c, i], *d_cues[c, i]]
                writer.writerow([condition, *(csv_cell(v) for v in cells)])


def simulate(args, console):
    """``jaxadapt psychometric simulate``: a simulated experiment into ``--out``."""
    import dataclasses

    import jax
    from rich.progress import Progress

    from jaxadapt import cluster, io
    from jaxadapt.psychophysics import design
    from jaxadapt.psychophysics import experiment as simulated
    from jaxadapt.psychophysics import observer as obs
    from jaxadapt.psychophysics import population as populations
    from jaxadapt.psychophysics.trials import csv_cell

    if args.protocol not in design.PROTOCOLS:
        raise UsageError(
            f"--protocol: expected one of {', '.join(design.PROTOCOLS)}, got {args.protocol!r}"
        )
    if args.observers < 1:
        raise UsageError(f"--observers: expected a positive number, got {args.observers}")
    check_cluster_options(args)
    protocol = design.PROTOCOLS[args.protocol]
    population = dataclasses.replace(
        populations.POPULATIONS[args.protocol], weights=_weights(args.weight, obs.CUES)
    )
    # --out is checked (and staged) before the minutes of simulating
    with (
        _staged(args.out, console) as staging,
        cluster.connected(args.scheduler, args.workers) as client,
    ):
        render_key, simulate_key = jax.random.split(jax.random.key(args.seed))
        stimuli = obs.render_stimuli(protocol, key=render_key)
        _write_stimuli(staging / "stimuli.csv", protocol, stimuli)
        # Observers in blocks, each block's rows written before the next is
        # simulated: memory does not grow with --observers.
        bar = Progress(console=console, transient=True, disable=not console.is_terminal)
        n_rows = excluded = 0
        with (
            open(staging / "trials.csv", "w", newline="") as trials_file,
            open(staging / "observers.csv", "w", newline="") as observers_file,
            bar,
        ):
            trial_writer, observer_writer = map(io.csv_writer, (trials_file, observers_file))
            trial_writer.writerow(simulated.TRIAL_COLUMNS)
            task = bar.add_task(f"simulating {args.observers} observers", total=args.observers)
            for first, experiment in _simulated(
                client,
                _cluster_option(args),
                simulate_key,
                protocol,
                stimuli,
                population,
                args.observers,
            ):
                n_rows += simulated.append_trials(
                    trial_writer, protocol, experiment, first, args.observers
                )
                table = simulated.observer_table(
                    protocol, stimuli, experiment, first, args.observers
                )
                if first == 0:
                    observer_writer.writerow(table)
                for row in zip(*table.values(), strict=True):
                    observer_writer.writerow([csv_cell(v) for v in row])
                excluded += int(np.sum(table["excluded"]))
                bar.advance(task, len(table["excluded"]))
    _report(
        f"{args.protocol}: {args.observers} observers, {excluded} excluded (training below "
        f"{protocol.exclusion:.0%} correct); wrote trials.csv ({n_rows} trials, training "
        "included), "
        f"observers.csv, stimuli.csv to {args.out}/"
    )


def _cluster_option(args):
    """The option that named the cluster, for its errors."""
    return f"--scheduler {args.scheduler}" if args.scheduler is not None else "--workers"


def _simulated(client, option, key, protocol, stimuli, population, n):
    """``(first, experiment)`` blocks of the simulation, in order: in this
    process (:func:`~jaxadapt.psychophysics.experiment.simulate_in_chunks`),
    or on the cluster of ``client``, in blocks small enough to keep each
    worker busy (an observer depends only on the key and its index: the
    blocks' size changes nothing)."""
    from jaxadapt import cluster
    from jaxadapt.psychophysics import experiment as simulated

    if client is None:
        yield from simulated.simulate_in_chunks(key, protocol, stimuli, population, n)
        return
    tasks = cluster.AHEAD_PER_WORKER * cluster.workers_of(client)
    size = min(simulated.CHUNK, -(-n // tasks))
    starts = range(0, n, size)
    args = (key, protocol, stimuli, population, n, size)
    blocks = cluster.in_order(client, simulated.simulate_block, args, starts, option)
    yield from zip(starts, blocks, strict=True)


def _fitted(client, option, groups, key, options, advance):
    """:func:`~jaxadapt.psychophysics.fit_table.fit_groups` of ``groups`` on
    the cluster of ``client``, in consecutive parts of whole bootstrap
    blocks (up to two parts a worker), each resampled with its groups' keys
    and in blocks of the whole table's size: the whole table's fit, bit for
    bit. A table of one block (or Wald intervals, one vmapped fit) is one
    task."""
    from jaxadapt import cluster
    from jaxadapt.psychophysics import bootstrap, fit_table
    from jaxadapt.psychophysics.trials import Groups

    count, resamples = len(groups.participant), options["n_resamples"]
    block = (
        bootstrap.bootstrap_blocks(count, resamples, options["budget"])[0] if resamples else count
    )
    blocks = -(-count // block)
    size = block * -(-blocks // (cluster.AHEAD_PER_WORKER * cluster.workers_of(client)))
    starts = range(0, count, size)
    parts = ((start, Groups(*(f[start : start + size] for f in groups))) for start in starts)
    tables = []
    args = (key, options, count)
    for table in cluster.in_order(client, fit_table.fit_rows, args, parts, option):
        tables.append(table)
        advance(len(table.participant))
    return fit_table.concatenated(tables)
