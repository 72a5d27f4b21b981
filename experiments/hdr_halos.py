"""Figs. 6.14-6.16 of the HDR-imaging chapter: halos of local averages, and edge-preserving ones.

The HDR interior of :func:`jaxadapt.scenes.interior_with_window` (a room at
1.7-52 cd/m2 with a window onto a sunlit street at up to 2e4 cd/m2) is
reduced to a background luminance I_b by each estimator of
:data:`jaxadapt.background.BACKGROUNDS`. Writes

* ``backgrounds.png`` (Fig. 6.16): the scene linearly scaled, and the
  backgrounds on one log scale;
* ``tone_mapped.png`` (Figs. 6.14, 6.15): Eq 6.2 with each local I_b;
* ``profile.png``: log luminance and backgrounds along a row through the window;
* ``halos.csv``: the halo of each estimator by side of the window's edge.

The halo of a side (the room, or the sky and facade) is the mean
``|log10(I_b / I_b')|`` over its pixels within ``BAND`` pixels of the edge,
where ``I_b'`` is the same estimator applied to that region on its own (the
image with every other pixel replaced by the region's nearest one): the
part of I_b that comes from across the edge. A background that does not
cross the edge (I_b = L, for one) scores 0, whatever the texture inside the
region.

Full run (``python hdr_halos.py``), room side / outside, log10 units:
global 0.357 / 1.948, box 1.252 / 0.231, gaussian 1.403 / 0.231, bilateral
(Pattanaik-Yee) 0.008 / 0.002, bilateral (Durand-Dorsey) 0.023 / 0.003,
adaptive 0.012 / 0.014, multiscale 1.070 / 0.230. The edge-preserving
backgrounds stay within 0.025 log units of their region's own; the box and
Gaussian ones raise the room side's by 1.25-1.4 log units (Fig. 6.14's dark
band), and the multiscale one, whose coarse levels cross the edge, by 1.07.
"""

import functools

import jax.numpy as jnp
import numpy as np
from common import setup
from matplotlib.figure import Figure
from scipy import ndimage

from jaxadapt import background
from jaxadapt.color import photopic_luminance
from jaxadapt.display import encode_srgb
from jaxadapt.io import csv_writer
from jaxadapt.operators import classic
from jaxadapt.scenes import OUTSIDE, ROOM, interior_with_window

#: Width of the bands on either side of the window's edge, pixels at full size.
BAND = 12


def estimators(scale):
    """The backgrounds compared, with sizes for an image ``scale`` times 480x320.

    Box and Gaussian: ``s`` = 16 pixels at full size; bilateral: 8. The
    adaptive and multiscale stacks start at the pixel (``s`` = 1) and double
    their size over 8 levels (up to 128 pixels) at full size: one level
    fewer per halving of the image, so their largest size scales with it.
    """
    s = max(1.0, 16.0 * scale)
    levels = max(2, 8 + round(np.log2(scale)))
    return {
        "global": background.global_background,
        "box": functools.partial(background.box_background, scale=s),
        "gaussian": functools.partial(background.gaussian_background, scale=s),
        "bilateral (Pattanaik-Yee)": functools.partial(
            background.bilateral_background, scale=s / 2, kind="pattanaik-yee"
        ),
        "bilateral (Durand-Dorsey)": functools.partial(
            background.bilateral_background, scale=s / 2
        ),
        "adaptive": functools.partial(background.adaptive_background, levels=levels),
        "multiscale": functools.partial(background.multiscale_background, levels=levels),
    }


def edge_bands(labels, width):
    """Masks of the room and outside pixels within ``width`` pixels of the window's edge."""
    outside = labels != ROOM
    near = np.zeros_like(outside)
    for dy in range(-width, width + 1):
        for dx in range(-width, width + 1):
            near |= np.roll(outside, (dy, dx), axis=(0, 1)) != outside
    return near & (labels == ROOM), near & (labels == OUTSIDE)


def region_alone(L, region):
    """``L`` (cd/m2) with every pixel outside the mask ``region`` replaced by
    the nearest pixel inside it: the region on its own, meeting no edge."""
    nearest = ndimage.distance_transform_edt(~region, return_distances=False, return_indices=True)
    return L[tuple(nearest)]


def halo(background, alone, band):
    """Mean ``|log10(background / alone)|`` over the mask ``band``, log10 units.

    ``background`` and ``alone`` are one estimator's I_b (cd/m2) of the
    scene and of the band's region on its own (:func:`region_alone`).
    """
    return float(np.mean(np.abs(np.log10(background[band] / alone[band]))))


def main():
    args, out = setup("hdr_halos", __doc__.splitlines()[0])
    scale = 0.25 if args.smoke else 1.0
    width, height = int(480 * scale), int(320 * scale)
    rgb, labels = interior_with_window(width, height)
    L = np.asarray(photopic_luminance(rgb))
    backgrounds = {name: np.asarray(f(jnp.asarray(L))) for name, f in estimators(scale).items()}
    lo, hi = np.log10(L.min()), np.log10(L.max())

    # Fig. 6.16: the backgrounds
    fig = Figure(figsize=(16, 6.4))
    axes = fig.subplots(2, 4).ravel()
    axes[0].imshow(encode_srgb(rgb / rgb.max()), interpolation="nearest")
    axes[0].set_title("scene, linearly scaled")
    for ax, (name, b) in zip(axes[1:], backgrounds.items(), strict=True):
        ax.imshow((np.log10(b) - lo) / (hi - lo), cmap="gray", vmin=0, vmax=1)
        ax.set_title(f"$I_b$: {name}")
    for ax in axes:
        ax.set_axis_off()
    fig.suptitle(f"Fig. 6.16: background luminance, log scale 10^{lo:.1f}-10^{hi:.1f} cd/m$^2$")
    fig.tight_layout()
    fig.savefig(out / "backgrounds.png", dpi=90)

    # Figs. 6.14 and 6.15: Eq 6.2 with each background
    curve = classic.Photographic(a=1.0)
    fig = Figure(figsize=(16, 6.4))
    axes = fig.subplots(2, 4).ravel()
    axes[0].imshow(np.log10(L / L.min()) / (hi - lo), cmap="gray", vmin=0, vmax=1)
    axes[0].set_title("log luminance")
    for ax, (name, b) in zip(axes[1:], backgrounds.items(), strict=True):
        shown = classic.tone_map(curve, jnp.asarray(rgb), jnp.asarray(b))
        ax.imshow(np.asarray(encode_srgb(shown)), interpolation="nearest")
        ax.set_title(f"Eq 6.2, $I_b$: {name}")
    for ax in axes:
        ax.set_axis_off()
    fig.suptitle("Figs. 6.14-6.15: R = I / (I + I_b), halos where I_b crosses the window's edge")
    fig.tight_layout()
    fig.savefig(out / "tone_mapped.png", dpi=90)

    # a profile through the window, and the halo measure
    row = int(0.5 * height)
    fig = Figure(figsize=(10, 4.5))
    ax = fig.subplots()
    ax.plot(np.log10(L[row]), "k", lw=2, label="luminance")
    for name, b in backgrounds.items():
        ax.plot(np.log10(b[row]), lw=1, label=name)
    ax.set(xlabel="column (pixels)", ylabel="log$_{10}$ cd/m$^2$", title=f"row {row}")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "profile.png", dpi=100)
    room, outside = edge_bands(labels, max(1, int(BAND * scale)))
    sides = {"room": (labels == ROOM, room), "outside": (labels == OUTSIDE, outside)}
    alone = {side: jnp.asarray(region_alone(L, region)) for side, (region, _) in sides.items()}
    with open(out / "halos.csv", "w", newline="") as f:
        writer = csv_writer(f)
        writer.writerow(["estimator", "halo_room_side_log10", "halo_outside_side_log10"])
        for name, estimate in estimators(scale).items():
            halos = [
                halo(backgrounds[name], np.asarray(estimate(alone[side])), band)
                for side, (_, band) in sides.items()
            ]
            writer.writerow([name, *halos])
    print(f"wrote {out}/backgrounds.png, tone_mapped.png, profile.png, halos.csv")


if __name__ == "__main__":
    main()
