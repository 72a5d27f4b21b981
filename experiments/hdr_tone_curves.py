"""The photoreceptor family of tone curves (chapter 6, §6.3) on one HDR interior.

Tone-maps the interior of ``hdr_halos.py`` with every curve of
:data:`jaxadapt.operators.classic.TONE_CURVES` (default parameters), with the
global background (the log average) and with two local ones (bilateral, and
the variable-size neighbourhood), and plots the curves themselves against
log luminance at the scene's log average. Writes ``tone_curves.png``,
``curves.png`` and ``curves.csv``.
"""

import csv

import jax.numpy as jnp
import numpy as np
from common import setup
from hdr_halos import interior_with_window
from matplotlib.figure import Figure

from jaxadapt.color import W_PHOTOPIC
from jaxadapt.display import encode_srgb
from jaxadapt.operators import classic, goal


def main():
    args, out = setup("hdr_tone_curves", __doc__.splitlines()[0])
    scale = 0.25 if args.smoke else 1.0
    rgb, _ = interior_with_window(int(480 * scale), int(320 * scale))
    rgb = jnp.asarray(rgb)
    L = rgb @ jnp.asarray(W_PHOTOPIC, dtype=rgb.dtype)
    backgrounds = {
        "global": None,
        "bilateral": goal.bilateral_background(L, scale=max(1.0, 8.0 * scale)),
        "adaptive": goal.adaptive_background(L),
    }
    curves = {name: make() for name, make in classic.TONE_CURVES.items()}

    fig = Figure(figsize=(3.2 * len(curves), 2.4 * len(backgrounds) + 0.6))
    axes = fig.subplots(len(backgrounds), len(curves))
    for row, (where, background) in zip(axes, backgrounds.items(), strict=True):
        for ax, (name, params) in zip(row, curves.items(), strict=True):
            shown = classic.tone_map(params, rgb, background)
            ax.imshow(np.asarray(encode_srgb(shown)), interpolation="nearest")
            ax.set_title(f"{name}, $I_b$ {where}", fontsize=9)
            ax.set_axis_off()
    fig.suptitle("The Eq 6.2 family of tone curves with a global and two local backgrounds")
    fig.tight_layout()
    fig.savefig(out / "tone_curves.png", dpi=90)

    # the curves themselves, at the scene's log average, up to its maximum
    I_b = float(goal.log_average(L))
    log_I = np.linspace(-1.0, np.log10(float(L.max())), 31 if args.smoke else 301)
    I = jnp.asarray(10.0**log_I)[None, :]  # one row: Schlick takes I_max from it
    values = {name: np.asarray(p.curve(I, jnp.full_like(I, I_b)))[0] for name, p in curves.items()}
    fig = Figure(figsize=(8, 4.5))
    ax = fig.subplots()
    for name, v in values.items():
        ax.plot(log_I, np.clip(v, 0, 1), label=name)
    ax.axvline(np.log10(I_b), color="grey", lw=0.5)
    ax.set(
        xlabel="log$_{10}$ luminance (cd/m$^2$)",
        ylabel="display value (linear)",
        title=f"tone curves at $I_b$ = {I_b:.1f} cd/m$^2$ (the scene's log average)",
    )
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "curves.png", dpi=100)
    with open(out / "curves.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["I_cd_m2", *values])
        writer.writerows(zip(10.0**log_I, *values.values(), strict=True))
    print(f"wrote {out}/tone_curves.png, curves.png, curves.csv")


if __name__ == "__main__":
    main()
