"""Finite or refused (issue 13, point 2).

A number that is not finite, or finite but so large that it overflows once scaled, squared or
turned into an angle (``1e308``), is refused with a typed error naming the file and line or the
field, wherever it enters: BVH OFFSET and motion values and Frame Time (the BVH cases are in
tests/bvh_cases.py, run by test_bvh_errors.py and test_cli.py), glTF node transforms and
accessors, project numbers, constraint goals and weights, scales, floors and IK settings. JSON
output is strict JSON, and no RuntimeWarning reaches stderr (the suite turns warnings into
errors, pyproject.toml; the CLI runs here in-process, so a warning fails the test).
"""
from __future__ import annotations

import json
import re
import os
import struct
import subprocess
import sys
import warnings

import numpy as np
import pytest

from motion_composer.app.cli import main
from conftest import REPO, SHARED_BVH, clip_path, shared_path
from motion_composer.engine.errors import GLTFError, MotionComposerError
from motion_composer.engine.formats import read_character
from motion_composer.engine.limits import MAX_MAGNITUDE, all_usable, problem
from motion_composer.engine.project import load_project
from motion_composer.engine.project.model import ProjectError

WALK = clip_path("cmu_131_01_walk.bvh")
TPOSE = clip_path("cmu_rest_tpose.bvh")
GLBS = ["target_fox.glb", "target_mixamo_ely.glb", "target_mixamo_mannequin.glb",
        "target_robot_expressive.glb"]


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line(code, out, err, *phrases):
    assert code == 2, err
    assert err.startswith("motion-composer: error: ") and err.count("\n") == 1, err
    for phrase in phrases:
        assert phrase in err, err


def strict_json(text: str):
    """``json.loads`` that refuses NaN and Infinity (Python's own accepts them)."""
    def refuse(name):
        raise AssertionError(f"{name} in JSON output")
    return json.loads(text, parse_constant=refuse)


# ------------------------------------------------------------------ the limits themselves
def test_limits():
    assert problem(1.0) is None and problem(-MAX_MAGNITUDE) is None
    assert "finite" in problem(float("nan")) and "finite" in problem(float("-inf"))
    assert "beyond the range" in problem(1e308)
    assert all_usable(np.zeros((0, 3))) and all_usable([[1.0, -1e9]])
    assert not all_usable([1.0, np.nan]) and not all_usable([1.0, 2e9])


# ------------------------------------------------------------------ BVH, end to end
def _mutated(tmp_path, source, name, old: bytes, new: bytes, *, line_starts: bytes):
    """``source`` with the first line starting with ``line_starts`` having ``old`` -> ``new``;
    the path and the 1-based line number."""
    lines = source.read_bytes().splitlines(keepends=True)
    i = next(k for k, line in enumerate(lines) if line.strip().startswith(line_starts))
    assert old in lines[i]
    lines[i] = lines[i].replace(old, new, 1)
    path = tmp_path / name
    path.write_bytes(b"".join(lines))
    return path, i + 1


def _subprocess(*argv):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run([sys.executable, "-m", "motion_composer.app.cli", *map(str, argv)],
                          capture_output=True, text=True, cwd=REPO, env=env, timeout=300)


def test_a_target_offset_of_1e308_is_refused_not_nan_on_every_frame(tmp_path):
    """The fuzzed target of the issue: exit 0 and NaN on every frame before; now one line
    naming the file and the line of the OFFSET, and no output written."""
    target, line = _mutated(tmp_path, TPOSE, "tpose.bvh", b"OFFSET 0.000000 0.000000 0.000000",
                            b"OFFSET 1e308 1e308 1e308", line_starts=b"OFFSET")
    run = _subprocess("retarget", WALK, "--target", target, "-o", tmp_path / "out.bvh")
    assert run.returncode == 2 and run.stderr.count("\n") == 1, run.stderr
    assert f"{target}:{line}: expected the X value of OFFSET, found '1e308'" in run.stderr
    assert not (tmp_path / "out.bvh").exists()


def test_performer_motion_of_1e308_is_refused_not_a_scipy_traceback(tmp_path):
    """A deep-learning exporter's unnormalised output: a rotation of 1e308 degrees."""
    lines = WALK.read_bytes().splitlines(keepends=True)
    first = next(k for k, line in enumerate(lines) if line.startswith(b"Frame Time")) + 1
    row = lines[first + 10].split()
    row[4] = b"1e308"
    lines[first + 10] = b" ".join(row) + b"\n"
    clip = tmp_path / "walk.bvh"
    clip.write_bytes(b"".join(lines))
    run = _subprocess("retarget", clip, "--target", TPOSE, "-o", tmp_path / "out.bvh")
    assert run.returncode == 2 and run.stderr.count("\n") == 1, run.stderr
    assert f"{clip}:{first + 11}: value 5 of frame 11 (Hips Yrotation)" in run.stderr
    assert "Traceback" not in run.stderr and not (tmp_path / "out.bvh").exists()


@pytest.mark.parametrize("frame_time", [b"1e308", b"10.5", b"-0.01", b"1e-320"])
def test_frame_time_outside_0_to_10_seconds(capsys, tmp_path, frame_time):
    """A Frame Time that is a frame rate or garbage; 1e-320 is positive but its inverse (the
    frame rate) overflows."""
    clip, line = _mutated(tmp_path, WALK, "walk.bvh", b".0083333", frame_time,
                          line_starts=b"Frame Time")
    one_line(*run(capsys, "info", clip, "--json"), f"{clip}:{line}:",
             "expected a positive number of seconds, at most 10")


def test_frame_time_of_10_seconds_is_accepted(capsys, tmp_path):
    clip, _ = _mutated(tmp_path, WALK, "walk.bvh", b".0083333", b"10", line_starts=b"Frame Time")
    code, out, err = run(capsys, "info", clip, "--json")
    assert (code, err) == (0, "")
    assert strict_json(out)["fps"] == 0.1


@pytest.mark.parametrize("scale", ["1e300", "1e-300", "inf", "nan", "0"])
def test_a_scale_that_overflows_or_collapses_is_refused(capsys, scale):
    one_line(*run(capsys, "info", WALK, "--scale", scale),
             "the scale must be a positive number of metres per unit, from 1e-06 to 1000")


# ------------------------------------------------------------------ glTF
def _glb_parts(path):
    data = path.read_bytes()
    length = struct.unpack_from("<I", data, 12)[0]
    js = json.loads(data[20:20 + length])
    binary = bytearray(data[20 + length + 8:])
    return js, binary


def _glb(js, binary) -> bytes:
    text = json.dumps(js).encode()
    text += b" " * (-len(text) % 4)
    binary = bytes(binary) + b"\0" * (-len(binary) % 4)
    body = (struct.pack("<II", len(text), 0x4E4F534A) + text +
            struct.pack("<II", len(binary), 0x004E4942) + binary)
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


def test_a_gltf_node_translation_of_1e308_is_refused(tmp_path, capsys):
    """A Mixamo-rigged GLB whose first node's translation was corrupted."""
    js, binary = _glb_parts(shared_path("target_mixamo_ely.glb"))
    js["nodes"][0]["translation"] = [1e308, 0.0, 0.0]
    path = tmp_path / "ely.glb"
    path.write_bytes(_glb(js, binary))
    with pytest.raises(GLTFError, match=r"nodes\[0\]\.translation: expected 3 finite numbers "
                                        r"of magnitude at most 1e\+09"):
        read_character(path)
    one_line(*run(capsys, "retarget", WALK, "--target", path, "-o", tmp_path / "out.glb"),
             "nodes[0].translation")
    assert not (tmp_path / "out.glb").exists()


def test_a_gltf_accessor_value_of_3e38_is_refused(tmp_path):
    """The largest float32 in an inverse bind matrix: finite in the file, it overflows once
    multiplied (the fox's skin, written by a converter that lost a scale)."""
    js, binary = _glb_parts(shared_path("target_fox.glb"))
    index = js["skins"][0]["inverseBindMatrices"]
    accessor = js["accessors"][index]
    view = js["bufferViews"][accessor["bufferView"]]
    at = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
    struct.pack_into("<f", binary, at + 4 * 12, 3e38)         # the first matrix's X translation
    path = tmp_path / "fox.glb"
    path.write_bytes(_glb(js, binary))
    with pytest.raises(GLTFError, match=rf"accessors\[{index}\]: element 0 is not a finite "
                                        r"number of magnitude at most 1e\+09"):
        read_character(path)


# ------------------------------------------------------------------ projects and settings
@pytest.fixture
def project(tmp_path, capsys):
    for clip in (WALK, TPOSE):
        (tmp_path / clip.name).write_bytes(clip.read_bytes())
    code, _, err = run(capsys, "retarget", tmp_path / WALK.name, "--target",
                       tmp_path / TPOSE.name, "-o", tmp_path / "made.bvh",
                       "--save-project", tmp_path / "p.mcp")
    assert code == 0, err
    return tmp_path / "p.mcp"


@pytest.mark.parametrize("old, new, field", [
    ('"floor": null', '"floor": 1e308', "floor"),
    ('"scale": null\n  },\n  "contacts"', '"scale": [1.0, 1e300]\n  },\n  "contacts"',
     "root.scale[1]"),
    ('"damping": 0.005', '"damping": 1e200', "ik.damping"),
    ('"tolerance": 0.0001', '"tolerance": -1e308', "ik.tolerance"),
    ('"current_frame": 0', '"current_frame": 1e308', "viewer.current_frame"),
])
def test_project_numbers_beyond_the_range_name_their_field(project, tmp_path, capsys, old, new,
                                                           field):
    text = project.read_text()
    assert old in text
    project.write_text(text.replace(old, new, 1))
    with pytest.raises(ProjectError, match=re.escape(f": {field}: ")):
        load_project(project)
    one_line(*run(capsys, "export", project, "-o", tmp_path / "out.bvh"), field)
    assert not (tmp_path / "out.bvh").exists()


@pytest.mark.parametrize("change, field", [
    ({"goal": {"point": [0.0, 1e308, 0.0]}}, "goal.point"),
    ({"goal": {"point": [0.0, float("nan"), 0.0]}}, "goal.point"),
    ({"kind": "trajectory", "goal": {"keys": [[5, 0.0, 1e308, 0.0]]}}, "goal.keys"),
    ({"kind": "trajectory", "goal": {"points": [[0.0, 1e300, 0.0]] * 6}}, "goal.points"),
    ({"weight": 1e308}, "weight"),
    ({"weight": float("inf")}, "weight"),
])
def test_constraint_goals_and_weights_beyond_the_range(capsys, tmp_path, change, field):
    constraint = {"joint": "LeftAnkle", "kind": "position", "goal": {"point": [0.0, 0.1, 0.0]},
                  "range": [0, 5, 10, 15], "priority": 1, "weight": 1.0, **change}
    path = tmp_path / "c.json"
    path.write_text(json.dumps({"constraints": [constraint]}))       # NaN as Python writes it
    one_line(*run(capsys, "retarget", WALK, "--target", TPOSE, "-o", tmp_path / "out.bvh",
                  "--constraints", path), str(path), field)
    assert not (tmp_path / "out.bvh").exists()


@pytest.mark.parametrize("flags, phrase", [
    (["--floor", "1e308"], "floor: expected a finite height"),
    (["--floor", "nan"], "floor: expected a finite height"),
    (["--root-scale", "1e300", "1"], "root scale must be two finite numbers"),
    (["--ik-damping", "1e308"], "--ik-damping: expected a number of magnitude at most"),
    (["--ik-tolerance", "inf"], "--ik-tolerance: expected a finite number"),
])
def test_settings_on_the_command_line_beyond_the_range(capsys, tmp_path, flags, phrase):
    one_line(*run(capsys, "retarget", WALK, "--target", TPOSE, "-o", tmp_path / "out.bvh",
                  *flags), phrase)
    assert not (tmp_path / "out.bvh").exists()


def test_a_project_floor_beyond_the_range_is_refused_in_the_model(project):
    with pytest.raises(MotionComposerError, match="floor: expected a finite height"):
        load_project(project).replace(floor=float("inf"))


# ------------------------------------------------------------------ strict JSON, no warnings
@pytest.mark.parametrize("name", ["bundled/" + WALK.name, "bundled/" + TPOSE.name,
                                  *SHARED_BVH, *GLBS])
def test_info_json_is_strict_json_without_warnings(capsys, name):
    path = clip_path(name[8:]) if name.startswith("bundled/") else shared_path(name)
    code, out, err = run(capsys, "info", path, "--json")
    assert (code, err) == (0, "")
    info = strict_json(out)
    assert np.isfinite(info["duration"]) and np.isfinite(info["stature_m"])


@pytest.mark.parametrize("target", GLBS)
def test_retarget_onto_every_glb_prints_no_warning_and_a_strict_report(capsys, tmp_path,
                                                                       target):
    """In-process, so a RuntimeWarning anywhere in reading, converting, IK (automatic contacts
    and a floor), key fitting or writing fails the test (the Bandai walk, 195 frames: the CMU
    walk's refused fits onto the fox are test_foot_contacts')."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        code, out, err = run(capsys, "retarget", shared_path("bandai1_walk_normal_001.bvh"),
                             "--target", shared_path(target), "-o", tmp_path / "out.glb",
                             "--auto-contacts", "--floor", "0", "--report",
                             tmp_path / "r.json")
    # (the robot's legs end at the knee: its feet, control joints carried with the shins,
    # are held through them, with no warning)
    assert (code, err) == (0, ""), err
    report = strict_json((tmp_path / "r.json").read_text())
    assert report["output"] == str(tmp_path / "out.glb")
    # the whole pipeline ran: contacts were made, solved and their keys fitted
    assert report["constraints"] and report["keys"]["count"] > 0


def test_viewport_normals_match_pyqtgraph_where_it_has_them_and_are_zero_where_not():
    """The viewport's numpy normals on the fox's mesh (which has degenerate triangles):
    the same as pyqtgraph's per-vertex loop where that is finite, zero (not NaN) elsewhere."""
    pytest.importorskip("pyqtgraph")
    from motion_composer.app.gui.viewport import SkinMeshData, vertex_normals
    import pyqtgraph.opengl as gl

    character = read_character(shared_path("target_fox.glb"))
    mesh = character.meshes[0]
    verts, faces = np.asarray(mesh.positions, dtype=float), np.asarray(mesh.triangles)
    ours = vertex_normals(verts, faces)
    with np.errstate(invalid="ignore", divide="ignore"):          # pyqtgraph's own NaNs
        theirs = gl.MeshData(vertexes=verts, faces=faces).vertexNormals()
    finite = np.all(np.isfinite(theirs), axis=1)
    assert np.all(np.isfinite(ours))
    np.testing.assert_allclose(ours[finite], theirs[finite], atol=1e-5)
    assert np.all(ours[~finite] == 0)
    assert SkinMeshData(verts, faces).vertexNormals(indexed="faces").shape == (len(faces), 3, 3)


def test_a_one_frame_performer_with_automatic_contacts(capsys, tmp_path):
    """A T-pose file (one frame) as the performer with --auto-contacts: there is no velocity
    to detect contacts from (numpy's gradient raised before), so none, and the pose is
    written."""
    code, out, err = run(capsys, "retarget", TPOSE, "--target", TPOSE, "-o",
                         tmp_path / "out.bvh", "--auto-contacts", "--floor", "0")
    assert (code, err) == (0, ""), err
    assert "wrote" in out and (tmp_path / "out.bvh").is_file()


@pytest.mark.parametrize("target, output, phrase", [
    (TPOSE, "out.bvh", "frame 2, Hips Xposition: -5e+10 in file units is beyond the range"),
    ("target_fox.glb", "out.glb", "frame 2: the translation of 'b_Hip_01'"),
])
def test_an_output_that_would_not_read_back_is_refused(capsys, tmp_path, target, output,
                                                       phrase):
    """A root position just inside the range (5e8 file units in the first frame, a
    video-to-BVH exporter's runaway root) blown up by ``--root-scale 100 100``: the result would
    hold numbers the readers refuse, so the writer refuses it instead of writing a file that
    does not read back."""
    clip, _ = _mutated(tmp_path, WALK, "walk.bvh", b"5.2300 ", b"500000000 ",
                       line_starts=b"5.2300")
    target = target if isinstance(target, type(TPOSE)) else shared_path(target)
    one_line(*run(capsys, "retarget", clip, "--target", target, "-o", tmp_path / output,
                  "--root-scale", "100", "100"), phrase, "would not read back")
    assert not (tmp_path / output).exists()
