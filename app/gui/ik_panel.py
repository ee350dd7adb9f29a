"""The IK solver's settings (the project's ``IKOptions``), edited as typed numbers.

Each field is a line edit showing the exact value (``1e-06`` stays ``1e-06``); Enter or leaving
the field sets it as one undoable command, merged with further edits of the same field, and
re-solves the constraints in the background when there are any. A value the solver refuses
(:class:`~engine.errors.IKOptionsError`) is shown in red with the reason and not applied.
"""
from __future__ import annotations

import dataclasses

from motion_composer.app.gui.qt import QtCore, QtGui, QtWidgets
from motion_composer.engine.errors import IKOptionsError

__all__ = ["IKPanel", "FIELDS"]

#: (IKOptions field, label, tooltip); joint limits and scale are not typed here
FIELDS = (
    ("tolerance", "Tolerance [m]", "A position or plane goal counts as met below this error"),
    ("max_iterations", "Iterations", "The cap of solver iterations per frame"),
    ("damping", "Damping", "Damped least squares lambda, as a fraction of the character's "
                           "height: larger is steadier near a stretched limb, slower to reach"),
    ("max_step", "Largest step", "The largest correction asked of one goal per iteration, as a "
                                 "fraction of the height"),
    ("attraction", "Attraction", "Gain from 0 to 1 of the pull towards the converted posture"),
    ("settle", "Settle", "A frame whose goals are met stops once its largest step is below "
                         "this (radians or metres)"),
    ("nullspace_damping", "Null-space damping", "Damping of the projections of lower "
                                                "priorities, as a fraction of the height"),
    ("step_cap", "Joint step cap [rad]", "The largest turn of any joint in one iteration"),
    ("polish_share", "Polish share", "The share of the iterations, at their end, that only "
                                     "restore the first priority"),
    ("priority_gate", "Priority gate", "A lower priority runs while the higher ones are "
                                       "within this many tolerances"),
)


def _text(value) -> str:
    return repr(value) if isinstance(value, float) else str(value)


class IKPanel(QtWidgets.QGroupBox):
    """The document's IK options, wired both ways."""

    def __init__(self, document, parent=None):
        super().__init__("IK solver", parent)
        self.doc = document
        self.edits: dict[str, QtWidgets.QLineEdit] = {}
        form = QtWidgets.QFormLayout(self)
        for name, label, tip in FIELDS:
            edit = QtWidgets.QLineEdit()
            edit.setToolTip(tip)
            if name == "max_iterations":
                edit.setValidator(QtGui.QIntValidator(0, 100000, edit))
            edit.editingFinished.connect(lambda n=name: self._edited(n))
            form.addRow(label + ":", edit)
            self.edits[name] = edit
        self.message = QtWidgets.QLabel()
        self.message.setWordWrap(True)
        self.message.setStyleSheet("color: #c0392b")
        self.message.setVisible(False)
        form.addRow(self.message)
        document.optionsChanged.connect(self.refresh)
        self.refresh()

    def refresh(self) -> None:
        options = self.doc.scene.ik_options
        for name, edit in self.edits.items():
            text = _text(getattr(options, name))
            if edit.text() != text:
                with QtCore.QSignalBlocker(edit):
                    edit.setText(text)
            edit.setStyleSheet("")

    def _edited(self, name: str) -> None:
        edit = self.edits[name]
        current = self.doc.scene.ik_options
        try:
            value = int(edit.text()) if name == "max_iterations" else float(edit.text())
            options = dataclasses.replace(current, **{name: value})
        except (ValueError, IKOptionsError) as exc:
            problem = exc.problem if isinstance(exc, IKOptionsError) else \
                f"expected a number, not {edit.text()!r}"
            edit.setStyleSheet("color: #c0392b")
            self.message.setText(f"{dict((f[0], f[1]) for f in FIELDS)[name]}: {problem}")
            self.message.setVisible(True)
            return
        self.message.setVisible(False)
        edit.setStyleSheet("")
        if options == current:
            return
        scene = self.doc.scene
        solve = scene.composed is not None and any(c.enabled for c in scene.constraints)
        self.doc.edit(f"Set IK {name.replace('_', ' ')} to {_text(value)}",
                      merge=f"ik {name}", solve=solve, ik_options=options)
