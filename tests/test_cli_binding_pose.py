"""`retarget` and `batch` with a retarget pose (issue 18): ``--pose-offsets``,
``--chain-settings``, ``--profile`` (and ``retarget --save-profile``).

Real clips: the first 60 frames of the bundled CMU walk onto the bundled CMU T-pose. The
written files are read back and compared with the engine called directly with the same
options; bad settings files exit 2 with one line on stderr naming the file and the field,
also when fuzzed (tests/cli_fuzz.py's mutations and verdict).
"""
from __future__ import annotations

import json
import random
from pathlib import Path

import numpy as np
import pytest

import cli_fuzz
from conftest import REPO, clip_path
from motion_composer.app.cli import main
from motion_composer.engine import read_bvh
from motion_composer.engine.conversion import (BindOptions, ChainSettings, automap,
                                               euler_to_offset, retarget)
from motion_composer.engine.project import load_project, read_profile

WALK_60 = REPO / "tests" / "data" / "walk_first_60.bvh"
TPOSE = clip_path("cmu_rest_tpose.bvh")
OFFSETS = {"LeftArm": [0.0, 0.0, 10.0], "RightUpLeg": [-4.0, 2.5, 0.0]}
CHAINS = {"arm_r": {"weight": 0.5, "twist": False}, "spine": {"distribute": "first"}}


def _write(folder: Path, name: str, data) -> Path:
    path = folder / name
    path.write_text(json.dumps(data))
    return path


def _expected_options() -> BindOptions:
    return BindOptions(
        pose_offsets={j: tuple(euler_to_offset(a)) for j, a in OFFSETS.items()},
        chains={"arm_r": ChainSettings(weight=0.5, twist=False),
                "spine": ChainSettings(distribute="first")})


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_pose_offsets_and_chain_settings_reach_the_conversion(tmp_path, capsys):
    offsets = _write(tmp_path, "offsets.json", OFFSETS)
    chains = _write(tmp_path, "chains.json", CHAINS)
    out, project = tmp_path / "out.bvh", tmp_path / "p.mcp"
    code, _, err = _run(capsys, "retarget", WALK_60, "--target", TPOSE, "-o", out,
                        "--pose-offsets", offsets, "--chain-settings", chains,
                        "--save-project", project)
    assert code == 0, err
    saved = load_project(project)
    assert saved.bind_options == _expected_options()
    performer, target = read_bvh(WALK_60), read_bvh(TPOSE)
    direct = retarget(performer, target, automap(target.skeleton, performer.skeleton),
                      bind_options=_expected_options())
    plain = retarget(performer, target, automap(target.skeleton, performer.skeleton))
    written = read_bvh(out)
    # the file keeps 6 decimals of degrees: compare world positions, as test_cli_retarget
    from motion_composer.engine import forward_kinematics
    got = forward_kinematics(written).positions
    assert np.abs(got - forward_kinematics(direct).positions).max() < 1e-4
    assert np.abs(got - forward_kinematics(plain).positions).max() > 0.02


def test_a_profile_carries_the_whole_setup_and_flags_override_it(tmp_path, capsys):
    offsets = _write(tmp_path, "offsets.json", OFFSETS)
    chains = _write(tmp_path, "chains.json", CHAINS)
    profile = tmp_path / "holden.mcprofile"
    first = tmp_path / "first.bvh"
    code, _, err = _run(capsys, "retarget", WALK_60, "--target", TPOSE, "-o", first,
                        "--pose-offsets", offsets, "--chain-settings", chains,
                        "--reference", "rest", "--root", "in-place", "--auto-contacts",
                        "--ik-iterations", "20", "--save-profile", profile)
    assert code == 0, err
    saved = read_profile(profile)
    assert saved.bind_options == BindOptions(performer_reference="rest",
                                             pose_offsets=_expected_options().pose_offsets,
                                             chains=_expected_options().chains)
    assert saved.root.mode == "in-place" and saved.auto_contacts
    assert saved.ik_options.max_iterations == 20
    # the profile alone gives the same file
    again = tmp_path / "again.bvh"
    code, _, err = _run(capsys, "retarget", WALK_60, "--target", TPOSE, "-o", again,
                        "--profile", profile)
    assert code == 0, err
    assert again.read_bytes() == first.read_bytes()
    # given flags win; the rest stays the profile's; a chain file changes only what it gives
    more = _write(tmp_path, "more.json", {"arm_r": {"ik_blend": 1.0}})
    p2 = tmp_path / "p2.mcp"
    code, _, err = _run(capsys, "retarget", WALK_60, "--target", TPOSE, "-o",
                        tmp_path / "o2.bvh", "--profile", profile, "--distribute", "first",
                        "--root", "scaled", "--chain-settings", more,
                        "--pose-offsets", _write(tmp_path, "o.json", {"LeftArm": [0, 0, 0]}),
                        "--save-project", p2)
    assert code == 0, err
    options = load_project(p2).bind_options
    assert options.distribute == "first" and options.performer_reference == "rest"
    assert options.chain("arm_r") == ChainSettings(weight=0.5, twist=False, ik_blend=1.0)
    assert [j for j, _ in options.pose_offsets] == ["RightUpLeg"]    # 0 0 0 removed it
    project = load_project(p2)
    assert project.root.mode == "scaled" and project.auto_contacts
    assert any(c.name == "reach arm_r" for c in project.constraints)


def test_batch_applies_the_profile_to_every_clip(tmp_path, capsys):
    offsets = _write(tmp_path, "offsets.json", OFFSETS)
    profile, project = tmp_path / "p.mcprofile", tmp_path / "plain.mcp"
    single = tmp_path / "single.bvh"
    code, _, err = _run(capsys, "retarget", WALK_60, "--target", TPOSE, "-o", single,
                        "--pose-offsets", offsets, "--save-profile", profile)
    assert code == 0, err
    code, _, err = _run(capsys, "retarget", WALK_60, "--target", TPOSE, "-o",
                        tmp_path / "plain.bvh", "--save-project", project)
    assert code == 0, err
    clips = []
    for name in ("a", "b"):
        clip = tmp_path / f"{name}.bvh"
        clip.write_bytes(WALK_60.read_bytes())
        clips.append(clip)
    out = tmp_path / "out"
    code, _, err = _run(capsys, "batch", project, *clips, "-o", out, "--workers", "1",
                        "--profile", profile)
    assert code == 0, err
    for clip in clips:
        assert (out / clip.name).read_bytes() == single.read_bytes()
    # and the chain settings flag on top, for every clip
    chains = _write(tmp_path, "chains.json", {"arm_l": {"weight": 0}})
    code, _, err = _run(capsys, "batch", project, clips[0], "-o", tmp_path / "out2",
                        "--workers", "1", "--profile", profile, "--chain-settings", chains)
    assert code == 0, err
    assert (tmp_path / "out2" / "a.bvh").read_bytes() != single.read_bytes()


BAD_SETTINGS = [
    ("--pose-offsets", b"[1, 2]", "expected an object"),
    ("--pose-offsets", b'{"LeftArm": [0, 0]}', "LeftArm: expected [x, y, z]"),
    ("--pose-offsets", b'{"LeftArm": [0, "a", 0]}', "LeftArm[1]: expected a number"),
    ("--pose-offsets", b'{"LeftArm": [0, 1e999, 0]}', "LeftArm[1]"),
    ("--pose-offsets", b'{"Tail": [0, 0, 10]}', "Tail: 'Tail' is not a joint"),
    ("--pose-offsets", b'{"LeftArm": [0, 0, 10],', "truncated"),
    ("--pose-offsets", b"", "empty"),
    ("--chain-settings", b'{"tail": {}}', "tail: unknown chain"),
    ("--chain-settings", b'{"arm_l": {"weight": 2}}', "arm_l.weight: expected a number from 0"),
    ("--chain-settings", b'{"arm_l": {"twist": "no"}}', "arm_l.twist: expected true or false"),
    ("--chain-settings", b'{"arm_l": {"distribute": 1}}', "arm_l.distribute: expected one of"),
    ("--chain-settings", b'{"arm_l": {"reach": 1}}', "arm_l.reach: unknown field"),
    ("--chain-settings", b'{"fingers_l": {"ik_blend": 1}}', "fingers_l.ik_blend"),
    ("--chain-settings", b"\xff\xfe", "UTF-8"),
    ("--profile", b'{"format": "motion-composer-profile", "version": 1}', "correspondence"),
    ("--profile", b'{"format": "x", "version": 1, "correspondence": {"pairs": {}}}',
     "format: not a Motion Composer profile"),
    ("--profile", b'{"format": "motion-composer-profile", "version": 1, "correspondence": '
                  b'{"pairs": {"Nobody": "Hips"}}}', "Nobody"),
]


#: batch checks a map on each clip (a failed clip, exit 1:
#: test_batch_a_bad_profile_map_fails_the_clips), so not the profile naming a joint
BAD_CASES = [pytest.param(command, flag, content, words, id=f"{command} {flag} {words}")
             for command in ("retarget", "batch") for flag, content, words in BAD_SETTINGS
             if not (command == "batch" and b"Nobody" in content)]


@pytest.mark.parametrize("command, flag, content, words", BAD_CASES)
def test_bad_settings_files_exit_2_with_one_line(tmp_path, capsys, command, flag, content,
                                                 words):
    bad = tmp_path / "bad.json"
    bad.write_bytes(content)
    if command == "retarget":
        argv = ["retarget", WALK_60, "--target", TPOSE, "-o", tmp_path / "o.bvh", flag, bad]
    else:
        argv = ["batch", _plain_project(tmp_path), WALK_60, "-o", tmp_path / "out",
                "--workers", "1", flag, bad]
    code, out, err = _run(capsys, *argv)
    assert code == 2, err
    assert err.count("\n") == 1 and str(bad) in err and words in err, err
    assert not (tmp_path / "o.bvh").exists() and not (tmp_path / "out").exists()


def _plain_project(folder: Path) -> Path:
    project = folder / "plain.mcp"
    if not project.exists():
        assert main(["retarget", str(WALK_60), "--target", str(TPOSE), "-o",
                     str(folder / "plain.bvh"), "--save-project", str(project)]) == 0
    return project


def test_batch_a_bad_profile_map_fails_the_clips(tmp_path, capsys):
    bad = tmp_path / "bad.mcprofile"
    bad.write_text(json.dumps({"format": "motion-composer-profile", "version": 1,
                               "correspondence": {"pairs": {"Nobody": "Hips"}}}))
    project = _plain_project(tmp_path)
    summary = tmp_path / "s.json"
    code, out, err = _run(capsys, "batch", project, WALK_60, "-o", tmp_path / "out",
                          "--workers", "1", "--profile", bad, "--summary", summary)
    assert code == 1
    (clip,) = json.loads(summary.read_text())
    assert clip["status"] == "failed" and "Nobody" in clip["reason"]


def test_missing_settings_files_exit_2(tmp_path, capsys):
    for flag in ("--pose-offsets", "--chain-settings", "--profile"):
        code, _, err = _run(capsys, "retarget", WALK_60, "--target", TPOSE, "-o",
                            tmp_path / "o.bvh", flag, tmp_path / "none.json")
        assert code == 2 and err.count("\n") == 1 and "no such" in err, err


def test_fuzzed_settings_files_through_the_real_cli(tmp_path):
    """Mutated pose-offsets, chain-settings and profile files (the fuzz's JSON edits,
    truncations, flipped bytes, wild numbers): every run exits 0 or 2 with one line, never
    a traceback or exit 3."""
    seeds = tmp_path / "seeds"
    seeds.mkdir()
    profile = seeds / "p.mcprofile"
    assert main(["retarget", str(WALK_60), "--target", str(TPOSE), "-o",
                 str(seeds / "o.bvh"), "--save-profile", str(profile),
                 "--pose-offsets", str(_write(seeds, "offsets.json", OFFSETS)),
                 "--chain-settings", str(_write(seeds, "chains.json", CHAINS))]) == 0
    sources = {"--pose-offsets": seeds / "offsets.json", "--chain-settings": seeds /
               "chains.json", "--profile": profile}
    mutations = (cli_fuzz.json_edit, cli_fuzz.json_edit, cli_fuzz.json_edit,
                 cli_fuzz.truncate, cli_fuzz.flip_bytes, cli_fuzz.wild_numbers)
    rng = random.Random(18)
    codes, problems = [], []
    for n in range(45):
        flag = list(sources)[n % 3]
        path, what = cli_fuzz._mutate(sources[flag], mutations, tmp_path / f"c{n}.json", rng)
        out = tmp_path / f"c{n}.bvh"
        case = cli_fuzz.Case(f"c{n}", ["retarget", str(WALK_60), "--target", str(TPOSE),
                                       "-o", str(out), flag, str(path)], [str(out)], what,
                             f"retarget {flag}")
        result = cli_fuzz.run_in_process(case)
        codes.append(result["code"])
        if result["problem"]:
            problems.append(f"{case.kind} {what}: {result['problem']}: {result['stderr']}")
    assert not problems, "\n".join(problems[:10])
    assert set(codes) == {0, 2}
