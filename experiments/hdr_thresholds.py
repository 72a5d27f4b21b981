"""Fig. 6.12 of the HDR-imaging chapter: thresholds derived from photoreceptor responses.

Top: the response of Eq 6.2 (cones, n = 0.73, Hunt's sigma) adapted to three
backgrounds L1, L2, L3 two log units apart, the response to each background
(*) and the increment dL_i that raises it by a fixed criterion dR. Bottom:
dL against L from the derivation of §6.2.4, the three dots, and the n = 1,
sigma_b = I_b case, whose thresholds follow Weber's law. Writes
``thresholds.png`` and ``thresholds.csv``.
"""

import csv

import jax.numpy as jnp
import numpy as np
from common import setup
from matplotlib.figure import Figure

from jaxadapt.physiology.response import N_HUNT, naka_rushton, naka_rushton_inverse, sigma_cone
from jaxadapt.physiology.threshold import increment_threshold

DELTA = 0.02  # criterion response, of R_max = 1


def main():
    args, out = setup("hdr_thresholds", __doc__.splitlines()[0])
    log_L = np.linspace(-3, 7, 41 if args.smoke else 401)
    L = jnp.asarray(10.0**log_L)
    backgrounds = 10.0 ** np.array([0.0, 2.0, 4.0])
    fig = Figure(figsize=(8, 9))
    top, bottom = fig.subplots(2, 1)
    for L_b, colour in zip(backgrounds, ("C0", "C1", "C2"), strict=True):
        sigma = sigma_cone(jnp.asarray(L_b))
        top.plot(log_L, np.asarray(naka_rushton(L, sigma, 1.0, N_HUNT)), color=colour)
        R_b = float(naka_rushton(L_b, sigma, 1.0, N_HUNT))
        L_up = float(naka_rushton_inverse(R_b + DELTA, sigma, 1.0, N_HUNT))
        top.plot(np.log10(L_b), R_b, "*", ms=12, color=colour)
        top.plot([np.log10(L_b), np.log10(L_up)], [R_b + DELTA] * 2, color=colour, lw=3)
        top.annotate(
            f"exact $\\Delta L$ = {L_up - L_b:.3g}", (np.log10(L_up), R_b + DELTA), color=colour
        )
    top.set(
        xlabel="log$_{10}$ luminance (cd/m$^2$)",
        ylabel="response $R / R_{max}$",
        title=f"responses adapted to L = 1, 100, 1e4 cd/m$^2$ (criterion $\\Delta R$ = {DELTA})",
    )
    hunt = np.asarray(increment_threshold(L, sigma_cone(L), DELTA, 1.0, N_HUNT))
    weber = np.asarray(increment_threshold(L, L, DELTA, 1.0, 1.0))
    bottom.plot(log_L, np.log10(hunt), label="n = 0.73, Hunt's $\\sigma_{cone}(L)$")
    bottom.plot(log_L, np.log10(weber), "--", label="n = 1, $\\sigma_b = I_b$: Weber's law")
    dots = np.asarray(
        increment_threshold(jnp.asarray(backgrounds), sigma_cone(backgrounds), DELTA, 1.0, N_HUNT)
    )
    bottom.plot(np.log10(backgrounds), np.log10(dots), "o", color="k", label="$L_1, L_2, L_3$")
    bottom.set(
        xlabel="log$_{10}$ background luminance (cd/m$^2$)",
        ylabel="log$_{10}$ threshold $\\Delta L$ (cd/m$^2$)",
        title="thresholds derived from the responses (§6.2.4)",
    )
    bottom.legend()
    fig.suptitle("HDR imaging ch. 6, Fig. 6.12: the response-threshold relation")
    fig.tight_layout()
    fig.savefig(out / "thresholds.png", dpi=110)
    with open(out / "thresholds.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["L_cd_m2", "dL_hunt_cd_m2", "dL_weber_cd_m2"])
        writer.writerows(zip(10.0**log_L, hunt, weber, strict=True))
    print(f"wrote {out}/thresholds.png")


if __name__ == "__main__":
    main()
