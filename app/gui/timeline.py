"""The constraint timeline: one row per constraint with its four time handles, a playhead,
add / delete / duplicate.

Built from a :class:`~app.gui.document.Document` and wired both ways: the document's signals
update the rows and move the playhead without feeding back (blocked signals, a guard flag
for the playhead, whose label follows its own signal); the widgets change the
document only through :func:`~app.gui.commands.push_constraints` (through the live solver's
final solve) and ``doc.set_frame`` (viewer state, not undoable).

The plot (pyqtgraph, 2D only):

* x is frames; the bottom axis counts frames, the top one shows seconds from the performer's
  exact frame time and is a ruler: click or drag on it to scrub. The wheel zooms x about the
  pointer, a drag on empty space pans x; y never zooms: rows keep a fixed height, the scroll
  bar, Shift+wheel or the wheel over the row names scroll them.
* each row (:class:`ConstraintRow`, one ``GraphicsObject`` per constraint, as pyqtgraph's
  ``CustomGraphItem`` example does for many keys on one curve) draws the input and output
  ramps as lighter hatched wedges and the active range as a solid bar: blue for manual
  constraints, green for automatic ones (contacts, floor), grey when disabled. Its four
  handles (smooth_in, start, end, smooth_out) drag; a handle cannot cross its neighbours (it
  clamps), dragging the bar moves the whole range. Where handles coincide, the drag direction
  picks the one that can move. While dragging the live solver previews the motion; release
  pushes one command ("Move start of contact LeftFoot 32-91 to 28"); a right click during the
  drag cancels it.
* the playhead is an ``InfiniteLine`` kept equal to ``doc.scene.viewer.current_frame`` both ways.
* a click on a row selects its constraint (``selected_index``, ``constraintSelected``) and its
  joint in the document (the viewport highlights it).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from motion_composer.app.gui.qt import (QtCore, QtGui,  # noqa: F401  (Qt set up before pyqtgraph)
                                        QtWidgets)

import pyqtgraph as pg  # noqa: E402

from motion_composer.app.gui.live import live_solver  # noqa: E402
from motion_composer.engine.correction.preview import retimed  # noqa: E402
from motion_composer.engine.correction.constraints import Constraint, ConstraintError  # noqa: E402

__all__ = ["ConstraintTimeline", "ConstraintRow", "FIELDS", "moved_range", "retimed",
           "row_label", "COLORS"]

Qt = QtCore.Qt

#: the four time fields, in order
FIELDS = ("smooth_in", "start", "end", "smooth_out")
_FIELD_WORDS = {"smooth_in": "smooth-in", "start": "start", "end": "end",
                "smooth_out": "smooth-out"}
#: pixels per row, bar half-height as a fraction of a row, handle width and grab distance
ROW_PX = 26
BAR_HALF = 0.32
HANDLE_PX = 6
GRAB_PX = 7
#: row names longer than this are elided in the middle
LABEL_MAX_PX = 230
#: fill colours: manual, automatic, disabled
COLORS = {"manual": QtGui.QColor(61, 125, 216), "auto": QtGui.QColor(40, 150, 100),
          "disabled": QtGui.QColor(160, 160, 160)}
#: frames around the current one covered by a new constraint: ramps, then active
ADD_RAMP, ADD_HALF = 10, 5


# ====================================================================== pure helpers
def row_label(c: Constraint) -> str:
    return c.name or c.joint


def moved_range(rng: tuple, which: str, value: int, last: int) -> tuple[int, int, int, int]:
    """The range ``rng`` after moving handle ``which`` to frame ``value`` (``"all"``: the
    whole range by ``value`` frames), clamped: a handle stays between its neighbours, the
    range within ``[0, last]``."""
    si, st, en, so = (int(v) for v in rng)
    value = int(value)
    if which == "smooth_in":
        si = min(max(value, 0), st)
    elif which == "start":
        st = min(max(value, si), en)
    elif which == "end":
        en = min(max(value, st), so)
    elif which == "smooth_out":
        so = min(max(value, en), last)
    elif which == "all":
        d = min(max(value, -si), last - so)
        si, st, en, so = si + d, st + d, en + d, so + d
    else:
        raise ValueError(f"unknown handle {which!r}")
    return si, st, en, so


def describe_move(c: Constraint, which: str, rng: tuple) -> str:
    """The undo text of a handle drag."""
    label = row_label(c)
    if which == "all":
        return f"Move {label} to {rng[1]}-{rng[2]}"
    return f"Move {_FIELD_WORDS[which]} of {label} to {rng[FIELDS.index(which)]}"


def _unique_name(base: str, taken) -> str:
    taken = set(taken)
    if base not in taken:
        return base
    k = 2
    while f"{base} {k}" in taken:
        k += 1
    return f"{base} {k}"


# ====================================================================== plot items
class ConstraintRow(pg.GraphicsObject):
    """One constraint's row: ramps, active bar and four draggable handles.

    Drawn in device pixels (crisp handles of a fixed width at any zoom); the item's
    coordinates are the plot's (x frames, y row index, row ``i`` centred on ``y = i``).
    """

    def __init__(self, timeline: "ConstraintTimeline", index: int, constraint: Constraint):
        super().__init__()
        self.timeline = timeline
        self.index = index
        self.constraint = constraint
        self.range = constraint.range
        self.selected = False
        self.hover: str | None = None
        self.dragging: str | None = None
        self._grab = 0.0                   # handle value minus the pointer's frame at press
        self.setAcceptHoverEvents(True)
        self.setZValue(20)

    # ------------------------------------------------------------------ model
    def set_constraint(self, index: int, constraint: Constraint) -> None:
        self.prepareGeometryChange()
        self.index = index
        self.constraint = constraint
        self.range = constraint.range
        self.update()

    def set_range(self, rng) -> None:
        self.prepareGeometryChange()
        self.range = tuple(int(v) for v in rng)
        self.update()

    def set_selected(self, on: bool) -> None:
        if on != self.selected:
            self.selected = on
            self.update()

    @property
    def auto(self) -> bool:
        return self.constraint.auto

    @property
    def color(self) -> QtGui.QColor:
        if not self.constraint.enabled:
            return COLORS["disabled"]
        return COLORS["auto" if self.constraint.auto else "manual"]

    def handle_positions(self) -> dict:
        return dict(zip(FIELDS, self.range))

    # ------------------------------------------------------------------ geometry
    def _px(self) -> float:
        """Frames per device pixel."""
        px = self.pixelWidth()
        return px if px and np.isfinite(px) else 1.0

    def boundingRect(self) -> QtCore.QRectF:   # noqa: N802 - Qt's name
        pad = (GRAB_PX + 2) * self._px()
        si, _st, _en, so = self.range
        return QtCore.QRectF(si - pad, self.index - 0.5, so - si + 2 * pad, 1.0)

    def viewTransformChanged(self) -> None:    # noqa: N802 - pyqtgraph's name
        self.prepareGeometryChange()
        super().viewTransformChanged()

    def pick(self, pos: QtCore.QPointF, direction: int = 0) -> str | None:
        """The handle (or ``"all"`` for the bar's body) under ``pos`` (item coordinates);
        where handles coincide, the one that can move in ``direction`` (-1 left, +1 right)."""
        if abs(pos.y() - self.index) > 0.5:
            return None
        px = self._px()
        dist = [abs(pos.x() - v) / px for v in self.range]
        nearest = int(np.argmin(dist))
        if dist[nearest] <= GRAB_PX:
            # coincident handles: only the first can move left, only the last right
            same = [i for i in range(4) if self.range[i] == self.range[nearest]]
            i = same[0] if direction < 0 else same[-1] if direction > 0 else nearest
            return FIELDS[i]
        si, st, en, so = self.range
        if st <= pos.x() <= en and abs(pos.y() - self.index) <= BAR_HALF:
            return "all"
        return None

    # ------------------------------------------------------------------ drawing
    def paint(self, p: QtGui.QPainter, *_args) -> None:
        tr = p.transform()
        si, st, en, so = self.range
        xs = [tr.map(QtCore.QPointF(v, 0.0)).x() for v in (si, st, en, so)]
        ya = tr.map(QtCore.QPointF(0.0, self.index - BAR_HALF)).y()
        yb = tr.map(QtCore.QPointF(0.0, self.index + BAR_HALF)).y()
        top, bottom = min(ya, yb), max(ya, yb)
        x_si, x_st, x_en, x_so = xs
        if x_en - x_st < 2:                   # a one-frame range still shows
            mid = (x_st + x_en) / 2
            x_st, x_en = mid - 1, mid + 1
        color = self.color
        dark = color.darker(150)
        light = QtGui.QColor(color)
        light.setAlpha(70)

        p.save()
        p.resetTransform()
        p.setRenderHint(QtGui.QPainter.RenderHint.Antialiasing, True)
        # ramps: wedges rising towards the active range, light fill plus hatching
        hatch = QtGui.QBrush(dark, Qt.BrushStyle.BDiagPattern)
        for poly in (
                QtGui.QPolygonF([QtCore.QPointF(x_si, bottom), QtCore.QPointF(x_st, top),
                                 QtCore.QPointF(x_st, bottom)]),
                QtGui.QPolygonF([QtCore.QPointF(x_en, top), QtCore.QPointF(x_so, bottom),
                                 QtCore.QPointF(x_en, bottom)])):
            p.setPen(QtGui.QPen(dark, 1))
            p.setBrush(light)
            p.drawPolygon(poly)
            p.setPen(Qt.PenStyle.NoPen)
            p.setBrush(hatch)
            p.drawPolygon(poly)
        # active range
        bar = QtCore.QRectF(x_st, top, x_en - x_st, bottom - top)
        p.setPen(QtGui.QPen(QtGui.QColor(20, 20, 20) if self.selected else dark,
                            2 if self.selected else 1))
        p.setBrush(color if self.dragging != "all" else color.lighter(115))
        p.drawRoundedRect(bar, 2, 2)
        text = f"{st}\u2013{en}"
        fm = QtGui.QFontMetrics(p.font())
        if fm.horizontalAdvance(text) + 10 < bar.width() and bar.height() >= fm.height() - 2:
            p.setPen(QtGui.QColor(255, 255, 255))
            p.drawText(bar, int(Qt.AlignmentFlag.AlignCenter), text)
        # handles: start/end full height, smooth ones a lower half-height grip
        for name, x in zip(FIELDS, (x_si, xs[1], xs[2], x_so)):
            inner = name in ("start", "end")
            h_top = top - 2 if inner else (top + bottom) / 2
            rect = QtCore.QRectF(x - HANDLE_PX / 2, h_top, HANDLE_PX, bottom + 2 - h_top)
            hot = name in (self.hover, self.dragging)
            fill = QtGui.QColor(255, 200, 40) if hot else (
                QtGui.QColor(30, 30, 30) if inner else QtGui.QColor(250, 250, 250))
            p.setPen(QtGui.QPen(QtGui.QColor(30, 30, 30), 1))
            p.setBrush(fill)
            p.drawRoundedRect(rect, 1.5, 1.5)
        p.restore()

    # ------------------------------------------------------------------ mouse
    def hoverEvent(self, ev) -> None:          # noqa: N802 - pyqtgraph's name
        which = None if ev.isExit() else self.pick(ev.pos())
        if which is not None and ev.acceptDrags(Qt.MouseButton.LeftButton):
            self.setCursor(Qt.CursorShape.SizeHorCursor if which != "all"
                           else Qt.CursorShape.OpenHandCursor)
        else:
            which = None
            self.unsetCursor()
        if which != self.hover:
            self.hover = which
            self.update()

    def mouseDragEvent(self, ev) -> None:      # noqa: N802 - pyqtgraph's name
        if ev.button() != Qt.MouseButton.LeftButton:
            ev.ignore()
            return
        if ev.isStart():
            down = ev.buttonDownPos()
            dx = ev.pos().x() - down.x()
            which = self.pick(down, int(np.sign(dx)))
            if which is None or not self.timeline.drag_started(self, which):
                ev.ignore()
                return
            self.dragging = which
            self._grab = 0.0 if which == "all" else \
                self.range[FIELDS.index(which)] - down.x()
            self.update()
        ev.accept()
        if self.dragging is None:              # cancelled by a right click: wait for release
            return
        if self.dragging == "all":
            value = int(round(ev.pos().x() - ev.buttonDownPos().x()))
        else:
            value = int(round(ev.pos().x() + self._grab))
        self.timeline.drag_moved(self, self.dragging, value)
        if ev.isFinish():
            which, self.dragging = self.dragging, None
            self.update()
            self.timeline.drag_finished(self, which)

    def mouseClickEvent(self, ev) -> None:     # noqa: N802 - pyqtgraph's name
        if self.dragging is not None and ev.button() == Qt.MouseButton.RightButton:
            ev.accept()
            self.dragging = None
            self.update()
            self.timeline.drag_cancelled(self)
        else:
            ev.ignore()


class _RowBackground(pg.GraphicsObject):
    """Alternate row shading and the selected row's highlight, across the whole width."""

    def __init__(self, timeline: "ConstraintTimeline"):
        super().__init__()
        self.timeline = timeline
        self.setZValue(-10)

    def boundingRect(self) -> QtCore.QRectF:   # noqa: N802 - Qt's name
        n = max(len(self.timeline.rows), 1)
        return QtCore.QRectF(-1e7, -0.5, 2e7, n)

    def paint(self, p, *_args) -> None:
        tr = p.transform()
        pal = self.timeline.palette()
        base = pal.color(QtGui.QPalette.ColorRole.Base)
        alt = pal.color(QtGui.QPalette.ColorRole.AlternateBase)
        sel = QtGui.QColor(pal.color(QtGui.QPalette.ColorRole.Highlight))
        sel.setAlpha(60)
        width = p.device().width() if p.device() is not None else 10000
        p.save()
        p.resetTransform()
        for i, _row in enumerate(self.timeline.rows):
            ya = tr.map(QtCore.QPointF(0.0, i - 0.5)).y()
            yb = tr.map(QtCore.QPointF(0.0, i + 0.5)).y()
            rect = QtCore.QRectF(0, min(ya, yb), width, abs(yb - ya))
            p.fillRect(rect, alt if i % 2 else base)
            if i == self.timeline.selected_index:
                p.fillRect(rect, sel)
        p.restore()


class _RowAxis(pg.AxisItem):
    """Row names on the left, coloured like the rows (manual, automatic, disabled)."""

    def __init__(self, timeline: "ConstraintTimeline"):
        super().__init__("left")
        self.timeline = timeline
        self.setStyle(tickLength=0, autoExpandTextSpace=False)

    def tickValues(self, minVal, maxVal, size):   # noqa: N802,N803 - pyqtgraph's names
        n = len(self.timeline.rows)
        minVal, maxVal = sorted((minVal, maxVal))
        lo, hi = max(int(np.ceil(minVal)), 0), min(int(np.floor(maxVal)), n - 1)
        return [(1.0, list(range(lo, hi + 1)))]

    def tickStrings(self, values, scale, spacing):   # noqa: N802 - pyqtgraph's name
        rows = self.timeline.rows
        return [self.timeline.label_of(int(v)) if 0 <= int(v) < len(rows) else ""
                for v in values]

    def drawPicture(self, p, axisSpec, tickSpecs, textSpecs):   # noqa: N802,N803
        super().drawPicture(p, axisSpec, tickSpecs, [])
        colours = self.timeline.label_colours()
        if self.style["tickFont"] is not None:
            p.setFont(self.style["tickFont"])
        for rect, flags, text in textSpecs:
            colour, bold = colours.get(text, (self.textPen().color(), False))
            font = p.font()
            font.setBold(bold)
            p.setFont(font)
            p.setPen(colour)
            p.drawText(rect, int(flags), text)


class _SecondsAxis(pg.AxisItem):
    """Seconds at nice values, placed on the frame axis with the exact frame time; a ruler:
    a click or a drag on it moves the current frame."""

    def __init__(self, timeline: "ConstraintTimeline"):
        super().__init__("top")
        self.timeline = timeline

    def _ft(self) -> float:
        return self.timeline.frame_time or 1.0

    def tickValues(self, minVal, maxVal, size):   # noqa: N802,N803
        ft = self._ft()
        minVal, maxVal = sorted((minVal, maxVal))
        levels = super().tickValues(minVal * ft, maxVal * ft, size)
        return [(spacing / ft, [v / ft for v in values]) for spacing, values in levels]

    def tickStrings(self, values, scale, spacing):   # noqa: N802
        step = spacing * self._ft()
        decimals = max(0, int(np.ceil(-np.log10(step) - 1e-9))) if step > 0 else 0
        return [f"{v * self._ft():.{decimals}f}" for v in values]

    def _scrub(self, scene_pos) -> None:
        view = self.linkedView()
        if view is not None:
            self.timeline.scrub_to(view.mapSceneToView(scene_pos).x())

    def mouseClickEvent(self, ev):   # noqa: N802
        if ev.button() == Qt.MouseButton.LeftButton:
            ev.accept()
            self._scrub(ev.scenePos())

    def mouseDragEvent(self, ev):    # noqa: N802
        if ev.button() == Qt.MouseButton.LeftButton:
            ev.accept()
            self._scrub(ev.scenePos())
        else:
            ev.ignore()


class _Playhead(pg.InfiniteLine):
    """The current frame. It yields to a row's handle or bar under the pointer, so that a
    handle at the current frame can still be grabbed (grab the line in an empty stretch of a
    row, or click or drag on the seconds ruler)."""

    def __init__(self, timeline: "ConstraintTimeline"):
        super().__init__(pos=0, angle=90, movable=True,
                         pen=pg.mkPen(QtGui.QColor(220, 40, 40), width=2),
                         hoverPen=pg.mkPen(QtGui.QColor(255, 120, 60), width=3),
                         label="{value:.0f}",
                         labelOpts={"position": 0.985, "color": (200, 30, 30),
                                    "fill": (255, 255, 255, 220), "anchors": [(0, 1), (0, 1)]})
        self.timeline = timeline
        self.setZValue(30)

    def hoverEvent(self, ev):    # noqa: N802
        if not ev.isExit() and self.timeline.row_handle_at(ev.scenePos()):
            self.setMouseHover(False)
            return
        super().hoverEvent(ev)

    def mouseDragEvent(self, ev):    # noqa: N802
        if ev.isStart() and self.timeline.row_handle_at(ev.buttonDownScenePos()):
            ev.ignore()
            return
        super().mouseDragEvent(ev)


class _TimelineView(pg.ViewBox):
    """x zooms and pans with the mouse, y scrolls rows; a click selects the row under it."""

    def __init__(self, timeline: "ConstraintTimeline"):
        super().__init__(enableMenu=False)
        self.timeline = timeline
        self.setMouseEnabled(x=True, y=False)
        self.invertY(True)

    def wheelEvent(self, ev, axis=None):   # noqa: N802
        if axis == 1 or ev.modifiers() & Qt.KeyboardModifier.ShiftModifier:
            self.timeline.scroll_rows(-1 if ev.delta() > 0 else 1)
            ev.accept()
            return
        super().wheelEvent(ev, axis=0)

    def mouseClickEvent(self, ev):   # noqa: N802
        pos = self.mapSceneToView(ev.scenePos())
        row = int(np.floor(pos.y() + 0.5))
        if ev.button() == Qt.MouseButton.LeftButton:
            ev.accept()
            self.timeline.select(row if 0 <= row < len(self.timeline.rows) else None)
        elif ev.button() == Qt.MouseButton.RightButton and 0 <= row < len(self.timeline.rows):
            ev.accept()
            self.timeline.select(row)
            self.timeline.context_menu(ev.screenPos().toPoint())
        else:
            ev.ignore()


# ====================================================================== the widget
class ConstraintTimeline(QtWidgets.QWidget):
    """Rows of constraints over time, with a playhead; edits are undoable commands.

    Signals: ``constraintSelected(int)`` (-1 for none).
    Attributes: ``selected_index`` (``None`` for none), ``rows`` (:class:`ConstraintRow`),
    ``playhead``, ``plot``, ``view``, ``live`` (the document's :class:`LiveSolver`).
    """

    constraintSelected = QtCore.Signal(int)

    def __init__(self, document, parent=None):
        super().__init__(parent)
        self.doc = document
        self.live = live_solver(document)
        self.rows: list[ConstraintRow] = []
        self.selected_index: int | None = None
        self._drag: dict | None = None
        self._num_frames = 0
        self._following = False          # the playhead is being set from the document
        self._labels: list[str] = []     # row names as shown (elided)
        self._build()
        self.doc.constraintsChanged.connect(self.refresh)
        self.doc.sourcesChanged.connect(self._sources_changed)
        self.doc.frameChanged.connect(self._frame_changed)
        self.doc.selectionChanged.connect(self._joint_selected)
        self.live.previewShown.connect(self._preview_shown)
        self._sources_changed()

    # ------------------------------------------------------------------ building
    def _build(self) -> None:
        self.add_button = self._tool("Add", "list-add",
                                     "Add a position constraint on the selected target joint "
                                     "at the current frame", self.add_constraint)
        self.delete_button = self._tool("Delete", "list-remove",
                                        "Delete the selected constraint", self.delete_selected)
        self.duplicate_button = self._tool("Duplicate", "edit-copy",
                                           "Duplicate the selected constraint",
                                           self.duplicate_selected)
        self.fit_button = self._tool("Fit", "zoom-fit-best", "Show the whole clip",
                                     self.fit)
        self.status = QtWidgets.QLabel()
        self.status.setTextFormat(Qt.TextFormat.PlainText)
        self.status.setMinimumWidth(120)
        bar = QtWidgets.QHBoxLayout()
        bar.setContentsMargins(4, 2, 4, 0)
        bar.setSpacing(4)
        for b in (self.add_button, self.delete_button, self.duplicate_button):
            bar.addWidget(b)
        bar.addSpacing(8)
        bar.addWidget(self.fit_button)
        bar.addSpacing(12)
        for key, text in (("manual", "manual"), ("auto", "automatic"),
                          ("disabled", "disabled")):
            bar.addWidget(self._swatch(COLORS[key], text))
        bar.addStretch(1)
        bar.addWidget(self.status)

        self.view = _TimelineView(self)
        self.row_axis = _RowAxis(self)
        self.seconds_axis = _SecondsAxis(self)
        frames_axis = pg.AxisItem("bottom")
        self.plot = pg.PlotWidget(viewBox=self.view,
                                  axisItems={"left": self.row_axis, "top": self.seconds_axis,
                                             "bottom": frames_axis})
        pal = self.palette()
        self.plot.setBackground(pal.color(QtGui.QPalette.ColorRole.Base))
        text_pen = pg.mkPen(pal.color(QtGui.QPalette.ColorRole.Text))
        for name in ("left", "top", "bottom"):
            axis = self.plot.getPlotItem().getAxis(name)
            axis.setTextPen(text_pen)
            axis.setPen(pg.mkPen(pal.color(QtGui.QPalette.ColorRole.Mid)))
        self.plot.getPlotItem().showAxis("top")
        self.plot.setLabel("bottom", "frame")
        self.plot.setLabel("top", "seconds")
        self.plot.getPlotItem().hideButtons()
        self.plot.setMinimumHeight(4 * ROW_PX + 80)
        self.background = _RowBackground(self)
        self.view.addItem(self.background, ignoreBounds=True)
        self.playhead = _Playhead(self)
        self.view.addItem(self.playhead, ignoreBounds=True)
        self.playhead.sigPositionChanged.connect(self._playhead_moved)
        self.view.sigResized.connect(self._layout_rows)

        self.scrollbar = QtWidgets.QScrollBar(Qt.Orientation.Vertical)
        self.scrollbar.setRange(0, 0)
        self.scrollbar.valueChanged.connect(self._layout_rows)
        body = QtWidgets.QHBoxLayout()
        body.setContentsMargins(0, 0, 0, 0)
        body.setSpacing(0)
        body.addWidget(self.plot, 1)
        body.addWidget(self.scrollbar)
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(2)
        layout.addLayout(bar)
        layout.addLayout(body, 1)

    def _tool(self, text, icon, tip, slot) -> QtWidgets.QToolButton:
        button = QtWidgets.QToolButton()
        button.setText(text)
        button.setIcon(QtGui.QIcon.fromTheme(icon))
        button.setToolButtonStyle(Qt.ToolButtonStyle.ToolButtonTextBesideIcon)
        button.setToolTip(tip)
        button.setAutoRaise(True)
        button.clicked.connect(lambda _checked=False: slot())
        return button

    @staticmethod
    def _swatch(colour: QtGui.QColor, text: str) -> QtWidgets.QLabel:
        label = QtWidgets.QLabel(f'<span style="color:{colour.name()}">\u25a0</span> {text}')
        label.setToolTip(f"{text} constraints")
        return label

    # ------------------------------------------------------------------ model -> widget
    @property
    def frame_time(self) -> float | None:
        p = self.doc.scene.performer
        return p.frame_time if p is not None else None

    def _sources_changed(self) -> None:
        n = self.doc.scene.num_frames
        last = max(n - 1, 1)
        self.playhead.setBounds((0, last))
        self.view.setLimits(xMin=-0.02 * last - 2, xMax=last * 1.02 + 2, minXRange=8)
        if n != self._num_frames:
            self._num_frames = n
            self.fit()
        self.refresh()
        self._frame_changed(self.doc.scene.viewer.current_frame)

    def refresh(self) -> None:
        """Rows from ``doc.scene.constraints`` (existing row items are reused)."""
        if self._drag is not None:             # the model changed under a drag: drop it
            self._end_drag()
            self.live.cancel()
        constraints = self.doc.scene.constraints
        for i, c in enumerate(constraints):
            if i < len(self.rows):
                self.rows[i].set_constraint(i, c)
            else:
                row = ConstraintRow(self, i, c)
                self.view.addItem(row, ignoreBounds=True)
                self.rows.append(row)
        for row in self.rows[len(constraints):]:
            self.view.removeItem(row)
        del self.rows[len(constraints):]
        index = self.selected_index
        if index is not None and index >= len(constraints):
            index = len(constraints) - 1 if constraints else None
        self._set_selected(index, emit=index != self.selected_index)
        self._fit_label_width()
        self._layout_rows()
        self.background.prepareGeometryChange()
        self.background.update()
        self.row_axis.picture = None
        self.row_axis.update()
        self._update_buttons()

    def _frame_changed(self, frame: int) -> None:
        # no QSignalBlocker here: the line's own label follows sigPositionChanged
        self._following = True
        try:
            self.playhead.setValue(frame)
        finally:
            self._following = False

    def _fit_label_width(self) -> None:
        """Row names, elided in the middle beyond ``LABEL_MAX_PX``; the axis as wide as the
        widest (bold: the selected row's name is bold)."""
        bold = QtGui.QFont(self.row_axis.style["tickFont"] or self.font())
        bold.setBold(True)
        fm = QtGui.QFontMetrics(bold)
        self._labels = [fm.elidedText(row_label(r.constraint), Qt.TextElideMode.ElideMiddle,
                                      LABEL_MAX_PX) for r in self.rows]
        widths = [fm.horizontalAdvance(t) for t in self._labels]
        self.row_axis.setWidth(int(max(widths + [fm.horizontalAdvance("constraint")]) + 16))

    def label_of(self, i: int) -> str:
        """Row ``i``'s name as shown."""
        return self._labels[i] if i < len(self._labels) else row_label(self.rows[i].constraint)

    def label_colours(self) -> dict:
        out = {}
        for row in self.rows:
            colour = row.color.darker(130) if row.constraint.enabled else row.color
            out[self.label_of(row.index)] = (colour, row.selected)
        return out

    # ------------------------------------------------------------------ view
    def visible_rows(self) -> float:
        h = self.view.height()
        return max(h / ROW_PX, 1.0) if h > 0 else 8.0

    def _layout_rows(self, *_args) -> None:
        n = len(self.rows)
        visible = self.visible_rows()
        top_max = max(int(np.ceil(n - visible)), 0)
        blocked = self.scrollbar.blockSignals(True)
        try:
            self.scrollbar.setRange(0, top_max)
            self.scrollbar.setPageStep(max(int(visible), 1))
        finally:
            self.scrollbar.blockSignals(blocked)
        top = self.scrollbar.value()
        self.view.setYRange(top - 0.5, top - 0.5 + visible, padding=0)

    def scroll_rows(self, step: int) -> None:
        self.scrollbar.setValue(self.scrollbar.value() + step)

    def ensure_visible(self, row: int) -> None:
        visible = int(self.visible_rows())
        top = self.scrollbar.value()
        if row < top:
            self.scrollbar.setValue(row)
        elif row >= top + visible:
            self.scrollbar.setValue(row - visible + 1)

    def fit(self) -> None:
        last = max(self.doc.scene.num_frames - 1, 1)
        self.view.setXRange(0, last, padding=0.01)

    def frame_to_pixel(self, frame: float, row: float) -> QtCore.QPoint:
        """Widget pixel (in ``plot.viewport()``) of a frame on a row: for tests and tools."""
        scene = self.view.mapViewToScene(QtCore.QPointF(frame, row))
        return self.plot.mapFromScene(scene)

    def row_handle_at(self, scene_pos) -> bool:
        """Whether a row's handle or bar is under a scene position."""
        for row in self.rows:
            if row.pick(row.mapFromScene(scene_pos)) is not None:
                return True
        return False

    # ------------------------------------------------------------------ selection
    def select(self, index: int | None) -> None:
        """Select constraint ``index`` (``None``: none) and its joint in the document."""
        if index is not None and not 0 <= index < len(self.rows):
            index = None
        changed = index != self.selected_index
        self._set_selected(index, emit=changed)
        if index is not None:
            self.ensure_visible(index)
            self.doc.select("target", self.rows[index].constraint.joint)

    def _set_selected(self, index: int | None, emit: bool) -> None:
        self.selected_index = index
        for row in self.rows:
            row.set_selected(row.index == index)
        self.background.update()
        self.row_axis.picture = None
        self.row_axis.update()
        self._update_buttons()
        if emit:
            self.constraintSelected.emit(-1 if index is None else index)

    @property
    def selected(self) -> Constraint | None:
        i = self.selected_index
        return self.doc.scene.constraints[i] if i is not None and i < len(self.doc.scene.constraints) \
            else None

    def _joint_selected(self, _side: str, _joint: str) -> None:
        self._update_buttons()

    def _update_buttons(self) -> None:
        has = self.selected is not None
        self.delete_button.setEnabled(has)
        self.duplicate_button.setEnabled(has)
        side, joint = self.doc.selection
        ok = self.doc.scene.ready and side == "target" and bool(joint)
        self.add_button.setEnabled(ok)
        self.add_button.setToolTip(
            f"Add a position constraint on {joint} at the current frame" if ok else
            "Select a joint of the target (in the viewport) to add a constraint on it")

    # ------------------------------------------------------------------ playhead
    def _playhead_moved(self) -> None:
        if self._following:
            return
        frame = int(round(self.playhead.value()))
        if abs(self.playhead.value() - frame) > 1e-9:      # snap to whole frames
            self._following = True
            try:
                self.playhead.setValue(frame)
            finally:
                self._following = False
        self.doc.set_frame(frame)

    def scrub_to(self, x: float) -> None:
        self.doc.set_frame(int(round(x)))

    # ------------------------------------------------------------------ dragging
    def drag_started(self, row: ConstraintRow, which: str) -> bool:
        self.live.settle()                       # a previewed inspector edit commits first
        if self._drag is not None or self.live.active or \
                row.index >= len(self.doc.scene.constraints):
            return False
        self.select(row.index)
        original = self.doc.scene.constraints[row.index]
        self._drag = {"index": row.index, "which": which, "original": original,
                      "constraints": list(self.doc.scene.constraints), "row": row}
        self.live.begin()
        return True

    def _dragged(self, which: str, value: int):
        d = self._drag
        c = d["original"]
        rng = moved_range(c.range, which, value, max(self.doc.scene.num_frames - 1, 0))
        shift = rng[0] - c.smooth_in if which == "all" else None
        new = retimed(c, rng, shift)
        constraints = list(d["constraints"])
        constraints[d["index"]] = new
        return rng, constraints

    def drag_moved(self, row: ConstraintRow, which: str, value: int) -> None:
        if self._drag is None or self._drag["row"] is not row:
            return
        try:
            rng, constraints = self._dragged(which, value)
        except ConstraintError:
            return
        if rng == row.range:
            return
        row.set_range(rng)
        ft = self.frame_time or 0.0
        frame = rng[1] if which == "all" else rng[FIELDS.index(which)]
        self.status.setText(f"{_FIELD_WORDS.get(which, 'range')} {frame} "
                            f"({frame * ft:.3f} s)")
        self.live.request(constraints)

    def drag_finished(self, row: ConstraintRow, which: str) -> None:
        if self._drag is None or self._drag["row"] is not row:
            return
        original = self._drag["original"]
        rng = row.range
        try:
            _rng, constraints = self._dragged(which, self._value_for(which, rng, original))
        except ConstraintError as exc:
            self.drag_cancelled(row)
            self.doc.errorRaised.emit(str(exc))
            return
        self._end_drag()
        if rng == original.range:
            self.live.cancel()
            return
        self.live.commit(constraints, describe_move(original, which, rng))

    @staticmethod
    def _value_for(which: str, rng, original) -> int:
        return rng[0] - original.smooth_in if which == "all" else rng[FIELDS.index(which)]

    def drag_cancelled(self, row: ConstraintRow) -> None:
        if self._drag is None:
            return
        original = self._drag["original"]
        self._end_drag()
        row.set_range(original.range)
        self.live.cancel()
        self.status.setText("drag cancelled")

    def _end_drag(self) -> None:
        if self._drag is not None:
            row = self._drag["row"]
            row.dragging = None
            row.update()
        self._drag = None

    def cancel_drag(self) -> None:
        """Cancel a drag in progress (as a right click does)."""
        if self._drag is not None:
            self.drag_cancelled(self._drag["row"])

    def _preview_shown(self, seconds: float) -> None:
        if self._drag is not None:
            mode = self.live.modes[-1] if self.live.modes else ""
            self.status.setText(f"{self.status.text().split('  ')[0]}  preview "
                                f"{seconds * 1000:.0f} ms ({mode})")

    # ------------------------------------------------------------------ add, delete, duplicate
    def add_constraint(self, joint: str | None = None) -> None:
        """A position constraint on ``joint`` (the selected target joint by default) at the
        current frame, its goal where the joint is now; range current-10 .. current+10
        (active current-5 .. current+5), clipped to the clip."""
        doc = self.doc
        self.live.settle()
        if joint is None:
            side, joint = doc.selection
            if side != "target" or not joint:
                return
        pose = doc.pose("target")
        if pose is None or joint not in doc.motion.skeleton.index:
            return
        frame = doc.scene.viewer.current_frame
        last = doc.scene.num_frames - 1
        j = doc.motion.skeleton.index[joint]
        rng = (max(frame - ADD_RAMP, 0), max(frame - ADD_HALF, 0), min(frame + ADD_HALF, last),
               min(frame + ADD_RAMP, last))
        name = _unique_name(f"position {joint}", (c.name for c in doc.scene.constraints))
        c = Constraint(joint=joint, kind="position",
                       goal={"point": pose.positions[frame, j].copy()},
                       smooth_in=rng[0], start=rng[1], end=rng[2], smooth_out=rng[3],
                       name=name)
        constraints = list(doc.scene.constraints) + [c]
        self.live.commit(constraints, f"Add {name} at frame {frame}",
                         on_done=lambda: self.select(len(constraints) - 1))

    def delete_selected(self) -> None:
        self.live.settle()
        c = self.selected
        if c is None:
            return
        i = self.selected_index
        constraints = list(self.doc.scene.constraints)
        del constraints[i]
        self.live.commit(constraints, f"Delete {row_label(c)}")

    def duplicate_selected(self) -> None:
        self.live.settle()
        c = self.selected
        if c is None:
            return
        i = self.selected_index
        meta = {k: v for k, v in c.meta.items() if k != "source"}
        name = _unique_name(f"{row_label(c)} copy", (x.name for x in self.doc.scene.constraints))
        copy = dataclasses.replace(c, name=name, auto=False, meta=meta)
        constraints = list(self.doc.scene.constraints)
        constraints.insert(i + 1, copy)
        self.live.commit(constraints, f"Duplicate {row_label(c)}",
                         on_done=lambda: self.select(i + 1))

    def toggle_selected(self) -> None:
        self.live.settle()
        c = self.selected
        if c is None:
            return
        constraints = list(self.doc.scene.constraints)
        constraints[self.selected_index] = dataclasses.replace(c, enabled=not c.enabled)
        self.live.commit(constraints, f"{'Disable' if c.enabled else 'Enable'} {row_label(c)}")

    def context_menu(self, global_pos: QtCore.QPoint) -> None:
        c = self.selected
        if c is None:
            return
        menu = QtWidgets.QMenu(self)
        menu.addAction("Duplicate", self.duplicate_selected)
        menu.addAction("Disable" if c.enabled else "Enable", self.toggle_selected)
        menu.addSeparator()
        menu.addAction("Delete", self.delete_selected)
        menu.popup(global_pos)

    def keyPressEvent(self, ev) -> None:       # noqa: N802 - Qt's name
        if ev.key() in (Qt.Key.Key_Delete, Qt.Key.Key_Backspace):
            self.delete_selected()
        elif ev.key() == Qt.Key.Key_Escape:
            self.cancel_drag()
        else:
            super().keyPressEvent(ev)
