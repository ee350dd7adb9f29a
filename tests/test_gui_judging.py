"""Judging motion in the viewport (issue 16), in the real main window under Xvfb: the follow
camera, onion-skin ghosts and foot trails drawn where forward kinematics puts them (pixel
checks), framing and the named views, labels and the skinned mesh's lighting, the layout,
repaints on a frame change, and files dropped on the window."""
from __future__ import annotations

import numpy as np
import pytest

from gui_support import WAIT_MS, quiet_window, require_gl, view_pixels


@pytest.fixture()
def window(qtbot, tmp_path, monkeypatch):
    """The real window on the bundled walk (performer) and T-pose (target), shown, frame 300."""
    require_gl()
    from conftest import clip_path
    w = quiet_window(qtbot, tmp_path, monkeypatch)
    w.show()
    qtbot.waitExposed(w, timeout=WAIT_MS)
    qtbot.waitExposed(w.viewport, timeout=WAIT_MS)
    w.windowHandle().requestActivate()            # the View menu's shortcuts need it
    qtbot.waitUntil(w.isActiveWindow, timeout=WAIT_MS)
    assert w.import_file("performer", clip_path("cmu_131_01_walk.bvh"))
    assert w.import_file("target", clip_path("cmu_rest_tpose.bvh"))
    assert w.doc.scene.ready, w.errors
    w.doc.set_frame(300)
    w.viewport.frame_all()
    yield w
    w.doc.undo_stack.setClean()


def _image(qtbot, v) -> np.ndarray:
    """The viewport's pixels ``(H, W, 3)`` RGB, after it has drawn what it was last told."""
    v.update()
    qtbot.wait(30)
    return view_pixels(v)


def _changed(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """``(N, 2)`` x, y of the pixels that differ between two images."""
    ys, xs = np.nonzero(np.abs(before - after).sum(axis=-1) > 30)
    return np.stack([xs, ys], axis=1)


def _near(pixels: np.ndarray, points: np.ndarray, radius: float) -> np.ndarray:
    """For each pixel ``(N, 2)``, whether a projected point ``(M, 2)`` is within ``radius``."""
    d = np.linalg.norm(pixels[:, None, :] - points[None, :, :], axis=-1)
    return d.min(axis=1) <= radius


def _key(qtbot, widget, key, modifier=None):
    from motion_composer.app.gui.qt import QtCore
    qtbot.keyClick(widget, key, modifier or QtCore.Qt.KeyboardModifier.NoModifier)


def test_the_follow_camera_keeps_the_root_in_view_over_the_walk(window, qtbot):
    from motion_composer.app.gui.qt import QtCore
    from motion_composer.app.gui.viewport import to_view
    doc, v = window.doc, window.viewport
    doc.set_viewer(show_performer=False)
    v.opts["distance"] = 2.0                       # close: the walk leaves a still camera
    pose = doc.pose("target").positions

    def root_pixels():
        out = []
        for f in range(0, doc.scene.num_frames, 60):
            doc.set_frame(f)
            root = to_view(pose[f, 0]) + v.figures["target"].offset
            out.append(v.project(root[None])[0])
        return np.array(out)

    inside = lambda px: (px[:, 0] >= 0) & (px[:, 0] < v.width()) & \
        (px[:, 1] >= 0) & (px[:, 1] < v.height())                    # noqa: E731
    assert not inside(root_pixels()).all()         # without it the root walks out of view
    _key(qtbot, window, QtCore.Qt.Key.Key_F, QtCore.Qt.KeyboardModifier.ShiftModifier)
    assert v.option("follow_root") and window.view_actions["follow_root"].isChecked()
    px = root_pixels()
    assert inside(px).all()
    centre = np.array([v.width() / 2, v.height() / 2])
    assert np.abs(px[:, 0] - centre[0]).max() < 0.1 * v.width()     # on the centre line
    _key(qtbot, window, QtCore.Qt.Key.Key_F, QtCore.Qt.KeyboardModifier.ShiftModifier)
    assert not v.option("follow_root")


def test_onion_skin_ghosts_are_drawn_where_forward_kinematics_puts_them(window, qtbot):
    from motion_composer.app.gui.qt import QtCore
    from motion_composer.app.gui.viewport import GHOST_OFFSETS, to_view
    doc, v = window.doc, window.viewport
    doc.set_viewer(show_performer=False)
    v.frame_all()
    before = _image(qtbot, v)
    _key(qtbot, window, QtCore.Qt.Key.Key_O)
    assert v.option("onion_skin")
    after = _image(qtbot, v)
    pose, off = doc.pose("target").positions, v.figures["target"].offset
    sk = doc.scene.target.skeleton
    child = np.flatnonzero(sk.parents >= 0)
    shown = [g for g in v.ghosts if g.visible()]
    assert len(shown) == len(GHOST_OFFSETS)
    for ghost, offset in zip(v.ghosts, GHOST_OFFSETS):
        # the ghost's bones run from each parent's FK position to its child's at f + offset
        segments = ghost.pos.reshape(-1, 2, 3)
        pts = to_view(pose[300 + offset]) + off
        np.testing.assert_allclose(segments[:, 0], pts[sk.parents[child]], atol=1e-5)
        np.testing.assert_allclose(segments[:, 1], pts[child], atol=1e-5)
    # on screen: new pixels appear, along the ghosts' bones (and nowhere else)
    changed = _changed(before, after)
    assert len(changed) > 300
    ghost_points = []
    for o in GHOST_OFFSETS:
        pts = to_view(pose[300 + o]) + off
        for t in np.linspace(0, 1, 9):
            ghost_points.append(pts[sk.parents[child]] * t + pts[child] * (1 - t))
    near = _near(changed.astype(float), v.project(np.concatenate(ghost_points)), 12)
    assert near.mean() > 0.95
    _key(qtbot, window, QtCore.Qt.Key.Key_O)
    assert not any(g.visible() for g in v.ghosts)


def test_foot_trails_follow_the_feet_with_planted_frames_and_contacts_on_the_floor(window,
                                                                                  qtbot):
    from motion_composer.app.gui.qt import QtCore
    from motion_composer.app.gui.viewport import to_view
    from motion_composer.engine.correction.contacts import detect_contacts, find_feet
    doc, v = window.doc, window.viewport
    doc.set_viewer(show_performer=False, play_range=(200, 420))
    v.frame_all()
    before = _image(qtbot, v)
    _key(qtbot, window, QtCore.Qt.Key.Key_T)
    assert v.option("foot_trails") and v.trail.visible()
    after = _image(qtbot, v)
    trails = v.foot_trails()
    sk = doc.scene.target.skeleton
    feet = find_feet(sk)
    assert trails.joints == [n for pair in feet for n in pair if n is not None]
    pose, off = doc.pose("target").positions, v.figures["target"].offset
    ankle = sk.index[feet[0][0]]
    path = to_view(pose[200:421, ankle]) + off
    # the trail's first segments are the first ankle's path over the play range
    segments = v.trail.pos.reshape(-1, 2, 3)[:220]
    np.testing.assert_allclose(segments[:, 0], path[:-1], atol=1e-5)
    np.testing.assert_allclose(segments[:, 1], path[1:], atol=1e-5)
    # planted frames: those of the contacts detected on the motion shown
    planted = np.zeros(221, dtype=bool)
    for c in detect_contacts(doc.motion, feet):
        a, b = max(c.start, 200), min(c.end, 420)
        if c.joint == feet[0][0] and a <= b:
            planted[a - 200:b - 200 + 1] = True
    assert 0 < planted.sum() < 221
    np.testing.assert_array_equal(trails.planted[0], planted)
    # on screen, along the trails
    changed = _changed(before, after)
    assert len(changed) > 100
    drawn = to_view(trails.paths) + off
    near = _near(changed.astype(float), v.project(drawn.reshape(-1, 3)), 10)
    assert near.mean() > 0.9
    # the contacts active now lie on the floor, under the planted joint
    f = 200 + int(np.flatnonzero(planted)[0])
    doc.set_frame(f)
    assert v.contacts.visible()
    quad = v.contacts.opts["meshdata"].vertexes()[:4]
    floor = to_view(np.array([0.0, trails.floor, 0.0]))[2] + off[2]
    np.testing.assert_allclose(quad[:, 2], floor, atol=1e-5)
    np.testing.assert_allclose(quad.mean(axis=0)[:2], path[f - 200, :2], atol=1e-5)


def test_the_selected_constraints_goal_is_always_visible(window):
    from motion_composer.app.gui.commands import push_constraints
    from motion_composer.engine.correction.constraints import Constraint
    doc, v = window.doc, window.viewport
    hand = doc.pose("target").positions[100, doc.scene.target.skeleton.index["LeftHand"]]
    push_constraints(doc, [Constraint("LeftHand", "position", {"point": hand + 0.1}, 80, 90,
                                      110, 120, name="reach")])
    doc.set_frame(500)                              # far outside the constraint
    v.set_active_constraint(None)
    assert not v.goals.visible()
    v.set_active_constraint(0)
    assert v.goals.visible()
    np.testing.assert_allclose(v.goals.pos[0], v._active_goal()[2], atol=1e-5)


def test_framing_shows_everything_and_f_after_an_orbit_is_not_grazing(window, qtbot):
    from motion_composer.app.gui.qt import QtCore
    from motion_composer.app.gui.viewport import FRAME_ELEVATION, VIEWS
    v = window.viewport
    v.setCameraPosition(elevation=88.0, azimuth=10.0)        # an orbit to straight above
    _key(qtbot, v, QtCore.Qt.Key.Key_F)
    assert v.opts["elevation"] == FRAME_ELEVATION and v.opts["azimuth"] == 10.0
    for which in ("performer", "target"):                    # heads and feet in view
        px = v.project(v.figures[which].points)
        assert (px[:, 0] > 0).all() and (px[:, 0] < v.width()).all()
        assert (px[:, 1] > 0).all() and (px[:, 1] < v.height()).all()
    for key, name in ((QtCore.Qt.Key.Key_1, "front"), (QtCore.Qt.Key.Key_3, "side"),
                      (QtCore.Qt.Key.Key_7, "top")):
        _key(qtbot, v, key)
        assert (v.opts["azimuth"], v.opts["elevation"]) == pytest.approx(VIEWS[name])
        px = v.project(np.concatenate([f.points for f in v.figures.values()]))
        assert (px > 0).all() and (px[:, 0] < v.width()).all() and \
            (px[:, 1] < v.height()).all()


def test_figures_are_labelled_and_joints_sized_by_the_skeleton(window):
    doc, v = window.doc, window.viewport
    assert v.figures["performer"].label.text == f"performer: {doc.scene.performer.name}"
    assert v.figures["target"].label.text == f"target: {doc.scene.target.name}"
    sizes = v.figures["target"].joints.size
    assert np.allclose(sizes, 0.022 * v._size())                       # a fraction of stature
    doc.select("target", "LeftHand")
    sizes = v.figures["target"].joints.size
    assert np.argmax(sizes) == doc.scene.target.skeleton.index["LeftHand"]


def test_the_default_layout_gives_the_viewport_half_the_window(qtbot, tmp_path, monkeypatch):
    require_gl()
    from motion_composer.app.gui.main_window import WINDOW_SIZE
    w = quiet_window(qtbot, tmp_path, monkeypatch)
    w.show()
    qtbot.waitExposed(w, timeout=WAIT_MS)
    assert (w.width(), w.height()) == WINDOW_SIZE
    v = w.viewport
    assert v.width() * v.height() >= 0.5 * w.width() * w.height()


def test_a_frame_change_repaints_the_playheads_not_the_window(window, qtbot):
    """Only the timeline's playhead strip and the transport's widgets repaint; the window
    around the viewport does not."""
    from motion_composer.app.gui.qt import QtCore, QtWidgets

    class Paints(QtCore.QObject):
        def __init__(self):
            super().__init__()
            self.regions = []

        def eventFilter(self, obj, event):       # noqa: N802 - Qt's name
            if event.type() == QtCore.QEvent.Type.Paint:
                self.regions.append((obj, event.region().boundingRect()))
            return False

    qtbot.wait(100)
    paints = Paints()
    for widget in QtWidgets.QApplication.allWidgets():
        widget.installEventFilter(paints)
    window.doc.set_frame(320)
    qtbot.wait(100)
    window.doc.set_frame(340)
    qtbot.wait(100)
    for widget in QtWidgets.QApplication.allWidgets():
        widget.removeEventFilter(paints)
    assert paints.regions
    timeline = window.timeline.plot.viewport()
    for obj, rect in paints.regions:
        if obj is timeline:
            assert rect.width() < 0.1 * timeline.width()
        else:                                     # the transport bar's line, at most
            assert rect.height() <= window.playback.height(), (obj, rect)


def test_the_skinned_mesh_is_lit_from_its_skinned_normals(qtbot, tmp_path):
    from conftest import shared_path
    from gui_support import skinned_character_in_window
    from motion_composer.app.gui.viewport import SKIN, TWO_SIDED, vertex_normals
    robot = shared_path("target_robot_expressive.glb")
    doc, v, _first, second, _back = skinned_character_in_window(qtbot, tmp_path, robot)
    skin = v.skin
    assert skin.opts["shader"] is TWO_SIDED and skin.opts["color"] == SKIN
    md = skin.opts["meshdata"]
    np.testing.assert_allclose(md.vertexNormals(),
                               vertex_normals(np.asarray(second, dtype=float), md.faces()),
                               atol=1e-3)          # the mesh holds float32
    # light and even: the mesh's pixels are bright, none black (no speckle)
    v.frame_all()
    img = _image(qtbot, v)
    mesh = np.abs(img - np.array(SKIN[:3]) * 255).sum(axis=-1) < 200
    grey = np.all(np.abs(img - img.mean(axis=-1, keepdims=True)) < 12, axis=-1)
    on_mesh = img[grey & (img.mean(axis=-1) > 60) & mesh]
    assert len(on_mesh) > 5000
    assert np.median(on_mesh.mean(axis=-1)) > 140


def test_the_robots_trails_follow_its_carried_feet(qtbot, tmp_path):
    """The robot's legs end at the shins and its skeleton names no foot: its trails follow the
    feet the scene puts the performer's feet on (FootL and FootR, control joints carried with
    the shins), planted where the contacts detected on the motion shown hold them."""
    from conftest import shared_path
    from gui_support import skinned_character_in_window
    from motion_composer.engine.correction.contacts import detect_contacts, find_feet
    robot = shared_path("target_robot_expressive.glb")
    doc, v, _first, _second, _back = skinned_character_in_window(qtbot, tmp_path, robot)
    sk = doc.scene.target.skeleton
    assert find_feet(sk) == []
    trails = v.foot_trails()
    assert trails.joints == ["FootL", "FootR"]
    lo, hi = trails.frames
    pose = doc.pose("target").positions
    for k, name in enumerate(trails.joints):
        np.testing.assert_allclose(trails.paths[k], pose[lo:hi + 1, sk.index[name]])
    planted = np.zeros(hi - lo + 1, dtype=bool)
    for c in detect_contacts(doc.motion, [("FootL", None), ("FootR", None)]):
        if c.joint == "FootL":
            planted[c.start - lo:c.end - lo + 1] = True
    assert 0 < planted.sum() < len(planted)
    np.testing.assert_array_equal(trails.planted[0], planted)


def _drop(qtbot, w, *paths):
    """A real drop of ``paths`` on the window: drag enter, then drop, with file URLs."""
    from motion_composer.app.gui.qt import QtCore, QtGui, QtWidgets
    mime = QtCore.QMimeData()
    mime.setUrls([QtCore.QUrl.fromLocalFile(str(p)) for p in paths])
    at = QtCore.QPointF(w.width() / 2, w.height() / 2)        # a window or the 3D view
    enter = QtGui.QDragEnterEvent(at.toPoint(), QtCore.Qt.DropAction.CopyAction, mime,
                                  QtCore.Qt.MouseButton.LeftButton,
                                  QtCore.Qt.KeyboardModifier.NoModifier)
    QtWidgets.QApplication.sendEvent(w, enter)
    assert enter.isAccepted()
    drop = QtGui.QDropEvent(at, QtCore.Qt.DropAction.CopyAction, mime,
                            QtCore.Qt.MouseButton.LeftButton,
                            QtCore.Qt.KeyboardModifier.NoModifier)
    QtWidgets.QApplication.sendEvent(w, drop)
    assert drop.isAccepted()


def test_dropped_files_are_imported_as_what_they_are(qtbot, tmp_path, monkeypatch):
    from conftest import clip_path
    w = quiet_window(qtbot, tmp_path, monkeypatch)
    w.show()
    qtbot.waitExposed(w, timeout=WAIT_MS)
    asked = []
    w.ask_role = lambda name: asked.append(name) or "target"
    _drop(qtbot, w, clip_path("cmu_131_01_walk.bvh"))        # a motion: the performer
    assert w.doc.scene.performer.name == "cmu_131_01_walk" and not asked
    _drop(qtbot, w, clip_path("fair1_child8_jumping.bvh"))   # could be either: asked
    assert asked == ["fair1_child8_jumping.bvh"]
    assert w.doc.scene.target.name == "fair1_child8_jumping" and w.doc.scene.ready
    _drop(qtbot, w, clip_path("cmu_rest_tpose.bvh"))         # one frame: a target
    assert w.doc.scene.target.name == "cmu_rest_tpose" and len(asked) == 1
    w.ask_role = lambda name: None                           # cancelled: nothing changes
    _drop(qtbot, w, clip_path("cmu_131_01_walk.bvh"))
    assert w.doc.scene.target.name == "cmu_rest_tpose"
    w.doc.undo_stack.setClean()


def test_a_dropped_character_is_the_target_and_a_bad_file_says_why(qtbot, tmp_path,
                                                                   monkeypatch):
    from conftest import clip_path
    w = quiet_window(qtbot, tmp_path, monkeypatch)
    w.show()
    qtbot.waitExposed(w, timeout=WAIT_MS)
    from motion_composer.app.gui.main import SKINNED_CHARACTER
    _drop(qtbot, w, clip_path("cmu_131_01_walk.bvh"), SKINNED_CHARACTER)
    assert w.doc.scene.character is not None and w.doc.scene.ready, w.errors
    # dropped on the 3D view itself (a native window: its own drag events), the same
    w.ask_role = lambda name: "performer"
    _drop(qtbot, w.viewport, clip_path("fair1_child8_jumping.bvh"))
    assert w.doc.scene.performer.name == "fair1_child8_jumping"
    junk = tmp_path / "notes.txt"
    junk.write_text("not a motion\n")
    _drop(qtbot, w, junk)
    assert w.errors and "notes.txt" in w.errors[-1]
    w.doc.undo_stack.setClean()


def _same_figures(a, b) -> None:
    """Two quality reports hold the same figures (floats to rounding)."""
    if isinstance(a, dict):
        assert set(a) == set(b)
        for k in a:
            _same_figures(a[k], b[k])
    elif isinstance(a, list):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            _same_figures(x, y)
    elif isinstance(a, float):
        assert a == pytest.approx(b, rel=1e-6, abs=1e-9)
    else:
        assert a == b


def test_the_quality_panel_shows_the_reports_figures_and_its_rows_go_to_their_frame(
        qtbot, tmp_path, monkeypatch):
    import json
    from conftest import clip_path
    from motion_composer.app.cli import main
    from motion_composer.app.gui.qt import QtCore
    from motion_composer.app.gui.quality_panel import GROUPS, quality_rows
    require_gl()
    walk, tpose = clip_path("cmu_131_01_walk.bvh"), clip_path("cmu_rest_tpose.bvh")
    report = tmp_path / "report.json"
    assert main(["retarget", str(walk), "--target", str(tpose), "-o", str(tmp_path / "o.bvh"),
                 "--auto-contacts", "--report", str(report)]) == 0
    expected = json.loads(report.read_text())["quality"]

    w = quiet_window(qtbot, tmp_path, monkeypatch)
    w.show()
    qtbot.waitExposed(w, timeout=WAIT_MS)
    assert w.import_file("performer", walk) and w.import_file("target", tpose)
    panel, doc = w.quality_panel, w.doc
    assert panel.quality is None and not w.quality_strip.isVisible()
    w.solve_contacts()                                   # Tools > Add Foot Contacts and Solve
    qtbot.waitUntil(lambda: panel.quality is not None, timeout=WAIT_MS * 4)
    _same_figures(json.loads(json.dumps(panel.quality)), expected)
    # the rows are the report's, as the panel words them
    rows = quality_rows(expected)
    for key, _title in GROUPS:
        shown = [(i.text(0), i.text(1), i.text(2)) for i in panel.rows(key)]
        assert shown == [(a, b, "" if f is None else str(f)) for a, b, f, _j in rows[key]]
    assert rows["contacts"] and rows["pops"] and rows["bone_directions"]
    # the strip under the timeline: foot slide and largest residual per frame, in cm
    assert w.quality_strip.isVisible()
    np.testing.assert_allclose(w.quality_strip.slide.yData,
                               np.asarray(expected["per_frame"]["foot_slide_m"]) * 100)
    # a click on a row goes to its frame and selects its joint
    w.quality_dock.raise_()
    item = panel.rows("pops")[0]
    panel.tree.scrollToItem(item)
    rect = panel.tree.visualItemRect(item)
    qtbot.mouseClick(panel.tree.viewport(), QtCore.Qt.MouseButton.LeftButton,
                     pos=rect.center())
    frame, joint = expected["pops"][0]["frame"], expected["pops"][0]["joint"]
    assert doc.scene.viewer.current_frame == frame and doc.selection == ("target", joint)
    # Measure solves as retarget does: the same figures again
    panel.show_quality(None)
    qtbot.mouseClick(panel.measure_button, QtCore.Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: panel.quality is not None, timeout=WAIT_MS * 4)
    _same_figures(json.loads(json.dumps(panel.quality)), expected)
    doc.undo_stack.setClean()
