"""The BVH reader on real files (../shared/data and the bundled clips) and on small synthetic texts.

The independent reference for the real files is the table in ../shared/data/README.md: it was
measured with two third-party parsers and a separate forward-kinematics pass, so the figures
below (frames, frame time, joints, End Sites, up axis, units, head-ankle distance) are copied
from that table, not from this reader's output.
"""
from __future__ import annotations

import math
import re
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from conftest import BUNDLED_BVH, SHARED_BVH, clip_path, shared_path
from motion_composer.engine.formats._numparse import parse_number_rows
from motion_composer.engine.formats.bvh import (detect_position_modes, parse_bvh, parse_bvh_text,
                                                read_bvh)
from motion_composer.engine.describe import stature
from motion_composer.engine.errors import BVHError
from motion_composer.engine.kinematics import forward_kinematics
from motion_composer.engine.units import UNITS

# --------------------------------------------------------------------------- the README table
#: file -> (frames, frame time as written, FPS column, joints, End Sites, up axis, units,
#:          head-ankle in file units at frame 0, duration s)
README = {
    "cmu_mb_01_01_jumps.bvh": (2752, 0.0083333, 120, 31, 7, "+Y", "cmu", 24.162, 22.93),
    "cmu_max_131_01_walk.bvh": (994, 0.0083333, 120, 31, 7, "+Y", "cmu", 22.069, 8.28),
    "cmu_xia_angry_13_000_run.bvh": (140, 0.008333, 120, 31, 7, "+Y", "cmu", 20.506, 1.17),
    "bandai1_walk_normal_001.bvh": (195, 0.0333333, 30, 22, 5, "+Y", "cm", 119.286, 6.5),
    "bandai1_run_active_001.bvh": (72, 0.0333333, 30, 22, 5, "+Y", "cm", 101.923, 2.4),
    "bandai1_kick_normal_001.bvh": (358, 0.0333333, 30, 22, 5, "+Y", "cm", 122.266, 11.93),
    "bandai2_raise-up-right-hand_normal_001.bvh": (59, 0.0333333, 30, 22, 5, "+Y", "cm",
                                                   128.862, 1.97),
    "fair1_child8_jumping.bvh": (654, 0.008342, 119.88, 27, 7, "+Z", "in", 39.789, 5.46),
    "fair1_child5_wave_hello.bvh": (839, 0.008342, 119.88, 27, 7, "+Z", "in", 33.899, 7.0),
    "rokoko_mixamo_jesse_dance.bvh": (1007, 0.01, 100, 60, 13, "+Y", "cm", 140.387, 10.07),
    "cc3_cmu_02_06_pickup.bvh": (1118, 0.016667, 60, 100, 41, "+Y", "cm", 158.693, 18.63),
    "cc3_cmu_02_01_walk.bvh": (171, 0.016667, 60, 101, 41, "+Y", "cm", 154.156, 2.85),
    "target_cmu_mb_rest_tpose.bvh": (1, 0.041667, 24, 31, 7, "+Y", "cmu", 23.29, 0.04),
}
#: bundled clips are byte-for-byte copies of these shared files (resources/clips/NOTICE.md)
BUNDLED_AS = {
    "cmu_131_01_walk.bvh": "cmu_max_131_01_walk.bvh",
    "fair1_child8_jumping.bvh": "fair1_child8_jumping.bvh",
    "cmu_rest_tpose.bvh": "target_cmu_mb_rest_tpose.bvh",
}
#: README's "Skeleton conventions": the head joint and the two ankle joints of each
HEAD_ANKLES = {
    "cmu_mb": ("Head", "LeftFoot", "RightFoot"),
    "cmu_xia": ("Head", "LeftFoot", "RightFoot"),
    "target_cmu": ("Head", "LeftFoot", "RightFoot"),
    "cmu_max": ("Head", "LeftAnkle", "RightAnkle"),
    "bandai": ("Head", "Foot_L", "Foot_R"),
    "fair1": ("Head", "LeftFoot", "RightFoot"),
    "rokoko": ("Head", "LeftFoot", "RightFoot"),
    "cc3": ("CC_Base_Head", "CC_Base_L_Foot", "CC_Base_R_Foot"),
}
CHILDREN = {"fair1_child8_jumping.bvh", "fair1_child5_wave_hello.bvh"}


def _params():
    return ([pytest.param(("bundled", n), id=f"bundled/{n}") for n in BUNDLED_BVH] +
            [pytest.param(("shared", n), id=n) for n in SHARED_BVH])


def _resolve(spec) -> tuple[Path, str]:
    """(path, README row name)."""
    kind, name = spec
    if kind == "bundled":
        return clip_path(name), BUNDLED_AS[name]
    return shared_path(name), name


@lru_cache(maxsize=None)
def _read(path: str, **options):
    return read_bvh(path, **options)


def read(path, **options):
    return _read(str(path), **options)


def _convention(row_name: str):
    return next(v for k, v in HEAD_ANKLES.items() if row_name.startswith(k))


# --------------------------------------------------------------------------- an independent reader
def raw_motion_block(path: Path) -> tuple[list[str], int]:
    """The lines after 'Frame Time:' (line endings normalised by hand) and the declared columns."""
    text = path.read_bytes().decode("utf-8")
    lines = re.split(r"\r\n|\r|\n", text)
    k = next(i for i, line in enumerate(lines) if line.strip().lower().startswith("frame time"))
    columns = sum(int(m) for m in re.findall(r"CHANNELS\s+(\d+)", text))
    return lines[k + 1:], columns


def raw_values(path: Path) -> np.ndarray:
    rows, _ = raw_motion_block(path)
    return np.array([[float(t) for t in row.split()] for row in rows if row.strip()])


def raw_end_site_offsets(path: Path) -> list[tuple[float, float, float]]:
    text = path.read_bytes().decode("utf-8")
    return [tuple(float(v) for v in m) for m in
            re.findall(r"End\s+Site\s*\{\s*OFFSET\s+(\S+)\s+(\S+)\s+(\S+)", text)]


# --------------------------------------------------------------------------- every real file
@pytest.mark.parametrize("spec", _params())
def test_frames_joints_and_frame_rate_match_the_readme(spec):
    path, row = _resolve(spec)
    frames, frame_time, fps, joints, end_sites, *_ = README[row]
    duration = README[row][-1]
    m = read(path)
    assert m.num_frames == frames
    assert m.skeleton.num_joints == joints
    assert len(m.skeleton.end_sites) == end_sites
    assert m.frame_time == frame_time                   # exactly as written in the file
    assert m.fps == 1.0 / frame_time                    # never rounded (119.88..., 120.0005)
    assert m.fps == pytest.approx(fps, rel=1e-3)
    # README durations are frames x frame time; ours run from the first frame to the last
    assert abs(m.duration - duration) <= frame_time + 0.006


def test_fair1_frame_rate_is_not_rounded():
    m = read(clip_path("fair1_child8_jumping.bvh"))
    assert m.fps == 1 / 0.008342
    assert 119.87 < m.fps < 119.88


@pytest.mark.parametrize("spec", _params())
def test_units_and_up_axis_are_detected_as_the_readme_says(spec):
    path, row = _resolve(spec)
    up, units = README[row][5], README[row][6]
    src = read(path).skeleton.source
    assert (src.units, src.up_axis) == (units, up)
    assert src.scale == UNITS[units]
    assert src.detected
    assert src.reason                                 # says how it decided


@pytest.mark.parametrize("spec", _params())
def test_head_ankle_distance_at_frame_0_matches_the_readme(spec):
    """Units, up axis and position modes together: frame 0's head-ankle distance along the up
    axis, converted back to file units, is the README's independently measured figure."""
    path, row = _resolve(spec)
    head, left, right = _convention(row)
    m = read(path)
    sk = m.skeleton
    p = forward_kinematics(m.frames(slice(0, 1))).positions[0]      # internal: metres, +Y up
    ankle_y = (p[sk.index[left], 1] + p[sk.index[right], 1]) / 2
    head_ankle = (p[sk.index[head], 1] - ankle_y) / sk.source.scale
    assert head_ankle == pytest.approx(README[row][7], abs=2e-3)


@pytest.mark.parametrize("spec", _params())
def test_stature_is_plausible(spec):
    """describe.stature is the vertical extent of joints and End Sites (it stops at the head
    joint or head End Site, not the top of the skull), so it must be at least the head-ankle
    span and not much more; and it must look like a person of the right age."""
    path, row = _resolve(spec)
    m = read(path)
    s = stature(m)
    head_ankle_m = README[row][7] * UNITS[README[row][6]]
    assert 0.98 * head_ankle_m <= s <= 1.45 * head_ankle_m
    if row in CHILDREN:
        assert 0.85 <= s <= 1.3
    else:
        assert 1.25 <= s <= 2.0


@pytest.mark.parametrize("spec", _params())
def test_values_are_the_files_numbers_exactly(spec):
    path, _ = _resolve(spec)
    record = parse_bvh_text(path.read_bytes().decode("utf-8"), path)
    expected = raw_values(path)
    assert record.values.shape == expected.shape
    assert np.array_equal(record.values.view(np.int64), expected.view(np.int64))


@pytest.mark.parametrize("spec", _params())
def test_end_sites_are_kept_with_their_offsets(spec):
    path, row = _resolve(spec)
    m = read(path)
    sk = m.skeleton
    expected = np.array(raw_end_site_offsets(path))
    assert len(expected) == README[row][4]
    got = np.array([site.offset for site in sk.end_sites]) / sk.source.scale
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)
    # each End Site hangs from a leaf joint
    parents = {site.parent for site in sk.end_sites}
    assert all(not sk.children[j] for j in parents)


# --------------------------------------------------------------------------- position modes
@pytest.mark.parametrize("name", [n for n in SHARED_BVH if n.startswith("bandai")])
def test_bandai_position_channels_are_absolute_on_every_joint(name):
    path = shared_path(name)
    m = read(path)
    sk = m.skeleton
    assert sk.num_joints == 22
    assert all(mode == "absolute" for mode in sk.position_modes)    # every joint has them


def test_bandai_relative_override_doubles_bone_lengths():
    """README: the position channels repeat the OFFSET; adding them doubles bone lengths."""
    path = shared_path("bandai1_walk_normal_001.bvh")
    record = parse_bvh_text(path.read_text(), path)
    spine = record.names.index("Spine")
    bone = np.linalg.norm(record.offsets[spine]) * 0.01

    def spine_length(m):
        p = forward_kinematics(m.frames(slice(0, 1))).positions[0]
        return np.linalg.norm(p[spine] - p[record.parents[spine]])

    assert spine_length(read(path)) == pytest.approx(bone, rel=1e-3)
    assert spine_length(read(path, position_mode="relative")) == pytest.approx(2 * bone, rel=1e-3)


def test_cc3_hip_rooted_root_is_relative_and_stands_on_the_floor():
    path = shared_path("cc3_cmu_02_06_pickup.bvh")
    m = read(path)
    sk = m.skeleton
    assert sk.names[0] == "CC_Base_Hip"
    assert sk.position_modes[0] == "relative"
    assert [n for n, mode in zip(sk.names, sk.position_modes) if mode] == ["CC_Base_Hip"]
    record = parse_bvh_text(path.read_text(), path)
    assert detect_position_modes(record) == {"CC_Base_Hip": "relative"}
    # the OFFSET is added: (105.214226 + Yposition at frame 0) cm
    assert m.root_positions[0, 1] == pytest.approx((105.214226 + record.values[0, 1]) * 0.01)
    pose = forward_kinematics(m.frames(slice(0, 1)))
    assert 0.9 <= pose.positions[0, 0, 1] <= 1.15                  # hip height, metres
    assert -0.05 <= pose.all_positions()[0, :, 1].min() <= 0.15    # lowest point near the floor
    # read the usual way (absolute), the character is about a metre under the floor
    wrong = forward_kinematics(read(path, position_mode="absolute").frames(slice(0, 1)))
    assert wrong.positions[0, 0, 1] < 0.2
    assert wrong.all_positions()[0, :, 1].min() < -0.8


def test_cc3_rl_bone_root_is_absolute_and_hips_stay_at_105_cm():
    path = shared_path("cc3_cmu_02_01_walk.bvh")
    m = read(path)
    sk = m.skeleton
    assert sk.names[0] == "RL_BoneRoot"
    assert sk.position_modes[0] == "absolute"
    hip = sk.index["CC_Base_Hip"]
    assert sk.position_modes[hip] is None                          # rotation-only child
    y = forward_kinematics(m).positions[:, hip, 1]
    np.testing.assert_allclose(y, 1.052, atol=0.002)                # README: constant 105.2 cm


def test_position_mode_mapping_override():
    path = shared_path("cc3_cmu_02_06_pickup.bvh")
    by_name = read_bvh(path, position_mode={"CC_Base_Hip": "absolute"})
    by_str = read(path, position_mode="absolute")
    assert by_name.skeleton.position_modes[0] == "absolute"
    np.testing.assert_array_equal(by_name.translations, by_str.translations)
    with pytest.raises(BVHError, match="no position channels"):
        read_bvh(path, position_mode={"CC_Base_Spine01": "absolute"})
    with pytest.raises(BVHError, match="absolute' or 'relative"):
        read_bvh(path, position_mode="sideways")


# --------------------------------------------------------------------------- rotation orders
def test_cmu_max_mixes_rotation_orders():
    """README: the 12 arm-chain joints use Z X Y, every other joint Z Y X."""
    path = clip_path("cmu_131_01_walk.bvh")
    m = read(path)
    sk = m.skeleton
    arms = {f"{s}{j}" for s in ("Left", "Right") for j in ("Shoulder", "Elbow", "Wrist")}
    arms |= {"lhand", "LFingers", "LThumb", "rhand", "RFingers", "RThumb"}
    for name, order in zip(sk.names, sk.rotation_orders):
        assert order == ("ZXY" if name in arms else "ZYX"), name
    # and each order is applied: R = Rz Rx Ry (intrinsic) for the arm, Rz Ry Rx elsewhere
    values = raw_values(path)
    col = 0
    for j, chans in enumerate(sk.channels):
        if j > 0:                                   # the root also carries the up-axis turn
            angles = values[:, col + len(chans) - 3: col + len(chans)]
            expected = Rotation.from_euler(sk.rotation_orders[j], angles, degrees=True)
            got = Rotation.from_quat(m.rotations[:, j])
            assert np.all((got.inv() * expected).magnitude() < 1e-9), sk.names[j]
        col += len(chans)


def test_fair1_thumbs_use_their_own_order():
    sk = read(clip_path("fair1_child8_jumping.bvh")).skeleton
    orders = dict(zip(sk.names, sk.rotation_orders))
    assert orders.pop("RightHandThumb1") == orders.pop("LeftHandThumb1") == "YXZ"
    assert set(orders.values()) == {"XYZ"}


# --------------------------------------------------------------------------- overrides
def test_units_and_scale_overrides_scale_the_skeleton():
    path = clip_path("cmu_131_01_walk.bvh")
    record = parse_bvh_text(path.read_bytes().decode(), path)
    for options, scale, units in [({"units": "m"}, 1.0, "m"), ({"units": "cm"}, 0.01, "cm"),
                                  ({"units": "in"}, 0.0254, "in"),
                                  ({"scale": 0.5}, 0.5, "custom")]:
        m = read(path, **options)
        assert (m.skeleton.source.units, m.skeleton.source.scale) == (units, scale)
        np.testing.assert_allclose(m.skeleton.offsets[1:], record.offsets[1:] * scale)
        np.testing.assert_allclose(m.root_positions, record.values[:, :3] * scale)
    default = read(path)
    assert stature(read(path, units="m")) == pytest.approx(stature(default) / UNITS["cmu"])


def test_up_axis_override():
    path = clip_path("fair1_child8_jumping.bvh")
    record = parse_bvh_text(path.read_text(), path)
    assert record.channels[0][:3] == ("Xposition", "Yposition", "Zposition")
    z_up = read(path)                                # detected +Z: file Z becomes internal Y
    np.testing.assert_allclose(z_up.root_positions[:, 1], record.values[:, 2] * 0.0254)
    np.testing.assert_allclose(z_up.root_positions[:, 2], -record.values[:, 1] * 0.0254)
    y_up = read(path, up_axis="+Y")                 # told otherwise: file Y stays up
    assert y_up.skeleton.source.up_axis == "+Y"
    np.testing.assert_allclose(y_up.root_positions, record.values[:, :3] * 0.0254)
    assert stature(y_up) < 0.5 * stature(z_up)      # the child now lies on the floor
    given = read(path, units="in", up_axis="+Z")
    assert not given.skeleton.source.detected
    np.testing.assert_array_equal(given.rotations, z_up.rotations)


@pytest.mark.parametrize("options, match", [
    ({"units": "furlong"}, "unknown units"),
    ({"up_axis": "up"}, "unknown up axis"),
    ({"scale": 0.0}, "positive"),
    ({"scale": -1.0}, "positive"),
    ({"scale": float("nan")}, "positive"),
])
def test_bad_overrides_raise_typed_errors(options, match):
    path = clip_path("cmu_rest_tpose.bvh")
    with pytest.raises(BVHError, match=match) as info:
        read_bvh(path, **options)
    assert info.value.path == str(path)


# --------------------------------------------------------------------------- synthetic texts
SMALL = """HIERARCHY
ROOT Hips
{
  OFFSET 1 2 3
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Left Arm
  {
    OFFSET 4 5 6
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 7 8 9
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.5
1 2 3 10 20 30 40 50 60
-1 -2 -3 -10 -20 -30 -40 -50 -60
"""
SMALL_VALUES = [[1, 2, 3, 10, 20, 30, 40, 50, 60], [-1, -2, -3, -10, -20, -30, -40, -50, -60]]


def check_small(record, name="Left Arm"):
    assert record.names == ["Hips", name]
    assert record.parents == [-1, 0]
    assert record.offsets.tolist() == [[1, 2, 3], [4, 5, 6]]
    assert record.channels == [("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation",
                                "Xrotation"), ("Zrotation", "Xrotation", "Yrotation")]
    assert [(p, o.tolist()) for p, o in record.end_sites] == [(1, [7, 8, 9])]
    assert record.frame_time == 0.5
    assert record.values.tolist() == SMALL_VALUES


@pytest.mark.parametrize("variant", [
    "as is", "tabs", "crlf", "bare cr", "no final newline", "blank lines", "brace on name line",
    "brace glued", "lower case channels", "trailing spaces",
])
def test_small_text_variants_parse_to_the_same_values(variant):
    text = {
        "as is": SMALL,
        "tabs": SMALL.replace("  ", "\t").replace(" ", "\t").replace("Left\tArm", "Left Arm"),
        "crlf": SMALL.replace("\n", "\r\n"),
        "bare cr": SMALL.replace("\n", "\r"),
        "no final newline": SMALL.rstrip("\n"),
        "blank lines": SMALL.replace("\n", "\n\n").replace("60\n", "60\n \t \n"),
        "brace on name line": SMALL.replace("Hips\n{", "Hips {").replace("Arm\n  {", "Arm {")
                                   .replace("Site\n    {", "Site {"),
        "brace glued": SMALL.replace("Hips\n{", "Hips{").replace("Arm\n  {", "Arm{")
                            .replace("Site\n    {", "Site{"),
        "lower case channels": SMALL.replace("Zrotation Xrotation Yrotation",
                                             "zrotation XROTATION yRotation")
                                    .replace("Xposition", "xposition"),
        "trailing spaces": SMALL.replace("\n", "  \n"),
    }[variant]
    check_small(parse_bvh_text(text))


def test_tabs_crlf_and_cr_give_the_right_line_numbers():
    for text in (SMALL, SMALL.replace("\n", "\r\n"), SMALL.replace("\n", "\r"),
                 SMALL.replace("  ", "\t")):
        record = parse_bvh_text(text)
        assert record.joint_lines == [2, 6]
        assert record.first_row_line == 19
        bad = text.replace("-40", "x40")
        with pytest.raises(BVHError) as info:
            parse_bvh_text(bad, "small.bvh")
        assert info.value.line == 20


def test_multi_word_joint_names():
    text = SMALL.replace("JOINT Left Arm", "JOINT  Left  Upper   Arm ")
    check_small(parse_bvh_text(text), name="Left Upper Arm")
    motion = parse_bvh(text, units="m")
    assert motion.skeleton.index["Left Upper Arm"] == 1


def test_scientific_notation_everywhere():
    text = (SMALL.replace("OFFSET 4 5 6", "OFFSET 4e0 0.5E+1 600e-2")
            .replace("1 2 3 10 20 30", "1.0e0 2E0 +3e+0 1e1 2.0E1 3e1")
            .replace("-40 -50 -60", "-4.0e+1 -5E1 -0.6e2"))
    check_small(parse_bvh_text(text))


def test_tricky_plain_numbers_in_rows():
    text = SMALL.replace("1 2 3 10 20 30 40 50 60", "+1 2. .5 -0 -0.000000 0.1 1e-3 1E+2 007")
    record = parse_bvh_text(text)
    expected = [float(t) for t in "+1 2. .5 -0 -0.000000 0.1 1e-3 1E+2 007".split()]
    assert np.array_equal(record.values[0].view(np.int64), np.array(expected).view(np.int64))
    assert math.copysign(1, record.values[0, 3]) == -1          # -0 keeps its sign


def test_frame_time_is_kept_exactly():
    record = parse_bvh_text(SMALL.replace("Frame Time: 0.5", "Frame Time:\t0.008342"))
    assert record.frame_time == 0.008342
    motion = parse_bvh(SMALL.replace("Frame Time: 0.5", "Frame Time: .0083333"), units="m")
    assert motion.fps == 1 / 0.0083333


def test_two_rotation_channels():
    text = SMALL.replace("CHANNELS 3 Zrotation Xrotation Yrotation",
                         "CHANNELS 2 Yrotation Xrotation")
    text = text.replace(" 60\n", "\n").replace(" -60\n", "\n")
    record = parse_bvh_text(text)
    assert record.channels[1] == ("Yrotation", "Xrotation")
    assert record.values.tolist() == [row[:8] for row in SMALL_VALUES]
    m = parse_bvh(text, units="m", up_axis="+Y")
    assert m.skeleton.rotation_orders[1] == "YX"
    expected = Rotation.from_euler("YX", [[40, 50], [-40, -50]], degrees=True)
    assert np.all((Rotation.from_quat(m.rotations[:, 1]).inv() * expected).magnitude() < 1e-12)


def test_root_rotation_and_translation_applied():
    m = parse_bvh(SMALL, units="cm", up_axis="+Y")
    np.testing.assert_allclose(m.root_positions, [[0.01, 0.02, 0.03], [-0.01, -0.02, -0.03]])
    expected = Rotation.from_euler("ZYX", [[10, 20, 30], [-10, -20, -30]], degrees=True)
    assert np.all((Rotation.from_quat(m.rotations[:, 0]).inv() * expected).magnitude() < 1e-12)
    np.testing.assert_allclose(m.skeleton.offsets[1], [0.04, 0.05, 0.06])
    np.testing.assert_allclose(m.skeleton.end_sites[0].offset, [0.07, 0.08, 0.09])


NON_ROOT_POSITIONS = """HIERARCHY
ROOT Root
{
\tOFFSET 0 0 0
\tCHANNELS 3 Xposition Yposition Zposition
\tJOINT Hips
\t{
\t\tOFFSET 0 90 0
\t\tCHANNELS 5 Xposition Yposition Zposition Yrotation Xrotation
\t\tJOINT Spine
\t\t{
\t\t\tOFFSET 0 10 0
\t\t\tCHANNELS 1 Yposition
\t\t\tEnd Site
\t\t\t{
\t\t\t\tOFFSET 0 5 0
\t\t\t}
\t\t}
\t}
}
MOTION
Frames: 2
Frame Time: 0.1
0 0 0 1 <hy> 2 30 40 <sy>
5 0 5 3 <hy2> 4 0 0 <sy2>
"""


def non_root(hy, sy, hy2, sy2):
    return (NON_ROOT_POSITIONS.replace("<hy>", str(hy)).replace("<sy>", str(sy))
            .replace("<hy2>", str(hy2)).replace("<sy2>", str(sy2)))


def test_non_root_position_channels_absolute():
    text = non_root(89, 11, 91, 9)
    record = parse_bvh_text(text)
    assert record.channels[1] == ("Xposition", "Yposition", "Zposition", "Yrotation",
                                  "Xrotation")
    assert record.channels[2] == ("Yposition",)
    assert detect_position_modes(record) == {"Root": "absolute", "Hips": "absolute",
                                             "Spine": "absolute"}
    m = parse_bvh(text, units="cm", up_axis="+Y")
    assert list(m.skeleton.translated) == [0, 1, 2]
    np.testing.assert_allclose(m.translations[:, 1], [[0.01, 0.89, 0.02], [0.03, 0.91, 0.04]])
    # Spine has only a Y channel: X and Z stay at its OFFSET (0 and 0)
    np.testing.assert_allclose(m.translations[:, 2], [[0, 0.11, 0], [0, 0.09, 0]])


def test_non_root_position_channels_relative():
    text = non_root(-1, 1, 1, -1)
    record = parse_bvh_text(text)
    assert detect_position_modes(record) == {"Root": "absolute", "Hips": "relative",
                                             "Spine": "relative"}
    m = parse_bvh(text, units="cm", up_axis="+Y")
    np.testing.assert_allclose(m.translations[:, 1], [[0.01, 0.89, 0.02], [0.03, 0.91, 0.04]])
    np.testing.assert_allclose(m.translations[:, 2], [[0, 0.11, 0], [0, 0.09, 0]])
    # a per-joint override wins over detection
    m2 = parse_bvh(text, units="cm", up_axis="+Y", position_mode={"Spine": "absolute"})
    np.testing.assert_allclose(m2.translations[:, 2], [[0, 0.01, 0], [0, -0.01, 0]])
    np.testing.assert_allclose(m2.translations[:, 1], m.translations[:, 1])


@pytest.mark.parametrize("how", ["CHANNELS 0", "no CHANNELS line"])
def test_joint_without_channels(how):
    replacement = "CHANNELS 0" if how == "CHANNELS 0" else ""
    text = SMALL.replace("CHANNELS 3 Zrotation Xrotation Yrotation", replacement)
    text = text.replace(" 40 50 60", "").replace(" -40 -50 -60", "")
    record = parse_bvh_text(text)
    assert record.channels[1] == ()
    assert record.values.tolist() == [row[:6] for row in SMALL_VALUES]
    m = parse_bvh(text, units="m", up_axis="+Y")
    np.testing.assert_allclose(m.rotations[:, 1], [[0, 0, 0, 1]] * 2)
    assert list(m.skeleton.translated) == [0]
    np.testing.assert_allclose(m.local_translations()[:, 1], [[4, 5, 6]] * 2)


def test_no_channels_at_all_reads_empty_rows():
    text = (SMALL.replace("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 0")
            .replace("CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation",
                     "CHANNELS 0"))
    rows = "1 2 3 10 20 30 40 50 60\n-1 -2 -3 -10 -20 -30 -40 -50 -60\n"
    record = parse_bvh_text(text.replace(rows, "\n\n"))
    assert record.values.shape == (2, 0)
    m = parse_bvh(text.replace(rows, "\n\n"), units="m", up_axis="+Y")
    assert m.num_frames == 2
    with pytest.raises(BVHError, match="no channels") as info:
        parse_bvh_text(text.replace(rows, "\n1\n"), "none.bvh")
    assert info.value.line == 20


# --------------------------------------------------------------------------- the fast number parser
@pytest.mark.parametrize("spec", _params())
def test_fast_number_parser_is_bit_identical_to_float_on_real_files(spec):
    path, _ = _resolve(spec)
    rows, columns = raw_motion_block(path)
    parsed = parse_number_rows("\n".join(rows).encode(), columns)
    assert parsed is not None                       # real files stay on the fast path
    values, n = parsed
    expected = raw_values(path)
    assert n == expected.shape[0]
    assert np.array_equal(values.view(np.int64), expected.view(np.int64))


TRICKY = ["-0", ".5", "5.", "+3", "1e-3", "1E+2", "-0.000000", "0", "+0", "-.5", "+.5", "007",
          "123456789012345", "-123456789012345", "0.12345678901234", "-9.99999999999999",
          "12345678.9012345", ".123456789012345", "99999999999999.9", "0.00000000000001",
          "1e-320", "-1.7976931348623157e308", "4.9e-324", "2.2250738585072014e-308",
          "0.1", "0.2", "0.3", "1.1", "2.675", "9007199254740993e0", "-6.4e-05"]


@pytest.mark.parametrize("token", TRICKY)
def test_fast_number_parser_tricky_tokens(token):
    parsed = parse_number_rows(f"{token} 1\n".encode(), 2)
    assert parsed is not None
    got = parsed[0][0, 0]
    assert np.float64(got).view(np.int64) == np.float64(float(token)).view(np.int64)


@pytest.mark.parametrize("block, columns", [
    ("nan 1", 2), ("inf 1", 2), ("-inf 1", 2), ("1e400 1", 2), ("abc 1", 2), ("1.2.3 1", 2),
    ("1-2 1", 2), ("--1 1", 2), ("+-1 1", 2), ("- 1", 2), (". 1", 2), ("e5 1", 2), ("1e 1", 2),
    ("1e+ 1", 2), ("0x10 1", 2), ("1,5 1", 2), ("1 2 3", 2), ("1", 2), ("1 2\n3", 2),
    ("1 2\n3 4 5", 2), ("1\x002", 1), ("1 2\x01", 2), ("\xb2 1", 2), ("1d5 1", 2),
    ("1" * 30 + " 1", 2),
])
def test_fast_number_parser_refuses(block, columns):
    assert parse_number_rows(block.encode("latin-1"), columns) is None


@pytest.mark.parametrize("shift", range(13))
def test_fast_number_parser_measures_long_tokens_wherever_they_sit(shift):
    """Tokens up to 24 characters are taken and longer ones refused, at every position
    against the 12-byte blocks that are looked at first, within a block and at its end."""
    for width in (8, 11, 12, 14, 15, 16, 23, 24, 25, 26, 40):
        token = "1" + "0" * (width - 3) + ".5"
        for block in (f"{' ' * shift}1 {token}\n" + "2 3\n" * 20,
                      "2 3\n" * 20 + f"{' ' * shift}1 {token}",
                      "2 3\n" * 20 + f"{' ' * shift}{token} 1\n"):
            parsed = parse_number_rows(block.encode(), 2)
            if width <= 24:
                assert parsed is not None and float(token) in parsed[0]
            else:
                assert parsed is None, (width, block)


def test_fast_number_parser_counts_rows_and_skips_blank_lines():
    values, rows = parse_number_rows(b"\n1 2\n\n \t\n3 4\r\n5 6", 2)
    assert rows == 3
    assert values.tolist() == [[1, 2], [3, 4], [5, 6]]
    values, rows = parse_number_rows(b"  \n\n", 3)
    assert rows == 0 and values.shape == (0, 3)


_plain = st.builds(
    lambda sign, whole, dot, frac: sign + whole + dot + frac,
    st.sampled_from(["", "-", "+"]), st.text("0123456789", max_size=8),
    st.sampled_from(["", "."]), st.text("0123456789", max_size=7),
).filter(lambda t: any(c.isdigit() for c in t))
_expo = st.builds(lambda m, e, x: m + e + x, _plain,
                  st.sampled_from(["e", "E", "e-", "E+", "e+"]),
                  st.integers(0, 400).map(str))


@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(st.lists(st.one_of(_plain, _expo), min_size=1, max_size=12))
def test_fast_number_parser_matches_float_on_generated_tokens(tokens):
    expected = []
    for t in tokens:
        try:
            expected.append(float(t))
        except ValueError:
            expected.append(None)
    parsed = parse_number_rows(" ".join(tokens).encode(), len(tokens))
    if any(v is None or not math.isfinite(v) for v in expected):
        assert parsed is None
        return
    plain = all("e" not in t.lower() and sum(c.isdigit() for c in t) <= 15 for t in tokens)
    if plain:
        assert parsed is not None                     # the common case must stay fast
    if parsed is not None:
        got = parsed[0][0]
        assert np.array_equal(got.view(np.int64), np.array(expected).view(np.int64))
