"""The Purkinje shift on a ColorChecker in mesopic light (Jacobs 2015, Fig. 10).

Columns: the chart rendered without mesopic cues; the luminance channel of
the rendering without the Purkinje shift; and with it (Eq 13, rho from the
local luminance, clamped to [0, 1]). Rows: the chart's white at 100, 0.1
and 0.01 cd/m2. Each row's linear display values (``J^(1/gamma)``) are
scaled by one factor that gives its no-cue rendering a mean of 0.3, so
that rows can be compared; the largest scaled value is then 0.82 to 0.83
(printed), so nothing clips. Blue patches brighten and red ones darken as
light falls. Writes ``purkinje.png``.
"""

import dataclasses

import jax.numpy as jnp
import numpy as np
from common import setup
from jacobs_common import encode, linear
from matplotlib.figure import Figure

from jaxadapt import scenes
from jaxadapt.operators import jacobs2015 as op

WHITES = (100.0, 0.1, 0.01)
MEAN = 0.3


def main():
    args, out = setup("jacobs_fig10_purkinje", __doc__.splitlines()[0])
    width, height = (120, 80) if args.smoke else (360, 240)
    bare = op.only()
    purkinje = dataclasses.replace(bare, purkinje=True)
    fig = Figure(figsize=(12, 2.9 * len(WHITES)))
    axes = fig.subplots(len(WHITES), 3, squeeze=False)
    for row, white in zip(axes, WHITES, strict=True):
        frames = jnp.asarray(scenes.colorchecker_image(width, height, white), jnp.float32)[None]
        plain, _ = op.run(bare, frames, 1 / 30)
        shifted, _ = op.run(purkinje, frames, 1 / 30)
        plain, shifted = linear(plain[0], bare), linear(shifted[0], bare)
        scale = MEAN / plain.mean()
        colour = plain * scale
        lum_off = (plain @ np.asarray(bare.w_P)) * scale
        lum_on = (shifted @ np.asarray(bare.w_P)) * scale
        print(
            f"white {white:g} cd/m2: largest scaled linear value {colour.max():.3f}, "
            f"luminance {lum_off.max():.3f} (Purkinje {lum_on.max():.3f})"
        )
        panels = (
            (colour, "no mesopic cues"),
            (lum_off, "luminance"),
            (lum_on, "luminance with the Purkinje shift"),
        )
        for ax, (image, title) in zip(row, panels, strict=True):
            ax.imshow(encode(image, bare), cmap="gray", vmin=0, vmax=1, interpolation="nearest")
            ax.set_title(f"white {white:g} cd/m$^2$: {title}", fontsize=9)
            ax.axis("off")
    fig.suptitle("Purkinje shift (Jacobs et al. 2015, Fig. 10)")
    fig.tight_layout()
    fig.savefig(out / "purkinje.png", dpi=90)
    print(f"wrote {out}/purkinje.png")


if __name__ == "__main__":
    main()
