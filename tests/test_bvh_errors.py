"""Bad input: each kind raises a typed error naming the file, the line and what was expected."""
from __future__ import annotations

import pytest

from bvh_cases import CASES, WALK, find, walk_lines
from motion_composer.engine import MotionComposerError
from motion_composer.engine.formats.bvh import parse_bvh_text, read_bvh
from motion_composer.engine.errors import BVHError, FileFormatError


def check(error: BVHError, path, line, expects):
    assert isinstance(error, FileFormatError) and isinstance(error, MotionComposerError)
    assert error.path == str(path)
    assert error.line == line
    message = str(error)
    assert "\n" not in message and "\r" not in message
    where = f"{path}:{line}" if line is not None else f"{path}"
    assert message.startswith(f"{where}: ")
    assert message == f"{where}: {error.problem}"
    for phrase in expects:
        assert phrase.lower() in error.problem.lower(), (phrase, error.problem)


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_file_raises_bvh_error_naming_file_line_and_expectation(case, tmp_path):
    path, line = case.write(tmp_path)
    with pytest.raises(BVHError) as info:
        read_bvh(path)
    check(info.value, path, line, case.expects)


def test_the_unmutated_base_file_reads():
    """The cases above fail because of their mutation, not because of the base file."""
    assert read_bvh(WALK).num_frames == 994


def test_mixed_line_endings_are_counted_as_one_line_each():
    data = WALK.read_bytes()
    assert b"\r\n" in data and data.count(b"\n") > data.count(b"\r\n")   # both kinds present
    lines = walk_lines()
    i = find(lines, b"JOINT RightToe")
    assert lines[i - 1].endswith(b"\r\n")                                  # CRLF region
    assert not lines[-1].endswith(b"\r\n")                                # LF region


@pytest.mark.parametrize("ending", ["\n", "\r\n", "\r"])
def test_line_numbers_with_each_line_ending(ending, tmp_path):
    text = WALK.read_bytes().decode().replace("\r\n", "\n")
    lines = text.split("\n")
    k = lines.index("Frame Time: .0083333") + 100             # frame 100, 0-based line index
    lines[k] = lines[k].replace(lines[k].split()[3], "oops", 1)
    path = tmp_path / "endings.bvh"
    path.write_bytes(ending.join(lines).encode())
    with pytest.raises(BVHError) as info:
        read_bvh(path)
    check(info.value, path, k + 1, ("value 4 of frame 100", "'oops'"))


def test_missing_file_and_folder(tmp_path):
    missing = tmp_path / "nothing.bvh"
    with pytest.raises(BVHError) as info:
        read_bvh(missing)
    check(info.value, missing, None, ("no such file",))
    with pytest.raises(BVHError) as info:
        read_bvh(tmp_path)
    check(info.value, tmp_path, None, ("folder",))


def test_text_without_a_file_is_named_as_text():
    with pytest.raises(BVHError) as info:
        parse_bvh_text("HIERARCHY\nROOT Hips\n{\n")
    assert info.value.path is None
    assert str(info.value).startswith("<text>:3: ")


@pytest.mark.parametrize("count", ["7", "-1", "three", "\u00b3"])
def test_bad_channel_count(count, tmp_path):
    lines = walk_lines()
    i = find(lines, b"CHANNELS", find(lines, b"JOINT LeftKnee"))
    lines[i] = lines[i].replace(b"CHANNELS 3", b"CHANNELS " + count.encode())
    path = tmp_path / "count.bvh"
    path.write_bytes(b"".join(lines))
    with pytest.raises(BVHError) as info:
        read_bvh(path)
    check(info.value, path, i + 1, ("expected a channel count from 0 to 6",))


def test_error_on_the_first_bad_row_not_a_later_one(tmp_path):
    lines = walk_lines()
    row = find(lines, b"Frame Time") + 1
    lines[row + 9] = lines[row + 9].replace(b" ", b" nan ", 1)     # frame 10: one value too many
    lines[row + 19] = b"abc\n"                                      # frame 20
    path = tmp_path / "two.bvh"
    path.write_bytes(b"".join(lines))
    with pytest.raises(BVHError) as info:
        read_bvh(path)
    check(info.value, path, row + 10, ("frame 10 has 97 values",))
