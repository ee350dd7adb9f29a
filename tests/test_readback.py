"""Whatever the program writes, it reads back with the same units and up axis from the content
alone (no marker of its own in the file), and the same joints where it wrote them: every
shared clip retargeted onto glTF characters (Mixamo's Ely and mannequin, the robot) and onto
BVH targets in CMU units (+Y) and in inches (+Z), written as BVH and as GLB; then the BVH files
after a round trip through Blender's BVH import and export."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from blender_util import blender_or_skip, run_blender_roundtrip
from conftest import SHARED_BVH, clip_path, shared_path
from detect_cases import world_positions
from motion_composer.engine.conversion.automap import automap
from motion_composer.engine.formats import (read_character, read_motion, read_performer,
                                            write_motion)
from motion_composer.engine.project import Project, Source
from motion_composer.engine.scene import Scene

TARGETS = ["target_mixamo_ely.glb", "target_mixamo_mannequin.glb",
           "target_robot_expressive.glb", "cmu_rest_tpose.bvh", "fair1_child8_jumping.bvh"]
CLIPS = [n for n in SHARED_BVH if not n.startswith("target_")]


def _target_path(name: str) -> Path:
    return clip_path(name) if name in ("cmu_rest_tpose.bvh", "fair1_child8_jumping.bvh") \
        else shared_path(name)


def retarget(clip: Path, target: Path):
    """The direct retarget of ``clip`` onto ``target`` as the ``retarget`` command makes it:
    ``(motion, character or None)``."""
    performer = read_performer(clip)
    character = read_character(target)
    tgt = character.rest_motion() if character is not None else read_motion(target)
    project = Project(performer=Source(str(clip)), target=Source(str(target)),
                      correspondence=automap(tgt.skeleton, performer.skeleton))
    return Scene(project, performer, tgt).solve(regenerate=True).motion, character


def _stature(motion) -> float:
    """[m] the height of the first frame's joints."""
    return float(np.ptp(world_positions(motion.frames(slice(0, 1)))[0, :, 1]))


@pytest.fixture(scope="module")
def outputs(tmp_path_factory):
    """Every (clip, target): the motion in memory and the BVH and GLB files written."""
    folder = tmp_path_factory.mktemp("readback")
    done = {}
    for target in TARGETS:
        for clip in CLIPS:
            motion, character = retarget(shared_path(clip), _target_path(target))
            stem = f"{Path(clip).stem}__{Path(target).stem}"
            files = {suffix: folder / f"{stem}{suffix}" for suffix in (".bvh", ".glb")}
            for path in files.values():
                write_motion(motion, path, character)
            done[clip, target] = motion, files
    return done


@pytest.mark.parametrize("target", TARGETS)
@pytest.mark.parametrize("clip", CLIPS)
def test_bvh_output_reads_back_in_its_units_and_axes(outputs, clip, target):
    motion, files = outputs[clip, target]
    back = read_motion(files[".bvh"])
    written = motion.skeleton.source
    src = back.skeleton.source
    assert (src.units, src.up_axis) == (written.units, written.up_axis), src.reason
    if target != "target_robot_expressive.glb":
        assert src.doubt == ""
    else:                    # a robot 4 m tall in metres: said, in one sentence about units
        assert "fits no unit for a person" in src.doubt and "\n" not in src.doubt
    error = np.abs(world_positions(back) - world_positions(motion)).max()
    assert error <= 1e-6 * _stature(motion)


@pytest.mark.parametrize("target", TARGETS)
@pytest.mark.parametrize("clip", CLIPS)
def test_glb_output_reads_back_in_metres_y_up(outputs, clip, target):
    motion, files = outputs[clip, target]
    character = read_character(files[".glb"])
    assert len(character.motions) == 1
    back = character.motions[0]
    src = back.skeleton.source
    assert (src.units, src.up_axis) == ("m", "+Y")
    assert back.num_frames == motion.num_frames
    names = motion.skeleton.names
    index = [back.skeleton.joint(n) for n in names]
    world = world_positions(motion)
    error = np.abs(world_positions(back)[:, index] - world).max()
    # glTF holds 32-bit floats: every stored value moves by up to half a float32 step
    # (2 ** -24 of itself), along a chain of joints and the root far from the origin; the key
    # times too, which moves a joint by its speed times that step of the clip's duration
    depth = int(motion.skeleton.depth.max()) + 1
    speed = np.abs(np.diff(world, axis=0)).max() / motion.frame_time if motion.num_frames > 1 \
        else 0.0
    bound = 2.0 ** -23 * (depth * max(np.abs(world).max(), _stature(motion)) +
                          speed * motion.duration)
    print(f"GLB {clip} on {target}: {error:.2e} m, bound {bound:.2e} m")
    assert error <= bound


# --------------------------------------------------------------------------- Blender
@pytest.mark.blender
def test_bvh_outputs_read_back_the_same_after_blender(outputs, tmp_path):
    # one Blender process imports and exports every BVH output of two glTF targets (the
    # case that re-read Z-up) and of the inches/Z-up target, 120 frames of each (36 files);
    # Blender exports positions on every joint (the robot's IK bones translate)
    blender_or_skip()
    chosen = [(c, t) for (c, t) in outputs if t in ("target_mixamo_ely.glb",
                                                    "target_robot_expressive.glb",
                                                    "fair1_child8_jumping.bvh")]
    files, short = [], {}
    for clip, target in chosen:
        motion, paths = outputs[clip, target]
        part = motion.frames(slice(0, 120))
        source = tmp_path / f"{paths['.bvh'].stem}.bvh"
        write_motion(part, source)
        short[clip, target] = part
        files.append({"path": str(source), "out": str(tmp_path / f"{source.stem}.blender.bvh"),
                      "frames": part.num_frames})
    run_blender_roundtrip(files, tmp_path)
    for (clip, target), item in zip(chosen, files):
        part = short[clip, target]
        back = read_motion(item["out"])
        written = part.skeleton.source
        src = back.skeleton.source
        assert (src.units, src.up_axis) == (written.units, written.up_axis), (item, src.reason)
        # Blender writes its own channel layout and End Sites; the joints stay where they were
        names = part.skeleton.names
        index = [back.skeleton.joint(n) for n in names]
        error = np.abs(world_positions(back)[:, index] - world_positions(part)).max()
        assert error <= 1e-4 * _stature(part), (item, error)
