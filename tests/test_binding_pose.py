"""The animator's hand on the binding (issue 18), the behaviour: pose offsets and chain
settings in the conversion, and chains' IK blends as reach goals in a solve.

Real clips of several conventions: CMU (bundled walk, T-pose character), Mixamo (Ely), CC3,
Bandai, FAIR and RobotExpressive from ../shared/data where present.
"""
from __future__ import annotations

import numpy as np
import pytest

from conftest import clip_path, shared_path
from motion_composer.engine.conversion import (BindOptions, ChainSettings, automap, bind,
                                               chains_of, euler_to_offset, mirrored_offset,
                                               retarget, transfer)
from motion_composer.engine.conversion.automap import identify
from motion_composer.engine.formats import read_motion
from motion_composer.engine.kinematics import forward_kinematics
from motion_composer.engine.project import Project, Source
from motion_composer.engine.quaternions import qconj, qmul, qslerp, twist_about
from motion_composer.engine.scene import Scene

#: (performer, target): bundled or shared files
PAIRS = [
    (("bundled", "cmu_131_01_walk.bvh"), ("bundled", "cmu_rest_tpose.bvh")),
    (("bundled", "cmu_131_01_walk.bvh"), ("shared", "target_mixamo_ely.glb")),
    (("shared", "bandai1_walk_normal_001.bvh"), ("shared", "cc3_cmu_02_01_walk.bvh")),
    (("shared", "cc3_cmu_02_06_pickup.bvh"), ("shared", "bandai1_kick_normal_001.bvh")),
    (("bundled", "fair1_child8_jumping.bvh"), ("shared", "target_robot_expressive.glb")),
]
IDS = [f"{p[1].split('.')[0]}->{t[1].split('.')[0]}" for p, t in PAIRS]


def _path(spec):
    where, name = spec
    return clip_path(name) if where == "bundled" else shared_path(name)


_CACHE: dict = {}


def _pair(performer, target):
    key = (performer, target)
    if key not in _CACHE:
        p, t = read_motion(_path(performer)), read_motion(_path(target))
        _CACHE[key] = (p, t, automap(t.skeleton, p.skeleton))
    return _CACHE[key]


def _same_rotation(a, b) -> np.ndarray:
    """How far unit quaternions ``a`` and ``b`` (``(..., 4)``) are apart, up to sign."""
    return np.minimum(np.linalg.norm(a - b, axis=-1), np.linalg.norm(a + b, axis=-1))


def _roles(motion, binding):
    return identify(motion.skeleton, binding.aligned_positions)


# --------------------------------------------------------------------------- pose offsets
@pytest.mark.parametrize("performer, target", PAIRS, ids=IDS)
def test_a_shoulder_offset_turns_that_local_rotation_only(performer, target):
    """10 degrees on a shoulder: that joint's local rotation is the converted one times the
    offset (in its binding frame) on every frame; every other local rotation and every
    translation stays as it was."""
    p, t, corr = _pair(performer, target)
    base_binding = bind(p, t, corr)
    shoulder = _roles(t, base_binding)["upper_arm_l"]
    q = euler_to_offset([0.0, 0.0, 10.0])
    base = transfer(base_binding, p)
    posed = retarget(p, t, corr, bind_options=BindOptions(pose_offsets={shoulder: tuple(q)}))
    j = t.skeleton.index[shoulder]
    want = qmul(base.rotations[:, j], q)
    assert _same_rotation(posed.rotations[:, j], want).max() < 1e-12
    turn = qmul(qconj(base.rotations[:, j]), posed.rotations[:, j])
    angle = np.degrees(2 * np.arccos(np.clip(np.abs(turn[:, 3]), 0, 1)))
    assert np.allclose(angle, 10.0, atol=1e-5)
    others = np.arange(t.skeleton.num_joints) != j
    assert _same_rotation(posed.rotations[:, others], base.rotations[:, others]).max() < 1e-12
    assert np.allclose(posed.translations, base.translations, atol=1e-12)
    # and the hand moved: the offset is visible
    hand = t.skeleton.index[_roles(t, base_binding)["hand_l"]]
    moved = np.linalg.norm(forward_kinematics(posed).positions[:, hand] -
                           forward_kinematics(base).positions[:, hand], axis=-1)
    assert moved.min() > 0.01


def test_offsets_on_several_joints_and_a_mirrored_one():
    """Offsets on a clavicle, a spine joint and a mirrored pair at once: each joint's local
    rotation is turned by its own offset, the right shoulder by the mirror of the left."""
    p, t, corr = _pair(("bundled", "cmu_131_01_walk.bvh"), ("shared", "target_mixamo_ely.glb"))
    plain = bind(p, t, corr)
    roles = _roles(t, plain)
    left = roles["upper_arm_l"]
    q = euler_to_offset([15.0, -5.0, 20.0])
    right, mirrored = mirrored_offset(bind(p, t, corr, BindOptions(pose_offsets={
        left: tuple(q)})), left, q)
    assert right == roles["upper_arm_r"]
    offsets = {left: tuple(q), right: tuple(mirrored),
               roles["clavicle_r"]: tuple(euler_to_offset([0, 8, 0])),
               roles.spine[0]: tuple(euler_to_offset([-6, 0, 0]))}
    base = transfer(plain, p)
    posed = retarget(p, t, corr, bind_options=BindOptions(pose_offsets=offsets))
    for name, offset in offsets.items():
        j = t.skeleton.index[name]
        assert _same_rotation(posed.rotations[:, j],
                              qmul(base.rotations[:, j], offset)).max() < 1e-12, name
    rest = [t.skeleton.index[n] for n in t.skeleton.names if n not in offsets]
    assert _same_rotation(posed.rotations[:, rest], base.rotations[:, rest]).max() < 1e-12


# --------------------------------------------------------------------------- chain settings
@pytest.mark.parametrize("performer, target", PAIRS, ids=IDS)
def test_weight_zero_keeps_the_binding_pose_of_the_chain(performer, target):
    p, t, corr = _pair(performer, target)
    options = BindOptions(chains={"arm_l": ChainSettings(weight=0.0)},
                          pose_offsets={_roles(t, bind(p, t, corr))["forearm_l"]:
                                        tuple(euler_to_offset([0, 20, 0]))})
    binding = bind(p, t, corr, options)
    arm = [t.skeleton.index[n] for n in chains_of(t.skeleton, binding.aligned_positions)
           ["arm_l"]]
    moved = transfer(binding, p)
    assert list(binding.held) == arm
    assert np.array_equal(moved.rotations[:, arm],
                          np.broadcast_to(binding.rest_local[arm], moved.rotations[:, arm].shape))
    from motion_composer.engine.conversion import compose, convert
    composed = compose(binding, convert(binding, p), p.frame_time)  # the scene's stages
    assert np.array_equal(composed.rotations, moved.rotations)
    # the rest of the body is what it is without the setting (offset included)
    full = retarget(p, t, corr, bind_options=options.with_chain("arm_l", None))
    others = np.setdiff1d(np.arange(t.skeleton.num_joints), arm)
    assert _same_rotation(moved.rotations[:, others], full.rotations[:, others]).max() < 1e-12
    assert not np.allclose(full.rotations[:, arm], binding.rest_local[arm], atol=1e-3)


def test_a_weight_between_slerps_each_local_rotation():
    p, t, corr = _pair(("bundled", "cmu_131_01_walk.bvh"), ("bundled", "cmu_rest_tpose.bvh"))
    options = BindOptions(chains={"leg_r": ChainSettings(weight=0.3)})
    binding = bind(p, t, corr, options)
    leg = [t.skeleton.index[n] for n in chains_of(t.skeleton)["leg_r"]]
    full = retarget(p, t, corr)
    part = transfer(binding, p)
    for j in leg:
        want = qslerp(np.broadcast_to(binding.rest_local[j], full.rotations[:, j].shape),
                      full.rotations[:, j], 0.3)
        assert _same_rotation(part.rotations[:, j], want).max() < 1e-12
    others = np.setdiff1d(np.arange(t.skeleton.num_joints), leg)
    assert _same_rotation(part.rotations[:, others], full.rotations[:, others]).max() < 1e-12


@pytest.mark.parametrize("performer, target", PAIRS[:3], ids=IDS[:3])
def test_twist_off_keeps_the_binding_twist(performer, target):
    """With twist off, each arm joint's rotation relative to the binding has no twist about
    its bone and the same swing as the full conversion's."""
    p, t, corr = _pair(performer, target)
    binding = bind(p, t, corr, BindOptions(chains={"arm_r": ChainSettings(twist=False)}))
    arm = [t.skeleton.index[n] for n in chains_of(t.skeleton, binding.aligned_positions)
           ["arm_r"]]
    full = retarget(p, t, corr)
    untwisted = transfer(binding, p)
    sk = t.skeleton
    twisted_somewhere = 0.0
    for j in arm:
        kids = sk.children[j]
        if not kids:
            continue
        subtree = {c: len([k for k in range(sk.num_joints) if c in sk.ancestors(k)])
                   for c in kids}
        bone = sk.offsets[max(kids, key=lambda c: subtree[c])]
        if np.linalg.norm(bone) < 1e-9:
            continue
        axis = bone / np.linalg.norm(bone)
        rest = binding.rest_local[j]
        change = qmul(qconj(rest), untwisted.rotations[:, j])
        twist = twist_about(change, axis)
        assert np.abs(twist[:, :3]).max() < 1e-9
        full_change = qmul(qconj(rest), full.rotations[:, j])
        swing = qmul(full_change, qconj(twist_about(full_change, axis)))
        assert _same_rotation(change, swing).max() < 1e-9
        twisted_somewhere = max(twisted_somewhere,
                                np.abs(twist_about(full_change, axis)[:, :3]).max())
    assert twisted_somewhere > 1e-3                  # the performer's twist was there to drop


def test_a_chains_own_distribution_overrides_the_global_one():
    """CC3's spine has more joints than Bandai's maps: "first" on the spine chain alone
    turns it as the global "first" does, and leaves the rest as "even"."""
    p, t, corr = _pair(*PAIRS[2])
    spine = [t.skeleton.index[n] for n in chains_of(t.skeleton)["spine"]]
    first = retarget(p, t, corr, bind_options=BindOptions(distribute="first"))
    even = retarget(p, t, corr)
    own = retarget(p, t, corr, bind_options=BindOptions(
        chains={"spine": ChainSettings(distribute="first")}))
    assert np.abs(first.rotations[:, spine] - even.rotations[:, spine]).max() > 1e-3
    assert _same_rotation(own.rotations[:, spine], first.rotations[:, spine]).max() < 1e-12
    back = retarget(p, t, corr, bind_options=BindOptions(
        distribute="first", chains={"spine": ChainSettings(distribute="even")}))
    assert _same_rotation(back.rotations[:, spine], even.rotations[:, spine]).max() < 1e-12


def test_default_settings_change_nothing_bit_for_bit():
    p, t, corr = _pair(("bundled", "cmu_131_01_walk.bvh"), ("bundled", "cmu_rest_tpose.bvh"))
    base = retarget(p, t, corr)
    same = retarget(p, t, corr, bind_options=BindOptions(
        chains={c: ChainSettings() for c in ("arm_l", "leg_r", "spine")},
        pose_offsets={"LeftArm": (0.0, 0.0, 0.0, 1.0)}))
    assert np.array_equal(base.rotations, same.rotations)
    assert np.array_equal(base.translations, same.translations)


# --------------------------------------------------------------------------- IK blend
def _scene(performer, target, options, **project):
    p, t, corr = _pair(performer, target)
    return Scene(Project(performer=Source(str(_path(performer))),
                         target=Source(str(_path(target))), correspondence=corr,
                         bind_options=options, **project), p, t)


def _reachable(pos, sk, chain_root: str, goal: np.ndarray, joint: str) -> np.ndarray:
    """Frames whose goal lies within the chain's length (less a millimetre) from its root's
    position in ``pos`` ``(F, J, 3)``."""
    top, end = sk.index[chain_root], sk.index[joint]
    length = 0.0
    k = end
    while k != top:
        length += np.linalg.norm(sk.offsets[k])
        k = sk.parents[k]
    return np.linalg.norm(goal - pos[:, top], axis=1) < length - 1e-3


@pytest.mark.parametrize("performer, target", [PAIRS[1], PAIRS[4]], ids=[IDS[1], IDS[4]])
def test_ik_blend_one_puts_the_hand_on_the_performers_scaled_hand(performer, target):
    scene = _scene(performer, target, BindOptions(chains={"arm_l": ChainSettings(ik_blend=1)}))
    solution = scene.solve()
    (reach,) = solution.constraints
    assert reach.name == "reach arm_l" and reach.auto and reach.kind == "trajectory"
    assert (reach.start, reach.end) == (0, scene.num_frames - 1)
    binding = scene.binding
    roles = _roles(scene.target, binding)
    hand = roles.get("hand_l", reach.joint)
    assert reach.joint == hand
    # the goal is the performer's hand about the character's root, scaled as the root motion
    p_pos = forward_kinematics(scene.performer).positions
    t_pos = forward_kinematics(scene.composed).positions
    p_hand = scene.performer.skeleton.index[scene.correspondence.pairs[hand]]
    p_root = binding.mapped[binding.body_root]
    want = (t_pos[:, binding.body_root] +
            binding.hip_height_ratio * (p_pos[:, p_hand] - p_pos[:, p_root]))
    assert np.allclose(reach.goal["points"], want, atol=1e-12)
    # without contacts the whole body may move: every frame is reachable
    got = forward_kinematics(solution.motion).positions[:, scene.target.skeleton.index[hand]]
    err = np.linalg.norm(got - want, axis=1)
    assert err.max() < 1e-3
    before = np.linalg.norm(t_pos[:, scene.target.skeleton.index[hand]] - want, axis=1)
    assert before.mean() > 0.01                       # it had somewhere to go


def test_ik_blend_between_and_below_the_contacts():
    scene = _scene(("bundled", "cmu_131_01_walk.bvh"), ("bundled", "cmu_rest_tpose.bvh"),
                   BindOptions(chains={"arm_r": ChainSettings(ik_blend=0.5),
                                       "leg_l": ChainSettings(ik_blend=0.25)}),
                   auto_contacts=True)
    solution = scene.solve(regenerate=True)
    reach = {c.name: c for c in solution.constraints if c.meta.get("source") == "reach"}
    assert set(reach) == {"reach arm_r", "reach leg_l"}
    contacts = [c for c in solution.constraints if c.meta.get("source") == "contact"]
    assert contacts
    lowest = max(c.priority for c in contacts)
    assert all(c.priority == lowest + 1 for c in reach.values())
    t_pos = forward_kinematics(scene.composed).positions
    binding = scene.binding
    from motion_composer.engine.correction.reach import reach_goal
    for c in reach.values():
        j = scene.target.skeleton.index[c.joint]
        blend = c.meta["ik_blend"]
        scaled = reach_goal(binding, scene.performer, scene.composed, c.joint)
        assert np.allclose(c.goal["points"], t_pos[:, j] + blend * (scaled - t_pos[:, j]),
                           atol=1e-12)
    # solved again, the goals are made again (not doubled); blend 0 removes them
    again = solution.scene.solve()
    assert sorted(c.name for c in again.constraints if c.meta.get("source") == "reach") == \
        ["reach arm_r", "reach leg_l"]
    off = solution.scene.replace(bind_options=BindOptions()).solve()
    assert not [c for c in off.constraints if c.meta.get("source") == "reach"]
    assert len(off.constraints) == len(solution.constraints) - 2


def test_an_ik_blend_on_an_unmapped_effector_warns():
    p, t, corr = _pair(("bundled", "cmu_131_01_walk.bvh"), ("bundled", "cmu_rest_tpose.bvh"))
    hand = identify(t.skeleton)["hand_l"]
    pairs = {k: v for k, v in corr.pairs.items() if k != hand}
    from motion_composer.engine.conversion import Correspondence
    scene = Scene(Project(performer=Source(str(clip_path("cmu_131_01_walk.bvh"))),
                          target=Source(str(clip_path("cmu_rest_tpose.bvh"))),
                          correspondence=Correspondence(pairs),
                          bind_options=BindOptions(chains={"arm_l":
                                                           ChainSettings(ik_blend=1)})), p, t)
    solution = scene.solve()
    assert not solution.constraints
    assert any("arm_l" in w and "not mapped" in w for w in solution.report["warnings"])


def test_ik_blend_below_pinned_feet_reaches_where_the_arm_can():
    """With the feet held by contacts, the hand reaches its goal wherever the solved shoulder
    lets it and the contacts above it are met (the IK runs a lower level only once the
    higher ones are nearly met: :class:`IKOptions.priority_gate`). A leg's reach on the same
    level would share that level's compromise with the pinned foot, so the arm is alone."""
    scene = _scene(("bundled", "cmu_131_01_walk.bvh"), ("bundled", "cmu_rest_tpose.bvh"),
                   BindOptions(chains={"arm_r": ChainSettings(ik_blend=1.0)}),
                   auto_contacts=True)
    solution = scene.solve(regenerate=True)
    (c,) = [c for c in solution.constraints if c.meta.get("source") == "reach"]
    solved = forward_kinematics(solution.motion).positions
    sk = scene.target.skeleton
    shoulder = _roles(scene.target, scene.binding)["upper_arm_r"]
    met = np.ones(scene.num_frames, dtype=bool)
    for i, other in enumerate(solution.constraints):
        if other.priority < c.priority:
            met &= ~(solution.correction.residual[i] > 5e-4)        # NaN: not active there
    ok = _reachable(solved, sk, shoulder, c.goal["points"], c.joint) & met
    assert ok.mean() > 0.5
    err = np.linalg.norm(solved[:, sk.index[c.joint]] - c.goal["points"], axis=1)
    assert err[ok].max() < 1e-3
    before = forward_kinematics(scene.composed).positions[:, sk.index[c.joint]]
    assert np.linalg.norm(before - c.goal["points"], axis=1)[ok].mean() > 0.01


# --------------------------------------------------------------------------- scene, files
def test_a_saved_posed_project_gives_the_same_motion_bit_for_bit(tmp_path):
    from motion_composer.engine.project import open_project, save_project
    options = BindOptions(pose_offsets={"LeftArm": tuple(euler_to_offset([3, -2, 11]))},
                          chains={"arm_r": ChainSettings(weight=0.4, twist=False),
                                  "leg_l": ChainSettings(ik_blend=0.5)})
    scene = _scene(("bundled", "cmu_131_01_walk.bvh"), ("bundled", "cmu_rest_tpose.bvh"),
                   options, auto_contacts=True)
    solved = scene.solve(regenerate=True).scene
    path = tmp_path / "posed.mcp"
    save_project(solved.project, path)
    opened = open_project(path)
    assert opened.project.bind_options == options
    again = Scene(opened.project, opened.performer, opened.target)
    assert np.array_equal(again.motion.rotations, solved.motion.rotations)
    assert np.array_equal(again.motion.translations, solved.motion.translations)
    assert [c.name for c in again.constraints] == [c.name for c in solved.constraints]
    save_project(again.project, tmp_path / "again.mcp")
    assert (tmp_path / "again.mcp").read_bytes() == path.read_bytes()


def test_an_offset_edit_binds_again_and_undoing_it_hits_the_cache():
    scene = _scene(("bundled", "cmu_131_01_walk.bvh"), ("bundled", "cmu_rest_tpose.bvh"),
                   BindOptions())
    base = scene.motion
    assert scene.derived.computed["binding"] == 1
    q = tuple(euler_to_offset([0, 0, 10]))
    posed = scene.replace(bind_options=scene.bind_options.with_offset("LeftArm", q))
    assert not np.array_equal(posed.motion.rotations, base.rotations)
    assert scene.derived.computed["binding"] == 2
    back = posed.replace(bind_options=posed.bind_options.without_offsets())
    assert back.motion is base and scene.derived.computed["binding"] == 2
