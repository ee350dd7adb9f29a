"""Where the bundled resources (demo project, clips, icons) are.

From the source tree (or an editable install) they are the repository's ``resources/``
folder; inside a PyInstaller bundle they are the ``resources/`` folder the spec copies next to
the program's modules (``sys._MEIPASS``). The layout is the same in both, so the demo project's
``../clips/*.bvh`` paths hold either way.
"""
from __future__ import annotations

import sys
from pathlib import Path

__all__ = ["resources_folder", "resource_path", "is_frozen"]


def is_frozen() -> bool:
    """Whether this is the built program (PyInstaller) rather than Python on the sources."""
    return bool(getattr(sys, "frozen", False)) and hasattr(sys, "_MEIPASS")


def resources_folder() -> Path:
    """The folder holding ``demo/``, ``clips/`` and ``icons/``."""
    if is_frozen():
        return Path(sys._MEIPASS) / "resources"          # noqa: SLF001 - PyInstaller's name
    return Path(__file__).resolve().parent.parent / "resources"


def resource_path(relative: str) -> Path:
    """``resource_path("demo/demo.mcp")``: the path of a bundled resource (it may not exist
    if the resources were not installed; callers report that)."""
    return resources_folder() / relative
