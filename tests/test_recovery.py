"""Crash recovery: a session killed with SIGKILL is offered back through every way of opening
its project; autosaves go only when declined or saved; leftovers of killed saves are cleaned.

The crashes are real: a child Python process runs the real window offscreen on a copy of the
demo project, makes an edit, and is killed (SIGKILL) once its autosave file exists.
"""
from __future__ import annotations

import os
import select
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from motion_composer.app.gui.qt import QtCore
from conftest import REPO, clip_path

pytestmark = pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs POSIX signals")

#: [s] how long a child may take to start, open the demo and autosave (generous: 2 shared cores)
CHILD_TIMEOUT_S = 90.0

_CHILD = r"""
import os, sys
import motion_composer.app.gui.main_window as mw
mw.AUTOSAVE_MS = 50          # autosave soon after the edit (the parent waits on the file)
from motion_composer.app.gui.qt import QtCore, application
settings = sys.argv[2]
QtCore.QSettings.setDefaultFormat(QtCore.QSettings.Format.IniFormat)
QtCore.QSettings.setPath(QtCore.QSettings.Format.IniFormat, QtCore.QSettings.Scope.UserScope,
                         settings)
app = application()
window = mw.MainWindow()
def fail(message):
    print("error", " ".join(str(message).split()), flush=True)
    os._exit(3)
window.show_error = fail
window.ask_yes_no = lambda question: fail("asked: " + question)
project = sys.argv[1]
if project:
    if not window.open_project(project):
        fail("did not open")
    from motion_composer.app.gui.commands import push_pair
    push_pair(window.doc, "Head", None)
else:                                     # an unsaved session: two clips imported
    for side, clip in (("performer", sys.argv[3]), ("target", sys.argv[4])):
        if not window.import_file(side, clip):
            fail("import failed")
print("edited", window.doc.session, flush=True)
QtCore.QTimer.singleShot(300_000, lambda: os._exit(4))     # never left running
app.exec()
"""


def _settings(tmp_path, monkeypatch) -> None:
    QtCore.QSettings.setDefaultFormat(QtCore.QSettings.Format.IniFormat)
    QtCore.QSettings.setPath(QtCore.QSettings.Format.IniFormat,
                             QtCore.QSettings.Scope.UserScope, str(tmp_path / "settings"))
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))


def _answering(w, answers: list[bool]):
    """Replace the window's dialogs by answers, as tests/test_gui_main.py does; the recovery
    question pops ``answers`` and is recorded in ``w.asked``."""
    w.errors = []
    w.show_error = w.errors.append
    w.asked = []
    w.unsaved_answers = []
    w.ask_unsaved = lambda: w.unsaved_answers.pop(0) if w.unsaved_answers else "discard"

    def ask_yes_no(question):
        w.asked.append(question)
        return answers.pop(0)
    w.ask_yes_no = ask_yes_no
    return w


@pytest.fixture()
def make_window(qtbot, tmp_path, monkeypatch):
    """Windows answering the recovery question with the answers given."""
    from motion_composer.app.gui.main_window import MainWindow
    _settings(tmp_path, monkeypatch)
    made = []

    def make(*answers: bool):
        w = _answering(MainWindow(), list(answers))
        qtbot.addWidget(w)
        made.append(w)
        return w
    yield make
    for w in made:
        w.doc.undo_stack.setClean()


def _demo_copy(folder: Path) -> Path:
    shutil.copytree(REPO / "resources", folder / "resources")
    return folder / "resources" / "demo" / "demo.mcp"


def _crash(project: str, settings: Path, state: Path, done) -> str:
    """Run the child on ``project`` ("" for an unsaved session), wait until ``done()`` (its
    autosave is there), kill it with SIGKILL; returns the child's session name."""
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen", XDG_STATE_HOME=str(state))
    proc = subprocess.Popen(
        [sys.executable, "-c", _CHILD, project, str(settings),
         str(clip_path("cmu_131_01_walk.bvh")), str(clip_path("fair1_child8_jumping.bvh"))],
        cwd=REPO, env=env, stdout=subprocess.PIPE, text=True)
    try:
        ready, _, _ = select.select([proc.stdout], [], [], CHILD_TIMEOUT_S)
        assert ready, "the child did not start"
        line = proc.stdout.readline().split()
        assert line and line[0] == "edited", line
        deadline = time.monotonic() + CHILD_TIMEOUT_S
        while not done():
            assert proc.poll() is None, "the child ended before autosaving"
            assert time.monotonic() < deadline, "no autosave appeared"
            time.sleep(0.02)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL
    return line[1]


@pytest.fixture(scope="module")
def crashed(tmp_path_factory) -> Path:
    """A folder with a copy of the demo project whose session was killed after an edit
    (Head unmapped) was autosaved; tests copy it."""
    folder = tmp_path_factory.mktemp("crashed")
    path = _demo_copy(folder)
    from motion_composer.engine.project import autosave_path
    _crash(str(path), folder / "child-settings", folder / "child-state",
           lambda: autosave_path(path).exists())
    return folder


def _copy_crashed(crashed: Path, tmp_path: Path) -> Path:
    folder = tmp_path / "project"
    shutil.copytree(crashed / "resources", folder / "resources")   # copy2: the times stay
    return folder / "resources" / "demo" / "demo.mcp"


def _file_action(w, text: str):
    file_menu = w.menuBar().actions()[0].menu()
    return next(a for a in file_menu.actions() if a.text() == text)


def _state(w, auto: Path) -> dict:
    """What the test checks of a window that opened the crashed project."""
    doc = w.doc
    return {"asked": list(w.asked), "errors": list(w.errors), "path": doc.path,
            "ready": doc.scene.ready, "head": doc.scene.correspondence.pairs.get("Head"),
            "modified": doc.modified, "title": w.windowTitle(), "autosave": auto.exists()}


def _open_from_command_line(w, path, auto):
    """``motion-composer P.mcp``: what :func:`app.gui.main.run` does with the window before
    its event loop (not run itself here: a finished ``app.exec()`` stops the timers of the
    tests that come after it in this process)."""
    from motion_composer.app.gui.main import start
    start(w, str(path))
    return w, _state(w, auto)


def _open_with_dialog(w, path, auto):
    w.ask_open_path = lambda caption, filters: str(path)
    _file_action(w, "&Open...").trigger()
    return w, _state(w, auto)


def _open_recent(w, path, auto):
    w._add_recent(str(path))
    (action,) = [a for a in w.recent_menu.actions() if a.text() == str(path.resolve())]
    action.trigger()
    return w, _state(w, auto)


def _open_project(w, path, auto):
    w.open_project(path)
    return w, _state(w, auto)


ENTRIES = {"command line": _open_from_command_line, "File > Open": _open_with_dialog,
           "Open Recent": _open_recent, "open_project": _open_project}


@pytest.mark.parametrize("accept", [True, False], ids=["accepted", "declined"])
@pytest.mark.parametrize("entry", list(ENTRIES))
def test_a_killed_session_is_offered_through_every_entry(crashed, tmp_path, make_window,
                                                         entry, accept):
    from motion_composer.engine.project import autosave_path
    path = _copy_crashed(crashed, tmp_path)
    auto = autosave_path(path)
    assert auto.exists() and auto.stat().st_mtime_ns > path.stat().st_mtime_ns
    w = make_window(accept)
    shown, state = ENTRIES[entry](w, path, auto)
    assert len(state["asked"]) == 1 and str(auto) in state["asked"][0], state["asked"]
    assert not state["errors"]
    assert state["path"] == path and state["ready"]
    if accept:
        assert state["head"] is None                             # the edit is back
        assert state["modified"] and state["title"].startswith("demo.mcp* - ")
        assert state["autosave"]                                 # until saved or discarded
    else:
        assert not state["autosave"]
        assert state["head"] == "Head"                           # the saved project
        assert not state["modified"] and state["title"].startswith("demo.mcp - ")
    if accept:
        shown.unsaved_answers = ["cancel"]
        assert not shown.close() and auto.exists()               # closing asks to save
    shown.unsaved_answers = ["discard"]
    assert shown.close()
    assert not auto.exists()                # closed with "discard": declined after all


def test_a_killed_unsaved_session_is_offered_at_start(tmp_path, make_window, monkeypatch,
                                                      qtbot):
    from motion_composer.app.gui.main import start
    from motion_composer.engine.project import autosave_path
    state = tmp_path / "state"
    session = _crash("", tmp_path / "child-settings", state,
                     lambda: any(state.glob("motion-composer/untitled-*.autosave")))
    monkeypatch.setenv("XDG_STATE_HOME", str(state))
    auto = autosave_path(None, session)
    assert auto.exists()
    # a running unsaved session's autosave is not offered: this process's own one
    other = make_window()
    other.import_file("performer", clip_path("cmu_131_01_walk.bvh"))
    other.import_file("target", clip_path("fair1_child8_jumping.bvh"))
    mine = other.doc.autosave()
    assert mine != auto and mine.exists()
    assert other.doc.recovery_candidate(None) == auto

    w = make_window(True)
    assert start(w)
    assert len(w.asked) == 1 and str(auto) in w.asked[0]
    assert w.doc.path is None and w.doc.modified and w.doc.scene.ready
    assert w.doc.scene.performer_path == clip_path("cmu_131_01_walk.bvh").resolve()
    # its own autosave supersedes the crashed one
    w.autosave()
    assert not auto.exists() and autosave_path(None, w.doc.session).exists()
    assert mine.exists()                                  # the other session's is untouched
    w.unsaved_answers = ["discard"]
    assert w.close()
    assert not autosave_path(None, w.doc.session).exists()
    assert mine.exists()

    declined = make_window(False)
    other.doc.undo_stack.setClean()
    assert not start(declined)                            # nothing else to offer
    assert not declined.asked


def test_the_timer_autosaves_an_edit_even_when_the_scene_is_not_ready(make_window, tmp_path,
                                                                      qtbot):
    import dataclasses
    from motion_composer.app.gui.commands import push_correspondence
    from motion_composer.engine.project import autosave_path, load_project
    path = _demo_copy(tmp_path / "p")
    w = make_window()
    assert w.open_project(path)
    w.autosave_timer.setInterval(20)
    auto = autosave_path(path)
    qtbot.wait(100)
    assert not auto.exists()                              # nothing to save while unmodified
    doc = w.doc
    push_correspondence(doc, dataclasses.replace(doc.scene.correspondence, pairs={}), "Unmap all")
    assert not doc.scene.ready                            # a half-done mapping
    qtbot.waitUntil(auto.exists, timeout=30000)
    assert load_project(auto, check_sources=False).correspondence.pairs == {}
    # and it comes back as it was, unfinished
    again = make_window(True)
    assert again.open_project(path) and again.asked and not again.errors
    assert again.doc.scene.correspondence.pairs == {} and again.doc.modified
    assert not again.doc.scene.ready
    assert again.doc.scene.evaluation_error == doc.scene.evaluation_error


def test_an_autosave_survives_cancel_another_project_new_and_a_failed_save(make_window,
                                                                           tmp_path):
    from motion_composer.app.gui.commands import push_pair
    from motion_composer.engine.project import autosave_path
    path = _demo_copy(tmp_path / "a")
    other = _demo_copy(tmp_path / "b")
    w = make_window(True)
    assert w.open_project(path)
    push_pair(w.doc, "Head", None)
    auto = w.doc.autosave()
    assert auto == autosave_path(path) and auto.exists()
    w.unsaved_answers = ["cancel"]
    assert not w.close() and auto.exists()                # closing cancelled
    assert not w._save_to(tmp_path / "no such folder" / "x.mcp")
    assert w.errors and auto.exists()                     # a failed save
    w.unsaved_answers = ["discard"]
    _file_action(w, "&New").trigger()                     # New
    assert w.doc.path is None and auto.exists()
    assert w.open_project(path) and w.asked               # still offered
    w.unsaved_answers = ["discard"]
    w.ask_open_path = lambda caption, filters: str(other)
    _file_action(w, "&Open...").trigger()                 # another project
    assert w.doc.path == other and auto.exists()
    w.unsaved_answers = ["discard"]
    assert w.close()                                      # this work's autosave only
    assert auto.exists()


def test_saving_removes_the_autosave_and_closing_with_discard_is_a_decline(make_window,
                                                                           tmp_path):
    from motion_composer.app.gui.commands import push_pair
    from motion_composer.engine.project import autosave_path, find_autosave
    path = _demo_copy(tmp_path / "a")
    w = make_window()
    assert w.open_project(path)
    push_pair(w.doc, "Head", None)
    auto = w.doc.autosave()
    assert auto.exists()
    assert w.save() and not auto.exists() and find_autosave(path) is None
    # save as: the old place's autosave goes too
    push_pair(w.doc, "Neck", None)
    assert w.doc.autosave().exists()
    w.ask_save_path = lambda caption, filters: str(tmp_path / "a" / "copy.mcp")
    assert w.save_as()
    assert not auto.exists() and not autosave_path(tmp_path / "a" / "copy.mcp").exists()
    push_pair(w.doc, "Spine", None)
    again = w.doc.autosave()
    w.unsaved_answers = ["discard"]
    assert w.close() and not again.exists()


def test_two_unsaved_sessions_keep_their_own_autosaves(make_window):
    from motion_composer.engine.project import autosave_path
    first, second = make_window(), make_window()
    for w in (first, second):
        w.import_file("performer", clip_path("cmu_131_01_walk.bvh"))
        w.import_file("target", clip_path("fair1_child8_jumping.bvh"))
    a, b = first.doc.autosave(), second.doc.autosave()
    assert a != b and a.exists() and b.exists()
    assert a == autosave_path(None, first.doc.session)
    second.unsaved_answers = ["discard"]
    assert second.close()
    assert a.exists() and not b.exists()


# --------------------------------------------------------------------------- stale temporaries
_SAVER = r"""
import os, sys, time
from motion_composer.engine import project as P
path, original = sys.argv[1], sys.argv[2]
project = P.load_project(original, check_sources=False)
real = os.fsync
def fsync(fd):                   # stop inside the save, its temporary file written
    real(fd)
    print("paused", flush=True)
    time.sleep(300)
os.fsync = fsync
P.save_project(project, path)
"""


def test_a_killed_saves_leftover_goes_at_the_next_save_once_stale(tmp_path):
    from motion_composer.engine.fileio import STALE_TMP_S, remove_stale_temporaries
    from motion_composer.engine.project import load_project, project_to_json, save_project
    folder = tmp_path / "p"
    original = _demo_copy(folder)
    path = original.with_name("walk.mcp")
    project = load_project(original, check_sources=False)
    proc = subprocess.Popen([sys.executable, "-c", _SAVER, str(path), str(original)],
                            cwd=REPO, stdout=subprocess.PIPE, text=True)

    def leftovers():
        return sorted(p.name for p in path.parent.glob(".walk.mcp.*.tmp")
                      if ".bak." not in p.name)

    def age(name, seconds):
        old = time.time() - seconds
        os.utime(path.parent / name, (old, old))
    try:
        ready, _, _ = select.select([proc.stdout], [], [], CHILD_TIMEOUT_S)
        assert ready and proc.stdout.readline().strip() == "paused"
        (left,) = leftovers()
        # a live writer's file stays, however old it looks
        age(left, 10 * STALE_TMP_S)
        save_project(project, path)
        assert leftovers() == [left]
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        proc.stdout.close()
    # killed: a file written just now stays (a writer may be between creating and locking it)
    os.utime(path.parent / left)
    save_project(project, path)
    assert leftovers() == [left]
    # the backup's temporary files are not this file's
    backup_tmp = path.parent / ".walk.mcp.bak.abcdefgh.tmp"
    backup_tmp.write_text("x")
    age(backup_tmp.name, 10 * STALE_TMP_S)
    assert remove_stale_temporaries(path) == [] and backup_tmp.exists()
    # stale and unlocked: the next save removes it
    age(left, 2 * STALE_TMP_S)
    save_project(project, path)
    assert leftovers() == []
    assert path.read_text(encoding="utf-8") == project_to_json(project, path)
