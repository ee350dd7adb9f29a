"""`motion-composer info`: text and JSON output, overrides, and bad input (exit 2, one line)."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from motion_composer.app.cli import main
from bvh_cases import CASES, WALK
from conftest import REPO, clip_path, shared_path
from motion_composer.engine.formats.bvh import read_bvh
from motion_composer.engine.describe import describe_motion

FAIR = clip_path("fair1_child8_jumping.bvh")
TPOSE = clip_path("cmu_rest_tpose.bvh")


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def info_json(capsys, path, *options):
    code, out, err = run(capsys, "info", path, "--json", *options)
    assert (code, err) == (0, "")
    return json.loads(out)


def field(out: str, label: str) -> str:
    m = re.search(rf"^{re.escape(label)}:\s+(.*)$", out, re.MULTILINE)
    assert m, f"no '{label}:' line in\n{out}"
    return m.group(1)


def tree(out: str) -> dict[str, tuple[int, str]]:
    """joint name -> (indent depth, channel layout) from the 'joint tree:' block."""
    lines = out.split("joint tree:\n", 1)[1].splitlines()
    result = {}
    for line in lines:
        m = re.match(r"^  ((?:  )*)(\S.*?)  \[(.*)\]$", line)
        assert m, line
        result[m.group(2)] = (len(m.group(1)) // 2, m.group(3))
    return result


# --------------------------------------------------------------------------- text output
def test_info_text_walk(capsys):
    code, out, err = run(capsys, "info", WALK)
    assert (code, err) == (0, "")
    assert field(out, "frames") == "994"
    assert field(out, "frame rate").startswith("120 fps (frame time 0.0083333 s)")
    assert float(field(out, "duration").split()[0]) == pytest.approx(993 * 0.0083333, abs=1e-3)
    assert field(out, "units").startswith("cmu (0.0564444 m per unit, detected)")
    assert field(out, "up axis") == "+Y (detected)"
    stature_m = float(field(out, "stature").split()[0])
    assert 1.25 <= stature_m <= 2.0
    assert field(out, "joints") == "31 (+7 End Sites), 96 channels"
    assert field(out, "rotation orders") == "ZXY, ZYX"
    joints = tree(out)
    assert len(joints) == 31
    # README, CMU-MAX: Hips > LHipJoint > LeftHip > LeftKnee > LeftAnkle > LeftToe;
    # lowerback > Chest > Chest2 > {lowerneck > Neck > Head; LeftCollar > LeftShoulder >
    # LeftElbow > LeftWrist > {lhand > LFingers; LThumb}}
    for chain in (["Hips", "LHipJoint", "LeftHip", "LeftKnee", "LeftAnkle", "LeftToe"],
                  ["Hips", "lowerback", "Chest", "Chest2", "lowerneck", "Neck", "Head"],
                  ["Chest2", "LeftCollar", "LeftShoulder", "LeftElbow", "LeftWrist", "lhand",
                   "LFingers"],
                  ["LeftWrist", "LThumb"]):
        depths = [joints[name][0] for name in chain]
        assert depths == list(range(depths[0], depths[0] + len(chain))), chain
    assert joints["Hips"] == (0, "pos XYZ (absolute), rot ZYX")
    assert joints["LeftShoulder"][1] == "rot ZXY"
    assert joints["LeftHip"][1] == "rot ZYX"


def test_info_text_fair1(capsys):
    code, out, err = run(capsys, "info", FAIR)
    assert (code, err) == (0, "")
    assert field(out, "frames") == "654"
    assert field(out, "frame rate").startswith("119.875 fps (frame time 0.008342 s)")
    assert field(out, "units").startswith("in (0.0254 m per unit, detected)")
    assert field(out, "up axis") == "+Z (detected)"
    assert 0.85 <= float(field(out, "stature").split()[0]) <= 1.3       # a child
    assert field(out, "joints") == "27 (+7 End Sites), 84 channels"
    joints = tree(out)
    assert joints["RightHandThumb1"][1] == "rot YXZ"
    assert joints["Spine3"][0] == joints["Spine"][0] + 3                # four spine joints


# --------------------------------------------------------------------------- JSON output
def _json_specs():
    return ([pytest.param(("bundled", n), id=f"bundled/{n}")
             for n in ("cmu_131_01_walk.bvh", "fair1_child8_jumping.bvh",
                       "cmu_rest_tpose.bvh")] +
            [pytest.param(("shared", n), id=n)
             for n in ("bandai1_run_active_001.bvh", "cc3_cmu_02_01_walk.bvh",
                       "rokoko_mixamo_jesse_dance.bvh")])


#: README: frames, frame time, joints (End Sites not counted)
README = {"cmu_131_01_walk.bvh": (994, 0.0083333, 31),
          "fair1_child8_jumping.bvh": (654, 0.008342, 27),
          "cmu_rest_tpose.bvh": (1, 0.041667, 31),
          "bandai1_run_active_001.bvh": (72, 0.0333333, 22),
          "cc3_cmu_02_01_walk.bvh": (171, 0.016667, 101),
          "rokoko_mixamo_jesse_dance.bvh": (1007, 0.01, 60)}


@pytest.mark.parametrize("spec", _json_specs())
def test_info_json(capsys, spec):
    kind, name = spec
    path = clip_path(name) if kind == "bundled" else shared_path(name)
    data = info_json(capsys, path)
    frames, frame_time, joints = README[name]
    assert type(data["frames"]) is int and data["frames"] == frames
    assert data["fps"] == 1 / frame_time
    assert len(data["joints"]) == joints
    text = path.read_bytes().decode()
    names = [" ".join(m.split()) for m in re.findall(r"(?:ROOT|JOINT)[ \t]+([^\r\n{]+)", text)]
    assert data["joints"] == names                  # file order, End Sites left out
    assert not any("end" == j.lower() or "site" in j.lower() for j in data["joints"])
    # and it is exactly what the engine reports
    assert data == json.loads(json.dumps(describe_motion(read_bvh(path))))


@pytest.mark.parametrize("frame_time", ["0.008342", "1e-320", "1e-308"])
def test_json_is_strict_json(capsys, tmp_path, frame_time):
    """A frame time so small that 1 / frame_time overflows must not print fps: Infinity."""
    path = tmp_path / "fast.bvh"
    path.write_bytes(FAIR.read_bytes().replace(b"Frame Time: 0.008342",
                                               b"Frame Time: " + frame_time.encode()))
    code, out, err = run(capsys, "info", path, "--json")
    if code == 0:
        json.loads(out, parse_constant=lambda c: pytest.fail(f"non-standard JSON {c}"))
    else:
        assert (code, out) == (2, "") and "Frame Time" in err and err.count("\n") == 1


# --------------------------------------------------------------------------- overrides
def test_units_and_scale_overrides(capsys):
    base = info_json(capsys, TPOSE)
    metres = info_json(capsys, TPOSE, "--units", "m")
    assert (metres["units"], metres["metres_per_unit"]) == ("m", 1.0)
    assert metres["stature_m"] == pytest.approx(base["stature_m"] / base["metres_per_unit"])
    half = info_json(capsys, TPOSE, "--scale", "0.5")
    assert (half["units"], half["metres_per_unit"]) == ("custom", 0.5)
    assert half["stature_m"] == pytest.approx(metres["stature_m"] * 0.5)
    code, out, _ = run(capsys, "info", TPOSE, "--units", "cm")
    assert field(out, "units").startswith("cm (0.01 m per unit, given)")
    assert field(out, "up axis") == "+Y (detected)"


def test_up_axis_override(capsys):
    detected = info_json(capsys, FAIR)
    y_up = info_json(capsys, FAIR, "--up-axis", "+Y")
    assert (detected["up_axis"], y_up["up_axis"]) == ("+Z", "+Y")
    assert y_up["stature_m"] < 0.5 * detected["stature_m"]   # the child now lies down
    code, out, _ = run(capsys, "info", FAIR, "--up-axis", "+Y")
    assert field(out, "up axis") == "+Y (given)"
    assert field(out, "units").endswith("detected)")


def test_position_mode_override(capsys):
    assert info_json(capsys, WALK)["position_channels"] == {"Hips": "absolute"}
    relative = info_json(capsys, WALK, "--position-mode", "relative")
    assert relative["position_channels"] == {"Hips": "relative"}
    code, out, _ = run(capsys, "info", WALK, "--position-mode", "relative")
    assert tree(out)["Hips"][1] == "pos XYZ (relative), rot ZYX"


def test_position_mode_override_on_cc3(capsys):
    path = shared_path("cc3_cmu_02_06_pickup.bvh")
    assert info_json(capsys, path)["position_channels"] == {"CC_Base_Hip": "relative"}
    forced = info_json(capsys, path, "--position-mode", "absolute")
    assert forced["position_channels"] == {"CC_Base_Hip": "absolute"}


@pytest.mark.parametrize("options", [["--scale", "-1"], ["--scale", "0"], ["--scale", "nan"]])
def test_bad_override_values_exit_2_with_one_line(capsys, options):
    code, out, err = run(capsys, "info", TPOSE, *options)
    assert (code, out) == (2, "")
    assert err.count("\n") == 1 and err.endswith("\n")
    assert TPOSE.name in err and "scale" in err


def test_unknown_option_values_are_usage_errors(capsys):
    with pytest.raises(SystemExit) as info:
        main(["info", str(TPOSE), "--units", "furlong"])
    assert info.value.code == 2
    assert "Traceback" not in capsys.readouterr().err


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_file_exits_2_with_one_line_on_stderr(capsys, tmp_path, case):
    path, line = case.write(tmp_path)
    for extra in ([], ["--json"]):
        code, out, err = run(capsys, "info", path, *extra)
        assert code == 2
        assert out == ""
        assert err.endswith("\n") and err.count("\n") == 1, err
        assert "Traceback" not in err
        assert path.name in err
        where = f"{path}:{line}:" if line is not None else f"{path}:"
        assert where in err
        assert case.expects[0].lower() in err.lower()


def test_missing_file_exits_2(capsys, tmp_path):
    code, out, err = run(capsys, "info", tmp_path / "nope.bvh")
    assert (code, out) == (2, "")
    assert err.count("\n") == 1 and "nope.bvh" in err and "no such file" in err


def test_help_lists_the_commands(capsys):
    # with no command at all motion-composer opens the window (tests/test_gui_main.py)
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "info" in out and "retarget" in out


def _help(capsys, *args) -> str:
    with pytest.raises(SystemExit) as exc:
        main([*args, "--help"])
    assert exc.value.code == 0
    return " ".join(capsys.readouterr().out.split())


def test_help_names_the_window_flags_the_batch_extra_and_the_ik_correction(capsys):
    out = _help(capsys)
    for flag in ("--demo", "--screenshot PNG", "--frame N", "--self-test", "PROJECT.mcp"):
        assert flag in out, flag
    retarget = _help(capsys, "retarget")
    assert retarget.startswith("usage: motion-composer retarget ")
    assert "no IK correction" not in retarget
    assert "inverse kinematics" in retarget and "--auto-contacts" in retarget
    batch = _help(capsys, "batch")
    assert "needs the batch extra" in batch and "composer[batch]" in batch   # wrapped at "-"


# --------------------------------------------------------------------------- a real process
def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    return env


def console_script() -> str | None:
    """The ``motion-composer`` script installed beside the Python running the tests (its
    venv's ``bin``, on PATH or not), else one on PATH, else None."""
    beside = Path(sys.executable).parent / "motion-composer"
    return str(beside) if beside.is_file() else shutil.which("motion-composer")


def _commands():
    yield pytest.param([sys.executable, "-m", "motion_composer.app.cli"], id="python -m motion_composer.app.cli")
    script = console_script()
    yield pytest.param([script] if script else None, id="motion-composer script")


@pytest.mark.parametrize("command", list(_commands()))
def test_subprocess_good_and_bad(command, tmp_path):
    if command is None:
        pytest.skip("the motion-composer console script is not installed (beside "
                    f"{sys.executable} or on PATH)")
    good = subprocess.run(command + ["info", str(WALK), "--json"], capture_output=True,
                          text=True, cwd=REPO, env=_env(), timeout=120)
    assert good.returncode == 0, good.stderr
    data = json.loads(good.stdout)
    assert data["frames"] == 994 and data["fps"] == 1 / 0.0083333 and len(data["joints"]) == 31

    case = next(c for c in CASES if c.id == "truncated-mid-row")
    path, line = case.write(tmp_path)
    bad = subprocess.run(command + ["info", str(path)], capture_output=True, text=True,
                         cwd=REPO, env=_env(), timeout=120)
    assert bad.returncode == 2
    assert bad.stdout == ""
    assert bad.stderr.count("\n") == 1 and bad.stderr.endswith("\n")
    assert "Traceback" not in bad.stderr
    assert f"{path}:{line}:" in bad.stderr and "expected 96" in bad.stderr


def test_subprocess_binary_file(tmp_path):
    path = tmp_path / "picture.bvh"
    path.write_bytes(bytes(range(256)) * 8)
    result = subprocess.run([sys.executable, "-m", "motion_composer.app.cli", "info", str(path)],
                            capture_output=True, cwd=REPO, env=_env(), timeout=120)
    assert result.returncode == 2
    err = result.stderr.decode()
    assert err.count("\n") == 1 and "picture.bvh" in err and "Traceback" not in err
    assert result.stdout == b""
