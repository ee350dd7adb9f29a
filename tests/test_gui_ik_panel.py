"""The IK dock: the solver's settings typed exactly, one command per field, undoable,
re-solving the constraints, refused values shown and not applied; and the floor above them,
switched on where the character stands, a typed height standing the character on it (the
conversion moved by the floor less its own), the stand switch, one undoable command each
that re-solves with the floor's planes. Driven with real mouse clicks and key presses on the
bundled CMU walk onto the bundled T-pose skeleton (its hips at 0, its feet 0.92 m lower)."""
from __future__ import annotations


import numpy as np
import pytest

pytest.importorskip("PySide6")

from motion_composer.app.gui.qt import QtCore  # noqa: E402
from motion_composer.app.gui.floor_panel import FloorPanel  # noqa: E402
from motion_composer.app.gui.ik_panel import IKPanel  # noqa: E402
from motion_composer.engine.correction.constraints import Constraint  # noqa: E402
from motion_composer.engine.correction.ik import IKOptions  # noqa: E402
from motion_composer.engine.kinematics import fk_arrays  # noqa: E402
from gui_support import SOLVE_WAIT_MS, demo_document  # noqa: E402

ENTER = QtCore.Qt.Key.Key_Return
LEFT = QtCore.Qt.MouseButton.LeftButton


@pytest.fixture
def doc(qtbot):
    d = demo_document()
    yield d
    d.close()


def _shown(qtbot, w):
    qtbot.addWidget(w)
    w.show()
    qtbot.waitExposed(w)
    return w


@pytest.fixture
def panel(qtbot, doc):
    return _shown(qtbot, IKPanel(doc))


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


# --------------------------------------------------------------------------- the floor
@pytest.fixture
def floor(qtbot, doc):
    return _shown(qtbot, FloorPanel(doc))


def _click(qtbot, box):
    qtbot.mouseClick(box, LEFT, pos=QtCore.QPoint(8, box.height() // 2))


def _floor_planes(doc):
    """The automatic floor planes: the contacts' (which stand on the project's floor) and the
    project's own on foot joints the contacts leave."""
    return [c for c in doc.scene.constraints if c.auto and c.kind == "plane"]


def test_a_floor_switched_on_starts_where_the_character_stands(qtbot, floor, doc):
    assert doc.scene.project.floor is None and not floor.enabled.isChecked()
    assert not floor.height.isEnabled()
    # independently: the child's lowest foot joint or End Site in its reference pose
    target = doc.scene.target
    pose = fk_arrays(target.skeleton, target.rotations, target.translations, end_sites=True)
    standing = doc.scene.standing_floor()
    assert standing <= min(pose.positions[..., 1].min(), pose.end_positions[..., 1].min()) \
        + 0.05
    count = doc.undo_stack.count()
    _click(qtbot, floor.enabled)
    assert doc.scene.project.floor == standing and doc.scene.lift() == 0.0
    assert doc.undo_stack.count() == count + 1
    assert floor.height.isEnabled() and floor.height.text() == repr(standing)
    assert floor.where.text() == f"The character stands at {standing:.3f} m."
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)
    assert _floor_planes(doc)                                   # made again, then solved
    doc.undo_stack.undo()
    assert doc.scene.project.floor is None and not floor.enabled.isChecked()


def test_a_typed_height_stands_the_character_on_it(qtbot, floor, doc):
    free = doc.scene.composed
    _click(qtbot, floor.enabled)
    standing = doc.scene.standing_floor()
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)
    unsolved = doc.scene.displacement
    _type(qtbot, floor.height, "0.5")
    scene = doc.scene
    assert scene.project.floor == 0.5 and scene.lift() == pytest.approx(0.5 - standing)
    np.testing.assert_array_equal(scene.composed.rotations, free.rotations)
    rise = scene.composed.translations[:, 0, 1] - free.translations[:, 0, 1]
    np.testing.assert_allclose(rise, 0.5 - standing, atol=1e-12)
    assert f"raised {(0.5 - standing) * 1000:.0f} mm onto the floor" in floor.where.text()
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
    _click(qtbot, floor.stand)
    assert not doc.scene.project.stand_on_floor and doc.scene.lift() == 0.0
    np.testing.assert_array_equal(doc.scene.composed.translations, free.translations)
    assert floor.where.text() == (
        f"The character stands at {standing:.3f} m. The conversion stays: the floor is "
        f"{(0.5 - standing) * 1000:.0f} mm above its feet, and its planes push them up.")
    doc.undo_stack.undo()
    assert doc.scene.project.stand_on_floor and floor.stand.isChecked()
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)


def test_a_goal_set_by_hand_moves_with_the_character_onto_the_floor(qtbot, floor, doc):
    """A hand goal set by hand rises with the character when a typed floor raises it, in
    the same undoable step; undo puts both back."""
    from motion_composer.app.gui.commands import push_constraints
    def hand():
        [c] = [c for c in doc.scene.project.constraints if not c.auto]
        return np.array(c.goal["point"])

    push_constraints(doc, [Constraint("LeftHand", "position", {"point": [0.3, -0.1, 0.2]},
                                      280, 290, 310, 320)])
    before = hand()
    _click(qtbot, floor.enabled)
    np.testing.assert_array_equal(hand(), before)              # switched on: nothing moves
    standing = doc.scene.standing_floor()
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)
    count = doc.undo_stack.count()
    _type(qtbot, floor.height, "0.5")
    assert doc.undo_stack.count() == count + 1
    np.testing.assert_allclose(hand(), before + [0.0, 0.5 - standing, 0.0], atol=1e-12)
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)
    # typing on merges into that step, and typing the height it started from drops it
    _type(qtbot, floor.height, "0.7")
    assert doc.undo_stack.count() == count + 1
    np.testing.assert_allclose(hand(), before + [0.0, 0.7 - standing, 0.0], atol=1e-12)
    _type(qtbot, floor.height, repr(standing))
    assert doc.undo_stack.count() == count
    np.testing.assert_allclose(hand(), before, atol=1e-12)
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)
    _type(qtbot, floor.height, "0.5")
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)
    doc.undo_stack.undo()
    assert doc.scene.project.floor == standing
    np.testing.assert_allclose(hand(), before, atol=1e-12)
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)


def test_a_height_that_is_not_a_number_is_refused(qtbot, floor, doc):
    _click(qtbot, floor.enabled)
    before, count = doc.scene.project.floor, doc.undo_stack.count()
    for text in ("low", "nan", "1e400"):
        _type(qtbot, floor.height, text)
        assert doc.scene.project.floor == before and doc.undo_stack.count() == count
        assert floor.message.isVisibleTo(floor) and "Floor height" in floor.message.text()
    _type(qtbot, floor.height, "0.25")
    assert doc.scene.project.floor == 0.25 and not floor.message.isVisibleTo(floor)
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)
    _type(qtbot, floor.height, "low")                 # refused, then the step undone
    assert floor.message.isVisibleTo(floor)
    doc.undo_stack.undo()
    assert doc.scene.project.floor == before and not floor.message.isVisibleTo(floor)
    assert floor.height.text() == repr(before)


def test_the_absolute_root_mode_keeps_the_character_where_the_performer_is(qtbot, floor, doc):
    from motion_composer.engine.conversion.converter import RootOptions
    doc.edit("Absolute root", root=RootOptions(mode="absolute"))
    _click(qtbot, floor.enabled)
    _type(qtbot, floor.height, "0.5")
    assert doc.scene.project.floor == 0.5 and doc.scene.lift() == 0.0
    assert not floor.stand.isEnabled()                # it would change nothing
    standing = doc.scene.standing_floor()
    assert floor.where.text().endswith(
        f"The absolute root mode places the root where the performer's is: the floor is "
        f"{(0.5 - standing) * 1000:.0f} mm above its feet, and its planes push them up.")
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)
