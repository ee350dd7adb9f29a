"""Issue 14 point 2, degenerate ramps: a constraint whose ramps are one frame long (or whose
active range is one frame between one-frame ramps) is solved without a pop, by the no-pop
rule of :mod:`engine.correction.quality` (over a one-frame span a smoothstep may turn the
whole correction in that frame, times 1.5), on a real walk; the goal is still met."""
from __future__ import annotations

import numpy as np
import pytest

from ik_fixtures import walk_on_holden
from motion_composer.engine import forward_kinematics
from motion_composer.engine.correction.constraints import Constraint, ConstraintError
from motion_composer.engine.correction.enforcement import enforce
from motion_composer.engine.correction.quality import angular_speed, pop_limits, quality


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


@pytest.mark.xfail(strict=True, reason="open (issue 14 point 2): three reaches whose ramps all "
                   "overlap turn the Neck 1.28 times the limit at frame 230 (241 deg/s) with "
                   "the joints weighed alike. It is the held goals, not the easing: the body "
                   "walks away from three fixed points and, while all three are held (to "
                   "frame 230), the Neck's correction grows 1.4 degrees a frame (frames "
                   "226-231: 170-230 deg/s; the direct Neck turns 18). With joints stiffer "
                   "towards the root (ik.STIFFNESS 2) it passed, but the demo's stretched arm "
                   "then flipped")
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
    sk = composed.skeleton
    p = forward_kinematics(composed).positions
    left = Constraint("LeftHand", "position", {"point": p[110, sk.index["LeftHand"]]
                                               + [0.1, 0.15, 0.05]}, 90, 100, 120, 135)
    right = Constraint("RightHand", "position", {"point": p[130, sk.index["RightHand"]]
                                                 + [-0.1, 0.2, 0.1]}, 106, 121, 140, 155)
    return [left, right]


def test_a_key_posture_without_its_ramp_that_holds_nothing_is_the_composed_one(monkeypatch):
    """On frame 120 without the left hand's goal nothing is held: the posture its ramp eases
    from is the composed one. It started from frame 121's correction (the right hand's) and,
    with no task to solve, stayed there: the ramp then took the right hand's correction off
    at 121 and eased it back in (on the CMU walk onto the fox, 9 degrees of the right leg
    between frames 138 and 139)."""
    from motion_composer.engine.correction import enforcement
    _, _, _, composed = walk_on_holden()
    seen = {}
    blend = enforcement._blend

    def spy(problem, rot_v, tra_v, src, units, deltas):
        seen.update(rot_v=rot_v.copy(), tra_v=tra_v.copy(), src=src, units=units,
                    deltas=deltas)
        return blend(problem, rot_v, tra_v, src, units, deltas)

    monkeypatch.setattr(enforcement, "_blend", spy)
    enforce(composed, _two_hands(composed))
    src, units = seen["src"], seen["units"]
    out = [without for k, _, without in seen["deltas"] if units[k][:3] == (120, 135, False)]
    assert len(out) == 1 and src[out[0]] == 120
    assert np.array_equal(seen["rot_v"][out[0]], composed.rotations[120])
    assert np.array_equal(seen["tra_v"][out[0]], composed.translations[120])


def test_back_to_back_ramps_of_two_goals_ease_without_a_pop():
    """Two goals whose ramps meet back to back (one eased out from frame 120, the other in
    to 121) ease without a pop. Each frame's pass-two repair holds its own goal (the left
    hand on 120, the right on 121) and the solve after the easing undoes part of it: eased
    once, Spine1 turned 1.93 times the limit at 121 (487 deg/s; not eased: 2.31). The
    easing is repeated where the repair still jumps (enforcement.EASE_ROUNDS)."""
    performer, _, _, composed = walk_on_holden()
    cons = _two_hands(composed)
    result = enforce(composed, cons)
    q = quality(performer, composed, result.motion, cons, result.residual)
    assert max(c["max_residual"] for c in q["constraints"]) < 1e-3
    assert max(p["ratio"] for p in q["pops"]) <= 1.0, q["pops"][:2]


def test_the_repair_is_eased_again_while_it_jumps(monkeypatch):
    """The back-to-back goals above: each easing shrinks the repair's jump between frames 120
    and 121 (Spine1's 4.9 degrees by about a fifth a round: each frame's solve after the
    easing pulls the posture back towards its own goal), so it is eased again, every
    round of EASE_ROUNDS (the composed spine hardly turns there: any jump shows)."""
    from motion_composer.engine.correction import enforcement
    _, _, _, composed = walk_on_holden()
    jumps = []
    ease = enforcement._ease_repairs

    def spy(problem, units, rot1, tra1, rot2, tra2, blended, held, *more):
        base = composed.rotations[[120, 121]]
        repair = (enforcement._offsets(rot2[[120, 121]], base)
                  - enforcement._offsets(rot1[[120, 121]], base))
        jumps.append(np.linalg.norm(repair[0] - repair[1], axis=-1).max())
        return ease(problem, units, rot1, tra1, rot2, tra2, blended, held, *more)

    monkeypatch.setattr(enforcement, "_ease_repairs", spy)
    enforce(composed, _two_hands(composed))
    assert len(jumps) == enforcement.EASE_ROUNDS
    assert all(b < enforcement.EASE_SHRINK * a for a, b in zip(jumps, jumps[1:]))
    assert jumps[-1] < 0.4 * jumps[0]


def test_a_repair_jump_the_easing_does_not_shrink_is_eased_once():
    """The CMU walk onto Bandai with automatic contacts and a hand reach (benchmarks/
    bench_ik.py's job): at the heel planted on frame 489 under the reach the repair jumps
    0.54 degrees of the hips, and easing it again leaves it so (the solve after it undoes
    it). No round after the first eases anything there: the rounds cost a solve each."""
    from motion_composer.engine.conversion import retarget
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.correction import enforcement
    from motion_composer.engine.correction.contacts import contact_constraints, detect_contacts
    from ik_fixtures import walk_on_bandai
    performer, target, _, _ = walk_on_bandai()
    corr = automap(target.skeleton, performer.skeleton)
    composed = retarget(performer, target, corr)
    cons = contact_constraints(detect_contacts(performer), performer, composed, corr.pairs)
    here = forward_kinematics(composed).positions[:, target.skeleton.index["Hand_L"]]
    cons.append(Constraint("Hand_L", "position", {"point": here[500] + [0.10, 0.15, 0.05]},
                           460, 480, 520, 540, priority=2, name="hand"))
    rounds = []
    ease = enforcement._ease_repairs
    still = enforcement._still_jumps
    asked = []

    def spy(*args):
        out = ease(*args)
        rounds.append(0 if out is None else int(out[4].sum()))
        return out

    def jumps(problem, a, jump_rot, jump_tra):
        out = still(problem, a, jump_rot, jump_tra)
        asked.append((a, out))
        return out

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(enforcement, "_ease_repairs", spy)
        mp.setattr(enforcement, "_still_jumps", jumps)
        enforce(composed, cons)
    assert rounds[0] > 300 and rounds[1:] == [0]
    assert (488, True) in asked            # it still jumps, but the easing did not shrink it
