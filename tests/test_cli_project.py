"""`retarget --save-project` and `export`: a session saved from the command line and re-run
headless, on the bundled CMU walk and T-pose character; a corrupt project gives one line on
stderr and exit code 2."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from motion_composer.app.cli import main
from conftest import REPO, clip_path
from motion_composer.engine import forward_kinematics, read_bvh
from motion_composer.engine.formats.bvh import format_bvh
from motion_composer.engine.project import (VERSION, MissingSourceError, ProjectError, load_project,
                            open_project)
from motion_composer.engine.scene import evaluate_project
from ik_fixtures import MAX_TO_HOLDEN

WALK = clip_path("cmu_131_01_walk.bvh")
TPOSE = clip_path("cmu_rest_tpose.bvh")


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """One `retarget` run with a map, a hand constraint and automatic contacts, saving a
    project; the clips are copies in the session's folder."""
    folder = tmp_path_factory.mktemp("session")
    shutil.copy(WALK, folder / WALK.name)
    shutil.copy(TPOSE, folder / TPOSE.name)
    (folder / "map.json").write_text(json.dumps({"pairs": MAX_TO_HOLDEN}))
    (folder / "hand.json").write_text(json.dumps({"constraints": [
        {"joint": "LeftHand", "kind": "position", "goal": {"point": [0.25, 0.15, 0.2]},
         "range": [380, 400, 420, 440], "name": "hand on the rail"}]}))
    code = main(["retarget", str(folder / WALK.name), "--target", str(folder / TPOSE.name),
                 "-o", str(folder / "direct.bvh"), "--map", str(folder / "map.json"),
                 "--constraints", str(folder / "hand.json"), "--auto-contacts",
                 "--root", "in-place", "--save-project", str(folder / "walk.mcp")])
    assert code == 0
    return folder


def test_retarget_saves_the_whole_session(session):
    project = load_project(session / "walk.mcp")
    assert project.correspondence.pairs == MAX_TO_HOLDEN
    assert project.root.mode == "in-place" and project.auto_contacts is True
    assert [c.name for c in project.constraints if not c.auto] == ["hand on the rail"]
    assert sum(c.auto for c in project.constraints) >= 10
    assert len(project.displacement) > 10
    data = json.loads((session / "walk.mcp").read_text())
    assert data["performer"]["path"] == WALK.name and data["target"]["path"] == TPOSE.name
    assert "embedded" not in data


def test_export_writes_the_project_motion(session, capsys, tmp_path):
    out = tmp_path / "exported.bvh"
    code, text, err = _run(capsys, "export", session / "walk.mcp", "-o", out)
    assert code == 0, err
    assert "994 frames" in text and "constraints" in text
    # exactly the project's motion, written as the writer writes it
    project, performer, target = open_project(session / "walk.mcp")
    assert out.read_text() == format_bvh(evaluate_project(project, performer, target).motion)
    # and within the keys' tolerance of what retarget wrote (the dense IK result)
    exported = forward_kinematics(read_bvh(out)).positions
    direct = forward_kinematics(read_bvh(session / "direct.bvh")).positions
    assert np.abs(exported - direct).max() < 2e-3
    # the target's file conventions are kept
    assert read_bvh(out).skeleton.names == read_bvh(TPOSE).skeleton.names


def test_export_solve_runs_ik_again(session, capsys, tmp_path):
    # unchanged, the project solves to the keys it holds
    code, _, err = _run(capsys, "export", session / "walk.mcp", "-o", tmp_path / "a.bvh")
    assert code == 0, err
    code, _, err = _run(capsys, "export", session / "walk.mcp", "-o", tmp_path / "b.bvh",
                        "--solve")
    assert code == 0, err
    assert (tmp_path / "a.bvh").read_text() == (tmp_path / "b.bvh").read_text()
    # a goal edited by hand in the file: only --solve moves the hand there
    data = json.loads((session / "walk.mcp").read_text())
    hand = next(c for c in data["constraints"] if c.get("name") == "hand on the rail")
    hand["goal"]["point"] = [0.3, 0.3, 0.1]
    edited = tmp_path / "edited.mcp"
    edited.write_text(json.dumps(data))
    shutil.copy(session / WALK.name, tmp_path / WALK.name)
    shutil.copy(session / TPOSE.name, tmp_path / TPOSE.name)
    for flag, out in (([], "stale.bvh"), (["--solve"], "solved.bvh")):
        code, _, err = _run(capsys, "export", edited, "-o", tmp_path / out, *flag)
        assert code == 0, err
    j = read_bvh(TPOSE).skeleton.index["LeftHand"]
    solved = forward_kinematics(read_bvh(tmp_path / "solved.bvh")).positions[400:421, j]
    stale = forward_kinematics(read_bvh(tmp_path / "stale.bvh")).positions[400:421, j]
    assert np.linalg.norm(solved - [0.3, 0.3, 0.1], axis=1).max() < 2e-3
    assert np.linalg.norm(stale - [0.3, 0.3, 0.1], axis=1).min() > 0.05


def test_embed_sources_makes_a_project_that_travels(session, capsys, tmp_path):
    away = tmp_path / "away"
    away.mkdir()
    code, _, err = _run(capsys, "retarget", session / WALK.name, "--target",
                        session / TPOSE.name, "-o", tmp_path / "x.bvh", "--map",
                        session / "map.json", "--save-project", away / "sent.mcp",
                        "--embed-sources")
    assert code == 0, err
    moved = tmp_path / "elsewhere.mcp"
    (away / "sent.mcp").rename(moved)
    code, _, err = _run(capsys, "export", moved, "-o", tmp_path / "y.bvh")
    assert code == 0, err
    assert (tmp_path / "y.bvh").read_text() == (tmp_path / "x.bvh").read_text()  # no IK


def _one_line_exit_2(code, out, err, *words):
    assert code == 2
    assert out == ""
    assert err.count("\n") == 1 and err.endswith("\n") and err.startswith("motion-composer: ")
    assert "Traceback" not in err
    for w in words:
        assert w in err, err


def test_a_corrupt_project_gives_one_line_and_exit_2(session, capsys, tmp_path):
    text = (session / "walk.mcp").read_text()
    bad = tmp_path / "bad.mcp"
    bad.write_text(text[:len(text) // 3])
    _one_line_exit_2(*_run(capsys, "export", bad, "-o", tmp_path / "o.bvh"), str(bad),
                     "truncated")
    data = json.loads(text)
    data["constraints"][2]["range"] = [1, 2]
    bad.write_text(json.dumps(data))
    _one_line_exit_2(*_run(capsys, "export", bad, "-o", tmp_path / "o.bvh"),
                     "constraints[2].range")
    data = json.loads(text)
    data["version"] = 7
    bad.write_text(json.dumps(data))
    _one_line_exit_2(*_run(capsys, "export", bad, "-o", tmp_path / "o.bvh"),
                     f"newer Motion Composer (format version 7; this one reads up to {VERSION})")
    _one_line_exit_2(*_run(capsys, "export", tmp_path / "none.mcp", "-o", tmp_path / "o.bvh"),
                     "none.mcp", "no such project file")
    assert not (tmp_path / "o.bvh").exists()


def test_a_moved_clip_names_the_missing_path(session, capsys, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(session, copy)
    (copy / WALK.name).rename(copy / "renamed.bvh")
    with pytest.raises(MissingSourceError) as exc:
        load_project(copy / "walk.mcp")
    assert exc.value.missing == str(copy / WALK.name)
    _one_line_exit_2(*_run(capsys, "export", copy / "walk.mcp", "-o", tmp_path / "o.bvh"),
                     str(copy / WALK.name), "performer.path")


def test_save_project_into_a_missing_folder(session, capsys, tmp_path):
    code, out, err = _run(capsys, "retarget", session / WALK.name, "--target",
                          session / TPOSE.name, "-o", tmp_path / "x.bvh", "--map",
                          session / "map.json", "--save-project", tmp_path / "no" / "p.mcp")
    assert code == 2 and "does not exist" in err and err.count("\n") == 1


def test_export_in_a_real_process(session, tmp_path):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    bad = tmp_path / "broken.mcp"
    bad.write_text((session / "walk.mcp").read_text().replace('"pairs": {', '"pairs": [', 1))
    result = subprocess.run([sys.executable, "-m", "motion_composer.app.cli", "export", str(bad), "-o",
                             str(tmp_path / "o.bvh")], capture_output=True, text=True,
                            cwd=REPO, env=env, timeout=120)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    assert str(bad) in result.stderr and "not valid JSON" in result.stderr
    good = subprocess.run([sys.executable, "-m", "motion_composer.app.cli", "export", str(session / "walk.mcp"),
                           "-o", str(tmp_path / "o.bvh")], capture_output=True, text=True,
                          cwd=REPO, env=env, timeout=120)
    assert good.returncode == 0, good.stderr
    assert read_bvh(tmp_path / "o.bvh").num_frames == 994


def test_project_errors_are_motion_composer_errors():
    from motion_composer.engine.errors import MotionComposerError
    assert issubclass(ProjectError, MotionComposerError)
    assert issubclass(MissingSourceError, ProjectError)
