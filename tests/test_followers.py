"""Control joints carried with the limbs (engine/conversion/followers.py): the robot's feet are
IK targets under its root ``Bone`` (its legs end at ``LowerLegL``), Kenney's Maya character has
``LeftFootCtrl`` under ``Root`` on ``LeftFoot``. Retargeted, they stay with the legs."""
from __future__ import annotations

import functools

import numpy as np
import pytest

from conftest import clip_path, shared_path
from motion_composer.engine.conversion.automap import automap
from motion_composer.engine.conversion.binding import bind
from motion_composer.engine.conversion.composer import retarget
from motion_composer.engine.conversion.followers import follow
from motion_composer.engine.correction.constraints import Constraint
from motion_composer.engine.correction.displacement import Curve, DisplacementMap, Layer
from motion_composer.engine.describe import stature
from motion_composer.engine.formats import read_character, read_motion, read_performer
from motion_composer.engine.kinematics import fk_arrays, forward_kinematics
from motion_composer.engine.project import Project, Source
from motion_composer.engine.quaternions import qconj, qmul, qrot
from motion_composer.engine.scene import Scene

ROBOT = shared_path("target_robot_expressive.glb")
KENNEY = shared_path("fbx/maya_kenney_character_7700_binary.fbx")
#: clips of four conventions, two of them (BANDAI) bound on their first frame, mid-stride
CLIPS = ["cmu_max_131_01_walk.bvh", "bandai1_run_active_001.bvh", "cc3_cmu_02_01_walk.bvh",
         "cmu_mb_01_01_jumps.bvh", "bandai1_kick_normal_001.bvh"]


@functools.lru_cache(maxsize=None)
def _character(path):
    return read_character(path)


@functools.lru_cache(maxsize=None)
def _performer(name):
    return read_performer(shared_path(name))


def _world(motion):
    pose = fk_arrays(motion.skeleton, motion.rotations, motion.translations, end_sites=False)
    return pose.rotations, pose.positions


def _angle(a, b):
    """[deg] between rotations ``a`` and ``b`` (same shapes)."""
    return np.degrees(2.0 * np.arccos(np.clip(np.abs(np.sum(a * b, axis=-1)), 0.0, 1.0)))


def _own_feet(character):
    """The robot's foot positions in its shins' frames over every frame of its own 14 clips
    (where its IK put them): ``(n, 3)`` per side."""
    out = {}
    for side in "LR":
        rel = []
        for clip in character.motions:
            rot, pos = _world(clip)
            a, f = clip.skeleton.index[f"LowerLeg{side}"], clip.skeleton.index[f"Foot{side}"]
            rel.append(qrot(qconj(rot[:, a]), pos[:, f] - pos[:, a]))
        out[side] = np.concatenate(rel)
    return out


@pytest.mark.parametrize("clip", CLIPS)
def test_the_robots_feet_walk_with_its_legs(clip):
    """Each foot stays at its shin's end where the robot's own clips keep it, the shin points
    along the performer's (knee to ankle, even where the performer is bound mid-stride), and
    the foot pitches as the performer's foot pitches, without its roll."""
    character = _character(ROBOT)
    target, performer = character.rest_motion(), _performer(clip)
    correspondence = automap(target.skeleton, performer.skeleton)
    binding = bind(performer, target, correspondence)
    sk, psk = target.skeleton, performer.skeleton
    carried = {sk.names[f.joint]: (sk.names[f.anchor], psk.names[f.source])
               for f in binding.followers}
    assert set(carried) == {"FootL", "FootR"}
    motion = retarget(performer, target, correspondence)
    rot, pos = _world(motion)
    p_rot, p_pos = _world(performer)
    size = stature(target)
    own = _own_feet(character)
    for side in "LR":
        shin, ankle = carried[f"Foot{side}"]
        assert shin == f"LowerLeg{side}"
        a, f = sk.index[shin], sk.index[f"Foot{side}"]
        knee, p_ankle = psk.index[correspondence.pairs[shin]], psk.index[ankle]
        assert psk.parents[p_ankle] == knee
        rel = qrot(qconj(rot[:, a]), pos[:, f] - pos[:, a])
        # rigid on the shin, where the robot's own IK held it on some frame of its clips (they
        # hold it 0.88-0.97 m from the knee, rolled two ways about the shin)
        assert np.ptp(rel, axis=0).max() < 1e-9 * size
        assert np.linalg.norm(own[side] - rel[0], axis=1).min() < 0.005 * size
        # the shin along the performer's shin
        shin_dir = pos[:, f] - pos[:, a]
        p_dir = p_pos[:, p_ankle] - p_pos[:, knee]
        cos = np.sum(shin_dir * p_dir, axis=1) / (np.linalg.norm(shin_dir, axis=1) *
                                                  np.linalg.norm(p_dir, axis=1))
        assert np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max() < 0.01
        # the foot pitches as the performer's foot (ankle to toe) pitches from standing
        # flat, and never rolls: its up axis tilts by that pitch alone
        follower = next(x for x in binding.followers if x.joint == f)
        assert follower.toe >= 0 and psk.parents[follower.toe] == p_ankle
        foot = p_pos[:, follower.toe] - p_pos[:, p_ankle]
        pitch = np.degrees(np.arctan2(-foot[:, 1], np.linalg.norm(foot[:, [0, 2]], axis=1)))
        up = qrot(qmul(rot[:, f], qconj(np.broadcast_to(_world(target)[0][0, f],
                                                        rot[:, f].shape))),
                  np.broadcast_to([0.0, 1.0, 0.0], pos[:, f].shape))
        tilt = np.degrees(np.arccos(np.clip(up[:, 1], -1.0, 1.0)))
        np.testing.assert_allclose(tilt, np.abs(pitch - np.degrees(follower.pitch)),
                                   atol=1e-3)
    # the knees' pole targets are not carried: they keep their rest place on the root
    rest_rot, rest_pos = _world(target)
    for pole in ("PoleTargetL", "PoleTargetR"):
        j = sk.index[pole]
        assert sk.parents[j] == 0
        on_root = qrot(qconj(rot[:, 0]), pos[:, j] - pos[:, 0])
        rest = qrot(qconj(rest_rot[0, 0]), rest_pos[0, j] - rest_pos[0, 0])
        assert np.abs(on_root - rest).max() < 1e-9 * size


def test_a_control_joint_on_a_mapped_joint_moves_with_it():
    """Kenney's ``LeftFootCtrl`` / ``RightFootCtrl`` (under ``Root``, on the feet) stay on the
    feet, turned as they are, through a walk."""
    character = _character(KENNEY)
    target, performer = character.rest_motion(), _performer(CLIPS[0])
    correspondence = automap(target.skeleton, performer.skeleton)
    motion = retarget(performer, target, correspondence)
    sk = target.skeleton
    rot, pos = _world(motion)
    for side in ("Left", "Right"):
        ctrl, foot = sk.index[f"{side}FootCtrl"], sk.index[f"{side}Foot"]
        assert f"{side}Foot" in correspondence.pairs
        gap = np.linalg.norm(pos[:, ctrl] - pos[:, foot], axis=1)
        assert gap.max() < 1e-3 * stature(target)
        assert np.ptp(pos[:, foot], axis=0).max() > 0.3 * stature(target)   # the feet walk
        between = qmul(qconj(rot[:, foot]), rot[:, ctrl])
        assert _angle(between, between[:1]).max() < 1e-4


@pytest.mark.parametrize("target", ["target_mixamo_ely.glb", "target_fox.glb",
                                    "target_cmu_mb_rest_tpose.bvh", "fbx/mixamo.fbx",
                                    "fbx/maya_character_7500_binary.fbx"])
def test_no_joint_is_carried_where_no_rig_has_a_control_joint(target):
    character = read_character(shared_path(target))
    t = character.rest_motion() if character is not None else read_motion(shared_path(target))
    for clip in CLIPS[:3]:
        performer = _performer(clip)
        binding = bind(performer, t, automap(t.skeleton, performer.skeleton))
        assert binding.followers == ()


def _feet_on_shins(scene):
    motion = scene.motion
    rot, pos = _world(motion)
    sk = motion.skeleton
    out = []
    for side in "LR":
        a, f = sk.index[f"LowerLeg{side}"], sk.index[f"Foot{side}"]
        out.append(qrot(qconj(rot[:, a]), pos[:, f] - pos[:, a]))
    return np.array(out), pos


def _walking_robot() -> Scene:
    """The bundled CMU walk onto the robot, mapped automatically."""
    walk = clip_path("cmu_131_01_walk.bvh")
    performer, target = read_motion(walk), _character(ROBOT).rest_motion()
    project = Project(performer=Source(str(walk)), target=Source(str(ROBOT)),
                      correspondence=automap(target.skeleton, performer.skeleton))
    return Scene(project, performer, target)


def test_the_feet_follow_a_correction_and_a_layer():
    """A solved constraint on a knee and an animator's layer on a thigh move the shins: the
    feet come along (the final motion, not the conversion's)."""
    scene = _walking_robot()
    before, pos0 = _feet_on_shins(scene)
    sk = scene.target.skeleton
    knee = sk.index["LowerLegL"]
    goal = pos0[100, knee] + np.array([0.0, 0.4, 0.3])
    solved = scene.replace(constraints=(Constraint(
        joint="LowerLegL", kind="position", goal={"point": goal.tolist()}, smooth_in=80,
        start=100, end=120, smooth_out=140, name="knee up"),)).solve().scene
    after, pos1 = _feet_on_shins(solved)
    assert np.linalg.norm(pos1[110, knee] - goal) < 1e-3             # the knee moved up
    foot = sk.index["FootL"]
    assert np.linalg.norm(pos1[110, foot] - pos0[110, foot]) > 0.2    # and the foot with it
    assert np.abs(after - before[:, :1]).max() < 1e-9                 # still on the shin
    layer = Layer("lift the thigh", DisplacementMap({("UpperLegR", "rx"): Curve(
        [0.0, 150.0, 300.0], [0.0, 40.0, 0.0], ("smooth",) * 3)}))
    layered = scene.replace(layers=(layer,))
    after, pos2 = _feet_on_shins(layered)
    foot = sk.index["FootR"]
    assert np.linalg.norm(pos2[150, foot] - pos0[150, foot]) > 0.2
    assert np.abs(after - before[:, :1]).max() < 1e-9


def test_a_goal_on_a_carried_joint_is_held_through_its_limb():
    """A point goal on the robot's FootL (a control joint under the root, carried with the
    shin) is met by turning the leg that carries it (``Task.point``), not by dragging the
    root: the delivered foot stands on the goal, still on its shin, and outside the
    constraint's range the motion is the conversion's bit for bit."""
    scene = _walking_robot()
    before, pos0 = _feet_on_shins(scene)
    sk = scene.target.skeleton
    foot = sk.index["FootL"]
    # the foot 25 cm higher and 15 cm to the side over the hold, where it strides
    goal = pos0[120, foot] + np.array([0.15, 0.25, 0.0])
    shown = []
    solution = scene.replace(constraints=(Constraint(
        joint="FootL", kind="position", goal={"point": goal.tolist()}, smooth_in=100,
        start=110, end=130, smooth_out=140, name="step"),)).solve(on_dense=shown.append)
    # what the window shows while the keys are fitted: the dense solve as delivered, its
    # carried foot placed on the goal with its shin
    assert len(shown) == 1 and shown[0] is solution.correction.motion
    dense = forward_kinematics(shown[0]).positions
    assert np.linalg.norm(dense[110:131, foot] - goal, axis=1).max() < 1e-3
    after, pos1 = _feet_on_shins(solution.scene)
    assert np.linalg.norm(pos1[110:131, foot] - goal, axis=1).max() < 1e-3
    assert solution.report["constraints"][0]["max_residual"] < 1e-3
    assert np.abs(after - before[:, :1]).max() < 1e-9                 # still on the shin
    # the leg took a share (the root alone, as before, moves the hips as much as the foot)
    hips = sk.index["Hips"]
    leg = (pos1[120, foot] - pos1[120, hips]) - (pos0[120, foot] - pos0[120, hips])
    assert np.linalg.norm(leg) > 0.1, leg
    composed, motion = scene.composed, solution.scene.motion
    outside = np.r_[0:100, 141:composed.num_frames]
    np.testing.assert_array_equal(motion.rotations[outside], composed.rotations[outside])
    np.testing.assert_array_equal(motion.translations[outside],
                                  composed.translations[outside])


def test_an_orientation_on_a_carried_joint_is_refused_in_one_line(tmp_path, capsys):
    """A carried control joint turns as its performer joint (the robot's FootL as the
    performer's ankle), placed after the IK: no turn of the limb holds an orientation goal on
    it. The CLI says so in one line naming the limb, and writes nothing; a point goal on it
    is solved."""
    import json
    from motion_composer.app.cli import main
    walk = clip_path("cmu_131_01_walk.bvh")
    for kind, goal, code in (("orientation", {"quaternion": [0.0, 0.0, 0.0, 1.0]}, 2),
                             ("position", {"point": [0.6, 0.5, 0.3]}, 0)):
        cons = tmp_path / f"{kind}.json"
        cons.write_text(json.dumps({"constraints": [
            {"joint": "FootL", "kind": kind, "goal": goal, "range": [100, 110, 130, 140],
             "name": "step"}]}))
        out = tmp_path / f"{kind}.bvh"
        assert main(["retarget", str(walk), "--target", str(ROBOT), "-o", str(out),
                     "--constraints", str(cons)]) == code
        err = capsys.readouterr().err
        if code:
            lines = err.strip().splitlines()
            assert len(lines) == 1 and "Traceback" not in err, err
            assert "FootL is a control joint carried with LowerLegL" in lines[0]
            assert "'step'" in lines[0] and "orientation goal on LowerLegL" in lines[0]
            assert not out.exists()
        else:
            assert out.exists(), err


def test_a_goal_on_a_joint_hanging_from_a_carried_joint_is_refused(tmp_path, capsys):
    """Kenney's ``LeftHeelRoll`` hangs from ``LeftFootCtrl``, a control joint carried with
    the left foot and placed after the IK. The IK cannot move it: solved, a goal on it
    turned the control joint and the root above it, and the control joint was put back. The
    CLI refuses it in one line naming the control joint and the limb, and writes nothing;
    ``enforce`` given the carried joints refuses it too."""
    import json
    from motion_composer.app.cli import main
    from motion_composer.engine.conversion.followers import carriers
    from motion_composer.engine.correction.constraints import ConstraintError
    from motion_composer.engine.correction.enforcement import enforce
    walk = shared_path("bandai1_walk_normal_001.bvh")
    cons = tmp_path / "heel.json"
    cons.write_text(json.dumps({"constraints": [
        {"joint": "LeftHeelRoll", "kind": "position", "goal": {"point": [0.1, 0.2, 0.3]},
         "range": [40, 50, 60, 70], "name": "heel"}]}))
    out = tmp_path / "out.bvh"
    assert main(["retarget", str(walk), "--target", str(KENNEY), "-o", str(out),
                 "--constraints", str(cons)]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "'heel'" in lines[0] and "LeftHeelRoll hangs from LeftFootCtrl" in lines[0]
    assert "carried with LeftFoot" in lines[0]
    assert not out.exists()
    character = _character(KENNEY)
    performer = read_motion(walk)
    scene = Scene(Project(performer=Source(str(walk)), target=Source(str(KENNEY)),
                          correspondence=automap(character.rest_motion().skeleton,
                                                 performer.skeleton)),
                  performer, character.rest_motion())
    heel = Constraint.from_dict(json.loads(cons.read_text())["constraints"][0])
    with pytest.raises(ConstraintError, match="LeftHeelRoll hangs from LeftFootCtrl"):
        enforce(scene.edited, [heel], carried=carriers(scene.binding.followers))


@pytest.mark.parametrize("clip", ["bandai1_walk_normal_001.bvh", "bandai1_kick_normal_001.bvh"])
def test_the_robots_feet_stand_flat_where_the_performers_do(clip):
    """A carried foot turns as the performer's ankle turns from standing flat (the pitch of
    its foot on the frames where it is low), not from the reference pose: BANDAI clips are
    bound on a mid-stride frame 0, where the left foot points 79 degrees down, and the robot's
    left foot stood 56 degrees off the floor wherever the performer's was flat."""
    character = _character(ROBOT)
    target, performer = character.rest_motion(), _performer(clip)
    project = Project(performer=Source(shared_path(clip)), target=Source(str(ROBOT)),
                      correspondence=automap(target.skeleton, performer.skeleton),
                      auto_contacts=True)
    scene = Scene(project, performer, target)
    rot, _ = _world(scene.composed)
    rest, _ = _world(target)
    sk = target.skeleton
    checked = 0
    for c in scene.contacts():
        name = "FootL" if c.joint.endswith("_L") else "FootR"
        j = sk.index[name]
        for s, e in c.heel:
            # the foot's up axis against the rest pose's (its tilt, whatever its heading)
            turn = qmul(rot[s:e + 1, j], qconj(np.broadcast_to(rest[0, j], (e - s + 1, 4))))
            up = qrot(turn, np.broadcast_to([0.0, 1.0, 0.0], (e - s + 1, 3)))
            tilt = np.degrees(np.arccos(np.clip(up[:, 1], -1.0, 1.0)))
            assert np.median(tilt) < 8.0, (name, s, e, np.median(tilt))
            checked += 1
    assert checked >= 6


def test_an_orientation_on_a_carried_joint_is_refused_by_the_engine_too():
    """``enforce`` given the carried joints refuses an orientation goal on one with a
    ConstraintError naming it (not a bare ValueError from the IK's task)."""
    from motion_composer.engine.correction.constraints import ConstraintError
    from motion_composer.engine.correction.enforcement import enforce
    from motion_composer.engine.conversion.followers import carriers
    scene = _walking_robot()
    turn = Constraint(joint="FootL", kind="orientation", goal={"quaternion": [0, 0, 0, 1]},
                      smooth_in=100, start=110, end=130, smooth_out=140, name="turn")
    with pytest.raises(ConstraintError, match="FootL is carried"):
        enforce(scene.edited, [turn], carried=carriers(scene.binding.followers))


@functools.lru_cache(maxsize=None)
def _robot_solved(clip):
    """``clip`` onto the robot with automatic contacts: ``(scene, solution)``."""
    target, performer = _character(ROBOT).rest_motion(), _performer(clip)
    project = Project(performer=Source(shared_path(clip)), target=Source(str(ROBOT)),
                      correspondence=automap(target.skeleton, performer.skeleton),
                      auto_contacts=True)
    scene = Scene(project, performer, target)
    return scene, scene.solve(regenerate=True)


def _sole_heights(motion, floor):
    """Per foot of the robot, the height over ``floor`` of the lowest vertex of its mesh (the
    vertices bound mostly to it, skinned as drawn) on each frame of ``motion``."""
    from motion_composer.engine.skinning import skin_character
    character = _character(ROBOT)
    sk = motion.skeleton
    lows = {}
    for mesh, vertices in zip(character.meshes, skin_character(character, motion)):
        main = mesh.joints[np.arange(len(mesh.joints)), np.argmax(mesh.weights, axis=1)]
        for foot in ("FootL", "FootR"):
            on = main == sk.index[foot]
            if on.any():
                low = vertices[:, on, 1].min(axis=1) - floor
                lows[foot] = np.minimum(lows.get(foot, low), low)
    return lows


@pytest.mark.parametrize("clip", ["bandai1_walk_normal_001.bvh", "cc3_cmu_02_01_walk.bvh"])
def test_the_robots_soles_stay_on_the_floor(clip):
    """The robot's feet have no toe joint and pitch with the performer's feet (its rigid
    foot is 0.95 m long): the direct conversion takes their tips 0.42 and 0.47 m under the
    floor, and held at the ankle alone, through heel-off and the swings, as deep. The floor
    constraint turns each foot back towards flat where its mesh would go under, just as far
    as it needs, eased over a quarter second: every vertex stays above the floor on every
    frame, within a millimetre; the feet are turned only within a quarter second of where
    they would go under; and no joint pops (raising the ankle there instead turned the legs
    1.12 times the limit, or, eased, floated the planted feet 17 cm). Without a floor the
    feet turn as converted, bit for bit."""
    scene, solution = _robot_solved(clip)
    sk = scene.target.skeleton
    floor = solution.scene.ground().floor
    followers = scene.binding.followers
    held = follow(followers, solution.scene.displacement.apply(scene.edited), scene.edited)
    direct, before, after = (_sole_heights(m, floor) for m in
                             (scene.composed, held, solution.motion))
    near = int(round(0.25 * scene.composed.fps))
    for foot in ("FootL", "FootR"):
        assert direct[foot].min() < -0.2 and before[foot].min() < -0.01
        assert after[foot].min() >= -1e-3, (foot, after[foot].min())
        j = sk.index[foot]
        turned = np.flatnonzero(np.any(solution.motion.rotations[:, j] != held.rotations[:, j],
                                       axis=-1))
        under = np.flatnonzero(before[foot] < -1e-9)
        assert len(turned) and all(np.abs(under - f).min() <= near for f in turned)
    assert max(p["ratio"] for p in solution.report["quality"]["pops"]) <= 1.0
    bare = Scene(scene.project.replace(auto_contacts=False), scene.performer, scene.target)
    np.testing.assert_array_equal(bare.motion.rotations, scene.composed.rotations)


def test_the_robots_feet_keep_their_turn_through_the_correction_not_through_a_layer():
    """The robot's feet hang from its root (``Bone``) and turn as the performer's feet. The
    IK turns the root a little to meet the contacts: the solved layer leaves the feet's
    world turn as converted (before, they swung with the root by up to 5.5 degrees, their
    0.95 m soles several centimetres into the floor). An animator's layer that turns the
    root turns them with it."""
    scene, solution = _robot_solved("cc3_cmu_02_01_walk.bvh")
    sk = scene.target.skeleton
    root = sk.index["Bone"]
    keyed = solution.scene.displacement.apply(scene.edited)
    edited_rot, _ = _world(scene.edited)
    solved_rot, _ = _world(follow(scene.binding.followers, keyed, scene.edited))
    swung_rot, _ = _world(follow(scene.binding.followers, keyed))
    assert _angle(solved_rot[:, root], edited_rot[:, root]).max() > 0.5     # the IK turned it
    for foot in ("FootL", "FootR"):
        j = sk.index[foot]
        assert _angle(solved_rot[:, j], edited_rot[:, j]).max() < 1e-5
        assert _angle(swung_rot[:, j], edited_rot[:, j]).max() > 0.5
    layer = Layer("turn the root", DisplacementMap({("Bone", "ry"): Curve(
        [0.0, 80.0, 170.0], [0.0, np.radians(30.0), 0.0], ("smooth",) * 3)}))
    turned_rot, _ = _world(scene.replace(layers=(layer,)).edited)
    for foot in ("FootL", "FootR"):
        j = sk.index[foot]
        np.testing.assert_allclose(_angle(turned_rot[80, j], edited_rot[80, j]), 30.0, atol=1e-6)


def _without_animations(path, out):
    """The GLB at ``path`` written to ``out`` with its animations removed: the character as
    it is often delivered, in its rest pose only."""
    import json
    import struct
    data = path.read_bytes()
    length = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20:20 + length])
    assert doc.pop("animations")
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<I4s", len(text), b"JSON") + text + data[20 + length:]
    out.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)
    return out


def test_a_character_without_animation_carries_its_feet_alike(tmp_path, capsys):
    """The robot delivered without its clips: no pose moves its feet, so the file gives them
    no translation channels, and they were left at the origin while the robot walked 5 m away
    from them. They are carried as the animated file's are: the binding gives them position
    channels, and the retarget (with automatic contacts, written and read back) puts every
    joint where the animated file's retarget does, bit for bit."""
    from motion_composer.app.cli import main
    bare = _without_animations(ROBOT, tmp_path / "robot_bare.glb")
    target = read_character(bare).rest_motion()
    sk = target.skeleton
    assert sk.index["FootL"] not in sk.translated and sk.index["FootR"] not in sk.translated
    performer = _performer("bandai1_walk_normal_001.bvh")
    correspondence = automap(sk, performer.skeleton)
    binding = bind(performer, target, correspondence)
    assert sorted(sk.names[f.joint] for f in binding.followers) == ["FootL", "FootR"]
    assert {"FootL", "FootR"} <= {binding.target.names[j] for j in binding.target.translated}
    full = _character(ROBOT).rest_motion()
    _, bare_pos = _world(retarget(performer, target, correspondence))
    _, full_pos = _world(retarget(performer, full, automap(full.skeleton,
                                                               performer.skeleton)))
    np.testing.assert_array_equal(bare_pos, full_pos)
    walk = clip_path("cmu_131_01_walk.bvh")
    worlds = []
    for name, character in (("bare", bare), ("full", ROBOT)):
        out = tmp_path / f"{name}.bvh"
        assert main(["retarget", str(walk), "--target", str(character), "-o", str(out),
                     "--auto-contacts"]) == 0, capsys.readouterr().err
        worlds.append(_world(read_motion(out))[1])
    np.testing.assert_array_equal(worlds[0], worlds[1])
    shin = worlds[0][:, sk.index["LowerLegL"]] - worlds[0][:, sk.index["FootL"]]
    assert np.ptp(np.linalg.norm(shin, axis=1)) < 1e-6


def _unreal_with_ik_bones_on_the_limbs():
    """The UE4 mannequin's names and IK bones (tests/test_automap.py), each IK bone where
    Unreal puts it: ``ik_foot_l`` on ``foot_l`` and ``ik_hand_gun`` on ``hand_r`` (both under
    IK roots at the origin), ``ik_hand_l`` on ``hand_l`` under the gun. Only the root and the
    pelvis translate (no clip of the file moves the IK bones)."""
    from motion_composer.engine.motion import Motion
    from motion_composer.engine.skeleton import Skeleton
    from test_automap import unreal_mannequin
    sk = unreal_mannequin()
    rest = np.tile([0.0, 0.0, 0.0, 1.0], (1, sk.num_joints, 1))
    pos = fk_arrays(sk, rest, sk.offsets[sk.translated][None]).positions[0]
    offsets = sk.offsets.copy()
    for bone, on in (("ik_foot_l", "foot_l"), ("ik_foot_r", "foot_r"),
                     ("ik_hand_gun", "hand_r"), ("ik_hand_l", "hand_l")):
        j = sk.index[bone]
        offsets[j] = pos[sk.index[on]] - pos[sk.parents[j]] - (
            0.0 if bone != "ik_hand_l" else pos[sk.index["hand_r"]] - pos[sk.parents[j]])
    sk = Skeleton(sk.names, sk.parents, offsets, sk.channels)
    return Motion(sk, rest, sk.offsets[sk.translated][None], 1 / 30, name="mannequin")


def test_unreals_ik_bones_follow_the_feet_and_hand_without_clips():
    """Unreal's IK bones hang under IK roots at the origin (``ik_foot_root``,
    ``ik_hand_root``), which follow nothing. A root that follows nothing does not hold back
    the bones under it: ``ik_foot_l`` follows ``foot_l``, ``ik_hand_gun`` follows ``hand_r``
    and ``ik_hand_l`` moves with the gun (a bone under a follower is not carried again),
    though no clip ever translated them. Retargeted, each stays on its limb on every
    frame, and ``ik_hand_l`` where it was on the gun."""
    target = _unreal_with_ik_bones_on_the_limbs()
    sk = target.skeleton
    performer = read_performer(clip_path("cmu_131_01_walk.bvh"))
    correspondence = automap(sk, performer.skeleton)
    binding = bind(performer, target, correspondence)
    carried = {sk.names[f.joint]: sk.names[f.anchor] for f in binding.followers}
    assert carried == {"ik_foot_l": "foot_l", "ik_foot_r": "foot_r", "ik_hand_gun": "hand_r"}
    motion = retarget(performer, target, correspondence)
    _, pos = _world(motion)
    assert np.ptp(pos[:, sk.index["pelvis"]], axis=0).max() > 1.0      # it walks
    for bone, on in (("ik_foot_l", "foot_l"), ("ik_foot_r", "foot_r"),
                     ("ik_hand_gun", "hand_r")):
        gap = np.linalg.norm(pos[:, sk.index[bone]] - pos[:, sk.index[on]], axis=1)
        assert gap.max() < 1e-9, (bone, gap.max())
    rot, _ = _world(motion)
    gun, hand = sk.index["ik_hand_gun"], sk.index["ik_hand_l"]
    on_gun = qrot(qconj(rot[:, gun]), pos[:, hand] - pos[:, gun])
    np.testing.assert_allclose(on_gun, np.broadcast_to(sk.offsets[hand], on_gun.shape),
                               atol=1e-9)
