"""The binding panel and the playback bar, built from a document of real clips.

Binding: the document's options show in the widgets (model -> widget), the widgets change the
options and the evaluated motion (widget -> model), undo/redo restores both and names the
change, spin-box edits merge into one step. Playback: real-time play, loop, stop at the end,
speed, shortcuts, the time label. No OpenGL: these run under Xvfb and offscreen alike.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from motion_composer.app.gui.qt import QtCore, QtWidgets  # noqa: E402
from motion_composer.app.gui.binding_panel import BindingPanel  # noqa: E402
from motion_composer.app.gui.commands import (push_correspondence, push_options,  # noqa: E402
                                              push_sources)
from motion_composer.app.gui.document import Document  # noqa: E402
from motion_composer.app.gui.playback import PlaybackBar  # noqa: E402
from motion_composer.engine import read_bvh  # noqa: E402
from motion_composer.engine.conversion.correspondence import Correspondence  # noqa: E402
from motion_composer.engine.conversion import BindOptions  # noqa: E402
from motion_composer.engine.conversion import RootOptions  # noqa: E402
from motion_composer.engine.rotations import angle_between  # noqa: E402

from conftest import clip_path  # noqa: E402
from gui_support import WAIT_MS, shown  # noqa: E402
from ik_fixtures import MAX_TO_HOLDEN  # noqa: E402

Qt = QtCore.Qt


@pytest.fixture(scope="module")
def clips():
    return (read_bvh(clip_path("cmu_131_01_walk.bvh")),
            read_bvh(clip_path("cmu_rest_tpose.bvh")))


@pytest.fixture
def doc(qtbot, clips):
    performer, target = clips
    d = Document()
    push_sources(d, performer=performer, performer_path=clip_path("cmu_131_01_walk.bvh"),
                 target=target, target_path=clip_path("cmu_rest_tpose.bvh"))
    push_correspondence(d, Correspondence(MAX_TO_HOLDEN), "Map CMU to Holden")
    assert d.scene.ready, d.scene.evaluation_error
    d.undo_stack.setClean()
    yield d
    d.close()


@pytest.fixture
def panel(qtbot, doc):
    return shown(qtbot, BindingPanel(doc), 440)


@pytest.fixture
def bar(qtbot, doc):
    w = shown(qtbot, PlaybackBar(doc), 900)
    yield w
    w.pause()


def _root_xz(doc):
    return doc.motion.translations[:, 0, [0, 2]]


# ====================================================================== binding: model -> widget
def test_panel_shows_defaults_notes_and_ratio(panel, doc):
    assert panel.performer_reference.combo.currentData() == "auto"
    assert not panel.performer_reference.frame.isEnabled()
    assert panel.performer_reference.frame.maximum() == doc.scene.performer.num_frames - 1
    assert panel.target_reference.frame.maximum() == doc.scene.target.num_frames - 1 == 0
    assert panel.align_on.isChecked() and not panel.align_off.isChecked()
    assert panel.distribute.currentData() == "even"
    assert panel.root_mode.currentData() == "scaled"
    assert panel.auto_scale.isChecked()
    assert not panel.scale_h.isEnabled() and not panel.scale_v.isEnabled()
    ratio = doc.scene.binding.hip_height_ratio
    assert panel.ratio_label.text() == f"ratio {ratio:.3f}"
    assert panel.scale_h.value() == pytest.approx(ratio, abs=1e-3)
    # notes name the references used
    for key, value in doc.scene.binding.notes.items():
        assert str(value) in panel.notes.text()
    assert "rest pose" in panel.notes.text()


def test_model_changes_show_in_panel(panel, doc):
    push_options(doc, bind_options=BindOptions(performer_reference=12, rest_alignment=False,
                                               distribute="first"),
                 root_options=RootOptions(mode="in-place", scale=(1.25, 0.75)), text="x")
    assert panel.performer_reference.combo.currentData() == "frame"
    assert panel.performer_reference.frame.value() == 12
    assert panel.performer_reference.frame.isEnabled()
    assert panel.align_off.isChecked() and not panel.align_on.isChecked()
    assert panel.distribute.currentData() == "first"
    assert panel.root_mode.currentData() == "in-place"
    assert not panel.auto_scale.isChecked()
    assert panel.scale_h.value() == pytest.approx(1.25)
    assert panel.scale_v.value() == pytest.approx(0.75)
    assert not panel.scale_h.isEnabled()        # in place: no horizontal displacement
    assert panel.scale_v.isEnabled()
    assert "frame 12" in panel.notes.text()
    # showing the model pushed nothing
    assert doc.undo_stack.count() == 3

    push_options(doc, root_options=RootOptions(mode="absolute"), text="y")
    assert panel.root_mode.currentData() == "absolute"
    assert not panel.auto_scale.isEnabled() and not panel.scale_v.isEnabled()
    assert doc.undo_stack.count() == 4


def test_flat_feet_turns_only_the_feet_and_undoes(qtbot, panel, doc):
    sk = doc.scene.target.skeleton
    feet = [sk.index[n] for n in ("LeftFoot", "RightFoot")]
    before = doc.motion.rotations.copy()
    assert not panel.flat_feet.isChecked() and panel.flat_feet.isEnabled()
    count = doc.undo_stack.count()
    qtbot.mouseClick(panel.flat_feet, Qt.MouseButton.LeftButton)
    assert doc.scene.bind_options.flat_feet is True and panel.flat_feet.isChecked()
    assert doc.undo_stack.undoText() == "Turn flat feet on"
    # the walk's feet turn by how its flat feet differ from the T-pose's (a few degrees)
    turn = np.degrees(angle_between(doc.motion.rotations[:, feet], before[:, feet]))
    assert 0.5 < turn.max() < 10.0
    doc.undo_stack.undo()
    assert doc.scene.bind_options.flat_feet is False and not panel.flat_feet.isChecked()
    np.testing.assert_allclose(doc.motion.rotations, before, atol=1e-12)
    assert doc.undo_stack.count() == count + 1
    # with the target's own posture kept there is no rest posture to stand them in
    qtbot.mouseClick(panel.align_off, Qt.MouseButton.LeftButton)
    assert not panel.flat_feet.isEnabled()
    doc.undo_stack.undo()
    assert panel.flat_feet.isEnabled()


def test_evaluation_error_shows_in_notes(panel, doc):
    # the target has one frame: frame 5 cannot be its reference
    push_options(doc, bind_options=BindOptions(target_reference=5), text="bad")
    assert doc.scene.binding is None and doc.scene.evaluation_error
    assert "outside the clip" in panel.notes.text()
    assert panel.ratio_label.text() == "ratio -"


# ====================================================================== binding: widget -> model
def test_rest_alignment_off_changes_first_frame_and_undoes(qtbot, panel, doc):
    before = doc.motion.rotations[0].copy()
    qtbot.mouseClick(panel.align_off, Qt.MouseButton.LeftButton)
    assert doc.scene.bind_options.rest_alignment is False
    assert not np.allclose(doc.motion.rotations[0], before, atol=1e-6)
    assert doc.undo_stack.count() == 3
    assert doc.undo_stack.undoText() == "Turn rest alignment off"

    doc.undo_stack.undo()
    assert doc.scene.bind_options.rest_alignment is True
    assert panel.align_on.isChecked()
    np.testing.assert_allclose(doc.motion.rotations[0], before, atol=1e-12)
    assert doc.undo_stack.redoText() == "Turn rest alignment off"

    doc.undo_stack.redo()
    assert doc.scene.bind_options.rest_alignment is False and panel.align_off.isChecked()
    qtbot.mouseClick(panel.align_on, Qt.MouseButton.LeftButton)
    assert doc.undo_stack.undoText() == "Turn rest alignment on"
    assert doc.undo_stack.count() == 4


def test_root_in_place_keeps_hips_horizontal(qtbot, panel, doc):
    assert np.ptp(_root_xz(doc), axis=0).max() > 1.0        # the walk travels metres
    panel.root_mode.setCurrentIndex(panel.root_mode.findData("in-place"))
    assert doc.scene.root.mode == "in-place"
    assert np.ptp(_root_xz(doc), axis=0).max() < 1e-9
    assert doc.undo_stack.undoText() == "Keep the root in place"
    assert not panel.scale_h.isEnabled()
    doc.undo_stack.undo()
    assert panel.root_mode.currentData() == "scaled"
    assert np.ptp(_root_xz(doc), axis=0).max() > 1.0


def test_reference_frame_choice(qtbot, panel, doc):
    chooser = panel.performer_reference
    chooser.combo.setCurrentIndex(chooser.combo.findData("frame"))
    assert doc.scene.bind_options.performer_reference == 0
    assert doc.undo_stack.undoText() == "Set performer reference pose to frame 0"
    # spin edits merge into one step named after the last value
    n = doc.undo_stack.count()
    for f in (10, 11, 12):
        chooser.frame.setValue(f)
    assert doc.scene.bind_options.performer_reference == 12
    assert doc.undo_stack.count() == n + 1
    assert doc.undo_stack.undoText() == "Set performer reference pose to frame 12"
    assert "frame 12" in panel.notes.text()
    assert doc.scene.binding.notes["performer reference"] == "frame 12"
    doc.undo_stack.undo()
    assert doc.scene.bind_options.performer_reference == 0
    assert chooser.frame.value() == 0 and chooser.combo.currentData() == "frame"
    doc.undo_stack.undo()
    assert doc.scene.bind_options.performer_reference == "auto"
    assert chooser.combo.currentData() == "auto" and not chooser.frame.isEnabled()
    # the spin box is limited to the clip
    chooser.combo.setCurrentIndex(chooser.combo.findData("frame"))
    chooser.frame.setValue(10 ** 6)
    assert doc.scene.bind_options.performer_reference == doc.scene.performer.num_frames - 1
    chooser.combo.setCurrentIndex(chooser.combo.findData("rest"))
    assert doc.undo_stack.undoText() == "Set performer reference pose to rest pose"
    assert doc.scene.bind_options.performer_reference == "rest"


def test_distribution_and_target_reference(panel, doc):
    panel.distribute.setCurrentIndex(panel.distribute.findData("first"))
    assert doc.scene.bind_options.distribute == "first"
    assert doc.undo_stack.undoText() == "Turn only each chain's first joint"
    t = panel.target_reference
    t.combo.setCurrentIndex(t.combo.findData("frame"))
    assert doc.scene.bind_options.target_reference == 0
    assert doc.scene.binding.notes["target reference"] == "frame 0"
    assert doc.undo_stack.undoText() == "Set target reference pose to frame 0"


def test_root_scale_by_hand_merges_and_scales(qtbot, panel, doc):
    ratio = doc.scene.binding.hip_height_ratio
    travel = np.ptp(_root_xz(doc)[:, 1])
    qtbot.mouseClick(panel.auto_scale, Qt.MouseButton.LeftButton)     # uncheck
    assert doc.scene.root.scale == pytest.approx((ratio, ratio))
    assert doc.undo_stack.undoText() == "Set the root scale by hand"
    assert panel.scale_h.isEnabled() and panel.scale_v.isEnabled()
    n = doc.undo_stack.count()
    for v in (1.0, 1.5, 2.0):
        panel.scale_h.setValue(v * ratio)
    panel.scale_v.setValue(0.5)
    # four spin-box changes (both root scales) are one undo step named after the last
    assert doc.undo_stack.count() == n + 1
    assert doc.scene.root.scale == pytest.approx((2.0 * ratio, 0.5), abs=1e-3)
    assert doc.undo_stack.undoText().startswith("Set root scale to")
    assert "0.500 (vertical)" in doc.undo_stack.undoText()
    # the horizontal travel doubled (the hips' own sway is not scaled)
    assert np.ptp(_root_xz(doc)[:, 1]) == pytest.approx(2.0 * travel, rel=0.02)
    doc.undo_stack.undo()
    assert doc.scene.root.scale == pytest.approx((ratio, ratio))
    assert panel.scale_h.value() == pytest.approx(ratio, abs=1e-3)
    assert np.ptp(_root_xz(doc)[:, 1]) == pytest.approx(travel, rel=1e-9)
    doc.undo_stack.redo()
    assert panel.scale_v.value() == pytest.approx(0.5)
    # another edit after something else was pushed is a step of its own
    panel.align_off.click()
    n = doc.undo_stack.count()
    panel.scale_v.setValue(0.6)
    assert doc.undo_stack.count() == n + 1
    qtbot.mouseClick(panel.auto_scale, Qt.MouseButton.LeftButton)     # check again
    assert doc.scene.root.scale is None
    assert doc.undo_stack.undoText() == "Scale the root by hip heights"
    assert not panel.scale_h.isEnabled()


def test_spin_runs_do_not_merge_across_spin_boxes(panel, doc):
    panel.performer_reference.combo.setCurrentIndex(2)
    panel.auto_scale.setChecked(False)
    n = doc.undo_stack.count()
    panel.performer_reference.frame.setValue(30)
    panel.performer_reference.frame.setValue(31)
    panel.scale_v.setValue(1.1)
    assert doc.undo_stack.count() == n + 2
    doc.undo_stack.undo()
    # undoing the scale leaves the reference frame
    assert doc.scene.bind_options.performer_reference == 31
    assert doc.scene.root.scale[1] != pytest.approx(1.1)


def test_new_sources_update_frame_limits(panel, doc):
    short = doc.scene.performer.frames(slice(0, 50))
    push_sources(doc, performer=short, performer_path=Path("short.bvh"), text="Short")
    assert panel.performer_reference.frame.maximum() == 49
    doc.undo_stack.undo()
    assert panel.performer_reference.frame.maximum() == doc.scene.performer.num_frames - 1


def test_binding_panel_screenshot(qtbot, panel, doc, tmp_path):
    push_options(doc, bind_options=BindOptions(performer_reference=12),
                 root_options=RootOptions(scale=(1.1, 0.95)), text="shot")
    qtbot.wait(20)
    assert panel.grab().save(str(tmp_path / "binding_panel.png"))


# ====================================================================== playback
def _fps(doc):
    return 1.0 / doc.scene.performer.frame_time


def _play_for(qtbot, bar, ms, at_least=5):
    """Play for ``ms`` and until ``at_least`` frames have gone by (a loaded machine may tick
    late); returns the frames advanced and the seconds that took."""
    start_frame = bar.doc.scene.viewer.current_frame
    t0 = time.perf_counter()
    bar.play()
    qtbot.wait(ms)
    qtbot.waitUntil(lambda: bar.doc.scene.viewer.current_frame - start_frame >= at_least,
                    timeout=WAIT_MS)
    frame = bar.doc.scene.viewer.current_frame
    elapsed = time.perf_counter() - t0
    bar.pause()
    return frame - start_frame, elapsed


def test_plays_in_real_time(qtbot, bar, doc):
    assert bar.slider.maximum() == bar.spin.maximum() == doc.scene.num_frames - 1
    assert not bar.playing
    advanced, elapsed = _play_for(qtbot, bar, 300)
    assert advanced >= 5
    assert advanced <= elapsed * _fps(doc) * 1.5 + 2
    assert not bar.playing
    # the widgets followed
    f = doc.scene.viewer.current_frame
    assert bar.slider.value() == bar.spin.value() == f
    # frame changes are not edits
    assert doc.undo_stack.count() == 2 and not doc.modified


def test_double_speed_is_faster(qtbot, bar, doc):
    a1, e1 = _play_for(qtbot, bar, 300)
    bar.set_speed(2.0)
    assert bar.speed_combo.currentText() == "2x"
    a2, e2 = _play_for(qtbot, bar, 300)
    assert a2 / e2 > 1.4 * (a1 / e1)
    assert a2 <= e2 * 2 * _fps(doc) * 1.5 + 2


def test_play_button_toggles(qtbot, bar):
    qtbot.mouseClick(bar.play_button, Qt.MouseButton.LeftButton)
    assert bar.playing and "Pause" in bar.play_button.toolTip()
    qtbot.mouseClick(bar.play_button, Qt.MouseButton.LeftButton)
    assert not bar.playing and "Play" in bar.play_button.toolTip()


def test_loop_wraps_within_play_range(qtbot, bar, doc):
    doc.set_viewer(play_range=(10, 20))
    doc.set_frame(18)
    seen = []
    doc.frameChanged.connect(seen.append)
    bar.set_loop(True)
    bar.play()
    qtbot.waitUntil(lambda: any(b < a for a, b in zip(seen, seen[1:])), timeout=WAIT_MS)
    assert bar.playing
    bar.pause()
    assert seen and all(10 <= f <= 20 for f in seen)
    assert any(b < a for a, b in zip(seen, seen[1:])), seen       # wrapped


def test_loop_whole_clip_wraps(qtbot, bar, doc):
    doc.set_frame(doc.scene.num_frames - 3)
    bar.set_loop(True)
    bar.play()
    qtbot.waitUntil(lambda: doc.scene.viewer.current_frame < 50, timeout=WAIT_MS)
    assert bar.playing


def test_stops_at_end_without_loop(qtbot, bar, doc):
    bar.set_loop(False)
    doc.set_frame(doc.scene.num_frames - 5)
    bar.play()
    qtbot.waitUntil(lambda: not bar.playing, timeout=WAIT_MS)
    assert doc.scene.viewer.current_frame == doc.scene.num_frames - 1
    # play at the end starts again from the start
    bar.play()
    assert doc.scene.viewer.current_frame < 10
    bar.pause()
    # a play range ends playing at its last frame
    doc.set_viewer(play_range=(10, 20))
    doc.set_frame(15)
    bar.play()
    qtbot.waitUntil(lambda: not bar.playing, timeout=WAIT_MS)
    assert doc.scene.viewer.current_frame == 20


def test_widgets_and_external_frame_changes(qtbot, bar, doc):
    bar.spin.setValue(120)
    assert doc.scene.viewer.current_frame == 120
    assert bar.slider.value() == 120
    assert bar.label.text().split()[0] == "120"
    assert "1.000 s" in bar.label.text()              # 120 x 0.0083333 s
    bar.slider.setValue(240)
    assert doc.scene.viewer.current_frame == 240 and bar.spin.value() == 240
    doc.set_frame(600)                                  # from elsewhere (the timeline)
    assert bar.spin.value() == bar.slider.value() == 600
    expected = f"{600 * doc.scene.performer.frame_time:.3f} s"
    assert expected in bar.label.text()
    # while playing, a jump elsewhere plays on from there
    t0 = time.perf_counter()
    bar.play()
    doc.set_frame(300)
    qtbot.wait(100)
    elapsed = time.perf_counter() - t0
    assert 300 <= doc.scene.viewer.current_frame < 300 + (elapsed + 0.4) * _fps(doc)
    bar.pause()


def test_shortcuts_on_host_window(qtbot, doc):
    host = QtWidgets.QWidget()
    qtbot.addWidget(host)
    bar = PlaybackBar(doc, host)
    layout = QtWidgets.QVBoxLayout(host)
    layout.addWidget(bar)
    shortcuts = bar.install_shortcuts(host)
    assert len(shortcuts) >= 5
    host.show()
    qtbot.waitExposed(host, timeout=WAIT_MS)
    host.windowHandle().requestActivate()        # WindowShortcut needs the active window
    qtbot.waitUntil(host.isActiveWindow, timeout=WAIT_MS)
    host.setFocus()
    doc.set_frame(100)
    key = qtbot.keyClick
    key(host, Qt.Key.Key_Right)
    assert doc.scene.viewer.current_frame == 101
    key(host, Qt.Key.Key_Left)
    key(host, Qt.Key.Key_Left)
    assert doc.scene.viewer.current_frame == 99
    key(host, Qt.Key.Key_Right, Qt.KeyboardModifier.ShiftModifier)
    assert doc.scene.viewer.current_frame == 109
    key(host, Qt.Key.Key_End)
    assert doc.scene.viewer.current_frame == doc.scene.num_frames - 1
    key(host, Qt.Key.Key_Home)
    assert doc.scene.viewer.current_frame == 0
    key(host, Qt.Key.Key_Space)
    assert bar.playing
    qtbot.waitUntil(lambda: doc.scene.viewer.current_frame > 0, timeout=WAIT_MS)
    key(host, Qt.Key.Key_Space)
    assert not bar.playing
    assert doc.scene.viewer.current_frame > 0
    # a step while playing stops playing
    bar.play()
    key(host, Qt.Key.Key_Right)
    assert not bar.playing
    # Home/End go to the play range first, then the clip
    doc.set_viewer(play_range=(50, 80))
    key(host, Qt.Key.Key_Home)
    assert doc.scene.viewer.current_frame == 50
    key(host, Qt.Key.Key_Home)
    assert doc.scene.viewer.current_frame == 0
    key(host, Qt.Key.Key_End)
    assert doc.scene.viewer.current_frame == 80
    bar.pause()


def test_empty_document(qtbot):
    d = Document()
    bar = PlaybackBar(d)
    qtbot.addWidget(bar)
    panel = BindingPanel(d)
    qtbot.addWidget(panel)
    bar.play()
    assert not bar.playing and not bar.play_button.isEnabled()
    assert bar.label.text() == "no clip"
    assert "Load a performer" in panel.notes.text()


def test_playback_screenshot(qtbot, bar, doc, tmp_path):
    doc.set_frame(120)
    qtbot.wait(20)
    assert bar.grab().save(str(tmp_path / "playback.png"))
