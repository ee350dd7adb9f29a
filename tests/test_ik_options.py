"""IK settings as real options: validated, stored in projects (format version 2), given on the
command line, and reaching the solver."""
from __future__ import annotations

import dataclasses
import json
import math
import pickle

import numpy as np
import pytest

from motion_composer.app.cli import IK_FLAGS, main
from conftest import REPO, clip_path
from motion_composer.engine import forward_kinematics
from motion_composer.engine.batch import process_clip, recipe_from_project
from motion_composer.engine.correction.constraints import Constraint
from motion_composer.engine.correction.enforcement import enforce
from motion_composer.engine.correction import ik
from motion_composer.engine.correction.ik import IKOptions
from motion_composer.engine.errors import IKOptionsError, MotionComposerError
from motion_composer.engine.formats.bvh import write_bvh
from motion_composer.engine.project import (VERSION, ProjectError, load_project, open_project,
                            project_from_json, project_to_json, save_project)
from motion_composer.engine.scene import Scene, evaluate_project, solve_project
from ik_fixtures import walk_on_holden

DATA = REPO / "tests" / "data"
#: A real format-version-1 project, written before IK settings were stored, by
#:   cd tests/data && motion-composer retarget walk_first_60.bvh
#:       --target ../../resources/clips/fair1_child8_jumping.bvh -o x.bvh
#:       --auto-contacts --floor 0 --save-project project_v1.mcp
#: (walk_first_60.bvh: the first 60 frames of resources/clips/cmu_131_01_walk.bvh, cut as
#: text), and project_v1_motion.bvh is what `motion-composer export project_v1.mcp` wrote
#: then: the motion the project evaluates to.
V1_FIXTURE = DATA / "project_v1.mcp"
V1_MOTION = DATA / "project_v1_motion.bvh"

#: options differing from the defaults in every stored field
CHANGED = IKOptions(tolerance=2e-4, max_iterations=7, damping=0.02, max_step=0.1,
                    attraction=0.25, settle=2e-5, nullspace_damping=3e-6, step_cap=0.2,
                    polish_share=0.5, priority_gate=4.0, joint_limits={5: 0.75, 2: 1.5})


def _pos(motion, joint):
    return forward_kinematics(motion).positions[:, motion.skeleton.index[joint]]


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


# --------------------------------------------------------------------------- the options
def test_the_defaults_are_the_solvers_former_constants():
    o = IKOptions()
    assert (o.tolerance, o.max_iterations, o.damping, o.max_step, o.attraction, o.settle,
            o.nullspace_damping, o.step_cap, o.polish_share, o.priority_gate) == \
        (1e-4, 60, 0.005, 0.05, 0.5, 1e-5, 1e-6, 0.3, 0.25, 10.0)
    assert o.joint_limits == () and o.scale is None


@pytest.mark.parametrize("field, value, words", [
    ("damping", -0.1, "above 0"), ("damping", 0.0, "above 0"),
    ("damping", math.nan, "finite"), ("tolerance", math.inf, "finite"),
    ("tolerance", "0.1", "expected a number"), ("damping", True, "expected a number"),
    ("max_step", 0.0, "above 0"), ("attraction", 1.5, "from 0 to 1"),
    ("attraction", -0.1, "from 0 to 1"), ("settle", -1e-9, ">= 0"),
    ("nullspace_damping", 0.0, "above 0"), ("step_cap", -0.3, "above 0"),
    ("polish_share", 1.25, "from 0 to 1"), ("priority_gate", 0.0, "above 0"),
    ("scale", 0.0, "above 0"), ("scale", math.nan, "finite"),
    ("max_iterations", -1, ">= 0"), ("max_iterations", 2.5, "whole number"),
    ("max_iterations", True, "whole number"),
    ("joint_limits", {3: -0.1}, ">= 0"), ("joint_limits", {-1: 0.5}, "joint index"),
    ("joint_limits", [(3, 0.5), (3, 0.2)], "limited twice"),
    ("joint_limits", [(3,)], "(joint index, angle)"), ("joint_limits", 5, "pairs"),
])
def test_a_bad_value_names_its_field(field, value, words):
    with pytest.raises(IKOptionsError) as exc:
        IKOptions(**{field: value})
    assert exc.value.field == field and words in exc.value.problem
    assert str(exc.value).startswith(f"IK option {field}: ")
    assert isinstance(exc.value, MotionComposerError)
    again = pickle.loads(pickle.dumps(exc.value))           # crosses worker processes
    assert (again.field, str(again)) == (field, str(exc.value))


def test_the_options_are_frozen_hashable_values():
    a = IKOptions(damping=0.01, joint_limits={7: 0.5, 3: 1.0})
    b = IKOptions(damping=0.01, joint_limits=[(3, 1.0), (7, 0.5)])
    assert a.joint_limits == ((3, 1.0), (7, 0.5))
    assert a == b and hash(a) == hash(b) and {a: "cached"}[b] == "cached"
    assert a != IKOptions(damping=0.02, joint_limits=a.joint_limits)
    assert type(IKOptions(max_iterations=np.int64(5)).max_iterations) is int
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.damping = 0.5


def test_no_options_and_the_default_options_give_the_same_correction():
    performer, target, corr, composed = walk_on_holden()
    goal = _pos(composed, "LeftHand")[420] + [0.12, 0.20, 0.08]
    c = Constraint("LeftHand", "position", {"point": goal}, 380, 420, 520, 570)
    a = enforce(composed, [c])
    b = enforce(composed, [c], options=IKOptions())
    np.testing.assert_array_equal(a.rotvecs, b.rotvecs)
    np.testing.assert_array_equal(a.root, b.root)


# --------------------------------------------------------------------------- effects
@pytest.fixture(scope="module")
def v1_session():
    return open_project(V1_FIXTURE)


def _worst(session, options):
    project, performer, target = session
    result = Scene(project, performer, target).solve(ik_options=options)
    return max(c["max_residual"] for c in result.report["constraints"]), result


@pytest.mark.parametrize("change", [{"max_iterations": 1}, {"step_cap": 0.001},
                                    {"nullspace_damping": 0.1}, {"damping": 0.2}])
def test_a_cramped_solver_leaves_a_larger_residual_on_a_real_clip(v1_session, change):
    """The walk's feet pinned by automatic contacts (and a floor): the defaults meet them
    to a few micrometres; one iteration, a tiny joint step, a heavy damping leave more."""
    default, _ = _worst(v1_session, IKOptions())
    cramped, result = _worst(v1_session, IKOptions(**change))
    assert default < 5e-6
    assert cramped > 3 * default
    if "max_iterations" in change:
        assert result.correction.iterations.max() == 1 and cramped > 1e-3


@pytest.fixture(scope="module")
def out_of_reach():
    """Both feet pinned (first priority), the left hand asked 3 m away (second)."""
    performer, target, corr, composed = walk_on_holden()
    feet = [Constraint(foot, "position", {"point": _pos(composed, foot)[300]}, 300, 300, 320,
                       320, name=foot) for foot in ("LeftFoot", "RightFoot")]
    far = _pos(composed, "LeftHand")[300] + [3.0, 0.0, 0.0]
    hand = Constraint("LeftHand", "position", {"point": far}, 300, 300, 320, 320, priority=2)
    return composed, feet + [hand]


def _residuals(case, **change):
    composed, constraints = case
    result = enforce(composed, constraints, options=IKOptions(**change))
    feet = max(np.nanmax(result.residual[i][300:321]) for i in (0, 1))
    return feet, np.nanmax(result.residual[2][300:321])


def test_the_polishing_share_restores_the_first_level(out_of_reach):
    feet, hand = _residuals(out_of_reach)
    assert feet < 1e-9 and hand < 2.5                     # the hand reached out
    feet, _ = _residuals(out_of_reach, polish_share=0.0)  # ends mid-oscillation
    assert feet > 1e-3
    feet, still = _residuals(out_of_reach, polish_share=1.0)  # only ever the first level
    assert feet < 1e-9 and still > hand + 0.5


def test_the_priority_gate_holds_a_lower_level_back(out_of_reach):
    _, hand = _residuals(out_of_reach)
    feet, held = _residuals(out_of_reach, priority_gate=0.01)
    assert feet < 1e-9 and held > hand + 0.1


# --------------------------------------------------------------------------- projects
def test_a_version_1_project_migrates_and_evaluates_to_the_same_motion(v1_session, tmp_path,
                                                                      monkeypatch):
    assert json.loads(V1_FIXTURE.read_text())["version"] == 1
    project, performer, target = v1_session
    assert project.ik_options == IKOptions()
    motion = evaluate_project(project, performer, target).motion
    write_bvh(motion, tmp_path / "now.bvh")
    assert (tmp_path / "now.bvh").read_bytes() == V1_MOTION.read_bytes()
    # solved again with the migrated settings, the correction is the one version 1 stored
    # (its keys are fitted otherwise since version 3: the same motion within their tolerance)
    # wherever the constraints decide it; inside the ramps the correction eases in and out
    # along a smoothstep since the no-pop rule (issue 14 point 2), no longer along the goal
    # line version 1 solved; version 1 took the plain least-norm step, where the solver now
    # weighs the root's translation (ik.ROOT_TRANSLATION): the key postures are those of that
    # norm; and the solved layer's keys are fitted to the tasks since issue 15 and leave what
    # no task holds to the fit: compared here is the IK's dense correction
    monkeypatch.setattr(ik, "STIFFNESS", None)
    solved = Scene.from_project(project, performer, target).solve().correction.motion
    gap = forward_kinematics(solved).positions - forward_kinematics(motion).positions
    ramps = np.zeros(len(gap), dtype=bool)
    for c in project.constraints:
        ramps[c.smooth_in + 1:c.start] = True
        ramps[c.end + 1:c.smooth_out] = True
    assert ramps.sum() < 0.3 * len(gap)
    assert np.abs(gap[~ramps]).max() < 1e-3
    # saved, it is a current-version file with every setting written
    save_project(project, tmp_path / "v2.mcp")
    data = json.loads((tmp_path / "v2.mcp").read_text())
    assert data["version"] == VERSION == 4
    assert list(data)[list(data).index("floor") + 2] == "ik"
    # its floor stays the feet's plane only (format 4 moves a new project's conversion
    # onto its floor: :func:`_v3_to_v4`)
    assert data["floor"] == 0.0 and data["stand_on_floor"] is False
    assert data["ik"] == {"tolerance": 1e-4, "max_iterations": 60, "damping": 0.005,
                          "max_step": 0.05, "attraction": 0.5, "settle": 1e-5,
                          "nullspace_damping": 1e-6, "step_cap": 0.3, "polish_share": 0.25,
                          "priority_gate": 10.0, "joint_limits": []}
    again = evaluate_project(load_project(tmp_path / "v2.mcp")).motion
    np.testing.assert_array_equal(again.rotations, motion.rotations)


def test_version_2_round_trips_byte_identical_with_changed_options(v1_session, tmp_path):
    project = v1_session.project.replace(ik_options=CHANGED)
    text = project_to_json(project, V1_FIXTURE)
    loaded = project_from_json(text, V1_FIXTURE)
    assert loaded.ik_options == CHANGED
    assert project_to_json(loaded, V1_FIXTURE) == text
    ik = json.loads(text)["ik"]
    assert ik["max_iterations"] == 7 and ik["joint_limits"] == [[2, 1.5], [5, 0.75]]
    assert "scale" not in ik
    path = tmp_path / "p.mcp"
    path.write_text(text)
    assert load_project(path, check_sources=False).ik_options == CHANGED


def test_a_project_does_not_hold_a_scale():
    project = load_project(V1_FIXTURE, check_sources=False)
    with pytest.raises(ValueError, match="scale"):
        project.replace(ik_options=IKOptions(scale=1.2))


@pytest.mark.parametrize("key, value, field, words", [
    ("damping", "NaN", "ik.damping", "NaN"),
    ("damping", "-0.5", "ik.damping", "above 0"),
    ("damping", '"strong"', "ik.damping", "expected a number, not a string"),
    ("tolerance", "1e999", "ik.tolerance", "too large"),
    ("max_iterations", "2.5", "ik.max_iterations", "whole number"),
    ("max_iterations", "-3", "ik.max_iterations", "from 0"),
    ("attraction", "2", "ik.attraction", "from 0 to 1"),
    ("polish_share", "null", "ik.polish_share", "expected a number"),
    ("joint_limits", "[[3, -1]]", "ik.joint_limits", ">= 0"),
    ("joint_limits", "[[3]]", "ik.joint_limits[0]", "[joint index, angle]"),
    ("joint_limits", '[["LeftArm", 1]]', "ik.joint_limits[0][0]", "whole number"),
    ("scale", "1.7", "ik.scale", "unknown field"),
])
def test_a_bad_ik_value_in_a_file_names_its_field(tmp_path, key, value, field, words):
    text = project_to_json(load_project(V1_FIXTURE, check_sources=False), V1_FIXTURE)
    data = json.loads(text)
    data["ik"][key] = "@@"
    bad = tmp_path / "bad.mcp"
    bad.write_text(json.dumps(data).replace('"@@"', value))
    with pytest.raises(ProjectError) as exc:
        load_project(bad, check_sources=False)
    assert exc.value.field == field and words in exc.value.problem, str(exc.value)


def test_a_limited_joint_must_be_in_the_target(tmp_path):
    project = load_project(V1_FIXTURE, check_sources=False)
    limits = IKOptions(joint_limits={3: 0.5, 27: 0.5})          # the child has 27 joints
    save_project(project.replace(ik_options=limits), tmp_path / "limits.mcp")
    with pytest.raises(ProjectError) as exc:
        load_project(tmp_path / "limits.mcp")
    assert exc.value.field == "ik.joint_limits[1]" and "last joint (26)" in exc.value.problem


def test_solving_with_other_options_keeps_them(v1_session):
    project, performer, target = v1_session
    solved = solve_project(project, performer, target,
                           ik_options=IKOptions(max_iterations=2, scale=1.3))
    assert solved.ik_options == IKOptions(max_iterations=2)
    assert solved.displacement.to_dict() != project.displacement.to_dict()


# --------------------------------------------------------------------------- the CLI
WALK60 = DATA / "walk_first_60.bvh"
CHILD = clip_path("fair1_child8_jumping.bvh")
FLAGS = ["--ik-iterations", "2", "--ik-damping", "0.02", "--ik-step-cap", "0.25",
         "--ik-tolerance", "2e-4", "--ik-nullspace-damping", "3e-6", "--ik-max-step", "0.1",
         "--ik-attraction", "0.4", "--ik-settle", "2e-5", "--ik-polish-share", "0.5",
         "--ik-priority-gate", "5"]
FLAGGED = IKOptions(max_iterations=2, damping=0.02, step_cap=0.25, tolerance=2e-4,
                    nullspace_damping=3e-6, max_step=0.1, attraction=0.4, settle=2e-5,
                    polish_share=0.5, priority_gate=5.0)


def test_every_setting_has_a_flag():
    stored = [f.name for f in dataclasses.fields(IKOptions)
              if f.name not in ("joint_limits", "scale")]
    assert sorted(name for _, name, _ in IK_FLAGS) == sorted(stored)
    assert len(FLAGS) == 2 * len(IK_FLAGS)


def test_retarget_flags_reach_the_solver_and_the_project(v1_session, capsys, tmp_path):
    code, _, err = _run(capsys, "retarget", WALK60, "--target", CHILD, "-o",
                        tmp_path / "cli.bvh", "--auto-contacts", "--floor", "0", *FLAGS,
                        "--save-project", tmp_path / "cli.mcp")
    assert code == 0, err
    project, performer, target = v1_session
    fresh = Scene(project.replace(constraints=(), auto_contacts=True, floor=0.0,
                                  stand_on_floor=True), performer, target)
    result = fresh.solve(regenerate=True, ik_options=FLAGGED)
    write_bvh(result.motion, tmp_path / "engine.bvh")
    assert (tmp_path / "cli.bvh").read_bytes() == (tmp_path / "engine.bvh").read_bytes()
    default = fresh.solve(regenerate=True, ik_options=IKOptions())
    assert not np.array_equal(default.motion.rotations, result.motion.rotations)
    assert load_project(tmp_path / "cli.mcp").ik_options == FLAGGED


def test_export_solves_with_the_projects_options_unless_overridden(v1_session, capsys,
                                                                   tmp_path):
    project, performer, target = v1_session
    path = tmp_path / "p.mcp"
    save_project(project.replace(ik_options=IKOptions(max_iterations=1)), path)
    for flags, options in (((), IKOptions(max_iterations=1)),
                           (("--ik-iterations", "3", "--ik-damping", "0.01"),
                            IKOptions(max_iterations=3, damping=0.01))):
        code, _, err = _run(capsys, "export", path, "-o", tmp_path / "cli.bvh", "--solve",
                            *flags)
        assert code == 0, err
        solved = solve_project(project, performer, target, ik_options=options)
        write_bvh(evaluate_project(solved, performer, target).motion, tmp_path / "engine.bvh")
        assert (tmp_path / "cli.bvh").read_bytes() == (tmp_path / "engine.bvh").read_bytes()


def test_batch_flags_override_the_projects_options(v1_session, capsys, tmp_path):
    project = v1_session.project
    path = tmp_path / "p.mcp"
    save_project(project.replace(ik_options=IKOptions(damping=0.01)), path)
    code, _, err = _run(capsys, "batch", path, WALK60, "-o", tmp_path / "cli", "--workers",
                        "1", "--ik-iterations", "2")
    assert code == 0, err
    recipe = recipe_from_project(project.replace(
        ik_options=IKOptions(damping=0.01, max_iterations=2)))
    # the migrated floor stays the feet's plane only, clip after clip
    assert recipe.floor == 0.0 and recipe.stand_on_floor is False
    summary = process_clip(recipe, str(WALK60), str(tmp_path / "engine"))
    assert summary["status"] == "written"
    assert ((tmp_path / "cli" / WALK60.name).read_bytes() ==
            (tmp_path / "engine" / WALK60.name).read_bytes())
    plain = process_clip(recipe_from_project(project), str(WALK60), str(tmp_path / "plain"))
    assert plain["max_residual_m"] < summary["max_residual_m"]


@pytest.mark.parametrize("flag, value, words", [
    ("--ik-damping", "-1", "--ik-damping: expected a number above 0, not -1.0"),
    ("--ik-damping", "soft", "--ik-damping: expected a number, not 'soft'"),
    ("--ik-tolerance", "nan", "--ik-tolerance: expected a finite number"),
    ("--ik-iterations", "2.5", "--ik-iterations: expected a whole number, not '2.5'"),
    ("--ik-iterations", "-4", "--ik-iterations: expected a whole number >= 0"),
    ("--ik-attraction", "1.5", "--ik-attraction: expected a number from 0 to 1"),
    ("--ik-step-cap", "0", "--ik-step-cap: expected a number above 0"),
])
def test_a_bad_flag_value_gives_one_line_and_exit_2(capsys, tmp_path, flag, value, words):
    for argv in (["retarget", WALK60, "--target", CHILD, "-o", tmp_path / "x.bvh"],
                 ["export", V1_FIXTURE, "-o", tmp_path / "x.bvh", "--solve"],
                 ["batch", V1_FIXTURE, WALK60, "-o", tmp_path / "out", "--workers", "1"]):
        code, out, err = _run(capsys, *argv, flag, value)
        assert code == 2 and out == ""
        assert err.count("\n") == 1 and err.startswith("motion-composer: error: ")
        assert words in err, err
    assert not (tmp_path / "x.bvh").exists() and not (tmp_path / "out").exists()


def test_the_tolerance_grows_with_a_giant_and_only_with_a_giant():
    """A task is met below ``tolerance``, or MIN_TOLERANCE of the character's size where that
    is more: human sizes keep the setting as it is."""
    from motion_composer.engine.correction.ik import MIN_TOLERANCE
    assert IKOptions().met_below() == 1e-4
    assert IKOptions(scale=1.8).met_below() == 1e-4
    assert IKOptions(scale=60.0).met_below() == pytest.approx(MIN_TOLERANCE * 60.0)
    assert IKOptions(scale=60.0, tolerance=0.01).met_below() == 0.01
