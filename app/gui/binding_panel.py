"""The binding panel: reference poses, rest alignment, the retarget pose, per-chain settings
and root motion.

Built straight from a :class:`~app.gui.document.Document` and wired both ways: the document's
signals (options changed, sources loaded, motion re-evaluated, selection, undo and redo) update
the widgets inside ``QSignalBlocker`` s, and every widget change pushes one undoable command
through :func:`app.gui.commands.push_options`.

The retarget pose: the selected target joint (the document's selection, shared with the
viewport and the correspondence editor), its pose offset as typed X, Y, Z angles [deg] about its
binding-frame axes (:func:`~engine.conversion.chains.euler_to_offset`), Mirror to the other
side, Reset joint and Reset all, and "Edit in the viewport" (the viewport's binding-pose mode
with its rotation gizmo). The chain table: per chain of the target (spine, neck, arms, legs,
fingers) its rotation weight, twist on or off, chain turns and IK blend (an IK blend edit
solves the scene in the background: only a solve meets, or drops, its reach goals).

Spin boxes and sliders merge: consecutive edits of one control (the two root scales count as
one; a slider's drag) are one undo step whose text names the last value.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from motion_composer.app.gui.commands import push_options
from motion_composer.app.gui.qt import QtCore, QtWidgets
from motion_composer.engine.conversion import BindOptions
from motion_composer.engine.conversion import RootOptions
from motion_composer.engine.conversion.chains import (chains_of, euler_to_offset, mirror_joint,
                                                      mirrored_offset, offset_to_euler)
from motion_composer.engine.errors import MotionComposerError

__all__ = ["BindingPanel", "ReferenceChooser", "FractionSlider", "CHAIN_TITLES"]

_Blocker = QtCore.QSignalBlocker

#: (BindOptions.distribute value, shown text, undo text)
DISTRIBUTIONS = (
    ("even", "Spread over the chain", "Spread chain turns over every joint"),
    ("first", "First joint only", "Turn only each chain's first joint"),
)
#: (RootOptions.mode value, shown text, undo text)
ROOT_MODES = (
    ("scaled", "Scaled", "Scale the root motion"),
    ("absolute", "Absolute (as captured)", "Keep the root motion as captured"),
    ("in-place", "In place", "Keep the root in place"),
)
#: a chain's shown name
CHAIN_TITLES = {"spine": "Spine", "neck": "Neck", "arm_l": "Left arm", "arm_r": "Right arm",
                "leg_l": "Left leg", "leg_r": "Right leg", "fingers_l": "Left fingers",
                "fingers_r": "Right fingers"}
#: (ChainSettings.distribute value, shown text) of a chain's own "chain turns"
CHAIN_DISTRIBUTIONS = ((None, "As above"), ("even", "Spread"), ("first", "First only"))
#: the chain table's columns
CHAIN_COLUMNS = ("Chain", "Weight", "Twist", "Chain turns", "IK blend")
#: [deg] the typed pose angles' range
ANGLE_RANGE = 180.0
ROOT_TIPS = {
    "scaled": "The performer's root displacement times the root scale (by default the ratio "
              "of hip heights).",
    "absolute": "The performer's world trajectory as it is, in metres; the scale is unused.",
    "in-place": "Horizontal displacement removed; the vertical one scaled.",
}


class ReferenceChooser(QtWidgets.QWidget):
    """A reference pose: Automatic, Rest pose (zero rotations) or Frame N.

    ``value`` is what :class:`BindOptions` takes: ``"auto"``, ``"rest"`` or a frame number.
    ``choiceChanged`` fires when the combo changes, ``frameEdited`` when the spin box does;
    :meth:`set_value` updates both without emitting.
    """

    CHOICES = (("auto", "Automatic"), ("rest", "Rest pose (zero rotations)"),
               ("frame", "Frame"))

    choiceChanged = QtCore.Signal()
    frameEdited = QtCore.Signal(int)

    def __init__(self, parent=None):
        super().__init__(parent)
        self.combo = QtWidgets.QComboBox()
        for key, text in self.CHOICES:
            self.combo.addItem(text, key)
        self.combo.setItemData(0, "The rest pose when it stands upright, else frame 0",
                               QtCore.Qt.ItemDataRole.ToolTipRole)
        self.frame = QtWidgets.QSpinBox()
        self.frame.setRange(0, 0)
        self.frame.setKeyboardTracking(False)      # typed numbers commit on Enter
        self.frame.setAccelerated(True)
        self.frame.setMinimumWidth(70)
        self.frame.setEnabled(False)
        layout = QtWidgets.QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.combo, 1)
        layout.addWidget(self.frame)
        self.combo.currentIndexChanged.connect(self._combo_changed)
        self.frame.valueChanged.connect(self.frameEdited)

    def _combo_changed(self, _index: int) -> None:
        self.frame.setEnabled(self.combo.currentData() == "frame")
        self.choiceChanged.emit()

    @property
    def value(self) -> str | int:
        key = self.combo.currentData()
        return self.frame.value() if key == "frame" else key

    def set_value(self, value: str | int, num_frames: int) -> None:
        """Show ``value`` with the spin box limited to ``num_frames`` frames, emitting nothing.

        A frame outside the clip (a shorter clip was loaded) is shown clamped; the panel's
        notes show the evaluation error."""
        with _Blocker(self.combo), _Blocker(self.frame):
            self.frame.setRange(0, max(num_frames - 1, 0))
            if isinstance(value, str):
                self.combo.setCurrentIndex(self.combo.findData(value))
            else:
                self.combo.setCurrentIndex(self.combo.findData("frame"))
                self.frame.setValue(int(value))
            self.frame.setEnabled(self.combo.currentData() == "frame")


class FractionSlider(QtWidgets.QWidget):
    """A value in [0, 1] in hundredths: a slider and the value as text.

    ``edited(float)`` fires as the user moves it (every step of a drag); :meth:`set_value`
    shows a value without emitting."""

    edited = QtCore.Signal(float)

    def __init__(self, tip: str, parent=None):
        super().__init__(parent)
        self.slider = QtWidgets.QSlider(QtCore.Qt.Orientation.Horizontal)
        self.slider.setRange(0, 100)
        self.slider.setPageStep(10)
        self.slider.setMinimumWidth(60)
        self.slider.setToolTip(tip)
        self.label = QtWidgets.QLabel("0.00")
        self.label.setMinimumWidth(self.label.fontMetrics().horizontalAdvance("0.00") + 2)
        layout = QtWidgets.QHBoxLayout(self)
        layout.setContentsMargins(2, 0, 2, 0)
        layout.addWidget(self.slider, 1)
        layout.addWidget(self.label)
        self.slider.valueChanged.connect(self._moved)

    @property
    def value(self) -> float:
        return self.slider.value() / 100.0

    def _moved(self, step: int) -> None:
        self.label.setText(f"{step / 100:.2f}")
        self.edited.emit(step / 100.0)

    def set_value(self, value: float) -> None:
        with _Blocker(self.slider):
            self.slider.setValue(int(round(value * 100)))
        self.label.setText(f"{value:.2f}")


def _reference_text(side: str, value: str | int) -> str:
    if value == "auto":
        return f"Choose the {side} reference pose automatically"
    if value == "rest":
        return f"Set {side} reference pose to rest pose"
    return f"Set {side} reference pose to frame {value}"


class BindingPanel(QtWidgets.QWidget):
    """Binding and root options of one document."""

    def __init__(self, document, parent=None):
        super().__init__(parent)
        self.doc = document
        self._build()
        self._connect()
        self.refresh()

    # ------------------------------------------------------------------ building
    def _build(self) -> None:
        outer = QtWidgets.QVBoxLayout(self)

        refs = QtWidgets.QGroupBox("Reference poses")
        form = QtWidgets.QFormLayout(refs)
        self.performer_reference = ReferenceChooser()
        self.performer_reference.setToolTip("The performer's pose in which its bones are "
                                            "matched to the target's")
        self.target_reference = ReferenceChooser()
        self.target_reference.setToolTip("The target's pose that the motion starts from")
        form.addRow("Performer:", self.performer_reference)
        form.addRow("Target:", self.target_reference)
        outer.addWidget(refs)

        posture = QtWidgets.QGroupBox("Rest posture")
        box = QtWidgets.QVBoxLayout(posture)
        self.align_on = QtWidgets.QRadioButton(
            "Turn the target's bones onto the performer's (rest posture)")
        self.align_off = QtWidgets.QRadioButton("Keep the target's own posture")
        self.align_on.setToolTip("Each target bone is turned along the performer's bone in "
                                 "the reference pose, so the target copies its posture")
        self.align_off.setToolTip("The motion is added to the target's own reference posture")
        self.align_group = QtWidgets.QButtonGroup(self)
        self.align_group.addButton(self.align_on)
        self.align_group.addButton(self.align_off)
        box.addWidget(self.align_on)
        box.addWidget(self.align_off)
        self.flat_feet = QtWidgets.QCheckBox("Stand the feet flat as the target's own")
        self.flat_feet.setToolTip(
            "Where the performer's foot stands flat, the target's stands as flat as in its own "
            "rest pose, headed as the performer's, instead of along the performer's foot "
            "(feet of another shape then stand flat through every stance); with the rest "
            "posture only")
        box.addWidget(self.flat_feet)
        chain_row = QtWidgets.QFormLayout()
        self.distribute = QtWidgets.QComboBox()
        for key, text, _undo in DISTRIBUTIONS:
            self.distribute.addItem(text, key)
        self.distribute.setToolTip("How a target chain with more joints than the performer "
                                   "maps (a longer spine) turns")
        chain_row.addRow("Chain turns:", self.distribute)
        box.addLayout(chain_row)
        outer.addWidget(posture)
        outer.addWidget(self._build_pose())
        outer.addWidget(self._build_chains())

        root = QtWidgets.QGroupBox("Root motion")
        form = QtWidgets.QFormLayout(root)
        self.root_mode = QtWidgets.QComboBox()
        for key, text, _undo in ROOT_MODES:
            self.root_mode.addItem(text, key)
            self.root_mode.setItemData(self.root_mode.count() - 1, ROOT_TIPS[key],
                                       QtCore.Qt.ItemDataRole.ToolTipRole)
        form.addRow("Mode:", self.root_mode)
        self.auto_scale = QtWidgets.QCheckBox("Automatic (hip heights)")
        self.auto_scale.setToolTip("Scale the root's displacement by the target's hip height "
                                   "over the performer's")
        self.ratio_label = QtWidgets.QLabel()
        self.ratio_label.setTextInteractionFlags(
            QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
        auto_row = QtWidgets.QHBoxLayout()
        auto_row.addWidget(self.auto_scale)
        auto_row.addStretch(1)
        auto_row.addWidget(self.ratio_label)
        form.addRow("Scale:", auto_row)
        self.scale_h = self._scale_spin("Horizontal root scale")
        self.scale_v = self._scale_spin("Vertical root scale")
        scale_row = QtWidgets.QHBoxLayout()
        scale_row.addWidget(QtWidgets.QLabel("H"))
        scale_row.addWidget(self.scale_h, 1)
        scale_row.addSpacing(8)
        scale_row.addWidget(QtWidgets.QLabel("V"))
        scale_row.addWidget(self.scale_v, 1)
        form.addRow("", scale_row)
        outer.addWidget(root)

        self.notes = QtWidgets.QLabel()
        self.notes.setWordWrap(True)
        self.notes.setTextInteractionFlags(QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
        font = self.notes.font()
        font.setPointSizeF(font.pointSizeF() * 0.9)
        self.notes.setFont(font)
        outer.addWidget(self.notes)
        outer.addStretch(1)

    def _build_pose(self) -> QtWidgets.QGroupBox:
        """The retarget pose: the selected target joint, its typed angles and the buttons."""
        pose = QtWidgets.QGroupBox("Retarget pose")
        form = QtWidgets.QFormLayout(pose)
        self.pose_joint = QtWidgets.QComboBox()
        self.pose_joint.setToolTip("The target joint to turn in the binding pose (the "
                                   "selection of the viewport and the correspondence editor)")
        self.pose_edit = QtWidgets.QCheckBox("Edit in the viewport")
        self.pose_edit.setToolTip("Show the binding pose beside the performer's reference "
                                  "pose, with a rotation gizmo on the selected joint")
        row = QtWidgets.QHBoxLayout()
        row.addWidget(self.pose_joint, 1)
        row.addWidget(self.pose_edit)
        form.addRow("Joint:", row)
        self.angles = []
        angle_row = QtWidgets.QHBoxLayout()
        for axis in "XYZ":
            spin = QtWidgets.QDoubleSpinBox()
            spin.setRange(-ANGLE_RANGE, ANGLE_RANGE)
            spin.setDecimals(1)
            spin.setSingleStep(1.0)
            spin.setSuffix(" \N{DEGREE SIGN}")
            spin.setKeyboardTracking(False)
            spin.setAccelerated(True)
            spin.setToolTip(f"Turn about the joint's binding-frame {axis} axis (angles "
                            f"applied X, then Y, then Z, each about the turned axes)")
            angle_row.addWidget(QtWidgets.QLabel(axis))
            angle_row.addWidget(spin, 1)
            self.angles.append(spin)
        form.addRow("Offset:", angle_row)
        self.mirror_button = QtWidgets.QPushButton("Mirror")
        self.mirror_button.setToolTip("Give the other side's joint the same turn, reflected "
                                      "through the character's middle")
        self.reset_joint_button = QtWidgets.QPushButton("Reset joint")
        self.reset_all_button = QtWidgets.QPushButton("Reset all")
        buttons = QtWidgets.QHBoxLayout()
        for button in (self.mirror_button, self.reset_joint_button, self.reset_all_button):
            buttons.addWidget(button)
        form.addRow("", buttons)
        self.pose_summary = QtWidgets.QLabel()
        self.pose_summary.setWordWrap(True)
        form.addRow("", self.pose_summary)
        return pose

    def _build_chains(self) -> QtWidgets.QGroupBox:
        """The chain table (its rows are made per target skeleton, :meth:`_chain_rows`)."""
        group = QtWidgets.QGroupBox("Chains")
        box = QtWidgets.QVBoxLayout(group)
        self.chain_table = QtWidgets.QTableWidget(0, len(CHAIN_COLUMNS))
        self.chain_table.setHorizontalHeaderLabels(list(CHAIN_COLUMNS))
        self.chain_table.verticalHeader().setVisible(False)
        self.chain_table.setSelectionMode(QtWidgets.QAbstractItemView.SelectionMode.NoSelection)
        self.chain_table.setEditTriggers(QtWidgets.QAbstractItemView.EditTrigger.NoEditTriggers)
        self.chain_table.setVerticalScrollBarPolicy(QtCore.Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        header = self.chain_table.horizontalHeader()
        header.setSectionResizeMode(QtWidgets.QHeaderView.ResizeMode.ResizeToContents)
        for column in (1, 4):
            header.setSectionResizeMode(column, QtWidgets.QHeaderView.ResizeMode.Stretch)
        tips = ("", "Rotation transfer: 0 keeps the character's binding pose, 1 follows the "
                    "performer", "Transfer the twist about each bone",
                "How the chain's unmapped inner joints turn ('As above': the Chain turns "
                "choice of the rest posture)",
                "The end effector's reach for the performer's (scaled) position, below the "
                "contacts' priority: 0 pure converted motion, 1 reach it")
        for column, tip in enumerate(tips):
            self.chain_table.horizontalHeaderItem(column).setToolTip(tip)
        self.chain_notes = QtWidgets.QLabel()
        self.chain_notes.setWordWrap(True)
        box.addWidget(self.chain_table)
        box.addWidget(self.chain_notes)
        self._chains_for = None                    # the skeleton the rows were made for
        self.chain_rows: dict[str, dict] = {}
        return group

    def _chain_rows(self) -> None:
        """One row per chain the target has (made again when the target changes)."""
        target = self.doc.scene.target
        skeleton = target.skeleton if target is not None else None
        if skeleton is self._chains_for:
            return
        self._chains_for = skeleton
        binding = self.doc.scene.binding
        chains = chains_of(skeleton, binding.rest_positions if binding is not None else None) \
            if skeleton is not None else {}
        self.chain_rows = {}
        table = self.chain_table
        table.setRowCount(len(chains))
        for row, (name, joints) in enumerate(chains.items()):
            title = QtWidgets.QTableWidgetItem(CHAIN_TITLES[name])
            title.setToolTip(", ".join(joints))
            table.setItem(row, 0, title)
            weight = FractionSlider(f"{CHAIN_TITLES[name]}: rotation transfer weight")
            twist = QtWidgets.QCheckBox()
            twist.setToolTip(f"{CHAIN_TITLES[name]}: transfer the twist")
            twist_cell = QtWidgets.QWidget()
            twist_box = QtWidgets.QHBoxLayout(twist_cell)
            twist_box.setContentsMargins(0, 0, 0, 0)
            twist_box.setAlignment(QtCore.Qt.AlignmentFlag.AlignCenter)
            twist_box.addWidget(twist)
            turns = QtWidgets.QComboBox()
            for key, text in CHAIN_DISTRIBUTIONS:
                turns.addItem(text, key)
            blend = FractionSlider(f"{CHAIN_TITLES[name]}: IK blend of its end effector")
            blend.setEnabled(name in chains.effectors)      # the fingers reach for nothing
            for column, widget in ((1, weight), (2, twist_cell), (3, turns), (4, blend)):
                table.setCellWidget(row, column, widget)
            weight.edited.connect(lambda v, n=name: self._chain_edited(n, "weight", v))
            twist.toggled.connect(lambda on, n=name: self._chain_edited(n, "twist", on))
            turns.currentIndexChanged.connect(
                lambda i, n=name: self._chain_edited(n, "distribute",
                                                     CHAIN_DISTRIBUTIONS[i][0]))
            blend.edited.connect(lambda v, n=name: self._chain_edited(n, "ik_blend", v))
            self.chain_rows[name] = {"weight": weight, "twist": twist, "distribute": turns,
                                     "ik_blend": blend}
        table.resizeRowsToContents()
        height = table.horizontalHeader().height() + 2 * table.frameWidth() + sum(
            table.rowHeight(r) for r in range(table.rowCount()))
        table.setFixedHeight(height)
        self.chain_notes.setText("<i>No limb chains: the target's joints have no humanoid "
                                 "roles.</i>")
        self.chain_notes.setVisible(skeleton is not None and not chains)
        table.setVisible(bool(chains))

    @staticmethod
    def _scale_spin(tip: str) -> QtWidgets.QDoubleSpinBox:
        spin = QtWidgets.QDoubleSpinBox()
        spin.setRange(0.0, 100.0)
        spin.setDecimals(3)
        spin.setSingleStep(0.01)
        spin.setKeyboardTracking(False)
        spin.setAccelerated(True)
        spin.setToolTip(tip)
        return spin

    def _connect(self) -> None:
        d = self.doc
        d.optionsChanged.connect(self.refresh)
        d.sourcesChanged.connect(self.refresh)
        d.motionChanged.connect(self.refresh)          # new binding: notes, hip-height ratio
        self.performer_reference.choiceChanged.connect(
            lambda: self._reference_chosen("performer"))
        self.target_reference.choiceChanged.connect(lambda: self._reference_chosen("target"))
        self.performer_reference.frameEdited.connect(
            lambda f: self._reference_frame_edited("performer", f))
        self.target_reference.frameEdited.connect(
            lambda f: self._reference_frame_edited("target", f))
        self.align_on.toggled.connect(self._alignment_toggled)
        self.flat_feet.toggled.connect(self._flat_feet_toggled)
        self.distribute.currentIndexChanged.connect(self._distribute_changed)
        self.root_mode.currentIndexChanged.connect(self._root_mode_changed)
        self.auto_scale.toggled.connect(self._auto_scale_toggled)
        self.scale_h.valueChanged.connect(lambda h: self._scale_edited(h=h))
        self.scale_v.valueChanged.connect(lambda v: self._scale_edited(v=v))
        d.selectionChanged.connect(lambda *_: self.refresh())
        d.viewerChanged.connect(self.refresh)
        self.pose_joint.currentIndexChanged.connect(self._pose_joint_chosen)
        self.pose_edit.toggled.connect(lambda on: d.set_viewer_options(pose_edit=bool(on)))
        for axis, spin in enumerate(self.angles):
            spin.valueChanged.connect(lambda value, a=axis: self._angle_edited(a, value))
        self.mirror_button.clicked.connect(self.mirror)
        self.reset_joint_button.clicked.connect(self.reset_joint)
        self.reset_all_button.clicked.connect(self.reset_all)

    # ------------------------------------------------------------------ model -> widgets
    def refresh(self) -> None:
        """Show the document's options, the binding's notes and the hip-height ratio."""
        d = self.doc
        b, r = d.scene.bind_options, d.scene.root
        self.performer_reference.set_value(
            b.performer_reference, d.scene.performer.num_frames if d.scene.performer is not None else 0)
        self.target_reference.set_value(
            b.target_reference, d.scene.target.num_frames if d.scene.target is not None else 0)
        with _Blocker(self.align_on), _Blocker(self.align_off):
            (self.align_on if b.rest_alignment else self.align_off).setChecked(True)
        with _Blocker(self.flat_feet):
            self.flat_feet.setChecked(b.flat_feet)
        self.flat_feet.setEnabled(b.rest_alignment)
        with _Blocker(self.distribute):
            self.distribute.setCurrentIndex(self.distribute.findData(b.distribute))
        with _Blocker(self.root_mode):
            self.root_mode.setCurrentIndex(self.root_mode.findData(r.mode))
            self.root_mode.setToolTip(ROOT_TIPS[r.mode])
        ratio = self._ratio()
        self.ratio_label.setText(f"ratio {ratio:.3f}" if ratio is not None else "ratio -")
        auto = r.scale is None
        h, v = r.scale if not auto else ((ratio,) * 2 if ratio is not None else (1.0, 1.0))
        with _Blocker(self.auto_scale), _Blocker(self.scale_h), _Blocker(self.scale_v):
            self.auto_scale.setChecked(auto)
            self.scale_h.setValue(h)
            self.scale_v.setValue(v)
        uses_scale = r.mode != "absolute"
        self.auto_scale.setEnabled(uses_scale)
        self.scale_h.setEnabled(uses_scale and not auto and r.mode != "in-place")
        self.scale_v.setEnabled(uses_scale and not auto)
        self._refresh_pose()
        self._refresh_chains()
        self.notes.setText(self._notes_text())

    @property
    def pose_target(self) -> str | None:
        """The target joint the retarget pose controls act on
        (:attr:`~app.gui.document.Document.selected_target_joint`)."""
        return self.doc.selected_target_joint

    def _refresh_pose(self) -> None:
        d = self.doc
        target = d.scene.target
        names = list(target.skeleton.names) if target is not None else []
        joint = self.pose_target
        offsets = dict(d.scene.bind_options.pose_offsets)
        with _Blocker(self.pose_joint):
            if [self.pose_joint.itemData(i) for i in range(self.pose_joint.count())] != names:
                self.pose_joint.clear()
                self.pose_joint.addItem("(select a target joint)", None)
                for name in names:
                    self.pose_joint.addItem(name, name)
            for i in range(1, self.pose_joint.count()):
                name = self.pose_joint.itemData(i)
                self.pose_joint.setItemText(i, f"{name} *" if name in offsets else name)
            self.pose_joint.setCurrentIndex(max(self.pose_joint.findData(joint), 0))
        with _Blocker(self.pose_edit):
            self.pose_edit.setChecked(bool(d.scene.viewer.options.get("pose_edit", False)))
        self.pose_edit.setEnabled(d.scene.binding is not None)
        angles = offset_to_euler(d.scene.bind_options.offset(joint)) if joint else np.zeros(3)
        for spin, value in zip(self.angles, angles):
            with _Blocker(spin):
                spin.setValue(float(value))
            spin.setEnabled(joint is not None and d.scene.binding is not None)
        other = self._mirror_of(joint)
        self.mirror_button.setText(f"Mirror to {other}" if other else "Mirror")
        self.mirror_button.setEnabled(other is not None and d.scene.binding is not None)
        self.reset_joint_button.setEnabled(joint in offsets)
        self.reset_all_button.setEnabled(bool(offsets))
        self.pose_summary.setText(
            f"Turned in the binding pose: {', '.join(offsets)}" if offsets else
            "<i>The binding pose is as the rest alignment made it.</i>")

    def _mirror_of(self, joint: str | None) -> str | None:
        b = self.doc.scene.binding
        if joint is None or b is None:
            return None
        return mirror_joint(b.target, joint, b.rest_positions)

    def _refresh_chains(self) -> None:
        self._chain_rows()
        b = self.doc.scene.bind_options
        for name, widgets in self.chain_rows.items():
            settings = b.chain(name)
            widgets["weight"].set_value(settings.weight)
            widgets["ik_blend"].set_value(settings.ik_blend)
            with _Blocker(widgets["twist"]), _Blocker(widgets["distribute"]):
                widgets["twist"].setChecked(settings.twist)
                widgets["distribute"].setCurrentIndex(
                    widgets["distribute"].findData(settings.distribute))

    def _ratio(self) -> float | None:
        b = self.doc.scene.binding
        return float(b.hip_height_ratio) if b is not None else None

    def _notes_text(self) -> str:
        d = self.doc
        if d.scene.evaluation_error:
            return f"<span style='color:#c0392b'>{_escape(d.scene.evaluation_error)}</span>"
        if d.scene.binding is None:
            return "<i>Load a performer and a target and map their joints to bind them.</i>"
        lines = [f"{_escape(k[:1].upper() + k[1:])}: {_escape(str(v))}"
                 for k, v in d.scene.binding.notes.items()]
        return "<br>".join(lines)

    # ------------------------------------------------------------------ widgets -> model
    def _push(self, text: str, bind: BindOptions | None = None,
              root: RootOptions | None = None, merge_key: str | None = None,
              solve: bool = False) -> None:
        """One command; with ``merge_key`` (naming the control), consecutive pushes with the
        same key (nothing else pushed in between) are one undo step named after the last one
        (:meth:`~app.gui.commands.SceneCommand.mergeWith`): a spin box's run, a slider's
        drag. ``solve``: the new scene is solved in the background."""
        push_options(self.doc, bind_options=bind, root_options=root, text=text,
                     merge=merge_key or False, solve=solve)
        # a refused change (push_options ignores no-ops) must not leave the widgets wrong
        self.refresh()

    def _pose_joint_chosen(self, index: int) -> None:
        joint = self.pose_joint.itemData(index)
        self.doc.select("target" if joint else "", joint or "")

    def _angle_edited(self, axis: int, value: float) -> None:
        joint = self.pose_target
        if joint is None:
            return
        b = self.doc.scene.bind_options
        # the other two angles come from the model, not from their rounded spin boxes
        angles = offset_to_euler(b.offset(joint))
        angles[axis] = value
        x, y, z = angles
        self._push(f"Set {joint}'s pose offset to X {x:.1f}, Y {y:.1f}, Z {z:.1f} deg",
                   bind=b.with_offset(joint, euler_to_offset(angles)),
                   merge_key=f"pose offset {joint}")

    def mirror(self) -> None:
        """Give the other side's joint the selected joint's offset, reflected."""
        joint, b = self.pose_target, self.doc.scene.binding
        if joint is None or b is None:
            return
        try:
            other, quat = mirrored_offset(b, joint, self.doc.scene.bind_options.offset(joint))
        except MotionComposerError as exc:
            self.doc.errorRaised.emit(str(exc))
            return
        self._push(f"Mirror {joint}'s pose offset to {other}",
                   bind=self.doc.scene.bind_options.with_offset(other, quat))

    def reset_joint(self) -> None:
        joint = self.pose_target
        if joint is not None:
            self._push(f"Reset {joint}'s pose offset",
                       bind=self.doc.scene.bind_options.with_offset(joint, None))

    def reset_all(self) -> None:
        self._push("Reset the binding pose",
                   bind=self.doc.scene.bind_options.without_offsets())

    def _chain_edited(self, name: str, key: str, value) -> None:
        b = self.doc.scene.bind_options
        settings = dataclasses.replace(b.chain(name), **{key: value})
        sliding = key in ("weight", "ik_blend")
        if sliding:
            what = f"{'weight' if key == 'weight' else 'IK blend'} to {value:.2f}"
        elif key == "twist":
            what = f"twist {'on' if value else 'off'}"
        else:
            what = f"chain turns to {dict(CHAIN_DISTRIBUTIONS)[value].lower()}"
        # an IK blend's reach goals are met, or dropped, by a solve
        self._push(f"Set {CHAIN_TITLES[name].lower()} {what}",
                   bind=b.with_chain(name, settings),
                   merge_key=f"chain {name} {key}" if sliding else None,
                   solve=key == "ik_blend")

    def _reference_chosen(self, side: str) -> None:
        chooser = getattr(self, f"{side}_reference")
        value = chooser.value
        self._push(_reference_text(side, value),
                   bind=dataclasses.replace(self.doc.scene.bind_options,
                                            **{f"{side}_reference": value}))

    def _reference_frame_edited(self, side: str, frame: int) -> None:
        if getattr(self, f"{side}_reference").combo.currentData() != "frame":
            return
        self._push(_reference_text(side, frame),
                   bind=dataclasses.replace(self.doc.scene.bind_options,
                                            **{f"{side}_reference": int(frame)}),
                   merge_key=f"{side} frame")

    def _alignment_toggled(self, on: bool) -> None:
        self._push(f"Turn rest alignment {'on' if on else 'off'}",
                   bind=dataclasses.replace(self.doc.scene.bind_options, rest_alignment=bool(on)))

    def _flat_feet_toggled(self, on: bool) -> None:
        self._push(f"Turn flat feet {'on' if on else 'off'}",
                   bind=dataclasses.replace(self.doc.scene.bind_options, flat_feet=bool(on)))

    def _distribute_changed(self, index: int) -> None:
        key, _text, undo = DISTRIBUTIONS[index]
        self._push(undo, bind=dataclasses.replace(self.doc.scene.bind_options, distribute=key))

    def _root_mode_changed(self, index: int) -> None:
        key, _text, undo = ROOT_MODES[index]
        self._push(undo, root=dataclasses.replace(self.doc.scene.root, mode=key))

    def _auto_scale_toggled(self, auto: bool) -> None:
        if auto:
            self._push("Scale the root by hip heights",
                       root=dataclasses.replace(self.doc.scene.root, scale=None))
        else:
            ratio = self._ratio()
            start = (ratio, ratio) if ratio is not None else (1.0, 1.0)
            self._push("Set the root scale by hand",
                       root=dataclasses.replace(self.doc.scene.root, scale=start))

    def _scale_edited(self, h: float | None = None, v: float | None = None) -> None:
        scale = self.doc.scene.root.scale
        if self.auto_scale.isChecked() or scale is None:
            return
        # the other factor comes from the model, not from its rounded spin box
        h = scale[0] if h is None else h
        v = scale[1] if v is None else v
        self._push(f"Set root scale to {h:.3f} (horizontal), {v:.3f} (vertical)",
                   root=dataclasses.replace(self.doc.scene.root, scale=(h, v)),
                   merge_key="root scale")


def _escape(text: str) -> str:
    return (text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;"))
