"""Automatic mapping: role identification and role-to-role correspondence on every convention.

The expected joints per convention (:data:`EXPECTED`) are written from ``../shared/data/README.md``
(and, for RobotExpressive, from its glTF node hierarchy), not from the code's output. Every
ordered pair of conventions is mapped and checked against them.
"""
from __future__ import annotations

import ast
import dataclasses
import json
import struct
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from motion_composer.engine.conversion.automap import Roles, automap, identify, parse_name
from motion_composer.engine.formats.bvh import read_bvh
from motion_composer.engine.conversion.correspondence import Correspondence
from motion_composer.engine.errors import MappingError
from motion_composer.engine.kinematics import forward_kinematics
from motion_composer.engine.skeleton import EndSite, Skeleton
from conftest import REPO, SHARED_BVH, clip_path, shared_path

SIDED = ("upper_arm", "forearm", "hand", "thigh", "shin", "foot")
#: the roles every mapping must get right wherever both skeletons have them
REQUIRED = ("hips", "spine_first", "chest", "head") + tuple(
    f"{r}_{s}" for r in SIDED for s in "lr")


def _sided(**pairs):
    """``upper_arm=("LeftArm", "RightArm")`` -> ``{"upper_arm_l": "LeftArm", ...}``."""
    out = {}
    for role, (left, right) in pairs.items():
        if left is not None:
            out[f"{role}_l"] = left
        if right is not None:
            out[f"{role}_r"] = right
    return out


_CMU_MB = dict(
    hips="Hips", spine_first="LowerBack", chest="Spine1", head="Head",
    **_sided(upper_arm=("LeftArm", "RightArm"), forearm=("LeftForeArm", "RightForeArm"),
             hand=("LeftHand", "RightHand"), thigh=("LeftUpLeg", "RightUpLeg"),
             shin=("LeftLeg", "RightLeg"), foot=("LeftFoot", "RightFoot")))
_BANDAI = dict(
    hips="Hips", spine_first="Spine", chest="Chest", head="Head",
    **_sided(upper_arm=("UpperArm_L", "UpperArm_R"), forearm=("LowerArm_L", "LowerArm_R"),
             hand=("Hand_L", "Hand_R"), thigh=("UpperLeg_L", "UpperLeg_R"),
             shin=("LowerLeg_L", "LowerLeg_R"), foot=("Foot_L", "Foot_R")))
_CMU_MAX = dict(
    # LeftShoulder is the UPPER ARM here (LeftCollar the clavicle), LeftHip the thigh
    hips="Hips", spine_first="lowerback", chest="Chest2", head="Head",
    **_sided(upper_arm=("LeftShoulder", "RightShoulder"),
             forearm=("LeftElbow", "RightElbow"), hand=("LeftWrist", "RightWrist"),
             thigh=("LeftHip", "RightHip"), shin=("LeftKnee", "RightKnee"),
             foot=("LeftAnkle", "RightAnkle")))
_FAIR1 = dict(
    hips="Hips", spine_first="Spine", chest="Spine3", head="Head",
    **{k: v for k, v in _CMU_MB.items() if k[-2:] in ("_l", "_r")})
_ROKOKO = dict(
    hips="Hips", spine_first="Spine", chest="Spine2", head="Head",
    **{k: v for k, v in _CMU_MB.items() if k[-2:] in ("_l", "_r")})
_CC3 = dict(
    # CC_Base_Hip carries the Waist (spine) and CC_Base_Pelvis (both legs)
    hips="CC_Base_Hip", spine_first="CC_Base_Waist", chest="CC_Base_Spine02",
    head="CC_Base_Head",
    **_sided(upper_arm=("CC_Base_L_Upperarm", "CC_Base_R_Upperarm"),
             forearm=("CC_Base_L_Forearm", "CC_Base_R_Forearm"),
             hand=("CC_Base_L_Hand", "CC_Base_R_Hand"),
             thigh=("CC_Base_L_Thigh", "CC_Base_R_Thigh"),
             shin=("CC_Base_L_Calf", "CC_Base_R_Calf"),
             foot=("CC_Base_L_Foot", "CC_Base_R_Foot")))
_ROBOT = dict(
    # Bone (ground root) > Body > {Hips > Abdomen > Torso_1 > {Neck > Head, arms}; legs}:
    # the legs hang from Body, so Body is the pelvis; the joint named "Hips" turns only the
    # upper body (the spine's first joint). The hand is Palm2L (the middle finger's palm,
    # one of three palms at the wrist); legs end at the knee (FootL/FootR are IK bones on
    # the root), so there is no foot.
    hips="Body", spine_first="Hips", chest="Torso_1", head="Head",
    **_sided(upper_arm=("UpperArmL", "UpperArmR"), forearm=("LowerArmL", "LowerArmR"),
             hand=("Palm2L", "Palm2R"), thigh=("UpperLegL", "UpperLegR"),
             shin=("LowerLegL", "LowerLegR")))
_UNREAL = dict(
    hips="pelvis", spine_first="spine_01", chest="spine_03", head="head",
    **_sided(upper_arm=("upperarm_l", "upperarm_r"), forearm=("lowerarm_l", "lowerarm_r"),
             hand=("hand_l", "hand_r"), thigh=("thigh_l", "thigh_r"),
             shin=("calf_l", "calf_r"), foot=("foot_l", "foot_r")))
_UNITY = dict(
    hips="Hips", spine_first="Spine", chest="UpperChest", head="Head",
    **_sided(upper_arm=("LeftUpperArm", "RightUpperArm"),
             forearm=("LeftLowerArm", "RightLowerArm"), hand=("LeftHand", "RightHand"),
             thigh=("LeftUpperLeg", "RightUpperLeg"), shin=("LeftLowerLeg", "RightLowerLeg"),
             foot=("LeftFoot", "RightFoot")))

_DAZ = dict(
    # hip > pelvis > legs; hip > abdomenLower ... chestUpper > neckLower > neckUpper > head;
    # each limb bone a Bend joint with a Twist joint below it (Genesis 3 and 8)
    hips="hip", spine_first="abdomenLower", chest="chestUpper", head="head",
    **_sided(upper_arm=("lShldrBend", "rShldrBend"), forearm=("lForearmBend", "rForearmBend"),
             hand=("lHand", "rHand"), thigh=("lThighBend", "rThighBend"),
             shin=("lShin", "rShin"), foot=("lFoot", "rFoot")))
_MOTIVE = dict(
    hips="Hip", spine_first="Ab", chest="Chest", head="Head",
    **_sided(upper_arm=("LUArm", "RUArm"), forearm=("LFArm", "RFArm"), hand=("LHand", "RHand"),
             thigh=("LThigh", "RThigh"), shin=("LShin", "RShin"), foot=("LFoot", "RFoot")))

#: convention -> (source, expected role -> joint name). Sources: ("shared", file),
#: ("bundled", file), ("glb", file), ("synthetic", kind), ("unnamed", inner source, frame).
CONVENTIONS = {
    "CMU-MB": (("shared", "cmu_mb_01_01_jumps.bvh"), _CMU_MB),
    "CMU-MAX": (("shared", "cmu_max_131_01_walk.bvh"), _CMU_MAX),
    "CMU-HOLDEN": (("shared", "cmu_xia_angry_13_000_run.bvh"), _CMU_MB),
    "CMU-HOLDEN-rest": (("shared", "target_cmu_mb_rest_tpose.bvh"), _CMU_MB),
    "BANDAI": (("shared", "bandai1_walk_normal_001.bvh"), _BANDAI),
    "FAIR1": (("shared", "fair1_child8_jumping.bvh"), _FAIR1),
    "ROKOKO-MIXAMO": (("shared", "rokoko_mixamo_jesse_dance.bvh"), _ROKOKO),
    "CC3-HIPROOT": (("shared", "cc3_cmu_02_06_pickup.bvh"), _CC3),
    "CC3-RLROOT": (("shared", "cc3_cmu_02_01_walk.bvh"), _CC3),
    "ROBOT": (("glb", "target_robot_expressive.glb"), _ROBOT),
    "UNREAL": (("synthetic", "unreal"), _UNREAL),
    "UNITY": (("synthetic", "unity"), _UNITY),
    "DAZ": (("synthetic", "daz"), _DAZ),
    "MOTIVE": (("synthetic", "motive"), _MOTIVE),
    "UNNAMED-CMU-MB": (("unnamed", ("shared", "cmu_mb_01_01_jumps.bvh"), 300), _CMU_MB),
    "UNNAMED-BANDAI": (("unnamed", ("shared", "bandai1_walk_normal_001.bvh"), 50), _BANDAI),
    "bundled-CMU-MAX": (("bundled", "cmu_131_01_walk.bvh"), _CMU_MAX),
    "bundled-FAIR1": (("bundled", "fair1_child8_jumping.bvh"), _FAIR1),
    "bundled-CMU-rest": (("bundled", "cmu_rest_tpose.bvh"), _CMU_MB),
    "UNNAMED-bundled-CMU-MAX": (("unnamed", ("bundled", "cmu_131_01_walk.bvh"), 400), _CMU_MAX),
    "UNNAMED-bundled-FAIR1": (("unnamed", ("bundled", "fair1_child8_jumping.bvh"), 200),
                              _FAIR1),
}


# --------------------------------------------------------------------------- loaders
def read_glb_skeleton(path) -> tuple[Skeleton, np.ndarray]:
    """A skeleton from a binary glTF's first skin, and its joints' world positions in the
    default node pose.

    Reads the JSON chunk (12-byte header, then chunk length and type ``JSON``), keeps the
    skin's joints and their ancestors up to their common root, parents before children;
    offsets are node translations; ``*_end`` child nodes become End Sites. Positions come from
    the nodes' translation, rotation and scale composed from the scene root.
    """
    data = Path(path).read_bytes()
    magic, _version, _length = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF"
    chunk_len, chunk_type = struct.unpack_from("<I4s", data, 12)
    assert chunk_type == b"JSON"
    gltf = json.loads(data[20:20 + chunk_len])
    nodes = gltf["nodes"]
    parent = {c: i for i, n in enumerate(nodes) for c in n.get("children", [])}

    def local(i):
        node = nodes[i]
        if "matrix" in node:
            return np.array(node["matrix"], float).reshape(4, 4).T
        m = np.eye(4)
        m[:3, :3] = (Rotation.from_quat(node.get("rotation", [0, 0, 0, 1])).as_matrix() *
                     np.array(node.get("scale", [1, 1, 1]), float))
        m[:3, 3] = node.get("translation", [0, 0, 0])
        return m

    def up(i):
        out = [i]
        while out[-1] in parent:
            out.append(parent[out[-1]])
        return out

    def world(i):
        m = np.eye(4)
        for a in up(i):
            m = local(a) @ m
        return m

    joints = gltf["skins"][0]["joints"]
    common = set(up(joints[0]))
    for j in joints[1:]:
        common &= set(up(j))
    root = max(common, key=lambda k: len(up(k)))
    keep = set()
    for j in joints:
        for a in up(j):
            keep.add(a)
            if a == root:
                break
    order: list[int] = []
    stack = [root]
    while stack:
        i = stack.pop()
        order.append(i)
        stack.extend(reversed([c for c in nodes[i].get("children", []) if c in keep]))
    index = {n: k for k, n in enumerate(order)}
    names = [nodes[i].get("name", f"node{i}") for i in order]
    parents = [-1] + [index[parent[i]] for i in order[1:]]
    offsets = np.array([nodes[i].get("translation", [0, 0, 0]) for i in order], float)
    channels = ([("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")]
                + [("Zrotation", "Xrotation", "Yrotation")] * (len(order) - 1))
    ends = [EndSite(index[i], nodes[c].get("translation", [0, 0, 0]), nodes[c]["name"])
            for i in order for c in nodes[i].get("children", [])
            if c not in keep and nodes[c].get("name", "").endswith("_end")]
    skeleton = Skeleton(names=names, parents=parents, offsets=offsets, channels=channels,
                        end_sites=ends)
    return skeleton, np.array([world(i)[:3, 3] for i in order])


def build_skeleton(spec, moving=("root",)) -> Skeleton:
    """A skeleton from ``[(name, parent name or None, (x, y, z) offset [m]), ...]``."""
    names = [s[0] for s in spec]
    index = {n: k for k, n in enumerate(names)}
    return Skeleton(
        names=names, parents=[-1 if p is None else index[p] for _, p, _ in spec],
        offsets=[o for _, _, o in spec],
        channels=[("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation",
                   "Yrotation") if (p is None or n in moving) else
                  ("Zrotation", "Xrotation", "Yrotation") for n, p, _ in spec])


def _mirror(spec, left, right):
    """Add the right side of ``spec``'s left-side entries (x mirrored, names swapped)."""
    out = list(spec)
    for name, parent, (x, y, z) in spec:
        if left in name:
            out.append((name.replace(left, right),
                        parent.replace(left, right) if parent and left in parent else parent,
                        (-x, y, z)))
    return out


def _fingers(hand: str, fingers: tuple, name, thumb_base: float = 0.09) -> list:
    """Three joints per finger under ``hand`` (left side, x along the arm): ``fingers`` the
    five names from the thumb, ``name(finger, k)`` the k-th joint's name (k = 1, 2, 3)."""
    spec = []
    for finger, z in zip(fingers, (0.03, 0.02, 0.0, -0.02, -0.04)):
        base = thumb_base if finger == fingers[0] else 0.09
        spec += [(name(finger, 1), hand, (base, 0, z)),
                 (name(finger, 2), name(finger, 1), (0.04, 0, 0)),
                 (name(finger, 3), name(finger, 2), (0.03, 0, 0))]
    return spec


def unreal_mannequin() -> Skeleton:
    """The UE4 mannequin's names (T-pose, facing +Z, left at +X), with its twist and IK bones."""
    spec = [("root", None, (0, 0, 0)), ("pelvis", "root", (0, 0.95, 0)),
            ("spine_01", "pelvis", (0, 0.10, 0)), ("spine_02", "spine_01", (0, 0.12, 0)),
            ("spine_03", "spine_02", (0, 0.14, 0)), ("neck_01", "spine_03", (0, 0.15, 0)),
            ("head", "neck_01", (0, 0.10, 0.02)),
            ("ik_foot_root", "root", (0, 0, 0)), ("ik_hand_root", "root", (0, 0, 0)),
            ("ik_hand_gun", "ik_hand_root", (-0.5, 1.2, 0.1))]
    left = [("clavicle_l", "spine_03", (0.03, 0.08, 0)),
            ("upperarm_l", "clavicle_l", (0.15, 0, 0)),
            ("upperarm_twist_01_l", "upperarm_l", (0.14, 0, 0)),
            ("lowerarm_l", "upperarm_l", (0.28, 0, 0)),
            ("lowerarm_twist_01_l", "lowerarm_l", (0.12, 0, 0)),
            ("hand_l", "lowerarm_l", (0.25, 0, 0))]
    left += _fingers("hand_l", ("thumb", "index", "middle", "ring", "pinky"),
                     lambda f, k: f"{f}_0{k}_l", thumb_base=0.03)
    left += [("thigh_l", "pelvis", (0.09, -0.05, 0)),
             ("thigh_twist_01_l", "thigh_l", (0, -0.2, 0)),
             ("calf_l", "thigh_l", (0, -0.42, 0)),
             ("calf_twist_01_l", "calf_l", (0, -0.2, 0)),
             ("foot_l", "calf_l", (0, -0.42, 0)), ("ball_l", "foot_l", (0, -0.06, 0.13)),
             ("ik_foot_l", "ik_foot_root", (0.09, 0.1, 0)),
             ("ik_hand_l", "ik_hand_gun", (1.0, 0, 0))]
    return build_skeleton(_mirror(spec + left, "_l", "_r"), moving=("root", "pelvis"))


def unity_humanoid() -> Skeleton:
    """Unity's HumanBodyBones names (T-pose, facing +Z, left at +X), with fingers."""
    spec = [("Hips", None, (0, 0.95, 0)), ("Spine", "Hips", (0, 0.10, 0)),
            ("Chest", "Spine", (0, 0.12, 0)), ("UpperChest", "Chest", (0, 0.12, 0)),
            ("Neck", "UpperChest", (0, 0.15, 0)), ("Head", "Neck", (0, 0.10, 0)),
            ("LeftShoulder", "UpperChest", (0.03, 0.08, 0)),
            ("LeftUpperArm", "LeftShoulder", (0.14, 0, 0)),
            ("LeftLowerArm", "LeftUpperArm", (0.28, 0, 0)),
            ("LeftHand", "LeftLowerArm", (0.25, 0, 0))]
    spec += _fingers("LeftHand", ("Thumb", "Index", "Middle", "Ring", "Little"),
                     lambda f, k: f"Left{f}{('Proximal', 'Intermediate', 'Distal')[k - 1]}")
    spec += [("LeftUpperLeg", "Hips", (0.09, -0.05, 0)),
             ("LeftLowerLeg", "LeftUpperLeg", (0, -0.42, 0)),
             ("LeftFoot", "LeftLowerLeg", (0, -0.42, 0)),
             ("LeftToes", "LeftFoot", (0, -0.06, 0.13))]
    return build_skeleton(_mirror(spec, "Left", "Right"))


def daz_genesis() -> Skeleton:
    """Daz Genesis 8's names (T-pose, facing +Z, left at +X): a Bend and a Twist joint per
    limb bone, the legs under ``pelvis``, the spine in lower/upper pairs."""
    spec = [("hip", None, (0, 0.95, 0)), ("pelvis", "hip", (0, -0.02, 0)),
            ("abdomenLower", "hip", (0, 0.08, 0)), ("abdomenUpper", "abdomenLower", (0, 0.1, 0)),
            ("chestLower", "abdomenUpper", (0, 0.1, 0)), ("chestUpper", "chestLower", (0, 0.1, 0)),
            ("neckLower", "chestUpper", (0, 0.15, 0)), ("neckUpper", "neckLower", (0, 0.05, 0)),
            ("head", "neckUpper", (0, 0.06, 0)),
            ("lCollar", "chestUpper", (0.03, 0.08, 0)),
            ("lShldrBend", "lCollar", (0.14, 0, 0)), ("lShldrTwist", "lShldrBend", (0.14, 0, 0)),
            ("lForearmBend", "lShldrTwist", (0.14, 0, 0)),
            ("lForearmTwist", "lForearmBend", (0.12, 0, 0)),
            ("lHand", "lForearmTwist", (0.13, 0, 0))]
    spec += _fingers("lHand", ("Thumb", "Index", "Mid", "Ring", "Pinky"),
                     lambda f, k: f"l{f}{k}", thumb_base=0.03)
    spec += [("lThighBend", "pelvis", (0.09, -0.03, 0)),
             ("lThighTwist", "lThighBend", (0, -0.21, 0)),
             ("lShin", "lThighTwist", (0, -0.21, 0)), ("lFoot", "lShin", (0, -0.42, 0)),
             ("lMetatarsals", "lFoot", (0, -0.03, 0.06)),
             ("lToe", "lMetatarsals", (0, -0.03, 0.07))]
    right = [("r" + n[1:], "r" + p[1:] if p[0] == "l" and p[1].isupper() else p, (-x, y, z))
             for n, p, (x, y, z) in spec if n[0] == "l" and n[1].isupper()]
    return build_skeleton(spec + right)


def optitrack_motive() -> Skeleton:
    """OptiTrack Motive's skeleton names on the Unity figure: ``LUArm``/``LFArm`` (upper
    arm, forearm), ``LThigh``/``LShin``, a spine of ``Ab`` and ``Chest``."""
    rename = {"Hips": "Hip", "Spine": "Ab", "Chest": "Chest", "UpperChest": None,
              "Neck": "Neck", "Head": "Head", "Shoulder": "Shoulder", "UpperArm": "UArm",
              "LowerArm": "FArm", "Hand": "Hand", "UpperLeg": "Thigh", "LowerLeg": "Shin",
              "Foot": "Foot", "Toes": "Toe"}
    sk = unity_humanoid()
    keep = [j for j, n in enumerate(sk.names)
            if rename.get(n.removeprefix("Left").removeprefix("Right"), "") is not None
            and not any(f in n for f in ("Thumb", "Index", "Middle", "Ring", "Little"))]
    names = []
    for j in keep:
        n = sk.names[j]
        side = "L" if n.startswith("Left") else "R" if n.startswith("Right") else ""
        names.append(side + rename[n.removeprefix("Left").removeprefix("Right")])
    spec = []
    for j, name in zip(keep, names):
        p = sk.parents[j]
        offset = sk.offsets[j].copy()
        while p >= 0 and p not in keep:             # UpperChest left out: its children
            offset += sk.offsets[p]                 # hang from Chest
            p = sk.parents[p]
        spec.append((name, names[keep.index(p)] if p >= 0 else None, tuple(offset)))
    return build_skeleton(spec)


def unnamed(skeleton: Skeleton) -> Skeleton:
    """The same skeleton with every joint renamed ``j0`` ... ``jN``."""
    return dataclasses.replace(skeleton, names=[f"j{k}" for k in range(skeleton.num_joints)])


@lru_cache(maxsize=None)
def _motion(kind: str, name: str):
    return read_bvh(clip_path(name) if kind == "bundled" else shared_path(name))


@lru_cache(maxsize=None)
def _source(source) -> tuple[Skeleton, np.ndarray | None]:
    kind = source[0]
    if kind in ("shared", "bundled"):
        return _motion(*source).skeleton, None
    if kind == "glb":
        return read_glb_skeleton(shared_path(source[1]))
    if kind == "synthetic":
        return {"unreal": unreal_mannequin, "unity": unity_humanoid, "daz": daz_genesis,
                "motive": optitrack_motive}[source[1]](), None
    if kind == "unnamed":
        motion = _motion(*source[1])
        frame = min(source[2], motion.num_frames - 1)
        positions = forward_kinematics(motion.frames(slice(frame, frame + 1))).positions[0]
        return unnamed(motion.skeleton), positions
    raise AssertionError(source)


def load(convention: str) -> tuple[Skeleton, np.ndarray | None, dict[str, str]]:
    """Skeleton, reference positions (or None) and expected role -> joint of a convention."""
    source, expected = CONVENTIONS[convention]
    skeleton, positions = _source(source)
    if source[0] == "unnamed":
        named = _motion(*source[1]).skeleton
        expected = {role: f"j{named.index[joint]}" for role, joint in expected.items()}
    return skeleton, positions, expected


def _role_joint(roles: Roles, role: str) -> str | None:
    if role == "spine_first":
        return roles.spine[0] if roles.spine else None
    return roles.get(role)


# --------------------------------------------------------------------------- names
@pytest.mark.parametrize("name, side, roles, finger, helper", [
    ("LeftShoulder", "l", {"clavicle", "upper_arm"}, None, False),     # CMU-MB / MAX: ambiguous
    ("LeftLeg", "l", {"thigh", "shin"}, None, False),
    ("LeftHip", "l", {"hip_joint", "thigh"}, None, False),              # CMU-MAX thigh
    ("LHipJoint", "l", {"hip_joint"}, None, False),
    ("lhand", "l", {"hand"}, None, False),                              # CMU-MAX
    ("RightCollar", "r", {"clavicle"}, None, False),
    ("UpperArm_L", "l", {"upper_arm"}, None, False),                    # Bandai
    ("Toes_R", "r", {"toe"}, None, False),
    ("mixamorig:LeftForeArm", "l", {"forearm"}, None, False),
    ("LeftInHandIndex", "l", set(), "index", False),                    # Rokoko metacarpal
    ("LeftHandThumb1", "l", set(), "thumb", False),
    ("RightHandEnd", "r", set(), None, True),                           # FAIR1 end joint
    ("headend", None, set(), None, True),                               # an end glued on
    ("lShldrBend", "l", {"clavicle", "upper_arm"}, None, False),        # Daz: not an "end"
    ("rForearmBend", "r", {"forearm"}, None, False),
    ("lThighTwist", "l", set(), None, True),
    ("LFArm", "l", {"forearm"}, None, False),                           # OptiTrack Motive
    ("RUArm", "r", {"upper_arm"}, None, False),
    ("CC_Base_L_Thigh", "l", {"thigh"}, None, False),
    ("CC_Base_R_Calf", "r", {"shin"}, None, False),
    ("CC_Base_L_UpperarmTwist01", "l", set(), None, True),
    ("CC_Base_R_ElbowShareBone", "r", set(), None, True),
    ("CC_Base_L_Mid2", "l", set(), "middle", False),
    ("CC_Base_JawRoot", None, set(), None, True),
    ("ShoulderL", "l", {"clavicle", "upper_arm"}, None, False),          # RobotExpressive
    ("LowerLegR", "r", {"shin"}, None, False),
    ("Palm2L", "l", {"hand"}, None, False),
    ("PoleTargetR", "r", set(), None, True),
    ("thigh_l", "l", {"thigh"}, None, False),                            # Unreal
    ("calf_r", "r", {"shin"}, None, False),
    ("ball_l", "l", {"toe"}, None, False),
    ("lowerarm_twist_01_r", "r", set(), None, True),
    ("ik_foot_l", "l", set(), None, True),
    ("LeftUpperLeg", "l", {"thigh"}, None, False),                       # Unity
    ("RightLittleDistal", "r", set(), "pinky", False),
    ("Bip01 L UpperArm", "l", {"upper_arm"}, None, False),               # 3ds Max Biped
    ("Bip01 R Finger1", "r", set(), "index", False),
    ("b_LeftLeg01_015", "l", {"thigh", "shin"}, None, False),            # fox numbering
    ("upper_arm.L", "l", {"upper_arm"}, None, False),                    # Blender
    ("Hips", None, set(), None, False),
    ("j7", None, set(), None, False),
])
def test_names_are_normalised_per_convention(name, side, roles, finger, helper):
    info = parse_name(name)
    assert (info.side, set(info.roles), info.finger, info.helper) == (side, roles, finger, helper)


# --------------------------------------------------------------------------- identification
@pytest.mark.parametrize("convention", list(CONVENTIONS))
def test_identify_finds_the_expected_joint_for_every_role(convention):
    skeleton, positions, expected = load(convention)
    roles = identify(skeleton, positions)
    got = {role: _role_joint(roles, role) for role in REQUIRED}
    want = {role: expected.get(role) for role in REQUIRED}
    assert got == want
    if convention.startswith("UNNAMED"):
        assert (roles.method, roles.sides) == ("structure", "geometry")
    else:
        assert (roles.method, roles.sides) == ("names", "names")


def test_the_robots_ik_feet_and_pole_targets_are_not_legs():
    skeleton, positions, _ = load("ROBOT")
    roles = identify(skeleton, positions)
    assert "foot_l" not in roles and "foot_r" not in roles
    assert not {"FootL", "FootR", "PoleTargetL", "PoleTargetR"} & set(roles.values())
    assert roles["root"] == "Bone"
    assert roles.spine == ("Hips", "Abdomen", "Torso_1")


def test_ambiguous_names_are_resolved_by_the_chain():
    mb = identify(load("CMU-MB")[0])
    mx = identify(load("CMU-MAX")[0])
    assert (mb["clavicle_l"], mb["upper_arm_l"]) == ("LeftShoulder", "LeftArm")
    assert (mx["clavicle_l"], mx["upper_arm_l"]) == ("LeftCollar", "LeftShoulder")
    assert (mb["hip_joint_l"], mb["thigh_l"], mb["shin_l"]) == ("LHipJoint", "LeftUpLeg",
                                                                  "LeftLeg")
    assert (mx["hip_joint_l"], mx["thigh_l"], mx["shin_l"]) == ("LHipJoint", "LeftHip",
                                                                  "LeftKnee")
    # CMU-MAX's lhand hangs below the wrist: the wrist is the hand
    assert mx["hand_l"] == "LeftWrist"
    corr = automap(load("CMU-MB")[0], load("CMU-MAX")[0])
    assert {k: corr.pairs[k] for k in ("LeftShoulder", "LeftArm", "LeftUpLeg", "LeftLeg")} == {
        "LeftShoulder": "LeftCollar", "LeftArm": "LeftShoulder", "LeftUpLeg": "LeftHip",
        "LeftLeg": "LeftKnee"}


@pytest.mark.parametrize("name", SHARED_BVH)
def test_structural_fallback_on_every_real_skeleton_over_its_frames(name):
    """Every convention with its names removed: the required roles, left and right included,
    on 12 frames spread over the clip (positions from each frame)."""
    motion = _motion("shared", name)
    named = identify(motion.skeleton)
    bare = unnamed(motion.skeleton)
    frames = np.unique(np.linspace(0, motion.num_frames - 1, 12).astype(int))
    positions = forward_kinematics(motion.frames(frames)).positions
    for f, pos in zip(frames, positions):
        roles = identify(bare, pos)
        for role in REQUIRED:
            want = _role_joint(named, role)
            want = f"j{motion.skeleton.index[want]}" if want else None
            assert _role_joint(roles, role) == want, (name, int(f), role)


def test_a_hand_whose_end_site_is_most_of_its_arm_is_still_the_hand(tmp_path):
    """The Bandai clip with its right hand renamed ``_`` (no name to go by) and that hand's
    End Site OFFSET mistyped as 1e6: the arm's length is then almost all End Site, no joint
    lies three quarters along it, and the hand is the arm's last joint (it raised
    StopIteration, a traceback from the command line: the CLI fuzz, seed 4801)."""
    lines = shared_path("bandai2_raise-up-right-hand_normal_001.bvh").read_text().splitlines()
    at = next(i for i, line in enumerate(lines) if line.strip() == "JOINT Hand_R")
    lines[at] = lines[at].replace("Hand_R", "_")
    end = next(i for i in range(at, len(lines)) if lines[i].strip() == "End Site")
    lines[end + 2] = lines[end + 2].split("OFFSET")[0] + "OFFSET 1e6 1e6 1e6"
    path = tmp_path / "long_end_site.bvh"
    path.write_text("\n".join(lines) + "\n")
    skeleton = read_bvh(path).skeleton
    hand = skeleton.index["_"]
    tip = next(e for e in skeleton.end_sites if e.parent == hand)
    assert np.linalg.norm(tip.offset) > 1e4 * np.linalg.norm(skeleton.offsets[hand])
    roles = identify(skeleton)
    assert _role_joint(roles, "hand_r") == "_" and _role_joint(roles, "hand_l") == "Hand_L"


def test_geometry_decides_the_sides_of_an_unnamed_skeleton():
    skeleton, positions, expected = load("UNNAMED-bundled-FAIR1")   # lists the right side first
    roles = identify(skeleton, positions)
    assert roles["thigh_l"] == expected["thigh_l"] and roles["hand_r"] == expected["hand_r"]
    # turning the whole pose (lying on its side, upside down) changes nothing ...
    for angles in ([90, 0, 0], [0, 0, 180], [35, -120, 70]):
        turned = positions @ Rotation.from_euler("xyz", angles, degrees=True).as_matrix().T
        assert dict(identify(skeleton, turned)) == dict(roles)
    # ... but a mirror image swaps left and right
    mirrored = identify(skeleton, positions * np.array([-1.0, 1.0, 1.0]))
    for role in SIDED:
        assert (mirrored[f"{role}_l"], mirrored[f"{role}_r"]) == (roles[f"{role}_r"],
                                                                  roles[f"{role}_l"])


def test_the_zero_pose_gives_sides_where_it_is_anatomical():
    """CMU's zero-rotation pose is an upright T-pose: without a frame the sides still come
    out right for the unnamed CMU skeleton."""
    skeleton, _, expected = load("UNNAMED-bundled-CMU-MAX")
    roles = identify(skeleton)
    assert all(roles[f"{r}_{s}"] == expected[f"{r}_{s}"] for r in SIDED for s in "lr")


def test_a_skeleton_that_is_not_humanoid_is_refused_with_a_reason():
    snake = build_skeleton([(f"seg{k}", None if k == 0 else f"seg{k - 1}", (0, 0, 0.1))
                            for k in range(8)])
    with pytest.raises(MappingError, match="humanoid"):
        identify(snake)
    with pytest.raises(MappingError):
        automap(snake, unity_humanoid())


def test_roles_read_as_a_mapping_and_serve_foot_detection():
    from motion_composer.engine.correction.contacts import find_feet
    skeleton = load("bundled-CMU-rest")[0]
    roles = identify(skeleton)
    assert roles.get("foot_l") == "LeftFoot" and roles["toe_r"] == "RightToeBase"
    assert "foot_l" in roles and len(roles) == len(dict(roles))
    assert roles.role_of("LeftForeArm") == "forearm_l"
    assert find_feet(skeleton) == [("LeftFoot", "LeftToeBase"), ("RightFoot", "RightToeBase")]


# --------------------------------------------------------------------------- mapping
PAIRS = [pytest.param(t, p, id=f"{t}<-{p}") for t in CONVENTIONS for p in CONVENTIONS]


@pytest.mark.parametrize("target_conv, performer_conv", PAIRS)
def test_automap_gets_every_required_role_right_for_every_ordered_pair(target_conv,
                                                                        performer_conv):
    target, t_pos, t_exp = load(target_conv)
    performer, p_pos, p_exp = load(performer_conv)
    corr = automap(target, performer, target_positions=t_pos, performer_positions=p_pos)
    corr.validate(target, performer)
    wrong = {role: (t_exp[role], corr.pairs.get(t_exp[role]), p_exp[role])
             for role in REQUIRED if role in t_exp and role in p_exp
             if corr.pairs.get(t_exp[role]) != p_exp[role]}
    assert not wrong, "target joint: (name, mapped to, expected)"
    assert all(corr.notes.get(t) for t in corr.pairs)


def _arc(skeleton: Skeleton, chain) -> np.ndarray:
    s = np.cumsum([np.linalg.norm(skeleton.offsets[skeleton.index[j]]) for j in chain])
    return (s - s[0]) / (s[-1] - s[0])


def test_spine_middles_follow_arc_length_one_to_one():
    names = ["CMU-MB", "CMU-MAX", "BANDAI", "FAIR1", "ROKOKO-MIXAMO", "CC3-RLROOT", "ROBOT",
             "UNREAL", "UNITY"]
    for tn in names:
        target = load(tn)[0]
        t_sp = identify(target).spine
        for pn in names:
            performer = load(pn)[0]
            p_sp = identify(performer).spine
            corr = automap(target, performer)
            mapped = [corr.pairs.get(j) for j in t_sp]
            assert mapped[0] == p_sp[0] and mapped[-1] == p_sp[-1]
            inner = [m for m in mapped[1:-1] if m is not None]
            assert len(inner) == len(set(inner))                    # one to one
            assert [p_sp.index(m) for m in inner] == sorted(p_sp.index(m) for m in inner)
            if len(t_sp) > 2 and len(p_sp) > 2:
                ta, pa = _arc(target, t_sp), _arc(performer, p_sp)
                for i, m in enumerate(mapped[1:-1], start=1):
                    if m is not None:                               # the nearest middle joint
                        k = p_sp.index(m)
                        assert abs(pa[k] - ta[i]) <= np.abs(pa[1:-1] - ta[i]).min() + 1e-9
    fair = automap(load("FAIR1")[0], load("CMU-MB")[0])
    assert [fair.pairs.get(j) for j in ("Spine", "Spine1", "Spine2", "Spine3")].count(
        "Spine") == 1
    assert (fair.pairs["Spine"], fair.pairs["Spine3"]) == ("LowerBack", "Spine1")


def test_ground_roots():
    cmu, bandai = load("CMU-MB")[0], load("BANDAI")[0]
    rl, hip_rooted, robot = load("CC3-RLROOT")[0], load("CC3-HIPROOT")[0], load("ROBOT")[0]
    # the performer has no ground root: the target's stays unmapped, its hips carry the motion
    corr = automap(bandai, cmu)
    assert "joint_Root" not in corr.pairs and corr.pairs["Hips"] == "Hips"
    assert corr.notes["joint_Root"].startswith("ground root: unmapped")
    assert "Bone" not in automap(robot, cmu).pairs
    assert "RL_BoneRoot" not in automap(rl, hip_rooted).pairs
    # CC3-RLROOT's ground root carries its travel: roots map to each other
    assert automap(bandai, rl).pairs["joint_Root"] == "RL_BoneRoot"
    assert automap(robot, rl).pairs["Bone"] == "RL_BoneRoot"
    # Bandai's travel is on its hips, which CC3-RLROOT's hips cannot carry
    corr = automap(rl, bandai)
    assert "RL_BoneRoot" not in corr.pairs and corr.pairs["CC_Base_Hip"] == "Hips"
    assert "ground root: unmapped" in corr.notes["RL_BoneRoot"]
    # both hips carry their travel: roots map to each other
    assert automap(bandai, load_bandai_kick()).pairs["joint_Root"] == "joint_Root"
    # a target without ground root takes the performer's hips, not its ground root
    assert automap(cmu, bandai).pairs["Hips"] == "Hips"
    assert automap(hip_rooted, rl).pairs["CC_Base_Hip"] == "CC_Base_Hip"


def load_bandai_kick() -> Skeleton:
    return _motion("shared", "bandai1_kick_normal_001.bvh").skeleton


_HELPER_WORDS = ("Twist", "Share", "Pole", "ik_", "Eye", "Jaw", "Teeth", "Tongue", "Breast",
                 "Facial", "End")


def test_helper_joints_are_never_mapped():
    names = ["CC3-RLROOT", "CC3-HIPROOT", "ROBOT", "UNREAL", "FAIR1", "ROKOKO-MIXAMO",
             "CMU-MB"]
    for tn in names:
        for pn in names:
            target, performer = load(tn)[0], load(pn)[0]
            corr = automap(target, performer)
            for t, p in corr.pairs.items():
                for joint in (t, p):
                    # CC3's neck joints are called NeckTwist01/02: they are the neck
                    if "NeckTwist" in joint:
                        continue
                    assert not any(w in joint for w in _HELPER_WORDS), (tn, pn, t, p)
            assert not {"FootL", "FootR"} & (set(corr.pairs) | set(corr.pairs.values()))


def test_fingers_map_by_finger_and_number():
    rokoko, cc3, robot, unity = (load(n)[0] for n in ("ROKOKO-MIXAMO", "CC3-RLROOT", "ROBOT",
                                                      "UNITY"))
    corr = automap(rokoko, cc3)
    for side, s in (("Left", "L"), ("Right", "R")):
        for finger, cc in (("Thumb", "Thumb"), ("Index", "Index"), ("Middle", "Mid"),
                           ("Ring", "Ring"), ("Pinky", "Pinky")):
            for n in (1, 2, 3):
                assert corr.pairs[f"{side}Hand{finger}{n}"] == f"CC_Base_{s}_{cc}{n}"
        assert f"{side}InHandIndex" not in corr.pairs          # CC3 has no metacarpals
    corr = automap(robot, rokoko)
    assert {k: corr.pairs[k] for k in ("IndexL", "Index2L", "Middle1L", "Middle2L", "ThumbL",
                                       "Thumb2R", "Ring1R")} == {
        "IndexL": "LeftHandIndex1", "Index2L": "LeftHandIndex2",
        "Middle1L": "LeftHandMiddle1", "Middle2L": "LeftHandMiddle2",
        "ThumbL": "LeftHandThumb1", "Thumb2R": "RightHandThumb2", "Ring1R": "RightHandRing1"}
    corr = automap(unity, rokoko)
    assert corr.pairs["LeftThumbProximal"] == "LeftHandThumb1"
    assert corr.pairs["RightLittleDistal"] == "RightHandPinky3"
    # CC3 under the robot: the robot's index and ring do not hang from its hand (Palm2L),
    # so CC3's would invert ancestry; they are left out with a note, the middle finger maps
    corr = automap(cc3, robot)
    assert corr.pairs["CC_Base_L_Mid1"] == "Middle1L"
    assert "CC_Base_L_Index1" not in corr.pairs
    assert "ancestry" in corr.notes["CC_Base_L_Index1"]


def test_an_automatic_map_saves_and_loads_as_json(tmp_path):
    target, performer = load("UNITY")[0], load("bundled-CMU-MAX")[0]
    corr = automap(target, performer)
    path = tmp_path / "unity_from_cmu.json"
    corr.save(path)
    data = json.loads(path.read_text(encoding="utf-8"))
    assert data["pairs"] == corr.pairs
    back = Correspondence.load(path)
    assert back == corr and back.pairs == corr.pairs and back.notes == corr.notes
    assert list(back.pairs) == list(corr.pairs)                  # target joint order kept
    back.validate(target, performer, path=path)


def test_automap_is_quick():
    import time
    target, performer = load("UNREAL")[0], load("bundled-FAIR1")[0]
    # the processor time of this process: other work on a loaded machine does not count
    start = time.process_time()
    for _ in range(20):
        automap(target, performer)
    assert (time.process_time() - start) / 20 < 0.05


def test_the_engine_module_imports_only_stdlib_numpy_and_scipy():
    import sys
    tree = ast.parse((REPO / "engine" / "conversion" / "automap.py").read_text(encoding="utf-8"))
    roots = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            roots |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            roots.add(node.module.split(".")[0])
    allowed = set(sys.stdlib_module_names) | {"numpy", "scipy"}
    assert roots <= allowed, roots - allowed
