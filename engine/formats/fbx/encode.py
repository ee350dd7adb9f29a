"""The document tree (:class:`~.nodes.Node`) to binary FBX bytes: the inverse of
:func:`~.binary.parse_binary`.

The layout written is the one the FBX SDK writes (and Blender's exporter; checked against the
files in ``shared/data/fbx``):

* the 23-byte magic ``b"Kaydara FBX Binary  \\x00\\x1a\\x00"`` and the ``uint32`` version;
* the records, each ``end_offset, property_count, property_bytes`` (``uint32`` up to 7.4,
  ``uint64`` from 7.5), the name's length byte and name, the properties, then the children
  closed by an empty record (13 zero bytes in 7.4, 25 from 7.5). A record gets that closing
  record when it has children *or no properties*; a record with properties and no children
  ends right after them, except ``AnimationLayer`` and ``AnimationStack`` (:data:`ALWAYS_CLOSED`:
  every real file here closes its childless ``AnimationLayer``, and Blender's exporter does the
  same for both). The top-level list is closed by an empty record too;
* arrays longer than :data:`DEFLATE_ABOVE` bytes zlib-deflated (encoding 1), shorter ones raw;
* the footer: a 16-byte footer code, 4 zero bytes, zero padding to the next multiple of 16
  (a full 16 when already aligned), the version again, 120 zero bytes and a fixed 16-byte
  closing magic.

The FBX SDK checks a binary file's ``FileId`` and footer code against its ``CreationTime``;
:data:`CREATION_TIME`, :data:`FILE_ID` and :data:`FOOTER_ID` are one consistent triple (the one
Blender's exporter writes, which the SDK and the tools built on it accept), so a writer that puts
:data:`CREATION_TIME` and :data:`FILE_ID` in its tree gets files the SDK opens.
"""
from __future__ import annotations

import struct
import zlib

import numpy as np

from ...errors import ExportError
from .binary import MAGIC
from .nodes import Node, type_code

__all__ = ["encode_binary", "DEFLATE_ABOVE", "ALWAYS_CLOSED", "CREATION_TIME", "FILE_ID",
           "FOOTER_ID"]

#: arrays of more bytes than this are deflated (the size FBX converters use)
DEFLATE_ABOVE = 128
#: records closed by an empty record even with properties and no children
ALWAYS_CLOSED = frozenset({"AnimationLayer", "AnimationStack"})
#: the ``CreationTime`` string that :data:`FILE_ID` and :data:`FOOTER_ID` belong to
CREATION_TIME = "1970-01-01 10:00:00:000"
#: the ``FileId`` (raw bytes) matching :data:`CREATION_TIME`
FILE_ID = bytes.fromhex("28b32aebb624ccc2bfc8b02aa92bfcf1")
#: the footer code matching :data:`CREATION_TIME`
FOOTER_ID = bytes.fromhex("fabcab09d0c8d466b176fb831cf7267e")
_CLOSING_MAGIC = bytes.fromhex("f85a8c6adef5d97eece90ce3758f290b")
_OLDEST, _NEWEST = 7100, 7700
_ZLIB_LEVEL = 6
_SCALAR_FORMATS = {"Y": "<h", "C": "<?", "I": "<i", "L": "<q", "F": "<f", "D": "<d"}
_ARRAY_DTYPES = {"f": "<f4", "d": "<f8", "i": "<i4", "l": "<i8", "b": "|b1"}


class _Writer:
    def __init__(self, wide: bool):
        self.out = bytearray()
        self.header = struct.Struct("<QQQ" if wide else "<III")
        self.empty = bytes(self.header.size + 1)
        self.limit = 2 ** 64 if wide else 2 ** 32

    def record(self, node: Node) -> None:
        name = node.name.encode("ascii")
        if len(name) > 255:
            raise ValueError(f"FBX record name longer than 255 bytes: {node.name[:40]!r}...")
        start = len(self.out)
        self.out += self.empty                       # the header, filled in below
        self.out[start + self.header.size] = len(name)
        self.out += name
        props_at = len(self.out)
        for value in node.props:
            self.prop(value)
        props_bytes = len(self.out) - props_at
        if node.children or not node.props or node.name in ALWAYS_CLOSED:
            for child in node.children:
                self.record(child)
            self.out += self.empty
        end = len(self.out)
        if end >= self.limit:
            raise ExportError(f"the FBX document passes {self.limit // 2 ** 30} GiB, the most "
                              "FBX 7.4's 32-bit record offsets reach: write fewer frames "
                              "(--frames, --fps)")
        self.header.pack_into(self.out, start, end, len(node.props), props_bytes)

    def prop(self, value) -> None:
        code = type_code(value)
        self.out += code.encode("ascii")
        if code in _SCALAR_FORMATS:
            self.out += struct.pack(_SCALAR_FORMATS[code], value)
        elif code in ("S", "R"):
            raw = value.encode("utf-8", errors="surrogateescape") if code == "S" else value
            self.out += struct.pack("<I", len(raw)) + raw
        else:
            raw = np.ascontiguousarray(value, dtype=_ARRAY_DTYPES[code]).tobytes()
            encoding = 0
            if len(raw) > DEFLATE_ABOVE:
                raw, encoding = zlib.compress(raw, _ZLIB_LEVEL), 1
            self.out += struct.pack("<III", len(value), encoding, len(raw)) + raw


def encode_binary(root: Node, version: int = 7400) -> bytes:
    """The bytes of a binary FBX file holding ``root``'s children as its top-level records.

    ``root`` is a document tree as :func:`~.binary.parse_binary` returns it (a node named
    ``"FBX"``; its own properties, the version it was read with, are not written): ``version``
    (7100-7700; 7400 for FBX 7.4) is the one written, with 64-bit record offsets from 7500.
    Property values must carry their FBX type (see :mod:`.nodes`).

    Raises:
        ExportError: for a 7.1-7.4 document over 4 GiB (a motion too long for FBX 7.4).
        ValueError: for a version outside 7.1-7.7 or a record name that is not ASCII or longer
            than 255 bytes (programming errors: the tree is built by the writer).
        TypeError: for a property value with no FBX type.
    """
    if not _OLDEST <= version <= _NEWEST:
        raise ValueError(f"FBX binary version {version} is outside 7100-7700")
    writer = _Writer(wide=version >= 7500)
    writer.out += MAGIC + struct.pack("<I", version)
    for node in root.children:
        writer.record(node)
    writer.out += writer.empty
    writer.out += FOOTER_ID + bytes(4)
    writer.out += bytes(16 - len(writer.out) % 16)
    writer.out += struct.pack("<I", version) + bytes(120) + _CLOSING_MAGIC
    return bytes(writer.out)
