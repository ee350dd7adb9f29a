"""Binary FBX encoding (:mod:`engine.formats.fbx.encode`): every real binary 7.x file's tree,
written as FBX 7.4 and read back by :func:`parse_binary`, is the same tree value by value and
type by type; the layout (empty records, deflated arrays, footer) is the one the FBX SDK
writes."""
from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest

from conftest import shared_path
from motion_composer.engine.formats.fbx.binary import MAGIC, parse_binary
from motion_composer.engine.formats.fbx.encode import (DEFLATE_ABOVE, FOOTER_ID,
                                                       encode_binary)
from motion_composer.engine.formats.fbx.nodes import Node, type_code

#: every binary FBX 7.x file of ../shared/data/fbx
BINARY_7 = ["Samba_Dancing.fbx", "blender_279_sausage_7400_binary.fbx",
            "maya_character_7500_binary.fbx", "maya_kenney_character_7700_binary.fbx",
            "mixamo.fbx", "motionbuilder_actor_7700_binary.fbx"]


def assert_same_tree(a: Node, b: Node, path: str = "") -> None:
    """``a`` and ``b`` have the same names, property types and values, and children."""
    here = f"{path}/{a.name}"
    assert a.name == b.name, here
    assert len(a.props) == len(b.props), here
    for k, (x, y) in enumerate(zip(a.props, b.props)):
        assert type_code(x) == type_code(y), f"{here} property {k}"
        assert type(x) is type(y), f"{here} property {k}"
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), \
                f"{here} property {k}"
        elif isinstance(x, float | np.floating) and np.isnan(x):
            assert np.isnan(y), f"{here} property {k}"
        else:
            assert x == y, f"{here} property {k}"
    assert [c.name for c in a.children] == [c.name for c in b.children], here
    for x, y in zip(a.children, b.children):
        assert_same_tree(x, y, here)


@pytest.fixture(scope="module", params=BINARY_7)
def real_tree(request):
    return parse_binary(shared_path(f"fbx/{request.param}").read_bytes())


def test_real_files_read_back_as_the_same_tree(real_tree):
    data = encode_binary(real_tree, 7400)
    back = parse_binary(data)
    assert back.props == [np.int32(7400)]
    assert_same_tree(Node("FBX", [np.int32(7400)], real_tree.children), back)


def test_real_files_at_their_own_version(real_tree):
    version = int(real_tree.props[0])
    assert_same_tree(real_tree, parse_binary(encode_binary(real_tree, version)))


def _tree() -> Node:
    return Node("FBX", [np.int32(7400)], [
        Node("Empty"),
        Node("Scalars", [np.int16(-3), True, np.int32(7), 2 ** 40, np.float32(1.5), 0.25,
                         "Name\x00\x01Model", b"\x00\xff"]),
        Node("Parent", [], [Node("Child", [1]), Node("Leaf")]),
        Node("Arrays", [np.arange(4, dtype=np.float64), np.arange(200, dtype=np.int32),
                        np.array([True, False]), np.arange(3, dtype=np.int64),
                        np.linspace(0, 1, 50).astype(np.float32)]),
    ])


def test_layout_is_the_sdks():
    data = encode_binary(_tree())
    assert data.startswith(MAGIC + struct.pack("<I", 7400))
    # records: end offset, property count, property bytes (uint32 in 7.4)
    end, count, size = struct.unpack_from("<III", data, 27)
    assert (count, size, data[39:45]) == (0, 0, b"\x05Empty")
    assert end == 27 + 12 + 6 + 13                        # an empty record closes it
    # Scalars has properties and no children: no closing empty record
    end2, count2, size2 = struct.unpack_from("<III", data, end)
    assert count2 == 8 and end2 == end + 12 + 8 + size2
    # the footer: code, 4 zeros, padding to 16, version, 120 zeros, closing magic
    tail = data[-(16 + 4 + 120):]
    assert struct.unpack_from("<I", tail)[0] == 7400 and tail[4:124] == bytes(120)
    at = data.rindex(FOOTER_ID)
    assert data[at - 13:at] == bytes(13)                  # the top-level list is closed
    padding = len(data) - 140 - (at + 20)
    assert 1 <= padding <= 16 and (at + 20 + padding) % 16 == 0
    assert data[at + 16:at + 20 + padding] == bytes(4 + padding)


def test_childless_animation_layer_is_closed_as_the_sdk_closes_it(real_tree):
    data = encode_binary(real_tree, 7400)
    layers = [n for n in parse_binary(data).walk() if n.name == "AnimationLayer"]
    for layer in layers:
        end, count, size = struct.unpack_from("<III", data, layer.offset)
        closed_at = layer.offset + 13 + len("AnimationLayer") + size
        assert not layer.children and end == closed_at + 13
        assert data[closed_at:end] == bytes(13)


def test_small_arrays_raw_large_ones_deflated():
    data = encode_binary(_tree())
    small = np.arange(4, dtype=np.float64).tobytes()
    large = np.arange(200, dtype=np.int32).tobytes()
    assert len(small) <= DEFLATE_ABOVE < len(large)
    assert struct.pack("<III", 4, 0, len(small)) + small in data
    deflated = zlib.compress(large, 6)
    assert struct.pack("<III", 200, 1, len(deflated)) + deflated in data
    assert_same_tree(_tree(), parse_binary(data))


def test_wide_offsets_from_7500():
    data = encode_binary(_tree(), 7500)
    end, count, size = struct.unpack_from("<QQQ", data, 27)
    assert (end, count, size) == (27 + 24 + 6 + 25, 0, 0)
    assert_same_tree(Node("FBX", [np.int32(7500)], _tree().children),
                     parse_binary(data))


def test_versions_outside_7_refused():
    with pytest.raises(ValueError, match="7100-7700"):
        encode_binary(_tree(), 6100)
