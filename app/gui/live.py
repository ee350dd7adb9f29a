"""Live re-solve: while a time handle or a goal is dragged, the corrected motion follows; on
release the final solve is pushed as one undoable command.

A drag calls :meth:`LiveSolver.request` with the whole constraint list as it would be if the
drag ended here. Requests are coalesced by a zero-delay ``QTimer``: the solver runs once the
pending mouse events are handled, on the latest request only, so at most one solve is in
flight and a slow solve drops intermediate positions instead of queueing them. The preview
solve runs on the GUI thread (it has to be short anyway) and is shown with
``Document.show_preview`` (no undo step).

What a preview solves:

* the whole set, when the last full solve of this document took at most ``budget`` seconds
  (~50 ms: a few constraints, a short clip);
* otherwise only the frames that can change: the *window* ``[lo, hi]`` covers the changed
  constraints' old and new ``[smooth_in, smooth_out]`` (outside it nothing they do reaches;
  a drag of one side's handles reaches that side only, :func:`affected_frames`),
  and :func:`window_problem` cuts the constraint set down to what decides the window's
  frames: the constraints overlapping it, plus those active at the pass-one key postures that
  its ramps take (a ramp in the window eases from the posture at its ``smooth_in``, or towards
  the ones at its ``end`` and ``smooth_out``, section 3.3), each with its active range clipped
  to the frames ``[L, H]`` spanning the window and those keys. Every frame of the window then
  sees the same tasks and the same key postures as in the full solve, so the window is the
  full solve's (to the solver's tolerance; a test checks it); its frames are spliced into the
  motion shown before the drag. The final solve on release is always the full one.

:meth:`LiveSolver.commit` solves the whole set and pushes ``push_constraints(doc, constraints,
displacement, text)``: in the window's worker when a :class:`~app.gui.main_window.MainWindow`
was given (progress, cancel, the GUI stays live; the preview stays up until the command
lands), else synchronously. A failed or cancelled solve puts the document's own motion back.

One solver per document (:func:`live_solver`), shared by the timeline, the inspector and the
viewport's goal gizmo, so two previews never fight.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from app.gui.commands import push_constraints
from app.gui.qt import QtCore
from engine.correction.displacement import DisplacementMap
from engine.errors import MotionComposerError

__all__ = ["LiveSolver", "live_solver", "changed_window", "affected_frames", "overlapping",
           "window_problem",
           "retimed", "BUDGET", "ROTATION_TOLERANCE", "TRANSLATION_TOLERANCE"]

#: [s] a full solve at most this long is used for previews; longer ones solve the window only
BUDGET = 0.05
#: key reduction of the displacement map pushed on release (the window's solve uses the same)
ROTATION_TOLERANCE = 1.7e-4
TRANSLATION_TOLERANCE = 5e-5


def _same_but_range(a, b) -> bool:
    """``a`` and ``b`` differ at most in their time range."""
    if (a.joint, a.kind, a.priority, a.weight, a.enabled) != \
            (b.joint, b.kind, b.priority, b.weight, b.enabled) or a.goal.keys() != b.goal.keys():
        return False
    for key, value in a.goal.items():
        other = b.goal[key]
        if isinstance(value, np.ndarray) or isinstance(other, np.ndarray):
            if not np.array_equal(np.asarray(value), np.asarray(other)):
                return False
        elif value != other:
            return False
    return True


def affected_frames(old, new) -> tuple[int, int]:
    """The frames whose solution can differ between two versions of one constraint.

    A change of the time range only (a handle drag) reaches the side that moved: moving
    ``smooth_in`` or ``start`` changes ``[min smooth_in, max start]`` (the input ramp and the
    frames entering or leaving the active range); the active frames beyond keep the same goal
    and the output ramp the same key postures. Likewise on the ``end`` side. Any other change
    reaches the whole of both ``[smooth_in, smooth_out]``."""
    if not _same_but_range(old, new):
        return min(old.smooth_in, new.smooth_in), max(old.smooth_out, new.smooth_out)
    spans = []
    if (old.smooth_in, old.start) != (new.smooth_in, new.start):
        spans.append((min(old.smooth_in, new.smooth_in), max(old.start, new.start)))
    if (old.end, old.smooth_out) != (new.end, new.smooth_out):
        spans.append((min(old.end, new.end), max(old.smooth_out, new.smooth_out)))
    if not spans:
        return new.start, new.start
    return min(s[0] for s in spans), max(s[1] for s in spans)


def changed_window(before: list, after: list) -> tuple[int, int] | None:
    """Frames ``(lo, hi)`` covering what can change between two constraint lists of the same
    length (compared by identity: constraints are immutable, an edit makes a new one; see
    :func:`affected_frames`). ``None`` when nothing differs or the lengths differ (a
    constraint added or removed: solve everything)."""
    if len(before) != len(after):
        return None
    lo, hi = None, None
    for old, new in zip(before, after):
        if old is new:
            continue
        a, b = affected_frames(old, new)
        lo = a if lo is None else min(lo, a)
        hi = b if hi is None else max(hi, b)
    return None if lo is None else (lo, hi)


def overlapping(constraints: list, lo: int, hi: int) -> list:
    """The enabled constraints whose ``[smooth_in, smooth_out]`` meets ``[lo, hi]``."""
    return [c for c in constraints if c.enabled and c.smooth_in <= hi and c.smooth_out >= lo]


def retimed(c, rng: tuple, shift: int | None = None):
    """``c`` over the range ``rng`` (smooth_in, start, end, smooth_out). A trajectory given
    per frame becomes keys at the same frames (its length is tied to the old range);
    ``shift`` (a whole-range move) moves a trajectory's keys along."""
    goal = c.kind_object.retimed_goal(c, shift)
    return dataclasses.replace(c, goal=goal, smooth_in=int(rng[0]), start=int(rng[1]),
                               end=int(rng[2]), smooth_out=int(rng[3]))


def window_problem(constraints: list, lo: int, hi: int) -> list:
    """The constraints that decide frames ``lo..hi``, cut to the frames that matter.

    * every enabled constraint overlapping ``[lo, hi]``;
    * the key frames its ramps need from pass one, where a ramp reaches into the window: an
      input ramp its ``smooth_in``, an output ramp its ``end`` and ``smooth_out``;
      ``[L, H]`` spans the window and those keys;
    * every other enabled constraint active at one of those keys (it shapes that key posture);
    * each constraint's active range clipped to ``[L, H]``, dropping a ramp that lies wholly
      outside (a clipped end has no ramp: what lies beyond does not reach the window).
    """
    inside = overlapping(constraints, lo, hi)
    keys = set()
    for c in inside:
        if c.smooth_in < c.start and c.smooth_in <= hi and c.start >= lo:
            keys.add(c.smooth_in)
        if c.end < c.smooth_out and c.end <= hi and c.smooth_out >= lo:
            keys.update((c.end, c.smooth_out))
    outside_keys = sorted(k for k in keys if not lo <= k <= hi)
    L, H = min([lo, *keys]), max([hi, *keys])
    chosen = list(inside)
    for c in constraints:
        if c.enabled and c not in chosen and any(c.start <= k <= c.end for k in outside_keys):
            chosen.append(c)
    out = []
    for c in constraints:                       # the document's order
        if not any(c is x for x in chosen):
            continue
        si, st, en, so = c.range
        if c not in inside:                     # only its active frames at the keys
            si, so = st, en
        if st < L:
            si = st = min(L, en)
        if en > H:
            en = so = max(H, st)
        out.append(c if (si, st, en, so) == c.range else retimed(c, (si, st, en, so)))
    return out


def _splice(base, part, lo: int, hi: int):
    """``base`` with frames ``lo..hi`` taken from ``part`` (same skeleton and length)."""
    rot = np.array(base.rotations)
    tra = np.array(base.translations)
    rot[lo:hi + 1] = part.rotations[lo:hi + 1]
    tra[lo:hi + 1] = part.translations[lo:hi + 1]
    return base.replace(rotations=rot, translations=tra)


class LiveSolver(QtCore.QObject):
    """Previews of a changing constraint list, and the final undoable solve.

    Signals: ``previewShown(float)`` the seconds the preview's solve took, after each preview;
    ``settleRequested()`` another edit is about to start: a panel holding a previewed edit
    commits it now (:meth:`settle`).

    Attributes:
        latencies: seconds of every preview solve since the solver was made.
        modes: ``"full"`` or ``"window"`` for each of them.
        full_seconds: the last full solve's time (``None`` until one ran).
    """

    previewShown = QtCore.Signal(float)
    settleRequested = QtCore.Signal()

    def __init__(self, document, window=None, budget: float = BUDGET, parent=None):
        super().__init__(parent if parent is not None else document)
        self.doc = document
        self.window = window
        self.budget = budget
        self.full_seconds: float | None = None
        self.latencies: list[float] = []
        self.modes: list[str] = []
        self._pending: list | None = None
        self._base_constraints: list | None = None
        self._base_motion = None
        self._shown = False
        self._options_for = (None, None)        # (composed motion, IKOptions)
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
        self._base_constraints = list(self.doc.constraints)
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
        if constraints is None or not self.active or self.doc.composed is None:
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
    def _options(self, composed):
        from engine.describe import stature
        from engine.correction.ik import IKOptions
        if self._options_for[0] is not composed:
            self._options_for = (composed, IKOptions(scale=max(stature(composed), 0.1)))
        return self._options_for[1]

    def preview_motion(self, constraints: list):
        """``(motion, seconds, mode)``: the corrected motion for ``constraints``, solved whole
        or in the changed window (see the module doc)."""
        from engine.correction.enforcement import enforce
        doc = self.doc
        composed = doc.composed
        base_constraints = self._base_constraints if self.active else list(doc.constraints)
        base_motion = self._base_motion if self.active else doc.motion
        window = changed_window(base_constraints, constraints)
        t0 = time.perf_counter()
        whole = window is None or base_motion is None or (
            self.full_seconds is not None and self.full_seconds <= self.budget)
        if whole:
            motion = enforce(composed, constraints, options=self._options(composed)).motion
            seconds = time.perf_counter() - t0
            self.full_seconds = seconds
            return motion, seconds, "full"
        lo, hi = window
        subset = window_problem(constraints, lo, hi)
        part = enforce(composed, subset, options=self._options(composed)).motion
        motion = _splice(base_motion, part, lo, hi)
        return motion, time.perf_counter() - t0, "window"

    def solve(self, constraints: list, progress=None, cancel=None) -> DisplacementMap:
        """The displacement map of the full solve of ``constraints`` (empty without enabled
        constraints). Raises :class:`~engine.errors.MotionComposerError`."""
        from engine.correction.enforcement import enforce
        composed = self.doc.composed
        if not any(c.enabled for c in constraints):
            return DisplacementMap()
        t0 = time.perf_counter()
        correction = enforce(composed, constraints, progress=progress, cancel=cancel)
        self.full_seconds = time.perf_counter() - t0
        return correction.displacement_map(rotation_tolerance=ROTATION_TOLERANCE,
                                           translation_tolerance=TRANSLATION_TOLERANCE)

    def commit(self, constraints: list, text: str, on_abort=None, on_done=None) -> None:
        """Solve ``constraints`` fully and push them with their displacement map as one
        command named ``text``; then ``on_done()`` (at once without a window, when the worker
        is done with one). ``on_abort()`` runs instead if the solve fails or is cancelled (the
        caller puts its widgets back); the error is shown through ``doc.errorRaised`` (or the
        window's dialog)."""
        doc = self.doc
        constraints = list(constraints)
        shown = self._shown
        self._reset()

        def abort(message: str | None = None):
            if shown:
                doc.show_preview(None)
            if on_abort is not None:
                on_abort()
            if message:
                doc.errorRaised.emit(message)

        if doc.composed is None:              # nothing to solve on yet: keep the constraints
            push_constraints(doc, constraints, text=text)
            if on_done is not None:
                on_done()
            return
        composed = doc.composed

        def work(progress=None, cancel=None):
            if doc.composed is not composed:
                raise MotionComposerError("the motion changed while solving")
            return self.solve(constraints, progress, cancel)

        def done(displacement):
            push_constraints(doc, constraints, displacement, text=text)
            if on_done is not None:
                on_done()

        window = self.window
        if window is not None and hasattr(window, "run_job"):
            before = window.job
            window.run_job(work, done, "Solving")
            job = window.job
            if job is None or job is before:           # refused: another job is running
                abort()
                return
            job.failed.connect(lambda _message: abort())
            job.done.connect(lambda: abort() if job.cancelled else None)
            return
        try:
            displacement = work()
        except MotionComposerError as exc:
            abort(str(exc))
            return
        done(displacement)


def live_solver(document, window=None) -> LiveSolver:
    """The document's one :class:`LiveSolver` (made on first use; ``window`` sets the window
    whose worker runs the final solves)."""
    solver = document.findChild(LiveSolver)
    if solver is None:
        solver = LiveSolver(document, window)
    elif window is not None:
        solver.window = window
    return solver
