"""Time constants from a time course: t0 and tau of rods and cones recovered from thresholds.

A uniform field is stepped in luminance: a viewer adapted to a bleaching
field (1e6 cd/m2) is put in the dark for 30 minutes (dark adaptation, as in
Crawford 1937 and Haig 1941, Fig. 2 of Pattanaik et al. 2000), then sees a
dim field (0.03 cd/m2, rods, as in Adelson 1982) for 30 s and a bright one
(1000 cd/m2, cones, as in Baker 1949) for 5 minutes (light adaptation, the
paper's Fig. 3). The increment threshold at each moment is the chapter's
response-to-threshold relation (§6.2.4: the increment that raises the
response by a criterion delta = 0.01) applied to the 2000 operator's state
(``pattanaik2000.run``: sigma from A, the maximum response B) for rods and
for cones, pooled by probability summation (close to the lower of the two).
Simulated observers (their t0 and tau drawn around the paper's values, 20 %
log-normal spread) give log10 thresholds with Gaussian noise of 0.05 log
units, and :func:`jaxadapt.fitting.fit` recovers t0 and tau of rods and
cones for all observers in one vmapped Levenberg-Marquardt call.

What it shows (the numbers are printed by the run and written to
``summary.json``):

* With the three steps, the four constants are identified in every fit:
  median standard errors of about 1 % (t0_cone, tau_rod), 5 % (tau_cone)
  and 8 % (t0_rod) of the estimates, and the 95 % intervals from the
  Gauss-Newton standard errors cover the true values in 90-97 % of the
  observers (t0_rod lowest: its likelihood is the least quadratic).
* Dark adaptation alone does not pin t0_rod: the rods are saturated
  (B_rod below delta) while their neural adaptation runs, so the data
  barely depend on it. Only about one fit in five identifies it; in the
  others the solver, which damps each parameter in its own units, runs it
  along the flat direction towards 0 and it is flagged (``converged``
  False, standard error inf), while t0_cone, tau_rod and tau_cone stay
  identified in every fit and as well determined as with three steps.
* tau_cone is identified, but not by the cone recovery, which the rods hide
  after the rod-cone break: with the bleaching constant c_cone held at the
  paper's value it is set by the static bleach of the pre-adaptation field,
  ``B = 1 / (1 + G tau / c)`` (Eq 7's fixed point). Freeing c_rod and
  c_cone as well shows it: tau_cone and c_cone then correlate at 0.999,
  only their ratio is determined, and both standard errors exceed the
  estimates (median 1.13 and 1.15 of them; c_rod's is 0.89 of its own).
  ``converged`` stays True in 99 % of those fits, since every parameter is
  identified in the numeric sense (a finite standard error); how well one
  is determined is its standard error against its estimate. Along that
  ridge the likelihood is far from quadratic, and the 95 % intervals of
  tau_cone cover the truth in 62 % of the observers, not 95 % (the t0 and
  tau_rod results do not change).
* The curves are the 2000 model's with the paper's constants, not the
  measured ones the protocol follows: after the 1e6 cd/m2 field the cones
  are a third bleached (B_cone = 0.67), their threshold falls with the
  neural adaptation (t0_cone = 80 ms), and the rods, whose pigment comes
  back from B_rod = 4e-8 at 1/tau_rod, are already the more sensitive
  5 s into the dark; measured curves (Haig's, the paper's Fig. 2) show the
  rod-cone break after several minutes. The fits recover the constants of
  whatever data they are given; these data test the fitting, not the model.

Writes ``fit_time_constants.png``, ``estimates.csv`` and ``summary.json``.
"""

import json

import jax

jax.config.update("jax_enable_x64", True)  # Gauss-Newton standard errors in float64

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from common import setup  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from jaxadapt import fitting  # noqa: E402
from jaxadapt.io import csv_writer  # noqa: E402
from jaxadapt.operators import pattanaik2000 as op  # noqa: E402
from jaxadapt.physiology.response import sigma_cone, sigma_rod  # noqa: E402
from jaxadapt.physiology.threshold import increment_sensitivity  # noqa: E402

#: Criterion response of the response-to-threshold relation (of R_max = 1).
DELTA = 0.01
#: Measurement noise, log10 units.
NOISE = 0.05
#: Luminance of the pre-adaptation (bleaching) field, cd/m2.
PRE = 1e6
#: The steps: (luminance cd/m2, duration s, thresholds measured).
STEPS = ((1e-6, 1800.0, 60), (0.03, 30.0, 30), (1e3, 300.0, 40))
NAMES = ("t0_rod", "t0_cone", "tau_rod", "tau_cone")
#: Thresholds above this (cd/m2) are not measured: the test is not seen.
CEILING = 1e8
#: Minkowski exponent pooling the rod and cone sensitivities.
POOLING = 4.0


def protocol(steps):
    """Frame luminances (cd/m2) and durations (s) of a stepped field.

    Each step holds its luminance for its duration, cut into frames whose
    starts lie at 0 and then geometrically from 10 ms to the end: fine
    sampling where adaptation is fast, coarse where it is slow. Returns
    ``(L, dt, since, segment)``, ``since`` the time since the step.
    """
    L, dt, since, segment = [], [], [], []
    for k, (lum, duration, count) in enumerate(steps):
        starts = np.concatenate([[0.0], np.geomspace(0.01, duration, count)])
        L.append(np.full(count, lum))
        dt.append(np.diff(starts))
        since.append(starts[:-1])
        segment.append(np.full(count, k))
    return tuple(np.concatenate(a) for a in (L, dt, since, segment))


def components(params, args):
    """log10 rod and cone sensitivities (1/(cd/m2)) at each frame."""
    L, dt, pre = args
    frames = jnp.broadcast_to(L[:, None, None, None], (L.shape[0], 1, 1, 3))
    state = op.static_state(params, pre, pre)
    _, diag = op.run(params, frames, dt, state=state)
    s = diag.state
    rod = increment_sensitivity(L, sigma_rod(s.A_rod, params.n), DELTA, s.B_rod, params.n)
    cone = increment_sensitivity(L, sigma_cone(s.A_cone, params.n), DELTA, s.B_cone, params.n)
    return rod, cone


def log_threshold(params, args):
    """log10 increment threshold (cd/m2) at each frame: the model fitted.

    ``args = (L, dt, pre)``. The rod and cone sensitivities are pooled by
    probability summation, ``(s_rod^4 + s_cone^4)^(1/4)`` (Quick's Minkowski
    form, exponent :data:`POOLING`): within 0.08 log units of the more
    sensitive system alone (the chapter's lower envelope of the two TVI
    curves), and smooth where they cross, which a least-squares solver needs
    (the bare minimum has a kink at the rod-cone break that stalls
    Levenberg-Marquardt). Capped at :data:`CEILING` where both are saturated.
    """
    rod, cone = components(params, args)
    pooled = rod**POOLING + cone**POOLING
    return -jnp.log10(jnp.maximum(pooled, CEILING**-POOLING)) / POOLING


def population(rng, count, spread=0.2):
    """``count`` observers: the paper's constants times log-normal factors."""
    base = op.Params()
    values = {
        name: float(getattr(base, name)) * np.exp(spread * rng.standard_normal(count))
        for name in NAMES
    }
    return values


def simulate(rng, values, args):
    """Noisy log10 thresholds of each observer ``(count, T)``; NaN where not seen."""
    truth = jax.vmap(lambda v: log_threshold(op.Params(**v), args))(
        {k: jnp.asarray(v) for k, v in values.items()}
    )
    data = np.asarray(truth) + NOISE * rng.standard_normal(truth.shape)
    return np.where(np.asarray(truth) >= np.log10(CEILING), np.nan, data)


def summarise(result, values, names):
    """Per parameter: median relative SE, share of fits identified, coverage of
    the 95 % intervals, median |error| relative to the truth."""
    out = {}
    converged = np.asarray(result.converged)
    for name in names:
        est, se = np.asarray(result.estimate[name]), np.asarray(result.se[name])
        truth = np.asarray(values[name]) if name in values else None
        row = {
            "median_relative_se": float(np.median(se / est)),
            "identified_fraction": float(np.mean(np.isfinite(se))),
        }
        if truth is not None:
            ok = np.isfinite(se)
            row["coverage_95"] = float(np.mean(np.abs(est - truth)[ok] <= 1.96 * se[ok]))
            row["median_abs_relative_error"] = float(np.median(np.abs(est / truth - 1)))
        out[name] = row
    out["converged_fraction"] = float(np.mean(converged))
    out["median_steps"] = float(np.median(np.asarray(result.steps)))
    corr = np.asarray(result.correlation)
    out["median_correlation"] = np.round(
        np.median(corr[converged] if converged.any() else corr, 0), 3
    ).tolist()
    return out


def main():
    args, out = setup("fit_time_constants", __doc__.splitlines()[0])
    count = 8 if args.smoke else 200
    scale = 3 if args.smoke else 1
    steps = tuple((lum, dur, n // scale) for lum, dur, n in STEPS)
    rng = np.random.default_rng(0)
    values = population(rng, count)
    start = op.Params()  # the paper's constants as the start of every fit
    designs = {
        "three steps": (steps, NAMES),
        "dark adaptation only": (steps[:1], NAMES),
        "three steps, c free": (steps, NAMES + ("c_rod", "c_cone")),
    }
    results, summaries, runs = {}, {}, {}
    for label, (design, names) in designs.items():
        L, dt, since, segment = protocol(design)
        model_args = (jnp.asarray(L), jnp.asarray(dt), jnp.asarray(PRE))
        data = simulate(np.random.default_rng(1), values, model_args)
        result = fitting.fit(log_threshold, start, names, data, args=model_args)
        results[label] = result
        runs[label] = (model_args, data, since, segment)
        summaries[label] = summarise(result, values, names)

    lines = []
    for label, summary in summaries.items():
        lines.append(f"{label}: {summary['converged_fraction']:.0%} of {count} fits converged")
        for name in designs[label][1]:
            row = summary[name]
            cover = f", 95% coverage {row['coverage_95']:.0%}" if "coverage_95" in row else ""
            lines.append(
                f"  {name:9s} median SE / estimate {row['median_relative_se']:8.3g}, "
                f"identified in {row['identified_fraction']:.0%}{cover}"
            )
    c_free = summaries["three steps, c free"]["median_correlation"]
    names_c = designs["three steps, c free"][1]
    pairs = [
        (abs(c_free[i][j]), names_c[i], names_c[j])
        for i in range(len(names_c))
        for j in range(i + 1, len(names_c))
    ]
    r, a, b = max(pairs)
    lines.append(f"strongest correlation with c free: {a} and {b}, |r| = {r:.3f}")
    text = "\n".join(lines)
    print(text)

    # -- figure -----------------------------------------------------------------
    fig = Figure(figsize=(15, 9))
    grid = fig.add_gridspec(2, 4)
    model_args, data, since, segment = runs["three steps"]
    fitted = results["three steps"]
    one = jax.tree.map(lambda a: a[0], fitted.params)
    rod, cone = (np.asarray(-jnp.log10(c)) for c in components(one, model_args))
    pred = np.asarray(fitted.prediction[0])
    titles = ("dark, after 1e6 cd/m$^2$", "step to 0.03 cd/m$^2$", "step to 1000 cd/m$^2$")
    for k in range(3):
        ax = fig.add_subplot(grid[0, k])
        sel = segment == k
        t = np.maximum(since[sel], 3e-3)  # the sample at the step itself, drawn at 3 ms
        ax.plot(t, data[0][sel], "o", ms=3, color="k", label="simulated thresholds")
        ax.plot(t, pred[sel], "-", color="C3", label="fit")
        ax.plot(t, np.where(np.isfinite(rod[sel]), rod[sel], np.nan), ":", color="C0", label="rods")
        ax.plot(t, cone[sel], "--", color="C1", label="cones")
        ax.set(
            xscale="log",
            xlabel="time since the step (s; the step itself at 3 ms)",
            ylabel="log$_{10}$ threshold (cd/m$^2$)",
            title=titles[k],
        )
        ax.set_ylim(np.nanmin(data[0][sel]) - 0.5, np.nanmax(data[0][sel]) + 0.5)
        if k == 0:
            ax.legend(fontsize=8)
    ax = fig.add_subplot(grid[0, 3])
    for i, name in enumerate(NAMES):
        truth = values[name] / float(getattr(op.Params(), name))
        est = np.asarray(fitted.estimate[name]) / float(getattr(op.Params(), name))
        se = np.asarray(fitted.se[name]) / float(getattr(op.Params(), name))
        ax.errorbar(truth, est, yerr=1.96 * se, fmt="o", ms=2, lw=0.5, color=f"C{i}", label=name)
    lim = (0.3, 2.2)
    ax.plot(lim, lim, color="grey", lw=0.5)
    ax.set(
        xlim=lim,
        ylim=lim,
        xlabel="true / paper's value",
        ylabel="estimate / paper's value (95% interval)",
        title="recovery, three steps",
    )
    ax.legend(fontsize=8)

    ax = fig.add_subplot(grid[1, :2])
    width = 0.8 / len(designs)
    all_names = names_c
    rels = {
        label: np.array([summary.get(n, {}).get("median_relative_se", np.nan) for n in all_names])
        for label, summary in summaries.items()
    }
    # A median SE of inf (not identified in most fits): a hatched bar, a
    # decade above every finite one, labelled.
    finite = [r for rel in rels.values() for r in rel if np.isfinite(r)]
    top = 10.0 ** (np.ceil(np.log10(max(finite + [1.0]))) + 1)
    for j, (label, rel) in enumerate(rels.items()):
        x = np.arange(len(all_names)) + j * width
        bars = ax.bar(x, np.where(np.isinf(rel), top, rel), width, label=label)
        for bar, r in zip(bars, rel, strict=True):
            if np.isinf(r):
                bar.set_hatch("//")
                ax.annotate(
                    "inf", (bar.get_x() + width / 2, top), ha="center", va="bottom", fontsize=7
                )
    ax.axhline(1.0, color="grey", lw=0.5)
    ax.set_xticks(np.arange(len(all_names)) + width, all_names)
    ax.set(
        yscale="log",
        ylabel="median SE / estimate",
        title="what the data pin down (hatched, 'inf': not identified in most fits)",
    )
    ax.legend(fontsize=8)
    ax = fig.add_subplot(grid[1, 2:])
    image = ax.imshow(np.asarray(c_free), vmin=-1, vmax=1, cmap="RdBu_r")
    ax.set_xticks(range(len(names_c)), names_c, rotation=45, fontsize=8)
    ax.set_yticks(range(len(names_c)), names_c, fontsize=8)
    ax.set_title("correlations, three steps, c free")
    fig.colorbar(image, ax=ax, shrink=0.8, label="correlation of the estimates (median)")
    fig.suptitle("Recovering t0 and tau from thresholds during dark and light adaptation")
    fig.tight_layout()
    fig.savefig(out / "fit_time_constants.png", dpi=100)

    with open(out / "estimates.csv", "w", newline="") as f:
        writer = csv_writer(f)
        writer.writerow(["design", "observer", "parameter", "true", "estimate", "se", "converged"])
        for label, result in results.items():
            for name in designs[label][1]:
                est, se = np.asarray(result.estimate[name]), np.asarray(result.se[name])
                truth = values.get(name, np.full(count, float(getattr(op.Params(), name))))
                for i in range(count):
                    writer.writerow(
                        [label, i, name, truth[i], est[i], se[i], bool(result.converged[i])]
                    )
    record = {"observers": count, "noise_log10": NOISE, "delta": DELTA, "designs": summaries}
    (out / "summary.json").write_text(json.dumps(record, indent=2) + "\n")
    print(f"wrote {out}/fit_time_constants.png")


if __name__ == "__main__":
    main()
