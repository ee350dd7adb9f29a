"""File > Export's options: a frame range, an output frame rate and rotation-only BVH channels.

The dialog only collects the choices; :func:`engine.motion.export_selection` applies (and
checks) them and :func:`engine.formats.write_motion` writes.
"""
from __future__ import annotations

from dataclasses import dataclass

from motion_composer.engine.motion import MAX_FPS, Motion

from .qt import QtWidgets

#: digits of the frame-rate field
FPS_DECIMALS = 3


@dataclass(frozen=True)
class ExportOptions:
    """What File > Export writes.

    Attributes:
        frames: ``(first, last)`` inclusive, 0-based; ``None``: every frame.
        fps: the output frame rate [1/s]; ``None``: the motion's own.
        channels: ``"all"`` or ``"rotation"`` (BVH: rotation channels only below the root).
    """

    frames: tuple[int, int] | None = None
    fps: float | None = None
    channels: str = "all"


class ExportOptionsDialog(QtWidgets.QDialog):
    """A small form: first and last frame, frames per second, rotation channels only."""

    def __init__(self, motion: Motion, parent=None):
        super().__init__(parent)
        self.setWindowTitle("Export options")
        self._frames = motion.num_frames
        self._fps = round(motion.fps, FPS_DECIMALS)
        last = max(motion.num_frames - 1, 0)
        self.first = QtWidgets.QSpinBox()
        self.first.setObjectName("first_frame")
        self.first.setRange(0, last)
        self.last = QtWidgets.QSpinBox()
        self.last.setObjectName("last_frame")
        self.last.setRange(0, last)
        self.last.setValue(last)
        self.fps = QtWidgets.QDoubleSpinBox()
        self.fps.setObjectName("fps")
        self.fps.setDecimals(FPS_DECIMALS)
        self.fps.setRange(10.0 ** -FPS_DECIMALS, MAX_FPS)
        self.fps.setValue(self._fps)
        self.fps.setSuffix(" fps")
        self.rotation_only = QtWidgets.QCheckBox("Rotation channels only below the root (BVH)")
        self.rotation_only.setObjectName("rotation_only")
        form = QtWidgets.QFormLayout()
        form.addRow("First frame", self.first)
        form.addRow("Last frame", self.last)
        form.addRow("Frame rate", self.fps)
        form.addRow(self.rotation_only)
        buttons = QtWidgets.QDialogButtonBox(QtWidgets.QDialogButtonBox.StandardButton.Ok |
                                             QtWidgets.QDialogButtonBox.StandardButton.Cancel)
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        self.buttons = buttons
        layout = QtWidgets.QVBoxLayout(self)
        layout.addLayout(form)
        layout.addWidget(buttons)

    def options(self) -> ExportOptions:
        """The choices; a field left as it was asks for no change (the whole clip, its rate,
        its channels)."""
        first, last = self.first.value(), self.last.value()
        frames = None if (first, last) == (0, max(self._frames - 1, 0)) else (first, last)
        fps = None if self.fps.value() == self._fps else self.fps.value()
        return ExportOptions(frames, fps, "rotation" if self.rotation_only.isChecked() else "all")
