"""The parser for blocks of decimal numbers (the MOTION section of a BVH file).

``float()`` on each of a large file's 340,000 numbers costs about 70 ms. numpy's C reader
(``numpy.loadtxt``) splits and converts them with the same correctly rounded conversion as
``float()`` (``PyOS_string_to_double``), so it returns the *same* doubles, in about 13 ms; this
module adds the checks that keep its result a plain decimal block: only the bytes of decimal
and exponent notation and white space, tokens of at most 24 characters, every non-blank line
``columns`` numbers, every value finite. Anything else (``nan``, a stray character, a
misplaced sign, a row of the wrong length) makes it return ``None``; the caller then parses
line by line, which also words the error.

The block is parsed a piece of about a megabyte at a time, so that the temporaries stay small
beside the values of a large file (a 72 MB file's values are 61 MB).
"""
from __future__ import annotations

import io

import numpy as np

__all__ = ["parse_number_rows", "parse_number_pieces", "file_pieces"]

#: the bytes of numbers in decimal or exponent notation, and white space
_VALID_BYTES = b"0123456789.-+eE \t\n\r\f\v"
#: the longest token taken: longer than any number a real file writes
_MAX_WIDTH = 24
#: characters parsed at a time (then up to the end of the line)
_PIECE = 1 << 20


def parse_number_rows(data: bytes | str, columns: int, *, start: int = 0,
                      rows: int | None = None, limit: float = np.inf):
    """Parse white-space separated decimals laid out ``columns`` to a non-blank line.

    ``data[start:]`` is the block (text must be ASCII to pass); with ``rows`` given, a block of
    another number of rows is refused too, and the values go straight into one array; a value
    of magnitude above ``limit`` refuses the block.

    Returns ``(values, rows)`` with ``values`` of shape ``(rows, columns)``, or ``None`` when the
    block is not plain decimal notation with exactly ``columns`` finite numbers on every
    non-blank line.
    """
    return parse_number_pieces(_pieces(data, start), columns, rows=rows, limit=limit)


def _pieces(data: bytes | str, start: int):
    """``data[start:]`` as ASCII bytes in pieces of whole lines (None for text that is not
    ASCII)."""
    newline = b"\n" if isinstance(data, bytes) else "\n"
    pos, size = start, len(data)
    while pos < size:
        end = data.find(newline, pos + _PIECE)
        end = size if end < 0 else end + 1
        piece = data[pos:end]
        yield piece if isinstance(piece, bytes) else (
            piece.encode("ascii") if piece.isascii() else None)
        pos = end


def file_pieces(handle, carry: bytes = b""):
    """``carry`` then the rest of the binary file ``handle``, in pieces of whole lines of
    about :data:`_PIECE` bytes: a large file's block is parsed without being read whole."""
    while True:
        chunk = handle.read(_PIECE)
        if not chunk:
            if carry:
                yield carry
            return
        chunk = carry + chunk
        cut = chunk.rfind(b"\n") + 1
        if cut:
            yield chunk[:cut]
        carry = chunk[cut:]


def parse_number_pieces(pieces, columns: int, *, rows: int | None = None,
                        limit: float = np.inf):
    """:func:`parse_number_rows` of a block given as pieces of whole lines (bytes; a None
    piece refuses the block)."""
    parts, count = [], 0
    out = None if rows is None else np.empty((rows, columns))
    for piece in pieces:
        values = None if piece is None else _parse_piece(piece, columns)
        if values is None or not np.all(np.abs(values) <= limit):
            return None
        if out is not None:
            if count + len(values) > rows:
                return None
            out[count:count + len(values)] = values
        else:
            parts.append(values)
        count += len(values)
    if out is not None:
        return (out, count) if count == rows else None
    if not parts:
        return np.zeros((0, columns)), 0
    return (np.concatenate(parts) if len(parts) > 1 else parts[0]), count


def _parse_piece(data: bytes, columns: int) -> np.ndarray | None:
    """``(rows, columns)`` values of whole lines of ``data``, or None."""
    if data.translate(None, _VALID_BYTES) or _has_long_token(data):
        return None
    if not data or data.isspace():
        return np.zeros((0, columns))
    try:
        values = np.loadtxt(io.BytesIO(data), dtype=float, comments=None, ndmin=2,
                            encoding="ascii")
    except ValueError:                     # a token that is no number, or a ragged row
        return None
    if values.shape[1] != columns or not np.isfinite(values).all():
        return None
    return values


#: 4 flags ``bytes > 32``, all set, as one little-endian integer
_SOLID = 0x01010101
#: the blocks looked at first: any run of 23 bytes or more covers a whole one
_BLOCK = 12


def _has_long_token(data: bytes) -> bool:
    """Whether ``data`` holds a token longer than :data:`_MAX_WIDTH` characters (a run of
    bytes above the space, white space being the only bytes at or below it that are left).

    The blocks of :data:`_BLOCK` bytes (at multiples of it) are looked at first, as integers
    of 4 flags: a run of 25 bytes or more covers a whole block (any 23 consecutive bytes do;
    one reaching past the last whole block has 14 or more bytes before its end, which is a
    block's end). Only where a block is solid (a token of 12 characters or more sits on it)
    are the runs measured.
    """
    flags = np.frombuffer(data, dtype=np.uint8) > 32
    whole = len(flags) // _BLOCK * _BLOCK
    words = flags[:whole].view("<u4") == _SOLID
    return bool((words[0::3] & words[1::3] & words[2::3]).any()) and \
        _longest_token(data) > _MAX_WIDTH


def _longest_token(data: bytes) -> int:
    """The length of the longest run of bytes above the space."""
    gaps = np.flatnonzero(np.frombuffer(data, dtype=np.uint8) <= 32)
    return int(np.diff(gaps, prepend=-1, append=len(data)).max(initial=1)) - 1
