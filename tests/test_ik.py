"""Constraints over time on real clips: goals met, ramps smooth, nothing touched outside."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from motion_composer.engine import forward_kinematics
from motion_composer.engine.conversion import retarget
from motion_composer.engine.correction.constraints import Constraint, ConstraintError, constraints_from_json, \
    constraints_to_json, floor_constraint
from motion_composer.engine.correction.contacts import contact_constraints, detect_contacts, horizontal_drift
from motion_composer.engine.correction.enforcement import enforce
from motion_composer.engine.correction.ik import IKOptions
from motion_composer.engine.quaternions import qmul
from motion_composer.engine.rotations import angle_between
from ik_fixtures import run_on_bandai, walk_on_bandai, walk_on_holden, walk_window_on_tpose


def _pos(motion, joint):
    return forward_kinematics(motion).positions[:, motion.skeleton.index[joint]]


def _max_turn_rate(motion):
    """Largest local rotation change between consecutive frames, per joint [rad/frame]."""
    q = motion.rotations
    return angle_between(q[1:], q[:-1]).max(axis=0)


@pytest.fixture(scope="module")
def hand_case():
    performer, target, corr, composed = walk_on_holden()
    goal = _pos(composed, "LeftHand")[420] + [0.12, 0.20, 0.08]
    c = Constraint("LeftHand", "position", {"point": goal}, 380, 420, 520, 570,
                   name="reach")
    return composed, c, enforce(composed, [c])


def test_a_reachable_goal_is_met_within_a_millimetre_on_every_active_frame(hand_case):
    composed, c, result = hand_case
    err = np.linalg.norm(_pos(result.motion, "LeftHand")[c.start:c.end + 1] - c.goal["point"],
                         axis=1)
    assert err.max() < 1e-3
    assert np.nanmax(result.residual[0][c.start:c.end + 1]) < 1e-3


def test_outside_every_range_the_result_is_the_direct_conversion_exactly(hand_case):
    composed, c, result = hand_case
    outside = np.r_[0:c.smooth_in, c.smooth_out + 1:composed.num_frames]
    np.testing.assert_array_equal(result.motion.rotations[outside], composed.rotations[outside])
    np.testing.assert_array_equal(result.motion.translations[outside],
                                  composed.translations[outside])
    assert np.all(result.rotvecs[outside] == 0) and np.all(result.root[outside] == 0)


def test_the_composed_motion_itself_never_changes(hand_case):
    composed, c, result = hand_case
    before = composed.rotations.copy()
    enforce(composed, [c])
    np.testing.assert_array_equal(composed.rotations, before)
    assert not composed.rotations.flags.writeable


def test_no_pops_at_the_ramp_boundaries(hand_case):
    composed, c, result = hand_case
    source = _max_turn_rate(composed).max()
    rate = _max_turn_rate(result.motion)
    bound = max(source, np.radians(3.0))          # 3 degrees a frame at 120 fps
    assert rate.max() <= bound, (np.degrees(rate.max()), np.degrees(source))


def test_the_input_ramp_eases_the_correction_in_along_a_smoothstep(hand_case):
    """Issue 14 point 2: on an input ramp the correction is the key posture's (the one that
    holds the goal at ``start``) times a smoothstep of the ramp's fraction (zero slope at both
    ends: the correction neither jumps nor kinks where the ramp begins or where the range
    starts), ``exp(s r) direct``, the form the no-pop limit is built on."""
    composed, c, result = hand_case
    key = result.rotvecs[c.start]
    assert np.abs(key).max() > 0.01
    for f in (c.smooth_in + 1, (c.smooth_in + c.start) // 2, c.start - 1):
        u = (f - c.smooth_in) / (c.start - c.smooth_in)
        share = u * u * (3 - 2 * u)
        np.testing.assert_allclose(result.rotvecs[f], share * key, atol=1e-9)
    goal = np.linalg.norm(_pos(result.motion, "LeftHand")[c.start] - c.goal["point"])
    assert goal < 1e-3


def test_the_output_ramp_eases_the_correction_out_and_leaves_other_joints_alone(hand_case):
    composed, c, result = hand_case
    sk = composed.skeleton
    j = sk.index["LeftHand"]
    chain = sorted(sk.ancestors(j) + [j])
    key = result.rotvecs[c.end]
    for f in (c.end + 1, (c.end + c.smooth_out) // 2, c.smooth_out - 1):
        u = (f - c.end) / (c.smooth_out - c.end)
        share = 1 - u * u * (3 - 2 * u)
        np.testing.assert_allclose(result.rotvecs[f], share * key, atol=1e-9)
    others = [k for k in range(sk.num_joints) if k not in chain]
    np.testing.assert_array_equal(result.motion.rotations[c.end + 1:c.smooth_out, others],
                                  composed.rotations[c.end + 1:c.smooth_out, others])


def test_batches_and_the_papers_warm_start_reach_the_same_posture(hand_case):
    composed, c, result = hand_case
    short = c.with_range(400, 410, 430, 440)
    a = enforce(composed, [short])
    b = enforce(composed, [short], warm_start=True)
    assert np.abs(a.rotvecs - b.rotvecs).max() < 1e-3
    assert np.linalg.norm(_pos(b.motion, "LeftHand")[410:431] - c.goal["point"], axis=1).max() \
        < 1e-3


@pytest.mark.parametrize("frames", [(190, 240), (150, 300)])
def test_the_papers_warm_start_and_the_batches_agree_with_automatic_contacts(frames):
    """Issue 19 point 5 on a real clip: feet pinned heel and toe, foot-flat orientations one
    priority lower and whole-clip floors (one-sided planes that hold a joint once it touches
    them). Frame by frame from t - 1 and in batches from the attraction posture, the solver
    reaches the same posture: the one nearest the attraction that meets the tasks (a floor
    that held a toe while the posture no longer pushes it down lets it go). On 150-300 ramps
    overlap: a ramp frame's posture with a ramp's goal held starts from the frame before's
    posture with the same goals held (3.5 mm apart when it started from another one's)."""
    performer, target, corr, _ = walk_on_bandai()
    performer = performer.frames(slice(*frames))
    composed = retarget(performer, target, corr)
    cons = contact_constraints(detect_contacts(performer), performer, composed, corr.pairs)
    assert {"position", "orientation", "plane"} <= {c.kind for c in cons}
    batched = enforce(composed, cons)
    framewise = enforce(composed, cons, warm_start=True)
    a, b = (forward_kinematics(r.motion).positions for r in (batched, framewise))
    assert np.linalg.norm(a - b, axis=-1).max() < 1e-3
    for result in (batched, framewise):
        for i, c in enumerate(cons):
            if c.kind == "position":
                assert np.nanmax(result.residual[i][c.start:c.end + 1]) < 1e-3, c.name


def test_an_unreachable_goal_stops_at_the_closest_posture_and_reports_the_residual():
    """Both feet pinned where they stand (first priority), the left hand asked to go 3 m
    away (second): the root cannot follow, the arm reaches out as far as it can."""
    performer, target, corr, composed = walk_on_holden()
    feet = [Constraint(foot, "position", {"point": _pos(composed, foot)[300]}, 300, 300, 320,
                       320, name=foot) for foot in ("LeftFoot", "RightFoot")]
    far = _pos(composed, "LeftHand")[300] + [3.0, 0.0, 0.0]
    hand = Constraint("LeftHand", "position", {"point": far}, 300, 300, 320, 320, priority=2)
    result = enforce(composed, feet + [hand], options=IKOptions(scale=1.7, max_iterations=80))
    assert np.all(np.isfinite(result.motion.rotations))
    assert np.all(np.isfinite(result.motion.translations))
    for i in (0, 1):
        assert np.nanmax(result.residual[i][300:321]) < 1e-3
    res = result.residual[2][300:321]
    assert np.all(np.isfinite(res)) and res.min() > 1.0
    reached = np.linalg.norm(_pos(result.motion, "LeftHand")[300:321] - far, axis=1)
    before = np.linalg.norm(_pos(composed, "LeftHand")[300:321] - far, axis=1)
    assert np.all(reached < before - 0.2)                   # it reached out as far as it could
    np.testing.assert_allclose(res, reached, atol=1e-6)


def test_a_higher_priority_wins_a_conflict():
    performer, target, corr, composed = walk_on_holden()
    here = _pos(composed, "LeftHand")[500]
    up = Constraint("LeftHand", "position", {"point": here + [0, 0.5, 0]}, 500, 500, 510, 510,
                    priority=1, name="up")
    down = Constraint("LeftHand", "position", {"point": here + [0, -0.5, 0]}, 500, 500, 510,
                      510, priority=2, name="down")
    result = enforce(composed, [up, down])
    assert np.nanmax(result.residual[0][500:511]) < 1e-3
    assert np.nanmin(result.residual[1][500:511]) > 0.9
    swapped = enforce(composed, [up.with_priority(2), down.with_priority(1)])
    assert np.nanmax(swapped.residual[1][500:511]) < 1e-3


def test_a_floor_plane_is_never_violated_inside_its_range_and_does_not_pull_above_it():
    performer, target, corr, composed = walk_on_holden()
    toe = _pos(composed, "LeftToeBase")[:, 1]
    floor_height = float(np.percentile(toe, 30))                     # the toe dips below it
    c = floor_constraint("LeftToeBase", composed.num_frames, floor_height)
    result = enforce(composed, [c])
    after = _pos(result.motion, "LeftToeBase")[:, 1]
    assert after.min() > floor_height - 1e-3
    assert np.sum(toe < floor_height - 0.005) > 50                   # a real correction
    free = toe > floor_height + 0.02                                  # already clear: untouched
    np.testing.assert_allclose(after[free], toe[free], atol=1e-3)


def test_every_floor_holds_where_another_floor_pushes():
    """The bundled walk's frames 200-399 onto the bundled T-pose with automatic contacts and
    the floor at 0 (the capture walks 0.9 m under it there). On frame 25 the right foot's
    floor pushes and nothing else is held; the left foot's floor, clear at the start, was
    left out of that solve, which sank the left ankle 49 mm through it while its residual
    said 0. Every floor holds on every frame, and the residuals say what the motion shows."""
    solution = walk_window_on_tpose(200, 400)
    dense = solution.correction.motion
    active = [c for c in solution.constraints if c.enabled]
    floors = [(i, c) for i, c in enumerate(active) if c.kind == "plane"]
    assert len(floors) >= 4
    pushed = 0
    for i, c in floors:
        height = _pos(solution.scene.composed, c.joint)[:, 1] - c.goal["point"][1]
        pushed += int(np.sum(height < -0.01))
        depth = c.goal["point"][1] - _pos(dense, c.joint)[:, 1]
        assert depth.max() < 1e-3, (c.name, int(depth.argmax()), depth.max())
        reported = np.nan_to_num(solution.correction.residual[i], nan=0.0)
        assert np.all(reported >= depth - 1e-6), c.name
    assert pushed > 100                                # a real lift, on many frames


def test_overlapping_constraints_on_both_hands_are_both_met():
    performer, target, corr, composed = walk_on_holden()
    left = _pos(composed, "LeftHand")[300] + [0.1, 0.15, 0.0]
    right = _pos(composed, "RightHand")[340] + [-0.1, 0.1, 0.05]
    a = Constraint("LeftHand", "position", {"point": left}, 260, 300, 380, 420)
    b = Constraint("RightHand", "position", {"point": right}, 300, 340, 400, 440)
    result = enforce(composed, [a, b])
    assert np.linalg.norm(_pos(result.motion, "LeftHand")[300:381] - left, axis=1).max() < 1e-3
    assert np.linalg.norm(_pos(result.motion, "RightHand")[340:401] - right, axis=1).max() < 1e-3
    rate = _max_turn_rate(result.motion).max()
    assert rate <= max(_max_turn_rate(composed).max(), np.radians(3.0))


def test_an_orientation_and_a_trajectory():
    performer, target, corr, composed = walk_on_holden()
    pose = forward_kinematics(composed)
    j = composed.skeleton.index["RightHand"]
    goal_q = qmul([0, 0, np.sin(0.3), np.cos(0.3)], pose.rotations[450, j])
    o = Constraint("RightHand", "orientation", {"quaternion": goal_q}, 430, 450, 470, 490)
    path = pose.positions[600:641, j] + [0.0, 0.1, 0.0]
    t = Constraint("RightHand", "trajectory", {"points": path}, 580, 600, 640, 660)
    result = enforce(composed, [o, t])
    got = forward_kinematics(result.motion)
    assert np.degrees(angle_between(got.rotations[450:471, j], goal_q)).max() < 0.1
    assert np.linalg.norm(got.positions[600:641, j] - path, axis=1).max() < 1e-3


def test_joint_limits_hold():
    performer, target, corr, composed = walk_on_holden()
    sk = composed.skeleton
    goal = _pos(composed, "LeftHand")[200] + [0.2, 0.3, 0.1]
    c = Constraint("LeftHand", "position", {"point": goal}, 200, 200, 220, 220)
    limit = np.radians(5)
    elbow = sk.index["LeftForeArm"]
    result = enforce(composed, [c], options=IKOptions(scale=1.7, joint_limits={elbow: limit}))
    turn = angle_between(result.motion.rotations[200:221, elbow],
                         composed.rotations[200:221, elbow])
    assert turn.max() <= limit + 1e-6


# --------------------------------------------------------------------------- contacts
@pytest.mark.parametrize("case", [walk_on_holden, walk_on_bandai, run_on_bandai],
                         ids=["walk-bundled", "walk-bandai", "run-bandai"])
def test_automatic_contacts_stop_the_planted_foot_sliding(case, record_property):
    performer, target, corr, composed = case()
    contacts = detect_contacts(performer)
    assert len(contacts) >= 2
    cons = contact_constraints(contacts, performer, composed, corr.pairs)
    result = enforce(composed, cons)
    pins = [c for c in cons if c.kind == "position"]
    direct = [horizontal_drift(composed, c.joint, c.start, c.end) for c in pins]
    fixed = [horizontal_drift(result.motion, c.joint, c.start, c.end) for c in pins]
    record_property("drift_direct_mean_m", float(np.mean(direct)))
    record_property("drift_ik_mean_m", float(np.mean(fixed)))
    print(f"\n{case.__name__}: {len(pins)} contacts; planted-foot drift: direct conversion "
          f"mean {np.mean(direct) * 1000:.1f} mm (max {np.max(direct) * 1000:.1f}), with "
          f"contacts mean {np.mean(fixed) * 1000:.2f} mm (max {np.max(fixed) * 1000:.2f})")
    assert np.mean(fixed) < 0.1 * np.mean(direct)
    for i, c in enumerate(cons):
        res = result.residual[i][c.start:c.end + 1]
        assert np.nanmax(res) < 1e-3, c.name
    # no joint turns faster than the conversion's fastest turn (the run's fastest is a joint
    # the contacts leave alone: the same turn to rounding) or 3 degrees a frame at 120 fps
    rate = _max_turn_rate(result.motion).max()
    assert rate <= max(_max_turn_rate(composed).max() + 1e-12,
                       np.radians(3.0) * 120 * composed.frame_time)


# --------------------------------------------------------------------------- the model
def test_constraint_ranges_and_fields_are_validated():
    with pytest.raises(ConstraintError, match="smooth_in <= start <= end <= smooth_out"):
        Constraint("Hips", "position", {"point": [0, 0, 0]}, 10, 5, 20, 30)
    with pytest.raises(ConstraintError, match="kind must be one of"):
        Constraint("Hips", "glue", {"point": [0, 0, 0]}, 0, 0, 1, 1)
    with pytest.raises(ConstraintError, match="goal.point must be 3 numbers"):
        Constraint("Hips", "position", {"point": [0, "a", 0]}, 0, 0, 1, 1)
    with pytest.raises(ConstraintError, match="one \\[x, y, z\\] per frame"):
        Constraint("Hips", "trajectory", {"points": [[0, 0, 0]]}, 0, 0, 5, 5)
    with pytest.raises(ConstraintError, match="priority"):
        Constraint("Hips", "position", {"point": [0, 0, 0]}, 0, 0, 1, 1, priority=0)
    with pytest.raises(ConstraintError, match="goal.side"):
        Constraint("Hips", "plane", {"point": [0, 0, 0], "side": "beside"}, 0, 0, 1, 1)
    composed = walk_on_holden()[3]
    with pytest.raises(ConstraintError, match="not a joint of the target"):
        enforce(composed, [Constraint("Tail", "position", {"point": [0, 0, 0]}, 0, 0, 1, 1)])
    with pytest.raises(ConstraintError, match="past the last frame"):
        enforce(composed, [Constraint("Hips", "position", {"point": [0, 0, 0]}, 0, 0, 1,
                                      10**6)])


@pytest.mark.parametrize("constraint", [
    Constraint("LeftHand", "position", {"point": [0.3, -0.1, 0.2]}, 280, 290, 310, 320),
    Constraint("LeftHand", "trajectory", {"keys": [[290, 0.3, -0.1, 0.2], [310, 0.4, 0.0, 0.2]]},
               280, 290, 310, 320, name="path"),
    Constraint("LeftFoot", "plane", {"point": [0, 0.92, 0], "normal": [0.1, 1, 0],
                                     "side": "above"}, 0, 0, 99, 99, auto=True)],
    ids=["position", "trajectory", "plane"])
def test_a_goal_moved_there_and_back_is_the_same_constraint(constraint):
    """``Constraint.same_as``: moved up by a floor's lift and down again, a goal ends a few ulps
    off and is the same constraint (the window's undo merge drops such a step); a millimetre
    off, another range or another flag is not."""
    back = constraint.moved([0.0, 0.9217, 0.0]).moved([0.0, -0.9217, 0.0])
    assert back is not constraint and back.same_as(constraint)
    assert not constraint.moved([0.0, 1e-3, 0.0]).same_as(constraint)
    assert not constraint.with_range(280, 291, 310, 320).same_as(constraint)
    assert not dataclasses.replace(constraint, enabled=False).same_as(constraint)
    assert not constraint.same_as(constraint.to_dict())


def test_constraints_round_trip_through_json():
    cons = [Constraint("LeftHand", "position", {"point": [0.1, 1.2, 0.3]}, 1, 2, 3, 4,
                       priority=2, weight=0.5, name="cup"),
            Constraint("LeftToeBase", "plane", {"point": [0, 0.01, 0], "normal": [0, 2, 0],
                                                "side": "above"}, 0, 0, 9, 9),
            Constraint("Head", "orientation", {"quaternion": [0, 0, 0, 2]}, 3, 4, 5, 6),
            Constraint("RightHand", "trajectory", {"keys": [[0, 0, 1, 0], [10, 1, 1, 0]]},
                       0, 0, 10, 12, enabled=False)]
    back = constraints_from_json(constraints_to_json(cons))
    assert [c.to_dict() for c in back] == [c.to_dict() for c in cons]
    assert back[1].goal["normal"].tolist() == [0, 1, 0]
    with pytest.raises(ConstraintError, match="line 1"):
        constraints_from_json('{"constraints": [}')
    with pytest.raises(ConstraintError, match="constraint 1: the field 'range' is missing"):
        constraints_from_json('{"constraints": [{"joint": "a", "kind": "position", '
                              '"goal": {"point": [0,0,0]}}]}')
