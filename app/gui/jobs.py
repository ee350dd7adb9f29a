"""The document's job runner: long engine work (IK over a clip) off the GUI thread.

One runner per document, shared by everything that solves (the live preview's final solve,
Tools > Solve, the foot contacts), so two solves never race. Starting a job while another runs
cancels the running one (its result is dropped) and starts the new one at once: the newest
request always wins and nothing is refused. Signals come back on the GUI thread.
"""
from __future__ import annotations

from motion_composer.app.gui.qt import QtCore
from motion_composer.app.gui.worker import Job

__all__ = ["JobRunner"]


class JobRunner(QtCore.QObject):
    """Runs ``fn(progress=..., cancel=...)`` in a thread, one at a time.

    Signals: ``started(str)`` a label, ``progressed(float)`` in [0, 1], ``failed(str)`` a
    message for the user, ``finished()`` after every job (success, failure or cancel).

    Attributes:
        last_outcome: ``"succeeded"``, ``"failed"`` or ``"cancelled"`` for the job that
            finished last (read it in ``on_end`` callbacks).
    """

    started = QtCore.Signal(str)
    progressed = QtCore.Signal(float)
    failed = QtCore.Signal(str)
    finished = QtCore.Signal()

    def __init__(self, parent=None):
        super().__init__(parent)
        self._job: Job | None = None
        self._retired: list[Job] = []
        self.last_outcome = ""

    @property
    def busy(self) -> bool:
        return self._job is not None

    def run(self, label: str, fn, on_success, on_end=None) -> None:
        """Start ``fn`` (dropping a running job); ``on_success(result)`` on the GUI thread,
        then ``on_end(outcome)`` with ``"succeeded"``, ``"failed"`` or ``"cancelled"`` (also
        for a job dropped by a newer one)."""
        self._drop()
        job = Job(fn, self)
        self._job = job
        state = {"failed": False}

        def succeeded(result):
            if job is self._job:
                on_success(result)

        def failed(message):
            state["failed"] = True
            if job is self._job:
                self.failed.emit(message)

        def done():
            current = job is self._job
            if job in self._retired:
                self._retired.remove(job)
            outcome = ("cancelled" if job.cancelled else
                       "failed" if state["failed"] else "succeeded")
            if current:
                self._job = None
                self.last_outcome = outcome
            if on_end is not None:
                on_end(outcome)
            if current:
                self.finished.emit()

        job.progressed.connect(lambda f: job is self._job and self.progressed.emit(f))
        job.succeeded.connect(succeeded)
        job.failed.connect(failed)
        job.done.connect(done)
        self.started.emit(label)
        job.start()

    def cancel(self) -> None:
        """Stop the running job at the user's request (its result is dropped)."""
        if self._drop():
            self.last_outcome = "cancelled"
            self.finished.emit()

    def _drop(self) -> bool:
        job, self._job = self._job, None
        if job is None:
            return False
        job.cancel()
        self._retired.append(job)
        return True

    def wait(self, ms: int = 30000) -> bool:
        """Block until every started job's thread has ended (closing, tests)."""
        ok = True
        for job in ([self._job] if self._job else []) + list(self._retired):
            ok = job.wait(ms) and ok
        return ok
