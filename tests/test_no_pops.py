"""Issue 14 point 2, degenerate ramps: a constraint whose ramps are one frame long (or whose
active range is one frame between one-frame ramps) is solved without a pop, by the no-pop
rule of :mod:`engine.correction.quality` (over a one-frame span a smoothstep may turn the
whole correction in that frame, times 1.5), on a real walk; the goal is still met."""
from __future__ import annotations

import functools

import numpy as np
import pytest

from conftest import shared_path
from ik_fixtures import walk_on_holden
from motion_composer.engine import forward_kinematics
from motion_composer.engine.conversion.automap import automap
from motion_composer.engine.conversion.binding import BindOptions
from motion_composer.engine.correction import enforcement
from motion_composer.engine.correction.constraints import Constraint, ConstraintError
from motion_composer.engine.correction.enforcement import enforce
from motion_composer.engine.correction.ik import column_scale, quat_to_rotvec
from motion_composer.engine.correction.preview import WindowSolver
from motion_composer.engine.correction.quality import angular_speed, pop_limits, quality, ramps
from motion_composer.engine.formats import read_character, read_performer
from motion_composer.engine.project import Project, Source
from motion_composer.engine.quaternions import qconj, qmul, qnormalize
from motion_composer.engine.scene import Scene


@pytest.mark.parametrize("frames", [(199, 200, 240, 241), (199, 200, 200, 201)],
                         ids=["one-frame ramps", "one frame between one-frame ramps"])
def test_one_frame_ramps_are_solved_without_a_pop(frames):
    performer, _, _, composed = walk_on_holden()
    sk = composed.skeleton
    hand = forward_kinematics(composed).positions[:, sk.index["LeftHand"]]
    c = Constraint("LeftHand", "position", {"point": hand[220] + [0.1, 0.15, 0.05]}, *frames)
    result = enforce(composed, [c])
    q = quality(performer, composed, result.motion, [c], result.residual)
    assert q["constraints"][0]["max_residual"] < 1e-3
    worst = q["pops"][0]
    assert worst["ratio"] <= 1.0, worst
    # a real correction: on the first held frame the hand is far from its own path
    moved = forward_kinematics(result.motion).positions[c.start, sk.index["LeftHand"]]
    assert np.linalg.norm(moved - hand[c.start]) > 0.1


def _reaches(composed, joints, ramps):
    """Position goals 10 cm above each joint's path at frame 220, each eased over ``ramps``
    frames on both sides of its range 210-230 (so every ramp overlaps every other's)."""
    p = forward_kinematics(composed).positions
    sk = composed.skeleton
    return [Constraint(j, "position", {"point": p[220, sk.index[j]] + [0.0, 0.1, 0.0]},
                       210 - ramps + k, 210 + k, 230 + k, 230 + ramps + k)
            for k, j in enumerate(joints)]


@pytest.mark.parametrize("ramps", [20, 8])
def test_overlapping_ramps_ease_together_on_moving_goals_without_a_pop(ramps):
    """The three reaches of the test below, each 10 cm above its joint's own path over its
    range (a trajectory goal: the body carries it as it walks) rather than at one point:
    their ramps, every one overlapping every other, ease the corrections in and out together
    with no joint past the no-pop rule, and every goal is met."""
    performer, _, _, composed = walk_on_holden()
    p = forward_kinematics(composed).positions
    sk = composed.skeleton
    cons = []
    for k, j in enumerate(["LeftHand", "RightHand", "Head"]):
        start, end = 210 + k, 230 + k
        path = p[start:end + 1, sk.index[j]] + [0.0, 0.1, 0.0]
        cons.append(Constraint(j, "trajectory", {"points": path},
                               start - ramps, start, end, end + ramps))
    result = enforce(composed, cons)
    q = quality(performer, composed, result.motion, cons, result.residual)
    assert max(c["max_residual"] for c in q["constraints"]) < 1e-3
    assert max(p["ratio"] for p in q["pops"]) <= 1.0, q["pops"]
    moved = forward_kinematics(result.motion).positions[220, sk.index["Head"]]
    assert abs(moved[1] - p[220, sk.index["Head"], 1] - 0.1) < 1e-3


@pytest.mark.xfail(strict=True, reason="open (issue 14 point 2): three reaches whose ramps all "
                   "overlap turn the Neck 1.28 times the limit at frame 230 (241 deg/s) with "
                   "the joints weighed alike. It is the held goals, not the easing (the same "
                   "reaches on goals that move with the body pass, the test above): the body "
                   "walks away from three fixed points and, while all three are held (to "
                   "frame 230), the hands hold the trunk and the Neck alone keeps the head "
                   "back, its correction growing 1.4 degrees a frame (frames 226-231: 170-243 "
                   "deg/s; the direct Neck turns 18) until the Head's ramp out stops it at "
                   "232 (31 deg/s). With joints stiffer towards the root (ik.STIFFNESS 2) it "
                   "passed, but the demo's stretched arm then flipped")
def test_overlapping_ramps_ease_together_without_a_pop():
    performer, _, _, composed = walk_on_holden()
    cons = _reaches(composed, ["LeftHand", "RightHand", "Head"], 20)
    result = enforce(composed, cons)
    q = quality(performer, composed, result.motion, cons, result.residual)
    assert max(c["max_residual"] for c in q["constraints"]) < 1e-3
    assert max(p["ratio"] for p in q["pops"]) <= 1.0, q["pops"]


def test_a_tangle_of_overlapping_ramps_is_refused_by_name():
    _, _, _, composed = walk_on_holden()
    sk = composed.skeleton
    joints = [n for n in sk.names if n != sk.names[0]][:9]
    cons = _reaches(composed, joints, 30)
    with pytest.raises(ConstraintError, match=r"9 ramps overlap at frame \d+ .*at most 8"):
        enforce(composed, cons)


def test_a_ramp_starts_from_the_posture_next_to_it_under_a_reach():
    """The CMU walk onto Bandai with automatic contacts and a hand reaching 20 cm off its path
    (benchmarks/bench_ik.py's job). The left heel lets go at frame 501 while the right leg,
    near its full stretch, holds the body under the reach: postures degrees apart meet the
    same tasks there. The key frame's posture without the heel (what its output ramp eases
    from) is solved from the frame inside the ramp next to it; solved from the composed
    posture it ended 2.8 degrees of the hips and a centimetre of the root away, and the ramp
    turned the hips 314 deg/s in its first frame (limit 302)."""
    from motion_composer.engine.conversion import retarget
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.correction.contacts import contact_constraints, detect_contacts
    from ik_fixtures import walk_on_bandai
    performer, target, _, _ = walk_on_bandai()
    corr = automap(target.skeleton, performer.skeleton)
    composed = retarget(performer, target, corr)
    cons = contact_constraints(detect_contacts(performer), performer, composed, corr.pairs)
    here = forward_kinematics(composed).positions[:, target.skeleton.index["Hand_L"]]
    reach = Constraint("Hand_L", "position", {"point": here[500] + [0.10, 0.15, 0.05]},
                       460, 480, 520, 540, priority=2, name="hand")
    heel = [c for c in cons if c.joint == "Foot_L" and c.kind == "position" and c.end == 501]
    assert heel and heel[0].smooth_out == 515
    cons = cons + [reach]
    result = enforce(composed, cons)
    q = quality(performer, composed, result.motion, cons, result.residual)
    assert max(c["max_residual"] for c in q["constraints"]) < 1e-3
    limit = pop_limits(composed, result.motion, [(501, 515)])
    speed = angular_speed(result.motion)
    ratio = speed[501:517] / limit[501:517]
    assert ratio.max() <= 1.0, (np.unravel_index(ratio.argmax(), ratio.shape), ratio.max())


def _two_hands(composed):
    """The left hand let go at frame 120 (ramp out to 135) and the right hand's goal held
    from 121 (ramp in from 106)."""
    from ik_fixtures import two_hands
    return two_hands(composed)


def test_the_key_postures_of_a_ramp_hold_the_goals_held_across_it(monkeypatch):
    """The left hand is let go on frame 120 (ramp out to 135) and the right hand's goal held
    from 121, across that ramp: both key postures of the left hand's ramp (with and without
    its goal) hold the right hand's goal too, so that the ramp's correction is what the left
    hand's goal adds to the right's. Each solved without the other's goal, the corrections
    added up over the ramps missed both (the test below)."""
    from motion_composer.engine.correction import enforcement
    from motion_composer.engine.motion import Motion
    _, _, _, composed = walk_on_holden()
    cons = _two_hands(composed)
    sk = composed.skeleton
    seen = {}
    blend = enforcement._blend

    def spy(problem, rot_v, tra_v, src, units, deltas):
        seen.update(rot_v=rot_v.copy(), tra_v=tra_v.copy(), src=src, units=units,
                    deltas=deltas)
        return blend(problem, rot_v, tra_v, src, units, deltas)

    monkeypatch.setattr(enforcement, "_blend", spy)
    enforce(composed, cons)
    src, units = seen["src"], seen["units"]
    pairs = [(w, wo) for k, w, wo in seen["deltas"] if units[k][:3] == (120, 135, False)]
    assert len(pairs) == 1
    w, wo = pairs[0]
    assert src[w] == src[wo] == 120 and w >= composed.num_frames     # postures of their own
    pose = Motion._trusted(sk, seen["rot_v"][[w, wo]], seen["tra_v"][[w, wo]],
                           composed.frame_time, "keys")
    p = forward_kinematics(pose).positions
    left, right = (c.goal["point"] for c in cons)
    for k in (0, 1):
        assert np.linalg.norm(p[k, sk.index["RightHand"]] - right) < 1e-3
    assert np.linalg.norm(p[0, sk.index["LeftHand"]] - left) < 1e-3
    assert np.linalg.norm(p[1, sk.index["LeftHand"]] - left) > 0.05


def test_back_to_back_ramps_of_two_goals_ease_without_a_pop():
    """Two goals whose ramps meet back to back (one eased out from frame 120, the other in
    to 121) ease without a pop. Each ramp's correction was solved without the other's goal
    (the left hand's at 120 without the right hand's, held from 121), and the two added up
    missed both: pass two's repair held the left hand on 120 and the right on 121, and
    Spine1 turned 1.93 times the limit at 121 (487 deg/s) even with the repair's jump
    eased. The key postures now hold the goals held on the frame next to them inside the
    ramp (enforcement._virtual_frames)."""
    performer, _, _, composed = walk_on_holden()
    cons = _two_hands(composed)
    result = enforce(composed, cons)
    q = quality(performer, composed, result.motion, cons, result.residual)
    assert max(c["max_residual"] for c in q["constraints"]) < 1e-3
    assert max(p["ratio"] for p in q["pops"]) <= 1.0, q["pops"][:2]


def _walk_onto_bandai_with_a_floor(lo: int, hi: int):
    """The CMU walk's frames ``lo .. hi - 1`` onto the Bandai skeleton (../shared/data), as
    ``motion-composer retarget --auto-contacts --floor 0`` sets it up: the scene."""
    from conftest import shared_path
    from ik_fixtures import window_scene
    return window_scene(shared_path("cmu_max_131_01_walk.bvh"),
                        shared_path("bandai1_walk_normal_001.bvh"), lo, hi)


def test_the_project_floor_adds_no_second_plane_where_the_contacts_hold_the_floor():
    """With automatic contacts and ``--floor``, the contacts' floor planes stand on that
    floor: the project's floor adds none on the joints they already keep above it."""
    scene = _walk_onto_bandai_with_a_floor(500, 760)
    planes = [(c.joint, c.goal["point"][1]) for c in scene.automatic_constraints()
              if c.kind == "plane"]
    assert len(planes) == 4 and len(set(planes)) == 4            # heels and toes, once each
    assert {j for j, _ in planes} == {"Foot_L", "Foot_R", "Toes_L", "Toes_R"}


def test_a_plane_given_twice_is_solved_once_without_a_pop():
    """The same floor plane twice on a joint (the contacts' and the project's, as the scene
    made them before it made them once): the solve is the one with each plane once, bit for
    bit, and each copy reports the plane's residual. Solved as two tasks, the active set
    held the right toe on the floor through its releases on one frame of a swing (the
    second copy kept it there while the first was let go): 5.7 cm below both neighbours on
    frame 635 of the whole clip, Foot_R turning 1.8 times its no-pop limit; in this window
    the hips turned 1.87 times theirs (frame 140), where each plane once keeps 0.99."""
    from motion_composer.engine.correction.constraints import floor_constraint
    scene = _walk_onto_bandai_with_a_floor(500, 760)
    composed = scene.composed
    once = scene.automatic_constraints()
    twice = once + [floor_constraint(c.joint, composed.num_frames, c.goal["point"][1])
                    for c in once if c.kind == "plane"]
    single, double = enforce(composed, once), enforce(composed, twice)
    np.testing.assert_array_equal(double.motion.rotations, single.motion.rotations)
    np.testing.assert_array_equal(double.motion.translations, single.motion.translations)
    planes = [i for i, c in enumerate(once) if c.kind == "plane"]
    for k, i in enumerate(planes):
        np.testing.assert_array_equal(double.residual[len(once) + k], single.residual[i])
    q = quality(scene.performer, composed, double.motion, twice, double.residual)
    assert max(p["ratio"] for p in q["pops"]) <= 1.0, q["pops"][:3]


def _walk_onto_the_tpose(floor, lo: int = 400, hi: int = 660, mode: str = "scaled"):
    """The bundled CMU walk's frames ``lo .. hi - 1`` onto the bundled T-pose skeleton, whose
    hips are at 0 and feet 0.92 m lower, as ``retarget --auto-contacts [--floor F]
    [--root-mode M]`` sets it up: the scene."""
    from conftest import clip_path
    from ik_fixtures import window_scene
    from motion_composer.engine.conversion.converter import RootOptions
    scene = window_scene(clip_path("cmu_131_01_walk.bvh"), clip_path("cmu_rest_tpose.bvh"),
                         lo, hi)
    return scene.replace(floor=floor, root=RootOptions(mode=mode))


def test_the_project_floor_moves_the_conversion_onto_it():
    """``--floor F`` stands the character on F: the direct conversion is the one without a
    floor, every rotation bit for bit, with the root raised by F less the floor the
    character stands on in its rest pose (found here independently: the lowest joint or
    End Site of the T-pose, its toes' tips). In the absolute root mode, which places the
    root where the performer's is, nothing moves."""
    from motion_composer.engine.kinematics import fk_arrays
    free, floored = _walk_onto_the_tpose(None), _walk_onto_the_tpose(0.25)
    rest = floored.target
    pose = fk_arrays(rest.skeleton, rest.rotations, rest.translations, end_sites=True)
    lowest = min(pose.positions[0, :, 1].min(), pose.end_positions[0, :, 1].min())
    assert lowest < -0.9                                       # hips at 0, feet far below
    assert free.lift() == 0.0
    assert floored.lift() == pytest.approx(0.25 - lowest, abs=1e-9)
    a, b = free.composed, floored.composed
    np.testing.assert_array_equal(b.rotations, a.rotations)
    np.testing.assert_allclose(b.translations - a.translations,
                               np.broadcast_to([0.0, 0.25 - lowest, 0.0], a.translations.shape),
                               atol=1e-12)
    absolute = _walk_onto_the_tpose(0.25, mode="absolute")
    assert absolute.lift() == 0.0
    np.testing.assert_array_equal(absolute.composed.translations,
                                  _walk_onto_the_tpose(None, mode="absolute").composed.translations)


def test_goals_set_by_hand_move_with_the_character_onto_the_floor():
    """A floor set after goals were placed moves them with the character
    (``Scene.floor_changes``): each goal's points rise by the change of the lift (a hand's
    point, a trajectory's keys, a plane's point; not a plane's normal nor an orientation),
    so a hand placed on the character as shown is still there against it, and solved the
    hand is as high over the new floor as it was over the old. Automatic constraints are
    made again, not moved; nothing moves where the lift does not change."""
    from motion_composer.engine.correction.constraints import Constraint
    from motion_composer.engine.kinematics import fk_arrays
    free = _walk_onto_the_tpose(None)
    sk = free.target.skeleton
    hand = fk_arrays(sk, free.composed.rotations, free.composed.translations).positions[
        :, sk.index["LeftHand"]]
    turn = [0.0, np.sin(0.2), 0.0, np.cos(0.2)]
    goals = (Constraint("LeftHand", "position", {"point": hand[60] + [0.05, 0.1, 0.0]},
                        40, 50, 70, 80, name="hand"),
             Constraint("RightHand", "trajectory", {"keys": [[50, 0.1, 0.2, 0.3],
                                                             [70, 0.2, 0.3, 0.4]]},
                        40, 50, 70, 80),
             Constraint("Head", "orientation", {"quaternion": turn}, 40, 50, 70, 80),
             Constraint("LeftFoot", "plane", {"point": [0.0, -0.8, 0.0],
                                              "normal": [0.0, 1.0, 0.2]}, 0, 0, 99, 99))
    scene = free.replace(constraints=goals, auto_contacts=True)
    changes = scene.floor_changes(floor=0.0)
    after = scene.replace(**changes)
    rise = after.lift()
    assert rise > 0.9 and set(changes) == {"floor", "constraints"}
    hand_goal, path, head, plane = changes["constraints"]
    np.testing.assert_allclose(hand_goal.goal["point"], goals[0].goal["point"] + [0, rise, 0],
                               atol=1e-12)
    keys = np.asarray(path.goal["keys"])
    np.testing.assert_array_equal(keys[:, 0], [50, 70])
    np.testing.assert_allclose(keys[:, 1:], np.asarray(goals[1].goal["keys"])[:, 1:]
                               + [0, rise, 0], atol=1e-12)
    np.testing.assert_array_equal(head.goal["quaternion"], goals[2].goal["quaternion"])
    np.testing.assert_allclose(plane.goal["point"], [0.0, -0.8 + rise, 0.0], atol=1e-12)
    np.testing.assert_array_equal(plane.goal["normal"], goals[3].goal["normal"])
    assert [c.range for c in changes["constraints"]] == [c.range for c in goals]
    # solved, the hand reaches its moved goal: as high over the floor at 0 as over the old
    solved = after.solve(constraints=[hand_goal])
    sk = solved.motion.skeleton
    got = fk_arrays(sk, solved.motion.rotations, solved.motion.translations).positions[
        60, sk.index["LeftHand"]]
    np.testing.assert_allclose(got, hand_goal.goal["point"], atol=1e-3)
    # the stand switch off moves them back down; the same floor again moves nothing
    back = after.floor_changes(stand_on_floor=False)
    np.testing.assert_allclose(back["constraints"][0].goal["point"], goals[0].goal["point"],
                               atol=1e-12)
    assert after.floor_changes(floor=0.0) == {"floor": 0.0}
    # automatic constraints are made again with the floor, not moved
    auto = scene.replace(constraints=goals + tuple(scene.automatic_constraints()))
    moved = auto.floor_changes(floor=0.0)["constraints"]
    assert [c for c in moved if c.auto] == [c for c in auto.project.constraints if c.auto]


def test_a_floor_moves_nothing_on_a_target_without_feet():
    """A target without feet (the T-pose skeleton with its legs removed): where it stands is
    not known (``standing_floor`` None), so a floor neither moves its conversion nor adds
    planes. The robot, whose legs end at the shins, stands on its feet (control joints
    carried with the shins): a floor moves it onto itself and holds both feet above it."""
    from conftest import shared_path
    from test_edge_cases import TPOSE, WALK, scene_of, without_legs
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.formats import read_character, read_motion, read_performer
    from motion_composer.engine.project import Project, Source
    from motion_composer.engine.scene import Scene
    scene = scene_of(read_motion(WALK), without_legs(read_motion(TPOSE)), floor=0.5)
    assert scene.ready and scene.standing_floor() is None and scene.lift() == 0.0
    np.testing.assert_array_equal(scene.composed.translations,
                                  scene.replace(floor=None).composed.translations)
    assert scene.automatic_constraints() == []
    clip, robot = shared_path("bandai1_walk_normal_001.bvh"), \
        shared_path("target_robot_expressive.glb")
    performer, target = read_performer(clip), read_character(robot).rest_motion()
    project = Project(performer=Source(str(clip)), target=Source(str(robot)),
                      correspondence=automap(target.skeleton, performer.skeleton), floor=0.5)
    scene = Scene(project, performer, target)
    standing = scene.standing_floor()
    assert standing is not None and scene.lift() == pytest.approx(0.5 - standing)
    planes = scene.automatic_constraints()
    assert sorted(c.joint for c in planes) == ["FootL", "FootR"]
    assert all(c.kind == "plane" and c.goal["point"][1] > 0.5 for c in planes)


def test_a_floor_far_above_the_characters_feet_is_solved_without_a_pop():
    """``--floor 0`` onto the T-pose skeleton (its feet 0.92 m under 0). Until round 33 the
    floor planes and contacts lifted the body onto that floor by force on every frame:
    joints turned at 2.4-4.8 times the no-pop limit on all four clips tried (this walk's
    hips 4.8 on frame 348; in this window, frames 250-449, 8.7 on its frame 98). Now the
    conversion stands on the floor: the solve is the one without a floor, moved up, and no
    joint pops."""
    free, floored = _walk_onto_the_tpose(None, 250, 450), _walk_onto_the_tpose(0.0, 250, 450)
    a, b = free.solve(regenerate=True), floored.solve(regenerate=True)
    lift = floored.lift()
    assert lift > 0.9
    for solution in (a, b):
        assert max(c["max_residual"] for c in solution.report["quality"]["constraints"]) < 1e-3
        assert max(p["ratio"] for p in solution.report["quality"]["pops"]) <= 1.0
    pa = forward_kinematics(a.correction.motion).positions
    pb = forward_kinematics(b.correction.motion).positions
    np.testing.assert_allclose(pb - [0.0, lift, 0.0], pa, atol=1e-4)
    assert b.report["floor"] == {"height_m": 0.0, "lift_m": pytest.approx(lift)}


def _shared_scene(clip: str, character: str, flat_feet: bool = False):
    """``clip`` onto ``character`` (files of ``../shared/data``) with automatic contacts,
    as ``retarget --auto-contacts`` maps and binds them (with flat feet where
    ``flat_feet``): the scene and its enabled constraints."""
    performer_file, target_file = shared_path(clip), shared_path(character)
    performer = read_performer(performer_file)
    target = read_character(target_file).rest_motion()
    project = Project(performer=Source(str(performer_file)), target=Source(str(target_file)),
                      correspondence=automap(target.skeleton, performer.skeleton),
                      auto_contacts=True, bind_options=BindOptions(flat_feet=flat_feet))
    scene = Scene(project, performer, target).regenerated()
    return scene, [c for c in scene.constraints if c.enabled]


@functools.lru_cache(maxsize=None)
def _jumps_onto_kenney(flat_feet: bool = False):
    """The CMU jumps onto Kenney's Maya character (FBX) with automatic contacts (bound with
    flat feet where ``flat_feet``): the scene, its enabled constraints and a window solver
    over its composed motion."""
    scene, cons = _shared_scene("cmu_mb_01_01_jumps.bvh",
                                "fbx/maya_kenney_character_7700_binary.fbx", flat_feet)
    solver = WindowSolver(scene.edited, scene.project.ik_options, carried=scene.carried)
    return scene, cons, solver


#: the landing of the CMU jumps onto Kenney's character: the ramp into the plant of both feet
LANDING = (2240, 2280)


def _solves_of(stage: str, monkeypatch, solver, cons):
    """The window ``LANDING`` solved, with every call of the IK solver that ``stage``
    (``"_pass_one"`` or ``"_pass_two"`` of :mod:`enforcement`) makes recorded: ``(part,
    first, calls)``, each call ``(skeleton, tasks, attraction rot, attraction root, start
    translations, options, locked, result)``. Pass one solves its frames that start under a
    floor again from above it and keeps the nearer (:func:`enforcement._nearer_from_above`):
    the rows it kept replace the first solve's (:func:`_as_kept`)."""
    calls, inside, again, kept = [], [], [], []
    wrapped, solve = getattr(enforcement, stage), enforcement.solve_frames
    nearer = enforcement._nearer_from_above

    def spy_stage(*args, **kwargs):
        inside.append(True)
        try:
            return wrapped(*args, **kwargs)
        finally:
            inside.pop()

    def spy_nearer(problem, entries, rot, tra, *args):
        again.append(True)
        try:
            out = nearer(problem, entries, rot, tra, *args)
        finally:
            again.pop()
        kept.append((problem.composed, rot, tra))
        return out

    def spy_solve(skeleton, tasks, rot, tra, attraction_rot, attraction_root, options,
                  locked=frozenset()):
        out = solve(skeleton, tasks, rot, tra, attraction_rot, attraction_root, options,
                    locked)
        if inside:
            calls.append((skeleton, tasks, attraction_rot, attraction_root, tra, options,
                          locked, out, bool(again)))
        return out

    monkeypatch.setattr(enforcement, stage, spy_stage)
    monkeypatch.setattr(enforcement, "_nearer_from_above", spy_nearer)
    monkeypatch.setattr(enforcement, "solve_frames", spy_solve)
    part, first = solver.solve(cons, *LANDING)
    monkeypatch.undo()
    return part, first, _as_kept(calls, kept)


def _as_kept(calls, kept) -> list:
    """``calls`` (:func:`_solves_of`) with each row that a solve from above the floors
    replaced (``kept``: per :func:`enforcement._nearer_from_above` the composed motion and
    the postures it left) holding the row kept: the same frame (attraction posture) and
    tasks, the result it ended with; those solves left out."""
    def key(tasks, arot, aroot, i):
        return (arot[i].tobytes(), aroot[i].tobytes(),
                tuple((t.joint, t.goal[i].tobytes(), float(t.weight[i])) for t in tasks))

    taken = {}
    for composed, rot, tra in kept:
        for sk, tasks, arot, aroot, _, _, _, (r, t, res, _), above in calls:
            if not above:
                continue
            for i in range(len(r)):
                same = np.flatnonzero(
                    (composed.rotations == arot[i]).all(axis=(1, 2))
                    & (composed.translations[:, 0] == aroot[i]).all(axis=1))
                if any(np.array_equal(rot[f], r[i]) and np.array_equal(tra[f], t[i])
                       for f in same):
                    taken[key(tasks, arot, aroot, i)] = (r[i], t[i], res[i])
    out = []
    for *call, (r, t, res, it), above in calls:
        if above:
            continue
        r, t, res = r.copy(), t.copy(), res.copy()
        for i in range(len(r)):
            row = taken.pop(key(call[1], call[2], call[3], i), None)
            if row is not None:
                r[i], t[i], res[i] = row
        out.append((*call, (r, t, res, it)))
    assert not taken                    # each kept row replaced one of the first solve's
    return out


def _nearest_whatever_the_start(calls) -> int:
    """Each frame of the recorded solves ``calls`` (:func:`_solves_of`) solved again from each
    neighbouring row's correction added to its own attraction posture: asserts that none ends
    nearer that posture, in the solver's weighted norm (the root's translation in its share
    of the stature), than the solve did. Returns how many were compared."""
    solve = enforcement.solve_frames
    checked = 0
    for sk, tasks, arot, aroot, tra, options, locked, (rot2, tra2, residual, _) in calls:
        weight = column_scale(sk, np.arange(sk.num_joints), options.scale)

        def distance(r, t, i):
            turn = quat_to_rotvec(qmul(r, qconj(arot[i])))
            return float(np.sqrt(np.sum(((t[0] - aroot[i]) / weight[:3]) ** 2)
                                 + np.sum(turn ** 2)))

        for i in range(len(rot2)):
            if residual[i].max() > 1e-4:
                continue
            own = distance(rot2[i], tra2[i], i)
            for k in (i - 1, i + 1):
                if not 0 <= k < len(rot2):
                    continue
                start_rot = qnormalize(qmul(qmul(rot2[k], qconj(arot[k])), arot[i]))
                start_tra = tra[i].copy()
                start_tra[0] = aroot[i] + tra2[k][0] - aroot[k]
                r, t, res, _ = solve(sk, [task.take([i]) for task in tasks],
                                     start_rot[None], start_tra[None], arot[i:i + 1],
                                     aroot[i:i + 1], options, locked)
                if res.max() > 1e-4:
                    continue
                assert own <= distance(r[0], t[0], i) + 1e-3, (i, k, own)
                checked += 1
    return checked


def _floors_hold(part, first, cons) -> None:
    """Each foot joint at or above its floor, less a millimetre, over ``LANDING``."""
    floors = [c for c in cons if c.kind == "plane"]
    assert floors
    frames = slice(LANDING[0] - first, LANDING[1] + 1 - first)
    pose = forward_kinematics(part).positions
    for c in floors:
        y = pose[frames, part.skeleton.index[c.joint], 1]
        assert y.min() >= c.goal["point"][1] - 1e-3, c.joint


@pytest.mark.parametrize("stage, flat_feet", [
    ("_pass_two", False),
    ("_pass_one", True),
], ids=["pass-two", "pass-one-flat-feet"])
def test_each_frame_ends_nearest_its_attraction_whatever_the_start(stage, flat_feet,
                                                                   monkeypatch):
    """Pass one solves each frame from the composed posture, pass two the tasks held on a
    ramp's frames (here the floors under six foot joints) from the blend, pass one's sum of
    corrections; each is pulled towards where it starts, and must end at the posture nearest
    it that meets the tasks, whatever side of the floors it starts on. On the landing of the
    CMU jumps onto Kenney's character (frames 2252-2266) the blend adds the key frame's turn
    of each foot (flat: 25 degrees) to feet still pitched toe down and puts the toes' tips up
    to 83 mm under the floor; solved from there, pass two's first step turned the feet heel
    down about the toes and pinned an ankle on its own floor, a hold the pull to the blend
    kept: 0.18 from the blend in the solver's weighted norm, where the same frame started
    from either neighbour's correction ends at 0.05, and its neighbours lifted the body
    instead (the hips 90 mm apart in one frame). Bound with flat feet, the composed posture
    itself sinks the ankles 59 mm and 30 mm under their floors on 2262, and pass one's solve
    from there ended 0.46 from it where a start above the floors ends at 0.10 (the hips 216 mm
    under the frame before's; the no-pop rule 2.88): pass one now solves such frames from
    above the floors too and keeps the nearer. Every frame the stage solves on the landing is
    solved again from each neighbour's correction: none may end nearer where it started from;
    the floors hold."""
    scene, cons, solver = _jumps_onto_kenney(flat_feet=flat_feet)
    part, first, calls = _solves_of(stage, monkeypatch, solver, cons)
    assert calls
    _floors_hold(part, first, cons)
    assert _nearest_whatever_the_start(calls) >= 10


def test_a_second_start_above_the_floors_leaves_frames_it_does_not_bring_nearer_alone(
        monkeypatch):
    """Pass one solves each frame that starts under a floor a second time, from above it,
    and keeps that solve only where it ends nearer the composed posture by more than
    NEARER (:func:`enforcement._nearer_from_above`). On the Bandai walk onto Ely's glTF
    character, where frames start under the floors but none in a hold, the correction is
    the one solved without the second start bit for bit: the key fit's choices, which turn
    on the last bits, do not move for nothing."""
    scene, cons = _shared_scene("bandai1_walk_normal_001.bvh", "target_mixamo_ely.glb")
    lifted = []
    nearer = enforcement._nearer_from_above

    def spy(problem, entries, rot, tra, residual, iters, only):
        start = enforcement._above_planes(problem, entries, problem.composed.rotations,
                                          problem.composed.translations, only)
        lifted.append(int(np.any(start != problem.composed.translations, axis=(1, 2)).sum()))
        return nearer(problem, entries, rot, tra, residual, iters, only)

    monkeypatch.setattr(enforcement, "_nearer_from_above", spy)
    both = enforce(scene.edited, cons)
    assert lifted and lifted[0] >= 10                   # frames were solved twice
    monkeypatch.setattr(enforcement, "NEARER", np.inf)
    first = enforce(scene.edited, cons)
    np.testing.assert_array_equal(both.rotvecs, first.rotvecs)
    np.testing.assert_array_equal(both.root, first.root)


@pytest.mark.xfail(strict=True, reason=(
    "open (issue 14 point 2): RightUpLeg 1.07 times the no-pop limit at 2262 (283 deg/s over "
    "263), where the capture's own thigh turns 220: pass two now ends each frame at the "
    "posture nearest its blend (was 2.00, the Hips, from a hold the solve kept), and that "
    "posture follows the blend's toes, 45, 83 and 59 mm under the floor over 2260-2262: the "
    "lift the floors need changes by the frame"))
def test_a_landing_whose_blend_sinks_the_feet_is_solved_without_a_pop():
    """The CMU jumps onto Kenney's Maya character (FBX), the landing of frames 2252-2266
    (:func:`test_each_frame_ends_nearest_its_attraction_whatever_the_start`): no joint turns
    faster than the no-pop rule allows around the ramps of frames 2240-2280. Solved in a
    window (:class:`WindowSolver`): the frames a whole solve gives there."""
    scene, cons, solver = _jumps_onto_kenney()
    composed = scene.edited
    lo, hi = LANDING
    spans = [(a, b) for a, b in ramps(cons, composed.num_frames) if lo <= a and b <= hi]
    assert any(a < 2262 < b for a, b in spans)            # the landing's ramp in
    part, first = solver.solve(cons, lo, hi)
    direct = composed.frames(slice(first, first + part.num_frames))
    limit = pop_limits(direct, part, [(a - first, b - first) for a, b in spans])
    frames = slice(lo + 1 - first, hi + 1 - first)
    ratio = angular_speed(part)[frames] / limit[frames]
    worst = np.unravel_index(np.argmax(ratio), ratio.shape)
    assert ratio[worst] <= 1.0, (part.skeleton.names[worst[1]], lo + 1 + worst[0],
                                 float(ratio[worst]))
