"""Issue 14, "How it is checked": feet that stay planted heel to toe, on the character's floor,
and corrections that never pop, on real clips of several conventions (walk, run, kick, jumps)
onto several characters.

The test finds the performer's planted intervals itself, independently of the engine's detector:
a foot joint (heel: the ankle; toe: the ball joint) is planted where it is within 2 % of the
stature of its own lowest height and moves horizontally slower than 0.15 statures per second,
for at least 3 frames. Then:

* the engine's contacts cover at least 90 % of those frames;
* in each interval the target's corresponding joint drifts horizontally no more than the
  performer's (each as a fraction of its stature);
* in each interval the target's joint stays at or above its rest height over the character's
  floor (the lowest point of its feet in the rest pose: mesh vertices for a skinned glTF, joints
  and End Sites for a BVH), minus 1 mm;
* around every ramp every joint turns no faster than max(1.2 x the direct conversion's fastest
  turn at that joint within 0.25 s of the ramp, that turn + what a smoothstep over the ramp
  needs for the correction's size there); where ramps overlap, a frame around several has the
  sum of their smoothsteps' needs, since they ease the correction together.

Each clip and character pair is solved once (module-scoped fixture).
"""
from __future__ import annotations

import functools

import numpy as np
import pytest

from conftest import clip_path, shared_path
from test_flat_feet import held_at_converted_headings
from motion_composer.engine import scene as scene_module
from motion_composer.engine.conversion.automap import automap
from motion_composer.engine.correction.contacts import find_feet
from motion_composer.engine.describe import stature
from motion_composer.engine.formats import read_character, read_motion
from motion_composer.engine.kinematics import fk_arrays
from motion_composer.engine.project import Project, Source
from motion_composer.engine.scene import Scene
from motion_composer.engine.skinning import skin_character

#: (performer, target): a walk, a run, a kick and two jump clips of five conventions onto
#: two skinned Mixamo characters, a CMU T-pose, the bundled skeleton, a skinned FBX
#: character (Kenney's, whose toes end in a ``*_end`` joint 7 cm past the toe joint) and the
#: glTF fox (a digitigrade quadruped 61 m tall, whose heel stands 16 % of it off the floor:
#: its toe is released inside its heel's output ramp, where pass two's repair once jumped
#: 6 degrees of the hips in a frame), and a CC3 walk onto Ely and onto the fox (a toe let
#: go on frame 72 and the other foot planted on 73: eased from both sides, the two frames
#: once swapped their repairs and turned Ely's hips 537 deg/s; with each foot's correction
#: solved without the other's goals, the fox's repairs were 12 degrees of the hips apart
#: there, 1.34 times the no-pop limit), and a Rokoko dance onto the CMU T-pose (its right foot
#: flat on the floor from the first frame to the 9th at 100 fps, a plant the clip cuts: the
#: floor rule lifts the target's toe there, and left free the heel slid 0.13 % of stature more
#: than the performer's), and a Bandai walk onto Quaternius' robot (its legs end at the shins;
#: its feet are control joints under the root, carried with the shins, with no toe: held
#: through the shins; the clip is bound on a mid-stride frame, where the left foot pitches
#: 79 degrees down), and a Bandai kick onto the robot (found from the heel alone, a contact
#: ended a frame before the performer's heel rose, and the hold on the other foot carried the
#: released foot 19 cm in that frame: the heel drifted 3.9 % of the stature)
CASES = [
    (("shared", "cmu_max_131_01_walk.bvh"), ("shared", "target_mixamo_ely.glb")),
    (("shared", "bandai1_run_active_001.bvh"), ("shared", "target_mixamo_mannequin.glb")),
    (("shared", "bandai1_kick_normal_001.bvh"), ("shared", "target_cmu_mb_rest_tpose.bvh")),
    (("bundled", "fair1_child8_jumping.bvh"), ("shared", "target_mixamo_ely.glb")),
    (("shared", "cmu_mb_01_01_jumps.bvh"), ("bundled", "cmu_rest_tpose.bvh")),
    (("shared", "bandai1_walk_normal_001.bvh"),
     ("shared", "fbx/maya_kenney_character_7700_binary.fbx")),
    (("shared", "cmu_max_131_01_walk.bvh"), ("shared", "target_fox.glb")),
    (("shared", "cc3_cmu_02_01_walk.bvh"), ("shared", "target_mixamo_ely.glb")),
    (("shared", "cc3_cmu_02_01_walk.bvh"), ("shared", "target_fox.glb")),
    (("shared", "rokoko_mixamo_jesse_dance.bvh"), ("shared", "target_cmu_mb_rest_tpose.bvh")),
    (("shared", "bandai1_walk_normal_001.bvh"), ("shared", "target_robot_expressive.glb")),
    (("shared", "bandai1_kick_normal_001.bvh"), ("shared", "target_robot_expressive.glb")),
]
IDS = ["walk-cmumax-ely", "run-bandai-mannequin", "kick-bandai-cmutpose",
       "jump-fair1-ely", "jumps-cmumb-holden", "walk-bandai-kenney", "walk-cmumax-fox",
       "walk-cc3-ely", "walk-cc3-fox", "dance-rokoko-cmutpose", "walk-bandai-robot",
       "kick-bandai-robot"]

NEAR = 0.02          # of the stature above the joint's lowest height
SLOW = 0.15          # statures per second
SHORTEST = 3         # frames


def _path(where: str, name: str):
    return clip_path(name) if where == "bundled" else shared_path(name)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(),
                    (np.flatnonzero(edges == -1) - 1).tolist()))


def planted_intervals(positions: np.ndarray, fps: float, size: float) -> list[tuple[int, int]]:
    """Runs where a joint's world positions ``(F, 3)`` are near its lowest height and slow."""
    y = positions[:, 1]
    speed = np.zeros(len(y))
    speed[1:] = np.linalg.norm(np.diff(positions[:, [0, 2]], axis=0), axis=1) * fps
    low = y < y.min() + NEAR * size
    return [(s, e) for s, e in _runs(low & (speed < SLOW * size)) if e - s + 1 >= SHORTEST]


def drift(positions: np.ndarray, s: int, e: int) -> float:
    p = positions[s:e + 1][:, [0, 2]]
    return float(np.linalg.norm(p - p[0], axis=1).max())


def rest_floor_and_heights(target_file, target, joints) -> tuple[float, dict]:
    """The character's floor (its feet's lowest point in the rest pose) and each foot joint's
    height above it, measured here from the file: the skinned mesh where there is one."""
    sk = target.skeleton
    pose = fk_arrays(sk, target.rotations[:1], target.translations[:1], end_sites=True)
    y = pose.positions[0, :, 1]
    feet = {j for j in joints} | {k for k in range(sk.num_joints)
                                  if set(sk.ancestors(k)) & set(joints)}
    low = min([y[j] for j in joints] + [pose.end_positions[0, k, 1]
                                        for k, site in enumerate(sk.end_sites)
                                        if site.parent in feet])
    if str(target_file).endswith(".glb"):
        character = read_character(target_file)
        for mesh, vertices in zip(character.meshes, skin_character(character)):
            main = mesh.joints[np.arange(len(mesh.joints)), np.argmax(mesh.weights, axis=1)]
            on_feet = np.isin(main, list(feet))
            if on_feet.any():
                low = min(low, float(vertices[0, on_feet, 1].min()))
    return low, {j: float(y[j] - low) for j in joints}


def angular_speed(rotations: np.ndarray, fps: float) -> np.ndarray:
    """``(F, J)`` [rad/s] the turn of each joint's local rotation into each frame."""
    out = np.zeros(rotations.shape[:2])
    a, b = rotations[:-1], rotations[1:]
    dot = np.abs(np.sum(a * b, axis=-1))
    out[1:] = 2.0 * np.arccos(np.clip(dot, -1.0, 1.0)) * fps
    return out


def relative_angle(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """[rad] the angle between rotations ``q`` and ``r`` (same shapes)."""
    return 2.0 * np.arccos(np.clip(np.abs(np.sum(q * r, axis=-1)), -1.0, 1.0))


@functools.lru_cache(maxsize=None)
def solve_case(case):
    """A pair of :data:`CASES` solved with automatic contacts, once per session (the tests
    here read the same solves; none changes them): ``(scene, solution, target file)``."""
    (pw, pn), (tw, tn) = case
    performer_file, target_file = _path(pw, pn), _path(tw, tn)
    performer, target = read_motion(performer_file), read_motion(target_file)
    project = Project(performer=Source(str(performer_file)), target=Source(str(target_file)),
                      correspondence=automap(target.skeleton, performer.skeleton),
                      auto_contacts=True)
    scene = Scene(project, performer, target)
    return scene, scene.solve(regenerate=True), target_file


@pytest.fixture(scope="module", params=CASES, ids=IDS)
def solved(request):
    return solve_case(request.param)


def _feet(scene):
    """``(performer joint, target joint, part)`` of every mapped foot joint (and of every
    control joint carried with a leg that takes a performer foot joint's turn:
    :meth:`Scene.foot_pairs`)."""
    by_performer = {p: t for t, p in scene.foot_pairs().items()}
    out = []
    for ankle, toe in find_feet(scene.performer.skeleton):
        for joint, part in ((ankle, "heel"), (toe, "toe")):
            if joint in by_performer:
                out.append((joint, by_performer[joint], part, ankle))
    return out


def _intervals(scene):
    performer = scene.performer
    sk = performer.skeleton
    pos = fk_arrays(sk, performer.rotations, performer.translations, end_sites=False).positions
    size = stature(performer)
    out = []
    for pj, tj, part, ankle in _feet(scene):
        for s, e in planted_intervals(pos[:, sk.index[pj]], performer.fps, size):
            out.append((pj, tj, part, ankle, s, e))
    return out, pos, size


def covered_frames(intervals, contacts) -> tuple[int, int]:
    """``(covered, total)``: how many frames of the performer's planted ``intervals``
    (:func:`_intervals`) lie in a detected contact of their foot (by ankle), of how many."""
    total = covered = 0
    for _, _, _, ankle, s, e in intervals:
        frames = np.arange(s, e + 1)
        inside = np.zeros(len(frames), dtype=bool)
        for c in contacts:
            if c.joint == ankle:
                inside |= (frames >= c.start) & (frames <= c.end)
        total += len(frames)
        covered += int(inside.sum())
    return covered, total


def test_a_giant_keeps_keys_fitted_to_the_tasks():
    """The FAIR child waving onto the fox (61 m as written), solved as ``retarget
    --auto-contacts`` does: the key fit's lengths grow with the figure over 2 m
    (:func:`~engine.correction.keyfit.fit_share`), so its keys are fitted to the tasks and
    kept, few, every goal held, the feet planted as the performer's and on the floor to the
    millimetre. Held to the absolute millimetre, its three fits were refused (a miss of
    1.63 mm) and the solve kept 9,183 keys fitted to the dense curves, in 73 s."""
    from motion_composer.engine.formats import read_performer
    clip, fox = shared_path("fair1_child5_wave_hello.bvh"), shared_path("target_fox.glb")
    performer, target = read_performer(clip), read_character(fox).rest_motion()
    project = Project(performer=Source(str(clip)), target=Source(str(fox)),
                      correspondence=automap(target.skeleton, performer.skeleton),
                      auto_contacts=True)
    scene = Scene(project, performer, target)
    solution = scene.solve(regenerate=True)
    keys = solution.report["keys"]
    assert keys["fitted_to"] == "tasks", keys
    assert keys["count"] < 0.1 * scene.composed.num_frames * len(solution.scene.displacement)
    assert max(c["max_residual"] for c in solution.report["quality"]["constraints"]) < 1e-3
    solved = (scene, solution, fox)
    test_planted_heels_drift_no_more_than_the_performers(solved)
    test_planted_toes_drift_no_more_than_the_performers(solved)
    test_planted_feet_stay_on_or_above_the_floor(solved)
    # the floors stay held to the millimetre: a floor's miss counts as many times more as
    # the lengths grew, and a refusal for a miss says so
    from motion_composer.engine.correction.keyfit import GIANT, TASK_LIMIT, _Judge
    from motion_composer.engine.describe import figure_size
    size = figure_size(scene.edited)
    judge = _Judge(scene.composed, scene.edited, solution.constraints, solution.correction)
    assert not judge.keeps(None, {"worst_task_m": TASK_LIMIT * size})
    assert judge.reason.endswith(f"; on this figure of {size:.3g} m a floor's millimetre "
                                 f"counts {size / GIANT:.3g}")


def test_the_detector_covers_the_planted_frames(solved):
    scene, solution, _ = solved
    intervals, _, _ = _intervals(scene)
    assert intervals, "the clip has planted feet"
    covered, total = covered_frames(intervals, scene.contacts())
    assert covered >= 0.9 * total, f"{covered} of {total} planted frames in contacts"


def _drift_excess(solved, part: str):
    """The largest excess of the target's drift over the performer's (fractions of their
    statures) over the intervals of ``part``, and where."""
    scene, solution, _ = solved
    intervals, p_pos, p_size = _intervals(scene)
    motion = solution.motion
    sk = motion.skeleton
    t_pos = fk_arrays(sk, motion.rotations, motion.translations, end_sites=False).positions
    t_size = stature(motion)
    worst = [(0.0, "")]
    for pj, tj, kind, _, s, e in intervals:
        if kind != part:
            continue
        mine = drift(t_pos[:, sk.index[tj]], s, e) / t_size
        theirs = drift(p_pos[:, scene.performer.skeleton.index[pj]], s, e) / p_size
        worst.append((mine - theirs, f"{kind} {tj} {s}-{e}: {mine:.4f} > {theirs:.4f}"))
    return max(worst)


def test_a_plant_the_clip_cuts_is_a_contact():
    """A foot low at a clip's first or last frames is planted with the run beside it even
    where the clip leaves it shorter than the shortest contact (the speed at the edge is
    one-sided): the Rokoko dance's right foot on frames 0-8, and every contact of three clips at
    120 fps (a walk, jumps and a run) with the clip cut a few frames before it ends or after it
    starts. A foot in the air at the cut is not planted."""
    from motion_composer.engine.correction.contacts import (PART_MIN_FRAMES, ContactOptions,
                                                            detect_contacts)
    dance = read_motion(shared_path("rokoko_mixamo_jesse_dance.bvh"))
    first = detect_contacts(dance)
    assert any(c.joint == "RightFoot" and c.start == 0 and c.end >= 7 for c in first)
    assert not any(c.joint == "LeftFoot" and c.start < 900 for c in first)   # off the floor
    checked = swings = 0
    for name in ("cmu_max_131_01_walk.bvh", "cmu_mb_01_01_jumps.bvh",
                 "cmu_xia_angry_13_000_run.bvh"):
        clip = read_motion(shared_path(name))
        shortest = round(ContactOptions().min_duration * clip.fps)
        left = shortest - 3                         # shorter than the shortest contact
        assert left >= PART_MIN_FRAMES
        F = clip.num_frames
        whole = detect_contacts(clip)
        for c in whole:
            if c.end - c.start + 1 < 2 * shortest or c.start < 10 or c.end > F - 11:
                continue
            # the excerpt's floor and speeds at its edge are its own: a frame either way
            head = detect_contacts(clip.excerpt(c.end - left + 1, None))
            assert any(h.joint == c.joint and h.start == 0 and h.end >= left - 2 for h in head)
            tail = detect_contacts(clip.excerpt(None, c.start + left - 1))
            assert any(t.joint == c.joint and abs(t.start - c.start) <= 1 and
                       t.end == c.start + left - 1 for t in tail)
            checked += 1
            # cut mid-swing (a third of a second or more since the foot's contact before)
            before = [b.end for b in whole if b.joint == c.joint and b.end < c.start]
            if before and c.start - before[-1] > clip.fps / 3:
                air = detect_contacts(clip.excerpt((before[-1] + c.start) // 2, None))
                assert not any(a.joint == c.joint and a.start == 0 for a in air)
                swings += 1
    assert checked >= 6 and swings >= 3


def test_planted_heels_drift_no_more_than_the_performers(solved):
    excess, where = _drift_excess(solved, "heel")
    assert excess <= 1e-3, where            # 0.1 % of the stature: the solver's tolerance


def test_planted_toes_drift_no_more_than_the_performers(solved):
    excess, where = _drift_excess(solved, "toe")
    assert excess <= 1e-3, where


def test_planted_feet_stay_on_or_above_the_floor(solved):
    scene, solution, target_file = solved
    intervals, _, _ = _intervals(scene)
    motion = solution.motion
    sk = motion.skeleton
    joints = sorted({sk.index[tj] for _, tj, _, _, _, _ in intervals})
    floor, heights = rest_floor_and_heights(target_file, scene.target, joints)
    y = fk_arrays(sk, motion.rotations, motion.translations, end_sites=False).positions[..., 1]
    for _, tj, part, _, s, e in intervals:
        j = sk.index[tj]
        low = float(y[s:e + 1, j].min() - floor - heights[j])
        assert low >= -1e-3, f"{part} {tj} {s}-{e}: {low * 1000:.1f} mm below its rest height"


def test_the_joints_below_the_feet_stay_on_or_above_the_floor(solved):
    """Each foot joint, not only the mapped ankle and toe: a joint below the foot that no
    performer joint maps (a toe's end joint: Mixamo's ``*Toe_End``, Kenney's ``*Toes_end``)
    stays at or above its rest height over the floor in the performer's planted intervals of
    its foot. (Holding the ankle and the toe joint alone left the toe's tip bending up to
    7 cm into the floor.)"""
    scene, solution, target_file = solved
    intervals, _, _ = _intervals(scene)
    motion = solution.motion
    sk = motion.skeleton
    by_performer = {p: t for t, p in scene.correspondence.pairs.items()}
    below = {}
    for ankle, toe in find_feet(scene.performer.skeleton):
        if ankle in by_performer:
            a, t = sk.index[by_performer[ankle]], by_performer.get(toe)
            below[ankle] = [k for k in range(sk.num_joints)
                            if a in sk.ancestors(k) and sk.names[k] != t]
    joints = sorted({k for ks in below.values() for k in ks})
    if not joints:
        pytest.skip("the character has no joint below its feet but the mapped toe")
    floor, heights = rest_floor_and_heights(target_file, scene.target, joints)
    y = fk_arrays(sk, motion.rotations, motion.translations, end_sites=False).positions[..., 1]
    checked = 0
    for _, _, part, ankle, s, e in intervals:
        for j in below.get(ankle, ()):
            low = float(y[s:e + 1, j].min() - floor - heights[j])
            assert low >= -1e-3, (f"{part} interval {s}-{e}: {sk.names[j]} "
                                  f"{low * 1000:.1f} mm below its rest height")
            checked += 1
    assert checked


def test_a_flat_foot_is_held_at_the_converted_foots_heading(solved):
    """test_flat_feet.py's rule (a flat foot held at the converted foot's heading) on this
    module's solves."""
    scene, solution, _ = solved
    if not any(toe for _, toe in scene.target_feet()):
        pytest.skip("the character's feet have no toe: its ankles are pinned, and turn as "
                    "the performer's (the robot's feet, carried with its shins)")
    assert held_at_converted_headings(scene, solution), "the clip has flat feet"


def test_a_giant_holds_its_flat_feet():
    """The glTF fox is 61 m tall (its file's metres): the solver's 0.1 mm tolerance is a
    millionth of it, its stretched legs converge towards that so slowly that the lower
    priority holding a flat foot's orientation was gated off, and the right foot rolled 7.9
    degrees on the floor at frame 798 of the CMU walk. The tolerance grows with a giant
    (ik.MIN_TOLERANCE): every flat is held within a degree."""
    scene, solution, _ = solve_case(CASES[IDS.index("walk-cmumax-fox")])
    flats = [c for c in solution.report["quality"]["constraints"]
             if c["kind"] == "orientation" and c["name"].startswith("foot flat")]
    assert len(flats) >= 10
    worst = max(flats, key=lambda c: c["max_residual"])
    assert np.degrees(worst["max_residual"]) < 1.0, worst


def test_a_fit_no_round_held_stops_when_its_later_rounds_run_away(monkeypatch):
    """The CMU 131 walk onto the fox, the light pull's fit: its rounds of added keys end 11
    times over the task limit, none within it (they stall, or spend their rounds: which, is
    rounding; with numpy 2.4 and scipy 1.17 the twelfth round misses by 0.03 % more than
    the eleventh, one stall short), and it goes on to its rounds of emphasis and calming,
    which miss by over 30 times the limit. It stops there, at more than keyfit.RUNAWAY
    times its least miss since its keys were added: run on through every emphasis round,
    it ends over the limit, refused all the same. The solve keeps the keys that follow the
    dense curves."""
    from motion_composer.engine.correction import keyfit
    scene, solution, _ = solve_case(CASES[IDS.index("walk-cmumax-fox")])
    args = (solution.scene.edited, solution.constraints, solution.correction.rotvecs,
            solution.correction.root)
    stopped: dict = {}
    keyfit.fit_to_tasks(*args, pull=keyfit.PULL, stats=stopped)
    limit = stopped["limit_m"]              # the 1 mm limit grown with the 61 m fox
    assert limit > keyfit.TASK_LIMIT
    assert stopped["ran_away"]
    assert stopped["stalled"] or len(stopped["adding_misses_m"]) == keyfit.ROUNDS + 1
    least = min(stopped["adding_misses_m"])
    assert least > limit
    assert stopped["worst_task_m"] > keyfit.RUNAWAY * least
    monkeypatch.setattr(keyfit, "RUNAWAY", np.inf)
    unstopped: dict = {}
    keyfit.fit_to_tasks(*args, pull=keyfit.PULL, stats=unstopped)
    assert not unstopped["ran_away"] and unstopped["spent"]
    assert unstopped["adding_misses_m"] == stopped["adding_misses_m"]     # the same fit
    assert unstopped["worst_task_m"] > limit                    # not kept either
    assert unstopped["iterations"] > stopped["iterations"]
    assert solution.report["keys"]["fitted_to"] == "dense curves"


#: the pairs where the no-pop rule is still open (issue 14 point 2), with what the keyed result
#: shows: the worst joint over its limit, and why
POPS_OPEN = {
    "jumps-cmumb-holden": "1.02: LeftLeg at frame 1538, 523 deg/s over a limit of 513, the "
                          "take-off of a jump: every hold of the left foot ends within seven "
                          "frames (the flat at heel-off, 1533, the heel's pivot about the toe "
                          "at 1539, the toe at 1540) and their ramps out overlap while the "
                          "foot leaves the floor. It was 1.07 at 1539 with the heel held "
                          "down while the performer's rose 20 mm over 1533-1539 (heel-off "
                          "was not told apart: engine/correction/contacts.py, _heel_offs). "
                          "The capture's one-frame glitches at 975 and 980, which popped "
                          "1.43 here, are solved from the frames around them "
                          "(engine/correction/glitches.py)",
}


def test_no_joint_pops_around_a_ramp(solved, request):
    case = request.node.callspec.id
    if case in POPS_OPEN:
        request.applymarker(pytest.mark.xfail(strict=True, reason="open (issue 14 point 2): "
                                              + POPS_OPEN[case]))
    scene, solution, _ = solved
    direct, corrected = scene.composed, solution.motion
    fps = direct.fps
    F = direct.num_frames
    speed_d = angular_speed(direct.rotations, fps)
    speed_c = angular_speed(corrected.rotations, fps)
    window = int(round(0.25 * fps))
    spans = set()
    enabled = [c for c in solution.constraints if c.enabled]
    # a constraint that switches without a ramp where another's ramp of two frames or more
    # is keyed (a toe held from the flat foot on) is eased with the shortest such ramp: it is
    # judged over that ramp, not allowed a one-frame jump
    into = {c.start: max(d.smooth_in for d in enabled
                         if d.start == c.start and d.start - d.smooth_in >= 2)
            for c in enabled if c.start - c.smooth_in >= 2}
    out_of = {c.end: min(d.smooth_out for d in enabled
                         if d.end == c.end and d.smooth_out - d.end >= 2)
              for c in enabled if c.smooth_out - c.end >= 2}
    for c in enabled:
        if c.start - c.smooth_in >= 2:
            spans.add((c.smooth_in, c.start))
        elif c.start in into:
            spans.add((into[c.start], c.start))
        elif c.start > 0:
            spans.add((c.start - 1, c.start))
        if c.smooth_out - c.end >= 2:
            spans.add((c.end, c.smooth_out))
        elif c.end in out_of:
            spans.add((c.end, out_of[c.end]))
        elif c.end < F - 1:
            spans.add((c.end, c.end + 1))
    assert spans
    # per frame: the fastest direct turn within 0.25 s of the ramps around it and the sum of
    # their smoothsteps' needs (overlapping ramps ease the correction together: judged against
    # one ramp alone, a joint eased by another ramp that overlaps it would be held to the
    # first one's need only)
    J = speed_d.shape[1]
    base = np.zeros((F, J))
    need = np.zeros((F, J))
    around = np.zeros(F, dtype=bool)
    for a, b in sorted(spans):
        here = slice(a, b + 1)
        # the correction's own turn over the ramp: from its value at either end
        off = _offsets(direct.rotations[here], corrected.rotations[here])
        size = np.maximum(relative_angle(off, off[:1]), relative_angle(off, off[-1:])).max(0)
        seen = slice(max(1, a), min(F, b + 2))
        base[seen] = np.maximum(base[seen],
                                speed_d[max(0, a - window):b + window + 1].max(axis=0))
        need[seen] += 1.5 * size * fps / (b - a)
        around[seen] = True
    # no limit under 10 deg/s: a turn that slow is no pop (where the capture holds a joint
    # still the rule's limit falls towards zero)
    limit = np.maximum(np.maximum(1.2 * base, base + need), np.radians(10.0))
    ratio = np.where(around[:, None], speed_c / limit, 0.0)
    k, j = np.unravel_index(np.argmax(ratio), ratio.shape)
    assert ratio[k, j] <= 1.0, (f"{ratio[k, j]:.2f}: {corrected.skeleton.names[j]} at frame {k}: "
                                f"{np.degrees(speed_c[k, j]):.0f} deg/s, limit "
                                f"{np.degrees(limit[k, j]):.0f}")




def keyed_steadiness(scene, solution, keyed=None) -> tuple[float, str]:
    """The delivered motion's (the solved keys'; or ``keyed``'s) worst turn over its steady
    limit, on every frame: 1.5 times the fastest turn of that joint in the direct conversion
    or the dense IK result within two frames, and at least 30 deg/s; with the joint, frame
    and speeds. The control joints carried with the limbs (placed after the keys) are not
    judged."""
    from scipy.ndimage import maximum_filter1d
    direct, keyed = scene.composed, solution.motion if keyed is None else keyed
    dense = solution.correction.motion
    fps = direct.fps
    fastest = np.maximum(angular_speed(direct.rotations, fps),
                         angular_speed(dense.rotations, fps))
    limit = np.maximum(1.5 * maximum_filter1d(fastest, 5, axis=0, mode="nearest"),
                       np.radians(30.0))
    speed = angular_speed(keyed.rotations, fps)
    ratio = speed / limit
    ratio[:, list(scene.carried)] = 0.0
    k, j = np.unravel_index(np.argmax(ratio), ratio.shape)
    return float(ratio[k, j]), (f"{keyed.skeleton.names[j]}@{k} {np.degrees(speed[k, j]):.0f}/"
                                f"{np.degrees(limit[k, j]):.0f} deg/s")


def test_the_keys_turn_no_joint_faster_than_the_conversion_or_the_dense_solve(solved):
    """On every frame, not only around the ramps, the delivered motion (the solved keys) turns
    no joint more than 1.5 times as fast as the direct conversion or the dense IK result does
    within two frames (:func:`keyed_steadiness`): between the tasks, a chain's keys could
    trade turns that hold a planted foot (before: the CMU jumps onto the CMU T-pose turned a
    held right ankle 236 deg/s at frame 122, the conversion 16, the dense solve 18; 9 of
    these 12 pairs went 1.2 to 5 times over)."""
    scene, solution, _ = solved
    ratio, where = keyed_steadiness(scene, solution)
    assert ratio <= 1.0, f"{ratio:.2f}: {where}"


def test_where_the_dense_correction_rests_the_keys_leave_the_conversion_alone(solved):
    """Where the dense solve leaves a joint (or the root's translation) uncorrected for a key
    interval or more, inside a constraint's window too (a foot between its contacts under
    the floor plane, which spans the clip), the delivered motion is the direct conversion
    there bit for bit: no keys run through the rest (before, the Rokoko dance onto the CMU
    T-pose's keys wobbled within 1.4 degrees of the right foot's rest between its
    correction over frames 60-75 and its contact's ramp from 125, turning it 46 deg/s where
    the capture and the dense solve hold it still). The control joints carried with the
    limbs (placed after the keys) are not judged."""
    from motion_composer.engine.correction.keyfit import key_budget
    scene, solution, _ = solved
    if solution.report["keys"]["fitted_to"] != "tasks":
        pytest.skip("the solve kept keys fitted to the dense curves")
    direct, keyed = scene.composed, solution.motion
    gap = int(np.ceil(2.0 / key_budget(direct.fps)))
    rested = 0
    columns = [(j, solution.correction.rotvecs[:, j], keyed.rotations[:, j],
                direct.rotations[:, j]) for j in range(direct.skeleton.num_joints)
               if j not in scene.carried]
    columns.append((-1, solution.correction.root, keyed.translations[:, 0],
                    direct.translations[:, 0]))
    for j, dense, got, want in columns:
        moved = np.flatnonzero(np.any(dense != 0, axis=1))
        if not len(moved):
            continue
        for a, b in zip(moved[:-1], moved[1:]):
            if b - a > gap:
                rested += b - a - 1
                np.testing.assert_array_equal(got[a + 1:b], want[a + 1:b],
                                              err_msg=f"joint {j}, frames {a + 1}-{b - 1}")
    if not rested:
        pytest.skip("the dense solve rests no joint for a key interval between corrections")


def _auto_scene(clip: str, target: str, frames: slice = slice(None)) -> Scene:
    """A scene of ../shared/data's ``clip`` (its ``frames``) onto its character ``target``,
    auto-mapped, with automatic contacts (as ``retarget --auto-contacts``)."""
    clip_file, target_file = shared_path(clip), shared_path(target)
    performer = read_motion(clip_file)
    performer = performer.replace(rotations=performer.rotations[frames],
                                  translations=performer.translations[frames])
    character = read_character(target_file).rest_motion()
    return Scene(Project(performer=Source(str(clip_file)), target=Source(str(target_file)),
                         correspondence=automap(character.skeleton, performer.skeleton),
                         auto_contacts=True), performer, character)


def test_the_steadying_keeps_the_round_least_over_the_steady_limit(monkeypatch):
    """Of the rounds of the key fit's steadying (the Rokoko dance onto the Mixamo mannequin,
    glTF, whose keys before their steadying turn a joint well past the steady limit), the
    keys kept are those of the round whose worst turn is least over it (at least 1), among
    the rounds that pop and lurch no more than before the steadying and hold the tasks as
    well (before: the round with the fewest frames over; the dance onto the Mixamo FBX
    character was kept 1.72 times over where a round was 1.68). Each fit's rounds are
    watched through the fit's own measures."""
    from motion_composer.engine.correction import keyfit
    from motion_composer.engine.correction.ik import length_share
    from motion_composer.engine.describe import figure_size
    scene = _auto_scene("rokoko_mixamo_jesse_dance.bvh", "target_mixamo_mannequin.glb")
    steady_ratios = keyfit._steady_ratios
    fits = []

    def watch(name, note):
        real = getattr(keyfit, name)

        def spy(*args, **kwargs):
            out = real(*args, **kwargs)
            if fits:
                note(fits[-1], args, out)
            return out
        monkeypatch.setattr(keyfit, name, spy)

    real_fit = keyfit.fit_to_tasks

    def fit(edited, *args, **kwargs):
        fits.append({"edited": edited, "rounds": [], "pops": 0})
        fits[-1]["keys"] = real_fit(edited, *args, **kwargs)
        return fits[-1]["keys"]

    monkeypatch.setattr(keyfit, "fit_to_tasks", fit)
    watch("_gauss_newton", lambda f, args, out: f.update(worst=out[1]))
    watch("_popping", lambda f, args, out: f.update(pops=len(out)))
    watch("_lurching", lambda f, args, out: f.update(pops=f["pops"] + len(out)))
    watch("_steady_ratios", lambda f, args, out: (
        f.update(limit=args[1]), f["rounds"].append((f["worst"], f["pops"], out.max()))))
    scene.solve(regenerate=True)
    assert fits
    chosen = []
    for f in fits:
        if not f["rounds"]:
            continue
        limit = keyfit.TASK_LIMIT * length_share(figure_size(f["edited"]))
        worst0, pops0, _ = f["rounds"][0]
        eligible = [(max(1.0, over), worst) for worst, pops, over in f["rounds"]
                    if pops <= pops0 and worst <= max(limit, worst0)]
        best = min(eligible)
        kept = steady_ratios(f["keys"].apply(f["edited"]), f["limit"]).max()
        assert max(1.0, kept) == pytest.approx(best[0], rel=1e-6), (kept, eligible)
        chosen.append((best[0], max(1.0, f["rounds"][0][2])))
    # the rule mattered here: a round well under the first one's worst was kept
    assert any(best < 0.5 * first for best, first in chosen), chosen


def _stricter_judge(monkeypatch, scale: float):
    """The key-fit judge's steady limit (:func:`keyfit._steady_limit`) times ``scale``; the
    fits' own steadying is left as it is."""
    from motion_composer.engine.correction import keyfit
    monkeypatch.setattr(keyfit._Judge, "steady_limit", property(
        lambda judge: scale * keyfit._steady_limit(judge.edited, judge.correction.motion)))


def _watched_fits(monkeypatch) -> list:
    """Each task fit of the solves that follow: ``(stagger, keys, the keys' worst turn over
    the steady limit as the judge measures it, unscaled, whether keyed at the ramps'
    ends)``."""
    from motion_composer.engine.correction import keyfit
    real_fit, real_keys = keyfit.fit_to_tasks, keyfit.solved_keys
    fits, seen = [], {}

    def keys_for(direct, edited, constraints, correction, **kwargs):
        seen.update(edited=edited, dense=correction.motion)
        return real_keys(direct, edited, constraints, correction, **kwargs)

    def fit(*args, **kwargs):
        keys = real_fit(*args, **kwargs)
        limit = keyfit._steady_limit(seen["edited"], seen["dense"])
        ratio = float(keyfit._steady_ratios(keys.apply(seen["edited"]), limit).max())
        fits.append((kwargs.get("stagger", 0.0), keys, ratio, kwargs.get("at_ramps", False)))
        return keys

    monkeypatch.setattr(keyfit, "fit_to_tasks", fit)
    monkeypatch.setattr(scene_module, "solved_keys", keys_for)
    return fits


def test_keys_left_unsteady_are_fitted_again_staggered_and_the_steadier_kept(monkeypatch):
    """A solve whose kept keys still turn a joint past the steady limit fits them once more
    with every channel's keys staggered by half a key spacing (keyfit.RESTAGGER) and keeps
    the steadier. The Bandai run onto Ely: its first keys are steady and are fitted once;
    with the judge's limit made just stricter than they are (99 % of their worst turn over
    it), the keys are fitted again staggered, and the restaggered keys, steadier, are the
    ones delivered. (Real pairs that need it take minutes: the CMU jumps onto the Mixamo
    mannequin, 4.34 times past the limit, restaggered 1.00; the sweep. The Bandai walk onto
    the robot served here until the robot's fit, a figure of 4.2 m, grew its lengths with
    it: its restaggered keys are no steadier now.)"""
    from motion_composer.engine.correction import keyfit
    scene = _auto_scene("bandai1_run_active_001.bvh", "target_mixamo_ely.glb")
    fits = _watched_fits(monkeypatch)
    solution = scene.solve(regenerate=True)
    assert solution.report["keys"]["fitted_to"] == "tasks"
    assert [(stagger, at_ramps) for stagger, _, _, at_ramps in fits] == [(0.0, False)]
    first = fits[0][2]
    fits.clear()
    _stricter_judge(monkeypatch, 0.99 * first)
    solution = scene.solve(regenerate=True)
    assert [(stagger, at_ramps) for stagger, _, _, at_ramps in fits] == \
        [(0.0, False), (keyfit.RESTAGGER, False)]
    assert fits[0][2] == pytest.approx(first, rel=1e-9)      # the same first fit
    again, kept = fits[1][2], fits[1][1]
    assert again < 0.99 * first
    assert solution.report["keys"]["fitted_to"] == "tasks"
    assert solution.report["keys"]["why_dense_curves"] is None
    # the restaggered keys are the ones delivered (the control joints carried with the
    # limbs, IK targets such as the robot's foot controls, are placed after the keys)
    keyed = [j for j in range(scene.composed.skeleton.num_joints) if j not in scene.carried]
    np.testing.assert_allclose(solution.motion.rotations[:, keyed],
                               kept.apply(solution.scene.edited).rotations[:, keyed],
                               atol=1e-12)
    ratio, where = keyed_steadiness(scene, solution)
    assert ratio <= 1.0, f"{ratio:.2f}: {where}"


def test_keys_still_unsteady_after_the_second_fit_are_not_kept(monkeypatch):
    """Keys that still turn a joint past the steady limit after the restaggered fit are not
    the solve's, as keys that pop are not: the Bandai walk onto Quaternius' robot with the
    judge's limit made a hundred times stricter than its first keys need. The light pull is
    not tried for a wobble; the keys at the ramps' ends are, restaggered too; none is kept,
    and the solve delivers the keys fitted to the dense curves, which follow the dense solve
    (within the real limit, the test's own measure, :func:`keyed_steadiness`), and the
    report says why, of the last fit's steadier keys. (On real pairs: the CMU jumps onto
    Mixamo's Ely, 6.45 and 7.26 times past the limit, five minutes a solve; the sweep.)"""
    from motion_composer.engine.correction import keyfit
    scene = _auto_scene("bandai1_walk_normal_001.bvh", "target_robot_expressive.glb")
    fits = _watched_fits(monkeypatch)
    scene.solve(regenerate=True)
    scale = 0.01 * fits[0][2]
    fits.clear()
    _stricter_judge(monkeypatch, scale)
    solution = scene.solve(regenerate=True)
    assert [(stagger, at_ramps) for stagger, _, _, at_ramps in fits] == \
        [(0.0, False), (keyfit.RESTAGGER, False), (0.0, True), (keyfit.RESTAGGER, True)]
    assert all(ratio > scale for _, _, ratio, _ in fits)
    assert solution.report["keys"]["fitted_to"] == "dense curves"
    why = solution.report["keys"]["why_dense_curves"]
    steadier = min(fits[2][2], fits[3][2])
    assert why.startswith("the keys fitted to the tasks turned ") and \
        f" {steadier / scale:.2f} times past the steady limit at frame " in why, why
    ratio, where = keyed_steadiness(scene, solution)
    assert ratio <= 1.0, f"{ratio:.2f}: {where}"


def test_a_correction_eased_in_after_a_rest_has_keys_at_its_ramps_ends():
    """Where the keys spaced evenly are not kept, the last fit keys each joint at the ends
    of the ramps of the constraints on it too, where its correction is eased in and out
    (one Hermite segment between them makes the smoothstep the dense solve eases with). The
    first 300 frames of the Rokoko dance onto the Mixamo FBX character, whose right toe is
    held, let go for four frames and held again (frames 137-149): the evenly spaced keys
    turn the right toe 2.71 times past the steady limit (each channel's first free key lies
    up to a key spacing into a correction that starts after a rest) and, with the light
    pull, the right foot 2.51 times the no-pop limit where the dense solve keeps 1.08. The
    keys at the ramps' ends are fitted to the tasks, turn no joint past the steady limit
    (the test's own measure) and pop no more than the dense solve (on the whole dance 977
    keys, where the keys fitted to the dense curves are 1,820)."""
    scene = _auto_scene("rokoko_mixamo_jesse_dance.bvh", "fbx/mixamo.fbx", slice(0, 300))
    solution = scene.solve(regenerate=True)
    assert solution.report["keys"]["fitted_to"] == "tasks"
    sk = scene.composed.skeleton
    curves = solution.scene.displacement.curves
    checked = 0
    for c in solution.constraints:
        if not c.enabled or sk.index[c.joint] in scene.carried:
            continue
        ends = ([c.smooth_in, c.start] if c.start - c.smooth_in >= 2 else []) + \
            ([c.end, c.smooth_out] if c.smooth_out - c.end >= 2 else [])
        for (joint, _), curve in curves.items():
            if joint != c.joint:
                continue
            inside = [f for f in ends if curve.frames[0] < f < curve.frames[-1]]
            assert set(inside) <= set(curve.frames.astype(int)), (c.joint, ends, curve.frames)
            checked += len(inside)
    assert checked > 20
    ratio, where = keyed_steadiness(scene, solution)
    assert ratio <= 1.0, f"{ratio:.2f}: {where}"
    from motion_composer.engine.correction.quality import quality
    keyed = solution.report["quality"]["pops"][0]["ratio"]
    dense = quality(scene.performer, scene.composed, solution.correction.motion,
                    solution.constraints, solution.correction.residual)["pops"][0]["ratio"]
    assert keyed <= max(1.0, dense * 1.02), (keyed, dense)


def _offsets(direct: np.ndarray, corrected: np.ndarray) -> np.ndarray:
    """The corrections ``corrected * direct^-1`` (x, y, z, w)."""
    x1, y1, z1, w1 = np.moveaxis(corrected, -1, 0)
    x2, y2, z2, w2 = np.moveaxis(direct * [-1, -1, -1, 1], -1, 0)
    return np.stack([w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
                     w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2], axis=-1)
