"""The public surface: each package's ``__all__`` names what it exports, and
importing the top-level package costs nothing (the command line takes its
signals first)."""

import importlib
import subprocess
import sys

import pytest

PACKAGES = [
    "jaxadapt",
    "jaxadapt.fitting",
    "jaxadapt.operators",
    "jaxadapt.operators.jacobs2015",
    "jaxadapt.io",
    "jaxadapt.physiology",
    "jaxadapt.psychophysics",
]


@pytest.mark.parametrize("package", PACKAGES)
def test_every_name_of_all_is_importable_from_its_package(package):
    module = importlib.import_module(package)
    for name in module.__all__:
        exec(f"from {package} import {name}", {})


def test_importing_jaxadapt_imports_no_numerical_library():
    code = (
        "import sys, jaxadapt; heavy = {'jax', 'numpy'} & set(sys.modules); "
        "assert not heavy, heavy; assert jaxadapt.io.__name__ == 'jaxadapt.io'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
