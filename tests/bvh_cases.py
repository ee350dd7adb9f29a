"""Bad BVH inputs, each built from a real bundled clip, with the line an error must name.

Shared by test_bvh_errors.py (the typed error) and test_cli.py (exit code 2, one line on stderr).
The base is ``cmu_131_01_walk.bvh``, which mixes CRLF and LF line endings, so the expected line
numbers also check that both count as one line. Line numbers here follow
``bytes.splitlines()`` (a line ends at CRLF, LF or a bare CR), counted from 1.
"""
from __future__ import annotations

import gzip
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from conftest import clip_path

WALK = clip_path("cmu_131_01_walk.bvh")


@dataclass(frozen=True)
class BadCase:
    """``build()`` returns the file's bytes and the line the error must name (None: no line)."""

    id: str
    build: Callable[[], tuple[bytes, int | None]]
    expects: tuple[str, ...]          # phrases the message must contain (case-insensitive)

    def write(self, folder: Path) -> tuple[Path, int | None]:
        data, line = self.build()
        path = folder / f"bad_{self.id}.bvh"
        path.write_bytes(data)
        return path, line


def walk_lines() -> list[bytes]:
    return WALK.read_bytes().splitlines(keepends=True)


def find(lines: list[bytes], start: bytes, after: int = 0) -> int:
    """0-based index of the first line at or after ``after`` whose stripped text starts so."""
    return next(i for i in range(after, len(lines)) if lines[i].strip().startswith(start))


def first_row(lines) -> int:
    return find(lines, b"Frame Time") + 1


def _replace_line(index_of, old: bytes, new: bytes):
    def build():
        lines = walk_lines()
        i = index_of(lines)
        assert old in lines[i]
        lines[i] = lines[i].replace(old, new, 1)
        return b"".join(lines), i + 1
    return build


def _row_token(row: int, value: int, token: bytes):
    """Frame ``row`` (1-based), value ``value`` (1-based) replaced by ``token``."""
    def build():
        lines = walk_lines()
        i = first_row(lines) + row - 1
        body = lines[i].rstrip(b"\r\n")
        ending = lines[i][len(body):]
        parts = body.split()
        if token == b"<drop>":
            del parts[value - 1]
        elif token == b"<extra>":
            parts.append(b"1.0")
        else:
            parts[value - 1] = token
        lines[i] = b" ".join(parts) + ending
        return b"".join(lines), i + 1
    return build


def _truncate_hierarchy():
    lines = walk_lines()
    elbow = find(lines, b"JOINT LeftElbow")
    kept = lines[:elbow + 3]                         # ends on LeftElbow's OFFSET line
    return b"".join(kept), len(kept)


def _truncate_mid_offset():
    lines = walk_lines()
    i = find(lines, b"OFFSET", find(lines, b"JOINT LeftShoulder"))
    head = b"".join(lines[:i])
    cut = lines[i][:lines[i].index(b"OFFSET") + len(b"OFFSET 3.05381")]
    return head + cut, i + 1


def _truncate_mid_row():
    lines = walk_lines()
    i = first_row(lines) + 499                       # frame 500
    return b"".join(lines[:i]) + lines[i][:len(lines[i]) // 2], i + 1


def _truncate_at_row_end():
    lines = walk_lines()
    i = first_row(lines) + 499                       # frames 1..499 complete
    return b"".join(lines[:i]), i


def _truncate_after(start: bytes):
    def build():
        lines = walk_lines()
        i = find(lines, start)
        return b"".join(lines[:i + 1]), i + 1
    return build


def _drop_motion_keyword():
    lines = walk_lines()
    i = find(lines, b"MOTION")
    del lines[i]
    return b"".join(lines), i + 1                    # 'Frames:' now sits on MOTION's line


def _no_motion_section():
    lines = walk_lines()
    i = find(lines, b"MOTION")
    return b"".join(lines[:i]), i                    # the root's closing brace is last


def _frames(n: bytes, line_of):
    def build():
        lines = walk_lines()
        i = find(lines, b"Frames:")
        lines[i] = lines[i].replace(b"994", n)
        return b"".join(lines), line_of(lines, i)
    return build


def _last_line(lines, _):
    return len(lines)


def _extra_brace():
    lines = walk_lines()
    i = find(lines, b"MOTION")
    lines.insert(i, b"}\r\n")
    return b"".join(lines), i + 1


def _missing_brace():
    lines = walk_lines()
    i = find(lines, b"MOTION")
    assert lines[i - 1].strip() == b"}"
    del lines[i - 1]
    return b"".join(lines), i                        # stops at MOTION, now one line up


def _duplicate_name():
    lines = walk_lines()
    i = find(lines, b"JOINT RightToe")
    lines[i] = lines[i].replace(b"RightToe", b"LeftToe")
    return b"".join(lines), i + 1


CASES = [
    BadCase("truncated-hierarchy", _truncate_hierarchy,
            ("LeftElbow", "expected '}'", "truncated")),
    BadCase("truncated-mid-offset", _truncate_mid_offset,
            ("expected the Y value of OFFSET",)),
    BadCase("truncated-mid-row", _truncate_mid_row,
            ("frame 500 has", "expected 96")),
    BadCase("truncated-between-rows", _truncate_at_row_end,
            ("'Frames: 994'", "ends after 499 rows")),
    BadCase("truncated-after-motion", _truncate_after(b"MOTION"),
            ("expected a 'Frames:' line",)),
    BadCase("truncated-after-frames", _truncate_after(b"Frames:"),
            ("expected a 'Frame Time:' line",)),
    BadCase("missing-value", _row_token(114, 40, b"<drop>"),
            ("frame 114 has 95 values", "expected 96")),
    BadCase("extra-value", _row_token(3, 1, b"<extra>"),
            ("frame 3 has 97 values", "expected 96")),
    BadCase("not-a-number", _row_token(10, 5, b"abc"),
            ("value 5 of frame 10", "Hips Yrotation", "'abc'", "expected a number")),
    BadCase("nan", _row_token(20, 2, b"nan"),
            ("value 2 of frame 20", "Hips Yposition", "expected a finite number")),
    BadCase("inf", _row_token(994, 96, b"inf"),
            ("value 96 of frame 994", "expected a finite number")),
    BadCase("minus-infinity", _row_token(1, 7, b"-Infinity"),
            ("value 7 of frame 1", "expected a finite number")),
    BadCase("overflow", _row_token(2, 8, b"1e999"),
            ("value 8 of frame 2", "expected a finite number")),
    # finite numbers that overflow once scaled, squared or turned into angles (issue 13): a
    # deep-learning exporter writing an unnormalised output, a corrupted float written as text
    BadCase("value-1e308-position", _row_token(1, 1, b"1e308"),
            ("value 1 of frame 1", "Hips Xposition", "'1e308'", "beyond the range")),
    BadCase("value-1e308-rotation", _row_token(40, 5, b"-1e308"),
            ("value 5 of frame 40", "Hips Yrotation", "'-1e308'", "beyond the range")),
    BadCase("value-just-too-large", _row_token(7, 9, b"1000000001"),
            ("value 9 of frame 7", "beyond the range")),
    BadCase("offset-1e308",
            _replace_line(lambda ls: find(ls, b"OFFSET", find(ls, b"JOINT Chest")),
                          b"OFFSET ", b"OFFSET 1e308 "),
            ("expected the X value of OFFSET", "'1e308'", "beyond the range")),
    BadCase("offset-not-a-number",
            _replace_line(lambda ls: find(ls, b"OFFSET", find(ls, b"JOINT LeftShoulder")),
                          b"1.47088", b"abc"),
            ("expected the Y value of OFFSET", "'abc'")),
    BadCase("offset-nan",
            _replace_line(lambda ls: find(ls, b"OFFSET", find(ls, b"JOINT Chest")),
                          b"OFFSET ", b"OFFSET nan "),
            ("expected the X value of OFFSET", "finite")),
    BadCase("no-motion-keyword", _drop_motion_keyword, ("'Frames:'", "expected MOTION")),
    BadCase("no-motion-section", _no_motion_section, ("no MOTION section", "expected")),
    BadCase("frames-fewer-than-rows", _frames(b"993", _last_line),
            ("'Frames: 993'", "994 rows", "disagrees")),
    BadCase("frames-more-than-rows", _frames(b"995", _last_line),
            ("'Frames: 995'", "ends after 994 rows", "disagrees")),
    BadCase("frames-zero", _frames(b"0", lambda ls, i: i + 1),
            ("Frames: 0", "expected at least one frame")),
    BadCase("frames-not-a-number", _frames(b"many", lambda ls, i: i + 1),
            ("expected a whole number of frames",)),
    BadCase("frames-superscript", _frames("\u00b2".encode(), lambda ls, i: i + 1),
            ("expected a whole number of frames",)),
    BadCase("frame-time-not-a-number",
            _replace_line(lambda ls: find(ls, b"Frame Time"), b".0083333", b"fast"),
            ("expected a positive number of seconds",)),
    BadCase("frame-time-zero",
            _replace_line(lambda ls: find(ls, b"Frame Time"), b".0083333", b"0"),
            ("expected a positive number of seconds",)),
    # a Frame Time that is a frame rate, or garbage: 1e308 s per frame, and 12 s (more than
    # the 10 s accepted; a stop-motion export at 1/12 fps written as 12)
    BadCase("frame-time-1e308",
            _replace_line(lambda ls: find(ls, b"Frame Time"), b".0083333", b"1e308"),
            ("expected a positive number of seconds, at most 10", "'1e308'")),
    BadCase("frame-time-12-seconds",
            _replace_line(lambda ls: find(ls, b"Frame Time"), b".0083333", b"12"),
            ("expected a positive number of seconds, at most 10", "'12'")),
    BadCase("extra-closing-brace", _extra_brace, ("unbalanced braces", "'}'")),
    BadCase("missing-closing-brace", _missing_brace,
            ("joint 'Hips' (opened at line 2)", "expected '}'")),
    BadCase("duplicate-joint-name", _duplicate_name,
            ("duplicate joint name 'LeftToe'", "first at line 22", "unique")),
    BadCase("unknown-channel",
            _replace_line(lambda ls: find(ls, b"CHANNELS", find(ls, b"JOINT Chest")),
                          b"Yrotation", b"Wrotation"),
            ("unknown channel 'Wrotation'", "expected one of")),
    BadCase("empty", lambda: (b"", None), ("empty", "expected")),
    BadCase("blank", lambda: (b" \r\n\t\n\n", None), ("empty", "expected")),
    BadCase("binary-nul", lambda: (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x01", None),
            ("binary",)),
    BadCase("binary-gzip", lambda: (gzip.compress(WALK.read_bytes(), mtime=0), None),
            ("binary",)),
    BadCase("binary-no-nul", lambda: (bytes(range(128, 256)) * 4, 1),
            ("expected the keyword HIERARCHY",)),
    BadCase("not-bvh-text", lambda: (b"ply\nformat ascii 1.0\nelement vertex 8\n", 1),
            ("expected the keyword HIERARCHY", "'ply'")),
]
