"""The 2000 operator's part of the render contract: its :class:`Params` from
a render's :class:`~jaxadapt.operators.Settings`, a title, and the plot of
its diagnostics."""

from jaxadapt.operators.pattanaik2000._params import CURVE_LOG10_LUMINANCE, Params


def configure(settings):
    """The :class:`Params` of ``settings``: its goal, background and
    pixels per degree.

    Refuses (``ValueError`` naming the setting) what the model would
    ignore: a goal chosen for a local background, whose estimate is each
    pixel's goal; a gaze or a resolution, which only the foveal goal of a
    global background reads (a local background's diagnostics read the
    gaze too).
    """
    goal, background, given = settings.goal, settings.background, settings.given
    if "goal" in given and background != "global":
        raise ValueError(
            f"goal: applies to a global background, not {background}, whose local estimate "
            "is each pixel's goal"
        )
    if "gaze" in given and background == "global" and goal != "foveal":
        raise ValueError(
            f"gaze: {settings.name} reads the gaze for the foveal adaptation goal or the "
            f"diagnostics of a local background, not for goal {goal} with a global background"
        )
    if "pixels_per_degree" in given and (goal, background) != ("foveal", "global"):
        raise ValueError(
            "pixels_per_degree: applies to the foveal adaptation goal with a global "
            f"background, not goal {goal} with a {background} background"
        )
    return Params(
        goal=goal,
        pixels_per_degree=settings.pixels_per_degree,
        background=background,
        background_scale=settings.background_scale,
    )


def describe(settings):
    """``Pattanaik et al. 2000`` and its goal, or its local background."""
    where = (
        f"goal {settings.goal}"
        if settings.background == "global"
        else f"{settings.background} background"
    )
    return f"Pattanaik et al. 2000, {where}"


def plot_diagnostics(path, table, params, title):
    """The adaptation state over time and the scene-to-display curve
    (:func:`jaxadapt.figures.plot_adaptation`)."""
    from jaxadapt import figures

    return figures.plot_adaptation(path, table, title, CURVE_LOG10_LUMINANCE)
