"""Bleaching afterimage colour over time for flashes of 1e3 to 1e7 cd/m2 (Jacobs 2015, Fig. 5).

For each flash luminance, a 1/8 s white flash over the fixation point, then
darkness; each row shows the display colour at the fixation point against
the time since the flash ended. Top: the colour scaled to a maximum channel
of one (hue and saturation); bottom: as displayed (brightness too). The
maps are not blurred between frames (§2.4), as in the paper's figure. Writes
``flash_colours.png``.
"""

import numpy as np
from common import setup
from jacobs_common import run_scene, scaled_to_max
from matplotlib.figure import Figure

from jaxadapt import scenes
from jaxadapt.operators import jacobs2015 as op

LOG_LUMINANCES = (3.0, 4.0, 4.5, 5.0, 6.0, 7.0)


def main():
    args, out = setup("jacobs_fig5_flash_colours", __doc__.splitlines()[0])
    fps, after = (15.0, 2.0) if args.smoke else (30.0, 8.0)
    onset, length = 0.25, 0.125
    params = op.Params(acuity=False, dithering=False, afterimage_blur=0.0)
    rows = []
    for log_L in LOG_LUMINANCES:
        scene = scenes.flash(
            16,
            16,
            duration=onset + length + after,
            fps=fps,
            luminance=10.0**log_L,
            onset=onset,
            flash_duration=length,
        )
        display, _ = run_scene(scene, params)
        after_flash = scene.times >= onset + length - 1e-9
        rows.append(display[after_flash, 8, 8])
    shown = np.stack(rows)
    hue = scaled_to_max(shown, params, axis=-1)
    fig = Figure(figsize=(9, 6))
    axes = fig.subplots(2, 1)
    extent = (0, after, len(LOG_LUMINANCES) - 0.5, -0.5)
    for ax, image, title in zip(
        axes, (hue, shown), ("hue (maximum channel = 1)", "as displayed"), strict=True
    ):
        ax.imshow(np.clip(image, 0, 1), aspect="auto", extent=extent, interpolation="nearest")
        ax.set_yticks(
            range(len(LOG_LUMINANCES)), [f"$10^{{{v:g}}}$ cd/m$^2$" for v in LOG_LUMINANCES]
        )
        ax.set(xlabel="time since the end of the flash (s)", title=title)
    fig.suptitle("Bleaching afterimage colours (Jacobs et al. 2015, Fig. 5)")
    fig.tight_layout()
    fig.savefig(out / "flash_colours.png", dpi=110)
    print(f"wrote {out}/flash_colours.png")


if __name__ == "__main__":
    main()
