"""The 2015 paper's brightness studies run with people: ``jaxadapt experiment``.

- :mod:`~jaxadapt.experiment.calibration`: the monitor as a photometer
  measures it, and the dithered codes that show a luminance;
- :mod:`~jaxadapt.experiment.stimuli`: the paper's stimuli rendered by the
  2015 operator for that monitor, as PNG images and display frames;
- :mod:`~jaxadapt.experiment.session`: one participant's session, its
  plan and its table of answers, continued after a crash;
- :mod:`~jaxadapt.experiment.server`: the page that runs the trials and
  the server behind it; :mod:`~jaxadapt.experiment.scripted`: a scripted
  participant that drives the page in a browser (tests, rehearsals).

Jacobs, Gallo, Cooper, Pulli, Levoy (2015), *Simulating the Visual
Experience of Very Bright and Very Dark Scenes*, ACM TOG 34(3), §4.1-4.2.
"""

import importlib

__all__ = ["calibration", "scripted", "session", "server", "stimuli"]


def __getattr__(name):
    if name in __all__:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(__all__)
