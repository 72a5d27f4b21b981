"""The method of constant stimuli as data, and the 2015 paper's two protocols.

A :class:`Protocol` says what is shown (a standard and a set of test
luminances, in cd/m2), under which conditions (control, manipulated), how
often, in which blocks, and who is excluded (a minimum fraction correct in the
training trials). :func:`trial_list` turns it into the trial-by-trial
sequence one participant sees: randomised within each block, with the
standard/test order counter-balanced, the same for the same PRNG key, and
``vmap``-able over keys (one sequence per simulated observer). Responses to
those trials are scored by :func:`training_accuracy` and :func:`excluded` and
counted per condition and level by :func:`counts`, which gives the arrays
:func:`jaxadapt.psychophysics.psychometric.fit` takes.

Levels are log10 units relative to the standard, ``log10(test / standard)``,
and a response is 1 when the test was judged brighter.

References
----------
Jacobs, Gallo, Cooper, Pulli, Levoy (2015), *Simulating the Visual Experience
of Very Bright and Very Dark Scenes*, ACM TOG 34(3), §4.1.1 and §4.2.1.
"""

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt.psychophysics.trials import EXCLUSION

__all__ = [
    "Block",
    "Protocol",
    "AFTERIMAGE",
    "MESOPIC",
    "PROTOCOLS",
    "Trials",
    "trial_list",
    "training_accuracy",
    "excluded",
    "counts",
]


class Block(eqx.Module):
    """A block of trials, shown in a random order.

    Attributes
    ----------
    name : str
        Label, e.g. ``"training"``.
    repetitions : tuple of (str, int)
        ``(condition, n)``: each selected test level is paired with the
        standard ``n`` times under that condition.
    levels : tuple of int, optional
        Indices of the protocol's tests used in this block (default: all).
    training : bool, optional
        Training trials: scored for exclusion, not analysed. Their levels must
        differ from the standard, so that every answer is right or wrong.
    """

    name: str
    repetitions: tuple[tuple[str, int], ...]
    levels: tuple[int, ...] | None = None
    training: bool = False


class Protocol(eqx.Module):
    """A method-of-constant-stimuli experiment.

    Attributes
    ----------
    name : str
    standard : float
        Luminance of the standard, cd/m2.
    tests : tuple of float
        Luminances of the tests, cd/m2.
    blocks : tuple of Block
        In presentation order.
    conditions : tuple of str, optional
        Condition names; responses are counted in this order.
    exclusion : float, optional
        Participants who answer fewer than this fraction of the training
        trials correctly are excluded (the paper's 70%).
    presentation_s, blank_s : float, optional
        Each image is shown for ``presentation_s`` seconds, then a black
        screen for ``blank_s`` seconds.
    dark_adaptation_s : float, optional
        Time in complete darkness before the first trial, s.
    ambient : float, optional
        Luminance of the room with the black screen shown, cd/m2.
    """

    name: str
    standard: float
    tests: tuple[float, ...]
    blocks: tuple[Block, ...]
    conditions: tuple[str, ...] = ("control", "manipulated")
    exclusion: float = EXCLUSION
    presentation_s: float = 0.05
    blank_s: float = 2.5
    dark_adaptation_s: float = 0.0
    ambient: float = 1.8e-4

    def __check_init__(self):
        luminances = np.asarray((self.standard, *self.tests), float)
        if not self.tests or not np.all(np.isfinite(luminances) & (luminances > 0)):
            raise ValueError(
                f"standard, tests: expected positive, finite luminances in cd/m2, "
                f"got {self.standard!r} and {self.tests!r}"
            )
        if len(set(self.conditions)) != len(self.conditions):
            raise ValueError(f"conditions: expected distinct names, got {self.conditions!r}")
        if not 0 < self.exclusion <= 1:
            raise ValueError(f"exclusion: expected a fraction in (0, 1], got {self.exclusion!r}")
        if not (np.isfinite(self.presentation_s) and self.presentation_s > 0):
            raise ValueError(
                f"presentation_s: expected a positive duration in s, got {self.presentation_s!r}"
            )
        for name in ("blank_s", "dark_adaptation_s", "ambient"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"{name}: expected a finite value >= 0, got {value!r}")
        if not self.blocks:
            raise ValueError("blocks: expected at least one block, got none")
        for block in self.blocks:
            _check_block(self, block)
        if not any(n for block in self.blocks for _, n in block.repetitions):
            raise ValueError("blocks: expected at least one trial, got blocks of 0 repetitions")

    @property
    def levels(self):
        """Test levels, log10 units relative to the standard, shape ``(L,)``."""
        return np.log10(np.asarray(self.tests) / self.standard)

    @property
    def n_trials(self):
        """Number of trials, training included."""
        return len(_schedule(self)[0])


def _check_block(protocol, block):
    where = f"blocks[{block.name!r}]"
    for condition, n in block.repetitions:
        if condition not in protocol.conditions:
            raise ValueError(
                f"{where}.repetitions: expected conditions from {protocol.conditions}, "
                f"got {condition!r}"
            )
        if not isinstance(n, int) or n < 0:
            raise ValueError(f"{where}.repetitions: expected counts >= 0, got {n!r}")
    indices = range(len(protocol.tests)) if block.levels is None else block.levels
    if any(not 0 <= i < len(protocol.tests) for i in indices):
        raise ValueError(
            f"{where}.levels: expected indices into {len(protocol.tests)} tests, "
            f"got {block.levels!r}"
        )
    if block.training and any(protocol.tests[i] == protocol.standard for i in indices):
        raise ValueError(
            f"{where}.levels: training trials need tests that differ from the standard "
            f"({protocol.standard} cd/m2), got {[protocol.tests[i] for i in indices]}"
        )


#: Training, control block, main block: §4.1.1. The 20 training trials
#: compare "pairs of un-manipulated images with large brightness
#: differences"; which ones is not said, so the two extreme tests are used,
#: 10 times each.
_PAPER_BLOCKS = (
    Block("training", (("control", 10),), levels=(0, 4), training=True),
    Block("control", (("control", 20),)),
    Block("main", (("manipulated", 30), ("control", 10))),
)

#: §4.1.1: the camera-flash scene at 27 cd/m2, tests 14-49 cd/m2, each image
#: shown for 50 ms followed by 2.5 s of black on which afterimages appear (weak
#: synthetic afterimage in control trials, 2.2e-2 cd/m2 and j1 = 0.0003; strong
#: in manipulated ones, 6.5e-2 cd/m2 and j1 = 0.001), in a dark room
#: (1.8e-4 cd/m2).
AFTERIMAGE = Protocol(
    name="afterimage",
    standard=27.0,
    tests=(14.0, 19.0, 27.0, 35.0, 49.0),
    blocks=_PAPER_BLOCKS,
    presentation_s=0.05,
    blank_s=2.5,
)

#: §4.2.1: the colour checker at 5.5e-2 cd/m2 on its white tile, tests
#: 4.1e-2-7.5e-2 cd/m2, shown for 1.25 s followed by 0.75 s of black, after
#: five minutes in complete darkness; manipulated tests are rendered with the
#: mesopic colour and acuity effects (§2.3.2-2.3.3). "The rest of the
#: experimental procedure was identical to that of the afterimage experiment."
MESOPIC = Protocol(
    name="mesopic",
    standard=5.5e-2,
    tests=(4.1e-2, 4.8e-2, 5.5e-2, 6.8e-2, 7.5e-2),
    blocks=_PAPER_BLOCKS,
    presentation_s=1.25,
    blank_s=0.75,
    dark_adaptation_s=300.0,
)

#: The presets by name (``--protocol afterimage|mesopic``).
PROTOCOLS = {p.name: p for p in (AFTERIMAGE, MESOPIC)}


class Trials(NamedTuple):
    """A trial sequence, one entry per trial in presentation order (leading
    axes: one sequence per key when ``vmap``-ped).

    Attributes
    ----------
    block : array of int
        Index into ``protocol.blocks``.
    condition : array of int
        Index into ``protocol.conditions``.
    level_index : array of int
        Index into ``protocol.tests``.
    level : array of float
        ``log10(test / standard)``.
    luminance : array of float
        Test luminance, cd/m2.
    test_first : array of bool
        Whether the test is shown before the standard.
    training : array of bool
        Training trial (scored for exclusion, not analysed).
    """

    block: jax.Array
    condition: jax.Array
    level_index: jax.Array
    level: jax.Array
    luminance: jax.Array
    test_first: jax.Array
    training: jax.Array


def _schedule(protocol):
    """The trials before randomisation, as NumPy columns ``(block, condition,
    level_index, repetition, repetitions)``, block after block."""
    rows = []
    for b, block in enumerate(protocol.blocks):
        indices = range(len(protocol.tests)) if block.levels is None else block.levels
        c_of = protocol.conditions.index
        rows += [
            (b, c_of(condition), i, r, n)
            for condition, n in block.repetitions
            for i in indices
            for r in range(n)
        ]
    return tuple(np.asarray(column, dtype=np.int32) for column in zip(*rows, strict=True))


def _segments(block):
    """``(start, stop)`` of each run of equal values in the static ``block`` column."""
    edges = np.flatnonzero(np.diff(block)) + 1
    return tuple(zip((0, *edges), (*edges, len(block)), strict=True))


def _index_bits(n):
    """Bits that hold an index into ``n`` entries."""
    return int(max(n, 1) - 1).bit_length()


def _rounds(n):
    """Sorting rounds of :func:`_shuffle` for ``n`` entries.

    A round gives each entry ``32 - b`` random bits (``b`` =
    :func:`_index_bits`). Enough rounds that these add up to at least 32
    bits, and to ``3 log2 n`` (the rule of :func:`jax.random.permutation`).
    """
    b = _index_bits(n)
    if b > 24:
        raise ValueError(f"blocks: expected at most {2**24} trials in a block, got {n}")
    return 0 if n < 2 else -(-max(32, 3 * b) // (32 - b))


def _shuffle(words, n):
    """A uniformly random permutation of ``arange(n)`` (int32) from random
    ``words``, uint32 of shape ``(rounds, n)`` with ``rounds >=``
    :func:`_rounds`, of which the low :func:`_index_bits` bits are unused.

    Each round keeps the high ``32 - b`` bits of a word per entry, puts the
    entry itself in the low ``b`` bits and sorts these words: one
    single-operand integer sort, which XLA's CPU backend runs faster than a
    key-value sort (``argsort``, or ``jax.random.permutation``
    then a stable sort). Entries whose random bits tie in a round come out
    in the order of their low bits, but a given pair ties in every round
    with probability at most ``2**-32``.
    """
    b = _index_bits(n)
    low = jnp.uint32(2**b - 1)
    order = jnp.arange(n, dtype=jnp.uint32)
    for r in range(_rounds(n)):
        order = jnp.sort((words[r] & ~low) | order) & low
    return order.astype(jnp.int32)


@eqx.filter_jit
def _trial_list(protocol, key):
    columns = _schedule(protocol)
    block, condition, level_index, repetition, repetitions = (jnp.asarray(c) for c in columns)
    # Blocks are contiguous in the schedule: shuffle each one in place. One
    # draw of random words for all of them; bit 0 of the first round's words,
    # never part of a sort key (blocks of one trial are not sorted), gives
    # the coin tosses.
    segments = _segments(columns[0])
    rounds = max([1, *(_rounds(stop - start) for start, stop in segments)])
    words = jax.random.bits(key, (rounds, block.shape[0]), jnp.uint32)
    order = jnp.concatenate(
        [start + _shuffle(words[:, start:stop], stop - start) for start, stop in segments]
    )
    # Alternate the order within each cell; an odd cell's last trial is a coin toss.
    last_odd = (repetition == repetitions - 1) & (repetitions % 2 == 1)
    coin = (words[0] & 1).astype(bool)
    test_first = jnp.where(last_odd, coin, repetition % 2 == 0)
    levels = jnp.asarray(protocol.levels, dtype=jnp.result_type(float))
    tests = jnp.asarray(protocol.tests, dtype=levels.dtype)
    training = jnp.asarray([b.training for b in protocol.blocks])[block]
    trials = Trials(
        block, condition, level_index, levels[level_index], tests[level_index], test_first, training
    )
    return jax.tree.map(lambda column: column[order], trials)


def trial_list(protocol, key):
    """The sequence of trials one participant sees.

    Parameters
    ----------
    protocol : Protocol
    key : PRNG key
        Same key, same sequence.

    Returns
    -------
    Trials
        Columns of length ``protocol.n_trials``: blocks in order, trials in a
        uniformly random order within each block; within each block,
        condition and level, half of the repetitions show the test first
        (an odd count's extra trial is decided by a coin toss).

    Examples
    --------
    >>> trials = trial_list(AFTERIMAGE, jax.random.key(0))
    >>> trials.level.shape, int(trials.training.sum()), int(trials.test_first.sum())
    ((320,), 20, 160)
    >>> keys = jax.random.split(jax.random.key(0), 8)
    >>> jax.vmap(lambda k: trial_list(AFTERIMAGE, k))(keys).level.shape
    (8, 320)
    """
    return _trial_list(protocol, key)


def _responses(trials, responses):
    """``responses`` as an array, checked to hold one answer per trial on its
    last axis, each 0 or 1 (``ValueError`` otherwise; traced values are not
    checked): scoring and counting would silently misread any other coding
    (1/2, or NaN for a missing answer)."""
    responses = jnp.asarray(responses)
    n_trials = trials.level.shape[-1]
    if responses.shape[-1:] != (n_trials,):
        raise ValueError(
            f"responses: expected shape (..., {n_trials}), one per trial, got shape "
            f"{responses.shape}"
        )
    if not isinstance(responses, jax.core.Tracer):
        values = np.asarray(responses)
        other = np.unique(values[(values != 0) & (values != 1)])
        if other.size:
            raise ValueError(
                f"responses: expected 0 or 1 (1: the test judged brighter), got "
                f"{', '.join(map(str, other[:5]))}{' ...' if other.size > 5 else ''}"
            )
    return responses


def training_accuracy(trials, responses):
    """Fraction of training trials answered correctly.

    Parameters
    ----------
    trials : Trials
    responses : array, shape (..., n_trials)
        1 when the test was judged brighter; leading axes are observers.

    Returns
    -------
    array, shape (...)
        Correct means judging the brighter image brighter: ``response == 1``
        exactly when the test is brighter than the standard (``level > 0``).
    """
    correct = (_responses(trials, responses) > 0.5) == (trials.level > 0)
    weight = trials.training.astype(jnp.result_type(float))
    return jnp.sum(correct * weight, axis=-1) / jnp.maximum(jnp.sum(weight, axis=-1), 1.0)


def excluded(protocol, trials, responses):
    """Whether a participant is excluded: fewer than ``protocol.exclusion`` of
    the training trials correct (§4.1.1: "less than 70% of the time"). A
    protocol without training trials excludes no one: there is nothing to
    score, and 0 of 0 correct is no failure.

    Examples
    --------
    >>> trials = trial_list(AFTERIMAGE, jax.random.key(0))
    >>> bool(excluded(AFTERIMAGE, trials, (trials.level > 0).astype(float)))
    False
    """
    scored = jnp.any(trials.training, axis=-1)
    return scored & (training_accuracy(trials, responses) < protocol.exclusion)


def counts(protocol, trials, responses):
    """Responses counted per condition and level, training trials left out.

    Parameters
    ----------
    protocol : Protocol
    trials : Trials
    responses : array, shape (..., n_trials)
        1 when the test was judged brighter.

    Returns
    -------
    (array, array)
        ``n_yes`` and ``n_total``, shape ``(..., n_conditions, n_levels)``,
        ready for :func:`jaxadapt.psychophysics.psychometric.fit` with
        ``protocol.levels``.

    Examples
    --------
    >>> trials = trial_list(AFTERIMAGE, jax.random.key(0))
    >>> n_yes, n_total = counts(AFTERIMAGE, trials, jnp.ones(320))
    >>> n_total.tolist()
    [[30.0, 30.0, 30.0, 30.0, 30.0], [30.0, 30.0, 30.0, 30.0, 30.0]]
    """
    shape = (len(protocol.conditions), len(protocol.tests))
    cell = trials.condition * shape[1] + trials.level_index
    onehot = jax.nn.one_hot(cell, shape[0] * shape[1]) * ~trials.training[..., None]
    responses = _responses(trials, responses).astype(onehot.dtype)
    n_yes = jnp.einsum("...t,...tc->...c", responses, onehot)
    n_total = jnp.broadcast_to(jnp.sum(onehot, axis=-2), n_yes.shape)
    return n_yes.reshape(n_yes.shape[:-1] + shape), n_total.reshape(n_yes.shape[:-1] + shape)
