"""Helpers for the GUI tests: a document on real clips, and GL availability."""
from __future__ import annotations

import pytest

from motion_composer.app.gui.qt import (QtGui,  # noqa: F401  (sets Qt up before anything else)
                                        QtWidgets)

#: the longest a GUI test waits for a condition, a signal or a window, in ms: generous, since
#: a loaded CI machine may be many times slower, and the suite runs a test file per core
#: (a wait that is met returns at once)
WAIT_MS = 60_000
#: the longest a GUI test waits for a whole solve of the demo to land (about 10 s on a quiet
#: machine: the IK and the key fit of its contacts and hand): with two other processes on
#: each of two cores a solve took over 30 s
SOLVE_WAIT_MS = 180_000


def gl_available() -> bool:
    """Whether this process can make an OpenGL context (Xvfb with Mesa can; 'offscreen'
    cannot): the viewport's own check."""
    from motion_composer.app.gui.viewport import gl_possible
    return gl_possible()


def require_gl():
    if not gl_available():
        pytest.skip("no OpenGL context can be made here (run under Xvfb: pytest-xvfb starts "
                    "it when Xvfb is installed; the 'offscreen' Qt platform has no GL)")


def view_pixels(view):
    """The viewport's picture as drawn now (:meth:`Viewport.render_image`): ``(H, W, 3)`` RGB
    integers. Waits (up to 30 s, processing events) until the view can be drawn: on a busy
    machine a viewport just shown may not be exposed yet, and its picture is then null."""
    import time
    import numpy as np
    from motion_composer.app.gui.qt import QtCore
    deadline = time.monotonic() + 30.0
    img = view.render_image()
    while img.isNull() and time.monotonic() < deadline:
        QtCore.QCoreApplication.processEvents(QtCore.QEventLoop.ProcessEventsFlag.AllEvents, 50)
        img = view.render_image()
    assert not img.isNull(), "the viewport could not be drawn within 30 s"
    img = img.convertToFormat(QtGui.QImage.Format.Format_RGB32)
    arr = np.frombuffer(img.constBits(), dtype=np.uint8).reshape(
        img.height(), img.bytesPerLine() // 4, 4)                     # B G R A per pixel
    return arr[:, :img.width(), :3][..., ::-1].astype(int)


def count_colour(pixels, rgb, tol: int = 40) -> int:
    """How many of ``pixels`` (:func:`view_pixels`) are within ``tol`` of ``rgb`` in every
    channel."""
    import numpy as np
    return int(np.sum(np.all(np.abs(pixels - np.asarray(rgb)) < tol, axis=-1)))


def demo_document():
    """The bundled CMU walk on the bundled CMU T-pose skeleton, mapped, evaluated."""
    from motion_composer.app.gui.document import Document
    from conftest import clip_path
    from motion_composer.engine import read_bvh
    from motion_composer.engine.conversion.correspondence import Correspondence
    from motion_composer.engine.project import Project, Source
    from motion_composer.engine.scene import Scene
    from ik_fixtures import MAX_TO_HOLDEN

    performer, target = clip_path("cmu_131_01_walk.bvh"), clip_path("cmu_rest_tpose.bvh")
    project = Project(performer=Source(path=str(performer)), target=Source(path=str(target)),
                      correspondence=Correspondence(MAX_TO_HOLDEN))
    doc = Document()
    doc.load_scene(Scene(project, read_bvh(performer), read_bvh(target)))
    return doc


def shown(qtbot, widget, width: int, height: int | None = None):
    """``widget`` handed to ``qtbot`` (closed after the test), ``width`` by ``height`` pixels
    (its size hint's height by default), shown, and once the window system has exposed it:
    the widget."""
    qtbot.addWidget(widget)
    widget.resize(width, widget.sizeHint().height() if height is None else height)
    widget.show()
    qtbot.waitExposed(widget, timeout=WAIT_MS)
    return widget


def quiet_window(qtbot, tmp_path, monkeypatch):
    """A real :class:`MainWindow` whose settings and autosaves live in ``tmp_path`` and which
    asks nothing: errors are kept in ``w.errors``, closing discards. Tests set other answers
    (``ask_yes_no``, ``ask_open_path``...) on the window they get."""
    from motion_composer.app.gui.main_window import MainWindow
    from motion_composer.app.gui.qt import QtCore
    QtCore.QSettings.setDefaultFormat(QtCore.QSettings.Format.IniFormat)
    QtCore.QSettings.setPath(QtCore.QSettings.Format.IniFormat,
                             QtCore.QSettings.Scope.UserScope, str(tmp_path / "settings"))
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    w = MainWindow()
    w.errors = []
    w.show_error = w.errors.append
    w.ask_unsaved = lambda: "discard"
    qtbot.addWidget(w)
    return w


def skinned_character_in_window(qtbot, tmp_path, character):
    """Import the bundled CMU walk as performer and ``character`` (a glTF file) as target in a
    real window, and read the skinned mesh's vertices at frames 100 and 400 and the character
    exported back as GLB: ``(doc, viewport, first, second, exported)``."""
    import pytest
    from conftest import clip_path
    from motion_composer.app.gui.main_window import MainWindow
    from motion_composer.engine.formats.gltf import read_gltf
    require_gl()
    w = MainWindow()
    qtbot.addWidget(w)
    w.show_error = lambda message: pytest.fail(message)
    w.resize(1200, 800)
    w.show()
    assert w.import_file("performer", clip_path("cmu_131_01_walk.bvh"))
    assert w.import_file("target", character)
    doc, v = w.doc, w.viewport
    assert doc.scene.ready and doc.scene.character is not None
    assert v.skin is not None and v.skin.visible()
    doc.set_frame(100)
    first = v.skin.opts["meshdata"].vertexes().copy()
    doc.set_frame(400)
    second = v.skin.opts["meshdata"].vertexes().copy()
    assert w.export_motion(tmp_path / "out.glb")
    exported = read_gltf(tmp_path / "out.glb")
    doc.undo_stack.setClean()
    return doc, v, first, second, exported
