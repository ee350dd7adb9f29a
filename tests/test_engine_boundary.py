"""The engine never loads a GUI toolkit: no Qt, pyqtgraph or OpenGL under ``engine/``.

Two checks, because each misses what the other sees:

* at run time, a fresh interpreter imports ``engine`` and then every submodule found by
  :func:`pkgutil.walk_packages`, and must end with none of the GUI packages in ``sys.modules``
  (this catches an indirect import through some third-party package);
* statically, no file under ``engine/`` has an import statement naming one of them, parsed with
  :mod:`ast` (this catches an import inside a function that the run-time check never calls).
"""
from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
ENGINE = REPO / "engine"

#: top-level packages the engine must never load: Qt bindings (and their shims), pyqtgraph,
#: PyOpenGL
FORBIDDEN = ("PySide6", "shiboken6", "PyQt5", "PyQt6", "PySide2", "shiboken2", "PyQt4", "qtpy",
             "pyqtgraph", "OpenGL")

#: submodules that must be found, so that an empty package walk cannot pass unnoticed
KNOWN_SUBMODULES = {"engine.formats.bvh", "engine.kinematics", "engine.quaternions",
                    "engine.rotations", "engine.skeleton", "engine.motion"}


def forbidden_name(module: str | None) -> str | None:
    """The forbidden top-level package that ``module`` (dotted name) belongs to, or None."""
    if not module:
        return None
    top = module.split(".", 1)[0]
    return top if top in FORBIDDEN else None


# --------------------------------------------------------------------------- run time
_CHILD = textwrap.dedent("""
    import importlib, json, pkgutil, sys
    forbidden = set(sys.argv[1].split(","))

    def gui_modules():
        return sorted(m for m in sys.modules if m.split(".", 1)[0] in forbidden)

    report = {"preloaded": gui_modules(), "steps": []}
    import engine
    report["engine_file"] = engine.__file__
    report["steps"].append(["engine", gui_modules()])
    names = sorted(m.name for m in pkgutil.walk_packages(engine.__path__, "engine."))
    for name in names:
        importlib.import_module(name)
        report["steps"].append([name, gui_modules()])
    report["submodules"] = names
    print(json.dumps(report))
""")


def _import_engine_in_fresh_interpreter() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    proc = subprocess.run([sys.executable, "-c", _CHILD, ",".join(FORBIDDEN)],
                          capture_output=True, text=True, cwd=REPO, env=env, timeout=300)
    assert proc.returncode == 0, f"importing the engine failed:\n{proc.stderr}"
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_importing_the_engine_loads_no_gui_module():
    report = _import_engine_in_fresh_interpreter()
    assert Path(report["engine_file"]).resolve().is_relative_to(ENGINE), \
        f"the child imported another engine: {report['engine_file']}"
    assert report["preloaded"] == [], \
        f"GUI modules loaded before the engine was imported: {report['preloaded']}"
    missing = KNOWN_SUBMODULES - set(report["submodules"])
    assert not missing, f"the package walk missed {sorted(missing)}"
    # name the first import that brought a GUI module in
    for name, loaded in report["steps"]:
        packages = sorted({m.split(".", 1)[0] for m in loaded})
        assert not loaded, (f"importing {name} loaded {', '.join(packages)} ({len(loaded)} "
                            "modules); the engine must not depend on Qt, pyqtgraph or OpenGL "
                            "(move that code to app/)")


# --------------------------------------------------------------------------- static
def gui_imports(source: str, filename: str = "<source>") -> list[tuple[int, str]]:
    """``(line, statement)`` for every import of a forbidden package in ``source``.

    Covers ``import X``, ``from X import y`` (absolute only: relative imports stay inside the
    package) and ``importlib.import_module("X")`` / ``__import__("X")`` with a literal name,
    wherever they are: module level, inside functions, under ``if TYPE_CHECKING``.
    """
    found = []
    for node in ast.walk(ast.parse(source, filename)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, f"import {a.name}") for a in node.names
                      if forbidden_name(a.name)]
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0 and forbidden_name(node.module):
                found.append((node.lineno, f"from {node.module} import ..."))
        elif isinstance(node, ast.Call) and node.args:
            func = node.func
            called = (func.attr if isinstance(func, ast.Attribute) else
                      func.id if isinstance(func, ast.Name) else None)
            arg = node.args[0]
            if (called in ("import_module", "__import__") and isinstance(arg, ast.Constant)
                    and isinstance(arg.value, str) and forbidden_name(arg.value)):
                found.append((node.lineno, f"{called}({arg.value!r})"))
    return found


def engine_sources() -> list[Path]:
    return sorted(ENGINE.rglob("*.py"))


def test_engine_sources_have_no_gui_import():
    files = engine_sources()
    assert len(files) >= len(KNOWN_SUBMODULES), f"too few engine sources found in {ENGINE}"
    problems = [f"{path.relative_to(REPO)}:{line}: {what}"
                for path in files
                for line, what in gui_imports(path.read_text(encoding="utf-8"), str(path))]
    assert not problems, ("the engine must not import Qt, pyqtgraph or OpenGL (move that code "
                          "to app/):\n" + "\n".join(problems))


@pytest.mark.parametrize("source", [
    "import PySide6",
    "import PySide6.QtCore as qc",
    "import numpy, pyqtgraph",
    "from OpenGL import GL",
    "from PyQt5.QtWidgets import QWidget",
    "from shiboken6 import isValid",
    "def f():\n    from PyQt6 import QtCore",
    "if TYPE_CHECKING:\n    import pyqtgraph.opengl",
    "import importlib\nimportlib.import_module('PySide6.QtGui')",
    "__import__('OpenGL.GL')",
])
def test_the_static_check_sees_gui_imports(source):
    assert gui_imports(source), source


@pytest.mark.parametrize("source", [
    "import numpy as np",
    "from . import qt_names",                 # relative: inside the engine
    "from .OpenGL_free import x",
    "import PySide6_helpers",                 # a different package that merely starts alike
    "import pyqtgraphs_like_name",
    "name = 'PySide6'",
])
def test_the_static_check_leaves_other_imports(source):
    assert gui_imports(source) == [], source
