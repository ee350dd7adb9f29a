"""The correspondence editor: which performer joint drives each target joint.

Both hierarchies stand side by side as trees (target left, performer right) with a line from
each mapped target joint to its performer joint; below them the mapping is a table (target
joint, performer joint, the auto-mapping note) whose performer cell is edited in place through
a combo box. Joints are mapped by dragging a joint onto one of the other tree, or by selecting
one in each tree and pressing *Map*; *Auto-map*, *Unmap*, *Clear* and mapping presets (JSON,
:meth:`engine.conversion.correspondence.Correspondence.load`/``save``) complete it.

The panel is built from a :class:`~app.gui.document.Document` and wired both ways (napari's
rule): document signals update the widgets inside ``QSignalBlocker`` (no feedback loop), and
every user edit is one undoable command pushed through :mod:`app.gui.commands`. Changing the
mapping re-evaluates the document, which the viewport follows.

Required target joints (hips, both spine ends, head, upper arms, elbows, wrists, thighs, knees
and ankles, as :func:`engine.conversion.automap.identify` finds them) left unmapped are flagged in red, and
the document's ``evaluation_error`` (an impossible mapping) is shown under the trees.

File dialogs and message boxes go through :meth:`CorrespondencePanel.ask_load_path`,
:meth:`CorrespondencePanel.ask_save_path` and :meth:`CorrespondencePanel.show_error`, so tests
(and a host window) can replace them.
"""
from __future__ import annotations

from pathlib import Path

from motion_composer.app.gui.commands import push_correspondence
from motion_composer.app.gui.qt import QtCore, QtGui, QtWidgets
from motion_composer.engine.conversion.correspondence import BY_HAND, Correspondence
from motion_composer.engine.errors import MotionComposerError

__all__ = ["CorrespondencePanel", "JointTree", "LinkView", "MappingModel", "MappingTable",
           "required_joints", "REQUIRED_ROLES", "MIME_TYPE"]

Qt = QtCore.Qt

#: drag and drop payload: ``"<side>\n<joint name>"`` in UTF-8
MIME_TYPE = "application/x-motion-composer-joint"

#: the roles (keys of :class:`engine.conversion.automap.Roles`) a target must have mapped, with labels;
#: the first spine joint (``spine0``) is added from ``Roles.spine``
REQUIRED_ROLES = {
    "hips": "hips", "chest": "chest (top of the spine)", "head": "head",
    "upper_arm_l": "left upper arm", "upper_arm_r": "right upper arm",
    "forearm_l": "left elbow", "forearm_r": "right elbow",
    "hand_l": "left wrist", "hand_r": "right wrist",
    "thigh_l": "left thigh", "thigh_r": "right thigh",
    "shin_l": "left knee", "shin_r": "right knee",
    "foot_l": "left ankle", "foot_r": "right ankle",
}

NAME_ROLE = Qt.ItemDataRole.UserRole
#: per tree item: ``"mapped"``, ``"required"`` (target joint required and unmapped) or
#: ``"unmapped"``
STATE_ROLE = Qt.ItemDataRole.UserRole + 1

_RED = QtGui.QColor("#c62828")
_GREEN = QtGui.QColor("#2e7d32")
_LINK = QtGui.QColor(70, 120, 190, 170)
_LINK_SELECTED = QtGui.QColor("#ef6c00")


def required_joints(skeleton) -> dict[str, str]:
    """Target joint name -> what it is, for the joints a usable mapping should cover.

    The roles come from :func:`engine.conversion.automap.identify`; where it is not available or finds no
    humanoid, only the root is required.
    """
    if skeleton is None:
        return {}
    fallback = {skeleton.names[0]: "root"}
    try:
        from motion_composer.engine.conversion.automap import identify
    except ImportError:
        return fallback
    try:
        roles = identify(skeleton)
    except Exception:       # noqa: BLE001 - not humanoid (MappingError) or anything else:
        return fallback     # the panel must keep working on any skeleton
    out: dict[str, str] = {}
    for key, label in REQUIRED_ROLES.items():
        if key in roles:
            out.setdefault(roles[key], label)
    if roles.spine:
        out.setdefault(roles.spine[0], "spine base")
    return out or fallback


def _map_command(doc, target: str, performer: str | None) -> bool:
    """Push "Map <target> to <performer>" (or "Unmap <target>"): one undoable command. A
    performer joint already driving another target joint is taken from it. The pair's note
    says it was set by hand (``with_pair`` would keep a stale auto-mapping note); a pair the
    map loses that way is named in the command and in a note for the status bar."""
    corr = doc.scene.correspondence
    if corr.performer_of(target) == performer:
        return False
    new = corr.with_pair(target, performer)
    notes = dict(new.notes)
    if performer is not None:
        notes[target] = BY_HAND
    text = f"Map {target} to {performer}" if performer else f"Unmap {target}"
    previous = corr.target_of(performer) if performer is not None else None
    if previous is not None and previous != target:
        # one to one: the other target joint loses this performer joint; say so
        text += f" (replaces {previous} -> {performer})"
        doc.noted.emit(f"{performer} drove {previous}; {previous} is now unmapped")
    push_correspondence(doc, Correspondence(new.pairs, notes), text)
    return True


def _dot_icon(fill: QtGui.QColor | None, outline: QtGui.QColor, mark: str = "") -> QtGui.QIcon:
    size = 14
    pixmap = QtGui.QPixmap(size, size)
    pixmap.fill(Qt.GlobalColor.transparent)
    painter = QtGui.QPainter(pixmap)
    painter.setRenderHint(QtGui.QPainter.RenderHint.Antialiasing)
    painter.setPen(QtGui.QPen(outline, 1.4))
    painter.setBrush(fill if fill is not None else Qt.BrushStyle.NoBrush)
    painter.drawEllipse(QtCore.QRectF(2, 2, size - 4, size - 4))
    if mark:
        font = painter.font()
        font.setBold(True)
        font.setPixelSize(9)
        painter.setFont(font)
        painter.setPen(QtGui.QColor("white"))
        painter.drawText(QtCore.QRectF(0, 0, size, size), Qt.AlignmentFlag.AlignCenter, mark)
    painter.end()
    return QtGui.QIcon(pixmap)


# ============================================================================ trees
class JointTree(QtWidgets.QTreeWidget):
    """One skeleton's hierarchy. Items carry their joint name (``NAME_ROLE``) and mapping
    state (``STATE_ROLE``). A joint dragged from the other tree and dropped on an item emits
    :attr:`jointDropped`."""

    #: (joint dropped on, the dragged joint's side, the dragged joint's name)
    jointDropped = QtCore.Signal(str, str, str)

    def __init__(self, side: str, parent=None):
        super().__init__(parent)
        self.side = side
        self.items: dict[str, QtWidgets.QTreeWidgetItem] = {}
        self._drop_item: QtWidgets.QTreeWidgetItem | None = None
        self.setColumnCount(1)
        self.setHeaderLabels([side.capitalize()])
        self.setSelectionMode(QtWidgets.QAbstractItemView.SelectionMode.SingleSelection)
        self.setDragEnabled(True)
        self.setAcceptDrops(True)
        self.viewport().setAcceptDrops(True)
        self.setDragDropMode(QtWidgets.QAbstractItemView.DragDropMode.DragDrop)
        self.setDropIndicatorShown(False)
        self.setUniformRowHeights(True)
        self.setIndentation(12)
        self.setIconSize(QtCore.QSize(14, 14))
        self.setMinimumWidth(120)
        self._icons = {"mapped": _dot_icon(_GREEN, _GREEN),
                       "required": _dot_icon(_RED, _RED, "!"),
                       "unmapped": _dot_icon(None, QtGui.QColor(150, 150, 150))}

    # ------------------------------------------------------------------ content
    def build(self, skeleton, title: str) -> None:
        """Fill the tree from ``skeleton`` (or empty it for ``None``), all expanded."""
        with QtCore.QSignalBlocker(self):
            self.clear()
            self.items = {}
            self.setHeaderLabels([title])
            if skeleton is None:
                return
            flags = (Qt.ItemFlag.ItemIsEnabled | Qt.ItemFlag.ItemIsSelectable |
                     Qt.ItemFlag.ItemIsDragEnabled | Qt.ItemFlag.ItemIsDropEnabled)
            for j, name in enumerate(skeleton.names):
                item = QtWidgets.QTreeWidgetItem([name])
                item.setData(0, NAME_ROLE, name)
                item.setFlags(flags)
                parent = int(skeleton.parents[j])
                if parent < 0:
                    self.addTopLevelItem(item)
                else:
                    self.items[skeleton.names[parent]].addChild(item)
                self.items[name] = item
            self.expandAll()

    def set_state(self, name: str, state: str, tooltip: str) -> None:
        item = self.items[name]
        item.setData(0, STATE_ROLE, state)
        item.setIcon(0, self._icons[state])
        item.setToolTip(0, tooltip)
        font = item.font(0)
        font.setBold(state == "required")
        item.setFont(0, font)
        if state == "required":
            item.setForeground(0, QtGui.QBrush(_RED))
        elif state == "unmapped":
            item.setForeground(0, self.palette().brush(QtGui.QPalette.ColorGroup.Disabled,
                                                       QtGui.QPalette.ColorRole.Text))
        else:
            item.setForeground(0, self.palette().brush(QtGui.QPalette.ColorRole.Text))

    def state(self, name: str) -> str | None:
        item = self.items.get(name)
        return None if item is None else item.data(0, STATE_ROLE)

    def selected_joint(self) -> str | None:
        items = self.selectedItems()
        return items[0].data(0, NAME_ROLE) if items else None

    def select_joint(self, name: str | None, scroll: bool = True) -> None:
        """Select ``name`` (or nothing); the caller blocks signals."""
        item = self.items.get(name) if name else None
        if item is None:
            self.clearSelection()
            self.setCurrentItem(None)
            return
        self.setCurrentItem(item)
        item.setSelected(True)
        if scroll:
            self.scrollToItem(item)

    def apply_filter(self, text: str) -> None:
        """Hide the items whose name does not contain ``text`` (case-insensitive), keeping
        the ancestors of matches; an empty text shows everything."""
        needle = text.strip().lower()

        def visit(item) -> bool:
            below = [visit(item.child(i)) for i in range(item.childCount())]
            keep = not needle or needle in item.data(0, NAME_ROLE).lower() or any(below)
            item.setHidden(not keep)
            return keep

        for i in range(self.topLevelItemCount()):
            visit(self.topLevelItem(i))
        if needle:
            self.expandAll()

    def is_shown(self, name: str) -> bool:
        """Whether the joint's item is visible (not filtered out, all ancestors expanded)."""
        item = self.items.get(name)
        if item is None or item.isHidden():
            return False
        parent = item.parent()
        while parent is not None:
            if parent.isHidden() or not parent.isExpanded():
                return False
            parent = parent.parent()
        return True

    def item_centre_y(self, name: str) -> int | None:
        """The y of the joint's row centre in viewport coordinates, or ``None`` where the row
        is not on screen (filtered out, collapsed away or scrolled out of view)."""
        if not self.is_shown(name):
            return None
        rect = self.visualItemRect(self.items[name])
        if not rect.isValid():
            return None
        y = rect.center().y()
        if y < 0 or y > self.viewport().height():
            return None
        return y

    # ------------------------------------------------------------------ drag and drop
    def startDrag(self, supported_actions) -> None:     # noqa: N802 - Qt's name
        name = self.selected_joint()
        if name is None:
            return
        drag = QtGui.QDrag(self)
        drag.setMimeData(self.mime_data(self.side, name))
        drag.setPixmap(_drag_pixmap(name, self.font()))
        drag.exec(Qt.DropAction.LinkAction | Qt.DropAction.CopyAction, Qt.DropAction.LinkAction)

    @staticmethod
    def mime_data(side: str, name: str) -> QtCore.QMimeData:
        """The drag payload of joint ``name`` of tree ``side``."""
        mime = QtCore.QMimeData()
        mime.setData(MIME_TYPE, QtCore.QByteArray(f"{side}\n{name}".encode("utf-8")))
        mime.setText(name)
        return mime

    @staticmethod
    def decode(mime: QtCore.QMimeData) -> tuple[str, str] | None:
        if mime is None or not mime.hasFormat(MIME_TYPE):
            return None
        side, _, name = bytes(mime.data(MIME_TYPE)).decode("utf-8").partition("\n")
        return (side, name) if name else None

    def _drop_target(self, event) -> QtWidgets.QTreeWidgetItem | None:
        payload = self.decode(event.mimeData())
        if payload is None or payload[0] == self.side:
            return None
        return self.itemAt(event.position().toPoint())

    def _set_drop_item(self, item) -> None:
        if item is self._drop_item:
            return
        if self._drop_item is not None:
            self._drop_item.setBackground(0, QtGui.QBrush())
        self._drop_item = item
        if item is not None:
            item.setBackground(0, QtGui.QBrush(QtGui.QColor(239, 108, 0, 70)))

    def dragEnterEvent(self, event) -> None:             # noqa: N802
        payload = self.decode(event.mimeData())
        if payload is not None and payload[0] != self.side:
            event.acceptProposedAction()
        else:
            event.ignore()

    def dragMoveEvent(self, event) -> None:              # noqa: N802
        super().dragMoveEvent(event)                     # auto-scroll near the edges
        item = self._drop_target(event)
        self._set_drop_item(item)
        if item is not None:
            event.setDropAction(Qt.DropAction.LinkAction)
            event.accept()
        else:
            event.ignore()

    def dragLeaveEvent(self, event) -> None:             # noqa: N802
        self._set_drop_item(None)
        super().dragLeaveEvent(event)

    def dropEvent(self, event) -> None:                  # noqa: N802
        self._set_drop_item(None)
        self.stopAutoScroll()
        self.setState(QtWidgets.QAbstractItemView.State.NoState)
        item = self._drop_target(event)
        if item is None:
            event.ignore()
            return
        side, name = self.decode(event.mimeData())
        event.setDropAction(Qt.DropAction.LinkAction)
        event.accept()
        self.jointDropped.emit(item.data(0, NAME_ROLE), side, name)


def _drag_pixmap(text: str, font: QtGui.QFont) -> QtGui.QPixmap:
    metrics = QtGui.QFontMetrics(font)
    w, h = metrics.horizontalAdvance(text) + 16, metrics.height() + 8
    pixmap = QtGui.QPixmap(w, h)
    pixmap.fill(Qt.GlobalColor.transparent)
    painter = QtGui.QPainter(pixmap)
    painter.setRenderHint(QtGui.QPainter.RenderHint.Antialiasing)
    painter.setBrush(QtGui.QColor(239, 108, 0, 220))
    painter.setPen(Qt.PenStyle.NoPen)
    painter.drawRoundedRect(QtCore.QRectF(0, 0, w, h), 5, 5)
    painter.setFont(font)
    painter.setPen(QtGui.QColor("white"))
    painter.drawText(QtCore.QRectF(0, 0, w, h), Qt.AlignmentFlag.AlignCenter, text)
    painter.end()
    return pixmap


# ============================================================================ lines
class LinkView(QtWidgets.QWidget):
    """The strip between the trees: a curve from each mapped target row to its performer row
    (only where both rows are on screen), the selected pairs highlighted. Positions are
    recomputed at every paint, so scrolling, expanding, filtering and resizing only need an
    ``update()``."""

    def __init__(self, panel: "CorrespondencePanel"):
        super().__init__(panel)
        self.panel = panel
        self.setMinimumWidth(40)
        self.setFixedWidth(72)
        self.setAttribute(Qt.WidgetAttribute.WA_OpaquePaintEvent, False)

    def _y(self, tree: JointTree, name: str) -> float | None:
        y = tree.item_centre_y(name)
        if y is None:
            return None
        point = tree.viewport().mapToGlobal(QtCore.QPoint(0, y))
        return float(self.mapFromGlobal(point).y())

    def segments(self) -> list[tuple[str, str, float, float, bool]]:
        """``(target, performer, y_target, y_performer, selected)`` per drawn line, in this
        widget's coordinates."""
        panel = self.panel
        selected = set(panel.table.selected_targets())
        out = []
        for target, performer in panel.doc.scene.correspondence.pairs.items():
            y0 = self._y(panel.target_tree, target)
            y1 = self._y(panel.performer_tree, performer)
            if y0 is None or y1 is None:
                continue
            out.append((target, performer, y0, y1, target in selected))
        return out

    def paintEvent(self, event) -> None:                 # noqa: N802
        painter = QtGui.QPainter(self)
        painter.setRenderHint(QtGui.QPainter.RenderHint.Antialiasing)
        w = float(self.width())
        segments = sorted(self.segments(), key=lambda s: s[4])     # selected on top
        for _t, _p, y0, y1, selected in segments:
            color = _LINK_SELECTED if selected else _LINK
            painter.setPen(QtGui.QPen(color, 2.6 if selected else 1.3))
            path = QtGui.QPainterPath(QtCore.QPointF(0.0, y0))
            path.lineTo(4.0, y0)
            path.cubicTo(w / 2, y0, w / 2, y1, w - 4.0, y1)
            path.lineTo(w, y1)
            painter.setBrush(Qt.BrushStyle.NoBrush)
            painter.drawPath(path)
            painter.setBrush(color)
            painter.setPen(Qt.PenStyle.NoPen)
            r = 3.0 if selected else 2.2
            painter.drawEllipse(QtCore.QPointF(r, y0), r, r)
            painter.drawEllipse(QtCore.QPointF(w - r, y1), r, r)
        painter.end()


# ============================================================================ table
class MappingModel(QtCore.QAbstractTableModel):
    """The mapping as rows ``(target joint, performer joint, note)`` in target joint order: a
    thin adapter over the document's :class:`Correspondence`. Editing the performer cell pushes
    one command (an empty value unmaps)."""

    HEADERS = ("Target joint", "Performer joint", "Note")

    def __init__(self, document, parent=None):
        super().__init__(parent)
        self.doc = document
        self.rows: list[tuple[str, str, str]] = []

    def reload(self) -> None:
        corr = self.doc.scene.correspondence
        order = self.doc.scene.target.skeleton.index if self.doc.scene.target is not None else {}
        targets = sorted(corr.pairs, key=lambda t: order.get(t, len(order)))
        self.beginResetModel()
        self.rows = [(t, corr.pairs[t], corr.notes.get(t, "")) for t in targets]
        self.endResetModel()

    def row_of(self, target: str) -> int | None:
        for i, row in enumerate(self.rows):
            if row[0] == target:
                return i
        return None

    # Qt interface
    def rowCount(self, parent=QtCore.QModelIndex()) -> int:       # noqa: N802
        return 0 if parent.isValid() else len(self.rows)

    def columnCount(self, parent=QtCore.QModelIndex()) -> int:    # noqa: N802
        return 0 if parent.isValid() else len(self.HEADERS)

    def headerData(self, section, orientation, role=Qt.ItemDataRole.DisplayRole):  # noqa: N802
        if orientation == Qt.Orientation.Horizontal and role == Qt.ItemDataRole.DisplayRole:
            return self.HEADERS[section]
        return None

    def data(self, index, role=Qt.ItemDataRole.DisplayRole):
        if not index.isValid():
            return None
        row = self.rows[index.row()]
        if role in (Qt.ItemDataRole.DisplayRole, Qt.ItemDataRole.EditRole):
            return row[index.column()]
        if role == Qt.ItemDataRole.ToolTipRole:
            if index.column() == 1:
                return "Double-click to choose another performer joint"
            return row[2] or None
        return None

    def flags(self, index):
        flags = Qt.ItemFlag.ItemIsEnabled | Qt.ItemFlag.ItemIsSelectable
        if index.column() == 1:
            flags |= Qt.ItemFlag.ItemIsEditable
        return flags

    def setData(self, index, value, role=Qt.ItemDataRole.EditRole) -> bool:  # noqa: N802
        if role != Qt.ItemDataRole.EditRole or index.column() != 1 or not index.isValid():
            return False
        target = self.rows[index.row()][0]
        performer = str(value) if value else None
        if performer is not None and (self.doc.scene.performer is None or
                                      performer not in self.doc.scene.performer.skeleton.index):
            return False
        # the command re-evaluates and the panel reloads this model (an open editor is
        # released by the reset; Qt then skips closing it again)
        return _map_command(self.doc, target, performer)


class PerformerDelegate(QtWidgets.QStyledItemDelegate):
    """The performer cell's editor: a combo box of the performer's joints (indented by depth,
    each marked with the target joint it already drives) plus "(unmapped)"; choosing commits."""

    UNMAPPED = "(unmapped)"

    def __init__(self, document, parent=None):
        super().__init__(parent)
        self.doc = document

    def createEditor(self, parent, option, index):       # noqa: N802
        combo = QtWidgets.QComboBox(parent)
        combo.addItem(self.UNMAPPED, "")
        if self.doc.scene.performer is not None:
            sk = self.doc.scene.performer.skeleton
            driven = {p: t for t, p in self.doc.scene.correspondence.pairs.items()}
            for j, name in enumerate(sk.names):
                text = "  " * int(sk.depth[j]) + name
                if name in driven:
                    text += f"   \u2190 {driven[name]}"
                combo.addItem(text, name)
        combo.setMaxVisibleItems(24)
        combo.activated.connect(lambda _i, c=combo: self._commit(c))
        return combo

    def _commit(self, combo) -> None:
        self.commitData.emit(combo)
        self.closeEditor.emit(combo, QtWidgets.QAbstractItemDelegate.EndEditHint.NoHint)

    def setEditorData(self, editor, index) -> None:      # noqa: N802
        i = editor.findData(index.data(Qt.ItemDataRole.EditRole) or "")
        editor.setCurrentIndex(max(i, 0))

    def setModelData(self, editor, model, index) -> None:    # noqa: N802
        model.setData(index, editor.currentData() or "", Qt.ItemDataRole.EditRole)


class MappingTable(QtWidgets.QTableView):
    """The mapping table; emits :attr:`targetsSelected` from its own selection (so the panel
    can block that signal without blocking the view's repaint of the selection)."""

    targetsSelected = QtCore.Signal(list)

    def __init__(self, model: MappingModel, parent=None):
        super().__init__(parent)
        self.setModel(model)
        self.setSelectionBehavior(QtWidgets.QAbstractItemView.SelectionBehavior.SelectRows)
        self.setSelectionMode(QtWidgets.QAbstractItemView.SelectionMode.ExtendedSelection)
        self.setEditTriggers(QtWidgets.QAbstractItemView.EditTrigger.DoubleClicked |
                             QtWidgets.QAbstractItemView.EditTrigger.SelectedClicked |
                             QtWidgets.QAbstractItemView.EditTrigger.EditKeyPressed)
        self.setAlternatingRowColors(True)
        self.setWordWrap(False)
        self.setTextElideMode(Qt.TextElideMode.ElideRight)
        self.verticalHeader().setVisible(False)
        self.verticalHeader().setDefaultSectionSize(self.fontMetrics().height() + 6)
        header = self.horizontalHeader()
        header.setSectionResizeMode(0, QtWidgets.QHeaderView.ResizeMode.ResizeToContents)
        header.setSectionResizeMode(1, QtWidgets.QHeaderView.ResizeMode.ResizeToContents)
        header.setSectionResizeMode(2, QtWidgets.QHeaderView.ResizeMode.Stretch)
        header.setHighlightSections(False)

    def selected_targets(self) -> list[str]:
        model = self.model()
        rows = sorted({i.row() for i in self.selectionModel().selectedRows()})
        return [model.rows[r][0] for r in rows if r < len(model.rows)]

    def select_targets(self, targets) -> None:
        """Select the rows of ``targets`` (the caller blocks this view's signals)."""
        model = self.model()
        selection = QtCore.QItemSelection()
        last = None
        for t in targets:
            r = model.row_of(t)
            if r is not None:
                selection.select(model.index(r, 0), model.index(r, model.columnCount() - 1))
                last = r
        flags = (QtCore.QItemSelectionModel.SelectionFlag.ClearAndSelect |
                 QtCore.QItemSelectionModel.SelectionFlag.Rows)
        self.selectionModel().select(selection, flags)
        if last is not None:
            index = model.index(last, 0)
            self.selectionModel().setCurrentIndex(
                index, QtCore.QItemSelectionModel.SelectionFlag.NoUpdate)
            self.scrollTo(index)

    def selectionChanged(self, selected, deselected) -> None:     # noqa: N802
        super().selectionChanged(selected, deselected)
        self.targetsSelected.emit(self.selected_targets())


# ============================================================================ the panel
class CorrespondencePanel(QtWidgets.QWidget):
    """The correspondence editor of the composer window, built from a document."""

    def __init__(self, document, parent=None):
        super().__init__(parent)
        self.doc = document
        self.required: dict[str, str] = {}
        self._build()
        document.sourcesChanged.connect(self._sources_changed)
        document.mappingChanged.connect(self._mapping_changed)
        document.motionChanged.connect(self._motion_changed)
        document.selectionChanged.connect(self._selection_changed)
        self._sources_changed()
        self._motion_changed()
        if any(document.selection):        # a panel built after a joint was selected
            self._selection_changed(*document.selection)

    # ------------------------------------------------------------------ building
    def _make_action(self, text: str, slot, tip: str, shortcut=None) -> QtGui.QAction:
        action = QtGui.QAction(text, self)
        action.setToolTip(tip)
        action.setStatusTip(tip)
        if shortcut is not None:
            action.setShortcut(QtGui.QKeySequence(shortcut))
            action.setShortcutContext(Qt.ShortcutContext.WidgetWithChildrenShortcut)
        action.triggered.connect(lambda _checked=False: slot())
        self.addAction(action)
        return action

    @staticmethod
    def _button(action: QtGui.QAction) -> QtWidgets.QToolButton:
        button = QtWidgets.QToolButton()
        button.setDefaultAction(action)
        button.setToolButtonStyle(Qt.ToolButtonStyle.ToolButtonTextOnly)
        return button

    def _build(self) -> None:
        self.automap_action = self._make_action(
            "Auto-map", self.auto_map, "Map every joint whose role both skeletons have")
        self.map_action = self._make_action(
            "Map", self.map_selected, "Map the selected target joint to the selected "
            "performer joint (or drag a joint onto the other tree)")
        self.unmap_action = self._make_action(
            "Unmap", self.unmap_selected, "Unmap the selected pairs",
            QtGui.QKeySequence.StandardKey.Delete)
        self.clear_action = self._make_action("Clear", self.clear, "Unmap every joint")
        self.load_action = self._make_action(
            "Load preset...", self.load_preset, "Load a mapping preset (JSON)")
        self.save_action = self._make_action(
            "Save preset...", self.save_preset, "Save this mapping as a preset (JSON)")

        self.automap_button = self._button(self.automap_action)
        self.map_button = self._button(self.map_action)
        self.unmap_button = self._button(self.unmap_action)
        self.clear_button = self._button(self.clear_action)
        self.load_button = self._button(self.load_action)
        self.save_button = self._button(self.save_action)

        self.filter_edit = QtWidgets.QLineEdit()
        self.filter_edit.setPlaceholderText("Filter joints by name")
        self.filter_edit.setClearButtonEnabled(True)
        self.filter_edit.textChanged.connect(self._filter_changed)

        self.target_tree = JointTree("target")
        self.performer_tree = JointTree("performer")
        self.links = LinkView(self)
        for tree in (self.target_tree, self.performer_tree):
            tree.itemSelectionChanged.connect(
                lambda t=tree: self._tree_selection_changed(t))
            tree.jointDropped.connect(self._joint_dropped)
            tree.verticalScrollBar().valueChanged.connect(lambda _v: self.links.update())
            tree.itemExpanded.connect(lambda _i: self.links.update())
            tree.itemCollapsed.connect(lambda _i: self.links.update())
            tree.viewport().installEventFilter(self)
            tree.addAction(self.map_action)
            tree.addAction(self.unmap_action)
            tree.setContextMenuPolicy(Qt.ContextMenuPolicy.ActionsContextMenu)

        self.model = MappingModel(self.doc, self)
        self.table = MappingTable(self.model)
        self.table.setItemDelegateForColumn(1, PerformerDelegate(self.doc, self.table))
        self.table.targetsSelected.connect(self._table_selection_changed)
        self.table.addAction(self.unmap_action)
        self.table.setContextMenuPolicy(Qt.ContextMenuPolicy.ActionsContextMenu)

        self.summary_label = QtWidgets.QLabel()
        self.required_label = QtWidgets.QLabel()
        self.required_label.setWordWrap(True)
        self.required_label.setStyleSheet(f"color: {_RED.name()};")
        self.error_label = QtWidgets.QLabel()
        self.error_label.setWordWrap(True)
        self.error_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.error_label.setStyleSheet(
            f"color: {_RED.name()}; background: rgba(198, 40, 40, 24); padding: 3px;")

        # layout
        buttons = QtWidgets.QHBoxLayout()
        buttons.setSpacing(4)
        for b in (self.automap_button, self.map_button, self.unmap_button, self.clear_button):
            buttons.addWidget(b)
        buttons.addStretch(1)
        presets = QtWidgets.QHBoxLayout()
        presets.setSpacing(4)
        presets.addWidget(self.filter_edit, 1)
        presets.addWidget(self.load_button)
        presets.addWidget(self.save_button)

        trees = QtWidgets.QHBoxLayout()
        trees.setSpacing(0)
        trees.setContentsMargins(0, 0, 0, 0)
        trees.addWidget(self.target_tree, 1)
        trees.addWidget(self.links)
        trees.addWidget(self.performer_tree, 1)

        top = QtWidgets.QWidget()
        top_layout = QtWidgets.QVBoxLayout(top)
        top_layout.setContentsMargins(0, 0, 0, 0)
        top_layout.setSpacing(3)
        top_layout.addLayout(trees, 1)
        top_layout.addWidget(self.summary_label)
        top_layout.addWidget(self.required_label)
        top_layout.addWidget(self.error_label)

        self.splitter = QtWidgets.QSplitter(Qt.Orientation.Vertical)
        self.splitter.addWidget(top)
        self.splitter.addWidget(self.table)
        self.splitter.setStretchFactor(0, 3)
        self.splitter.setStretchFactor(1, 2)
        self.splitter.setChildrenCollapsible(False)
        self.splitter.setSizes([640, 260])              # the trees get most of the height

        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(4, 4, 4, 4)
        layout.setSpacing(4)
        layout.addLayout(buttons)
        layout.addLayout(presets)
        layout.addWidget(self.splitter, 1)

    def sizeHint(self) -> QtCore.QSize:                  # noqa: N802
        return QtCore.QSize(460, 720)

    def eventFilter(self, watched, event) -> bool:       # noqa: N802
        if event.type() in (QtCore.QEvent.Type.Resize, QtCore.QEvent.Type.Show):
            self.links.update()
        return False

    # ------------------------------------------------------------------ document -> widgets
    def _sources_changed(self) -> None:
        doc = self.doc
        self.required = required_joints(doc.scene.target.skeleton if doc.scene.target is not None else None)
        self.target_tree.build(doc.scene.target.skeleton if doc.scene.target is not None else None,
                               self._title("Target", doc.scene.target, doc.scene.target_path))
        self.performer_tree.build(doc.scene.performer.skeleton if doc.scene.performer is not None else None,
                                  self._title("Performer", doc.scene.performer, doc.scene.performer_path))
        self.target_tree.apply_filter(self.filter_edit.text())
        self.performer_tree.apply_filter(self.filter_edit.text())
        self._mapping_changed()

    @staticmethod
    def _title(side: str, motion, path) -> str:
        if motion is None:
            return f"{side} (none loaded)"
        name = Path(path).stem if path else motion.name
        return f"{side}: {name}"

    def _mapping_changed(self) -> None:
        with QtCore.QSignalBlocker(self.table):
            self.model.reload()
        self._refresh_marks()
        self._selection_changed(*self.doc.selection)
        self._update_actions()
        self.links.update()

    def _carried(self) -> dict:
        """Target joint -> what carries it, for the control joints the binding carries with
        the limbs (:mod:`engine.conversion.followers`); empty without a binding."""
        binding = self.doc.scene.binding
        if binding is None:
            return {}
        tsk, psk = binding.target, binding.performer
        return {tsk.names[f.joint]: (tsk.names[f.anchor],
                                     psk.names[f.source] if f.source >= 0 else None)
                for f in binding.followers}

    def _refresh_marks(self) -> None:
        corr = self.doc.scene.correspondence
        driven = {p: t for t, p in corr.pairs.items()}
        carried = self._carried()
        with QtCore.QSignalBlocker(self.target_tree):
            for name in self.target_tree.items:
                performer = corr.performer_of(name)
                role = self.required.get(name)
                if performer is not None:
                    tip = f"{name} is driven by performer joint {performer}"
                    note = corr.notes.get(name)
                    if note:
                        tip += f"\n{note}"
                    self.target_tree.set_state(name, "mapped", tip)
                elif role is not None:
                    self.target_tree.set_state(
                        name, "required", f"{name} ({role}) is required and unmapped: map it "
                        "to a performer joint")
                elif name in carried:
                    anchor, source = carried[name]
                    turn = (f"turned as performer joint {source}" if source else
                            f"turned with {anchor}")
                    self.target_tree.set_state(
                        name, "unmapped", f"{name} is a control joint: unmapped, it is carried "
                        f"with {anchor}, {turn}")
                else:
                    self.target_tree.set_state(
                        name, "unmapped", f"{name} is unmapped: it follows its parent")
        with QtCore.QSignalBlocker(self.performer_tree):
            for name in self.performer_tree.items:
                if name in driven:
                    self.performer_tree.set_state(
                        name, "mapped", f"{name} drives target joint {driven[name]}")
                else:
                    self.performer_tree.set_state(
                        name, "unmapped", f"{name} is not used by the mapping")
        missing = self.unmapped_required()
        n_target = len(self.target_tree.items)
        if n_target:
            mapped = sum(1 for t in corr.pairs if t in self.target_tree.items)
            self.summary_label.setText(f"{mapped} of {n_target} target joints mapped")
        else:
            self.summary_label.setText("Import a target and a performer to map their joints")
        if missing:
            named = [f"{t} ({self.required[t]})" for t in missing]
            shown = ", ".join(named[:4])
            if len(named) > 4:
                shown += f" and {len(named) - 4} more"
            self.required_label.setText(
                f"{len(missing)} required joint{'s' if len(missing) > 1 else ''} unmapped: "
                f"{shown}")
            self.required_label.setToolTip("Required and unmapped:\n" + "\n".join(named))
        self.required_label.setVisible(bool(missing))

    def unmapped_required(self) -> list[str]:
        """Required target joints that are unmapped, in joint order."""
        pairs = self.doc.scene.correspondence.pairs
        return [t for t in self.target_tree.items if t in self.required and t not in pairs]

    def _motion_changed(self) -> None:
        error = self.doc.scene.evaluation_error
        self.error_label.setText(f"The mapping cannot drive the target: {error}" if error
                                 else "")
        self.error_label.setVisible(bool(error))

    def _selection_changed(self, side: str, joint: str) -> None:
        """Show the document's selection: the joint in its tree; for a target joint its
        performer joint too; the pair's table row and line highlighted."""
        corr = self.doc.scene.correspondence
        pair = None
        if side == "target" and joint:
            pair = joint if joint in corr.pairs else None
        elif side == "performer" and joint:
            pair = next((t for t, p in corr.pairs.items() if p == joint), None)
        with QtCore.QSignalBlocker(self.target_tree), \
                QtCore.QSignalBlocker(self.performer_tree), QtCore.QSignalBlocker(self.table):
            if not side or not joint:
                self.target_tree.select_joint(None)
                self.performer_tree.select_joint(None)
                self.table.select_targets([])
            elif side == "target":
                self.target_tree.select_joint(joint)
                if pair is not None:
                    self.performer_tree.select_joint(corr.pairs[pair])
                if joint not in self.table.selected_targets():
                    self.table.select_targets([pair] if pair else [])
            else:
                # keep the target tree's selection: the user is picking a pair to map
                self.performer_tree.select_joint(joint)
                if pair is None or pair not in self.table.selected_targets():
                    self.table.select_targets([pair] if pair else [])
        self._update_actions()
        self.links.update()

    def _update_actions(self) -> None:
        doc = self.doc
        both = doc.scene.target is not None and doc.scene.performer is not None
        target = self.target_tree.selected_joint()
        performer = self.performer_tree.selected_joint()
        self.automap_action.setEnabled(both)
        self.map_action.setEnabled(
            both and target is not None and performer is not None and
            doc.scene.correspondence.performer_of(target) != performer)
        self.unmap_action.setEnabled(bool(self.table.selected_targets()))
        self.clear_action.setEnabled(len(doc.scene.correspondence) > 0)
        self.save_action.setEnabled(len(doc.scene.correspondence) > 0)

    # ------------------------------------------------------------------ widgets -> document
    def _tree_selection_changed(self, tree: JointTree) -> None:
        name = tree.selected_joint()
        if name is not None:
            self.doc.select(tree.side, name)
        self._update_actions()

    def _table_selection_changed(self, targets: list) -> None:
        if targets:
            current = self.table.currentIndex()
            row = current.row() if current.isValid() else -1
            target = (self.model.rows[row][0] if 0 <= row < len(self.model.rows) and
                      self.model.rows[row][0] in targets else targets[0])
            self.doc.select("target", target)
        self._update_actions()
        self.links.update()

    def _filter_changed(self, text: str) -> None:
        self.target_tree.apply_filter(text)
        self.performer_tree.apply_filter(text)
        self.links.update()

    def _joint_dropped(self, on: str, side: str, name: str) -> None:
        """A joint of one tree dropped on a joint of the other: map them (one command)."""
        if side == "performer":
            self.map_pair(on, name)
        elif side == "target":
            self.map_pair(name, on)

    def map_pair(self, target: str, performer: str) -> bool:
        """Map ``target`` to ``performer`` (one command) and select the pair."""
        doc = self.doc
        if doc.scene.target is None or doc.scene.performer is None or \
                target not in doc.scene.target.skeleton.index or \
                performer not in doc.scene.performer.skeleton.index:
            return False
        changed = _map_command(doc, target, performer)
        doc.select("target", target)
        return changed

    def map_selected(self) -> None:
        target = self.target_tree.selected_joint()
        performer = self.performer_tree.selected_joint()
        if target is not None and performer is not None:
            self.map_pair(target, performer)

    def unmap_selected(self) -> None:
        """Unmap the selected pairs (table rows; they follow the selected joint): one
        command."""
        targets = [t for t in self.table.selected_targets() if t in self.doc.scene.correspondence.pairs]
        if not targets:
            return
        if len(targets) == 1:
            _map_command(self.doc, targets[0], None)
            return
        corr = self.doc.scene.correspondence
        pairs = {t: p for t, p in corr.pairs.items() if t not in targets}
        notes = {t: n for t, n in corr.notes.items() if t in pairs}
        label = ", ".join(targets[:3]) + (f" and {len(targets) - 3} more"
                                          if len(targets) > 3 else "")
        push_correspondence(self.doc, Correspondence(pairs, notes), f"Unmap {label}")

    def clear(self) -> None:
        if len(self.doc.scene.correspondence):
            push_correspondence(self.doc, Correspondence({}), "Clear mapping")

    def auto_map(self) -> None:
        """Map by humanoid role (:func:`engine.conversion.automap.automap`): one command, "Auto-map"."""
        doc = self.doc
        if doc.scene.target is None or doc.scene.performer is None:
            return
        try:
            from motion_composer.engine.conversion.automap import automap
        except ImportError:
            self.show_error("Auto-map", "Automatic mapping is not available in this build; "
                            "map the joints by hand.")
            return
        try:
            corr = automap(doc.scene.target.skeleton, doc.scene.performer.skeleton)
        except MotionComposerError as exc:
            self.show_error("Auto-map", f"Automatic mapping failed: {exc}")
            return
        if corr.pairs == doc.scene.correspondence.pairs and corr.notes == doc.scene.correspondence.notes:
            return
        push_correspondence(doc, corr, "Auto-map")

    def load_preset(self) -> None:
        path = self.ask_load_path()
        if not path:
            return
        path = Path(path)
        try:
            corr = Correspondence.load(path)
        except MotionComposerError as exc:
            self.show_error("Load preset", f"Cannot load the mapping preset: {exc}")
            return
        problem = self._preset_problem(corr)
        if problem:
            self.show_error("Load preset", f"{path}: {problem}")
            return
        push_correspondence(self.doc, corr, f"Load preset {path.name}")

    def _preset_problem(self, corr: Correspondence) -> str:
        """Why ``corr`` cannot be used with the loaded skeletons ("" when it can)."""
        doc = self.doc
        for side, motion, names in (("target", doc.scene.target, list(corr.pairs)),
                                    ("performer", doc.scene.performer, list(corr.pairs.values()))):
            if motion is None:
                continue
            unknown = [n for n in names if n not in motion.skeleton.index]
            if unknown:
                shown = ", ".join(unknown[:5]) + (" ..." if len(unknown) > 5 else "")
                return (f"the preset names {len(unknown)} joint(s) the {side} skeleton lacks "
                        f"({shown}); it was made for another skeleton")
        if len(set(corr.pairs.values())) != len(corr.pairs):
            return "the preset maps one performer joint to several target joints"
        return ""

    def save_preset(self) -> None:
        path = self.ask_save_path()
        if not path:
            return
        path = Path(path)
        if not path.suffix:
            path = path.with_suffix(".json")
        try:
            self.doc.scene.correspondence.save(path)
        except (MotionComposerError, OSError) as exc:
            self.show_error("Save preset", f"Cannot save the mapping preset: {exc}")

    # ------------------------------------------------------------------ dialogs (overridable)
    def _preset_dir(self) -> str:
        path = self.doc.scene.target_path or self.doc.path
        return str(Path(path).parent) if path else ""

    def ask_load_path(self) -> str | None:
        """The preset file to load, or ``None`` (a file dialog; tests replace it)."""
        path, _ = QtWidgets.QFileDialog.getOpenFileName(
            self, "Load mapping preset", self._preset_dir(),
            "Mapping presets (*.json);;All files (*)")
        return path or None

    def ask_save_path(self) -> str | None:
        """Where to save the preset, or ``None`` (a file dialog; tests replace it)."""
        path, _ = QtWidgets.QFileDialog.getSaveFileName(
            self, "Save mapping preset", self._preset_dir(), "Mapping presets (*.json)")
        return path or None

    def show_error(self, title: str, text: str) -> None:
        """Tell the user (a message box; tests replace it)."""
        QtWidgets.QMessageBox.warning(self, title, text)
