"""File > Import's options dialog: how a BVH file is read (units, scale, up axis, what its
position channels mean), each "detected" unless chosen, with what detection found and any
doubt about it. The choices become the project's :class:`~engine.project.Source` overrides,
as ``--performer-units`` ... do on the command line."""
from __future__ import annotations

from pathlib import Path

from motion_composer.app.gui.qt import QtWidgets
from motion_composer.engine.units import AXES, UNITS

DETECTED = "detected"
MODES = ("absolute", "relative")


class ImportOptionsDialog(QtWidgets.QDialog):
    """Ask how to read the BVH file ``path`` for ``side`` (``"performer"``/``"target"``).

    ``detected`` is the motion read with everything detected (its
    :attr:`~engine.skeleton.Skeleton.source` is shown), ``given`` the overrides to start from
    (a re-import keeps the project's). :meth:`options` gives the overrides chosen.
    """

    def __init__(self, parent, side: str, path, detected, given: dict | None = None):
        super().__init__(parent)
        given = given or {}
        src = detected.skeleton.source
        self.setWindowTitle(f"Import {side}: {Path(path).name}")
        form = QtWidgets.QFormLayout(self)
        found = QtWidgets.QLabel(f"Detected: {src.units}, {src.up_axis} up ({src.reason})")
        found.setWordWrap(True)
        form.addRow(found)
        self.doubt = QtWidgets.QLabel(f"Check this: {src.doubt}" if src.doubt else "")
        self.doubt.setWordWrap(True)
        self.doubt.setVisible(bool(src.doubt))
        form.addRow(self.doubt)
        self.units = self._combo(sorted(UNITS), given.get("units"), src.units)
        form.addRow("Units", self.units)
        self.scale = QtWidgets.QLineEdit("" if given.get("scale") is None
                                         else repr(float(given["scale"])))
        self.scale.setPlaceholderText("metres per file unit (overrides the units)")
        form.addRow("Scale", self.scale)
        self.up_axis = self._combo(AXES, given.get("up_axis"), src.up_axis)
        form.addRow("Up axis", self.up_axis)
        mode = given.get("position_mode")
        self.position_mode = self._combo(MODES, mode if isinstance(mode, str) else None, None)
        form.addRow("Position channels", self.position_mode)
        self.error = QtWidgets.QLabel("")
        self.error.setVisible(False)
        form.addRow(self.error)
        buttons = QtWidgets.QDialogButtonBox(QtWidgets.QDialogButtonBox.StandardButton.Ok |
                                             QtWidgets.QDialogButtonBox.StandardButton.Cancel)
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        form.addRow(buttons)

    @staticmethod
    def _combo(choices, given, detected) -> QtWidgets.QComboBox:
        combo = QtWidgets.QComboBox()
        combo.addItem(DETECTED if detected is None else f"{DETECTED} ({detected})", None)
        for choice in choices:
            combo.addItem(choice, choice)
        if given is not None:
            combo.setCurrentIndex(combo.findData(given))
        return combo

    def options(self) -> dict:
        """The overrides chosen (``units``, ``scale``, ``up_axis``, ``position_mode``; those
        left "detected" are left out). Raises ``ValueError`` for a scale that is not a positive
        number."""
        options = {"units": self.units.currentData(), "up_axis": self.up_axis.currentData(),
                   "position_mode": self.position_mode.currentData()}
        text = self.scale.text().strip()
        if text:
            try:
                scale = float(text)
            except ValueError:
                scale = float("nan")
            if not 0 < scale < float("inf"):
                raise ValueError(f"the scale must be a positive number of metres per unit, "
                                 f"not {text!r}")
            options["scale"] = scale
        return {k: v for k, v in options.items() if v is not None}

    def accept(self) -> None:
        """Close only with options that can be used; else say what is wrong."""
        try:
            self.options()
        except ValueError as exc:
            self.error.setText(str(exc))
            self.error.setVisible(True)
            return
        super().accept()
