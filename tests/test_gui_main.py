"""The composer window: the demo project, files, undo, errors, long work, closing."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from motion_composer.app.gui.qt import QtCore
from conftest import REPO, clip_path
from gui_support import SOLVE_WAIT_MS, WAIT_MS, quiet_window

DEMO = REPO / "resources" / "demo" / "demo.mcp"


@pytest.fixture()
def window(qtbot, tmp_path, monkeypatch):
    w = quiet_window(qtbot, tmp_path, monkeypatch)
    w.answers = []
    w.ask_unsaved = lambda: w.answers.pop(0) if w.answers else "discard"
    w.ask_yes_no = lambda question: True
    yield w
    w.doc.undo_stack.setClean()


def _demo_copy(tmp_path) -> Path:
    folder = tmp_path / "project"
    shutil.copytree(REPO / "resources", folder / "resources")
    return folder / "resources" / "demo" / "demo.mcp"


def test_the_demo_opens_ready_to_play(window):
    assert window.open_project(DEMO), window.errors
    doc = window.doc
    assert doc.scene.ready and doc.scene.num_frames == 994
    assert doc.scene.viewer.current_frame == 560
    assert any(c.auto for c in doc.scene.constraints)                      # automatic foot contacts
    assert any(not c.auto for c in doc.scene.constraints)                  # and a hand constraint
    assert len(doc.scene.displacement) > 0
    assert not doc.modified and window.windowTitle().startswith("demo.mcp - ")


def test_edits_are_undoable_and_named_and_the_title_shows_them(window):
    from motion_composer.app.gui.commands import push_pair
    window.open_project(DEMO)
    doc = window.doc
    before = doc.motion.rotations.copy()
    push_pair(doc, "LeftForeArm", None)
    assert doc.modified and "*" in window.windowTitle()
    assert window.undo_action.text() == "&Undo Unmap LeftForeArm"
    assert not np.array_equal(doc.motion.rotations, before)
    window.undo_action.trigger()
    np.testing.assert_array_equal(doc.motion.rotations, before)
    assert not doc.modified and "*" not in window.windowTitle()
    assert window.redo_action.text() == "&Redo Unmap LeftForeArm"


def test_save_as_open_and_recent(window, tmp_path):
    from motion_composer.app.gui.commands import push_options
    from motion_composer.engine.conversion import RootOptions
    path = _demo_copy(tmp_path)
    window.open_project(path)
    push_options(window.doc, root_options=RootOptions(mode="in-place"), text="In place")
    out = tmp_path / "saved.mcp"
    window.ask_save_path = lambda *a: str(out)
    assert window.save_as()
    assert out.is_file() and not window.doc.modified
    assert window.doc.path == out
    window.new_project()
    assert window.doc.scene.performer is None
    actions = window.recent_menu.actions()
    assert actions and actions[0].text() == str(out.resolve())
    actions[0].trigger()
    assert window.doc.scene.root.mode == "in-place"
    assert window.doc.scene.ready


def test_import_export_and_automatic_mapping(window, tmp_path):
    assert window.import_file("performer", clip_path("cmu_131_01_walk.bvh"))
    assert window.import_file("target", clip_path("cmu_rest_tpose.bvh"))
    doc = window.doc
    assert doc.scene.ready and doc.scene.correspondence.pairs["LeftArm"] == "LeftShoulder"
    # the import that completes the pair auto-maps, in the same undoable command
    assert window.undo_action.text() == "&Undo Import target cmu_rest_tpose.bvh"
    out = tmp_path / "out.bvh"
    assert window.export_motion(out)
    from motion_composer.engine import read_bvh
    assert read_bvh(out).num_frames == 994


def test_bad_files_show_an_error_and_the_window_keeps_running(window, tmp_path):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0\n")
    assert not window.import_file("performer", bad)
    assert window.errors and "bad.bvh:4" in window.errors[-1]
    corrupt = tmp_path / "corrupt.mcp"
    corrupt.write_text('{"format": "motion-composer-project", "version": 1, "performer": ')
    assert not window.open_project(corrupt)
    assert "corrupt.mcp" in window.errors[-1]
    assert window.open_project(DEMO)                                  # still fine


def test_a_moved_clip_is_asked_for(window, tmp_path):
    path = _demo_copy(tmp_path)
    clip = path.parent.parent / "clips" / "cmu_131_01_walk.bvh"
    moved = tmp_path / "elsewhere.bvh"
    clip.rename(moved)
    asked = []
    window.ask_open_path = lambda caption, filters: asked.append(caption) or str(moved)
    assert window.open_project(path), window.errors
    assert asked and "cmu_131_01_walk.bvh" in asked[0]
    assert window.doc.scene.ready and window.doc.scene.performer_path == moved.resolve()
    assert window.doc.modified                                       # the new place is unsaved


def test_closing_with_unsaved_changes_asks(window, qtbot):
    from motion_composer.app.gui.commands import push_pair
    window.open_project(DEMO)
    push_pair(window.doc, "Head", None)
    window.answers = ["cancel"]
    assert not window.close()
    window.answers = ["discard"]
    assert window.close()


def test_long_work_runs_in_a_thread_with_progress_and_cancel(window, qtbot):
    window.open_project(DEMO)
    doc = window.doc
    window.solve()
    assert doc.jobs.busy and window.progress.isVisibleTo(window)
    ticks = []
    timer = QtCore.QTimer()
    timer.timeout.connect(lambda: ticks.append(1))
    timer.start(5)
    qtbot.waitUntil(lambda: not doc.jobs.busy, timeout=SOLVE_WAIT_MS)
    timer.stop()
    assert len(ticks) > 3                                   # the event loop kept running
    assert window.undo_action.text() == "&Undo Solve constraints"
    assert not window.errors
    # cancel: the motion stays the one solved before (the "Solve" step is there to undo)
    motion = doc.motion
    window.solve()
    window.cancel_job()
    qtbot.waitUntil(lambda: not doc.jobs.busy, timeout=SOLVE_WAIT_MS)
    assert doc.motion is motion and not doc.pending
    assert window.statusBar().currentMessage() == "Cancelled"


def test_the_ik_correction_is_shown_while_its_keys_are_fitted(window, qtbot, monkeypatch):
    """Fitting the keys is most of a solve (the CMU jumps onto the CMU T-pose: 32 s of 34,
    the IK 1.2 s): the IK's dense correction is shown as soon as it has run, the bar turns
    busy, and the solved keys replace it when they land. (The fit is held here until the
    test has looked, so that nothing depends on how long it takes.)"""
    import threading
    from motion_composer.app.gui.main_window import FITTING_KEYS
    from motion_composer.engine import forward_kinematics
    from motion_composer.engine import scene as scene_module
    window.open_project(DEMO)
    doc = window.doc
    release, seen = threading.Event(), {}
    real = scene_module.solved_keys

    def held(direct, edited, constraints, correction, **kw):
        seen["dense"] = correction.motion
        release.wait(SOLVE_WAIT_MS / 1000)
        return real(direct, edited, constraints, correction, **kw)

    monkeypatch.setattr(scene_module, "solved_keys", held)
    keyed = doc.motion
    try:
        window.solve()
        qtbot.waitUntil(lambda: "dense" in seen and doc.motion is seen["dense"],
                        timeout=SOLVE_WAIT_MS)
        assert doc.jobs.busy and doc.pending
        assert window.progress.maximum() == 0 and window.progress.format() == "Fitting keys"
        assert window.statusBar().currentMessage() == FITTING_KEYS
        # a correction of the conversion, and not the keys shown before
        shown = doc.pose("target").positions
        assert not np.allclose(shown, doc.pose("composed").positions, atol=1e-3)
        assert not np.array_equal(shown, forward_kinematics(keyed).positions)
    finally:
        release.set()
    qtbot.waitUntil(lambda: not doc.jobs.busy, timeout=SOLVE_WAIT_MS)
    assert not window.errors and not doc.pending
    assert doc.motion is doc.scene.motion and doc.motion is not seen["dense"]
    assert doc.scene.displacement is not None
    assert window.statusBar().currentMessage() != FITTING_KEYS


def test_added_foot_contacts_are_on_the_timeline_while_they_are_solved(window, qtbot,
                                                                          monkeypatch):
    """Tools > Add Foot Contacts and Solve puts the contacts it finds on the timeline at
    once, while the IK and the key fit run (they used to appear when the keys landed); an
    edit meanwhile (the hand's constraint disabled) keeps them, the solve enforces those same
    contacts, and undo takes the edit, then them and the correction away. (The IK is held
    here until the test has looked.)"""
    import threading
    from motion_composer.engine import scene as scene_module
    window.open_project(DEMO)
    doc = window.doc
    timeline = window.timeline
    hand = tuple(c for c in doc.scene.constraints if not c.auto)
    doc.load_scene(doc.scene.replace(auto_contacts=False, constraints=hand))
    assert [r.constraint for r in timeline.rows] == list(hand)
    release, seen = threading.Event(), {}
    real = scene_module.enforce

    def held(edited, constraints, **kw):
        seen["enforced"] = list(constraints)
        release.wait(SOLVE_WAIT_MS / 1000)
        return real(edited, constraints, **kw)

    monkeypatch.setattr(scene_module, "enforce", held)
    before = doc.scene
    action = next(a for m in window.menuBar().actions() for a in m.menu().actions()
                  if a.text() == "Add &Foot Contacts and Solve")
    try:
        action.trigger()
        qtbot.waitUntil(lambda: "enforced" in seen, timeout=SOLVE_WAIT_MS)
        assert doc.jobs.busy and doc.pending
        shown = [r.constraint for r in timeline.rows]
        contacts = [c for c in shown if c.auto]
        assert len(contacts) >= 8 and {c.meta.get("source") for c in contacts} == {"contact"}
        assert shown[:len(hand)] == list(hand) and len(shown) == len(doc.scene.constraints)
        assert doc.scene.displacement is before.displacement       # not solved yet
        # the hand's constraint disabled meanwhile (the edit restarts the solve): the
        # contacts stay, and are what the new solve enforces
        timeline.select(0)
        timeline.toggle_selected()
        assert not doc.scene.constraints[0].enabled
        assert list(doc.scene.constraints[len(hand):]) == shown[len(hand):]
    finally:
        release.set()
    qtbot.waitUntil(lambda: not doc.jobs.busy and not doc.pending, timeout=SOLVE_WAIT_MS)
    assert not window.errors
    # what was shown is what was solved and what the scene keeps
    assert len(seen["enforced"]) == len(shown)
    assert all(a.same_as(b) for a, b in zip(seen["enforced"][len(hand):], shown[len(hand):]))
    assert all(a.same_as(b) for a, b in zip(doc.scene.constraints[len(hand):],
                                            shown[len(hand):]))
    assert not doc.scene.constraints[0].enabled
    assert doc.scene.displacement is not before.displacement
    window.undo_action.trigger()                       # the hand enabled again, contacts kept
    assert doc.scene.constraints[0].enabled and len(timeline.rows) == len(shown)
    window.undo_action.trigger()                       # the contacts gone
    assert [r.constraint for r in timeline.rows] == list(hand)
    assert doc.scene.displacement is before.displacement


def test_autosave_is_offered_at_the_next_start(window, qtbot, tmp_path):
    from motion_composer.app.gui.commands import push_pair
    from motion_composer.app.gui.main_window import MainWindow
    path = _demo_copy(tmp_path)
    window.open_project(path)
    push_pair(window.doc, "Head", None)
    window.autosave()
    second = MainWindow()
    qtbot.addWidget(second)
    second.ask_yes_no = lambda q: True
    second.show_error = window.errors.append
    assert second.offer_recovery(path)
    assert "Head" not in second.doc.scene.correspondence.pairs
    assert second.doc.modified
    second.doc.undo_stack.setClean()


def test_the_command_line_opens_the_window(monkeypatch):
    import motion_composer.app.cli
    import motion_composer.app.gui.main
    calls = []
    monkeypatch.setattr(motion_composer.app.gui.main, "run", lambda *a, **k: calls.append((a, k)) or 0)
    assert motion_composer.app.cli.main([]) == 0
    assert motion_composer.app.cli.main(["some.mcp"]) == 0
    assert motion_composer.app.cli.main(["--demo"]) == 0
    assert calls[0][0] == (None,) and calls[1][0] == ("some.mcp",)
    assert calls[2][1]["demo"] is True


def test_screenshot_of_the_demo(window, qtbot, tmp_path):
    """The window draws the demo (the README's picture is made the same way with
    ``motion-composer --demo --screenshot docs/screenshots/window-demo.png``)."""
    from gui_support import gl_available
    window.resize(1400, 900)
    window.show()
    with qtbot.waitExposed(window, timeout=WAIT_MS):
        pass
    window.open_project(DEMO)
    window.viewport.frame_all()
    qtbot.wait(200)
    image = window.grab()
    assert image.width() >= 1000
    assert image.save(str(tmp_path / "window.png"))
    if gl_available():
        # the viewport really drew: orange target bones in the picture
        from gui_support import count_colour, view_pixels
        assert count_colour(view_pixels(window.viewport), (242, 153, 64)) > 100
