"""The afterimage and mesopic experiments of Jacobs 2015 (§4), simulated (Figs. 13-14).

For each protocol: the paper's design (training, control and main blocks),
the stimuli rendered with the 2015 operator (the flash with a weak or a
strong synthetic afterimage; the ColorChecker with or without the mesopic
colour and acuity effects), 13 model observers (the paper recruited 13),
the training criterion (70% correct), cumulative-Gaussian fits with
bootstrap intervals (Wald intervals with --smoke), the rank-sum test between control and manipulated
PSEs, and the figures: ``<protocol>_psychometric.png`` (Fig. 13, every
participant), ``<protocol>_pse.png`` (Fig. 14), ``<protocol>_fits.csv``,
``stimuli.png`` (what the observers saw) and ``summary.json``.

The observers' cue weights are *set*, not fitted: each protocol's mean
weights are chosen (:func:`jaxadapt.psychophysics.observer.weights_for_pse`)
so that an observer without bias has the paper's median PSE in the
manipulated condition (afterimage -0.02 log units from the afterimage cue;
mesopic +0.13 from desaturation and blur, weighted 2:1 because ten of the
eleven participants said darker images were less colourful and five that
they were blurrier), with a between-observer spread of half the mean. So the
medians reproduce the paper by construction; what the simulation adds is
everything else: the scatter of the PSEs, the fits' intervals, how often
such an experiment reaches significance (``replications``: the same
experiment run many times) and the rate of exclusions. Calibrating the
population against the paper's data is issue 6.
"""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
from common import setup
from matplotlib.figure import Figure
from scipy.stats import mannwhitneyu

from jaxadapt import figures
from jaxadapt.color import W_PHOTOPIC
from jaxadapt.psychophysics import design, fit_table, psychometric, stats
from jaxadapt.psychophysics import experiment as simulated
from jaxadapt.psychophysics import observer as obs
from jaxadapt.psychophysics import population as populations

#: §4.1.2 and §4.2.2: median manipulated PSE (log10 units) and rank-sum p.
PAPER = {
    "afterimage": {"median_pse": -0.02, "p": 0.449, "direction": (1.0, 0.0, 0.0)},
    "mesopic": {"median_pse": 0.13, "p": 2.84e-6, "direction": (0.0, 2.0, 1.0)},
}
PARTICIPANTS = 13
#: Between-observer spread of each cue weight, as a fraction of its mean.
WEIGHT_SPREAD = 0.5


def population(name, stimuli):
    """The protocol's default population with cue weights set for the paper's median."""
    paper = PAPER[name]
    weights = obs.weights_for_pse(stimuli, jnp.asarray(paper["direction"]), paper["median_pse"])
    return dataclasses.replace(
        populations.POPULATIONS[name],
        weights=weights,
        weight_spread=WEIGHT_SPREAD * jnp.abs(weights),
    )


def replications(protocol, e, n):
    """``n`` experiments of :data:`PARTICIPANTS` (consecutive observers of
    ``e``): how often each reaches p < 0.05, and the spread of its medians."""
    n_yes, n_total = design.counts(protocol, e.trials, e.responses)
    fits = psychometric.fit(protocol.levels, n_yes, n_total)
    pse = fits.pse.reshape(n, PARTICIPANTS, 2)
    keep = ~e.excluded.reshape(n, PARTICIPANTS)
    c = stats.compare(pse[..., 1], pse[..., 0], x_mask=keep, y_mask=keep)
    return {
        "replications": n,
        "significant_fraction": float(jnp.mean(c.test.p < 0.05)),
        "p_quartiles": np.quantile(np.asarray(c.test.p), [0.25, 0.5, 0.75]).tolist(),
        "median_manipulated_quartiles": np.quantile(np.asarray(c.median_x), [0.25, 0.5, 0.75])
        .astype(float)
        .tolist(),
        "excluded_fraction": float(jnp.mean(e.excluded)),
    }


def exact_p(table):
    """The exact two-sided rank-sum p (SciPy) of the fitted PSEs.

    The paper's mesopic p = 2.84e-6 is 2 / C(22, 11), the exact p of 11
    manipulated PSEs all above 11 control ones; the normal approximation
    of :func:`jaxadapt.psychophysics.stats.ranksum` gives 8.15e-5 there.
    """
    condition = np.asarray(table.condition)
    x, y = (table.pse[condition == c] for c in ("manipulated", "control"))
    return float(mannwhitneyu(x, y, method="exact").pvalue)


def plot_stimuli(path, displays):
    """What the observers saw: the afterimage at the fixation over time, and
    the mesopic standard beside the manipulated test at level 0."""
    fig = Figure(figsize=(12, 3.4))
    ax, *images = fig.subplots(1, 3, width_ratios=(1.4, 1, 1))
    a = displays["afterimage"]
    t = np.asarray(a.times)
    for c, label in ((0, "weak (standard, control)"), (1, "strong (manipulated)")):
        Y = np.asarray(a.test[c, 2] @ W_PHOTOPIC)
        peak = np.unravel_index(np.argmax(Y[np.asarray(a.blank)].mean(0)), Y.shape[1:])
        ax.semilogy(t, np.maximum(Y[:, peak[0], peak[1]], 1e-6), label=label)
    ax.axhline(a.ambient, color="0.5", ls=":", label="dark room")
    ax.set(xlabel="time (s)", ylabel="cd/m$^2$ at the afterimage's peak", ylim=(1e-5, 100))
    ax.set_title("afterimage stimuli (level 0)", fontsize=10)
    ax.legend(fontsize=8)
    m = displays["mesopic"]
    white = float(np.max(np.asarray(m.standard[0] @ W_PHOTOPIC)))
    shown = (m.standard[0], m.test[1, 2, 0])
    titles = ("mesopic standard", "manipulated test, level 0")
    for axis, image, title in zip(images, shown, titles, strict=True):
        axis.imshow(np.clip(np.asarray(image) / white, 0, 1) ** 0.455, interpolation="nearest")
        axis.set_title(f"{title} (brightened)", fontsize=10)
        axis.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main():
    args, out = setup("jacobs_psychophysics", __doc__.splitlines()[0])
    sizes = {
        "afterimage": dict(width=24, height=24, fps=20.0) if args.smoke else {},
        "mesopic": dict(width=48, height=32, fps=4.0) if args.smoke else {},
    }
    resamples, n_replications = (0, 50) if args.smoke else (1000, 1000)
    key = jax.random.key(2015)
    summary, displays = {}, {}
    for name, protocol in design.PROTOCOLS.items():
        k_render, k_sim, k_boot = jax.random.split(jax.random.fold_in(key, len(name)), 3)
        displays[name] = obs.DISPLAYS[name](protocol, key=k_render, **sizes[name])
        stimuli = obs.stimuli_from_displays(protocol, displays[name])
        pop = population(name, stimuli)
        # All replications in one call; the first is the experiment shown.
        everyone = simulated.simulate(k_sim, protocol, stimuli, pop, n_replications * PARTICIPANTS)
        experiment = jax.tree.map(lambda a: a[:PARTICIPANTS], everyone)
        groups = simulated.groups(protocol, experiment)
        # Every simulated participant enters the medians and the test below,
        # with the prior's PSE where the data fix none, as the replications do.
        table = fit_table.fit_groups(
            groups, key=k_boot, n_resamples=resamples, keep_undetermined=True
        )
        fit_table.write_fits(out / f"{name}_fits.csv", table)
        condition = np.asarray(table.condition)
        c = stats.compare(
            jnp.asarray(table.pse[condition == "manipulated"]),
            jnp.asarray(table.pse[condition == "control"]),
        )
        figures.plot_psychometric(out / f"{name}_psychometric.png", groups, table)
        figures.plot_pse(out / f"{name}_pse.png", table)
        d_lum, d_cues = (np.asarray(a) for a in stimuli.differences())
        summary[name] = {
            "render": {k: float(v) for k, v in sizes[name].items()} or "defaults",
            "cue_differences_manipulated": {
                cue: np.asarray(d_cues[1, :, i]).round(4).tolist() for i, cue in enumerate(obs.CUES)
            },
            "weights": dict(zip(obs.CUES, np.asarray(pop.weights).round(4).tolist(), strict=True)),
            "participants": PARTICIPANTS,
            "excluded": int(np.sum(experiment.excluded)),
            "median_pse": {"control": float(c.median_y), "manipulated": float(c.median_x)},
            "ranksum_p": float(c.test.p),
            "ranksum_p_exact": exact_p(table),
            "paper": {"median_pse": PAPER[name]["median_pse"], "p": PAPER[name]["p"]},
            "replications": replications(protocol, everyone, n_replications),
        }
        rep = summary[name]["replications"]
        print(
            f"{name}: {PARTICIPANTS - summary[name]['excluded']} of {PARTICIPANTS} analysed, "
            f"median PSE {c.median_x:+.3f} (control {c.median_y:+.3f}) log units, rank-sum "
            f"p = {c.test.p:.3g}, exact {summary[name]['ranksum_p_exact']:.3g} (paper: "
            f"{PAPER[name]['median_pse']:+.2f}, p = "
            f"{PAPER[name]['p']:.3g}); p < 0.05 in {rep['significant_fraction']:.0%} of "
            f"{n_replications} replications"
        )
    plot_stimuli(out / "stimuli.png", displays)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(
        f"wrote {out}/summary.json, stimuli.png and per protocol _fits.csv, _psychometric.png, "
        "_pse.png"
    )


if __name__ == "__main__":
    main()
