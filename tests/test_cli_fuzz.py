"""The real command line on mutated real files: every run exits 0 with finite output, or 2
with one line on stderr (``batch``: or 1 for clips that failed for a typed reason); nothing
else (no exit 3, traceback, warning, crash or hang). See tests/cli_fuzz.py.

The seeds are real: a CMU walk (the CMU mocap database's BVH, as cgspeed's conversion writes
it), the CMU rest T-pose, glTF characters written by this program (JSON and GLB, as a user's
pipeline feeds them back), projects saved by ``retarget --save-project`` (sources by path and
embedded) and, with ../shared/data, more clips and characters (:data:`SHARED_BVH`,
:data:`SHARED_GLB`). The cases are the same on every run (a fixed seed).
``MC_FUZZ_CASES=3000`` runs more by hand, ``MC_FUZZ_SEED`` others, and ``MC_FUZZ_KEEP=DIR``
keeps the mutated files (and the seeds) there.
"""
from __future__ import annotations

import collections
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import cli_fuzz
from motion_composer.app.cli import main
from conftest import CLIPS, REPO, SHARED_DATA

CASES = int(os.environ.get("MC_FUZZ_CASES", "200"))
SEED = int(os.environ.get("MC_FUZZ_SEED", "13"))
#: cases per driver process
CHUNK = 150
#: every this many cases one runs as its own process (``python -m motion_composer.app.cli``, and every other
#: one the ``motion-composer`` console script when it is on PATH)
SUBPROCESS_EVERY = 20
WALK_60 = REPO / "tests" / "data" / "walk_first_60.bvh"
#: with ../shared/data, more seeds: the Bandai-Namco dataset's BVH (its own 21-joint rig) and
#: a CMU clip retargeted by Xia et al. (deep-learning output)
SHARED_BVH = ("bandai2_raise-up-right-hand_normal_001.bvh", "cmu_xia_angry_13_000_run.bvh")
#: the Khronos sample Fox (Blender's glTF exporter) and a Mixamo-rigged character
SHARED_GLB = ("target_fox.glb", "target_mixamo_ely.glb")


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    return env


def _cli(*argv, cwd=REPO, timeout=cli_fuzz.CASE_TIMEOUT_S):
    return subprocess.run([sys.executable, "-m", "motion_composer.app.cli", *map(str, argv)],
                          capture_output=True, text=True, cwd=cwd, env=_env(), timeout=timeout)


@pytest.fixture(scope="module")
def seeds(tmp_path_factory) -> cli_fuzz.Seeds:
    keep = os.environ.get("MC_FUZZ_KEEP")
    folder = Path(keep) / "seeds" if keep else tmp_path_factory.mktemp("fuzz-seeds")
    folder.mkdir(parents=True, exist_ok=True)
    walk = folder / "walk.bvh"
    shutil.copy(WALK_60, walk)
    tpose = folder / "tpose.bvh"
    shutil.copy(CLIPS / "cmu_rest_tpose.bvh", tpose)
    for argv in (
            ["retarget", walk, "--target", tpose, "-o", folder / "walk_on_tpose.gltf",
             "--auto-contacts", "--save-project", folder / "walk.mcp"],
            ["retarget", walk, "--target", tpose, "-o", folder / "walk_on_tpose.glb",
             "--save-project", folder / "embedded.mcp", "--embed-sources"]):
        assert main([str(a) for a in argv]) == 0
    glb = [folder / "walk_on_tpose.glb"]
    glb += [SHARED_DATA / n for n in SHARED_GLB if (SHARED_DATA / n).is_file()]
    bvh = [walk, tpose] + [SHARED_DATA / n for n in SHARED_BVH if (SHARED_DATA / n).is_file()]
    return cli_fuzz.Seeds(walk=walk, tpose=tpose, bvh=bvh,
                          gltf=[folder / "walk_on_tpose.gltf"], glb=glb,
                          projects=[folder / "walk.mcp", folder / "embedded.mcp"])


def _run_driver(cases, folder: Path) -> dict[str, dict]:
    """Run ``cases`` in driver processes of :data:`CHUNK` cases; results by case id (a case
    whose process died has none)."""
    results = {}
    for start in range(0, len(cases), CHUNK):
        chunk = cases[start:start + CHUNK]
        cases_file = folder / f"cases_{start}.json"
        results_file = folder / f"results_{start}.jsonl"
        cli_fuzz.write_cases(chunk, cases_file)
        proc = subprocess.run([sys.executable, str(REPO / "tests" / "cli_fuzz.py"),
                               str(cases_file), str(results_file)], capture_output=True,
                              text=True, cwd=folder, env=_env(),
                              timeout=cli_fuzz.CASE_TIMEOUT_S * (len(chunk) + 1))
        if results_file.exists():
            for line in results_file.read_text().splitlines():
                r = json.loads(line)
                results[r["id"]] = r
        if proc.returncode != 0 and len(results) < start + len(chunk):
            dead = chunk[len(results) - start]
            results[dead.id] = dict(id=dead.id, code=proc.returncode, stderr=proc.stderr[-2000:],
                                    problem=f"the process died (exit {proc.returncode})")
    return results


def _run_subprocess(case: cli_fuzz.Case, script: str | None) -> dict:
    """``case`` as its own process: the ``motion-composer`` console script when ``script``,
    else ``python -m motion_composer.app.cli``."""
    if script:
        proc = subprocess.run([script, *case.argv], capture_output=True, text=True, cwd=REPO,
                              env=_env(), timeout=cli_fuzz.CASE_TIMEOUT_S)
    else:
        proc = _cli(*case.argv)
    return dict(id=case.id, code=proc.returncode, stderr=proc.stderr,
                problem=cli_fuzz.judge(case, proc.returncode, proc.stdout, proc.stderr))


def test_fuzzed_files_through_the_real_cli(seeds, tmp_path):
    keep = os.environ.get("MC_FUZZ_KEEP")
    folder = Path(keep) if keep else tmp_path / "cases"
    cases = cli_fuzz.make_cases(seeds, folder, CASES, SEED)
    alone = cases[::SUBPROCESS_EVERY]
    pooled = [c for c in cases if c not in alone]
    results = _run_driver(pooled, folder)
    script = shutil.which("motion-composer")
    results.update({c.id: _run_subprocess(c, script if i % 2 else None)
                    for i, c in enumerate(alone)})

    by_kind = collections.Counter(c.kind for c in cases)
    codes = collections.Counter((c.kind, results.get(c.id, {}).get("code")) for c in cases)
    failures = [(c, results.get(c.id)) for c in cases
                if results.get(c.id) is None or results[c.id]["problem"]]
    report = "\n".join(
        f"{c.id} [{c.kind}] {c.what}\n    argv: {' '.join(c.argv)}\n    "
        f"{(r or {}).get('problem', 'no result (an earlier case killed the driver)')}\n    "
        f"stderr: {(r or {}).get('stderr', '')[-600:]}" for c, r in failures[:15])
    print(f"{len(cases)} cases ({len(alone)} as their own process): "
          f"{dict(sorted(by_kind.items()))}; exit codes {dict(sorted(codes.items(), key=str))}; "
          f"{len(failures)} failures")
    assert not failures, f"{len(failures)} of {len(cases)} cases failed:\n{report}"
    # the mutations reach the engine: both outcomes are common in every command
    assert {k for (k, code) in codes if code == 0} >= {"info bvh", "export project"}
    assert sum(n for (k, code), n in codes.items() if code == 2) > len(cases) // 4


# --------------------------------------------------------------------------- the contract
SUBCOMMAND_ERRORS = {
    "info": [[], ["F", "--bogus"], ["F", "--units", "furlong"], ["F", "--scale", "x"]],
    "retarget": [["F"], ["F", "--target", "F", "-o", "o.bvh", "--bogus"],
                 ["F", "--target", "F", "-o", "o.bvh", "--root", "sideways"],
                 ["F", "--target", "F", "-o", "o.bvh", "--floor", "low"],
                 ["F", "--target", "F", "-o", "o.bvh", "--reference", "frame:x"],
                 ["F", "--target", "F", "-o", "o.bvh", "--root-scale", "1"]],
    "batch": [["P"], ["P", "F", "-o", "d", "--bogus"], ["P", "F", "-o", "d", "--workers", "two"]],
    "export": [["P"], ["P", "-o", "o.bvh", "--bogus"], ["P", "-o", "o.bvh", "--solve=yes"]],
    "window": [["--frame", "x"], ["--bogus"], ["a.mcp", "b.mcp"]],
}


@pytest.mark.parametrize("command,args", [(c, a) for c, cases in SUBCOMMAND_ERRORS.items()
                                          for a in cases],
                         ids=lambda v: v if isinstance(v, str) else " ".join(v) or "nothing")
def test_argument_errors_are_one_line_and_exit_2(command, args, tmp_path):
    names = {"F": str(WALK_60), "P": str(REPO / "tests" / "data" / "project_v1.mcp")}
    argv = ([] if command == "window" else [command]) + [names.get(a, a) for a in args]
    proc = _cli(*argv, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and proc.stderr.endswith("\n"), proc.stderr
    assert proc.stderr.startswith("motion-composer") and "--help" in proc.stderr
    assert "usage:" not in proc.stderr and "Traceback" not in proc.stderr
    assert not list(tmp_path.iterdir())


def test_help_still_prints_the_usage():
    proc = _cli("retarget", "--help")
    assert proc.returncode == 0 and proc.stdout.startswith("usage: motion-composer retarget")
    assert proc.stderr == ""


def test_an_unexpected_exception_exits_3_with_its_traceback(monkeypatch, capsys):
    import motion_composer.app.cli

    def broken(args):
        raise ZeroDivisionError("an injected bug")

    monkeypatch.setattr(motion_composer.app.cli, "cmd_info", broken)
    assert main(["info", str(WALK_60)]) == 3
    err = capsys.readouterr().err
    assert err.startswith("Traceback (most recent call last):")
    assert "ZeroDivisionError: an injected bug" in err
    assert err.splitlines()[-1].startswith("motion-composer: internal error (a bug, exit 3)")


def test_a_bug_in_one_batch_clip_exits_3_with_its_traceback(seeds, monkeypatch, capsys,
                                                            tmp_path):
    import motion_composer.engine.scene

    def broken(self, **kwargs):
        raise ZeroDivisionError("an injected bug")

    monkeypatch.setattr(motion_composer.engine.scene.Scene, "solve", broken)
    code = main(["batch", str(seeds.projects[0]), str(seeds.walk), "-o", str(tmp_path / "out"),
                 "--workers", "1"])
    err = capsys.readouterr().err
    assert code == 3
    assert "Traceback (most recent call last):" in err and "ZeroDivisionError" in err
    assert err.splitlines()[-1].startswith("motion-composer: internal error (a bug, exit 3) "
                                           "in 1 of 1 clips")


@pytest.mark.parametrize("platform", [None, "xcb"])
def test_the_window_without_a_display_says_so_in_one_line(platform, tmp_path):
    env = {k: v for k, v in _env().items()
           if k not in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM")}
    if platform is not None:
        env["QT_QPA_PLATFORM"] = platform
    proc = subprocess.run([sys.executable, "-m", "motion_composer.app.cli", "--demo"], capture_output=True,
                          text=True, cwd=tmp_path, env=env, timeout=60)
    assert (proc.returncode, proc.stdout) == (2, "")
    assert proc.stderr == ("motion-composer: error: no display: run it under xvfb-run, or use "
                           "--screenshot\n")


def test_a_screenshot_without_a_display_draws_offscreen(tmp_path):
    env = {k: v for k, v in _env().items()
           if k not in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM")}
    shot = tmp_path / "window.png"
    proc = subprocess.run([sys.executable, "-m", "motion_composer.app.cli", "--demo", "--screenshot", str(shot)],
                          capture_output=True, text=True, cwd=tmp_path, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ("motion-composer: note: no display: drawing offscreen, without the "
                           "3D viewport\n")
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("role", ["project", "map", "constraints", "clip", "target"])
@pytest.mark.parametrize("special", ["/dev/zero", "fifo"])
def test_reads_refuse_devices_and_pipes(role, special, tmp_path):
    if special == "fifo":
        special = tmp_path / "pipe"
        os.mkfifo(special)
    walk, tpose = WALK_60, CLIPS / "cmu_rest_tpose.bvh"
    out = tmp_path / "out.bvh"
    argv = {"project": ["export", special, "-o", out],
            "map": ["retarget", walk, "--target", tpose, "-o", out, "--map", special],
            "constraints": ["retarget", walk, "--target", tpose, "-o", out,
                            "--constraints", special],
            "clip": ["info", special],
            "target": ["retarget", walk, "--target", special, "-o", out]}[role]
    proc = _cli(*argv, cwd=tmp_path, timeout=60)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert str(special) in proc.stderr and "not a regular file" in proc.stderr
    assert not out.exists()


# --------------------------------------------------------------------------- what it found
def test_a_one_frame_clip_with_auto_contacts(tmp_path, capsys):
    # a pose file: the CMU walk (cgspeed's BVH) cut to its first frame
    lines = WALK_60.read_text().splitlines(keepends=True)
    at = next(i for i, line in enumerate(lines) if line.startswith("Frames:"))
    pose = tmp_path / "pose.bvh"
    pose.write_text("".join(lines[:at] + ["Frames: 1\n", lines[at + 1], lines[at + 2]]))
    out = tmp_path / "out.bvh"
    assert main(["retarget", str(pose), "--target", str(CLIPS / "cmu_rest_tpose.bvh"),
                 "-o", str(out), "--auto-contacts"]) == 0
    assert capsys.readouterr().err == ""
    from motion_composer.engine.formats import read_motion
    assert read_motion(out).num_frames == 1


def test_zero_quaternion_keys_are_refused_with_their_sampler(seeds, tmp_path, capsys):
    # an exporter that leaves a rotation output accessor without a buffer view (all zeros,
    # by the glTF specification)
    doc = json.loads(seeds.gltf[0].read_text())
    a, s = next((a, ch["sampler"]) for a, anim in enumerate(doc["animations"])
                for ch in anim["channels"] if ch["target"]["path"] == "rotation")
    output = doc["animations"][a]["samplers"][s]["output"]
    del doc["accessors"][output]["bufferView"]
    path = tmp_path / "zeros.gltf"
    path.write_text(json.dumps(doc))
    code = main(["info", str(path)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "Warning" not in err
    assert (f"{path}: animations[{a}].samplers[{s}].output: key 0 is a zero quaternion" in err)
