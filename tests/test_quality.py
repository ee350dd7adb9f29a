"""The quality figures (``engine.correction.quality``) that ``retarget --report`` writes under
``"quality"`` and the window's quality panel shows: their schema, and what they say on real
clips."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from conftest import clip_path
from motion_composer.app.cli import main
from motion_composer.engine.conversion.correspondence import Correspondence
from motion_composer.engine.correction.constraints import Constraint
from motion_composer.engine.correction.quality import angular_speed, goal_jumps, quality, ramps
from motion_composer.engine.formats import read_motion
from motion_composer.engine.project import Project, Source
from motion_composer.engine.scene import Scene
from ik_fixtures import MAX_TO_HOLDEN

WALK = clip_path("cmu_131_01_walk.bvh")
TPOSE = clip_path("cmu_rest_tpose.bvh")


@pytest.fixture(scope="module")
def walk_solution():
    performer, target = read_motion(WALK), read_motion(TPOSE)
    project = Project(performer=Source(str(WALK)), target=Source(str(TPOSE)),
                      correspondence=Correspondence(MAX_TO_HOLDEN), auto_contacts=True)
    return Scene(project, performer, target).solve(regenerate=True)


def _check_schema(q: dict, frames: int) -> None:
    assert set(q) >= {"constraints", "contacts", "pops", "bone_directions", "per_frame"}
    for c in q["constraints"]:
        assert isinstance(c["name"], str) and isinstance(c["joint"], str)
        for key in ("max_residual", "mean_residual"):
            assert c[key] is None or isinstance(c[key], float)
        assert c["frame"] is None or isinstance(c["frame"], int)
    for c in q["contacts"]:
        assert c["part"] in ("heel", "toe") and isinstance(c["joint"], str)
        assert isinstance(c["start"], int) and isinstance(c["end"], int)
        assert isinstance(c["drift_direct_m"], float)
        assert isinstance(c["drift_corrected_m"], float)
    for p in q["pops"]:
        assert isinstance(p["joint"], str) and isinstance(p["frame"], int)
        for key in ("ratio", "speed_deg_s", "limit_deg_s"):
            assert isinstance(p[key], float)
    for b in q["bone_directions"]:
        assert isinstance(b["joint"], str) and isinstance(b["frame"], int)
        assert isinstance(b["max_error_deg"], float)
    for key in ("foot_slide_m", "max_residual_m"):
        values = q["per_frame"][key]
        assert len(values) == frames and all(isinstance(v, float) for v in values)


def test_the_report_holds_the_quality_figures(walk_solution):
    q = walk_solution.report["quality"]
    F = walk_solution.motion.num_frames
    _check_schema(q, F)
    json.dumps(q, allow_nan=False)
    enabled = [c for c in walk_solution.constraints if c.enabled]
    assert [c["name"] for c in q["constraints"]] == [c.name or c.joint for c in enabled]
    # the residuals are those of the correction, the frame is where the largest is
    for i, (c, entry) in enumerate(zip(enabled, q["constraints"])):
        res = walk_solution.correction.residual[i]
        assert entry["max_residual"] == pytest.approx(np.nanmax(res[c.start:c.end + 1]))
        assert res[entry["frame"]] == entry["max_residual"]
    # every contact is held: the corrected drift is below the direct conversion's
    assert q["contacts"]
    for c in q["contacts"]:
        assert c["drift_corrected_m"] <= c["drift_direct_m"] + 1e-9
    # the per-frame slide is the contacts' drift
    slide = np.array(q["per_frame"]["foot_slide_m"])
    assert slide.max() == pytest.approx(max(c["drift_corrected_m"] for c in q["contacts"]))
    # the worst pop comes first, and a mapped bone follows its performer bone
    ratios = [p["ratio"] for p in q["pops"]]
    assert ratios == sorted(ratios, reverse=True)
    assert {b["joint"] for b in q["bone_directions"]} >= {"LeftLeg", "RightFoot"}


def test_without_constraints_the_direct_conversion_is_measured():
    performer, target = read_motion(WALK), read_motion(TPOSE)
    project = Project(performer=Source(str(WALK)), target=Source(str(TPOSE)),
                      correspondence=Correspondence(MAX_TO_HOLDEN))
    solution = Scene(project, performer, target).solve(regenerate=True)
    q = solution.report["quality"]
    _check_schema(q, performer.num_frames)
    assert q["constraints"] == [] and q["contacts"] == [] and q["pops"] == []
    assert q["per_frame"]["foot_slide_m"] == [0.0] * performer.num_frames
    # the direct conversion orients each bone along its performer bone
    primary = {b["joint"]: b["max_error_deg"] for b in q["bone_directions"]}
    assert primary["LeftLeg"] < 1.0 and primary["RightFoot"] < 1.0


def test_a_hard_switch_is_a_one_frame_ramp_and_the_frames_around_it_are_measured(
        walk_solution):
    performer = read_motion(WALK)
    composed = walk_solution.scene.composed
    hand = Constraint("LeftHand", "position", {"point": [0.3, 0.0, 0.3]}, 100, 100, 120, 120)
    assert ramps([hand], composed.num_frames) == [(99, 100), (120, 121)]
    from motion_composer.engine.correction.enforcement import enforce
    result = enforce(composed, [hand])
    q = quality(performer, composed, result.motion, [hand], result.residual)
    worst = q["pops"][0]
    assert 99 <= worst["frame"] <= 122          # turned into from 98 .. 121
    speed = angular_speed(result.motion)
    joint = composed.skeleton.index[worst["joint"]]
    assert np.degrees(speed[worst["frame"], joint]) == pytest.approx(worst["speed_deg_s"])


def test_a_switch_eased_with_another_ramp_is_judged_over_that_ramp():
    """A toe held from the flat foot on (no ramp of its own, switched on where the heel's and
    the flat turn's input ramps end) is eased with the shortest of them (enforcement's
    _virtual_frames), so the no-pop rule judges it over that ramp; a lone switch, or one next
    to a ramp of one frame only, is still a one-frame span."""
    heel = Constraint("LeftFoot", "position", {"point": [0.0, 0.1, 0.0]}, 10, 24, 50, 64)
    flat = Constraint("LeftFoot", "orientation", {"quaternion": [0, 0, 0, 1]}, 16, 24, 50, 60)
    toe = Constraint("LeftToeBase", "position", {"point": [0.0, 0.0, 0.1]}, 24, 24, 50, 50)
    assert ramps([heel, flat, toe], 100) == [(10, 24), (16, 24), (50, 60), (50, 64)]
    lone = Constraint("RightToeBase", "position", {"point": [0.0, 0.0, 0.1]}, 30, 30, 40, 40)
    short = Constraint("RightFoot", "position", {"point": [0.0, 0.1, 0.0]}, 29, 30, 40, 41)
    assert ramps([lone], 100) == [(29, 30), (40, 41)]
    assert ramps([lone, short], 100) == [(29, 30), (40, 41)]
    # a ramp of one frame is no ramp to enforcement either: the toe goes with the heel's
    brief = Constraint("LeftToeBase", "position", {"point": [0.0, 0.0, 0.1]}, 23, 24, 50, 51)
    assert ramps([heel, brief], 100) == [(10, 24), (50, 64)]


def test_retarget_report_writes_the_quality_figures(tmp_path, capsys):
    report = tmp_path / "report.json"
    code = main(["retarget", str(WALK), "--target", str(TPOSE), "-o", str(tmp_path / "o.bvh"),
                 "--auto-contacts", "--report", str(report)])
    assert code == 0, capsys.readouterr().err
    data = json.loads(report.read_text())
    _check_schema(data["quality"], data["frames"])
    assert data["quality"]["contacts"]


def test_contradicting_goals_at_one_priority_give_a_continuous_compromise(walk_solution):
    """Two goals 80 cm apart for one hand at one priority: neither is met, and the hand
    settles between them without a flip (no joint turns faster than the no-pop limit)."""
    from motion_composer.engine.correction.enforcement import enforce
    from motion_composer.engine.kinematics import fk_arrays
    performer = read_motion(WALK)
    composed = walk_solution.scene.composed
    sk = composed.skeleton
    here = fk_arrays(sk, composed.rotations, composed.translations,
                     end_sites=False).positions[400, sk.index["LeftHand"]]
    there = [Constraint("LeftHand", "position", {"point": here + offset}, 300, 320, 480, 500,
                        name=name)
             for name, offset in (("up", [0.4, 0.3, 0.0]), ("down", [-0.4, -0.2, 0.3]))]
    result = enforce(composed, there)
    q = quality(performer, composed, result.motion, there, result.residual)
    assert all(c["max_residual"] > 0.1 for c in q["constraints"])       # a compromise
    assert max(p["ratio"] for p in q["pops"]) <= 1.0


def _hand_goals(composed, first: int, second: int, apart):
    """Two of the user's goals for the left hand: one held to frame ``first`` (where the
    conversion puts it then, 10 cm higher) and one from frame ``second`` (``apart`` [m] along
    x from it, or where the conversion puts the hand then, 10 cm higher, with ``None``)."""
    from motion_composer.engine.kinematics import fk_arrays
    sk = composed.skeleton
    hand = fk_arrays(sk, composed.rotations, composed.translations,
                     end_sites=False).positions[:, sk.index["LeftHand"]] + [0.0, 0.1, 0.0]
    b = hand[second] if apart is None else hand[first] + [apart, 0.0, 0.0]
    return (Constraint("LeftHand", "position", {"point": hand[first]}, first - 20, first - 10,
                       first, first + 15, name="reach A"),
            Constraint("LeftHand", "position", {"point": b}, second - 15, second, second + 20,
                       second + 35, name="reach B"))


def test_two_goals_a_joint_cannot_travel_between_are_named_in_one_line(walk_solution):
    """The reviewer's case: the left hand held until frame 120 and from frame 121 at goals
    19 cm apart (the walk moves it about a centimetre a frame). The request asks for a jump
    that no easing hides (it turned 2.6 times the no-pop limit), so it is said, once, with
    both constraints, the frames and the distance; the automatic contacts of the walk say
    nothing."""
    composed = walk_solution.scene.composed
    assert walk_solution.report["warnings"] == []
    a, b = _hand_goals(composed, 120, 121, 0.19)
    lines = goal_jumps(composed, [a, b])
    assert len(lines) == 1
    assert lines[0].startswith("LeftHand: 'reach A' holds it to frame 120 and 'reach B' from "
                               "frame 121, at goals 19.0 cm apart, ")
    assert "the motion jumps there" in lines[0]
    # the order the constraints come in does not matter, nor the contacts beside them
    assert goal_jumps(composed, [b, *walk_solution.constraints, a]) == lines


@pytest.mark.parametrize("case", ["with the conversion", "frames to travel", "overlapping",
                                  "held between", "disabled", "a few millimetres"])
def test_goals_a_joint_can_travel_between_are_not_a_jump(walk_solution, case):
    composed = walk_solution.scene.composed
    if case == "with the conversion":     # the second goal where the hand goes on its own
        a, b = _hand_goals(composed, 120, 121, None)
    elif case == "frames to travel":      # 19 cm over 40 frames: slower than the walk's hand
        a, b = _hand_goals(composed, 120, 160, 0.19)
    elif case == "overlapping":           # a compromise, not a jump
        a, b = _hand_goals(composed, 120, 121, 0.19)
        b = b.with_range(b.smooth_in, 118, b.end, b.smooth_out)
    elif case == "a few millimetres":     # under JUMP_FLOOR of the stature
        a, b = _hand_goals(composed, 120, 121, 0.005)
    else:
        a, b = _hand_goals(composed, 120, 124, 0.19)
    extra = []
    if case in ("held between", "disabled"):    # a jump but for the third goal, or if enabled
        assert len(goal_jumps(composed, [a, b])) == 1
    if case == "held between":            # a third goal takes the hand from one to the other
        extra = [Constraint("LeftHand", "trajectory", {"keys": [
            [119, *a.goal["point"]], [125, *b.goal["point"]]]}, 115, 119, 125, 130)]
    if case == "disabled":
        b = dataclasses.replace(b, enabled=False)
    assert goal_jumps(composed, [a, b, *extra]) == []


def test_retarget_warns_of_a_jump_in_one_line_and_solves(tmp_path, capsys):
    """Through the CLI: one warning line on stderr, exit 0, the output written, the report
    holding the same line."""
    plain = tmp_path / "plain.bvh"
    assert main(["retarget", str(WALK), "--target", str(TPOSE), "-o", str(plain)]) == 0
    a, b = _hand_goals(read_motion(plain), 120, 121, 0.19)
    cons = tmp_path / "c.json"
    cons.write_text(json.dumps({"constraints": [c.to_dict() for c in (a, b)]}))
    capsys.readouterr()
    report = tmp_path / "r.json"
    code = main(["retarget", str(WALK), "--target", str(TPOSE), "-o", str(tmp_path / "o.bvh"),
                 "--constraints", str(cons), "--report", str(report)])
    err = capsys.readouterr().err
    assert code == 0, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("motion-composer: warning: LeftHand: "
                                                   "'reach A' holds it to frame 120")
    assert (tmp_path / "o.bvh").exists()
    assert json.loads(report.read_text())["warnings"] == [lines[0].split("warning: ", 1)[1]]


def test_the_window_shows_a_jump_in_the_status_bar(qtbot, tmp_path, monkeypatch):
    """The window's solve says it too, as the other warnings of a solve (the status bar)."""
    from gui_support import SOLVE_WAIT_MS, quiet_window
    performer, target = read_motion(WALK), read_motion(TPOSE)
    project = Project(performer=Source(str(WALK)), target=Source(str(TPOSE)),
                      correspondence=Correspondence(MAX_TO_HOLDEN))
    scene = Scene(project, performer, target)
    jump = _hand_goals(scene.composed, 120, 121, 0.19)
    w = quiet_window(qtbot, tmp_path, monkeypatch)
    w.doc.load_scene(scene.replace(constraints=jump))
    with qtbot.waitSignal(w.doc.solved, timeout=SOLVE_WAIT_MS):
        w.doc.solve()
    assert w.statusBar().currentMessage() == f"Warning: {goal_jumps(scene.composed, jump)[0]}"
    assert w.errors == []


def test_the_window_says_how_far_the_solved_keys_are_from_the_dense_solve(qtbot, tmp_path,
                                                                          monkeypatch):
    """After a real solve the status bar says the stored keys and the report's largest
    distance of a joint from the dense solve (the walk's contacts, no warning after it)."""
    from gui_support import SOLVE_WAIT_MS, quiet_window
    from motion_composer.app.gui.document import keys_note
    performer, target = read_motion(WALK), read_motion(TPOSE)
    performer = performer.replace(rotations=performer.rotations[:240],
                                  translations=performer.translations[:240])
    project = Project(performer=Source(str(WALK)), target=Source(str(TPOSE)),
                      correspondence=Correspondence(MAX_TO_HOLDEN), auto_contacts=True)
    scene = Scene(project, performer, target)
    w = quiet_window(qtbot, tmp_path, monkeypatch)
    w.doc.load_scene(scene)
    notes = []
    w.doc.noted.connect(notes.append)
    with qtbot.waitSignal(w.doc.solved, timeout=SOLVE_WAIT_MS):
        w.doc.solve(regenerate=True)
    keys = scene.solve(regenerate=True).report["keys"]
    assert keys["count"] > 0 and keys["joint"] in scene.composed.skeleton.names
    assert keys_note(keys) in notes
    assert w.statusBar().currentMessage() == keys_note(keys)
    assert "keys fitted to the" in w.statusBar().currentMessage()
    assert w.errors == []
    # nothing to solve (the contacts not generated): no keys, and nothing said of them
    bare = scene.solve().report["keys"]
    assert bare["fitted_to"] is None and bare["count"] == 0
