"""The engine's typed errors.

Every error a user can cause (a malformed file, an impossible mapping, a corrupt project) is
an instance of :class:`MotionComposerError`, so callers catch one class and show its message.
Messages say where (file and line where there is one) and what was expected, in words a person
can act on; the command-line interface prints them on one line.
"""
from __future__ import annotations

import os

__all__ = [
    "MotionComposerError",
    "FileFormatError",
    "BVHError",
    "GLTFError",
    "FBXError",
    "UnknownFormatError",
    "UnsupportedFormatError",
    "ExportError",
    "SkeletonError",
    "MappingError",
    "IKOptionsError",
]


class MotionComposerError(Exception):
    """Base class of every error the engine raises on bad input."""


class FileFormatError(MotionComposerError):
    """A file that cannot be read: it names the file, the line (if known) and what was expected.

    Attributes:
        path: the file's path as given (``None`` for text that came from no file).
        line: 1-based line number, or ``None`` when the problem is not on one line.
        problem: the message without the location prefix.
    """

    def __init__(self, problem: str, path: str | os.PathLike | None = None,
                 line: int | None = None):
        self.path = os.fspath(path) if path is not None else None
        self.line = line
        self.problem = problem
        where = self.path or "<text>"
        if line is not None:
            where = f"{where}:{line}"
        super().__init__(f"{where}: {problem}")


class BVHError(FileFormatError):
    """A BVH file that is malformed or holds values that cannot be used."""


class GLTFError(FileFormatError):
    """A glTF 2.0 file (``.glb`` or ``.gltf``) that is malformed or uses what the reader cannot.

    Attributes:
        where: the JSON path of the offending value (``"accessors[12].count"``), or a part of
            the binary container (``"GLB header"``), or ``None``.
    """

    def __init__(self, problem: str, path: str | os.PathLike | None = None,
                 where: str | None = None):
        self.where = where
        super().__init__(f"{where}: {problem}" if where else problem, path)
        self.problem = problem


class FBXError(FileFormatError):
    """An FBX file (binary or ASCII) that is malformed, truncated or holds what the reader
    cannot use.

    Attributes:
        where: the part of the file (``"node Objects/Model at byte 1234"``, ``"header"``), or
            ``None``.
    """

    def __init__(self, problem: str, path: str | os.PathLike | None = None,
                 where: str | None = None, line: int | None = None):
        self.where = where
        super().__init__(f"{where}: {problem}" if where else problem, path, line)
        self.problem = problem


class UnknownFormatError(FileFormatError):
    """A file whose content is none of the formats the application reads (see
    :mod:`engine.formats`); the message names the formats it knows."""


class UnsupportedFormatError(FileFormatError):
    """A file in a format that is recognised but not read or written (FBX), an output path
    whose suffix no writer writes, or a file used where its format cannot serve (a glTF
    character as the performer)."""


class ExportError(MotionComposerError):
    """A motion that cannot be written in the requested form."""


class SkeletonError(MotionComposerError):
    """A skeleton that is inconsistent (a parent after its child, a duplicate name, ...)."""


class MappingError(MotionComposerError):
    """A joint correspondence that cannot be used (unknown joint, inverted ancestry, ...).

    Attributes:
        path: the mapping file, when the mapping came from one.
    """

    def __init__(self, problem: str, path=None):
        self.path = os.fspath(path) if path is not None else None
        self.problem = problem
        super().__init__(f"{self.path}: {problem}" if self.path else problem)


class IKOptionsError(MotionComposerError):
    """An inverse-kinematics setting out of its range (a negative damping, a NaN tolerance).

    Attributes:
        field: the :class:`~engine.correction.ik.IKOptions` field (``"damping"``).
        problem: the message without the field.
    """

    def __init__(self, field: str, problem: str):
        self.field = field
        self.problem = problem
        super().__init__(f"IK option {field}: {problem}")

    def __reduce__(self):                     # survives pickling (worker processes)
        return type(self), (self.field, self.problem)
