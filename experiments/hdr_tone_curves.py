"""The photoreceptor family of tone curves (chapter 6, §6.3) on one HDR interior.

Tone-maps :func:`jaxadapt.scenes.interior_with_window` with every curve of
:data:`jaxadapt.operators.classic.TONE_CURVES` (default parameters), with the
global background (the log average) and with two local ones of
``hdr_halos.py`` (Durand and Dorsey's bilateral, and the variable-size
neighbourhood), and plots the curves themselves against log luminance at the
scene's log average. Schlick's curve is drawn with the global background
only: the chapter's form (§6.3) has ``sigma_b = (I_max - I) / p``, "as if
the value of every pixel served as the background intensity", so it does
not depend on I_b. (Its background-dependent variant, ``k > 0`` in
:class:`~jaxadapt.operators.classic.Schlick1994`, is Schlick's non-uniform
quantisation, which the chapter does not give.) Writes ``tone_curves.png``,
``curves.png`` and ``curves.csv``; the curves, in both, are display values
clipped to [0, 1], as :func:`~jaxadapt.operators.classic.tone_map` shows
them (Ward's JND mapping, unclipped, reaches 215 times display white at the
scene's 2e4 cd/m2 in a full run, ``python hdr_tone_curves.py``).
"""

import jax.numpy as jnp
import numpy as np
from common import setup
from hdr_halos import estimators
from matplotlib.figure import Figure

from jaxadapt.color import photopic_luminance
from jaxadapt.display import encode_srgb
from jaxadapt.io import csv_writer
from jaxadapt.operators import classic, goal
from jaxadapt.scenes import interior_with_window

#: Curves that do not depend on the background: drawn with the global one only.
WITHOUT_BACKGROUND = ("schlick1994",)


def main():
    args, out = setup("hdr_tone_curves", __doc__.splitlines()[0])
    scale = 0.25 if args.smoke else 1.0
    rgb, _ = interior_with_window(int(480 * scale), int(320 * scale))
    rgb = jnp.asarray(rgb)
    L = photopic_luminance(rgb)
    local = estimators(scale)
    backgrounds = {
        "global": None,
        "bilateral": local["bilateral (Durand-Dorsey)"](L),
        "adaptive": local["adaptive"](L),
    }
    curves = {name: make() for name, make in classic.TONE_CURVES.items()}

    fig = Figure(figsize=(3.2 * len(curves), 2.4 * len(backgrounds) + 0.6))
    axes = fig.subplots(len(backgrounds), len(curves))
    for row, (where, background) in zip(axes, backgrounds.items(), strict=True):
        for ax, (name, params) in zip(row, curves.items(), strict=True):
            ax.set_axis_off()
            if background is not None and name in WITHOUT_BACKGROUND:
                ax.text(0.5, 0.5, f"{name}: no $I_b$\n(as with the global one)", ha="center")
                continue
            shown = classic.tone_map(params, rgb, background)
            ax.imshow(np.asarray(encode_srgb(shown)), interpolation="nearest")
            ax.set_title(f"{name}, $I_b$ {where}", fontsize=9)
    fig.suptitle("The Eq 6.2 family of tone curves with a global and two local backgrounds")
    fig.tight_layout()
    fig.savefig(out / "tone_curves.png", dpi=90)

    # the curves themselves, at the scene's log average, up to its maximum
    I_b = float(goal.log_average(L))
    log_I = np.linspace(-1.0, np.log10(float(L.max())), 31 if args.smoke else 301)
    I = jnp.asarray(10.0**log_I)[None, :]  # one row: Schlick takes I_max from it
    values = {
        name: np.clip(np.asarray(p.curve(I, jnp.full_like(I, I_b)))[0], 0.0, 1.0)
        for name, p in curves.items()
    }
    fig = Figure(figsize=(8, 4.5))
    ax = fig.subplots()
    for name, v in values.items():
        ax.plot(log_I, v, label=name)
    ax.axvline(np.log10(I_b), color="grey", lw=0.5)
    ax.set(
        xlabel="log$_{10}$ luminance (cd/m$^2$)",
        ylabel="display value (linear, clipped to [0, 1])",
        title=f"tone curves at $I_b$ = {I_b:.1f} cd/m$^2$ (the scene's log average)",
    )
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "curves.png", dpi=100)
    with open(out / "curves.csv", "w", newline="") as f:
        writer = csv_writer(f)
        writer.writerow(["I_cd_m2", *values])
        writer.writerows(zip(10.0**log_I, *values.values(), strict=True))
    print(f"wrote {out}/tone_curves.png, curves.png, curves.csv")


if __name__ == "__main__":
    main()
