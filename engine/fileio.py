"""Atomic file writing: a save either completes or leaves the previous file untouched; and
reading that refuses what is not a regular file (:func:`read_regular_file`).

A write goes through ``.<name>.<random>.tmp`` beside the file. A process killed in the middle
of a write leaves that temporary file behind; the next write of the same file removes such
leftovers once they are stale (:func:`remove_stale_temporaries`).

A write never destroys what it should not: it goes through a symbolic link to the link's
target (the link stays), refuses a directory, a device or any other non-regular file, and the
commands check their outputs against their inputs before any work (:func:`check_outputs`).
"""
from __future__ import annotations

import errno
import os
import stat
import tempfile
import time
from contextlib import contextmanager

from .errors import MotionComposerError

try:                                    # POSIX: a writer holds a lock on its temporary file
    import fcntl
except ImportError:                     # Windows: leftovers are told by their age alone
    fcntl = None

__all__ = ["atomic_write", "remove_stale_temporaries", "FileWriteError", "STALE_TMP_S",
           "resolve_write_target", "check_output_path", "check_outputs", "read_regular_file"]

#: [s] a leftover temporary file last written longer ago than this, and (on POSIX) not locked
#: by a live writer, is removed by the next write of the same file
STALE_TMP_S = 60.0


class FileWriteError(MotionComposerError):
    """A file that could not be written (no such folder, no permission, disk full); the
    previous file, if any, is intact."""


def _kind(mode: int) -> str | None:
    """What a non-regular file is, in words (``None`` for a regular file)."""
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISFIFO(mode):
        return "a named pipe"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def resolve_write_target(path: str | os.PathLike) -> str:
    """The file a write to ``path`` replaces: the final target of a symbolic link (so that the
    link is kept and its target gets the new content), else ``path`` itself.

    Raises :class:`FileWriteError` when that file exists and is not a regular file (a folder,
    a device such as ``/dev/full``, a named pipe), or when its folder does not exist.
    """
    path = os.fspath(path)
    target = os.path.realpath(path) if os.path.islink(path) else path
    try:
        mode = os.stat(target).st_mode
    except FileNotFoundError:
        mode = None
    except OSError as exc:
        raise FileWriteError(f"{path}: cannot be written: {exc.strerror or exc}") from None
    kind = _kind(mode) if mode is not None else None
    if kind is not None:
        raise FileWriteError(f"{path}: cannot be written: it is {kind}, not a regular file")
    folder = os.path.dirname(os.path.abspath(target))
    if not os.path.isdir(folder):
        raise FileWriteError(f"{path}: cannot be written: the folder {folder} does not exist")
    return target


def _same_file(a: str, b: str) -> bool:
    """Whether paths ``a`` and ``b`` name one file (through links, hard links included)."""
    try:
        return os.path.samefile(a, b)
    except OSError:                            # one of them does not exist (yet)
        return os.path.realpath(a) == os.path.realpath(b)


def check_output_path(path: str | os.PathLike, inputs=(), *, label: str | None = None) -> None:
    """Refuse, before any work, an output ``path`` that cannot be written without destroying
    something: a folder, a device or other non-regular file, a missing folder
    (:func:`resolve_write_target`), or one of ``inputs`` (pairs ``(what, path)``: the files the
    same command reads, e.g. ``("the performer", "walk.bvh")``).

    ``label`` names the output in the message (the command-line flag, ``"-o"``); the error is
    a :class:`FileWriteError`.
    """
    path = os.fspath(path)
    shown = f"{label} {path}" if label else path
    try:
        resolve_write_target(path)
    except FileWriteError as exc:
        raise FileWriteError(f"{label} {exc}" if label else str(exc)) from None
    for what, source in inputs:
        if source is not None and _same_file(path, os.fspath(source)):
            raise FileWriteError(f"{shown}: is {what}, an input of this command; writing it "
                                 "would destroy it: choose another file")


def check_outputs(outputs, inputs=()) -> None:
    """:func:`check_output_path` for every ``(label, path)`` of ``outputs`` (``None`` paths
    skipped), and refuse two outputs that are one file."""
    given = [(label, os.fspath(path)) for label, path in outputs if path is not None]
    for i, (label, path) in enumerate(given):
        check_output_path(path, inputs, label=label)
        for other_label, other in given[:i]:
            if _same_file(path, other):
                raise FileWriteError(f"{label} {path}: is also the file of {other_label}; "
                                     "give each output its own file")


def atomic_write(path: str | os.PathLike, data: str | bytes, *, encoding: str = "utf-8") -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder, then rename.

    The temporary file is flushed and fsynced before :func:`os.replace`, so a crash at any
    moment leaves either the old file or the complete new one, never a half-written file.
    On POSIX the writer holds an exclusive ``flock`` on its temporary file until it is
    renamed, so that another process cleaning up leftovers never takes it for a dead one.
    Stale leftovers of earlier writes of ``path`` are removed first. A symbolic link is
    written through (its target is replaced, the link stays); a folder, device or other
    non-regular file is refused (:func:`resolve_write_target`).
    """
    path = resolve_write_target(path)
    folder = os.path.dirname(os.path.abspath(path))
    payload = data.encode(encoding) if isinstance(data, str) else data
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


@contextmanager
def reading(path, error, kind: str, missing: str = "no such file"):
    """Inside it, the operating system's errors reading ``path`` become ``error(message,
    path)`` (a typed file error) saying why: ``missing``, "this is a folder, not a ``kind``",
    or "cannot be read: ..." with the system's reason."""
    try:
        yield
    except FileNotFoundError:
        raise error(missing, path) from None
    except IsADirectoryError:
        raise error(f"this is a folder, not {kind}", path) from None
    except OSError as exc:
        raise error(f"cannot be read: {exc.strerror or exc}", path) from None


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
