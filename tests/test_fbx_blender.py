"""The FBX reader against Blender 3.4's importer: joint world positions of every binary test
file, in the bind pose and in every take on several frames, including times between keys and
the Maya rigs with pivots, PreRotation and InheritType 2.

Blender runs once for all files (a module-scoped fixture, about 10-40 s a file; see
tests/blender_fbx.py for its settings and quirks). What is compared:

* the bind pose: each bone's rest head against :attr:`Character.bind_positions`;
* key times (the file's frames): within 1e-5 of the stature (Blender computes in float32;
  seen: 3e-6 at most, on the Maya rig);
* times between keys (half frames): Blender 3.4's importer samples every curve linearly at
  the union of its keys and keys the bones' quaternions linearly ("assume linear
  interpolation between key frames", its ``blen_read_animations_curves_iter``), so between
  keys it is not the FBX curve: files whose keys are all linear agree within 1e-5 of the
  stature (seen: 2e-7), files with cubic keys within 1 % (seen: 0.35 % on the Mixamo dance,
  0.46 % on the Maya rig; the cubic shape itself is checked in tests/test_fbx_read.py);
* a file without takes (the Maya rig) in its models' own pose (Blender's pose without an
  action) against :attr:`Character.node_pose`;
* the skinned vertices of the Mixamo dance (two meshes, 24,746 vertices) and of the Maya
  rig's mesh on the frames of their take, against Blender's armature modifier.

Blender names bones by their models; the models Blender turns into the armature object (a
``Null`` or ``Root`` above the bones) are not bones and are left out.
"""
from __future__ import annotations

import numpy as np
import pytest

from blender_fbx import engine_axes, run_blender_fbx
from blender_util import run_blender_fbx as blender_job
from conftest import SHARED_DATA
from motion_composer.engine.formats.fbx.scene import read_fbx
from motion_composer.engine.kinematics import forward_kinematics
from motion_composer.engine.skinning import skin_character

pytestmark = [pytest.mark.blender, pytest.mark.slow, pytest.mark.shared_data]

#: every binary FBX 7.x character of ../shared/data/fbx, and whether its takes' keys are
#: all linear
FILES = {"blender_279_sausage_7400_binary.fbx": True,
         "maya_kenney_character_7700_binary.fbx": False,
         "maya_character_7500_binary.fbx": True,
         "Samba_Dancing.fbx": False,
         "mixamo.fbx": False}
#: frames compared per take
FRAMES = 7
#: the files whose skinned vertices are compared too (Blender's armature modifier)
SKINNED = ("Samba_Dancing.fbx", "maya_kenney_character_7700_binary.fbx")


def _frames(motion) -> list[int]:
    return sorted({int(k) for k in np.linspace(0, motion.num_frames - 1, FRAMES)})


@pytest.fixture(scope="module")
def readers(tmp_path_factory):
    """Per file: our character at its own rate, at twice its rate (half frames), and
    Blender's positions at the frames and half frames of every take."""
    if not (SHARED_DATA / "fbx").is_dir():
        pytest.skip(f"../shared/data/fbx is absent ({SHARED_DATA}); these tests need its files")
    ours, jobs = {}, []
    for name in FILES:
        path = SHARED_DATA / "fbx" / name
        character = read_fbx(path)
        halves = read_fbx(path, fps=2 * character.fps)
        ours[name] = character, halves
        takes = [[None, [0.0]]] if not character.motions else []
        for m in character.motions:
            times = [f / m.fps for f in _frames(m)]
            times += [(f + 0.5) / m.fps for f in _frames(m)[:-1]]
            takes.append([m.name, times])
        jobs.append({"key": name, "path": str(path), "takes": takes,
                     "meshes": name in SKINNED})
    blender = run_blender_fbx(jobs, tmp_path_factory.mktemp("blender-fbx"))
    return ours, blender


def _common(character, blender_positions: dict) -> tuple[list[int], np.ndarray]:
    names = character.skeleton.names
    shared = [n for n in names if n in blender_positions]
    assert len(shared) >= len(names) - 1, set(names) - set(shared)
    return [names.index(n) for n in shared], engine_axes([blender_positions[n]
                                                          for n in shared])


def _stature(character) -> float:
    return float(np.ptp(character.bind_positions[:, 1]))


@pytest.mark.parametrize("name", FILES)
def test_bind_pose_matches_blender(readers, name):
    ours, blender = readers
    character, _ = ours[name]
    index, theirs = _common(character, blender[name]["bind"])
    error = np.abs(character.bind_positions[index] - theirs).max()
    assert error < 1e-5 * _stature(character), error


@pytest.mark.parametrize("name", FILES)
def test_every_take_matches_blender_on_its_frames_and_between(readers, name):
    ours, blender = readers
    character, halves = ours[name]
    result = blender[name]
    assert result["fps"] == round(character.fps)
    stature = _stature(character)
    if not character.motions:                       # the models' own pose
        index, theirs = _common(character, result["takes"]["None"][0])
        pos = forward_kinematics(character.node_pose, end_sites=False).positions[0]
        assert np.abs(pos[index] - theirs).max() < 1e-5 * stature
        return
    between_tol = 1e-5 if FILES[name] else 1e-2
    for motion, fine in zip(character.motions, halves.motions):
        frames = _frames(motion)
        on_keys = forward_kinematics(motion, end_sites=False).positions
        between = forward_kinematics(fine, end_sites=False).positions
        samples = result["takes"][motion.name]
        expected = [on_keys[f] for f in frames] + [between[2 * f + 1] for f in frames[:-1]]
        tolerances = [1e-5] * len(frames) + [between_tol] * (len(frames) - 1)
        for k, (pos, tol) in enumerate(zip(expected, tolerances)):
            index, theirs = _common(character, samples[k])
            error = np.abs(pos[index] - theirs).max()
            assert error < tol * stature, (motion.name, k, error / stature)


@pytest.mark.parametrize("name", SKINNED)
def test_skinned_vertices_match_blenders_armature_modifier(readers, name):
    """Every vertex of every skinned mesh on the frames of the first take, against the
    vertices Blender's armature modifier deforms (linear blend skinning from the same
    weights): within 1e-5 of the stature (seen: 5e-6 at most, on the Maya rig)."""
    ours, blender = readers
    character, _ = ours[name]
    motion = character.motions[0]
    frames = _frames(motion)
    skinned = skin_character(character, motion, frames=frames)
    theirs = blender[name]["takes"][motion.name + " meshes"]
    stature = _stature(character)
    for mesh, vertices in zip(character.meshes, skinned):
        for k in range(len(frames)):
            other = engine_axes(theirs[k][mesh.name])
            assert other.shape == vertices[k].shape
            error = np.abs(vertices[k] - other).max()
            assert error < 1e-5 * stature, (mesh.name, frames[k], error / stature)


def test_rigid_parts_under_joints_are_read_as_the_gltf_reads_them(tmp_path):
    """Quaternius' robot is rigid parts under its bones (15 meshes without a skin) and two
    skinned hands. Written by Blender's FBX exporter, the parts' models hang under the bone
    models: each is read as a rigid part bound wholly to that joint (they were left out,
    and the robot had no feet to stand on), placed as the glTF reader places it on the same
    joint (to 1e-5 of the stature relative to the joint: Blender moves the whole figure
    2.37 m down), and posed on a take it turns and moves with its joint."""
    from motion_composer.engine.formats import read_character
    from motion_composer.engine.kinematics import forward_kinematics
    from motion_composer.engine.skinning import skin_character
    from conftest import shared_path
    out = tmp_path / "robot.fbx"
    blender_job({"exports": [{"key": "robot", "out": str(out),
                              "source": str(shared_path("target_robot_expressive.glb"))}]},
                tmp_path)
    gltf = read_character(shared_path("target_robot_expressive.glb"))
    fbx = read_character(out)
    size = float(np.ptp(gltf.bind_positions, axis=0).max())
    rigid = [m for m in fbx.meshes if m.skin is None]
    assert len(rigid) == 15 == sum(1 for m in gltf.meshes if m.skin is None)
    assert any("15 rigid mesh parts" in n for n in fbx.notes)
    by_name = {m.name: m for m in gltf.meshes}
    for part in rigid:
        theirs = by_name[part.name]
        j, k = int(part.joints[0, 0]), int(theirs.joints[0, 0])
        assert np.all(part.joints == j) and np.all(part.weights == 1.0)
        assert fbx.skeleton.names[j] == gltf.skeleton.names[k], part.name
        np.testing.assert_allclose(part.positions - fbx.bind_positions[j],
                                   theirs.positions - gltf.bind_positions[k], atol=1e-5 * size)
    # posed on the dance, at the same times: each part where the glTF's is, relative to its
    # joint (the two files' takes read independently; Blender bakes the take at its own
    # rate: 1.5 mm apart at 1 s), and the parts move
    ours = next(m for m in fbx.motions if "Dance" in m.name)
    theirs = next(m for m in gltf.motions if m.name == "Dance")
    times = np.array([0.0, 0.5, 1.0])
    skinned = [skin_character(c, m, np.round(times * m.fps).astype(int))
               for c, m in ((fbx, ours), (gltf, theirs))]
    poses = [forward_kinematics(m.frames(np.round(times * m.fps).astype(int)))
             for m in (ours, theirs)]
    moved = 0.0
    for index, part in enumerate(fbx.meshes):
        if part.skin is None:
            other = next(i for i, m in enumerate(gltf.meshes) if m.name == part.name)
            j, k = int(part.joints[0, 0]), int(gltf.meshes[other].joints[0, 0])
            np.testing.assert_allclose(skinned[0][index] - poses[0].positions[:, j, None],
                                       skinned[1][other] - poses[1].positions[:, k, None],
                                       atol=1e-3 * size)
            moved = max(moved, float(np.ptp(skinned[0][index], axis=0).max()))
    assert moved > 0.05 * size


def test_blenders_leaf_bones_do_not_change_the_root_scale(tmp_path):
    """Blender's FBX exporter adds a leaf bone past each last bone by default (``_end``).
    Ely exported so gave the BANDAI walk a root scale of 1.16 where Ely's glTF gives 1.09:
    bound on a mid-stride frame, the pitched foot put the leaf past the toe lowest, and the
    hips were measured from it. The ratio is now the glTF's (to the file's float precision),
    with the leaf bones read as joints and left unmapped."""
    from motion_composer.engine.conversion import automap, bind
    from motion_composer.engine.formats import read_character, read_performer
    from conftest import shared_path
    out = tmp_path / "ely_leaf.fbx"
    blender_job({"exports": [{"key": "ely", "out": str(out),
                              "source": str(shared_path("target_mixamo_ely.glb")),
                              "options": {"add_leaf_bones": True}}]}, tmp_path)
    performer = read_performer(shared_path("bandai1_walk_normal_001.bvh"))
    ratios = []
    for path in (shared_path("target_mixamo_ely.glb"), out):
        target = read_character(path).rest_motion()
        corr = automap(target.skeleton, performer.skeleton)
        ratios.append(bind(performer, target, corr).hip_height_ratio)
        if path == out:
            leaves = [n for n in target.skeleton.names if n.endswith("_end")]
            assert "mixamorig:LeftToe_End_end" in leaves
            assert not set(leaves) & set(corr.pairs)
    assert ratios[1] == pytest.approx(ratios[0], rel=1e-5)
    assert ratios[0] == pytest.approx(1.086, abs=0.001)
