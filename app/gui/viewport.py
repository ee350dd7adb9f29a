"""The 3D viewport: performer, intermediate and target skeletons, floor, goals, picking.

pyqtgraph's GL view is Z-up; the engine is Y-up. Everything shown goes through
:func:`to_view` ((x, y, z) -> (x, -z, y)), a rotation, so nothing is mirrored.

Mouse, as in Blender and Maya: left click selects a joint; left drag (or Alt + left, or middle
drag) orbits; Shift + drag or middle + Shift pans; the wheel or right drag zooms; F frames all.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from motion_composer.app.gui.qt import QtCore, QtGui, QtWidgets
from motion_composer.engine.quaternions import to_matrix

import pyqtgraph.opengl as gl  # noqa: E402  (after app.gui.qt chose PySide6)

__all__ = ["Viewport", "to_view", "bone_mesh"]

COLORS = {
    "performer": (0.45, 0.62, 0.85, 1.0),
    "intermediate": (0.65, 0.65, 0.65, 0.6),
    "target": (0.95, 0.60, 0.25, 1.0),
}
SELECTED = (1.0, 1.0, 0.2, 1.0)
VIRTUAL = (0.2, 1.0, 0.5, 1.0)
#: an orientation goal's x, y, z axes (two vertices each)
AXES = np.array([(1.0, 0.25, 0.25, 1.0)] * 2 + [(0.3, 1.0, 0.3, 1.0)] * 2 +
                [(0.35, 0.5, 1.0, 1.0)] * 2)


def to_view(points: np.ndarray) -> np.ndarray:
    """Engine (Y up) to view (Z up) coordinates."""
    p = np.asarray(points, dtype=float)
    return np.stack([p[..., 0], -p[..., 2], p[..., 1]], axis=-1)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(V, 3)`` float32 unit normals of a triangle mesh's ``vertices`` ``(V, 3)`` (``faces``
    ``(T, 3)`` vertex indices): the sum of the normals of the faces around each vertex,
    weighted by their areas. A vertex whose faces are all degenerate (zero area, as the
    collapsed triangles of a skinned glTF character often are) or that has none gets a zero
    normal rather than NaN."""
    v = vertices[faces]                                           # (T, 3 corners, 3)
    face_normals = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])  # length: twice the area
    summed = np.zeros((len(vertices), 3))
    for corner in range(3):
        np.add.at(summed, faces[:, corner], face_normals)
    length = np.linalg.norm(summed, axis=1, keepdims=True)
    return np.divide(summed, length, out=np.zeros_like(summed),
                     where=length > 0).astype(np.float32)


class SkinMeshData(gl.MeshData):
    """Mesh data whose smooth-shading normals come from :func:`vertex_normals` (numpy, in
    one pass) instead of pyqtgraph's per-vertex loop, which divides by zero on degenerate
    faces and prints a RuntimeWarning."""

    def __init__(self, vertexes: np.ndarray, faces: np.ndarray):
        super().__init__(vertexes=vertexes, faces=faces)
        self._normals = vertex_normals(np.asarray(vertexes, dtype=float), np.asarray(faces))

    def vertexNormals(self, indexed=None):                       # noqa: N802 (pyqtgraph)
        return self._normals if indexed is None else self._normals[self.faces()]


# an octahedral bone from (0,0,0) to (0,0,1) with its waist at 0.15 and radius 0.08
_OCTA_V = np.array([[0, 0, 0], [0.08, 0, 0.15], [0, 0.08, 0.15], [-0.08, 0, 0.15],
                    [0, -0.08, 0.15], [0, 0, 1.0]])
_OCTA_F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1],
                    [5, 2, 1], [5, 3, 2], [5, 4, 3], [5, 1, 4]])


def bone_mesh(heads: np.ndarray, tails: np.ndarray, width: float):
    """Vertices and faces of octahedral bones from ``heads`` to ``tails`` ``(B, 3)``.

    ``width`` caps the bones' thickness for long bones; short bones stay proportionate.
    """
    d = tails - heads
    length = np.linalg.norm(d, axis=1)
    keep = length > 1e-9
    heads, d, length = heads[keep], d[keep], length[keep]
    z = d / length[:, None]
    helper = np.where(np.abs(z[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    thick = np.minimum(length, width / 0.16)[:, None]
    v = (heads[:, None, :] + _OCTA_V[None, :, 0:1] * thick[:, None] * x[:, None, :]
         + _OCTA_V[None, :, 1:2] * thick[:, None] * y[:, None, :]
         + _OCTA_V[None, :, 2:3] * length[:, None, None] * z[:, None, :])
    faces = (_OCTA_F[None, :, :] + 6 * np.arange(len(heads))[:, None, None]).reshape(-1, 3)
    return v.reshape(-1, 3), faces


@dataclass
class _Shapes:
    """What the goals draw, in view space: points, path segments (starts and ends in turn),
    plane quads (4 corners each) and frame axes (3 segments each)."""

    points: list = field(default_factory=list)
    lines: list = field(default_factory=list)
    quads: list = field(default_factory=list)
    axes: list = field(default_factory=list)


class _Figure:
    """One skeleton's items: bones as a shaded mesh, joints as spheres."""

    def __init__(self, view: gl.GLViewWidget, color):
        self.color = color
        self.mesh = gl.GLMeshItem(vertexes=np.zeros((3, 3)), faces=np.array([[0, 1, 2]]),
                                  color=color, shader="shaded", smooth=False,
                                  glOptions="opaque")
        self.joints = gl.GLScatterPlotItem(pos=np.zeros((1, 3)), color=color, size=0.02,
                                           pxMode=False)
        self.joints.setGLOptions("opaque")
        view.addItem(self.mesh)
        view.addItem(self.joints)

    def set_visible(self, on: bool) -> None:
        self.mesh.setVisible(on)
        self.joints.setVisible(on)

    def update(self, positions: np.ndarray, parents: np.ndarray, offset: np.ndarray,
               width: float, selected: int = -1) -> None:
        pts = to_view(positions) + offset
        child = np.flatnonzero(parents >= 0)
        verts, faces = bone_mesh(pts[parents[child]], pts[child], width)
        if len(faces):
            self.mesh.setMeshData(vertexes=verts, faces=faces, color=self.color,
                                  shader="shaded", smooth=False)
        colors = np.tile(self.color, (len(pts), 1))
        sizes = np.full(len(pts), width * 1.2)
        if 0 <= selected < len(pts):
            colors[selected] = SELECTED
            sizes[selected] = width * 2.5
        self.joints.setData(pos=pts, color=colors, size=sizes)
        self.points = pts

    def remove(self, view) -> None:
        view.removeItem(self.mesh)
        view.removeItem(self.joints)


class Viewport(gl.GLViewWidget):
    """The document's skeletons at its current frame."""

    #: a joint was clicked: side ("performer", "target") and name
    jointPicked = QtCore.Signal(str, str)

    def __init__(self, document, parent=None):
        super().__init__(parent)
        self.doc = document
        self.setBackgroundColor((38, 40, 44))
        self.setMinimumSize(320, 240)
        self.grid = gl.GLGridItem()
        self.grid.setSpacing(0.5, 0.5)
        self.grid.setSize(20, 20)
        self.grid.setColor((120, 120, 120, 90))
        self.addItem(self.grid)
        self.figures: dict[str, _Figure] = {}
        self.virtual = gl.GLLinePlotItem(pos=np.zeros((2, 3)), color=VIRTUAL, width=3,
                                         mode="lines")
        self.virtual.setVisible(False)
        self.addItem(self.virtual)
        self.goals = gl.GLScatterPlotItem(pos=np.zeros((1, 3)), color=(1, 0.3, 0.3, 1),
                                          size=0.05, pxMode=False)
        self.goals.setVisible(False)
        self.addItem(self.goals)
        self.paths = gl.GLLinePlotItem(pos=np.zeros((2, 3)), color=(1, 0.3, 0.3, 0.8),
                                       width=2, mode="lines")
        self.paths.setVisible(False)
        self.addItem(self.paths)
        self.planes = gl.GLMeshItem(vertexes=np.zeros((3, 3)), faces=np.array([[0, 1, 2]]),
                                    color=(0.3, 0.6, 1.0, 0.25), glOptions="translucent",
                                    smooth=False)
        self.planes.setVisible(False)
        self.addItem(self.planes)
        self.axes = gl.GLLinePlotItem(pos=np.zeros((2, 3)), width=3, mode="lines")
        self.axes.setVisible(False)
        self.addItem(self.axes)
        self.skin = None                  # the target character's skinned mesh, when it has one
        self.active_constraint: int | None = None   # the constraint whose goal can be dragged
        self._goal_drag = None
        self._skin_key = None
        self._press = None
        self._framed = False
        #: the camera state last set (as the project held it) and the view it made
        self._camera_set: tuple[dict, dict] | None = None
        self.setCameraPosition(distance=5.0, elevation=15, azimuth=-90)
        document.frameChanged.connect(lambda _f: self.refresh())
        document.motionChanged.connect(self._motion_changed)
        document.selectionChanged.connect(lambda *_: self.refresh())
        document.constraintsChanged.connect(self.refresh)
        self._motion_changed()

    # ------------------------------------------------------------------ content
    def _motion_changed(self) -> None:
        if not self._framed and self.doc.scene.performer is not None:
            self.frame_all()
        self.refresh()

    def _layout(self) -> dict[str, np.ndarray]:
        """View-space offsets of the shown skeletons (side by side along X, or overlaid)."""
        v = self.doc.scene.viewer
        shown = [k for k, on in (("performer", v.show_performer),
                                 ("intermediate", v.show_intermediate),
                                 ("target", v.show_target)) if on]
        gap = 1.2 * self._size()
        out = {}
        # every skeleton starts where the performer starts (its root over the performer's at
        # frame 0), then travels as it travels; side by side, each is moved along the view's x
        anchor = self._root_start("performer")
        for i, k in enumerate(shown):
            x = (i - (len(shown) - 1) / 2) * gap if v.side_by_side else 0.0
            start = self._root_start(k)
            shift = np.zeros(3) if anchor is None or start is None else anchor - start
            shift[2] = 0.0
            out[k] = np.array([x, 0.0, 0.0]) + shift
        return out

    def _root_start(self, which: str):
        pose = {"performer": self.doc.pose("performer"),
                "intermediate": self.doc.pose("composed"),
                "target": self.doc.pose("target") or self.doc.pose("character")}.get(which)
        return None if pose is None else to_view(pose.positions[0, 0])

    def _size(self) -> float:
        from motion_composer.engine.describe import stature
        m = self.doc.scene.target if self.doc.scene.target is not None else self.doc.scene.performer
        if m is None:
            return 1.7
        if not hasattr(self, "_size_cache") or self._size_cache[0] is not m:
            self._size_cache = (m, max(stature(m), 0.2))
        return self._size_cache[1]

    def skeleton_points(self, which: str) -> tuple[np.ndarray, np.ndarray] | None:
        """World positions (engine axes) of a skeleton at the current frame, and parents."""
        doc = self.doc
        f = doc.scene.viewer.current_frame
        if which == "performer":
            pose = doc.pose("performer")
            sk = doc.scene.performer.skeleton if doc.scene.performer is not None else None
        elif which == "target":
            pose = doc.pose("target") or doc.pose("character")
            sk = doc.scene.target.skeleton if doc.scene.target is not None else None
            if doc.motion is None and pose is not None:
                f = 0
        else:                                                     # intermediate
            pose = doc.pose("composed")
            sk = doc.scene.target.skeleton if doc.scene.target is not None else None
        if pose is None or sk is None:
            return None
        f = min(f, pose.positions.shape[0] - 1)
        return pose.positions[f], sk.parents

    def refresh(self) -> None:
        doc = self.doc
        layout = self._layout()
        width = 0.04 * self._size()
        side, joint = doc.selection
        for which in ("performer", "intermediate", "target"):
            data = self.skeleton_points(which) if which in layout else None
            if data is None:
                if which in self.figures:
                    self.figures[which].set_visible(False)
                continue
            if which not in self.figures:
                self.figures[which] = _Figure(self, COLORS[which])
            fig = self.figures[which]
            fig.set_visible(True)
            sk = (doc.scene.performer if which == "performer" else doc.scene.target).skeleton
            sel = sk.index.get(joint, -1) if side == (
                "performer" if which == "performer" else "target") else -1
            fig.update(data[0], data[1], layout[which], width, sel)
            fig.offset = layout[which]
        self._refresh_skin(layout)
        self._refresh_virtual(layout)
        self._refresh_goals(layout)

    def _refresh_skin(self, layout) -> None:
        """The target character's mesh, deformed by the motion at the current frame."""
        doc = self.doc
        character = doc.scene.character if "target" in layout else None
        motion = doc.motion if doc.motion is not None else doc.scene.target
        if character is None or motion is None or not character.meshes:
            if self.skin is not None:
                self.skin.setVisible(False)
            return
        from motion_composer.engine.skinning import skin_character
        f = min(doc.scene.viewer.current_frame, motion.num_frames - 1)
        parts = skin_character(character, motion, frames=[f])
        verts = np.concatenate([p[0] for p in parts])
        offsets = np.cumsum([0] + [len(m.positions) for m in character.meshes[:-1]])
        faces = np.concatenate([m.triangles + o for m, o in zip(character.meshes, offsets)])
        verts = to_view(verts) + layout["target"]
        if self.skin is None:
            self.skin = gl.GLMeshItem(meshdata=SkinMeshData(verts, faces),
                                      color=(0.85, 0.80, 0.72, 0.55), shader="shaded",
                                      smooth=True, glOptions="translucent")
            self.addItem(self.skin)
        else:
            self.skin.setMeshData(meshdata=SkinMeshData(verts, faces),
                                  color=(0.85, 0.80, 0.72, 0.55), shader="shaded", smooth=True)
        self.skin.setVisible(True)

    def _refresh_virtual(self, layout) -> None:
        """Highlight the virtual bones of the selected mapping on the performer."""
        doc = self.doc
        side, joint = doc.selection
        pairs = doc.scene.correspondence.pairs
        performer_joint = (pairs.get(joint) if side == "target" else
                           joint if side == "performer" else None)
        if not performer_joint or "performer" not in layout or doc.scene.performer is None:
            self.virtual.setVisible(False)
            return
        psk = doc.scene.performer.skeleton
        tsk = doc.scene.target.skeleton if doc.scene.target is not None else None
        data = self.skeleton_points("performer")
        if data is None or performer_joint not in psk.index or tsk is None:
            self.virtual.setVisible(False)
            return
        pts = to_view(data[0]) + layout["performer"]
        inverse = {p: t for t, p in pairs.items()}
        t_joint = inverse.get(performer_joint)
        segments = []
        if t_joint is not None:
            # the virtual bone that ends at the selection and those that start from it
            tj = tsk.index[t_joint]
            up = [a for a in tsk.ancestors(tj) if tsk.names[a] in pairs]
            if up:
                segments += [pts[psk.index[pairs[tsk.names[up[0]]]]],
                             pts[psk.index[performer_joint]]]
            for k in range(tsk.num_joints):
                anc = [a for a in tsk.ancestors(k) if tsk.names[a] in pairs]
                if tsk.names[k] in pairs and anc and anc[0] == tj:
                    segments += [pts[psk.index[performer_joint]],
                                 pts[psk.index[pairs[tsk.names[k]]]]]
        if not segments:
            self.virtual.setVisible(False)
            return
        self.virtual.setData(pos=np.array(segments), color=VIRTUAL, width=3, mode="lines")
        self.virtual.setVisible(True)

    def _refresh_goals(self, layout) -> None:
        """The goals of the constraints acting at the current frame, each drawn as its kind
        says (:attr:`~engine.correction.constraints.ConstraintKind.draw`)."""
        doc = self.doc
        if "target" not in layout or not doc.scene.constraints:
            for item in (self.goals, self.paths, self.planes, self.axes):
                item.setVisible(False)
            return
        off = layout["target"]
        f = doc.scene.viewer.current_frame
        shapes = _Shapes()
        size = self._size()
        for c in doc.scene.constraints:
            if not c.enabled or not c.smooth_in <= f <= c.smooth_out:
                continue                      # only what acts at this frame
            self._DRAW[c.kind_object.draw](self, c, shapes, off, f, size)
        points, lines, quads, axes = shapes.points, shapes.lines, shapes.quads, shapes.axes
        active = self._active_goal()
        if active is not None:
            points.append(active[2])                       # the draggable goal, always shown
        if points:
            sizes = np.full(len(points), 0.03 * size)
            if active is not None:
                sizes[-1] = 0.06 * size
            self.goals.setData(pos=np.array(points), color=(1, 0.3, 0.3, 1), size=sizes)
        self.goals.setVisible(bool(points))
        if lines:
            seg = np.stack([np.concatenate(lines[0::2]), np.concatenate(lines[1::2])], axis=1)
            self.paths.setData(pos=seg.reshape(-1, 3), mode="lines")
        self.paths.setVisible(bool(lines))
        if quads:
            v = np.concatenate(quads)
            faces = np.concatenate([[[4 * i, 4 * i + 1, 4 * i + 2], [4 * i, 4 * i + 2, 4 * i + 3]]
                                    for i in range(len(quads))])
            self.planes.setMeshData(vertexes=v, faces=faces, color=(0.3, 0.6, 1.0, 0.25))
        self.planes.setVisible(bool(quads))
        if axes:
            self.axes.setData(pos=np.concatenate(axes), color=np.tile(AXES, (len(axes), 1)),
                              mode="lines")
        self.axes.setVisible(bool(axes))

    def _draw_point(self, c, shapes, off, f, size) -> None:
        shapes.points.append(to_view(c.goal_point(np.array([f]))[0]) + off)

    def _draw_path(self, c, shapes, off, f, size) -> None:
        frames = np.arange(c.start, c.end + 1)
        path = to_view(c.goal_point(frames)) + off
        shapes.lines += [path[:-1], path[1:]]
        if c.start <= f <= c.end:
            shapes.points.append(path[f - c.start])

    def _draw_plane(self, c, shapes, off, f, size) -> None:
        shapes.quads.append(self._plane_quad(c, off, size))

    def _draw_axes(self, c, shapes, off, f, size) -> None:
        """The goal orientation's x, y, z axes at where the joint is now."""
        data = self.skeleton_points("target")
        sk = self.doc.scene.target.skeleton
        if data is None or c.joint not in sk.index:
            return
        origin = data[0][sk.index[c.joint]]
        tips = origin + 0.08 * size * to_matrix(np.asarray(c.goal["quaternion"])).T
        shapes.axes.append(to_view(np.stack([origin, tips[0], origin, tips[1], origin,
                                             tips[2]])) + off)

    #: a kind's drawing (:data:`~engine.correction.constraints.base.DRAWINGS`) -> its drawer
    _DRAW = {"point": _draw_point, "path": _draw_path, "plane": _draw_plane, "axes": _draw_axes}

    @staticmethod
    def _plane_quad(c, off, size):
        n = c.goal["normal"]
        helper = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 0, 1.0])
        u = np.cross(n, helper)
        u /= np.linalg.norm(u)
        w = np.cross(n, u)
        p = c.goal["point"]
        r = 0.25 * size
        corners = [p + r * (a * u + b * w) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        return to_view(np.array(corners)) + off

    # ------------------------------------------------------------------ camera
    def frame_all(self) -> None:
        """Fit every shown skeleton, as it stands at the current frame, in the view."""
        layout = self._layout()
        boxes = []
        for which, off in layout.items():
            data = self.skeleton_points(which)
            if data is not None:
                pts = to_view(data[0]) + off
                boxes.append(np.array([pts.min(axis=0), pts.max(axis=0)]))
        if not boxes:
            return
        lo = np.min([b[0] for b in boxes], axis=0)
        hi = np.max([b[1] for b in boxes], axis=0)
        center = (lo + hi) / 2
        radius = max(float(np.linalg.norm(hi - lo)) / 2, 0.5)
        self.setCameraPosition(pos=QtGui.QVector3D(*center), distance=radius * 2.6)
        self._framed = True
        self.update()

    def camera_state(self) -> dict:
        """The camera for the project's viewer state: the state last set, as it was given,
        while the view has not moved since (the view holds its centre in single precision,
        so reading it back would change a saved project that was only opened); else the
        view's camera."""
        view = self._view_camera()
        if self._camera_set is not None and self._camera_set[1] == view:
            return dict(self._camera_set[0])
        return view

    def _view_camera(self) -> dict:
        c = self.opts["center"]
        return {"center": [c.x(), c.y(), c.z()], "distance": float(self.opts["distance"]),
                "elevation": float(self.opts["elevation"]),
                "azimuth": float(self.opts["azimuth"])}

    def set_camera_state(self, state: dict) -> None:
        if not state:
            return
        self.setCameraPosition(pos=QtGui.QVector3D(*state.get("center", (0, 0, 0))),
                               distance=state.get("distance", 5.0),
                               elevation=state.get("elevation", 15.0),
                               azimuth=state.get("azimuth", -90.0))
        self._camera_set = (dict(state), self._view_camera())
        self._framed = True

    # ------------------------------------------------------------------ picking
    def project(self, points_view: np.ndarray) -> np.ndarray:
        """Pixel coordinates (x right, y down) of view-space points ``(N, 3)``."""
        viewport = (0, 0, self.width(), self.height())
        m = np.array(self.projectionMatrix(viewport, viewport).data()).reshape(4, 4).T @ \
            np.array(self.viewMatrix().data()).reshape(4, 4).T
        h = np.concatenate([points_view, np.ones((len(points_view), 1))], axis=1) @ m.T
        ndc = h[:, :2] / h[:, 3:4]
        w, hgt = self.width(), self.height()
        return np.stack([(ndc[:, 0] + 1) * w / 2, (1 - ndc[:, 1]) * hgt / 2], axis=1)

    def joint_at(self, x: float, y: float, radius: float = 12.0):
        """The (side, joint name) nearest to pixel (x, y) within ``radius``, or None."""
        best = None
        for which in ("target", "performer"):
            fig = self.figures.get(which)
            if fig is None or not fig.mesh.visible() or not hasattr(fig, "points"):
                continue
            px = self.project(fig.points)
            d = np.hypot(px[:, 0] - x, px[:, 1] - y)
            k = int(np.argmin(d))
            if d[k] <= radius and (best is None or d[k] < best[0]):
                sk = (self.doc.scene.performer if which == "performer" else self.doc.scene.target).skeleton
                best = (d[k], which, sk.names[k])
        return None if best is None else (best[1], best[2])

    # ------------------------------------------------------------------ mouse and keys
    def set_active_constraint(self, index) -> None:
        """Which constraint's goal the gizmo drags (the timeline's selection)."""
        self.active_constraint = None if index is None or index < 0 else int(index)
        self.refresh()

    def _active_goal(self):
        """(index, constraint, goal in view space, offset) of a draggable goal point (a kind
        with a ``drag_key``: a position), or None."""
        i = self.active_constraint
        cons = self.doc.scene.constraints
        if i is None or not 0 <= i < len(cons) or cons[i].kind_object.drag_key is None:
            return None
        off = self._layout().get("target")
        if off is None:
            return None
        return i, cons[i], to_view(cons[i].goal[cons[i].kind_object.drag_key]) + off, off

    def _unproject(self, x: float, y: float, through: np.ndarray) -> np.ndarray:
        """The view-space point under pixel (x, y) on the plane through ``through`` facing
        the camera."""
        viewport = (0, 0, self.width(), self.height())
        m = np.array(self.projectionMatrix(viewport, viewport).data()).reshape(4, 4).T @ \
            np.array(self.viewMatrix().data()).reshape(4, 4).T
        inv = np.linalg.inv(m)
        ndc = np.array([2 * x / self.width() - 1, 1 - 2 * y / self.height()])
        near = inv @ np.array([ndc[0], ndc[1], -1.0, 1.0])
        far = inv @ np.array([ndc[0], ndc[1], 1.0, 1.0])
        near, far = near[:3] / near[3], far[:3] / far[3]
        direction = far - near
        eye = np.array(self.cameraPosition())
        normal = np.asarray(through) - eye
        normal /= np.linalg.norm(normal)
        t = np.dot(through - near, normal) / np.dot(direction, normal)
        return near + t * direction

    def mousePressEvent(self, ev):
        self._press = ev.position()
        self.mousePos = ev.position()
        goal = self._active_goal()
        if goal is not None and ev.button() == QtCore.Qt.MouseButton.LeftButton:
            i, c, point, off = goal
            px = self.project(point[None])[0]
            if np.hypot(px[0] - ev.position().x(), px[1] - ev.position().y()) <= 14:
                from motion_composer.app.gui.live import live_solver
                self._goal_drag = (i, c, off, live_solver(self.doc))
                self._goal_drag[3].begin()

    def _dragged_goal(self, pos):
        i, c, off, _solver = self._goal_drag
        key = c.kind_object.drag_key
        point = self._unproject(pos.x(), pos.y(), to_view(c.goal[key]) + off) - off
        engine = np.array([point[0], point[2], -point[1]])        # view (Z up) -> engine (Y up)
        import dataclasses
        moved = dataclasses.replace(c, goal={**c.goal, key: engine})
        constraints = list(self.doc.scene.constraints)
        constraints[i] = moved
        return constraints, engine

    def mouseMoveEvent(self, ev):
        if self._goal_drag is not None:
            constraints, _ = self._dragged_goal(ev.position())
            self._goal_drag[3].request(constraints)
            self.mousePos = ev.position()
            return
        pos = ev.position()
        diff = pos - self.mousePos
        self.mousePos = pos
        buttons = ev.buttons()
        mods = ev.modifiers()
        shift = bool(mods & QtCore.Qt.KeyboardModifier.ShiftModifier)
        if buttons & QtCore.Qt.MouseButton.RightButton:
            self.opts["distance"] *= 0.995 ** diff.y()
        elif shift and buttons & (QtCore.Qt.MouseButton.LeftButton |
                                  QtCore.Qt.MouseButton.MiddleButton):
            self.pan(diff.x(), diff.y(), 0, relative="view")
        elif buttons & (QtCore.Qt.MouseButton.LeftButton | QtCore.Qt.MouseButton.MiddleButton):
            self.orbit(-diff.x(), diff.y())
        self.update()

    def mouseReleaseEvent(self, ev):
        if self._goal_drag is not None:
            constraints, point = self._dragged_goal(ev.position())
            solver = self._goal_drag[3]
            name = self._goal_drag[1].name or self._goal_drag[1].joint
            self._goal_drag = None
            self._press = None
            solver.commit(constraints, f"Move goal of {name}")
            return
        if self._press is not None and ev.button() == QtCore.Qt.MouseButton.LeftButton:
            moved = ev.position() - self._press
            if abs(moved.x()) + abs(moved.y()) < 4:
                hit = self.joint_at(ev.position().x(), ev.position().y())
                if hit is not None:
                    self.doc.select(*hit)
                    self.jointPicked.emit(*hit)
                else:
                    self.doc.select("", "")
        self._press = None

    def keyPressEvent(self, ev):
        if ev.key() == QtCore.Qt.Key.Key_F:
            self.frame_all()
            return
        super().keyPressEvent(ev)
