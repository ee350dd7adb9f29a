"""External references in glTF files stay inside the file's own folder.

The cases are crafted copies of a real GLB (../shared/data/target_robot_expressive.glb, the
three.js RobotExpressive asset): its JSON chunk becomes a ``.gltf`` file and its binary chunk a
``.bin`` file beside it (what Blender's "glTF Separate" export writes), then the buffer URI is
rewritten the way a crafted or careless file would carry it.
"""
from __future__ import annotations

import base64
import json
import socket
import struct

import numpy as np
import pytest

from conftest import shared_path
from motion_composer.engine.errors import GLTFError
from motion_composer.engine.formats.gltf import read_gltf

ROBOT = "target_robot_expressive.glb"


def _split_glb(path) -> tuple[dict, bytes]:
    """(JSON, binary chunk) of a GLB file."""
    data = path.read_bytes()
    jlen, = struct.unpack_from("<I", data, 12)
    js = json.loads(data[20:20 + jlen])
    blen, = struct.unpack_from("<I", data, 20 + jlen)
    return js, data[28 + jlen:28 + jlen + blen]


@pytest.fixture(scope="module")
def robot_parts():
    return _split_glb(shared_path(ROBOT))


@pytest.fixture(scope="module")
def robot():
    return read_gltf(shared_path(ROBOT))


def _write(folder, name: str, js: dict, uri: str, *, image_uri: str | None = None):
    js = json.loads(json.dumps(js))
    js["buffers"][0]["uri"] = uri
    if image_uri is not None:
        js["images"] = [{"uri": image_uri}]
    path = folder / name
    path.write_text(json.dumps(js), encoding="utf-8")
    return path


def _same(a, b):
    np.testing.assert_array_equal(a.skeleton.offsets, b.skeleton.offsets)
    np.testing.assert_array_equal(a.meshes[0].positions, b.meshes[0].positions)


def test_data_uris_and_relative_files_inside_the_folder_still_work(tmp_path, robot_parts,
                                                                     robot):
    js, binary = robot_parts
    folder = tmp_path / "char"
    (folder / "sub").mkdir(parents=True)
    (folder / "robot.bin").write_bytes(binary)
    (folder / "sub" / "robot 2.bin").write_bytes(binary)
    (folder / "alias.bin").symlink_to(folder / "sub" / "robot 2.bin")
    inline = "data:application/octet-stream;base64," + base64.b64encode(binary).decode()
    for name, uri in (("plain.gltf", "robot.bin"), ("sub.gltf", "sub/robot%202.bin"),
                      ("back_in.gltf", "sub/../robot.bin"),
                      ("link_inside.gltf", "alias.bin"), ("inline.gltf", inline)):
        _same(read_gltf(_write(folder, name, js, uri, image_uri="sub/texture.png")), robot)


@pytest.mark.parametrize("uri, says", [
    ("/etc/hostname", "absolute path"),
    ("%2Fetc%2Fhostname", "absolute path"),
    ("C:\\Windows\\robot.bin", "absolute path"),
    ("C:/robot.bin", "absolute path"),
    ("\\\\server\\share\\robot.bin", "absolute path"),
    ("file:///etc/hostname", "file: URL"),
    ("http://example.com/robot.bin", "http: URL"),
    ("https://example.com/robot.bin", "https: URL"),
    ("ftp://example.com/robot.bin", "ftp: URL"),
    ("blob:robot", "blob: URL"),
    ("../robot.bin", "out of the glTF file's folder"),
    ("%2e%2e/robot.bin", "out of the glTF file's folder"),
    ("%2E%2E%2Frobot.bin", "out of the glTF file's folder"),
    ("..\\robot.bin", "out of the glTF file's folder"),
    ("sub/../../robot.bin", "out of the glTF file's folder"),
    ("escape.bin", "out of the glTF file's folder"),        # a symlink to ../robot.bin
])
def test_uris_outside_the_folder_are_refused_with_their_json_path(tmp_path, robot_parts, uri,
                                                                  says, monkeypatch):
    js, binary = robot_parts
    (tmp_path / "robot.bin").write_bytes(binary)          # the real data, one folder up
    folder = tmp_path / "char"
    (folder / "sub").mkdir(parents=True)
    (folder / "escape.bin").symlink_to(tmp_path / "robot.bin")

    def no_network(*args, **kwargs):
        raise AssertionError("the reader opened a network connection")

    monkeypatch.setattr(socket.socket, "connect", no_network)
    with pytest.raises(GLTFError) as info:
        read_gltf(_write(folder, "crafted.gltf", js, uri))
    assert info.value.where == "buffers[0].uri"
    assert says in str(info.value) and "crafted.gltf" in str(info.value)
    # the same URI on an image (never read, but it would travel with the character)
    with pytest.raises(GLTFError) as info:
        read_gltf(_write(folder, "image.gltf", js, "robot.bin", image_uri=uri))
    assert info.value.where == "images[0].uri" and says in str(info.value)


def test_a_glb_whose_buffer_names_a_local_file_is_refused(tmp_path, robot_parts):
    """Today's attack: a GLB whose buffer says ``"uri": "/etc/hostname"`` read the host's
    file as its data (and an export would have carried it on)."""
    js, binary = robot_parts
    js = json.loads(json.dumps(js))
    js["buffers"].append({"uri": "/etc/hostname", "byteLength": 4})
    text = json.dumps(js).encode()
    text += b" " * (-len(text) % 4)
    body = (struct.pack("<II", len(text), 0x4E4F534A) + text +
            struct.pack("<II", len(binary), 0x004E4942) + binary)
    path = tmp_path / "crafted.glb"
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)
    with pytest.raises(GLTFError) as info:
        read_gltf(path)
    assert info.value.where == f"buffers[{len(js['buffers']) - 1}].uri"
    assert "absolute path" in str(info.value)
