"""Psychophysics: experiment designs, psychometric fits, group statistics and
simulated observers.

- :mod:`~jaxadapt.psychophysics.design`: the method of constant stimuli and
  the 2015 paper's two protocols as data;
- :mod:`~jaxadapt.psychophysics.psychometric`: cumulative-Gaussian (probit) fits with
  bootstrap intervals;
- :mod:`~jaxadapt.psychophysics.stats`: the rank-sum group test between
  conditions;
- :mod:`~jaxadapt.psychophysics.trials`: trial tables read, grouped and
  fitted, fit tables written (the ``psychometric fit`` command);
- :mod:`~jaxadapt.psychophysics.observer`: the paper's stimuli rendered with
  the 2015 operator and judged by simulated observers (``psychometric
  simulate``).

Each module is imported when first used.
"""

import importlib

__all__ = ["design", "observer", "psychometric", "stats", "trials"]


def __getattr__(name):
    if name in __all__:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(__all__)
