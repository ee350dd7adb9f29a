"""Start the composer window: ``motion-composer [PROJECT] [--demo]``."""
from __future__ import annotations

from pathlib import Path

REPO_RESOURCES = Path(__file__).resolve().parent.parent.parent / "resources"
DEMO_PROJECT = REPO_RESOURCES / "demo" / "demo.mcp"


def run(project: str | None = None, *, demo: bool = False, screenshot: str | None = None,
        frame: int | None = None, quit_after_ms: int | None = None) -> int:
    """Open the window (on ``project`` or the demo) and run the event loop.

    ``screenshot``: save a PNG of the window once it is drawn, then quit (for documentation
    and self-tests); ``frame``: go to that frame first.
    """
    from app.gui.qt import QtCore, application
    from app.runtime import tune_allocator

    tune_allocator()
    app = application()
    from app.gui.main_window import MainWindow
    window = MainWindow()
    window.show()
    path = DEMO_PROJECT if demo else project
    if path is not None:
        window.open_project(path)
    else:
        window.offer_recovery()
    if frame is not None:
        window.doc.set_frame(frame)
    if screenshot is not None:
        def shoot():
            window.viewport.frame_all()
            app.processEvents()
            window.grab().save(screenshot)
            app.quit()
        QtCore.QTimer.singleShot(1500, shoot)
    elif quit_after_ms is not None:
        QtCore.QTimer.singleShot(quit_after_ms, app.quit)
    return app.exec()
