"""File > Import's options dialog: how a BVH file is read (units, scale, up axis, what its
position channels mean), each "detected" unless chosen, with what detection found and any
doubt about it. The choices become the project's :class:`~engine.project.Source` overrides,
as ``--performer-units`` ... do on the command line. For a glTF or FBX character, which
states its units and axes, only the up axis is asked, and only of a file whose figure does
not stand along +Y as the file says (written with another axis up): the axis it stands along
is offered."""
from __future__ import annotations

from pathlib import Path

from motion_composer.app.gui.qt import QtWidgets
from motion_composer.engine.units import AXES, UNITS

DETECTED = "detected"
MODES = ("absolute", "relative")


class ImportOptionsDialog(QtWidgets.QDialog):
    """Ask how to read the BVH file ``path`` for ``side`` (``"performer"``/``"target"``), or
    (``character``) the up axis of a glTF or FBX file.

    ``detected`` is the motion read with everything detected (its
    :attr:`~engine.skeleton.Skeleton.source` is shown), ``given`` the overrides to start from
    (a re-import keeps the project's). :meth:`options` gives the overrides chosen.
    """

    def __init__(self, parent, side: str, path, detected, given: dict | None = None, *,
                 character: bool = False):
        super().__init__(parent)
        given = given or {}
        src = detected.skeleton.source
        self.setWindowTitle(f"Import {side}: {Path(path).name}")
        form = QtWidgets.QFormLayout(self)
        found = QtWidgets.QLabel(f"The file says: {src.units}, {src.up_axis} up ({src.reason})"
                                 if character else
                                 f"Detected: {src.units}, {src.up_axis} up ({src.reason})")
        found.setWordWrap(True)
        form.addRow(found)
        self.doubt = QtWidgets.QLabel(f"Check this: {src.doubt}" if src.doubt else "")
        self.doubt.setWordWrap(True)
        self.doubt.setVisible(bool(src.doubt))
        form.addRow(self.doubt)
        self.units = self._combo(sorted(UNITS), given.get("units"), src.units)
        self.scale = QtWidgets.QLineEdit("" if given.get("scale") is None
                                         else repr(float(given["scale"])))
        self.scale.setPlaceholderText("metres per file unit (overrides the units)")
        mode = given.get("position_mode")
        self.position_mode = self._combo(MODES, mode if isinstance(mode, str) else None, None)
        if character:
            # the axis the figure stands along is offered (a re-import starts from the
            # project's choice)
            suggested = dict(src.overrides).get("up_axis") or None
            self.up_axis = self._combo(AXES, given.get("up_axis", suggested), src.up_axis,
                                       "as the file says")
            form.addRow("Up axis", self.up_axis)
        else:
            form.addRow("Units", self.units)
            form.addRow("Scale", self.scale)
            self.up_axis = self._combo(AXES, given.get("up_axis"), src.up_axis)
            form.addRow("Up axis", self.up_axis)
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
    def _combo(choices, given, detected, first: str = DETECTED) -> QtWidgets.QComboBox:
        combo = QtWidgets.QComboBox()
        combo.addItem(first if detected is None else f"{first} ({detected})", None)
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
