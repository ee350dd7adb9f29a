"""The document: one retargeting session, the undo stack, and the evaluated motions.

The document holds plain engine data (motions, the correspondence, binding and root options,
constraints, the displacement map, viewer state); widgets never change it directly but push
commands (:mod:`app.gui.commands`) on its one ``QUndoStack``. Every change re-evaluates what
depends on it (the direct conversion takes milliseconds, so it runs at once; IK runs in a
worker, see :mod:`app.gui.worker`) and emits the signals the widgets listen to.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from app.gui.qt import QtCore, QtGui
from engine.conversion.correspondence import Correspondence
from engine.correction.displacement import DisplacementMap
from engine.errors import MotionComposerError
from engine.kinematics import WorldPose, forward_kinematics
from engine.motion import Motion
from engine.conversion import BindOptions, bind
from engine.conversion import RootOptions, convert
from engine.conversion import compose

__all__ = ["Document", "ViewerState"]


@dataclasses.dataclass
class ViewerState:
    """What the viewer shows: frame, play range, camera, which skeletons."""

    current_frame: int = 0
    play_range: tuple[int, int] | None = None
    camera: dict = dataclasses.field(default_factory=dict)
    show_performer: bool = True
    show_intermediate: bool = False
    show_target: bool = True
    side_by_side: bool = True


class Document(QtCore.QObject):
    """A retargeting session with undo."""

    #: anything changed (title, modified mark)
    changed = QtCore.Signal()
    #: a performer or target was loaded
    sourcesChanged = QtCore.Signal()
    #: the correspondence changed
    mappingChanged = QtCore.Signal()
    #: binding or root options changed
    optionsChanged = QtCore.Signal()
    #: constraints changed
    constraintsChanged = QtCore.Signal()
    #: the evaluated motions changed
    motionChanged = QtCore.Signal()
    #: the current frame changed
    frameChanged = QtCore.Signal(int)
    #: a joint was selected: side ("target" or "performer") and joint name ("" for none)
    selectionChanged = QtCore.Signal(str, str)
    #: an error the user should see (the window shows a dialog)
    errorRaised = QtCore.Signal(str)

    def __init__(self, parent=None):
        super().__init__(parent)
        self.undo_stack = QtGui.QUndoStack(self)
        self.undo_stack.cleanChanged.connect(self._stack_changed)
        self.undo_stack.indexChanged.connect(self._stack_changed)
        self.path: Path | None = None
        self.performer: Motion | None = None
        self.target: Motion | None = None
        self.performer_path: Path | None = None
        self.target_path: Path | None = None
        #: the project's sources as loaded (embedded text, reader overrides), by role
        self.sources: dict = {}
        self.correspondence = Correspondence({})
        self.bind_options = BindOptions()
        self.root_options = RootOptions()
        self.constraints: list = []
        self.auto_contacts = False
        self.floor: float | None = None
        self.displacement = DisplacementMap()
        self.viewer = ViewerState()
        self.selection: tuple[str, str] = ("", "")
        # evaluated
        self.composed: Motion | None = None
        self.motion: Motion | None = None
        self.binding = None
        self.intermediate = None
        self.evaluation_error: str = ""
        self._poses: dict[str, WorldPose] = {}

    def _stack_changed(self, *_args) -> None:
        self.changed.emit()

    # ------------------------------------------------------------------ state
    @property
    def modified(self) -> bool:
        return not self.undo_stack.isClean()

    @property
    def title(self) -> str:
        name = self.path.name if self.path else "Untitled"
        return f"{name}{'*' if self.modified else ''} - Motion Composer"

    @property
    def character(self):
        """The target's glTF character (mesh and skin), or None for a BVH target (or one
        embedded in the project whose file is gone)."""
        path = self.target_path
        if path is None:
            return None
        cached = getattr(self, "_character", None)
        if cached is None or cached[0] != str(path):
            from engine.formats import read_character
            try:
                self._character = (str(path),
                                   read_character(path) if Path(path).is_file() else None)
            except MotionComposerError as exc:
                self.errorRaised.emit(str(exc))
                self._character = (str(path), None)
        return self._character[1]

    @property
    def num_frames(self) -> int:
        return self.performer.num_frames if self.performer is not None else 0

    @property
    def ready(self) -> bool:
        return self.motion is not None

    # ------------------------------------------------------------------ evaluation
    def evaluate(self) -> None:
        """Re-run the direct conversion and apply the displacement map. Errors (an impossible
        mapping while it is being edited) leave no motion and are kept in
        ``evaluation_error`` for the panels to show."""
        self.composed = self.motion = self.binding = self.intermediate = None
        self._poses = {}
        self.evaluation_error = ""
        if self.performer is not None and self.target is not None and len(self.correspondence):
            try:
                self.binding = bind(self.performer, self.target, self.correspondence,
                                    self.bind_options)
                self.intermediate = convert(self.binding, self.performer, self.root_options)
                self.composed = compose(self.binding, self.intermediate,
                                        self.performer.frame_time,
                                        name=f"{self.performer.name}_on_{self.target.name}")
                self.motion = self.displacement.apply(self.composed)
            except MotionComposerError as exc:
                self.composed = self.motion = self.binding = self.intermediate = None
                self.evaluation_error = str(exc)
        self.motionChanged.emit()

    def show_preview(self, motion: Motion | None) -> None:
        """Show ``motion`` as the target's motion without changing the document (a live
        preview while a handle or goal is dragged); ``None`` goes back to the evaluated one.
        Nothing is pushed on the undo stack."""
        if motion is None:
            self.evaluate()
            return
        self.motion = motion
        self._poses.pop("target", None)
        self.motionChanged.emit()

    def pose(self, which: str) -> WorldPose | None:
        """World pose over all frames of ``"performer"``, ``"target"`` (the final motion),
        ``"composed"`` or ``"character"`` (the target file itself), computed once."""
        if which not in self._poses:
            motion = {"performer": self.performer, "target": self.motion,
                      "composed": self.composed, "character": self.target}.get(which)
            if motion is None:
                return None
            self._poses[which] = forward_kinematics(motion)
        return self._poses[which]

    # ------------------------------------------------------------------ frame, selection
    def set_frame(self, frame: int) -> None:
        frame = int(np.clip(frame, 0, max(self.num_frames - 1, 0)))
        if frame != self.viewer.current_frame:
            self.viewer.current_frame = frame
            self.frameChanged.emit(frame)

    def select(self, side: str, joint: str) -> None:
        if (side, joint) != self.selection:
            self.selection = (side, joint)
            self.selectionChanged.emit(side, joint)

    # ------------------------------------------------------------------ raw setters (commands)
    # Commands call these; widgets call the push_* helpers of app.gui.commands.
    def _set_sources(self, performer, performer_path, target, target_path) -> None:
        self.performer, self.performer_path = performer, performer_path
        self.target, self.target_path = target, target_path
        if self.performer is not None:
            self.viewer.current_frame = min(self.viewer.current_frame,
                                            self.performer.num_frames - 1)
        self.sourcesChanged.emit()
        self.evaluate()

    def _set_correspondence(self, correspondence: Correspondence) -> None:
        self.correspondence = correspondence
        self.mappingChanged.emit()
        self.evaluate()

    def _set_options(self, bind_options: BindOptions, root_options: RootOptions) -> None:
        self.bind_options, self.root_options = bind_options, root_options
        self.optionsChanged.emit()
        self.evaluate()

    def _set_constraints(self, constraints: list, displacement: DisplacementMap) -> None:
        self.constraints = list(constraints)
        self.displacement = displacement
        self.constraintsChanged.emit()
        self.evaluate()

    def _set_displacement(self, displacement: DisplacementMap) -> None:
        self.displacement = displacement
        self.evaluate()
