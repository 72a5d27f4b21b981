"""Pupil diameter against luminance: Moon and Spencer, and de Groot and Gebhard (chapter 6, §6.2.2).

Plots both formulas from 1e-6 to 1e6 cd/m2, with the 2-8 mm range the
chapter quotes, and the retinal illuminance (td) each pupil lets through.
Writes ``pupil.png`` and ``pupil.csv``.
"""

import jax.numpy as jnp
import numpy as np
from common import setup
from matplotlib.figure import Figure

from jaxadapt.io import csv_writer
from jaxadapt.physiology import pupil
from jaxadapt.physiology.threshold import trolands

LABELS = {"moon-spencer": "Moon and Spencer", "de-groot-gebhard": "de Groot and Gebhard"}


def main():
    args, out = setup("hdr_pupil", __doc__.splitlines()[0])
    log_L = np.linspace(-6, 6, 49 if args.smoke else 481)
    L = jnp.asarray(10.0**log_L)
    diameters = {name: np.asarray(f(L)) for name, f in pupil.DIAMETERS.items()}
    fig = Figure(figsize=(11, 4.5))
    ax, td = fig.subplots(1, 2)
    for name, d in diameters.items():
        ax.plot(log_L, d, label=LABELS[name])
        td.plot(log_L, np.log10(np.asarray(trolands(L, d))), label=LABELS[name])
    ax.axhspan(2.0, 8.0, color="grey", alpha=0.12, label="2-8 mm (chapter)")
    td.plot(log_L, log_L, "k:", lw=0.8, label="1 mm$^2$ pupil")
    ax.set(xlabel="log$_{10}$ luminance (cd/m$^2$)", ylabel="pupil diameter (mm)")
    td.set(xlabel="log$_{10}$ luminance (cd/m$^2$)", ylabel="log$_{10}$ retinal illuminance (td)")
    ax.legend()
    td.legend()
    fig.suptitle("Pupil diameter and retinal illuminance (HDR imaging ch. 6, §6.2.2)")
    fig.tight_layout()
    fig.savefig(out / "pupil.png", dpi=110)
    with open(out / "pupil.csv", "w", newline="") as f:
        writer = csv_writer(f)
        writer.writerow(["L_cd_m2", *(f"d_{name}_mm" for name in diameters)])
        writer.writerows(zip(10.0**log_L, *diameters.values(), strict=True))
    print(f"wrote {out}/pupil.png")


if __name__ == "__main__":
    main()
