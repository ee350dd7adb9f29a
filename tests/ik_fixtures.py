"""Shared set-ups for the IK tests: real clips converted onto other skeletons."""
from __future__ import annotations

from functools import lru_cache

from motion_composer.engine import read_bvh
from motion_composer.engine.conversion.correspondence import Correspondence
from motion_composer.engine.conversion import retarget

from conftest import clip_path, shared_path

#: the bundled CMU 3dsMax walk onto the bundled CMU (Holden) T-pose skeleton: same topology,
#: other names, other bone lengths
MAX_TO_HOLDEN = {
    "Hips": "Hips", "LHipJoint": "LHipJoint", "LeftUpLeg": "LeftHip", "LeftLeg": "LeftKnee",
    "LeftFoot": "LeftAnkle", "LeftToeBase": "LeftToe", "RHipJoint": "RHipJoint",
    "RightUpLeg": "RightHip", "RightLeg": "RightKnee", "RightFoot": "RightAnkle",
    "RightToeBase": "RightToe", "LowerBack": "lowerback", "Spine": "Chest", "Spine1": "Chest2",
    "Neck": "lowerneck", "Neck1": "Neck", "Head": "Head", "LeftShoulder": "LeftCollar",
    "LeftArm": "LeftShoulder", "LeftForeArm": "LeftElbow", "LeftHand": "LeftWrist",
    "RightShoulder": "RightCollar", "RightArm": "RightShoulder", "RightForeArm": "RightElbow",
    "RightHand": "RightWrist",
}

#: CMU 3dsMax names onto Bandai
MAX_TO_BANDAI = {
    "Hips": "Hips", "Spine": "Chest", "Chest": "Chest2", "Neck": "Neck", "Head": "Head",
    "Shoulder_L": "LeftCollar", "UpperArm_L": "LeftShoulder", "LowerArm_L": "LeftElbow",
    "Hand_L": "LeftWrist", "Shoulder_R": "RightCollar", "UpperArm_R": "RightShoulder",
    "LowerArm_R": "RightElbow", "Hand_R": "RightWrist", "UpperLeg_L": "LeftHip",
    "LowerLeg_L": "LeftKnee", "Foot_L": "LeftAnkle", "Toes_L": "LeftToe",
    "UpperLeg_R": "RightHip", "LowerLeg_R": "RightKnee", "Foot_R": "RightAnkle",
    "Toes_R": "RightToe",
}

#: Bandai onto Bandai-named... CMU MotionBuilder names (the Xia run) onto Bandai
MB_TO_BANDAI = {
    "Hips": "Hips", "Spine": "Spine", "Chest": "Spine1", "Neck": "Neck", "Head": "Head",
    "Shoulder_L": "LeftShoulder", "UpperArm_L": "LeftArm", "LowerArm_L": "LeftForeArm",
    "Hand_L": "LeftHand", "Shoulder_R": "RightShoulder", "UpperArm_R": "RightArm",
    "LowerArm_R": "RightForeArm", "Hand_R": "RightHand", "UpperLeg_L": "LeftUpLeg",
    "LowerLeg_L": "LeftLeg", "Foot_L": "LeftFoot", "Toes_L": "LeftToeBase",
    "UpperLeg_R": "RightUpLeg", "LowerLeg_R": "RightLeg", "Foot_R": "RightFoot",
    "Toes_R": "RightToeBase",
}


@lru_cache(maxsize=None)
def walk_on_holden():
    performer = read_bvh(clip_path("cmu_131_01_walk.bvh"))
    target = read_bvh(clip_path("cmu_rest_tpose.bvh"))
    corr = Correspondence(MAX_TO_HOLDEN)
    return performer, target, corr, retarget(performer, target, corr)


@lru_cache(maxsize=None)
def walk_on_bandai():
    performer = read_bvh(shared_path("cmu_max_131_01_walk.bvh"))
    target = read_bvh(shared_path("bandai1_walk_normal_001.bvh"))
    corr = Correspondence(MAX_TO_BANDAI)
    return performer, target, corr, retarget(performer, target, corr)


@lru_cache(maxsize=None)
def run_on_bandai():
    performer = read_bvh(shared_path("cmu_xia_angry_13_000_run.bvh"))
    target = read_bvh(shared_path("bandai1_walk_normal_001.bvh"))
    corr = Correspondence(MB_TO_BANDAI)
    return performer, target, corr, retarget(performer, target, corr)


def window_scene(clip, character, lo: int, hi: int):
    """The clip's frames ``lo .. hi - 1`` onto the character (paths), as ``motion-composer
    retarget --auto-contacts --floor 0`` sets them up: the :class:`Scene`, not solved."""
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.formats import read_motion, read_performer
    from motion_composer.engine.project import Project, Source
    from motion_composer.engine.scene import Scene
    performer, target = read_performer(clip), read_motion(character)
    performer = performer.replace(rotations=performer.rotations[lo:hi],
                                  translations=performer.translations[lo:hi])
    project = Project(performer=Source(str(clip)), target=Source(str(character)),
                      correspondence=automap(target.skeleton, performer.skeleton),
                      auto_contacts=True, floor=0.0)
    return Scene(project, performer, target)


def walk_window_on_tpose(lo: int, hi: int):
    """The bundled CMU walk's frames ``lo .. hi - 1`` onto the bundled T-pose with automatic
    contacts and floor planes on a floor 0.92 m above the one the conversion walks on: the
    :class:`Solution`. A hard case for the IK and the key fit: every foot is pushed up on
    most frames and the body must follow.

    The T-pose's hips are at 0, its feet 0.92 m lower. Until round 33 this was what
    ``retarget --auto-contacts --floor 0`` solved; now the project's floor moves the
    conversion onto it (:meth:`Scene.lift`), so the same constraints are made on that
    lifted scene and given, as a user's constraints file could, to the unlifted one."""
    import dataclasses
    from motion_composer.engine.scene import Scene
    lifted = window_scene(clip_path("cmu_131_01_walk.bvh"), clip_path("cmu_rest_tpose.bvh"),
                          lo, hi)
    assert lifted.lift() > 0.9
    constraints = lifted.automatic_constraints()
    project = dataclasses.replace(lifted.project, auto_contacts=False, floor=None)
    scene = Scene(project, lifted.performer, lifted.target)
    return scene.solve(constraints=constraints)


def two_hands(composed, left_range=(90, 100, 120, 135)):
    """Two hand goals back to back on the bundled walk onto the T-pose
    (:func:`walk_on_holden`'s ``composed``): the left hand 15 cm above its frame-110 place,
    let go at frame 120 (ramp out to 135; ``left_range``), and the right hand's goal above
    its frame-130 place held from 121 (ramp in from 106)."""
    from motion_composer.engine.correction.constraints import Constraint
    from motion_composer.engine.kinematics import forward_kinematics
    sk = composed.skeleton
    p = forward_kinematics(composed).positions
    left = Constraint("LeftHand", "position", {"point": p[110, sk.index["LeftHand"]]
                                               + [0.1, 0.15, 0.05]}, *left_range)
    right = Constraint("RightHand", "position", {"point": p[130, sk.index["RightHand"]]
                                                 + [-0.1, 0.2, 0.1]}, 106, 121, 140, 155)
    return [left, right]
