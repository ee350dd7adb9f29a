"""The MOTION parser's path for plain decimal notation (``_numparse._parse_plain``: numpy on the
bytes instead of ``loadtxt``) gives ``float()``'s double for every token, bit for bit, takes
every token of that shape and refuses every other (so that ``loadtxt`` and the careful parser
decide them): on every clip, a piece at a time as a read does, and on generated tokens."""
from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from conftest import all_bvh_params, resolve, shared_path
from motion_composer.engine.formats import _numparse
from motion_composer.engine.formats._numparse import _parse_plain, parse_number_rows

#: the shape the plain path takes, written from its definition (not from the code): an
#: optional minus, at most 8 digits, an optional point and at most 8 digits, 1 to 15 in all
_PLAIN = re.compile(r"-?(\d{0,8})(?:\.(\d{0,8}))?")


def _is_plain(token: str) -> bool:
    m = _PLAIN.fullmatch(token)
    return bool(m) and 1 <= len(m.group(1)) + len(m.group(2) or "") <= 15


def _bits(values) -> np.ndarray:
    return np.asarray(values, dtype=float).view(np.int64)


def _block(path) -> tuple[bytes, int]:
    """The bytes after the ``Frame Time:`` line and the number of values on the first row."""
    data = path.read_bytes()
    at = data.index(b"\n", data.lower().index(b"frame time")) + 1
    return data[at:], len(data[at:].split(b"\n", 1)[0].split())


@pytest.mark.parametrize("spec", all_bvh_params())
def test_every_clip_piece_by_piece(spec, monkeypatch):
    """Each piece a read parses: where all its tokens are plain, the plain path takes it and
    gives float()'s values; elsewhere it refuses it."""
    block, columns = _block(resolve(spec))
    for size in (1 << 20, 4093):
        monkeypatch.setattr(_numparse, "_PIECE", size)
        for piece in _numparse._pieces(block, 0):
            got = _parse_plain(piece, columns) if not piece.translate(
                None, _numparse._PLAIN_BYTES) else None
            tokens = piece.decode("ascii").split()
            if tokens and all(_is_plain(t) for t in tokens):
                assert got is not None
                expected = np.array([float(t) for t in tokens]).reshape(-1, columns)
                assert np.array_equal(_bits(got), _bits(expected))
            else:
                assert got is None


def test_the_large_clip_takes_the_plain_path():
    """The benchmark's clip (six decimals) is parsed without loadtxt, piece by piece."""
    block, columns = _block(shared_path("cc3_cmu_02_06_pickup.bvh"))
    pieces = list(_numparse._pieces(block, 0))
    assert len(pieces) > 1
    assert all(_parse_plain(p, columns) is not None for p in pieces)


_digits = st.text("0123456789", max_size=10)
_token = st.one_of(
    st.builds(lambda sign, whole, dot, frac: sign + whole + dot + frac,
              st.sampled_from(["", "-", "-", "+"]), _digits, st.sampled_from(["", ".", "."]),
              _digits),
    st.sampled_from(["-0", "-0.000000", "0.", ".0", "-.5", ".", "-", "--1", "1-2", "1.2.3",
                     "99999999.9999999", "12345678.1234567", "123456789", "0.123456789",
                     "1e5", "-0000000.00000000", "00000000.00000001"]))


@settings(max_examples=400, deadline=None, derandomize=True, database=None)
@given(st.lists(_token, min_size=1, max_size=9), st.sampled_from([" ", "  ", "\t", " \t"]),
       st.sampled_from(["\n", "\r\n", "\n\n", "\n \t\n"]), st.integers(1, 3),
       st.booleans(), st.booleans())
def test_generated_tokens(tokens, sep, newline, rows, indent, last_newline):
    columns = len(tokens)
    lines = [(" " if indent else "") + sep.join(tokens[k:] + tokens[:k]) for k in range(rows)]
    text = newline.join(lines) + (newline if last_newline else "")
    data = text.encode()
    plain = all(_is_plain(t) for t in tokens)
    got = (_parse_plain(data, columns) if not data.translate(None, _numparse._PLAIN_BYTES)
           else None)
    if not plain:
        assert got is None
    else:
        assert got is not None
        expected = [[float(t) for t in line.split()] for line in lines]
        assert got.shape == (rows, columns)
        assert np.array_equal(_bits(got), _bits(expected))
    # the whole parser agrees with float() whichever path it takes
    parsed = parse_number_rows(data, columns)
    if all(re.fullmatch(r"[-+]?(\d+\.?\d*|\.\d+)", t) for t in tokens):
        assert parsed is not None
        assert np.array_equal(_bits(parsed[0]),
                              _bits([[float(t) for t in line.split()] for line in lines]))


@pytest.mark.parametrize("text, columns", [
    ("1.5 2.5\r3.5 4.5\n", 2),           # a lone CR ends a line for the careful parser
    ("1.5 2.5\r3.5 4.5\n", 4),
    ("1.5 2.5\n3.5\n", 2), ("1.5 2.5 3.5\n", 2), ("1.5\n", 2), ("", 2), (" \n\t\n", 1),
    ("1.-5 2\n", 2), ("-1.5- 2\n", 2), ("1..5 2\n", 2), (". 2\n", 2), ("- 2\n", 2),
    ("123456789.5 2\n", 2), ("1.123456789 2\n", 2), ("12345678.12345678 2\n", 2),
])
def test_refused_layouts_and_tokens(text, columns):
    assert _parse_plain(text.encode(), columns) is None


def test_layouts_taken():
    values = _parse_plain(b"\n\n  1.5\t-2\r\n\r\n-0 .25\n \n3. -0.0", 2)
    assert values.tolist() == [[1.5, -2.0], [-0.0, 0.25], [3.0, -0.0]]
    assert list(np.signbit(values.ravel())) == [False, True, True, False, False, True]
