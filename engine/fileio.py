"""Atomic file writing: a save either completes or leaves the previous file untouched.

A write goes through ``.<name>.<random>.tmp`` beside the file. A process killed in the middle
of a write leaves that temporary file behind; the next write of the same file removes such
leftovers once they are stale (:func:`remove_stale_temporaries`).
"""
from __future__ import annotations

import os
import tempfile
import time

from .errors import MotionComposerError

try:                                    # POSIX: a writer holds a lock on its temporary file
    import fcntl
except ImportError:                     # Windows: leftovers are told by their age alone
    fcntl = None

__all__ = ["atomic_write", "remove_stale_temporaries", "FileWriteError", "STALE_TMP_S"]

#: [s] a leftover temporary file last written longer ago than this, and (on POSIX) not locked
#: by a live writer, is removed by the next write of the same file
STALE_TMP_S = 60.0


class FileWriteError(MotionComposerError):
    """A file that could not be written (no such folder, no permission, disk full); the
    previous file, if any, is intact."""


def atomic_write(path: str | os.PathLike, data: str | bytes, *, encoding: str = "utf-8") -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder, then rename.

    The temporary file is flushed and fsynced before :func:`os.replace`, so a crash at any
    moment leaves either the old file or the complete new one, never a half-written file.
    On POSIX the writer holds an exclusive ``flock`` on its temporary file until it is
    renamed, so that another process cleaning up leftovers never takes it for a dead one.
    Stale leftovers of earlier writes of ``path`` are removed first.
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    payload = data.encode(encoding) if isinstance(data, str) else data
    if not os.path.isdir(folder):
        raise FileWriteError(f"{path}: cannot be written: the folder {folder} does not exist")
    try:
        fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp",
                                   dir=folder)
    except OSError as exc:
        raise FileWriteError(f"{path}: cannot be written: {exc.strerror or exc}") from None
    try:
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX)
        remove_stale_temporaries(path, keep=tmp)
        # mkstemp makes the file private (0600): give it the mode the file had, or the
        # ordinary one a new file gets (0666 less the umask)
        try:
            mode = os.stat(path).st_mode & 0o7777
        except FileNotFoundError:
            umask = os.umask(0)
            os.umask(umask)
            mode = 0o666 & ~umask
        os.chmod(tmp, mode)
        with os.fdopen(fd, "wb") as handle:
            handle.write(payload)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(exc, OSError):
            raise FileWriteError(f"{path}: cannot be written: {exc.strerror or exc}") from None
        raise


def _temporary_names(path: str) -> tuple[str, str]:
    """The prefix and suffix of :func:`atomic_write`'s temporary files for ``path``."""
    return "." + os.path.basename(path) + ".", ".tmp"


def remove_stale_temporaries(path: str | os.PathLike, *, keep: str | None = None,
                             now: float | None = None) -> list[str]:
    """Remove the temporary files that killed writes of ``path`` left beside it, and return
    their paths.

    A leftover is ``.<name>.<random>.tmp`` (the random part has no dot, so the temporary files
    of ``<name>.bak`` are not taken for this file's) other than ``keep``. It is removed only
    when it is stale: last written more than :data:`STALE_TMP_S` seconds before ``now`` (the
    clock, by default) and, on POSIX, not locked, i.e. no live process is writing it (a killed
    writer's lock goes with it). The age also covers the instant between a writer creating
    its file and locking it. Files that cannot be examined are left alone."""
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    prefix, suffix = _temporary_names(path)
    now = time.time() if now is None else now
    removed = []
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    for name in names:
        middle = name[len(prefix):-len(suffix)]
        if not (name.startswith(prefix) and name.endswith(suffix)) or not middle or \
                "." in middle:
            continue
        candidate = os.path.join(folder, name)
        if keep is not None and os.path.abspath(candidate) == os.path.abspath(keep):
            continue
        if _remove_if_stale(candidate, now):
            removed.append(candidate)
    return removed


def _remove_if_stale(candidate: str, now: float) -> bool:
    try:
        fd = os.open(candidate, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return False
    try:
        info = os.fstat(fd)
        if now - info.st_mtime <= STALE_TMP_S:
            return False
        if fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:                 # a live writer holds it
                return False
        try:
            os.unlink(candidate)
        except OSError:
            return False
        return True
    finally:
        os.close(fd)
