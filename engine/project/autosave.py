"""Crash recovery: an autosave beside the project file (or in the per-user state folder for
a project never saved), offered at start when it is newer than the project."""
from __future__ import annotations

import os
from pathlib import Path

from ..fileio import FileWriteError, atomic_write
from .json import project_to_json
from .model import Project

__all__ = ["autosave_path", "write_autosave", "find_autosave", "discard_autosave"]


def _state_folder() -> Path:
    if os.name == "nt":
        base = os.environ.get("LOCALAPPDATA") or os.path.expanduser("~/AppData/Local")
        return Path(base) / "Motion Composer"
    base = os.environ.get("XDG_STATE_HOME") or os.path.expanduser("~/.local/state")
    return Path(base) / "motion-composer"


def autosave_path(project_path=None) -> Path:
    """Where the autosave of ``project_path`` goes: ``.<name>.autosave`` beside it, or
    ``untitled.autosave`` in the per-user state folder (``$XDG_STATE_HOME/motion-composer``,
    else ``~/.local/state/motion-composer``) for a project never saved."""
    if project_path is None:
        return _state_folder() / "untitled.autosave"
    p = Path(os.path.abspath(os.fspath(project_path)))
    return p.with_name(f".{p.name}.autosave")


def write_autosave(project: Project, project_path=None) -> Path:
    """Write the autosave of a project saved at ``project_path`` (``None``: never saved),
    atomically, and return where it went. It is an ordinary project file."""
    target = autosave_path(project_path)
    if project_path is None:
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise FileWriteError(f"{target.parent}: cannot be created: "
                                 f"{exc.strerror or exc}") from None
    atomic_write(target, project_to_json(project, target))
    return target


def find_autosave(project_path=None) -> Path | None:
    """The autosave to offer at start, or None: one exists and is newer than the project
    file (or the project file is gone, or was never saved)."""
    auto = autosave_path(project_path)
    try:
        auto_time = auto.stat().st_mtime_ns
    except OSError:
        return None
    if project_path is None:
        return auto
    try:
        saved_time = os.stat(project_path).st_mtime_ns
    except OSError:
        return auto
    return auto if auto_time > saved_time else None


def discard_autosave(project_path=None) -> None:
    """Remove the autosave of ``project_path`` (after a save, or when the user declines it)."""
    try:
        autosave_path(project_path).unlink()
    except FileNotFoundError:
        pass
