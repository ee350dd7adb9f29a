"""The document: a Qt shell over one engine :class:`~engine.scene.Scene`.

The scene holds the session's choices and sources and derives the binding, the direct
conversion and the final motion (:mod:`engine.scene`); the document holds the current scene,
the undo stack, the selection, the job runner and the signals the widgets listen to. Widgets
never change the scene: every edit is a command (:mod:`app.gui.commands`) that swaps one scene
for another. Undo holds scenes (choices; derived results are cached by their inputs in the
engine), so undo and redo cost no recomputation when the result is still cached.

Solving runs in the document's one :class:`~app.gui.jobs.JobRunner`. An edit that needs a
solve is applied at once (its command is on the stack straight away) and the scene it made is
marked *pending*; the solve's result then replaces that scene everywhere in the history (no
second undo step). An edit made while a solve runs applies at once too and restarts the solve
for the newest pending scene; a scene whose solve was dropped is solved again when undo or
redo comes back to it.
"""
from __future__ import annotations

import dataclasses
import time
import weakref
from pathlib import Path

import numpy as np

from motion_composer.app.gui.jobs import JobRunner
from motion_composer.app.gui.qt import QtCore, QtGui
from motion_composer.engine.errors import MotionComposerError
from motion_composer.engine.kinematics import WorldPose, forward_kinematics
from motion_composer.engine.motion import Motion
from motion_composer.engine.project import (MissingSourceError, autosave_path, check_project, find_autosave,
                            load_project, new_session, project_from_json, read_sources,
                            remove_autosave_file, save_project, write_autosave)
from motion_composer.engine.scene import Scene

__all__ = ["Document"]

#: which signal each project field's change emits
_FIELD_SIGNALS = {
    "performer": "sourcesChanged", "target": "sourcesChanged",
    "correspondence": "mappingChanged",
    "bind_options": "optionsChanged", "root": "optionsChanged",
    "auto_contacts": "optionsChanged", "contact_options": "optionsChanged",
    "floor": "optionsChanged", "stand_on_floor": "optionsChanged",
    "ik_options": "optionsChanged",
    "constraints": "constraintsChanged",
}


def keys_note(keys: dict) -> str:
    """The status line of a solve's stored keys (``report["keys"]``): how many, fitted to what,
    how far they put any joint from the dense solve (where: joint and frame), and why keys
    fitted to the tasks were not kept where they were not."""
    where = (f" ({keys['joint']}, frame {keys['frame']})" if keys.get("joint") is not None
             else "")
    why = f", because {keys['why_dense_curves']}" if keys.get("why_dense_curves") else ""
    return (f"Solved: {keys['count']} keys fitted to the {keys['fitted_to']}, at most "
            f"{keys['largest_distance_from_dense_m'] * 1000:.1f} mm from the dense "
            f"solve{where}{why}")


class Document(QtCore.QObject):
    """A retargeting session with undo: the current scene and what the window shows of it."""

    #: anything changed (title, modified mark)
    changed = QtCore.Signal()
    #: a performer or target was loaded
    sourcesChanged = QtCore.Signal()
    #: the correspondence changed
    mappingChanged = QtCore.Signal()
    #: binding, root, contact or IK options changed
    optionsChanged = QtCore.Signal()
    #: constraints changed
    constraintsChanged = QtCore.Signal()
    #: the motion shown changed
    motionChanged = QtCore.Signal()
    #: the current frame changed
    frameChanged = QtCore.Signal(int)
    #: what the viewer shows changed (skeletons shown, side by side, camera, play range)
    viewerChanged = QtCore.Signal()
    #: a joint was selected: side ("target" or "performer") and joint name ("" for none)
    selectionChanged = QtCore.Signal(str, str)
    #: an error the user should see (the window shows a dialog)
    errorRaised = QtCore.Signal(str)
    #: a short note for the status bar (a pair an edit replaced, a solve restarted)
    noted = QtCore.Signal(str)
    #: a pending solve landed (the scene now carries its correction)
    solved = QtCore.Signal()
    #: a running solve's IK has run: its dense correction is shown (as a preview) while its
    #: keys are fitted, the longer part of a solve
    keysFitting = QtCore.Signal()
    #: (scene, motion) from the solving thread: the dense correction of ``scene``'s solve
    _denseSolved = QtCore.Signal(object, object)

    def __init__(self, parent=None):
        super().__init__(parent)
        self.undo_stack = QtGui.QUndoStack(self)
        self.undo_stack.cleanChanged.connect(self._stack_changed)
        self.undo_stack.indexChanged.connect(self._stack_changed)
        self.jobs = JobRunner(self)
        self._denseSolved.connect(self._dense_solved, QtCore.Qt.ConnectionType.QueuedConnection)
        self.path: Path | None = None
        self.selection: tuple[str, str] = ("", "")
        self._scene = Scene.empty()
        self._preview: Motion | None = None
        self._poses: dict[str, tuple[Motion, WorldPose]] = {}
        #: scenes whose correction is still to be solved -> solve keyword arguments
        self._pending: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
        self._solving: Scene | None = None
        #: [s] how long the last solve that landed took (None before one did)
        self.solve_seconds: float | None = None
        #: the quality figures (``report["quality"]`` of :func:`engine.correction.quality`)
        #: of the solve that landed last (None before one did)
        self.last_quality: dict | None = None
        #: names this session's autosave while the project was never saved
        self.session = new_session()
        #: autosave files that hold the current work: the ones this document wrote and the
        #: one it was recovered from (removed when the work is saved or discarded)
        self._autosaves: set[Path] = set()

    def _stack_changed(self, *_args) -> None:
        self.changed.emit()

    # ------------------------------------------------------------------ state
    @property
    def scene(self) -> Scene:
        return self._scene

    @property
    def modified(self) -> bool:
        return not self.undo_stack.isClean()

    @property
    def title(self) -> str:
        name = self.path.name if self.path else "Untitled"
        return f"{name}{'*' if self.modified else ''} - Motion Composer"

    @property
    def motion(self) -> Motion | None:
        """The target motion shown: a live preview while one is up, else the scene's."""
        return self._preview if self._preview is not None else self._scene.motion

    @property
    def pending(self) -> bool:
        """The current scene's correction is still being solved."""
        return self._scene in self._pending

    def pose(self, which: str) -> WorldPose | None:
        """World pose over all frames of ``"performer"``, ``"target"`` (the motion shown),
        ``"composed"`` or ``"character"`` (the target file itself), computed once per motion."""
        s = self._scene
        motion = {"performer": s.performer, "target": self.motion, "composed": s.composed,
                  "character": s.target}.get(which)
        if motion is None:
            return None
        cached = self._poses.get(which)
        if cached is None or cached[0] is not motion:
            cached = (motion, forward_kinematics(motion))
            self._poses[which] = cached
        return cached[1]

    # ------------------------------------------------------------------ applying scenes
    def _apply(self, scene: Scene) -> None:
        """Make ``scene`` current (commands call this) and tell the widgets what changed.
        The viewer state is not part of the history: the current one is kept."""
        old = self._scene
        if scene.project.viewer is not old.project.viewer:
            scene = _with_viewer(scene, old.project.viewer)
        self._scene = scene
        if scene not in self._pending:
            # a live preview ends when its edit lands; one whose solve is still running
            # stays up until the solve does
            self._preview = None
            self._emit_changes(old, scene)
            self.motionChanged.emit()
        else:
            self._emit_changes(old, scene)
        self._solve_if_pending()

    def _emit_changes(self, old: Scene, new: Scene) -> None:
        signals = []
        if old.performer is not new.performer or old.target is not new.target:
            signals.append("sourcesChanged")
        for name, signal in _FIELD_SIGNALS.items():
            if name in ("performer", "target"):
                continue
            if getattr(old.project, name, None) is not getattr(new.project, name, None) and \
                    signal not in signals:
                signals.append(signal)
        for signal in signals:
            getattr(self, signal).emit()

    def load_scene(self, scene: Scene, path=None, *, modified: bool = False) -> None:
        """Start a fresh history on ``scene`` (a project opened, recovered or new)."""
        self.cancel_solve()
        self._pending.clear()
        self.undo_stack.clear()
        self._autosaves = set()     # the previous work's autosaves stay on disk, to be offered
        self.path = Path(path) if path is not None else None
        self.selection = ("", "")
        self._preview = None
        self._scene = scene
        for signal in ("sourcesChanged", "mappingChanged", "optionsChanged",
                       "constraintsChanged", "motionChanged", "viewerChanged"):
            getattr(self, signal).emit()
        self.frameChanged.emit(scene.viewer.current_frame)
        if modified:
            self.undo_stack.resetClean()
        else:
            self.undo_stack.setClean()
        self.changed.emit()

    # ------------------------------------------------------------------ edits
    def edit(self, text: str, *, merge: str | None = None, solve: bool = False,
             regenerate: bool = False, **changes) -> bool:
        """Push one command setting project fields (``constraints=...``, ``root=...``).
        ``solve``: the new scene's correction is solved in the background (``regenerate``
        makes the automatic constraints again). ``merge``: consecutive edits with the same
        key become one step. False when nothing changes."""
        from motion_composer.app.gui.commands import push_scene
        current = self._scene
        if not solve and all(_same(getattr(current.project, k), v) for k, v in changes.items()):
            return False
        after = current.replace(**changes)
        if solve and regenerate:
            # the automatic constraints made at once, so that the timeline shows them while
            # the solve runs (it makes the same again); one that cannot be made is reported
            # by the solve, as its error
            try:
                after = after.regenerated()
            except MotionComposerError:
                pass
        if solve:
            self._pending[after] = {"regenerate": regenerate}
        push_scene(self, text, current, after, merge=merge, fields=tuple(changes),
                   regenerate=solve and regenerate)
        return True

    def set_source(self, role: str, motion: Motion, source, text: str) -> None:
        """Replace the performer or target (one command): the map is redone, keeping the
        pairs set by hand that still fit (:meth:`engine.scene.Scene.with_source`)."""
        from motion_composer.app.gui.commands import push_scene
        current = self._scene
        after = current.with_source(role, motion, source)
        push_scene(self, text, current, after)

    def solve(self, *, regenerate: bool = False, text: str = "Solve constraints",
              **changes) -> None:
        """Solve the constraints (with ``changes`` applied first) as one undoable step."""
        self.edit(text, solve=True, regenerate=regenerate, **changes)

    def show_preview(self, motion: Motion | None) -> None:
        """Show ``motion`` as the target's motion without changing the scene (a live preview
        while a handle or goal is dragged); ``None`` goes back to the scene's motion."""
        if motion is None and self._preview is None:
            return
        self._preview = motion
        self.motionChanged.emit()

    # ------------------------------------------------------------------ solving
    def _solve_if_pending(self) -> None:
        scene = self._scene
        if scene not in self._pending or scene is self._solving:
            return
        kwargs = self._pending[scene]
        self._solving = scene
        if self.jobs.busy:
            self.noted.emit("The edit restarted the solve")

        def work(progress, cancel):
            t0 = time.perf_counter()
            solution = scene.solve(progress=progress, cancel=cancel,
                                   on_dense=lambda motion: self._denseSolved.emit(scene, motion),
                                   **kwargs)
            return (solution.scene, time.perf_counter() - t0, solution.report["warnings"],
                    solution.report["quality"], solution.report.get("keys"))

        self.jobs.run("Solving", work, lambda result: self._solved(scene, result),
                      on_end=lambda outcome: self._solve_ended(scene, outcome))

    def _dense_solved(self, scene: Scene, motion: Motion) -> None:
        """Show the dense correction of the solve still running for the current scene."""
        if self._solving is scene and self._scene is scene:
            self.show_preview(motion)
            self.keysFitting.emit()

    def _solved(self, scene: Scene, outcome: tuple) -> None:
        result, self.solve_seconds, warnings, quality, keys = outcome
        self._pending.pop(scene, None)
        from motion_composer.app.gui.commands import replace_scene
        replace_scene(self, scene, result)
        if self._scene is scene:
            old, self._scene = self._scene, _with_viewer(result, self._scene.project.viewer)
            self._preview = None
            self._emit_changes(old, self._scene)
            self.motionChanged.emit()
        if keys is not None and keys["fitted_to"] is not None:
            self.noted.emit(keys_note(keys))
        for line in warnings:
            self.noted.emit(f"Warning: {line}")
        self.last_quality = quality
        self.solved.emit()

    def _solve_ended(self, scene: Scene, outcome: str) -> None:
        if self._solving is scene:
            self._solving = None
        if outcome == "failed":
            self._pending.pop(scene, None)          # not retried on its own
            if self._scene is scene:
                self.show_preview(None)
        self._solve_if_pending()

    def cancel_solve(self) -> None:
        """Stop the running solve at the user's request: the scene keeps the correction it
        had (its constraints as edited), and the preview goes."""
        solving, self._solving = self._solving, None
        if solving is not None:
            self._pending.pop(solving, None)
        self.jobs.cancel()
        self.show_preview(None)

    # ------------------------------------------------------------------ frame, viewer, selection
    def set_frame(self, frame: int) -> None:
        frame = int(np.clip(frame, 0, max(self._scene.num_frames - 1, 0)))
        if frame != self._scene.viewer.current_frame:
            self._scene = _with_viewer(self._scene, dataclasses.replace(
                self._scene.viewer, current_frame=frame))
            self.frameChanged.emit(frame)

    def set_viewer(self, **changes) -> None:
        """Change what the viewer shows (not undoable): ``show_performer=False``,
        ``side_by_side=True``, ``camera={...}``, ``play_range=(a, b)``."""
        viewer = self._scene.viewer.with_(**changes)
        if viewer != self._scene.viewer:
            self._scene = _with_viewer(self._scene, viewer)
            self.viewerChanged.emit()

    def set_viewer_options(self, **options) -> None:
        """Change display settings kept in the viewer's ``options`` (not undoable), e.g.
        ``follow_root=True``; the others stay as they are."""
        viewer = dataclasses.replace(self._scene.viewer,
                                     options={**self._scene.viewer.options, **options})
        if viewer != self._scene.viewer:
            self._scene = _with_viewer(self._scene, viewer)
            self.viewerChanged.emit()

    def select(self, side: str, joint: str) -> None:
        if (side, joint) != self.selection:
            self.selection = (side, joint)
            self.selectionChanged.emit(side, joint)

    @property
    def selected_target_joint(self) -> str | None:
        """The target joint the selection names: the selected target joint, or the target
        joint mapped to the selected performer joint; None without one."""
        side, joint = self.selection
        target = self._scene.target
        if target is None or not joint:
            return None
        if side == "performer":
            joint = next((t for t, p in self._scene.correspondence.pairs.items()
                          if p == joint), None)
        elif side != "target":
            return None
        return joint if joint in target.skeleton.index else None

    # ------------------------------------------------------------------ files
    def open(self, path, locate=None) -> None:
        """Open the project at ``path``. A clip that has moved is asked for through
        ``locate(role, missing) -> new path or None`` and the project is retried there (the
        project is then modified). Raises :class:`~engine.errors.MotionComposerError`."""
        path = Path(path)
        scene, moved = _open_scene(path, locate)
        self.load_scene(scene, path, modified=moved)

    def recover(self, autosave, project_path=None, locate=None) -> None:
        """Open the autosave ``autosave`` as the project at ``project_path`` (or unsaved), with
        its work still to be saved. A map still half done opens as it was (the conversion
        says what it lacks). The autosave file stays until that work is saved, discarded, or
        this document's own autosave holds it."""
        autosave = Path(autosave)
        scene, _moved = _open_scene(autosave, locate, check_map=False)
        self.load_scene(scene, project_path, modified=True)
        self._autosaves = {autosave}

    def save(self, path) -> None:
        """Save the scene's project at ``path`` (atomic, with a backup), then drop the
        autosaves of the work saved and the one of the new place (older than the file now).
        A failed save raises and leaves every autosave in place."""
        path = Path(path)
        save_project(self._scene.project, path)
        self.path = path
        self.undo_stack.setClean()
        self._drop_autosaves(autosave_path(path))
        self.changed.emit()

    def close(self) -> None:
        """Stop background work, wait for its threads, and let Qt delete the document."""
        self.cancel_solve()
        self.jobs.wait()
        self.deleteLater()

    def reset(self) -> None:
        """An empty, unsaved document."""
        self.load_scene(Scene.empty())

    def autosave(self) -> Path | None:
        """Write the current project to this document's autosave (beside the project file,
        or this session's unsaved one) atomically and return it; None when the project cannot
        be written yet (a performer or target still missing). Once written, an autosave this
        document was recovered from is superseded and removed. Raises
        :class:`~engine.fileio.FileWriteError`."""
        project = self._scene.project
        if not all(getattr(project, role).path or getattr(project, role).embedded
                   for role in ("performer", "target")):
            return None
        written = write_autosave(project, self.path, self.session)
        for superseded in self._autosaves - {written}:
            remove_autosave_file(superseded)
        self._autosaves = {written}
        return written

    def discard_autosave(self) -> None:
        """Remove the autosaves holding the current work (the user discarded it). Autosaves
        of other work, e.g. a crashed session's not offered yet, are left alone."""
        self._drop_autosaves()

    def _drop_autosaves(self, *also: Path) -> None:
        for path in self._autosaves.union(also):
            remove_autosave_file(path)
        self._autosaves = set()

    @staticmethod
    def recovery_candidate(project_path=None):
        """The autosave to offer when opening ``project_path`` (or at start), or None."""
        return find_autosave(project_path)


def _with_viewer(scene: Scene, viewer) -> Scene:
    return Scene(scene.project.replace(viewer=viewer), scene.performer, scene.target,
                 scene.derived)


def _same(a, b) -> bool:
    if a is b:
        return True
    try:
        return bool(a == b)
    except (TypeError, ValueError):
        return False


def _open_scene(path: Path, locate, *, check_map: bool = True) -> tuple[Scene, bool]:
    """The scene of the project file at ``path`` and whether a moved clip was located.
    ``check_map=False``: a map the conversion cannot use yet is let through."""
    try:
        if check_map:
            return Scene.open(path), False
        return _scene_of(load_project(path, check_sources=False), path, False), False
    except MissingSourceError as exc:
        if locate is None:
            raise
        missing = exc
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise MotionComposerError(f"{path}: cannot be read: {exc.strerror or exc}") from None
    project = project_from_json(text, path)
    while True:
        new = locate(missing.role, missing.missing)
        if not new:
            raise missing
        source = dataclasses.replace(getattr(project, missing.role),
                                     path=str(Path(new).resolve()))
        project = project.replace(**{missing.role: source})
        try:
            return _scene_of(project, path, check_map), True
        except MissingSourceError as again:
            missing = again


def _scene_of(project, path: Path, check_map: bool) -> Scene:
    if check_map:
        return Scene.from_project(project, path=path)
    performer, target = read_sources(project, path=path)
    check_project(project, performer, target, path=path, check_map=False)
    return Scene(project, performer, target)
