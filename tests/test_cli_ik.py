"""retarget with constraints, automatic contacts, a floor and a report, through the CLI."""
from __future__ import annotations

import json

import numpy as np
import pytest

from motion_composer.app.cli import main
from motion_composer.engine import forward_kinematics, read_bvh
from ik_fixtures import MAX_TO_HOLDEN
from conftest import clip_path

WALK = str(clip_path("cmu_131_01_walk.bvh"))
TPOSE = str(clip_path("cmu_rest_tpose.bvh"))


@pytest.fixture()
def mapping(tmp_path):
    path = tmp_path / "map.json"
    path.write_text(json.dumps({"pairs": MAX_TO_HOLDEN}))
    return str(path)


def _run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_auto_contacts_floor_and_report(tmp_path, mapping, capsys):
    out = tmp_path / "out.bvh"
    report = tmp_path / "report.json"
    plain = tmp_path / "plain.bvh"
    code, _, err = _run(capsys, "retarget", WALK, "--target", TPOSE, "-o", str(plain),
                        "--map", mapping)
    assert code == 0, err
    # the T-pose file stands its hips at the origin: its floor is about 0.9 m below
    toes = forward_kinematics(read_bvh(plain)).positions[:, [5, 10], 1]
    floor = float(np.percentile(toes.min(axis=1), 2))
    assert -1.0 < floor < -0.8
    code, text, err = _run(capsys, "retarget", WALK, "--target", TPOSE, "-o", str(out),
                           "--map", mapping, "--auto-contacts", "--floor", str(floor),
                           "--report", str(report))
    assert code == 0, err
    assert "constraints" in text
    data = json.loads(report.read_text())
    # the largest residual per unit: the contacts' in mm, the flat feet's turns in degrees
    # (one figure mixed them: 0.013 rad printed as 13 mm)
    metric = max(c["max_residual"] for c in data["constraints"]
                 if c["residual_unit"] == "m" and c["max_residual"] is not None)
    angular = max(c["max_residual"] for c in data["constraints"]
                  if c["residual_unit"] == "rad" and c["max_residual"] is not None)
    assert f"(largest residual {metric * 1000:.2f} mm, {np.degrees(angular):.2f} deg)" in text
    # the keys stored and how far the delivered motion is from the dense solve, as reported
    keys = data["keys"]
    assert keys["count"] > 0 and keys["fitted_to"] in ("tasks", "dense curves")
    assert (f"{keys['count']} keys fitted to the {keys['fitted_to']} (at most "
            f"{keys['largest_distance_from_dense_m'] * 1000:.1f} mm from the dense solve)") in text
    assert data["frames"] == 994
    # how the figures were bound: both rest poses face +Z, so the target was not turned
    assert data["binding"]["performer reference"] == "rest pose (zero rotations)"
    assert data["binding"]["hip height ratio"] and "target facing" not in data["binding"]
    # the character stands on that floor: the conversion moved by it less the T-pose's own
    # (its lowest foot point with the hips at 0), and the summary says so
    rest_floor = forward_kinematics(read_bvh(TPOSE)).end_positions[0, :, 1].min()
    assert data["floor"]["height_m"] == pytest.approx(floor)
    assert data["floor"]["lift_m"] == pytest.approx(floor - rest_floor, abs=1e-9)
    direction = "raised" if floor > rest_floor else "lowered"
    assert (f"standing on the floor at {floor:.3f} m (the conversion {direction} "
            f"{abs(floor - rest_floor) * 1000:.0f} mm onto it)") in text
    drift = data["contact_drift"]
    assert drift["count"] >= 10
    assert drift["corrected_mean_m"] < 0.1 * drift["direct_mean_m"]
    assert all(c["max_residual"] is None or c["max_residual"] < 1e-3
               for c in data["constraints"])
    assert data["timings"]["ik_s"] > 0
    # the written motion is the corrected one: its planted feet stay put, the plain one's slide
    fixed, direct = read_bvh(out), read_bvh(plain)
    contact = next(c for c in data["contacts"] if c["end"] - c["start"] > 40)
    j = fixed.skeleton.index[contact["joint"]]
    span = slice(contact["start"], contact["end"] + 1)
    moved = forward_kinematics(fixed).positions[span, j][:, [0, 2]]
    slid = forward_kinematics(direct).positions[span, j][:, [0, 2]]
    assert np.linalg.norm(moved - moved[0], axis=1).max() < 1e-3 + 1e-5   # file rounding
    assert np.linalg.norm(slid - slid[0], axis=1).max() > 0.01
    # the floor holds for the feet and toes, which dipped below it before
    pos = forward_kinematics(fixed).positions
    before = forward_kinematics(direct).positions
    for name in ("LeftFoot", "RightFoot", "LeftToeBase", "RightToeBase"):
        assert pos[:, fixed.skeleton.index[name], 1].min() > floor - 1e-3
    assert before[:, [5, 10], 1].min() < floor - 0.005


def test_a_constraints_file_is_enforced(tmp_path, mapping, capsys):
    plain = tmp_path / "plain.bvh"
    assert _run(capsys, "retarget", WALK, "--target", TPOSE, "-o", str(plain),
                "--map", mapping)[0] == 0
    hand = forward_kinematics(read_bvh(plain)).positions[:, 20]      # LeftHand
    goal = (hand[400] + [0.1, 0.2, 0.05]).tolist()
    cons = tmp_path / "c.json"
    cons.write_text(json.dumps({"constraints": [
        {"joint": "LeftHand", "kind": "position", "goal": {"point": goal},
         "range": [370, 400, 440, 470], "name": "reach"}]}))
    out = tmp_path / "out.bvh"
    report = tmp_path / "r.json"
    code, _, err = _run(capsys, "retarget", WALK, "--target", TPOSE, "-o", str(out), "--map",
                        mapping, "--constraints", str(cons), "--report", str(report))
    assert code == 0, err
    got = forward_kinematics(read_bvh(out)).positions[400:441, 20]
    assert np.linalg.norm(got - goal, axis=1).max() < 1e-3 + 1e-5
    data = json.loads(report.read_text())
    assert data["constraints"][0]["constraint"] == "reach"
    assert data["constraints"][0]["max_residual"] < 1e-3


@pytest.mark.parametrize("content, expected", [
    ('{"constraints": [}', "line 1"),
    ('{"constraints": [{"joint": "LeftHand", "kind": "position", "goal": {"point": [0,0,0]},'
     ' "range": [5, 4, 6, 7]}]}', "smooth_in <= start"),
    ('{"constraints": [{"joint": "Tail", "kind": "position", "goal": {"point": [0,0,0]},'
     ' "range": [1, 2, 3, 4]}]}', "'Tail' is not a joint of the target"),
    ('{"constraints": [{"joint": "LeftHand", "kind": "position", "goal": {"point": [0,0,0]},'
     ' "range": [1, 2, 3, 99999]}]}', "past the last frame"),
])
def test_bad_constraint_files_give_one_line_and_exit_2(tmp_path, mapping, capsys, content,
                                                       expected):
    cons = tmp_path / "c.json"
    cons.write_text(content)
    code, out, err = _run(capsys, "retarget", WALK, "--target", TPOSE, "-o",
                          str(tmp_path / "o.bvh"), "--map", mapping, "--constraints", str(cons))
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0] and "Traceback" not in err
    assert not (tmp_path / "o.bvh").exists()


def test_a_missing_constraints_file(tmp_path, mapping, capsys):
    code, _, err = _run(capsys, "retarget", WALK, "--target", TPOSE, "-o",
                        str(tmp_path / "o.bvh"), "--map", mapping, "--constraints",
                        str(tmp_path / "absent.json"))
    assert code == 2 and "absent.json" in err and len(err.strip().splitlines()) == 1


def test_the_report_says_when_the_target_was_turned_to_face_as_the_performer(tmp_path, capsys):
    """The Bandai run is bound on its first frame (its rest pose lies), where the performer
    faces 3.7 degrees from +Z: the CMU T-pose is turned so, and the report says it."""
    from conftest import shared_path
    report = tmp_path / "r.json"
    code, _, err = _run(capsys, "retarget", str(shared_path("bandai1_run_active_001.bvh")),
                        "--target", TPOSE, "-o", str(tmp_path / "out.bvh"), "--auto-contacts",
                        "--report", str(report))
    assert code == 0, err
    binding = json.loads(report.read_text())["binding"]
    assert binding["performer reference"] == "frame 0"
    assert binding["target facing"] == ("turned +3.7 degrees about the vertical to face as "
                                        "the performer")
