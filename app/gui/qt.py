"""Qt set-up that must happen before any window exists.

* pyqtgraph picks PySide6 (it would otherwise prefer PyQt6 when both are installed);
* ``Qt.AA_ShareOpenGLContexts`` is set before the QApplication exists, or a second GL view in
  the process draws nothing.

PySide6 is pinned below 6.12 in pyproject.toml: 6.12.0 drops a reference to ``None`` on every
call that returns nothing (and to ``True`` on every signal emit), which aborts Python 3.11 after
a few thousand calls ("Fatal Python error: none_dealloc").
"""
from __future__ import annotations

import os
import sys

os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

from PySide6 import QtCore, QtGui, QtWidgets  # noqa: E402

QtCore.QCoreApplication.setAttribute(QtCore.Qt.ApplicationAttribute.AA_ShareOpenGLContexts)

__all__ = ["QtCore", "QtGui", "QtWidgets", "application"]


def application(argv=None) -> QtWidgets.QApplication:
    """The process's QApplication, created once."""
    app = QtWidgets.QApplication.instance()
    if app is None:
        app = QtWidgets.QApplication(list(argv if argv is not None else sys.argv))
        app.setApplicationName("Motion Composer")
        app.setOrganizationName("Motion Composer")
    return app
