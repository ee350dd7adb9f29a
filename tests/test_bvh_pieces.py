"""read_bvh parses a file's rows from the file a piece at a time (never the whole file as bytes
or text beside its values): the same motion as parsing the whole text, bit for bit, wherever the
pieces and the header reads end, and the same errors."""
from __future__ import annotations

import numpy as np
import pytest

from motion_composer.engine.errors import BVHError
from motion_composer.engine.formats import _numparse, bvh
from motion_composer.engine.formats.bvh import parse_bvh, read_bvh
from conftest import all_bvh_params, clip_path, resolve


def _same(a, b):
    np.testing.assert_array_equal(a.rotations, b.rotations)
    np.testing.assert_array_equal(a.translations, b.translations)
    np.testing.assert_array_equal(a.skeleton.offsets, b.skeleton.offsets)
    assert a.skeleton.names == b.skeleton.names and a.frame_time == b.frame_time
    assert a.skeleton.source == b.skeleton.source and a.name == b.name


@pytest.mark.parametrize("spec", all_bvh_params())
def test_pieces_give_the_whole_texts_motion(spec, monkeypatch):
    path = resolve(spec)
    whole = parse_bvh(path.read_text(encoding="utf-8-sig"), path)
    _same(read_bvh(path), whole)
    monkeypatch.setattr(_numparse, "_PIECE", 997)           # rows cut mid-line, many pieces
    monkeypatch.setattr(bvh, "_HEAD_BYTES", 211)            # the header read in many reads
    _same(read_bvh(path), whole)


@pytest.mark.parametrize("spec", all_bvh_params())
def test_rotations_are_every_frames_euler_angles_bit_for_bit(spec):
    """The reader turns a joint whose angles never change once and copies it to every frame,
    and the others in blocks of frames on component rows: the rotations are still
    ``from_euler`` of every frame's angles, bit for bit (file axes, a +Y file's root too)."""
    from motion_composer.engine.quaternions import from_euler
    path = resolve(spec)
    record = bvh._read_bvh_record(path)
    rotations, _ = bvh._local_arrays(record, bvh.detect_position_modes(record))
    rot_cols, _ = bvh._column_layout(record.channels)
    for j, chans in enumerate(record.channels):
        order = "".join(c[0] for c in chans if c.endswith("rotation"))
        expected = (from_euler(record.values[:, rot_cols[j]], order) if order else
                    np.tile([0.0, 0.0, 0.0, 1.0], (record.num_frames, 1)))
        assert np.ascontiguousarray(rotations[:, j].T).tobytes() == expected.tobytes(), \
            record.names[j]
    motion = read_bvh(path)
    if motion.skeleton.source.up_axis == "+Y":                # the root is not turned
        np.testing.assert_array_equal(motion.rotations, rotations.T)


def _write(tmp_path, text: str, name="clip.bvh"):
    out = tmp_path / name
    out.write_bytes(text.encode("latin-1"))
    return out


def _walk_text() -> str:
    return clip_path("cmu_131_01_walk.bvh").read_text()


@pytest.mark.parametrize("change", ["crlf", "rows_crlf", "tail_blank", "no_final_newline"])
def test_line_endings_and_blank_lines(tmp_path, change):
    text = _walk_text()
    head, rows = text.split("Frame Time:", 1)
    changed = {"crlf": text.replace("\n", "\r\n"),
               "rows_crlf": head + "Frame Time:" + rows.replace("\n", "\r\n"),
               "tail_blank": text + "\n\n  \n",
               "no_final_newline": text.rstrip("\n")}[change]
    path = _write(tmp_path, changed)
    _same(read_bvh(path), parse_bvh(changed, path))


@pytest.mark.parametrize("bad, message", [("nan", "finite"), ("1e400", "finite"),
                                          ("abc", "expected a number"),
                                          ("2e9", "beyond the range")])
def test_a_bad_value_is_named_as_the_text_parser_names_it(tmp_path, bad, message):
    lines = _walk_text().split("\n")
    at = next(k for k, line in enumerate(lines) if line.startswith("Frame Time")) + 500
    values = lines[at].split()
    values[7] = bad
    lines[at] = " ".join(values)
    text = "\n".join(lines)
    path = _write(tmp_path, text)
    with pytest.raises(BVHError, match=message) as from_file:
        read_bvh(path)
    with pytest.raises(BVHError) as from_text:
        parse_bvh(text, path)
    assert str(from_file.value) == str(from_text.value)
    assert from_file.value.line == at + 1


def test_rows_that_disagree_with_the_frame_count_are_named(tmp_path):
    text = _walk_text().rstrip("\n")
    path = _write(tmp_path, text.rsplit("\n", 3)[0] + "\n")
    with pytest.raises(BVHError, match="truncated"):
        read_bvh(path)
