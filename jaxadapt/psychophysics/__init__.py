"""Psychophysics: experiment designs, psychometric fits, group statistics and
simulated observers.

- :mod:`~jaxadapt.psychophysics.design`: the method of constant stimuli and
  the 2015 paper's two protocols as data;
- :mod:`~jaxadapt.psychophysics.psychometric`: cumulative-Gaussian (probit)
  fits; :mod:`~jaxadapt.psychophysics.flags`: the flags of degenerate data;
- :mod:`~jaxadapt.psychophysics.bootstrap`: bootstrap intervals of those
  fits; :mod:`~jaxadapt.psychophysics.sharding`: the fits across devices;
- :mod:`~jaxadapt.psychophysics.stats`: the rank-sum group test between
  conditions;
- :mod:`~jaxadapt.psychophysics.trials`: trial tables read and grouped;
  :mod:`~jaxadapt.psychophysics.fit_table`: groups fitted, fit tables
  written (the ``psychometric fit`` command);
  :mod:`~jaxadapt.psychophysics.separation`: what separated data say;
- :mod:`~jaxadapt.psychophysics.observer`: the decision model of simulated
  observers; :mod:`~jaxadapt.psychophysics.population`: where they come
  from; :mod:`~jaxadapt.psychophysics.stimuli` and
  :mod:`~jaxadapt.psychophysics.displays`: the paper's stimuli rendered with
  the 2015 operator and reduced to cues;
  :mod:`~jaxadapt.psychophysics.experiment`: whole simulated experiments
  (``psychometric simulate``).

Each module is imported when first used.
"""

import importlib

__all__ = [
    "bootstrap",
    "design",
    "displays",
    "experiment",
    "fit_table",
    "flags",
    "observer",
    "population",
    "psychometric",
    "separation",
    "sharding",
    "stats",
    "stimuli",
    "trials",
]


def __getattr__(name):
    if name in __all__:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(__all__)
