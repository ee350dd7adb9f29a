"""Bad input and edge cases of the correction (issue 14, point 5), on real clips: clips of one
and two frames with automatic contacts, targets and performers without feet, a position
constraint on the root, and constraint goals and weights that are refused."""
from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import clip_path
from motion_composer.app.cli import main
from motion_composer.engine.conversion.automap import automap
from motion_composer.engine.conversion.correspondence import Correspondence
from motion_composer.engine.correction.constraints import (Constraint, ConstraintError,
                                                           constraints_from_json)
from motion_composer.engine.correction.contacts import find_feet
from motion_composer.engine.formats import read_motion, write_motion
from motion_composer.engine.kinematics import fk_arrays
from motion_composer.engine.motion import Motion
from motion_composer.engine.project import Project, Source
from motion_composer.engine.scene import Scene
from motion_composer.engine.skeleton import EndSite, Skeleton

WALK = clip_path("cmu_131_01_walk.bvh")
TPOSE = clip_path("cmu_rest_tpose.bvh")
NO_TARGET_FEET = "no feet found on the target: no automatic contacts"


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def without_legs(motion: Motion) -> Motion:
    """``motion`` with both legs removed (every joint below the hip joints, which go too)."""
    sk = motion.skeleton
    gone = set()
    for j, name in enumerate(sk.names):
        if name in ("LHipJoint", "RHipJoint") or sk.parents[j] in gone:
            gone.add(j)
    keep = [j for j in range(sk.num_joints) if j not in gone]
    new = {old: k for k, old in enumerate(keep)}
    legless = Skeleton(
        names=[sk.names[j] for j in keep],
        parents=[new[sk.parents[j]] if sk.parents[j] >= 0 else -1 for j in keep],
        offsets=sk.offsets[keep], channels=[sk.channels[j] for j in keep],
        position_modes=[sk.position_modes[j] for j in keep],
        end_sites=[EndSite(new[e.parent], e.offset, e.name) for e in sk.end_sites
                   if e.parent not in gone],
        source=sk.source)
    assert legless.translated == sk.translated            # only the root is translated
    return Motion(legless, motion.rotations[:, keep], motion.translations, motion.frame_time,
                  motion.name)


def full_map() -> Correspondence:
    """The automatic map of the walk onto the T-pose, both with their legs."""
    return automap(read_motion(TPOSE).skeleton, read_motion(WALK).skeleton)


def kept_pairs(target: Motion, performer: Motion) -> Correspondence:
    """:func:`full_map`'s pairs whose joints both skeletons still have (a skeleton without
    legs is no humanoid the auto-map recognises: it is mapped by hand)."""
    return Correspondence({t: p for t, p in full_map().pairs.items()
                           if t in target.skeleton.index and p in performer.skeleton.index})


def scene_of(performer: Motion, target: Motion, correspondence=None, **project) -> Scene:
    corr = correspondence or kept_pairs(target, performer)
    return Scene(Project(performer=Source(), target=Source(), correspondence=corr, **project),
                 performer, target)


# ------------------------------------------------------------------ one and two frames
@pytest.mark.parametrize("frames", [1, 2])
def test_a_short_clip_with_automatic_contacts_gives_no_contacts_and_no_error(
        capsys, tmp_path, frames):
    clip = tmp_path / f"walk{frames}.bvh"
    write_motion(read_motion(WALK).excerpt(200, 200 + frames - 1), clip)
    code, out, err = run(capsys, "retarget", clip, "--target", TPOSE, "-o",
                         tmp_path / "out.bvh", "--auto-contacts", "--report",
                         tmp_path / "r.json")
    assert (code, err) == (0, ""), err
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["frames"] == frames
    assert report["contacts"] == [] and report["warnings"] == []
    assert read_motion(tmp_path / "out.bvh").num_frames == frames

    performer = read_motion(clip)
    solution = scene_of(performer, read_motion(TPOSE), auto_contacts=True).solve(
        regenerate=True)
    assert solution.constraints == [] and solution.correction is None
    assert solution.report["warnings"] == []
    assert solution.motion.num_frames == frames


@pytest.mark.parametrize("start", [0, 200])
def test_a_three_frame_clip_gets_its_keys(capsys, tmp_path, start):
    """Three frames of the walk with automatic contacts: the clip is long enough for them,
    and its layer's key budget (a tenth of a key a frame) rounded to no key at all, and the
    key fit raised IndexError (exit 3, the CLI fuzz at seed 4807). Every curve keeps at
    least its span's two ends."""
    clip = tmp_path / "walk3.bvh"
    write_motion(read_motion(WALK).excerpt(start, start + 2), clip)
    code, out, err = run(capsys, "retarget", clip, "--target", TPOSE, "-o",
                         tmp_path / "out.bvh", "--auto-contacts", "--report",
                         tmp_path / "r.json")
    assert (code, err) == (0, ""), err
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["frames"] == 3 and report["constraints"]
    assert max(c["max_residual"] for c in report["constraints"]
               if c["residual_unit"] == "m") < 1e-3
    assert read_motion(tmp_path / "out.bvh").num_frames == 3


# ------------------------------------------------------------------ no feet
def test_a_target_without_legs_warns_once_on_stderr_and_in_the_report(capsys, tmp_path):
    target = tmp_path / "legless.bvh"
    write_motion(without_legs(read_motion(TPOSE)), target)
    # a figure without legs leaves its up axis in doubt (a warning of its own): it is given
    legless = read_motion(target)
    assert find_feet(legless.skeleton) == []
    kept_pairs(legless, read_motion(WALK)).save(tmp_path / "map.json")
    code, out, err = run(capsys, "retarget", WALK, "--target", target, "-o",
                         tmp_path / "out.bvh", "--map", tmp_path / "map.json",
                         "--target-up-axis", "+Y", "--auto-contacts", "--report",
                         tmp_path / "r.json")
    assert code == 0
    assert err == f"motion-composer: warning: {NO_TARGET_FEET}\n"
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["warnings"] == [NO_TARGET_FEET] and report["contacts"] == []

    # without automatic contacts nothing was asked for: no warning
    code, out, err = run(capsys, "retarget", WALK, "--target", target, "-o",
                         tmp_path / "out.bvh", "--map", tmp_path / "map.json",
                         "--target-up-axis", "+Y")
    assert (code, err) == (0, "")


def test_the_scene_reports_missing_feet_on_either_side():
    walk, tpose = read_motion(WALK), read_motion(TPOSE)
    solution = scene_of(walk, without_legs(tpose), auto_contacts=True).solve(regenerate=True)
    assert solution.report["warnings"] == [NO_TARGET_FEET]
    assert not any(c.auto for c in solution.constraints)

    solution = scene_of(without_legs(walk), tpose, auto_contacts=True).solve(regenerate=True)
    assert solution.report["warnings"] == ["no feet found on the performer: no automatic "
                                           "contacts"]
    # a solve that does not regenerate the automatic constraints makes none: no warning
    assert scene_of(walk, without_legs(tpose), auto_contacts=True).solve(
        constraints=[]).report["warnings"] == []


def test_a_foot_whose_toe_the_map_leaves_out_is_held_by_its_ankle_once():
    """With the toes unmapped, the target's feet are found twice (by its own skeleton, with
    toes, and through the map, without): each foot joint still gets one floor plane, and the
    contacts are found from the performer's heels (each ankle pinned over its contact, its
    orientation held)."""
    walk, tpose = read_motion(WALK), read_motion(TPOSE)
    full = full_map()
    toes = [t for _, t in find_feet(walk.skeleton) if t]
    assert toes
    corr = Correspondence({t: p for t, p in full.pairs.items() if p not in toes})
    floors = scene_of(walk, tpose, corr, floor=0.0).automatic_constraints()
    planes = [c.joint for c in floors if c.kind == "plane"]
    assert planes and len(planes) == len(set(planes))
    scene = scene_of(walk, tpose, corr, auto_contacts=True, floor=0.0)
    assert all(c.toe is None for c in scene.contacts())
    held = [c for c in scene.automatic_constraints() if c.kind == "position"]
    turned = [c for c in scene.automatic_constraints() if c.kind == "orientation"]
    assert held and [(c.joint, c.range) for c in held] == [(c.joint, c.range) for c in turned]


def test_performer_feet_the_map_leaves_out_are_named():
    walk, tpose = read_motion(WALK), read_motion(TPOSE)
    full = full_map()
    feet = [a for a, _ in find_feet(walk.skeleton)]
    assert feet == ["LeftAnkle", "RightAnkle"]

    def mapped_without(*performer_joints):
        return Correspondence({t: p for t, p in full.pairs.items()
                               if p not in performer_joints})

    solution = scene_of(walk, tpose, mapped_without(*feet), auto_contacts=True).solve(
        regenerate=True)
    assert solution.report["warnings"] == [
        "the performer's feet (LeftAnkle, RightAnkle) are not mapped to the target: no "
        "automatic contacts"]
    assert not any(c.auto for c in solution.constraints)

    solution = scene_of(walk, tpose, mapped_without("LeftAnkle"), auto_contacts=True).solve(
        regenerate=True)
    assert solution.report["warnings"] == [
        "the performer's foot LeftAnkle is not mapped to the target: no automatic contacts "
        "on it"]
    pinned = {c.meta["performer_joint"] for c in solution.constraints if c.auto}
    assert "RightAnkle" in pinned and "LeftAnkle" not in pinned

    assert scene_of(walk, tpose, full, auto_contacts=True).solve(
        regenerate=True).report["warnings"] == []


def test_the_window_shows_the_warning_in_the_status_bar(qtbot, tmp_path, monkeypatch):
    from gui_support import WAIT_MS, quiet_window
    w = quiet_window(qtbot, tmp_path, monkeypatch)
    w.doc.load_scene(scene_of(read_motion(WALK), without_legs(read_motion(TPOSE))))
    with qtbot.waitSignal(w.doc.solved, timeout=WAIT_MS):
        w.solve_contacts()
    assert w.statusBar().currentMessage() == f"Warning: {NO_TARGET_FEET}"
    assert w.errors == []


# ------------------------------------------------------------------ the root
def test_a_position_constraint_on_the_root_moves_the_root_to_its_goal():
    scene = scene_of(read_motion(WALK), read_motion(TPOSE))
    composed = scene.composed
    sk = composed.skeleton
    pos = fk_arrays(sk, composed.rotations, composed.translations, end_sites=False).positions
    goal = pos[300, 0] + [0.10, -0.15, 0.05]                 # a crouch, aside and forward
    root = Constraint(joint=sk.names[0], kind="position", goal={"point": goal},
                      smooth_in=280, start=300, end=340, smooth_out=360)
    motion = scene.solve(constraints=[root]).motion
    after = fk_arrays(sk, motion.rotations, motion.translations, end_sites=False).positions
    assert np.linalg.norm(after[300:341, 0] - goal, axis=1).max() < 1e-3
    assert np.array_equal(motion.rotations[:280], composed.rotations[:280])


# ------------------------------------------------------------------ refused goals and weights
BAD = [
    ({"kind": "trajectory", "goal": {"keys": [[0, "a", 0.0, 0.0]]}}, "goal.keys"),
    ({"kind": "trajectory", "goal": {"keys": [["0", 0.0, 1.0, 0.0]]}}, "goal.keys"),
    ({"kind": "trajectory", "goal": {"keys": [[0, True, 1.0, 0.0]]}}, "goal.keys"),
    ({"kind": "trajectory", "goal": {"keys": [[0, None, 1.0, 0.0]]}}, "goal.keys"),
    ({"kind": "trajectory", "goal": {"keys": [[0, 0.0, 1.0, 0.0], [5, 0.0, 1.0]]}},
     "goal.keys"),
    ({"kind": "trajectory", "goal": {"keys": [[0, 0.0, 1.0, 0.0], 5]}}, "goal.keys"),
    ({"kind": "trajectory", "goal": {"points": [[0.0, 1.0, 0.0]] * 5 + [[0.0, 1.0]]}},
     "goal.points"),
    ({"goal": {"point": ["0", 1.0, 0.0]}}, "goal.point"),
    ({"weight": 1e6 * (1 + 1e-9)}, "weight"),
    ({"weight": 1e7}, "weight"),
    ({"weight": True}, "weight"),
]


@pytest.mark.parametrize("change, field", BAD)
def test_goals_that_are_not_numbers_and_huge_weights_are_refused_naming_the_field(
        capsys, tmp_path, change, field):
    constraint = {"joint": "LeftFoot", "kind": "position", "goal": {"point": [0.0, 0.1, 0.0]},
                  "range": [0, 5, 10, 15], "priority": 1, "weight": 1.0, **change}
    text = json.dumps({"constraints": [constraint]})
    with pytest.raises(ConstraintError, match=field.replace(".", r"\.")) as caught:
        constraints_from_json(text, "c.json")
    assert caught.value.field == field

    path = tmp_path / "c.json"
    path.write_text(text)
    code, out, err = run(capsys, "retarget", WALK, "--target", TPOSE, "-o",
                         tmp_path / "out.bvh", "--constraints", path)
    assert code == 2 and err.count("\n") == 1 and field in err and str(path) in err
    assert not (tmp_path / "out.bvh").exists()


@pytest.mark.parametrize("change, field", BAD)
def test_a_project_with_such_a_constraint_is_refused_in_one_line(capsys, tmp_path, change,
                                                                field):
    from motion_composer.engine.project import save_project
    scene = scene_of(read_motion(WALK), read_motion(TPOSE))
    project = scene.project.replace(performer=Source(str(WALK)), target=Source(str(TPOSE)))
    save_project(project.replace(constraints=(Constraint(
        "LeftFoot", "position", {"point": [0.0, 0.1, 0.0]}, 0, 5, 10, 15),)),
        tmp_path / "p.mcp")
    data = json.loads((tmp_path / "p.mcp").read_text())
    entry = data["constraints"][0]
    entry.update(change)
    (tmp_path / "p.mcp").write_text(json.dumps(data))
    code, out, err = run(capsys, "export", tmp_path / "p.mcp", "-o", tmp_path / "out.bvh")
    assert code == 2 and err.count("\n") == 1 and field in err, err
    assert not (tmp_path / "out.bvh").exists()


def test_the_largest_weight_is_accepted():
    c = Constraint("LeftFoot", "position", {"point": [0.0, 0.1, 0.0]}, 0, 5, 10, 15,
                   weight=1e6)
    assert c.weight == 1e6


def test_a_zero_length_range_inside_the_clip_is_refused_naming_the_range():
    """``[20, 20, 20, 20]``: one frame held with no ramps would jump there and back (issue 14
    point 2); at the clip's first or last frame there is nothing to jump from."""
    from motion_composer.engine.correction.enforcement import enforce
    walk, tpose = read_motion(WALK), read_motion(TPOSE)
    scene = scene_of(walk, tpose, automap(tpose.skeleton, walk.skeleton))
    composed = scene.composed
    point = {"point": [0.0, 0.0, 0.0]}
    with pytest.raises(ConstraintError, match=r"\[20, 20, 20, 20\].*ramps") as caught:
        enforce(composed, [Constraint("Hips", "position", point, 20, 20, 20, 20)])
    assert caught.value.field == "range"
    last = composed.num_frames - 1
    enforce(composed, [Constraint("Hips", "position", point, last, last, last, last)])


@pytest.mark.parametrize("shift", [10.0, 40.0])
def test_a_body_far_from_its_still_ground_root_is_measured_as_the_body(shift):
    """Bandai's walk with its hips ``shift`` metres along the floor from its ground root, which
    stays at the origin (a long take: the root is where the capture began): the figure is
    measured by its body, so its size and the contacts found in it are those of the walk
    itself. The share of the largest extent that a flat figure is measured by took in the
    still root: 40 m away the size grew from 1.37 to about 4 m, and the contacts lengthened
    by the looser height and speed thresholds."""
    from motion_composer.engine.correction.contacts import detect_contacts
    from motion_composer.engine.describe import figure_size
    from conftest import shared_path
    walk = read_motion(shared_path("bandai1_walk_normal_001.bvh"))
    sk = walk.skeleton
    assert sk.names[0] == "joint_Root" and not np.any(walk.translations[:, 0])
    slot = list(sk.translated).index(sk.index["Hips"])
    moved = walk.translations.copy()
    moved[:, slot, 0] += shift
    far = walk.replace(translations=moved)
    assert figure_size(far) == figure_size(walk)
    found = detect_contacts(far)
    assert found == detect_contacts(walk)
    assert len(found) >= 10
