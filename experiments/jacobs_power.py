"""Power of the 2015 paper's design to detect a 0.13 log-unit PSE shift (Jacobs 2015, §4).

The probability that the rank-sum test between control and manipulated
PSEs (two-sided, p < 0.05, as in §4.1.2) detects a shift of the median PSE
of 0.13 log units, the size of the mesopic effect the paper found, as a
function of the number of participants (recruited; those below 70% correct
in training are excluded, as in the paper) and of the repetitions per level
and condition (the paper: 30; the control block gets two thirds of the
control repetitions and the main block the rest, 20 + 10 in the paper).

Both protocols: the mesopic one (the shift darkens the manipulated test,
through desaturation and blur weighted 2:1) and the afterimage one with an
afterimage cue made strong enough to brighten the test by 0.13 log units
(could the paper's design see an afterimage effect as large as the
mesopic one?), and, for comparison, by the 0.02 log units the paper
measured (could it see that?). Observers come from the protocol's default population
(:data:`jaxadapt.psychophysics.population.POPULATIONS`) with the cue weights
set for the shift (:func:`jaxadapt.psychophysics.observer.weights_for_pse`)
and a between-observer spread of half their mean. Each cell runs many
simulated experiments; the experiments of different cells of one
repetition count draw their participants from one simulated pool (common
random numbers: each cell is an unbiased estimate, and the curves are
smooth). Writes ``power.csv``, ``power.json`` and ``power.png``.
"""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
from common import setup
from matplotlib.figure import Figure
from matplotlib.ticker import NullLocator

from jaxadapt.io import csv_writer
from jaxadapt.psychophysics import design, psychometric, stats
from jaxadapt.psychophysics import experiment as simulated
from jaxadapt.psychophysics import observer as obs
from jaxadapt.psychophysics import population as populations

SHIFT = 0.13
#: (protocol, relative cue weights, median PSE shift in log10 units): the
#: 0.13 shift in both protocols, and the afterimage effect the paper
#: measured (-0.02, not significant).
SCENARIOS = (
    ("mesopic", (0.0, 2.0, 1.0), SHIFT),
    ("afterimage", (1.0, 0.0, 0.0), -SHIFT),
    ("afterimage", (1.0, 0.0, 0.0), -0.02),
)
WEIGHT_SPREAD = 0.5
PARTICIPANTS = (4, 5, 6, 8, 11, 16, 24, 48)
REPETITIONS = (10, 20, 30, 60)
#: Observers simulated per call (bounds the memory of one call).
CHUNK = 4000


def with_repetitions(protocol, r):
    """The protocol with ``r`` repetitions per level and condition: control
    block ``round(2r/3)``, main block ``r`` manipulated and the rest of the
    control ones (the paper: r = 30, 20 + 10)."""
    training, _, _ = protocol.blocks
    first = int(round(2 * r / 3))
    blocks = (
        training,
        design.Block("control", (("control", first),)),
        design.Block("main", (("manipulated", r), ("control", r - first))),
    )
    return dataclasses.replace(protocol, blocks=blocks)


def pool(key, protocol, stimuli, population, n):
    """PSEs ``(n, 2)`` and exclusions ``(n,)`` of ``n`` simulated observers."""
    pse, excluded = [], []
    chunk = min(CHUNK, n)
    for i in range(-(-n // chunk)):
        e = simulated.simulate(jax.random.fold_in(key, i), protocol, stimuli, population, chunk)
        n_yes, n_total = design.counts(protocol, e.trials, e.responses)
        pse.append(np.asarray(psychometric.fit(protocol.levels, n_yes, n_total).pse))
        excluded.append(np.asarray(e.excluded))
    return np.concatenate(pse)[:n], np.concatenate(excluded)[:n]


def power(pse, excluded, participants, experiments):
    """Rank-sum power of ``experiments`` experiments of ``participants``."""
    n = participants * experiments
    pse = jnp.asarray(pse[:n]).reshape(experiments, participants, 2)
    keep = ~jnp.asarray(excluded[:n]).reshape(experiments, participants)
    c = stats.compare(pse[..., 1], pse[..., 0], x_mask=keep, y_mask=keep)
    detected = np.asarray(c.test.p < 0.05)
    rate = float(detected.mean())
    return {
        "power": rate,
        "power_se": float(np.sqrt(rate * (1 - rate) / experiments)),
        "median_shift": float(np.median(np.asarray(c.median_x - c.median_y))),
        "analysed": float(np.mean(np.asarray(keep.sum(-1)))),
    }


def main():
    args, out = setup("jacobs_power", __doc__.splitlines()[0])
    experiments = 40 if args.smoke else 1000
    participants = (4, 11, 24) if args.smoke else PARTICIPANTS
    repetitions = (30,) if args.smoke else REPETITIONS
    sizes = {
        "afterimage": dict(width=24, height=24, fps=20.0) if args.smoke else {},
        "mesopic": dict(width=48, height=32, fps=4.0) if args.smoke else {},
    }
    key = jax.random.key(13)
    rows, stimuli = [], {}
    for name, direction, shift in SCENARIOS:
        protocol = design.PROTOCOLS[name]
        k_render, k_sim = jax.random.split(jax.random.fold_in(key, len(name)))
        if name not in stimuli:
            stimuli[name] = obs.render_stimuli(protocol, key=k_render, **sizes[name])
        weights = obs.weights_for_pse(stimuli[name], jnp.asarray(direction), shift)
        population = dataclasses.replace(
            populations.POPULATIONS[name],
            weights=weights,
            weight_spread=WEIGHT_SPREAD * jnp.abs(weights),
        )
        for r in repetitions:
            variant = with_repetitions(protocol, r)
            pse, excluded = pool(
                jax.random.fold_in(k_sim, r),
                variant,
                stimuli[name],
                population,
                max(participants) * experiments,
            )
            for n in participants:
                cell = power(pse, excluded, n, experiments)
                rows.append(
                    {"protocol": name, "shift": shift, "participants": n, "repetitions": r, **cell}
                )
                print(
                    f"{name}, shift {shift:+.2f}: {n:2d} participants x {r:2d} repetitions: "
                    f"power {cell['power']:.2f} +- {cell['power_se']:.2f} (median shift "
                    f"{cell['median_shift']:+.3f}, {cell['analysed']:.1f} analysed)"
                )
    with open(out / "power.csv", "w", newline="") as f:
        writer = csv_writer(f, list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    record = {
        "alpha": 0.05,
        "experiments_per_cell": experiments,
        "weight_spread": WEIGHT_SPREAD,
        "cells": rows,
    }
    (out / "power.json").write_text(json.dumps(record, indent=2) + "\n")
    fig = Figure(figsize=(4.2 * len(SCENARIOS), 4))
    axes = fig.subplots(1, len(SCENARIOS), sharey=True)
    for ax, (name, _, shift) in zip(axes, SCENARIOS, strict=True):
        for r in repetitions:
            cells = [
                c for c in rows if (c["protocol"], c["shift"], c["repetitions"]) == (name, shift, r)
            ]
            ax.errorbar(
                [c["participants"] for c in cells],
                [c["power"] for c in cells],
                yerr=[2 * c["power_se"] for c in cells],
                marker="o",
                ms=4,
                capsize=2,
                label=f"{r} repetitions",
            )
        ax.axhline(0.8, color="0.6", ls=":", lw=1)
        ax.axvline(13, color="0.6", ls="--", lw=1)
        ax.set_xscale("log")
        ax.xaxis.set_minor_locator(NullLocator())
        ax.set_xticks(participants, [str(n) for n in participants])
        ax.set(xlabel="participants (recruited)", title=f"{name}: shift {shift:+.2f} log units")
    axes[0].set_ylabel("P(rank-sum p < 0.05)")
    axes[0].legend(fontsize=8)
    fig.suptitle("Power of the rank-sum test on PSEs (dashed: the paper's 13 recruited)")
    fig.tight_layout()
    fig.savefig(out / "power.png", dpi=100)
    print(f"wrote {out}/power.csv, power.json, power.png")


if __name__ == "__main__":
    main()
