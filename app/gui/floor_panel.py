"""The project's floor (``floor``, ``stand_on_floor``), wired both ways to the document.

*Floor* on keeps the target's feet and toes on or above a floor (floor planes, the floor the
automatic contacts stand on); switched on it starts where the character stands, so nothing
moves until a height is typed. *Stand the character on it* moves the whole conversion onto
that floor (:meth:`engine.scene.Scene.lift`), as ``retarget --floor`` does; off, the floor is
only the feet's plane. Goals set by hand move with the character
(:meth:`engine.scene.Scene.floor_changes`). Each change is one undoable command that makes
the automatic constraints again and re-solves in the background. The line below says where
the character stands and how far the floor moves it. A height that is not a usable number
is shown in red with the reason and not applied.
"""
from __future__ import annotations

from motion_composer.app.gui.qt import QtCore, QtWidgets
from motion_composer.engine.errors import MotionComposerError

__all__ = ["FloorPanel"]


def _text(value: float) -> str:
    return repr(float(value))


def _check(form, text: str, tip: str, slot) -> QtWidgets.QCheckBox:
    """A check box on its own row of ``form``, calling ``slot`` when toggled."""
    box = QtWidgets.QCheckBox(text)
    box.setToolTip(tip)
    box.toggled.connect(slot)
    form.addRow(box)
    return box


class FloorPanel(QtWidgets.QGroupBox):
    """The document's floor, wired both ways."""

    def __init__(self, document, parent=None):
        super().__init__("Floor", parent)
        self.doc = document
        form = QtWidgets.QFormLayout(self)
        self.enabled = _check(form, "Keep the feet on or above a floor",
                              "Floor planes under every foot joint, and the floor the "
                              "automatic contacts stand on", self._toggled)
        self.height = QtWidgets.QLineEdit()
        self.height.setToolTip("The floor's height in metres (+Y up)")
        self.height.editingFinished.connect(self._height_edited)
        form.addRow("Height [m]:", self.height)
        self.stand = _check(form, "Stand the character on it",
                            "Raise or lower the whole conversion onto the floor; off, the "
                            "floor only keeps the feet above it", self._stand_toggled)
        self.where = QtWidgets.QLabel()
        self.where.setWordWrap(True)
        form.addRow(self.where)
        self.message = QtWidgets.QLabel()
        self.message.setWordWrap(True)
        self.message.setStyleSheet("color: #c0392b")
        self.message.setVisible(False)
        form.addRow(self.message)
        for signal in (document.optionsChanged, document.sourcesChanged,
                       document.mappingChanged):
            signal.connect(self.refresh)
        self.refresh()

    # ------------------------------------------------------------------ model -> view
    def refresh(self) -> None:
        scene = self.doc.scene
        floor = scene.project.floor
        ready = scene.composed is not None
        with QtCore.QSignalBlocker(self.enabled):
            self.enabled.setChecked(floor is not None)
        with QtCore.QSignalBlocker(self.stand):
            self.stand.setChecked(bool(scene.project.stand_on_floor))
        absolute = scene.project.root.mode == "absolute"
        self.enabled.setEnabled(ready)
        self.height.setEnabled(ready and floor is not None)
        self.stand.setEnabled(ready and floor is not None and not absolute)
        text = _text(floor) if floor is not None else ""
        if self.height.text() != text:
            with QtCore.QSignalBlocker(self.height):
                self.height.setText(text)
        self.height.setStyleSheet("")
        self.message.setVisible(False)             # a refused text is gone with the refresh
        self.where.setText(self._where())

    def _where(self) -> str:
        scene = self.doc.scene
        if scene.composed is None:
            return ""
        standing = scene.standing_floor()
        if standing is None:
            return "No feet found on the target: the floor moves nothing."
        line = f"The character stands at {standing:.3f} m."
        lift = scene.lift()
        floor = scene.project.floor
        if lift:
            line += (f" The conversion is {'raised' if lift > 0 else 'lowered'} "
                     f"{abs(lift) * 1000:.0f} mm onto the floor.")
        elif floor is not None and floor != standing:
            why = ("The absolute root mode places the root where the performer's is"
                   if scene.project.root.mode == "absolute" else "The conversion stays")
            line += (f" {why}: the floor is {abs(floor - standing) * 1000:.0f} mm "
                     f"{'above' if floor > standing else 'below'} its feet"
                     f"{', and its planes push them up' if floor > standing else ''}.")
        return line

    # ------------------------------------------------------------------ view -> model
    def _apply(self, text: str, merge: str | None = None, **changes) -> None:
        self.message.setVisible(False)
        if self.doc.scene.composed is None:
            return
        # the goals set by hand move with the character (one command with the floor)
        self.doc.edit(text, merge=merge, solve=True, regenerate=True,
                      **self.doc.scene.floor_changes(**changes))

    def _toggled(self, on: bool) -> None:
        scene = self.doc.scene
        if on:
            # start where the character stands: nothing moves until a height is typed
            standing = scene.standing_floor()
            height = 0.0 if standing is None else standing
            self._apply(f"Floor at {height:.3f} m", floor=height)
        else:
            self._apply("No floor", floor=None)

    def _stand_toggled(self, on: bool) -> None:
        self._apply("Stand the character on the floor" if on else
                    "Floor keeps only the feet above it", stand_on_floor=on)

    def _height_edited(self) -> None:
        if self.doc.scene.project.floor is None:
            return
        raw = self.height.text().strip()
        try:
            value = float(raw)
            self.doc.scene.project.replace(floor=value)      # the project's own check
        except (ValueError, MotionComposerError) as exc:
            problem = (str(exc).removeprefix("floor: ") if isinstance(exc, MotionComposerError)
                       else f"expected a number, not {raw!r}")
            self.height.setStyleSheet("color: #c0392b")
            self.message.setText(f"Floor height: {problem}")
            self.message.setVisible(True)
            return
        self.height.setStyleSheet("")
        if value == self.doc.scene.project.floor:
            self.message.setVisible(False)
            return
        self._apply(f"Floor at {value:.3f} m", merge="floor height", floor=value)
