"""Figures: the adaptation plot under the paper's Fig. 7 and contact sheets.

Used by the command line and by the scripts in ``experiments/``. The
diagnostics come as a dict of numpy columns (``t``, ``G_rod``, ``A_cone``,
..., ``curve``), as the command line gathers them chunk by chunk.

Figures are drawn with matplotlib's object-oriented API (no pyplot), so
that writing one changes no global backend state.
"""

import matplotlib
import numpy as np
from matplotlib.figure import Figure

from jaxadapt.operators.pattanaik2000 import CURVE_LOG10_LUMINANCE


def plot_adaptation(path, diag, title):
    """Adaptation state over time and the scene-to-display curve at a few times."""
    t = diag["t"]
    fig = Figure(figsize=(15, 4.2))
    axes = fig.subplots(1, 3)
    ax = axes[0]
    for name, style in (("G_cone", "C1:"), ("A_cone", "C1-"), ("G_rod", "C0:"), ("A_rod", "C0-")):
        ax.semilogy(t, diag[name], style, label=name)
    ax.set(xlabel="time (s)", ylabel="cd/m$^2$", title="goal G and neural adaptation A")
    ax.legend()
    ax = axes[1]
    ax.semilogy(t, diag["B_cone"], "C1", label="B_cone")
    ax.semilogy(t, diag["B_rod"], "C0", label="B_rod")
    ax.set(xlabel="time (s)", ylabel="unbleached fraction", title="pigment B")
    ax.legend()
    ax = axes[2]
    picks = np.unique(np.linspace(0, len(t) - 1, 8).round().astype(int))
    colors = matplotlib.colormaps["viridis"](np.linspace(0, 1, len(picks)))
    for c, i in zip(colors, picks, strict=True):
        ax.plot(
            np.asarray(CURVE_LOG10_LUMINANCE), diag["curve"][i], color=c, label=f"t={t[i]:.2f} s"
        )
    ax.set(
        xlabel="scene luminance (log$_{10}$ cd/m$^2$)",
        ylabel="display value (linear)",
        title="scene-to-display curve",
    )
    ax.legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def contact_sheet(frames, columns=4):
    """Tile uint8 frames ``(K, H, W, 3)`` into one image, with white gutters."""
    K, H, W, _ = frames.shape
    rows = -(-K // columns)
    sheet = np.full((rows * (H + 4) + 4, columns * (W + 4) + 4, 3), 255, np.uint8)
    for k in range(K):
        r, c = divmod(k, columns)
        sheet[4 + r * (H + 4) : 4 + r * (H + 4) + H, 4 + c * (W + 4) : 4 + c * (W + 4) + W] = (
            frames[k]
        )
    return sheet


def plot_columns(path, table, title):
    """Every per-frame column of a diagnostics table against time, one panel each.

    For operators whose diagnostics are not the 2000 operator's (the 2015
    renderer's state at the gaze point, the static curves' background). A
    positive column spanning more than two decades is drawn on a log scale.
    """
    t = table["t"]
    columns = [name for name, column in table.items() if name != "t" and column.ndim == 1]
    ncols = min(4, len(columns))
    nrows = -(-len(columns) // ncols)
    fig = Figure(figsize=(3.6 * ncols, 2.6 * nrows + 0.5))
    axes = np.atleast_1d(fig.subplots(nrows, ncols)).ravel()
    for ax, name in zip(axes, columns, strict=False):
        column = table[name]
        wide = np.all(column > 0) and column.max() > 100 * column.min()
        ax.plot(t, column)
        ax.set(xlabel="time (s)", title=name, yscale="log" if wide else "linear")
    for ax in axes[len(columns) :]:
        ax.set_axis_off()
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
