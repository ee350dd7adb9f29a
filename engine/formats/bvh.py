"""BVH (Biovision Hierarchy) reading and writing.

Reading happens in two steps, as Blender does: :func:`parse_bvh_text` turns text into a plain
:class:`BVHRecord` (names, offsets and channel values exactly as written, with line numbers),
then :func:`record_to_motion` interprets it: rotation orders, what position channels mean,
units and up axis, and converts everything to the internal convention of :mod:`engine.units`.

What real files do and this reader accepts: a rotation order per joint (mixed in one file), any
subset of position and rotation channels on any joint, End Sites with offsets, tabs, CRLF and
bare CR line endings, multi-word joint names, ``{`` on the name's line, scientific notation,
blank lines, no newline at the end. Anything else raises :class:`~engine.errors.BVHError` naming
the file, the line and what was expected.
"""
from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from itertools import count, repeat
from pathlib import Path

import numpy as np

from ._numparse import file_pieces, parse_number_pieces, parse_number_rows
from .figure import UP_AXIS_TOLERANCE, body_roles, body_vertical
from ..errors import BVHError, ExportError
from .. import limits
from ..fileio import atomic_write, reading
from ..kinematics import WorldPose, fk_components
from ..motion import Motion
from ..quaternions import cfrom_euler, from_matrix, qmul
from ..rotations import euler_to_quat, quat_to_euler
from ..skeleton import POSITION_CHANNELS, ROTATION_CHANNELS, EndSite, Skeleton
from ..units import UNITS, AXES, SourceFrame, detect_units, nearest_axis

__all__ = ["BVHRecord", "parse_bvh_text", "read_bvh", "parse_bvh", "record_to_motion",
           "format_bvh", "write_bvh", "detect_position_modes", "CHANNEL_CHOICES"]

_KNOWN_CHANNELS = ROTATION_CHANNELS + POSITION_CHANNELS
_CHANNEL_CANON = {c.lower(): c for c in _KNOWN_CHANNELS}
_FRAMES_RE = re.compile(r"^\s*frames\s*:\s*(\S+)\s*$", re.IGNORECASE)
_FRAME_TIME_RE = re.compile(r"^\s*frame\s+time\s*:\s*(\S+)\s*$", re.IGNORECASE)
_CMU_NAMES = {"lhipjoint", "rhipjoint", "lowerback", "lfingers", "rfingers", "lthumb"}
#: Largest frame count accepted from a ``Frames:`` line before the rows are counted.
_MAX_FRAMES = 50_000_000


# --------------------------------------------------------------------------- plain records
@dataclass
class BVHRecord:
    """A BVH file as written: nothing interpreted, lengths in file units, angles in degrees.

    Attributes:
        names: joint names (ROOT and JOINT entries) in file order.
        parents: parent index per joint, ``-1`` for the root.
        offsets: ``(J, 3)`` OFFSET values.
        channels: per joint, canonical channel names in file order.
        end_sites: ``(parent index, offset (3,))`` per End Site, in file order.
        frame_time: seconds per frame as written.
        values: ``(F, C)`` channel values, one row per frame.
        joint_lines: line number of each joint's ROOT/JOINT keyword.
        first_row_line: line number of the first motion row.
        path: the file the text came from, if any.
    """

    names: list[str]
    parents: list[int]
    offsets: np.ndarray
    channels: list[tuple[str, ...]]
    end_sites: list[tuple[int, np.ndarray]]
    frame_time: float
    values: np.ndarray
    joint_lines: list[int] = field(default_factory=list)
    first_row_line: int = 0
    path: str | None = None

    @property
    def num_frames(self) -> int:
        return self.values.shape[0]


def _is_count(token: str) -> bool:
    """True for a whole number written in ASCII digits (``str.isdigit`` also takes '²',
    which ``int`` refuses)."""
    return token.isascii() and token.isdigit()


class _Tokens:
    """Whitespace tokens of the hierarchy with their line numbers."""

    def __init__(self, lines: list[str], path):
        self.path = path
        self.toks: list[tuple[str, int, int]] = []   # (token, line number, index in line)
        self.line_tokens: dict[int, list[str]] = {}
        self.pos = 0
        self.motion_line = None
        for number, line in enumerate(lines, start=1):
            parts = line.split()
            if not parts:
                continue
            if parts[0].upper() == "MOTION":
                self.motion_line = number
                break
            self.line_tokens[number] = parts
            self.toks.extend(zip(parts, repeat(number), count()))
        self.last_line = self.toks[-1][1] if self.toks else 1

    def error(self, problem, line=None):
        return BVHError(problem, self.path, line if line is not None else self.here())

    def here(self) -> int:
        if self.pos < len(self.toks):
            return self.toks[self.pos][1]
        return self.motion_line or self.last_line

    def peek(self):
        return self.toks[self.pos] if self.pos < len(self.toks) else None

    def next(self, expected: str):
        if self.pos >= len(self.toks):
            where = ("before MOTION" if self.motion_line else "at the end of the file")
            raise self.error(f"the hierarchy stops {where}; expected {expected}")
        tok = self.toks[self.pos]
        self.pos += 1
        return tok

    def rest_of_line(self, line: int, index: int) -> list[str]:
        """Tokens after position ``index`` on ``line``, consuming them."""
        rest = self.line_tokens[line][index + 1:]
        self.pos += len(rest)
        return rest

    def number(self, what: str) -> float:
        tok, line, _ = self.next(what)
        try:
            value = float(tok)
        except ValueError:
            raise BVHError(f"expected {what}, found {tok!r}", self.path, line) from None
        if not math.isfinite(value):
            raise BVHError(f"expected {what} (a finite number), found {tok!r}", self.path, line)
        wrong = limits.problem(value)
        if wrong is not None:
            raise BVHError(f"expected {what}, found {tok[:40]!r}: {wrong}", self.path, line)
        return value


def _decode(data: bytes, path) -> str:
    if not data.strip():
        raise BVHError("the file is empty; expected a BVH file starting with HIERARCHY", path,
                       None)
    if b"\x00" in data:
        raise BVHError("this is a binary file, not a BVH text file (it contains NUL bytes)",
                       path, None)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def parse_bvh_text(text: str, path: str | os.PathLike | None = None) -> BVHRecord:
    """Parse BVH text into a :class:`BVHRecord`, checking its structure and every value."""
    path = os.fspath(path) if path is not None else None
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    lines, rows_at = _head_lines(text)
    if rows_at is not None:
        record = _record(lines, path, lambda n_cols, frames: parse_number_rows(
            text, n_cols, start=rows_at, rows=frames, limit=limits.MAX_MAGNITUDE))
        if record is not None:
            return record
    return _record(text.split("\n"), path, None)


def _read_bvh_record(path) -> BVHRecord:
    """:func:`parse_bvh_text` of the file at ``path``, reading only its header whole: the rows
    are parsed from the file a piece at a time, so that a large file is never in memory as
    bytes or text beside its values (its peak memory). A file with carriage returns in its
    header, whose header the text reading would find elsewhere, or whose rows the fast
    parser refuses, is read and parsed whole as text, as :func:`parse_bvh_text` does."""
    with reading(path, BVHError, "a BVH file"), open(path, "rb") as handle:
        data = handle.read(_HEAD_BYTES)
        while True:
            _, rows_at = _head_lines(data)
            more = rows_at is None and handle.read(_HEAD_BYTES)
            if not more:
                break
            data += more
        if rows_at is not None and b"\r" not in data[:rows_at] \
                and b"\0" not in data[:rows_at]:
            head = _decode(data[:rows_at], path)
            lines, end = _head_lines(head)
            if end == len(head):
                rest = data[rows_at:]
                del data
                record = _record(lines, os.fspath(path), lambda n_cols, frames:
                                 parse_number_pieces(file_pieces(handle, rest), n_cols,
                                                     rows=frames,
                                                     limit=limits.MAX_MAGNITUDE))
                if record is not None:
                    return record
    return parse_bvh_text(_decode(_read_bytes(path), path), path)


#: bytes of a file read at a time while looking for the end of its header
_HEAD_BYTES = 1 << 16


def _record(lines: list[str], path, fast) -> BVHRecord | None:
    """The record of a file: with ``fast``, ``lines`` are its header and ``fast(columns,
    frames)`` parses its rows in one pass (:func:`parse_number_rows`' result), the record
    being None where that fails or finds a value out of range; without, ``lines`` are all its
    lines and the rows are parsed row by row, so that an error names the line."""
    toks = _Tokens(lines, path)
    tree = _parse_hierarchy(toks)
    head = _parse_motion_header(lines, toks.motion_line, path)
    n_cols = sum(len(c) for c in tree.channels)
    if fast is not None:
        parsed = fast(n_cols, head.frames) if n_cols else None
        if parsed is None:
            return None
        values = parsed[0]
    else:
        values = _parse_rows_carefully(lines, head.first_row, n_cols, head.frames,
                                       head.frames_line, tree.names, tree.channels, path)
    return BVHRecord(names=tree.names, parents=tree.parents,
                     offsets=np.array(tree.offsets, dtype=float),
                     channels=list(tree.channels),  # type: ignore[arg-type]
                     end_sites=tree.end_sites, frame_time=head.frame_time, values=values,
                     joint_lines=tree.joint_lines, first_row_line=head.first_row + 1, path=path)


def _head_lines(text: str | bytes) -> tuple[list, int | None]:
    """The lines of ``text`` up to and including ``Frame Time:`` (the second line with content
    after the line starting with MOTION) and the offset of the rows after them, without
    splitting the rows themselves (a large file's rows are most of it); every line and None
    where there is no such header (the parsers then say what is missing)."""
    newline, keyword = ("\n", "MOTION") if isinstance(text, str) else (b"\n", b"MOTION")
    lines, pos, motion, after = [], 0, False, 0
    while True:
        end = text.find(newline, pos)
        line = text[pos:] if end < 0 else text[pos:end]
        lines.append(line)
        if end < 0:
            return lines, None
        pos = end + 1
        if not motion:
            parts = line.split(None, 1)
            motion = bool(parts) and parts[0].upper() == keyword
        elif line.strip():
            after += 1
            if after == 2:
                return lines, pos


# ------------------------------------------------------------------ HIERARCHY section
class _Hierarchy:
    """The joints and End Sites of the HIERARCHY section, filled keyword by keyword.

    ``names``, ``parents``, ``offsets`` (3 values in file units, ``None`` until read),
    ``channels`` (``None`` until read) and ``joint_lines`` have one entry per joint in file
    order; ``end_sites`` holds ``(parent joint, offset (3,))``. ``stack`` holds the open
    blocks as ``(kind, joint index, line)``, kind ``"joint"`` or ``"end"`` (an End Site of that
    joint).
    """

    def __init__(self, toks: _Tokens):
        self.toks = toks
        self.path = toks.path
        self.names: list[str] = []
        self.name_lines: dict[str, int] = {}
        self.parents: list[int] = []
        self.offsets: list[list[float] | None] = []
        self.channels: list[tuple[str, ...] | None] = []
        self.joint_lines: list[int] = []
        self.end_sites: list[tuple[int, np.ndarray]] = []
        self.stack: list[tuple[str, int, int]] = []
        self.end_offset: list[float] | None = None
        self.closed_root = False

    def open_brace(self):
        tok, line, _ = self.toks.next("'{'")
        if tok != "{":
            raise BVHError(f"expected '{{', found {tok!r}", self.path, line)

    def joint(self, key: str, line: int, index: int):
        """``ROOT name`` or ``JOINT name`` (a name may have several words; ``{`` may end it)."""
        stack, path = self.stack, self.path
        if key == "ROOT" and stack:
            raise BVHError("ROOT inside another joint; expected JOINT or '}'", path, line)
        if key == "ROOT" and self.closed_root:
            raise BVHError("a second ROOT: this reader takes one skeleton per file", path,
                           line)
        if key == "JOINT" and (not stack or stack[-1][0] != "joint"):
            where = "inside an End Site" if stack else "outside any ROOT"
            raise BVHError(f"JOINT {where}; expected it inside a ROOT or JOINT", path, line)
        rest = self.toks.rest_of_line(line, index)
        brace_on_line = False
        if rest and rest[-1].endswith("{"):
            brace_on_line = True
            rest[-1] = rest[-1][:-1]
            if not rest[-1]:
                rest.pop()
        name = " ".join(rest)
        if not name:
            raise BVHError(f"expected a joint name after {key}", path, line)
        if name in self.name_lines:
            raise BVHError(f"duplicate joint name {name!r} (first at line "
                           f"{self.name_lines[name]}); joint names must be unique", path, line)
        self.name_lines[name] = line
        self.names.append(name)
        self.parents.append(stack[-1][1] if stack else -1)
        self.offsets.append(None)
        self.channels.append(None)
        self.joint_lines.append(line)
        if not brace_on_line:
            self.open_brace()
        stack.append(("joint", len(self.names) - 1, line))

    def end_site(self, line: int):
        """``End Site`` (``{`` may end it)."""
        site, sline, _ = self.toks.next("'Site' after 'End'")
        if site.upper().rstrip("{") != "SITE":
            raise BVHError(f"expected 'End Site', found 'End {site}'", self.path, sline)
        if not self.stack or self.stack[-1][0] != "joint":
            raise BVHError("End Site outside a joint; expected it inside a JOINT", self.path,
                           line)
        if not site.endswith("{"):
            self.open_brace()
        self.stack.append(("end", self.stack[-1][1], line))
        self.end_offset = None

    def offset(self, line: int):
        """``OFFSET x y z`` of the open joint or End Site."""
        if not self.stack:
            raise BVHError("OFFSET outside any joint", self.path, line)
        values = [self.toks.number(f"the {axis} value of OFFSET") for axis in "XYZ"]
        kind, j, _ = self.stack[-1]
        if kind == "end":
            if self.end_offset is not None:
                raise BVHError("a second OFFSET in one End Site", self.path, line)
            self.end_offset = values
        else:
            if self.offsets[j] is not None:
                raise BVHError(f"a second OFFSET for joint {self.names[j]!r}", self.path, line)
            self.offsets[j] = values

    def channel_list(self, line: int):
        """``CHANNELS n name...`` of the open joint: 0 to 6 known channels, none twice."""
        path = self.path
        if not self.stack or self.stack[-1][0] != "joint":
            raise BVHError("CHANNELS outside a joint (End Sites have no channels)", path,
                           line)
        j = self.stack[-1][1]
        if self.channels[j] is not None:
            raise BVHError(f"a second CHANNELS line for joint {self.names[j]!r}", path, line)
        count_tok, cline, _ = self.toks.next("the channel count after CHANNELS")
        if not _is_count(count_tok) or int(count_tok) > 6:
            raise BVHError(f"expected a channel count from 0 to 6 after CHANNELS, found "
                           f"{count_tok!r}", path, cline)
        found = []
        for _ in range(int(count_tok)):
            ch, chline, _ = self.toks.next(f"{count_tok} channel names after CHANNELS")
            canon = _CHANNEL_CANON.get(ch.lower())
            if canon is None:
                raise BVHError(f"unknown channel {ch!r} (channel {len(found) + 1} of "
                               f"{count_tok}); expected one of {', '.join(_KNOWN_CHANNELS)}",
                               path, chline)
            if canon in found:
                raise BVHError(f"channel {canon} appears twice for joint {self.names[j]!r}",
                               path, chline)
            found.append(canon)
        self.channels[j] = tuple(found)

    def close(self, line: int):
        """``}``: the open joint (it must have an OFFSET) or End Site ends."""
        if not self.stack:
            raise BVHError("unbalanced braces: '}' with no open joint", self.path, line)
        kind, j, opened = self.stack.pop()
        if kind == "end":
            if self.end_offset is None:
                raise BVHError(f"the End Site opened at line {opened} has no OFFSET", self.path,
                               line)
            self.end_sites.append((j, np.array(self.end_offset)))
        else:
            if self.offsets[j] is None:
                raise BVHError(f"joint {self.names[j]!r} (line {opened}) has no OFFSET",
                               self.path, line)
            if self.channels[j] is None:
                self.channels[j] = ()
        if not self.stack:
            self.closed_root = True

    def finish(self):
        """At the end of the hierarchy's tokens: every block closed, MOTION next."""
        if self.stack:
            kind, j, line = self.stack[-1]
            what = f"joint {self.names[j]!r}" if kind == "joint" else "an End Site"
            raise self.toks.error(f"the hierarchy stops before {what} (opened at line {line}) "
                                  "is closed; expected '}' (the file may be truncated)")
        if self.toks.motion_line is None:
            raise self.toks.error("no MOTION section; expected the keyword MOTION after the "
                                  "hierarchy (the file may be truncated)")


def _parse_hierarchy(toks: _Tokens) -> _Hierarchy:
    """Read the HIERARCHY section's tokens, up to the MOTION keyword."""
    path = toks.path
    first = toks.peek()
    if first is None:
        raise BVHError("no HIERARCHY section; expected a BVH file starting with HIERARCHY",
                       path, toks.motion_line or 1)
    if first[0].upper() != "HIERARCHY":
        raise BVHError(f"expected the keyword HIERARCHY, found {first[0][:40]!r}; is this a BVH "
                       "file?", path, first[1])
    toks.pos = 1
    tree = _Hierarchy(toks)
    while toks.peek() is not None:
        tok, line, index = toks.next("a keyword")
        key = tok.upper()
        if key in ("ROOT", "JOINT"):
            tree.joint(key, line, index)
        elif key == "END":
            tree.end_site(line)
        elif key == "OFFSET":
            tree.offset(line)
        elif key == "CHANNELS":
            tree.channel_list(line)
        elif tok == "}":
            tree.close(line)
        elif key == "HIERARCHY":
            raise BVHError("a second HIERARCHY keyword", path, line)
        else:
            expected = ("ROOT" if not tree.stack and not tree.closed_root else
                        "MOTION" if not tree.stack else
                        "OFFSET, CHANNELS, JOINT, End Site or '}'")
            raise BVHError(f"unexpected {tok[:40]!r}; expected {expected}", path, line)
    tree.finish()
    if not tree.names:
        raise BVHError("the hierarchy has no ROOT joint", path, toks.motion_line)
    return tree


# ------------------------------------------------------------------ MOTION section
@dataclass(frozen=True)
class _MotionHeader:
    """The ``Frames:`` and ``Frame Time:`` lines after MOTION.

    ``frames``: the frame count; ``frames_line``: its line number; ``frame_time``: seconds per
    frame; ``first_row``: the 0-based index in the text's lines of the first row of values (the
    line after ``Frame Time:``).
    """

    frames: int
    frames_line: int
    frame_time: float
    first_row: int


def _header_line(motion_rest: list[str], motion_line: int, regex, label: str, start: int,
                 path) -> tuple[str, int]:
    """The value of the first line with content at or after ``motion_rest[start]``, which must
    match ``regex`` (``label <number>``), and its index in ``motion_rest``."""
    k = start
    while k < len(motion_rest) and not motion_rest[k].strip():
        k += 1
    if k >= len(motion_rest):
        # point at the last line with content (MOTION itself, or the Frames: line)
        last = max((i for i in range(start) if motion_rest[i].strip()), default=-1)
        raise BVHError(f"the file ends after MOTION; expected a '{label}' line", path,
                       motion_line + last + 1)
    m = regex.match(motion_rest[k])
    if not m:
        raise BVHError(f"expected '{label} <number>', found {motion_rest[k].strip()[:60]!r}",
                       path, motion_line + k + 1)
    return m.group(1), k


def _parse_motion_header(lines: list[str], motion_line: int, path) -> _MotionHeader:
    """Read ``Frames: n`` (1 to :data:`_MAX_FRAMES`) and ``Frame Time: seconds`` (positive)
    after the MOTION keyword on line ``motion_line``."""
    motion_rest = lines[motion_line:]                   # lines after MOTION
    frames_tok, k = _header_line(motion_rest, motion_line, _FRAMES_RE, "Frames:", 0, path)
    frames_line = motion_line + k + 1
    if not _is_count(frames_tok):
        raise BVHError(f"expected a whole number of frames after 'Frames:', found "
                       f"{frames_tok!r}", path, frames_line)
    n_frames = int(frames_tok)
    if n_frames == 0:
        raise BVHError("'Frames: 0': the file holds no motion; expected at least one frame",
                       path, frames_line)
    if n_frames > _MAX_FRAMES:
        raise BVHError(f"'Frames: {n_frames}' is more than this reader accepts "
                       f"({_MAX_FRAMES})", path, frames_line)
    ft_tok, k = _header_line(motion_rest, motion_line, _FRAME_TIME_RE, "Frame Time:", k + 1,
                             path)
    ft_line = motion_line + k + 1
    try:
        frame_time = float(ft_tok)
    except ValueError:
        frame_time = float("nan")
    if not (math.isfinite(frame_time) and 0 < frame_time <= limits.MAX_FRAME_TIME
            and math.isfinite(1.0 / frame_time)):
        raise BVHError(f"expected a positive number of seconds, at most "
                       f"{limits.MAX_FRAME_TIME:g}, after 'Frame Time:', found {ft_tok[:40]!r}",
                       path, ft_line)
    return _MotionHeader(n_frames, frames_line, frame_time, ft_line)


def _channel_label(col: int, names, channels) -> str:
    for name, chans in zip(names, channels):
        if col < len(chans):
            return f"{name} {chans[col]}"
        col -= len(chans)
    return "?"


def _parse_rows_carefully(lines, first_row, n_cols, n_frames, frames_line, names, channels,
                          path) -> np.ndarray:
    """The slow path: parse row by row so that the first problem is reported exactly."""
    values = np.empty((n_frames, n_cols))
    row = 0
    line = first_row                        # the last line with content (Frame Time: at first)
    for k in range(first_row, len(lines)):
        parts = lines[k].split()
        if not parts:
            continue
        line = k + 1
        if not n_cols:
            raise BVHError(f"a row of {len(parts)} values, but the hierarchy declares no "
                           "channels; expected empty rows", path, line)
        if row >= n_frames:
            extra = sum(1 for rest in lines[k:] if rest.strip())
            raise BVHError(f"'Frames: {n_frames}' (line {frames_line}) but {n_frames + extra} "
                           "rows of values follow; the frame count disagrees with the rows",
                           path, line)
        if len(parts) != n_cols:
            raise BVHError(f"frame {row + 1} has {len(parts)} values; expected {n_cols} (one per "
                           "channel declared in the hierarchy)", path, line)
        for c, tok in enumerate(parts):
            try:
                v = float(tok)
            except ValueError:
                raise BVHError(f"value {c + 1} of frame {row + 1} "
                               f"({_channel_label(c, names, channels)}) is {tok[:40]!r}; "
                               "expected a number", path, line) from None
            if not math.isfinite(v):
                raise BVHError(f"value {c + 1} of frame {row + 1} "
                               f"({_channel_label(c, names, channels)}) is {tok[:40]!r}; "
                               "expected a finite number", path, line)
            wrong = limits.problem(v)
            if wrong is not None:
                raise BVHError(f"value {c + 1} of frame {row + 1} "
                               f"({_channel_label(c, names, channels)}) is {tok[:40]!r}: "
                               f"{wrong}", path, line)
            values[row, c] = v
        row += 1
    if row < n_frames and n_cols:
        raise BVHError(f"'Frames: {n_frames}' (line {frames_line}) but the file ends after "
                       f"{row} rows; the frame count disagrees with the rows (truncated file?)",
                       path, line)
    return values


# --------------------------------------------------------------------------- interpretation
def _column_layout(channels):
    """Per joint: (rotation columns, {axis index: position column})."""
    col = 0
    rot_cols, pos_cols = [], []
    for chans in channels:
        r, p = [], {}
        for c in chans:
            if c in ROTATION_CHANNELS:
                r.append(col)
            else:
                p["XYZ".index(c[0])] = col
            col += 1
        rot_cols.append(r)
        pos_cols.append(p)
    return rot_cols, pos_cols


def detect_position_modes(record: BVHRecord) -> dict[str, str]:
    """Decide, per joint with position channels, whether they replace or add to its OFFSET.

    The first frame's position values are compared with the OFFSET on the axes where the
    offset is large (at least a tenth of its length): values near the offset mean *absolute*
    (the value is the local position and replaces the OFFSET: Bandai, Rokoko, most roots),
    values near zero mean *relative* (added to the OFFSET: CC3 hip-rooted exports).
    Exporters that write a joint's OFFSET take it from the first frame, which is why frame 0
    decides rather than an average over a clip that travels. A zero OFFSET makes both readings
    equal: *absolute*.
    """
    _, pos_cols = _column_layout(record.channels)
    return {record.names[j]: _position_mode(record.offsets[j], {
        a: record.values[0, c] for a, c in cols.items()}) for j, cols in enumerate(pos_cols)
        if cols}


def _position_mode(offset: np.ndarray, first: dict) -> str:
    """:func:`detect_position_modes` for one joint: its ``offset (3,)`` and its position
    channels' values on the first frame ``{axis: value}``."""
    axes = [a for a in first if abs(offset[a]) >= 0.1 * np.linalg.norm(offset) and
            abs(offset[a]) > 0]
    if not axes:
        return "absolute"
    values = np.array([first[a] for a in axes])
    near_offset = np.linalg.norm(values - offset[axes])
    return "relative" if np.linalg.norm(values) < near_offset else "absolute"


#: angles turned into quaternions at a time by :func:`_local_arrays` (2 MB of them)
_EULER_VALUES = 1 << 18


def _local_arrays(record: BVHRecord, modes: Mapping[str, str]):
    """Local rotations ``(4, J, F)`` and translations ``(3, K, F)`` in file units and file
    axes, as component arrays (:mod:`engine.quaternions`: one contiguous row of frames per
    joint and component, what forward kinematics works on; ``.T`` of each is the
    ``(F, J, 4)`` or ``(F, K, 3)`` view a :class:`Motion` holds).

    The angles go from the rows into per-axis rows and through :func:`cfrom_euler` a block of
    frames at a time; a joint whose angles never change (bit for bit) is turned once and its
    rotation copied to every frame: the same values, without the sines and cosines of every
    frame (a quarter of a CC3 clip's rotation channels are fingers that never move)."""
    values = record.values
    F = values.shape[0]
    J = len(record.names)
    rot_cols, pos_cols = _column_layout(record.channels)
    bits = values.view(np.int64)
    still = (bits == bits[:1]).all(axis=0)                        # (C,) never changes
    rotations = np.empty((4, J, F))
    groups: dict[tuple[str, bool], list[int]] = {}
    for j, chans in enumerate(record.channels):
        order = "".join(c[0] for c in chans if c in ROTATION_CHANNELS)
        groups.setdefault((order, bool(still[rot_cols[j]].all())), []).append(j)
    for (order, constant), joints in groups.items():
        if not order:
            rotations[:3, joints] = 0.0
            rotations[3, joints] = 1.0
            continue
        cols = np.array([rot_cols[j] for j in joints]).T            # (n, Jg)
        if constant:
            rotations[:, joints] = cfrom_euler(values.T[cols, :1], order)
            continue
        step = max(1, _EULER_VALUES // cols.size)
        for lo in range(0, F, step):              # frames at a time: small temporaries
            rotations[:, joints, lo:lo + step] = cfrom_euler(values.T[cols, lo:lo + step], order)
    translated = [0] + [j for j in range(1, J) if pos_cols[j]]
    translations = np.empty((3, len(translated), F))
    for k, j in enumerate(translated):
        off = record.offsets[j]
        cols = pos_cols[j]
        relative = modes.get(record.names[j]) == "relative"
        for axis in range(3):
            if axis in cols:
                v = values[:, cols[axis]]
                translations[axis, k] = v + off[axis] if relative else v
            else:
                translations[axis, k] = off[axis]
    return rotations, translations


@dataclass(frozen=True)
class _Detection:
    """What :func:`_detect_frame` found (file units, file axes)."""

    up_axis: str
    units: str
    stature: float
    reason: str
    doubt: str
    overrides: tuple[tuple[str, str], ...]


def _detect_frame(record: BVHRecord, rotations, translations,
                  skeleton_file: Skeleton) -> _Detection:
    """Detect the up axis and the units from a sample of frames (file units, file axes) of
    the local ``rotations`` ``(4, J, F)`` and ``translations`` ``(3, K, F)`` (component arrays,
    as :func:`_local_arrays` gives them).

    The up axis is the coordinate axis nearest the body's vertical
    (:func:`.figure.body_vertical`, median over the sample) when the skeleton is a humanoid,
    whatever its joints are called; for another figure, the axis from its feet to its head
    by name; else +Y with a doubt.
    The stature is the median height of the figure along that axis (for a humanoid, of the
    body below its hips joint, so that IK targets hanging from a ground root do not count);
    the units follow from it (:func:`engine.units.detect_units`).
    """
    F = rotations.shape[-1]
    sample = np.unique(np.linspace(0, F - 1, min(F, 48)).round().astype(int))
    pose = WorldPose(*(a.T for a in fk_components(skeleton_file, rotations[..., sample],
                                                  translations[..., sample])))
    pts = pose.all_positions()                                        # (S, J+E, 3)
    roles = body_roles(skeleton_file, pose.positions[0])
    lower = [n.lower() for n in record.names]
    doubts, overrides = [], []
    if roles is not None:
        v = np.median(body_vertical(roles, skeleton_file, pose), axis=0)
        up = nearest_axis(v)
        how = (f"the body stands along {up} (feet to '{roles['head']}', square to the "
               "shoulders)")
    else:
        head = [j for j, n in enumerate(lower) if "head" in n and "end" not in n
                and "top" not in n]
        feet = [j for j, n in enumerate(lower) if any(w in n for w in ("foot", "ankle", "toe"))]
        v = (np.median(pose.positions[:, head[0]] - pose.positions[:, feet].mean(axis=1),
                       axis=0) if head and feet else None)
        up = nearest_axis(v) if v is not None else "+Y"
        how = (f"'{record.names[head[0]]}' is above the feet along {up}" if v is not None
               else "not a humanoid and no head and foot joints to tell the up axis by: +Y "
                    "assumed")
    if v is not None and np.any(v):
        v = v / np.abs(v).max()          # a tiny figure's norm would underflow to zero
    k = "XYZ".index(up[1])
    if v is None or not np.any(v):
        doubts.append("the up axis cannot be told from the figure (+Y assumed)")
        overrides.append(("up_axis", ""))
    else:
        angle = math.degrees(math.acos(min(1.0, abs(v[k]) / np.linalg.norm(v))))
        if angle > UP_AXIS_TOLERANCE:
            doubts.append(f"the figure stands {angle:.0f} degrees off {up}, its nearest axis")
            overrides.append(("up_axis", ""))
    if roles is not None:
        body = set(_subtree(skeleton_file, skeleton_file.index[roles["hips"]]))
        keep = [j for j in range(skeleton_file.num_joints) if j in body]
        keep += [skeleton_file.num_joints + e for e, site in enumerate(skeleton_file.end_sites)
                 if site.parent in body]
        pts = pts[:, keep]
    heights = pts[..., k]
    stature = float(np.median(heights.max(axis=1) - heights.min(axis=1)))
    cmu = bool(_CMU_NAMES & set(lower))
    units, why, unit_doubt, other = detect_units(stature, cmu_names=cmu,
                                                 humanoid=roles is not None)
    if unit_doubt:
        doubts.append(unit_doubt)
        overrides.append(("units", other))
    return _Detection(up, units, stature, f"{how}; {why}", "; ".join(doubts), tuple(overrides))


def _subtree(skeleton: Skeleton, top: int) -> list[int]:
    """``top`` and every joint below it."""
    out, stack = [], [top]
    while stack:
        j = stack.pop()
        out.append(j)
        stack.extend(skeleton.children[j])
    return out


def record_to_motion(record: BVHRecord, *, units: str | None = None, scale: float | None = None,
                     up_axis: str | None = None,
                     position_mode: str | Mapping[str, str] | None = None,
                     name: str = "") -> Motion:
    """Interpret a parsed BVH file and convert it to the internal convention.

    Args:
        units: the file's length unit (a key of :data:`engine.units.UNITS`); detected if None.
        scale: metres per file unit, overriding ``units``.
        up_axis: the file's up axis (``"+Y"``, ``"+Z"``, ...); detected if None.
        position_mode: ``"absolute"`` or ``"relative"`` for every joint with position
            channels, or a mapping from joint name to mode; detected where not given.

    Detection (:func:`_detect_frame`) never warns: a detected figure in doubt is put in the
    skeleton's :attr:`~engine.units.SourceFrame.doubt` with the overrides that settle it,
    for the caller to show in one line (the CLI on stderr, the window in its status bar).
    A doubt about a figure given here is dropped.
    """
    path = record.path
    modes = detect_position_modes(record)
    if isinstance(position_mode, str):
        _check_mode(position_mode, path)
        modes = {n: position_mode for n in modes}
    elif position_mode:
        for joint, mode in position_mode.items():
            if joint not in modes:
                raise BVHError(f"position mode given for {joint!r}, which has no position "
                               "channels in this file", path, None)
            _check_mode(mode, path)
            modes[joint] = mode
    if units is not None and units not in UNITS:
        raise BVHError(f"unknown units {units!r}; expected one of {', '.join(UNITS)}", path,
                       None)
    if up_axis is not None and up_axis not in AXES:
        raise BVHError(f"unknown up axis {up_axis!r}; expected one of {', '.join(AXES)}", path,
                       None)
    names = record.names
    channels = [tuple(c) for c in record.channels]
    pos_modes = [modes.get(n) for n in names]
    file_skeleton = Skeleton(names=names, parents=record.parents, offsets=record.offsets,
                             channels=channels, position_modes=pos_modes,
                             end_sites=[EndSite(p, o, f"{names[p]}_end")
                                        for p, o in record.end_sites])
    rotations, translations = _local_arrays(record, modes)

    units_given = units is not None or scale is not None
    detected = not units_given or up_axis is None
    reason, doubt, overrides = "", "", ()
    if detected:
        found = _detect_frame(record, rotations, translations, file_skeleton)
        reason = found.reason
        # a doubt about a figure the caller gave is settled
        kept = [(o, v) for o, v in found.overrides
                if not (o == "units" and units_given or o == "up_axis" and up_axis)]
        if kept:
            doubt, overrides = found.doubt, tuple(kept)
        up_axis = up_axis or found.up_axis
        if not units_given:
            units = found.units
    if scale is None:
        scale = UNITS[units]
    elif units is None:
        units = "custom"
    low, high = limits.SCALE_RANGE
    if not (math.isfinite(scale) and low <= scale <= high):
        raise BVHError(f"the scale must be a positive number of metres per unit, from {low:g} "
                       f"to {high:g}, not {scale!r}", path, None)
    source = SourceFrame(units=units, scale=float(scale), up_axis=up_axis, detected=detected,
                         reason=reason, doubt=doubt, overrides=overrides)
    C = source.rotation
    offsets = record.offsets * scale
    offsets[0] = C @ record.offsets[0] * scale
    skeleton = Skeleton(names=names, parents=record.parents, offsets=offsets, channels=channels,
                        position_modes=pos_modes,
                        end_sites=[EndSite(p, o * scale, f"{names[p]}_end")
                                   for p, o in record.end_sites],
                        source=source)
    translations = translations * scale
    if up_axis != "+Y":
        translations[:, 0] = (np.ascontiguousarray(translations[:, 0].T) @ C.T).T
        rotations[:, 0] = qmul(from_matrix(C), rotations[:, 0].T).T
    # computed here, unit quaternions (Euler angles or scipy's output) and finite numbers:
    # the checks and copies of Motion() would only double a large clip's peak memory; the
    # motion holds the component arrays' transposes, so that forward kinematics of it
    # (kinematics.joint_major) takes them as they are
    return Motion._trusted(skeleton, rotations.T, translations.T, record.frame_time, name)


def _check_mode(mode, path):
    if mode not in ("absolute", "relative"):
        raise BVHError(f"position mode must be 'absolute' or 'relative', not {mode!r}", path,
                       None)


def parse_bvh(text: str, path: str | os.PathLike | None = None, **options) -> Motion:
    """Parse BVH text into a :class:`Motion` (options as :func:`record_to_motion`)."""
    record = parse_bvh_text(text, path)
    options.setdefault("name", Path(path).stem if path is not None else "")
    return record_to_motion(record, **options)


def read_bvh(path: str | os.PathLike, **options) -> Motion:
    """Read a BVH file into a :class:`Motion` in the internal convention.

    Options (all detected when not given): ``units``, ``scale``, ``up_axis``,
    ``position_mode``; see :func:`record_to_motion`.
    """
    record = _read_bvh_record(path)
    options.setdefault("name", Path(path).stem)
    return record_to_motion(record, **options)


def _read_bytes(path) -> bytes:
    """The bytes of the file at ``path``, or a :class:`BVHError` saying why not."""
    with reading(path, BVHError, "a BVH file"):
        return Path(path).read_bytes()


# --------------------------------------------------------------------------- writing
#: [m] the stature the written precision of lengths is measured against
_PERSON = 1.7


def _fmt(value: float, decimals: int) -> str:
    text = f"{value:.{decimals}f}"
    return "0" + text[2:] if text.startswith("-0") and float(text) == 0 else text


#: the ``channels`` choices of :func:`format_bvh`
CHANNEL_CHOICES = ("all", "rotation")


def format_bvh(motion: Motion, *, source: SourceFrame | None = None,
               position_modes: str | Mapping[str, str] | None = None,
               decimals: int = 6, channels: str = "all") -> str:
    """The BVH text of ``motion``.

    Args:
        source: units and up axis to write in; the skeleton's own (the file it came from) by
            default.
        position_modes: ``"absolute"`` or ``"relative"`` for every joint with position
            channels, or per joint name; the skeleton's own by default.
        decimals: digits after the decimal point of angles, and the fewest of lengths;
            lengths get more where the unit is large (metres: 7), so that they are exact to
            a ten-millionth of a 1.7 m person and a file is read back within a millionth of
            the figure's stature.
        channels: ``"all"``: every joint's own channels (a glTF character's joints have six
            each); ``"rotation"``: the root keeps its channels and every other joint writes
            its rotation channels only (what many DCC importers expect), its bone in its
            OFFSET (the constant translation its position channels held).

    Raises:
        ExportError: for an unknown ``channels``, or, with ``"rotation"``, a non-root joint
            whose position channels really move it (its bone changes length).
    """
    if channels not in CHANNEL_CHOICES:
        raise ExportError(f"channels must be one of {', '.join(CHANNEL_CHOICES)}, not "
                          f"{channels!r}")
    sk = motion.skeleton
    written = list(sk.channels) if channels == "all" else [
        tuple(c for c in chans if j == 0 or c in ROTATION_CHANNELS)
        for j, chans in enumerate(sk.channels)]
    src = source or sk.source
    C = src.rotation
    s = src.scale
    length_decimals = max(decimals, math.ceil(7 + math.log10(s / _PERSON)))
    modes = list(sk.position_modes)
    if isinstance(position_modes, str):
        _check_mode(position_modes, None)
        modes = [position_modes if m else None for m in modes]
    elif position_modes:
        for joint, mode in position_modes.items():
            j = sk.joint(joint)
            if modes[j] is None:
                raise ExportError(f"joint {joint!r} has no position channels")
            _check_mode(mode, None)
            modes[j] = mode

    offsets = sk.offsets / s
    offsets[0] = (C.T @ sk.offsets[0]) / s
    F = motion.num_frames
    rotations = motion.rotations
    translations = motion.translations / s
    if src.up_axis != "+Y":
        translations = translations.copy()
        translations[:, 0] = translations[:, 0] @ C
        rotations = rotations.copy()
        rotations[:, 0] = qmul(from_matrix(C.T), rotations[:, 0])

    # channel values
    rot_cols, pos_cols = _column_layout(written)
    values = np.zeros((F, sum(len(c) for c in written)))
    by_order: dict[str, list[int]] = {}
    for j, order in enumerate(sk.rotation_orders):
        by_order.setdefault(order, []).append(j)
    for order, joints in by_order.items():
        q = rotations[:, joints]                                   # (F, Jg, 4)
        if not order:
            angle = 2 * np.arccos(np.clip(np.abs(q[..., 3]), 0, 1))
            if np.any(angle > 1e-6):
                j = joints[int(np.argmax(angle.max(axis=0)))]
                raise ExportError(f"joint {sk.names[j]!r} rotates, but it has no rotation "
                                  "channels to write the rotation in")
            continue
        angles = _joint_angles(q, order)                           # (Jg, F, n)
        # unwrapping changes nothing in a curve where no step reaches half a turn (but the
        # sign of zeros, which the rows do not write): only the curves that jump are unwrapped
        g, k = _jumps(angles)
        if len(g):
            angles[g, :, k] = np.unwrap(angles[g, :, k], period=360.0, axis=1)
        if len(order) < 3:
            back = euler_to_quat(angles.reshape(-1, len(order)), order).reshape(len(joints), F, 4)
            flat = q.transpose(1, 0, 2).reshape(-1, 4)
            err = np.abs(np.sum(back * flat.reshape(len(joints), F, 4), axis=-1))
            if np.any(err < np.cos(0.5e-5)):
                j = joints[int(np.argmin(err.min(axis=1)))]
                raise ExportError(f"joint {sk.names[j]!r} rotates about an axis it has no "
                                  f"channel for (it has only {sk.describe_channels(j)})")
        for g, j in enumerate(joints):
            values[:, rot_cols[j]] = angles[g]
    for k, j in enumerate(sk.translated):
        cols = pos_cols[j]
        t = translations[:, k]
        if not cols:
            tol = 1e-6 * max(1.0, np.abs(offsets[j]).max())
            if written[j] != sk.channels[j] and F and np.all(np.ptp(t, axis=0) <= tol):
                offsets[j] = t[0]             # a constant translation is the joint's bone
                continue
            if np.any(np.abs(t - offsets[j]) > tol):
                if written[j] != sk.channels[j]:
                    raise ExportError(f"joint {sk.names[j]!r} moves over the clip (its position "
                                      "channels change), so it cannot be written with rotation "
                                      "channels only; export it with all channels")
                raise ExportError(f"joint {sk.names[j]!r} moves, but it has no position "
                                  "channels to write the movement in")
            continue
        if F and np.any(offsets[j]) and _position_mode(offsets[j], {
                a: t[0, a] - (offsets[j][a] if modes[j] == "relative" else 0.0)
                for a in cols}) != modes[j]:
            # a reader tells the two modes apart by the first frame (detect_position_modes):
            # a joint that has moved far from its OFFSET there (the robot's foot, an IK target
            # carried away from its rest place; the robot's root turned with the figure to
            # face as the performer) is written with its first frame's position as its
            # OFFSET, as exporters write it (a zero OFFSET reads the same either way)
            offsets[j] = t[0].copy()
        for axis, col in cols.items():
            values[:, col] = t[:, axis] - offsets[j][axis] if modes[j] == "relative" \
                else t[:, axis]

    _check_range(sk, offsets, values, s)

    out = ["HIERARCHY"]
    sites_of: dict[int, list[EndSite]] = {}
    for site in sk.end_sites:
        sites_of.setdefault(site.parent, []).append(site)

    def off(v):
        return " ".join(_fmt(x, length_decimals) for x in v)

    def emit(j: int, depth: int):
        pad = "\t" * depth
        out.append(f"{pad}{'ROOT' if j == 0 else 'JOINT'} {sk.names[j]}")
        out.append(f"{pad}{{")
        out.append(f"{pad}\tOFFSET {off(offsets[j])}")
        out.append(f"{pad}\tCHANNELS {len(written[j])}"
                   + "".join(" " + c for c in written[j]))
        for child in sk.children[j]:
            emit(child, depth + 1)
        for site in sites_of.get(j, ()):
            out.append(f"{pad}\tEnd Site")
            out.append(f"{pad}\t{{")
            out.append(f"{pad}\t\tOFFSET {off(site.offset / s)}")
            out.append(f"{pad}\t}}")
        out.append(f"{pad}}}")

    import sys
    limit = sys.getrecursionlimit()
    if sk.depth.max() + 50 > limit:
        sys.setrecursionlimit(int(sk.depth.max()) + 100)
    emit(0, 0)
    out.append("MOTION")
    out.append(f"Frames: {F}")
    out.append(f"Frame Time: {motion.frame_time!r}")
    if values.shape[1]:
        column_decimals = np.full(values.shape[1], decimals)
        for cols in pos_cols:
            column_decimals[list(cols.values())] = length_decimals
        values = np.where(np.abs(values) < 0.5 * 10.0 ** -column_decimals, 0.0, values)
        if F:
            out.append(_format_rows(values, column_decimals))
    else:
        out.extend("" for _ in range(F))
    out.append("")                  # the last newline, by the join: no copy of the whole text
    return "\n".join(out)


def _joint_angles(q: np.ndarray, order: str) -> np.ndarray:
    """The Euler angles ``(Jg, F, len(order))`` of joints' rotations ``q`` ``(F, Jg, 4)``
    (``quat_to_euler`` of each joint's, not unwrapped). A joint whose rotation never changes
    (bit for bit) is turned once, its angles copied to every frame: the same values, the
    decomposition being value by value (a CC3 figure's fingers mostly never move)."""
    F, G = q.shape[:2]
    bits = np.ascontiguousarray(q).view(np.int64).reshape(F, G * 4)
    still = (np.equal(bits, bits[:1]).all(axis=0).reshape(G, 4).all(axis=1) if F
             else np.zeros(G, dtype=bool))
    angles = np.empty((G, F, len(order)))
    for joints, frames in ((np.flatnonzero(still), slice(0, 1)),
                           (np.flatnonzero(~still), slice(None))):
        if len(joints):
            part = q[frames, joints].transpose(1, 0, 2).reshape(-1, 4)      # joint-major
            angles[joints] = quat_to_euler(part, order, unwrap=False).reshape(
                len(joints), -1, len(order))
    return angles


def _jumps(angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The curves ``(g, k)`` of ``angles`` ``(Jg, F, n)`` with a step of half a turn or more
    (those ``np.unwrap`` may change), in order; found on the joint-major rows, the steps from
    one joint's last frame to the next one's first left out."""
    G, F, n = angles.shape
    if F < 2:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    at, k = np.nonzero(np.abs(np.diff(angles.reshape(G * F, n), axis=0)) >= 180.0)
    inside = at % F != F - 1
    curves = np.unique(at[inside] // F * n + k[inside])
    return curves // n, curves % n


def _slots(texts) -> np.ndarray:
    """Texts of at most 4 ASCII characters as little-endian 4-byte integers, NUL-padded."""
    return np.frombuffer(b"".join(t.encode("ascii").ljust(4, b"\0") for t in texts),
                         dtype="<u4")


#: 4-byte slots of the rows' text (NULs are dropped at the end, so a slot may hold fewer
#: characters, padded anywhere): three digits (a group of the fraction, or of the integer part
#: below its leading group), indexed by their value
_DIGITS3 = _slots(f"{g:03d}" for g in range(1000))
#: the leading group of an integer part, right-aligned, without the sign and with it
_LEAD = np.concatenate([_slots(f"{g}".rjust(4, "\0") for g in range(1000)),
                        _slots(f"-{g}".rjust(4, "\0") for g in range(1000))])
#: the first group of a fraction, ``.`` and 1, 2 or 3 digits
_POINT = {k: _slots(f".{g:0{k}d}" for g in range(10 ** k)) for k in (1, 2, 3)}
#: the separators after a value, in the last byte of a slot
_SPACE, _NEWLINE = ord(" ") << 24, ord("\n") << 24


def _format_rows(values: np.ndarray, decimals: np.ndarray) -> str:
    """The rows of ``values`` ``(F, C)`` in fixed point with ``decimals[c]`` digits after the
    point in column ``c``, values separated by a space and rows by a newline: the text of
    ``"%.6f"``-style formatting, character for character, built for all values at once.

    ``rint(|v| 10^d)`` of the rounded product is the correctly rounded value of the exact
    product (what ``%`` formatting rounds) unless the product lies within its rounding error of
    a half (a near tie) or beyond 2^52; a row holding such a value is formatted with ``%``.
    The others are written by :func:`_fixed_rows`, :data:`_FORMAT_VALUES` values at a time.
    """
    scale = 10.0 ** decimals                                 # exact up to 22 decimals
    with np.errstate(over="ignore", invalid="ignore"):      # huge: infinite, formatted alone
        mag = np.abs(values) * scale
        near = ((np.abs(mag - np.floor(mag) - 0.5) <= mag * 2.0 ** -51) | ~(mag < 2.0 ** 52)
                | (decimals > 22))
    number = np.rint(mag, out=mag)
    negative = np.signbit(values)
    exact = np.flatnonzero(near.any(axis=1)).tolist()
    row_format = " ".join(f"%.{d}f" for d in decimals) if exact else ""
    F, C = values.shape
    step = max(1, _FORMAT_VALUES // C)
    pieces, start = [], 0
    for f in [*exact, F]:
        for lo in range(start, f, step):        # the rows before it, a block at a time
            hi = min(f, lo + step)
            pieces.append(_fixed_rows(number[lo:hi], negative[lo:hi], decimals))
        if f < F:
            pieces.append(row_format % tuple(values[f].tolist()))
        start = f + 1
    return "\n".join(pieces)


#: values formatted at a time by :func:`_format_rows`: the temporaries of a block stay small
#: (a whole large clip's would be hundreds of MB) and in the caches
_FORMAT_VALUES = 1 << 16


def _fixed_rows(number: np.ndarray, negative: np.ndarray, decimals: np.ndarray) -> str:
    """:func:`_format_rows` of values whose digits are the whole numbers ``number`` ``(F, C)``
    (``rint(|v| 10^d)``, below 2^52) and signs ``negative``.

    Each value is a few 4-byte slots (its integer part's groups of three digits, the leading
    one with the sign; the fraction's groups, the first with the point; the separator in the
    last byte of the last slot), taken from tables for all values at once; the slots' NULs
    are dropped in one pass. The integer and the fraction's groups are split off in floating
    point, exactly: for whole numbers below 2^52, ``floor(n / 10^k)`` is the integer quotient.
    """
    F, C = number.shape
    plans = []
    for d in np.unique(decimals):
        cols = np.flatnonzero(decimals == d)
        d = int(d)
        groups = -(-d // 3)                                  # of the fraction
        integer = np.floor(number[:, cols] / 10.0 ** d)
        fraction = number[:, cols] - integer * 10.0 ** d
        top = float(integer.max(initial=0.0))
        lead = 1                                             # groups of the integer part
        while top >= 1000.0 ** lead:
            lead += 1
        plans.append((cols, d, groups, integer, fraction, lead))
    # slots: integer part, fraction, and one for the separator where the last slot is full
    width = max(lead + groups + (d in (0, 3)) for _, d, groups, _, _, lead in plans)
    slots = np.zeros((F, C, width), dtype="<u4")
    for cols, d, groups, integer, fraction, lead in plans:
        one = len(cols) == C                                 # every column: no gather
        out = slots if one else np.zeros((F, len(cols), width), dtype="<u4")
        full = d in (0, 3)                   # the last slot is full: "-123" or ".123"
        at = width - 1 - full                                # the fraction's last slot
        for k in range(groups):                              # the fraction, right to left
            size = min(3, d - 3 * k)
            if k < groups - 1:
                rest = np.floor(fraction / 1000.0)
                digits = fraction - rest * 1000.0
                fraction = rest
            else:
                digits = fraction
            table = _POINT[size] if k == groups - 1 else _DIGITS3
            out[:, :, at - k] = table[digits.astype(np.intp)]
        at -= groups                                         # the integer part's last slot
        sign = negative[:, cols] if not one else negative
        below = None                         # the digits of the group below, as indices
        for k in range(lead):                                # the integer part, right to left
            rest = np.floor(integer / 1000.0)
            digits = integer - rest * 1000.0
            leading = _LEAD[(digits + 1000.0 * sign).astype(np.intp)]
            if k:
                # the slot leads where something is left at it; the group below it, written
                # as a leading one, is padded to three digits there instead
                here = integer > 0
                out[:, :, at - k + 1] = np.where(here, _DIGITS3[below], out[:, :, at - k + 1])
                out[:, :, at - k] = np.where(here, leading, 0)
            else:
                out[:, :, at] = leading
            below = digits.astype(np.intp)
            integer = rest
        separator = np.full(len(cols), _SPACE, dtype="<u4")
        separator[cols == C - 1] = _NEWLINE
        if full:
            out[:, :, -1] = separator
        else:
            out[:, :, -1] |= separator
        if not one:
            slots[:, cols] = out
    # the NULs dropped by bytes.translate: a third faster than numpy's compress with its mask
    return slots.tobytes().translate(None, b"\0")[:-1].decode("ascii")


def _check_range(sk: Skeleton, offsets: np.ndarray, values: np.ndarray, scale: float) -> None:
    """Refuse, with an :class:`ExportError`, a motion whose numbers in file units (``offsets``
    ``(J, 3)``, channel ``values`` ``(F, C)``, End Site offsets over ``scale``) leave the range
    the reader takes (:data:`engine.limits.MAX_MAGNITUDE`): the file would not read back."""
    sites = np.array([site.offset / scale for site in sk.end_sites]).reshape(-1, 3)
    for what, array in (("OFFSET", offsets), ("End Site OFFSET", sites)):
        if not limits.all_usable(array):
            k = int(np.flatnonzero(~(np.abs(array) <= limits.MAX_MAGNITUDE).all(axis=1))[0])
            joint = sk.names[k] if what == "OFFSET" else sk.end_sites[k].name
            raise ExportError(f"the {what} of {joint!r} in file units ({array[k].tolist()}) is "
                              f"beyond the range a BVH file is read with (magnitude at most "
                              f"{limits.MAX_MAGNITUDE:g}); the file would not read back")
    if not limits.all_usable(values):
        f, c = (int(i[0]) for i in np.nonzero(~(np.abs(values) <= limits.MAX_MAGNITUDE)))
        raise ExportError(f"frame {f + 1}, {_channel_label(c, sk.names, sk.channels)}: "
                          f"{values[f, c]:g} in file units is beyond the range a BVH file is "
                          f"read with (magnitude at most {limits.MAX_MAGNITUDE:g}); the file "
                          "would not read back (a root scale or unit that blows the motion "
                          "up?)")


def write_bvh(motion: Motion, path: str | os.PathLike, **options) -> None:
    """Write ``motion`` as a BVH file, atomically (options as :func:`format_bvh`)."""
    atomic_write(path, format_bvh(motion, **options))
