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


@pytest.mark.parametrize(
    "argv, says", [(["--help"], "psychometric"), (["--version"], "jaxadapt "), ([], "COMMAND")]
)
def test_the_programs_own_options_import_no_numerical_library(argv, says):
    # The program's help, version and usage error name the commands only; a
    # command's options (its registries: JAX) are declared when it is run.
    code = (
        "import runpy, sys\n"
        f"sys.argv = ['jaxadapt', *{argv!r}]\n"
        "try:\n"
        "    runpy.run_module('jaxadapt', run_name='__main__')\n"
        "finally:\n"
        "    print(sorted({'jax', 'numpy', 'scipy', 'colour'} & set(sys.modules)), "
        "file=sys.stderr)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == (2 if not argv else 0), done.stderr
    assert done.stderr.splitlines()[-1] == "[]", done.stderr
    assert says in done.stdout + done.stderr


def test_a_commands_parser_declares_its_options_only():
    from jaxadapt.cli._main import build_parser

    for command, option in [("render", "--operator"), ("view", "--port"), ("psychometric", None)]:
        parser = build_parser(command)
        sub = next(a for a in parser._actions if a.dest == "command")
        for name, subparser in sub.choices.items():
            declared = [a for a in subparser._actions if a.dest != "help"]
            assert (name == command) == bool(declared), (command, name)
        if option:
            assert option in {s for a in sub.choices[command]._actions for s in a.option_strings}


def test_the_viewer_needs_only_the_base_install():
    # `pip install .` (the README's first command) brings everything that
    # `jaxadapt view` imports: no extra to know of.
    import ast
    import re
    from importlib.metadata import packages_distributions
    from pathlib import Path

    import tomllib

    root = Path(__file__).resolve().parent.parent
    project = tomllib.loads((root / "pyproject.toml").read_text())["project"]
    base = {re.split(r"[<>=!~;\[ ]", r)[0].lower() for r in project["dependencies"]}
    distributions = packages_distributions()
    imported = set()
    for path in [*(root / "jaxadapt" / "viewer").glob("*.py"), root / "jaxadapt/cli/view.py"]:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                imported |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                imported.add(node.module.split(".")[0])
    third_party = {m for m in imported if m in distributions and m != "jaxadapt"}
    assert {"aiohttp", "PIL"} <= third_party
    missing = {m for m in third_party if not {d.lower() for d in distributions[m]} & base}
    assert not missing, missing
