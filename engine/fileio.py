"""Atomic file writing: a save either completes or leaves the previous file untouched; and
reading that refuses what is not a regular file."""
from __future__ import annotations

import errno
import os
import stat
import tempfile

from .errors import MotionComposerError

__all__ = ["atomic_write", "FileWriteError", "read_regular_file"]


class FileWriteError(MotionComposerError):
    """A file that could not be written (no such folder, no permission, disk full); the
    previous file, if any, is intact."""


def atomic_write(path: str | os.PathLike, data: str | bytes, *, encoding: str = "utf-8") -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder, then rename.

    The temporary file is flushed and fsynced before :func:`os.replace`, so a crash at any
    moment leaves either the old file or the complete new one, never a half-written file.
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


def read_regular_file(path: str | os.PathLike) -> bytes:
    """The bytes of the regular file at ``path``; a folder, a device (``/dev/zero`` would be
    read forever), a pipe or a socket is refused before anything is read, and opening a pipe
    does not wait for a writer.

    Raises:
        FileNotFoundError: no such file.
        IsADirectoryError: a folder.
        OSError: any other file that is not regular (``strerror`` says so), or one that cannot
            be read.
    """
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
    with os.fdopen(fd, "rb") as handle:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise IsADirectoryError(errno.EISDIR, "this is a folder", os.fspath(path))
        if not stat.S_ISREG(mode):
            raise OSError(errno.EINVAL, "not a regular file (a device, pipe or socket)",
                          os.fspath(path))
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return handle.read()
