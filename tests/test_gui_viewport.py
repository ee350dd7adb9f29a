"""The 3D viewport under a real GL context (Xvfb): drawing, picking, camera, visibility."""
from __future__ import annotations

import numpy as np
import pytest

from gui_support import SOLVE_WAIT_MS, WAIT_MS, count_colour, demo_document, require_gl, view_pixels


@pytest.fixture()
def view(qtbot):
    require_gl()
    from motion_composer.app.gui.viewport import Viewport
    doc = demo_document()
    v = Viewport(doc)
    qtbot.addWidget(v.widget)
    v.widget.resize(800, 600)
    v.widget.show()
    qtbot.waitExposed(v, timeout=WAIT_MS)
    doc.set_frame(300)
    v.frame_all()
    qtbot.wait(50)
    return doc, v


def _pixels(v, rgb, tol=40):
    return count_colour(view_pixels(v), rgb, tol)


def test_both_skeletons_are_drawn_where_forward_kinematics_puts_them(view):
    doc, v = view
    from motion_composer.app.gui.viewport import to_view
    fig = v.figures["target"]
    pos = doc.pose("target").positions[300]
    np.testing.assert_allclose(fig.points - fig.offset, to_view(pos), atol=1e-9)
    perf = v.figures["performer"]
    np.testing.assert_allclose(perf.points - perf.offset,
                               to_view(doc.pose("performer").positions[300]), atol=1e-9)
    # and they are really on screen: orange (target) and blue (performer) pixels
    assert _pixels(v, (242, 153, 64)) > 200
    assert _pixels(v, (115, 158, 217)) > 200


def test_a_picture_taken_right_after_a_change_shows_the_change(view, qtbot):
    """``render_image`` draws the view for the call: taken straight after a frame change
    and a camera change (no event processed, no frame swapped in between), it is the
    picture the view settles on, not the one before (``grabFramebuffer`` of the native GL
    window read what was drawn last: ``--frame 900 --screenshot`` showed frame 0's camera)."""
    doc, v = view
    v.frame_all()
    qtbot.waitUntil(lambda: not v.render_image().isNull(), timeout=WAIT_MS)
    before = view_pixels(v)
    doc.set_frame(700)
    v.set_view("top")
    now = view_pixels(v)
    assert np.abs(now - before).sum(axis=-1).astype(bool).mean() > 0.01
    with qtbot.waitSignal(v.frameSwapped, timeout=WAIT_MS):
        v.update()
    settled = view_pixels(v)
    np.testing.assert_array_equal(now, settled)
    # and it shows the target where the top view puts it at frame 700: orange pixels around
    # the root's projection
    from motion_composer.app.gui.viewport import to_view
    root = to_view(doc.pose("target").positions[700, 0]) + v.figures["target"].offset
    x, y = v.project(root[None])[0]
    ys, xs = np.nonzero(np.all(np.abs(now - (242, 153, 64)) < 40, axis=-1))
    assert len(xs) > 50
    assert np.hypot(xs.mean() - x, ys.mean() - y) < 0.25 * v.width()



def test_the_view_follows_the_frame(view):
    doc, v = view
    before = v.figures["target"].points.copy()
    doc.set_frame(600)
    assert not np.allclose(v.figures["target"].points, before)


def test_clicking_a_joint_selects_it_everywhere(view, qtbot):
    from motion_composer.app.gui.qt import QtCore
    doc, v = view
    j = doc.scene.target.skeleton.index["LeftHand"]
    x, y = v.project(v.figures["target"].points[[j]])[0]
    got = []
    doc.selectionChanged.connect(lambda side, name: got.append((side, name)))
    qtbot.mouseClick(v, QtCore.Qt.MouseButton.LeftButton,
                     pos=QtCore.QPoint(int(round(x)), int(round(y))))
    assert doc.selection == ("target", "LeftHand")
    assert got[-1] == ("target", "LeftHand")
    # the selected joint is drawn bigger, in the selection colour
    sizes = v.figures["target"].joints.size
    assert np.argmax(sizes) == j
    # the virtual bones of the selected mapping are highlighted on the performer
    assert v.virtual.visible()
    # a click on empty floor clears the selection
    qtbot.mouseClick(v, QtCore.Qt.MouseButton.LeftButton, pos=QtCore.QPoint(5, 5))
    assert doc.selection == ("", "")


def test_orbit_pan_zoom_and_frame_all(view, qtbot):
    from motion_composer.app.gui.qt import QtCore
    doc, v = view
    az, dist, center = v.opts["azimuth"], v.opts["distance"], v.opts["center"]
    qtbot.mousePress(v, QtCore.Qt.MouseButton.LeftButton, pos=QtCore.QPoint(400, 300))
    qtbot.mouseMove(v, QtCore.QPoint(460, 300))
    qtbot.mouseRelease(v, QtCore.Qt.MouseButton.LeftButton, pos=QtCore.QPoint(460, 300))
    assert v.opts["azimuth"] != az                                # left drag orbits
    assert doc.selection == ("", "")                              # a drag is not a click
    state = v.camera_state()
    v.set_camera_state({**state, "distance": state["distance"] * 3})
    assert v.opts["distance"] == pytest.approx(dist * 3 if False else state["distance"] * 3)
    v.frame_all()
    framed = v.camera_state()
    assert framed["distance"] < state["distance"] * 3
    assert center is not None


def test_hiding_and_overlaying(view):
    doc, v = view
    doc.set_viewer(show_performer=False)
    v.refresh()
    assert not v.figures["performer"].mesh.visible()
    doc.set_viewer(show_performer=True)
    doc.set_viewer(side_by_side=False)
    v.refresh()
    # overlaid: both start at the same place
    assert np.allclose(v.figures["performer"].offset[:2] + v._root_start("performer")[:2],
                       v.figures["target"].offset[:2] + v._root_start("target")[:2])


def test_constraint_goals_are_drawn(view):
    doc, v = view
    from motion_composer.app.gui.commands import push_constraints
    from motion_composer.engine.correction.constraints import Constraint, floor_constraint
    hand = doc.pose("target").positions[300, doc.scene.target.skeleton.index["LeftHand"]]
    push_constraints(doc, [Constraint("LeftHand", "position", {"point": hand + 0.1}, 280, 290,
                                      310, 320),
                           floor_constraint("LeftToeBase", doc.scene.num_frames, -0.9)])
    assert v.goals.visible() and v.planes.visible()
    # the floor plane (its goal point at the origin) is a pad at -0.9 under the toe, drawn
    # a hair above it
    from motion_composer.app.gui.viewport import PLANE_LIFT, to_view
    toe = doc.pose("target").positions[300, doc.scene.target.skeleton.index["LeftToeBase"]]
    pad = v.planes.opts["meshdata"].vertexes()
    hair = PLANE_LIFT * v._size()
    assert 0 < hair < 0.005
    np.testing.assert_allclose(pad.mean(axis=0),
                               to_view([toe[0], -0.9 + hair, toe[2]]) + v.figures["target"].offset,
                               atol=1e-5)
    np.testing.assert_allclose(pad[:, 2], pad[0, 2], atol=1e-6)          # level
    doc.undo_stack.undo()
    assert not v.goals.visible()


def test_each_kind_draws_its_goal_as_it_says(view):
    """A trajectory draws its path and the point of the frame; an orientation the goal's
    axes at the joint (x along the goal's x)."""
    doc, v = view
    from motion_composer.app.gui.commands import push_constraints
    from motion_composer.app.gui.viewport import to_view
    from motion_composer.engine.correction.constraints import Constraint
    sk = doc.scene.target.skeleton
    pos = doc.pose("target").positions
    hand, head = sk.index["LeftHand"], sk.index["Head"]
    turn = [0.0, np.sin(0.3), 0.0, np.cos(0.3)]
    push_constraints(doc, [
        Constraint("LeftHand", "trajectory", {"points": pos[290:311, hand] + [0, 0.1, 0]},
                   280, 290, 310, 320),
        Constraint("Head", "orientation", {"quaternion": turn}, 280, 290, 310, 320)])
    assert v.paths.visible() and v.goals.visible() and v.axes.visible()
    assert not v.planes.visible()
    off = v.figures["target"].offset
    # the GL items hold float32
    np.testing.assert_allclose(v.goals.pos[0], to_view(pos[300, hand] + [0, 0.1, 0]) + off,
                               atol=1e-5)
    axes = v.axes.pos
    assert axes.shape == (6, 3)
    np.testing.assert_allclose(axes[0], to_view(pos[300, head]) + off, atol=1e-5)
    x_axis = (axes[1] - axes[0]) / np.linalg.norm(axes[1] - axes[0])
    np.testing.assert_allclose(x_axis, to_view(np.array([np.cos(0.6), 0, -np.sin(0.6)])),
                               atol=1e-6)
    doc.undo_stack.undo()
    assert not v.axes.visible() and not v.paths.visible()


def test_a_gltf_character_is_drawn_as_a_skinned_mesh_that_follows_the_motion(qtbot, tmp_path):
    from conftest import shared_path
    from gui_support import skinned_character_in_window
    robot = shared_path("target_robot_expressive.glb")
    doc, _v, first, second, back = skinned_character_in_window(qtbot, tmp_path, robot)
    assert first.shape == second.shape and first.shape[0] > 1000
    assert np.abs(first - second).max() > 0.05            # the mesh moves with the motion
    # exported onto the character as glTF, with its mesh
    assert back.skeleton.names == doc.scene.target.skeleton.names and back.meshes


def test_a_position_goal_can_be_dragged_in_3d(view, qtbot):
    from motion_composer.app.gui.qt import QtCore
    from motion_composer.app.gui.commands import push_constraints
    from motion_composer.engine.correction.constraints import Constraint
    doc, v = view
    hand = doc.pose("target").positions[300, doc.scene.target.skeleton.index["LeftHand"]]
    push_constraints(doc, [Constraint("LeftHand", "position", {"point": hand + [0.05, 0.1, 0]},
                                      280, 290, 310, 320, name="reach")])
    v.set_active_constraint(0)
    count = doc.undo_stack.count()
    start = np.array(doc.scene.constraints[0].goal["point"])
    x, y = v.project((v._active_goal()[2])[None])[0]
    qtbot.mousePress(v, QtCore.Qt.MouseButton.LeftButton, pos=QtCore.QPoint(int(x), int(y)))
    qtbot.mouseMove(v, QtCore.QPoint(int(x), int(y) - 15))
    qtbot.wait(50)                                      # the live preview runs
    assert doc.undo_stack.count() == count               # a preview, not yet a command
    qtbot.mouseMove(v, QtCore.QPoint(int(x), int(y) - 30))
    qtbot.mouseRelease(v, QtCore.Qt.MouseButton.LeftButton,
                       pos=QtCore.QPoint(int(x), int(y) - 30))
    qtbot.waitUntil(lambda: doc.undo_stack.count() == count + 1, timeout=WAIT_MS)
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)     # the solve landed
    assert doc.undo_stack.undoText() == "Move goal of reach"
    goal = np.array(doc.scene.constraints[0].goal["point"])
    assert goal[1] > start[1] + 0.02                     # dragged up on screen: higher
    # the camera looks along the view; the goal moved in the plane facing it
    reached = doc.pose("target").positions[290:311, doc.scene.target.skeleton.index["LeftHand"]]
    assert np.linalg.norm(reached - goal, axis=1).max() < 2e-3
    doc.undo_stack.undo()
    np.testing.assert_allclose(doc.scene.constraints[0].goal["point"], start)


def test_the_grid_lies_on_the_projects_floor(view, qtbot):
    """A character stood on a raised floor walks on the grid, not above it: the grid is
    drawn at the project's floor (at 0 without one), and moves back on undo."""
    from motion_composer.app.gui.qt import QtGui
    doc, v = view

    def grid_height():
        return v.grid.transform().map(QtGui.QVector3D(0, 0, 0)).z()

    def lowest():
        fig = v.figures["target"]
        return float((fig.points - fig.offset)[:, 2].min())

    def performer_lowest():
        return float(v.figures["performer"].points[:, 2].min())

    assert doc.scene.project.floor is None and grid_height() == 0.0
    standing, before, performer = doc.scene.standing_floor(), lowest(), performer_lowest()
    assert doc.edit("Floor at 0.5 m", floor=0.5)
    assert grid_height() == pytest.approx(0.5) and v.grid_height == 0.5
    # the character is as high over the grid as it was over its own floor, and the performer
    # beside it is raised as much
    assert lowest() - grid_height() == pytest.approx(before - standing, abs=1e-9)
    assert performer_lowest() == pytest.approx(performer + 0.5 - standing, abs=1e-9)
    assert doc.edit("Floor keeps only the feet above it", stand_on_floor=False)
    assert grid_height() == pytest.approx(0.5)       # the floor is still where the feet go
    doc.undo_stack.undo()
    doc.undo_stack.undo()
    assert doc.scene.project.floor is None and grid_height() == 0.0
    assert lowest() == pytest.approx(before, abs=1e-12)
    assert performer_lowest() == pytest.approx(performer, abs=1e-12)
    # an edit that solves in the background moves the grid at once, before the solve lands
    assert doc.edit("Floor at 0.25 m", floor=0.25, solve=True)
    assert doc.pending and grid_height() == pytest.approx(0.25)
    qtbot.waitUntil(lambda: not doc.pending, timeout=SOLVE_WAIT_MS)
    assert grid_height() == pytest.approx(0.25)
