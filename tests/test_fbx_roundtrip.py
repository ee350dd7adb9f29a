"""FBX written and read: the Mixamo round trip (a BVH capture retargeted onto a Mixamo FBX
character and written as FBX opens in Blender 3.4 on that character: its skinned meshes with
their vertex groups, the joints where the written motion puts them on every frame), and our
FBX reader reading what our writer writes."""
from __future__ import annotations

import numpy as np
import pytest

from blender_util import run_blender_fbx
from conftest import clip_path, shared_path
from motion_composer.app.cli import main
from motion_composer.engine.formats import read_character, read_motion
from motion_composer.engine.formats.fbx.write import write_fbx
from motion_composer.engine.kinematics import forward_kinematics

#: frames of the walk retargeted (2 s at 120 fps)
FRAMES = "0:239"


@pytest.fixture(scope="module")
def round_trip(tmp_path_factory):
    folder = tmp_path_factory.mktemp("mixamo")
    character = shared_path("fbx/mixamo.fbx")
    walk = clip_path("cmu_131_01_walk.bvh")
    out = {}
    for suffix in (".fbx", ".bvh"):              # the same retarget, also as BVH to compare
        out[suffix] = folder / f"walk_on_mixamo{suffix}"
        assert main(["retarget", str(walk), "--target", str(character), "--frames", FRAMES,
                     "-o", str(out[suffix])]) == 0
    motion = read_motion(out[".bvh"])
    job = {"imports": [{"key": "mixamo", "path": str(out[".fbx"]),
                        "frames": list(np.arange(motion.num_frames) + 1.0), "skin_at": [0]}]}
    return motion, read_character(character), run_blender_fbx(job, folder)["imports"]["mixamo"]


@pytest.mark.blender
def test_blender_opens_it_on_the_mixamo_character(round_trip):
    motion, character, result = round_trip
    assert result["armatures"] == 1
    assert sorted(result["meshes"]) == sorted(m.name for m in character.meshes)
    for m in character.meshes:
        mesh = result["meshes"][m.name]
        assert mesh["vertices"] == m.num_vertices
        weighed = {character.skeleton.names[j] for j in np.unique(m.joints[m.weights > 0])}
        assert set(mesh["groups"]) == weighed and weighed


@pytest.mark.blender
def test_blender_puts_the_joints_where_the_motion_does(round_trip):
    motion, character, result = round_trip
    ours = forward_kinematics(motion, end_sites=False).positions
    names = motion.skeleton.names
    theirs = np.array([[frame[n] for n in names] for frame in result["positions"]])
    theirs = np.stack([theirs[..., 0], theirs[..., 2], -theirs[..., 1]], axis=-1)
    stature = np.ptp(forward_kinematics(character.rest_motion(), end_sites=False)
                     .positions[0], axis=0).max()
    err = np.linalg.norm(theirs - ours, axis=-1)
    assert err.max() <= 1e-4 * stature, f"{err.max():.3g} m"


@pytest.mark.parametrize("source", ["cmu_131_01_walk.bvh", "target_fox.glb", "fbx/mixamo.fbx"])
def test_our_reader_reads_what_we_write(source, tmp_path):
    """Written and read back by the FBX reader: the same joints, bind pose, meshes and, on
    every frame, joint world positions (float32 keys: within 1e-6 of the stature)."""
    path = clip_path(source) if source.endswith(".bvh") else shared_path(source)
    character = read_character(path)
    motion = (read_motion(path).frames(slice(0, 240)) if character is None else
              character.motions[0] if character.motions else character.rest_motion())
    out = tmp_path / "out.fbx"
    write_fbx(motion, out, character=character)
    back = read_character(out)
    assert back.skeleton.names == motion.skeleton.names
    np.testing.assert_array_equal(back.skeleton.parents, motion.skeleton.parents)
    (again,) = back.motions
    assert again.num_frames == motion.num_frames
    assert again.fps == pytest.approx(motion.fps, rel=1e-4)
    ours = forward_kinematics(motion, end_sites=False).positions
    theirs = forward_kinematics(again, end_sites=False).positions
    stature = np.ptp(ours[0], axis=0).max()
    assert np.abs(theirs - ours).max() <= 1e-6 * stature
    if character is not None:
        np.testing.assert_allclose(back.bind_positions, character.bind_positions,
                                   atol=1e-9 * stature)
        assert [m.num_vertices for m in back.meshes] == [m.num_vertices for m in
                                                         character.meshes]
