"""The engine never loads a GUI toolkit: no Qt, pyqtgraph or OpenGL under ``engine/``.

Two checks, because each misses what the other sees:

* at run time, a fresh interpreter imports ``engine`` and then every submodule found by
  :func:`pkgutil.walk_packages`, and must end with none of the GUI packages in ``sys.modules``
  (this catches an indirect import through some third-party package);
* statically, no file under ``engine/`` has an import statement naming one of them, parsed with
  :mod:`ast` (this catches an import inside a function that the run-time check never calls).

And the other way round: nothing under ``app/`` runs the engine's derived stages (binding,
conversion, composition, enforcement, the IK solver) itself; it asks the scene. Checked
statically, each name resolved through the module's imports.
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
KNOWN_SUBMODULES = {"motion_composer.engine.formats.bvh", "motion_composer.engine.kinematics", "motion_composer.engine.quaternions",
                    "motion_composer.engine.rotations", "motion_composer.engine.skeleton", "motion_composer.engine.motion"}


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
    from motion_composer import engine
    report["engine_file"] = engine.__file__
    report["steps"].append(["engine", gui_modules()])
    names = sorted(m.name for m in pkgutil.walk_packages(engine.__path__, "motion_composer.engine."))
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


# --------------------------------------------------------------------------- app asks the scene
# Nothing under app/ binds, converts, composes, enforces or runs the IK solver itself: the
# window and the command line ask the scene (engine/scene.py), so a result never depends on
# who asked and every derived stage is cached in one place. Each reference is resolved through
# the module's own imports (aliases, ``import a.b as x``, relative imports, re-exports by the
# engine's packages and by other app modules), so ``from engine.conversion import bind as b``
# and ``import engine.correction.enforcement as e; e.enforce(...)`` are seen alike.
#
# ``automap`` stays allowed: it proposes a *choice* (a correspondence from two skeletons, which
# the user then edits and which becomes part of the project), not a derived stage; the Auto-map
# button and the command line without ``--map`` call it, and the scene's own remap uses it.
APP = REPO / "app"


def _qualified(obj) -> str:
    return f"{obj.__module__}.{obj.__qualname__}"


def _stages():
    from motion_composer.engine.conversion import bind, compose, convert, retarget
    from motion_composer.engine.correction.enforcement import enforce
    from motion_composer.engine.correction.ik import solve_frames
    return {_qualified(f): f.__name__ for f in (bind, convert, compose, retarget, enforce,
                                                solve_frames)}


def _absolute(module: str, is_package: bool, level: int, name: str | None) -> str:
    """The absolute module of ``from <level dots><name> import ...`` written in ``module``."""
    if level == 0:
        return name or ""
    parts = module.split(".") if is_package else module.split(".")[:-1]
    parts = parts[:len(parts) - (level - 1)]
    return ".".join(parts + ([name] if name else []))


def import_bindings(tree: ast.AST, module: str, is_package: bool = False) -> dict[str, str]:
    """Local name -> the dotted name an import statement anywhere in the module binds it to."""
    bound = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.asname:
                    bound[a.asname] = a.name
                else:
                    top = a.name.split(".", 1)[0]
                    bound[top] = top
        elif isinstance(node, ast.ImportFrom):
            base = _absolute(module, is_package, node.level, node.module)
            for a in node.names:
                if a.name != "*":
                    bound[a.asname or a.name] = f"{base}.{a.name}" if base else a.name
    return bound


def _dotted(node: ast.AST, bound: dict[str, str]) -> str | None:
    """The dotted name an expression reaches through imports (``eb.bind`` ->
    ``engine.conversion.binding.bind``), or None."""
    attrs = []
    while isinstance(node, ast.Attribute):
        attrs.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name) and isinstance(node.ctx, ast.Load) and node.id in bound:
        base = bound[node.id]
    elif (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
          and isinstance(node.args[0].value, str)
          and (getattr(node.func, "attr", None) or getattr(node.func, "id", None))
          in ("import_module", "__import__")):
        base = node.args[0].value
        if getattr(node.func, "id", None) == "__import__":
            base = base.split(".", 1)[0]
    else:
        return None
    return ".".join([base] + attrs[::-1])


class _Resolver:
    """Dotted names to the engine functions they are: engine names by importing the engine
    (no GUI toolkit), app names through the app module's own imports (read from its AST)."""

    def __init__(self, modules: dict[str, str], packages: frozenset):
        self.modules, self.packages = modules, packages
        self._bindings: dict[str, dict] = {}

    def bindings(self, module: str) -> dict[str, str]:
        """The module's import bindings, ``from X import *`` expanded (X's public names)."""
        if module not in self._bindings:
            is_package = module in self.packages
            tree = ast.parse(self.modules[module], module)
            bound = self._bindings[module] = import_bindings(tree, module, is_package)
            for node in ast.walk(tree):
                if isinstance(node, ast.ImportFrom) and any(a.name == "*" for a in node.names):
                    base = _absolute(module, is_package, node.level, node.module)
                    for name in self._public(base):
                        bound.setdefault(name, f"{base}.{name}")
        return self._bindings[module]

    def _public(self, module: str) -> list[str]:
        import importlib
        if module in self.modules:
            return list(self.bindings(module))
        if module.split(".")[:2] != ["motion_composer", "engine"]:
            return []
        mod = importlib.import_module(module)
        return list(getattr(mod, "__all__", [n for n in vars(mod) if not n.startswith("_")]))

    def resolve(self, dotted: str, depth: int = 0) -> str | None:
        """``module.qualname`` of the function ``dotted`` names, or None."""
        import importlib
        parts = dotted.split(".")
        if depth > 20:
            return None
        if parts[:2] == ["motion_composer", "app"]:
            for i in range(len(parts) - 1, 0, -1):
                module = ".".join(parts[:i])
                if module in self.modules:
                    target = self.bindings(module).get(parts[i])
                    return (self.resolve(".".join([target] + parts[i + 1:]), depth + 1)
                            if target else None)
            return None
        if parts[:2] != ["motion_composer", "engine"]:
            return None
        for i in range(len(parts), 0, -1):
            try:
                obj = importlib.import_module(".".join(parts[:i]))
            except ImportError:
                continue
            try:
                for attr in parts[i:]:
                    obj = getattr(obj, attr)
            except AttributeError:
                return None
            return _qualified(obj) if callable(obj) and hasattr(obj, "__qualname__") else None
        return None


def stage_calls(modules: dict[str, str], packages=frozenset()) -> list[str]:
    """``module:line: what`` for every import or use, in ``modules`` (name -> source), of a
    function the scene derives through (binding, conversion, composition, enforcement, IK)."""
    stages = _stages()
    resolver = _Resolver(modules, frozenset(packages))
    found = set()
    for module, source in modules.items():
        tree = ast.parse(source, module)
        bound = resolver.bindings(module)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                base = _absolute(module, module in packages, node.level, node.module)
                for a in node.names:
                    name = stages.get(resolver.resolve(f"{base}.{a.name}") or "")
                    if name:
                        found.add((module, node.lineno, f"imports {name} "
                                                        f"(from {base} import {a.name})"))
            elif isinstance(node, (ast.Name, ast.Attribute)):
                dotted = _dotted(node, bound)
                name = stages.get(resolver.resolve(dotted) or "") if dotted else None
                if name:
                    found.add((module, node.lineno, f"uses {name} (as {dotted})"))
    return [f"{m}:{line}: {what}" for m, line, what in sorted(found)]


def app_modules() -> tuple[dict[str, str], frozenset]:
    modules, packages = {}, set()
    for path in sorted(APP.rglob("*.py")):
        parts = ["motion_composer"] + list(path.relative_to(REPO).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
            packages.add(".".join(parts))
        modules[".".join(parts)] = path.read_text(encoding="utf-8")
    return modules, frozenset(packages)


def test_app_asks_the_scene_for_every_derived_stage():
    modules, packages = app_modules()
    assert {"motion_composer.app.cli", "motion_composer.app.gui.document", "motion_composer.app.gui.main_window"} <= set(modules)
    problems = stage_calls(modules, packages)
    assert not problems, ("app/ must ask the scene (engine.scene.Scene: binding, composed, "
                          "motion, solve, preview) instead of running the engine's stages "
                          "itself:\n" + "\n".join(problems))


@pytest.mark.parametrize("source", [
    "from motion_composer.engine.conversion import bind as b\nb(p, t, c)",
    "import motion_composer.engine.conversion.binding as eb\neb.bind(p, t, c)",
    "import motion_composer.engine.correction.enforcement\nmotion_composer.engine.correction.enforcement.enforce(m, [])",
    "from motion_composer import engine\nengine.conversion.retarget(p, t, c)",
    "def f():\n    from motion_composer.engine.correction.ik import solve_frames\n    return solve_frames",
    "from motion_composer.engine.conversion import converter\nrun = converter.convert",
    "from motion_composer.engine import conversion as c\nc.composer.compose(b, p, 0.01)",
    "import importlib\nimportlib.import_module('motion_composer.engine.conversion.composer').compose(b, p, 1)",
    "from motion_composer.engine.correction import enforcement\njobs.run(enforcement.enforce)",
    "from motion_composer.engine.conversion import *\nconvert(b, p)",
])
def test_the_stage_check_sees_planted_calls(source):
    assert stage_calls({"motion_composer.app.gui.planted": source}), source


def test_the_stage_check_follows_app_reexports_and_relative_imports():
    modules = {"motion_composer.app.gui": "", "motion_composer.app.gui.helpers": "from motion_composer.engine.conversion import bind as run\n",
               "motion_composer.app.gui.panel": "from .helpers import run\nrun(p, t, c)\n",
               "motion_composer.app.gui.other": "from motion_composer.app.gui import helpers\nhelpers.run(p, t, c)\n"}
    found = stage_calls(modules, {"motion_composer.app.gui"})
    assert any(f.startswith("motion_composer.app.gui.panel:2: uses bind") for f in found), found
    assert any(f.startswith("motion_composer.app.gui.other:2: uses bind") for f in found), found
    assert any(f.startswith("motion_composer.app.gui.helpers:1: imports bind")
               for f in found), found


@pytest.mark.parametrize("source", [
    "from motion_composer.engine.conversion import automap\ncorr = automap(t.skeleton, p.skeleton)",
    "from motion_composer.engine.conversion import BindOptions, RootOptions\nBindOptions()",
    "from motion_composer.engine.scene import Scene\nScene.empty().solve()",
    "import motion_composer.engine.scene as es\nes.evaluate_project(project).motion",
    "bind = lambda *a: a\nbind(1)",                    # a local name, not the engine's
    "def convert(x):\n    return x\nconvert(1)",
    "from motion_composer.app.gui.qt import QtCore",
])
def test_the_stage_check_leaves_other_calls(source):
    assert stage_calls({"motion_composer.app.gui.planted": source}) == [], source


_DEMO_CHILD = textwrap.dedent("""
    import sys
    from motion_composer.engine.scene import Scene
    scene = Scene.open(sys.argv[1])
    scene.motion, scene.binding
    print(sorted({m.split(".")[0] for m in sys.modules if m.split(".")[0] == "scipy"}))
""")


def test_opening_the_demo_needs_no_scipy():
    """Start-up: reading the bundled demo (Z-up BVH target included) and evaluating its
    motion stays off scipy, which costs about half a second to import."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    proc = subprocess.run([sys.executable, "-c", _DEMO_CHILD,
                           str(REPO / "resources" / "demo" / "demo.mcp")],
                          capture_output=True, text=True, cwd=REPO, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"
