"""The binary FBX parser (engine/formats/fbx/binary.py) on the real files of
``../shared/data/fbx``: every 7.x file parses into the document tree FBX files have, values
are typed as the tree's table says, and no corruption of a real file gets past it as anything
but an :class:`FBXError` naming where."""
from __future__ import annotations

import random
import struct
import zlib

import numpy as np
import pytest

from motion_composer.engine.errors import FBXError
from motion_composer.engine.formats.fbx.binary import parse_binary
from motion_composer.engine.formats.fbx.nodes import FBX_TICKS_PER_SECOND, Node, type_code

from conftest import shared_path

BINARY_7 = {"blender_279_sausage_7400_binary.fbx": 7400, "maya_character_7500_binary.fbx": 7500,
            "maya_kenney_character_7700_binary.fbx": 7700,
            "motionbuilder_actor_7700_binary.fbx": 7700, "Samba_Dancing.fbx": 7700,
            "mixamo.fbx": 7700}
SECTIONS = ["FBXHeaderExtension", "GlobalSettings", "Documents", "Definitions", "Objects",
            "Connections"]


def _data(name: str) -> bytes:
    return shared_path(f"fbx/{name}").read_bytes()


@pytest.fixture(scope="module")
def trees():
    return {name: parse_binary(_data(name), name) for name in BINARY_7}


@pytest.mark.parametrize("name", sorted(BINARY_7))
def test_real_files_parse_into_the_fbx_sections(trees, name):
    root = trees[name]
    assert root.name == "FBX" and root.props == [BINARY_7[name]]
    assert type_code(root.props[0]) == "I"
    names = [child.name for child in root.children]
    for section in SECTIONS:
        assert section in names, section
    # objects and connections name each other by 64-bit ids; every model is connected
    objects = root.find("Objects")
    ids = {node.props[0] for node in objects.children}
    assert ids and all(type_code(i) == "L" for i in ids)
    connected = set()
    for c in root.find("Connections").find_all("C"):
        assert c.props[0] in ("OO", "OP", "PO", "PP")
        connected |= {c.props[1], c.props[2]}
    models = {n.props[0] for n in objects.find_all("Model")}
    assert models <= connected


def test_values_have_the_types_fbx_declares(trees):
    root = trees["mixamo.fbx"]
    settings = root.find("GlobalSettings").find("Properties70")
    props = {p.props[0]: p.props for p in settings.find_all("P")}
    # P: name, type, label, flags, value...: UpAxis is an int, UnitScaleFactor a double
    assert props["UpAxis"][1] == "int" and type_code(props["UpAxis"][4]) == "I"
    assert props["UnitScaleFactor"][1] == "double" and type_code(props["UnitScaleFactor"][4]) == "D"
    assert props["UnitScaleFactor"][4] == pytest.approx(1.0)          # Mixamo: centimetres
    # the time span of the take is in KTime ticks: a whole number of frames at 30 fps
    stop = props["TimeSpanStop"][4]
    assert type_code(stop) == "L"
    assert (stop * 30) % FBX_TICKS_PER_SECOND == 0
    geometry = next(n for n in root.find("Objects").children if n.name == "Geometry")
    vertices = geometry.find("Vertices").props[0]
    indices = geometry.find("PolygonVertexIndex").props[0]
    assert vertices.dtype == np.float64 and vertices.size % 3 == 0
    assert indices.dtype == np.int32
    # polygon ends are stored as ~index: every index addresses a vertex
    ends = np.where(indices < 0, ~indices, indices)
    assert ends.min() >= 0 and ends.max() < vertices.size // 3


def test_walk_reaches_every_record_once(trees):
    root = trees["maya_character_7500_binary.fbx"]
    offsets = [n.offset for n in root.walk()]
    assert len(offsets) == len(set(offsets))
    assert [n.name for n in root.walk()][:2] == ["FBX", "FBXHeaderExtension"]


def test_old_and_non_binary_files_are_refused_by_name():
    with pytest.raises(FBXError, match="older than FBX 7.1.*re-export"):
        parse_binary(_data("max7_skin_5000_binary.fbx"), "max7.fbx")
    with pytest.raises(FBXError, match="not a binary FBX file"):
        parse_binary(_data("nurbs_ascii_7200.fbx"), "nurbs.fbx")
    with pytest.raises(FBXError, match="header"):
        parse_binary(b"", "empty.fbx")


def _record(name: bytes, props: bytes, count: int, at: int, children: bytes = b"") -> bytes:
    end = at + 13 + len(name) + len(props) + len(children)
    return struct.pack("<IIIB", end, count, len(props), len(name)) + name + props + children


def test_a_file_built_by_hand_reads_value_by_value():
    header = b"Kaydara FBX Binary  \x00\x1a\x00" + struct.pack("<I", 7400)
    array = np.arange(5, dtype="<f8")
    packed = zlib.compress(array.tobytes())
    props = (b"S" + struct.pack("<I", 8) + b"a\x00\x01Model" + b"L" + struct.pack("<q", -7)
             + b"d" + struct.pack("<III", 5, 1, len(packed)) + packed + b"C\x01"
             + b"Y" + struct.pack("<h", -3))
    body = _record(b"Thing", props, 5, len(header)) + b"\x00" * 13
    root = parse_binary(header + body + b"\x00" * 160)
    (thing,) = root.children
    name, ident, values, flag, small = thing.props
    assert name == "a\x00\x01Model" and ident == -7 and flag is True
    assert type_code(small) == "Y" and small == -3
    np.testing.assert_array_equal(values, array)
    assert thing.children == [] and isinstance(thing, Node)


def test_mutated_real_files_raise_fbx_error_or_parse():
    """Truncations, byte flips and deletions anywhere in real files: the parser returns a tree
    or raises FBXError naming the byte; nothing else escapes (seeded, so reproducible)."""
    rng = random.Random(20261201)
    sources = [_data(n) for n in ("blender_279_sausage_7400_binary.fbx",
                                  "maya_character_7500_binary.fbx",
                                  "motionbuilder_actor_7700_binary.fbx")]
    refused = 0
    for _ in range(400):
        data = bytearray(rng.choice(sources))
        mode = rng.randrange(3)
        if mode == 0:
            data = data[:rng.randrange(len(data))]
        elif mode == 1:
            for _ in range(rng.randrange(1, 16)):
                data[rng.randrange(len(data))] = rng.randrange(256)
        else:
            at = rng.randrange(len(data))
            del data[at:at + rng.randrange(1, 200)]
        try:
            parse_binary(bytes(data), "mutated.fbx")
        except FBXError as error:
            assert str(error).startswith("mutated.fbx: ")
            refused += 1
    assert refused > 300              # almost every mutation is caught, not silently read
