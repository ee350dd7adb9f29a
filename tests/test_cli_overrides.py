"""Per-side reader overrides on ``retarget``, ``batch`` and ``export`` (``--performer-units``
... ``--target-position-mode``), stored in the project; the one warning line of a doubtful
detection. The files are real clips written in another exporter's convention
(tests/detect_cases.py)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from motion_composer.app.cli import main
from conftest import clip_path, shared_path
from detect_cases import renamed, without_joint, world_positions, written_in
from motion_composer.engine.formats import read_motion
from motion_composer.engine.project import load_project

WALK = clip_path("cmu_131_01_walk.bvh")
TPOSE = clip_path("cmu_rest_tpose.bvh")


def cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture()
def ambiguous_walk(tmp_path):
    """The bundled CMU walk rescaled to a 0.95 m child in centimetres and numbered (a generic
    exporter's file): it reads as a 2.41 m person in inches unless told (one warning line)."""
    from motion_composer.engine.kinematics import fk_arrays
    motion = renamed(read_motion(WALK))
    points = fk_arrays(motion.skeleton, motion.rotations, motion.translations).all_positions()
    k = 0.95 / np.median(np.ptp(points[..., 1], axis=1))
    import dataclasses
    from motion_composer.engine.skeleton import EndSite
    sk = motion.skeleton
    small = motion.replace(translations=motion.translations * k, skeleton=dataclasses.replace(
        sk, offsets=sk.offsets * k,
        end_sites=[EndSite(s.parent, s.offset * k, s.name) for s in sk.end_sites]))
    path = tmp_path / "child_cm.bvh"
    path.write_text(written_in(small, "cm", "+Y"))
    return path


def test_a_command_that_fails_after_a_warning_prints_one_line_with_it(capsys, tmp_path,
                                                                      ambiguous_walk):
    """The performer's unit is in doubt and then the target cannot be read: exit 2 with the
    error's one line, and the warning (which flag settles the doubt) in it, not a line of its
    own before it (found by the CLI fuzz: a target of zero size, then no humanoid in it)."""
    code, out, err = cli(capsys, "retarget", ambiguous_walk, "--target",
                         tmp_path / "absent.bvh", "-o", tmp_path / "a.bvh")
    assert code == 2 and out == ""
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("motion-composer: error: "), err
    assert "absent.bvh" in lines[0]
    assert lines[0].endswith("give --performer-units cm]")
    assert "[warning: " in lines[0] and str(ambiguous_walk) in lines[0]
    assert not (tmp_path / "a.bvh").exists()


def test_retarget_warns_in_one_line_and_the_override_settles_it(capsys, tmp_path,
                                                                 ambiguous_walk):
    code, out, err = cli(capsys, "retarget", ambiguous_walk, "--target", TPOSE,
                         "-o", tmp_path / "a.bvh")
    assert code == 0
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("motion-composer: warning: ")
    assert lines[0].endswith("give --performer-units cm")
    code, out, err = cli(capsys, "retarget", ambiguous_walk, "--target", TPOSE,
                         "-o", tmp_path / "b.bvh", "--performer-units", "cm",
                         "--save-project", tmp_path / "p.mcp")
    assert code == 0 and err == ""
    project = load_project(tmp_path / "p.mcp")
    assert project.performer.units == "cm" and project.target.units is None


def test_retarget_target_overrides_are_used_and_stored(capsys, tmp_path):
    # the CMU T-pose target declared in metres and Z-up: a 24 m figure lying down
    code, _, err = cli(capsys, "retarget", WALK, "--target", TPOSE, "-o", tmp_path / "o.bvh",
                       "--target-scale", "0.05", "--target-up-axis", "+Y",
                       "--target-position-mode", "absolute", "--performer-up-axis", "+Y",
                       "--save-project", tmp_path / "p.mcp")
    assert code == 0, err
    project = load_project(tmp_path / "p.mcp")
    assert (project.target.scale, project.target.up_axis, project.target.position_mode) == \
        (0.05, "+Y", "absolute")
    assert project.performer.up_axis == "+Y" and project.performer.units is None
    out = read_motion(tmp_path / "o.bvh", scale=0.05)
    assert out.skeleton.source.scale == 0.05


def test_export_overrides_a_projects_reading_for_one_run(capsys, tmp_path, ambiguous_walk):
    # the root as captured (not scaled by the hip heights), so the performer's units show
    code, _, _ = cli(capsys, "retarget", ambiguous_walk, "--target", TPOSE, "--root",
                     "absolute", "-o", tmp_path / "a.bvh", "--save-project", tmp_path / "p.mcp")
    assert code == 0
    code, _, err = cli(capsys, "export", tmp_path / "p.mcp", "-o", tmp_path / "in.bvh")
    assert code == 0 and err.count("\n") == 1 and "--performer-units cm" in err
    code, _, err = cli(capsys, "export", tmp_path / "p.mcp", "-o", tmp_path / "cm.bvh",
                       "--performer-units", "cm")
    assert code == 0 and err == ""
    inches, cm = read_motion(tmp_path / "in.bvh"), read_motion(tmp_path / "cm.bvh")
    # the same target, driven by a performer 2.54 times smaller, travels 2.54 times less
    travel = [np.ptp(m.root_positions[:, [0, 2]], axis=0).max() for m in (inches, cm)]
    assert travel[0] / travel[1] == pytest.approx(2.54, rel=1e-3)
    assert load_project(tmp_path / "p.mcp").performer.units is None   # the file is unchanged


def test_a_gltf_target_refuses_reader_overrides_in_one_line(capsys, tmp_path):
    robot = shared_path("target_robot_expressive.glb")
    code, out, err = cli(capsys, "retarget", WALK, "--target", robot, "-o", tmp_path / "o.bvh",
                         "--target-units", "cm")
    assert code == 2 and err.count("\n") == 1 and "--target-units" in err
    assert "glTF is metres by definition" in err


def test_batch_takes_performer_overrides_for_every_clip(capsys, tmp_path, ambiguous_walk):
    code, _, _ = cli(capsys, "retarget", WALK, "--target", TPOSE, "-o", tmp_path / "a.bvh",
                     "--save-project", tmp_path / "p.mcp")
    assert code == 0
    code, _, err = cli(capsys, "batch", tmp_path / "p.mcp", ambiguous_walk, "--any-skeleton",
                       "-o", tmp_path / "warned", "--workers", "1",
                       "--summary", tmp_path / "s1.json")
    assert code == 0
    warnings = [line for line in err.splitlines() if "warning" in line]
    assert len(warnings) == 1 and warnings[0].endswith("give --performer-units cm")
    code, _, err = cli(capsys, "batch", tmp_path / "p.mcp", ambiguous_walk, "--any-skeleton",
                       "-o", tmp_path / "given", "--workers", "1", "--performer-units", "cm",
                       "--summary", tmp_path / "s2.json")
    assert code == 0 and "warning" not in err
    summary = json.loads((tmp_path / "s2.json").read_text())
    assert summary[0]["status"] == "written" and summary[0]["warnings"] == []


def test_info_keeps_its_flags_and_warns_with_them(capsys, ambiguous_walk):
    code, out, err = cli(capsys, "info", ambiguous_walk)
    assert code == 0 and err.count("\n") == 1 and err.rstrip().endswith("give --units cm")
    code, out, err = cli(capsys, "info", ambiguous_walk, "--units", "cm")
    assert code == 0 and err == "" and "units:       cm" in out


def test_a_video_to_bvh_file_needs_no_override(capsys, tmp_path):
    # the case: Rokoko Video's capture as a video-to-BVH tool writes it (Z-up
    # millimetres, no Head; it was read Y-up, every retarget 0.85 m under the floor): its
    # hips and legs retarget as the original's do (its arms and head map by structure, not
    # by name, which is automatic mapping's business)
    original = read_motion(shared_path("rokoko_mixamo_jesse_dance.bvh"))
    motion = renamed(without_joint(original, "Head"))
    clip = tmp_path / "video.bvh"
    clip.write_text(written_in(motion, "mm", "+Z"))
    code, _, err = cli(capsys, "retarget", clip, "--target", TPOSE, "-o", tmp_path / "v.bvh")
    assert code == 0 and err == ""
    code, _, err = cli(capsys, "retarget", shared_path("rokoko_mixamo_jesse_dance.bvh"),
                       "--target", TPOSE, "-o", tmp_path / "o.bvh")
    assert code == 0
    video, direct = (read_motion(tmp_path / n) for n in ("v.bvh", "o.bvh"))
    sk = direct.skeleton
    body = [j for j, n in enumerate(sk.names)
            if n == "Hips" or any(w in n for w in ("Leg", "Foot", "Toe"))]
    assert len(body) == 9
    error = np.abs(world_positions(video)[:, body] - world_positions(direct)[:, body]).max()
    assert error < 1e-4
