"""The binding panel: reference poses, rest alignment, chain distribution and root motion.

Built straight from a :class:`~app.gui.document.Document` and wired both ways: the document's
signals (options changed, sources loaded, motion re-evaluated, undo and redo) update the
widgets inside ``QSignalBlocker`` s, and every widget change pushes one undoable command
through :func:`app.gui.commands.push_options`.

Spin boxes merge: consecutive edits of one spin box (the two root scales count as one) are one
undo step whose text names the last value.
"""
from __future__ import annotations

import dataclasses

from motion_composer.app.gui.commands import push_options
from motion_composer.app.gui.qt import QtCore, QtWidgets
from motion_composer.engine.conversion import BindOptions
from motion_composer.engine.conversion import RootOptions

__all__ = ["BindingPanel", "ReferenceChooser"]

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
        self._merge_key: str | None = None
        self._merge_cmd = None
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
        chain_row = QtWidgets.QFormLayout()
        self.distribute = QtWidgets.QComboBox()
        for key, text, _undo in DISTRIBUTIONS:
            self.distribute.addItem(text, key)
        self.distribute.setToolTip("How a target chain with more joints than the performer "
                                   "maps (a longer spine) turns")
        chain_row.addRow("Chain turns:", self.distribute)
        box.addLayout(chain_row)
        outer.addWidget(posture)

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
        self.distribute.currentIndexChanged.connect(self._distribute_changed)
        self.root_mode.currentIndexChanged.connect(self._root_mode_changed)
        self.auto_scale.toggled.connect(self._auto_scale_toggled)
        self.scale_h.valueChanged.connect(lambda h: self._scale_edited(h=h))
        self.scale_v.valueChanged.connect(lambda v: self._scale_edited(v=v))

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
        self.notes.setText(self._notes_text())

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
              root: RootOptions | None = None, merge_key: str | None = None) -> None:
        """One command; with ``merge_key``, consecutive pushes with the same key (and nothing
        else pushed in between) are one undo step named after the last one."""
        stack = self.doc.undo_stack
        top = stack.command(stack.index() - 1) if stack.index() > 0 else None
        continuing = (merge_key is not None and merge_key == self._merge_key
                      and top is not None and top is self._merge_cmd)
        # push_options merges every mergeable options command with the one before; never
        # start a new run on top of someone else's mergeable command
        foreign_mergeable = top is not None and top.id() != -1 and not continuing
        merge = merge_key is not None and not foreign_mergeable
        index = stack.index()
        push_options(self.doc, bind_options=bind, root_options=root, text=text, merge=merge)
        new_top = stack.command(stack.index() - 1) if stack.index() > 0 else None
        merged = continuing and stack.index() == index and new_top is top
        if merged:
            # name the step after the latest value (the stack keeps the first one's text)
            new_top.setText(text)
            stack.undoTextChanged.emit(stack.undoText())
        if (merge_key is not None and new_top is not None and new_top.id() != -1
                and (merged or new_top is not top)):
            self._merge_key, self._merge_cmd = merge_key, new_top
        else:
            self._merge_key, self._merge_cmd = None, None
        # a refused change (push_options ignores no-ops) must not leave the widgets wrong
        self.refresh()

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
