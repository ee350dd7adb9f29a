"""Helpers for the GUI tests: a document on real clips, and GL availability."""
from __future__ import annotations

import pytest

from app.gui.qt import QtGui, QtWidgets  # noqa: F401  (sets Qt up before anything else)


def gl_available() -> bool:
    """Whether this process can make an OpenGL context (Xvfb with Mesa can; 'offscreen'
    cannot)."""
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


def require_gl():
    if not gl_available():
        pytest.skip("no OpenGL context can be made here (run under Xvfb: pytest-xvfb starts "
                    "it when Xvfb is installed; the 'offscreen' Qt platform has no GL)")


def demo_document():
    """The bundled CMU walk on the bundled CMU T-pose skeleton, mapped, evaluated."""
    from app.gui.commands import push_correspondence, push_sources
    from app.gui.document import Document
    from conftest import clip_path
    from engine import read_bvh
    from engine.conversion.correspondence import Correspondence
    from ik_fixtures import MAX_TO_HOLDEN

    doc = Document()
    push_sources(doc, read_bvh(clip_path("cmu_131_01_walk.bvh")),
                 clip_path("cmu_131_01_walk.bvh"), read_bvh(clip_path("cmu_rest_tpose.bvh")),
                 clip_path("cmu_rest_tpose.bvh"))
    push_correspondence(doc, Correspondence(MAX_TO_HOLDEN), "Map")
    doc.undo_stack.setClean()
    return doc
