"""The quality panel: where the result is bad, in the figures ``retarget --report`` writes.

The figures are the ``"quality"`` part of a solve's report, made by one engine function
(:func:`engine.correction.quality.quality`); the panel only shows them, it computes nothing.
They come from the document's last solve (Tools > Solve, foot contacts, an edit that solves),
or from **Measure**, which solves the current project as ``motion-composer retarget`` does
(its automatic constraints made again from the project's settings) in the document's job
runner, without changing the scene. Figures shown follow the scene: after an edit that changes
the motion (a pose offset, a chain setting, a key) they are measured again on the motion as
edited, without solving (:meth:`engine.scene.Scene.quality`: no residuals), so the bone
directions show an edit's effect at once; while nothing was measured, nothing is.

Rows, worst first within each group: per constraint its residual (max, mean); per contact the
foot's drift, direct conversion and corrected; per joint its worst angular-speed ratio against
the no-pop limit (above 1 is a pop) and the frame; per mapped bone its largest direction error.
Clicking a row goes to its frame and selects its target joint.

:class:`QualityStrip` draws the per-frame figures (foot slide and the largest metric residual)
on the timeline's frame axis, with the playhead.
"""
from __future__ import annotations

import numpy as np

from motion_composer.app.gui.qt import QtCore, QtGui, QtWidgets

import pyqtgraph as pg  # noqa: E402  (after app.gui.qt chose PySide6)

__all__ = ["QualityPanel", "QualityStrip", "quality_rows"]

#: the groups of rows: report key, title
GROUPS = (("constraints", "Constraints: residual max / mean"),
          ("contacts", "Contacts: drift direct -> corrected"),
          ("pops", "Pops: angular speed / no-pop limit"),
          ("bone_directions", "Bone directions: largest error"))
#: [m -> cm] lengths are shown in centimetres
CM = 100.0


def _length(value) -> str:
    """[m] in centimetres, or in millimetres below one centimetre."""
    if value is None:
        return "-"
    return f"{value * CM:.2f} cm" if abs(value) >= 0.01 else f"{value * 1000:.2f} mm"


def _residual(c: dict) -> str:
    if c["max_residual"] is None:
        return "not solved"
    if c.get("residual_unit") == "rad":
        return (f"{np.degrees(c['max_residual']):.2f} / "
                f"{np.degrees(c['mean_residual']):.2f} deg")
    return f"{_length(c['max_residual'])} / {_length(c['mean_residual'])}"


def quality_rows(quality: dict) -> dict[str, list[tuple[str, str, int | None, str]]]:
    """The panel's rows for ``report["quality"]``: per group, ``(label, figure, frame,
    joint)``, as shown (worst first where the report does not already order them)."""
    rows = {key: [] for key, _title in GROUPS}
    for c in sorted(quality["constraints"], key=lambda c: -(c["max_residual"] or 0.0)):
        rows["constraints"].append((c["name"], _residual(c), c["frame"], c["joint"]))
    for c in sorted(quality["contacts"], key=lambda c: -c["drift_corrected_m"]):
        rows["contacts"].append((f"{c['joint']} {c['part']} {c['start']}-{c['end']}",
                                 f"{_length(c['drift_direct_m'])} -> "
                                 f"{_length(c['drift_corrected_m'])}", c["start"], c["joint"]))
    for p in quality["pops"]:                                # the report's order: worst first
        rows["pops"].append((p["joint"], f"{p['ratio']:.2f} ({p['speed_deg_s']:.0f} / "
                                         f"{p['limit_deg_s']:.0f} deg/s)", p["frame"],
                             p["joint"]))
    for b in sorted(quality["bone_directions"], key=lambda b: -b["max_error_deg"]):
        rows["bone_directions"].append((b["joint"], f"{b['max_error_deg']:.1f} deg",
                                        b["frame"], b["joint"]))
    return rows


class QualityPanel(QtWidgets.QWidget):
    """The quality figures of the document's current motion, as rows to click."""

    #: the figures shown changed (a dict, or None when there are none)
    qualityChanged = QtCore.Signal(object)

    def __init__(self, document, parent=None):
        super().__init__(parent)
        self.doc = document
        self.quality: dict | None = None
        self.status = QtWidgets.QLabel()
        self.status.setWordWrap(True)
        self.measure_button = QtWidgets.QPushButton("Measure")
        self.measure_button.setToolTip("Solve the project as `motion-composer retarget` does "
                                       "and show its report's quality figures (the scene "
                                       "does not change)")
        self.measure_button.clicked.connect(self.measure)
        self.tree = QtWidgets.QTreeWidget()
        self.tree.setColumnCount(3)
        self.tree.setHeaderLabels(["", "figure", "frame"])
        self.tree.setRootIsDecorated(True)
        self.tree.setUniformRowHeights(True)
        self.tree.itemClicked.connect(self._clicked)
        top = QtWidgets.QHBoxLayout()
        top.addWidget(self.status, 1)
        top.addWidget(self.measure_button)
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(4, 4, 4, 4)
        layout.addLayout(top)
        layout.addWidget(self.tree, 1)
        document.solved.connect(lambda: self.show_quality(document.last_quality))
        document.motionChanged.connect(self._motion_changed)
        self.show_quality(None)

    # ------------------------------------------------------------------ figures
    def measure(self) -> None:
        """Solve the current scene as ``retarget`` does, in the job runner, and show its
        report's quality figures."""
        scene = self.doc.scene
        if not scene.ready:
            self.status.setText("Nothing to measure yet: import a performer and a target and "
                                "map them.")
            return

        def work(progress, cancel):
            return scene.solve(regenerate=True, progress=progress, cancel=cancel).report[
                "quality"]
        self.doc.jobs.run("Measuring quality", work, self._measured)

    def _measured(self, quality: dict) -> None:
        self.show_quality(quality)

    def _motion_changed(self) -> None:
        """The figures were of another motion: measure the scene's again (a live preview or
        a solve still running keeps them until its edit lands)."""
        doc = self.doc
        if self.quality is None or doc.pending or doc.motion is not doc.scene.motion:
            return
        self.show_quality(doc.scene.quality(), note="measured after the edit, not solved")

    def show_quality(self, quality: dict | None, note: str = "") -> None:
        """Show ``report["quality"]`` (None: nothing measured for this motion); ``note`` says
        where the figures come from when not from a solve."""
        self.quality = quality
        self.tree.clear()
        if quality is None:
            self.status.setText("Not measured for this motion: Measure, or solve.")
        else:
            rows = quality_rows(quality)
            bold = QtGui.QFont(self.font())
            bold.setBold(True)
            for key, title in GROUPS:
                group = QtWidgets.QTreeWidgetItem([f"{title} ({len(rows[key])})"])
                group.setFont(0, bold)
                group.setFirstColumnSpanned(True)
                self.tree.addTopLevelItem(group)
                for label, figure, frame, joint in rows[key]:
                    item = QtWidgets.QTreeWidgetItem(
                        [label, figure, "" if frame is None else str(frame)])
                    item.setData(0, QtCore.Qt.ItemDataRole.UserRole, (frame, joint))
                    group.addChild(item)
                group.setExpanded(True)
            for column in range(3):
                self.tree.resizeColumnToContents(column)
            slide = max(quality["per_frame"]["foot_slide_m"], default=0.0)
            self.status.setText(f"Largest foot slide {_length(slide)}; "
                                f"{sum(p['ratio'] > 1 for p in quality['pops'])} joints pop"
                                + (f" ({note})." if note else "."))
        self.qualityChanged.emit(quality)

    def rows(self, key: str) -> list[QtWidgets.QTreeWidgetItem]:
        """The tree items of one group (``"constraints"``, ``"contacts"``, ``"pops"``,
        ``"bone_directions"``)."""
        index = [k for k, _t in GROUPS].index(key)
        group = self.tree.topLevelItem(index)
        return [] if group is None else [group.child(i) for i in range(group.childCount())]

    def _clicked(self, item, _column) -> None:
        data = item.data(0, QtCore.Qt.ItemDataRole.UserRole)
        if not data:
            return
        frame, joint = data
        if frame is not None:
            self.doc.set_frame(frame)
        target = self.doc.scene.target
        if target is not None and joint in target.skeleton.index:
            self.doc.select("target", joint)


class QualityStrip(pg.PlotWidget):
    """Foot slide and the largest metric residual per frame [cm], under the timeline: its
    frame axis follows the timeline's (``link``), with the current frame's line."""

    SLIDE = (255, 150, 60)
    RESIDUAL = (120, 190, 255)

    def __init__(self, document, panel: QualityPanel, link: pg.ViewBox | None = None,
                 parent=None):
        super().__init__(parent)
        self.doc = document
        self.setFixedHeight(70)
        self.setBackground(self.palette().color(QtGui.QPalette.ColorRole.Base))
        item = self.getPlotItem()
        item.hideButtons()
        item.setMenuEnabled(False)
        item.setMouseEnabled(x=False, y=False)
        item.getAxis("bottom").setStyle(showValues=False)
        item.setLabel("left", "cm")
        item.getAxis("left").enableAutoSIPrefix(False)
        self.slide = self.plot(pen=pg.mkPen(*self.SLIDE, width=1.5), name="foot slide")
        self.residual = self.plot(pen=pg.mkPen(*self.RESIDUAL, width=1.5),
                                  name="largest residual")
        self.playhead = pg.InfiniteLine(0, angle=90, movable=False,
                                        pen=pg.mkPen(220, 40, 40, width=1.5))
        item.addItem(self.playhead, ignoreBounds=True)
        item.addLegend(offset=(4, 2), labelTextSize="7pt")
        if link is not None:
            self.setXLink(link)
        panel.qualityChanged.connect(self.show_quality)
        document.frameChanged.connect(self.playhead.setValue)
        self.show_quality(panel.quality)

    def show_quality(self, quality: dict | None) -> None:
        """The per-frame figures of ``quality`` (hidden when there are none)."""
        self.setVisible(quality is not None)
        if quality is None:
            return
        per = quality["per_frame"]
        frames = np.arange(len(per["foot_slide_m"]))
        self.slide.setData(frames, np.asarray(per["foot_slide_m"]) * CM)
        self.residual.setData(frames, np.asarray(per["max_residual_m"]) * CM)
        self.playhead.setValue(self.doc.scene.viewer.current_frame)
