"""Fig. 5 of Pattanaik et al. (2000): rod and cone responses at adaptation levels a decade apart.

For each adaptation luminance A (statically adapted: sigma from Eqs 4-5, B
from Eq 6) the response R = B L^n / (L^n + sigma^n) of Eq 2 is drawn against
log10 L, with, as in the paper's caption, a cross at the response to A
itself and a circle at the response to reference white, 5 A (§4.1.2,
Hunt's suggestion). The caption's levels read, in the extracted text,
"A_cone = A_rod = 2 10^5, 2 10^4, ..., 2 10^6, 2 10^7 cd/m2": a list that
falls and then rises, so the extraction lost the minus signs of its first
exponents; we read 2 10^k cd/m2 for k = -5 to 7, the same 13 levels for
rods and cones. Writes ``fig5_responses.png`` and ``fig5_responses.csv``.
"""

import jax.numpy as jnp
import matplotlib
import numpy as np
from common import setup
from matplotlib.figure import Figure

from jaxadapt.io import csv_writer
from jaxadapt.physiology.response import (
    bleach_cone,
    bleach_rod,
    naka_rushton,
    sigma_cone,
    sigma_rod,
)

RECEPTORS = {"rods": (sigma_rod, bleach_rod), "cones": (sigma_cone, bleach_cone)}

#: Adaptation levels of the caption, cd/m2: 2 10^k for k = -5 to 7.
LEVELS = np.array([2.0 * 10.0**k for k in range(-5, 8)])


def main():
    args, out = setup("pattanaik_fig5", __doc__.splitlines()[0])
    log_L = np.linspace(-8, 10, 91 if args.smoke else 721)
    fig = Figure(figsize=(12, 4.5))
    rows = []
    colours = matplotlib.colormaps["viridis"](np.linspace(0, 0.95, len(LEVELS)))
    for ax, (name, (sigma_of, bleach_of)) in zip(
        fig.subplots(1, 2), RECEPTORS.items(), strict=True
    ):
        for A, colour in zip(LEVELS, colours, strict=True):
            sigma, B = sigma_of(jnp.asarray(A)), bleach_of(jnp.asarray(A))
            R = np.asarray(naka_rushton(10.0 ** jnp.asarray(log_L), sigma, B))
            ax.plot(log_L, R, lw=1.2, color=colour, label=f"A = {A:.0e}")
            for L, marker in ((A, "x"), (5 * A, "o")):
                ax.plot(np.log10(L), float(naka_rushton(L, sigma, B)), marker, color=colour)
            rows.append((name, A, float(sigma), float(B), float(naka_rushton(5 * A, sigma, B))))
        ax.set(xlabel="log$_{10}$ luminance (cd/m$^2$)", ylabel="response R", title=name)
        ax.legend(fontsize=7, ncol=2)
    fig.suptitle(
        "Pattanaik et al. 2000, Fig. 5: responses at adaptation levels A a decade apart "
        "(x: response to A, o: to reference white, 5 A)"
    )
    fig.tight_layout()
    fig.savefig(out / "fig5_responses.png", dpi=110)
    with open(out / "fig5_responses.csv", "w", newline="") as f:
        writer = csv_writer(f)
        writer.writerow(["receptor", "A_cd_m2", "sigma_cd_m2", "B", "R_white"])
        writer.writerows(rows)
    print(f"wrote {out}/fig5_responses.png")


if __name__ == "__main__":
    main()
