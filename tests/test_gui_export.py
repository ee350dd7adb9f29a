"""File > Export's options dialog: frame range, frame rate, rotation-only BVH channels.

The real modal dialog is driven as a user would: File > Export asks for a path, the options
dialog opens, its fields are typed into and OK (or Cancel) is clicked. The clip is the bundled
CMU 131_01 walk (120 fps, 994 frames) onto the bundled CMU rest pose.
"""
from __future__ import annotations

import numpy as np
import pytest

from motion_composer.app.gui.export_dialog import ExportOptions, ExportOptionsDialog
from motion_composer.app.gui.qt import QtCore, QtWidgets
from gui_support import quiet_window
from conftest import clip_path
from motion_composer.engine.formats import read_motion
from motion_composer.engine.kinematics import forward_kinematics

WALK = clip_path("cmu_131_01_walk.bvh")
TPOSE = clip_path("cmu_rest_tpose.bvh")


@pytest.fixture()
def window(qtbot, tmp_path, monkeypatch):
    w = quiet_window(qtbot, tmp_path, monkeypatch)
    assert w.import_file("performer", WALK) and w.import_file("target", TPOSE), w.errors
    return w


def _type(qtbot, field: QtWidgets.QAbstractSpinBox, text: str) -> None:
    field.selectAll()
    qtbot.keyClicks(field, text)
    field.interpretText()


def _drive_dialog(qtbot, fill, button):
    """When the modal options dialog opens: ``fill(dialog)``, then click ``button``."""
    seen = []

    def act():
        dialog = QtWidgets.QApplication.activeModalWidget()
        assert isinstance(dialog, ExportOptionsDialog)
        seen.append(dialog)
        fill(dialog)
        qtbot.mouseClick(dialog.buttons.button(button), QtCore.Qt.MouseButton.LeftButton)
    QtCore.QTimer.singleShot(0, act)
    return seen


def test_file_export_writes_the_range_at_the_rate_with_rotation_channels(window, qtbot,
                                                                         tmp_path):
    out = tmp_path / "part.bvh"
    window.ask_save_path = lambda caption, filters: str(out)

    def fill(dialog):
        assert (dialog.first.value(), dialog.last.value(), dialog.fps.value()) == (0, 993, 120.0)
        _type(qtbot, dialog.first, "100")
        _type(qtbot, dialog.last, "499")
        _type(qtbot, dialog.fps, "30")
        qtbot.mouseClick(dialog.rotation_only, QtCore.Qt.MouseButton.LeftButton)
    seen = _drive_dialog(qtbot, fill, QtWidgets.QDialogButtonBox.StandardButton.Ok)
    window.export_dialog()
    assert seen and not window.errors
    written = read_motion(out)
    assert written.num_frames == 100 and written.frame_time == pytest.approx(1 / 30)
    assert all(len(c) == 3 for c in written.skeleton.channels[1:])
    expected = forward_kinematics(window.doc.motion.frames(slice(100, 500, 4))).positions
    np.testing.assert_allclose(forward_kinematics(written).positions, expected, rtol=0,
                               atol=1e-5)


def test_the_options_left_alone_write_the_whole_clip_as_before(window, qtbot, tmp_path):
    out, reference = tmp_path / "all.bvh", tmp_path / "reference.bvh"
    window.ask_save_path = lambda caption, filters: str(out)
    _drive_dialog(qtbot, lambda dialog: None, QtWidgets.QDialogButtonBox.StandardButton.Ok)
    window.export_dialog()
    assert window.export_motion(reference), window.errors
    assert out.read_bytes() == reference.read_bytes()
    assert read_motion(out).num_frames == 994


def test_cancelling_the_options_writes_nothing(window, qtbot, tmp_path):
    out = tmp_path / "never.bvh"
    window.ask_save_path = lambda caption, filters: str(out)
    seen = _drive_dialog(qtbot, lambda dialog: None,
                         QtWidgets.QDialogButtonBox.StandardButton.Cancel)
    window.export_dialog()
    assert seen and not out.exists() and not window.errors


def test_a_first_frame_after_the_last_is_refused_in_one_message(window, tmp_path):
    out = tmp_path / "bad.bvh"
    assert not window.export_motion(out, ExportOptions(frames=(600, 500)))
    assert "outside the clip" in window.errors[-1] and not out.exists()
