"""jaxadapt: time-dependent human visual adaptation to HDR scenes, in JAX.

Subpackages and modules, each imported when first used (the command line
takes its signals before anything heavy is imported):

- :mod:`~jaxadapt.operators`: the tone-reproduction operators and their
  registry (Pattanaik et al. 2000, Jacobs et al. 2015, the classic curves);
- :mod:`~jaxadapt.physiology`: the laws of the visual system;
- :mod:`~jaxadapt.psychophysics`: designs, psychometric fits, statistics,
  simulated observers;
- :mod:`~jaxadapt.fitting`: fits of any model's parameters to data;
- :mod:`~jaxadapt.pipeline`: sources and streaming renders;
- :mod:`~jaxadapt.viewer`: the live, gaze-contingent viewer (``jaxadapt view``);
- :mod:`~jaxadapt.scenes`, :mod:`~jaxadapt.gaze`, :mod:`~jaxadapt.background`,
  :mod:`~jaxadapt.io`, :mod:`~jaxadapt.display`,
  :mod:`~jaxadapt.figures`, :mod:`~jaxadapt.color`,
  :mod:`~jaxadapt.spatial`, :mod:`~jaxadapt.runtime`.
"""

import importlib

__all__ = [
    "background",
    "color",
    "display",
    "figures",
    "fitting",
    "gaze",
    "io",
    "operators",
    "physiology",
    "pipeline",
    "psychophysics",
    "runtime",
    "scenes",
    "spatial",
    "viewer",
]


def __getattr__(name):
    if name in __all__:
        return importlib.import_module(f"{__name__}.{name}")
    if name == "__version__":
        from importlib.metadata import version

        return version("jaxadapt")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted([*__all__, "__version__"])
