"""Crash recovery: an autosave beside the project file (or in the per-user state folder for
a project never saved), offered at start when it is newer than the project.

A project never saved has one autosave per session, ``untitled-<pid>-<stamp>.autosave``, so
that two unsaved sessions running at once never overwrite each other's. At start the newest
one whose session is no longer running is offered (a running session's is its own business).
"""
from __future__ import annotations

import os
import re
import time
from pathlib import Path

from ..fileio import FileWriteError, atomic_write
from .json import project_to_json
from .model import Project

__all__ = ["autosave_path", "write_autosave", "find_autosave", "discard_autosave",
           "remove_autosave_file", "new_session"]

_UNTITLED = re.compile(r"untitled(?:-(\d+)-[0-9a-f]+)?\.autosave")


def _state_folder() -> Path:
    if os.name == "nt":
        base = os.environ.get("LOCALAPPDATA") or os.path.expanduser("~/AppData/Local")
        return Path(base) / "Motion Composer"
    base = os.environ.get("XDG_STATE_HOME") or os.path.expanduser("~/.local/state")
    return Path(base) / "motion-composer"


def new_session() -> str:
    """A name for this session's unsaved autosave, unique across running processes and over
    time: ``<pid>-<start time in ns, hex>``."""
    return f"{os.getpid()}-{time.time_ns():x}"


def autosave_path(project_path=None, session: str | None = None) -> Path:
    """Where the autosave of ``project_path`` goes: ``.<name>.autosave`` beside it, or, for a
    project never saved, ``untitled-<session>.autosave`` (``untitled.autosave`` without a
    session) in the per-user state folder (``$XDG_STATE_HOME/motion-composer``, else
    ``~/.local/state/motion-composer``)."""
    if project_path is None:
        name = f"untitled-{session}.autosave" if session else "untitled.autosave"
        return _state_folder() / name
    p = Path(os.path.abspath(os.fspath(project_path)))
    return p.with_name(f".{p.name}.autosave")


def write_autosave(project: Project, project_path=None, session: str | None = None) -> Path:
    """Write the autosave of a project saved at ``project_path`` (``None``: never saved, the
    autosave of ``session``), atomically, and return where it went. It is an ordinary project
    file."""
    target = autosave_path(project_path, session)
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
    file (or the project file is gone); for a project never saved, the newest unsaved
    session's autosave whose session is not running."""
    if project_path is None:
        return _newest_untitled()
    auto = autosave_path(project_path)
    try:
        auto_time = auto.stat().st_mtime_ns
    except OSError:
        return None
    try:
        saved_time = os.stat(project_path).st_mtime_ns
    except OSError:
        return auto
    return auto if auto_time > saved_time else None


def _newest_untitled() -> Path | None:
    folder = _state_folder()
    try:
        names = os.listdir(folder)
    except OSError:
        return None
    found = []
    for name in names:
        match = _UNTITLED.fullmatch(name)
        if match is None or (match.group(1) and _running(int(match.group(1)))):
            continue
        try:
            found.append(((folder / name).stat().st_mtime_ns, folder / name))
        except OSError:
            continue
    return max(found)[1] if found else None


def _running(pid: int) -> bool:
    """Whether process ``pid`` runs (this one does). Windows cannot ask without a handle, so
    there only this process counts as running."""
    if pid == os.getpid():
        return True
    if os.name == "nt":
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:              # someone else's process
        return True
    return True


def discard_autosave(project_path=None, session: str | None = None) -> None:
    """Remove the autosave of ``project_path`` (of ``session`` for a project never saved)
    after a save, or when the user declines it."""
    remove_autosave_file(autosave_path(project_path, session))


def remove_autosave_file(path) -> None:
    """Remove the autosave file ``path`` (one offered and declined); gone already is fine."""
    try:
        Path(path).unlink()
    except FileNotFoundError:
        pass
