"""The public surface: each package's ``__all__`` names what it exports, and
importing the top-level package costs nothing (the command line takes its
signals first)."""

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

PACKAGES = [
    "jaxadapt",
    "jaxadapt.fitting",
    "jaxadapt.operators",
    "jaxadapt.operators.jacobs2015",
    "jaxadapt.io",
    "jaxadapt.physiology",
    "jaxadapt.psychophysics",
]


#: Every module whose path has no part with a leading underscore (a
#: package's ``__init__`` standing for the package).
PUBLIC_MODULES = sorted(
    ".".join(parts)
    for parts in (
        p.relative_to(ROOT).with_suffix("").parts for p in (ROOT / "jaxadapt").rglob("*.py")
    )
    for parts in [parts[:-1] if parts[-1] == "__init__" else parts]
    if not any(part.startswith("_") for part in parts)
)


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
    # `jaxadapt view` imports: no extra to know of, but the lsl extra of an
    # eye tracker's stream (--gaze-lsl), whose absence the option says.
    import ast
    import re
    from importlib.metadata import packages_distributions
    from pathlib import Path

    import tomllib

    root = Path(__file__).resolve().parent.parent
    project = tomllib.loads((root / "pyproject.toml").read_text())["project"]
    base = {re.split(r"[<>=!~;\[ ]", r)[0].lower() for r in project["dependencies"]}
    lsl = {re.split(r"[<>=!~;\[ ]", r)[0].lower() for r in project["optional-dependencies"]["lsl"]}
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
    assert {d.lower() for m in missing for d in distributions[m]} <= lsl, missing


@pytest.mark.parametrize("module", PUBLIC_MODULES)
def test_a_public_module_lists_what_it_defines_in_all(module):
    # One convention: a module without an underscore in its path names in
    # __all__ everything it defines without a leading underscore, and any
    # name it imports for its users (a package's __init__ re-exports only).
    import ast

    path = ROOT / Path(*module.split("."))
    path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
    tree = ast.parse(path.read_text())
    declared = next(
        (
            ast.literal_eval(node.value)
            for node in tree.body
            if isinstance(node, ast.Assign)
            and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets)
        ),
        None,
    )
    assert declared is not None, f"{module} has no __all__"
    module_object = importlib.import_module(module)
    assert all(hasattr(module_object, name) for name in declared), module
    defined = set()
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            defined.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                for name in [target, *getattr(target, "elts", [])]:
                    if isinstance(name, ast.Name):
                        defined.add(name.id)
    assert {n for n in defined if not n.startswith("_")} <= set(declared), module
