"""Fingers map thumb to thumb and index to index on every finger naming convention.

Each convention's finger joints are written out literally (:data:`LEFT_FINGERS`, from the
files' joint lists in ``../shared/data/README.md`` and the exporters' documented skeletons);
every ordered pair of conventions is auto-mapped and its finger pairs must be exactly those
that join the two tables by role. The conventions and the real files they come from:

* ``MIXAMO``: ``target_mixamo_ely.glb`` (Mixamo's auto-rigger, ``mixamorig:LeftHandThumb1``
  ... ``Thumb4``, the 4 a tip joint).
* ``ROKOKO``: ``rokoko_mixamo_jesse_dance.bvh`` (Rokoko Video's Mixamo preset, with
  ``LeftInHandIndex`` metacarpals; its hand lists the pinky before the ring finger).
* ``CC3``: ``cc3_cmu_02_01_walk.bvh`` (iClone's CC3 export, ``CC_Base_L_Thumb1``, ``Mid``).
* ``CMU``: ``cmu_mb_01_01_jumps.bvh`` (cgspeed's CMU conversion: a thumb ``LThumb`` and an
  unspecified ``LeftFingerBase > LFingers``, which takes no finger role).
* ``MAKEHUMAN``: the Rokoko file with its arms and hands renamed to MakeHuman 1.1's default
  skeleton as its BVH exporter writes it (``clavicle.L``, ``upperarm01.L``,
  ``lowerarm01.L``, ``wrist.L``, ``finger1-1.L`` the thumb ... ``finger5-3.L``,
  ``metacarpal1.L`` ... ``metacarpal4.L`` before the index ... little finger: the same
  topology as Rokoko's hand, a metacarpal per finger and none for the thumb).
* ``UNREAL``: the Rokoko file with every joint renamed to Unreal Engine 5's Manny skeleton as
  its FBX export names it (``pelvis``, ``spine_01``, ``clavicle_l``, ``hand_l``,
  ``index_metacarpal_l``, ``index_01_l`` ... ``thumb_03_l``).
* ``UNNAMED-GLTF``: ``target_mixamo_ely.glb`` with every node name removed (a glTF written by a
  converter that drops names: the reader calls them ``joint_<node>``): fingers by geometry.
"""
from __future__ import annotations

import json
import re
import struct

import pytest

from conftest import shared_path
from motion_composer.engine.conversion.automap import automap, identify, parse_name
from motion_composer.engine.formats.bvh import read_bvh
from motion_composer.engine.formats.gltf import read_gltf
from motion_composer.engine.kinematics import forward_kinematics

ROKOKO = "rokoko_mixamo_jesse_dance.bvh"
ELY = "target_mixamo_ely.glb"

_ROKOKO_TO_MAKEHUMAN = {
    "Shoulder": "clavicle", "Arm": "upperarm01", "ForeArm": "lowerarm01", "Hand": "wrist",
    "HandThumb1": "finger1-1", "HandThumb2": "finger1-2", "HandThumb3": "finger1-3",
    **{f"InHand{f}": f"metacarpal{k}" for k, f in enumerate(("Index", "Middle", "Ring",
                                                             "Pinky"), start=1)},
    **{f"Hand{f}{n}": f"finger{k}-{n}" for k, f in enumerate(("Index", "Middle", "Ring",
                                                             "Pinky"), start=2)
       for n in (1, 2, 3)},
}
_ROKOKO_TO_UNREAL = {
    "Shoulder": "clavicle", "Arm": "upperarm", "ForeArm": "lowerarm", "Hand": "hand",
    "UpLeg": "thigh", "Leg": "calf", "Foot": "foot", "ToeBase": "ball",
    **{f"InHand{f}": f"{f.lower()}_metacarpal" for f in ("Index", "Middle", "Ring", "Pinky")},
    **{f"Hand{f}{n}": f"{f.lower()}_0{n}" for f in ("Thumb", "Index", "Middle", "Ring",
                                                    "Pinky") for n in (1, 2, 3)},
}
_UNREAL_TRUNK = {"Hips": "pelvis", "Spine": "spine_01", "Spine1": "spine_02",
                 "Spine2": "spine_03", "Neck": "neck_01", "Head": "head"}


def _makehuman(name: str) -> str:
    m = re.fullmatch(r"(Left|Right)(\w+)", name)
    if m and m.group(2) in _ROKOKO_TO_MAKEHUMAN:
        return f"{_ROKOKO_TO_MAKEHUMAN[m.group(2)]}.{m.group(1)[0]}"
    return name


def _unreal(name: str) -> str:
    m = re.fullmatch(r"(Left|Right)(\w+)", name)
    if m and m.group(2) in _ROKOKO_TO_UNREAL:
        return f"{_ROKOKO_TO_UNREAL[m.group(2)]}_{m.group(1)[0].lower()}"
    return _UNREAL_TRUNK.get(name, name)


#: convention -> left-hand finger role -> joint, written out (right: :func:`_right`)
LEFT_FINGERS = {
    "MIXAMO": {f"{f.lower()}{n}": f"mixamorig:LeftHand{f}{n}"
               for f in ("Thumb", "Index", "Middle", "Ring", "Pinky") for n in (1, 2, 3, 4)},
    "ROKOKO": {
        "thumb1": "LeftHandThumb1", "thumb2": "LeftHandThumb2", "thumb3": "LeftHandThumb3",
        "index0": "LeftInHandIndex", "index1": "LeftHandIndex1", "index2": "LeftHandIndex2",
        "index3": "LeftHandIndex3",
        "middle0": "LeftInHandMiddle", "middle1": "LeftHandMiddle1",
        "middle2": "LeftHandMiddle2", "middle3": "LeftHandMiddle3",
        "ring0": "LeftInHandRing", "ring1": "LeftHandRing1", "ring2": "LeftHandRing2",
        "ring3": "LeftHandRing3",
        "pinky0": "LeftInHandPinky", "pinky1": "LeftHandPinky1", "pinky2": "LeftHandPinky2",
        "pinky3": "LeftHandPinky3"},
    "CC3": {
        "thumb1": "CC_Base_L_Thumb1", "thumb2": "CC_Base_L_Thumb2", "thumb3": "CC_Base_L_Thumb3",
        "index1": "CC_Base_L_Index1", "index2": "CC_Base_L_Index2", "index3": "CC_Base_L_Index3",
        "middle1": "CC_Base_L_Mid1", "middle2": "CC_Base_L_Mid2", "middle3": "CC_Base_L_Mid3",
        "ring1": "CC_Base_L_Ring1", "ring2": "CC_Base_L_Ring2", "ring3": "CC_Base_L_Ring3",
        "pinky1": "CC_Base_L_Pinky1", "pinky2": "CC_Base_L_Pinky2",
        "pinky3": "CC_Base_L_Pinky3"},
    "CMU": {"thumb1": "LThumb"},
    "MAKEHUMAN": {
        "thumb1": "finger1-1.L", "thumb2": "finger1-2.L", "thumb3": "finger1-3.L",
        "index0": "metacarpal1.L", "index1": "finger2-1.L", "index2": "finger2-2.L",
        "index3": "finger2-3.L",
        "middle0": "metacarpal2.L", "middle1": "finger3-1.L", "middle2": "finger3-2.L",
        "middle3": "finger3-3.L",
        "ring0": "metacarpal3.L", "ring1": "finger4-1.L", "ring2": "finger4-2.L",
        "ring3": "finger4-3.L",
        "pinky0": "metacarpal4.L", "pinky1": "finger5-1.L", "pinky2": "finger5-2.L",
        "pinky3": "finger5-3.L"},
    "UNREAL": {
        "thumb1": "thumb_01_l", "thumb2": "thumb_02_l", "thumb3": "thumb_03_l",
        "index0": "index_metacarpal_l", "index1": "index_01_l", "index2": "index_02_l",
        "index3": "index_03_l",
        "middle0": "middle_metacarpal_l", "middle1": "middle_01_l", "middle2": "middle_02_l",
        "middle3": "middle_03_l",
        "ring0": "ring_metacarpal_l", "ring1": "ring_01_l", "ring2": "ring_02_l",
        "ring3": "ring_03_l",
        "pinky0": "pinky_metacarpal_l", "pinky1": "pinky_01_l", "pinky2": "pinky_02_l",
        "pinky3": "pinky_03_l"},
}
CONVENTIONS = tuple(LEFT_FINGERS) + ("UNNAMED-GLTF",)


def _right(name: str) -> str:
    """The right-hand joint of a left-hand name in these conventions."""
    for left, right in (("Left", "Right"), ("_L_", "_R_"), (".L", ".R"), ("LThumb", "RThumb")):
        if left in name:
            return name.replace(left, right)
    return re.sub(r"_l$", "_r", name)


def _renamed_bvh(tmp_dir, source: str, rename) -> str:
    """A copy of a real BVH file with its joints renamed."""
    text = shared_path(source).read_text(encoding="utf-8")
    text = re.sub(r"^(\s*(?:ROOT|JOINT)\s+)(\S+)", lambda m: m.group(1) + rename(m.group(2)),
                  text, flags=re.M)
    path = tmp_dir / f"{rename.__name__.strip('_')}.bvh"
    path.write_text(text, encoding="utf-8")
    return path


def _unnamed_glb(tmp_dir, source: str):
    """A copy of a real GLB file with every node name removed, and old name -> the name the
    reader gives the unnamed node (``joint_<node index>``)."""
    data = shared_path(source).read_bytes()
    jlen, = struct.unpack_from("<I", data, 12)
    js = json.loads(data[20:20 + jlen])
    names = {}
    for k, node in enumerate(js["nodes"]):
        if "name" in node:
            names[node.pop("name")] = f"joint_{k}"
    text = json.dumps(js).encode()
    text += b" " * (-len(text) % 4)
    rest = data[20 + jlen:]
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + rest
    path = tmp_dir / "unnamed.glb"
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)
    return path, names


@pytest.fixture(scope="module")
def hands(tmp_path_factory):
    """convention -> (skeleton, reference positions or None, role -> joint, both sides)."""
    tmp = tmp_path_factory.mktemp("hands")
    out = {}

    def bvh(path):
        motion = read_bvh(path)
        return motion.skeleton, forward_kinematics(motion.frames(slice(0, 1))).positions[0]

    sources = {"MIXAMO": (read_gltf(shared_path(ELY)).skeleton, None),
               "ROKOKO": bvh(shared_path(ROKOKO)),
               "CC3": bvh(shared_path("cc3_cmu_02_01_walk.bvh")),
               "CMU": bvh(shared_path("cmu_mb_01_01_jumps.bvh")),
               "MAKEHUMAN": bvh(_renamed_bvh(tmp, ROKOKO, _makehuman)),
               "UNREAL": bvh(_renamed_bvh(tmp, ROKOKO, _unreal))}
    for conv, (skeleton, positions) in sources.items():
        table = {f"{r}_l": j for r, j in LEFT_FINGERS[conv].items()}
        table.update({f"{r}_r": _right(j) for r, j in LEFT_FINGERS[conv].items()})
        assert set(table.values()) <= set(skeleton.names), conv
        out[conv] = skeleton, positions, table
    # the unnamed copy: the same joints as MIXAMO, called by their node index
    path, node_of = _unnamed_glb(tmp, ELY)
    skeleton = read_gltf(path).skeleton
    out["UNNAMED-GLTF"] = skeleton, None, {r: node_of[j] for r, j in out["MIXAMO"][2].items()}
    return out


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_identify_finds_every_finger_joint(hands, convention):
    skeleton, positions, table = hands[convention]
    roles = identify(skeleton, positions)
    found = {k: v for k, v in roles.items()
             if re.fullmatch(r"(thumb|index|middle|ring|pinky)\d_[lr]", k)}
    assert found == table


@pytest.mark.parametrize("performer", CONVENTIONS)
@pytest.mark.parametrize("target", CONVENTIONS)
def test_fingers_map_role_to_role_on_every_pair(hands, target, performer):
    t_sk, t_pos, t_table = hands[target]
    p_sk, p_pos, p_table = hands[performer]
    corr = automap(t_sk, p_sk, target_positions=t_pos, performer_positions=p_pos)
    fingers = set(t_table.values())
    got = {t: p for t, p in corr.pairs.items() if t in fingers}
    expected = {joint: p_table[role] for role, joint in t_table.items() if role in p_table}
    assert got == expected


def test_makehuman_thumb_maps_to_thumb_not_index(hands):
    """The bug of issue 13: MakeHuman's ``finger1`` was read as 3ds Max Biped's ``Finger1``
    (Biped counts from ``Finger0``, the thumb), so every finger mapped one over."""
    corr = automap(hands["MAKEHUMAN"][0], hands["MIXAMO"][0])
    assert {t: corr.pairs.get(t) for t in ("finger1-1.L", "finger1-3.L", "finger2-1.L",
                                           "finger3-2.L", "finger4-3.L", "finger5-1.R",
                                           "metacarpal1.L")} == {
        "finger1-1.L": "mixamorig:LeftHandThumb1", "finger1-3.L": "mixamorig:LeftHandThumb3",
        "finger2-1.L": "mixamorig:LeftHandIndex1", "finger3-2.L": "mixamorig:LeftHandMiddle2",
        "finger4-3.L": "mixamorig:LeftHandRing3", "finger5-1.R": "mixamorig:RightHandPinky1",
        "metacarpal1.L": None}                      # Mixamo has no metacarpals
    corr = automap(hands["UNREAL"][0], hands["MAKEHUMAN"][0])
    assert {t: corr.pairs[t] for t in ("thumb_01_l", "index_metacarpal_l", "index_01_l",
                                       "pinky_03_r")} == {
        "thumb_01_l": "finger1-1.L", "index_metacarpal_l": "metacarpal1.L",
        "index_01_l": "finger2-1.L", "pinky_03_r": "finger5-3.R"}
    corr = automap(hands["CC3"][0], hands["MAKEHUMAN"][0])
    assert {t: corr.pairs[t] for t in ("CC_Base_L_Thumb1", "CC_Base_L_Index1", "CC_Base_R_Mid2",
                                       "CC_Base_R_Pinky3")} == {
        "CC_Base_L_Thumb1": "finger1-1.L", "CC_Base_L_Index1": "finger2-1.L",
        "CC_Base_R_Mid2": "finger3-2.R", "CC_Base_R_Pinky3": "finger5-3.R"}


@pytest.mark.parametrize("name, finger, number, metacarpal", [
    ("finger1-1.L", "thumb", 1, False),         # MakeHuman: finger1 is the thumb
    ("finger2-3.R", "index", 3, False),
    ("finger5-2.L", "pinky", 2, False),
    ("metacarpal1.L", "index", 1, True),        # MakeHuman: metacarpal1 is the index's
    ("metacarpal4.R", "pinky", 4, True),
    ("Bip01 L Finger0", "thumb", 1, False),     # 3ds Max Biped: Finger0 is the thumb
    ("Bip01 L Finger12", "index", 3, False),
    ("thumb_01_l", "thumb", 1, False),          # Unreal
    ("pinky_metacarpal_r", "pinky", None, True),
])
def test_finger_names(name, finger, number, metacarpal):
    info = parse_name(name)
    assert info.finger == finger and info.metacarpal == metacarpal
    if number is not None:
        assert info.numbers == (number,)
