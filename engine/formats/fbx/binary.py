"""Binary FBX: bytes to the document tree (:class:`~.nodes.Node`).

The layout (documented by Blender's and ufbx's readers, and checked on the files in
``shared/data/fbx``): a 23-byte magic ``b"Kaydara FBX Binary  \\x00\\x1a\\x00"``, a little-endian
``uint32`` version (7100-7700; 7500 and later widen record offsets to 64 bits), then records
until an empty one. A record is ``end_offset, property_count, property_bytes`` (``uint32`` or
``uint64``), a name length byte and the name, its properties, then its children ended by an
empty record (present whenever the record has children, or no properties). Each property is a
type code and its value; arrays carry ``length, encoding, byte_length`` and are raw
(encoding 0) or zlib-deflated (1).

Every malformed or truncated input raises :class:`~engine.errors.FBXError` naming the byte
offset and what was expected; nothing here can crash the process.
"""
from __future__ import annotations

import struct
import zlib

import numpy as np

from ...errors import FBXError
from .nodes import Node

__all__ = ["MAGIC", "is_binary_fbx", "binary_version", "parse_binary"]

MAGIC = b"Kaydara FBX Binary  \x00\x1a\x00"
_HEADER = len(MAGIC) + 4
_OLDEST, _NEWEST = 7100, 7700
_MAX_DEPTH = 64                 # real files nest under 10 deep
_SCALARS = {"Y": ("<h", np.int16), "C": ("<?", bool), "I": ("<i", np.int32),
            "F": ("<f", np.float32), "D": ("<d", float), "L": ("<q", int)}
_ARRAYS = {"f": np.dtype("<f4"), "d": np.dtype("<f8"), "i": np.dtype("<i4"),
           "l": np.dtype("<i8"), "b": np.dtype(np.bool_)}


def is_binary_fbx(head: bytes) -> bool:
    """Whether ``head`` (a file's first bytes) starts like a binary FBX file."""
    return head.startswith(MAGIC[:20])


def binary_version(data: bytes) -> int:
    """The version number in a binary FBX header (7400 for FBX 7.4)."""
    if len(data) < _HEADER or not data.startswith(MAGIC):
        raise FBXError("not a binary FBX file (expected the header 'Kaydara FBX Binary')",
                       where="header")
    return struct.unpack_from("<I", data, len(MAGIC))[0]


class _Reader:
    def __init__(self, data: bytes, path, wide: bool):
        self.data = memoryview(data)
        self.size = len(data)
        self.path = path
        self.offset_format = "<QQQ" if wide else "<III"
        self.offset_size = 24 if wide else 12

    def fail(self, problem: str, at: int, where: str = ""):
        place = f"byte {at}" + (f" ({where})" if where else "")
        raise FBXError(problem, self.path, where=place)

    def need(self, at: int, count: int, what: str) -> None:
        if count < 0 or at + count > self.size:
            self.fail(f"the file ends inside {what} (it is truncated)", at)

    def records(self, at: int, end: int, depth: int, parent: str) -> tuple[list[Node], int]:
        """The records from ``at`` until an empty record (or ``end`` for the top level)."""
        nodes = []
        while True:
            if depth == 0 and at + self.offset_size + 1 > end:
                return nodes, at                     # files without a final empty record
            self.need(at, self.offset_size + 1, f"a record header in {parent}")
            record_end, count, prop_bytes = struct.unpack_from(self.offset_format, self.data,
                                                               at)
            name_length = self.data[at + self.offset_size]
            if record_end == 0:
                if count or prop_bytes or name_length:
                    self.fail("an empty record with properties (the file is corrupt)", at,
                              parent)
                return nodes, at + self.offset_size + 1
            if not at < record_end <= end:
                self.fail(f"a record ending at byte {record_end}, outside its parent "
                          f"{parent} (bytes {at}-{end}; the file is corrupt or truncated)", at)
            nodes.append(self.record(at, record_end, count, prop_bytes, name_length, depth,
                                     parent))
            at = record_end

    def record(self, at, record_end, count, prop_bytes, name_length, depth, parent) -> Node:
        start = at + self.offset_size + 1
        self.need(start, name_length, "a record name")
        try:
            name = bytes(self.data[start:start + name_length]).decode("ascii")
        except UnicodeDecodeError:
            self.fail("a record name that is not ASCII (the file is corrupt)", at, parent)
        path = f"{parent}/{name}" if parent else name
        if depth >= _MAX_DEPTH:
            self.fail(f"records nested over {_MAX_DEPTH} deep (the file is corrupt)", at, path)
        props_at = start + name_length
        props_end = props_at + prop_bytes
        if props_end > record_end:
            self.fail(f"properties ({prop_bytes} bytes) longer than their record", at, path)
        props = []
        cursor = props_at
        for _ in range(count):
            value, cursor = self.prop(cursor, props_end, path)
            props.append(value)
        if cursor != props_end:
            self.fail(f"{count} properties taking {cursor - props_at} bytes where the record "
                      f"says {prop_bytes}", at, path)
        children = []
        if props_end < record_end:
            children, after = self.records(props_end, record_end, depth + 1, path)
            if after != record_end:
                self.fail(f"child records end at byte {after}, the record at {record_end}",
                          at, path)
        return Node(name, props, children, offset=at)

    def prop(self, at: int, end: int, path: str):
        self.need(at, 1, "a property type")
        if at >= end:
            self.fail("more properties than the record holds", at, path)
        code = chr(self.data[at])
        at += 1
        if code in _SCALARS:
            fmt, kind = _SCALARS[code]
            size = struct.calcsize(fmt)
            self.need(at, size, f"a '{code}' property")
            return kind(struct.unpack_from(fmt, self.data, at)[0]), at + size
        if code in ("S", "R"):
            self.need(at, 4, "a string length")
            (length,) = struct.unpack_from("<I", self.data, at)
            self.need(at + 4, length, f"a {length}-byte string")
            raw = bytes(self.data[at + 4:at + 4 + length])
            if code == "R":
                return raw, at + 4 + length
            return raw.decode("utf-8", errors="surrogateescape"), at + 4 + length
        if code in _ARRAYS:
            self.need(at, 12, "an array header")
            length, encoding, stored = struct.unpack_from("<III", self.data, at)
            at += 12
            self.need(at, stored, f"a {stored}-byte array")
            dtype = _ARRAYS[code]
            expected = length * dtype.itemsize
            raw = bytes(self.data[at:at + stored])
            if encoding == 1:
                try:
                    inflater = zlib.decompressobj()
                    raw = inflater.decompress(raw, expected + 1)
                except zlib.error as exc:
                    self.fail(f"a compressed '{code}' array that does not inflate ({exc})",
                              at, path)
            elif encoding != 0:
                self.fail(f"array encoding {encoding} (expected 0, raw, or 1, zlib)", at, path)
            if len(raw) != expected:
                self.fail(f"a '{code}' array of {length} values holding {len(raw)} bytes "
                          f"(expected {expected})", at, path)
            values = np.frombuffer(raw, dtype=dtype).astype(dtype.newbyteorder("="))
            return values, at + stored
        self.fail(f"unknown property type {code!r} (expected one of YCILFDSRfdilb)", at - 1,
                  path)


def parse_binary(data: bytes, path=None) -> Node:
    """The document tree of a binary FBX file's bytes: a root :class:`Node` named ``"FBX"``
    whose one property is the file's version (``numpy.int32``, 7400 for FBX 7.4) and whose
    children are the file's top-level records (``FBXHeaderExtension``, ``GlobalSettings``,
    ``Objects``, ``Connections``, ...).

    Raises:
        FBXError: not binary FBX, a version outside 7.1-7.7 (FBX 5 and 6 binary files are
            refused by name), or a malformed or truncated file.
    """
    version = binary_version(data) if data.startswith(MAGIC) else None
    if version is None:
        raise FBXError("not a binary FBX file (expected the header 'Kaydara FBX Binary')",
                       path, where="header")
    if not _OLDEST <= version <= _NEWEST:
        problem = (f"binary FBX version {version} is older than FBX 7.1 (FBX 6 and older are "
                   f"not read: re-export the file as FBX 7.x)" if version < _OLDEST else
                   f"binary FBX version {version} is newer than the FBX 7.7 this reader knows")
        raise FBXError(problem, path, where="header")
    reader = _Reader(data, path, wide=version >= 7500)
    nodes, _ = reader.records(_HEADER, len(data), 0, "")
    return Node("FBX", [np.int32(version)], nodes, offset=0)
