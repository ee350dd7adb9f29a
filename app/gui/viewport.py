"""The 3D viewport: performer, intermediate and target skeletons, the target's skinned mesh,
floor, goals, picking, and the judging tools (labels, onion skin, foot trails).

pyqtgraph's GL view is Z-up; the engine is Y-up. Everything shown goes through
:func:`to_view` ((x, y, z) -> (x, -z, y)), a rotation, so nothing is mirrored.

The view is a ``QOpenGLWindow`` (pyqtgraph's ``GLViewMixin``) in a window container
(:attr:`Viewport.widget`), not a ``QOpenGLWidget``: a ``QOpenGLWidget`` makes Qt compose the
whole main window through OpenGL on every frame, which under software GL (Mesa llvmpipe) costs
more than drawing the scene; a native child window swaps its own pixels only. Per frame only
what changed is sent: bone and joint positions, the skinned vertices and their normals
(numpy, from the document's cached world pose).

Mouse, as in Blender and Maya: left click selects a joint; left drag (or Alt + left, or middle
drag) orbits; Shift + drag or middle + Shift pans; the wheel or right drag zooms. Keys: F frames
all (from a sensible height), 1 / 3 / 7 front, side and top views.

Binding-pose editing (the viewer option ``pose_edit``, :meth:`Viewport.set_option`): the
target stands in its binding pose (the bound rest posture with its pose offsets,
:class:`~engine.conversion.binding.Binding`'s ``rest_*``) beside the performer in its reference
pose, and the selected target joint carries a rotation gizmo (:mod:`app.gui.pose_gizmo`):
dragging a ring turns the joint about that binding-frame axis, shown live, one command on
release; Esc or a right click during the drag cancels it.
"""
from __future__ import annotations

import atexit
import weakref
from dataclasses import dataclass, field

import numpy as np

from motion_composer.app.gui import pose_gizmo
from motion_composer.app.gui.qt import QtCore, QtGui, QtWidgets
from motion_composer.engine.kinematics import WorldPose, fk_arrays
from motion_composer.engine.quaternions import to_matrix

import pyqtgraph.opengl as gl  # noqa: E402  (after app.gui.qt chose PySide6)
from pyqtgraph.opengl import shaders  # noqa: E402
from pyqtgraph.opengl.GLGraphicsItem import GLGraphicsItem  # noqa: E402
from pyqtgraph.opengl.GLViewWidget import GLViewMixin  # noqa: E402
from OpenGL import GL  # noqa: E402
from PySide6 import QtOpenGL  # noqa: E402

__all__ = ["Viewport", "to_view", "bone_mesh", "gl_possible", "GHOST_OFFSETS"]

COLORS = {
    "performer": (0.45, 0.62, 0.85, 1.0),
    "intermediate": (0.65, 0.65, 0.65, 0.6),
    "target": (0.95, 0.60, 0.25, 1.0),
}
SELECTED = (1.0, 1.0, 0.2, 1.0)
VIRTUAL = (0.2, 1.0, 0.5, 1.0)
#: the skinned mesh: a light neutral material, opaque
SKIN = (0.80, 0.79, 0.76, 1.0)
#: onion skin: frames before and after the current one, and their colours (past blue, future
#: red, fainter further away)
GHOST_OFFSETS = (-20, -10, 10, 20)
GHOST_PAST, GHOST_FUTURE = (0.45, 0.7, 1.0), (1.0, 0.55, 0.45)
#: [share of the stature] half the side of the square a plane goal is drawn as
PLANE_PAD = 0.08
#: [share of the stature] how far a plane goal is drawn off its plane, along its normal (a
#: floor plane at the project's floor would otherwise flicker with the grid's lines)
PLANE_LIFT = 0.001
#: foot trails: the path, planted frames on it, and contacts active now on the floor
TRAIL = (0.95, 0.85, 0.35, 0.9)
PLANTED = (1.0, 0.25, 0.25, 1.0)
CONTACT_FLOOR = (1.0, 0.3, 0.3, 0.45)
#: camera elevations [deg] F keeps (outside them it goes back to FRAME_ELEVATION): a view from
#: below the floor or from straight above is no view of a motion
SENSIBLE_ELEVATION = (-5.0, 60.0)
FRAME_ELEVATION = 12.0
#: the named views (azimuth, elevation) [deg]: front looks along -Z (engine), side along -X
VIEWS = {"front": (-90.0, 5.0), "side": (0.0, 5.0), "top": (-90.0, 89.9)}
#: the fraction of the view's smaller field of view the framed figure fills
FILL = 0.8
#: the pose gizmo: its rings' radius as a fraction of the stature, the ring being dragged's
#: colour, and how near [px] the pointer must be to a ring to grab it
GIZMO_RADIUS = 0.09
GIZMO_ACTIVE = (1.0, 0.95, 0.3, 1.0)
GIZMO_PICK_PX = 9.0
#: drawn over everything (the skinned mesh hides no ring)
ON_TOP = {GL.GL_DEPTH_TEST: False, GL.GL_BLEND: True,
          "glBlendFunc": (GL.GL_SRC_ALPHA, GL.GL_ONE_MINUS_SRC_ALPHA)}

#: two-sided lighting, from the camera (eye space): a face seen from behind is lit as its front,
#: so thin or inverted parts of a character's mesh are never black
TWO_SIDED = shaders.ShaderProgram("two_sided", [
    shaders.VertexShader("""
        uniform mat4 u_mvp;
        uniform mat3 u_normal;
        attribute vec4 a_position;
        attribute vec3 a_normal;
        attribute vec4 a_color;
        varying vec4 v_color;
        varying vec3 v_normal;
        void main() {
            v_normal = u_normal * a_normal;
            v_color = a_color;
            gl_Position = u_mvp * a_position;
        }
    """),
    shaders.FragmentShader("""
        #ifdef GL_ES
        precision mediump float;
        #endif
        varying vec4 v_color;
        varying vec3 v_normal;
        void main() {
            float n = length(v_normal);
            vec3 normal = n > 0.0 ? v_normal / n : vec3(0.0, 0.0, 1.0);
            float key = abs(dot(normal, normalize(vec3(0.35, 0.6, 1.0))));
            float fill = abs(dot(normal, normalize(vec3(-0.6, -0.2, 0.6))));
            vec3 rgb = v_color.rgb * (0.28 + 0.62 * key + 0.18 * fill);
            gl_FragColor = vec4(min(rgb, vec3(1.0)), v_color.a);
        }
    """)])


#: a label's image on a quad given in window pixels (``u_rect``: left, top, width, height;
#: ``u_view``: the window's width and height), its texels premultiplied
LABEL_SHADER = shaders.ShaderProgram("label", [
    shaders.VertexShader("""
        uniform vec4 u_rect;
        uniform vec2 u_view;
        attribute vec4 a_position;
        varying vec2 v_texcoord;
        void main() {
            vec2 p = u_rect.xy + a_position.xy * u_rect.zw;
            gl_Position = vec4(2.0 * p.x / u_view.x - 1.0, 1.0 - 2.0 * p.y / u_view.y,
                               0.0, 1.0);
            v_texcoord = a_position.xy;
        }
    """),
    shaders.FragmentShader("""
        #ifdef GL_ES
        precision mediump float;
        #endif
        uniform sampler2D u_texture;
        varying vec2 v_texcoord;
        void main() {
            gl_FragColor = texture2D(u_texture, v_texcoord);
        }
    """)])


#: the views alive, deleted at exit while Qt still runs (see _delete_live_views)
_LIVE: "weakref.WeakSet[Viewport]" = weakref.WeakSet()


@atexit.register
def _delete_live_views() -> None:
    """Delete the GL windows still alive at exit while the application and their OpenGL
    contexts exist (a test session's application lives to the end): left to Python's
    teardown, a GL window goes after the application and the process dies in a segmentation
    fault on its way out."""
    import shiboken6
    if QtCore.QCoreApplication.instance() is None:       # gone first: nothing may be deleted
        return
    for view in list(_LIVE):
        if shiboken6.isValid(view) and shiboken6.isValid(view.widget):
            shiboken6.delete(view.widget.window())       # the window it is in, whole


def gl_possible() -> bool:
    """Whether this process can make an OpenGL context (not on Qt's 'offscreen' and 'minimal'
    platforms): where it cannot, the viewport is not embedded (a GL window without a context
    crashes on its first paint) and a note takes its place."""
    from PySide6.QtGui import QGuiApplication, QOffscreenSurface, QOpenGLContext
    if QGuiApplication.platformName() in ("offscreen", "minimal"):
        return False
    ctx = QOpenGLContext()
    if not ctx.create():
        return False
    surface = QOffscreenSurface()
    surface.create()
    ok = ctx.makeCurrent(surface)
    if ok:
        ctx.doneCurrent()
    return ok
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
    flat = faces.reshape(-1)
    per_corner = np.repeat(face_normals, 3, axis=0)                # (3T, 3)
    summed = np.stack([np.bincount(flat, per_corner[:, k], minlength=len(vertices))
                       for k in range(3)], axis=1)
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


class _Label(GLGraphicsItem):
    """A line of text over a point of the scene (view axes): its baseline's middle there,
    drawn over everything, at whole pixels.

    pyqtgraph's ``GLTextItem`` draws with a ``QPainter`` on the GL window: Qt's OpenGL paint
    engine then builds its programs and glyph cache on the first texts, a one-time stall of
    0.1 s and more under software GL (Mesa llvmpipe) that the window's first frame waited for,
    and it saves and restores the GL state on every frame. Here Qt's raster engine draws the
    text into an image once per change of text, which is drawn as one textured quad.

    Attributes: ``pos`` (3,) and ``text``, as ``GLTextItem``'s; set them with :meth:`setData`.
    """

    #: blending of premultiplied texels, no depth test: over the skeletons and the mesh
    GL_OPTIONS = {GL.GL_DEPTH_TEST: False, GL.GL_BLEND: True, GL.GL_CULL_FACE: False,
                  "glBlendFunc": (GL.GL_ONE, GL.GL_ONE_MINUS_SRC_ALPHA)}
    #: [px] room around the text's bounding box for its antialiased edges
    PAD = 2

    def __init__(self, font: QtGui.QFont, color: QtGui.QColor):
        super().__init__()
        self.setGLOptions(self.GL_OPTIONS)
        self.font = QtGui.QFont(font)
        self.color = QtGui.QColor(color)
        self.pos = np.zeros(3)
        self.text = ""
        self._image: QtGui.QImage | None = None      # the text drawn, None: to draw again
        self._origin = (0, 0)                         # [px] the baseline's start in it
        self._half_width = 0.0                        # [px] half the text's ink width
        self._texture = None                          # its GL name, made on the first paint
        self._uploaded = False                        # _image is in the texture

    def setData(self, *, pos=None, text: str | None = None) -> None:   # noqa: N802 (pyqtgraph)
        if pos is not None:
            self.pos = np.array(pos, dtype=float).reshape(3)
        if text is not None and text != self.text:
            self.text = text
            self._image = None
        self.update()

    def _draw_text(self, ratio: float) -> QtGui.QImage:
        """The text in its colour on a transparent image at ``ratio`` device pixels per
        pixel; sets where its baseline starts in it and half its ink's width (pixels)."""
        metrics = QtGui.QFontMetrics(self.font)
        box = metrics.boundingRect(self.text)
        self._half_width = metrics.tightBoundingRect(self.text).width() / 2.0
        pad = self.PAD
        width, height = box.width() + 2 * pad, box.height() + 2 * pad
        image = QtGui.QImage(max(1, round(width * ratio)), max(1, round(height * ratio)),
                             QtGui.QImage.Format.Format_RGBA8888_Premultiplied)
        image.setDevicePixelRatio(ratio)
        image.fill(QtCore.Qt.GlobalColor.transparent)
        self._origin = (pad - box.left(), pad - box.top())
        painter = QtGui.QPainter(image)
        painter.setRenderHints(QtGui.QPainter.RenderHint.Antialiasing |
                               QtGui.QPainter.RenderHint.TextAntialiasing)
        painter.setPen(self.color)
        painter.setFont(self.font)
        painter.drawText(QtCore.QPoint(*self._origin), self.text)
        painter.end()
        return image

    def _upload(self, image: QtGui.QImage, smooth: bool) -> None:
        if self._texture is None:
            self._texture = GL.glGenTextures(1)
        GL.glBindTexture(GL.GL_TEXTURE_2D, self._texture)
        filtering = GL.GL_LINEAR if smooth else GL.GL_NEAREST
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MIN_FILTER, filtering)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAG_FILTER, filtering)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_WRAP_S, GL.GL_CLAMP_TO_EDGE)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_WRAP_T, GL.GL_CLAMP_TO_EDGE)
        w, h = image.width(), image.height()
        rows = np.frombuffer(image.constBits(), dtype=np.uint8,
                             count=image.sizeInBytes()).reshape(h, image.bytesPerLine())
        GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 4)
        GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, GL.GL_RGBA, w, h, 0, GL.GL_RGBA,
                        GL.GL_UNSIGNED_BYTE, np.ascontiguousarray(rows[:, :4 * w]))
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)

    def paint(self) -> None:
        view = self.view()
        if not self.text or view is None or view.width() <= 0 or view.height() <= 0:
            return
        ratio = view.devicePixelRatio()
        if self._image is None or self._image.devicePixelRatio() != ratio:
            self._image = self._draw_text(ratio)
            self._uploaded = False
        if not self._uploaded:
            self._upload(self._image, smooth=ratio != int(ratio))
            self._uploaded = True
        # the point in window pixels (y down), as GLTextItem maps it; none behind the eye
        clip = self.mvpMatrix().map(QtGui.QVector4D(*self.pos, 1.0))
        if clip.w() <= 0:
            return
        x = (clip.x() / clip.w() + 1.0) / 2.0 * view.width()
        y = (1.0 - clip.y() / clip.w()) / 2.0 * view.height()
        x -= self._half_width      # centred on its ink, baseline on the point: GLTextItem's
        size = self._image.deviceIndependentSize()
        left = round((x - self._origin[0]) * ratio) / ratio
        top = round((y - self._origin[1]) * ratio) / ratio
        self.setupGLState()
        context = QtGui.QOpenGLContext.currentContext()
        program = LABEL_SHADER.program(
            es2_compat=context.hasExtension(b"GL_ARB_ES2_compatibility"))
        # the unit square's four corners from client memory (no buffer object to keep for
        # eight numbers; the view's compatibility context reads them at the draw)
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, 0)
        GL.glVertexAttribPointer(0, 2, GL.GL_FLOAT, False, 0, _UNIT_SQUARE)
        GL.glEnableVertexAttribArray(0)
        GL.glActiveTexture(GL.GL_TEXTURE0)
        GL.glBindTexture(GL.GL_TEXTURE_2D, self._texture)
        with LABEL_SHADER:
            GL.glUniform4f(GL.glGetUniformLocation(program, "u_rect"), left, top,
                           size.width(), size.height())
            GL.glUniform2f(GL.glGetUniformLocation(program, "u_view"), view.width(),
                           view.height())
            GL.glUniform1i(GL.glGetUniformLocation(program, "u_texture"), 0)
            GL.glDrawArrays(GL.GL_TRIANGLE_STRIP, 0, 4)
        GL.glDisableVertexAttribArray(0)
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)


#: the corners of a label's quad, drawn as a triangle strip and scaled by its shader
_UNIT_SQUARE = np.array([[0, 0], [1, 0], [0, 1], [1, 1]], dtype=np.float32)


class _Figure:
    """One skeleton's items: bones as a shaded mesh, joints as spheres, a name label."""

    def __init__(self, view: "Viewport", color):
        self.color = color
        self.mesh = gl.GLMeshItem(vertexes=np.zeros((3, 3)), faces=np.array([[0, 1, 2]]),
                                  color=color, shader="shaded", smooth=False,
                                  glOptions="opaque")
        self.joints = gl.GLScatterPlotItem(pos=np.zeros((1, 3)), color=color, size=0.02,
                                           pxMode=False)
        self.joints.setGLOptions("opaque")
        font = QtGui.QFont()
        font.setPointSizeF(10.5)
        font.setBold(True)
        self.label = _Label(font, QtGui.QColor.fromRgbF(*[min(1.0, c * 1.15 + 0.1)
                                                          for c in color[:3]]))
        self.label.setDepthValue(100)                 # drawn last: over a skinned mesh
        view.addItem(self.mesh)
        view.addItem(self.joints)
        view.addItem(self.label)

    def set_visible(self, on: bool) -> None:
        self.mesh.setVisible(on)
        self.joints.setVisible(on)
        self.label.setVisible(on)

    def update(self, positions: np.ndarray, parents: np.ndarray, offset: np.ndarray,
               width: float, joint_size: float, selected: int = -1, label: str = "") -> None:
        """Draw the joints ``positions`` ``(J, 3)`` [m] (engine axes) moved by ``offset`` (view
        axes): bones at most ``width`` thick, joints ``joint_size`` across (the ``selected``
        one twice that, in the selection colour), ``label`` above the head."""
        pts = to_view(positions) + offset
        child = np.flatnonzero(parents >= 0)
        verts, faces = bone_mesh(pts[parents[child]], pts[child], width)
        if len(faces):
            self.mesh.setMeshData(vertexes=verts, faces=faces, color=self.color,
                                  shader="shaded", smooth=False)
        colors = np.tile(self.color, (len(pts), 1))
        sizes = np.full(len(pts), joint_size)
        if 0 <= selected < len(pts):
            colors[selected] = SELECTED
            sizes[selected] = joint_size * 2.2
        self.joints.setData(pos=pts, color=colors, size=sizes)
        top = pts[np.argmax(pts[:, 2])]
        self.label.setData(pos=(float(pts[0, 0]), float(pts[0, 1]),
                                float(top[2] + 6 * joint_size)), text=label)
        self.points = pts

    def remove(self, view) -> None:
        view.removeItem(self.mesh)
        view.removeItem(self.joints)
        view.removeItem(self.label)


class _SkinBuffers:
    """A character's meshes as one: bind vertices ``(V, 3)``, influences ``(V, K)`` (meshes
    with fewer padded with zero weights) and triangles ``(T, 3)``, built once per character."""

    def __init__(self, character):
        self.character = character
        meshes = character.meshes
        K = max(m.joints.shape[1] for m in meshes)

        def pad(a, value):
            a = np.asarray(a)
            return np.pad(a, ((0, 0), (0, K - a.shape[1])), constant_values=value)
        self.positions = np.concatenate([np.asarray(m.positions, dtype=float) for m in meshes])
        self.joints = np.concatenate([pad(m.joints, 0) for m in meshes])
        self.weights = np.concatenate([pad(m.weights, 0.0) for m in meshes])
        offsets = np.cumsum([0] + [len(m.positions) for m in meshes[:-1]])
        self.faces = np.concatenate([m.triangles + o for m, o in zip(meshes, offsets)])

    def at(self, pose, frame: int) -> np.ndarray:
        """``(V, 3)`` [m] the vertices skinned by ``pose`` (the character's world pose over
        frames) at ``frame``."""
        from motion_composer.engine.skinning import joint_matrices, skin_vertices
        mats = joint_matrices(pose.rotations[frame:frame + 1], pose.positions[frame:frame + 1],
                              self.character.bind_positions)
        return skin_vertices(self.positions, self.joints, self.weights, mats)[0]


@dataclass
class FootTrails:
    """The target's feet over the play range (engine axes): per foot joint (ankles and toes)
    its path, the frames it is planted (contacts detected on the motion shown) and the floor
    under them."""

    motion: object
    frames: tuple[int, int]
    joints: list[str]
    paths: np.ndarray            # (n, F', 3) [m] frames first..last of the range
    planted: np.ndarray          # (n, F') bool
    floor: float                 # [m]


@dataclass
class _PoseDrag:
    """A pose gizmo ring being dragged: the joint (name and index), the ring (binding-frame
    axis 0, 1 or 2), its centre and normal (view space), the point grabbed on its plane, the
    joint's pose offset at the press and the one the drag has reached."""

    joint: str
    index: int
    axis: int
    center: np.ndarray
    normal: np.ndarray
    grabbed: np.ndarray
    start: np.ndarray
    offset: np.ndarray


class Viewport(GLViewMixin, QtOpenGL.QOpenGLWindow):
    """The document's skeletons at its current frame. Put :attr:`widget` in a layout."""

    #: a joint was clicked: side ("performer", "target") and name
    jointPicked = QtCore.Signal(str, str)
    #: files were dropped on the view: their local paths
    filesDropped = QtCore.Signal(list)

    def __init__(self, document, parent=None):
        super().__init__()
        self.doc = document
        # a depth buffer, asked for: left unspecified, Mesa under X may give a window none,
        # and a skinned mesh then shows whichever of its faces was drawn last (its back)
        surface = QtGui.QSurfaceFormat.defaultFormat()
        surface.setDepthBufferSize(24)
        self.setFormat(surface)
        #: whether this view draws (OpenGL here): it then emits ``frameSwapped`` per frame
        self.can_draw = gl_possible()
        if self.can_draw:
            self.widget = QtWidgets.QWidget.createWindowContainer(self, parent)
            self.widget.setFocusPolicy(QtCore.Qt.FocusPolicy.ClickFocus)
        else:
            self.widget = QtWidgets.QLabel("No OpenGL here: the 3D viewport is not drawn.",
                                           parent)
            self.widget.setAlignment(QtCore.Qt.AlignmentFlag.AlignCenter)
        self.widget.setMinimumSize(320, 240)
        _LIVE.add(self)
        self.setBackgroundColor((38, 40, 44))
        self.grid = gl.GLGridItem()
        self.grid.setSpacing(0.5, 0.5)
        self.grid.setSize(20, 20)
        self.grid.setColor((120, 120, 120, 90))
        self.addItem(self.grid)
        #: [m] the height the grid is drawn at (the project's floor, else 0)
        self.grid_height = 0.0
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
        # the judging tools: foot trails (path, planted frames, contacts on the floor), ghosts
        self.trail = gl.GLLinePlotItem(pos=np.zeros((2, 3)), color=TRAIL, width=2,
                                       mode="lines", antialias=True)
        self.planted = gl.GLScatterPlotItem(pos=np.zeros((1, 3)), color=PLANTED, size=6,
                                            pxMode=True)
        self.planted.setGLOptions("translucent")       # not added to the trail under it
        self.contacts = gl.GLMeshItem(vertexes=np.zeros((3, 3)), faces=np.array([[0, 1, 2]]),
                                      color=CONTACT_FLOOR, glOptions="translucent",
                                      smooth=False)
        for item in (self.trail, self.planted, self.contacts):
            item.setVisible(False)
            self.addItem(item)
        self.ghosts: list[gl.GLMeshItem] = []
        self.ghost_offsets: tuple[int, ...] = GHOST_OFFSETS
        self.skin = None                  # the target character's skinned mesh, when it has one
        self._skin_buffers: _SkinBuffers | None = None
        self._trails: FootTrails | None = None
        self.active_constraint: int | None = None   # the constraint whose goal can be dragged
        self._goal_drag = None
        # the pose gizmo's rings (x, y, z), the drag of one (a _PoseDrag) and the binding
        # poses drawn while editing, cached per binding
        self.rings = []
        for color in pose_gizmo.RING_COLORS:
            ring = gl.GLLinePlotItem(pos=np.zeros((2, 3)), color=color, width=3,
                                     mode="line_strip", antialias=True, glOptions=ON_TOP)
            ring.setDepthValue(50)
            ring.setVisible(False)
            self.rings.append(ring)
            self.addItem(ring)
        self._pose_drag: _PoseDrag | None = None
        self._drag_cancelled = False      # a cancelled drag's button is still held
        self._binding_poses: tuple | None = None
        self._press = None
        self.mousePos = QtCore.QPointF()
        self._framed = False
        #: the camera state last set (as the project held it) and the view it made
        self._camera_set: tuple[dict, dict] | None = None
        self.setCameraPosition(distance=5.0, elevation=15, azimuth=-90)
        document.frameChanged.connect(lambda _f: self.refresh())
        document.motionChanged.connect(self._motion_changed)
        document.selectionChanged.connect(lambda *_: self.refresh())
        document.constraintsChanged.connect(self.refresh)
        document.optionsChanged.connect(self._options_changed)
        self._motion_changed()

    # ------------------------------------------------------------------ display options
    def option(self, name: str) -> bool:
        """A display toggle kept in the project's viewer options: ``"follow_root"``,
        ``"onion_skin"``, ``"foot_trails"``, ``"pose_edit"`` (all off by default)."""
        return bool(self.doc.scene.viewer.options.get(name, False))

    def set_option(self, name: str, on: bool) -> None:
        """Turn a display toggle (:meth:`option`) on or off and redraw."""
        self.doc.set_viewer_options(**{name: bool(on)})
        self.refresh()

    def set_ghost_offsets(self, offsets) -> None:
        """The onion skin's frame offsets from the current frame (e.g. ``(-10, -5, 5, 10)``)."""
        self.ghost_offsets = tuple(int(o) for o in offsets if int(o) != 0)
        self.refresh()

    # ------------------------------------------------------------------ content
    def _motion_changed(self) -> None:
        if not self._framed and self.doc.scene.performer is not None:
            self.frame_all()
        self.refresh()

    def _layout(self) -> dict[str, np.ndarray]:
        """View-space offsets of the shown skeletons (side by side along X, or overlaid)."""
        v = self.doc.scene.viewer
        editing = self.pose_editing
        if editing:             # the binding pose beside the performer's reference pose
            shown = ["performer", "target"]
        else:
            shown = [k for k, on in (("performer", v.show_performer),
                                     ("intermediate", v.show_intermediate),
                                     ("target", v.show_target)) if on]
        gap = 1.2 * self._size()
        out = {}
        # every skeleton starts where the performer starts (its root over the performer's at
        # frame 0), then travels as it travels; side by side, each is moved along the view's x
        anchor = self._root_start("performer")
        # the performer is raised as the floor raises the character (Scene.lift), so that on
        # a raised floor it walks on the grid beside it, not under it
        lift = 0.0 if editing else self._lift()
        for i, k in enumerate(shown):
            x = (i - (len(shown) - 1) / 2) * gap if v.side_by_side or editing else 0.0
            start = self._root_start(k)
            shift = np.zeros(3) if anchor is None or start is None else anchor - start
            shift[2] = lift if k == "performer" else 0.0
            out[k] = np.array([x, 0.0, 0.0]) + shift
        return out

    def _lift(self) -> float:
        """The scene's :meth:`~engine.scene.Scene.lift`, once per scene (drawn on every
        frame of playback; it looks at the target file to find its cached floor)."""
        scene = self.doc.scene
        cached = self.__dict__.get("_lift_of")
        if cached is None or cached[0] is not scene:
            self._lift_of = cached = (scene, scene.lift())
        return cached[1]

    def _root_start(self, which: str):
        pose = self._pose(which)
        return None if pose is None else to_view(pose.positions[0, 0])

    def _pose(self, which: str):
        """The world pose over frames drawn for ``which`` skeleton, or None (while editing
        the binding pose, :meth:`binding_pose`'s single frame)."""
        if which != "intermediate" and self.pose_editing:
            return self.binding_pose(which)
        return {"performer": lambda: self.doc.pose("performer"),
                "intermediate": lambda: self.doc.pose("composed"),
                "target": lambda: self.doc.pose("target") or self.doc.pose("character")
                }[which]()

    def _size(self, motion=None) -> float:
        """[m] the stature of ``motion`` (by default the target, or else the performer),
        computed once per motion: joints, bones and goals are drawn in proportion to it."""
        from motion_composer.engine.describe import stature
        m = motion or (self.doc.scene.target if self.doc.scene.target is not None
                       else self.doc.scene.performer)
        if m is None:
            return 1.7
        cache = self.__dict__.setdefault("_statures", {})
        if cache.get(id(m), (None,))[0] is not m:
            cache[id(m)] = (m, max(stature(m), 0.2))
        return cache[id(m)][1]

    def _frame_of(self, which: str, pose) -> int:
        """The frame of ``pose`` shown for ``which`` (a target without motion: its rest)."""
        f = self.doc.scene.viewer.current_frame
        if which == "target" and self.doc.motion is None:
            f = 0
        return min(f, pose.positions.shape[0] - 1)

    def skeleton_points(self, which: str) -> tuple[np.ndarray, np.ndarray] | None:
        """World positions (engine axes) of a skeleton at the current frame, and parents."""
        doc = self.doc
        source = doc.scene.performer if which == "performer" else doc.scene.target
        pose = self._pose(which)
        if pose is None or source is None:
            return None
        return pose.positions[self._frame_of(which, pose)], source.skeleton.parents

    def _label(self, which: str) -> str:
        scene = self.doc.scene
        editing = self.pose_editing
        if which == "performer":
            return f"performer: {scene.performer.name}" + (" (reference pose)" if editing
                                                            else "")
        if which == "target":
            return f"target: {scene.target.name}" + (" (binding pose)" if editing else "")
        return "intermediate"

    def refresh(self) -> None:
        doc = self.doc
        layout = self._layout()
        side, joint = doc.selection
        for which in ("performer", "intermediate", "target"):
            size = self._size(doc.scene.performer if which == "performer" else None)
            width, joint_size = 0.03 * size, 0.022 * size
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
            fig.update(data[0], data[1], layout[which], width, joint_size, sel,
                       self._label(which))
            fig.offset = layout[which]
        self._refresh_grid()
        self._refresh_skin(layout)
        if self.skin is not None and self.skin.visible():
            # the mesh stands for the target's bones (its joints stay, to pick); the label
            # goes over the mesh
            self.figures["target"].mesh.setVisible(False)
            label = self.figures["target"].label
            top = float(self.skin.opts["meshdata"].vertexes()[:, 2].max())
            label.setData(pos=(*label.pos[:2], top + 0.06 * self._size()))
        self._refresh_virtual(layout)
        self._refresh_goals(layout)
        self._refresh_ghosts(layout)
        self._refresh_trails(layout)
        self._refresh_gizmo(layout)
        if self.option("follow_root") and not self.pose_editing:
            self._follow(layout)
        self.update()

    def _options_changed(self) -> None:
        # the floor moves the grid; what else an option moves comes with motionChanged
        self._refresh_grid()
        self.update()

    def _refresh_grid(self) -> None:
        """The grid lies on the project's floor where one is set (the character stands on
        it: :meth:`engine.scene.Scene.lift`), else at height 0, the files' own origin."""
        floor = self.doc.scene.project.floor
        height = 0.0 if floor is None else float(floor)
        if height != self.grid_height:
            self.grid.resetTransform()
            self.grid.translate(0.0, 0.0, height)       # view z is the engine's y (up)
            self.grid_height = height

    def _refresh_skin(self, layout) -> None:
        """The target character's mesh, deformed by the motion at the current frame: the
        vertices skinned with numpy from the document's cached world pose, smooth normals
        from those positions (:func:`vertex_normals`)."""
        doc = self.doc
        character = doc.scene.character if "target" in layout else None
        pose = self._pose("target") if character is not None else None
        if character is None or pose is None or not character.meshes:
            if self.skin is not None:
                self.skin.setVisible(False)
            return
        if self._skin_buffers is None or self._skin_buffers.character is not character:
            self._skin_buffers = _SkinBuffers(character)
        buffers = self._skin_buffers
        verts = to_view(buffers.at(pose, self._frame_of("target", pose))) + layout["target"]
        meshdata = SkinMeshData(verts, buffers.faces)
        if self.skin is None:
            self.skin = gl.GLMeshItem(meshdata=meshdata, color=SKIN, shader=TWO_SIDED,
                                      smooth=True, glOptions="opaque")
            self.addItem(self.skin)
        else:
            self.skin.setMeshData(meshdata=meshdata, color=SKIN, shader=TWO_SIDED, smooth=True)
        self.skin.setVisible(True)

    def _refresh_ghosts(self, layout) -> None:
        """Onion skin: the target's skeleton as lines at :attr:`ghost_offsets` frames from the
        current one (past blue, future red, fainter further away), while ``onion_skin`` is
        on. Lines, not shaded bones: light to draw, and legible beside a skinned mesh."""
        pose = self._pose("target") if "target" in layout and self.doc.motion is not None \
            else None
        on = self.option("onion_skin") and pose is not None and not self.pose_editing
        offsets = self.ghost_offsets if on else ()
        while len(self.ghosts) < len(offsets):
            ghost = gl.GLLinePlotItem(pos=np.zeros((2, 3)), width=2, mode="lines",
                                      antialias=True, glOptions="translucent")
            self.ghosts.append(ghost)
            self.addItem(ghost)
        for ghost in self.ghosts[len(offsets):]:
            ghost.setVisible(False)
        if not offsets:
            return
        f = self.doc.scene.viewer.current_frame
        F = pose.positions.shape[0]
        parents = self.doc.scene.target.skeleton.parents
        child = np.flatnonzero(parents >= 0)
        reach = max(abs(o) for o in offsets)
        for ghost, offset in zip(self.ghosts, offsets):
            g = f + offset
            if not 0 <= g < F:
                ghost.setVisible(False)
                continue
            pts = to_view(pose.positions[g]) + layout["target"]
            segments = np.stack([pts[parents[child]], pts[child]], axis=1).reshape(-1, 3)
            rgb = GHOST_PAST if offset < 0 else GHOST_FUTURE
            ghost.setData(pos=segments, color=(*rgb, 0.9 - 0.5 * abs(offset) / reach))
            ghost.setVisible(True)

    def foot_trails(self) -> FootTrails | None:
        """The target's foot trails over the play range (computed once per motion and range),
        or None where the target has no motion or no legs that can be found.

        The feet are the ankle and toe joints :func:`~engine.correction.contacts.find_feet`
        names, else those the scene puts the performer's feet on
        (:meth:`~engine.scene.Scene.target_feet`: a game rig's foot controls carried with its
        shins, as the robot's); a leg that ends without a foot joint and no control on it is
        followed at its shin's End Site, the ankle, with the planted frames the engine's
        contact detection finds for the shin."""
        motion = self.doc.motion
        if motion is None or self.doc.scene.target is None:
            return None
        lo, hi = self._play_range()
        cached = self._trails
        if cached is not None and cached.motion is motion and cached.frames == (lo, hi):
            return cached
        from motion_composer.engine.correction.contacts import (detect_contacts,
                                                                estimate_floor, find_feet)
        sk = motion.skeleton
        pose = self.doc.pose("target")
        feet = [(a, t) for a, t in find_feet(sk) or self.doc.scene.target_feet()
                if a in sk.index]
        if feet:
            joints = [name for pair in feet for name in pair if name is not None]
            tracks = pose.positions[:, [sk.index[name] for name in joints]]
            detects = joints
        else:
            feet, joints, columns = self._shin_ends(sk)
            tracks = pose.end_positions[:, columns]
            detects = [a for a, _t in feet]
        if not joints:
            self._trails = None
            return None
        paths = tracks[lo:hi + 1].transpose(1, 0, 2)
        planted = np.zeros(paths.shape[:2], dtype=bool)
        for c in detect_contacts(motion, feet):
            for name in (c.joint, c.toe):
                a, b = max(c.start, lo), min(c.end, hi)
                if name in detects and a <= b:
                    planted[detects.index(name), a - lo:b - lo + 1] = True
        floor = estimate_floor(tracks[..., 1])
        self._trails = FootTrails(motion, (lo, hi), joints, paths, planted, floor)
        return self._trails

    @staticmethod
    def _shin_ends(sk):
        """For a skeleton whose legs end without feet: ``(feet, names, columns)``, the shins
        as ``(ankle, None)`` pairs for contact detection, and their End Sites' names and
        columns in the pose's ``end_positions``."""
        from motion_composer.engine.conversion.automap import identify
        from motion_composer.engine.errors import MappingError
        try:
            roles = identify(sk)
        except MappingError:
            return [], [], []
        feet, names, columns = [], [], []
        for side in ("l", "r"):
            shin = roles.get(f"shin_{side}")
            ends = [k for k, e in enumerate(sk.end_sites) if shin and e.parent == sk.index[shin]]
            if ends:
                feet.append((shin, None))
                names.append(sk.end_sites[ends[0]].name)
                columns.append(ends[0])
        return feet, names, columns

    def _play_range(self) -> tuple[int, int]:
        last = max(self.doc.scene.num_frames - 1, 0)
        rng = self.doc.scene.viewer.play_range
        if rng is None:
            return 0, last
        lo, hi = sorted(min(max(int(v), 0), last) for v in rng)
        return lo, hi

    def _refresh_trails(self, layout) -> None:
        """Foot trails while ``foot_trails`` is on: each ankle's and toe's path over the play
        range, its planted frames marked on it, and the contacts active at the current frame
        drawn on the floor (a square under the planted joint)."""
        trails = self.foot_trails() if self.option("foot_trails") and "target" in layout \
            and not self.pose_editing else None
        for item in (self.trail, self.planted, self.contacts):
            item.setVisible(trails is not None)
        if trails is None:
            return
        off = layout["target"]
        paths = to_view(trails.paths) + off                          # (n, F', 3)
        segments = np.stack([paths[:, :-1], paths[:, 1:]], axis=2).reshape(-1, 3)
        if len(segments):
            self.trail.setData(pos=segments, color=TRAIL, mode="lines")
        else:
            self.trail.setVisible(False)
        marks = paths[trails.planted]
        self.planted.setData(pos=marks if len(marks) else np.zeros((1, 3)), color=PLANTED,
                             size=6)
        self.planted.setVisible(bool(len(marks)))
        f = self.doc.scene.viewer.current_frame - trails.frames[0]
        quads = []
        if 0 <= f < paths.shape[1]:
            r = 0.035 * self._size()
            floor = to_view(np.array([0.0, trails.floor, 0.0]))[2] + off[2]
            for k in np.flatnonzero(trails.planted[:, f]):
                x, y = paths[k, f, 0], paths[k, f, 1]
                quads.append(np.array([[x - r, y - r, floor], [x + r, y - r, floor],
                                       [x + r, y + r, floor], [x - r, y + r, floor]]))
        if quads:
            v = np.concatenate(quads)
            faces = np.concatenate([[[4 * i, 4 * i + 1, 4 * i + 2], [4 * i, 4 * i + 2, 4 * i + 3]]
                                    for i in range(len(quads))])
            self.contacts.setMeshData(vertexes=v, faces=faces, color=CONTACT_FLOOR)
        self.contacts.setVisible(bool(quads))

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
        says (:attr:`~engine.correction.constraints.ConstraintKind.draw`), and those of the
        selected constraint (:attr:`active_constraint`) at every frame."""
        doc = self.doc
        if "target" not in layout or not doc.scene.constraints or self.pose_editing:
            for item in (self.goals, self.paths, self.planes, self.axes):
                item.setVisible(False)
            return
        off = layout["target"]
        f = doc.scene.viewer.current_frame
        shapes = _Shapes()
        size = self._size()
        for i, c in enumerate(doc.scene.constraints):
            acting = c.enabled and c.smooth_in <= f <= c.smooth_out
            if not acting and i != self.active_constraint:
                continue                      # only what acts at this frame, or is selected
            self._DRAW[c.kind_object.draw](self, c, shapes, off,
                                           int(np.clip(f, c.smooth_in, c.smooth_out)), size)
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

    def _plane_quad(self, c, off, size):
        """A plane is unbounded: it is drawn as a square pad on it under where its joint is
        now (a floor plane's goal point is anywhere on it, the world's origin for the
        project's floor), so each foot joint's floor shows under that joint."""
        n = np.asarray(c.goal["normal"], dtype=float)
        n = n / np.linalg.norm(n)
        helper = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 0, 1.0])
        u = np.cross(n, helper)
        u /= np.linalg.norm(u)
        w = np.cross(n, u)
        p = np.asarray(c.goal["point"], dtype=float)
        data = self.skeleton_points("target")
        if data is not None and c.joint in self.doc.scene.target.skeleton.index:
            x = data[0][self.doc.scene.target.skeleton.index[c.joint]]
            p = x - np.dot(x - p, n) * n                   # the joint's foot on the plane
        p = p + PLANE_LIFT * size * n                      # off the grid's lines under it
        r = PLANE_PAD * size
        corners = [p + r * (a * u + b * w) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        return to_view(np.array(corners)) + off

    # ------------------------------------------------------------------ binding pose editing
    @property
    def pose_editing(self) -> bool:
        """The binding pose is shown for editing: the ``pose_edit`` option is on and the
        scene has a binding."""
        return self.option("pose_edit") and self.doc.scene.binding is not None

    def binding_pose(self, which: str) -> WorldPose:
        """The single-frame world pose drawn while editing: for ``"target"`` the binding pose
        (the bound rest posture with its pose offsets; during a gizmo drag, with the offset
        the drag has reached), for ``"performer"`` its reference pose."""
        b = self.doc.scene.binding
        cached = self._binding_poses
        if cached is None or cached[0] is not b:
            target = fk_arrays(b.target, b.rest_local[None], b.root_translation[None])
            performer = WorldPose(b.performer_rest_world[None],
                                  b.performer_rest_positions[None], np.zeros((1, 0, 3)))
            self._binding_poses = cached = (b, target, performer)
        drag = self._pose_drag
        if which == "performer" or drag is None:
            return cached[2] if which == "performer" else cached[1]
        local = pose_gizmo.with_turn(b.rest_local, drag.index, drag.start, drag.offset)
        return fk_arrays(b.target, local[None], b.root_translation[None])

    def gizmo(self) -> tuple | None:
        """The pose gizmo on the selected target joint (or the one mapped to the selected
        performer joint) while editing the binding pose: ``(joint, index, centre (3,), ring
        normals (3, 3) one a row, radius)`` in view space, or None. The normals are the axes
        of the joint's binding frame."""
        layout = self._layout()
        joint = self.doc.selected_target_joint
        if not self.pose_editing or "target" not in layout or joint is None:
            return None
        j = self.doc.scene.target.skeleton.index[joint]
        center = to_view(self.binding_pose("target").positions[0, j]) + layout["target"]
        frame = pose_gizmo.binding_frame(self.doc.scene.binding.rest_world[j],
                                         self.doc.scene.bind_options.offset(joint))
        normals = to_view(pose_gizmo.ring_axes(frame))
        return joint, j, center, normals, GIZMO_RADIUS * self._size()

    def _refresh_gizmo(self, layout) -> None:
        """The rings around the selected target joint (the one dragged highlighted)."""
        gizmo = self.gizmo() if "target" in layout else None
        drag = self._pose_drag
        for k, ring in enumerate(self.rings):
            ring.setVisible(gizmo is not None)
            if gizmo is None:
                continue
            _joint, _j, center, normals, radius = gizmo
            active = drag is not None and drag.axis == k
            ring.setData(pos=pose_gizmo.ring_points(center, normals[k], radius),
                         color=GIZMO_ACTIVE if active else pose_gizmo.RING_COLORS[k],
                         width=5 if active else 3)

    def _ring_hit(self, x: float, y: float, center: np.ndarray,
                  normal: np.ndarray) -> np.ndarray:
        """The view-space point under pixel (x, y) on the plane of the ring through
        ``center`` normal to ``normal``; for a ring seen edge-on, the point on the plane
        through the centre facing the camera (the angle is read about the normal anyway)."""
        origin, direction = self._ray(x, y)
        if not pose_gizmo.grazing(direction, normal):
            hit = pose_gizmo.plane_hit(origin, direction, center, normal)
            if hit is not None:
                return hit
        return self._unproject(x, y, center)

    def _grab_ring(self, x: float, y: float) -> _PoseDrag | None:
        """The drag of the gizmo ring under pixel (x, y), or None."""
        gizmo = self.gizmo()
        if gizmo is None:
            return None
        joint, j, center, normals, radius = gizmo
        pixels = [self.project(pose_gizmo.ring_points(center, n, radius)) for n in normals]
        k = pose_gizmo.nearest_ring(pixels, x, y, GIZMO_PICK_PX)
        if k is None:
            return None
        offset = np.asarray(self.doc.scene.bind_options.offset(joint), dtype=float)
        return _PoseDrag(joint, j, k, center, normals[k], self._ring_hit(x, y, center,
                                                                         normals[k]),
                         offset, offset)

    def _drag_ring(self, x: float, y: float) -> None:
        d = self._pose_drag
        angle = pose_gizmo.turn_angle(d.center, d.normal, d.grabbed,
                                      self._ring_hit(x, y, d.center, d.normal))
        d.offset = pose_gizmo.turned(d.start, d.axis, angle)

    def cancel_pose_drag(self) -> bool:
        """Drop a gizmo drag in progress (Esc, right click): the binding pose stays as it
        was, and the pointer does nothing more until the left button is released. False when
        there was none."""
        if self._pose_drag is None:
            return False
        self._pose_drag = None
        self._press = None
        self._drag_cancelled = True
        self.refresh()
        return True

    def _commit_pose_drag(self) -> None:
        """One command setting the dragged joint's pose offset (none for a click)."""
        from motion_composer.app.gui.commands import push_options
        d, self._pose_drag = self._pose_drag, None
        self._press = None
        options = self.doc.scene.bind_options.with_offset(d.joint, d.offset)
        push_options(self.doc, bind_options=options,
                     text=f"Turn {d.joint} in the binding pose")
        self.refresh()

    # ------------------------------------------------------------------ camera
    def _shown_box(self) -> np.ndarray | None:
        """``(2, 3)`` lowest and highest view-space corner of everything shown at the current
        frame (skeletons, their End Sites' parents, the skinned mesh), or None."""
        layout = self._layout()
        boxes = []
        for which, off in layout.items():
            data = self.skeleton_points(which)
            if data is not None:
                pts = to_view(data[0]) + off
                boxes.append(np.array([pts.min(axis=0), pts.max(axis=0)]))
        if self.skin is not None and self.skin.visible():
            verts = self.skin.opts["meshdata"].vertexes()
            boxes.append(np.array([verts.min(axis=0), verts.max(axis=0)]))
        if not boxes:
            return None
        return np.array([np.min([b[0] for b in boxes], axis=0),
                         np.max([b[1] for b in boxes], axis=0)])

    def _fit(self, box: np.ndarray) -> None:
        """Centre the camera on ``box`` and back off, along the current view direction, until
        each of its corners lies within :data:`FILL` of the view's width and height (so
        nothing is cropped: not the head, not the feet). pyqtgraph's ``fov`` is horizontal."""
        lo, hi = box
        center = (lo + hi) / 2
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                            for z in (lo[2], hi[2])]) - center
        az, el = np.radians(self.opts["azimuth"]), np.radians(self.opts["elevation"])
        back = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        right = np.array([-np.sin(az), np.cos(az), 0.0])
        up = np.cross(back, right)
        # not shown yet (no size): as a viewport of the default window's shape
        aspect = self.height() / self.width() if self.width() and self.height() else 0.6
        tan_x = np.tan(np.radians(self.opts["fov"]) / 2) * FILL
        tan_y = tan_x * aspect
        depth = corners @ back                       # towards the camera
        need = np.maximum(np.abs(corners @ right) / tan_x, np.abs(corners @ up) / tan_y)
        distance = max(float(np.max(depth + need)), 0.5)
        self.setCameraPosition(pos=QtGui.QVector3D(*center), distance=distance)
        self._framed = True
        self.update()

    def frame_all(self) -> None:
        """Fit everything shown, as it stands at the current frame, in the view, seen from a
        sensible height: an elevation outside :data:`SENSIBLE_ELEVATION` (grazing the floor
        from below, or from straight above after an orbit) goes back to
        :data:`FRAME_ELEVATION`; the azimuth is kept."""
        box = self._shown_box()
        if box is None:
            return
        lo, hi = SENSIBLE_ELEVATION
        if not lo <= self.opts["elevation"] <= hi:
            self.opts["elevation"] = FRAME_ELEVATION
        self._fit(box)

    def set_view(self, name: str) -> None:
        """Look from the ``"front"`` (along -Z), the ``"side"`` (along -X) or the ``"top"``,
        everything shown framed."""
        azimuth, elevation = VIEWS[name]
        self.setCameraPosition(azimuth=azimuth, elevation=elevation)
        box = self._shown_box()
        if box is not None:
            self._fit(box)

    def _follow(self, layout) -> None:
        """Keep the camera's centre over the root of the target (or else of the first figure
        shown), at the height it has: the follow camera."""
        for which in ("target", "performer", "intermediate"):
            data = self.skeleton_points(which) if which in layout else None
            if data is not None:
                root = to_view(data[0][0]) + layout[which]
                c = self.opts["center"]
                self.opts["center"] = QtGui.QVector3D(float(root[0]), float(root[1]), c.z())
                return

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

    # ------------------------------------------------------------------ pictures
    def render_image(self) -> QtGui.QImage:
        """The view as it stands now, drawn for this call: a null image where it cannot be
        drawn (no OpenGL, or not shown yet).

        ``grabFramebuffer`` of a ``QOpenGLWindow`` reads the window's framebuffer without
        drawing it, and a change asks for a frame that Qt draws later (throttled to the
        display's rate): read after ``update()`` it held whatever was drawn last, so a
        screenshot taken right after a camera change or a frame change showed the view
        before it (``--frame 900 --screenshot`` showed the camera of frame 0 with an old
        pose). Here the scene is drawn into the back buffer and read back before any swap.
        """
        if not (self.can_draw and self.isExposed() and self.isValid()):
            return QtGui.QImage()
        self.makeCurrent()
        self.paintGL()
        GL.glFinish()
        return self.grabFramebuffer()

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
            if fig is None or not fig.joints.visible() or not hasattr(fig, "points"):
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
        if i is None or not 0 <= i < len(cons) or cons[i].kind_object.drag_key is None \
                or self.pose_editing:
            return None
        off = self._layout().get("target")
        if off is None:
            return None
        return i, cons[i], to_view(cons[i].goal[cons[i].kind_object.drag_key]) + off, off

    def _ray(self, x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
        """The view-space ray under pixel (x, y): its point on the near plane and its
        direction (to the far plane's point)."""
        viewport = (0, 0, self.width(), self.height())
        m = np.array(self.projectionMatrix(viewport, viewport).data()).reshape(4, 4).T @ \
            np.array(self.viewMatrix().data()).reshape(4, 4).T
        inv = np.linalg.inv(m)
        ndc = np.array([2 * x / self.width() - 1, 1 - 2 * y / self.height()])
        near = inv @ np.array([ndc[0], ndc[1], -1.0, 1.0])
        far = inv @ np.array([ndc[0], ndc[1], 1.0, 1.0])
        near, far = near[:3] / near[3], far[:3] / far[3]
        return near, far - near

    def _unproject(self, x: float, y: float, through: np.ndarray) -> np.ndarray:
        """The view-space point under pixel (x, y) on the plane through ``through`` facing
        the camera."""
        near, direction = self._ray(x, y)
        eye = np.array(self.cameraPosition())
        normal = np.asarray(through) - eye
        normal /= np.linalg.norm(normal)
        t = np.dot(through - near, normal) / np.dot(direction, normal)
        return near + t * direction

    def mousePressEvent(self, ev):
        left = ev.button() == QtCore.Qt.MouseButton.LeftButton
        if self._pose_drag is not None:
            if not left:                          # a right click cancels the gizmo's drag
                self.cancel_pose_drag()
            return
        if self._drag_cancelled:
            return
        self._press = ev.position()
        self.mousePos = ev.position()
        if left:
            self._pose_drag = self._grab_ring(ev.position().x(), ev.position().y())
            if self._pose_drag is not None:
                self.refresh()
                return
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
        if self._drag_cancelled:
            return
        if self._pose_drag is not None:
            self._drag_ring(ev.position().x(), ev.position().y())
            self.mousePos = ev.position()
            self.refresh()
            return
        if self._goal_drag is not None:
            constraints, _ = self._dragged_goal(ev.position())
            self._goal_drag[3].request(constraints)
            self.mousePos = ev.position()
            return
        pos = ev.position()
        diff = pos - self.mousePos
        self.mousePos = pos
        buttons = ev.buttons()
        if not buttons:                   # a window sees the pointer hover: nothing to do
            return
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
        if self._drag_cancelled:
            self._drag_cancelled = ev.buttons() != QtCore.Qt.MouseButton.NoButton
            return
        if self._pose_drag is not None:
            if ev.button() == QtCore.Qt.MouseButton.LeftButton:
                self._drag_ring(ev.position().x(), ev.position().y())
                self._commit_pose_drag()
            return
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

    #: keys of the named views (as Blender's numpad: 1 front, 3 side, 7 top)
    _VIEW_KEYS = {QtCore.Qt.Key.Key_1: "front", QtCore.Qt.Key.Key_3: "side",
                  QtCore.Qt.Key.Key_7: "top"}

    def keyPressEvent(self, ev):
        if ev.key() == QtCore.Qt.Key.Key_Escape and self.cancel_pose_drag():
            return
        if ev.key() == QtCore.Qt.Key.Key_F:
            self.frame_all()
            return
        if ev.key() in self._VIEW_KEYS:
            self.set_view(self._VIEW_KEYS[ev.key()])
            return
        super().keyPressEvent(ev)

    # ------------------------------------------------------------------ files dropped
    def event(self, ev):
        """Files dragged onto the view are offered to the window (:attr:`filesDropped`): a
        native window gets its own drag events, which the main window never sees."""
        kind = ev.type()
        if kind in (QtCore.QEvent.Type.DragEnter, QtCore.QEvent.Type.DragMove):
            if ev.mimeData().hasUrls():
                ev.acceptProposedAction()
                return True
        elif kind == QtCore.QEvent.Type.Drop and ev.mimeData().hasUrls():
            paths = [u.toLocalFile() for u in ev.mimeData().urls() if u.isLocalFile()]
            ev.acceptProposedAction()
            self.filesDropped.emit(paths)
            return True
        return super().event(ev)
