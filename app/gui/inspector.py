"""The constraint inspector: the selected constraint's joint, kind, goal, priority, weight.

Built from a :class:`~app.gui.document.Document` (and a :class:`~app.gui.timeline.
ConstraintTimeline` whose selection it follows, or :meth:`ConstraintInspector.set_index`),
wired both ways: the document's signals refresh the fields with their signals blocked; a
user's change becomes one undoable command through the document's live solver
(:mod:`app.gui.live`), which re-solves the constraints and pushes them with their new
displacement map (``push_constraints``). With a ``window`` (the main window), the solve runs in
its worker with progress and cancel, the same pathway as Tools > Solve; without one (tests,
a bare inspector) it runs synchronously.

* Joint: a target joint. Kind: position, trajectory, plane above / on / below, orientation;
  changing the kind keeps what carries over (a point stays a point, a plane's normal stays) and
  takes the rest from the joint's current pose.
* Goal: x, y, z in metres (a position; a plane's point and normal); an orientation is shown as
  world XYZ Euler angles in degrees and stored as a quaternion; a trajectory shows its extent
  and is recorded from the pose.
* "Take from pose": the goal from the joint's world position / orientation at the current
  frame (``doc.pose("target")``; a trajectory takes the joint's path over the active range).
  "Pick in viewport": arms a one-shot; the next target joint selected in the viewport becomes
  the constraint's joint, its goal taken from that joint's pose.
* Spin boxes preview while they step (arrows, wheel: the live solver shows the corrected
  motion at once) and commit one command when editing finishes (Enter, focus leaving) or
  after ``COMMIT_IDLE_MS`` without a change, so a run of steps is one undo step.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from motion_composer.app.gui.qt import QtCore, QtGui, QtWidgets
from motion_composer.app.gui.live import live_solver
from motion_composer.engine.correction.constraints import KINDS, Constraint, ConstraintError
from motion_composer.engine.rotations import euler_to_quat, quat_to_euler

__all__ = ["ConstraintInspector", "Vec3Edit", "KIND_CHOICES", "converted"]

Qt = QtCore.Qt

#: the kind combo, from the registry: (kind, variant (a plane's side), text)
KIND_CHOICES = tuple((kind.name, variant, kind.choice_label(variant))
                     for kind in KINDS.values() for variant in kind.variants)
#: a spin box's run of steps becomes one command after this long without a change
COMMIT_IDLE_MS = 700
EULER_ORDER = "XYZ"


class _Blocked:
    """Block a widget's signals for a ``with`` block (``QSignalBlocker`` without it: see
    :mod:`app.gui.qt` on PySide6 6.12.0's lost ``None`` references)."""

    def __init__(self, *widgets):
        self.widgets = widgets

    def __enter__(self):
        self.before = [w.blockSignals(True) for w in self.widgets]

    def __exit__(self, *_exc):
        for w, b in zip(self.widgets, self.before):
            w.blockSignals(b)


def _label(c: Constraint) -> str:
    return c.name or c.joint


def _suffix(unit: str) -> str:
    """A spin box's suffix for ``unit``: a degree sign follows the number, a unit's name
    after a space."""
    return unit if unit in ("", "°") else f" {unit}"


# ====================================================================== goal conversions
def converted(c: Constraint, kind: str, side: str | None, here, turn, frame: int
              ) -> Constraint:
    """``c`` as another kind (``side``: its variant): a point carries over, a plane keeps its
    normal, a trajectory or an orientation its goal; what is missing comes from the joint's
    world position ``here`` and rotation ``turn`` (x-y-z-w) at ``frame``."""
    goal = KINDS[kind].converted_goal(c, side, here, turn, frame)
    return dataclasses.replace(c, kind=kind, goal=goal)


def from_pose(c: Constraint, joint: str, pose, frame: int, index: int) -> Constraint:
    """``c`` on ``joint`` (index ``index``) with its goal where the joint is at ``frame``: a
    position's point, a plane's point (the plane through the joint), an orientation's
    quaternion, a trajectory's points over the active range."""
    goal = c.kind_object.goal_from_pose(c, pose.positions, pose.rotations, frame, index)
    return dataclasses.replace(c, joint=joint, goal=goal)


# ====================================================================== widgets
class Vec3Edit(QtWidgets.QWidget):
    """Three spin boxes (x, y, z). ``componentChanged(k, value)`` when the user changes one
    (the others keep their exact stored values: the boxes round to their decimals),
    ``editingFinished`` when one's editing finishes."""

    componentChanged = QtCore.Signal(int, float)
    editingFinished = QtCore.Signal()

    def __init__(self, decimals=3, step=0.01, suffix="", lo=-1e4, hi=1e4, wrap=False,
                 labels=("x", "y", "z"), parent=None):
        super().__init__(parent)
        layout = QtWidgets.QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(4)
        self.spins = []
        for k, name in enumerate(labels):
            spin = QtWidgets.QDoubleSpinBox()
            spin.setDecimals(decimals)
            spin.setSingleStep(step)
            spin.setRange(lo, hi)
            spin.setSuffix(suffix)
            spin.setWrapping(wrap)
            spin.setKeyboardTracking(False)
            spin.setAccelerated(True)
            spin.setToolTip(name)
            spin.setPrefix(f"{name} ")
            spin.valueChanged.connect(lambda v, k=k: self.componentChanged.emit(k, v))
            spin.editingFinished.connect(self.editingFinished)
            layout.addWidget(spin, 1)
            self.spins.append(spin)

    def value(self) -> np.ndarray:
        return np.array([s.value() for s in self.spins])

    def setValue(self, v) -> None:     # noqa: N802 - Qt style
        with _Blocked(*self.spins):
            for s, x in zip(self.spins, v):
                s.setValue(float(x))


class ConstraintInspector(QtWidgets.QWidget):
    """The selected constraint's fields; every change one undoable command.

    Attributes: ``index`` (the constraint shown, ``None`` for none), the field widgets
    (``joint``, ``kind``, ``priority``, ``weight``, ``enabled``, ``name``, ``take_button``,
    ``pick_button``), ``goal_edits`` (kind name, goal key) -> the widget of that goal value,
    one page of ``goal_pages`` per kind (``_page``: kind name -> page index), built from each
    kind's :attr:`~engine.correction.constraints.ConstraintKind.fields`.
    """

    def __init__(self, document, timeline=None, parent=None):
        super().__init__(parent)
        self.doc = document
        self.timeline = timeline
        self.live = live_solver(document)
        self.index: int | None = None
        self._pending: tuple | None = None     # (constraint, text) previewed, not committed
        self._idle = QtCore.QTimer(self)
        self._idle.setSingleShot(True)
        self._idle.setInterval(COMMIT_IDLE_MS)
        self._idle.timeout.connect(self.commit_pending)
        self._build()
        self.live.settleRequested.connect(self.commit_pending)
        document.constraintsChanged.connect(self._model_changed)
        document.sourcesChanged.connect(self._sources_changed)
        document.selectionChanged.connect(self._selection_changed)
        document.frameChanged.connect(self._frame_changed)
        if timeline is not None:
            timeline.constraintSelected.connect(self._timeline_selected)
            self.index = timeline.selected_index
        self._sources_changed()

    # ------------------------------------------------------------------ building
    def _build(self) -> None:
        self.title = QtWidgets.QLabel()
        font = self.title.font()
        font.setBold(True)
        font.setPointSizeF(font.pointSizeF() * 1.1)
        self.title.setFont(font)
        self.title.setWordWrap(True)
        self.subtitle = QtWidgets.QLabel()
        self.subtitle.setWordWrap(True)
        self.subtitle.setForegroundRole(QtGui.QPalette.ColorRole.PlaceholderText)

        self.name = QtWidgets.QLineEdit()
        self.name.setPlaceholderText("(the joint's name)")
        self.name.editingFinished.connect(self._name_edited)
        self.joint = QtWidgets.QComboBox()
        self.joint.setToolTip("The constrained joint of the target")
        self.joint.activated.connect(self._joint_chosen)
        self.kind = QtWidgets.QComboBox()
        for kind, side, text in KIND_CHOICES:
            self.kind.addItem(text, (kind, side))
        self.kind.activated.connect(self._kind_chosen)

        # goal pages: one per kind, its fields as the kind describes them
        pages = QtWidgets.QStackedWidget()
        self.goal_pages = pages
        self._page = {}
        self.goal_edits = {}
        for kind in KINDS.values():
            page = QtWidgets.QWidget()
            form = QtWidgets.QFormLayout(page)
            form.setContentsMargins(0, 0, 0, 0)
            for goal_field in kind.fields:
                edit = self._goal_edit(kind.name, goal_field)
                self.goal_edits[kind.name, goal_field.key] = edit
                form.addRow(goal_field.label, edit)
            self._page[kind.name] = pages.addWidget(page)

        self.take_button = QtWidgets.QPushButton("Take from pose")
        self.take_button.setToolTip("The goal from where the joint is at the current frame")
        self.take_button.clicked.connect(lambda _c=False: self.take_from_pose())
        self.pick_button = QtWidgets.QPushButton("Pick in viewport")
        self.pick_button.setCheckable(True)
        self.pick_button.setToolTip("Click a joint of the target in the viewport: it becomes "
                                    "the constrained joint, its goal where it is now")
        self.pick_button.toggled.connect(self._pick_toggled)
        buttons = QtWidgets.QHBoxLayout()
        buttons.setContentsMargins(0, 0, 0, 0)
        buttons.addWidget(self.take_button)
        buttons.addWidget(self.pick_button)

        self.priority = QtWidgets.QSpinBox()
        self.priority.setRange(1, 9)
        self.priority.setKeyboardTracking(False)
        self.priority.setToolTip("1 is the highest; a lower level acts only where it does not "
                                 "disturb the higher ones")
        self.priority.valueChanged.connect(self._priority_stepped)
        self.priority.editingFinished.connect(self.commit_pending)
        self.weight = QtWidgets.QDoubleSpinBox()
        self.weight.setRange(0.01, 100.0)
        self.weight.setDecimals(2)
        self.weight.setSingleStep(0.1)
        self.weight.setKeyboardTracking(False)
        self.weight.setToolTip("Scales this constraint against the others of its level")
        self.weight.valueChanged.connect(self._weight_stepped)
        self.weight.editingFinished.connect(self.commit_pending)
        self.enabled = QtWidgets.QCheckBox("Enabled")
        self.enabled.toggled.connect(self._enabled_toggled)
        self.range_label = QtWidgets.QLabel()
        self.range_label.setToolTip("smooth-in · start–end · smooth-out (drag them in the "
                                    "timeline)")
        self.status = QtWidgets.QLabel()
        self.status.setWordWrap(True)
        self.status.setStyleSheet("color: #b00020")

        self.form_widget = QtWidgets.QWidget()
        form = QtWidgets.QFormLayout(self.form_widget)
        form.setContentsMargins(0, 0, 0, 0)
        form.setFieldGrowthPolicy(QtWidgets.QFormLayout.FieldGrowthPolicy.AllNonFixedFieldsGrow)
        form.addRow("Name", self.name)
        form.addRow("Joint", self.joint)
        form.addRow("Kind", self.kind)
        goal_box = QtWidgets.QGroupBox("Goal")
        goal_layout = QtWidgets.QVBoxLayout(goal_box)
        goal_layout.addWidget(pages)
        goal_layout.addLayout(buttons)
        form.addRow(goal_box)
        form.addRow("Priority", self.priority)
        form.addRow("Weight", self.weight)
        form.addRow("", self.enabled)
        form.addRow("Frames", self.range_label)

        self.empty = QtWidgets.QLabel("Select a constraint in the timeline.")
        self.empty.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.empty.setForegroundRole(QtGui.QPalette.ColorRole.PlaceholderText)
        layout = QtWidgets.QVBoxLayout(self)
        layout.addWidget(self.title)
        layout.addWidget(self.subtitle)
        layout.addWidget(self.form_widget)
        layout.addWidget(self.empty)
        layout.addWidget(self.status)
        layout.addStretch(1)

    def _goal_edit(self, kind: str, goal_field) -> QtWidgets.QWidget:
        """The widget of one goal value of ``kind`` (a :class:`~engine.correction.
        constraints.base.GoalField`), wired to preview its steps and commit."""
        if goal_field.editor == "summary":
            label = QtWidgets.QLabel()
            label.setWordWrap(True)
            return label
        lo, hi = goal_field.bounds
        edit = Vec3Edit(decimals=goal_field.decimals, step=goal_field.step,
                        suffix=_suffix(goal_field.unit), lo=lo, hi=hi,
                        wrap=goal_field.editor == "euler")
        edit.setToolTip(goal_field.tooltip)
        edit.componentChanged.connect(
            lambda k, v, f=goal_field: self._goal_stepped(kind, f, k, v))
        edit.editingFinished.connect(self.commit_pending)
        return edit

    # ------------------------------------------------------------------ model -> widgets
    @property
    def constraint(self) -> Constraint | None:
        i = self.index
        return self.doc.scene.constraints[i] if i is not None and 0 <= i < len(self.doc.scene.constraints) \
            else None

    def _working(self) -> Constraint | None:
        """The constraint as edited so far (a previewed step not yet committed included)."""
        return self._pending[0] if self._pending is not None else self.constraint

    def set_index(self, index: int | None) -> None:
        """Show constraint ``index`` (a pending spin-box edit of the previous one commits
        first)."""
        if index != self.index:
            self.commit_pending()
            self._disarm()
        self.index = index
        self.refresh()

    def _timeline_selected(self, index: int) -> None:
        self.set_index(None if index < 0 else index)

    def _frame_changed(self, _frame: int) -> None:
        self._show_range()

    def _sources_changed(self) -> None:
        names = list(self.doc.scene.target.skeleton.names) if self.doc.scene.target is not None else []
        with _Blocked(self.joint):
            self.joint.clear()
            self.joint.addItems(names)
        self.refresh()

    def _model_changed(self) -> None:
        # undo, redo or another panel changed the constraints: a pending step is dropped
        if self._pending is not None:
            self._pending = None
            self._idle.stop()
            if self.live.active:
                self.live.cancel()
        self.refresh()

    def refresh(self) -> None:
        c = self.constraint
        self.form_widget.setVisible(c is not None)
        self.empty.setVisible(c is None)
        self.take_button.setEnabled(c is not None and self.doc.scene.ready)
        self.pick_button.setEnabled(c is not None)
        if c is None:
            self.title.setText("No constraint")
            self.subtitle.setText("")
            return
        self.title.setText(_label(c))
        origin = "automatic" + (f" ({c.meta['source']})" if c.meta.get("source") else "") \
            if c.auto else "manual"
        self.subtitle.setText(f"{origin} · {c.kind_object.describe(c.goal)}" +
                              ("" if c.enabled else " · disabled"))
        widgets = (self.name, self.joint, self.kind, self.priority, self.weight, self.enabled)
        with _Blocked(*widgets):
            if self.name.text() != c.name:
                self.name.setText(c.name)
            self.joint.setCurrentIndex(self.joint.findText(c.joint))
            self.kind.setCurrentIndex(self._kind_index(c))
            self.priority.setValue(c.priority)
            self.weight.setValue(c.weight)
            self.enabled.setChecked(c.enabled)
        self._show_goal(c)
        self._show_range()

    @staticmethod
    def _kind_index(c: Constraint) -> int:
        choice = (c.kind, c.kind_object.variant(c.goal))
        for i, (kind, variant, _text) in enumerate(KIND_CHOICES):
            if (kind, variant) == choice:
                return i
        return 0

    def _show_goal(self, c: Constraint) -> None:
        page = self._page[c.kind]
        self.goal_pages.setCurrentIndex(page)
        ignored, preferred = (QtWidgets.QSizePolicy.Policy.Ignored,
                              QtWidgets.QSizePolicy.Policy.Preferred)
        for i in range(self.goal_pages.count()):      # the box as tall as the page shown
            self.goal_pages.widget(i).setSizePolicy(preferred,
                                                    preferred if i == page else ignored)
        self.goal_pages.adjustSize()
        kind = c.kind_object
        for goal_field in kind.fields:
            edit = self.goal_edits[c.kind, goal_field.key]
            if goal_field.editor == "summary":
                edit.setText(f"{kind.summary(c)}. {goal_field.tooltip}")
            elif goal_field.editor == "euler":
                edit.setValue(quat_to_euler(np.asarray(c.goal[goal_field.key])[None],
                                            EULER_ORDER, unwrap=False)[0])
            else:
                edit.setValue(c.goal[goal_field.key])

    def _show_range(self) -> None:
        c = self.constraint
        if c is None:
            return
        ft = self.doc.scene.performer.frame_time if self.doc.scene.performer is not None else 0.0
        self.range_label.setText(f"{c.smooth_in} · {c.start}\u2013{c.end} · {c.smooth_out}"
                                 f"   ({c.start * ft:.3f}\u2013{c.end * ft:.3f} s)")

    # ------------------------------------------------------------------ widgets -> model
    def _apply(self, make, text: str, preview: bool = False) -> None:
        """Edit the constraint with ``make(constraint) -> constraint``; ``preview``: show it
        now and commit when editing finishes, else commit at once (after a previewed edit,
        which is its own command)."""
        if not preview:
            self.commit_pending()
        c = self._working()
        if c is None:
            return
        try:
            new = make(c)
        except (ConstraintError, ValueError) as exc:
            self.status.setText(str(exc))
            self._pending = None
            self.refresh()
            return
        self.status.setText("")
        if preview:
            self._pending = (new, text)
            self.live.request(self._with(new))
            self._idle.start()
        else:
            self._pending = None
            self._idle.stop()
            self.live.commit(self._with(new), text)

    def _with(self, new: Constraint) -> list:
        constraints = list(self.doc.scene.constraints)
        constraints[self.index] = new
        return constraints

    def commit_pending(self) -> None:
        """Commit a previewed spin-box edit as one command."""
        self._idle.stop()
        if self._pending is None or self.constraint is None:
            self._pending = None
            return
        new, text = self._pending
        self._pending = None
        self.live.commit(self._with(new), text)

    def _name_edited(self) -> None:
        c = self.constraint
        if c is None or self.name.text() == c.name:
            return
        new_name = self.name.text().strip()
        self._apply(lambda c: dataclasses.replace(c, name=new_name),
                    f"Rename {_label(c)} to {new_name or c.joint}")

    def _joint_chosen(self, _index: int) -> None:
        c = self.constraint
        joint = self.joint.currentText()
        if c is None or not joint or joint == c.joint:
            return
        self._apply(lambda c: dataclasses.replace(c, joint=joint),
                    f"Set joint of {_label(c)} to {joint}")

    def _pose_and_index(self, joint: str):
        pose = self.doc.pose("target")
        motion = self.doc.motion
        if pose is None or motion is None or joint not in motion.skeleton.index:
            return None, None
        return pose, motion.skeleton.index[joint]

    def _kind_chosen(self, index: int) -> None:
        c = self.constraint
        kind, side = self.kind.itemData(index)
        if c is None or (kind, side) == (c.kind, c.kind_object.variant(c.goal)):
            return
        pose, j = self._pose_and_index(c.joint)
        frame = self.doc.scene.viewer.current_frame
        here = pose.positions[frame, j] if pose is not None else np.zeros(3)
        turn = pose.rotations[frame, j] if pose is not None else np.array([0.0, 0, 0, 1])
        text = KIND_CHOICES[index][2].lower().replace(":", "")
        self._apply(lambda c: converted(c, kind, side, here, turn, frame),
                    f"Make {_label(c)} a {text} constraint")

    def _goal_stepped(self, kind: str, goal_field, k: int, value: float) -> None:
        """Component ``k`` of a goal value of ``kind`` set to ``value``; the other components
        keep their stored values."""
        c = self._working()
        if c is None or c.kind != kind:
            return
        key = goal_field.key

        def replaced(v):
            v = np.array(v, dtype=float)
            v[k] = value
            return v

        if goal_field.editor == "euler":
            def make(c):
                angles = quat_to_euler(np.asarray(c.goal[key])[None], EULER_ORDER,
                                       unwrap=False)[0]
                q = euler_to_quat(replaced(angles)[None], EULER_ORDER)[0]
                return dataclasses.replace(c, goal={**c.goal, key: q})
        else:
            def make(c):
                return dataclasses.replace(c, goal={**c.goal, key: replaced(c.goal[key])})
        self._apply(make, f"Set {goal_field.name} of {_label(c)}", preview=True)

    def _priority_stepped(self, value: int) -> None:
        c = self._working()
        if c is not None and value != c.priority:
            self._apply(lambda c: dataclasses.replace(c, priority=int(value)),
                        f"Set priority of {_label(c)} to {value}", preview=True)

    def _weight_stepped(self, value: float) -> None:
        c = self._working()
        if c is not None and value != c.weight:
            self._apply(lambda c: dataclasses.replace(c, weight=float(value)),
                        f"Set weight of {_label(c)} to {value:g}", preview=True)

    def _enabled_toggled(self, on: bool) -> None:
        c = self.constraint
        if c is not None and on != c.enabled:
            self._apply(lambda c: dataclasses.replace(c, enabled=on),
                        f"{'Enable' if on else 'Disable'} {_label(c)}")

    def take_from_pose(self, joint: str | None = None, text: str | None = None) -> None:
        """The goal (and ``joint``, if given) from the joint's pose at the current frame."""
        c = self.constraint
        if c is None:
            return
        joint = joint or c.joint
        pose, j = self._pose_and_index(joint)
        if pose is None:
            self.status.setText(f"{joint}: no pose to take the goal from")
            return
        frame = self.doc.scene.viewer.current_frame
        self._apply(lambda c: from_pose(c, joint, pose, frame, j),
                    text or f"Take goal of {_label(c)} from pose at frame {frame}")

    # ------------------------------------------------------------------ picking
    @property
    def picking(self) -> bool:
        return self.pick_button.isChecked()

    def _pick_toggled(self, on: bool) -> None:
        self.status.setText("Click a joint of the target in the viewport." if on else "")

    def _disarm(self) -> None:
        if self.pick_button.isChecked():
            with _Blocked(self.pick_button):
                self.pick_button.setChecked(False)
            self.status.setText("")

    def _selection_changed(self, side: str, joint: str) -> None:
        if not self.picking or side != "target" or not joint:
            return
        self._disarm()
        c = self.constraint
        if c is not None:
            self.take_from_pose(joint, f"Pick {joint} for {_label(c)}")
