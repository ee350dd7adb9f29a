"""The window side of the retarget pose (issue 18): the gizmo's geometry, the binding panel's
pose and chain controls, the viewport's binding-pose mode with real mouse drags of the gizmo,
retarget profiles in the File menu and the quality panel following an edit.

Real clips: the bundled CMU walk on the bundled CMU T-pose skeleton (and the Mixamo character
of the shared data for the skinned view).
"""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from motion_composer.app.gui import pose_gizmo  # noqa: E402
from motion_composer.app.gui.binding_panel import BindingPanel  # noqa: E402
from motion_composer.app.gui.qt import QtCore, QtWidgets  # noqa: E402
from motion_composer.engine.conversion.chains import (ChainSettings, chains_of,  # noqa: E402
                                                      euler_to_offset, left_axis)
from motion_composer.engine.quaternions import about_axis, qconj, qmul, qrot  # noqa: E402

from conftest import clip_path  # noqa: E402
from gui_support import WAIT_MS, demo_document, quiet_window, require_gl, shown  # noqa: E402

Qt = QtCore.Qt
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def _angle_deg(q) -> float:
    """[deg] the angle of the turn ``q``."""
    q = np.asarray(q, dtype=float)
    return float(np.degrees(2 * np.arctan2(np.linalg.norm(q[:3]), abs(q[3]))))


def _same_turn(a, b) -> float:
    """[deg] the angle between two rotations."""
    return _angle_deg(qmul(qconj(np.asarray(a, float)), np.asarray(b, float)))


# ---------------------------------------------------------------------- gizmo geometry
def test_ring_geometry_and_turn_angles():
    rng = np.random.default_rng(18)
    for _ in range(20):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        center, radius = rng.normal(size=3), 0.1 + rng.random()
        pts = pose_gizmo.ring_points(center, axis, radius)
        np.testing.assert_allclose(np.linalg.norm(pts - center, axis=1), radius, rtol=1e-12)
        np.testing.assert_allclose((pts - center) @ axis, 0.0, atol=1e-12)
        a, b = rng.uniform(-np.pi, np.pi, size=2)
        start = pose_gizmo.ring_point(center, axis, radius, a)
        now = pose_gizmo.ring_point(center, axis, radius, b)
        expected = (b - a + np.pi) % (2 * np.pi) - np.pi
        assert pose_gizmo.turn_angle(center, axis, start, now) == pytest.approx(expected)
        # right-handed: turning the start point about the axis by the angle gives the other
        turned = center + qrot(about_axis(axis, expected), start - center)
        np.testing.assert_allclose(turned, now, atol=1e-12)
        # a point off the plane reads the same angle (its projection)
        assert pose_gizmo.turn_angle(center, axis, start, now + 0.3 * axis) == \
            pytest.approx(expected)
        # a ray through a ring point meets the plane there
        origin = now + rng.normal(size=3)
        hit = pose_gizmo.plane_hit(origin, now - origin, center, axis)
        np.testing.assert_allclose(hit, now, atol=1e-9)


def test_a_turn_about_a_binding_frame_axis_turns_the_joint_about_that_world_axis():
    rng = np.random.default_rng(7)
    rest_world = about_axis(np.array([0.3, 0.9, -0.2]) / np.linalg.norm([0.3, 0.9, -0.2]), 1.1)
    old = about_axis(np.array([1.0, 0.0, 0.0]), 0.4)
    world = qmul(rest_world, old)                       # the joint's world rotation, offset in
    frame = pose_gizmo.binding_frame(world, old)
    np.testing.assert_allclose(frame, rest_world, atol=1e-12)
    axes = pose_gizmo.ring_axes(frame)
    np.testing.assert_allclose(axes @ axes.T, np.eye(3), atol=1e-12)
    for k in range(3):
        angle = rng.uniform(-2, 2)
        new = pose_gizmo.turned(old, k, angle)
        # the new world rotation is the old one turned about the ring's world axis
        np.testing.assert_allclose(_same_turn(qmul(frame, new),
                                              qmul(about_axis(axes[k], angle), world)), 0.0,
                                   atol=1e-6)
    local = np.tile(IDENTITY, (5, 1))
    local[2] = qmul(about_axis(np.array([0.0, 0.0, 1.0]), 0.3), old)
    out = pose_gizmo.with_turn(local, 2, old, IDENTITY)
    np.testing.assert_allclose(out[[0, 1, 3, 4]], local[[0, 1, 3, 4]])
    assert _same_turn(out[2], about_axis(np.array([0.0, 0.0, 1.0]), 0.3)) < 1e-6


def test_the_nearest_ring_is_picked_within_its_radius():
    circle = np.stack([np.cos(np.linspace(0, 2 * np.pi, 73)),
                       np.sin(np.linspace(0, 2 * np.pi, 73))], axis=1)
    rings = [100 + 50 * circle, 100 + 20 * circle]
    assert pose_gizmo.nearest_ring(rings, 152, 100, 8) == 0
    assert pose_gizmo.nearest_ring(rings, 118, 100, 8) == 1
    assert pose_gizmo.nearest_ring(rings, 135, 100, 8) is None


# ---------------------------------------------------------------------- the binding panel
@pytest.fixture
def doc(qtbot):
    d = demo_document()
    assert d.scene.ready, d.scene.evaluation_error
    yield d
    d.close()


@pytest.fixture
def panel(qtbot, doc):
    return shown(qtbot, BindingPanel(doc), 460)


def _click(button):
    from PySide6.QtTest import QTest
    QTest.mouseClick(button, Qt.MouseButton.LeftButton)


def _local(doc, joint):
    """``(F, 4)`` the final motion's local rotations of ``joint``."""
    return doc.motion.rotations[:, doc.scene.target.skeleton.index[joint]]


def test_the_selected_joint_follows_the_selection_both_ways(panel, doc):
    doc.select("target", "LeftArm")
    assert panel.pose_joint.currentData() == "LeftArm" and panel.pose_target == "LeftArm"
    assert panel.mirror_button.text() == "Mirror to RightArm"
    # a performer joint selects the target joint mapped to it
    performer_joint = doc.scene.correspondence.pairs["RightForeArm"]
    doc.select("performer", performer_joint)
    assert panel.pose_joint.currentData() == "RightForeArm"
    # choosing in the panel selects it everywhere
    panel.pose_joint.setCurrentIndex(panel.pose_joint.findData("LeftUpLeg"))
    assert doc.selection == ("target", "LeftUpLeg")
    doc.select("", "")
    assert panel.pose_target is None and not any(s.isEnabled() for s in panel.angles)


def test_typed_angles_set_the_offset_merge_and_undo(qtbot, panel, doc):
    doc.select("target", "LeftArm")
    before = _local(doc, "LeftArm").copy()
    others = np.delete(doc.motion.rotations, doc.scene.target.skeleton.index["LeftArm"], axis=1)
    count = doc.undo_stack.count()
    x, y, z = panel.angles
    x.setValue(4.0)
    x.setValue(10.0)                               # one spin box's run: one step
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.undoText() == "Set LeftArm's pose offset to X 10.0, Y 0.0, Z 0.0 deg"
    q = doc.scene.bind_options.offset("LeftArm")
    assert _same_turn(q, euler_to_offset((10.0, 0.0, 0.0))) < 1e-9
    # every frame's local rotation of the joint is turned by the offset in its binding frame
    np.testing.assert_allclose(
        [_same_turn(a, b) for a, b in zip(_local(doc, "LeftArm"), qmul(before, q))], 0.0,
        atol=1e-6)
    # and no other joint's
    np.testing.assert_allclose(np.delete(doc.motion.rotations, doc.scene.target.skeleton.index[
        "LeftArm"], axis=1), others, atol=1e-12)
    z.setValue(-5.0)
    assert doc.undo_stack.count() == count + 1           # the same joint's angles merge
    assert _same_turn(doc.scene.bind_options.offset("LeftArm"),
                      euler_to_offset((10.0, 0.0, -5.0))) < 1e-9
    assert panel.pose_joint.currentText() == "LeftArm *"
    assert "LeftArm" in panel.pose_summary.text()
    doc.undo_stack.undo()
    assert _same_turn(doc.scene.bind_options.offset("LeftArm"), IDENTITY) < 1e-9
    assert [s.value() for s in panel.angles] == [0.0, 0.0, 0.0]
    np.testing.assert_allclose(_local(doc, "LeftArm"), before)


def test_mirror_gives_the_other_side_the_reflected_turn(panel, doc):
    doc.select("target", "LeftArm")
    panel.angles[0].setValue(12.0)
    panel.angles[2].setValue(-20.0)
    sk = doc.scene.target.skeleton
    world_turn = {}
    count = doc.undo_stack.count()
    _click(panel.mirror_button)
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.undoText() == "Mirror LeftArm's pose offset to RightArm"
    mirrored = doc.scene.binding
    for joint in ("LeftArm", "RightArm"):
        j = sk.index[joint]
        frame = qmul(mirrored.rest_world[j], qconj(doc.scene.bind_options.offset(joint)))
        world_turn[joint] = qmul(mirrored.rest_world[j], qconj(frame))
    # the right arm's world turn is the left's reflected through the sagittal plane: the
    # same angle, the axis reflected and negated (an axis is a pseudo-vector)
    n = left_axis(mirrored)
    left, right = world_turn["LeftArm"], world_turn["RightArm"]
    assert _angle_deg(right) == pytest.approx(_angle_deg(left), abs=1e-6)
    v = left[:3]
    np.testing.assert_allclose(right[:3] * np.sign(right[3]),
                               -(v - 2 * np.dot(v, n) * n) * np.sign(left[3]), atol=1e-9)
    assert _angle_deg(right) > 20


def test_reset_joint_and_reset_all(panel, doc):
    doc.select("target", "LeftArm")
    panel.angles[1].setValue(15.0)
    doc.select("target", "RightUpLeg")
    panel.angles[0].setValue(-8.0)
    assert {j for j, _q in doc.scene.bind_options.pose_offsets} == {"LeftArm", "RightUpLeg"}
    count = doc.undo_stack.count()
    _click(panel.reset_joint_button)
    assert {j for j, _q in doc.scene.bind_options.pose_offsets} == {"LeftArm"}
    assert doc.undo_stack.undoText() == "Reset RightUpLeg's pose offset"
    assert not panel.reset_joint_button.isEnabled()
    _click(panel.reset_all_button)
    assert doc.scene.bind_options.pose_offsets == ()
    assert doc.undo_stack.count() == count + 2 and not panel.reset_all_button.isEnabled()
    doc.undo_stack.undo()
    assert {j for j, _q in doc.scene.bind_options.pose_offsets} == {"LeftArm"}


def _slider_handle(slider) -> QtCore.QPoint:
    opt = QtWidgets.QStyleOptionSlider()
    slider.initStyleOption(opt)
    rect = slider.style().subControlRect(QtWidgets.QStyle.ComplexControl.CC_Slider, opt,
                                         QtWidgets.QStyle.SubControl.SC_SliderHandle, slider)
    return rect.center()


def test_the_chain_table_edits_each_chain_as_one_command(qtbot, panel, doc):
    from PySide6.QtTest import QTest
    chains = chains_of(doc.scene.target.skeleton, doc.scene.binding.rest_positions)
    assert list(panel.chain_rows) == list(chains)
    assert {"spine", "arm_l", "arm_r", "leg_l", "leg_r"} <= set(chains)
    arm = panel.chain_rows["arm_l"]
    assert arm["weight"].value == 1.0 and arm["twist"].isChecked()
    # a real drag of the weight slider to its left end: live, and one undo step
    slider = arm["weight"].slider
    panel.chain_table.scrollTo(panel.chain_table.model().index(
        list(chains).index("arm_l"), 1))
    count = doc.undo_stack.count()
    start = _slider_handle(slider)
    QTest.mousePress(slider, Qt.MouseButton.LeftButton, pos=start)
    for x in range(start.x(), -20, -6):
        QTest.mouseMove(slider, QtCore.QPoint(x, start.y()))
    assert doc.scene.bind_options.chain("arm_l").weight < 1.0       # live while dragging
    QTest.mouseRelease(slider, Qt.MouseButton.LeftButton, pos=QtCore.QPoint(-20, start.y()))
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.undoText() == "Set left arm weight to 0.00"
    assert doc.scene.bind_options.chain("arm_l") == ChainSettings(weight=0.0)
    assert arm["weight"].label.text() == "0.00"
    # weight 0: the arm keeps the character's binding pose on every frame
    b = doc.scene.binding
    for joint in chains["arm_l"]:
        j = b.target.index[joint]
        np.testing.assert_allclose(
            [_same_turn(q, b.rest_local[j]) for q in doc.motion.rotations[:, j]], 0.0,
            atol=1e-6)
    # twist off and a chain's own "chain turns": one command each
    QTest.mouseClick(panel.chain_rows["spine"]["twist"], Qt.MouseButton.LeftButton)
    assert doc.scene.bind_options.chain("spine").twist is False
    assert doc.undo_stack.undoText() == "Set spine twist off"
    panel.chain_rows["spine"]["distribute"].setCurrentIndex(2)
    assert doc.scene.bind_options.chain("spine").distribute == "first"
    assert doc.undo_stack.count() == count + 3
    # the fingers have no end effector: no IK blend
    for name in ("fingers_l", "fingers_r"):
        if name in panel.chain_rows:
            assert not panel.chain_rows[name]["ik_blend"].isEnabled()
    assert panel.chain_rows["arm_r"]["ik_blend"].isEnabled()
    for _ in range(3):
        doc.undo_stack.undo()
    assert doc.scene.bind_options.chains == ()
    assert arm["weight"].value == 1.0 and panel.chain_rows["spine"]["twist"].isChecked()


def test_an_ik_blend_edit_solves_and_the_hand_reaches(qtbot, panel, doc):
    blend = panel.chain_rows["arm_r"]["ik_blend"]
    count = doc.undo_stack.count()
    blend.slider.setValue(50)
    blend.slider.setValue(100)                     # one slider's run: one step, one solve
    assert doc.undo_stack.count() == count + 1
    assert doc.scene.bind_options.chain("arm_r").ik_blend == 1.0
    assert doc.undo_stack.undoText() == "Set right arm IK blend to 1.00"
    qtbot.waitUntil(lambda: not doc.pending, timeout=WAIT_MS * 4)
    reach = [c for c in doc.scene.constraints if c.name == "reach arm_r"]
    assert len(reach) == 1 and reach[0].auto
    frames = np.arange(reach[0].start, reach[0].end + 1)
    hand = doc.pose("target").positions[frames,
                                        doc.scene.target.skeleton.index[reach[0].joint]]
    miss = np.linalg.norm(hand - reach[0].goal_point(frames), axis=1)
    assert np.percentile(miss, 90) < 0.005, np.percentile(miss, [50, 90, 100])
    assert doc.undo_stack.count() == count + 1       # the solve landed in the same step
    doc.undo_stack.undo()
    assert doc.scene.bind_options.chain("arm_r").ik_blend == 0.0
    assert blend.value == 0.0 and not doc.scene.constraints


def test_edit_in_the_viewport_is_the_viewer_option(panel, doc):
    assert not panel.pose_edit.isChecked()
    panel.pose_edit.setChecked(True)
    assert doc.scene.viewer.options["pose_edit"] is True
    doc.set_viewer_options(pose_edit=False)
    assert not panel.pose_edit.isChecked()


# ---------------------------------------------------------------------- the viewport
@pytest.fixture()
def view(qtbot):
    require_gl()
    from motion_composer.app.gui.viewport import Viewport
    doc = demo_document()
    v = Viewport(doc)
    qtbot.addWidget(v.widget)
    v.widget.resize(900, 700)
    v.widget.show()
    qtbot.waitExposed(v, timeout=WAIT_MS)
    doc.set_frame(300)
    v.set_option("pose_edit", True)
    v.set_view("front")
    yield doc, v
    doc.close()


def test_the_binding_pose_is_shown_beside_the_reference_pose(view):
    from motion_composer.app.gui.viewport import to_view
    doc, v = view
    b = doc.scene.binding
    target, performer = v.figures["target"], v.figures["performer"]
    np.testing.assert_allclose(target.points - target.offset, to_view(b.rest_positions),
                               atol=1e-9)
    np.testing.assert_allclose(performer.points - performer.offset,
                               to_view(b.performer_rest_positions), atol=1e-9)
    assert abs(target.offset[0] - performer.offset[0]) > 0.5 * v._size()    # beside it
    assert "binding pose" in target.label.text and "reference pose" in performer.label.text
    doc.set_frame(600)                                   # the frame does not move it
    np.testing.assert_allclose(target.points - target.offset, to_view(b.rest_positions),
                               atol=1e-9)
    assert not any(r.visible() for r in v.rings)         # no joint selected: no gizmo
    # a performer joint puts the gizmo on the target joint mapped to it
    doc.select("performer", doc.scene.correspondence.pairs["LeftArm"])
    assert v.gizmo()[0] == "LeftArm" and all(r.visible() for r in v.rings)
    v.set_option("pose_edit", False)
    assert not any(r.visible() for r in v.rings)
    np.testing.assert_allclose(v.figures["target"].points - v.figures["target"].offset,
                               to_view(doc.pose("target").positions[600]), atol=1e-9)


def _facing(v):
    """``(3,)`` |cos| between each gizmo ring's normal and the line of sight to it."""
    _joint, _j, center, normals, _radius = v.gizmo()
    eye = np.array(v.cameraPosition())
    return np.abs(normals @ ((center - eye) / np.linalg.norm(center - eye)))


def _ring(v, k):
    """Gizmo ring ``k``: (k, centre, normal, radius)."""
    _joint, _j, center, normals, radius = v.gizmo()
    return k, center, normals[k], radius


def _facing_ring(v):
    """The gizmo ring most nearly facing the camera."""
    return _ring(v, int(np.argmax(_facing(v))))


def _pixel(v, point) -> QtCore.QPoint:
    x, y = v.project(np.asarray(point)[None])[0]
    return QtCore.QPoint(int(round(x)), int(round(y)))


def _drag_points(v, center, normal, radius, degrees, steps=6):
    """Pixels along the ring from angle 0.5 rad to 0.5 rad + ``degrees``."""
    angles = 0.5 + np.radians(degrees) * np.linspace(0, 1, steps + 1)
    return [_pixel(v, pose_gizmo.ring_point(center, normal, radius, a)) for a in angles]


def test_dragging_a_ring_turns_the_joint_by_the_rings_angle_and_undo_restores_it(view, qtbot):
    from motion_composer.app.gui.viewport import to_view
    doc, v = view
    sk = doc.scene.target.skeleton
    doc.select("target", "LeftArm")
    assert all(r.visible() for r in v.rings)
    k, center, normal, radius = _facing_ring(v)
    before_options = doc.scene.bind_options
    before = doc.scene.binding.rest_positions.copy()
    count = doc.undo_stack.count()
    points = _drag_points(v, center, normal, radius, 30.0)
    qtbot.mousePress(v, Qt.MouseButton.LeftButton, pos=points[0])
    assert v._pose_drag is not None and v._pose_drag.axis == k
    for p in points[1:4]:
        qtbot.mouseMove(v, p)
    # live: the drawn hand has moved, no command yet
    hand = sk.index["LeftHand"]
    fig = v.figures["target"]
    assert np.linalg.norm(fig.points[hand] - fig.offset - to_view(before[hand])) > 0.01
    assert doc.undo_stack.count() == count
    for p in points[4:]:
        qtbot.mouseMove(v, p)
    qtbot.mouseRelease(v, Qt.MouseButton.LeftButton, pos=points[-1])
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.undoText() == "Turn LeftArm in the binding pose"
    # the ring's geometry: 30 degrees right-handed about its normal, which is the binding
    # frame's axis k; to a pixel's rounding
    q = doc.scene.bind_options.offset("LeftArm")
    assert _same_turn(q, about_axis(np.eye(3)[k], np.radians(30.0))) < 1.0
    # the elbow has turned about the ring's world axis through the shoulder
    b = doc.scene.binding
    shoulder, elbow = sk.index["LeftArm"], sk.index["LeftForeArm"]
    np.testing.assert_allclose(b.rest_positions[shoulder], before[shoulder], atol=1e-9)
    expected = qrot(about_axis(_engine(normal), np.radians(30.0)),
                    before[elbow] - before[shoulder])
    assert np.linalg.norm(b.rest_positions[elbow] - b.rest_positions[shoulder] - expected) \
        < np.radians(1.0) * np.linalg.norm(expected)
    # undo restores it
    doc.undo_stack.undo()
    assert doc.scene.bind_options == before_options
    np.testing.assert_allclose(doc.scene.binding.rest_positions, before)
    np.testing.assert_allclose(fig.points - fig.offset, to_view(before), atol=1e-9)


def test_each_ring_seen_obliquely_turns_about_its_own_axis(view, qtbot):
    doc, v = view
    v.setCameraPosition(azimuth=-50, elevation=30)
    doc.select("target", "RightForeArm")
    seen = np.flatnonzero(_facing(v) > 0.35)
    assert len(seen) >= 2
    for k in seen:
        index = doc.undo_stack.index()
        _k, center, normal, radius = _ring(v, k)
        points = _drag_points(v, center, normal, radius, -40.0)
        qtbot.mousePress(v, Qt.MouseButton.LeftButton, pos=points[0])
        assert v._pose_drag.axis == k
        for p in points[1:]:
            qtbot.mouseMove(v, p)
        qtbot.mouseRelease(v, Qt.MouseButton.LeftButton, pos=points[-1])
        assert doc.undo_stack.index() == index + 1
        q = doc.scene.bind_options.offset("RightForeArm")
        # a pixel's rounding weighs more on a ring seen at a slant
        assert _same_turn(q, about_axis(np.eye(3)[k], np.radians(-40.0))) < 2.0, k
        doc.undo_stack.undo()
        assert doc.scene.bind_options.pose_offsets == ()


def _engine(view_vector):
    """A view-space direction in engine axes (to_view's inverse)."""
    x, y, z = view_vector
    return np.array([x, z, -y])


def test_esc_and_a_right_click_cancel_a_drag(view, qtbot):
    doc, v = view
    doc.select("target", "RightUpLeg")
    k, center, normal, radius = _facing_ring(v)
    shown = v.figures["target"].points.copy()
    count = doc.undo_stack.count()
    points = _drag_points(v, center, normal, radius, 25.0)
    qtbot.mousePress(v, Qt.MouseButton.LeftButton, pos=points[0])
    for p in points[1:]:
        qtbot.mouseMove(v, p)
    assert not np.allclose(v.figures["target"].points, shown)
    qtbot.keyClick(v, Qt.Key.Key_Escape)
    assert v._pose_drag is None
    np.testing.assert_allclose(v.figures["target"].points, shown)
    camera = v.camera_state()
    qtbot.mouseMove(v, points[0])              # the button still held: no orbit either
    assert v.camera_state() == camera
    qtbot.mouseRelease(v, Qt.MouseButton.LeftButton, pos=points[-1])
    assert doc.undo_stack.count() == count and doc.scene.bind_options.pose_offsets == ()
    # a right click during the drag cancels it too
    qtbot.mousePress(v, Qt.MouseButton.LeftButton, pos=points[0])
    for p in points[1:]:
        qtbot.mouseMove(v, p)
    qtbot.mousePress(v, Qt.MouseButton.RightButton, pos=points[-1])
    qtbot.mouseRelease(v, Qt.MouseButton.RightButton, pos=points[-1])
    qtbot.mouseRelease(v, Qt.MouseButton.LeftButton, pos=points[-1])
    np.testing.assert_allclose(v.figures["target"].points, shown)
    assert doc.undo_stack.count() == count and doc.scene.bind_options.pose_offsets == ()
    # and the next drag works again
    qtbot.mousePress(v, Qt.MouseButton.LeftButton, pos=points[0])
    for p in points[1:]:
        qtbot.mouseMove(v, p)
    qtbot.mouseRelease(v, Qt.MouseButton.LeftButton, pos=points[-1])
    assert doc.undo_stack.count() == count + 1


def _ring_pixels_drawn(v) -> list[int]:
    """How many pixels of each ring's colour the view shows."""
    from gui_support import count_colour, view_pixels
    pixels = view_pixels(v)
    return [count_colour(pixels, np.array(c[:3]) * 255) for c in pose_gizmo.RING_COLORS]


def test_the_rings_are_drawn_over_the_figure(view, qtbot):
    doc, v = view
    before = np.array(_ring_pixels_drawn(v))         # the performer's blue is near the z ring's
    doc.select("target", "LeftArm")
    qtbot.waitUntil(lambda: np.min(np.array(_ring_pixels_drawn(v)) - before) > 30,
                    timeout=WAIT_MS)


# ---------------------------------------------------------------------- profiles, quality
def _window(qtbot, tmp_path, monkeypatch):
    w = quiet_window(qtbot, tmp_path, monkeypatch)
    w.show()
    qtbot.waitExposed(w, timeout=WAIT_MS)
    assert w.import_file("performer", clip_path("cmu_131_01_walk.bvh"))
    assert w.import_file("target", clip_path("cmu_rest_tpose.bvh"))
    assert w.doc.scene.ready
    return w


def _menu_action(w, text):
    for menu in w.menuBar().findChildren(QtWidgets.QMenu):
        for action in menu.actions():
            if action.text().replace("&", "") == text:
                return action
    raise AssertionError(text)


def test_a_retarget_profile_saves_and_loads_as_one_command(qtbot, tmp_path, monkeypatch):
    w = _window(qtbot, tmp_path, monkeypatch)
    doc = w.doc
    q = euler_to_offset((0.0, 0.0, 15.0))
    options = doc.scene.bind_options.with_offset("LeftArm", q).with_chain(
        "leg_r", ChainSettings(weight=0.5, twist=False))
    doc.edit("Set up", bind_options=options)
    saved = doc.scene.bind_options
    path = tmp_path / "cmu.mcprofile"
    w.ask_save_path = lambda *a: str(tmp_path / "cmu")          # the suffix is added
    _menu_action(w, "Save Retarget Profile...").trigger()
    assert path.exists() and not w.errors
    doc.edit("Forget", bind_options=doc.scene.bind_options.without_offsets().with_chain(
        "leg_r", None))
    count = doc.undo_stack.count()
    w.ask_open_path = lambda *a: str(path)
    _menu_action(w, "Load Retarget Profile...").trigger()
    assert not w.errors
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.undoText() == "Load retarget profile cmu.mcprofile"
    assert doc.scene.bind_options == saved
    assert _same_turn(doc.scene.bind_options.offset("LeftArm"), q) < 1e-9
    doc.undo_stack.undo()
    assert doc.scene.bind_options.pose_offsets == ()


def test_a_bad_profile_shows_a_dialog_and_changes_nothing(qtbot, tmp_path, monkeypatch):
    import json
    w = _window(qtbot, tmp_path, monkeypatch)
    doc = w.doc
    count, scene = doc.undo_stack.count(), doc.scene
    bad = tmp_path / "bad.mcprofile"
    bad.write_text('{"format": "motion-composer-profile", "version": 1, "corr')
    assert not w.load_profile(bad)
    assert len(w.errors) == 1 and "bad.mcprofile" in w.errors[0]
    # a profile naming a joint the target does not have
    good = tmp_path / "good.mcprofile"
    assert w.save_profile(good)
    data = json.loads(good.read_text())
    data["binding"]["pose_offsets"] = {"NoSuchJoint": [0.0, 0.0, 15.0]}
    wrong = tmp_path / "wrong.mcprofile"
    wrong.write_text(json.dumps(data))
    assert not w.load_profile(wrong)
    assert len(w.errors) == 2 and "NoSuchJoint" in w.errors[1]
    assert doc.undo_stack.count() == count and doc.scene is scene
    assert w.isVisible()


def test_the_quality_panel_follows_an_offset_edit(qtbot, tmp_path, monkeypatch):
    w = _window(qtbot, tmp_path, monkeypatch)
    doc, quality = w.doc, w.quality_panel
    quality.show_quality(doc.scene.quality())

    def error(joint):
        return next(b["max_error_deg"] for b in quality.quality["bone_directions"]
                    if b["joint"] == joint)

    assert error("LeftForeArm") < 0.01                 # rest alignment: exact directions
    # turn the upper arm about the binding-frame axis most across its bone
    b = doc.scene.binding
    sk = b.target
    j, elbow = sk.index["LeftArm"], sk.index["LeftForeArm"]
    bone = b.rest_positions[elbow] - b.rest_positions[j]
    axes = pose_gizmo.ring_axes(pose_gizmo.binding_frame(b.rest_world[j], IDENTITY))
    k = int(np.argmin(np.abs(axes @ (bone / np.linalg.norm(bone)))))
    panel = w.binding_panel
    doc.select("target", "LeftArm")
    panel.angles[k].setValue(10.0)
    assert 8.0 < error("LeftForeArm") <= 10.0 + 1e-6
    assert "not solved" in quality.status.text()
    row = next(i for i in quality.rows("bone_directions") if i.text(0) == "LeftForeArm")
    assert float(row.text(1).split()[0]) == pytest.approx(error("LeftForeArm"), abs=0.06)
    doc.undo_stack.undo()
    assert error("LeftForeArm") < 0.01


def test_the_window_shares_the_joint_and_the_mode_between_its_panels(qtbot, tmp_path,
                                                                     monkeypatch):
    from PySide6.QtTest import QTest
    w = _window(qtbot, tmp_path, monkeypatch)
    doc, panel, corr = w.doc, w.binding_panel, w.correspondence_panel
    # a click in the correspondence editor's target tree selects the binding panel's joint
    w.correspondence_dock.raise_()
    tree = corr.target_tree
    item = tree.items["LeftArm"]
    tree.scrollToItem(item)
    QTest.mouseClick(tree.viewport(), Qt.MouseButton.LeftButton,
                     pos=tree.visualItemRect(item).center())
    assert doc.selection == ("target", "LeftArm")
    assert panel.pose_joint.currentData() == "LeftArm"
    # and the panel's choice selects it in the tree
    panel.pose_joint.setCurrentIndex(panel.pose_joint.findData("RightUpLeg"))
    assert tree.selected_joint() == "RightUpLeg"
    # View > Edit Binding Pose, the panel's check box and the viewport's mode are one
    action = _menu_action(w, "Edit Binding Pose")
    action.trigger()
    assert panel.pose_edit.isChecked() and w.viewport.option("pose_edit")
    panel.pose_edit.setChecked(False)
    assert not action.isChecked() and not w.viewport.option("pose_edit")


def test_two_slider_drags_in_a_row_are_two_steps(panel, doc):
    count = doc.undo_stack.count()
    for name, values in (("arm_l", (90, 80, 70)), ("arm_r", (95, 85, 75)),
                         ("arm_l", (60, 50))):
        for value in values:
            panel.chain_rows[name]["weight"].slider.setValue(value)
    assert doc.undo_stack.count() == count + 3
    assert doc.undo_stack.undoText() == "Set left arm weight to 0.50"
    doc.undo_stack.undo()
    assert doc.scene.bind_options.chain("arm_l").weight == 0.7
    doc.undo_stack.undo()
    assert doc.scene.bind_options.chain("arm_r").weight == 1.0
    assert doc.undo_stack.undoText() == "Set left arm weight to 0.70"
