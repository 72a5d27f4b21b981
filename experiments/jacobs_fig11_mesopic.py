"""A ColorChecker at decreasing luminance, mean pixel value held constant (Jacobs 2015, Fig. 11).

The chart (with a fine test pattern in its middle) rendered with all the
mesopic cues (Purkinje shift, hue shift and desaturation towards a dull
purple, stochastic acuity loss) for a white of 100 down to 0.001 cd/m2;
each rendering is scaled to the same mean linear display value as the
brightest, as in the paper, so that only the cues tell the light level.
Bottom row: the test pattern enlarged 4x, where the acuity loss shows.
Writes ``mesopic.png``.
"""

import jax
import jax.numpy as jnp
import numpy as np
from common import setup
from jacobs_common import linear, scaled_to_mean
from matplotlib.figure import Figure

from jaxadapt import scenes
from jaxadapt.operators import jacobs2015 as op

WHITES = (100.0, 1.0, 0.3, 0.1, 0.03, 0.01, 1e-3)


def chart(width, height, white):
    """The ColorChecker with a patch of one-pixel stripes and checks in the middle."""
    image = scenes.colorchecker_image(width, height, white)
    cy, cx, r = height // 2, width // 2, height // 8
    y, x = np.mgrid[-r:r, -r:r]
    pattern = np.where(x < 0, (y // 1) % 2, (x // 2 + y // 2) % 2).astype(float)
    image[cy - r : cy + r, cx - r : cx + r] = 0.9 * white * pattern[..., None]
    return image, (slice(cy - r, cy + r), slice(cx - r, cx + r))


def main():
    args, out = setup("jacobs_fig11_mesopic", __doc__.splitlines()[0])
    width, height = (144, 96) if args.smoke else (384, 256)
    params = op.Params(bleaching=False, local_adaptation=False, dithering=False)
    renders, insets = [], []
    for white in WHITES:
        image, inset = chart(width, height, white)
        frames = jnp.asarray(image, jnp.float32)[None]
        display, _ = op.run(params, frames, 1 / 30, key=jax.random.key(1))
        renders.append(display[0])
        insets.append(inset)
    target = linear(renders[0], params).mean()
    fig = Figure(figsize=(2.6 * len(WHITES), 4.4))
    axes = fig.subplots(2, len(WHITES), squeeze=False, height_ratios=(2, 1.3))
    for k, (white, render, inset) in enumerate(zip(WHITES, renders, insets, strict=True)):
        shown = scaled_to_mean(render, params, target)
        axes[0, k].imshow(shown, interpolation="nearest")
        axes[0, k].set_title(f"white {white:g} cd/m$^2$", fontsize=9)
        axes[1, k].imshow(shown[inset].repeat(4, 0).repeat(4, 1), interpolation="nearest")
        for ax in axes[:, k]:
            ax.axis("off")
    fig.suptitle("Mesopic cues at constant mean pixel value (Jacobs et al. 2015, Fig. 11)")
    fig.tight_layout()
    fig.savefig(out / "mesopic.png", dpi=100)
    print(f"wrote {out}/mesopic.png")


if __name__ == "__main__":
    main()
