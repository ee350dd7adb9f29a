"""The FBX document tree: what binary and ASCII FBX files both are, before any meaning.

An FBX file is a tree of named records (:class:`Node`), each with a list of typed values
(its *properties*) and child records. The binary form (:mod:`.binary`) and the ASCII form are
two spellings of the same tree; the scene reader interprets it and the writer builds one.

Property values carry their FBX type in their Python type, so a tree read from a file and
written back keeps every type code:

=========  =====================  ======================================
FBX code   meaning                Python value
=========  =====================  ======================================
``Y``      16-bit integer         ``numpy.int16``
``C``      boolean (one byte)     ``bool``
``I``      32-bit integer         ``numpy.int32``
``L``      64-bit integer         ``int`` (object ids, times in ticks)
``F``      32-bit float           ``numpy.float32``
``D``      64-bit float           ``float``
``S``      string                 ``str`` (UTF-8; binary ``Name\\x00\\x01Class`` is kept as is)
``R``      raw bytes              ``bytes``
``f``      float32 array          ``numpy.ndarray`` of dtype ``float32``
``d``      float64 array          ``numpy.ndarray`` of dtype ``float64``
``i``      int32 array            ``numpy.ndarray`` of dtype ``int32``
``l``      int64 array            ``numpy.ndarray`` of dtype ``int64``
``b``      boolean array          ``numpy.ndarray`` of dtype ``bool``
=========  =====================  ======================================
"""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Node", "FBX_TICKS_PER_SECOND", "type_code"]

#: FBX time unit: ticks per second (``KTime``)
FBX_TICKS_PER_SECOND = 46_186_158_000

_ARRAY_CODES = {np.dtype(np.float32): "f", np.dtype(np.float64): "d",
                np.dtype(np.int32): "i", np.dtype(np.int64): "l", np.dtype(np.bool_): "b"}


def type_code(value) -> str:
    """The FBX type code of a property value (see the module's table).

    Raises:
        TypeError: for a value with no FBX type (a programming error, not bad input).
    """
    if isinstance(value, bool | np.bool_):
        return "C"
    if isinstance(value, np.int16):
        return "Y"
    if isinstance(value, np.int32):
        return "I"
    if isinstance(value, int | np.int64):
        return "L"
    if isinstance(value, np.float32):
        return "F"
    if isinstance(value, float | np.float64):
        return "D"
    if isinstance(value, str):
        return "S"
    if isinstance(value, bytes):
        return "R"
    if isinstance(value, np.ndarray) and value.ndim == 1 and value.dtype in _ARRAY_CODES:
        return _ARRAY_CODES[value.dtype]
    raise TypeError(f"no FBX property type for {type(value).__name__}")


@dataclass
class Node:
    """One FBX record: ``name``, its typed ``props`` and its ``children`` in file order.

    Attributes:
        offset: where the record starts in its file (byte offset for binary files, line for
            ASCII), for error messages; ``None`` for a tree built in memory.
    """

    name: str
    props: list = field(default_factory=list)
    children: list["Node"] = field(default_factory=list)
    offset: int | None = None

    def find(self, name: str) -> "Node | None":
        """The first child called ``name``, or ``None``."""
        for child in self.children:
            if child.name == name:
                return child
        return None

    def find_all(self, name: str) -> Iterator["Node"]:
        """Every child called ``name``, in file order."""
        return (child for child in self.children if child.name == name)

    def walk(self) -> Iterator["Node"]:
        """This node and every node below it, depth first in file order."""
        stack = [self]
        while stack:
            node = stack.pop()
            yield node
            stack.extend(reversed(node.children))
