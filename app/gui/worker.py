"""Long engine work (IK over a clip) off the GUI thread, with progress and cancel.

The engine takes plain ``progress(fraction)`` and ``cancel() -> bool`` callables; this module
adapts them to Qt signals and a thread, so the window stays responsive.
"""
from __future__ import annotations

import threading
import traceback

from motion_composer.app.gui.qt import QtCore
from motion_composer.engine.errors import MotionComposerError

__all__ = ["Job"]


class _Runner(QtCore.QObject):
    progressed = QtCore.Signal(float)
    succeeded = QtCore.Signal(object)
    failed = QtCore.Signal(str)

    def __init__(self, fn, cancel_event: threading.Event):
        super().__init__()
        self._fn = fn
        self._cancel = cancel_event

    @QtCore.Slot()
    def run(self):
        try:
            result = self._fn(progress=self.progressed.emit, cancel=self._cancel.is_set)
        except MotionComposerError as exc:
            self.failed.emit(str(exc))
        except Exception:                       # noqa: BLE001 - shown, never swallowed
            self.failed.emit("an unexpected error stopped the work:\n" +
                             traceback.format_exc(limit=4))
        else:
            self.succeeded.emit(result)
        finally:
            # end the thread's event loop from inside, so that waiting for it never depends on
            # the GUI thread handling the result first
            QtCore.QThread.currentThread().quit()


class Job(QtCore.QObject):
    """Run ``fn(progress=..., cancel=...)`` in a thread; signals come back on the GUI thread.

    Signals: ``progressed(float)``, ``succeeded(object)``, ``failed(str)``, ``done()`` (after
    either, or after a cancel).
    """

    progressed = QtCore.Signal(float)
    succeeded = QtCore.Signal(object)
    failed = QtCore.Signal(str)
    done = QtCore.Signal()

    def __init__(self, fn, parent=None):
        super().__init__(parent)
        self._cancel = threading.Event()
        self._thread = QtCore.QThread()
        self._runner = _Runner(fn, self._cancel)
        self._runner.moveToThread(self._thread)
        self._thread.started.connect(self._runner.run)
        self._runner.progressed.connect(self.progressed)
        self._runner.succeeded.connect(self._finish_ok)
        self._runner.failed.connect(self._finish_failed)

    def start(self) -> None:
        self._thread.start()

    def cancel(self) -> None:
        self._cancel.set()

    @property
    def cancelled(self) -> bool:
        return self._cancel.is_set()

    def _finish_ok(self, result):
        self._stop()
        if not self._cancel.is_set():
            self.succeeded.emit(result)
        self.done.emit()

    def _finish_failed(self, message):
        self._stop()
        if not self._cancel.is_set():
            self.failed.emit(message)
        self.done.emit()

    def _stop(self):
        self._thread.quit()
        self._thread.wait()

    def wait(self, ms: int = 30000) -> bool:
        return self._thread.wait(ms)
