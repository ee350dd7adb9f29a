"""Where the bundled resources (demo project, clips, icons) are.

They are the ``resources/`` folder beside this ``app`` package inside ``motion_composer``:
in an installed wheel the package data ``motion_composer/resources/``; in a checkout or an
editable install ``motion_composer/app`` and ``motion_composer/resources`` are symlinks to the
repository's ``app/`` and ``resources/``, and the real location of this file leads to the
latter. Inside a PyInstaller bundle they are the ``resources/`` folder the spec copies next to
the program's modules (``sys._MEIPASS``). The layout is the same in all, so the demo project's
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
    """The folder holding ``demo/``, ``clips/``, ``characters/`` and ``icons/``."""
    if is_frozen():
        return Path(sys._MEIPASS) / "resources"          # noqa: SLF001 - PyInstaller's name
    return Path(__file__).resolve().parent.parent / "resources"


def resource_path(relative: str) -> Path:
    """``resource_path("demo/demo.mcp")``: the path of a bundled resource (it may not exist
    if the resources were not installed; callers report that)."""
    return resources_folder() / relative
