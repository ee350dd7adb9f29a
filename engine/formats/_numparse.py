"""The parser for blocks of decimal numbers (the MOTION section of a BVH file).

``float()`` on each of a large file's 340,000 numbers costs about 70 ms. numpy's C reader
(``numpy.loadtxt``) splits and converts them with the same correctly rounded conversion as
``float()`` (``PyOS_string_to_double``), so it returns the *same* doubles, in about 13 ms; this
module adds the checks that keep its result a plain decimal block: only the bytes of decimal
and exponent notation and white space, tokens of at most 24 characters, every non-blank line
``columns`` numbers, every value finite. Anything else (``nan``, a stray character, a
misplaced sign, a row of the wrong length) makes it return ``None``; the caller then parses
line by line, which also words the error.

The common shape of a token, plain decimal notation (``-12.345678``, ``0.5``, ``-17``: an optional
minus, at most 8 digits before the point and 8 after it, 15 in all), is parsed by numpy without
``loadtxt`` (:func:`_parse_plain`), about 4x faster: its digits make a whole number ``m`` below
10^15 and the value is ``m / 10^k`` (``k`` digits after the point), one correctly rounded
division of two exact doubles, which is the correctly rounded value of the decimal, the double
``float()`` returns (Clinger's fast path). A piece holding any other token goes to ``loadtxt``.

The block is parsed a piece of about a megabyte at a time, so that the temporaries stay small
beside the values of a large file (a 72 MB file's values are 61 MB).
"""
from __future__ import annotations

import io

import numpy as np

__all__ = ["parse_number_rows", "parse_number_pieces", "file_pieces"]

#: the bytes of numbers in decimal or exponent notation, and white space
_VALID_BYTES = b"0123456789.-+eE \t\n\r\f\v"
#: the bytes of the plain decimal notation :func:`_parse_plain` takes, and its white space
_PLAIN_BYTES = b"0123456789.- \t\n\r"
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
    if not data.translate(None, _PLAIN_BYTES):
        values = _parse_plain(data, columns)
        if values is not None:
            return values
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


# --------------------------------------------------------------------------- plain decimals
#: ``_TOP[k]``: the mask of the top ``k`` bytes of a little-endian 8-byte word (its last ``k``
#: characters), k = 0 to 8; ``_ZEROS[k]``: the character '0' in each of those bytes
_TOP = np.array([0] + [((1 << (8 * k)) - 1) << (8 * (8 - k)) for k in range(1, 9)],
                dtype=np.uint64)
_ZEROS = _TOP & np.uint64(0x3030303030303030)
_POWERS = 10 ** np.arange(9, dtype=np.uint64)
#: ``10^k`` then ``-10^k``, k = 0 to 8
_DIVISORS = np.concatenate([10.0 ** np.arange(9), -10.0 ** np.arange(9)])
#: digits before and after the point taken by :func:`_parse_plain` (8 each: one word), and in
#: all (below 10^15 < 2^53, a whole number exact in a double)
_PLAIN_SIDE, _PLAIN_DIGITS = 8, 15


def _parse_plain(data: bytes, columns: int) -> np.ndarray | None:
    """:func:`_parse_piece` of a piece whose tokens are all plain decimal notation: an optional
    minus, then digits with at most one point among them (``-12.5``, ``7``, ``.5``, ``5.``),
    at most :data:`_PLAIN_SIDE` digits either side of the point and :data:`_PLAIN_DIGITS` in
    all, laid out ``columns`` to a non-blank line (``data`` holds only :data:`_PLAIN_BYTES`);
    None for anything else (the caller then parses with ``loadtxt``, which also refuses what
    is no number).

    A token's digits before the point are the top bytes of the 8-byte word that ends at its
    point, those after it the top bytes of the word that ends at its end; each word's digits
    become a whole number in three multiply-and-add steps on pairs, fours and eights of
    digits (all tokens at once). With ``m`` the token's digits as one whole number (below
    10^15, exact) and ``k`` of them after the point, its value is ``m / 10^k``: both exact
    doubles, so the division's rounding is the correct rounding of the decimal, the double
    ``float()`` gives; with a minus the divisor is ``-10^k``, which gives ``-(m / 10^k)``
    (rounding to nearest is symmetric) and ``-0`` negative zero, as ``float`` does.
    """
    if b"\r" in data and data.count(b"\r") != data.count(b"\r\n"):
        return None                            # a lone CR ends a line for the careful parser
    padded = b" " * 8 + data + b" " * 8        # every word read lies inside
    chars = np.frombuffer(padded, dtype=np.uint8)
    solid = chars > 32
    edges = np.flatnonzero(solid[1:] != solid[:-1]) + 1
    starts, ends = edges[0::2], edges[1::2]
    n = len(starts)
    if n == 0:
        return None
    points = np.flatnonzero(chars == 46)       # '.'
    negative = chars[starts] == 45             # '-'
    if np.count_nonzero(negative) != np.count_nonzero(chars == 45):
        return None                            # a minus inside a token
    first = starts + negative                  # the first digit (or the point)
    if len(points) == n:
        # the i-th point is the i-th token's exactly where it lies inside that token (so then
        # no token has none and none two): checked by both sides' lengths being >= 0
        point = points
    else:
        # tokens with no point (whole numbers) among them: the point is counted per token
        seen = np.cumsum(chars == 46, dtype=np.int32)
        inside = seen[ends - 1] - seen[starts - 1]
        if inside.max() > 1:
            return None
        point = np.where(inside == 1, points[seen[ends - 1] - 1], ends) if len(points) \
            else ends
    whole = point - first                      # digits before the point
    fraction = np.maximum(ends - point - 1, 0)  # after it (none without a point)
    digits = whole + fraction
    if (whole.min() < 0 or (ends - point).min() < 0 or digits.min() < 1
            or whole.max() > _PLAIN_SIDE or fraction.max() > _PLAIN_SIDE
            or digits.max() > _PLAIN_DIGITS):
        return None
    lines = np.diff(np.searchsorted(starts, _newlines(padded)), prepend=0, append=n)
    if np.any((lines != columns) & (lines != 0)):
        return None                            # a row of another length
    words = np.ndarray((len(chars) - 7,), dtype="<u8", buffer=padded, strides=(1,))
    before = words[point - 8]
    before &= _TOP[whole]
    before -= _ZEROS[whole]
    after = words[ends - 8]
    after &= _TOP[fraction]
    after -= _ZEROS[fraction]
    number = _eight_digits(before)
    number *= _POWERS[fraction]
    number += _eight_digits(after)
    values = number.astype(float)
    values /= _DIVISORS[fraction + len(_POWERS) * negative]
    return values.reshape(-1, columns)


def _newlines(data: bytes) -> np.ndarray:
    """The offsets of the newlines in ``data`` (a few hundred in a piece: found by ``find``,
    faster than a pass of numpy over every byte)."""
    out, at = [], data.find(b"\n")
    while at >= 0:
        out.append(at)
        at = data.find(b"\n", at + 1)
    return np.array(out, dtype=np.intp)


_PAIRS, _FOURS, _EIGHT = (np.uint64(m) for m in (0x00FF00FF00FF00FF, 0x0000FFFF0000FFFF,
                                                 0xFFFFFFFF))


def _eight_digits(words: np.ndarray) -> np.ndarray:
    """The whole numbers of 8-digit strings held as digit values 0-9 in the bytes of
    little-endian words (the first, most significant digit in the lowest byte)."""
    for mask, shift, scale in ((_PAIRS, 8, 10), (_FOURS, 16, 100), (_EIGHT, 32, 10000)):
        # each even slot's number times the slot size's power of ten plus the next slot's
        low = words >> np.uint64(shift)
        words *= np.uint64(scale)
        words += low
        words &= mask
    return words
