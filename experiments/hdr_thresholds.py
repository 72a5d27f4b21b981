"""Fig. 6.12 of the HDR-imaging chapter: thresholds derived from photoreceptor responses.

Top: the response of Eq 6.2 (cones, n = 0.73, Hunt's sigma) adapted to three
backgrounds L1, L2, L3 two log units apart, the response to each background
(*) and the increment dL_i that raises it by a fixed criterion dR, exactly
(from the inverse of Eq 6.2). Bottom, as in the chapter: these exact dL_i
(dots) against L, and the curve through them, drawn from the first-order
formula of §6.2.4 (:func:`~jaxadapt.physiology.threshold.increment_threshold`,
``dR`` times the slope of the inverse at ``R_b + dR``; the exact curve
dotted), and the n = 1, sigma_b = I_b case, whose thresholds follow Weber's
law. With dR = 0.02 the first-order formula overestimates the exact
increments by 5-10 %: 0.851, 30.06 and 1472 cd/m2 at 1, 100 and 1e4 cd/m2
against 0.776, 28.44 and 1406 (``python hdr_thresholds.py``). Writes
``thresholds.png`` and ``thresholds.csv`` (first-order and exact
thresholds, cd/m2, by background luminance).
"""

import jax.numpy as jnp
import numpy as np
from common import setup
from matplotlib.figure import Figure

from jaxadapt.io import csv_writer
from jaxadapt.physiology.response import N_HUNT, naka_rushton, naka_rushton_inverse, sigma_cone
from jaxadapt.physiology.threshold import increment_threshold

DELTA = 0.02  # criterion response, of R_max = 1


def exact_increment(L, delta=DELTA):
    """The increment (cd/m2) that raises the cone response of Eq 6.2 (n = 0.73,
    Hunt's sigma) adapted to ``L`` (cd/m2) by ``delta``: the inverse of Eq 6.2
    at ``R_b + delta``, less ``L``."""
    sigma = sigma_cone(L)
    R_b = naka_rushton(L, sigma, 1.0, N_HUNT)
    return naka_rushton_inverse(R_b + delta, sigma, 1.0, N_HUNT) - L


def main():
    args, out = setup("hdr_thresholds", __doc__.splitlines()[0])
    log_L = np.linspace(-3, 7, 41 if args.smoke else 401)
    L = jnp.asarray(10.0**log_L)
    backgrounds = 10.0 ** np.array([0.0, 2.0, 4.0])
    steps = np.asarray(exact_increment(jnp.asarray(backgrounds)))
    fig = Figure(figsize=(8, 9))
    top, bottom = fig.subplots(2, 1)
    for L_b, dL, colour in zip(backgrounds, steps, ("C0", "C1", "C2"), strict=True):
        sigma = sigma_cone(jnp.asarray(L_b))
        top.plot(log_L, np.asarray(naka_rushton(L, sigma, 1.0, N_HUNT)), color=colour)
        R_b = float(naka_rushton(L_b, sigma, 1.0, N_HUNT))
        top.plot(np.log10(L_b), R_b, "*", ms=12, color=colour)
        top.plot([np.log10(L_b), np.log10(L_b + dL)], [R_b + DELTA] * 2, color=colour, lw=3)
        top.annotate(f"$\\Delta L$ = {dL:.3g}", (np.log10(L_b + dL), R_b + DELTA), color=colour)
    top.set(
        xlabel="log$_{10}$ luminance (cd/m$^2$)",
        ylabel="response $R / R_{max}$",
        title=f"responses adapted to L = 1, 100, 1e4 cd/m$^2$ (criterion $\\Delta R$ = {DELTA})",
    )
    first_order = np.asarray(increment_threshold(L, sigma_cone(L), DELTA, 1.0, N_HUNT))
    exact = np.asarray(exact_increment(L))
    weber = np.asarray(increment_threshold(L, L, DELTA, 1.0, 1.0))
    bottom.plot(
        log_L,
        np.log10(first_order),
        label="n = 0.73, Hunt's $\\sigma_{cone}(L)$: first-order formula",
    )
    bottom.plot(log_L, np.log10(exact), ":", color="k", lw=1, label="the same, exact")
    bottom.plot(
        log_L,
        np.log10(weber),
        "--",
        label="n = 1, $\\sigma_b = I_b$: first-order formula, Weber's law",
    )
    bottom.plot(
        np.log10(backgrounds),
        np.log10(steps),
        "o",
        color="k",
        label="exact $\\Delta L_i$ at $L_1, L_2, L_3$",
    )
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
        writer = csv_writer(f)
        writer.writerow(
            [
                "L_cd_m2",
                "dL_hunt_first_order_cd_m2",
                "dL_hunt_exact_cd_m2",
                "dL_weber_first_order_cd_m2",
            ]
        )
        writer.writerows(zip(10.0**log_L, first_order, exact, weber, strict=True))
    print(f"wrote {out}/thresholds.png")
    print("exact dL_i:", *(f"{v:.4g}" for v in steps), "cd/m2")
    at_backgrounds = increment_threshold(
        jnp.asarray(backgrounds), sigma_cone(jnp.asarray(backgrounds)), DELTA, 1.0, N_HUNT
    )
    print("first-order dL_i:", *(f"{v:.4g}" for v in np.asarray(at_backgrounds)), "cd/m2")


if __name__ == "__main__":
    main()
