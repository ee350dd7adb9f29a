"""Export the way pipelines want it: a frame range, an output frame rate (slerp resampling)
and BVH with rotation channels only below the root.

Real clips: CMU 131_01 (bundled, 120 fps, frame time 0.0083333 s as cgspeed's converter writes
it), CMU 01_01 (../shared/data, 120 fps), CC3 02_06 (iClone's 60 fps export, 0.016667 s);
targets: three.js's RobotExpressive (a glTF character whose clips translate nine joints, which
therefore get six channels when written as BVH), Mixamo's Ely, and Bandai's skeleton (whose
non-root Hips carries the travel).
"""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from conftest import REPO, clip_path, shared_path
from motion_composer.engine.errors import ExportError
from motion_composer.engine.formats import read_character, read_motion, write_motion
from motion_composer.engine.formats.bvh import format_bvh, read_bvh
from motion_composer.engine.kinematics import forward_kinematics
from motion_composer.engine.motion import export_selection, parse_frame_range

WALK = clip_path("cmu_131_01_walk.bvh")
ELY = "target_mixamo_ely.glb"
ROBOT = "target_robot_expressive.glb"


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles [rad] between unit quaternions ``(..., 4)``."""
    return 2 * np.arccos(np.minimum(np.abs(np.sum(a * b, axis=-1)), 1.0))


# --------------------------------------------------------------------------- resampling
@pytest.mark.parametrize("source", ["bundled", "shared"])
def test_120_fps_at_30_is_every_4th_frame_exactly(source):
    motion = read_bvh(WALK if source == "bundled" else shared_path("cmu_mb_01_01_jumps.bvh"))
    assert motion.frame_time == 0.0083333
    out = motion.resampled(30)
    every4 = np.arange(0, motion.num_frames, 4)
    assert out.num_frames == len(every4) and out.frame_time == 1 / 30
    np.testing.assert_array_equal(out.rotations, motion.rotations[every4])
    np.testing.assert_array_equal(out.translations, motion.translations[every4])


def test_60_fps_at_24_interpolates_like_scipys_slerp():
    motion = read_bvh(shared_path("cc3_cmu_02_06_pickup.bvh"))
    assert motion.frame_time == 0.016667
    out = motion.resampled(24)
    src_t = np.arange(motion.num_frames) * motion.frame_time
    out_t = np.arange(out.num_frames) / 24
    assert out_t[-1] <= src_t[-1] < out_t[-1] + 1 / 24           # the same span of time
    assert out.num_frames == 447
    for j in range(motion.skeleton.num_joints):
        reference = Slerp(src_t, Rotation.from_quat(motion.rotations[:, j]))(out_t).as_quat()
        assert _angle(out.rotations[:, j], reference).max() < 1e-6, motion.skeleton.names[j]
    for k in range(len(motion.skeleton.translated)):
        for axis in range(3):
            np.testing.assert_allclose(out.translations[:, k, axis],
                                       np.interp(out_t, src_t, motion.translations[:, k, axis]),
                                       rtol=0, atol=1e-9)
    # between two source frames, not on either: 2.5 source frames per output frame
    assert _angle(out.rotations[1], motion.rotations[2]).max() > 1e-4


@pytest.mark.parametrize("fps", [0, -30, float("nan"), float("inf"), 1001, "fast"])
def test_a_rate_outside_0_to_1000_is_refused(fps):
    with pytest.raises(ExportError, match="frame rate"):
        read_bvh(WALK).resampled(fps)


# --------------------------------------------------------------------------- frame range
def test_the_range_is_inclusive_and_checked():
    motion = read_bvh(WALK)
    part = motion.excerpt(10, 19)
    assert part.num_frames == 10
    np.testing.assert_array_equal(part.rotations, motion.rotations[10:20])
    assert motion.excerpt(993, None).num_frames == 1
    assert motion.excerpt(None, None).num_frames == 994
    for first, last in ((0, 994), (500, 499), (994, None)):
        with pytest.raises(ExportError, match="outside the clip, which has frames 0:993"):
            motion.excerpt(first, last)
    # range first, then rate: frames 100..499 at 30 fps are source frames 100, 104, ... 496
    out = export_selection(motion, (100, 499), 30)
    np.testing.assert_array_equal(out.rotations, motion.rotations[100:500:4])


@pytest.mark.parametrize("text, expected", [("0:239", (0, 239)), ("120:", (120, None)),
                                            (":99", (None, 99)), (" 5 : 6 ", (5, 6))])
def test_frame_ranges_parse(text, expected):
    assert parse_frame_range(text) == expected


@pytest.mark.parametrize("text", ["", "5", "1:2:3", "a:b", "-1:5", "1.5:3"])
def test_malformed_frame_ranges_are_refused(text):
    with pytest.raises(ExportError):
        parse_frame_range(text)


# --------------------------------------------------------------------------- channels
@pytest.fixture(scope="module")
def robot_dance():
    """RobotExpressive's own "Dance" clip (its joints below the root translate by a constant,
    so eight of them have six channels) and the character."""
    character = read_character(shared_path(ROBOT))
    return character.motion("Dance"), character


def test_rotation_only_bvh_has_three_channels_below_the_root_and_the_same_pose(robot_dance,
                                                                                tmp_path):
    motion, _ = robot_dance
    assert sum(len(c) == 6 for c in motion.skeleton.channels[1:]) == 8
    full, rot = tmp_path / "full.bvh", tmp_path / "rot.bvh"
    write_motion(motion, full)
    write_motion(motion, rot, channels="rotation")
    assert full.read_text() == format_bvh(motion)                  # the default is unchanged
    lines = [line.split() for line in rot.read_text().splitlines() if "CHANNELS" in line]
    assert lines[0][:2] == ["CHANNELS", "6"]
    assert all(line[1] == "3" and all(c.endswith("rotation") for c in line[2:])
               for line in lines[1:])
    assert len(lines) == motion.skeleton.num_joints
    a, b = read_bvh(full), read_bvh(rot)
    assert b.skeleton.names == a.skeleton.names and b.num_frames == a.num_frames
    np.testing.assert_allclose(forward_kinematics(b).positions, forward_kinematics(a).positions,
                               rtol=0, atol=1e-5)


def test_rotation_only_refuses_a_joint_that_travels(tmp_path):
    """Bandai: every joint has six channels and the hips (below joint_Root) carry the
    travel, which rotation channels cannot hold; so do RobotExpressive's Body in its Idle
    clip. Decision: refused, naming the joint, rather than losing the travel."""
    motion = read_bvh(shared_path("bandai1_walk_normal_001.bvh"))
    with pytest.raises(ExportError, match="'Hips' moves over the clip"):
        write_motion(motion, tmp_path / "out.bvh", channels="rotation")
    assert not (tmp_path / "out.bvh").exists()
    with pytest.raises(ExportError, match="'Body' moves over the clip"):
        format_bvh(read_character(shared_path(ROBOT)).motion("Idle"), channels="rotation")
    with pytest.raises(ExportError, match="channels must be one of"):
        format_bvh(motion, channels="positions")


def test_rotation_only_is_a_bvh_option(robot_dance, tmp_path):
    motion, character = robot_dance
    with pytest.raises(ExportError, match="BVH option"):
        write_motion(motion, tmp_path / "out.glb", character, channels="rotation")
    assert not (tmp_path / "out.glb").exists()


# --------------------------------------------------------------------------- command line
def _cli(*args):
    return subprocess.run([sys.executable, "-m", "motion_composer.app.cli", *map(str, args)], cwd=REPO,
                          capture_output=True, text=True, timeout=600)


def test_retarget_and_export_take_frames_fps_and_rotation_only(tmp_path):
    ely = shared_path(ELY)
    full, part, project = tmp_path / "full.bvh", tmp_path / "part.bvh", tmp_path / "p.mcp"
    run = _cli("retarget", WALK, "--target", ely, "-o", full, "--save-project", project)
    assert run.returncode == 0, run.stderr
    run = _cli("retarget", WALK, "--target", ely, "-o", part, "--frames", "100:499", "--fps",
               "30", "--rotation-only")
    assert run.returncode == 0 and run.stderr == "", run.stderr
    assert "100 frames at 30 fps" in run.stdout
    a, b = read_motion(full), read_motion(part)
    assert b.num_frames == 100 and b.frame_time == pytest.approx(1 / 30, abs=1e-15)
    assert all(len(c) == 3 for c in b.skeleton.channels[1:])
    np.testing.assert_allclose(forward_kinematics(b).positions,
                               forward_kinematics(a.frames(slice(100, 500, 4))).positions,
                               rtol=0, atol=1e-5)
    exported = tmp_path / "exported.bvh"
    run = _cli("export", project, "-o", exported, "--frames", "100:499", "--fps", "30",
               "--rotation-only")
    assert run.returncode == 0, run.stderr
    np.testing.assert_allclose(forward_kinematics(read_motion(exported)).positions,
                               forward_kinematics(b).positions, rtol=0, atol=1e-5)


@pytest.mark.parametrize("command", ["retarget", "export"])
def test_a_range_outside_the_clip_is_one_line_and_exit_2(tmp_path, command):
    project = tmp_path / "p.mcp"
    assert _cli("retarget", WALK, "--target", clip_path("cmu_rest_tpose.bvh"), "-o",
                tmp_path / "first.bvh", "--save-project", project).returncode == 0
    out = tmp_path / "out.bvh"
    head = (["retarget", WALK, "--target", clip_path("cmu_rest_tpose.bvh")] if
            command == "retarget" else ["export", project])
    run = _cli(*head, "-o", out, "--frames", "900:994")
    assert run.returncode == 2 and not out.exists()
    assert run.stderr.count("\n") == 1 and "outside the clip, which has frames 0:993" in \
        run.stderr
