"""ASCII FBX 7.x (and 6.x): text to the document tree (:class:`~.nodes.Node`), the binary
form's twin.

The syntax (as the FBX SDK writes it, e.g. ``nurbs_ascii_7200.fbx``): ``;`` starts a comment
to the end of the line; a record is ``Name: value, value, ...`` ended by the line's end (a
value list may continue on the next line after a comma), optionally followed by ``{`` its
child records ``}``. Values are numbers, double-quoted strings (``&quot;`` stands for a quote),
bare words (``T``, ``Y``, ``W``...) and arrays ``*N { a: v, v, ... }``.

Typed values, so that the scene reader sees one tree whichever form the file is in:

* integers are ``int``, other numbers ``float``; bare ``T``/``Y`` are ``True`` and ``F``/``N``
  ``False`` (the binary form's ``C``), other bare words ``str``;
* arrays are ``numpy.ndarray``: ``int64`` when every value is written as an integer, else
  ``float64`` (the scene reader converts them to what it needs);
* an object's name ``"Class::Name"`` (the second value of a record directly under
  ``Objects``, the first of ``SceneInfo``) becomes the binary form's
  ``"Name\\x00\\x01Class"``.

The root is a :class:`Node` named ``"FBX"`` whose one property is the file's version
(``FBXHeaderExtension/FBXVersion``, ``numpy.int32``), as :func:`~.binary.parse_binary` gives.
Every record's :attr:`Node.offset` is its line number. Malformed text raises
:class:`~engine.errors.FBXError` naming the line. FBX 6 text has the same syntax (its lists
of numbers are plain values, not ``*N`` arrays); :mod:`.legacy` rewrites its tree for the
scene reader. FBX 5 and older are refused by name.
"""
from __future__ import annotations

import re

import numpy as np

from ...errors import FBXError
from .nodes import Node

__all__ = ["is_ascii_fbx", "parse_ascii"]

_OLDEST, _NEWEST = 6000, 7700
_MAX_DEPTH = 64
_TOKEN = re.compile(r"""
    (?P<space>[ \t\r\f\v]+)
  | (?P<comment>;[^\n]*)
  | (?P<newline>\n)
  | (?P<string>"[^"]*")
  | (?P<key>[A-Za-z_][\w|\-]*[ \t]*:)
  | (?P<array>\*[0-9]+)
  | (?P<number>[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?)
  | (?P<word>[A-Za-z_][\w.#\-]*)
  | (?P<punct>[{},])
""", re.VERBOSE)
_INTEGER = re.compile(r"[-+]?[0-9]+\Z")
_TOO_OLD = "FBX 5 and older are not read (FBX 6.x ASCII and 7.x are): re-export as FBX 7"
_BOOLEANS = {"T": True, "Y": True, "F": False, "N": False}


def is_ascii_fbx(head: bytes) -> bool:
    """Whether ``head`` (a file's first bytes) starts like ASCII FBX: a ``; FBX`` comment or
    the ``FBXHeaderExtension`` record, after an optional byte-order mark and blank space."""
    start = head.removeprefix(b"\xef\xbb\xbf").lstrip(b" \t\n\r\x0b\x0c")
    return start.startswith(b"; FBX") or start.startswith(b"FBXHeaderExtension")


class _Parser:
    def __init__(self, text: str, path):
        self.text = text
        self.path = path
        self.pos = 0
        self.line = 1
        self.peeked: tuple[str, str, int] | None = None

    def fail(self, problem: str, line: int | None = None):
        raise FBXError(problem, self.path, line=line or self.line)

    def next(self) -> tuple[str, str, int]:
        """The next significant token: ``(kind, text, line)``; kind ``"end"`` at the end."""
        if self.peeked is not None:
            token, self.peeked = self.peeked, None
            return token
        text = self.text
        while True:
            if self.pos >= len(text):
                return "end", "", self.line
            match = _TOKEN.match(text, self.pos)
            if match is None:
                self.fail(f"unexpected character {text[self.pos]!r} (expected a record "
                          "name, a value, a comma or a brace)")
            kind = match.lastgroup
            self.pos = match.end()
            line = self.line
            if kind == "newline":
                self.line += 1
                return kind, "\n", line
            if kind == "string":
                self.line += match.group().count("\n")
            if kind not in ("space", "comment"):
                return kind, match.group(), line

    def peek(self) -> tuple[str, str, int]:
        if self.peeked is None:
            self.peeked = self.next()
        return self.peeked

    def skip_newlines(self) -> tuple[str, str, int]:
        while self.peek()[0] == "newline":
            self.next()
        return self.peek()

    def records(self, depth: int, parent: str) -> list[Node]:
        """The records up to the closing brace of ``parent`` (the end of the file at the top)."""
        nodes = []
        while True:
            kind, text, line = self.skip_newlines()
            if kind == "end":
                if depth:
                    self.fail(f"the file ends inside {parent} (a '}}' is missing: the file is "
                              "truncated)")
                return nodes
            if text == "}":
                if not depth:
                    self.fail("a '}' closing nothing", line)
                self.next()
                return nodes
            if kind != "key":
                self.fail(f"expected a record name followed by ':', found {text[:40]!r}", line)
            self.next()
            nodes.append(self.record(text[:-1].rstrip(), line, depth, parent))

    def record(self, name: str, line: int, depth: int, parent: str) -> Node:
        path = f"{parent}/{name}" if parent else name
        if depth >= _MAX_DEPTH:
            self.fail(f"records nested over {_MAX_DEPTH} deep (the file is corrupt)", line)
        props = []
        children: list[Node] = []
        while True:
            kind, text, at = self.peek()
            if kind in ("newline", "end") or text == "}":
                break
            if text == "{":
                self.next()
                children = self.records(depth + 1, path)
                break
            if text == ",":
                if not props:
                    self.fail(f"a comma before the first value of {path}", at)
                self.next()
                kind, text, at = self.skip_newlines()
                if kind == "end" or text in ("{", "}", ","):
                    self.fail(f"expected a value after the comma in {path}, found "
                              f"{text or 'the end of the file'!r}", at)
            elif props:
                self.fail(f"expected a comma between the values of {path}, found "
                          f"{text[:40]!r}", at)
            props.append(self.value(path))
        k = 1 if parent == "Objects" else 0 if name == "SceneInfo" else None
        if k is not None and len(props) > k and isinstance(props[k], str) and "::" in props[k]:
            cls, _, obj = props[k].partition("::")
            props[k] = f"{obj}\x00\x01{cls}"
        return Node(name, props, children, offset=line)

    def value(self, path: str):
        kind, text, at = self.next()
        if kind == "number":
            if not _INTEGER.match(text):
                return float(text)
            number = int(text)
            if not -2 ** 63 <= number < 2 ** 63:
                self.fail(f"the integer {text[:40]} in {path} is beyond 64 bits", at)
            return number
        if kind == "string":
            return text[1:-1].replace("&quot;", '"')
        if kind == "word":
            return _BOOLEANS.get(text, text)
        if kind == "array":
            return self.array(int(text[1:]), path, at)
        self.fail(f"expected a value in {path}, found {text[:40]!r}", at)

    def array(self, count: int, path: str, at: int) -> np.ndarray:
        """``*N { a: v, ... }`` after ``*N``: the ``N`` values, read in one go."""
        kind, text, _ = self.skip_newlines()
        if text != "{":
            self.fail(f"expected '{{' after the array size *{count} in {path}", at)
        self.next()
        kind, text, line = self.skip_newlines()
        if kind != "key" or text[:-1].rstrip() != "a":
            self.fail(f"expected 'a:' and the values of the array in {path}", line)
        self.next()
        close = self.text.find("}", self.pos)
        if close < 0:
            self.fail(f"the file ends inside the array of {path} (it is truncated)", line)
        body = self.text[self.pos:close]
        self.pos = close + 1
        self.line += body.count("\n")
        items = [item for item in re.split(r"[,\s]+", body.strip()) if item] if body.strip() \
            else []
        if len(items) != count:
            self.fail(f"the array of {path} says *{count} values but holds {len(items)}",
                      line)
        integers = not re.search(r"[.eEnN]", body)
        try:
            return np.array(items, dtype=np.int64 if integers else np.float64)
        except OverflowError:
            self.fail(f"the array of {path} holds an integer beyond 64 bits", line)
        except ValueError:
            bad = next((s for s in items if not _number(s)), items[0] if items else "")
            self.fail(f"the array of {path} holds {bad[:40]!r}, not a number", line)


def _number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _version(nodes: list[Node], path) -> int:
    header = next((n for n in nodes if n.name == "FBXHeaderExtension"), None)
    record = header.find("FBXVersion") if header is not None else None
    if record is None or not record.props or not isinstance(record.props[0], int):
        raise FBXError("no FBXHeaderExtension/FBXVersion (an ASCII FBX file states its "
                       "version there)", path, line=header.offset if header else 1)
    return record.props[0]


def parse_ascii(data: bytes, path=None) -> Node:
    """The document tree of an ASCII FBX 6.x or 7.x file's bytes (see the module notes).

    Raises:
        FBXError: text that is not UTF-8, malformed records (naming the line), no version,
            FBX 5 and older or a version newer than 7.7.
    """
    major = re.search(rb"FBXVersion:\s*([0-9]+)", data[:4096])
    if major and int(major.group(1)) < _OLDEST:
        raise FBXError(_TOO_OLD, path, line=data[:major.start()].count(b"\n") + 1)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise FBXError(f"byte {exc.start} is not UTF-8 text (a truncated or corrupt ASCII FBX "
                       "file)", path, line=line) from None
    if "\x00" in text:
        raise FBXError("a NUL byte in ASCII FBX text (the file is corrupt)", path,
                       line=text[:text.index("\x00")].count("\n") + 1)
    nodes = _Parser(text, path).records(0, "")
    version = _version(nodes, path)
    if version < _OLDEST:
        raise FBXError(_TOO_OLD, path)
    if version > _NEWEST:
        raise FBXError(f"ASCII FBX version {version} is newer than the FBX 7.7 this reader "
                       "knows", path)
    return Node("FBX", [np.int32(version)], nodes, offset=1)
