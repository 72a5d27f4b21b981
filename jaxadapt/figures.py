"""Figures: the adaptation plot under the paper's Fig. 7 and contact sheets.

Used by the command line and by the scripts in ``experiments/``. The
diagnostics come as a dict of numpy columns (``t``, ``G_rod``, ``A_cone``,
..., ``curve``), as the command line gathers them chunk by chunk.

Figures are drawn with matplotlib's object-oriented API (no pyplot), so
that writing one changes no global backend state.
"""

import contextlib
import functools

import matplotlib
import numpy as np
from matplotlib.figure import Figure

from jaxadapt._checks import check_whole

__all__ = [
    "curve_frames",
    "plot_adaptation",
    "CONTACT_WIDTH",
    "shrink",
    "spread_frames",
    "LABEL_HEIGHT",
    "contact_sheet",
    "plot_columns",
    "MAX_PANELS",
    "plot_psychometric",
    "plot_pse",
]


def _marker(t):
    """A point marker for a time series of one frame, where a line draws nothing."""
    return "o" if len(t) == 1 else None


def curve_frames(diag, count=8):
    """Indices of up to ``count`` frames at which to draw the scene-to-display
    curve: evenly spaced along a progress that is half time and half the
    change of adaptation (the summed ``|Delta log10 A|`` of rods and cones),
    so that a transient of a fraction of a second in a long sequence (the
    step on the title page, a tunnel's mouth) gets curves of its own, and a
    steady sequence gets them evenly in time."""
    t = np.asarray(diag["t"], float)
    if t.size == 0:
        raise ValueError("diag: expected at least one frame, got none")
    log_A = [np.log10(np.maximum(np.asarray(diag[k], float), 1e-30)) for k in ("A_rod", "A_cone")]
    change = np.concatenate([[0.0], np.cumsum(sum(np.abs(np.diff(a)) for a in log_A))])
    parts = [p / p[-1] for p in (t - t[0], change) if p[-1] > 0]
    if not parts:  # one frame, or frames at one time without change
        return np.array([0])
    progress = sum(parts) / len(parts)
    return np.unique(np.searchsorted(progress, np.linspace(0.0, 1.0, count) - 1e-12))


def plot_adaptation(path, diag, title, curve_log10_luminance):
    """Adaptation state over time and the scene-to-display curve at a few times.

    ``diag`` holds the columns of ``pattanaik2000.diagnostics_table``; its
    ``curve`` column is the display value at the scene luminances
    ``10**curve_log10_luminance`` cd/m2 (``pattanaik2000.CURVE_LOG10_LUMINANCE``),
    passed in so that figures depend on no operator.
    """
    t = diag["t"]
    marker = _marker(t)
    fig = Figure(figsize=(15, 4.2))
    axes = fig.subplots(1, 3)
    ax = axes[0]
    for name, style in (("G_cone", "C1:"), ("A_cone", "C1-"), ("G_rod", "C0:"), ("A_rod", "C0-")):
        ax.semilogy(t, diag[name], style, marker=marker, label=name)
    ax.set(xlabel="time (s)", ylabel="cd/m$^2$", title="goal G and neural adaptation A")
    ax.legend()
    ax = axes[1]
    ax.semilogy(t, diag["B_cone"], "C1", marker=marker, label="B_cone")
    ax.semilogy(t, diag["B_rod"], "C0", marker=marker, label="B_rod")
    ax.set(xlabel="time (s)", ylabel="unbleached fraction", title="pigment B")
    ax.legend()
    ax = axes[2]
    picks = curve_frames(diag)
    colors = matplotlib.colormaps["viridis"](np.linspace(0, 1, len(picks)))
    for c, i in zip(colors, picks, strict=True):
        ax.plot(
            np.asarray(curve_log10_luminance), diag["curve"][i], color=c, label=f"t={t[i]:.2f} s"
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


#: The widest frame of a contact sheet, pixels (:func:`shrink`).
CONTACT_WIDTH = 960


def shrink(frame, width=CONTACT_WIDTH):
    """A frame ``(H, W, C)`` made at most ``width`` pixels wide by the least
    whole factor ``f``: each pixel the mean of an ``f x f`` box (a last
    row or column that fills no box is dropped); the frame itself if it is
    narrow enough. For the contact sheet, so that large frames are neither
    held whole until the end nor tiled into a huge image. Given linear
    display values, the means are those of the light."""
    f = min(-(-frame.shape[1] // width), frame.shape[0])  # at least one row of boxes
    if f == 1:
        return np.array(frame)
    H, W = frame.shape[0] // f * f, frame.shape[1] // f * f
    return frame[:H, :W].reshape(H // f, f, W // f, f, -1).mean(axis=(1, 3), dtype=np.float32)


def spread_frames(t, log_adaptation, count, among=None):
    """Indices of ``count`` frames that show the course of a sequence, for a
    contact sheet: evenly spaced along a path whose length is half the time
    elapsed and half the change of log adaptation, each as a fraction of
    the whole sequence's. The tiles follow the clock, and crowd where vision
    adapts fastest (a tunnel's mouth and exit) rather than where nothing
    changes. The first and last frames are always among them.

    Parameters
    ----------
    t : array (T,)
        Each frame's time, s.
    log_adaptation : array (T,)
        Each frame's adaptation luminance, log10 cd/m2 (an operator's
        ``log_adaptation`` of its diagnostics); not finite counts as no change.
    count : int
    among : array of int, optional
        The frames that may be chosen (those kept while streaming); all.

    Returns
    -------
    numpy array of int, ascending: ``count`` indices (all of ``among`` where
    there are no more).
    """
    t = np.asarray(t, float)
    among = np.unique(np.arange(len(t)) if among is None else np.asarray(among, int))
    if len(among) <= count:
        return among
    with np.errstate(invalid="ignore"):
        step = np.abs(np.diff(np.asarray(log_adaptation, float)))
    change = np.concatenate([[0.0], np.cumsum(np.where(np.isfinite(step), step, 0.0))])
    path = np.zeros(len(t))
    for part in (t - t[0], change):
        if part[-1] > 0:
            path += part / part[-1]
    if path[-1] <= 0:  # one instant, nothing changes: evenly in frames
        path = np.arange(len(t), dtype=float)
    at = path[among]
    chosen = [0, len(among) - 1]
    for target in np.linspace(at[0], at[-1], count)[1:-1]:
        free = [k for k in range(len(among)) if k not in chosen]
        chosen.append(min(free, key=lambda k: abs(at[k] - target)))
    return np.sort(among[chosen])


#: Height of the strip under each frame of a contact sheet that holds its label, pixels.
LABEL_HEIGHT = 18


def contact_sheet(frames, columns=4, labels=None):
    """Tile uint8 frames ``(K, H, W, 3)`` into one image, with white gutters;
    with ``labels`` (K strings, e.g. each frame's time), each is written in
    a strip under its frame."""
    frames = np.asarray(frames)
    if frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3 or not len(frames):
        raise ValueError(
            f"frames: expected uint8 frames (K, H, W, 3), K >= 1, got {frames.dtype} of shape "
            f"{frames.shape}"
        )
    check_whole("columns", columns, least=1)
    K, H, W, _ = frames.shape
    if labels is not None and len(labels) != K:
        raise ValueError(f"labels: expected one for each of the {K} frames, got {len(labels)}")
    strip = 0 if labels is None else LABEL_HEIGHT
    rows = -(-K // columns)
    tile_h = H + strip + 4
    sheet = np.full((rows * tile_h + 4, columns * (W + 4) + 4, 3), 255, np.uint8)
    for k in range(K):
        r, c = divmod(k, columns)
        top, left = 4 + r * tile_h, 4 + c * (W + 4)
        sheet[top : top + H, left : left + W] = frames[k]
        if labels is not None:
            sheet[top + H : top + H + strip, left : left + W] = _label(labels[k], W, strip)
    return sheet


def _label(text, width, height):
    """``text`` in dark grey on white, centred: a ``(height, width, 3)`` uint8 image."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = Figure(figsize=(width / 100, height / 100), dpi=100)
    canvas = FigureCanvasAgg(fig)
    fig.text(0.5, 0.5, text, ha="center", va="center", fontsize=8, color="0.15")
    canvas.draw()
    drawn = np.asarray(canvas.buffer_rgba())[:height, :width, :3]
    image = np.full((height, width, 3), 255, np.uint8)
    image[: drawn.shape[0], : drawn.shape[1]] = drawn
    return image


def plot_columns(path, table, title, units=None, notes=()):
    """Every per-frame column of a diagnostics table against time, one panel each.

    For operators whose diagnostics are not the 2000 operator's (the 2015
    renderer's state at the gaze point, the static curves' background). A
    positive column spanning more than two decades is drawn on a log scale.
    ``units`` (by column) label the y axes; ``notes`` are lines printed
    under the panels (what a reader could take for a defect: a floor, an
    unclamped value). Returns the figure, saved to ``path``.
    """
    units = units or {}
    t = table["t"]
    columns = [name for name, column in table.items() if name != "t" and column.ndim == 1]
    if not columns:
        raise ValueError(f"table: expected a column besides t, got {list(table)}")
    ncols = min(4, len(columns))
    nrows = -(-len(columns) // ncols)
    fig = Figure(figsize=(3.6 * ncols, 2.6 * nrows + 0.5))
    axes = np.atleast_1d(fig.subplots(nrows, ncols)).ravel()
    for ax, name in zip(axes, columns, strict=False):
        column = table[name]
        wide = np.all(column > 0) and column.max() > 100 * column.min()
        ax.plot(t, column, marker=_marker(t))
        ax.set(
            xlabel="time (s)",
            ylabel=units.get(name, ""),
            title=name,
            yscale="log" if wide else "linear",
        )
    for ax in axes[len(columns) :]:
        ax.set_axis_off()
    fig.suptitle(title)
    for i, note in enumerate(notes):
        fig.text(0.01, 0.01 + 0.035 * (len(notes) - 1 - i), note, fontsize=8, color="0.3")
    fig.tight_layout(rect=(0, 0.035 * len(notes), 1, 1))
    fig.savefig(path, dpi=100)
    return fig


@functools.cache
def _characters(path):
    """The code points the font file at ``path`` has glyphs for."""
    from matplotlib.ft2font import FT2Font

    return frozenset(FT2Font(path).get_charmap())


#: Fonts never used as a fallback: they draw a placeholder for every character.
_PLACEHOLDER_FONTS = ("Last Resort",)


def _fonts_for(texts):
    """Font families that draw the characters of ``texts``: matplotlib's
    default, then installed fonts that have what it lacks (matplotlib falls
    back glyph by glyph along the list), and the characters none has."""
    from matplotlib import font_manager

    default = font_manager.findfont(font_manager.FontProperties())
    families = [font_manager.get_font(default).family_name]
    missing = {ord(c) for text in texts for c in text if not c.isspace()} - _characters(default)
    for entry in font_manager.fontManager.ttflist:
        if not missing:
            break
        if entry.name.startswith(_PLACEHOLDER_FONTS) or entry.name in families:
            continue
        try:
            found = missing & _characters(entry.fname)
        except (OSError, RuntimeError):  # a font FreeType cannot read
            continue
        if found:
            families.append(entry.name)
            missing -= found
    return families, missing


@contextlib.contextmanager
def _drawing(texts):
    """Yield ``drawable(text)`` for figures that show ``texts`` (participant
    and condition names, any script): within the block the fonts of
    :func:`_fonts_for` are used, and ``drawable`` writes a character no
    installed font has as its code point (``U+6697``) instead of an empty
    box and a matplotlib warning for each."""
    families, missing = _fonts_for(list(texts))

    def drawable(text):
        return "".join(f"U+{ord(c):04X}" if ord(c) in missing else c for c in str(text))

    with matplotlib.rc_context({"font.family": families}):
        yield drawable


#: Participants :func:`plot_psychometric` draws at most: a panel each.
MAX_PANELS = 24


def plot_psychometric(path, groups, table, columns=4):
    """Fig. 13 of Jacobs et al. (2015): each group's data and fitted curve.

    One panel per participant, for the first :data:`MAX_PANELS` in the
    table's order; the title says how many there are. (A panel for each of
    many participants makes a figure too tall to lay out quickly; the fits
    of all are in the table.)

    Parameters
    ----------
    groups : jaxadapt.psychophysics.trials.Groups
        Counts per (participant, condition).
    table : jaxadapt.psychophysics.fit_table.FitTable
        Their fits.
    """
    from scipy.special import ndtr

    every = list(dict.fromkeys(groups.participant))
    participants = every[:MAX_PANELS]
    conditions = list(dict.fromkeys(groups.condition))
    ncols = min(columns, len(participants))
    nrows = -(-len(participants) // ncols)
    with _drawing([*map(str, participants), *conditions]) as drawable:
        # Wide enough for the title with one participant; the constrained
        # layout keeps the title clear of the panels' titles with many.
        fig = Figure(figsize=(max(3.2 * ncols, 6.0), 2.6 * nrows + 0.5), layout="constrained")
        axes = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False)).ravel()
        x = np.linspace(groups.levels.min() - 0.1, groups.levels.max() + 0.1, 200)
        for g, (who, cond) in enumerate(zip(groups.participant, groups.condition, strict=True)):
            if who not in participants:
                continue
            ax = axes[participants.index(who)]
            colour = f"C{conditions.index(cond)}"
            shown = groups.n_total[g] > 0
            p = groups.n_yes[g][shown] / groups.n_total[g][shown]
            ax.plot(groups.levels[g][shown], p, "o", color=colour, ms=4)
            if np.isfinite(table.pse[g]):
                curve = ndtr((x - table.pse[g]) / table.sigma[g])
                label = f"{drawable(cond)}: PSE {round(table.pse[g], 3) + 0.0:+.3f}"
                ax.plot(x, curve, color=colour, label=label)
            else:  # the data do not determine the fit: no curve
                label = f"{drawable(cond)}: no PSE determined"
                ax.plot([], [], color=colour, ls="none", label=label)
            ax.set(
                title=drawable(who),
                ylim=(-0.03, 1.03),
                xlabel="log10 test / standard",
                ylabel="proportion 'test brighter'",
            )
            ax.legend(fontsize=7)
        for ax in axes[len(participants) :]:
            ax.set_axis_off()
        caption = (
            ""
            if len(every) == len(participants)
            else f" (the first {len(participants)} of {len(every)} participants)"
        )
        fig.suptitle(f"proportion 'test brighter' and cumulative-Gaussian fits{caption}")
        fig.savefig(path, dpi=100)


def plot_pse(path, table, tests=()):
    """Fig. 14 of Jacobs et al. (2015): the PSEs of every condition with their
    confidence intervals, the medians, and the group tests' p-values.

    The axis spans the PSEs (and 0). A group whose data do not determine
    its fit (:func:`jaxadapt.psychophysics.separation.undetermined`) is drawn
    hollow: where its PSE is NaN, as the interval of levels the data leave
    for it (a bar between two levels, or a triangle at the level it lies
    beyond); where it was kept (the prior's), at that PSE, on the axis'
    edge when beyond it (a triangle pointing its way). Medians are of the
    PSEs the group test takes. ``tests`` are the rows of
    ``group_test.csv``; one without a test says why instead of a p.
    Returns the figure, saved to ``path``.
    """
    from jaxadapt.psychophysics.separation import undetermined
    from jaxadapt.psychophysics.stats import untested

    conditions = list(dict.fromkeys(table.condition))
    pse = np.asarray(table.pse, float)
    hollow = undetermined(table.flags)
    placed = np.append(pse[~hollow & np.isfinite(pse)], 0.0)
    pad = max(0.1 * np.ptp(placed), 0.05)
    span = (placed.min() - pad, placed.max() + pad)
    condition = np.asarray(table.condition)
    with _drawing(conditions) as drawable:
        fig = Figure(figsize=(1.8 + 1.4 * len(conditions), 4.0))
        ax = fig.subplots()
        for i, cond in enumerate(conditions):
            here = np.flatnonzero(condition == cond)
            jitter = np.linspace(-0.12, 0.12, here.size) if here.size > 1 else np.zeros(1)
            for x, g in zip(i + jitter, here, strict=True):
                _pse_mark(ax, x, f"C{i}", table, g, hollow[g], span)
            shown = here[np.isfinite(pse[here])]
            if shown.size:
                middle = np.clip(np.median(pse[shown]), *span)
                ax.plot([i - 0.25, i + 0.25], [middle] * 2, "k", lw=2)
        ax.set_ylim(*span)
        ax.axhline(0.0, color="0.6", lw=0.8, ls=":")
        ax.set_xticks(range(len(conditions)), [drawable(c) for c in conditions])
        said = []
        for t in tests:
            why_not = untested(t)
            result = f"no test ({drawable(why_not)})" if why_not else f"p = {t['p']:.3g}"
            said.append(f"{drawable(t['condition'])} vs {drawable(t['control'])}: {result}")
        title = "\n".join(["PSEs, 95% intervals and medians", *said])
        ax.set(ylabel="PSE (log10 test / standard luminance)", title=title)
        ax.title.set_fontsize(9)
        fig.tight_layout()
        fig.savefig(path, dpi=100)
    return fig


def _pse_mark(ax, x, colour, table, g, hollow, span):
    """Group ``g``'s PSE at ``x`` (:func:`plot_pse`), clipped to ``span``."""
    pse = float(table.pse[g])
    if not hollow:
        ax.plot([x, x], np.clip([table.ci_low[g], table.ci_high[g]], *span), color=colour, lw=1)
        ax.plot(x, pse, "o", color=colour, alpha=0.7)
        return
    if np.isfinite(pse):  # kept: the prior's
        y = np.clip(pse, *span)
        ax.plot(x, y, "o" if y == pse else ("^" if y < pse else "v"), mfc="none", color=colour)
        return
    bracket = np.array([table.pse_low[g], table.pse_high[g]], float)
    if np.isfinite(bracket).all():
        ax.plot([x, x], np.clip(bracket, *span), color=colour, ls="--")
        ax.plot(x, np.clip(bracket.mean(), *span), "s", mfc="none", color=colour)
    elif np.isfinite(bracket).any():  # beyond one level
        below = np.isinf(bracket[0])
        y = np.clip(bracket[1] if below else bracket[0], *span)
        ax.plot(x, y, "v" if below else "^", mfc="none", color=colour)
