"""Project files (engine/project/): a whole session saved, loaded, migrated, recovered.

Real data throughout: the bundled CMU walk onto the bundled CMU T-pose character (always), and
CMU onto Bandai where ../shared/data is present. A project carries user and automatic
constraints, the IK correction as keys with a hand edit, reader options and viewer state; it
must come back value by value, save to the same bytes, and give the same motion bit for bit.
A child process is killed in the middle of saves to show the previous file survives.
"""
from __future__ import annotations

import dataclasses
import json
import os
import random
import re
import select
import shutil
import signal
import subprocess
import sys
import time
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import REPO, clip_path, shared_path
from motion_composer.engine import read_bvh
from motion_composer.engine.formats.bvh import format_bvh
from motion_composer.engine.correction.constraints import Constraint
from motion_composer.engine.conversion.correspondence import Correspondence
from motion_composer.engine.correction.displacement import Curve, DisplacementMap, Layer
from motion_composer.engine.errors import MotionComposerError
from motion_composer.engine.kinematics import forward_kinematics
from motion_composer.engine.scene import Scene, evaluate_project, solve_project
from motion_composer.engine.project import (MIGRATIONS, VERSION, MissingSourceError, Project, ProjectError,
                            Source, ViewerState, autosave_path, backup_path, check_project,
                            discard_autosave, embed_sources, find_autosave,
                            load_project, open_project, project_from_json, project_to_json,
                            read_sources, save_project, write_autosave)
from motion_composer.engine.conversion import BindOptions
from motion_composer.engine.conversion import RootOptions
from ik_fixtures import MAX_TO_BANDAI, MAX_TO_HOLDEN

WALK = clip_path("cmu_131_01_walk.bvh")
TPOSE = clip_path("cmu_rest_tpose.bvh")
V0_FIXTURE = REPO / "tests" / "data" / "project_v0.mcp"


def hand_constraint(frame=400) -> Constraint:
    return Constraint(joint="LeftHand", kind="position", goal={"point": [0.25, 0.15, 0.2]},
                      smooth_in=frame - 20, start=frame, end=frame + 20,
                      smooth_out=frame + 40, priority=1, weight=1.0, name="hand on the rail",
                      meta={"note": "from the storyboard"})


def with_hand_edits(project: Project) -> Project:
    """The animator's touch: one IK key moved (and made a step), one new smooth curve."""
    curves = dict(project.displacement.curves)
    key = next(k for k in curves if k[0] == "LeftForeArm")
    c = curves[key]
    values = c.values.copy()
    values[2] += 0.05
    interp = list(c.interpolation)
    interp[2] = "constant"
    curves[key] = Curve(c.frames, values, tuple(interp))
    curves[("Head", "ry")] = Curve([0.0, 200.0, 400.0], [0.0, 0.25, 0.0], ("smooth",) * 3)
    return project.replace(displacement=DisplacementMap(curves))


@lru_cache(maxsize=None)
def solved_walk() -> Project:
    """The walk on the T-pose character with automatic contacts, a hand constraint, reader
    overrides, solved, then hand-edited, with viewer state. Sources at the bundled clips."""
    project = Project(
        performer=Source(str(WALK), units="cmu", up_axis="+Y"),
        target=Source(str(TPOSE), position_mode="absolute"),
        correspondence=Correspondence(MAX_TO_HOLDEN, {"Hips": "by hand"}),
        bind_options=BindOptions(performer_reference="rest", target_reference="auto",
                                 rest_alignment=True, distribute="even"),
        root=RootOptions(mode="scaled", scale=(1.05, 0.98)),
        auto_contacts=True, floor=-0.93,
        constraints=(hand_constraint(),),
        viewer=ViewerState(current_frame=417, play_range=(100, 900),
                           camera={"target": [0.1, 0.9, -0.2], "distance": 3.75,
                                   "azimuth": -31.5, "elevation": 12.25},
                           shown=("performer", "intermediate", "target"),
                           options={"side_by_side": True, "grid": "1 m"}))
    project = solve_project(project, regenerate=True)
    return with_hand_edits(project)


def session_in(folder: Path, project: Project | None = None) -> Project:
    """``project`` (the solved walk) with its clips copied into ``folder/clips``."""
    project = project or solved_walk()
    clips = folder / "clips"
    clips.mkdir(parents=True, exist_ok=True)
    shutil.copy(WALK, clips / WALK.name)
    shutil.copy(TPOSE, clips / TPOSE.name)
    return project.replace(
        performer=dataclasses.replace(project.performer, path=str(clips / WALK.name)),
        target=dataclasses.replace(project.target, path=str(clips / TPOSE.name)))


def same_motion(a, b) -> bool:
    return (np.array_equal(a.rotations, b.rotations) and
            np.array_equal(a.translations, b.translations) and a.frame_time == b.frame_time
            and a.skeleton.names == b.skeleton.names)


def assert_same_project(a: Project, b: Project, *, paths: bool = True) -> None:
    for role in ("performer", "target"):
        sa, sb = getattr(a, role), getattr(b, role)
        if not paths:
            sb = dataclasses.replace(sb, path=sa.path)
        assert sa == sb, role
    assert list(a.correspondence.pairs.items()) == list(b.correspondence.pairs.items())
    assert a.correspondence.notes == b.correspondence.notes
    assert a.bind_options == b.bind_options
    assert a.root == b.root
    assert a.auto_contacts == b.auto_contacts and a.contact_options == b.contact_options
    assert a.floor == b.floor
    assert len(a.constraints) == len(b.constraints)
    for ca, cb in zip(a.constraints, b.constraints):
        assert ca.to_dict() == cb.to_dict()
        for k in ca.goal:
            assert np.array_equal(ca.goal[k], cb.goal[k])
    assert list(a.displacement.curves) == list(b.displacement.curves)
    for key, ca in a.displacement.curves.items():
        cb = b.displacement.curves[key]
        assert np.array_equal(ca.frames, cb.frames) and np.array_equal(ca.values, cb.values)
        assert ca.interpolation == cb.interpolation
    assert a.viewer == b.viewer


# --------------------------------------------------------------------------- round trip
def test_the_session_has_everything_the_issue_lists():
    p = solved_walk()
    auto = [c for c in p.constraints if c.auto]
    assert len(auto) >= 20 and any(c.name.startswith("floor ") for c in auto)
    assert any(c.name.startswith("contact ") for c in auto)
    assert [c.name for c in p.constraints if not c.auto] == ["hand on the rail"]
    assert len(p.displacement) > 20
    assert p.displacement.curves[("Head", "ry")].interpolation == ("smooth",) * 3


def test_round_trip_value_by_value(tmp_path):
    project = session_in(tmp_path)
    path = tmp_path / "walk.mcp"
    save_project(project, path)
    loaded = load_project(path)
    assert_same_project(project, loaded)
    assert loaded.performer.path == str(tmp_path / "clips" / WALK.name)
    data = json.loads(path.read_text())
    assert data["format"] == "motion-composer-project" and data["version"] == VERSION
    assert data["performer"]["path"] == "clips/cmu_131_01_walk.bvh"       # relative
    assert data["viewer"]["camera"]["distance"] == 3.75
    assert "embedded" not in data


def test_save_load_save_is_byte_identical(tmp_path):
    project = session_in(tmp_path)
    path = tmp_path / "walk.mcp"
    save_project(project, path)
    first = path.read_bytes()
    save_project(load_project(path), path)
    assert path.read_bytes() == first
    assert project_to_json(load_project(path), path).encode() == first
    # and the text is human-readable JSON: one key per line, numbers packed
    assert max(len(line) for line in first.decode().splitlines()) <= 100


@pytest.mark.parametrize("items", [
    [0.1 * k - 3e-7 * k * k for k in range(500)],                       # a curve's keys
    [True, None, "one, two", "x" * 120, "y" * 30, "z", "w" * 95, "v, " * 20],   # words
])
def test_lists_are_packed_greedily_into_lines(items):
    """A list that does not fit on its key's line is written one line per run of items, each
    line as full as 100 characters allow (a longer item alone on its line), in order."""
    from motion_composer.engine.project.json import _encode
    text = _encode({"list": items}, 0, "")
    assert json.loads(text)["list"] == items
    lines = text.splitlines()[2:-2]
    runs = [json.loads("[" + line.strip().rstrip(",") + "]") for line in lines]
    assert all(line.startswith("    ") for line in lines)
    assert all(len(line) <= 100 or len(run) == 1 for line, run in zip(lines, runs))
    for line, following in zip(lines, runs[1:]):
        assert len(line) + len(json.dumps(following[0])) + 2 > 100     # it would not fit


def test_the_retargeted_motion_is_identical_after_load(tmp_path):
    project = session_in(tmp_path)
    path = tmp_path / "walk.mcp"
    save_project(project, path)
    before = evaluate_project(project)
    after = evaluate_project(load_project(path))
    assert same_motion(before.composed, after.composed)
    assert same_motion(before.motion, after.motion)
    # the saved correction is applied: the motion is not the direct conversion, and the hand
    # edit shows on the head
    head = before.motion.skeleton.index["Head"]
    assert not np.array_equal(before.motion.rotations[:, head], before.composed.rotations[:, head])


def test_saved_correction_matches_the_solver(tmp_path):
    """The keys (0.01 degree, 0.05 mm) reproduce the IK result within a millimetre."""
    project = solve_project(session_in(tmp_path))            # hand edits replaced
    assert ("Head", "ry") not in project.displacement.curves
    performer, target = read_sources(project)
    keyed = evaluate_project(project, performer, target).motion
    dense = Scene.from_project(project, performer, target).solve().motion
    gap = forward_kinematics(keyed).positions - forward_kinematics(dense).positions
    assert np.abs(gap).max() < 1e-3
    # solving again gives the same keys: loading never needs IK, re-solving is repeatable
    again = solve_project(project, performer, target)
    assert project_to_json(again) == project_to_json(project)


def test_regenerate_replaces_only_automatic_constraints(tmp_path):
    project = session_in(tmp_path)
    edited = project.replace(constraints=tuple(
        c.with_range(c.smooth_in, c.start, c.end, c.smooth_out) if c.auto else c
        for c in project.constraints[:5]))
    again = solve_project(edited, regenerate=True)
    assert [c.name for c in again.constraints if not c.auto] == ["hand on the rail"]
    assert len([c for c in again.constraints if c.auto]) == \
        len([c for c in project.constraints if c.auto])
    # made before a solve (the window's timeline shows them while it runs): the constraints
    # the solve enforces, the user's kept as they are
    from motion_composer.engine.scene import Scene
    full = Scene.from_project(edited)
    made = full.regenerated().project.constraints
    assert len(made) == len(again.constraints)
    assert all(a.same_as(b) for a, b in zip(made, again.constraints))
    assert [c for c in made if not c.auto] == [c for c in edited.constraints if not c.auto]
    # nothing to find them in without both sources: the scene as it is
    alone = Scene(full.project, full.performer, None)
    assert alone.regenerated() is alone


# --------------------------------------------------------------------------- sources
def test_moving_the_project_folder_keeps_relative_sources(tmp_path):
    old = tmp_path / "session"
    project = session_in(old)
    save_project(project, old / "walk.mcp")
    motion = evaluate_project(load_project(old / "walk.mcp")).motion
    new = tmp_path / "elsewhere" / "moved"
    new.parent.mkdir()
    old.rename(new)
    loaded = load_project(new / "walk.mcp")
    assert loaded.performer.path == str(new / "clips" / WALK.name)
    assert same_motion(evaluate_project(loaded).motion, motion)


def test_a_moved_clip_names_the_missing_path(tmp_path):
    project = session_in(tmp_path)
    save_project(project, tmp_path / "walk.mcp")
    clip = tmp_path / "clips" / TPOSE.name
    clip.rename(tmp_path / "tpose_moved.bvh")
    with pytest.raises(MissingSourceError) as exc:
        load_project(tmp_path / "walk.mcp")
    err = exc.value
    assert isinstance(err, ProjectError) and isinstance(err, MotionComposerError)
    assert err.missing == str(clip) and err.role == "target"
    assert err.field == "target.path" and err.path == str(tmp_path / "walk.mcp")
    assert str(clip) in str(err)
    # the window points the project at the clip's new place and carries on
    fixed = load_project(tmp_path / "walk.mcp", check_sources=False)
    fixed = fixed.replace(target=dataclasses.replace(fixed.target,
                                                     path=str(tmp_path / "tpose_moved.bvh")))
    save_project(fixed, tmp_path / "walk.mcp")
    assert same_motion(evaluate_project(load_project(tmp_path / "walk.mcp")).motion,
                       evaluate_project(solved_walk()).motion)


def test_embedded_sources_travel_alone(tmp_path):
    project = embed_sources(session_in(tmp_path / "a"))
    assert project.performer.embedded.startswith("HIERARCHY")
    save_project(project, tmp_path / "a" / "walk.mcp")
    sent = tmp_path / "b" / "walk.mcp"
    sent.parent.mkdir()
    shutil.copy(tmp_path / "a" / "walk.mcp", sent)
    shutil.rmtree(tmp_path / "a")                      # the clips are gone
    loaded = load_project(sent)
    assert_same_project(project, loaded, paths=False)      # paths: where the clips came from
    assert loaded.performer.path == str(tmp_path / "b" / "clips" / WALK.name)
    assert same_motion(evaluate_project(loaded).motion, evaluate_project(solved_walk()).motion)
    first = sent.read_bytes()
    save_project(loaded, sent)
    assert sent.read_bytes() == first
    data = json.loads(first)
    assert list(data)[-1] == "embedded"                # the long text comes last


def test_reader_options_are_kept_and_used(tmp_path):
    project = session_in(tmp_path)
    save_project(project, tmp_path / "walk.mcp")
    data = json.loads((tmp_path / "walk.mcp").read_text())
    assert data["performer"]["units"] == "cmu" and data["target"]["position_mode"] == "absolute"
    data["performer"]["units"] = "cm"                  # a different reading gives another motion
    other = project_from_json(json.dumps(data), tmp_path / "walk.mcp")
    a, _ = read_sources(project)
    b, _ = read_sources(other)
    assert np.allclose(b.translations, a.translations * 0.01 / (0.0254 / 0.45))


# --------------------------------------------------------------------------- versions
def test_a_version_0_project_migrates_forward(tmp_path):
    assert 0 in MIGRATIONS
    project = load_project(V0_FIXTURE)
    assert project.correspondence.pairs == MAX_TO_HOLDEN
    assert list(project.correspondence.pairs) == list(MAX_TO_HOLDEN)
    assert project.performer.path == str(WALK)
    assert [c.name for c in project.constraints] == ["hand on the rail"]
    assert project.viewer == ViewerState() and project.auto_contacts is False
    assert project.displacement.curves[("Head", "ry")].interpolation == ("smooth",) * 3
    motion = evaluate_project(project).motion
    assert motion.num_frames == 994
    # saved again, it is a current file that loads to the same motion
    save_project(project, tmp_path / "now.mcp")
    data = json.loads((tmp_path / "now.mcp").read_text())
    assert data["version"] == VERSION and "mapping" not in data
    assert same_motion(evaluate_project(load_project(tmp_path / "now.mcp")).motion, motion)


@pytest.mark.parametrize("floor", [0.0, None], ids=["a floor", "no floor"])
def test_a_version_3_floor_stays_the_feet_plane_only(tmp_path, floor):
    """Format 3 read ``"floor"`` as the feet's floor plane only; format 4 also stands the
    conversion on it (``stand_on_floor``). A version-3 file with a floor keeps its reading:
    its conversion is the one without a floor (the walk onto the T-pose, whose hips are at
    0, is not raised 0.92 m onto the floor at 0), so it evaluates as it did. A new project
    with that floor stands on it; a file whose ``stand_on_floor`` is not true or false is
    refused by name."""
    assert 3 in MIGRATIONS
    project = session_in(tmp_path, Project(performer=Source(str(WALK)),
                                           target=Source(str(TPOSE)),
                                           correspondence=Correspondence(MAX_TO_HOLDEN),
                                           floor=floor))
    data = json.loads(project_to_json(project))
    assert data["stand_on_floor"] is True
    old = {k: v for k, v in data.items() if k != "stand_on_floor"}
    old["version"] = 3
    path = tmp_path / "v3.mcp"
    path.write_text(json.dumps(old))
    loaded = load_project(path)
    assert loaded.floor == floor and loaded.stand_on_floor is (floor is None)
    free = evaluate_project(project.replace(floor=None)).motion
    assert same_motion(evaluate_project(loaded).motion, free)
    if floor is not None:
        lifted = evaluate_project(project).motion
        rise = lifted.translations[:, 0, 1] - free.translations[:, 0, 1]
        assert rise.min() == pytest.approx(rise.max()) and rise.min() > 0.9
    data["stand_on_floor"] = "yes"
    path.write_text(json.dumps(data))
    with pytest.raises(ProjectError) as exc:
        load_project(path)
    assert exc.value.field == "stand_on_floor"
    with pytest.raises(MotionComposerError, match="stand_on_floor: expected true or false"):
        project.replace(stand_on_floor=1)


def test_a_broken_version_0_file_names_the_field(tmp_path):
    data = json.loads(V0_FIXTURE.read_text())
    data["mapping"][3] = ["LeftLeg"]
    path = tmp_path / "old.mcp"
    path.write_text(json.dumps(data))
    with pytest.raises(ProjectError) as exc:
        load_project(path, check_sources=False)
    assert exc.value.field == "mapping[3]"


def test_a_newer_version_is_refused_clearly(tmp_path):
    project = session_in(tmp_path)
    data = json.loads(project_to_json(project))
    data["version"] = VERSION + 1
    data["something_new"] = {"we": "cannot know"}
    path = tmp_path / "future.mcp"
    path.write_text(json.dumps(data))
    with pytest.raises(ProjectError) as exc:
        load_project(path)
    assert exc.value.field == "version"
    assert (f"was written by a newer Motion Composer (format version {VERSION + 1}; this one "
            f"reads up to {VERSION})") in str(exc.value)


def test_not_a_project(tmp_path):
    path = tmp_path / "map.mcp"
    path.write_text(json.dumps({"format": "motion-composer-mapping", "version": 1,
                                "pairs": {}}))
    with pytest.raises(ProjectError, match="not a Motion Composer project") as exc:
        load_project(path)
    assert exc.value.field == "format"
    for content, words in ((b"", "empty"), (b"\xff\xfe\x00garbage", "UTF-8"),
                           (b"[1, 2]", "expected a JSON object")):
        path.write_bytes(content)
        with pytest.raises(ProjectError, match=words):
            load_project(path)
    with pytest.raises(ProjectError, match="no such project file"):
        load_project(tmp_path / "nope.mcp")


@pytest.mark.parametrize("clip, words", [
    (lambda: clip_path("cmu_131_01_walk.bvh"), "a BVH file (a motion clip)"),
    (lambda: shared_path("target_mixamo_ely.glb"), "a GLB file (a character)"),
    (lambda: shared_path("fbx/Samba_Dancing.fbx"), "an FBX file (a character or its takes)")],
    ids=["bvh", "glb", "fbx"])
def test_a_clip_or_a_character_opened_as_a_project_is_named(clip, words, tmp_path, capsys):
    """Not "byte 8 is not UTF-8 text": what the file is, and what to do with it; the window's
    command line says it in one line and exits 2."""
    with pytest.raises(ProjectError, match=rf"this is {re.escape(words)}, not a project: "
                       "import it as the performer or the target"):
        load_project(clip())
    from motion_composer.app.cli import main
    assert main(["export", str(clip()), "-o", str(tmp_path / "out.bvh")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a project" in err, err
    assert not (tmp_path / "out.bvh").exists()


# --------------------------------------------------------------------------- bad input
@pytest.fixture()
def saved(tmp_path):
    project = session_in(tmp_path)
    path = tmp_path / "walk.mcp"
    save_project(project, path)
    return path


@pytest.mark.parametrize("share", [0.5, 0.33, 0.9])
def test_a_truncated_file(saved, share):
    text = saved.read_text()
    saved.write_text(text[:int(len(text) * share)])
    with pytest.raises(ProjectError) as exc:
        load_project(saved)
    assert exc.value.path == str(saved) and "truncated" in str(exc.value)
    assert "line" in str(exc.value)


def test_a_file_cut_anywhere_says_truncated(saved):
    """Cut inside a number, a key, a string or between values: always named truncated."""
    text = saved.read_text()
    rng = random.Random(7)
    for cut in sorted(rng.sample(range(1, len(text) - 2), 60)):
        saved.write_text(text[:cut])
        with pytest.raises(ProjectError, match="truncated"):
            load_project(saved)


def test_broken_json(saved):
    text = saved.read_text()
    saved.write_text(text.replace(f'"version": {VERSION},', f'"version": {VERSION}', 1))
    with pytest.raises(ProjectError, match=r"not valid JSON at line 4, column 3"):
        load_project(saved)
    saved.write_text(text.replace('"floor": -0.93', '"floor": NaN', 1))
    with pytest.raises(ProjectError, match="NaN"):
        load_project(saved)
    saved.write_text(text.replace('"floor": -0.93', '"floor": 1e999', 1))
    with pytest.raises(ProjectError, match="too large"):
        load_project(saved)
    saved.write_text(text.replace('"floor": -0.93', '"floor": -0.93, "floor": 0', 1))
    with pytest.raises(ProjectError, match="appears twice"):
        load_project(saved)


def _set(path, value):
    def edit(data):
        node = data
        for key in path[:-1]:
            node = node[key]
        if value is _DELETE:
            del node[path[-1]]
        else:
            node[path[-1]] = value
    return edit


_DELETE = object()

BAD_FIELDS = [
    (_set(["constraints", 1, "range"], "abc"), "constraints[1].range", "list"),
    (_set(["constraints", 1, "range"], [5, 4, 3, 2]), "constraints[1].range", "smooth_in <="),
    (_set(["constraints", 0, "range", 2], 1.5), "constraints[0].range[2]", "whole number"),
    (_set(["constraints", 0, "weight"], "heavy"), "constraints[0].weight", "number"),
    (_set(["constraints", 0, "priority"], 0), "constraints[0].priority", "from 1"),
    (_set(["constraints", 0, "kind"], "glue"), "constraints[0].kind", "position"),
    (_set(["constraints", 0, "goal"], {"point": [1, 2]}), "constraints[0].goal", "3 finite"),
    (_set(["constraints", 0, "colour"], "red"), "constraints[0].colour", "unknown field"),
    (_set(["constraints", 0, "joint"], _DELETE), "constraints[0].joint", "missing"),
    (_set(["binding", "rest_alignment"], "yes"), "binding.rest_alignment", "true or false"),
    (_set(["binding", "performer_reference"], -3), "binding.performer_reference", "frame"),
    (_set(["binding", "distribute"], "odd"), "binding.distribute", "even, first"),
    (_set(["root", "scale"], [1.0]), "root.scale", "horizontal, vertical"),
    (_set(["root", "mode"], 7), "root.mode", "scaled"),
    (_set(["contacts", "options", "height"], -1), "contacts.options.height", "positive"),
    (_set(["contacts", "auto"], 1), "contacts.auto", "true or false"),
    (_set(["floor"], "low"), "floor", "number"),
    (_set(["viewer", "current_frame"], -1), "viewer.current_frame", "from 0"),
    (_set(["viewer", "play_range"], [9, 3]), "viewer.play_range", "after"),
    (_set(["viewer", "camera", "distance"], "far"), "viewer.camera.distance", "number"),
    (_set(["viewer", "shown"], ["everything"]), "viewer.shown[0]", "intermediate"),
    (_set(["viewer", "options", "grid"], [1]), "viewer.options.grid", "string, number"),
    (_set(["layers", 0, "channels", 0, "values"], "x"), "layers[0].channels[0].values",
     "list"),
    (_set(["layers", 0, "channels", 0, "frames", 1], -5.0),
     "layers[0].channels[0].frames", "increase"),
    (_set(["layers", 0, "channels", 0, "channel"], "tx"),
     "layers[0].channels[0].channel", "rx, ry, rz"),
    (_set(["layers", 0, "channels", 0, "interpolation"], "cubic"),
     "layers[0].channels[0].interpolation", "linear"),
    (_set(["correspondence", "pairs", "Hips"], 3), "correspondence.pairs.Hips", "string"),
    (_set(["correspondence"], _DELETE), "correspondence", "missing"),
    (_set(["performer", "units"], "furlongs"), "performer.units", "cmu"),
    (_set(["performer", "scale"], 0), "performer.scale", "positive"),
    (_set(["target", "up_axis"], "up"), "target.up_axis", "+Y"),
    (_set(["performer", "path"], _DELETE), "performer", "path"),
    (_set(["extra"], 1), "extra", "unknown field"),
    (_set(["version"], "1"), "version", "whole number"),
]


@pytest.mark.parametrize("edit, field, words", BAD_FIELDS,
                         ids=[f for _, f, _ in BAD_FIELDS])
def test_wrong_types_name_the_field(saved, edit, field, words):
    data = json.loads(saved.read_text())
    edit(data)
    saved.write_text(json.dumps(data, indent=1))
    with pytest.raises(ProjectError) as exc:
        load_project(saved)
    assert exc.value.field == field, str(exc.value)
    assert words in exc.value.problem
    assert str(exc.value).startswith(f"{saved}: {field}: ")


BAD_JOINTS = [
    (_set(["correspondence", "pairs", "Tail"], "LeftToe_end"), 'correspondence.pairs.Tail',
     "not a joint of the target"),
    (_set(["correspondence", "pairs", "Head"], "Halo"), "correspondence.pairs.Head",
     "not a joint of the performer"),
    (_set(["correspondence", "pairs", "Head"], "LeftWrist"), "correspondence", "both mapped"),
    (_set(["constraints", 2, "joint"], "Tail"), "constraints[2].joint", "not a joint"),
    (_set(["constraints", 0, "range"], [0, 0, 5, 5000]), "constraints[0].range",
     "past the last frame"),
    (_set(["layers", 0, "channels", 3, "joint"], "Tail"),
     "layers[0].channels[3].joint", "not a joint"),
    (_set(["viewer", "current_frame"], 994), "viewer.current_frame", "past the last frame"),
    (_set(["binding", "target_reference"], 1), "binding.target_reference", "past the clip"),
    (_set(["target", "position_mode"], {"Nope": "absolute"}), "target.position_mode",
     "position mode"),
]


@pytest.mark.parametrize("edit, field, words", BAD_JOINTS, ids=[f for _, f, _ in BAD_JOINTS])
def test_unknown_joints_and_frames_name_the_field(saved, edit, field, words):
    data = json.loads(saved.read_text())
    edit(data)
    saved.write_text(json.dumps(data, indent=1))
    project_from_json(saved.read_text(), saved)      # well-formed: only the clips tell
    with pytest.raises(ProjectError) as exc:
        load_project(saved)
    assert exc.value.field == field, str(exc.value)
    assert words in exc.value.problem


def test_a_broken_embedded_clip(tmp_path):
    project = embed_sources(session_in(tmp_path))
    broken = project.replace(target=dataclasses.replace(
        project.target, embedded=project.target.embedded.replace("OFFSET", "OFFSTE", 3)))
    save_project(broken, tmp_path / "walk.mcp")
    with pytest.raises(ProjectError) as exc:
        load_project(tmp_path / "walk.mcp")
    assert exc.value.field == "embedded.target" and "line" in exc.value.problem


def test_unsavable_values_are_refused_before_writing(tmp_path):
    path = tmp_path / "walk.mcp"
    project = session_in(tmp_path)
    save_project(project, path)
    before = path.read_bytes()
    bad = project.replace(viewer=dataclasses.replace(project.viewer,
                                                     camera={"distance": float("nan")}))
    with pytest.raises(ProjectError) as exc:
        save_project(bad, path)
    assert exc.value.field == "viewer.camera.distance"
    assert path.read_bytes() == before


# --------------------------------------------------------------------------- fuzz
@lru_cache(maxsize=None)
def small_project_json() -> str:
    """A small, complete project (30 frames, embedded clips) for mutation."""
    walk = read_bvh(WALK)
    short = format_bvh(walk.frames(slice(380, 410)))
    project = Project(
        performer=Source(None, embedded=short), target=Source(None, embedded=TPOSE.read_text()),
        correspondence=Correspondence(MAX_TO_HOLDEN), auto_contacts=True, floor=-0.9,
        constraints=(hand_constraint(20).with_range(0, 5, 10, 20),
                     Constraint(joint="LeftToeBase", kind="plane",
                                goal={"point": [0, -0.9, 0], "normal": [0, 1, 0]},
                                smooth_in=0, start=0, end=29, smooth_out=29, auto=True)),
        displacement=DisplacementMap({("LeftForeArm", "rx"): Curve([0, 10, 29], [0, 0.1, 0]),
                                      ("<root>", "ty"): Curve([3], [0.01], ("constant",))}),
        viewer=ViewerState(5, (0, 29), {"distance": 2.0, "target": [0, 1, 0]}))
    return project_to_json(project)


def _paths(node, prefix=()):
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            if k != "embedded" or not prefix:
                yield from _paths(v, prefix + (k,))
    elif isinstance(node, list) and len(node) < 40:
        for i, v in enumerate(node):
            yield from _paths(v, prefix + (i,))


_JSON = st.recursive(
    st.none() | st.booleans() | st.integers(-10**6, 10**6) |
    st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=8) |
    st.sampled_from(["auto", "rest", "LeftHand", "Hips", "<root>", "rx", "tx", "smooth",
                     "position", "plane", "above", "absolute", "cmu", "+Z", "performer"]),
    lambda children: st.lists(children, max_size=4) |
    st.dictionaries(st.sampled_from(["point", "normal", "side", "keys", "points", "frames",
                                     "values", "path", "a"]), children, max_size=3),
    max_leaves=8)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_any_mutation_loads_or_raises_a_project_error(data):
    text = small_project_json()
    tree = json.loads(text)
    how = data.draw(st.sampled_from(["replace", "delete", "truncate", "byte"]))
    if how in ("replace", "delete"):
        paths = [p for p in _paths(tree) if p]
        path = data.draw(st.sampled_from(paths))
        node = tree
        for key in path[:-1]:
            node = node[key]
        if how == "delete":
            del node[path[-1]]
        else:
            node[path[-1]] = data.draw(_JSON)
        text = json.dumps(tree)
    elif how == "truncate":
        text = text[:data.draw(st.integers(0, len(text) - 1))]
    else:
        i = data.draw(st.integers(0, len(text) - 1))
        text = text[:i] + data.draw(st.characters()) + text[i + 1:]
    try:
        project = project_from_json(text, "fuzz.mcp")
        performer, target = read_sources(project, path="fuzz.mcp")
        check_project(project, performer, target, path="fuzz.mcp")
    except ProjectError:
        return
    # what loads evaluates, and saves to text that loads back to the same bytes
    evaluate_project(project, performer, target)
    again = project_to_json(project)
    assert project_to_json(project_from_json(again)) == again


# --------------------------------------------------------------------------- atomic saves
def test_one_backup_of_the_previous_version(tmp_path):
    path = tmp_path / "walk.mcp"
    project = session_in(tmp_path)
    save_project(project, path)
    assert not backup_path(path).exists()
    v1 = path.read_bytes()
    step = project.replace(viewer=dataclasses.replace(project.viewer, current_frame=1))
    save_project(step, path)
    v2 = path.read_bytes()
    assert backup_path(path).read_bytes() == v1 and backup_path(path).name == "walk.mcp.bak"
    save_project(step, path)                       # nothing changed: the backup stays v1
    assert backup_path(path).read_bytes() == v1
    save_project(project.replace(floor=None), path)
    assert backup_path(path).read_bytes() == v2
    assert load_project(backup_path(path)).viewer.current_frame == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clips", "walk.mcp", "walk.mcp.bak"]


_CHILD = r"""
import dataclasses, os, sys, time
from motion_composer.engine import project as P
path, mode, original = sys.argv[1], sys.argv[2], sys.argv[3]
a = P.load_project(original, check_sources=False)
b = a.replace(viewer=dataclasses.replace(a.viewer, current_frame=a.viewer.current_frame + 1))
if mode.startswith("pause"):
    pause_at = int(mode[5:])           # stop inside the n-th fsync of the save
    real, calls = os.fsync, [0]
    def fsync(fd):
        real(fd)
        calls[0] += 1
        if calls[0] == pause_at:
            print("paused", flush=True)
            time.sleep(120)
    os.fsync = fsync
    P.save_project(b, path)
    print("finished", flush=True)
else:
    # writes go out in 64 KiB pieces with a pause between them, so that a kill at a random
    # moment often lands inside a write
    real_fdopen = os.fdopen
    class Slow:
        def __init__(self, handle):
            self.handle = handle
        def __enter__(self):
            return self
        def __exit__(self, *exc):
            return self.handle.__exit__(*exc)
        def write(self, data):
            for i in range(0, len(data), 1 << 16):
                self.handle.write(data[i:i + (1 << 16)])
                self.handle.flush()
                time.sleep(0.004)
        def __getattr__(self, name):
            return getattr(self.handle, name)
    os.fdopen = lambda *args, **kwargs: Slow(real_fdopen(*args, **kwargs))
    print("saving", flush=True)
    while True:
        P.save_project(b, path)
        P.save_project(a, path)
"""


def _wait_line(proc, timeout=60.0) -> str:
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    assert ready, "the child did not answer"
    return proc.stdout.readline().strip()


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs POSIX signals")
def test_killing_a_save_leaves_the_previous_file_intact(tmp_path):
    path = tmp_path / "walk.mcp"
    project = embed_sources(session_in(tmp_path))
    # an animator layer keyed on every frame of every joint's rx: with the solved layer's
    # sparse keys, about 1.5 MB to write (long enough for a kill to land in the save)
    sk = read_bvh(TPOSE).skeleton
    frames = np.arange(read_bvh(WALK).num_frames, dtype=float)
    busy = DisplacementMap({(name, "rx"): Curve(frames, 0.01 * np.sin(frames / 7 + j))
                            for j, name in enumerate(sk.names)})
    project = project.replace(layers=(Layer("busy", busy),))
    save_project(project, path)
    text_a = path.read_bytes()
    original = tmp_path / "original.mcp"             # what the child loads: A, every time
    original.write_bytes(text_a)
    b = project.replace(viewer=dataclasses.replace(project.viewer,
                                                   current_frame=project.viewer.current_frame + 1))
    text_b = project_to_json(b, path).encode()
    assert len(text_a) > 1_000_000

    def run(mode):
        return subprocess.Popen([sys.executable, "-c", _CHILD, str(path), mode, str(original)],
                                cwd=REPO,
                                stdout=subprocess.PIPE, text=True)

    def leftovers():
        return [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")]

    # killed while writing the backup, then while the new file waits to be renamed
    for fsync_call, backup_after in ((1, None), (2, text_a)):
        proc = run(f"pause{fsync_call}")
        try:
            assert _wait_line(proc) == "paused"
            assert leftovers(), "the kill must land in the middle of a save"
        finally:
            proc.kill()
            proc.wait()
        assert path.read_bytes() == text_a
        if backup_after is not None:
            assert backup_path(path).read_bytes() == backup_after
        for p in tmp_path.glob(".*.tmp"):
            p.unlink()

    # killed at random moments of back-to-back saves
    rng = random.Random(5)
    mid_save = 0
    for _ in range(6):
        proc = run("loop")
        try:
            assert _wait_line(proc) == "saving"
            time.sleep(rng.uniform(0.0, 0.5))
        finally:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
        content = path.read_bytes()
        assert content in (text_a, text_b)
        mid_save += bool(leftovers())
        for p in tmp_path.glob(".*.tmp"):
            p.unlink()
        if backup_path(path).exists():
            assert backup_path(path).read_bytes() in (text_a, text_b)
        assert load_project(path, check_sources=False).viewer.current_frame in (417, 418)
    print(f"{mid_save} of 6 random kills landed while a temporary file was open")
    assert_same_project(load_project(path), project if path.read_bytes() == text_a else b)
    names = {p.name for p in tmp_path.iterdir()}
    expected = {"walk.mcp", "walk.mcp.bak", "clips", "original.mcp"}
    assert expected <= names
    assert all(n.endswith(".tmp") for n in names - expected)


# --------------------------------------------------------------------------- autosave
def test_autosave_next_to_the_project_found_only_when_newer(tmp_path):
    path = tmp_path / "walk.mcp"
    project = session_in(tmp_path)
    save_project(project, path)
    assert autosave_path(path) == tmp_path / ".walk.mcp.autosave"
    assert find_autosave(path) is None
    edited = project.replace(viewer=dataclasses.replace(project.viewer, current_frame=3))
    auto = write_autosave(edited, path)
    assert auto == autosave_path(path)
    now = time.time()
    os.utime(path, (now - 60, now - 60))
    os.utime(auto, (now, now))
    assert find_autosave(path) == auto
    recovered = load_project(find_autosave(path))
    assert recovered.viewer.current_frame == 3
    assert same_motion(evaluate_project(recovered).motion, evaluate_project(project).motion)
    os.utime(path, (now + 60, now + 60))          # saved after the autosave: nothing to offer
    assert find_autosave(path) is None
    discard_autosave(path)
    assert not auto.exists()
    discard_autosave(path)                         # twice is fine
    path.unlink()                                  # the project is gone, the autosave is not
    write_autosave(edited, path)
    assert find_autosave(path) == auto


def test_autosave_of_an_unsaved_project(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    assert find_autosave(None) is None
    project = session_in(tmp_path)
    auto = write_autosave(project, None)
    assert auto.parent == tmp_path / "state" / "motion-composer"
    assert find_autosave(None) == auto
    assert_same_project(load_project(auto), project)
    discard_autosave(None)
    assert find_autosave(None) is None
    monkeypatch.delenv("XDG_STATE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert autosave_path(None) == tmp_path / "home" / ".local" / "state" / "motion-composer" / \
        "untitled.autosave"


# --------------------------------------------------------------------------- shared clips
@pytest.mark.shared_data
def test_round_trip_on_shared_clips(tmp_path):
    """CMU (3dsMax export) onto Bandai, automatic contacts: the same bytes and motion."""
    project = Project(performer=Source(str(shared_path("cmu_max_131_01_walk.bvh"))),
                      target=Source(str(shared_path("bandai1_walk_normal_001.bvh"))),
                      correspondence=Correspondence(MAX_TO_BANDAI), auto_contacts=True,
                      viewer=ViewerState(current_frame=10))
    project = solve_project(project, regenerate=True)
    assert any(c.auto for c in project.constraints) and len(project.displacement)
    for variant, name in ((project, "relative.mcp"), (embed_sources(project), "embedded.mcp")):
        path = tmp_path / name
        save_project(variant, path)
        first = path.read_bytes()
        loaded, performer, target = open_project(path)
        assert_same_project(variant, loaded)
        save_project(loaded, path)
        assert path.read_bytes() == first
        assert same_motion(evaluate_project(loaded, performer, target).motion,
                           evaluate_project(project).motion)


def test_viewer_state_with_options_and_shown_figures():
    viewer = ViewerState(current_frame=3, options={"side_by_side": True, "ghosts": False})
    changed = viewer.with_(options={"follow_root": True}, show_performer=False,
                           current_frame=9)
    assert changed.options == {"follow_root": True}
    assert "performer" not in changed.shown and changed.current_frame == 9
    assert viewer.with_(side_by_side=False).options == {"side_by_side": False, "ghosts": False}
    assert viewer.options == {"side_by_side": True, "ghosts": False}      # unchanged
