"""ASCII FBX 7.x text of a document tree, as the FBX SDK spells it, for the tests.

The shared data has one ASCII FBX 7.x file (a NURBS scene, no character); the ASCII copies
of the binary characters made here let the tests read one scene in both forms and fuzz the
ASCII reader on characters. The spelling follows ``nurbs_ascii_7200.fbx``: ``Name: values``
per line, children in braces, arrays as ``*N { a: ... }``, object names (``"Name\\x00\\x01Class"``
in binary) as ``"Class::Name"``,
booleans as ``T``/``F``; raw bytes (``R``, only the header's ``FileId`` and the like) become
empty strings.
"""
from __future__ import annotations

import numpy as np

from motion_composer.engine.formats.fbx.nodes import Node


def _value(value) -> str:
    if isinstance(value, (bool, np.bool_)):
        return "T" if value else "F"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    if isinstance(value, bytes):
        return '""'
    if isinstance(value, str):
        if "\x00\x01" in value:
            name, _, cls = value.partition("\x00\x01")
            value = f"{cls}::{name}"
        return '"' + value.replace('"', "&quot;") + '"'
    array = np.asarray(value)
    numbers = [str(int(v)) for v in array] if array.dtype.kind in "biu" else \
        [repr(float(v)) for v in array]
    return f"*{len(array)} {{\n\ta: {','.join(numbers)}\n}}"


def _record(node: Node, depth: int, out: list[str]) -> None:
    pad = "\t" * depth
    values = ", ".join(_value(v) for v in node.props)
    line = f"{pad}{node.name}: {values}".rstrip()
    if node.children or not node.props:
        out.append(line + " {")
        for child in node.children:
            _record(child, depth + 1, out)
        out.append(pad + "}")
    else:
        out.append(line)


def ascii_fbx(root: Node) -> bytes:
    """The ASCII FBX text of the tree ``root`` (a parsed file's root, named ``"FBX"``)."""
    out = [f"; FBX {int(root.props[0]) // 1000}.{int(root.props[0]) % 1000 // 100}.0 project "
           "file", "; written by the Motion Composer tests", ""]
    for child in root.children:
        _record(child, 0, out)
    return ("\n".join(out) + "\n").encode("utf-8")
