"""Figs. 6.14-6.16 of the HDR-imaging chapter: halos of local averages, and edge-preserving ones.

A synthetic HDR interior (a room at about 10-50 cd/m2 with a window onto a
sunlit street at up to 2e4 cd/m2) is reduced to a background luminance I_b
by each estimator of :data:`jaxadapt.operators.goal.BACKGROUNDS`. Writes

* ``backgrounds.png`` (Fig. 6.16): the scene linearly scaled, and the
  backgrounds on one log scale;
* ``tone_mapped.png`` (Figs. 6.14, 6.15): Eq 6.2 with each local I_b;
* ``profile.png``: log luminance and backgrounds along a row through the window;
* ``halos.csv``: the halo of each estimator, the mean |log10(I_b / L)| over
  the pixels within ``BAND`` pixels of the window's edge, by side, where L is
  the median luminance of the pixel's own region.
"""

import csv
import functools

import jax.numpy as jnp
import numpy as np
from common import setup
from matplotlib.figure import Figure

from jaxadapt.color import W_PHOTOPIC
from jaxadapt.display import encode_srgb
from jaxadapt.operators import classic, goal

#: Width of the bands on either side of the window's edge, pixels at full size.
BAND = 12

ROOM, OUTSIDE, FRAME = 0, 1, 2


def _colour(luminance, tint):
    """Linear RGB of luminance ``luminance`` (cd/m2) and chromaticity ``tint``."""
    tint = np.asarray(tint, dtype=np.float64)
    return luminance[..., None] * tint / (tint @ W_PHOTOPIC)


def interior_with_window(width=480, height=320):
    """A room with a window onto a sunlit street, linear BT.709 RGB in cd/m2.

    The room is lit from the window (about 80 cd/m2 on a white surface near
    it, 30 at the far wall) and holds a striped wall, a floor, a dark
    cabinet and a picture; through the window, a sky at 6000 cd/m2 and a
    sunlit brick facade at up to 2e4 cd/m2 with a shaded part, behind a
    dark frame. Sizes scale with the image.

    Returns
    -------
    rgb : numpy array, shape (height, width, 3)
    labels : numpy array, shape (height, width)
        ``ROOM`` (0), ``OUTSIDE`` (1) or ``FRAME`` (2).
    """
    fy, fx = np.mgrid[0:height, 0:width] / np.array([height, width])[:, None, None]
    # the room: illumination from the window times reflectance
    light = 30.0 + 50.0 * fx
    reflectance = 0.6 * (1.0 + 0.1 * np.sin(2 * np.pi * 40 * fx))
    floor = fy > 0.75
    reflectance = np.where(floor, 0.25 * (1.0 + 0.15 * np.sin(2 * np.pi * 12 * fy)), reflectance)
    cabinet = (fx > 0.06) & (fx < 0.3) & (fy > 0.45) & (fy < 0.85)
    reflectance = np.where(cabinet, 0.05, reflectance)
    picture = (fx > 0.12) & (fx < 0.36) & (fy > 0.15) & (fy < 0.35)
    reflectance = np.where(
        picture, 0.2 + 0.6 * (np.sin(30 * fx) * np.sin(25 * fy)) ** 2, reflectance
    )
    rgb = _colour(light * reflectance, (1.0, 0.9, 0.75))
    labels = np.full((height, width), ROOM)
    # the window: sky above, a sunlit facade with a shaded part below
    window = (fx > 0.5) & (fx < 0.88) & (fy > 0.12) & (fy < 0.62)
    sky = window & (fy < 0.3)
    bricks = 0.8 + 0.2 * (
        (np.floor(fy * 60) + np.floor(fx * 25 + 0.5 * (np.floor(fy * 60) % 2))) % 2
    )
    facade = np.where(fx < 0.6, 1500.0, 2.0e4) * bricks
    rgb = np.where(sky[..., None], _colour(6000.0 - 4000.0 * fy, (0.7, 0.85, 1.2)), rgb)
    rgb = np.where((window & ~sky)[..., None], _colour(facade, (1.1, 0.95, 0.8)), rgb)
    labels = np.where(window, OUTSIDE, labels)
    # the window frame and mullions, dark against the light
    frame = window & (
        (np.abs(fx - 0.69) < 0.006)
        | (np.abs(fy - 0.36) < 0.008)
        | (fx < 0.508)
        | (fx > 0.872)
        | (fy < 0.132)
        | (fy > 0.608)
    )
    rgb = np.where(frame[..., None], _colour(np.full_like(fx, 15.0), (1.0, 0.95, 0.9)), rgb)
    labels = np.where(frame, FRAME, labels)
    return rgb.astype(np.float32), labels


def estimators(scale):
    """The backgrounds compared, with sizes for an image ``scale`` times 480x320."""
    s = max(1.0, 16.0 * scale)
    return {
        "global": goal.global_background,
        "box": functools.partial(goal.box_background, scale=s),
        "gaussian": functools.partial(goal.gaussian_background, scale=s),
        "bilateral (Pattanaik-Yee)": functools.partial(
            goal.bilateral_background, scale=s / 2, kind="pattanaik-yee"
        ),
        "bilateral (Durand-Dorsey)": functools.partial(goal.bilateral_background, scale=s / 2),
        "adaptive": goal.adaptive_background,
        "multiscale": goal.multiscale_background,
    }


def edge_bands(labels, width):
    """Masks of the room and outside pixels within ``width`` pixels of the window's edge."""
    outside = labels != ROOM
    near = np.zeros_like(outside)
    for dy in range(-width, width + 1):
        for dx in range(-width, width + 1):
            near |= np.roll(outside, (dy, dx), axis=(0, 1)) != outside
    return near & (labels == ROOM), near & (labels == OUTSIDE)


def halo(background, L, labels, mask):
    """Mean |log10(I_b / median L of the region)| over ``mask``."""
    region = np.zeros_like(L)
    for label in (ROOM, OUTSIDE, FRAME):
        region[labels == label] = np.median(L[labels == label])
    return float(np.mean(np.abs(np.log10(background[mask] / region[mask]))))


def main():
    args, out = setup("hdr_halos", __doc__.splitlines()[0])
    scale = 0.25 if args.smoke else 1.0
    width, height = int(480 * scale), int(320 * scale)
    rgb, labels = interior_with_window(width, height)
    L = np.asarray(rgb @ W_PHOTOPIC.astype(np.float32))
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
    with open(out / "halos.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["estimator", "halo_room_side_log10", "halo_outside_side_log10"])
        for name, b in backgrounds.items():
            writer.writerow([name, halo(b, L, labels, room), halo(b, L, labels, outside)])
    print(f"wrote {out}/backgrounds.png, tone_mapped.png, profile.png, halos.csv")


if __name__ == "__main__":
    main()
