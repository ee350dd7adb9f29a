"""The composer window (PySide6, pyqtgraph). Import :mod:`app.gui.qt` first: it sets what Qt
and pyqtgraph need before they load."""
