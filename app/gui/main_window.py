"""The composer window: viewport, correspondence editor, binding panel, playback, menus."""
from __future__ import annotations

import dataclasses
from pathlib import Path

from motion_composer.app.gui.qt import QtCore, QtGui, QtWidgets
from motion_composer.app.gui.document import Document
from motion_composer.app.gui.viewport import Viewport
from motion_composer.engine.errors import MotionComposerError

__all__ = ["MainWindow"]

#: panels built by MainWindow._panel -> their dock's name
_LAZY_PANELS = {"curve_editor": "curves", "binding_panel": "binding", "ik_panel": "ik",
                "inspector": "inspector", "correspondence_panel": "correspondence",
                "timeline": "timeline"}
#: the panels of _LAZY_PANELS in view at start: built once the viewport has drawn its first
#: frame (the others but the timeline when their dock is first shown). The constraint
#: timeline, in view too, is built with the window: built after it was shown, a frame change
#: soon after repainted it whole, where only its playhead should (test_gui_judging)
_FIRST_SHOWN = ("correspondence_panel",)

MAX_RECENT = 8
#: the status line while a solve's keys are fitted (its dense correction shown meanwhile)
FITTING_KEYS = "The IK's correction is shown while its keys are fitted"
#: [ms] how often a modified project is autosaved (a window's ``autosave_timer`` interval):
#: a crash loses at most this much work
AUTOSAVE_MS = 60_000
#: the window's default size and its side and bottom docks' [px]: the viewport gets more than
#: half of the window
WINDOW_SIZE = (1600, 1000)
SIDE_DOCK_PX = 380
BOTTOM_DOCK_PX = 210


class MainWindow(QtWidgets.QMainWindow):
    """One document, its panels and its menus."""

    def __init__(self, document: Document | None = None, parent=None):
        super().__init__(parent)
        self.doc = document or Document(self)
        self.settings = QtCore.QSettings()
        self.setWindowTitle(self.doc.title)
        self.setAcceptDrops(True)

        self.viewport = Viewport(self.doc)
        self._build_docks()
        self._panel("timeline")
        if self.viewport.can_draw:
            self.viewport.frameSwapped.connect(self._first_frame_drawn)
        else:                           # no first frame to wait for
            QtCore.QTimer.singleShot(0, self, self._build_first_shown)
        self._build_menus()
        self._build_status()

        self.doc.changed.connect(self._update_title)
        self.doc.errorRaised.connect(self.show_error)
        self.doc.motionChanged.connect(self._motion_changed)
        self.doc.viewerChanged.connect(self.viewport.refresh)
        self.viewport.filesDropped.connect(self.import_dropped)
        self.doc.noted.connect(lambda text: self.statusBar().showMessage(text, 5000))
        self.doc.jobs.started.connect(self._job_started)
        self.doc.jobs.progressed.connect(lambda f: self.progress.setValue(int(f * 1000)))
        self.doc.keysFitting.connect(self._keys_fitting)
        self.doc.jobs.failed.connect(self.show_error)
        self.doc.jobs.finished.connect(self._job_done)
        self.autosave_timer = QtCore.QTimer(self)
        self.autosave_timer.setInterval(AUTOSAVE_MS)
        self.autosave_timer.timeout.connect(self.autosave)
        self.autosave_timer.start()
        self._update_title()

    # ------------------------------------------------------------------ building
    def _build_docks(self) -> None:
        from motion_composer.app.gui.playback import PlaybackBar
        from motion_composer.app.gui.quality_panel import QualityPanel

        self.quality_panel = QualityPanel(self.doc)
        self.playback = PlaybackBar(self.doc)
        self._panels: dict = {}                     # the panels built so far (see _panel)
        self._quality_strip = None                  # built when needed (see _strip)
        docks = [
            ("Correspondence", QtWidgets.QWidget(),
             QtCore.Qt.DockWidgetArea.RightDockWidgetArea, "correspondence"),
            ("Binding", QtWidgets.QWidget(), QtCore.Qt.DockWidgetArea.RightDockWidgetArea,
             "binding"),
            ("IK", QtWidgets.QWidget(), QtCore.Qt.DockWidgetArea.RightDockWidgetArea, "ik"),
            ("Quality", self.quality_panel, QtCore.Qt.DockWidgetArea.RightDockWidgetArea,
             "quality"),
            ("Curves", QtWidgets.QWidget(), QtCore.Qt.DockWidgetArea.BottomDockWidgetArea,
             "curves"),
        ]
        try:                                   # the constraint timeline and inspector
            import motion_composer.app.gui.timeline  # noqa: F401
            docks += [("Constraints", QtWidgets.QWidget(),
                       QtCore.Qt.DockWidgetArea.BottomDockWidgetArea, "timeline"),
                      ("Constraint", QtWidgets.QWidget(),
                       QtCore.Qt.DockWidgetArea.RightDockWidgetArea, "inspector")]
        except ImportError:
            pass
        self.quality_panel.qualityChanged.connect(self._quality_changed)
        for title, widget, area, name in docks:
            dock = QtWidgets.QDockWidget(title, self)
            dock.setObjectName(name)
            dock.setWidget(widget)
            self.addDockWidget(area, dock)
            setattr(self, f"{name}_dock", dock)
        if getattr(self, "timeline_dock", None) is not None:
            self.tabifyDockWidget(self.curves_dock, self.timeline_dock)
            self.timeline_dock.raise_()
        for name, dock in _LAZY_PANELS.items():
            if name not in _FIRST_SHOWN and getattr(self, f"{dock}_dock", None) is not None:
                getattr(self, f"{dock}_dock").visibilityChanged.connect(
                    lambda shown, name=name: shown and self._panel(name))
        # the bottom docks' titles and tabs run down their left side: their height goes to
        # the viewport
        self.setTabPosition(QtCore.Qt.DockWidgetArea.BottomDockWidgetArea,
                            QtWidgets.QTabWidget.TabPosition.West)
        for dock in (self.curves_dock, getattr(self, "timeline_dock", None)):
            if dock is not None:
                dock.setFeatures(dock.features() |
                                 QtWidgets.QDockWidget.DockWidgetFeature.DockWidgetVerticalTitleBar)
        # the transport sits under the viewport it drives
        central = QtWidgets.QWidget()
        box = QtWidgets.QVBoxLayout(central)
        box.setContentsMargins(0, 0, 0, 0)
        box.setSpacing(2)
        box.addWidget(self.viewport.widget, 1)
        box.addWidget(self.playback)
        self.setCentralWidget(central)
        # the side panels share one column of tabs, so the viewport keeps most of the width
        self.tabifyDockWidget(self.correspondence_dock, self.binding_dock)
        self.tabifyDockWidget(self.binding_dock, self.ik_dock)
        self.tabifyDockWidget(self.ik_dock, self.quality_dock)
        if getattr(self, "inspector_dock", None) is not None:
            self.tabifyDockWidget(self.binding_dock, self.inspector_dock)
        self.correspondence_dock.raise_()
        # the minimum the layout set while the docks were still stacked, before the tabs
        self.setMinimumSize(0, 0)
        self.resize(*WINDOW_SIZE)
        self.resizeDocks([self.correspondence_dock], [SIDE_DOCK_PX],
                         QtCore.Qt.Orientation.Horizontal)
        self.resizeDocks([self.curves_dock], [BOTTOM_DOCK_PX], QtCore.Qt.Orientation.Vertical)
        self.playback.install_shortcuts(self)

    def _timeline_page(self, timeline) -> QtWidgets.QWidget:
        """The constraint timeline, and under it the quality strip (:attr:`quality_strip`)
        once there are quality figures."""
        page = QtWidgets.QWidget()
        self._timeline_box = QtWidgets.QVBoxLayout(page)
        self._timeline_box.setContentsMargins(0, 0, 0, 0)
        self._timeline_box.setSpacing(0)
        self._timeline_box.addWidget(timeline, 1)
        return page

    def _quality_changed(self, quality) -> None:
        if quality is not None:
            self._strip()               # it follows the figures from then on

    def _strip(self):
        """The quality strip under the timeline, on the timeline's frames; built the first
        time there are quality figures or it is asked for (it is hidden until there are: the
        window's first frame waits for no plot of them). None without the timeline."""
        if self._quality_strip is None and self.timeline is not None:
            from motion_composer.app.gui.quality_panel import QualityStrip
            strip = QualityStrip(self.doc, self.quality_panel, link=self.timeline.view)
            self._timeline_box.addWidget(strip)
            left = strip.getAxis("left")

            def align(*_args):              # its plot starts where the timeline's does
                left.setWidth(self.timeline.row_axis.width())
            self.timeline.view.sigResized.connect(align)
            align()
            self._quality_strip = strip
        return self._quality_strip

    quality_strip = property(lambda self: self._strip(),
                             doc="The quality strip (built when there are figures or asked "
                                 "for; None without the constraint timeline).")

    # ------------------------------------------------------------------ panels built when shown
    def _first_frame_drawn(self) -> None:
        self.viewport.frameSwapped.disconnect(self._first_frame_drawn)
        QtCore.QTimer.singleShot(0, self, self._build_first_shown)

    def _build_first_shown(self) -> None:
        """Build the panels in view at start (:data:`_FIRST_SHOWN`), once the viewport has
        drawn its first frame: the window shows the project without waiting for them (their
        docks are in place, empty for that moment). Each is built earlier if asked for."""
        for name in _FIRST_SHOWN:
            self._panel(name)

    def _panel(self, name: str):
        """The panel ``name`` of :data:`_LAZY_PANELS`, built the first time it is asked for
        (its attribute), its dock shows (those behind another tab) or the viewport has drawn
        its first frame (those in view at start, :meth:`_build_first_shown`): the window's
        first frame waits for none of them. None without the constraint timeline."""
        if name not in self._panels:
            dock = getattr(self, f"{_LAZY_PANELS[name]}_dock", None)
            if dock is None:
                return None
            panel, page = self._make_panel(name)
            self._panels[name] = panel
            old = dock.widget()
            dock.setWidget(page)
            if old is not None:
                old.deleteLater()
        return self._panels[name]

    def _make_panel(self, name: str):
        """A new panel and the page its dock holds."""
        if name == "curve_editor":
            from motion_composer.app.gui.curve_editor import CurveEditor
            panel = CurveEditor(self.doc)
        elif name == "binding_panel":
            from motion_composer.app.gui.binding_panel import BindingPanel
            panel = BindingPanel(self.doc)
            page = QtWidgets.QScrollArea()            # taller than the dock: it scrolls
            page.setWidget(panel)
            page.setWidgetResizable(True)
            page.setFrameShape(QtWidgets.QFrame.Shape.NoFrame)
            page.setHorizontalScrollBarPolicy(QtCore.Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
            page.setMinimumWidth(panel.minimumSizeHint().width() +
                                 page.verticalScrollBar().sizeHint().width())
            return panel, page
        elif name == "inspector":
            from motion_composer.app.gui.inspector import ConstraintInspector
            panel = ConstraintInspector(self.doc, self.timeline)
        elif name == "correspondence_panel":
            from motion_composer.app.gui.correspondence_panel import CorrespondencePanel
            panel = CorrespondencePanel(self.doc)
        elif name == "timeline":
            from motion_composer.app.gui.timeline import ConstraintTimeline
            panel = ConstraintTimeline(self.doc)
            panel.constraintSelected.connect(self.viewport.set_active_constraint)
            return panel, self._timeline_page(panel)
        else:
            from motion_composer.app.gui.floor_panel import FloorPanel
            from motion_composer.app.gui.ik_panel import IKPanel
            panel = IKPanel(self.doc)
            self._floor_panel = FloorPanel(self.doc)
            page = QtWidgets.QWidget()
            box = QtWidgets.QVBoxLayout(page)
            box.addWidget(self._floor_panel)
            box.addWidget(panel)
            box.addStretch(1)
            return panel, page
        return panel, panel

    curve_editor = property(lambda self: self._panel("curve_editor"),
                            doc="The curve editor (built when first shown or asked for).")
    binding_panel = property(lambda self: self._panel("binding_panel"),
                             doc="The binding panel (built when first shown or asked for).")
    floor_panel = property(lambda self: self._panel("ik_panel") and self._floor_panel,
                           doc="The floor's settings, in the IK dock above the solver's.")
    ik_panel = property(lambda self: self._panel("ik_panel"),
                        doc="The IK panel (built when first shown or asked for).")
    inspector = property(lambda self: self._panel("inspector"),
                         doc="The constraint inspector (built when first shown or asked for).")
    correspondence_panel = property(
        lambda self: self._panel("correspondence_panel"),
        doc="The correspondence editor (built after the first frame or when asked for).")
    timeline = property(lambda self: self._panel("timeline"),
                        doc="The constraint timeline (None where it cannot be imported).")

    def _action(self, menu, text, slot, shortcut=None, checkable=False, checked=False):
        action = QtGui.QAction(text, self)
        if shortcut:
            action.setShortcut(QtGui.QKeySequence(shortcut))
        if checkable:
            action.setCheckable(True)
            action.setChecked(checked)
            action.toggled.connect(slot)
        else:
            action.triggered.connect(lambda _checked=False: slot())
        menu.addAction(action)
        return action

    def _build_menus(self) -> None:
        bar = self.menuBar()
        file = bar.addMenu("&File")
        self._action(file, "&New", self.new_project, QtGui.QKeySequence.StandardKey.New)
        self._action(file, "&Open...", self.open_dialog, QtGui.QKeySequence.StandardKey.Open)
        self.recent_menu = file.addMenu("Open &Recent")
        self._action(file, "&Save", self.save, QtGui.QKeySequence.StandardKey.Save)
        self._action(file, "Save &As...", self.save_as, QtGui.QKeySequence.StandardKey.SaveAs)
        file.addSeparator()
        self._action(file, "Import &Performer...", lambda: self.import_dialog("performer"))
        self._action(file, "Import &Target...", lambda: self.import_dialog("target"))
        self._action(file, "&Export Motion (BVH, glTF, FBX)...", self.export_dialog, "Ctrl+E")
        file.addSeparator()
        self._action(file, "Save Retarget Pro&file...", self.save_profile_dialog)
        self._action(file, "&Load Retarget Profile...", self.load_profile_dialog)
        file.addSeparator()
        self._action(file, "&Quit", self.close, QtGui.QKeySequence.StandardKey.Quit)
        self._refresh_recent()

        edit = bar.addMenu("&Edit")
        self.undo_action = self.doc.undo_stack.createUndoAction(self, "&Undo")
        self.undo_action.setShortcut(QtGui.QKeySequence.StandardKey.Undo)
        self.redo_action = self.doc.undo_stack.createRedoAction(self, "&Redo")
        self.redo_action.setShortcut(QtGui.QKeySequence.StandardKey.Redo)
        edit.addAction(self.undo_action)
        edit.addAction(self.redo_action)

        view = bar.addMenu("&View")
        v = self.doc.scene.viewer
        self._action(view, "Show &Performer", lambda on: self._show("show_performer", on),
                     checkable=True, checked=v.show_performer)
        self._action(view, "Show &Intermediate", lambda on: self._show("show_intermediate", on),
                     checkable=True, checked=v.show_intermediate)
        self._action(view, "Show &Target", lambda on: self._show("show_target", on),
                     checkable=True, checked=v.show_target)
        self._action(view, "Side by &Side", lambda on: self._show("side_by_side", on),
                     checkable=True, checked=v.side_by_side)
        view.addSeparator()
        self._action(view, "&Frame All", self.viewport.frame_all, "F")
        self._action(view, "F&ront View", lambda: self.viewport.set_view("front"), "1")
        self._action(view, "Si&de View", lambda: self.viewport.set_view("side"), "3")
        self._action(view, "T&op View", lambda: self.viewport.set_view("top"), "7")
        view.addSeparator()
        self.view_actions = {
            name: self._action(view, text, lambda on, n=name: self.viewport.set_option(n, on),
                               shortcut, checkable=True, checked=self.viewport.option(name))
            for name, text, shortcut in (("follow_root", "Follow &Root", "Shift+F"),
                                         ("onion_skin", "&Onion Skin", "O"),
                                         ("foot_trails", "Foot Trai&ls", "T"),
                                         ("pose_edit", "Edit &Binding Pose", "B"))}
        self.doc.viewerChanged.connect(self._show_view_options)

        tools = bar.addMenu("&Tools")
        self._action(tools, "Add &Foot Contacts and Solve", self.solve_contacts)
        self._action(tools, "&Solve Constraints", self.solve)

    def _build_status(self) -> None:
        self.progress = QtWidgets.QProgressBar()
        self.progress.setRange(0, 1000)
        self.progress.setMaximumWidth(220)
        self.progress.setVisible(False)
        self.cancel_button = QtWidgets.QPushButton("Cancel")
        self.cancel_button.setVisible(False)
        self.cancel_button.clicked.connect(self.cancel_job)
        self.statusBar().addPermanentWidget(self.progress)
        self.statusBar().addPermanentWidget(self.cancel_button)

    # ------------------------------------------------------------------ state display
    def _update_title(self) -> None:
        self.setWindowTitle(self.doc.title)

    def _motion_changed(self) -> None:
        if self.doc.scene.evaluation_error:
            self.statusBar().showMessage(self.doc.scene.evaluation_error, 10000)

    def _show(self, key: str, on: bool) -> None:
        self.doc.set_viewer(**{key: on})

    def _show_view_options(self) -> None:
        """The View menu's toggles follow the viewer options (an opened project's)."""
        for name, action in self.view_actions.items():
            with QtCore.QSignalBlocker(action):
                action.setChecked(self.viewport.option(name))

    def screenshot(self) -> QtGui.QImage:
        """The window as drawn, the 3D view included (a native GL window, which
        ``QWidget.grab`` leaves black, is drawn for it: :meth:`Viewport.render_image`)."""
        image = self.grab().toImage()
        host = self.viewport.widget
        view = self.viewport.render_image()
        if not view.isNull():
            painter = QtGui.QPainter(image)
            painter.drawImage(host.mapTo(self, QtCore.QPoint(0, 0)), view)
            painter.end()
        return image

    # ------------------------------------------------------------------ dialogs (tests replace)
    def show_error(self, message: str) -> None:
        QtWidgets.QMessageBox.critical(self, "Motion Composer", message)

    def ask_open_path(self, caption: str, filters: str) -> str:
        return QtWidgets.QFileDialog.getOpenFileName(self, caption, "", filters)[0]

    def ask_save_path(self, caption: str, filters: str) -> str:
        return QtWidgets.QFileDialog.getSaveFileName(self, caption, "", filters)[0]

    def ask_unsaved(self) -> str:
        """'save', 'discard' or 'cancel' for a modified document about to be closed."""
        box = QtWidgets.QMessageBox(self)
        box.setWindowTitle("Motion Composer")
        box.setText(f"Save the changes to {self.doc.path.name if self.doc.path else 'Untitled'}?")
        box.setStandardButtons(QtWidgets.QMessageBox.StandardButton.Save |
                               QtWidgets.QMessageBox.StandardButton.Discard |
                               QtWidgets.QMessageBox.StandardButton.Cancel)
        answer = box.exec()
        return {QtWidgets.QMessageBox.StandardButton.Save: "save",
                QtWidgets.QMessageBox.StandardButton.Discard: "discard"}.get(
            QtWidgets.QMessageBox.StandardButton(answer), "cancel")

    def ask_export_options(self, motion):
        """File > Export's options for ``motion`` (an :class:`ExportOptions`), or ``None`` when
        the dialog is cancelled."""
        from .export_dialog import ExportOptionsDialog
        dialog = ExportOptionsDialog(motion, self)
        return dialog.options() if dialog.exec() else None

    def ask_yes_no(self, question: str) -> bool:
        return QtWidgets.QMessageBox.question(self, "Motion Composer", question) == \
            QtWidgets.QMessageBox.StandardButton.Yes

    # ------------------------------------------------------------------ files
    def _guard(self, fn, *args) -> bool:
        """Run ``fn``; a user error shows in a dialog and the window keeps running."""
        try:
            fn(*args)
        except MotionComposerError as exc:
            self.show_error(str(exc))
            return False
        return True

    def maybe_save(self) -> bool:
        if not self.doc.modified:
            return True
        answer = self.ask_unsaved()
        if answer == "save":
            return self.save()
        return answer == "discard"

    def new_project(self) -> None:
        if not self.maybe_save():
            return
        self.doc.reset()

    def open_dialog(self) -> None:
        if not self.maybe_save():
            return
        path = self.ask_open_path("Open project", "Motion Composer projects (*.mcp);;All (*)")
        if path:
            self.open_project(path)

    def open_project(self, path) -> bool:
        """Open a project; when its autosave is newer (a crash), offer to recover it."""
        path = Path(path)
        if self.offer_recovery(path):
            self._add_recent(str(path))
            return True
        ok = self._guard(self.doc.open, path, self._locate)
        if ok:
            self._add_recent(str(path))
            self._show_camera()
        return ok

    def _show_camera(self) -> None:
        """The opened project's camera, or everything framed when it has none."""
        self.viewport.set_camera_state(self.doc.scene.viewer.camera)
        if not self.doc.scene.viewer.camera:
            self.viewport.frame_all()

    def _locate(self, role: str, missing: str) -> str:
        from motion_composer.engine.formats import open_filters
        return self.ask_open_path(f"The {role} clip {missing} has moved: where is it?",
                                  open_filters())

    def save(self) -> bool:
        if self.doc.path is None:
            return self.save_as()
        return self._save_to(self.doc.path)

    def save_as(self) -> bool:
        path = self.ask_save_path("Save project", "Motion Composer projects (*.mcp)")
        if not path:
            return False
        if not path.endswith(".mcp"):
            path += ".mcp"
        return self._save_to(Path(path))

    def _save_to(self, path: Path) -> bool:
        self.doc.set_viewer(camera=self.viewport.camera_state())
        ok = self._guard(self.doc.save, Path(path))
        if ok:
            self._add_recent(str(path))
            self.statusBar().showMessage(f"Saved {path}", 5000)
        return ok

    def autosave(self) -> None:
        """Autosave a modified project (the timer calls this), ready or not: a half-done
        mapping is work too. A project without both clips yet has nothing to write."""
        if not self.doc.modified:
            return
        try:
            self.doc.autosave()
        except MotionComposerError as exc:
            self.statusBar().showMessage(f"Autosave failed: {exc}", 10000)

    def import_dialog(self, side: str) -> None:
        from motion_composer.engine.formats import open_filters
        path = self.ask_open_path(f"Import {side}", open_filters())
        if not path:
            return
        options = self.ask_import_options(side, path)
        if options is not None:
            self.import_file(side, path, **options)

    def ask_import_options(self, side: str, path) -> dict | None:
        """How to read ``path``: for a BVH file, the options dialog (:mod:`.import_options`,
        showing what detection found); for a glTF or FBX character, the dialog with its up
        axis alone where its figure does not stand along +Y as the file says (or the project
        gave it one), else ``{}`` (the file states its units and axes); ``{}`` for a file
        that cannot be read (:meth:`import_file` says why); ``None`` when the user
        cancels."""
        from motion_composer.app.gui.import_options import ImportOptionsDialog
        from motion_composer.engine.formats import read_motion, read_performer, sniff
        given = getattr(self.doc.scene.project, side).reader_options() if \
            getattr(self.doc.scene, f"{side}_path") == Path(path).resolve() else {}
        try:
            character = sniff(path).mesh
            detected = (read_performer if character and side == "performer" else
                        read_motion)(path)
        except MotionComposerError:
            return {}
        if character:
            given = {k: v for k, v in given.items() if k == "up_axis"}
            if not detected.skeleton.source.doubt and "up_axis" not in given:
                return {}
        dialog = ImportOptionsDialog(self, side, path, detected, given, character=character)
        if dialog.exec() != QtWidgets.QDialog.DialogCode.Accepted:
            return None
        return dialog.options()

    def import_file(self, side: str, path, **options) -> bool:
        """Import a performer or a target: one command, which also redoes the map (pairs set
        by hand that still fit are kept, the rest auto-mapped). ``options`` (``units``,
        ``scale``, ``up_axis``, ``position_mode``) override detection for a BVH file (the up
        axis alone what a glTF or FBX file says) and are kept in the project; a doubt about
        what was detected is shown in the status bar."""
        from motion_composer.engine.formats import read_motion, read_performer
        from motion_composer.engine.project import Source

        def load():
            # the file's content says its format; a glTF character can only be the target
            motion = (read_performer(path, **options) if side == "performer" else
                      read_motion(path, **options))
            self.doc.set_source(side, motion, Source(path=str(Path(path).resolve()),
                                                     **options),
                                f"Import {side} {Path(path).name}")
            self.viewport.frame_all()
            source = motion.skeleton.source
            if source.doubt:
                # an override settles the doubt (a BVH file's units or up axis, a glTF or
                # FBX file's up axis); else the file is to be written again
                hint = ("; if that is wrong, import it again and set it in the options"
                        if source.overrides else "")
                self.statusBar().showMessage(f"{Path(path).name}: {source.doubt}{hint}", 0)
        return self._guard(load)

    # ------------------------------------------------------------------ drag and drop
    def dragEnterEvent(self, event) -> None:   # noqa: N802 - Qt's name
        if self._dropped_paths(event.mimeData()):
            event.acceptProposedAction()

    def dragMoveEvent(self, event) -> None:    # noqa: N802 - Qt's name
        if self._dropped_paths(event.mimeData()):
            event.acceptProposedAction()

    def dropEvent(self, event) -> None:        # noqa: N802 - Qt's name
        paths = self._dropped_paths(event.mimeData())
        if paths:
            event.acceptProposedAction()
            self.import_dropped(paths)

    @staticmethod
    def _dropped_paths(mime) -> list[str]:
        return [u.toLocalFile() for u in mime.urls() if u.isLocalFile()]

    def import_dropped(self, paths) -> None:
        """Import files dropped on the window, each as :meth:`dropped_role` says (its content
        says its format: a file of none shows why, as File > Import does)."""
        for path in paths:
            role = self._guard_value(self.dropped_role, path)
            if role is not None:
                self.import_file(role, path)

    def dropped_role(self, path) -> str | None:
        """What a dropped file becomes: a character (a glTF mesh, or a skeleton of one frame)
        the target; a motion the performer while there is none; a motion dropped when a
        performer is loaded could be either (a new performer, or the target to retarget
        onto), so the user is asked (:meth:`ask_role`). None: cancelled."""
        from motion_composer.engine.formats import read_motion, sniff
        if sniff(path).mesh:
            return "target"
        if read_motion(path).num_frames <= 1:
            return "target"
        if self.doc.scene.performer is None:
            return "performer"
        return self.ask_role(Path(path).name)

    def ask_role(self, name: str) -> str | None:
        """'performer' or 'target' for a dropped motion that could be either, or None."""
        box = QtWidgets.QMessageBox(self)
        box.setWindowTitle("Motion Composer")
        box.setText(f"Import {name} as the performer (the motion to retarget) or as the "
                    f"target (the skeleton to retarget onto)?")
        performer = box.addButton("Performer", QtWidgets.QMessageBox.ButtonRole.AcceptRole)
        target = box.addButton("Target", QtWidgets.QMessageBox.ButtonRole.AcceptRole)
        box.addButton(QtWidgets.QMessageBox.StandardButton.Cancel)
        box.exec()
        return {performer: "performer", target: "target"}.get(box.clickedButton())

    def _guard_value(self, fn, *args):
        """``fn(*args)``, or None after showing a user error it raised."""
        try:
            return fn(*args)
        except MotionComposerError as exc:
            self.show_error(str(exc))
            return None

    def export_dialog(self) -> None:
        if not self.doc.scene.ready:
            self.show_error("Nothing to export yet: import a performer and a target and map "
                            "them first.")
            return
        from motion_composer.engine.formats import save_filters, with_output_suffix
        path = self.ask_save_path("Export", save_filters())
        if not path:
            return
        options = self.ask_export_options(self.doc.motion)
        if options is not None:
            self.export_motion(with_output_suffix(path), options)

    def export_motion(self, path, options=None) -> bool:
        """Write the final motion in the format ``path``'s suffix names: BVH, or glTF
        (.glb/.gltf) or FBX with the character's mesh and skin when the target has them;
        ``options`` (:class:`~app.gui.export_dialog.ExportOptions`) choose frames, frame rate
        and channels (default: all frames, as they are)."""
        from motion_composer.engine.formats import write_motion
        from motion_composer.engine.motion import export_selection
        from .export_dialog import ExportOptions
        options = options or ExportOptions()

        def write():
            motion = export_selection(self.doc.motion, options.frames, options.fps)
            write_motion(motion, path, self.doc.scene.character, channels=options.channels)
        ok = self._guard(write)
        if ok:
            self.statusBar().showMessage(f"Exported {path}", 5000)
        return ok

    # ------------------------------------------------------------------ retarget profiles
    def save_profile_dialog(self) -> None:
        from motion_composer.engine.project import PROFILE_SUFFIX
        path = self.ask_save_path("Save retarget profile",
                                  f"Retarget profiles (*{PROFILE_SUFFIX})")
        if path:
            self.save_profile(path if path.endswith(PROFILE_SUFFIX) else path + PROFILE_SUFFIX)

    def save_profile(self, path) -> bool:
        """Write the session's retarget profile (map, binding with its pose offsets and chain
        settings, root, IK and contact settings) to ``path``."""
        from motion_composer.engine.project import profile_of, save_profile
        ok = self._guard(lambda: save_profile(path, profile_of(self.doc.scene.project)))
        if ok:
            self.statusBar().showMessage(f"Saved retarget profile {path}", 5000)
        return ok

    def load_profile_dialog(self) -> None:
        from motion_composer.engine.project import PROFILE_SUFFIX
        path = self.ask_open_path("Load retarget profile",
                                  f"Retarget profiles (*{PROFILE_SUFFIX});;All (*)")
        if path:
            self.load_profile(path)

    def load_profile(self, path) -> bool:
        """Put the profile at ``path`` in place of the session's settings: one undoable
        command. A profile that cannot be read, or that names joints the clips loaded do not
        have, is shown in a dialog and changes nothing."""
        from motion_composer.engine.project import (Profile, apply_profile, check_project,
                                                    read_profile)

        def load():
            project = apply_profile(self.doc.scene.project, read_profile(path))
            scene = self.doc.scene
            if scene.performer is not None and scene.target is not None:
                check_project(project, scene.performer, scene.target, path=Path(path))
            fields = [f.name for f in dataclasses.fields(Profile)]
            self.doc.edit(f"Load retarget profile {Path(path).name}",
                          **{name: getattr(project, name) for name in fields})
        ok = self._guard(load)
        if ok:
            self.statusBar().showMessage(f"Loaded retarget profile {path}", 5000)
        return ok

    def offer_recovery(self, project_path=None) -> bool:
        """If an autosave newer than the project (or of an unsaved one) exists, offer it.
        Declined, it is deleted; accepted, it opens as that project with its work still to be
        saved (it is deleted once saved or discarded). False when nothing was recovered."""
        auto = self.doc.recovery_candidate(project_path)
        if auto is None:
            return False
        if not self.ask_yes_no(f"Motion Composer found unsaved work from an earlier session "
                               f"({auto}). Recover it?"):
            from motion_composer.engine.project import remove_autosave_file
            remove_autosave_file(auto)
            return False
        ok = self._guard(self.doc.recover, auto, project_path, self._locate)
        if ok:
            self._show_camera()
        return ok

    # ------------------------------------------------------------------ recent files
    def _recent(self) -> list[str]:
        value = self.settings.value("recent", [])
        if isinstance(value, str):
            value = [value]
        return [v for v in (value or []) if v]

    def _add_recent(self, path: str) -> None:
        path = str(Path(path).resolve())
        items = [path] + [p for p in self._recent() if p != path]
        self.settings.setValue("recent", items[:MAX_RECENT])
        self._refresh_recent()

    def _refresh_recent(self) -> None:
        self.recent_menu.clear()
        for path in self._recent():
            action = self.recent_menu.addAction(path)
            action.triggered.connect(lambda _c=False, p=path: self.maybe_save() and
                                     self.open_project(p))
        self.recent_menu.setEnabled(bool(self._recent()))

    # ------------------------------------------------------------------ long work
    def _job_started(self, label: str) -> None:
        self.progress.setRange(0, 1000)
        self.progress.setValue(0)
        self.progress.setFormat(f"{label} %p%")
        self.progress.setVisible(True)
        self.cancel_button.setVisible(True)

    def _keys_fitting(self) -> None:
        """The IK has run and its dense correction is shown: the keys' fit has no measure of
        its own progress, so the bar turns busy."""
        self.progress.setRange(0, 0)
        self.progress.setFormat("Fitting keys")
        self.statusBar().showMessage(FITTING_KEYS)

    def _job_done(self) -> None:
        if self.doc.jobs.busy:
            return
        self.progress.setVisible(False)
        self.cancel_button.setVisible(False)
        if self.statusBar().currentMessage() == FITTING_KEYS:
            self.statusBar().clearMessage()
        if self.doc.jobs.last_outcome == "cancelled":
            self.statusBar().showMessage("Cancelled", 5000)

    def cancel_job(self) -> None:
        self.doc.cancel_solve()

    def solve(self) -> None:
        """Enforce the constraints in the document's job runner: one undoable step."""
        if not self.doc.scene.ready:
            self.show_error("Nothing to solve yet: import a performer and a target first.")
            return
        if not self.doc.scene.constraints:
            self.show_error("There are no constraints to enforce.")
            return
        self.doc.solve()

    def solve_contacts(self) -> None:
        """Turn automatic foot contacts on (with the project's contact options and floor) and
        solve: one undoable step."""
        if not self.doc.scene.ready:
            self.show_error("Nothing to solve yet: import a performer and a target first.")
            return
        self.doc.solve(regenerate=True, auto_contacts=True,
                       text="Add foot contacts and solve")

    # ------------------------------------------------------------------ closing
    def closeEvent(self, event) -> None:   # noqa: N802 - Qt's name
        # an exception escaping a Qt event override crashes PySide's error reporting, so
        # nothing may leave this method: an unexpected error is printed and the window stays
        try:
            self.doc.cancel_solve()
            self.doc.jobs.wait()
            if self.maybe_save():
                # saved, discarded (a decline) or unchanged: the autosaves of this work go;
                # the ones of other work (another session's, another project's) stay
                self.doc.discard_autosave()
                self.autosave_timer.stop()
                event.accept()
            else:
                event.ignore()
        except Exception:                   # noqa: BLE001
            import traceback
            traceback.print_exc()
            event.ignore()
