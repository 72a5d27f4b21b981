"""Local-adaptation afterimages after a fixation and a saccade (Jacobs 2015, Figs. 3 b-d and 9).

The checkerboard and the coloured patches of Fig. 3: the viewer fixates the
stimulus (left) for 5 s, then saccades to the uniform field (right). Columns:
the frame just before the saccade, 0.1 s and 1 s after it, and the right
half 0.1 s after with its contrast stretched 10x about its mean so that the
faint afterimage shows. Rows: with the full model, and with local
adaptation switched off. Writes ``adaptation_afterimages.png``.
"""

import dataclasses

import numpy as np
from common import setup
from jacobs_common import encode, linear, run_scene
from matplotlib.figure import Figure

from jaxadapt import scenes
from jaxadapt.operators import jacobs2015 as op


def stretch(display, params, gain=10.0):
    """Contrast of a display region stretched ``gain`` times about its mean."""
    lin = linear(display, params)
    return encode(lin.mean() + gain * (lin - lin.mean()), params)


def main():
    args, out = setup("jacobs_fig9_adaptation_afterimages", __doc__.splitlines()[0])
    size = dict(width=128, height=64, fps=10.0) if args.smoke else dict(width=384, height=192)
    full = op.Params(dithering=False)
    models = {
        "full model": full,
        "no local adaptation": dataclasses.replace(full, local_adaptation=False),
    }
    stimuli = {"checkerboard": scenes.checkerboard, "coloured patches": scenes.patches}
    fig = Figure(figsize=(16, 3.2 * len(stimuli) * len(models)))
    axes = fig.subplots(len(stimuli) * len(models), 4, squeeze=False)
    row = 0
    for stimulus, make in stimuli.items():
        scene = make(duration=6.5, fixation=5.0, **size)
        saccade = int(np.searchsorted(scene.times, 5.0))
        fps = 1.0 / scene.dt[0]
        for model, params in models.items():
            display, _ = run_scene(scene, params)
            half = display.shape[2] // 2
            after = saccade + max(1, int(round(0.1 * fps)))
            panels = (
                (display[saccade - 1], "before the saccade"),
                (display[after], "0.1 s after"),
                (display[saccade + int(round(1.0 * fps))], "1 s after"),
                (stretch(display[after, :, half:], params), "right half, contrast x10"),
            )
            for ax, (image, title) in zip(axes[row], panels, strict=True):
                ax.imshow(np.clip(image, 0, 1), interpolation="nearest")
                ax.set_title(f"{stimulus}, {model}: {title}", fontsize=9)
                ax.axis("off")
            row += 1
    fig.suptitle("Adaptation afterimages (Jacobs et al. 2015, Figs. 3 and 9)")
    fig.tight_layout()
    fig.savefig(out / "adaptation_afterimages.png", dpi=90)
    print(f"wrote {out}/adaptation_afterimages.png")


if __name__ == "__main__":
    main()
