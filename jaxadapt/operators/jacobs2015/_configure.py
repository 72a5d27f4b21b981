"""The 2015 operator's part of the render contract: its :class:`Params` from
a render's :class:`~jaxadapt.operators.Settings`, a title, and the plot of
its diagnostics."""

from jaxadapt.operators.jacobs2015._afterimage import blur_for_display
from jaxadapt.operators.jacobs2015._params import EFFECTS, only
from jaxadapt.operators.jacobs2015._state import DIAGNOSTIC_UNITS, diagnostics_notes


def configure(settings):
    """The :class:`Params` of ``settings``: the effects on (all by default),
    the resolution, and the afterimage blur that spreads the maps at the
    frames' rate as the paper's display did (:func:`blur_for_display`)."""
    ppd = settings.pixels_per_degree
    effects = EFFECTS if settings.effects is None else settings.effects
    return only(
        *effects, pixels_per_degree=ppd, afterimage_blur=blur_for_display(ppd, settings.fps)
    )


def describe(settings):
    """``Jacobs et al. 2015``: its diagnostics are the state at the gaze point."""
    return "Jacobs et al. 2015, at the gaze point"


def plot_diagnostics(path, table, params, title):
    """Each column over time, with the notes a reader needs
    (:func:`diagnostics_notes`: the adaptation floor, the unclamped values)."""
    from jaxadapt import figures

    notes = diagnostics_notes(params)
    return figures.plot_columns(path, table, title, units=DIAGNOSTIC_UNITS, notes=notes)
