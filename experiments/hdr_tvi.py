"""Fig. 6.7 of the HDR-imaging chapter: the rod and cone TVI curves of Rushton and MacLeod.

Plots log10 threshold against log10 background retinal illuminance (td) for
``dI = 0.1 (I + 0.015)`` (rods, solid) and ``dI = 0.02 (I + 8)`` (cones,
dashed), the lower envelope that vision follows, and, on the right, the same
thresholds as Weber fractions ``dI / I``. Writes ``tvi.png`` and ``tvi.csv``.
"""

import jax.numpy as jnp
import numpy as np
from common import setup
from matplotlib.figure import Figure
from scipy.optimize import brentq

from jaxadapt.io import csv_writer
from jaxadapt.physiology.threshold import tvi_cone, tvi_rod, tvi_rod_cone


def rod_cone_crossing(lo=1e-4, hi=1e6):
    """The background (td) at which the rod and cone thresholds are equal,
    found by a root solve between ``lo`` and ``hi`` td (1.98 td)."""
    return brentq(lambda I: float(tvi_rod(I) - tvi_cone(I)), lo, hi, xtol=1e-12)


def main():
    args, out = setup("hdr_tvi", __doc__.splitlines()[0])
    log_I = np.linspace(-4, 6, 41 if args.smoke else 401)
    I = jnp.asarray(10.0**log_I)
    curves = {"rods": tvi_rod(I), "cones": tvi_cone(I), "envelope": tvi_rod_cone(I)}
    fig = Figure(figsize=(11, 4.5))
    ax, weber = fig.subplots(1, 2)
    for (name, dI), style in zip(curves.items(), ("-", "--", ":"), strict=True):
        dI = np.asarray(dI)
        ax.plot(log_I, np.log10(dI), style, lw=2 if name != "envelope" else 1, label=name)
        weber.plot(log_I, np.log10(dI / 10.0**log_I), style, label=name)
    crossing = rod_cone_crossing()
    ax.axvline(np.log10(crossing), color="grey", lw=0.5)
    ax.set(
        xlabel="log$_{10}$ background $I_b$ (td)",
        ylabel="log$_{10}$ threshold $\\Delta I_b$ (td)",
        title="TVI (Rushton and MacLeod)",
    )
    weber.set(
        xlabel="log$_{10}$ background $I_b$ (td)",
        ylabel="log$_{10}$ Weber fraction $\\Delta I_b / I_b$",
        title="Weber fractions: 10 % (rods), 2 % (cones)",
    )
    ax.legend()
    weber.legend()
    fig.suptitle(f"HDR imaging ch. 6, Fig. 6.7: rods and cones cross at {crossing:.2f} td")
    fig.tight_layout()
    fig.savefig(out / "tvi.png", dpi=110)
    with open(out / "tvi.csv", "w", newline="") as f:
        writer = csv_writer(f)
        writer.writerow(["I_b_td", "dI_rod_td", "dI_cone_td", "dI_envelope_td"])
        writer.writerows(zip(10.0**log_I, *(np.asarray(c) for c in curves.values()), strict=True))
    print(f"wrote {out}/tvi.png")


if __name__ == "__main__":
    main()
