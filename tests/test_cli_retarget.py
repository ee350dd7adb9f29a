"""`motion-composer retarget`: the written file, the options, bad input, and Blender playing it.

The command's output is read back with the engine's reader and compared with
``engine.conversion.retarget`` called directly with the same options; each option is checked for
the effect it promises on real clips (the bundled CMU walk onto the bundled CMU T-pose
character, and where ``../shared/data`` is present CMU onto Bandai and FAIR1 onto CC3). Bad input
must give exit code 2 and one line on stderr. The Blender test imports the command's output
with Blender's own BVH importer and compares its world joint positions with our forward
kinematics of the same file.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from motion_composer.app.cli import main
from blender_util import blender_or_skip, run_blender_fbx, run_blender_import
from conftest import REPO, SHARED_DATA, clip_path, resolve, shared_path
from test_cli import console_script
from motion_composer.engine import forward_kinematics, read_bvh
from motion_composer.engine.conversion.correspondence import Correspondence
from motion_composer.engine.describe import stature
from motion_composer.engine.conversion import BindOptions, bind
from motion_composer.engine.conversion import RootOptions
from motion_composer.engine.conversion import retarget
from motion_composer.engine.rotations import angle_between
from test_retarget import CMU_TO_BANDAI, bone_deviation

WALK = clip_path("cmu_131_01_walk.bvh")      # CMU-MAX names, +Y, CMU units, 994 frames
TPOSE = clip_path("cmu_rest_tpose.bvh")      # CMU-MB/Holden names, one T-pose frame

#: target (CMU-MB/Holden, the T-pose character) -> performer (CMU-MAX, README): the MAX
#: `LeftShoulder` is the upper arm, its `LeftCollar` the clavicle
MAX_TO_HOLDEN = {
    "Hips": "Hips", "LHipJoint": "LHipJoint", "LeftUpLeg": "LeftHip", "LeftLeg": "LeftKnee",
    "LeftFoot": "LeftAnkle", "LeftToeBase": "LeftToe", "RHipJoint": "RHipJoint",
    "RightUpLeg": "RightHip", "RightLeg": "RightKnee", "RightFoot": "RightAnkle",
    "RightToeBase": "RightToe", "LowerBack": "lowerback", "Spine": "Chest", "Spine1": "Chest2",
    "Neck": "lowerneck", "Neck1": "Neck", "Head": "Head",
    "LeftShoulder": "LeftCollar", "LeftArm": "LeftShoulder", "LeftForeArm": "LeftElbow",
    "LeftHand": "LeftWrist", "LeftFingerBase": "lhand", "LeftHandIndex1": "LFingers",
    "LThumb": "LThumb",
    "RightShoulder": "RightCollar", "RightArm": "RightShoulder", "RightForeArm": "RightElbow",
    "RightHand": "RightWrist", "RightFingerBase": "rhand", "RightHandIndex1": "RFingers",
    "RThumb": "RThumb",
}

#: target (CMU-Holden T-pose) -> performer (FAIR1: four spine joints, Z-up, inches)
FAIR_TO_HOLDEN = {
    "Hips": "Hips", "Spine": "Spine", "Spine1": "Spine3", "Neck": "Neck", "Head": "Head",
    "LeftArm": "LeftArm", "LeftForeArm": "LeftForeArm", "LeftHand": "LeftHand",
    "RightArm": "RightArm", "RightForeArm": "RightForeArm", "RightHand": "RightHand",
    "LeftUpLeg": "LeftUpLeg", "LeftLeg": "LeftLeg", "LeftFoot": "LeftFoot",
    "RightUpLeg": "RightUpLeg", "RightLeg": "RightLeg", "RightFoot": "RightFoot",
}

#: target (CC3 `CC_Base_*`) -> performer (FAIR1)
FAIR_TO_CC3 = {
    "CC_Base_Hip": "Hips", "CC_Base_Waist": "Spine", "CC_Base_Spine02": "Spine3",
    "CC_Base_NeckTwist01": "Neck", "CC_Base_Head": "Head",
    "CC_Base_L_Clavicle": "LeftShoulder", "CC_Base_L_Upperarm": "LeftArm",
    "CC_Base_L_Forearm": "LeftForeArm", "CC_Base_L_Hand": "LeftHand",
    "CC_Base_R_Clavicle": "RightShoulder", "CC_Base_R_Upperarm": "RightArm",
    "CC_Base_R_Forearm": "RightForeArm", "CC_Base_R_Hand": "RightHand",
    "CC_Base_L_Thigh": "LeftUpLeg", "CC_Base_L_Calf": "LeftLeg", "CC_Base_L_Foot": "LeftFoot",
    "CC_Base_L_ToeBase": "LeftToeBase", "CC_Base_R_Thigh": "RightUpLeg",
    "CC_Base_R_Calf": "RightLeg", "CC_Base_R_Foot": "RightFoot",
    "CC_Base_R_ToeBase": "RightToeBase",
}

#: world positions of the command's output against a direct call [m]: the file keeps 6
#: decimals (1e-6 file units, 1e-6 degree), far below this
POS_TOL = 1e-6


@dataclass(frozen=True)
class Case:
    id: str
    performer: tuple      # (kind, name) for conftest.resolve
    target: tuple
    pairs: dict


CASES = [
    Case("cmu-max-walk-onto-tpose", ("bundled", "cmu_131_01_walk.bvh"),
         ("bundled", "cmu_rest_tpose.bvh"), MAX_TO_HOLDEN),
    Case("fair1-zup-inches-onto-tpose", ("bundled", "fair1_child8_jumping.bvh"),
         ("bundled", "cmu_rest_tpose.bvh"), FAIR_TO_HOLDEN),
    Case("cmu-onto-bandai", ("shared", "cmu_mb_01_01_jumps.bvh"),
         ("shared", "bandai1_walk_normal_001.bvh"), CMU_TO_BANDAI),
    Case("fair1-onto-cc3-rlroot", ("shared", "fair1_child8_jumping.bvh"),
         ("shared", "cc3_cmu_02_01_walk.bvh"), FAIR_TO_CC3),
    Case("fair1-onto-cc3-hiproot", ("shared", "fair1_child8_jumping.bvh"),
         ("shared", "cc3_cmu_02_06_pickup.bvh"), FAIR_TO_CC3),
]


# --------------------------------------------------------------------------- helpers
def cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def write_map(path: Path, pairs: dict) -> Path:
    path.write_text(json.dumps({"pairs": pairs}, indent=2))
    return path


def positions(motion) -> np.ndarray:
    return forward_kinematics(motion).positions


def assert_same_motion(a, b, tol=POS_TOL):
    err = np.abs(positions(a) - positions(b)).max()
    assert err <= tol, f"world positions differ by {err:.3g} m (tolerance {tol:g} m)"


def assert_success(code, out, err, output: Path, frames: int, joints: int, mapped: int):
    assert (code, err) == (0, ""), err
    assert re.fullmatch(rf"wrote {re.escape(str(output))}: {frames} frames at [0-9.]+ fps onto "
                        rf"{joints} joints \({mapped} mapped\) in [0-9.]+ s\n", out), out
    assert output.is_file()


@pytest.fixture(scope="module")
def walk():
    return read_bvh(WALK)


@pytest.fixture(scope="module")
def tpose():
    return read_bvh(TPOSE)


@pytest.fixture
def run_walk(capsys, tmp_path, walk, tpose):
    """Retarget the bundled walk onto the T-pose with MAX_TO_HOLDEN and extra options through
    the command; returns the output read back."""
    mapping = write_map(tmp_path / "walk_map.json", MAX_TO_HOLDEN)
    count = iter(range(1000))

    def run(*options):
        out_path = tmp_path / f"walk_{next(count)}.bvh"
        code, out, err = cli(capsys, "retarget", WALK, "--target", TPOSE, "-o", out_path,
                             "--map", mapping, *options)
        assert_success(code, out, err, out_path, walk.num_frames, tpose.skeleton.num_joints,
                       len(MAX_TO_HOLDEN))
        return read_bvh(out_path)

    return run


def direct_walk(walk, tpose, bind_options=None, root=None):
    return retarget(walk, tpose, Correspondence(MAX_TO_HOLDEN), bind_options=bind_options,
                    root=root)


# --------------------------------------------------------------------------- explicit map
@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_retarget_with_an_explicit_map(case, capsys, tmp_path):
    performer_path, target_path = resolve(case.performer), resolve(case.target)
    mapping = write_map(tmp_path / "map.json", case.pairs)
    output, used = tmp_path / "out.bvh", tmp_path / "used.json"
    performer, target = read_bvh(performer_path), read_bvh(target_path)
    tsk = target.skeleton

    code, out, err = cli(capsys, "retarget", performer_path, "--target", target_path,
                         "-o", output, "--map", mapping, "--save-map", used)
    assert_success(code, out, err, output, performer.num_frames, tsk.num_joints,
                   len(case.pairs))

    back = read_bvh(output)
    sk = back.skeleton
    # the target's character: hierarchy, channel layout, units and up axis
    assert sk.names == tsk.names
    np.testing.assert_array_equal(sk.parents, tsk.parents)
    np.testing.assert_allclose(sk.offsets, tsk.offsets, atol=1e-6 * tsk.source.scale)
    assert sk.channels == tsk.channels
    assert sk.position_modes == tsk.position_modes
    assert [(e.parent, e.name) for e in sk.end_sites] == \
        [(e.parent, e.name) for e in tsk.end_sites]
    np.testing.assert_allclose([e.offset for e in sk.end_sites],
                               [e.offset for e in tsk.end_sites], atol=1e-6 * tsk.source.scale)
    for attribute in ("units", "scale", "up_axis"):
        assert getattr(sk.source, attribute) == getattr(tsk.source, attribute), attribute
    # the performer's timing
    assert back.num_frames == performer.num_frames
    assert back.frame_time == performer.frame_time

    # the same motion as a direct call with the same (default) options
    corr = Correspondence(case.pairs)
    direct = retarget(performer, target, corr)
    assert_same_motion(back, direct)
    # ...which really is the performer's motion: the target's bones follow its virtual bones
    # (the median over bones; a branching joint's secondary bones may differ by a few degrees)
    dev = bone_deviation(performer, back, corr)
    assert len(dev) >= 10 and float(np.median(list(dev.values()))) < 0.5, dev

    # --save-map: the map used, in the documented JSON form
    saved = json.loads(used.read_text())
    assert saved["pairs"] == case.pairs
    assert Correspondence.load(used) == corr


def _command():
    script = console_script()
    return [script] if script else [sys.executable, "-m", "motion_composer.app.cli"]


def test_retarget_as_a_real_process(capsys, tmp_path):
    """The installed command, in its own process, writes the same file as main() in-process,
    and a bad mapping file gives exit 2 and one line."""
    mapping = write_map(tmp_path / "map.json", MAX_TO_HOLDEN)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    proc = subprocess.run(_command() + ["retarget", str(WALK), "--target", str(TPOSE),
                                        "-o", str(tmp_path / "sub.bvh"), "--map", str(mapping),
                                        "--save-map", str(tmp_path / "sub.json")],
                          capture_output=True, text=True, timeout=60, env=env)
    assert (proc.returncode, proc.stderr) == (0, ""), proc.stderr
    assert proc.stdout.startswith(f"wrote {tmp_path / 'sub.bvh'}: 994 frames at 120 fps")
    code, out, err = cli(capsys, "retarget", WALK, "--target", TPOSE, "-o", tmp_path / "in.bvh",
                         "--map", mapping)
    assert code == 0
    assert (tmp_path / "sub.bvh").read_bytes() == (tmp_path / "in.bvh").read_bytes()
    assert json.loads((tmp_path / "sub.json").read_text())["pairs"] == MAX_TO_HOLDEN

    bad = tmp_path / "bad.json"
    bad.write_text('{"pairs": {"Hips": "Hips",\n "Spine": }}')
    proc = subprocess.run(_command() + ["retarget", str(WALK), "--target", str(TPOSE),
                                        "-o", str(tmp_path / "never.bvh"), "--map", str(bad)],
                          capture_output=True, text=True, timeout=60, env=env)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert "bad.json" in proc.stderr and "line 2" in proc.stderr
    assert not (tmp_path / "never.bvh").exists()


# --------------------------------------------------------------------------- options
def _hips(motion) -> np.ndarray:
    return positions(motion)[:, motion.skeleton.index["Hips"]]


def test_reference_frame_and_rest_bind_differently(run_walk, walk, tpose):
    N = 500
    rest = run_walk("--reference", "rest")
    frame = run_walk("--reference", f"frame:{N}")
    default = run_walk()
    assert_same_motion(rest, direct_walk(walk, tpose, BindOptions(performer_reference="rest")))
    assert_same_motion(frame, direct_walk(walk, tpose, BindOptions(performer_reference=N)))
    # 'auto' (the default) takes the rest pose: the CMU-MAX rest pose stands upright
    assert_same_motion(default, rest)

    # the root's displacement is measured from the reference pose: the hips stand where the
    # target's own hips are at the reference frame (frame 0 for the rest pose, whose root is
    # the first frame's) and elsewhere at other frames
    home = positions(tpose)[0, tpose.skeleton.index["Hips"]]
    h_rest, h_frame = _hips(rest), _hips(frame)
    np.testing.assert_allclose(h_rest[0], home, atol=POS_TOL)
    np.testing.assert_allclose(h_frame[N], home, atol=POS_TOL)
    assert np.linalg.norm(h_rest[N] - home) > 0.3       # the walk has moved on by frame 500
    assert np.linalg.norm(h_frame[0] - home) > 0.3
    # a different binding: the bones point the same way in both (every joint is mapped) but
    # their rolls differ, by tens of degrees for the arms
    joint_dirs = positions(rest) - _hips(rest)[:, None]
    np.testing.assert_allclose(positions(frame) - h_frame[:, None], joint_dirs, atol=POS_TOL)
    turn = np.degrees(angle_between(rest.rotations, frame.rotations))
    assert turn.max() > 30
    arm = tpose.skeleton.index["LeftArm"]
    assert np.median(turn[:, arm]) > 10


def _arm_angle(motion, upper: str, lower: str) -> np.ndarray:
    """Angle [deg] per frame between an upper arm and straight down."""
    pos = positions(motion)
    v = pos[:, motion.skeleton.index[lower]] - pos[:, motion.skeleton.index[upper]]
    return np.degrees(np.arccos(-v[:, 1] / np.linalg.norm(v, axis=1)))


def test_keep_target_pose_keeps_the_t_pose(run_walk, walk, tpose):
    """Bound at the performer's frame 0: with --keep-target-pose the output's frame 0 is the
    T-pose character itself (arms out) while the performer's arms hang; without it the
    target's arms follow the performer's."""
    kept = run_walk("--keep-target-pose", "--reference", "frame:0")
    aligned = run_walk("--reference", "frame:0")
    assert_same_motion(kept, direct_walk(
        walk, tpose, BindOptions(performer_reference=0, rest_alignment=False)))
    assert np.degrees(angle_between(kept.rotations[0], tpose.rotations[0])).max() < 1e-4
    np.testing.assert_allclose(positions(kept)[0], positions(tpose)[0], atol=POS_TOL)
    performer_arm = _arm_angle(walk, "LeftShoulder", "LeftElbow")      # MAX upper arm
    kept_arm = _arm_angle(kept, "LeftArm", "LeftForeArm")
    aligned_arm = _arm_angle(aligned, "LeftArm", "LeftForeArm")
    t_arm = _arm_angle(tpose, "LeftArm", "LeftForeArm")[0]
    assert t_arm > 80 and performer_arm[0] < 40
    assert abs(kept_arm[0] - t_arm) < 1e-3
    np.testing.assert_allclose(aligned_arm, performer_arm, atol=1e-3)
    # the kept arm moves with the performer's arm, from the T-pose: always well above it
    assert (kept_arm - aligned_arm).min() > 30


def test_keep_target_pose_keeps_the_bandai_arms(capsys, tmp_path):
    """CMU's frame 0 is a T-pose and Bandai's frame 0 has the arms down: kept, the Bandai
    character starts in its own frame-0 posture; aligned, it starts in CMU's T-pose."""
    perf_path = shared_path("cmu_mb_01_01_jumps.bvh")
    targ_path = shared_path("bandai1_walk_normal_001.bvh")
    performer, target = read_bvh(perf_path), read_bvh(targ_path)
    mapping = write_map(tmp_path / "map.json", CMU_TO_BANDAI)
    outs = {}
    for label, extra in (("kept", ["--keep-target-pose"]), ("aligned", [])):
        path = tmp_path / f"{label}.bvh"
        code, out, err = cli(capsys, "retarget", perf_path, "--target", targ_path, "-o", path,
                             "--map", mapping, "--reference", "frame:0", *extra)
        assert (code, err) == (0, "")
        outs[label] = read_bvh(path)
    kept, aligned = outs["kept"], outs["aligned"]
    assert_same_motion(kept, retarget(performer, target, Correspondence(CMU_TO_BANDAI),
                                      bind_options=BindOptions(performer_reference=0,
                                                               rest_alignment=False)))
    # frame 0 is Bandai's own frame 0, every joint (its position channels included)
    np.testing.assert_allclose(positions(kept)[0], positions(target)[0], atol=POS_TOL)
    assert np.degrees(angle_between(kept.rotations[0], target.rotations[0])).max() < 1e-4
    for side, cmu in (("L", "Left"), ("R", "Right")):
        bandai0 = _arm_angle(target, f"UpperArm_{side}", f"LowerArm_{side}")[0]
        cmu0 = _arm_angle(performer, f"{cmu}Arm", f"{cmu}ForeArm")[0]
        assert bandai0 < 30 and cmu0 > 70                      # arms down vs T-pose
        assert abs(_arm_angle(kept, f"UpperArm_{side}", f"LowerArm_{side}")[0] - bandai0) < 1e-3
        assert abs(_arm_angle(aligned, f"UpperArm_{side}", f"LowerArm_{side}")[0] - cmu0) < 0.1


def test_root_modes_and_scale(run_walk, walk, tpose):
    corr = Correspondence(MAX_TO_HOLDEN)
    ratio = bind(walk, tpose, corr).hip_height_ratio
    assert 0.8 < ratio < 1.3            # both are CMU skeletons of about the same build
    pp = _hips(walk)
    disp = pp - pp[0]
    assert np.ptp(disp[:, [0, 2]], axis=0).max() > 1.0     # the walk travels over a metre
    runs = {
        "scaled": run_walk(),
        "explicit scaled": run_walk("--root", "scaled"),
        "absolute": run_walk("--root", "absolute"),
        "in-place": run_walk("--root", "in-place"),
        "scale 2 0.5": run_walk("--root-scale", "2", "0.5"),
        "in-place scale 2 0.5": run_walk("--root", "in-place", "--root-scale", "2", "0.5"),
    }
    options = {
        "scaled": RootOptions(), "explicit scaled": RootOptions(mode="scaled"),
        "absolute": RootOptions(mode="absolute"), "in-place": RootOptions(mode="in-place"),
        "scale 2 0.5": RootOptions(scale=(2.0, 0.5)),
        "in-place scale 2 0.5": RootOptions(mode="in-place", scale=(2.0, 0.5)),
    }
    for label, motion in runs.items():
        assert_same_motion(motion, direct_walk(walk, tpose, root=options[label]))
    hips = {label: _hips(m) for label, m in runs.items()}
    atol = POS_TOL
    # scaled (default): the performer's displacement times the hip-height ratio
    np.testing.assert_allclose(hips["scaled"] - hips["scaled"][0], disp * ratio, atol=atol)
    np.testing.assert_allclose(hips["explicit scaled"], hips["scaled"], atol=atol)
    # absolute: the performer's hip trajectory as it is, in metres
    np.testing.assert_allclose(hips["absolute"], pp, atol=atol)
    # in-place: horizontal position constant, vertical as in scaled
    h = hips["in-place"]
    np.testing.assert_allclose(h[:, [0, 2]], np.broadcast_to(h[0, [0, 2]], (len(h), 2)),
                               atol=atol)
    np.testing.assert_allclose(h[:, 1], hips["scaled"][:, 1], atol=atol)
    assert np.ptp(h[:, 1]) > 0.01                         # the hips still bob up and down
    # --root-scale H V: per axis
    np.testing.assert_allclose(hips["scale 2 0.5"] - hips["scale 2 0.5"][0],
                               disp * [2.0, 0.5, 2.0], atol=atol)
    h = hips["in-place scale 2 0.5"]
    np.testing.assert_allclose(h[:, [0, 2]], np.broadcast_to(h[0, [0, 2]], (len(h), 2)),
                               atol=atol)
    np.testing.assert_allclose(h[:, 1] - h[0, 1], disp[:, 1] * 0.5, atol=atol)
    # the root option moves the whole body and nothing else
    body = positions(runs["scaled"]) - hips["scaled"][:, None]
    for label, motion in runs.items():
        np.testing.assert_allclose(positions(motion) - hips[label][:, None], body, atol=atol,
                                   err_msg=label)


# --------------------------------------------------------------------------- automatic map
#: pairs an automatic map must find, target (CMU-Holden) -> performer (CMU-MAX); note the
#: MAX `LeftShoulder` is the upper arm (README), so the name alone misleads
AUTO_EXPECTED = {
    "Hips": "Hips", "Head": "Head",
    "LeftUpLeg": "LeftHip", "LeftLeg": "LeftKnee", "LeftFoot": "LeftAnkle",
    "RightUpLeg": "RightHip", "RightLeg": "RightKnee", "RightFoot": "RightAnkle",
    "LeftArm": "LeftShoulder", "LeftForeArm": "LeftElbow", "LeftHand": "LeftWrist",
    "RightArm": "RightShoulder", "RightForeArm": "RightElbow", "RightHand": "RightWrist",
}


def _mismatches(pairs: dict, expected: dict) -> dict:
    return {t: (pairs.get(t), p) for t, p in expected.items() if pairs.get(t) != p}


def test_automatic_mapping_walk_onto_tpose(capsys, tmp_path, walk, tpose):
    output, used = tmp_path / "auto.bvh", tmp_path / "auto.json"
    code, out, err = cli(capsys, "retarget", WALK, "--target", TPOSE, "-o", output,
                         "--save-map", used)
    assert (code, err) == (0, ""), err
    pairs = json.loads(used.read_text())["pairs"]
    assert all(isinstance(k, str) and isinstance(v, str) for k, v in pairs.items())
    assert out.startswith(f"wrote {output}: 994 frames") and f"({len(pairs)} mapped)" in out
    assert not _mismatches(pairs, AUTO_EXPECTED), \
        f"target joint: (automatic, expected) {_mismatches(pairs, AUTO_EXPECTED)}"
    corr = Correspondence.load(used)
    corr.validate(tpose.skeleton, walk.skeleton)
    back = read_bvh(output)
    assert back.skeleton.names == tpose.skeleton.names and back.num_frames == walk.num_frames
    assert_same_motion(back, retarget(walk, tpose, corr))
    dev = bone_deviation(walk, back, corr)
    assert max(dev[("LeftArm", "LeftForeArm")], dev[("RightUpLeg", "RightLeg")]) < 0.5


def test_automatic_mapping_cmu_onto_bandai(capsys, tmp_path):
    perf_path = shared_path("cmu_mb_01_01_jumps.bvh")
    targ_path = shared_path("bandai1_walk_normal_001.bvh")
    output, used = tmp_path / "auto.bvh", tmp_path / "auto.json"
    code, out, err = cli(capsys, "retarget", perf_path, "--target", targ_path, "-o", output,
                         "--save-map", used)
    assert (code, err) == (0, ""), err
    pairs = json.loads(used.read_text())["pairs"]
    limbs = {t: p for t, p in CMU_TO_BANDAI.items()
             if t in ("Hips", "Head", "UpperArm_L", "LowerArm_L", "Hand_L", "UpperArm_R",
                      "LowerArm_R", "Hand_R", "UpperLeg_L", "LowerLeg_L", "Foot_L",
                      "UpperLeg_R", "LowerLeg_R", "Foot_R")}
    assert not _mismatches(pairs, limbs), \
        f"target joint: (automatic, expected) {_mismatches(pairs, limbs)}"
    performer, target = read_bvh(perf_path), read_bvh(targ_path)
    assert_same_motion(read_bvh(output),
                       retarget(performer, target, Correspondence.load(used)))


# --------------------------------------------------------------------------- bad input
def _args(tmp_path, *, performer=WALK, target=TPOSE, pairs=None, map_text=None, extra=()):
    argv = ["retarget", performer, "--target", target, "-o", tmp_path / "out.bvh",
            "--save-map", tmp_path / "used.json"]
    if pairs is not None or map_text is not None:
        path = tmp_path / "bad_map.json"
        path.write_text(map_text if map_text is not None else json.dumps({"pairs": pairs}))
        argv += ["--map", path]
    return argv + list(extra)


# id -> (argv builder, phrases the one line must hold, the file it must name)
BAD = {
    "unknown-target-joint": (
        lambda d: _args(d, pairs={"Hips": "Hips", "LeftArmm": "LeftShoulder"}),
        ["'LeftArmm' is not a joint of the target skeleton", "did you mean 'LeftArm'"],
        "bad_map.json"),
    "unknown-performer-joint": (
        lambda d: _args(d, pairs={"Hips": "Hips", "LeftArm": "Elbow"}),
        ["'Elbow' is not a joint of the performer skeleton", "'LeftArm'"], "bad_map.json"),
    "root-unmapped": (
        lambda d: _args(d, pairs={"LeftArm": "LeftShoulder", "RightArm": "RightShoulder"}),
        ["root 'Hips' is unmapped", "map the target's root or hips"], "bad_map.json"),
    "nothing-mapped": (
        lambda d: _args(d, pairs={}), ["no joint is mapped", "'Hips'"], "bad_map.json"),
    "ancestry-inverted": (
        lambda d: _args(d, pairs={"Hips": "Hips", "LeftArm": "LeftElbow",
                                  "LeftForeArm": "LeftShoulder"}),
        ["inverts ancestry"], "bad_map.json"),
    "performer-joint-used-twice": (
        lambda d: _args(d, pairs={"Hips": "Hips", "LeftArm": "LeftElbow",
                                  "LeftForeArm": "LeftElbow"}),
        ["both mapped to performer joint 'LeftElbow'"], "bad_map.json"),
    "malformed-json": (
        lambda d: _args(d, map_text='{"pairs": {"Hips": "Hips",\n "Spine": }}'),
        ["not valid JSON", "line 2"], "bad_map.json"),
    "no-pairs-object": (
        lambda d: _args(d, map_text='{"map": {"Hips": "Hips"}}'), ['"pairs"'], "bad_map.json"),
    "pairs-value-not-a-string": (
        lambda d: _args(d, map_text='{"pairs": {"Hips": "Hips", "Head": 3}}'),
        ['"pairs"', "strings to strings"], "bad_map.json"),
    "missing-mapping-file": (
        lambda d: _args(d) + ["--map", d / "absent_map.json"],
        ["no such mapping file"], "absent_map.json"),
    "missing-performer-file": (
        lambda d: _args(d, performer=d / "absent_performer.bvh", pairs=MAX_TO_HOLDEN),
        ["no such file"], "absent_performer.bvh"),
    "missing-target-file": (
        lambda d: _args(d, target=d / "absent_target.bvh", pairs=MAX_TO_HOLDEN),
        ["no such file"], "absent_target.bvh"),
    "reference-frame-outside-the-clip": (
        lambda d: _args(d, pairs=MAX_TO_HOLDEN, extra=["--reference", "frame:999999"]),
        ["reference frame 999999 is outside the clip", "frames 0 to 993"],
        "cmu_131_01_walk"),
    "target-reference-frame-outside-the-clip": (
        lambda d: _args(d, pairs=MAX_TO_HOLDEN, extra=["--target-reference", "frame:5"]),
        ["reference frame 5 is outside the clip", "frames 0 to 0"], "cmu_rest_tpose"),
    "root-scale-not-finite": (
        lambda d: _args(d, pairs=MAX_TO_HOLDEN, extra=["--root-scale", "nan", "1"]),
        ["root scale must be two finite numbers"], None),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_exits_2_with_one_line(case, capsys, tmp_path):
    build, phrases, name = BAD[case]
    code, out, err = cli(capsys, *build(tmp_path))
    assert (code, out) == (2, "")
    assert err.startswith("motion-composer: error: ") and err.endswith("\n")
    assert err.count("\n") == 1, err
    assert "Traceback" not in err
    for phrase in phrases:
        assert phrase in err, f"{phrase!r} not in {err!r}"
    if name is not None:
        assert name in err, f"{name!r} not in {err!r}"
    # nothing half-done is left behind
    assert not (tmp_path / "out.bvh").exists()
    assert not (tmp_path / "used.json").exists()


def test_a_limb_chain_alone_is_an_unmapped_root(capsys, tmp_path):
    code, out, err = cli(capsys, *_args(tmp_path, pairs={"LeftArm": "LeftShoulder",
                                                         "LeftForeArm": "LeftElbow"}))
    assert code == 2 and err.count("\n") == 1 and "Hips" in err


@pytest.mark.parametrize("option", ["-o", "--save-map"])
def test_writing_into_a_missing_folder_exits_2(option, capsys, tmp_path):
    argv = [str(a) for a in _args(tmp_path, pairs=MAX_TO_HOLDEN)]
    argv[argv.index(option) + 1] = str(tmp_path / "no_such_folder" / "file")
    code, out, err = cli(capsys, *argv)
    assert code == 2 and err.count("\n") == 1 and "no_such_folder" in err


def test_bad_reference_syntax_is_a_usage_error(capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        main([str(a) for a in _args(tmp_path, pairs=MAX_TO_HOLDEN,
                                    extra=["--reference", "frame:x"])])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "frame:x" in err
    assert not (tmp_path / "out.bvh").exists()


# --------------------------------------------------------------------------- Blender
#: Blender's positions against our FK of the same file, as a fraction of the body height
BLENDER_REL_TOL = 1e-4

BLENDER_CASES = {
    "cmu-onto-bandai": CASES[2],
    "cmu-max-walk-onto-tpose": CASES[0],
}


def _sample_frames(n: int, between: int = 10) -> list[int]:
    """First, middle, last and ``between`` more spread over the clip."""
    spread = np.linspace(0, n - 1, between + 2).round().astype(int).tolist()
    return sorted({0, n // 2, n - 1, *spread})


@pytest.fixture(scope="module")
def blender_outputs(tmp_path_factory):
    """Every available case retargeted by the command, then imported by one Blender process."""
    blender_or_skip()
    folder = tmp_path_factory.mktemp("cli_blender")
    made, files = {}, []
    for key, case in BLENDER_CASES.items():
        if case.performer[0] == "shared" and not SHARED_DATA.is_dir():
            continue
        performer_path, target_path = resolve(case.performer), resolve(case.target)
        mapping = write_map(folder / f"{key}.json", case.pairs)
        output = folder / f"{key}.bvh"
        code = main(["retarget", str(performer_path), "--target", str(target_path),
                     "-o", str(output), "--map", str(mapping)])
        assert code == 0, key
        motion = read_bvh(output)
        frames = _sample_frames(motion.num_frames)
        made[key] = (motion, frames, read_bvh(performer_path).num_frames)
        files.append({"key": key, "path": str(output), "frames": frames})
    results = run_blender_import(files, folder)
    return {key: (*made[key], results[key]) for key in made}


@pytest.mark.blender
@pytest.mark.parametrize("key", list(BLENDER_CASES))
def test_blender_plays_the_retargeted_file(key, blender_outputs):
    case = BLENDER_CASES[key]
    for spec in (case.performer, case.target):
        resolve(spec)                      # skips without ../shared/data
    motion, frames, performer_frames, res = blender_outputs[key]
    sk = motion.skeleton
    # Blender reads position channels as absolute: the file must be written that way
    assert set(sk.position_modes) <= {"absolute", None}
    np.testing.assert_array_equal(res["matrix_world"], np.eye(4))
    assert motion.num_frames == performer_frames
    assert res["keys_per_curve"] == [performer_frames]     # one key per frame of the capture
    assert res["first_key_frame"] == [1.0]
    assert len(frames) >= 12
    src = sk.source
    ours = src.points_to_file(forward_kinematics(motion, end_sites=False).positions)[frames]
    theirs = np.array([[res["positions"][str(f)][n] for n in sk.names] for f in frames])
    tol = BLENDER_REL_TOL * stature(motion) / src.scale
    err = np.abs(theirs - ours).max()
    assert err <= tol, f"{key}: Blender differs by {err:.3g} file units (tolerance {tol:.3g})"
    # the motion is really there: the body moves between the sampled frames
    assert np.ptp(theirs, axis=0).max() > 100 * tol
    print(f"{key}: Blender vs our FK {err:.3g} file units, tolerance {tol:.3g}")


@pytest.mark.blender
def test_leaf_bones_under_a_carried_foot_get_no_floor(capsys, tmp_path):
    """The robot as Blender's FBX exporter writes it with leaf bones (``FootL_end`` under
    ``FootL``, a control joint the binding carries with the shin): automatic contacts and an
    explicit floor held each joint below a held foot above the floor, leaf bones included,
    and the scene then refused its own constraint (exit 2: "FootL_end hangs from FootL, a
    control joint carried with LowerLegL"). Joints hanging from a carried joint follow it
    after the IK, which cannot move them: they get no floor, and both runs write the file."""
    robot = tmp_path / "robot_leaf.fbx"
    run_blender_fbx({"exports": [{"key": "robot", "out": str(robot),
                                  "source": str(shared_path("target_robot_expressive.glb")),
                                  "options": {"add_leaf_bones": True,
                                              "primary_bone_axis": "X",
                                              "secondary_bone_axis": "Y"}}]}, tmp_path)
    walk = shared_path("bandai1_walk_normal_001.bvh")
    for extra in (["--auto-contacts"], ["--floor", "0"]):
        report = tmp_path / "report.json"
        code = main(["retarget", str(walk), "--target", str(robot), "-o",
                     str(tmp_path / "out.glb"), "--report", str(report), *extra])
        err = capsys.readouterr().err
        assert code == 0, err
        floors = [c["joint"] for c in json.loads(report.read_text())["constraints"]
                  if c["kind"] == "plane"]
        assert floors and not any(j.endswith("_end") for j in floors), floors
        assert {"FootL", "FootR"} <= set(floors)
