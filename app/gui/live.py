"""Live re-solve: while a time handle or a goal is dragged, the corrected motion follows; on
release the final solve is pushed as one undoable command.

A drag calls :meth:`LiveSolver.request` with the whole constraint list as it would be if the
drag ended here. Requests are coalesced by a zero-delay ``QTimer``: the solver runs once the
pending mouse events are handled, on the latest request only, so at most one solve is in
flight and a slow solve drops intermediate positions instead of queueing them. The preview is
the scene's (:meth:`engine.scene.Scene.preview`), solved on the GUI thread (it has to be short
anyway) and shown with ``Document.show_preview`` (no undo step): the whole set when the last
full solve took at most ``budget`` seconds (~50 ms), else only the frames the change can reach
(:mod:`engine.correction.preview`).

:meth:`LiveSolver.commit` pushes the constraints as one command and solves them fully in the
document's job runner (progress, cancel, the GUI stays live; the preview stays up until the
solve lands). A failed or cancelled solve puts the document's own motion back.

One solver per document (:func:`live_solver`), shared by the timeline, the inspector and the
viewport's goal gizmo, so two previews never fight.
"""
from __future__ import annotations

import time

from motion_composer.app.gui.commands import push_constraints
from motion_composer.app.gui.qt import QtCore
from motion_composer.engine.errors import MotionComposerError

__all__ = ["LiveSolver", "live_solver", "BUDGET"]

#: [s] a full solve at most this long is used for previews; longer ones solve the window only
BUDGET = 0.05


class LiveSolver(QtCore.QObject):
    """Previews of a changing constraint list, and the final undoable solve.

    Signals: ``previewShown(float)`` the seconds the preview's solve took, after each preview;
    ``settleRequested()`` another edit is about to start: a panel holding a previewed edit
    commits it now (:meth:`settle`).

    Attributes:
        latencies: seconds of every preview solve since the solver was made.
        modes: ``"full"`` or ``"window"`` for each of them.
        full_seconds: the last full preview solve's time (``None`` until one ran; the
            document's last solve time stands in until then).
    """

    previewShown = QtCore.Signal(float)
    settleRequested = QtCore.Signal()

    def __init__(self, document, budget: float = BUDGET, parent=None):
        super().__init__(parent if parent is not None else document)
        self.doc = document
        self.budget = budget
        self.full_seconds: float | None = None
        self.latencies: list[float] = []
        self.modes: list[str] = []
        self._pending: list | None = None
        self._base_constraints: list | None = None
        self._base_motion = None
        self._shown = False
        self._timer = QtCore.QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.setInterval(0)
        self._timer.timeout.connect(self.flush)

    # ------------------------------------------------------------------ state
    @property
    def active(self) -> bool:
        """A drag is being previewed (between :meth:`begin` and commit or cancel)."""
        return self._base_constraints is not None

    @property
    def previewing(self) -> bool:
        """A preview motion is shown in place of the document's own."""
        return self._shown

    def settle(self) -> None:
        """Before a new edit: panels commit what they preview (the inspector's spin boxes)."""
        if self.active:
            self.settleRequested.emit()

    def begin(self) -> None:
        """Start a drag: remember the constraints and the motion shown now (the splice base).
        :meth:`request` calls it when needed."""
        if self.active:
            return
        self._base_constraints = list(self.doc.scene.constraints)
        self._base_motion = self.doc.motion
        self._shown = False

    def request(self, constraints: list) -> None:
        """Preview ``constraints`` (the whole list as it would be now) soon; only the latest
        request is solved."""
        self.begin()
        self._pending = list(constraints)
        if not self._timer.isActive():
            self._timer.start()

    def flush(self) -> None:
        """Solve the pending request now and show it."""
        self._timer.stop()
        constraints, self._pending = self._pending, None
        if constraints is None or not self.active or self.doc.scene.composed is None:
            return
        try:
            motion, seconds, mode = self.preview_motion(constraints)
        except MotionComposerError:
            return                  # an impossible intermediate state: keep the last preview
        self.latencies.append(seconds)
        self.modes.append(mode)
        self._shown = True
        self.doc.show_preview(motion)
        self.previewShown.emit(seconds)

    def cancel(self) -> None:
        """Drop the drag: no command, the document's own motion is shown again."""
        shown = self._shown
        self._reset()
        if shown:
            self.doc.show_preview(None)

    def _reset(self) -> None:
        self._timer.stop()
        self._pending = None
        self._base_constraints = None
        self._base_motion = None
        self._shown = False

    # ------------------------------------------------------------------ solving
    def preview_motion(self, constraints: list):
        """``(motion, seconds, mode)``: the corrected motion for ``constraints``, solved whole
        or in the changed window (:meth:`engine.scene.Scene.preview`)."""
        doc = self.doc
        base_constraints = self._base_constraints if self.active else list(doc.scene.constraints)
        base_motion = self._base_motion if self.active else doc.motion
        last = self.full_seconds if self.full_seconds is not None else doc.solve_seconds
        whole = last is not None and last <= self.budget
        t0 = time.perf_counter()
        motion, mode = doc.scene.preview(constraints, base_constraints=base_constraints,
                                         base_motion=base_motion, whole=whole)
        seconds = time.perf_counter() - t0
        if mode == "full":
            self.full_seconds = seconds
        return motion, seconds, mode

    def commit(self, constraints: list, text: str, on_done=None) -> None:
        """Push ``constraints`` as one command named ``text``, applied at once, then
        ``on_done()``; the document solves them fully in its job runner, and the preview
        stays up until that solve lands (a failed solve shows its error through the runner
        and leaves the constraints as edited)."""
        doc = self.doc
        self._reset()
        push_constraints(doc, list(constraints), text=text,
                         solve=doc.scene.composed is not None)
        if on_done is not None:
            on_done()


def live_solver(document) -> LiveSolver:
    """The document's one :class:`LiveSolver` (made on first use)."""
    solver = document.findChild(LiveSolver)
    return solver if solver is not None else LiveSolver(document)
