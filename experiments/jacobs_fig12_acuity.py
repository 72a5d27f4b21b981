"""Stochastic loss of acuity over time (Jacobs 2015, Fig. 12).

A resolution chart (bars 1 to 8 pixels wide, periods 2 to 16 pixels, finest
at the top; and a radial star) at 0.3 cd/m2 (bars and spokes 0.015 and
0.285 cd/m2), in the upper mesopic range, rendered with the acuity loss
alone at 30 frames per second. Top row: frames 0.2 s apart (scaled to a
common mean for display); bottom row: where each frame lost detail, the
absolute difference from the chart rendered without acuity loss. Patches
of detail come and go, the finest first: prints, per frame, the contrast
each bar width keeps (standard deviation of the linear display value over
its rows, relative to the chart rendered without acuity loss). In the full
run the 1-pixel bars keep 3 % to 28 % of it over the second, the 8-pixel
bars 72 % to 80 %. Writes ``acuity.png``.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from common import setup
from jacobs_common import linear, scaled_to_mean
from matplotlib.figure import Figure

from jaxadapt.operators import jacobs2015 as op


def resolution_chart(size):
    """Bars 1 to 8 pixels wide (periods 2 to 16; top half) and a 36-spoke
    star (bottom), ``(size, size)`` values in [0.05, 0.95]."""
    y, x = np.mgrid[:size, :size]
    bars = ((x // (1 + (16 * y) // size)) % 2).astype(float)
    angle = np.arctan2(y - 0.75 * size, x - size / 2)
    star = (np.sin(36 * angle) > 0).astype(float)
    return np.where(y < size // 2, bars, star) * 0.9 + 0.05


def contrast_kept(lin, sharp, size):
    """Per bar width 1 to 8 pixels: the standard deviation of the linear
    display values ``lin`` of a frame (grey, ``(size, size)``) over those
    bars' rows, over that of the frame rendered without acuity loss
    ``sharp``."""
    width = 1 + (16 * np.arange(size // 2)) // size
    return [
        float(lin[: size // 2][width == w].std() / sharp[: size // 2][width == w].std())
        for w in range(1, 9)
    ]


def main():
    args, out = setup("jacobs_fig12_acuity", __doc__.splitlines()[0])
    size, count, step = (64, 4, 6) if args.smoke else (192, 6, 6)
    luminance = 0.3
    chart = resolution_chart(size)[..., None] * np.ones(3) * luminance
    frames = jnp.broadcast_to(jnp.asarray(chart, jnp.float32), (count * step, size, size, 3))
    base = op.only("acuity")
    display, _ = op.run(base, frames, 1 / 30, key=jax.random.key(0))
    sharp, _ = op.run(dataclasses.replace(base, acuity=False), frames[:1], 1 / 30)
    sharp = linear(sharp[0], base)
    fig = Figure(figsize=(2.6 * count, 5.6))
    axes = fig.subplots(2, count, squeeze=False)
    for k in range(count):
        lin = linear(display[k * step], base)
        axes[0, k].imshow(scaled_to_mean(display[k * step], base, 0.4))
        axes[0, k].set_title(f"t = {k * step / 30:.1f} s", fontsize=9)
        kept = contrast_kept(lin.mean(-1), sharp.mean(-1), size)
        print(f"t = {k * step / 30:.1f} s, contrast kept by bars 1-8 px wide:", np.round(kept, 2))
        loss = np.abs(lin - sharp).mean(-1)
        axes[1, k].imshow(loss, cmap="magma", vmin=0, vmax=sharp.mean())
        axes[1, k].set_title("detail lost", fontsize=9)
        for ax in axes[:, k]:
            ax.axis("off")
    fig.suptitle(f"Stochastic acuity loss at {luminance:g} cd/m$^2$ (Jacobs et al. 2015, Fig. 12)")
    fig.tight_layout()
    fig.savefig(out / "acuity.png", dpi=100)
    print(f"wrote {out}/acuity.png")


if __name__ == "__main__":
    main()
