"""Names that moved between modules of :mod:`jaxadapt.psychophysics`, still
found in the module they came from.

A module that lost names to a module that imports it cannot import them back
(the import would be circular); it finds them on first use instead, through
a module ``__getattr__`` (PEP 562).
"""

import importlib


def forward(module, **moved):
    """A module ``__getattr__`` for ``module`` that finds each name of
    ``moved[new]`` (a tuple of names) in ``jaxadapt.psychophysics.<new>``."""
    where = {name: new for new, names in moved.items() for name in names}

    def find(name):
        if name in where:
            return getattr(importlib.import_module(f"jaxadapt.psychophysics.{where[name]}"), name)
        raise AttributeError(f"module {module!r} has no attribute {name!r}")

    return find
