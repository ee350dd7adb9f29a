"""The curve editor on a document of real clips with a real IK result on it.

The bundled walk on the bundled T-pose skeleton, a left-hand position constraint solved by
``engine.correction.enforcement.enforce`` and pushed with its reduced keys
(``push_constraints``); the editor shows LeftForeArm's offset curves. Keys are dragged with real mouse events sent to the plot's
viewport at the key's pixel (mapped through the ViewBox), and checked against the document: the
map, the undo stack, the previewed and the final motion. No OpenGL: runs under Xvfb and
offscreen alike.
"""
from __future__ import annotations

import dataclasses
import math
import sys

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")
pytest.importorskip("pyqtgraph")

import PySide6  # noqa: E402

if sys.version_info < (3, 12) and PySide6.__version__.startswith("6.12."):
    pytest.skip("PySide6 6.12.0 aborts Python 3.11 (it leaks references to None); "
                "pyproject.toml pins PySide6 below 6.12", allow_module_level=True)

from motion_composer.app.gui.qt import QtCore, QtWidgets  # noqa: E402
from motion_composer.app.gui.commands import push_constraints  # noqa: E402
from motion_composer.app.gui.curve_editor import CurveEditor  # noqa: E402
from motion_composer.engine.correction.constraints import Constraint  # noqa: E402
from motion_composer.engine.correction.enforcement import enforce  # noqa: E402
from motion_composer.engine.correction.displacement import ROOT, hermite_basis  # noqa: E402

from gui_support import WAIT_MS, demo_document, shown  # noqa: E402

Qt = QtCore.Qt
LEFT = Qt.MouseButton.LeftButton
NOMOD = Qt.KeyboardModifier.NoModifier
SHIFT = Qt.KeyboardModifier.ShiftModifier
DEG = 180.0 / math.pi
JOINT = "LeftForeArm"


@pytest.fixture
def doc(qtbot):
    d = demo_document()
    sk = d.scene.target.skeleton
    hand = d.pose("target").positions[300, sk.index["LeftHand"]]
    c = Constraint("LeftHand", "position", {"point": hand + [0.10, 0.15, 0.10]},
                   270, 290, 310, 330, name="reach")
    correction = enforce(d.scene.composed, [c])
    push_constraints(d, [c], displacement=correction.displacement_map(), text="Solve reach")
    d.undo_stack.setClean()
    yield d
    d.close()


@pytest.fixture
def editor(qtbot, doc):
    w = shown(qtbot, CurveEditor(doc), 1100, 480)
    w.activateWindow()
    qtbot.waitActive(w, timeout=WAIT_MS)    # keyboard shortcuts (Delete, Escape) need it
    doc.select("target", JOINT)
    doc.set_frame(300)
    # zoom on the IK range so keys are far enough apart to be picked one by one
    w.view_box.setRange(xRange=(262, 338), padding=0)
    _settle(qtbot, w)
    return w


# ---------------------------------------------------------------------------- helpers
def _settle(qtbot, editor):
    """Wait until the plot's layout is still: an axis whose tick labels got wider (other
    units) moves the ViewBox a few pixels at the next paint."""
    rect = None
    for _ in range(20):
        qtbot.wait(25)
        now = editor.view_box.sceneBoundingRect()
        if now == rect:
            return
        rect = now


def _pixel(editor, channel, index) -> QtCore.QPoint:
    """Where a key is drawn, in the plot viewport's pixels."""
    return editor.plot_widget.mapFromScene(editor.key_scene_pos(channel, index))


def _to_view(editor, point: QtCore.QPoint) -> QtCore.QPointF:
    return editor.view_box.mapSceneToView(editor.plot_widget.mapToScene(point))


def _drag(qtbot, editor, start: QtCore.QPoint, end: QtCore.QPoint, modifier=NOMOD,
          during=None, steps=6):
    """A real mouse drag on the plot viewport; ``during()`` is called halfway."""
    vp = editor.plot_widget.viewport()
    qtbot.mousePress(vp, LEFT, modifier, start)
    for k in range(1, steps + 1):
        qtbot.wait(15)              # pyqtgraph drops moves closer than 10 ms apart
        pos = start + (end - start) * (k / steps)
        qtbot.mouseMove(vp, pos)
        if during is not None and k == steps // 2:
            during()
    qtbot.wait(15)
    qtbot.mouseRelease(vp, LEFT, modifier, end)


def _double_click(qtbot, editor, pos: QtCore.QPoint):
    """A double-click at ``pos`` (viewport pixels) sent to the window, so that Qt's own
    double-click detection turns it into press, release, double-click, release as for a real
    mouse (QTest's mouseDClick on a widget sends the double-click event alone)."""
    window = editor.window().windowHandle()
    at = editor.plot_widget.viewport().mapTo(editor.window(), pos)
    qtbot.mouseDClick(window, LEFT, NOMOD, at)


def _roomy_key(curve, lo=272, hi=328, avoid=None):
    """Index of an interior key inside the IK range with the widest gap to its neighbours;
    not at frame ``avoid`` (for a drag: the playhead's frame, whose line a press there
    grabs)."""
    f = curve.frames
    best, gap = None, -1
    for i in range(1, len(f) - 1):
        if lo <= f[i] <= hi and f[i] != avoid and \
                min(f[i] - f[i - 1], f[i + 1] - f[i]) > gap:
            best, gap = i, min(f[i] - f[i - 1], f[i + 1] - f[i])
    assert gap >= 3, "the IK result should have keys a few frames apart"
    return best


def _clear_key(editor, channel, avoid=None, lo=272, hi=328, with_next=False) -> int:
    """Index of an interior key of ``channel`` inside the IK range, not at frame ``avoid``,
    whose pixel is at least 8 pixels from every other visible channel's keys (a click there
    picks this key, whatever the solve put in the other curves), and with ``with_next`` the
    key after it too; the widest-spaced such key."""
    curve = editor.curve(channel)
    others = [_pixel(editor, c, k) for c in editor.visible_channels() if c != channel
              for k in range(len(editor.curve(c)))]
    f = curve.frames
    best, gap = None, -1
    for i in range(1, len(f) - 1):
        if not lo <= f[i] <= hi or f[i] == avoid:
            continue
        if with_next and (i + 1 >= len(f) - 1 or f[i + 1] == avoid):
            continue
        mine = [_pixel(editor, channel, k) for k in ((i, i + 1) if with_next else (i,))]
        if any((p - at).manhattanLength() < 8 for p in others for at in mine):
            continue
        room = min(f[i] - f[i - 1], f[i + 1] - f[i])
        if room > gap:
            best, gap = i, room
    assert best is not None and gap >= 3, f"no key of {channel} clear of the other curves"
    return best


def _graph(editor, channel):
    return editor.key_graphs["xyz".index(channel[1])]


# ---------------------------------------------------------------------------- model -> widget
def test_curves_and_keys_show_the_map_in_degrees_over_the_base_motion(editor, doc):
    assert editor.joint == JOINT and editor.channels == ("rx", "ry", "rz")
    F = doc.scene.num_frames
    j = doc.scene.target.skeleton.index[JOINT]
    from scipy.spatial.transform import Rotation
    base = Rotation.from_quat(doc.scene.composed.rotations[:, j]).as_rotvec() * DEG
    for axis, channel in enumerate(("rx", "ry", "rz")):
        curve = doc.scene.displacement.curves[(JOINT, channel)]
        assert len(curve) > 3                              # real reduced keys
        graph = editor.key_graphs[axis]
        assert graph.channel == channel and graph.isVisible()
        np.testing.assert_array_equal(graph.frames, curve.frames)
        np.testing.assert_allclose(graph.values, curve.values * DEG, rtol=0, atol=1e-12)
        x, y = editor.curves[axis].getData()
        np.testing.assert_array_equal(x, np.arange(F))
        np.testing.assert_allclose(y, curve.evaluate(np.arange(F)) * DEG, rtol=0, atol=1e-12)
        bx, by = editor.bases[axis].getData()
        np.testing.assert_allclose(by, base[:, axis], rtol=0, atol=1e-9)
        assert editor.bases[axis].isVisible()
    assert "deg" in editor.plot.getAxis("left").labelText
    assert "base" in editor.plot.getAxis("right").labelText
    assert JOINT in editor.title.text()
    # the root's translation in centimetres
    editor.root_button.click()
    assert editor.joint == ROOT and editor.channels == ("tx", "ty", "tz")
    curve = doc.scene.displacement.curves[(ROOT, "ty")]
    np.testing.assert_allclose(_graph(editor, "ty").values, curve.values * 100.0, atol=1e-12)
    np.testing.assert_allclose(editor.bases[1].getData()[1],
                               doc.scene.composed.translations[:, 0, 1] * 100.0, atol=1e-12)
    assert "cm" in editor.plot.getAxis("left").labelText
    editor.root_button.click()
    assert editor.joint == JOINT


def test_channel_toggles_hide_curves_keys_and_base(editor):
    editor.channel_buttons[1].click()
    assert not editor.curves[1].isVisible() and not editor.key_graphs[1].isVisible()
    assert not editor.bases[1].isVisible()
    assert editor.visible_channels() == ["rx", "rz"]
    editor.base_check.click()
    assert not any(b.isVisible() for b in editor.bases.values())
    editor.channel_buttons[1].click()
    assert editor.curves[1].isVisible()


def test_selecting_another_joint_or_none_switches_curves(editor, doc):
    doc.select("target", "LeftArm")
    assert editor.joint == "LeftArm"
    np.testing.assert_array_equal(_graph(editor, "ry").frames,
                                  doc.scene.displacement.curves[("LeftArm", "ry")].frames)
    doc.select("performer", "LeftArm")                 # performer joints have no offsets
    assert editor.joint == "LeftArm"
    doc.select("", "")
    assert editor.joint == ROOT and editor.root_button.isChecked()
    editor.root_button.click()                         # nothing selected: the root joint
    assert editor.joint == doc.scene.target.skeleton.names[0]
    # a joint without curves shows flat zero lines and no keys
    doc.select("target", "RightFoot")
    assert all(len(g.frames) == 0 for g in editor.key_graphs.values())
    assert np.all(editor.curves[0].getData()[1] == 0)


# ---------------------------------------------------------------------------- dragging keys
def test_dragging_a_key_snaps_to_frames_previews_and_pushes_one_command(editor, doc, qtbot):
    before_map = doc.scene.displacement
    before_motion = doc.motion
    before_pose = doc.pose("target").positions.copy()
    count = doc.undo_stack.count()
    curve = before_map.curves[(JOINT, "rx")]
    i = _roomy_key(curve, avoid=doc.scene.viewer.current_frame)
    f0, v0 = curve.frames[i], curve.values[i]
    start = _pixel(editor, "rx", i)
    end = start + QtCore.QPoint(17, 0)                 # about 1.3 frames at this zoom
    seen = {}

    def during():
        seen["dragging"] = editor.dragging
        seen["count"] = doc.undo_stack.count()
        seen["previewed"] = doc.motion is not before_motion and not np.array_equal(
            doc.motion.rotations, before_motion.rotations)
        seen["map"] = doc.scene.displacement is before_map

    _drag(qtbot, editor, start, end, during=during)
    assert seen == {"dragging": True, "count": count, "previewed": True, "map": True}
    # one command, named
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.text(count) == f"Move 1 key of {JOINT}.rx"
    moved = doc.scene.displacement.curves[(JOINT, "rx")]
    expected = round(f0 + _to_view(editor, end).x() - _to_view(editor, start).x())
    assert moved.frames[i] == expected != f0           # snapped to a whole frame
    assert abs(moved.values[i] - v0) < 1e-9            # a horizontal drag keeps the value
    np.testing.assert_array_equal(np.delete(moved.frames, i), np.delete(curve.frames, i))
    for channel in ("ry", "rz"):
        assert doc.scene.displacement.curves[(JOINT, channel)] is before_map.curves[(JOINT, channel)]
    # the widget shows the new key; it stays selected
    assert _graph(editor, "rx").frames[i] == expected
    assert editor.selected_keys() == [("rx", i)]
    # the viewport follows: the pose changes around the key and nowhere else
    pose = doc.pose("target").positions
    lo, hi = int(curve.frames[max(i - 2, 0)]), int(curve.frames[min(i + 2, len(curve) - 1)])
    assert np.abs(pose[lo:hi + 1] - before_pose[lo:hi + 1]).max() > 1e-5
    np.testing.assert_array_equal(pose[:lo], before_pose[:lo])
    np.testing.assert_array_equal(pose[hi + 1:], before_pose[hi + 1:])
    # outside the keys' span of the IK result the motion is exactly the composed one
    np.testing.assert_array_equal(doc.motion.rotations[:270], doc.scene.composed.rotations[:270])
    np.testing.assert_array_equal(doc.motion.rotations[331:], doc.scene.composed.rotations[331:])
    # undo restores the exact map and motion, and the editor
    doc.undo_stack.undo()
    assert doc.scene.displacement is before_map
    np.testing.assert_array_equal(doc.motion.rotations, before_motion.rotations)
    np.testing.assert_array_equal(_graph(editor, "rx").frames, curve.frames)
    doc.undo_stack.redo()
    assert _graph(editor, "rx").frames[i] == expected


def test_several_selected_keys_move_together(editor, doc, qtbot):
    vp = editor.plot_widget.viewport()
    rx = doc.scene.displacement.curves[(JOINT, "rx")]
    ry = doc.scene.displacement.curves[(JOINT, "ry")]
    # not on the playhead's frame, whose line a press there grabs
    a = _clear_key(editor, "rx", avoid=doc.scene.viewer.current_frame, with_next=True)
    b = _clear_key(editor, "ry", avoid=doc.scene.viewer.current_frame)
    qtbot.mouseClick(vp, LEFT, NOMOD, _pixel(editor, "rx", a))
    qtbot.mouseClick(vp, LEFT, SHIFT, _pixel(editor, "rx", a + 1))
    qtbot.mouseClick(vp, LEFT, SHIFT, _pixel(editor, "ry", b))
    assert editor.selected_keys() == [("rx", a), ("rx", a + 1), ("ry", b)]
    before = doc.scene.displacement
    count = doc.undo_stack.count()
    start = _pixel(editor, "ry", b)
    end = start + QtCore.QPoint(0, -40)                # up: a larger value
    _drag(qtbot, editor, start, end)
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.text(count) == f"Move 3 keys of {JOINT}.rx, ry"
    dv = (_to_view(editor, end).y() - _to_view(editor, start).y()) / DEG
    assert dv > 0
    new_rx = doc.scene.displacement.curves[(JOINT, "rx")]
    new_ry = doc.scene.displacement.curves[(JOINT, "ry")]
    np.testing.assert_array_equal(new_rx.frames, rx.frames)   # a vertical drag keeps times
    np.testing.assert_allclose(new_rx.values[[a, a + 1]] - rx.values[[a, a + 1]], dv,
                               atol=1e-12)
    np.testing.assert_allclose(new_ry.values[b] - ry.values[b], dv, atol=1e-12)
    untouched = np.delete(np.arange(len(rx)), [a, a + 1])
    np.testing.assert_array_equal(new_rx.values[untouched], rx.values[untouched])
    doc.undo_stack.undo()
    assert doc.scene.displacement is before


def test_root_translation_keys_move_in_centimetres(editor, doc, qtbot):
    editor.root_button.click()
    editor.view_box.setRange(xRange=(262, 338), padding=0)
    _settle(qtbot, editor)
    before = doc.scene.displacement
    curve = before.curves[(ROOT, "ty")]
    # not on the playhead's frame, whose line a press there grabs
    i = _clear_key(editor, "ty", avoid=doc.scene.viewer.current_frame)
    start = _pixel(editor, "ty", i)
    end = start + QtCore.QPoint(0, 30)                 # down
    _drag(qtbot, editor, start, end)
    assert doc.undo_stack.text(doc.undo_stack.count() - 1) == "Move 1 key of root.ty"
    dcm = _to_view(editor, end).y() - _to_view(editor, start).y()
    moved = doc.scene.displacement.curves[(ROOT, "ty")]
    assert moved.values[i] - curve.values[i] == pytest.approx(dcm / 100.0, abs=1e-12)
    assert moved.frames[i] == curve.frames[i]
    # the root moves by as much at that frame
    f = int(curve.frames[i])
    delta = doc.motion.translations[f, 0, 1] - before.apply(doc.scene.composed).translations[f, 0, 1]
    assert delta == pytest.approx(dcm / 100.0, abs=1e-12)


def test_rubber_band_selects_the_keys_inside(editor, doc, qtbot):
    rz = doc.scene.displacement.curves[(JOINT, "rz")]
    inside = [i for i, f in enumerate(rz.frames) if 295 <= f <= 320]
    assert len(inside) >= 2
    # a band around those rz keys (in view coordinates, then pixels)
    vals = rz.values[inside] * DEG
    # a margin of a few pixels above and below (pixels round the band's edges)
    (_, _), (bottom, top) = editor.view_box.viewRange()
    margin = 3 * (top - bottom) / editor.view_box.height()
    tl = editor.view_box.mapViewToScene(QtCore.QPointF(294.5, vals.max() + margin))
    br = editor.view_box.mapViewToScene(QtCore.QPointF(320.5, vals.min() - margin))
    start, end = editor.plot_widget.mapFromScene(tl), editor.plot_widget.mapFromScene(br)
    count = doc.undo_stack.count()
    _drag(qtbot, editor, start, end)
    band = QtCore.QRectF(_to_view(editor, start), _to_view(editor, end)).normalized()
    expected = []
    for channel in ("rx", "ry", "rz"):
        c = doc.scene.displacement.curves[(JOINT, channel)]
        v = c.values * DEG
        expected += [(channel, i) for i in range(len(c))
                     if band.left() <= c.frames[i] <= band.right()
                     and band.top() <= v[i] <= band.bottom()]
    assert set((("rz", i) for i in inside)) <= set(expected)
    assert editor.selected_keys() == expected
    assert doc.undo_stack.count() == count             # selecting is not an edit
    # Shift adds to the selection; a click on the background clears it
    k = _roomy_key(doc.scene.displacement.curves[(JOINT, "rx")])
    qtbot.mouseClick(editor.plot_widget.viewport(), LEFT, SHIFT, _pixel(editor, "rx", k))
    assert editor.selected_keys() == sorted(expected + [("rx", k)])
    (_, _), (_, top) = editor.view_box.viewRange()
    empty = editor.plot_widget.mapFromScene(editor.view_box.mapViewToScene(
        QtCore.QPointF(265, top * 0.9)))
    qtbot.mouseClick(editor.plot_widget.viewport(), LEFT, NOMOD, empty)
    assert editor.selected_keys() == []


def test_snapping_to_5_frame_steps_and_value_steps(editor, doc, qtbot):
    editor.snap5_check.setChecked(True)
    editor.snap_value_check.setChecked(True)
    editor.value_step.setValue(0.25)
    curve = doc.scene.displacement.curves[(JOINT, "ry")]
    # a key with room to move by whole 5-frame steps, not on the playhead's frame
    i = _roomy_key(curve, avoid=doc.scene.viewer.current_frame)
    start = _pixel(editor, "ry", i)
    end = start + QtCore.QPoint(3, 23)
    _drag(qtbot, editor, start, end)
    moved = doc.scene.displacement.curves[(JOINT, "ry")]
    lo, hi = curve.frames[i - 1] + 1, curve.frames[i + 1] - 1
    target = round((curve.frames[i] + _to_view(editor, end).x() - _to_view(editor, start).x())
                   / 5) * 5
    assert moved.frames[i] == min(max(target, lo), hi)
    value = moved.values[i] * DEG
    assert abs(value / 0.25 - round(value / 0.25)) < 1e-9
    assert moved.values[i] < curve.values[i]           # dragged down


def test_keys_never_pass_their_neighbours(editor, doc, qtbot):
    curve = doc.scene.displacement.curves[(JOINT, "rx")]
    i = _roomy_key(curve, avoid=doc.scene.viewer.current_frame)
    start = _pixel(editor, "rx", i)
    _drag(qtbot, editor, start, start + QtCore.QPoint(600, 0))
    moved = doc.scene.displacement.curves[(JOINT, "rx")]
    assert moved.frames[i] == curve.frames[i + 1] - 1
    assert np.all(np.diff(moved.frames) > 0)


def test_escape_cancels_a_drag(editor, doc, qtbot):
    before_map, before_motion = doc.scene.displacement, doc.motion
    count = doc.undo_stack.count()
    curve = before_map.curves[(JOINT, "rx")]
    i = _roomy_key(curve)
    start = _pixel(editor, "rx", i)
    editor.plot_widget.setFocus()
    _drag(qtbot, editor, start, start + QtCore.QPoint(0, 40),
          during=lambda: qtbot.keyClick(editor.plot_widget, Qt.Key.Key_Escape))
    assert doc.undo_stack.count() == count and doc.scene.displacement is before_map
    np.testing.assert_array_equal(doc.motion.rotations, before_motion.rotations)
    np.testing.assert_array_equal(_graph(editor, "rx").values, curve.values * DEG)


# ---------------------------------------------------------------------------- add, delete
def test_add_key_button_keys_visible_channels_at_the_current_frame(editor, doc, qtbot):
    doc.set_frame(301)
    editor.channel_buttons[2].click()                  # rz hidden: not keyed
    before = doc.scene.displacement
    count = doc.undo_stack.count()
    values = {c: before.curves[(JOINT, c)].evaluate(np.array([301.0]))[0]
              for c in ("rx", "ry")}
    assert all(301.0 not in before.curves[(JOINT, c)].frames for c in ("rx", "ry"))
    qtbot.mouseClick(editor.add_button, LEFT)
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.text(count) == f"Add 2 keys of {JOINT}.rx, ry at frame 301"
    for c in ("rx", "ry"):
        new = doc.scene.displacement.curves[(JOINT, c)]
        assert len(new) == len(before.curves[(JOINT, c)]) + 1
        k = int(np.flatnonzero(new.frames == 301.0)[0])
        assert new.values[k] == pytest.approx(values[c], abs=1e-15)
        assert new.interpolation[k] == "smooth"
    assert doc.scene.displacement.curves[(JOINT, "rz")] is before.curves[(JOINT, "rz")]
    assert {c for c, _ in editor.selected_keys()} == {"rx", "ry"}
    doc.undo_stack.undo()
    assert doc.scene.displacement is before


def test_double_click_on_a_curve_adds_a_key_there(editor, doc, qtbot):
    curve = doc.scene.displacement.curves[(JOINT, "rz")]
    frame = next(f for f in range(285, 320) if f not in curve.frames)
    y = curve.evaluate(np.array([float(frame)]))[0] * DEG
    p = editor.plot_widget.mapFromScene(editor.view_box.mapViewToScene(
        QtCore.QPointF(frame, y)))
    count = doc.undo_stack.count()
    _double_click(qtbot, editor, p)
    assert doc.undo_stack.count() == count + 1
    new = doc.scene.displacement.curves[(JOINT, "rz")]
    clicked = round(_to_view(editor, p).x())
    assert len(new) == len(curve) + 1 and clicked in new.frames
    k = int(np.flatnonzero(new.frames == clicked)[0])
    assert new.values[k] == pytest.approx(curve.evaluate(np.array([float(clicked)]))[0],
                                          abs=1e-15)
    # far from any curve: nothing
    far = editor.plot_widget.mapFromScene(editor.view_box.mapViewToScene(
        QtCore.QPointF(frame, editor.view_box.viewRange()[1][1] * 0.95)))
    _double_click(qtbot, editor, far)
    assert doc.undo_stack.count() == count + 1


def test_delete_removes_the_selected_keys_in_one_command(editor, doc, qtbot):
    before = doc.scene.displacement
    rx = before.curves[(JOINT, "rx")]
    a = _roomy_key(rx)
    editor.set_selection([("rx", a), ("rx", a + 1), ("rz", 1)])
    count = doc.undo_stack.count()
    before_motion = doc.motion
    editor.plot_widget.setFocus()
    qtbot.keyClick(editor.plot_widget, Qt.Key.Key_Delete)
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.text(count) == f"Delete 3 keys of {JOINT}.rx, rz"
    new = doc.scene.displacement.curves[(JOINT, "rx")]
    np.testing.assert_array_equal(new.frames, np.delete(rx.frames, [a, a + 1]))
    assert len(doc.scene.displacement.curves[(JOINT, "rz")]) == len(before.curves[(JOINT, "rz")]) - 1
    assert not np.array_equal(doc.motion.rotations, before_motion.rotations)
    assert editor.selected_keys() == []
    doc.undo_stack.undo()
    assert doc.scene.displacement is before
    # deleting every key of a channel removes its curve: the channel is zero again
    curve = before.curves[(JOINT, "ry")]
    editor.set_selection([("ry", i) for i in range(len(curve))])
    qtbot.mouseClick(editor.delete_button, LEFT)
    assert (JOINT, "ry") not in doc.scene.displacement.curves


# ---------------------------------------------------------------------------- interpolation
def test_interpolation_change_alters_the_evaluated_curve(editor, doc, qtbot):
    before = doc.scene.displacement
    curve = before.curves[(JOINT, "rx")]
    i = _roomy_key(curve)
    editor.set_selection([("rx", i)])
    assert editor.interp_combo.currentData() == "smooth"
    count = doc.undo_stack.count()
    before_rot = doc.motion.rotations.copy()
    editor.interp_combo.setFocus()
    qtbot.keyClick(editor.interp_combo, Qt.Key.Key_Down)        # smooth -> constant
    assert editor.interp_combo.currentData() == "constant"
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.text(count) == f"Set 1 key of {JOINT}.rx to constant"
    new = doc.scene.displacement.curves[(JOINT, "rx")]
    assert new.interpolation[i] == "constant"
    seg = np.arange(curve.frames[i], curve.frames[i + 1])
    np.testing.assert_array_equal(new.evaluate(seg), curve.values[i])   # a held step
    y = editor.curves[0].getData()[1]
    np.testing.assert_allclose(y[seg.astype(int)], curve.values[i] * DEG, atol=1e-12)
    j = doc.scene.target.skeleton.index[JOINT]
    s = seg.astype(int)[1:]
    assert np.abs(doc.motion.rotations[s, j] - before_rot[s, j]).max() > 1e-6
    doc.undo_stack.undo()
    assert doc.scene.displacement is before
    assert editor.interp_combo.currentData() == "smooth"        # model -> widget
    # a right-click on a key opens its menu, which sets it too
    qtbot.mouseClick(editor.plot_widget.viewport(), Qt.MouseButton.RightButton, NOMOD,
                     _pixel(editor, "rx", i))
    menu = QtWidgets.QApplication.activePopupWidget()
    assert isinstance(menu, QtWidgets.QMenu)
    assert [a.text() for a in menu.actions() if a.isChecked()] == ["Smooth"]
    next(a for a in menu.actions() if a.text() == "Linear").trigger()
    menu.close()
    assert doc.scene.displacement.curves[(JOINT, "rx")].interpolation[i] == "linear"
    assert doc.undo_stack.text(doc.undo_stack.count() - 1) == f"Set 1 key of {JOINT}.rx to linear"


def test_typed_frame_and_value_of_one_key(editor, doc):
    curve = doc.scene.displacement.curves[(JOINT, "rz")]
    i = _roomy_key(curve)
    editor.set_selection([("rz", i)])
    assert editor.frame_box.isEnabled() and editor.frame_box.value() == curve.frames[i]
    assert editor.value_box.value() == pytest.approx(curve.values[i] * DEG, abs=1e-3)
    count = doc.undo_stack.count()
    editor.value_box.setValue(2.5)
    assert doc.scene.displacement.curves[(JOINT, "rz")].values[i] == pytest.approx(2.5 / DEG)
    editor.frame_box.setValue(int(curve.frames[i]) + 1)
    assert doc.scene.displacement.curves[(JOINT, "rz")].frames[i] == curve.frames[i] + 1
    assert doc.undo_stack.count() == count + 2
    editor.frame_box.setValue(int(curve.frames[i + 1]) + 3)     # past a neighbour: refused
    assert doc.undo_stack.count() == count + 2
    assert editor.frame_box.value() == curve.frames[i] + 1
    editor.set_selection([("rz", i), ("rz", i + 1)])
    assert not editor.frame_box.isEnabled() and not editor.value_box.isEnabled()


# ---------------------------------------------------------------------------- view, playhead
def test_frame_all_fits_the_visible_curves(editor, doc, qtbot):
    editor.view_box.setRange(xRange=(10, 20), yRange=(50, 60), padding=0)
    qtbot.mouseClick(editor.frame_all_button, LEFT)
    (x0, x1), (y0, y1) = editor.view_box.viewRange()
    F = doc.scene.num_frames
    ys = np.concatenate([doc.scene.displacement.curves[(JOINT, c)].evaluate(np.arange(F)) * DEG
                         for c in ("rx", "ry", "rz")] + [np.zeros(1)])
    lo, hi = ys.min(), ys.max()
    pad_y, pad_x = 0.04 * (hi - lo), 0.04 * (F - 1)
    assert x0 == pytest.approx(0 - pad_x, abs=0.02 * pad_x)
    assert x1 == pytest.approx(F - 1 + pad_x, abs=0.02 * pad_x)
    assert y0 == pytest.approx(lo - pad_y, abs=0.02 * pad_y)
    assert y1 == pytest.approx(hi + pad_y, abs=0.02 * pad_y)
    # only visible channels count
    editor.channel_buttons[0].click()
    editor.channel_buttons[1].click()
    editor.frame_all()
    rz = doc.scene.displacement.curves[(JOINT, "rz")].evaluate(np.arange(F)) * DEG
    (_, _), (y0, y1) = editor.view_box.viewRange()
    assert y1 == pytest.approx(rz.max() + 0.04 * (rz.max() - min(rz.min(), 0)), rel=0.02)


def test_playhead_follows_the_frame_and_scrubs_it(editor, doc, qtbot):
    doc.set_frame(290)
    assert editor.playhead.value() == 290
    editor.playhead.setValue(311.4)                    # as a drag of the line does
    assert doc.scene.viewer.current_frame == 311
    editor.playhead.sigPositionChangeFinished.emit(editor.playhead)
    assert editor.playhead.value() == 311


def test_undo_of_a_new_ik_result_updates_the_editor(editor, doc):
    keys = _graph(editor, "rx").frames.copy()
    doc.undo_stack.undo()          # the IK solve: no curves at all
    assert all(len(g.frames) == 0 for g in editor.key_graphs.values())
    doc.undo_stack.redo()
    np.testing.assert_array_equal(_graph(editor, "rx").frames, keys)


# ---------------------------------------------------------------------------- screenshot
def test_screenshot(editor, doc, qtbot, tmp_path):
    editor.view_box.setRange(xRange=(258, 342), padding=0.02)
    rx = doc.scene.displacement.curves[(JOINT, "rx")]
    i = _roomy_key(rx)
    editor.set_selection([("rx", i), ("rx", i + 1)])
    qtbot.wait(30)
    assert editor.grab().save(str(tmp_path / "curve_editor.png"))


# ---------------------------------------------------------------------------- tangents, layers
def _smooth_key(curve, lo=272, hi=328):
    """An interior key inside the IK range with smooth segments on both sides."""
    i = _roomy_key(curve, lo, hi)
    assert curve.interpolation[i - 1] == curve.interpolation[i] == "smooth"
    return i


def _hermite(curve, k, t):
    """The Hermite cubic of keys ``k`` and ``k + 1`` of ``curve`` at frames ``t``."""
    f0, f1 = curve.frames[k], curve.frames[k + 1]
    m = curve.tangent_slopes()
    h = f1 - f0
    b0, b1, b2, b3 = hermite_basis((np.asarray(t) - f0) / h)
    return b0 * curve.values[k] + b1 * h * m[k, 1] + b2 * curve.values[k + 1] + \
        b3 * h * m[k + 1, 0]


def test_dragging_a_tangent_handle_sets_the_slope_as_the_hermite_maths_says(editor, doc,
                                                                            qtbot):
    curve = doc.scene.displacement.curves[(JOINT, "rx")]
    i = _smooth_key(curve)
    editor.set_selection([("rx", i)])
    _settle(qtbot, editor)
    vp_start = editor.plot_widget.mapFromScene(editor.handle_scene_pos("rx", i, 1))
    vp_end = vp_start + QtCore.QPoint(0, -40)
    count = doc.undo_stack.count()
    seen = {}

    def during():
        seen["count"] = doc.undo_stack.count()
        seen["dragging"] = editor.dragging

    _drag(qtbot, editor, vp_start, vp_end, during=during)
    assert seen == {"count": count, "dragging": True}
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.text(count) == f"Set the tangent of 1 key of {JOINT}.rx"
    new = doc.scene.displacement.curves[(JOINT, "rx")]
    # the slope goes through where the handle was let go, on both sides (aligned)
    at = _to_view(editor, vp_end)
    slope = (at.y() / DEG - curve.values[i]) / (at.x() - curve.frames[i])
    assert new.tangents[i] == "aligned"
    np.testing.assert_allclose(new.tangent_slopes()[i], [slope, slope], rtol=1e-9)
    assert slope > curve.tangent_slopes()[i, 1]              # dragged up: steeper
    # between the keys either side the curve is the Hermite cubic with the new slope;
    # keys and the other segments are as they were
    for k in (i - 1, i):
        t = np.linspace(new.frames[k], new.frames[k + 1], 9)
        np.testing.assert_allclose(new.evaluate(t), _hermite(new, k, t), atol=1e-12)
    mid = (new.frames[i] + new.frames[i + 1]) / 2
    assert new.evaluate([mid])[0] > curve.evaluate([mid])[0]
    np.testing.assert_array_equal(new.values, curve.values)
    far = np.arange(0, int(new.frames[i - 1]))
    np.testing.assert_array_equal(new.evaluate(far), curve.evaluate(far))
    doc.undo_stack.undo()
    assert doc.scene.displacement.curves[(JOINT, "rx")] is curve


def test_a_broken_tangent_moves_one_side_only(editor, doc, qtbot):
    curve = doc.scene.displacement.curves[(JOINT, "ry")]
    i = _smooth_key(curve)
    editor.set_selection([("ry", i)])
    editor.tangent_combo.setCurrentIndex(editor.tangent_combo.findData("broken"))
    editor.tangent_combo.activated.emit(editor.tangent_combo.currentIndex())
    broken = doc.scene.displacement.curves[(JOINT, "ry")]
    assert broken.tangents[i] == "broken"
    np.testing.assert_array_equal(broken.tangent_slopes()[i], curve.tangent_slopes()[i])
    _settle(qtbot, editor)
    start = editor.plot_widget.mapFromScene(editor.handle_scene_pos("ry", i, 0))
    _drag(qtbot, editor, start, start + QtCore.QPoint(0, 35))
    new = doc.scene.displacement.curves[(JOINT, "ry")]
    assert new.tangents[i] == "broken"
    assert new.tangent_slopes()[i, 1] == broken.tangent_slopes()[i, 1]     # out side kept
    assert new.tangent_slopes()[i, 0] != broken.tangent_slopes()[i, 0]
    after = np.linspace(new.frames[i], new.frames[i + 1], 7)
    np.testing.assert_array_equal(new.evaluate(after), broken.evaluate(after))
    # flat and linear tangents, chosen for the key
    editor.set_tangent("flat")
    np.testing.assert_array_equal(doc.scene.displacement.curves[(JOINT, "ry")]
                                  .tangent_slopes()[i], [0.0, 0.0])


def test_the_selected_layer_alone_is_edited_and_weight_mute_are_commands(editor, doc, qtbot):
    solved = doc.scene.displacement
    assert [x.name for x in doc.scene.layers] == ["edit"]
    assert [editor.layer_combo.itemText(k) for k in range(editor.layer_combo.count())] == \
        ["solved (IK)", "edit"]
    editor.layer_combo.setCurrentIndex(1)
    editor.layer_combo.activated.emit(1)
    assert editor.layer == 1 and all(len(g.frames) == 0 for g in editor.key_graphs.values())
    assert editor.weight_box.isEnabled() and editor.mute_check.isEnabled()
    editor.add_keys(300, ["rx"])
    assert doc.scene.displacement is solved                  # the solved layer untouched
    keyed = doc.scene.layers[0].displacement.curves[(JOINT, "rx")]
    assert list(keyed.frames) == [300.0]
    # an animator key: the solved keys are drawn thin, not editable
    editor.set_selection([("rx", 0)])
    editor._set_single_key(value=10.0)
    assert doc.scene.layers[0].displacement.curves[(JOINT, "rx")].values[0] == \
        pytest.approx(10.0 / DEG)
    moved = doc.motion.rotations.copy()
    count = doc.undo_stack.count()
    editor.weight_box.setValue(0.5)
    assert doc.undo_stack.count() == count + 1 and doc.scene.layers[0].weight == 0.5
    editor.mute_check.setChecked(True)
    assert doc.undo_stack.count() == count + 2 and doc.scene.layers[0].mute
    np.testing.assert_array_equal(doc.motion.rotations, doc.scene.replace(
        layers=(doc.scene.layers[0].replace(mute=False, weight=0.0),)).motion.rotations)
    doc.undo_stack.undo()
    doc.undo_stack.undo()
    np.testing.assert_array_equal(doc.motion.rotations, moved)
    assert not editor.mute_check.isChecked() and editor.weight_box.value() == 1.0
    # a new layer is one command, and the editor edits it
    editor.new_layer_button.click()
    assert [x.name for x in doc.scene.layers] == ["edit", "edit 2"] and editor.layer == 2


def test_f_frames_the_selected_keys_and_a_frames_all(editor, doc, qtbot):
    curve = doc.scene.displacement.curves[(JOINT, "rz")]
    i = _roomy_key(curve)
    editor.set_selection([("rz", i), ("rz", i + 1)])
    editor.plot_widget.setFocus()
    qtbot.keyClick(editor.plot_widget, Qt.Key.Key_F)
    (x0, x1), (y0, y1) = editor.view_box.viewRange()
    assert x0 < curve.frames[i] < curve.frames[i + 1] < x1 and x1 - x0 < 30
    for k in (i, i + 1):
        assert y0 < curve.values[k] * DEG < y1
    qtbot.keyClick(editor.plot_widget, Qt.Key.Key_A)
    (x0, x1), _ = editor.view_box.viewRange()
    assert x0 < 0 and x1 > doc.scene.num_frames - 1


def test_constraint_names_elide_instead_of_overlapping(editor, doc, qtbot):
    base = doc.scene.constraints[0]
    crowd = [base.with_range(270 + 3 * k, 272 + 3 * k, 300 + k, 320 + k) for k in range(5)]
    crowd = [dataclasses.replace(c, name=f"a rather long constraint name number {k}")
             for k, c in enumerate(crowd)]
    doc.edit("Crowd", constraints=tuple(crowd))
    editor.view_box.setRange(xRange=(262, 338), padding=0)
    _settle(qtbot, editor)
    texts = editor.range_label_texts()
    names = [c.name for c in crowd]
    # every name drawn is the name or its start cut short; crowded, some are cut
    assert len(texts) == 5
    for text, name in zip(texts, names):
        assert text == name or (text.endswith("\u2026") and name.startswith(text[:-1]))
    assert any(t != n for t, n in zip(texts, names))
    # names on one line of text never overlap
    lines = {}
    for label, *_ in editor.range_labels:
        if label.textItem.toPlainText():
            box = label.sceneBoundingRect()
            lines.setdefault(round(box.top()), []).append((box.left(), box.right()))
    assert len(lines) > 1                                    # they use more than one line
    for boxes in lines.values():
        boxes.sort()
        for (l0, r0), (l1, _r1) in zip(boxes, boxes[1:]):
            assert r0 <= l1 + 1
    # alone, a name has room and shows whole
    doc.edit("One", constraints=(crowd[0],))
    editor.view_box.setRange(xRange=(262, 338), padding=0)
    _settle(qtbot, editor)
    assert editor.range_label_texts() == ["a rather long constraint name number 0"]
