"""Local, time-dependent adaptation on the tunnel exit, against the global operator and pfstmo.

Three renderings of the drive out of the tunnel: the paper's global
operator (one adaptation state per frame); our local mode (a bilateral
background per pixel and a state per pixel advanced with the exact
kinetics); and pfstmo_pattanaik00 ``--local`` (Pattanaik and Yee's local
gain, which drops time dependence), when pfstmo is installed. Writes
``local_vs_global.png``.
"""

import numpy as np
from common import setup
from matplotlib.figure import Figure

from jaxadapt import display, peers, pipeline, scenes
from jaxadapt.operators import pattanaik2000 as op

#: Times shown, s: inside, nearing the exit, leaving, outside.
SHOWN_TIMES = (10.0, 12.0, 12.4, 12.8, 13.2, 14.0)


def render(params, source, shown):
    """Display frames (linear) at the frame indices ``shown``."""
    frames, _ = pipeline.collect(op, params, source, shown, size=48)
    return np.stack([frames[i] for i in sorted(shown)])


def main():
    args, out = setup("pattanaik_local", __doc__.splitlines()[0])
    width, height = (96, 54) if args.smoke else (320, 180)
    scene = scenes.tunnel_drive(width, height, duration=14.1)
    source = pipeline.from_scene(scene)
    shown = {int(round(t / scene.dt[0])) for t in SHOWN_TIMES}
    common = {"goal": scene.goal, "pixels_per_degree": scene.pixels_per_degree}
    rows = {
        "global (paper)": render(op.Params(**common), source, shown),
        "local, time-dependent (ours)": render(
            op.Params(**common, background="bilateral", background_scale=4.0), source, shown
        ),
    }
    if peers.pfstmo_available():
        frames = source.frames(np.array(sorted(shown)))
        rows["pfstmo --local (static)"], _ = peers.pfstmo_pattanaik00(frames, "--local")

    fig = Figure(figsize=(2.4 * len(shown), 1.6 * len(rows) + 0.4))
    axes = fig.subplots(len(rows), len(shown), squeeze=False)
    for r, (name, frames) in enumerate(rows.items()):
        for c, frame in enumerate(frames):
            ax = axes[r, c]
            ax.imshow(display.to_uint8(display.encode_srgb(frame)))
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(f"t = {SHOWN_TIMES[c]:.1f} s", fontsize=8)
        axes[r, 0].set_ylabel(name, fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "local_vs_global.png", dpi=110)
    print(f"wrote {out}/local_vs_global.png")


if __name__ == "__main__":
    main()
