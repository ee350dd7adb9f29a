"""A vectorised parser for blocks of decimal numbers (the MOTION section of a BVH file).

``float()`` on each of a large file's 340,000 numbers costs about 70 ms; this parser gathers
the tokens into a small ``(tokens, width)`` byte matrix and evaluates the digits with numpy,
returning the *same* doubles as ``float()``: a value is an exact integer mantissa (at most 15
digits) divided by an exact power of ten, and IEEE division rounds that correctly. Tokens in
exponent notation are few in real files and go through ``float()`` one by one. Anything else
(``nan``, a stray character, a misplaced sign, a row of the wrong length) makes it return
``None``; the caller then parses line by line, which also words the error.
"""
from __future__ import annotations

import numpy as np

__all__ = ["parse_number_rows"]

_POW10 = 10.0 ** np.arange(0, 23)
_MAX_WIDTH = 24

_VALID_BYTES = b"0123456789.-+eE \t\n\r\f\v"


_CHUNK = 1 << 17      # bytes per piece: small enough for the temporaries to stay in cache


def parse_number_rows(data: bytes, columns: int):
    """Parse white-space separated decimals laid out ``columns`` to a non-blank line.

    Returns ``(values, rows)`` with ``values`` of shape ``(rows, columns)``, or ``None`` when the
    block is not plain decimal notation with exactly ``columns`` numbers on every non-blank
    line.
    """
    if data.translate(None, _VALID_BYTES):
        return None                       # a byte that cannot be part of a decimal number
    pieces = []
    pos, size = 0, len(data)
    while pos < size:
        end = data.find(b"\n", pos + _CHUNK)
        end = size if end < 0 else end + 1
        parsed = _parse_piece(data[pos:end], columns)
        if parsed is None:
            return None
        pieces.append(parsed)
        pos = end
    if not pieces:
        return np.zeros((0, columns)), 0
    values = np.concatenate(pieces) if len(pieces) > 1 else pieces[0]
    return values, values.shape[0]


def _parse_piece(data: bytes, columns: int):
    b = np.frombuffer(data, dtype=np.uint8)
    space = b <= 32
    body = ~space
    if not body.any():
        return np.zeros((0, columns))
    edge = np.diff(body.view(np.int8), prepend=np.int8(0), append=np.int8(0))
    starts = np.flatnonzero(edge == 1)
    ends = np.flatnonzero(edge == -1)
    n = len(starts)
    lengths = ends - starts
    width = int(lengths.max())
    if width > _MAX_WIDTH:
        return None
    # exactly `columns` tokens on every line that has any
    newlines = np.flatnonzero(b == 10)
    line_of_tok = np.searchsorted(newlines, starts)
    bounds = np.flatnonzero(np.diff(line_of_tok)) + 1
    per_line = np.diff(np.concatenate([[0], bounds, [n]]))
    if np.any(per_line != columns):
        return None
    rows = len(per_line)

    padded = np.concatenate([b, np.full(width, 32, dtype=np.uint8)])
    cols = np.arange(width)
    mat = padded[cols[:, None] + starts]                         # (width, n) bytes, one gather
    mat[cols[:, None] >= lengths] = 32                          # blank what is past each token

    digit = mat - np.uint8(48)
    is_digit = digit < 10
    is_dot = mat == 46
    is_sign = (mat == 45) | (mat == 43)
    is_exp = (mat | np.uint8(32)) == 101
    sci = is_exp.any(axis=0)                                     # tokens in exponent notation
    plain = ~sci
    # plain tokens: optional sign first, at most one dot, 1..15 digits
    if is_sign[1:].any(axis=None) and (is_sign[1:] & plain).any():
        return None
    n_digits = is_digit.sum(axis=0)
    if np.any(plain & ((is_dot.sum(axis=0) > 1) | (n_digits == 0) | (n_digits > 15))):
        return None
    mul = (is_digit * np.uint8(9)) + np.uint8(1)                 # 10 on digits, 1 elsewhere
    add = digit * is_digit
    mant = np.zeros(n)
    for w in range(width):                                       # Horner, exact below 2**53
        mant *= mul[w]
        mant += add[w]
    # digits after the dot: in a plain token everything after the dot is a digit
    dot_w, dot_tok = np.nonzero(is_dot)                          # at most one per token
    frac = np.zeros(n, dtype=np.intp)
    frac[dot_tok] = lengths[dot_tok] - 1 - dot_w
    value = mant / _POW10[np.clip(frac, 0, 22)]
    value = np.where(mat[0] == 45, -value, value)
    if sci.any():
        for t in np.flatnonzero(sci):
            token = data[starts[t]:ends[t]]
            try:
                value[t] = float(token)
            except ValueError:
                return None
        if not np.all(np.isfinite(value[sci])):
            return None
    return value.reshape(rows, columns)
