"""The constraint timeline, the inspector and the live re-solve, on the bundled walk.

The document is the bundled CMU walk on the bundled T-pose skeleton with its ankle-pin foot
contacts (as ``engine.correction.contacts`` built them before the foot model, recorded in
``data/contact_constraints_before.json``; solved) and a manual hand constraint, all set through
``push_constraints``. Handles are dragged with real mouse events on the plot's viewport
(frames mapped to pixels through the ViewBox): the handle moves and clamps, the motion is
previewed during the drag with no undo step, release pushes one named command, undo restores,
a right click cancels. The playhead follows the document both ways; a click selects a row;
add, delete, duplicate; the inspector's edits are undoable. pyqtgraph 2D only: this runs
under Xvfb and offscreen alike.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")
pytest.importorskip("pyqtgraph")

from motion_composer.app.gui.qt import QtCore, QtGui  # noqa: E402
from motion_composer.app.gui.commands import push_constraints  # noqa: E402
from motion_composer.app.gui.inspector import ConstraintInspector  # noqa: E402
from motion_composer.app.gui.live import live_solver  # noqa: E402
from motion_composer.app.gui.timeline import FIELDS, ConstraintTimeline, moved_range  # noqa: E402
from motion_composer.engine.correction.preview import (affected_frames, changed_window,  # noqa: E402
                                       overlapping, retimed, window_problem)
from motion_composer.engine.correction.constraints import Constraint  # noqa: E402
from motion_composer.engine.correction.enforcement import enforce  # noqa: E402
from motion_composer.engine.kinematics import forward_kinematics  # noqa: E402

from gui_support import SOLVE_WAIT_MS, WAIT_MS, demo_document, shown  # noqa: E402

Qt = QtCore.Qt
LEFT, RIGHT = Qt.MouseButton.LeftButton, Qt.MouseButton.RightButton
HAND = "reach LeftHand"


# ====================================================================== fixtures
def _contacts(doc) -> list:
    """The walk's automatic contacts of the ankle-pin model: a realistic, fixed list of ranges
    (the timeline's tests name its rows and ranges)."""
    recorded = json.loads((Path(__file__).parent / "data" / "contact_constraints_before.json")
                          .read_text(encoding="utf-8"))["walk_on_holden"]["constraints"]
    return [Constraint.from_dict({**c, "auto": True, "meta": {"source": "contact"}})
            for c in recorded]


def _hand(doc) -> Constraint:
    """A manual position constraint: the left hand 12 cm above where it is at frame 330."""
    pose = forward_kinematics(doc.scene.composed)
    j = doc.scene.composed.skeleton.index["LeftHand"]
    return Constraint(joint="LeftHand", kind="position",
                      goal={"point": pose.positions[330, j] + [0.0, 0.12, 0.0]},
                      smooth_in=300, start=320, end=340, smooth_out=360, name=HAND)


@pytest.fixture(scope="module")
def solved(qapp):
    """The contacts plus the hand constraint and their displacement map, solved once."""
    doc = demo_document()
    constraints = _contacts(doc) + [_hand(doc)]
    displacement = doc.scene.solve(constraints=constraints).scene.displacement
    doc.close()
    return constraints, displacement


@pytest.fixture
def doc(qtbot, solved):
    d = demo_document()
    constraints, displacement = solved
    push_constraints(d, constraints, displacement, text="Add contacts and a hand")
    assert d.scene.ready, d.scene.evaluation_error
    d.set_frame(60)
    yield d
    d.close()


@pytest.fixture
def timeline(qtbot, doc):
    w = shown(qtbot, ConstraintTimeline(doc), 1100, 440)
    w.view.setXRange(0, 240, padding=0)        # ~3.7 px per frame: drags land on frames
    qtbot.wait(10)
    return w


def _row_of(doc, name: str) -> int:
    return next(i for i, c in enumerate(doc.scene.constraints) if c.name == name)


def _px(tl, frame, row) -> QtCore.QPoint:
    return tl.frame_to_pixel(frame, row)


def _press(qtbot, tl, frame, row, button=LEFT):
    vp = tl.plot.viewport()
    pos = _px(tl, frame, row)
    qtbot.mouseMove(vp, pos)
    qtbot.wait(15)                             # pyqtgraph rate-limits moves (100/s)
    qtbot.mousePress(vp, button, pos=pos)
    qtbot.wait(15)


def _move(qtbot, tl, frame, row):
    qtbot.mouseMove(tl.plot.viewport(), _px(tl, frame, row))
    qtbot.wait(15)


def _release(qtbot, tl, frame, row, button=LEFT):
    qtbot.mouseRelease(tl.plot.viewport(), button, pos=_px(tl, frame, row))
    qtbot.wait(5)


def _arrays(motion):
    return np.array(motion.rotations), np.array(motion.translations)


# ====================================================================== pure helpers
def test_moved_range_clamps_between_neighbours():
    rng = (18, 32, 91, 105)
    assert moved_range(rng, "start", 28, 993) == (18, 28, 91, 105)
    assert moved_range(rng, "start", 120, 993) == (18, 91, 91, 105)      # stops at end
    assert moved_range(rng, "start", 5, 993) == (18, 18, 91, 105)        # at smooth_in
    assert moved_range(rng, "smooth_in", -4, 993) == (0, 32, 91, 105)
    assert moved_range(rng, "end", 10, 993) == (18, 32, 32, 105)
    assert moved_range(rng, "smooth_out", 2000, 993) == (18, 32, 91, 993)
    assert moved_range(rng, "all", -30, 993) == (0, 14, 73, 87)          # the clip's start
    assert moved_range(rng, "all", 5, 993) == (23, 37, 96, 110)


def test_retimed_trajectory_keeps_its_path():
    c = Constraint(joint="LeftHand", kind="trajectory",
                   goal={"points": np.arange(15.0).reshape(5, 3)},
                   smooth_in=8, start=10, end=14, smooth_out=16)
    longer = retimed(c, (8, 10, 20, 22))
    assert longer.goal_point(np.array([12]))[0] == pytest.approx(c.goal_point([12])[0])
    moved = retimed(c, (13, 15, 19, 21), shift=5)
    assert moved.goal_point(np.array([17]))[0] == pytest.approx(c.goal_point([12])[0])


def test_changed_window_and_overlap(solved):
    constraints, _ = solved
    c = constraints[2]
    new = c.with_range(10, 28, 91, 105)
    after = list(constraints)
    after[2] = new
    # a range change reaches the side that moved: here the input side, 10 .. 32
    assert changed_window(constraints, after) == (10, 32)
    assert affected_frames(c, c.with_range(18, 32, 95, 110)) == (91, 110)
    assert affected_frames(c, c.with_range(10, 28, 95, 110)) == (10, 110)
    goal = Constraint.from_dict({**c.to_dict(), "goal": {"point": [0.0, 0.0, 0.0]}})
    assert affected_frames(c, goal) == (18, 105)                 # a new goal: all of it
    assert changed_window(constraints, list(constraints)) is None
    assert changed_window(constraints, after[:-1]) is None
    subset = overlapping(after, 10, 105)
    assert new in subset and all(x.smooth_in <= 105 and x.smooth_out >= 10 for x in subset)
    assert len(subset) < len(after)
    # the window's problem: the right foot's contact 0-128 reaches into the window with its
    # active range only: clipped to the window (its output ramp lies beyond)
    problem = window_problem(after, 10, 105)
    assert [c.name for c in problem] == [c.name for c in subset]
    right = next(c for c in problem if c.name == "contact RightFoot 0-128")
    assert right.range == (10, 10, 105, 105)
    assert problem[[c.name for c in problem].index(new.name)] is new
    # a window holding ramps needs their key postures, those the solve blends: the right
    # foot's output ramp eases out the correction at its end (128), the left foot's input
    # ramp eases in the one at its start (123), each posture without them starting from the
    # frame next to it in the ramp (129, 122); all inside the window, so [L, H] is the
    # window: the right foot's contact is clipped to start at 120 (keeping its output ramp),
    # the left foot's contact 123-213 to end at 140 (keeping its input ramp from 109). The
    # postures at a ramp's smooth_in and smooth_out (109, 142) decide nothing in the window
    problem = window_problem(after, 120, 140)
    names = [c.name for c in problem]
    right = problem[names.index("contact RightFoot 0-128")]
    left = problem[names.index("contact LeftFoot 123-213")]
    assert right.range == (120, 120, 128, 142)
    assert left.range == (109, 123, 140, 140)
    assert all(109 <= c.smooth_in and c.smooth_out <= 142 for c in problem)


# ====================================================================== model -> widget
def test_rows_and_handles_for_every_constraint(timeline, doc):
    cons = doc.scene.constraints
    assert len(timeline.rows) == len(cons) == 31
    for i, (row, c) in enumerate(zip(timeline.rows, cons)):
        assert row.index == i and row.constraint is c
        assert row.handle_positions() == dict(zip(FIELDS, c.range))
        assert row.auto == c.auto
        assert timeline.label_of(i) == c.name
    autos = [r for r in timeline.rows if r.auto]
    assert len(autos) == 30
    # automatic and manual rows are drawn in different colours, the labels too
    hand = timeline.rows[_row_of(doc, HAND)]
    assert hand.color != autos[0].color
    colours = timeline.label_colours()
    assert colours[HAND][0] != colours[autos[0].constraint.name][0]
    # the left axis shows the names
    axis = timeline.row_axis
    values = axis.tickValues(0, 5, 200)[0][1]
    assert axis.tickStrings(values, 1, 1)[:2] == [cons[0].name, cons[1].name]
    # seconds on the top axis from the exact frame time
    ft = doc.scene.performer.frame_time
    spacing, ticks = timeline.seconds_axis.tickValues(0, 240, 900)[0]
    assert spacing * ft == pytest.approx(round(spacing * ft, 6))
    assert timeline.seconds_axis.tickStrings([120.0 / (ft * 120)], 1, 1 / ft)[0] == "1"


def test_model_changes_show_on_undo_redo(timeline, doc):
    i = _row_of(doc, HAND)
    moved = list(doc.scene.constraints)
    moved[i] = doc.scene.constraints[i].with_range(280, 300, 350, 380)
    disabled = moved[0] = Constraint.from_dict({**doc.scene.constraints[0].to_dict(),
                                                "enabled": False})
    push_constraints(doc, moved, text="Move and disable")
    assert timeline.rows[i].range == (280, 300, 350, 380)
    assert timeline.rows[0].constraint is disabled
    assert timeline.rows[0].color.name() == "#a0a0a0"           # greyed
    doc.undo_stack.undo()
    assert timeline.rows[i].range == (300, 320, 340, 360)
    assert timeline.rows[0].constraint.enabled
    doc.undo_stack.redo()
    assert timeline.rows[i].range == (280, 300, 350, 380)
    # fewer constraints: rows go, the selection clamps
    timeline.select(30)
    push_constraints(doc, doc.scene.constraints[:5], text="Keep five")
    assert len(timeline.rows) == 5 and timeline.selected_index == 4
    doc.undo_stack.undo()
    assert len(timeline.rows) == 31


# ====================================================================== dragging
def test_drag_start_handle_previews_then_pushes_one_command(qtbot, timeline, doc):
    row = 2
    c = doc.scene.constraints[row]
    assert c.name == "contact LeftFoot 32-91" and c.range == (18, 32, 91, 105)
    count = doc.undo_stack.count()
    rot0, tra0 = _arrays(doc.motion)
    timeline.live.latencies.clear()

    _press(qtbot, timeline, 32, row)
    assert timeline.rows[row].hover == "start"
    _move(qtbot, timeline, 30, row)
    _move(qtbot, timeline, 28, row)
    qtbot.waitUntil(lambda: bool(timeline.live.latencies), timeout=WAIT_MS)
    # during the drag: the handle moved, the motion is a preview, nothing was pushed
    assert timeline.rows[row].range == (18, 28, 91, 105)
    assert timeline.live.previewing
    assert doc.undo_stack.count() == count
    assert doc.scene.constraints[row] is c
    rot1, _ = _arrays(doc.motion)
    changed = np.flatnonzero(np.any(rot1 != rot0, axis=(1, 2)))
    assert len(changed) and changed.min() >= 18 and changed.max() <= 105   # only the window
    assert timeline.selected_index == row

    _release(qtbot, timeline, 28, row)
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.text(count) == "Move start of contact LeftFoot 32-91 to 28"
    assert doc.scene.constraints[row].range == (18, 28, 91, 105)
    assert timeline.rows[row].range == (18, 28, 91, 105)
    assert not timeline.live.previewing
    assert not np.array_equal(np.array(doc.motion.rotations), rot0)

    doc.undo_stack.undo()
    assert doc.scene.constraints[row] is c
    assert timeline.rows[row].range == c.range
    rot2, tra2 = _arrays(doc.motion)
    assert np.array_equal(rot2, rot0) and np.array_equal(tra2, tra0)


def test_drag_start_past_end_clamps(qtbot, timeline, doc):
    i = _row_of(doc, HAND)
    timeline.ensure_visible(i)
    timeline.view.setXRange(250, 420, padding=0)
    qtbot.wait(10)
    count = doc.undo_stack.count()
    _press(qtbot, timeline, 320, i)
    for f in (326, 335, 350, 380):
        _move(qtbot, timeline, f, i)
    assert timeline.rows[i].range == (300, 340, 340, 360)    # start stops at end
    _release(qtbot, timeline, 380, i)
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.text(count) == f"Move start of {HAND} to 340"
    assert doc.scene.constraints[i].range == (300, 340, 340, 360)
    # the end handle now coincides with start: dragging right takes the end, left the start
    _press(qtbot, timeline, 340, i)
    _move(qtbot, timeline, 345, i)
    _move(qtbot, timeline, 350, i)
    _release(qtbot, timeline, 350, i)
    assert doc.scene.constraints[i].range == (300, 340, 350, 360)
    assert doc.undo_stack.text(count + 1) == f"Move end of {HAND} to 350"
    doc.undo_stack.undo()
    doc.undo_stack.undo()
    assert doc.scene.constraints[i].range == (300, 320, 340, 360)


def test_drag_bar_moves_the_whole_range(qtbot, timeline, doc):
    row = 2
    count = doc.undo_stack.count()
    _press(qtbot, timeline, 60, row)
    for f in (64, 70, 75):
        _move(qtbot, timeline, f, row)
    _release(qtbot, timeline, 75, row)
    assert doc.scene.constraints[row].range == (33, 47, 106, 120)
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.text(count) == "Move contact LeftFoot 32-91 to 47-106"


def test_right_click_during_drag_cancels(qtbot, timeline, doc):
    row = 2
    c = doc.scene.constraints[row]
    count = doc.undo_stack.count()
    rot0, _ = _arrays(doc.motion)
    _press(qtbot, timeline, 91, row)                  # the end handle
    for f in (95, 100, 104):
        _move(qtbot, timeline, f, row)
    qtbot.waitUntil(lambda: timeline.live.previewing, timeout=WAIT_MS)
    assert timeline.rows[row].range == (18, 32, 104, 105)
    assert not np.array_equal(_arrays(doc.motion)[0], rot0)
    vp = timeline.plot.viewport()
    pos = _px(timeline, 104, row)
    qtbot.mousePress(vp, RIGHT, pos=pos)
    qtbot.mouseRelease(vp, RIGHT, pos=pos)
    assert timeline.rows[row].range == c.range               # restored at once
    _move(qtbot, timeline, 110, row)                          # moves after the cancel: ignored
    assert timeline.rows[row].range == c.range
    _release(qtbot, timeline, 110, row)
    assert doc.undo_stack.count() == count
    assert doc.scene.constraints[row] is c
    assert not timeline.live.previewing
    assert np.array_equal(_arrays(doc.motion)[0], rot0)


def test_window_preview_matches_the_full_solve(doc):
    """The preview solves only the constraints overlapping the change and splices their
    window into the shown motion; there it is the full solve's motion."""
    live = live_solver(doc)
    live.full_seconds = None                    # no measurement: window mode
    row = 2
    after = list(doc.scene.constraints)
    after[row] = doc.scene.constraints[row].with_range(10, 26, 91, 105)
    live.begin()
    motion, seconds, mode = live.preview_motion(after)
    live.cancel()
    assert mode == "window" and seconds > 0
    # the live solver's window (the window's frames cut from the clip and solved alone) is
    # the scene's window preview bit for bit
    ref, ref_mode = doc.scene.preview(after, base_constraints=list(doc.scene.constraints),
                                      base_motion=doc.motion, whole=False)
    assert ref_mode == "window"
    assert np.array_equal(motion.rotations, ref.rotations)
    assert np.array_equal(motion.translations, ref.translations)
    full = enforce(doc.scene.composed, after).motion
    a = forward_kinematics(motion).positions
    b = forward_kinematics(full).positions
    lo, hi = changed_window(doc.scene.constraints, after)
    assert (lo, hi) == (10, 32)
    assert np.abs(a - b)[lo:hi + 1].max() < 1e-4             # [m] the window: the full solve
    # beyond it the shown motion stays (the solved layer's keys, fitted to the tasks, leave
    # what no task holds to the fit: the shown motion, not the dense solve)
    shown = forward_kinematics(doc.scene.motion).positions
    outside = np.ones(len(a), dtype=bool)
    outside[lo:hi + 1] = False
    assert np.abs(a - shown)[outside].max() < 1e-3
    # a new goal reaches the whole range: the window is all of it
    goal = doc.scene.constraints[row].goal["point"] + [0.05, 0.0, 0.03]
    after[row] = Constraint.from_dict({**after[row].to_dict(), "goal": {"point": goal}})
    live.begin()
    motion, _s, mode = live.preview_motion(after)
    live.cancel()
    a = forward_kinematics(motion).positions
    b = forward_kinematics(enforce(doc.scene.composed, after).motion).positions
    assert changed_window(doc.scene.constraints, after) == (10, 105)
    assert mode == "window" and np.abs(a - b)[10:106].max() < 1e-4
    live.budget = 1e9                                       # a generous budget: full mode
    live.full_seconds = 0.0
    live.begin()
    _m, _s, mode = live.preview_motion(after)
    live.cancel()
    assert mode == "full"


# ====================================================================== playhead, selection
def test_playhead_follows_and_scrubs(qtbot, timeline, doc):
    doc.set_frame(150)
    assert timeline.playhead.value() == 150
    # drag the line (on a row with no handle at that frame) to frame 200
    row = 6
    assert not timeline.row_handle_at(timeline.view.mapViewToScene(QtCore.QPointF(150, row)))
    _press(qtbot, timeline, 150, row)
    for f in (160, 180, 200):
        _move(qtbot, timeline, f, row)
        assert abs(doc.scene.viewer.current_frame - f) <= 1
    _release(qtbot, timeline, 200, row)
    assert abs(doc.scene.viewer.current_frame - 200) <= 1
    assert timeline.playhead.value() == doc.scene.viewer.current_frame      # whole frames
    # the seconds ruler: a click moves the frame there
    axis = timeline.seconds_axis
    scene = QtCore.QPointF(timeline.view.mapViewToScene(QtCore.QPointF(90, 0)).x(),
                           axis.sceneBoundingRect().center().y())
    qtbot.mouseClick(timeline.plot.viewport(), LEFT, pos=timeline.plot.mapFromScene(scene))
    assert abs(doc.scene.viewer.current_frame - 90) <= 1
    assert timeline.doc.undo_stack.count() == 1                  # viewer state, not an edit


def test_click_selects_row_and_joint(qtbot, timeline, doc):
    seen = []
    timeline.constraintSelected.connect(seen.append)
    qtbot.mouseClick(timeline.plot.viewport(), LEFT, pos=_px(timeline, 200, 3))
    assert timeline.selected_index == 3 and seen == [3]
    assert timeline.rows[3].selected and not timeline.rows[2].selected
    assert doc.selection == ("target", doc.scene.constraints[3].joint)
    qtbot.mouseClick(timeline.plot.viewport(), LEFT, pos=_px(timeline, 200, 1))
    assert timeline.selected_index == 1 and seen == [3, 1]
    assert doc.undo_stack.count() == 1


def test_wheel_zooms_time_only(qtbot, timeline):
    vp = timeline.plot.viewport()
    (x0, x1), (y0, y1) = timeline.view.viewRange()
    pos = QtCore.QPointF(_px(timeline, 120, 2))

    def wheel(delta, modifiers=Qt.KeyboardModifier.NoModifier):
        ev = QtGui.QWheelEvent(pos, vp.mapToGlobal(pos), QtCore.QPoint(),
                               QtCore.QPoint(0, delta), Qt.MouseButton.NoButton, modifiers,
                               Qt.ScrollPhase.NoScrollPhase, False)
        QtCore.QCoreApplication.sendEvent(vp, ev)
        qtbot.wait(5)

    wheel(240)
    (a0, a1), (b0, b1) = timeline.view.viewRange()
    assert a1 - a0 < 0.9 * (x1 - x0)
    assert a0 < 120 < a1
    assert (b0, b1) == pytest.approx((y0, y1))
    top = timeline.scrollbar.value()
    wheel(-120, Qt.KeyboardModifier.ShiftModifier)            # Shift+wheel scrolls rows
    assert timeline.scrollbar.value() == top + 1
    assert timeline.view.viewRange()[1][0] == pytest.approx(y0 + 1)


# ====================================================================== add, delete, duplicate
def test_add_delete_duplicate(qtbot, timeline, doc):
    n = len(doc.scene.constraints)
    count = doc.undo_stack.count()
    doc.set_frame(200)
    doc.select("target", "RightHand")
    expected = doc.pose("target").positions[200, doc.motion.skeleton.index["RightHand"]].copy()
    assert timeline.add_button.isEnabled()
    qtbot.mouseClick(timeline.add_button, LEFT)
    assert len(doc.scene.constraints) == n + 1 == len(timeline.rows)
    new = doc.scene.constraints[-1]
    assert (new.joint, new.kind, new.auto) == ("RightHand", "position", False)
    assert new.range == (190, 195, 205, 210)
    assert new.goal["point"] == pytest.approx(expected)
    assert timeline.selected_index == n
    assert doc.undo_stack.text(count) == "Add position RightHand at frame 200"
    # near the clip's start the range is clipped
    doc.set_frame(3)
    qtbot.mouseClick(timeline.add_button, LEFT)
    assert doc.scene.constraints[-1].range == (0, 0, 8, 13)
    assert doc.scene.constraints[-1].name == "position RightHand 2"

    timeline.select(2)
    original = doc.scene.constraints[2]
    qtbot.mouseClick(timeline.duplicate_button, LEFT)
    copy = doc.scene.constraints[3]
    assert copy.name == "contact LeftFoot 32-91 copy" and not copy.auto
    assert copy.range == original.range and copy.joint == original.joint
    assert "source" not in copy.meta
    assert timeline.selected_index == 3
    assert doc.undo_stack.text(count + 2) == "Duplicate contact LeftFoot 32-91"

    qtbot.mouseClick(timeline.delete_button, LEFT)
    assert doc.scene.constraints[2] is original and len(doc.scene.constraints) == n + 2
    assert doc.undo_stack.text(count + 3) == "Delete contact LeftFoot 32-91 copy"
    assert doc.undo_stack.count() == count + 4
    for _ in range(4):
        doc.undo_stack.undo()
    assert len(doc.scene.constraints) == n == len(timeline.rows)
    # nothing selected in the target: Add is off
    doc.select("performer", "LeftAnkle")
    assert not timeline.add_button.isEnabled()


# ====================================================================== inspector
@pytest.fixture
def inspector(qtbot, timeline, doc):
    w = shown(qtbot, ConstraintInspector(doc, timeline), 380, 470)
    timeline.select(_row_of(doc, HAND))
    return w


def _type(qtbot, spin, text):
    spin.setFocus()
    spin.selectAll()
    qtbot.keyClicks(spin, text)
    qtbot.keyClick(spin, Qt.Key.Key_Return)


def test_inspector_follows_selection_and_undo(inspector, timeline, doc):
    i = _row_of(doc, HAND)
    c = doc.scene.constraints[i]
    assert inspector.index == i and inspector.title.text() == HAND
    assert inspector.joint.currentText() == "LeftHand"
    assert inspector.kind.currentText() == "Position"
    assert inspector.goal_edits["position", "point"].value() == \
        pytest.approx(np.round(c.goal["point"], 3))
    assert inspector.priority.value() == 1 and inspector.weight.value() == 1.0
    assert inspector.enabled.isChecked()
    timeline.select(0)
    assert inspector.title.text() == doc.scene.constraints[0].name
    assert "automatic" in inspector.subtitle.text()
    timeline.select(1)
    assert inspector.kind.currentText() == "Plane: above"
    assert inspector.goal_edits["plane", "normal"].value() == pytest.approx([0, 1, 0])
    timeline.select(None)
    assert not inspector.form_widget.isVisibleTo(inspector)


def test_the_inspector_lists_the_kinds_of_the_registry(inspector):
    from motion_composer.engine.correction.constraints import KINDS
    texts = [inspector.kind.itemText(i) for i in range(inspector.kind.count())]
    assert texts == [k.choice_label(v) for k in KINDS.values() for v in k.variants]
    assert sorted(inspector._page) == sorted(KINDS)
    assert len(set(inspector._page.values())) == inspector.goal_pages.count() == len(KINDS)


def test_inspector_edits_are_undoable(qtbot, inspector, doc):
    i = _row_of(doc, HAND)
    c0 = doc.scene.constraints[i]
    count = doc.undo_stack.count()

    # goal typed: one command, re-solved
    _type(qtbot, inspector.goal_edits["position", "point"].spins[1], "0.25")
    assert doc.scene.constraints[i].goal["point"][1] == pytest.approx(0.25)
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.text(count) == f"Set point of {HAND}"
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)   # the solve lands in that step
    j = doc.motion.skeleton.index["LeftHand"]
    hand = doc.pose("target").positions[330, j]
    assert np.linalg.norm(hand - doc.scene.constraints[i].goal["point"]) < 0.01   # solved

    # arrow steps preview and become one command after a pause
    spin = inspector.goal_edits["position", "point"].spins[0]
    x0 = spin.value()
    for _ in range(3):
        qtbot.keyClick(spin, Qt.Key.Key_Up)
    assert doc.undo_stack.count() == count + 1                # not yet
    qtbot.waitUntil(lambda: doc.undo_stack.count() == count + 2, timeout=WAIT_MS)
    assert doc.scene.constraints[i].goal["point"][0] == pytest.approx(x0 + 0.03)

    # kind, priority, weight, enabled
    inspector.kind.setCurrentIndex(3)
    inspector.kind.activated.emit(3)
    c = doc.scene.constraints[i]
    assert (c.kind, c.goal["side"]) == ("plane", "on")
    # edits replace one component: the others keep their exact values (not the boxes' mm)
    assert c.goal["point"][2] == c0.goal["point"][2]
    assert c.goal["point"] == pytest.approx([x0 + 0.03, 0.25, c0.goal["point"][2]])
    assert doc.undo_stack.text(count + 2) == f"Make {HAND} a plane on constraint"
    assert inspector.goal_pages.currentIndex() == inspector._page["plane"]
    _type(qtbot, inspector.priority, "3")
    assert doc.scene.constraints[i].priority == 3
    _type(qtbot, inspector.weight, "0.5")
    assert doc.scene.constraints[i].weight == 0.5
    inspector.enabled.click()
    assert not doc.scene.constraints[i].enabled
    assert doc.undo_stack.count() == count + 6
    assert [doc.undo_stack.text(count + k) for k in (3, 4, 5)] == [
        f"Set priority of {HAND} to 3", f"Set weight of {HAND} to 0.5", f"Disable {HAND}"]

    # orientation: Euler degrees shown, a quaternion stored
    inspector.enabled.click()
    inspector.kind.setCurrentIndex(5)
    inspector.kind.activated.emit(5)
    assert doc.scene.constraints[i].kind == "orientation"
    _type(qtbot, inspector.goal_edits["orientation", "quaternion"].spins[2], "30")
    q = doc.scene.constraints[i].goal["quaternion"]
    assert inspector.goal_edits["orientation", "quaternion"].value()[2] == \
        pytest.approx(30.0, abs=0.05)
    assert np.linalg.norm(q) == pytest.approx(1.0)

    # every step undoes, the widgets follow
    while doc.undo_stack.count() > count and doc.undo_stack.index() > count:
        doc.undo_stack.undo()
    assert doc.scene.constraints[i] is c0
    assert inspector.kind.currentText() == "Position"
    assert inspector.goal_edits["position", "point"].value() == \
        pytest.approx(np.round(c0.goal["point"], 3))
    assert inspector.priority.value() == 1 and inspector.enabled.isChecked()


def test_take_from_pose_and_pick(qtbot, inspector, doc):
    i = _row_of(doc, HAND)
    count = doc.undo_stack.count()
    doc.set_frame(410)
    sk = doc.motion.skeleton
    pose = doc.pose("target")
    expected = pose.positions[410, sk.index["LeftHand"]].copy()
    qtbot.mouseClick(inspector.take_button, LEFT)
    assert doc.scene.constraints[i].goal["point"] == pytest.approx(expected)
    assert doc.undo_stack.text(count) == f"Take goal of {HAND} from pose at frame 410"
    assert inspector.goal_edits["position", "point"].value() == \
        pytest.approx(np.round(expected, 3))

    # pick: the next target joint selected sets the joint, its position the goal
    expected = doc.pose("target").positions[410, sk.index["RightHand"]].copy()
    qtbot.mouseClick(inspector.pick_button, LEFT)
    assert inspector.picking
    doc.select("performer", "RightWrist")                  # not the target: still armed
    assert inspector.picking and doc.undo_stack.count() == count + 1
    doc.select("target", "RightHand")
    assert not inspector.picking
    c = doc.scene.constraints[i]
    assert c.joint == "RightHand" and c.goal["point"] == pytest.approx(expected, abs=1e-6)
    assert doc.undo_stack.text(count + 1) == f"Pick RightHand for {HAND}"
    assert inspector.joint.currentText() == "RightHand"
    doc.undo_stack.undo()
    assert doc.scene.constraints[i].joint == "LeftHand"
    assert inspector.joint.currentText() == "LeftHand"


# ====================================================================== screenshots
def test_screenshots(qtbot, solved, tmp_path):
    """The bundled demo: the hand constraint first, one contact disabled, the hand selected
    with its inspector."""
    d = demo_document()
    constraints, displacement = solved
    hand = constraints[-1]
    off = Constraint.from_dict({**constraints[3].to_dict(), "enabled": False})
    ordered = [hand] + constraints[:3] + [off] + constraints[4:-1]
    push_constraints(d, ordered, displacement, text="Demo")
    d.set_frame(330)
    tl = shown(qtbot, ConstraintTimeline(d), 1200, 520)
    tl.view.setXRange(0, 480, padding=0.005)
    insp = ConstraintInspector(d, tl)
    qtbot.addWidget(insp)
    insp.resize(420, insp.sizeHint().height())
    insp.show()
    qtbot.waitExposed(insp, timeout=WAIT_MS)
    tl.select(0)
    tl.rows[0].hover = "start"
    qtbot.wait(50)
    assert tl.grab().save(str(tmp_path / "timeline.png"))
    assert insp.grab().save(str(tmp_path / "inspector.png"))
    d.close()


def test_pending_inspector_step_commits_before_another_edit(qtbot, inspector, timeline, doc):
    """A spin-box step previewed in the inspector is its own command when the timeline
    starts another edit (here: Duplicate)."""
    i = _row_of(doc, HAND)
    count = doc.undo_stack.count()
    spin = inspector.goal_edits["position", "point"].spins[2]
    z0 = doc.scene.constraints[i].goal["point"][2]
    qtbot.keyClick(spin, Qt.Key.Key_Up)
    qtbot.waitUntil(lambda: timeline.live.previewing, timeout=WAIT_MS)
    assert doc.undo_stack.count() == count
    qtbot.mouseClick(timeline.duplicate_button, LEFT)
    assert doc.undo_stack.count() == count + 2
    assert doc.undo_stack.text(count) == f"Set point of {HAND}"
    assert doc.undo_stack.text(count + 1) == f"Duplicate {HAND}"
    assert doc.scene.constraints[i].goal["point"][2] == pytest.approx(round(z0, 3) + 0.01)
    assert doc.scene.constraints[i + 1].name == f"{HAND} copy"
    assert not timeline.live.active


def test_empty_document(qtbot):
    from motion_composer.app.gui.document import Document
    d = Document()
    tl = ConstraintTimeline(d)
    insp = ConstraintInspector(d, tl)
    qtbot.addWidget(tl)
    qtbot.addWidget(insp)
    tl.show()
    insp.show()
    qtbot.waitExposed(tl, timeout=WAIT_MS)
    assert tl.rows == [] and tl.selected_index is None
    assert not tl.add_button.isEnabled() and not tl.delete_button.isEnabled()
    tl.add_constraint("LeftHand")                 # nothing to add on: no motion
    assert d.undo_stack.count() == 0
    assert insp.title.text() == "No constraint"
    d.close()


def test_release_solves_in_the_document_job_runner(qtbot, timeline, doc):
    assert live_solver(doc) is timeline.live
    row = 2
    c = doc.scene.constraints[row]
    count = doc.undo_stack.count()
    _press(qtbot, timeline, 91, row)
    for f in (95, 100):
        _move(qtbot, timeline, f, row)
    qtbot.waitUntil(lambda: timeline.live.previewing, timeout=WAIT_MS)
    preview = doc.motion
    _release(qtbot, timeline, 100, row)
    # the edit is applied at once, as one command; the solve runs in the document's runner
    assert doc.undo_stack.count() == count + 1 and doc.pending and doc.jobs.busy
    assert doc.undo_stack.text(count) == "Move end of contact LeftFoot 32-91 to 100"
    assert doc.scene.constraints[row].range == (18, 32, 100, 105) == timeline.rows[row].range
    assert doc.motion is preview                     # the preview stays up meanwhile
    # (the solve fits its keys to the tasks too: about as long again as the IK on the demo)
    qtbot.waitUntil(lambda: not doc.pending and not doc.jobs.busy, timeout=90000)
    assert doc.undo_stack.count() == count + 1       # the solve landed in the same step
    assert doc.motion is not preview and doc.motion is doc.scene.motion
    assert c.range == (18, 32, 91, 105)


def test_an_edit_during_a_solve_is_applied_and_the_solve_restarts(qtbot, timeline, doc):
    errors = []
    doc.errorRaised.connect(errors.append)
    row = 2
    count = doc.undo_stack.count()
    doc.solve()                                      # a long solve is running
    assert doc.jobs.busy and doc.pending
    _press(qtbot, timeline, 91, row)
    for f in (95, 100):
        _move(qtbot, timeline, f, row)
    _release(qtbot, timeline, 100, row)
    # applied at once, never refused, no dialog
    assert doc.undo_stack.count() == count + 2 and not errors
    assert doc.scene.constraints[row].range == (18, 32, 100, 105) == timeline.rows[row].range
    assert doc.pending and doc.jobs.busy             # restarted for the edited constraints
    qtbot.waitUntil(lambda: not doc.pending and not doc.jobs.busy, timeout=60000)
    assert not errors and doc.undo_stack.count() == count + 2
    # the landed correction is the one of the edited constraints
    solved = doc.scene.solve().scene.motion
    np.testing.assert_allclose(doc.motion.rotations, solved.rotations, atol=1e-9)
    # undo comes back to the scene whose solve was dropped: it is solved again
    doc.undo_stack.undo()
    assert doc.scene.constraints[row].range == (18, 32, 91, 105)
    qtbot.waitUntil(lambda: not doc.pending and not doc.jobs.busy, timeout=60000)
    assert not errors
