"""The live preview's window problem (engine/correction/preview.py) on real automatic contacts:
dragging a contact's input handles back re-solves only the frames the change reaches, and
there the preview is the full solve's motion.

A constraint that only shapes a key posture outside the window is cut to its active frames at
that key; where that leaves it one frame long (a pin at the key, no ramps) the window problem
must still solve (a user's one-frame range with no ramps is refused, a key posture's is not).
The scene's preview (:class:`WindowSolver`) solves the same problem on the window's frames
cut from the clip: bit for bit the problem solved on the whole clip's arrays.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from motion_composer.engine.correction.enforcement import enforce
from motion_composer.engine.correction.preview import changed_window, splice, window_problem
from motion_composer.engine.kinematics import fk_arrays
from motion_composer.engine.project import open_project
from motion_composer.engine.scene import Scene

DEMO = Path(__file__).resolve().parent.parent / "resources" / "demo" / "demo.mcp"


def _positions(motion) -> np.ndarray:
    return fk_arrays(motion.skeleton, motion.rotations, motion.translations,
                     end_sites=False).positions


def test_a_moved_contact_previews_in_its_window_as_the_full_solve():
    project, performer, target = open_project(DEMO)
    solution = Scene(project, performer, target).solve()
    scene, constraints = solution.scene, list(solution.constraints)
    F = scene.num_frames
    pins = []                         # moves whose window problem pins a key posture's frame
    for i, c in enumerate(constraints):
        if not (c.auto and c.kind == "position" and c.smooth_in >= 4):
            continue
        after = list(constraints)
        after[i] = c.with_range(c.smooth_in - 4, c.start - 4, c.end, c.smooth_out)
        lo, hi = changed_window(constraints, after)
        problem = window_problem(after, lo, hi)
        if any(x.smooth_in == x.start == x.end == x.smooth_out and 0 < x.start < F - 1
               for x in problem):
            pins.append((after, lo, hi))
    assert pins, "the demo's contacts give no window with a pinned key posture"
    for after, lo, hi in pins[:2]:
        motion, mode = scene.preview(after, base_constraints=constraints,
                                     base_motion=scene.motion, whole=False)
        assert mode == "window"
        # the scene's preview solves the window's frames cut from the clip (WindowSolver):
        # bit for bit the window problem solved on the whole clip's arrays
        part = enforce(scene.edited, window_problem(after, lo, hi), options=project.ik_options,
                       pins=True).motion
        whole = splice(scene.motion, part, lo, hi)
        assert np.array_equal(whole.rotations, motion.rotations)
        assert np.array_equal(whole.translations, motion.translations)
        full = enforce(scene.edited, after, options=project.ik_options).motion
        gap = np.abs(_positions(motion) - _positions(full))[lo:hi + 1].max()
        assert gap < 1e-4, (lo, hi, gap)             # [m] the window: the full solve


def test_a_moved_goal_previews_as_the_full_solve_where_ramps_keyed_outside_ease_its_window():
    """A goal moved reaches its constraint's whole range; ramps of other constraints ease the
    window's edge frames in or out, keyed on frames beyond the window (another contact's
    input ramp keyed at its ``start`` after ``hi``, one's output ramp keyed at its ``end``
    before ``lo``). Their key postures must be solved with the constraints active there and
    next to them: the window's frames are then the full solve's. (The window problem once
    took a ramp's ``smooth_in`` and ``smooth_out`` for its keys, and these windows were up to
    10 mm off the full solve at their edge.)"""
    from motion_composer.engine.correction.constraints import Constraint
    project, performer, target = open_project(DEMO)
    scene = Scene(project, performer, target)
    constraints = list(scene.constraints)
    moved = {c.name: i for i, c in enumerate(constraints)}
    checked = 0
    for name in ("contact RightFoot #2", "contact LeftFoot #8"):
        i = moved[name]
        c = constraints[i]
        after = list(constraints)
        # a pin on a point, or a heel's pin that pivots about its toe after heel-off (a path)
        goal = ({"point": c.goal["point"] + [0.01, 0, 0]} if "point" in c.goal else
                {"points": np.asarray(c.goal["points"]) + [0.01, 0, 0]})
        after[i] = Constraint.from_dict({**c.to_dict(), "goal": goal})
        lo, hi = changed_window(constraints, after)
        outside = [x for x in after if x.enabled and x.smooth_in <= hi and x.smooth_out >= lo
                   and ((x.start - x.smooth_in >= 2 and x.start > hi) or
                        (x.smooth_out - x.end >= 2 and x.end < lo))]
        assert outside, (name, lo, hi)         # a ramp keyed outside eases the window
        motion, mode = scene.preview(after, base_constraints=constraints,
                                     base_motion=scene.edited, whole=False)
        assert mode == "window"
        full = enforce(scene.edited, after, options=project.ik_options).motion
        gap = np.abs(_positions(motion) - _positions(full))[lo:hi + 1].max()
        assert gap < 1e-6, (name, lo, hi, gap)      # [m] the full solve's to rounding
        checked += 1
    assert checked == 2


def test_a_solve_of_some_frames_gives_the_whole_solves_values_there():
    """enforce(frames=(lo, hi)) solves only what those frames depend on (themselves, the key
    postures of the ramps easing them and the frames those start from): bit for bit the
    solve of every frame on lo..hi, and no correction outside."""
    project, performer, target = open_project(DEMO)
    scene = Scene(project, performer, target)
    some = [c for c in scene.constraints if c.smooth_out < 250 and c.kind != "plane"]
    assert len(some) >= 6
    whole = enforce(scene.edited, some, options=project.ik_options)
    # ramps keyed past the window's edge ease its frames: LeftFoot #1's input ramp (18, 32)
    # in the first, its output ramp (89, 103) in the second
    for lo, hi in ((20, 28), (100, 138), (150, 200)):
        part = enforce(scene.edited, some, options=project.ik_options, frames=(lo, hi))
        assert np.array_equal(part.motion.rotations[lo:hi + 1],
                              whole.motion.rotations[lo:hi + 1])
        assert np.array_equal(part.motion.translations[lo:hi + 1],
                              whole.motion.translations[lo:hi + 1])
        outside = np.ones(scene.num_frames, dtype=bool)
        outside[lo:hi + 1] = False
        assert not part.rotvecs[outside].any() and not part.root[outside].any()
        assert not part.iterations[outside].any() and part.iterations[lo:hi + 1].any()


def test_a_window_eased_towards_a_key_back_to_back_with_another_previews_as_the_full_solve():
    """The right hand's goal held from 121 (ramp in from 106) and the left hand's let go on
    120 (ramp out to 135): pass two's repair jumps between 120 and 121 and is eased half
    into each ramp, so frames 107-114, inside the right hand's ramp, read it. The window
    problem holds what reaches those two frames too, the left hand's output ramp with it
    (cut to a pin at 120, the window was 5.3 mm off the full solve at frames 107-110 and
    16.5 mm at 107-114; then 0.1 and 0.4 mm once the key postures held each other's
    goals)."""
    import sys
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from ik_fixtures import two_hands, walk_on_holden
    _, _, _, composed = walk_on_holden()
    left, right = two_hands(composed, (115, 117, 120, 135))
    full = enforce(composed, [left, right]).motion
    for lo, hi in ((107, 110), (107, 114), (118, 122)):
        problem = window_problem([left, right], lo, hi)
        ranges = {c.joint: c.range for c in problem}
        assert ranges["LeftHand"][2:] == (120, 135)               # its ramp out is kept
        motion = enforce(composed, problem, pins=True).motion
        assert np.array_equal(_positions(motion)[lo:hi + 1], _positions(full)[lo:hi + 1])


def test_a_moved_contact_on_a_carried_foot_previews_as_the_full_solve():
    """The robot's feet are control joints carried with its shins: a contact's handle dragged
    on FootL previews in its window (the window solver holds the foot through the shin, as
    the full solve does), and the foot stands where the full solve puts it."""
    from conftest import clip_path, shared_path
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.formats import read_character, read_motion
    from motion_composer.engine.correction.preview import retimed
    from motion_composer.engine.project import Project, Source
    walk, robot = clip_path("cmu_131_01_walk.bvh"), shared_path("target_robot_expressive.glb")
    performer, target = read_motion(walk), read_character(robot).rest_motion()
    project = Project(performer=Source(str(walk)), target=Source(str(robot)),
                      correspondence=automap(target.skeleton, performer.skeleton),
                      auto_contacts=True)
    solution = Scene(project, performer, target).solve(regenerate=True)
    scene, constraints = solution.scene, list(solution.constraints)
    i = next(k for k, c in enumerate(constraints) if c.joint == "FootL" and c.kind ==
             "trajectory" and c.smooth_in >= 8 and c.end < scene.num_frames - 8)
    c = constraints[i]
    after = list(constraints)
    # as the timeline drags it: the per-frame path becomes keys at its frames
    after[i] = retimed(c, (c.smooth_in - 6, c.start - 6, c.end, c.smooth_out))
    lo, hi = changed_window(constraints, after)
    motion, mode = scene.preview(after, base_constraints=constraints,
                                 base_motion=scene.motion, whole=False)
    assert mode == "window"
    full, _ = scene.preview(after)
    foot = scene.target.skeleton.index["FootL"]
    here, there = _positions(motion), _positions(full)
    assert np.abs(here - there)[lo:hi + 1].max() < 1e-4
    # held through the shin: on its path (where it planted, rising through heel-off), and
    # from the new start on the path's first point
    path = np.asarray(c.goal["points"])
    assert np.linalg.norm(here[c.start:c.end + 1, foot] - path, axis=1).max() < 1e-3
    assert np.linalg.norm(here[c.start - 6:c.start, foot] - path[0], axis=1).max() < 1e-3
