"""Whole simulated experiments: observers drawn from a population, each
through every trial of a protocol, and the results as tables.

Thousands of observers run in one compiled, ``vmap``-ped call
(:func:`simulate`); their analysed trials come out as a trial table
(:func:`write_trials`, read back by
:func:`jaxadapt.psychophysics.trials.read_trials`) or as the counts the fits
take (:func:`groups`), leaving out training trials and excluded observers as
Jacobs et al. (2015), §4.1.1, does.
"""

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

# io as a module, not ``from jaxadapt.io import atomic_path``: JAX keeps this
# package's pytree classes until the interpreter exits, and through them a
# bare function would keep io's globals, OpenImageIO among them, alive past
# the clean-up of modules at exit, which OpenImageIO's bindings then report.
from jaxadapt import io
from jaxadapt._checks import check_whole
from jaxadapt.operators.checks import plain_errors
from jaxadapt.psychophysics import design
from jaxadapt.psychophysics import trials as trial_tables
from jaxadapt.psychophysics.observer import Observer, _checked, respond, true_pse
from jaxadapt.psychophysics.population import _observer_key, draw_observers
from jaxadapt.psychophysics.stimuli import CUES

__all__ = [
    "Experiment",
    "run_observer",
    "simulate_observers",
    "simulate",
    "CHUNK",
    "simulate_in_chunks",
    "simulate_block",
    "participant_names",
    "TRIAL_COLUMNS",
    "trial_table",
    "write_trials",
    "append_trials",
    "observer_table",
    "OBSERVER_FIELDS",
    "groups",
]


class Experiment(NamedTuple):
    """A simulated experiment (leading axis: observers).

    Attributes
    ----------
    observers : jaxadapt.psychophysics.observer.Observer
        Fields of shape ``(N,)`` (weights ``(N, K)``).
    trials : design.Trials
        Each observer's trial sequence, ``(N, n_trials)``.
    responses : array, (N, n_trials)
        1 when the test was judged brighter.
    excluded : array of bool, (N,)
        Fewer than ``protocol.exclusion`` of the training trials correct.
    """

    observers: Observer
    trials: design.Trials
    responses: jax.Array
    excluded: jax.Array


def run_observer(key, protocol, stimuli, observer):
    """One observer through a protocol: ``(trials, responses)``.

    The trial order comes from ``split(key)[0]``
    (:func:`jaxadapt.psychophysics.design.trial_list`), the answers from
    ``split(key)[1]`` (:func:`~jaxadapt.psychophysics.observer.respond`).
    """
    order_key, answer_key = jax.random.split(key)
    trials = design.trial_list(protocol, order_key)
    return trials, respond(answer_key, stimuli, observer, trials)


@eqx.filter_jit
def _simulate_observers(key, protocol, stimuli, observers, first=0):
    observers = _checked(observers, "observers")
    n = observers.noise.shape[0]
    keys = jax.vmap(_observer_key, (None, 0))(key, first + jnp.arange(n))
    trials, responses = jax.vmap(lambda k, o: run_observer(k, protocol, stimuli, o))(
        keys, observers
    )
    excluded = design.excluded(protocol, trials, responses)
    return Experiment(observers, trials, responses, excluded)


@plain_errors
def simulate_observers(key, protocol, stimuli, observers):
    """Given observers through a protocol, all in one ``vmap``-ped call.

    Parameters
    ----------
    key : PRNG key
        Observer ``i`` runs :func:`run_observer` with ``fold_in(key, i)``, so
        the result equals that loop and observer ``i``'s trials do not
        depend on how many observers there are.
    protocol : design.Protocol
    stimuli : jaxadapt.psychophysics.stimuli.Stimuli
    observers : jaxadapt.psychophysics.observer.Observer
        A batch: fields with a leading axis ``N``.

    Returns
    -------
    Experiment

    Raises
    ------
    ValueError
        Observers without one leading batch axis.
    equinox.EquinoxRuntimeError
        A noise that is not positive, or a lapse rate outside [0, 1).
    """
    if jnp.ndim(observers.noise) != 1:
        raise ValueError(
            f"observers: expected a batch with one leading axis, got noise of shape "
            f"{jnp.shape(observers.noise)}"
        )
    return _simulate_observers(key, protocol, stimuli, observers)


def simulate(key, protocol, stimuli, population, n_observers):
    """A whole experiment: ``n_observers`` drawn from a population, each
    through every trial of the protocol, in one compiled, ``vmap``-ped call.

    Parameters
    ----------
    key : PRNG key
        Same key, same experiment. ``split(key)[0]`` draws the observers
        (:func:`~jaxadapt.psychophysics.population.draw_observers`), ``split(key)[1]`` their trials
        (:func:`simulate_observers`).
    protocol : design.Protocol
    stimuli : jaxadapt.psychophysics.stimuli.Stimuli
        From :func:`~jaxadapt.psychophysics.stimuli.render_stimuli` (or
        :func:`~jaxadapt.psychophysics.stimuli.plain_stimuli`).
    population : jaxadapt.psychophysics.population.Population
    n_observers : int

    Returns
    -------
    Experiment

    Examples
    --------
    >>> from jaxadapt.psychophysics.population import POPULATIONS
    >>> from jaxadapt.psychophysics.stimuli import plain_stimuli
    >>> s = plain_stimuli(design.AFTERIMAGE)
    >>> e = simulate(jax.random.key(0), design.AFTERIMAGE, s, POPULATIONS["afterimage"], 4)
    >>> e.responses.shape, e.excluded.shape
    ((4, 320), (4,))
    """
    n = check_whole("n_observers", n_observers, least=1)
    draw_key, trial_key = jax.random.split(key)
    return _simulate_draws(draw_key, trial_key, protocol, stimuli, population, n)


#: Observers :func:`simulate_in_chunks` simulates in one compiled call: each
#: holds its trials and answers (a few kB), so a chunk takes tens of MB.
CHUNK = 4096


def simulate_in_chunks(key, protocol, stimuli, population, n_observers, chunk=None):
    """The experiment of :func:`simulate` with the same arguments, in
    consecutive blocks of at most ``chunk`` observers (default
    :data:`CHUNK`): yields ``(first, experiment)``, the observers ``first``,
    ``first + 1``, ... of the whole.

    Observer ``i`` depends only on ``key`` and ``i``, so the blocks equal
    the slices of the whole experiment, and memory does not grow with
    ``n_observers``. Every block is simulated at the size of the first (the
    last one padded, its extra observers dropped): one compilation.

    Examples
    --------
    >>> from jaxadapt.psychophysics.population import POPULATIONS
    >>> from jaxadapt.psychophysics.stimuli import plain_stimuli
    >>> s, pop = plain_stimuli(design.AFTERIMAGE), POPULATIONS["afterimage"]
    >>> blocks = simulate_in_chunks(jax.random.key(0), design.AFTERIMAGE, s, pop, 5, chunk=2)
    >>> [(first, e.responses.shape) for first, e in blocks]
    [(0, (2, 320)), (2, (2, 320)), (4, (1, 320))]
    """
    n = check_whole("n_observers", n_observers, least=1)
    chunk = CHUNK if chunk is None else check_whole("chunk", chunk, least=1)
    size = min(chunk, n)
    for first in range(0, n, size):
        yield first, simulate_block(key, protocol, stimuli, population, n, size, first)


def simulate_block(key, protocol, stimuli, population, n_observers, size, first):
    """The block of :func:`simulate_in_chunks` (blocks of ``size``) that
    starts at observer ``first``: a task of its own, which a cluster's
    worker computes (:mod:`jaxadapt.cluster`)."""
    draw_key, trial_key = jax.random.split(key)
    block = _simulate_draws(
        draw_key, trial_key, protocol, stimuli, population, size, jnp.asarray(first)
    )
    stop = min(size, n_observers - first)
    return jax.tree.map(lambda a: a[:stop], block)


@eqx.filter_jit
def _simulate_draws(draw_key, trial_key, protocol, stimuli, population, n, first=0):
    observers = draw_observers(draw_key, population, n, first)
    return _simulate_observers(trial_key, protocol, stimuli, observers, first)


# -- tables -------------------------------------------------------------------


def participant_names(n, first=0, count=None):
    """``s01, s02, ...``, zero-padded to the width of ``n``: the names of
    the ``count`` observers from ``first`` (all ``n`` by default)."""
    width = max(2, len(str(n)))
    stop = n if count is None else first + count
    return [f"s{i + 1:0{width}d}" for i in range(first, stop)]


#: The columns of :func:`trial_table`, in the order written: those of a
#: live session's table (:data:`jaxadapt.psychophysics.trials.SESSION_COLUMNS`).
TRIAL_COLUMNS = trial_tables.SESSION_COLUMNS


def trial_table(protocol, experiment, first=0, total=None):
    """Every trial of every observer, as the columns of a live session's table.

    ``experiment`` may be the block of observers ``first``, ``first + 1``,
    ... of an experiment of ``total`` observers (:func:`simulate_in_chunks`),
    which the participants' names count in (by default, all of it).

    Returns
    -------
    dict of numpy arrays
        The columns of :data:`TRIAL_COLUMNS`, one row per trial in
        presentation order, observer after observer: ``participant``
        (:func:`participant_names`), ``study`` (the protocol's name),
        ``block`` and ``condition`` (names), ``trial`` (its place in the
        order), ``level`` (log10 test/standard, the protocol's exact
        values), ``test_luminance`` and ``standard_luminance`` (cd/m2),
        ``test_interval`` (1 or 2), ``answer`` (the interval chosen),
        ``test_chosen`` (0/1), ``correct`` (training trials only), no
        frames dropped, and empty cells for the measurements a model
        observer has not (reaction time, durations, the time). Training
        trials and excluded observers are kept, as a person's session
        keeps them: the reader scores and leaves them out
        (:func:`jaxadapt.psychophysics.trials.read_trials`), as the paper
        does.
    """
    trials = jax.tree.map(np.asarray, experiment.trials)
    count, n = trials.level.shape
    names = np.array(participant_names(total or count, first, count), dtype=object)
    chosen = np.asarray(experiment.responses).astype(int).ravel()
    test_interval = np.where(trials.test_first, 1, 2).ravel()
    training = trials.training.ravel()
    level = np.asarray(protocol.levels)[trials.level_index].ravel()
    correct = np.where(training, np.where(chosen == (level > 0), "true", "false"), "")
    empty = np.full(count * n, "", dtype=object)
    return {
        "participant": np.repeat(names, n),
        "study": np.full(count * n, protocol.name, dtype=object),
        "block": np.array([b.name for b in protocol.blocks], dtype=object)[trials.block].ravel(),
        "trial": np.tile(np.arange(n), count),
        "condition": np.array(protocol.conditions, dtype=object)[trials.condition].ravel(),
        "level": level,
        "test_luminance": np.asarray(protocol.tests)[trials.level_index].ravel(),
        "standard_luminance": np.full(count * n, protocol.standard),
        "test_interval": test_interval,
        "answer": np.where(chosen == 1, test_interval, 3 - test_interval),
        "test_chosen": chosen,
        "correct": correct.astype(object),
        **{c: empty for c in ("rt_ms", "image1_ms", "image2_ms", "blank1_ms", "blank2_ms")},
        "dropped_frames": np.zeros(count * n, int),
        "flagged": np.full(count * n, "false", dtype=object),
        "answered_at": empty,
    }


def write_trials(path, protocol, experiment):
    """Write :func:`trial_table` as a CSV trial table (read back by
    :func:`jaxadapt.psychophysics.trials.read_trials`). Levels are written
    exactly (:func:`~jaxadapt.psychophysics.trials.csv_cell`). The file
    appears only once complete. Returns the number of rows."""
    with io.atomic_path(path) as tmp, open(tmp, "w", newline="") as file:
        writer = io.csv_writer(file)
        writer.writerow(TRIAL_COLUMNS)
        return append_trials(writer, protocol, experiment)


def append_trials(writer, protocol, experiment, first=0, total=None):
    """Write the rows of :func:`trial_table` (its arguments) with the CSV
    ``writer`` whose header :data:`TRIAL_COLUMNS` is written; returns
    their number."""
    table = trial_table(protocol, experiment, first, total)
    for row in zip(*(table[c] for c in TRIAL_COLUMNS), strict=True):
        writer.writerow([trial_tables.csv_cell(v) for v in row])
    return len(table["test_chosen"])


def observer_table(protocol, stimuli, experiment, first=0, total=None):
    """Each observer of ``experiment`` as a row of columns: its name (as in
    :func:`trial_table`, whose ``first`` and ``total`` it takes), noise,
    biases, lapse rate, cue weights ``weight_<cue>``, true PSE per condition
    ``pse_<condition>`` (log10 units, :func:`~jaxadapt.psychophysics.observer.true_pse`)
    and whether training excluded it."""
    observers = experiment.observers
    pse = np.asarray(jax.vmap(lambda o: true_pse(stimuli, o))(observers))
    count = pse.shape[0]
    return {
        "participant": participant_names(total or count, first, count),
        **{name: np.asarray(getattr(observers, name)) for name in OBSERVER_FIELDS},
        **{f"weight_{cue}": np.asarray(observers.weights[:, i]) for i, cue in enumerate(CUES)},
        **{f"pse_{c}": pse[:, i] for i, c in enumerate(protocol.conditions)},
        "excluded": np.asarray(experiment.excluded),
    }


#: The scalar fields of an observer that :func:`observer_table` writes.
OBSERVER_FIELDS = ("noise", "bias", "order_bias", "lapse")


def groups(protocol, experiment):
    """Counts of the included observers per condition and level, as the
    :class:`jaxadapt.psychophysics.trials.Groups` that
    :func:`jaxadapt.psychophysics.fit_table.fit_groups` and the figures take
    (participant-major, conditions in the protocol's order)."""
    n_yes, n_total = design.counts(protocol, experiment.trials, experiment.responses)
    keep = ~np.asarray(experiment.excluded)
    names = np.array(participant_names(keep.shape[0]), dtype=object)[keep]
    C, L = len(protocol.conditions), len(protocol.tests)
    n_yes, n_total = (np.asarray(a, float)[keep].reshape(-1, L) for a in (n_yes, n_total))
    return trial_tables.Groups(
        tuple(np.repeat(names, C)),
        tuple(protocol.conditions) * int(keep.sum()),
        np.broadcast_to(np.asarray(protocol.levels), n_yes.shape).copy(),
        n_yes,
        n_total,
    )
