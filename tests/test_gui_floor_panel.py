"""The floor in the window: switched on where the character stands, a typed height stands the
character on it (the conversion moved by the floor less its own), the stand switch, one
undoable command each that re-solves with the floor's planes, refused heights not applied.
Driven with real mouse clicks and key presses on the demo (the CMU walk onto the FAIR
child)."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("PySide6")

from motion_composer.app.gui.qt import QtCore  # noqa: E402
from motion_composer.app.gui.floor_panel import FloorPanel  # noqa: E402
from motion_composer.engine.kinematics import fk_arrays  # noqa: E402
from gui_support import SOLVE_WAIT_MS, demo_document  # noqa: E402

LEFT = QtCore.Qt.MouseButton.LeftButton
ENTER = QtCore.Qt.Key.Key_Return


@pytest.fixture
def doc(qtbot):
    d = demo_document()
    yield d
    d.close()


@pytest.fixture
def panel(qtbot, doc):
    w = FloorPanel(doc)
    qtbot.addWidget(w)
    w.show()
    qtbot.waitExposed(w)
    return w


def _click(qtbot, box):
    qtbot.mouseClick(box, LEFT, pos=QtCore.QPoint(8, box.height() // 2))


def _type(qtbot, edit, text):
    edit.setFocus()
    edit.selectAll()
    qtbot.keyClicks(edit, text)
    qtbot.keyClick(edit, ENTER)


def _floor_planes(doc):
    """The automatic floor planes: the contacts' (which stand on the project's floor) and the
    project's own on foot joints the contacts leave."""
    return [c for c in doc.scene.constraints if c.auto and c.kind == "plane"]


def test_a_floor_switched_on_starts_where_the_character_stands(qtbot, panel, doc):
    assert doc.scene.project.floor is None and not panel.enabled.isChecked()
    assert not panel.height.isEnabled()
    # independently: the child's lowest foot joint or End Site in its reference pose
    target = doc.scene.target
    pose = fk_arrays(target.skeleton, target.rotations, target.translations, end_sites=True)
    standing = doc.scene.standing_floor()
    assert standing <= min(pose.positions[..., 1].min(), pose.end_positions[..., 1].min()) \
        + 0.05
    count = doc.undo_stack.count()
    _click(qtbot, panel.enabled)
    assert doc.scene.project.floor == standing and doc.scene.lift() == 0.0
    assert doc.undo_stack.count() == count + 1
    assert panel.height.isEnabled() and panel.height.text() == repr(standing)
    assert panel.where.text() == f"The character stands at {standing:.3f} m."
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)
    assert _floor_planes(doc)                                   # made again, then solved
    doc.undo_stack.undo()
    assert doc.scene.project.floor is None and not panel.enabled.isChecked()


def test_a_typed_height_stands_the_character_on_it(qtbot, panel, doc):
    free = doc.scene.composed
    _click(qtbot, panel.enabled)
    standing = doc.scene.standing_floor()
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)
    unsolved = doc.scene.displacement
    _type(qtbot, panel.height, "0.5")
    scene = doc.scene
    assert scene.project.floor == 0.5 and scene.lift() == pytest.approx(0.5 - standing)
    np.testing.assert_array_equal(scene.composed.rotations, free.rotations)
    rise = scene.composed.translations[:, 0, 1] - free.translations[:, 0, 1]
    np.testing.assert_allclose(rise, 0.5 - standing, atol=1e-12)
    assert f"raised {(0.5 - standing) * 1000:.0f} mm onto the floor" in panel.where.text()
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)
    assert doc.scene.displacement is not unsolved                # the solve landed
    # every floor plane stands on 0.5, and the solved feet stay on or above it
    planes = _floor_planes(doc)
    assert planes and all(c.goal["point"][1] >= 0.5 for c in planes)
    motion = doc.scene.motion
    pose = fk_arrays(motion.skeleton, motion.rotations, motion.translations)
    for c in planes:
        y = pose.positions[:, motion.skeleton.index[c.joint], 1]
        assert y.min() > c.goal["point"][1] - 1e-3, c.joint
    # the stand switch: off, the conversion is back where it was and the floor is a plane
    _click(qtbot, panel.stand)
    assert not doc.scene.project.stand_on_floor and doc.scene.lift() == 0.0
    np.testing.assert_array_equal(doc.scene.composed.translations, free.translations)
    assert "raised" not in panel.where.text()
    doc.undo_stack.undo()
    assert doc.scene.project.stand_on_floor and panel.stand.isChecked()
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)


def test_a_height_that_is_not_a_number_is_refused(qtbot, panel, doc):
    _click(qtbot, panel.enabled)
    floor, count = doc.scene.project.floor, doc.undo_stack.count()
    for text in ("low", "nan", "1e400"):
        _type(qtbot, panel.height, text)
        assert doc.scene.project.floor == floor and doc.undo_stack.count() == count
        assert panel.message.isVisibleTo(panel) and "Floor height" in panel.message.text()
    _type(qtbot, panel.height, "0.25")
    assert doc.scene.project.floor == 0.25 and not panel.message.isVisibleTo(panel)
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)
