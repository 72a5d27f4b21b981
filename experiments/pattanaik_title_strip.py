"""The title-page strip of Pattanaik et al. (2000): moonlight to sunlight in 30 ms frames.

A ColorChecker seen by a viewer statically adapted to moonlight (goal 0.01
cd/m2) is suddenly lit to a 1000 cd/m2 goal. The frame after the step is
almost entirely white; in the frames that follow the chart re-emerges, as
in the paper, by "rapid retinal network adaptation": the cones' neural
filter (t0 = 80 ms) brings A_cone within 1 % of the goal in 0.4 s. The
rods' pigment helps: at 1000 cd/m2 it bleaches at ``G/c_rod = 62`` /s,
B_rod falling from 0.8 to 1e-4 in 0.18 s, which takes the saturated rods'
response out of the frames (with both pigments frozen the frames at 60 to
120 ms are 7 to 9 sRGB codes brighter on average, up to 26). The cones'
pigment plays no visible part: with tau = 110 s and a static B_cone of
0.9995 at 1000 cd/m2 it moves by less than 1e-4 in the 4 s shown
(``diagnostics.csv``). The strip's frames lie in the first half second.
Writes ``title_strip.png`` (frames at chosen times), ``adaptation.png``
and ``diagnostics.csv``.
"""

from common import setup
from matplotlib.figure import Figure

from jaxadapt import display, figures, io, pipeline, scenes
from jaxadapt.operators import pattanaik2000 as op

#: Times shown in the strip, s after the first (moonlit) frame.
STRIP_TIMES = (0.0, 0.03, 0.06, 0.09, 0.12, 0.18, 0.24, 0.36, 0.51)


def main():
    args, out = setup("pattanaik_title_strip", __doc__.splitlines()[0])
    width, height = (96, 64) if args.smoke else (288, 192)
    scene = scenes.title_step(width, height, duration=4.02)
    source = pipeline.from_scene(scene)
    params = op.Params(goal=scene.goal)
    shown = {int(round(t / 0.03)) for t in STRIP_TIMES}
    linear, table = pipeline.collect(op, params, source, shown, size=64)
    frames = {i: display.to_uint8(display.encode_srgb(f)) for i, f in linear.items()}

    fig = Figure(figsize=(2.2 * len(frames), 2.2))
    for ax, i in zip(fig.subplots(1, len(frames)), sorted(frames), strict=True):
        ax.imshow(frames[i])
        ax.set_axis_off()
        ax.set_title(f"t = {scene.times[i]:.2f} s\nG = {table['G_cone'][i]:.3g}", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "title_strip.png", dpi=110)
    figures.plot_adaptation(
        out / "adaptation.png",
        table,
        "title-page step, Pattanaik et al. 2000",
        op.CURVE_LOG10_LUMINANCE,
    )
    io.write_columns(out / "diagnostics.csv", table)
    print(f"wrote {out}/title_strip.png")


if __name__ == "__main__":
    main()
