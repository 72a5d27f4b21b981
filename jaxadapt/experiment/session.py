"""One participant's session of a study: its plan, its table of answers,
and where it stands, so that a run stopped at any point continues where
it stopped.

A session lives in a folder: ``session.json`` (written once, at the
start: the software's version, the study, the participant, the seed, the
display and the order of trials) and ``trials.csv`` (one row per answered
trial, appended, flushed and synced to the disk before the page is told
the answer is taken). Where the session stands is read from the table
alone: a trial is done when it has a row that is not flagged; a trial in
flight when the process stopped has no row, and is shown again. A
row cut short by a crash while it was being written is dropped when the
session is opened again (its trial is shown again).

Choices where the paper is silent
---------------------------------
* **Pilot counts** (:func:`scaled_protocol`): ``training`` trials split
  between the two extreme tests (an odd count rounded up), the control
  block ``repetitions`` times each test, the main block 1.5 and 0.5 times
  that (rounded up), which are the paper's 20, 20, 30 and 10 by default.
* **Exclusion** ends the session: once the training block is done and
  fewer than 70 % of it was answered correctly, the participant is told
  the session is over (their time is not spent on trials that will not
  be analysed).
* **Flagged trials** (a frame dropped while an image was up) keep their
  row, flagged, and are shown again at the end of their block; the
  analysis leaves flagged rows out.
* **Breaks** between blocks and every :data:`BREAK_EVERY` trials within
  one (``spec["break_every"]``).
"""

import csv
import dataclasses
import io
import json
import math
import os
import time
from pathlib import Path

import jax
import numpy as np

from jaxadapt.psychophysics import design
from jaxadapt.psychophysics.trials import SESSION_COLUMNS, csv_cell

__all__ = [
    "TRIAL_COLUMNS",
    "BREAK_EVERY",
    "SessionError",
    "scaled_protocol",
    "Session",
]

#: Columns of ``trials.csv``, in order.
TRIAL_COLUMNS = SESSION_COLUMNS
#: Trials between two breaks within a block.
BREAK_EVERY = 50


class SessionError(ValueError):
    """A session folder that cannot be used as asked (another participant's,
    finished, or not a session)."""


def scaled_protocol(protocol, training=20, repetitions=20):
    """``protocol`` (one of the 2015 presets) with its counts scaled for a
    pilot (see the module notes); a count of 0 drops its block.

    Examples
    --------
    >>> p = scaled_protocol(design.AFTERIMAGE, training=5, repetitions=1)
    >>> [(b.name, dict(b.repetitions)) for b in p.blocks]  # doctest: +NORMALIZE_WHITESPACE
    [('training', {'control': 3}), ('control', {'control': 1}),
     ('main', {'manipulated': 2, 'control': 1})]
    """
    for name, value in (("training", training), ("repetitions", repetitions)):
        if not isinstance(value, int) or value < 0:
            raise ValueError(f"{name}: expected a whole number >= 0, got {value!r}")
    extremes = (0, len(protocol.tests) - 1)
    blocks = [
        design.Block("training", (("control", -(-training // 2)),), extremes, True),
        design.Block("control", (("control", repetitions),)),
        design.Block(
            "main",
            (("manipulated", math.ceil(1.5 * repetitions)), ("control", -(-repetitions // 2))),
        ),
    ]
    kept = tuple(b for b in blocks if any(n for _, n in b.repetitions))
    if not kept:
        raise ValueError("training, repetitions: expected some trials, got 0 and 0")
    return dataclasses.replace(protocol, blocks=kept)


def _plan(protocol, seed):
    """The order of trials (:func:`jaxadapt.psychophysics.design.trial_list`
    of ``seed``), as a list of dicts for the session file."""
    trials = jax.tree.map(np.asarray, design.trial_list(protocol, jax.random.key(seed)))
    return [
        {
            "block": protocol.blocks[int(b)].name,
            "condition": protocol.conditions[int(c)],
            "level_index": int(i),
            "test_first": bool(f),
        }
        for b, c, i, f in zip(
            trials.block, trials.condition, trials.level_index, trials.test_first, strict=True
        )
    ]


def _synced_append(path, text):
    with open(path, "a", encoding="utf-8", newline="") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())


def _sync_folder(folder):
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class Session:
    """A participant's session in ``folder``: created, or continued.

    Parameters
    ----------
    folder : str or Path
        Created if it does not exist.
    spec : dict
        ``participant``, ``study`` (a name of
        :data:`jaxadapt.psychophysics.design.PROTOCOLS`), ``training``,
        ``repetitions``, ``dark_seconds``, ``display`` (a dict of the
        display's fields), ``software``, ``seed`` (None: a new random
        one; a session continued keeps its own) and optionally
        ``break_every`` (:data:`BREAK_EVERY`). A session continued takes
        ``dark_seconds`` and ``break_every`` anew.

    Raises
    ------
    SessionError
        The folder holds another session (a field of ``spec`` differs), a
        finished one, or files that are not a session's.
    """

    def __init__(self, folder, spec):
        self.folder = Path(folder)
        self.table = self.folder / "trials.csv"
        self.file = self.folder / "session.json"
        if self.file.exists():
            self._continue(spec)
        else:
            self._create(spec)
        self.protocol = scaled_protocol(
            design.PROTOCOLS[self.spec["study"]], self.spec["training"], self.spec["repetitions"]
        )
        self.blocks = [b.name for b in self.protocol.blocks]

    # -- opening ------------------------------------------------------------

    def _create(self, spec):
        if self.folder.exists() and any(self.folder.iterdir()):
            raise SessionError(
                f"{self.folder}: expected an empty or new folder for a session, got one "
                f"holding {next(self.folder.iterdir()).name}"
            )
        self.folder.mkdir(parents=True, exist_ok=True)
        spec = dict(spec)
        if spec.get("seed") is None:
            spec["seed"] = int.from_bytes(os.urandom(4), "little") >> 1
        protocol = scaled_protocol(
            design.PROTOCOLS[spec["study"]], spec["training"], spec["repetitions"]
        )
        spec["created"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
        spec["trials"] = _plan(protocol, spec["seed"])
        from jaxadapt.io import atomic_path

        with atomic_path(self.table) as tmp:
            with open(tmp, "w", encoding="utf-8") as f:
                f.write(",".join(TRIAL_COLUMNS) + "\n")
                f.flush()
                os.fsync(f.fileno())
        with atomic_path(self.file) as tmp:
            with open(tmp, "w", encoding="utf-8") as f:
                json.dump(spec, f, indent=1)
                f.flush()
                os.fsync(f.fileno())
        _sync_folder(self.folder)
        self.spec, self.rows = spec, []

    def _continue(self, spec):
        try:
            saved = json.loads(self.file.read_text(encoding="utf-8"))
            saved["trials"]
        except (ValueError, KeyError, TypeError):
            raise SessionError(f"{self.file}: expected a session file, got another file") from None
        for name in ("participant", "study", "training", "repetitions", "display"):
            if saved.get(name) != spec[name]:
                raise SessionError(
                    f"{self.folder}: holds a session of {name} {saved.get(name)!r}, not "
                    f"{spec[name]!r}; continue it with the same options, or choose another folder"
                )
        if spec.get("seed") is not None and spec["seed"] != saved["seed"]:
            raise SessionError(
                f"{self.folder}: holds a session of seed {saved['seed']}, not {spec['seed']}"
            )
        saved["dark_seconds"] = spec["dark_seconds"]
        saved["break_every"] = spec.get("break_every", BREAK_EVERY)
        self.spec = saved
        self.rows = self._read_rows()
        state = self.next()
        if state["phase"] in ("done", "excluded"):
            raise SessionError(
                f"{self.folder}: holds participant {saved['participant']!r}'s finished "
                f"{saved['study']} session ({state['phase']}, {len(self.rows)} answers); "
                f"choose another folder"
            )

    def _read_rows(self):
        """The rows of ``trials.csv``; a last row cut short by a crash is cut off."""
        if not self.table.is_file():
            raise SessionError(f"{self.table}: no such file (the session's table of answers)")
        raw = self.table.read_bytes()
        if not raw.endswith(b"\n"):
            with open(self.table, "r+b") as f:
                f.truncate(raw.rfind(b"\n") + 1)
                os.fsync(f.fileno())
        with open(self.table, newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            if tuple(reader.fieldnames or ()) != TRIAL_COLUMNS:
                raise SessionError(f"{self.table}: expected the columns {', '.join(TRIAL_COLUMNS)}")
            return list(reader)

    # -- where the session stands -----------------------------------------

    @property
    def plan(self):
        return self.spec["trials"]

    def _done(self):
        """Plan indices answered by an unflagged row; the flagged ones' last rows."""
        done, flagged = set(), {}
        for n, row in enumerate(self.rows):
            t = int(row["trial"])
            if row["flagged"] == "true":
                flagged[t] = n
            else:
                done.add(t)
        return done, {t: n for t, n in flagged.items() if t not in done}

    def training_accuracy(self):
        """Fraction of the training block answered correctly (None: not done)."""
        rows = [r for r in self.rows if r["block"] == "training" and r["flagged"] == "false"]
        planned = sum(1 for t in self.plan if t["block"] == "training")
        if not planned or len(rows) < planned:
            return None
        return sum(r["correct"] == "true" for r in rows) / planned

    def next(self):
        """What comes next: ``{"phase": "trial", "trial": index, "break":
        bool}``, or ``{"phase": "done"}`` or ``{"phase": "excluded"}``."""
        done, flagged = self._done()
        accuracy = self.training_accuracy()
        if accuracy is not None and accuracy < self.protocol_exclusion:
            return {"phase": "excluded", "accuracy": accuracy}
        for block in dict.fromkeys(t["block"] for t in self.plan):
            in_block = [i for i, t in enumerate(self.plan) if t["block"] == block]
            pending = [i for i in in_block if i not in done and i not in flagged]
            pending += sorted((i for i in in_block if i in flagged), key=flagged.get)
            if pending:
                answered = sum(1 for r in self.rows if r["block"] == block)
                last = self.rows[-1]["block"] if self.rows else None
                new_block = last is not None and last != block
                every = self.spec.get("break_every", BREAK_EVERY)
                pause = new_block or (answered > 0 and answered % every == 0)
                return {"phase": "trial", "trial": pending[0], "break": pause}
        return {"phase": "done"}

    @property
    def protocol_exclusion(self):
        return design.PROTOCOLS[self.spec["study"]].exclusion

    def progress(self):
        """``(answered, planned)``: trials with an unflagged row, and all."""
        return len(self._done()[0]), len(self.plan)

    # -- answers ------------------------------------------------------------

    def answer(self, trial, answer, rt_ms, durations, dropped_frames):
        """Record the answer to plan index ``trial`` (which must be the one
        :meth:`next` gives; otherwise nothing is written and False is
        returned): ``answer`` 1 or 2 (the interval chosen), ``rt_ms`` from the
        end of the second interval, ``durations`` the measured ms of image 1,
        image 2, blank 1, blank 2, ``dropped_frames`` while an image was up.
        The row is on the disk when this returns True."""
        state = self.next()
        if state["phase"] != "trial" or state["trial"] != trial or answer not in (1, 2):
            return False
        t = self.plan[trial]
        protocol = self.protocol
        test = protocol.tests[t["level_index"]]
        level = float(protocol.levels[t["level_index"]])
        test_interval = 1 if t["test_first"] else 2
        chosen = int(answer == test_interval)
        correct = "" if t["block"] != "training" else ("true" if chosen == (level > 0) else "false")
        row = {
            "participant": self.spec["participant"],
            "study": self.spec["study"],
            "block": t["block"],
            "trial": trial,
            "condition": t["condition"],
            "level": level,
            "test_luminance": test,
            "standard_luminance": protocol.standard,
            "test_interval": test_interval,
            "answer": answer,
            "test_chosen": chosen,
            "correct": correct,
            "rt_ms": round(float(rt_ms), 1),
            "image1_ms": round(float(durations[0]), 2),
            "image2_ms": round(float(durations[1]), 2),
            "blank1_ms": round(float(durations[2]), 2),
            "blank2_ms": round(float(durations[3]), 2),
            "dropped_frames": int(dropped_frames),
            "flagged": "true" if dropped_frames else "false",
            "answered_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }
        cells = [v if isinstance(v, str) else csv_cell(v) for v in (row[c] for c in TRIAL_COLUMNS)]
        line = io.StringIO()
        csv.writer(line, lineterminator="\n").writerow(cells)
        _synced_append(self.table, line.getvalue())
        self.rows.append({c: str(v) for c, v in zip(TRIAL_COLUMNS, cells, strict=True)})
        return True
