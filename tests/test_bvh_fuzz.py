"""Property test: mutated real BVH files either read or raise the engine's typed error.

Nothing else may come out of the reader (no ValueError, IndexError, ... and no traceback for
the command line): a mutated file either reads into a valid motion, or raises a
MotionComposerError whose message is one line starting with the file's path.

The bases are small real files so each example is fast: the bundled one-frame CMU T-pose, and
the hierarchies of the bundled walk (mixed CRLF/LF, mixed rotation orders) and FAIR1 clip
(Z-up, inches) with their first 12 frames. Hypothesis runs derandomized without a database, so
CI sees the same examples every time.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from conftest import clip_path
from motion_composer.engine import MotionComposerError
from motion_composer.engine.formats.bvh import read_bvh
from motion_composer.engine.describe import describe_motion


def _first_frames(name: str, frames: int) -> bytes:
    lines = clip_path(name).read_bytes().splitlines(keepends=True)
    k = next(i for i, line in enumerate(lines) if line.strip().startswith(b"Frames:"))
    lines[k] = b"Frames: %d\n" % frames
    return b"".join(lines[:k + 2 + frames])


BASES = [
    clip_path("cmu_rest_tpose.bvh").read_bytes(),
    _first_frames("cmu_131_01_walk.bvh", 12),
    _first_frames("fair1_child8_jumping.bvh", 12),
]

JUNK = [b"", b"nan", b"inf", b"-inf", b"1e999", b"abc", b"-", b".", b"+", b"e", b"1e-320",
        b"{", b"}", b"{ }", b"\x00", b"\r", b"\n", b"\r\n", b"\t", b" ", b"\xff\xfe",
        "\u00b2".encode(), "\u00a0".encode(), "\u2028".encode(), b"\x85", "\u0661".encode(),
        b"ROOT", b"JOINT", b"End Site", b"End", b"Site", b"OFFSET", b"CHANNELS", b"CHANNELS 0",
        b"CHANNELS 7", b"Xposition", b"zrotation", b"MOTION", b"HIERARCHY", b"Frames:",
        b"Frames: 0", b"Frame Time:", b"Frame Time: 0", b"0", b"-0", b"1", b"999999999999",
        b"9" * 40, b"1_0", b"0x10", b"JOINT Hips", b"ROOT Hips"]

_KEYWORDS = (b"CHANNELS", b"Frames:", b"Time:", b"OFFSET", b"ROOT", b"JOINT")
#: what a count, a frame time or an offset might wrongly be
_ARG_JUNK = [b"-1", b"7", b"0", b"00", b"1.5", b"x", b"1e999", b"nan", "\u00b2".encode(),
             "\u0663".encode(), "\uff13".encode(), b"1e-320", b"+2", b"99999999999"]

_frac = st.floats(0, 1, exclude_max=True)
_junk = st.one_of(st.sampled_from(JUNK), st.binary(max_size=6))

_ops = st.one_of(
    st.tuples(st.just("delete bytes"), _frac, st.integers(1, 40)),
    st.tuples(st.just("insert bytes"), _frac, _junk),
    st.tuples(st.just("replace byte"), _frac, st.integers(0, 255)),
    st.tuples(st.just("truncate"), _frac),
    st.tuples(st.just("delete line"), _frac),
    st.tuples(st.just("duplicate line"), _frac, _frac),
    st.tuples(st.just("swap lines"), _frac, _frac),
    st.tuples(st.just("replace token"), _frac, _frac, _junk),
    st.tuples(st.just("delete token"), _frac, _frac),
    st.tuples(st.just("number to junk"), _frac, _junk),
    st.tuples(st.just("keyword argument to junk"), st.sampled_from(_KEYWORDS), _frac,
              st.one_of(st.sampled_from(_ARG_JUNK), _junk)),
)


def _at(frac: float, n: int) -> int:
    return min(int(frac * n), max(n - 1, 0))


def mutate(data: bytes, op) -> bytes:
    kind, *args = op
    if kind == "delete bytes":
        i = _at(args[0], len(data))
        return data[:i] + data[i + args[1]:]
    if kind == "insert bytes":
        i = _at(args[0], len(data) + 1)
        return data[:i] + args[1] + data[i:]
    if kind == "replace byte":
        if not data:
            return data
        i = _at(args[0], len(data))
        return data[:i] + bytes([args[1]]) + data[i + 1:]
    if kind == "truncate":
        return data[:_at(args[0], len(data))]
    lines = data.splitlines(keepends=True) or [b""]
    i = _at(args[0], len(lines)) if isinstance(args[0], float) else 0
    if kind == "delete line":
        del lines[i]
    elif kind == "duplicate line":
        lines.insert(_at(args[1], len(lines) + 1), lines[i])
    elif kind == "swap lines":
        j = _at(args[1], len(lines))
        lines[i], lines[j] = lines[j], lines[i]
    elif kind in ("replace token", "delete token"):
        body = lines[i].rstrip(b"\r\n")
        ending = lines[i][len(body):]
        tokens = body.split()
        if tokens:
            k = _at(args[1], len(tokens))
            if kind == "replace token":
                tokens[k] = args[2]
            else:
                del tokens[k]
        lines[i] = b" ".join(tokens) + ending
    elif kind == "number to junk":
        # the k-th numeric token of the whole file becomes junk
        numbers = [(n, t) for n, line in enumerate(lines) for t, tok in enumerate(line.split())
                   if tok[:1] in b"-.0123456789"]
        if numbers:
            n, t = numbers[_at(args[0], len(numbers))]
            body = lines[n].rstrip(b"\r\n")
            ending = lines[n][len(body):]
            tokens = body.split()
            tokens[t] = args[1]
            lines[n] = b" ".join(tokens) + ending
    elif kind == "keyword argument to junk":
        # the token right after a keyword (a channel count, the frame count, the frame time,
        # an OFFSET value, a joint name) becomes junk
        keyword, where, junk = args
        spots = [(n, t + 1) for n, line in enumerate(lines)
                 for t, tok in enumerate(line.split()[:-1]) if tok == keyword]
        if spots:
            n, t = spots[_at(where, len(spots))]
            body = lines[n].rstrip(b"\r\n")
            ending = lines[n][len(body):]
            tokens = body.split()
            tokens[t] = junk
            lines[n] = b" ".join(tokens) + ending
    return b"".join(lines)


@pytest.fixture(scope="module")
def fuzz_file(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz") / "mutated.bvh"


def check_outcome(path):
    try:
        motion = read_bvh(path)
    except MotionComposerError as exc:
        message = str(exc)
        assert message.startswith(str(path))
        assert "\n" not in message and "\r" not in message
        return "error"
    # a success is a usable motion, and what the CLI does next also works
    assert motion.num_frames >= 1
    assert np.isfinite(motion.frame_time) and motion.frame_time > 0
    assert np.all(np.isfinite(motion.rotations)) and np.all(np.isfinite(motion.translations))
    info = describe_motion(motion)
    assert info["frames"] == motion.num_frames
    assert np.isfinite(info["fps"])
    return "read"


def test_the_bases_read(fuzz_file):
    for base in BASES:
        fuzz_file.write_bytes(base)
        assert check_outcome(fuzz_file) == "read"


@settings(max_examples=400, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(base=st.sampled_from(range(len(BASES))), ops=st.lists(_ops, min_size=1, max_size=4))
def test_mutated_files_read_or_raise_the_typed_error(fuzz_file, base, ops):
    data = BASES[base]
    for op in ops:
        data = mutate(data, op)
    fuzz_file.write_bytes(data)
    check_outcome(fuzz_file)


@settings(max_examples=120, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(base=st.sampled_from(range(len(BASES))), cut=_frac)
def test_every_truncation_reads_or_raises_the_typed_error(fuzz_file, base, cut):
    data = BASES[base]
    fuzz_file.write_bytes(data[:_at(cut, len(data))])
    check_outcome(fuzz_file)


@pytest.mark.parametrize("keyword", _KEYWORDS, ids=[k.decode() for k in _KEYWORDS])
def test_every_keyword_argument_replaced_by_junk(fuzz_file, keyword):
    """A deterministic sweep the random search reaches too rarely: the token after each
    keyword (first occurrence) replaced by each value a count or a number might wrongly be."""
    outcomes = set()
    for base in BASES:
        for junk in _ARG_JUNK:
            fuzz_file.write_bytes(mutate(base, ("keyword argument to junk", keyword, 0.0, junk)))
            outcomes.add(check_outcome(fuzz_file))
    if keyword in (b"ROOT", b"JOINT"):
        assert outcomes == {"read"}             # any word is a valid joint name
    else:
        assert "error" in outcomes              # the sweep did reach the parser's checks
