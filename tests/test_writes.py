"""Writes never destroy (issue 13, point 3).

An output that is an input of the same command, a folder, a device or another non-regular file
is refused in one line (exit 2) before any work; a write through a symbolic link replaces the
link's target and keeps the link (the project's ``.bak`` goes beside the target); ``batch``
refuses a file as its output folder, two clips with one output name and an output onto a clip,
and locks its folder for the run, so a second run into it is refused at once.

The commands run as real processes on the bundled CMU clips (``cmu_131_01_walk.bvh`` and the
``cmu_rest_tpose.bvh`` target); every refusal is checked to leave the files as they were.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import signal
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import REPO, clip_path
from motion_composer.engine.fileio import FileWriteError, atomic_write, check_output_path
from motion_composer.engine.project import load_project, save_project
from motion_composer.engine.project.files import backup_path

WALK = clip_path("cmu_131_01_walk.bvh")
TPOSE = clip_path("cmu_rest_tpose.bvh")


def _env():
    env = dict(os.environ, PYTHONPATH=str(REPO))
    env.pop("DISPLAY", None)
    return env


def cli(*argv, cwd=REPO):
    return subprocess.run([sys.executable, "-m", "motion_composer.app.cli", *map(str, argv)],
                          capture_output=True, text=True, cwd=cwd, env=_env(), timeout=300)


def refused(run, *phrases):
    """``run`` exited 2 with one line on stderr holding every phrase, and wrote nothing."""
    assert run.returncode == 2, run.stderr
    assert run.stdout == ""
    assert run.stderr.endswith("\n") and run.stderr.count("\n") == 1, run.stderr
    assert run.stderr.startswith("motion-composer: error: ")
    for phrase in phrases:
        assert phrase in run.stderr, run.stderr


def digest(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@pytest.fixture
def session(tmp_path):
    """A folder with copies of the walk and the T-pose, and a project made from them."""
    for clip in (WALK, TPOSE):
        shutil.copy(clip, tmp_path / clip.name)
    made = cli("retarget", tmp_path / WALK.name, "--target", tmp_path / TPOSE.name,
               "-o", tmp_path / "made.bvh", "--save-project", tmp_path / "p.mcp",
               "--save-map", tmp_path / "map.json")
    assert made.returncode == 0, made.stderr
    return tmp_path


# ------------------------------------------------------------------ outputs that are inputs
@pytest.mark.parametrize("flag", ["-o", "--report", "--save-project", "--save-map"])
@pytest.mark.parametrize("onto", ["performer", "target", "map"])
def test_retarget_refuses_an_output_onto_an_input(session, flag, onto):
    walk, tpose, mapping = session / WALK.name, session / TPOSE.name, session / "map.json"
    onto_path = {"performer": walk, "target": tpose, "map": mapping}[onto]
    before = {p: digest(p) for p in (walk, tpose, mapping)}
    outputs = {"-o": session / "out.bvh"}
    outputs[flag] = onto_path
    argv = [walk, "--target", tpose, "--map", mapping]
    for name, path in outputs.items():
        argv += [name, path]
    what = {"performer": "is the performer", "target": "is the target",
            "map": "is the --map file"}[onto]
    refused(cli("retarget", *argv), f"{flag} {onto_path}", what, "choose another file")
    assert {p: digest(p) for p in before} == before
    assert not (session / "out.bvh").exists()


def test_retarget_refuses_an_input_reached_another_way(session):
    """The same file through a relative path, a symbolic link and a hard link."""
    walk = session / WALK.name
    os.symlink(walk, session / "link.bvh")
    os.link(walk, session / "hard.bvh")
    before = digest(walk)
    for output in (WALK.name, "link.bvh", "hard.bvh", f"./sub/../{WALK.name}"):
        (session / "sub").mkdir(exist_ok=True)
        refused(cli("retarget", WALK.name, "--target", TPOSE.name, "-o", output, cwd=session),
                "is the performer")
    assert digest(walk) == before
    assert os.path.islink(session / "link.bvh")


def test_retarget_refuses_two_outputs_onto_one_file(session):
    refused(cli("retarget", session / WALK.name, "--target", session / TPOSE.name,
                "-o", session / "x.bvh", "--report", session / "x.bvh"),
            "--report", "is also the file of -o")
    assert not (session / "x.bvh").exists()


def test_export_refuses_the_project_and_its_sources(session):
    project = session / "p.mcp"
    before = {p: digest(p) for p in (project, session / WALK.name, session / TPOSE.name)}
    refused(cli("export", project, "-o", project), "is the project")
    refused(cli("export", project, "-o", session / WALK.name), "is the project's performer")
    refused(cli("export", project, "-o", session / TPOSE.name), "is the project's target")
    assert {p: digest(p) for p in before} == before


# ------------------------------------------------------------------ folders, devices, pipes
def test_retarget_refuses_a_folder(session):
    (session / "folder.bvh").mkdir()
    refused(cli("retarget", session / WALK.name, "--target", session / TPOSE.name,
                "-o", session / "folder.bvh"), "it is a folder, not a regular file")
    refused(cli("retarget", session / WALK.name, "--target", session / TPOSE.name,
                "-o", session / "o.bvh", "--report", session), "--report", "it is a folder")
    assert not (session / "o.bvh").exists()


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="/dev/full is Linux's")
def test_a_device_is_never_replaced(session):
    """``-o /dev/full`` (named directly, or through a link with a writable suffix) is refused;
    the device node stays a device."""
    refused(cli("retarget", session / WALK.name, "--target", session / TPOSE.name,
                "-o", "/dev/full"), "-o /dev/full", "it is a device")
    os.symlink("/dev/full", session / "full.bvh")
    refused(cli("retarget", session / WALK.name, "--target", session / TPOSE.name,
                "-o", session / "full.bvh", "--report", session / "r.json"), "it is a device")
    refused(cli("export", session / "p.mcp", "-o", session / "full.bvh"), "it is a device")
    assert stat.S_ISCHR(os.stat("/dev/full").st_mode)
    assert os.path.islink(session / "full.bvh")
    assert not (session / "r.json").exists()
    with pytest.raises(FileWriteError, match="it is a device"):
        atomic_write("/dev/full", "x")


def test_a_named_pipe_is_refused(tmp_path):
    os.mkfifo(tmp_path / "pipe.bvh")
    with pytest.raises(FileWriteError, match="it is a named pipe"):
        check_output_path(tmp_path / "pipe.bvh", label="-o")
    assert stat.S_ISFIFO(os.stat(tmp_path / "pipe.bvh").st_mode)


def test_a_missing_folder_is_refused_before_any_work(session):
    run = cli("retarget", session / WALK.name, "--target", session / TPOSE.name,
              "-o", session / "out.bvh", "--report", session / "no" / "r.json")
    refused(run, "--report", "does not exist")
    assert not (session / "out.bvh").exists()


# ------------------------------------------------------------------ symbolic links
def test_writing_through_a_link_keeps_the_link(session):
    real = session / "real"
    real.mkdir()
    (real / "out.bvh").write_text("old\n")
    os.symlink(real / "out.bvh", session / "link.bvh")
    run = cli("export", session / "p.mcp", "-o", session / "link.bvh")
    assert run.returncode == 0, run.stderr
    assert os.path.islink(session / "link.bvh")
    assert (real / "out.bvh").read_text().startswith("HIERARCHY")
    assert sorted(os.listdir(real)) == ["out.bvh"]                 # no temporary left over


def test_a_dangling_link_creates_its_target(tmp_path):
    os.symlink(tmp_path / "new.json", tmp_path / "link.json")
    atomic_write(tmp_path / "link.json", "{}\n")
    assert os.path.islink(tmp_path / "link.json")
    assert (tmp_path / "new.json").read_text() == "{}\n"


def test_saving_a_project_through_a_link(session):
    """The link (in another folder) stays; the target is replaced and its previous version
    kept as the target's own ``.bak`` beside it (never a ``.bak`` beside the link); source
    paths stay relative to the real file, so it opens directly and through the link."""
    links = session / "links"
    links.mkdir()
    os.symlink(session / "p.mcp", links / "link.mcp")
    old = (session / "p.mcp").read_bytes()
    project = load_project(links / "link.mcp")
    save_project(project.replace(floor=0.25), links / "link.mcp")
    assert os.path.islink(links / "link.mcp")
    assert load_project(session / "p.mcp").floor == 0.25
    assert load_project(links / "link.mcp").floor == 0.25
    assert backup_path(session / "p.mcp").read_bytes() == old
    assert os.listdir(links) == ["link.mcp"]


# ------------------------------------------------------------------ batch
def test_batch_refuses_a_file_as_its_folder(session):
    before = digest(session / "made.bvh")
    refused(cli("batch", session / "p.mcp", session / WALK.name, "-o", session / "made.bvh"),
            "is a file", "give a folder")
    assert digest(session / "made.bvh") == before


def test_batch_refuses_two_clips_with_one_output_name(session):
    (session / "other").mkdir()
    shutil.copy(WALK, session / "other" / WALK.name)
    refused(cli("batch", session / "p.mcp", session / WALK.name, session / "other" / WALK.name,
                "-o", session / "out"), "would both be written to")
    assert not (session / "out").exists()


def test_batch_refuses_an_output_onto_a_clip_or_the_summary_onto_an_input(session):
    walk = session / WALK.name
    before = digest(walk)
    refused(cli("batch", session / "p.mcp", walk, "-o", session), "is the clip")
    refused(cli("batch", session / "p.mcp", walk, "-o", session / "out",
                "--summary", session / "p.mcp"), "--summary", "is the project")
    assert digest(walk) == before


def test_two_batch_runs_into_one_folder(session):
    """Two real batch processes: while the first holds the folder (stopped with SIGSTOP right
    after its first clip, so the test does not depend on timing), the second is refused in one
    line; the first then finishes and wrote every clip; a third run afterwards works."""
    out = session / "out"
    clips = []
    for k in range(3):
        clips.append(session / f"walk{k}.bvh")
        shutil.copy(WALK, clips[-1])
    first = subprocess.Popen([sys.executable, "-m", "motion_composer.app.cli", "batch", str(session / "p.mcp"),
                              *map(str, clips), "-o", str(out), "--workers", "1"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             cwd=REPO, env=_env())
    try:
        progress = first.stderr.readline()                     # the first clip is written
        assert "1/3" in progress, progress
        first.send_signal(signal.SIGSTOP)
        try:
            second = cli("batch", session / "p.mcp", session / WALK.name, "-o", out)
        finally:
            first.send_signal(signal.SIGCONT)
        refused(second, f"-o {out}", "another batch run is writing into this folder")
        assert not (out / WALK.name).exists()
        stdout, _ = first.communicate(timeout=300)
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    assert first.returncode == 0, stdout
    assert sorted(os.listdir(out)) == ["walk0.bvh", "walk1.bvh", "walk2.bvh"]
    third = cli("batch", session / "p.mcp", session / WALK.name, "-o", out)
    assert third.returncode == 0, third.stderr
    assert (out / WALK.name).is_file()
