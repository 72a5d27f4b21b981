"""L, M and S cone bleaching after a 1/8 s, 1e7 cd/m2 white flash (Jacobs 2015, Fig. 4).

Runs the flash scene through the 2015 operator and plots the bleached
fraction of each cone type at the fixation point against the time since
the flash ended (without the blur of the maps between frames, §2.4, which
would mix in the unbleached surround: the kinetics of Eqs 4-6 alone).
Writes ``bleaching.png`` and ``bleaching.csv``.
"""

import numpy as np
from common import setup
from jacobs_common import run_scene
from matplotlib.figure import Figure

from jaxadapt import scenes
from jaxadapt.io import csv_writer
from jaxadapt.operators import jacobs2015 as op


def main():
    args, out = setup("jacobs_fig4_bleaching", __doc__.splitlines()[0])
    fps, after = (30.0, 2.0) if args.smoke else (120.0, 8.0)
    onset, length = 0.25, 0.125
    scene = scenes.flash(
        16,
        16,
        duration=onset + length + after,
        fps=fps,
        luminance=1e7,
        onset=onset,
        flash_duration=length,
    )
    _, diag = run_scene(scene, op.Params(acuity=False, dithering=False, afterimage_blur=0.0))
    t = scene.times - (onset + length)
    B = np.asarray(diag.B_gaze)
    fig = Figure(figsize=(6.5, 4))
    ax = fig.subplots()
    for k, (name, colour) in enumerate(
        zip("LMS", ("tab:red", "tab:green", "tab:blue"), strict=True)
    ):
        ax.plot(t, B[:, k], color=colour, label=f"{name} cones")
    ax.axvspan(-length, 0, color="gold", alpha=0.3, label="flash, 1e7 cd/m$^2$")
    ax.set(
        xlabel="time since the end of the flash (s)",
        ylabel="bleached fraction B",
        xlim=(-0.3, after),
        ylim=(0, 1.02),
    )
    ax.legend()
    ax.set_title("Cone bleaching after a white flash (Jacobs et al. 2015, Fig. 4)")
    fig.tight_layout()
    fig.savefig(out / "bleaching.png", dpi=110)
    with open(out / "bleaching.csv", "w", newline="") as f:
        writer = csv_writer(f)
        writer.writerow(["t_s", "B_L", "B_M", "B_S"])
        writer.writerows(zip(t, *B.T, strict=True))
    print(f"wrote {out}/bleaching.png")


if __name__ == "__main__":
    main()
