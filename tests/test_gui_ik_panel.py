"""The IK solver settings in the window: typed exactly, one command per field, undoable,
re-solving the constraints, refused values shown and not applied."""
from __future__ import annotations


import pytest

pytest.importorskip("PySide6")

from motion_composer.app.gui.qt import QtCore  # noqa: E402
from motion_composer.app.gui.ik_panel import IKPanel  # noqa: E402
from motion_composer.engine.correction.constraints import Constraint  # noqa: E402
from motion_composer.engine.correction.ik import IKOptions  # noqa: E402
from gui_support import SOLVE_WAIT_MS, demo_document  # noqa: E402

ENTER = QtCore.Qt.Key.Key_Return


@pytest.fixture
def doc(qtbot):
    d = demo_document()
    yield d
    d.close()


@pytest.fixture
def panel(qtbot, doc):
    w = IKPanel(doc)
    qtbot.addWidget(w)
    w.show()
    qtbot.waitExposed(w)
    return w


def _type(qtbot, edit, text):
    edit.setFocus()
    edit.selectAll()
    qtbot.keyClicks(edit, text)
    qtbot.keyClick(edit, ENTER)


def test_the_panel_shows_the_projects_options_exactly(panel, doc):
    options = doc.scene.ik_options
    assert options == IKOptions()
    assert panel.edits["nullspace_damping"].text() == repr(options.nullspace_damping) == "1e-06"
    assert panel.edits["max_iterations"].text() == "60"


def test_a_typed_value_is_one_command_and_undo_puts_it_back(qtbot, panel, doc):
    count = doc.undo_stack.count()
    _type(qtbot, panel.edits["damping"], "0.02")
    assert doc.scene.ik_options.damping == 0.02
    assert doc.scene.ik_options.max_iterations == 60          # the others untouched
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.undoText() == "Set IK damping to 0.02"
    _type(qtbot, panel.edits["damping"], "0.03")               # the same field: merged
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.undoText() == "Set IK damping to 0.03"
    doc.undo_stack.undo()
    assert doc.scene.ik_options == IKOptions()
    assert panel.edits["damping"].text() == "0.005"


def test_a_refused_value_is_shown_and_not_applied(qtbot, panel, doc):
    count = doc.undo_stack.count()
    _type(qtbot, panel.edits["attraction"], "1.5")
    assert doc.scene.ik_options.attraction == 0.5 and doc.undo_stack.count() == count
    assert panel.message.isVisibleTo(panel) and "Attraction" in panel.message.text()
    _type(qtbot, panel.edits["attraction"], "0.25")
    assert doc.scene.ik_options.attraction == 0.25 and not panel.message.isVisibleTo(panel)


def test_changing_an_option_re_solves_the_constraints_with_it(qtbot, panel, doc):
    j = doc.scene.target.skeleton.index["LeftHand"]
    hand = doc.pose("target").positions[300, j]
    doc.edit("Add reach", solve=True, constraints=(
        Constraint("LeftHand", "position", {"point": hand + [0.05, 0.1, 0.0]},
                   280, 290, 310, 320, name="reach"),))
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)
    solved = doc.scene.displacement
    _type(qtbot, panel.edits["max_iterations"], "1")           # a cramped solver
    assert doc.pending or doc.scene.displacement is not solved
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)
    assert doc.scene.displacement is not solved
    expected = doc.scene.solve().scene.displacement
    for key, curve in expected.curves.items():
        assert (doc.scene.displacement.curves[key].values == curve.values).all()
