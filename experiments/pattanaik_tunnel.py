"""The tunnel drive of Pattanaik et al. (2000), Fig. 7: frames with their tone curves.

Driving at 90 km/h on a sunny day into an unlit highway tunnel (road 5000
cd/m2 outside, 5 cd/m2 inside), the gaze on the road 40 m ahead. Under each
chosen frame, its scene-to-display curve (display value of a neutral scene
luminance) shows the adaptation state, as the graphs under Fig. 7 do.
Writes ``tunnel_fig7.png``, ``adaptation.png`` and ``diagnostics.csv``.
"""

import numpy as np
from common import setup
from matplotlib.figure import Figure

from jaxadapt import display, figures, io, pipeline, scenes
from jaxadapt.operators import pattanaik2000 as op

#: Times shown, s. At 25 m/s the fovea (1 degree about the gaze, 40 m
#: ahead) slides into the mouth from 1.4 to 3.0 s: the goal falls from 3800
#: to 6 cd/m2, and the cones' adaptation lags it most (A = 2.7 G) at 2.8 s.
#: It reaches the exit from 11.6 to 13.2 s (A = 0.52 G at 12.8 s). The car
#: itself enters at 4.0 s and leaves at 14.0 s (full-size run's
#: ``diagnostics.csv``). Approach; the black mouth; the temporary
#: blindness and the recovery; inside; the glaring exit; out.
SHOWN_TIMES = (1.0, 2.2, 2.6, 2.8, 3.1, 4.5, 12.4, 12.7, 12.9, 14.5)


def main():
    args, out = setup("pattanaik_tunnel", __doc__.splitlines()[0])
    width, height = (96, 54) if args.smoke else (480, 270)
    scene = scenes.tunnel_drive(width, height, duration=16.0)
    source = pipeline.from_scene(scene)
    params = op.Params(goal=scene.goal, pixels_per_degree=scene.pixels_per_degree)
    fps = 1.0 / scene.dt[0]
    shown = {int(round(t * fps)) for t in SHOWN_TIMES}
    linear, table = pipeline.collect(op, params, source, shown, size=48)
    frames = {i: display.to_uint8(display.encode_srgb(f)) for i, f in linear.items()}

    fig = Figure(figsize=(2.6 * len(frames), 4.6))
    axes = fig.subplots(2, len(frames), height_ratios=(1, 1))
    for (top, bottom), i in zip(axes.T, sorted(frames), strict=True):
        top.imshow(frames[i])
        top.set_axis_off()
        top.set_title(
            f"t = {scene.times[i]:.1f} s\nG = {table['G_cone'][i]:.3g} cd/m$^2$", fontsize=8
        )
        bottom.plot(np.asarray(op.CURVE_LOG10_LUMINANCE), table["curve"][i])
        bottom.axvline(np.log10(table["A_cone"][i]), color="C1", lw=0.8, ls=":")
        bottom.set(xlim=(-2, 6), ylim=(-0.02, 1.02))
        bottom.set_xlabel("log$_{10}$ scene cd/m$^2$", fontsize=7)
        bottom.tick_params(labelsize=7)
    axes[1, 0].set_ylabel("display value", fontsize=7)
    fig.suptitle(
        "Tunnel drive (Pattanaik et al. 2000, Fig. 7): frames and scene-to-display "
        "curves (dotted: cone adaptation A)",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(out / "tunnel_fig7.png", dpi=110)
    figures.plot_adaptation(
        out / "adaptation.png",
        table,
        "tunnel drive, Pattanaik et al. 2000",
        op.CURVE_LOG10_LUMINANCE,
    )
    io.write_columns(out / "diagnostics.csv", table)
    print(f"wrote {out}/tunnel_fig7.png")


if __name__ == "__main__":
    main()
