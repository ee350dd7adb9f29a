"""The bundled test character, ``tests/data/test_character.glb``: a small skinned glTF made by
our own code (``tests/data/make_test_character.py``, with our glTF writer), so that glTF
reading, skinning, export, retargeting onto a character and the window's skinned drawing are
tested without ``../shared``. Blender reads it too, where it is installed, so that a writer bug
and a reader bug of ours cannot cancel out."""
from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from blender_util import blender_or_skip, run_blender
from conftest import REPO, clip_path
from motion_composer.engine import read_bvh
from motion_composer.engine.formats.gltf import read_gltf, write_gltf
from motion_composer.engine.kinematics import forward_kinematics
from motion_composer.engine.skinning import skin_character
from test_gltf import BLENDER_GLTF_SCRIPT

CHARACTER = REPO / "tests" / "data" / "test_character.glb"
SHIPPED = REPO / "resources" / "characters" / "test_character.glb"
MAKER = REPO / "tests" / "data" / "make_test_character.py"
SWING = "Swing"
#: what the maker writes (tests/data/make_test_character.py)
JOINTS, VERTICES, TRIANGLES, FRAMES = 31, 480, 240, 30


@pytest.fixture(scope="module")
def character():
    return read_gltf(CHARACTER)


def test_the_file_is_what_the_maker_writes_and_is_small(tmp_path):
    sys.path.insert(0, str(MAKER.parent))
    try:
        import make_test_character as maker
    finally:
        sys.path.remove(str(MAKER.parent))
    outputs = (tmp_path / "a.glb", tmp_path / "b.glb")
    maker.build(outputs)
    assert outputs[0].read_bytes() == outputs[1].read_bytes() == CHARACTER.read_bytes(), \
        "tests/data/test_character.glb is stale: run python tests/data/make_test_character.py"
    assert SHIPPED.read_bytes() == CHARACTER.read_bytes()
    assert CHARACTER.stat().st_size < 200_000


def test_it_reads_as_the_cmu_skeleton_with_a_skinned_mesh(character):
    tpose = read_bvh(clip_path("cmu_rest_tpose.bvh")).skeleton
    sk = character.skeleton
    assert sk.num_joints == JOINTS and sk.names == tpose.names
    np.testing.assert_array_equal(sk.parents, tpose.parents)
    np.testing.assert_allclose(sk.offsets, tpose.offsets, atol=1e-6)
    assert character.notes == ()
    [mesh] = character.meshes
    assert mesh.skin == 0 and mesh.num_vertices == VERTICES and mesh.num_triangles == TRIANGLES
    np.testing.assert_allclose(mesh.weights.sum(axis=1), 1.0, atol=1e-6)
    assert set(np.count_nonzero(mesh.weights > 0, axis=1)) == {1, 2}      # 1-2 joints each
    np.testing.assert_allclose(np.linalg.norm(mesh.normals, axis=1), 1.0, atol=1e-5)
    [motion] = character.motions
    assert motion.name == SWING and motion.num_frames == FRAMES and motion.fps == 30.0
    assert character.fps == 30.0


def test_skinning_follows_the_swing(character):
    motion = character.motion(SWING)
    [verts] = skin_character(character, motion, frames=[0, 7])
    [bind] = skin_character(character)
    np.testing.assert_allclose(verts[0][:, 1], bind[0][:, 1], atol=1e-6)   # frame 0: rest
    moved = np.linalg.norm(verts[1] - verts[0], axis=1)
    assert moved.max() > 0.1                                   # legs and arms swing
    # a vertex weighted to one joint alone keeps its distance to that joint
    mesh = character.meshes[0]
    pose = forward_kinematics(motion.frames([7]))
    single = np.flatnonzero(mesh.weights[:, 0] == 1.0)
    joint = mesh.joints[single, 0]
    before = np.linalg.norm(mesh.positions[single] - character.bind_positions[joint], axis=1)
    after = np.linalg.norm(verts[1][single] - pose.positions[0, joint], axis=1)
    np.testing.assert_allclose(after, before, atol=1e-6)


def test_the_cli_reads_it_and_retargets_the_bundled_walk_onto_it(tmp_path, capsys):
    from motion_composer.app.cli import main
    assert main(["info", str(CHARACTER), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["frames"] == FRAMES and len(data["joints"]) == JOINTS
    assert [a["name"] for a in data["animations"]] == [SWING]
    assert data["meshes"][0]["vertices"] == VERTICES
    out = tmp_path / "walk_on_test_character.glb"
    code = main(["retarget", str(clip_path("cmu_131_01_walk.bvh")), "--target", str(CHARACTER),
                 "-o", str(out)])
    assert code == 0, capsys.readouterr().err
    back = read_gltf(out)
    assert back.skeleton.names == read_gltf(CHARACTER).skeleton.names
    assert back.num_vertices == VERTICES and back.motions[0].num_frames > 200
    travel = np.ptp(forward_kinematics(back.motions[0]).positions[:, 0], axis=0)
    assert travel.max() > 2.0                                  # it walks


def test_the_window_draws_it_as_a_skinned_mesh(qtbot, tmp_path):
    from gui_support import skinned_character_in_window
    doc, _v, first, second, back = skinned_character_in_window(qtbot, tmp_path, CHARACTER)
    assert first.shape == second.shape == (VERTICES, 3)
    assert np.abs(first - second).max() > 0.05                 # the mesh moves with the motion
    assert back.skeleton.names == doc.scene.target.skeleton.names
    assert back.num_vertices == VERTICES


@pytest.mark.blender
def test_blender_reads_it_where_our_reader_does(tmp_path, character):
    """Blender's glTF importer on the test character and on our export of it: its pose-bone
    heads sit where our forward kinematics puts the joints (within 1e-4 of its height)."""
    blender_or_skip()
    written = tmp_path / "swing_again.glb"
    write_gltf(character.motion(SWING), character, written)
    cases = [("test character", CHARACTER, [0, 7, 22]), ("written again", written, [0, 15, 29])]
    job = {"files": [{"key": key, "kind": "gltf", "path": str(path), "fps": 30, "frames": frames}
                     for key, path, frames in cases]}
    results = run_blender(BLENDER_GLTF_SCRIPT, "script.py", job, tmp_path)
    motion = character.motion(SWING)
    ours = forward_kinematics(motion).positions
    height = float(np.ptp(ours[0, :, 1]))
    names = motion.skeleton.names
    for key, _, frames in cases:
        assert SWING in results[key]["action"]
        for f in frames:
            bones = results[key]["positions"][str(f)]
            assert set(names) <= set(bones), key
            theirs = np.array([bones[n] for n in names])
            theirs = np.stack([theirs[:, 0], theirs[:, 2], -theirs[:, 1]], axis=1)   # Z-up
            err = np.abs(theirs - ours[f]).max()
            assert err < 1e-4 * height, (key, f, err, height)
