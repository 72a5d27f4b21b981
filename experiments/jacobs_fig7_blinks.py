"""Bleaching afterimages after a blink (Jacobs et al. 2015, Fig. 7).

A viewer looks for a second at a ColorChecker lit to a white of 10^3 cd/m2
with a lamp in its middle, then shuts the eyes: the scene radiance drops to
zero and only the afterimage remains. The lamp is a disk of the scene's
maximum luminance, 10^3.5, 10^4.5 or 10^8.5 cd/m2 (the maxima of the
figure's three scenes; rows), in a glow whose log luminance falls linearly
to the chart's white, so that one scene spans several decades (the chart
alone spans 1.4, one bleaching regime: one colour at a time). Columns: the
scene as displayed just before the blink, then the afterimage t seconds
after it, fixation held at the centre. Bottom block: the same afterimages
scaled to a maximum of one, to show their colours. Writes ``blinks.png``
and prints the afterimage's hue 0.1 s after the blink by scene decade.

The paper notes "cyan, green, and pink elements in each afterimage". Here
(full run, hue of the mean linear colour) 0.1 s after the blink the
10^8.5 scene shows all three at once: cyan where it exceeded 10^8 cd/m2
(177 degrees; 164 at 10^7 to 10^8), green at 10^4 to 10^7 (106 to 142)
and pink below 10^4, over the chart and the glow's rim (344 to 355); the
10^4.5 scene shows yellow-green (87) above 10^4 and pink below (344 to
353), and the 10^3.5 scene pink only (344 to 347).
Green needs the M cones bleached and cyan the S cones too: after a second
at a uniform luminance, the hue 0.1 s after the blink passes 100 degrees
only from 10^4.5 cd/m2 and 160 from 10^7.5, so a scene whose maximum is
10^3.5 shows pink alone, unlike the paper's top row.
"""

import numpy as np
from common import setup
from jacobs_common import linear, run_scene, scaled_to_max
from matplotlib.colors import rgb_to_hsv
from matplotlib.figure import Figure

from jaxadapt import scenes
from jaxadapt.gaze import fixate
from jaxadapt.operators import jacobs2015 as op

LOG_LAMPS = (3.5, 4.5, 8.5)
CHART_WHITE = 1e3
EXPOSURE = 1.0
AFTER_BLINK = (0.1, 0.5, 1.0, 2.0, 4.0)
FIELD_DEG = 20.0
LAMP_DEG, GLOW_DEG = 0.75, 3.0


def lamp_and_chart(width, height, lamp, white=CHART_WHITE, field_deg=FIELD_DEG):
    """A ColorChecker of ``white`` cd/m2 spanning ``field_deg`` degrees across,
    with a lamp at its centre: ``lamp`` cd/m2 within ``LAMP_DEG`` degrees,
    then a glow whose log luminance falls linearly to ``white`` at
    ``GLOW_DEG`` degrees. Linear BT.709 RGB, cd/m2, ``(height, width, 3)``."""
    ppd = width / field_deg
    y, x = np.mgrid[:height, :width]
    r = np.hypot(x - (width - 1) / 2.0, y - (height - 1) / 2.0) / ppd
    u = np.clip((r - LAMP_DEG) / (GLOW_DEG - LAMP_DEG), 0.0, 1.0)
    glow = lamp ** (1.0 - u) * white**u
    chart = scenes.colorchecker_image(width, height, white)
    return np.where((r < GLOW_DEG)[..., None], glow[..., None], chart)


def blink(image, fps, exposure=EXPOSURE, after=4.1, field_deg=FIELD_DEG):
    """A :class:`~jaxadapt.scenes.Scene` of ``image`` (cd/m2) for ``exposure``
    s, then ``after`` s of darkness, fixated at the centre."""
    height, width = image.shape[:2]
    count = int(round((exposure + after) * fps))
    times = np.arange(count) / fps
    image = image.astype(np.float32)

    def render(t):
        lit = np.asarray(t) < exposure - 1e-9
        return image[None] * lit[:, None, None, None].astype(np.float32)

    gaze = fixate((width - 1) / 2.0, (height - 1) / 2.0)
    dt = np.full(count, 1.0 / fps)
    return scenes.Scene(
        "blink", times, dt, render, gaze, "foveal", None, width / field_deg, (height, width)
    )


def hues_by_decade(afterimage, scene, params):
    """Hue (degrees, HSV of the mean linear colour) of a display frame
    ``afterimage`` over the pixels where ``scene`` (cd/m2, ``(H, W, 3)``) had
    a photopic luminance in each whole decade: ``{decade: hue}``."""
    lin = linear(afterimage, params)
    decade = np.floor(np.log10(np.maximum(scene @ np.asarray(params.w_P), 1e-12))).astype(int)
    return {int(d): float(rgb_to_hsv(lin[decade == d].mean(0))[0] * 360) for d in np.unique(decade)}


def main():
    args, out = setup("jacobs_fig7_blinks", __doc__.splitlines()[0])
    width, height, fps = (48, 32, 15.0) if args.smoke else (144, 96, 30.0)
    params = op.Params(acuity=False, dithering=False)
    columns = [-1 / fps] + list(AFTER_BLINK)
    shown, scaled = [], []
    for log_lamp in LOG_LAMPS:
        image = lamp_and_chart(width, height, 10.0**log_lamp)
        display, _ = run_scene(blink(image, fps), params)
        picks = [int(round((EXPOSURE + t) * fps)) for t in columns]
        hues = hues_by_decade(display[picks[1]], image, params)
        listed = ", ".join(f"10^{d}: {h:.0f}" for d, h in sorted(hues.items()))
        print(f"lamp 10^{log_lamp:g}, t = {AFTER_BLINK[0]:g} s, hue by scene decade: {listed}")
        shown.append(display[picks])
        scaled.append(scaled_to_max(display[picks], params, axis=(1, 2, 3)))
    fig = Figure(figsize=(2.0 * len(columns), 1.5 * 2 * len(LOG_LAMPS) + 0.6))
    axes = fig.subplots(2 * len(LOG_LAMPS), len(columns), squeeze=False)
    for block, images in enumerate((shown, scaled)):
        for r, row in enumerate(images):
            for c, image in enumerate(row):
                ax = axes[block * len(LOG_LAMPS) + r, c]
                ax.imshow(np.clip(image, 0, 1))
                ax.set_xticks([])
                ax.set_yticks([])
                if block == 0 and r == 0:
                    ax.set_title(
                        "before the blink" if c == 0 else f"t = {columns[c]:g} s", fontsize=8
                    )
            label = f"lamp $10^{{{LOG_LAMPS[r]:g}}}$" + (" (scaled)" if block else "")
            axes[block * len(LOG_LAMPS) + r, 0].set_ylabel(label, fontsize=8)
    fig.suptitle("Afterimages after shutting the eyes (Jacobs et al. 2015, Fig. 7)", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "blinks.png", dpi=110)
    print(f"wrote {out}/blinks.png")


if __name__ == "__main__":
    main()
