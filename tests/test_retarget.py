"""Direct conversion through the intermediate skeleton, on real clips."""
from __future__ import annotations

import json

import numpy as np
import pytest

from motion_composer.engine import forward_kinematics, read_bvh
from motion_composer.engine.formats.bvh import format_bvh, parse_bvh
from motion_composer.engine.conversion.correspondence import Correspondence
from motion_composer.engine.errors import MappingError, MotionComposerError
from motion_composer.engine.quaternions import qconj, qmul
from motion_composer.engine.conversion import BindOptions, bind
from motion_composer.engine.conversion import RootOptions
from motion_composer.engine.conversion import retarget
from motion_composer.engine.rotations import angle_between
from conftest import all_bvh_params, clip_path, resolve, shared_path

CMU_TO_BANDAI = {  # target (Bandai) -> performer (CMU MotionBuilder names)
    "Hips": "Hips", "Spine": "Spine", "Chest": "Spine1", "Neck": "Neck", "Head": "Head",
    "Shoulder_L": "LeftShoulder", "UpperArm_L": "LeftArm", "LowerArm_L": "LeftForeArm",
    "Hand_L": "LeftHand", "Shoulder_R": "RightShoulder", "UpperArm_R": "RightArm",
    "LowerArm_R": "RightForeArm", "Hand_R": "RightHand",
    "UpperLeg_L": "LeftUpLeg", "LowerLeg_L": "LeftLeg", "Foot_L": "LeftFoot",
    "Toes_L": "LeftToeBase", "UpperLeg_R": "RightUpLeg", "LowerLeg_R": "RightLeg",
    "Foot_R": "RightFoot", "Toes_R": "RightToeBase",
}


def _deg(qa, qb):
    return np.degrees(angle_between(qa, qb))


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def bone_deviation(performer, target_motion, corr):
    """Per (anchor, joint) pair of the target: max angle [deg] over frames between the target's
    bone (nearest mapped ancestor -> joint) and the performer's matching virtual bone."""
    tsk, psk = target_motion.skeleton, performer.skeleton
    a = forward_kinematics(performer).positions
    c = forward_kinematics(target_motion).positions
    mapped = {tsk.index[t]: psk.index[p] for t, p in corr.pairs.items()}
    out = {}
    for j, pj in mapped.items():
        anchors = [x for x in tsk.ancestors(j) if x in mapped]
        if not anchors:
            continue
        a0 = anchors[0]
        vt = c[:, j] - c[:, a0]
        vp = a[:, pj] - a[:, mapped[a0]]
        if np.linalg.norm(vp, axis=1).min() < 1e-6 or np.linalg.norm(vt, axis=1).min() < 1e-6:
            continue              # a zero-length bone has no direction to compare
        cos = np.sum(_unit(vt) * _unit(vp), axis=1)
        out[(tsk.names[a0], tsk.names[j])] = float(np.degrees(np.arccos(np.clip(cos, -1, 1))).max())
    return out


# --------------------------------------------------------------------------- identity
@pytest.mark.parametrize("spec", all_bvh_params())
def test_retargeting_a_clip_onto_its_own_skeleton_gives_it_back(spec):
    motion = read_bvh(resolve(spec))
    corr = Correspondence({n: n for n in motion.skeleton.names})
    out = retarget(motion, motion, corr)
    a, b = forward_kinematics(motion), forward_kinematics(out)
    assert _deg(a.rotations, b.rotations).max() < 0.01
    assert np.abs(a.positions - b.positions).max() < 1e-9
    assert out.frame_time == motion.frame_time


# --------------------------------------------------------------------------- across skeletons
@pytest.fixture(scope="module")
def cmu_on_bandai():
    performer = read_bvh(shared_path("cmu_mb_01_01_jumps.bvh"))
    target = read_bvh(shared_path("bandai1_walk_normal_001.bvh"))
    corr = Correspondence(CMU_TO_BANDAI)
    return performer, target, corr, retarget(performer, target, corr)


def test_chain_bones_follow_the_virtual_bones_on_every_frame(cmu_on_bandai):
    performer, target, corr, out = cmu_on_bandai
    dev = bone_deviation(performer, out, corr)
    branch = {("Hips", "UpperLeg_L"), ("Hips", "UpperLeg_R")}
    chains = {k: v for k, v in dev.items() if k not in branch}
    assert len(chains) >= 15
    worst = max(chains, key=chains.get)
    assert chains[worst] < 0.5, f"{worst}: {chains[worst]:.3f} deg"


def test_branching_joint_matches_its_primary_bone_and_rolls_to_the_others(cmu_on_bandai):
    performer, target, corr, out = cmu_on_bandai
    a = forward_kinematics(performer).positions
    c = forward_kinematics(out).positions
    t, p = target.skeleton.index, performer.skeleton.index
    # primary bone of the hips: towards the spine, exact
    vt = c[:, t["Spine"]] - c[:, t["Hips"]]
    vp = a[:, p["Spine"]] - a[:, p["Hips"]]
    assert np.degrees(np.arccos(np.clip(np.sum(_unit(vt) * _unit(vp), 1), -1, 1))).max() < 0.5
    # roll: the hip line (left thigh to right thigh) seen along the spine agrees
    n = _unit(vp)
    ht = c[:, t["UpperLeg_L"]] - c[:, t["UpperLeg_R"]]
    hp = a[:, p["LeftUpLeg"]] - a[:, p["RightUpLeg"]]
    ht = _unit(ht - np.sum(ht * n, 1, keepdims=True) * n)
    hp = _unit(hp - np.sum(hp * n, 1, keepdims=True) * n)
    roll = np.degrees(np.arccos(np.clip(np.sum(ht * hp, 1), -1, 1)))
    # One rotation cannot follow three bones that move against each other (CMU's LowerBack
    # bends the spine away from the pelvis): the spine is exact and the hip line agrees up to
    # that bend (4.6 degrees at worst on this clip, 0.4 typically).
    assert np.median(roll) < 1.0
    assert roll.max() < 8.0
    # ...which a roll from the spine swing alone would not give
    minimal = bind(performer, target, corr)
    assert minimal.bones[t["Hips"]].roll_by_bones


def test_output_keeps_the_target_units_axes_and_channels(cmu_on_bandai, tmp_path):
    performer, target, corr, out = cmu_on_bandai
    assert out.skeleton is target.skeleton
    path = tmp_path / "out.bvh"
    path.write_text(format_bvh(out))
    back = read_bvh(path, units="cm", up_axis="+Y")
    assert back.skeleton.channels == target.skeleton.channels
    np.testing.assert_allclose(back.skeleton.offsets, target.skeleton.offsets, atol=1e-8)
    np.testing.assert_allclose(forward_kinematics(back).positions,
                               forward_kinematics(out).positions, atol=2e-8)


def test_root_translation_is_scaled_by_hip_heights(cmu_on_bandai):
    performer, target, corr, out = cmu_on_bandai
    binding = bind(performer, target, corr)
    ratio = binding.hip_height_ratio
    # Bandai hips stand higher than CMU's: about 0.93 m against 0.96 m scaled to metres
    assert 0.7 < ratio < 1.3
    pp = forward_kinematics(performer).positions[:, performer.skeleton.index["Hips"]]
    tp = forward_kinematics(out).positions[:, target.skeleton.index["Hips"]]
    np.testing.assert_allclose(tp - tp[0], (pp - pp[0]) * ratio, atol=1e-9)


@pytest.mark.parametrize("mode", ["absolute", "in-place", "scale"])
def test_root_modes(cmu_on_bandai, mode):
    performer, target, corr, _ = cmu_on_bandai
    root = (RootOptions(mode="scaled", scale=(2.0, 0.5)) if mode == "scale"
            else RootOptions(mode=mode))
    out = retarget(performer, target, corr, root=root)
    pp = forward_kinematics(performer).positions[:, performer.skeleton.index["Hips"]]
    tp = forward_kinematics(out).positions[:, target.skeleton.index["Hips"]]
    if mode == "absolute":
        np.testing.assert_allclose(tp, pp, atol=1e-9)
    elif mode == "in-place":
        np.testing.assert_allclose(tp[:, [0, 2]], np.broadcast_to(tp[0, [0, 2]], (len(tp), 2)),
                                   atol=1e-9)
        assert np.ptp(tp[:, 1]) > 0.1            # the jumps still go up and down
    else:
        np.testing.assert_allclose(tp - tp[0], (pp - pp[0]) * [2.0, 0.5, 2.0], atol=1e-9)


def test_rest_alignment_turns_the_target_bones_and_keeping_the_pose_does_not(cmu_on_bandai):
    performer, target, corr, _ = cmu_on_bandai
    aligned = bind(performer, target, corr)
    kept = bind(performer, target, corr, BindOptions(rest_alignment=False))
    # kept: the bound rest posture is the target's own reference (frame 0: Bandai's rest pose
    # lies along +X, so 'auto' takes frame 0)
    ref = forward_kinematics(target.frames(slice(0, 1))).rotations[0]
    assert _deg(kept.rest_world, ref).max() < 1e-6
    # aligned: the left forearm bone points along the performer's reference forearm
    t, p = target.skeleton.index, performer.skeleton.index
    bone = aligned.rest_positions[t["Hand_L"]] - aligned.rest_positions[t["LowerArm_L"]]
    virt = (aligned.performer_rest_positions[p["LeftHand"]] -
            aligned.performer_rest_positions[p["LeftForeArm"]])
    assert np.degrees(np.arccos(np.dot(_unit(bone), _unit(virt)))) < 1e-6
    # the Bandai arms hang down in frame 0 but the CMU rest pose is a T-pose: a real turn
    assert _deg(aligned.rest_world[t["UpperArm_L"]], ref[t["UpperArm_L"]]) > 30


def test_reference_pose_choices(cmu_on_bandai):
    performer, target, corr, _ = cmu_on_bandai
    rest = bind(performer, target, corr, BindOptions(performer_reference="rest"))
    frame = bind(performer, target, corr, BindOptions(performer_reference=100))
    assert rest.notes["performer reference"] == "rest pose (zero rotations)"
    assert frame.notes["performer reference"] == "frame 100"
    assert not np.allclose(rest.performer_rest_world, frame.performer_rest_world)
    with pytest.raises(MotionComposerError, match="outside the clip"):
        bind(performer, target, corr, BindOptions(performer_reference=10**6))
    with pytest.raises(MotionComposerError):
        BindOptions(performer_reference="sideways")


# --------------------------------------------------------------------------- twist
def test_a_forearm_twist_in_the_capture_shows_on_the_target_wrist(cmu_on_bandai):
    """CMU stores the forearm's pronation in the hand joint's roll about the forearm; the
    Bandai hand must roll with it rather than keep the smallest swing."""
    performer, target, corr, out = cmu_on_bandai
    pw = forward_kinematics(performer)
    tw = forward_kinematics(out)
    p, t = performer.skeleton.index, target.skeleton.index

    def roll(pose, forearm, hand, child):
        # the hand's roll about the forearm axis relative to the forearm, per frame
        axis = _unit(pose.positions[:, hand] - pose.positions[:, forearm])
        rel = qmul(pose.rotations[:, hand], qconj(pose.rotations[:, forearm]))
        along = np.sum(rel[:, :3] * axis, axis=1)
        return 2 * np.degrees(np.arctan2(along, rel[:, 3]))

    pr = roll(pw, p["LeftForeArm"], p["LeftHand"], p["LeftFingerBase"])
    tr = roll(tw, t["LowerArm_L"], t["Hand_L"], None)
    pr = np.unwrap(np.radians(pr))
    tr = np.unwrap(np.radians(tr))
    # the capture twists (tens of degrees over the clip) and the target follows it
    assert np.degrees(np.ptp(pr)) > 20
    corr_coef = np.corrcoef(pr, tr)[0, 1]
    assert corr_coef > 0.95
    assert np.degrees(np.abs((tr - tr.mean()) - (pr - pr.mean()))).max() < 5.0


# --------------------------------------------------------------------------- topology
def test_a_longer_target_chain_shares_the_turn():
    performer = read_bvh(shared_path("cmu_mb_01_01_jumps.bvh")).frames(slice(0, 600))
    target = read_bvh(shared_path("cc3_cmu_02_06_pickup.bvh"))
    pairs = {"CC_Base_Hip": "Hips", "CC_Base_Waist": "LowerBack", "CC_Base_Spine02": "Spine1",
             "CC_Base_NeckTwist01": "Neck", "CC_Base_Head": "Head",
             "CC_Base_L_Thigh": "LeftUpLeg", "CC_Base_L_Calf": "LeftLeg",
             "CC_Base_L_Foot": "LeftFoot", "CC_Base_R_Thigh": "RightUpLeg",
             "CC_Base_R_Calf": "RightLeg", "CC_Base_R_Foot": "RightFoot"}
    corr = Correspondence(pairs)
    even = retarget(performer, target, corr)
    first = retarget(performer, target, corr, bind_options=BindOptions(distribute="first"))
    t = target.skeleton.index
    # CMU's LowerBack sits on the hips (a zero-length bone), so the waist follows LowerBack's
    # own turn; Spine01 is unmapped: with "first" it keeps its rest local rotation, with
    # "even" it takes a share of the waist -> Spine02 turn
    binding = bind(performer, target, corr)
    assert binding.chains[t["CC_Base_Waist"]] == [t["CC_Base_Spine01"]] or \
        binding.chains.get(t["CC_Base_Waist"]) in (None, [])
    rest_local = binding.rest_local[t["CC_Base_Spine01"]]
    turn_first = _deg(first.rotations[:, t["CC_Base_Spine01"]], rest_local)
    turn_even = _deg(even.rotations[:, t["CC_Base_Spine01"]], rest_local)
    assert turn_first.max() < 1e-6
    assert turn_even.max() > 1.0
    for motion in (even, first):
        dev = bone_deviation(performer, motion, corr)
        assert dev[("CC_Base_Waist", "CC_Base_Spine02")] < 0.5
        assert dev[("CC_Base_L_Thigh", "CC_Base_L_Calf")] < 0.5


def test_fewer_target_joints_ignore_performer_joints():
    """Bandai has one spine joint and one chest joint against CMU's three: the unmapped CMU
    joints are ignored and conversion still runs (CMU -> Bandai uses Spine and Spine1)."""
    performer = read_bvh(clip_path("cmu_131_01_walk.bvh"))
    target = read_bvh(shared_path("bandai1_walk_normal_001.bvh"))
    max_names = {"Hips": "Hips", "Spine": "Chest", "Chest": "Chest2", "Neck": "Neck",
                 "Head": "Head", "UpperArm_L": "LeftShoulder", "LowerArm_L": "LeftElbow",
                 "Hand_L": "LeftWrist", "UpperLeg_L": "LeftHip", "LowerLeg_L": "LeftKnee",
                 "Foot_L": "LeftAnkle"}
    out = retarget(performer, target, Correspondence(max_names))
    assert out.num_frames == performer.num_frames
    dev = bone_deviation(performer, out, Correspondence(max_names))
    assert dev[("UpperArm_L", "LowerArm_L")] < 0.5
    assert dev[("UpperLeg_L", "LowerLeg_L")] < 0.5


# --------------------------------------------------------------------------- units and axes
def test_z_up_inches_onto_a_y_up_target_in_cmu_units(tmp_path):
    performer = read_bvh(clip_path("fair1_child8_jumping.bvh"))          # +Z up, inches
    target = read_bvh(clip_path("cmu_rest_tpose.bvh"))                    # +Y up, CMU units
    pairs = {"Hips": "Hips", "Spine": "Spine", "Spine1": "Spine3", "Neck": "Neck",
             "Head": "Head", "LeftArm": "LeftArm", "LeftForeArm": "LeftForeArm",
             "LeftHand": "LeftHand", "RightArm": "RightArm", "RightForeArm": "RightForeArm",
             "RightHand": "RightHand", "LeftUpLeg": "LeftUpLeg", "LeftLeg": "LeftLeg",
             "LeftFoot": "LeftFoot", "RightUpLeg": "RightUpLeg", "RightLeg": "RightLeg",
             "RightFoot": "RightFoot"}
    corr = Correspondence(pairs)
    out = retarget(performer, target, corr)
    # the child jumps up: the target's head rises along +Y in internal axes too
    head = forward_kinematics(out).positions[:, target.skeleton.index["Head"]]
    phead = forward_kinematics(performer).positions[:, performer.skeleton.index["Head"]]
    assert np.corrcoef(head[:, 1], phead[:, 1])[0, 1] > 0.95
    text = format_bvh(out)
    back = parse_bvh(text, tmp_path / "o.bvh")
    assert back.skeleton.source.units == "cmu" and back.skeleton.source.up_axis == "+Y"
    np.testing.assert_allclose(forward_kinematics(back).positions,
                               forward_kinematics(out).positions, atol=1e-6)
    dev = bone_deviation(performer, out, corr)
    assert dev[("LeftArm", "LeftForeArm")] < 0.5
    assert dev[("RightUpLeg", "RightLeg")] < 0.5


# --------------------------------------------------------------------------- the mapping
@pytest.fixture(scope="module")
def walk():
    return read_bvh(clip_path("cmu_131_01_walk.bvh"))


@pytest.fixture(scope="module")
def tpose():
    return read_bvh(clip_path("cmu_rest_tpose.bvh"))


def test_mapping_names_must_exist(walk, tpose):
    with pytest.raises(MappingError, match="'LeftArmm' is not a joint of the target.*LeftArm"):
        Correspondence({"Hips": "Hips", "LeftArmm": "LeftShoulder"}).validate(
            tpose.skeleton, walk.skeleton)
    with pytest.raises(MappingError, match="'Elbow' is not a joint of the performer"):
        Correspondence({"Hips": "Hips", "LeftArm": "Elbow"}).validate(
            tpose.skeleton, walk.skeleton)


def test_mapping_is_one_to_one(walk, tpose):
    with pytest.raises(MappingError, match="both mapped to performer joint 'LeftElbow'"):
        Correspondence({"Hips": "Hips", "LeftArm": "LeftElbow",
                        "LeftForeArm": "LeftElbow"}).validate(tpose.skeleton, walk.skeleton)


def test_mapping_keeps_ancestry(walk, tpose):
    with pytest.raises(MappingError, match="inverts ancestry"):
        Correspondence({"Hips": "Hips", "LeftArm": "LeftElbow",
                        "LeftForeArm": "LeftShoulder"}).validate(tpose.skeleton, walk.skeleton)


def test_mapping_needs_a_mapped_root(walk, tpose):
    with pytest.raises(MappingError, match="root 'Hips' is unmapped"):
        Correspondence({"LeftArm": "LeftShoulder", "RightArm": "RightShoulder"}).validate(
            tpose.skeleton, walk.skeleton)
    with pytest.raises(MappingError, match="no joint is mapped"):
        Correspondence({}).validate(tpose.skeleton, walk.skeleton)


def test_mapping_files_round_trip_and_bad_files_name_the_problem(tmp_path):
    corr = Correspondence(CMU_TO_BANDAI)
    path = tmp_path / "map.json"
    corr.save(path)
    data = json.loads(path.read_text())
    assert data["pairs"] == CMU_TO_BANDAI
    assert Correspondence.load(path) == corr
    bad = tmp_path / "bad.json"
    bad.write_text('{"pairs": {"Hips": "Hips",\n "Spine": }}')
    with pytest.raises(MappingError, match=r"bad.json: not valid JSON at line 2"):
        Correspondence.load(bad)
    bad.write_text('{"map": {}}')
    with pytest.raises(MappingError, match='"pairs"'):
        Correspondence.load(bad)
    bad.write_text('{"pairs": {"Hips": 3}}')
    with pytest.raises(MappingError, match="strings to strings"):
        Correspondence.load(bad)
    with pytest.raises(MappingError, match="no such mapping file"):
        Correspondence.load(tmp_path / "absent.json")


def _under_an_armature_node(motion):
    """``motion``'s skeleton under a new root ``Armature`` at the origin, as the FBX reader
    gives a character Blender exported (its armature object is a node above the hips)."""
    from motion_composer.engine.motion import Motion
    from motion_composer.engine.skeleton import Skeleton
    sk = motion.skeleton
    wrapped = Skeleton(names=("Armature",) + sk.names,
                       parents=np.concatenate([[-1], np.where(sk.parents < 0, 0,
                                                              sk.parents + 1)]),
                       offsets=np.vstack([np.zeros(3), sk.offsets]),
                       channels=(("Xposition", "Yposition", "Zposition", "Zrotation",
                                  "Xrotation", "Yrotation"),) + sk.channels)
    rot = np.concatenate([np.tile([0.0, 0.0, 0.0, 1.0], (motion.num_frames, 1, 1)),
                          motion.rotations], axis=1)
    tra = np.concatenate([np.zeros((motion.num_frames, 1, 3)), motion.translations], axis=1)
    assert list(wrapped.translated) == [0] + [j + 1 for j in sk.translated]
    return Motion(wrapped, rot, tra, motion.frame_time, name=motion.name)


def test_a_node_above_the_target_hips_does_not_change_the_root_scale():
    """Ely read from its glTF and from Blender's FBX of it (the same joints at the same places,
    the FBX one under an ``Armature`` node at the origin) got different root scales for the
    CMU walk (0.97 against 1.13): the hip height was measured above the lowest joint, the
    origin node, instead of the feet the bound posture lifts. The ratio and the hips' path
    are now the same with and without the node."""
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.formats import read_character
    performer = read_bvh(clip_path("cmu_131_01_walk.bvh"))
    plain = read_character(shared_path("target_mixamo_ely.glb")).rest_motion()
    results = []
    for target in (plain, _under_an_armature_node(plain)):
        corr = automap(target.skeleton, performer.skeleton)
        assert "Armature" not in corr.pairs
        binding = bind(performer, target, corr)
        out = retarget(performer, target, corr)
        hips = forward_kinematics(out).positions[:, target.skeleton.index["mixamorig:Hips"]]
        results.append((binding.hip_height_ratio, hips))
    (ratio, hips), (ratio_wrapped, hips_wrapped) = results
    assert ratio_wrapped == pytest.approx(ratio, rel=1e-12)
    np.testing.assert_allclose(hips_wrapped, hips, atol=1e-9)


@pytest.mark.parametrize("clip", ["bandai1_walk_normal_001.bvh", "cc3_cmu_02_01_walk.bvh"])
def test_a_ground_level_root_on_a_node_above_the_hips_scales_by_the_hips(clip):
    """A performer's ground-level root (Bandai's ``joint_Root``, CC3's) mapped to the node
    above a target's hips (Blender's FBX ``Armature``) stands on the floor on both sides: it
    has no height, and the root scale fell back to 1 (the character walked at the
    performer's pace whatever its size). The ratio is measured at the hips below it, each
    side's above its own feet (the nodes above the hips are no points of the body, mapped or
    not: the target's node at the origin counted, CC3's walk got 0.93 on Ely where Ely's
    glTF gave 0.81; now 0.88 on both): the ratio is the same target's without the node, and
    a target twice as large gets twice the ratio."""
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.formats import read_character
    from motion_composer.engine.skeleton import Skeleton
    performer = read_bvh(shared_path(clip))
    plain = read_character(shared_path("target_mixamo_ely.glb")).rest_motion()
    without = bind(performer, plain, automap(plain.skeleton, performer.skeleton))
    ratios = []
    for size in (1.0, 2.0):
        sk = plain.skeleton
        grown = plain.replace(skeleton=Skeleton(names=sk.names, parents=sk.parents,
                                                offsets=sk.offsets * size,
                                                channels=sk.channels),
                              translations=plain.translations * size)
        target = _under_an_armature_node(grown)
        corr = automap(target.skeleton, performer.skeleton)
        assert corr.pairs.get("Armature") == performer.skeleton.names[0]
        ratios.append(bind(performer, target, corr).hip_height_ratio)
    assert ratios[0] != pytest.approx(1.0, abs=0.02)
    assert ratios[0] == pytest.approx(without.hip_height_ratio, rel=1e-12)
    assert ratios[1] == pytest.approx(2 * ratios[0], rel=1e-9)


def _with_tips(motion, as_joints):
    """``motion`` with a tip past each childless joint, along its bone and as long: a leaf bone
    ``<joint>_end`` (``as_joints``, Blender's FBX exporter adds them) or an End Site (its BVH
    exporter writes them)."""
    from motion_composer.engine.motion import Motion
    from motion_composer.engine.skeleton import EndSite, Skeleton
    sk = motion.skeleton
    leaves = [j for j in range(1, sk.num_joints) if not sk.children[j]]
    offsets = sk.offsets[leaves]
    if as_joints:
        wrapped = Skeleton(names=sk.names + tuple(f"{sk.names[j]}_end" for j in leaves),
                           parents=np.concatenate([sk.parents, leaves]),
                           offsets=np.vstack([sk.offsets, offsets]),
                           channels=sk.channels + (("Zrotation", "Xrotation", "Yrotation"),) *
                           len(leaves))
        rot = np.concatenate([motion.rotations, np.tile([0.0, 0.0, 0.0, 1.0],
                                                        (motion.num_frames, len(leaves), 1))],
                             axis=1)
        return Motion(wrapped, rot, motion.translations, motion.frame_time, name=motion.name)
    sites = tuple(EndSite(j, o, f"{sk.names[j]}_end") for j, o in zip(leaves, offsets))
    return motion.replace(skeleton=Skeleton(sk.names, sk.parents, sk.offsets, sk.channels,
                                            end_sites=sites))


@pytest.mark.parametrize("clip", ["bandai1_walk_normal_001.bvh", "bandai1_run_active_001.bvh",
                                  "rokoko_mixamo_jesse_dance.bvh"])
def test_tips_past_the_last_joints_do_not_change_the_root_scale(clip):
    """Ely with a leaf bone past each last joint (Blender's FBX of Ely) or an End Site there
    (Blender's BVH of it) got a root scale of 1.16 for the BANDAI walk where Ely's glTF gave
    1.09: bound on a mid-stride frame, the pitched foot put the tip past the toe lowest, and
    the hips were measured from it. The tips are each exporter's convention, not the body:
    each side's floor leaves out what hangs past the joints the two sides share, and the
    ratio and the hips' path are the same with and without them."""
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.formats import read_character
    performer = read_bvh(shared_path(clip))
    plain = read_character(shared_path("target_mixamo_ely.glb")).rest_motion()
    results = []
    for target in (plain, _with_tips(plain, True), _with_tips(plain, False)):
        corr = automap(target.skeleton, performer.skeleton)
        assert corr.pairs == automap(plain.skeleton, performer.skeleton).pairs
        out = retarget(performer, target, corr)
        hips = forward_kinematics(out).positions[:, target.skeleton.index["mixamorig:Hips"]]
        results.append((bind(performer, target, corr).hip_height_ratio, hips))
    for ratio, hips in results[1:]:
        assert ratio == pytest.approx(results[0][0], rel=1e-12)
        np.testing.assert_allclose(hips, results[0][1], atol=1e-9)


@pytest.mark.parametrize("target_file", ["bandai1_walk_normal_001.bvh", "target_mixamo_ely.glb"])
def test_a_writers_rounding_on_position_channels_is_no_movement(target_file):
    """Blender writes a position channel on every bone not connected to its parent, its values
    the bone's offset printed to six decimals of the file's unit (up to 1.0e-6 m apart on its
    export of the CMU walk). The same walk with a position channel on every joint, its values
    the offsets give or take 6e-7 m, retargets as the file without them does: a rounding is
    no movement, and the virtual bones across those joints keep their directions (a bound
    of 1e-6 m took Chest2 for a moving joint there, and the arms turned 0.8 degrees away)."""
    import dataclasses
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.formats import read_character, read_motion
    from motion_composer.engine.motion import Motion
    walk = read_bvh(shared_path("cmu_max_131_01_walk.bvh"))
    sk = walk.skeleton
    J = sk.num_joints
    channels = tuple(("Xposition", "Yposition", "Zposition") +
                     tuple(c for c in ch if c.endswith("rotation")) for ch in sk.channels)
    noisy_sk = dataclasses.replace(sk, channels=channels, position_modes=("absolute",) * J)
    assert len(noisy_sk.translated) == J
    rng = np.random.default_rng(7)
    translations = sk.offsets[None] + rng.uniform(-6e-7, 6e-7, (walk.num_frames, J, 3))
    translations[:, 0] = walk.translations[:, 0]
    noisy = Motion(noisy_sk, walk.rotations, translations, walk.frame_time, walk.name)
    assert np.ptp(translations[:, 1:], axis=0).max() > 1e-6
    path = shared_path(target_file)
    character = read_character(path)
    target = character.rest_motion() if character is not None else read_motion(path)
    corr = automap(target.skeleton, sk)
    plain, written = retarget(walk, target, corr), retarget(noisy, target, corr)
    assert _deg(plain.rotations, written.rotations).max() < 0.01
    assert np.abs(plain.translations - written.translations).max() < 1e-5


def test_a_target_clips_moving_hips_give_its_ground_root_no_bone_to_align():
    """The CC3 walk (its ground root ``RL_BoneRoot`` carrying the walk, the hips a fixed 1.05 m
    above it) onto the Bandai walk's skeleton used as a target: Bandai's hips move under its
    ground root, and on the clip's first frame (the target's reference) they stand 4.07 m along
    the floor from it. That ground-root-to-hips vector is where the walk has taken the hips,
    not a bone: aligned onto the performer's vertical root-to-hips bone it stood the hips
    4.2 m above the floor, and the character came out 4.6 m tall (Bandai is 1.37 m). As the
    performer's moving joints do, the target's give the bones across them no direction: the
    character stands as tall as Bandai, its hips at Bandai's height, upright on every frame."""
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.describe import stature
    from motion_composer.engine.formats import read_motion, read_performer
    performer = read_performer(shared_path("cc3_cmu_02_01_walk.bvh"))
    target = read_motion(shared_path("bandai1_walk_normal_001.bvh"))
    corr = automap(target.skeleton, performer.skeleton)
    assert corr.pairs["joint_Root"] == "RL_BoneRoot" and corr.pairs["Hips"] == "CC_Base_Hip"
    composed = retarget(performer, target, corr)
    assert stature(composed) == pytest.approx(stature(target), rel=0.05)
    sk = composed.skeleton
    p = forward_kinematics(composed).positions
    t = forward_kinematics(target).positions
    hips, head = sk.index["Hips"], sk.index["Head"]
    ground = p[:, sk.index["joint_Root"], 1]
    assert np.allclose(p[:, hips, 1] - ground, t[0, hips, 1] - t[0, 0, 1], rtol=0.05)
    assert np.all(p[:, head, 1] > p[:, hips, 1] + 0.3)


def _under_a_reference_root(text: str) -> str:
    """BVH ``text`` with a still ``reference`` root added above its root (six channels, all
    zero on every frame), as some exporters write a capture: the old root (the hips) keeps
    its OFFSET and its six channels."""
    lines = text.splitlines()
    top = next(k for k, line in enumerate(lines) if line.startswith("ROOT"))
    motion = lines.index("MOTION")
    head = ["HIERARCHY", "ROOT reference", "{", "\tOFFSET 0 0 0",
            "\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"]
    body = ["\t" + ("JOINT " + line.split(None, 1)[1] if line.startswith("ROOT") else line)
            for line in lines[top:motion]]
    rows = lines[motion:]
    k = next(n for n, line in enumerate(rows) if line.startswith("Frame Time"))
    frames = ["0 0 0 0 0 0 " + row for row in rows[k + 1:] if row.strip()]
    return "\n".join(head + body + ["}"] + rows[:k + 1] + frames) + "\n"


@pytest.mark.parametrize("clip", [("bundled", "cmu_131_01_walk.bvh"),
                                  ("shared", "cmu_xia_angry_13_000_run.bvh"),
                                  ("bundled", "fair1_child8_jumping.bvh"),
                                  ("shared", "rokoko_mixamo_jesse_dance.bvh")],
                         ids=lambda c: c[1].split(".")[0])
def test_a_still_reference_root_above_the_hips_changes_nothing(clip):
    """A capture written with a still ``reference`` root above its hips retargets as the
    capture itself does, joint for joint, onto Ely.

    * Hips whose OFFSET is zero (CMU's, FAIR's), their channels carrying their whole place:
      the binding's rest pose (zero channel values) put them on the ground at the reference,
      where a file's root stands at its first frame, and the root motion, measured from
      there, lifted the CMU walk's character by the performer's hip height (1.18 m on
      Kenney's Maya character) and moved it by where the capture began.
    * Rokoko's, whose zero pose lies (hips, knees and feet at one height): the reference
      root on the ground below made that pose tall enough to pass for standing, and it was
      bound on it instead of on its first frame (the root scale 1.25 instead of 1.05)."""
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.formats import read_character
    where, name = clip
    text = format_bvh(read_bvh(clip_path(name) if where == "bundled" else shared_path(name)))
    plain, wrapped = parse_bvh(text), parse_bvh(_under_a_reference_root(text))
    assert wrapped.skeleton.names[1:] == plain.skeleton.names
    target = read_character(shared_path("target_mixamo_ely.glb")).rest_motion()
    out, notes = [], []
    for performer in (plain, wrapped):
        corr = automap(target.skeleton, performer.skeleton)
        notes.append(bind(performer, target, corr).notes)      # reference poses, root scale
        out.append(forward_kinematics(retarget(performer, target, corr)).positions)
    assert notes[1] == notes[0]
    np.testing.assert_allclose(out[1], out[0], atol=1e-9)


@pytest.mark.parametrize("name, above", [
    ("bandai1_walk_normal_001.bvh", ["joint_Root"]),
    ("cc3_cmu_02_01_walk.bvh", ["RL_BoneRoot"]),
    ("cmu_max_131_01_walk.bvh", []),
    ("target_fox.glb", ["b_Root_00", "_rootJoint"]),
    ("fbx/maya_character_7500_binary.fbx", ["Character1_Reference"]),
    ("fbx/maya_kenney_character_7700_binary.fbx", []),        # its Root carries the controls
])
def test_the_nodes_above_the_body_are_those_above_where_it_branches(name, above):
    """``Skeleton.above_the_body`` (which the figure's size and the upright check leave out):
    the ground roots and exporters' nodes above the hips, on real files of several
    conventions; none where the root itself branches."""
    from motion_composer.engine.formats import read_character
    path = shared_path(name)
    character = read_character(path)
    sk = character.skeleton if character is not None else read_bvh(path).skeleton
    assert [sk.names[j] for j in sk.above_the_body()] == above


def _turned_about_up(path, tmp_path, degrees: float):
    """A copy of the glb character at ``path`` under a new top node turned ``degrees`` about
    +Y: the same figure, its rest pose facing elsewhere (as a file whose front is +X)."""
    from test_gltf import pack_glb, unpack_glb
    js, binary = unpack_glb(path.read_bytes())
    half = np.radians(degrees) / 2
    top = len(js["nodes"])
    js["nodes"].append({"name": "turned", "rotation": [0.0, float(np.sin(half)), 0.0,
                                                       float(np.cos(half))],
                        "children": list(js["scenes"][0]["nodes"])})
    js["scenes"][0]["nodes"] = [top]
    out = tmp_path / f"turned_{degrees:g}.glb"
    out.write_bytes(pack_glb(js, binary))
    return out


@pytest.mark.parametrize("clip", [("bundled", "cmu_131_01_walk.bvh"),
                                  ("shared", "cmu_xia_angry_13_000_run.bvh"),
                                  ("bundled", "fair1_child8_jumping.bvh"),
                                  ("shared", "bandai1_kick_normal_001.bvh")],
                         ids=lambda c: c[1].split(".")[0])
@pytest.mark.parametrize("degrees", [90.0, 180.0, -90.0])
def test_a_target_whose_rest_pose_faces_elsewhere_moves_the_same(clip, degrees, tmp_path):
    """Ely's glb with its rest pose turned about the vertical (a new top node) takes every
    clip to the same motion, joint for joint, as Ely facing +Z. CMU's hips (the walk's Max
    naming, the run's MotionBuilder one) have no bone of their own (LowerBack sits on them)
    and take their performer joint's turn from the reference pose: the turned Ely kept its
    rest facing on every frame and walked sideways (a joint 0.5 of its size from where it
    is now). FAIR's and Bandai's hips roll by their bones, which already faced them."""
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.formats import read_character
    performer = read_bvh(resolve(clip))
    ely = shared_path("target_mixamo_ely.glb")
    out, stands = [], []
    for path in (ely, _turned_about_up(ely, tmp_path, degrees)):
        target = read_character(path).rest_motion()
        corr = automap(target.skeleton, performer.skeleton)
        out.append(forward_kinematics(retarget(performer, target, corr)).positions)
        stands.append(forward_kinematics(target).positions[0, 0])      # its hips at rest
    # the turn about the origin moves where the hips stand (Ely's are 6 mm off it), and the
    # character starts where it stands
    size = np.ptp(out[0][0], axis=0).max()
    np.testing.assert_allclose(out[1] - (stands[1] - stands[0]), out[0], atol=1e-6 * size)


def _pelvis_turn(motion, left: str, right: str) -> np.ndarray:
    """[deg] per frame, the heading of the line from the ``left`` to the ``right`` joint."""
    p = forward_kinematics(motion).positions
    d = p[:, motion.skeleton.index[right]] - p[:, motion.skeleton.index[left]]
    return np.degrees(np.arctan2(d[:, 0], d[:, 2]))


@pytest.mark.parametrize("clip, target, thighs", [
    ("cc3_cmu_02_06_pickup.bvh", "target_cmu_mb_rest_tpose.bvh", ("LeftUpLeg", "RightUpLeg")),
    ("bandai1_kick_normal_001.bvh", "target_cmu_mb_rest_tpose.bvh",
     ("LeftUpLeg", "RightUpLeg")),
    ("rokoko_mixamo_jesse_dance.bvh", "target_cmu_mb_rest_tpose.bvh",
     ("LeftUpLeg", "RightUpLeg")),
    ("cc3_cmu_02_01_walk.bvh", "target_robot_expressive.glb", ("UpperLegL", "UpperLegR")),
    ("cc3_cmu_02_06_pickup.bvh", "fbx/maya_kenney_character_7700_binary.fbx",
     ("LeftUpLeg", "RightUpLeg")),
], ids=lambda v: v.split(".")[0] if isinstance(v, str) else "")
def test_a_pelvis_bound_on_a_clips_frame_faces_as_the_performers(clip, target, thighs):
    """Clips whose rest pose lies are bound on their frame 0, which faces wherever the
    performer stood; onto a target whose pelvis no bone rolls (the CMU T-pose's hips, the
    robot's Body, Kenney's hips), the pelvis took its performer joint's turn from there and
    kept the target's own facing at that frame: turned 11 to 123 degrees from the
    performer's pelvis, between legs that point as the performer's do (the CC3 pickup onto
    the CMU T-pose: 123). The line between the thigh roots now heads as the performer's
    within 3 degrees on every frame (the two pelvises are built differently)."""
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.formats import read_motion, read_performer
    performer = read_performer(shared_path(clip))
    target = read_motion(shared_path(target))
    corr = automap(target.skeleton, performer.skeleton)
    b = bind(performer, target, corr)
    assert b.notes["performer reference"] == "frame 0"
    out = retarget(performer, target, corr)
    mine = _pelvis_turn(out, *thighs)
    theirs = _pelvis_turn(performer, corr.pairs[thighs[0]], corr.pairs[thighs[1]])
    off = (mine - theirs + 180.0) % 360.0 - 180.0
    assert np.abs(off).max() < 3.0, np.abs(off).max()


def _turned_performer(motion, degrees: float):
    """``motion`` with its rest pose turned ``degrees`` about the vertical and the same
    motion in the world: the offsets turned about the file's up axis, the root's rotations
    turned back, every other joint's conjugated (a capture whose zero pose faces +X)."""
    import dataclasses
    from motion_composer.engine.motion import Motion
    from motion_composer.engine.quaternions import about_axis, from_matrix, qrot
    sk = motion.skeleton
    up = from_matrix(sk.source.rotation)                   # the file's axes -> the engine's
    q = qmul(qmul(qconj(up), about_axis(np.array([0.0, 1.0, 0.0]), np.radians(degrees))), up)
    ends = tuple(dataclasses.replace(e, offset=qrot(q, np.asarray(e.offset)))
                 for e in sk.end_sites)
    turned = dataclasses.replace(sk, offsets=qrot(q, sk.offsets), end_sites=ends)
    rot = motion.rotations.copy()
    rot[:, 0] = qmul(motion.rotations[:, 0], qconj(q))
    rot[:, 1:] = qmul(qmul(q, motion.rotations[:, 1:]), qconj(q))
    tra = motion.translations.copy()
    for k, j in enumerate(sk.translated):
        if j != 0:
            tra[:, k] = qrot(q, motion.translations[:, k])
    return Motion(turned, rot, tra, motion.frame_time, motion.name)


@pytest.mark.parametrize("clip", [("bundled", "cmu_131_01_walk.bvh"),
                                  ("shared", "cmu_xia_angry_13_000_run.bvh"),
                                  ("bundled", "fair1_child8_jumping.bvh"),
                                  ("shared", "fair1_child5_wave_hello.bvh")],
                         ids=lambda c: c[1].split(".")[0])
@pytest.mark.parametrize("degrees", [90.0, 180.0])
def test_a_capture_whose_rest_pose_faces_elsewhere_retargets_the_same(clip, degrees):
    """The same captures written with their zero pose facing elsewhere (the same motion in
    the world, to 1e-9 m) retarget onto Ely to the same motion. Before the target was turned
    to face as the performer's rest pose, the CMU walk and run were 10 % of the size off
    turned a quarter and 29-33 % turned half round, the FAIR clips 14-16 % half round."""
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.formats import read_character
    performer = read_bvh(resolve(clip))
    turned = _turned_performer(performer, degrees)
    np.testing.assert_allclose(forward_kinematics(turned).positions,
                               forward_kinematics(performer).positions, atol=1e-9)
    target = read_character(shared_path("target_mixamo_ely.glb")).rest_motion()
    out = []
    for p in (performer, turned):
        corr = automap(target.skeleton, p.skeleton)
        out.append(forward_kinematics(retarget(p, target, corr)).positions)
    size = np.ptp(out[0][0], axis=0).max()
    np.testing.assert_allclose(out[1], out[0], atol=1e-9 * size)
