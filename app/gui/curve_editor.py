"""The curve editor: the displacement map's keys of one joint (or the root), edited by hand.

For the selected target joint it shows the three rotation channels of its offset (``rx ry rz``,
a rotation vector in the parent frame, applied before the joint's own rotation); with nothing
selected, or with "Root translation" on, the root's translation offset (``tx ty tz``; the
root joint itself, selected, shows its rotation like any joint). Each
channel is drawn as its evaluated curve at every frame with its keys as draggable points, over
the base motion's own channel (the composed motion's local rotation of that joint as a rotation
vector, or the root's translation), dimmed and dashed on its own right-hand axis: the offsets
are a few degrees where the base swings through tens.

Units are converted at the edge only: the map holds radians and metres, the editor shows
degrees and centimetres (:data:`UNITS`).

Interaction (pyqtgraph):

* keys are one :class:`KeyGraph` (a ``GraphItem`` subclass overriding ``mouseDragEvent``, as
  pyqtgraph's CustomGraphItem example) per channel; clicking a key selects it, Shift/Ctrl-click
  adds or removes it, dragging the background draws a rubber band (Shift adds), dragging a key
  moves every selected key together (Escape cancels the drag);
* time snaps to whole frames always (or 5-frame steps), the value to a step when asked;
  keys never cross their unselected neighbours and stay inside the clip;
* double-click on a curve adds a key on it; "Add key" keys the visible channels at the current
  frame; Delete removes the selected keys; the interpolation of the selected keys is chosen in a
  combo box or a key's context menu; the frame and value of a single key can be typed;
* middle-drag pans, right-drag and the wheel zoom, "Frame all" (F) fits the visible curves;
* the playhead is the document's current frame, and dragging it scrubs.

A key drag previews live (``doc.show_preview``, nothing on the undo stack) and pushes one
command on release; every add, delete, interpolation or typed change is one command through
:func:`app.gui.commands.push_displacement`. The editor follows the document (undo, redo, a new
IK result, another joint) and updates its widgets with their signals blocked (a
``QSignalBlocker`` equivalent, see :func:`_Blocker`).
"""
from __future__ import annotations

import contextlib
import math

import numpy as np
import pyqtgraph as pg
from scipy.spatial.transform import Rotation

from motion_composer.app.gui.commands import layer_map, push_layer_keys, push_layers
from motion_composer.app.gui.qt import QtCore, QtGui, QtWidgets
from motion_composer.engine.correction.displacement import (INTERPOLATIONS, ROOT, TANGENTS,
                                                            Curve, DisplacementMap, Layer)

__all__ = ["CurveEditor", "KeyGraph", "TangentHandles", "UNITS", "CHANNEL_COLORS"]

Qt = QtCore.Qt


@contextlib.contextmanager
def _Blocker(obj):
    """Block ``obj``'s signals for the block and restore the previous state: what
    ``QSignalBlocker`` does, without it. PySide6 6.12.0's ``QSignalBlocker.unblock()`` (and so
    its ``__exit__``) drops a reference to ``None`` at every call, and on Python 3.11, where
    ``None`` is not immortal, a few tens of thousands of uses abort the process
    (``none_dealloc``)."""
    before = obj.blockSignals(True)
    try:
        yield obj
    finally:
        obj.blockSignals(before)

ROTATION = ("rx", "ry", "rz")
TRANSLATION = ("tx", "ty", "tz")
#: display unit per kind of channel: (factor from the map's unit, suffix, axis label)
UNITS = {"rotation": (180.0 / math.pi, "°", "deg"), "translation": (100.0, " cm", "cm")}
#: one colour per axis, the same for rotation and translation channels
CHANNEL_COLORS = ((239, 83, 80), (102, 187, 106), (66, 165, 245))
_SELECTED = (255, 213, 79)
_BACKGROUND = (32, 33, 36)
_FOREGROUND = (200, 200, 200)
_KEY_SIZE = 9
_SELECTED_SIZE = 12
_PICK_PX = 10            # how near (pixels) a double-click must be to a curve to key it
_PICK_KEY_PX = 7         # how near (pixels) a click must be to a key to pick it
_LABEL_LANES = 3         # lines of constraint names at the top of the plot


def _label(joint: str) -> str:
    return "root" if joint == ROOT else joint


def _axis(channel: str) -> int:
    return "xyz".index(channel[1])


class _KeySymbols(pg.ScatterPlotItem):
    """The key symbols; clicks go to the :class:`KeyGraph` that owns them."""

    def mouseClickEvent(self, ev):
        ev.ignore()


class KeyGraph(pg.GraphItem):
    """The keys of one channel: draggable points (several selected keys move together)."""

    def __init__(self, editor: "CurveEditor", channel: str):
        super().__init__()
        self.editor = editor
        self.channel = channel
        self.frames = np.zeros(0)
        self.values = np.zeros(0)          # display units
        self._dragging = False
        # clicks and drags are handled here, by key positions (see key_at), not by the
        # scatter's own click handling
        self.scatter.setParentItem(None)
        self.scatter = _KeySymbols()
        self.scatter.setParentItem(self)
        self.setZValue(10)

    def set_keys(self, frames, values, selected) -> None:
        """Positions in frames and display units, and which keys are selected."""
        self.frames = np.asarray(frames, dtype=float)
        self.values = np.asarray(values, dtype=float)
        color = CHANNEL_COLORS[_axis(self.channel)]
        sel = np.asarray(selected, dtype=bool)
        brushes = [pg.mkBrush(*(_SELECTED if s else color)) for s in sel]
        pens = [pg.mkPen(255, 255, 255, width=1.5) if s else pg.mkPen(20, 20, 20, width=1)
                for s in sel]
        sizes = np.where(sel, _SELECTED_SIZE, _KEY_SIZE)
        pos = np.column_stack([self.frames, self.values]) if len(self.frames) else \
            np.zeros((0, 2))
        self.setData(pos=pos, adj=None, pen=None, symbol="o", size=sizes, symbolBrush=brushes,
                     symbolPen=pens, pxMode=True)

    def key_at(self, pos) -> int | None:
        """Index of the key drawn under ``pos`` (item coordinates), the nearest if several.
        Measured in pixels from the keys' positions, so it holds before the keys are first
        painted (the scatter's own ``pointsAt`` needs a paint to know the symbols' size)."""
        if not len(self.frames) or not self.isVisible():
            return None
        px, py = self.pixelWidth(), self.pixelHeight()
        if not (px > 0 and py > 0):
            return None
        d2 = ((self.frames - pos.x()) / px) ** 2 + ((self.values - pos.y()) / py) ** 2
        i = int(np.argmin(d2))
        return i if d2[i] <= _PICK_KEY_PX ** 2 else None

    # ------------------------------------------------------------------ mouse
    def mouseClickEvent(self, ev):
        index = self.key_at(ev.pos())
        if index is None:
            ev.ignore()
            return
        ev.accept()
        if ev.button() == Qt.MouseButton.LeftButton:
            self.editor._key_clicked(self.channel, index, ev.modifiers())
        elif ev.button() == Qt.MouseButton.RightButton:
            menu = self.editor._key_menu(self.channel, index)
            menu.popup(ev.screenPos().toPoint())
        else:
            ev.ignore()

    def mouseDragEvent(self, ev):
        if ev.button() != Qt.MouseButton.LeftButton:
            ev.ignore()
            return
        if ev.isStart():
            index = self.key_at(ev.buttonDownPos())
            if index is None:
                ev.ignore()
                return
            self._dragging = self.editor._drag_start(self.channel, index, ev.modifiers())
            if not self._dragging:
                ev.ignore()
                return
        elif not self._dragging:
            ev.ignore()
            return
        ev.accept()
        delta = ev.pos() - ev.buttonDownPos()
        if ev.isFinish():
            self._dragging = False
            self.editor._drag_finish(delta.x(), delta.y())
        else:
            self.editor._drag_move(delta.x(), delta.y())


class TangentHandles(pg.GraphItem):
    """The tangent handles of the selected smooth keys: a point a third of the way to the
    neighbouring key on each side, on the key's tangent, joined to the key by a line.
    Dragging a handle sets that key's slope (both sides, unless the key is broken): one
    command on release."""

    def __init__(self, editor: "CurveEditor"):
        super().__init__()
        self.editor = editor
        #: per handle: (channel, key index, side 0 in / 1 out)
        self.handles: list[tuple[str, int, int]] = []
        self.points = np.zeros((0, 2))
        self._dragging: tuple | None = None
        self.scatter.setParentItem(None)
        self.scatter = _KeySymbols()
        self.scatter.setParentItem(self)
        self.setZValue(15)

    def set_handles(self, handles, points, anchors) -> None:
        """``handles`` as (channel, index, side), their ``points`` and the keys they hang
        from (``anchors``), both ``(H, 2)`` in frames and display units."""
        self.handles = list(handles)
        self.points = np.asarray(points, dtype=float).reshape(-1, 2)
        anchors = np.asarray(anchors, dtype=float).reshape(-1, 2)
        if not self.handles:
            self.setData(pos=np.zeros((0, 2)), adj=None)
            return
        pos = np.concatenate([self.points, anchors])
        n = len(self.handles)
        adj = np.column_stack([np.arange(n), np.arange(n) + n])
        colors = [CHANNEL_COLORS[_axis(c)] for c, _, _ in self.handles]
        self.setData(pos=pos, adj=adj, pen=pg.mkPen(230, 230, 230, 170, width=1),
                     symbol=["s"] * n + ["o"] * n, size=[8] * n + [0] * n,
                     symbolBrush=[pg.mkBrush(*c) for c in colors] + [None] * n,
                     symbolPen=[pg.mkPen(255, 255, 255, width=1)] * n + [None] * n,
                     pxMode=True)

    def handle_at(self, pos) -> int | None:
        """Index of the handle drawn under ``pos`` (item coordinates), by pixel distance."""
        if not self.handles or not self.isVisible():
            return None
        px, py = self.pixelWidth(), self.pixelHeight()
        if not (px > 0 and py > 0):
            return None
        d2 = ((self.points[:, 0] - pos.x()) / px) ** 2 + \
            ((self.points[:, 1] - pos.y()) / py) ** 2
        i = int(np.argmin(d2))
        return i if d2[i] <= _PICK_KEY_PX ** 2 else None

    def mouseClickEvent(self, ev):
        if self.handle_at(ev.pos()) is None:
            ev.ignore()
        else:
            ev.accept()

    def mouseDragEvent(self, ev):
        if ev.button() != Qt.MouseButton.LeftButton:
            ev.ignore()
            return
        if ev.isStart():
            index = self.handle_at(ev.buttonDownPos())
            if index is None:
                ev.ignore()
                return
            self._dragging = self.handles[index]
            self.editor._tangent_drag_start(*self._dragging)
        elif self._dragging is None:
            ev.ignore()
            return
        ev.accept()
        if ev.isFinish():
            self._dragging = None
            self.editor._tangent_drag_finish(ev.pos())
        else:
            self.editor._tangent_drag_move(ev.pos())


class _KeyViewBox(pg.ViewBox):
    """Left-drag on the background draws a rubber band, double-click adds a key; middle-drag
    pans and right-drag or the wheel zoom as in any ViewBox."""

    def __init__(self):
        super().__init__()
        self.editor: CurveEditor | None = None
        self.band = QtWidgets.QGraphicsRectItem()
        self.band.setPen(pg.mkPen(255, 255, 255, 180, width=1, style=Qt.PenStyle.DashLine))
        self.band.setBrush(pg.mkBrush(255, 255, 255, 30))
        self.band.setParentItem(self)
        self.band.setZValue(1e9)
        self.band.hide()

    def mouseDragEvent(self, ev, axis=None):
        if axis is None and ev.button() == Qt.MouseButton.LeftButton and self.editor:
            ev.accept()
            rect = QtCore.QRectF(ev.buttonDownPos(), ev.pos()).normalized()
            if ev.isFinish():
                self.band.hide()
                self.editor._select_rect(self.childGroup.mapRectFromParent(rect),
                                         ev.modifiers())
            else:
                self.band.setRect(rect)
                self.band.show()
            return
        super().mouseDragEvent(ev, axis)

    def mouseClickEvent(self, ev):
        if ev.button() == Qt.MouseButton.LeftButton and self.editor:
            ev.accept()
            if ev.double():
                self.editor._add_key_near(self.mapToView(ev.pos()))
            elif not ev.modifiers() & (Qt.KeyboardModifier.ShiftModifier |
                                       Qt.KeyboardModifier.ControlModifier):
                self.editor.set_selection(set())
            return
        super().mouseClickEvent(ev)


def _swatch(color) -> QtGui.QIcon:
    pix = QtGui.QPixmap(14, 14)
    pix.fill(Qt.GlobalColor.transparent)
    painter = QtGui.QPainter(pix)
    painter.setRenderHint(QtGui.QPainter.RenderHint.Antialiasing)
    painter.setPen(Qt.PenStyle.NoPen)
    painter.setBrush(QtGui.QColor(*color))
    painter.drawEllipse(2, 2, 10, 10)
    painter.end()
    return QtGui.QIcon(pix)


class CurveEditor(QtWidgets.QWidget):
    """Displacement-map curves of one joint (or the root) of a document, edited by hand."""

    def __init__(self, document, parent=None):
        super().__init__(parent)
        self.doc = document
        self.joint: str = ROOT                  # joint name or ROOT
        self.channels: tuple[str, ...] = TRANSLATION
        #: the layer whose keys are shown and edited: 0 the solved layer (where the editor
        #: starts: a solve's keys are what there is to see), 1 and up the animator's, which
        #: a solve keeps (see :func:`app.gui.commands.layer_map`)
        self.layer: int = 0
        self.selected: set[tuple[str, float]] = set()   # (channel, key frame)
        self._drag: dict | None = None
        self._tangent_drag: dict | None = None
        self.range_labels: list = []        # (TextItem, name, start, end) per constraint
        self._base_cache: tuple | None = None
        self._shown_map: DisplacementMap | None = None
        self._drawn: dict = {}          # what is on screen, to redraw only what changed
        self._placing_playhead = False  # the editor itself moves the playhead
        self._build()
        self.doc.motionChanged.connect(self._motion_changed)
        self.doc.constraintsChanged.connect(self._constraints_changed)
        self.doc.selectionChanged.connect(self._selection_changed)
        self.doc.frameChanged.connect(self._frame_changed)
        self.doc.sourcesChanged.connect(self._sources_changed)
        self._selection_changed(*self.doc.selection)
        self._sources_changed()

    # ================================================================== building
    def _build(self) -> None:
        # ---- first row: what is shown
        self.title = QtWidgets.QLabel()
        font = self.title.font()
        font.setBold(True)
        self.title.setFont(font)
        self.root_button = QtWidgets.QToolButton()
        self.root_button.setText("Root translation")
        self.root_button.setCheckable(True)
        self.root_button.setToolTip("Show the root's translation offset instead of the "
                                    "selected joint's rotation offset")
        self.root_button.toggled.connect(self._root_toggled)
        self.channel_buttons: dict[int, QtWidgets.QToolButton] = {}
        for axis, name in enumerate("xyz"):
            button = QtWidgets.QToolButton()
            button.setText(name.upper())
            button.setIcon(_swatch(CHANNEL_COLORS[axis]))
            button.setToolButtonStyle(Qt.ToolButtonStyle.ToolButtonTextBesideIcon)
            button.setCheckable(True)
            button.setChecked(True)
            button.setToolTip(f"Show the {name} channel")
            button.toggled.connect(self._visibility_changed)
            self.channel_buttons[axis] = button
        self.base_check = QtWidgets.QCheckBox("Base motion")
        self.base_check.setChecked(True)
        self.base_check.setToolTip("Show the base (converted) motion's own channels, dashed, "
                                   "on the right-hand axis")
        self.base_check.toggled.connect(self._visibility_changed)
        self.frame_all_button = QtWidgets.QPushButton("Frame all")
        self.frame_all_button.setToolTip("Fit the visible curves (A; F frames the selected "
                                         "keys)")
        self.frame_all_button.clicked.connect(self.frame_all)
        # ---- layers: which one is edited, its weight and mute
        self.layer_combo = QtWidgets.QComboBox()
        self.layer_combo.setToolTip("The layer whose keys are shown and edited; the others "
                                    "are drawn thin. A solve replaces the solved layer only")
        self.layer_combo.activated.connect(self._layer_chosen)
        self.weight_box = QtWidgets.QDoubleSpinBox()
        self.weight_box.setRange(0.0, 10.0)
        self.weight_box.setSingleStep(0.1)
        self.weight_box.setDecimals(2)
        self.weight_box.setPrefix("weight ")
        self.weight_box.setKeyboardTracking(False)
        self.weight_box.setToolTip("The layer's offsets are scaled by its weight")
        self.weight_box.valueChanged.connect(self._weight_typed)
        self.mute_check = QtWidgets.QCheckBox("Mute")
        self.mute_check.setToolTip("A muted layer has no effect on the motion")
        self.mute_check.toggled.connect(self._mute_toggled)
        self.new_layer_button = QtWidgets.QPushButton("New layer")
        self.new_layer_button.setToolTip("Add an empty animator layer on top")
        self.new_layer_button.clicked.connect(self.add_layer)

        top = QtWidgets.QHBoxLayout()
        top.setContentsMargins(0, 0, 0, 0)
        top.addWidget(self.title)
        top.addStretch(1)
        top.addWidget(QtWidgets.QLabel("Layer"))
        top.addWidget(self.layer_combo)
        top.addWidget(self.weight_box)
        top.addWidget(self.mute_check)
        top.addWidget(self.new_layer_button)
        top.addWidget(self.root_button)
        for button in self.channel_buttons.values():
            top.addWidget(button)
        top.addWidget(self.base_check)
        top.addWidget(self.frame_all_button)

        # ---- second row: keys
        self.add_button = QtWidgets.QPushButton("Add key")
        self.add_button.setToolTip("Key the visible channels at the current frame "
                                   "(or double-click on a curve)")
        self.add_button.clicked.connect(self.add_keys_at_current_frame)
        self.delete_button = QtWidgets.QPushButton("Delete")
        self.delete_button.setToolTip("Delete the selected keys (Delete)")
        self.delete_button.clicked.connect(self.delete_selected)
        self.interp_combo = QtWidgets.QComboBox()
        for kind in INTERPOLATIONS:
            self.interp_combo.addItem(kind.capitalize(), kind)
        self.interp_combo.setToolTip("Interpolation of the segment after each selected key")
        self.interp_combo.activated.connect(self._interp_chosen)
        self.tangent_combo = QtWidgets.QComboBox()
        for mode in TANGENTS:
            self.tangent_combo.addItem(mode.capitalize(), mode)
        self.tangent_combo.setToolTip("Tangent of each selected key: auto (smooth through "
                                      "its neighbours), flat, linear (towards the "
                                      "neighbours), aligned (one slope, drag a handle) or "
                                      "broken (in and out slopes apart)")
        self.tangent_combo.activated.connect(self._tangent_chosen)
        self.frame_box = QtWidgets.QSpinBox()
        self.frame_box.setPrefix("frame ")
        self.frame_box.setSpecialValueText("frame –")
        self.frame_box.setKeyboardTracking(False)
        self.frame_box.setToolTip("Frame of the selected key")
        self.frame_box.valueChanged.connect(self._frame_typed)
        self.value_box = QtWidgets.QDoubleSpinBox()
        self.value_box.setDecimals(3)
        self.value_box.setRange(-1e6, 1e6)
        self.value_box.setSpecialValueText("value –")
        self.value_box.setKeyboardTracking(False)
        self.value_box.setToolTip("Value of the selected key")
        self.value_box.valueChanged.connect(self._value_typed)
        self.snap5_check = QtWidgets.QCheckBox("5-frame steps")
        self.snap5_check.setToolTip("Keys snap to whole frames; with this, to every 5th frame")
        self.snap_value_check = QtWidgets.QCheckBox("Snap value")
        self.value_step = QtWidgets.QDoubleSpinBox()
        self.value_step.setDecimals(2)
        self.value_step.setRange(0.01, 1000.0)
        self.value_step.setValue(0.5)
        self.value_step.setToolTip("Value snapping step")

        keys = QtWidgets.QHBoxLayout()
        keys.setContentsMargins(0, 0, 0, 0)
        keys.addWidget(self.add_button)
        keys.addWidget(self.delete_button)
        keys.addWidget(QtWidgets.QLabel("Interpolation"))
        keys.addWidget(self.interp_combo)
        keys.addWidget(QtWidgets.QLabel("Tangent"))
        keys.addWidget(self.tangent_combo)
        keys.addWidget(self.frame_box)
        keys.addWidget(self.value_box)
        keys.addStretch(1)
        keys.addWidget(QtWidgets.QLabel("Snap: whole frames"))
        keys.addWidget(self.snap5_check)
        keys.addWidget(self.snap_value_check)
        keys.addWidget(self.value_step)

        # ---- the plot
        self.view_box = _KeyViewBox()
        self.view_box.editor = self
        self.plot_widget = pg.PlotWidget(viewBox=self.view_box, background=_BACKGROUND)
        self.plot_widget.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
        self.plot = self.plot_widget.getPlotItem()
        self.plot.showGrid(x=True, y=True, alpha=0.15)
        self.plot.setLabel("bottom", "frame")
        self.plot.showAxis("right")
        self.view_box.disableAutoRange()
        for name in ("left", "bottom", "right"):
            axis = self.plot.getAxis(name)
            axis.setPen(pg.mkPen(*_FOREGROUND))
            axis.setTextPen(pg.mkPen(*_FOREGROUND))
        self.plot.getAxis("right").setTextPen(pg.mkPen(150, 150, 150))
        # fixed widths: other units' tick labels do not shift the plot
        self.plot.getAxis("left").setWidth(58)
        self.plot.getAxis("right").setWidth(58)
        # the base motion on its own y axis (right), x linked
        self.base_box = pg.ViewBox(enableMouse=False)
        self.base_box.setMouseEnabled(False, False)
        self.base_box.setAcceptedMouseButtons(Qt.MouseButton.NoButton)
        self.base_box.setMenuEnabled(False)
        self.plot.scene().addItem(self.base_box)
        self.base_box.setZValue(-100)
        self.plot.getAxis("right").linkToView(self.base_box)
        self.base_box.setXLink(self.view_box)
        self.view_box.sigResized.connect(self._sync_base_box)
        self._sync_base_box()

        self.zero_line = pg.InfiniteLine(0, angle=0, movable=False,
                                         pen=pg.mkPen(120, 120, 120, 160, width=1))
        self.view_box.addItem(self.zero_line, ignoreBounds=True)
        self.playhead = pg.InfiniteLine(0, angle=90, movable=True,
                                        pen=pg.mkPen(255, 255, 255, 200, width=1.5),
                                        hoverPen=pg.mkPen(255, 213, 79, width=2.5),
                                        label="{value:.0f}",
                                        labelOpts={"position": 0.03, "color": (255, 255, 255),
                                                   "fill": (60, 60, 60, 220),
                                                   "anchors": [(0.5, 1), (0.5, 1)]})
        self.playhead.setZValue(20)
        self.playhead.sigPositionChanged.connect(self._playhead_moved)
        self.playhead.sigPositionChangeFinished.connect(self._playhead_released)
        self.view_box.addItem(self.playhead, ignoreBounds=True)
        self.ranges: list[pg.LinearRegionItem] = []

        self.curves: dict[int, pg.PlotDataItem] = {}
        self.others: dict[int, pg.PlotDataItem] = {}
        self.bases: dict[int, pg.PlotDataItem] = {}
        self.key_graphs: dict[int, KeyGraph] = {}
        for axis in range(3):
            color = CHANNEL_COLORS[axis]
            base = pg.PlotDataItem(pen=pg.mkPen(*color, 120, width=1.2,
                                                style=Qt.PenStyle.DashLine))
            self.base_box.addItem(base)
            self.bases[axis] = base
            other = pg.PlotDataItem(pen=pg.mkPen(*color, 110, width=1))
            other.setZValue(4)
            self.view_box.addItem(other)
            self.others[axis] = other
            curve = pg.PlotDataItem(pen=pg.mkPen(*color, width=2))
            curve.setZValue(5)
            self.view_box.addItem(curve)
            self.curves[axis] = curve
            graph = KeyGraph(self, "")
            self.view_box.addItem(graph)
            self.key_graphs[axis] = graph
        self.handles = TangentHandles(self)
        self.view_box.addItem(self.handles)
        self.view_box.sigRangeChanged.connect(self._place_range_labels)
        # below the lines of constraint names
        self.legend = pg.LegendItem(offset=(-10, 58), labelTextColor=_FOREGROUND,
                                    brush=pg.mkBrush(20, 20, 22, 170),
                                    pen=pg.mkPen(90, 90, 90))
        self.legend.setParentItem(self.view_box)
        self._legend_other = pg.PlotDataItem(pen=pg.mkPen(170, 170, 170, 160, width=1))
        self._legend_base = pg.PlotDataItem(pen=pg.mkPen(170, 170, 170, 160, width=1.2,
                                                         style=Qt.PenStyle.DashLine))

        self.delete_shortcut = QtGui.QShortcut(QtGui.QKeySequence(QtGui.QKeySequence.StandardKey
                                                                  .Delete), self)
        self.delete_shortcut.setContext(Qt.ShortcutContext.WidgetWithChildrenShortcut)
        self.delete_shortcut.activated.connect(self.delete_selected)
        self.backspace_shortcut = QtGui.QShortcut(QtGui.QKeySequence(Qt.Key.Key_Backspace), self)
        self.backspace_shortcut.setContext(Qt.ShortcutContext.WidgetWithChildrenShortcut)
        self.backspace_shortcut.activated.connect(self.delete_selected)
        self.frame_shortcut = QtGui.QShortcut(QtGui.QKeySequence(Qt.Key.Key_F), self)
        self.frame_shortcut.setContext(Qt.ShortcutContext.WidgetWithChildrenShortcut)
        self.frame_shortcut.activated.connect(self.frame_selected)
        self.all_shortcut = QtGui.QShortcut(QtGui.QKeySequence(Qt.Key.Key_A), self)
        self.all_shortcut.setContext(Qt.ShortcutContext.WidgetWithChildrenShortcut)
        self.all_shortcut.activated.connect(self.frame_all)
        self.cancel_shortcut = QtGui.QShortcut(QtGui.QKeySequence(Qt.Key.Key_Escape), self)
        self.cancel_shortcut.setContext(Qt.ShortcutContext.WidgetWithChildrenShortcut)
        self.cancel_shortcut.activated.connect(self.cancel_drag)

        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(4, 4, 4, 4)
        layout.setSpacing(3)
        layout.addLayout(top)
        layout.addLayout(keys)
        layout.addWidget(self.plot_widget, 1)

    def _sync_base_box(self) -> None:
        self.base_box.setGeometry(self.view_box.sceneBoundingRect())
        self.base_box.linkedViewChanged(self.view_box, self.base_box.XAxis)

    def sizeHint(self) -> QtCore.QSize:
        return QtCore.QSize(900, 420)

    # ================================================================== what is shown
    @property
    def kind(self) -> str:
        return "translation" if self.joint == ROOT else "rotation"

    @property
    def scale(self) -> float:
        """Display units per map unit (degrees per radian, centimetres per metre)."""
        return UNITS[self.kind][0]

    @property
    def suffix(self) -> str:
        return UNITS[self.kind][1]

    def visible_channels(self) -> list[str]:
        return [c for c in self.channels if self.channel_buttons[_axis(c)].isChecked()]

    def curve(self, channel: str) -> Curve | None:
        """The shown map's curve of ``channel`` of the shown joint (None if it has none)."""
        shown = self._shown_map if self._shown_map is not None else self._layer_map()
        return shown.curves.get((self.joint, channel))

    def _layer_map(self) -> DisplacementMap:
        """The keys of the layer being edited."""
        return layer_map(self.doc.scene, self.layer)

    def _scene_with(self, new_map: DisplacementMap):
        """The document's scene with the edited layer's keys ``new_map`` (a preview)."""
        scene = self.doc.scene
        if self.layer == 0:
            return scene.replace(displacement=new_map)
        layers = list(scene.layers)
        layers[self.layer - 1] = layers[self.layer - 1].replace(displacement=new_map)
        return scene.replace(layers=tuple(layers))

    def _other_offsets(self, channel: str, frames: np.ndarray) -> np.ndarray | None:
        """The other layers' offsets of ``channel`` (weighted, muted ones left out), summed,
        or None when no other layer keys it."""
        scene = self.doc.scene
        maps = [(scene.displacement, 1.0)] + [(x.displacement, x.weight)
                                               for x in scene.layers if not x.mute]
        total, any_curve = np.zeros(len(frames)), False
        for i, (displacement, weight) in enumerate(maps):
            curve = displacement.curves.get((self.joint, channel))
            if i != self.layer and curve is not None:
                total += weight * curve.evaluate(frames)
                any_curve = True
        return total if any_curve else None

    def show_joint(self, joint: str) -> None:
        """Show ``joint``'s rotation channels, or the root's translation for ROOT."""
        if joint != self.joint:
            self.selected = set()
        self.joint = joint
        self.channels = TRANSLATION if joint == ROOT else ROTATION
        with _Blocker(self.root_button):
            self.root_button.setChecked(joint == ROOT)
        self.refresh()
        self.frame_all()

    def _selected_target_joint(self) -> str | None:
        side, joint = self.doc.selection
        if side == "target" and joint and self.doc.scene.target is not None and \
                joint in self.doc.scene.target.skeleton.index:
            return joint
        return None

    def _selection_changed(self, side: str, joint: str) -> None:
        if side == "performer" and joint:
            return                              # performer joints have no offsets
        chosen = self._selected_target_joint()
        self.show_joint(chosen if chosen is not None else ROOT)

    def _root_toggled(self, checked: bool) -> None:
        if checked:
            self.show_joint(ROOT)
        else:
            chosen = self._selected_target_joint()
            if chosen is None and self.doc.scene.target is not None:
                chosen = self.doc.scene.target.skeleton.names[0]
            self.show_joint(chosen if chosen is not None else ROOT)

    def _sources_changed(self) -> None:
        self._base_cache = None
        self._update_playhead_bounds()
        self.refresh()
        self.frame_all()

    def _constraints_changed(self) -> None:
        # a new IK result: show its keys whole
        if not self.dragging:
            self.refresh()
            self.frame_all()

    def _motion_changed(self) -> None:
        if self.dragging:
            return                              # our own preview
        self._update_playhead_bounds()
        self.refresh()

    # ================================================================== model -> widget
    def _base_values(self) -> np.ndarray | None:
        """``(F, 3)`` the base motion's channels of the shown joint, in display units."""
        composed = self.doc.scene.composed
        if composed is None:
            return None
        if self._base_cache is None or self._base_cache[0] is not composed or \
                self._base_cache[1] != self.joint:
            if self.joint == ROOT:
                values = composed.translations[:, 0, :] * self.scale
            else:
                j = composed.skeleton.index[self.joint]
                values = Rotation.from_quat(composed.rotations[:, j]).as_rotvec() * self.scale
            self._base_cache = (composed, self.joint, values)
        return self._base_cache[2]

    def refresh(self) -> None:
        """Redraw from the document (or from the drag's preview map). Only what changed is
        redrawn: a drag step touches the dragged channels' curves and keys alone."""
        ready = self.doc.scene.composed is not None
        if ready and self.joint != ROOT and self.joint not in self.doc.scene.composed.skeleton.index:
            self.joint, self.channels = ROOT, TRANSLATION
        F = self.doc.scene.composed.num_frames if ready else 0
        frames = np.arange(F, dtype=float)
        visible = tuple(self.visible_channels()) if ready else ()
        decor = (self.joint, visible, self.base_check.isChecked())
        if decor != self._drawn.get("decor"):
            self._drawn["decor"] = decor
            self._update_labels()
            self._update_legend()
        # keep the selection to keys that exist
        self.selected = {(c, f) for c, f in self.selected
                         if c in self.channels and (cv := self.curve(c)) is not None
                         and np.any(cv.frames == f)}
        base = self._base_values() if ready else None
        for channel in self.channels:
            axis = _axis(channel)
            curve = self.curve(channel) if ready else None
            shown = channel in visible
            graph = self.key_graphs[axis]
            graph.channel = channel
            sel = tuple((channel, f) in self.selected for f in curve.frames) \
                if curve is not None else ()
            # curves compare by identity (frozen, eq=False): a new curve is a new object
            state = (self.joint, channel, F, curve, sel)
            if state != self._drawn.get(axis):
                self._drawn[axis] = state
                if curve is not None:
                    self.curves[axis].setData(frames, curve.evaluate(frames) * self.scale)
                    graph.set_keys(curve.frames, curve.values * self.scale, sel)
                else:
                    self.curves[axis].setData(frames, np.zeros(F))
                    graph.set_keys([], [], [])
            scene = self.doc.scene
            ostate = (self.joint, channel, F, self.layer, scene.displacement, scene.layers)
            if ostate != self._drawn.get(("others", axis)):
                self._drawn[("others", axis)] = ostate
                others = self._other_offsets(channel, frames) if ready else None
                self.others[axis].setData(frames if others is not None else [],
                                          others * self.scale if others is not None else [])
            if self.curves[axis].isVisible() != shown:
                self.curves[axis].setVisible(shown)
                self.others[axis].setVisible(shown)
                graph.setVisible(shown)
            if base is not self._drawn.get(("base", axis)):
                self._drawn[("base", axis)] = base
                if base is not None:
                    self.bases[axis].setData(frames, base[:, axis])
                else:
                    self.bases[axis].setData([], [])
                self.base_box.enableAutoRange(axis=pg.ViewBox.YAxis)
            base_shown = shown and self.base_check.isChecked()
            if self.bases[axis].isVisible() != base_shown:
                self.bases[axis].setVisible(base_shown)
        self._update_handles()
        self._update_ranges()
        self._update_layer_widgets()
        self._update_key_widgets()
        if self.playhead.value() != self.doc.scene.viewer.current_frame:
            self._show_frame(self.doc.scene.viewer.current_frame)
        if ready != self._drawn.get("ready"):
            self._drawn["ready"] = ready
            for widget in (self.add_button, self.root_button, self.frame_all_button,
                           self.layer_combo, self.new_layer_button):
                widget.setEnabled(ready)

    def _update_labels(self) -> None:
        unit = UNITS[self.kind][2]
        if self.joint == ROOT:
            self.title.setText("Root: translation offset, world axes (cm)")
        else:
            self.title.setText(f"{self.joint}: rotation offset, parent frame (deg)")
        self.plot.setLabel("left", f"offset ({unit})", color="#c8c8c8")
        self.plot.setLabel("right", f"base motion, dashed ({unit})", color="#969696")

    def _update_legend(self) -> None:
        self.legend.clear()
        for channel in self.channels:
            axis = _axis(channel)
            if self.channel_buttons[axis].isChecked():
                self.legend.addItem(self.curves[axis], f"{channel} offset")
        self.legend.addItem(self._legend_other, "other layers (thin)")
        if self.base_check.isChecked():
            self.legend.addItem(self._legend_base, "base motion (right axis)")

    def _update_ranges(self) -> None:
        """Faint bands where constraints act (easing in and out), stronger where they hold,
        each with the constraint's name, elided to the room it has (:meth:`_place_range_labels`)
        so that names never overlap."""
        ready = self.doc.scene.composed is not None
        spans = tuple((c.name or c.joint, c.smooth_in, c.start, c.end, c.smooth_out)
                      for c in self.doc.scene.constraints if getattr(c, "enabled", True)) \
            if ready else ()
        if spans == self._drawn.get("ranges"):
            return
        self._drawn["ranges"] = spans
        for item in self.ranges:
            self.view_box.removeItem(item)
        self.ranges = []
        self.range_labels = []
        for name, smooth_in, start, end, smooth_out in spans:
            for lo, hi, alpha in ((smooth_in, smooth_out, 14), (start, end, 22)):
                region = pg.LinearRegionItem((lo, hi), movable=False,
                                             brush=pg.mkBrush(255, 255, 255, alpha),
                                             pen=pg.mkPen(None))
                region.setZValue(-50)
                self.view_box.addItem(region, ignoreBounds=True)
                self.ranges.append(region)
            label = pg.TextItem("", color=(170, 170, 170), anchor=(0, 0))
            label.setZValue(-40)
            self.view_box.addItem(label, ignoreBounds=True)
            self.ranges.append(label)
            self.range_labels.append((label, name, float(start), float(end)))
        self._place_range_labels()

    def _place_range_labels(self, *_args) -> None:
        """Each constraint's name at the top of its active band, in one of
        :data:`_LABEL_LANES` lines of text: a name goes in the first line that is free where
        its band starts (else in the line that frees first) and is elided to its band's width
        and to the room before the next name on its line, in pixels (again on every zoom or
        pan), so that names never overlap."""
        labels = self.range_labels
        if not labels:
            return
        (x0, x1), (y0, y1) = self.view_box.viewRange()
        px, py = self.view_box.viewPixelSize()
        if not (px > 0 and py > 0):
            return
        metrics = QtGui.QFontMetrics(labels[0][0].textItem.font())
        order = sorted(range(len(labels)), key=lambda k: (max(labels[k][2], x0), k))
        lane_end = [-math.inf] * _LABEL_LANES
        lanes: list[list[int]] = [[] for _ in range(_LABEL_LANES)]
        for k in order:
            _label, name, start, end = labels[k]
            left = max(start, x0)
            free = [n for n in range(_LABEL_LANES) if lane_end[n] <= left]
            lane = free[0] if free else int(np.argmin(lane_end))
            want = min(metrics.horizontalAdvance(name) + 8, (end - left) / px) * px
            lane_end[lane] = left + want
            lanes[lane].append(k)
        for lane, members in enumerate(lanes):
            for n, k in enumerate(members):
                label, name, start, end = labels[k]
                left = max(start, x0)
                stop = min(end, x1)
                if n + 1 < len(members):
                    stop = min(stop, max(labels[members[n + 1]][2], x0))
                room = (stop - left) / px - 6
                text = metrics.elidedText(name, Qt.TextElideMode.ElideRight,
                                          int(max(room, 0)))
                label.setText(text if room >= metrics.horizontalAdvance("\u2026") * 3 else "")
                label.setPos(left, y1 - lane * metrics.height() * py)

    def range_label_texts(self) -> list[str]:
        """The constraint names as drawn (elided), in constraint order."""
        return [label.textItem.toPlainText() for label, *_ in self.range_labels]

    def _update_key_widgets(self) -> None:
        """Interpolation combo and frame/value boxes from the selection (no signals out)."""
        keys = self._selected_keys()
        kinds = {self.curve(c).interpolation[i] for c, i in keys}
        modes = {self.curve(c).tangents[i] for c, i in keys}
        with _Blocker(self.tangent_combo):
            self.tangent_combo.setEnabled(bool(keys))
            self.tangent_combo.setCurrentIndex(TANGENTS.index(modes.pop())
                                               if len(modes) == 1 else -1)
        with _Blocker(self.interp_combo):
            self.interp_combo.setEnabled(bool(keys))
            if len(kinds) == 1:
                self.interp_combo.setCurrentIndex(INTERPOLATIONS.index(kinds.pop()))
            else:
                self.interp_combo.setCurrentIndex(-1)
        self.delete_button.setEnabled(bool(keys))
        single = len(keys) == 1
        with _Blocker(self.frame_box), _Blocker(self.value_box):
            self.frame_box.setEnabled(single)
            self.value_box.setEnabled(single)
            self.value_box.setSuffix(self.suffix)
            F = self.doc.scene.composed.num_frames if self.doc.scene.composed is not None else 1
            # one below the range shows the special text: no single key selected
            self.frame_box.setRange(-1, max(F - 1, 0))
            if single:
                c, i = keys[0]
                curve = self.curve(c)
                self.frame_box.setValue(int(round(curve.frames[i])))
                self.value_box.setValue(float(curve.values[i] * self.scale))
            else:
                self.frame_box.setValue(-1)
                self.value_box.setValue(self.value_box.minimum())
        with _Blocker(self.value_step):
            self.value_step.setSuffix(self.suffix)

    def _visibility_changed(self, *_args) -> None:
        visible = set(self.visible_channels())
        self.selected = {(c, f) for c, f in self.selected if c in visible}
        self.refresh()

    def _update_playhead_bounds(self) -> None:
        F = self.doc.scene.num_frames
        self.playhead.setBounds((0, max(F - 1, 0)))

    def _show_frame(self, frame: int) -> None:
        """Put the playhead on ``frame`` without setting the document's frame back. (Its
        signals are not blocked: its label follows them.)"""
        self._placing_playhead = True
        try:
            self.playhead.setValue(frame)
        finally:
            self._placing_playhead = False

    def _frame_changed(self, frame: int) -> None:
        self._show_frame(frame)

    def _playhead_moved(self) -> None:
        if not self._placing_playhead:
            self.doc.set_frame(int(round(self.playhead.value())))

    def _playhead_released(self) -> None:
        self._show_frame(self.doc.scene.viewer.current_frame)     # on the whole frame

    # ================================================================== view
    def curves_extent(self) -> tuple[float, float, float, float] | None:
        """``(x0, x1, y0, y1)`` of the visible offset curves and their keys (display units)."""
        if self.doc.scene.composed is None:
            return None
        F = self.doc.scene.composed.num_frames
        frames = np.arange(F, dtype=float)
        x0, x1 = 0.0, float(max(F - 1, 1))
        ys = [np.zeros(1)]
        for channel in self.visible_channels():
            curve = self.curve(channel)
            if curve is not None and len(curve):
                ys.append(curve.evaluate(frames) * self.scale)
                ys.append(curve.values * self.scale)
                x0, x1 = min(x0, curve.frames[0]), max(x1, curve.frames[-1])
        y = np.concatenate(ys)
        y0, y1 = float(y.min()), float(y.max())
        if y1 - y0 < 1e-9:
            y0, y1 = y0 - 1.0, y1 + 1.0
        return x0, x1, y0, y1

    def frame_all(self) -> None:
        """Fit the view to the visible curves."""
        extent = self.curves_extent()
        if extent is None:
            return
        x0, x1, y0, y1 = extent
        self.view_box.setRange(xRange=(x0, x1), yRange=(y0, y1), padding=0.04)

    def frame_selected(self) -> None:
        """Fit the view to the selected keys (F); with none selected, to everything."""
        keys = self._selected_keys()
        if not keys:
            self.frame_all()
            return
        frames = [float(self.curve(c).frames[i]) for c, i in keys]
        values = [float(self.curve(c).values[i] * self.scale) for c, i in keys]
        x0, x1 = min(frames), max(frames)
        y0, y1 = min(values), max(values)
        if x1 - x0 < 10:
            x0, x1 = x0 - 5, x1 + 5
        if y1 - y0 < 1e-3:
            y0, y1 = y0 - 0.5, y1 + 0.5
        self.view_box.setRange(xRange=(x0, x1), yRange=(y0, y1), padding=0.15)

    def key_scene_pos(self, channel: str, index: int) -> QtCore.QPointF:
        """Where key ``index`` of ``channel`` is drawn, in scene coordinates."""
        curve = self.curve(channel)
        point = QtCore.QPointF(float(curve.frames[index]),
                               float(curve.values[index] * self.scale))
        return self.view_box.mapViewToScene(point)

    # ================================================================== selection
    def _selected_keys(self) -> list[tuple[str, int]]:
        """Selected keys as (channel, index) in channel order."""
        out = []
        for channel in self.channels:
            curve = self.curve(channel)
            if curve is None:
                continue
            for i, f in enumerate(curve.frames):
                if (channel, f) in self.selected:
                    out.append((channel, i))
        return out

    def selected_keys(self) -> list[tuple[str, int]]:
        return self._selected_keys()

    def set_selection(self, keys) -> None:
        """Select keys given as (channel, index) pairs (or (channel, frame) floats)."""
        chosen = set()
        for channel, which in keys:
            curve = self.curve(channel)
            if curve is None:
                continue
            if isinstance(which, (int, np.integer)):
                chosen.add((channel, float(curve.frames[which])))
            else:
                chosen.add((channel, float(which)))
        self.selected = chosen
        self.refresh()

    def _key_clicked(self, channel: str, index: int, modifiers) -> None:
        frame = float(self.curve(channel).frames[index])
        if modifiers & (Qt.KeyboardModifier.ShiftModifier | Qt.KeyboardModifier.ControlModifier):
            self.selected ^= {(channel, frame)}
            self.refresh()
        else:
            self.set_selection({(channel, frame)})

    def _select_rect(self, rect: QtCore.QRectF, modifiers) -> None:
        """Select the visible keys inside ``rect`` (view coordinates); Shift/Ctrl adds."""
        add = bool(modifiers & (Qt.KeyboardModifier.ShiftModifier |
                                Qt.KeyboardModifier.ControlModifier))
        chosen = set(self.selected) if add else set()
        for channel in self.visible_channels():
            curve = self.curve(channel)
            if curve is None:
                continue
            v = curve.values * self.scale
            inside = ((curve.frames >= rect.left()) & (curve.frames <= rect.right()) &
                      (v >= rect.top()) & (v <= rect.bottom()))
            chosen |= {(channel, float(f)) for f in curve.frames[inside]}
        self.selected = chosen
        self.refresh()

    # ================================================================== editing helpers
    def _what(self, keys) -> str:
        channels = [c for c in self.channels if any(k[0] == c for k in keys)]
        n = len(keys)
        return (f"{n} key{'s' if n != 1 else ''} of {_label(self.joint)}."
                f"{', '.join(channels)}")

    def _with_curves(self, base: DisplacementMap, changed: dict) -> DisplacementMap:
        """``base`` with the shown joint's channels replaced (None removes a curve)."""
        curves = dict(base.curves)
        for channel, curve in changed.items():
            if curve is None or len(curve) == 0:
                curves.pop((self.joint, channel), None)
            else:
                curves[(self.joint, channel)] = curve
        return DisplacementMap(curves)

    def _push(self, new_map: DisplacementMap, text: str) -> None:
        push_layer_keys(self.doc, self.layer, new_map, text=text)

    def _snap_step(self) -> int:
        return 5 if self.snap5_check.isChecked() else 1

    # ================================================================== dragging keys
    def _drag_start(self, channel: str, index: int, modifiers) -> bool:
        if self.doc.scene.composed is None:
            return False
        frame = float(self.curve(channel).frames[index])
        if (channel, frame) not in self.selected:
            if modifiers & (Qt.KeyboardModifier.ShiftModifier |
                            Qt.KeyboardModifier.ControlModifier):
                self.selected.add((channel, frame))
            else:
                self.selected = {(channel, frame)}
        original = self._layer_map()
        keys = self._selected_keys()
        F = self.doc.scene.composed.num_frames
        # how far the selection may move in time: keys never pass an unselected neighbour
        # (strictly) and stay inside the clip
        open_lo, open_hi = -math.inf, math.inf
        closed_lo, closed_hi = -math.inf, math.inf
        for c in {k[0] for k in keys}:
            curve = original.curves[(self.joint, c)]
            sel = np.zeros(len(curve), dtype=bool)
            sel[[i for cc, i in keys if cc == c]] = True
            for i in np.flatnonzero(sel):
                f = curve.frames[i]
                closed_lo, closed_hi = max(closed_lo, -f), min(closed_hi, F - 1 - f)
                left = np.flatnonzero(~sel[:i])
                right = np.flatnonzero(~sel[i + 1:])
                if len(left):
                    open_lo = max(open_lo, curve.frames[left[-1]] - f)
                if len(right):
                    open_hi = min(open_hi, curve.frames[i + 1 + right[0]] - f)
        grabbed = self.curve(channel)
        self._drag = {"original": original, "keys": keys, "channel": channel,
                      "frame": float(grabbed.frames[index]),
                      "value": float(grabbed.values[index] * self.scale),
                      "open": (open_lo, open_hi), "closed": (closed_lo, closed_hi),
                      "map": original, "delta": (0.0, 0.0)}
        self.refresh()
        return True

    def _snapped_delta(self, dx: float, dy: float) -> tuple[float, float]:
        """The selection's move in (frames, display units) for a mouse move of (dx, dy)."""
        d = self._drag
        f0, v0 = d["frame"], d["value"]
        step = self._snap_step()
        target = round((f0 + dx) / step) * step
        open_lo, open_hi = d["open"]
        closed_lo, closed_hi = d["closed"]
        lo = max(math.floor(f0 + open_lo) + 1 if open_lo > -math.inf else -math.inf,
                 math.ceil(f0 + closed_lo - 1e-9))
        hi = min(math.ceil(f0 + open_hi) - 1 if open_hi < math.inf else math.inf,
                 math.floor(f0 + closed_hi + 1e-9))
        if lo > hi:
            dframe = 0.0
        else:
            dframe = float(min(max(target, lo), hi)) - f0
        value = v0 + dy
        if self.snap_value_check.isChecked():
            q = self.value_step.value()
            value = round(value / q) * q
        return dframe, value - v0

    def _moved_map(self, dframe: float, dvalue: float) -> DisplacementMap:
        d = self._drag
        if dframe == 0.0 and dvalue == 0.0:
            return d["original"]
        changed = {}
        for c in {k[0] for k in d["keys"]}:
            curve = d["original"].curves[(self.joint, c)]
            idx = [i for cc, i in d["keys"] if cc == c]
            frames = curve.frames.copy()
            values = curve.values.copy()
            frames[idx] += dframe
            values[idx] += dvalue / self.scale
            changed[c] = curve.moved(frames, values)
        return self._with_curves(d["original"], changed)

    def _drag_move(self, dx: float, dy: float) -> None:
        if self._drag is None:
            return
        delta = self._snapped_delta(dx, dy)
        if delta == self._drag["delta"]:
            return
        self._drag["delta"] = delta
        new_map = self._moved_map(*delta)
        self._drag["map"] = new_map
        self._shown_map = new_map
        self.selected = {(c, f + delta[0]) for c, f in self._drag_frames()}
        self.doc.show_preview(self._scene_with(new_map).motion)
        self.refresh()

    def _drag_frames(self) -> set:
        d = self._drag
        return {(c, float(d["original"].curves[(self.joint, c)].frames[i]))
                for c, i in d["keys"]}

    def _drag_finish(self, dx: float, dy: float) -> None:
        if self._drag is None:
            return
        delta = self._snapped_delta(dx, dy)
        new_map = self._moved_map(*delta)
        keys = self._drag["keys"]
        moved = {(c, f + delta[0]) for c, f in self._drag_frames()}
        self._drag = None
        self._shown_map = None
        if new_map is self._layer_map():
            self.doc.show_preview(None)         # back to the evaluated motion
            return
        self.selected = moved
        self._push(new_map, f"Move {self._what(keys)}")

    def cancel_drag(self) -> None:
        """Abandon a key or tangent drag (Escape): the document shows its own motion again."""
        if self._tangent_drag is not None:
            self._tangent_drag = None
            self._shown_map = None
            self.handles._dragging = None
            self.doc.show_preview(None)
            self.refresh()
            return
        if self._drag is None:
            return
        self.selected = self._drag_frames()
        self._drag = None
        self._shown_map = None
        for graph in self.key_graphs.values():
            graph._dragging = False
        self.doc.show_preview(None)

    @property
    def dragging(self) -> bool:
        """A key or a tangent handle is being dragged (the document shows a preview)."""
        return self._drag is not None or self._tangent_drag is not None

    # ================================================================== other edits
    def add_keys(self, frame: float, channels=None) -> None:
        """Key ``channels`` (default: the visible ones) at ``frame`` with the curve's value
        there, as one command; channels already keyed there are left alone."""
        if self.doc.scene.composed is None:
            return
        frame = float(frame)
        channels = self.visible_channels() if channels is None else list(channels)
        changed, added = {}, []
        for channel in channels:
            curve = self.curve(channel)
            if curve is None:
                curve = Curve([], [])
            if np.any(curve.frames == frame):
                continue
            value = float(curve.evaluate(np.array([frame]))[0])
            i = int(np.searchsorted(curve.frames, frame))
            kind = curve.interpolation[i - 1] if i > 0 else (
                curve.interpolation[0] if len(curve) else "smooth")
            frames = np.insert(curve.frames, i, frame)
            values = np.insert(curve.values, i, value)
            interp = curve.interpolation[:i] + (kind,) + curve.interpolation[i:]
            tangents = curve.tangents[:i] + ("auto",) + curve.tangents[i:]
            slopes = np.insert(curve.slopes, i, (0.0, 0.0), axis=0)
            changed[channel] = Curve(frames, values, interp, tangents, slopes)
            added.append((channel, frame))
        if not changed:
            return
        self.selected = set(added)
        self._push(self._with_curves(self._layer_map(), changed),
                   f"Add {self._what(added)} at frame {frame:g}")

    def add_keys_at_current_frame(self) -> None:
        self.add_keys(self.doc.scene.viewer.current_frame)

    def _add_key_near(self, pos: QtCore.QPointF) -> None:
        """Double-click: key the visible curve nearest ``pos`` (view coordinates) at the whole
        frame there, if the curve passes within a few pixels."""
        if self.doc.scene.composed is None:
            return
        F = self.doc.scene.composed.num_frames
        frame = float(min(max(round(pos.x()), 0), F - 1))
        px = self.view_box.viewPixelSize()[1]
        best, best_d = None, _PICK_PX * px
        for channel in self.visible_channels():
            curve = self.curve(channel)
            value = 0.0 if curve is None else float(curve.evaluate(np.array([pos.x()]))[0])
            d = abs(value * self.scale - pos.y())
            if d <= best_d:
                best, best_d = channel, d
        if best is not None:
            self.add_keys(frame, [best])

    def delete_selected(self) -> None:
        """Delete the selected keys, as one command (a curve left empty is removed)."""
        keys = self._selected_keys()
        if not keys or self._drag is not None:
            return
        changed = {}
        for c in {k[0] for k in keys}:
            curve = self.curve(c)
            keep = np.ones(len(curve), dtype=bool)
            keep[[i for cc, i in keys if cc == c]] = False
            changed[c] = curve.take(keep)
        self.selected = set()
        self._push(self._with_curves(self._layer_map(), changed),
                   f"Delete {self._what(keys)}")

    def set_interpolation(self, kind: str, keys=None) -> None:
        """Set the interpolation of the selected keys (or ``keys``), as one command."""
        if kind not in INTERPOLATIONS:
            raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, not {kind!r}")
        keys = self._selected_keys() if keys is None else list(keys)
        changed = {}
        for c in {k[0] for k in keys}:
            curve = self.curve(c)
            interp = list(curve.interpolation)
            for cc, i in keys:
                if cc == c:
                    interp[i] = kind
            if tuple(interp) != curve.interpolation:
                changed[c] = Curve(curve.frames, curve.values, tuple(interp), curve.tangents,
                                   curve.slopes)
        if not changed:
            return
        self._push(self._with_curves(self._layer_map(), changed),
                   f"Set {self._what(keys)} to {kind}")

    def _interp_chosen(self, index: int) -> None:
        if index >= 0:
            self.set_interpolation(self.interp_combo.itemData(index))

    def _set_single_key(self, frame: float | None = None, value: float | None = None) -> None:
        keys = self._selected_keys()
        if len(keys) != 1:
            return
        c, i = keys[0]
        curve = self.curve(c)
        frames, values = curve.frames.copy(), curve.values.copy()
        if frame is not None:
            lo = curve.frames[i - 1] if i > 0 else -math.inf
            hi = curve.frames[i + 1] if i + 1 < len(curve) else math.inf
            if not lo < frame < hi:                 # would pass a neighbour: refuse
                self._update_key_widgets()
                return
            frames[i] = frame
        if value is not None:
            values[i] = value / self.scale
        if np.array_equal(frames, curve.frames) and np.array_equal(values, curve.values):
            return
        self.selected = {(c, float(frames[i]))}
        verb = "Move" if frame is not None else "Set"
        self._push(self._with_curves(self._layer_map(),
                                     {c: curve.moved(frames, values)}),
                   f"{verb} {self._what(keys)}")

    def _frame_typed(self, frame: int) -> None:
        if frame >= 0:
            self._set_single_key(frame=float(frame))

    def _value_typed(self, value: float) -> None:
        if value > self.value_box.minimum():
            self._set_single_key(value=float(value))

    def _key_menu(self, channel: str, index: int) -> QtWidgets.QMenu:
        """The context menu of a key: interpolation of the selection and delete."""
        frame = float(self.curve(channel).frames[index])
        if (channel, frame) not in self.selected:
            self.set_selection({(channel, frame)})
        menu = QtWidgets.QMenu(self)
        menu.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        kinds = {self.curve(c).interpolation[i] for c, i in self._selected_keys()}
        for kind in INTERPOLATIONS:
            action = menu.addAction(kind.capitalize())
            action.setCheckable(True)
            action.setChecked(kinds == {kind})
            action.triggered.connect(lambda _c=False, k=kind: self.set_interpolation(k))
        menu.addSeparator()
        menu.addAction("Delete", self.delete_selected)
        return menu

    # ================================================================== layers
    def _update_layer_widgets(self) -> None:
        """The layer combo, weight and mute from the document (no signals out)."""
        scene = self.doc.scene
        names = ["solved (IK)"] + [layer.name for layer in scene.layers]
        self.layer = min(self.layer, len(names) - 1)
        with _Blocker(self.layer_combo):
            if [self.layer_combo.itemText(i) for i in range(self.layer_combo.count())] != names:
                self.layer_combo.clear()
                self.layer_combo.addItems(names)
            self.layer_combo.setCurrentIndex(self.layer)
        animator = scene.layers[self.layer - 1] if self.layer else None
        with _Blocker(self.weight_box), _Blocker(self.mute_check):
            self.weight_box.setEnabled(animator is not None)
            self.mute_check.setEnabled(animator is not None)
            self.weight_box.setValue(animator.weight if animator else 1.0)
            self.mute_check.setChecked(bool(animator and animator.mute))

    def set_layer(self, layer: int) -> None:
        """Show and edit layer ``layer`` (0: solved, 1 and up: the animator's)."""
        if layer != self.layer:
            self.selected = set()
        self.layer = layer
        self.refresh()

    def _layer_chosen(self, index: int) -> None:
        if index >= 0:
            self.set_layer(index)

    def _set_animator(self, text: str, merge: str | None = None, **changes) -> None:
        if self.layer == 0:
            return
        layers = list(self.doc.scene.layers)
        layers[self.layer - 1] = layers[self.layer - 1].replace(**changes)
        push_layers(self.doc, layers, text, merge=merge)

    def _weight_typed(self, value: float) -> None:
        name = self.doc.scene.layers[self.layer - 1].name if self.layer else ""
        self._set_animator(f"Set the weight of layer {name} to {value:g}",
                           merge=f"layer weight {self.layer}", weight=float(value))

    def _mute_toggled(self, on: bool) -> None:
        name = self.doc.scene.layers[self.layer - 1].name if self.layer else ""
        self._set_animator(f"{'Mute' if on else 'Unmute'} layer {name}", mute=bool(on))

    def add_layer(self) -> None:
        """Add an empty animator layer on top and edit it (one command)."""
        taken = {layer.name for layer in self.doc.scene.layers}
        n = len(taken) + 1
        while f"edit {n}" in taken:
            n += 1
        layers = list(self.doc.scene.layers) + [Layer(f"edit {n}")]
        self.layer = len(layers)
        self.selected = set()
        push_layers(self.doc, layers, f"Add layer edit {n}")

    # ================================================================== tangents
    def _update_handles(self) -> None:
        """Handles of the selected keys' tangents where a smooth segment meets them."""
        handles, points, anchors = [], [], []
        visible = set(self.visible_channels()) if self.doc.scene.composed is not None else set()
        for channel, i in self._selected_keys():
            if channel not in visible:
                continue
            curve = self.curve(channel)
            slopes = curve.tangent_slopes()
            f, v = curve.frames[i], curve.values[i] * self.scale
            for side in (0, 1):
                j = i - 1 if side == 0 else i + 1
                if not 0 <= j < len(curve):
                    continue
                if curve.interpolation[min(i, j)] != "smooth":
                    continue
                dx = (curve.frames[j] - f) / 3.0
                points.append((f + dx, v + slopes[i, side] * self.scale * dx))
                anchors.append((f, v))
                handles.append((channel, i, side))
        state = (tuple(handles), tuple(points))
        if state != self._drawn.get("handles"):
            self._drawn["handles"] = state
            self.handles.set_handles(handles, points, anchors)

    def handle_scene_pos(self, channel: str, index: int, side: int) -> QtCore.QPointF:
        """Where the handle of key ``index`` of ``channel`` on ``side`` (0 in, 1 out) is
        drawn, in scene coordinates."""
        k = self.handles.handles.index((channel, index, side))
        x, y = self.handles.points[k]
        return self.view_box.mapViewToScene(QtCore.QPointF(float(x), float(y)))

    def set_tangent(self, mode: str, keys=None) -> None:
        """Set the tangent mode of the selected keys (or ``keys``), as one command; aligned
        and broken keys keep the slopes they have now."""
        if mode not in TANGENTS:
            raise ValueError(f"tangent must be one of {TANGENTS}, not {mode!r}")
        keys = self._selected_keys() if keys is None else list(keys)
        changed = {}
        for c in {k[0] for k in keys}:
            curve = self.curve(c)
            for cc, i in keys:
                if cc == c and curve.tangents[i] != mode:
                    curve = curve.with_tangent(i, mode)
            if curve is not self.curve(c):
                changed[c] = curve
        if changed:
            self._push(self._with_curves(self._layer_map(), changed),
                       f"Set the tangents of {self._what(keys)} to {mode}")

    def _tangent_chosen(self, index: int) -> None:
        if index >= 0:
            self.set_tangent(self.tangent_combo.itemData(index))

    def _tangent_drag_start(self, channel: str, index: int, side: int) -> None:
        self._tangent_drag = {"channel": channel, "index": index, "side": side,
                              "original": self._layer_map()}

    def _tangent_map(self, pos) -> DisplacementMap:
        """The edited layer with the dragged handle at ``pos`` (view coordinates): the key's
        slope through it (only that side for a broken key; aligned otherwise)."""
        d = self._tangent_drag
        curve = d["original"].curves[(self.joint, d["channel"])]
        i, side = d["index"], d["side"]
        f, v = curve.frames[i], curve.values[i] * self.scale
        dx = pos.x() - f
        dx = max(dx, 1e-3) if side == 1 else min(dx, -1e-3)     # a handle stays its side
        slope = (pos.y() - v) / dx / self.scale
        now = curve.tangent_slopes()[i]
        if curve.tangents[i] == "broken":
            pair = (slope, now[1]) if side == 0 else (now[0], slope)
            new = curve.with_tangent(i, "broken", pair)
        else:
            new = curve.with_tangent(i, "aligned", (slope, slope))
        return self._with_curves(d["original"], {d["channel"]: new})

    def _tangent_drag_move(self, pos) -> None:
        if self._tangent_drag is None:
            return
        new_map = self._tangent_map(pos)
        self._shown_map = new_map
        self.doc.show_preview(self._scene_with(new_map).motion)
        self.refresh()

    def _tangent_drag_finish(self, pos) -> None:
        if self._tangent_drag is None:
            return
        new_map = self._tangent_map(pos)
        d = self._tangent_drag
        self._tangent_drag = None
        self._shown_map = None
        keys = [(d["channel"], d["index"])]
        self._push(new_map, f"Set the tangent of {self._what(keys)}")
