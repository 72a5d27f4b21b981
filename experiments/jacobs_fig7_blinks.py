"""Bleaching afterimages after a blink (Jacobs et al. 2015, Fig. 7).

A viewer looks at a ColorChecker for a second, then shuts the eyes: the
scene radiance drops to zero and only the afterimage remains. Rows: the
chart's white at about 10^3.5, 10^4.5 and 10^8.5 cd/m2 (the three scenes of
the figure); columns: the scene as displayed just before the blink, then
the afterimage t seconds after it, fixation held at the centre. Bottom
block: the same afterimages scaled to a maximum of one, to show their
colours. Writes ``blinks.png``.
"""

import jax
import jax.numpy as jnp
import numpy as np
from common import setup
from jacobs_common import linear
from matplotlib.figure import Figure

from jaxadapt.operators import jacobs2015 as op
from jaxadapt.scenes import colorchecker_image

LOG_WHITES = (3.5, 4.5, 8.5)
AFTER_BLINK = (0.1, 0.5, 1.0, 2.0, 4.0)


def blink_sequence(width, height, white, fps, exposure=1.0, after=4.1):
    """The chart at ``white`` cd/m2 for ``exposure`` s, then darkness."""
    chart = colorchecker_image(width, height, white).astype(np.float32)
    n_on, n_off = int(round(exposure * fps)), int(round(after * fps))
    return np.concatenate(
        [np.repeat(chart[None], n_on, 0), np.zeros((n_off,) + chart.shape, np.float32)]
    )


def main():
    args, out = setup("jacobs_fig7_blinks", __doc__.splitlines()[0])
    width, height, fps = (48, 32, 15.0) if args.smoke else (144, 96, 30.0)
    params = op.Params(acuity=False, dithering=False, pixels_per_degree=width / 20.0)
    columns = [-1 / fps] + list(AFTER_BLINK)
    shown, scaled = [], []
    for log_white in LOG_WHITES:
        frames = blink_sequence(width, height, 10.0**log_white, fps)
        display, _ = op.run(params, jnp.asarray(frames), 1 / fps, key=jax.random.key(0))
        blink = int(round(1.0 * fps))
        picks = [blink + int(round(t * fps)) for t in columns]
        row = np.asarray(display)[picks]
        shown.append(row)
        lin = linear(row, params)
        scaled.append(
            (lin / np.maximum(lin.max(axis=(1, 2, 3), keepdims=True), 1e-12)) ** float(params.gamma)
        )
    fig = Figure(figsize=(2.0 * len(columns), 1.5 * 2 * len(LOG_WHITES) + 0.6))
    axes = fig.subplots(2 * len(LOG_WHITES), len(columns), squeeze=False)
    for block, images in enumerate((shown, scaled)):
        for r, row in enumerate(images):
            for c, image in enumerate(row):
                ax = axes[block * len(LOG_WHITES) + r, c]
                ax.imshow(np.clip(image, 0, 1))
                ax.set_xticks([])
                ax.set_yticks([])
                if block == 0 and r == 0:
                    ax.set_title(
                        "before the blink" if c == 0 else f"t = {columns[c]:g} s", fontsize=8
                    )
            label = f"$10^{{{LOG_WHITES[r]:g}}}$" + (" (scaled)" if block else "")
            axes[block * len(LOG_WHITES) + r, 0].set_ylabel(label, fontsize=8)
    fig.suptitle("Afterimages after shutting the eyes (Jacobs et al. 2015, Fig. 7)", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "blinks.png", dpi=110)
    print(f"wrote {out}/blinks.png")


if __name__ == "__main__":
    main()
