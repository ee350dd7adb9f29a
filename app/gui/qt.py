"""Qt set-up that must happen before any window exists.

* pyqtgraph picks PySide6 (it would otherwise prefer PyQt6 when both are installed);
* ``Qt.AA_ShareOpenGLContexts`` is set before the QApplication exists, or a second GL view in
  the process draws nothing;
* where the installed PySide6 drops a reference to ``None`` on calls that return nothing
  (PySide6 6.12.0 does, on every ``update()``, ``setText()``, ``processEvents()``...), ``None``
  is made immortal as Python 3.12 does it. On Python 3.11 its count otherwise reaches zero
  after a few thousand such calls and the process aborts with ``Fatal Python error:
  none_dealloc``.
"""
from __future__ import annotations

import os
import sys

os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

from PySide6 import QtCore, QtGui, QtWidgets  # noqa: E402

QtCore.QCoreApplication.setAttribute(QtCore.Qt.ApplicationAttribute.AA_ShareOpenGLContexts)


def _keep_none_alive() -> bool:
    """Detect the lost ``None`` references (16 calls of a void method) and, if they are lost,
    raise ``None``'s reference count by 2**40 (never reached). Python 3.12+ has an immortal
    ``None``; debug builds that trace references (``sys.getobjects``) are left alone.
    Returns whether the count was raised."""
    if sys.version_info >= (3, 12) or hasattr(sys, "getobjects"):
        return False
    probe = QtCore.QObject()
    before = sys.getrefcount(None)
    for _ in range(16):
        probe.setObjectName("probe")
    if sys.getrefcount(None) >= before:
        return False
    import ctypes
    ctypes.c_ssize_t.from_address(id(None)).value += 1 << 40
    return True


NONE_REFCOUNT_RAISED = _keep_none_alive()

__all__ = ["QtCore", "QtGui", "QtWidgets", "application"]


def application(argv=None) -> QtWidgets.QApplication:
    """The process's QApplication, created once."""
    app = QtWidgets.QApplication.instance()
    if app is None:
        app = QtWidgets.QApplication(list(argv if argv is not None else sys.argv))
        app.setApplicationName("Motion Composer")
        app.setOrganizationName("Motion Composer")
    return app
