"""The playback bar: play/pause, steps, start/end, loop, speed, a frame slider and spin box.

Playback runs in real time at the performer's exact frame rate: a ``QTimer`` only wakes the bar
up; each tick computes the frame from the wall-clock time elapsed since playing started
(``QElapsedTimer``) times the speed, so slow drawing drops frames and never slows playback.
With loop on it wraps within ``doc.scene.viewer.play_range`` (or the whole clip), otherwise it stops
at the end.

The current frame is viewer state, not an edit: the bar calls ``doc.set_frame`` (not undoable)
and follows ``doc.frameChanged``, updating its widgets inside ``QSignalBlocker`` s.
"""
from __future__ import annotations

import math

from motion_composer.app.gui.qt import QtCore, QtGui, QtWidgets

__all__ = ["PlaybackBar", "SPEEDS"]

_Blocker = QtCore.QSignalBlocker

#: playback speeds offered (factor, label)
SPEEDS = ((0.25, "0.25x"), (0.5, "0.5x"), (1.0, "1x"), (2.0, "2x"))
#: the timer never wakes more often than a display refreshes
_MIN_TICK_MS = 1000.0 / 60.0


class _FrameText(QtWidgets.QWidget):
    """A line of text that only repaints itself when it changes. (A ``QLabel`` asks for a new
    layout on every ``setText``, and the main window then repaints everything around the
    viewport: on every frame while playing.) Its width is set for the widest text
    (:meth:`fit`)."""

    def __init__(self, parent=None):
        super().__init__(parent)
        self._text = ""
        self.setSizePolicy(QtWidgets.QSizePolicy.Policy.Fixed,
                           QtWidgets.QSizePolicy.Policy.Preferred)

    def text(self) -> str:
        return self._text

    def setText(self, text: str) -> None:       # noqa: N802 - as QLabel's
        if text != self._text:
            self._text = text
            self.update()

    def fit(self, widest: str) -> None:
        """As wide as ``widest`` (a layout change, once per clip, not per frame)."""
        self.setFixedWidth(self.fontMetrics().horizontalAdvance(widest) + 8)

    def sizeHint(self) -> QtCore.QSize:         # noqa: N802 - Qt's name
        return QtCore.QSize(self.width(), self.fontMetrics().height() + 4)

    def paintEvent(self, _event) -> None:       # noqa: N802 - Qt's name
        painter = QtGui.QPainter(self)
        painter.setPen(self.palette().color(QtGui.QPalette.ColorRole.WindowText))
        painter.drawText(self.rect().adjusted(4, 0, 0, 0),
                         QtCore.Qt.AlignmentFlag.AlignVCenter, self._text)


class PlaybackBar(QtWidgets.QWidget):
    """Transport controls of one document."""

    #: playing started (True) or stopped (False)
    playingChanged = QtCore.Signal(bool)

    def __init__(self, document, parent=None):
        super().__init__(parent)
        self.doc = document
        self.speed = 1.0
        self._clock = QtCore.QElapsedTimer()
        self._anchor_frame = 0          # frame shown when the clock (re)started
        self._setting = False           # the bar itself is moving the frame
        self.timer = QtCore.QTimer(self)
        self.timer.setTimerType(QtCore.Qt.TimerType.PreciseTimer)
        self.timer.timeout.connect(self._tick)
        self.shortcuts: list[QtGui.QShortcut] = []
        self._build()
        self.doc.frameChanged.connect(self._frame_changed)
        self.doc.sourcesChanged.connect(self._sources_changed)
        self._sources_changed()

    # ------------------------------------------------------------------ building
    def _button(self, icon, tip: str, slot, checkable: bool = False) -> QtWidgets.QToolButton:
        button = QtWidgets.QToolButton()
        button.setIcon(self.style().standardIcon(icon))
        button.setToolTip(tip)
        button.setAutoRaise(True)
        button.setCheckable(checkable)
        button.setIconSize(QtCore.QSize(20, 20))
        if checkable:
            button.toggled.connect(slot)
        else:
            button.clicked.connect(lambda _checked=False: slot())
        return button

    def _build(self) -> None:
        sp = QtWidgets.QStyle.StandardPixmap
        self.start_button = self._button(sp.SP_MediaSkipBackward, "Go to start (Home)",
                                         self.to_start)
        self.back_button = self._button(sp.SP_MediaSeekBackward, "Step back (Left)",
                                        lambda: self.step(-1))
        self.play_button = self._button(sp.SP_MediaPlay, "Play (Space)", self.toggle)
        self.forward_button = self._button(sp.SP_MediaSeekForward, "Step forward (Right)",
                                           lambda: self.step(1))
        self.end_button = self._button(sp.SP_MediaSkipForward, "Go to end (End)", self.to_end)
        self.loop_button = QtWidgets.QToolButton()
        self.loop_button.setText("Loop")
        self.loop_button.setIcon(self.style().standardIcon(sp.SP_BrowserReload))
        self.loop_button.setToolButtonStyle(QtCore.Qt.ToolButtonStyle.ToolButtonTextBesideIcon)
        self.loop_button.setCheckable(True)
        self.loop_button.setChecked(True)
        self.loop_button.setAutoRaise(True)
        self.loop_button.setToolTip("Loop within the play range (or the whole clip)")
        self.speed_combo = QtWidgets.QComboBox()
        for factor, text in SPEEDS:
            self.speed_combo.addItem(text, factor)
        self.speed_combo.setCurrentIndex(self.speed_combo.findData(1.0))
        self.speed_combo.setToolTip("Playback speed")
        self.speed_combo.currentIndexChanged.connect(self._speed_changed)

        self.slider = QtWidgets.QSlider(QtCore.Qt.Orientation.Horizontal)
        self.slider.setMinimumWidth(200)
        self.slider.setFocusPolicy(QtCore.Qt.FocusPolicy.NoFocus)   # arrows are shortcuts
        self.slider.valueChanged.connect(self._widget_frame)
        self.spin = QtWidgets.QSpinBox()
        self.spin.setKeyboardTracking(False)
        self.spin.setToolTip("Current frame")
        self.spin.valueChanged.connect(self._widget_frame)
        self.label = _FrameText()
        self.label.setFont(QtGui.QFontDatabase.systemFont(
            QtGui.QFontDatabase.SystemFont.FixedFont))
        self.label.setToolTip("Frame / last frame, and time from the clip's frame time")

        layout = QtWidgets.QHBoxLayout(self)
        layout.setContentsMargins(4, 2, 4, 2)
        layout.setSpacing(2)
        for w in (self.start_button, self.back_button, self.play_button, self.forward_button,
                  self.end_button):
            layout.addWidget(w)
        layout.addSpacing(6)
        layout.addWidget(self.loop_button)
        layout.addWidget(self.speed_combo)
        layout.addSpacing(6)
        layout.addWidget(self.slider, 1)
        layout.addWidget(self.spin)
        layout.addSpacing(4)
        layout.addWidget(self.label)

    def install_shortcuts(self, widget: QtWidgets.QWidget) -> list[QtGui.QShortcut]:
        """Space, Left/Right (Shift: 10 frames), Home and End on ``widget``'s window."""
        Key = QtCore.Qt.Key
        Mod = QtCore.Qt.KeyboardModifier
        keys = ((Key.Key_Space, self.toggle), (Key.Key_Left, lambda: self.step(-1)),
                (Key.Key_Right, lambda: self.step(1)),
                (QtCore.QKeyCombination(Mod.ShiftModifier, Key.Key_Left),
                 lambda: self.step(-10)),
                (QtCore.QKeyCombination(Mod.ShiftModifier, Key.Key_Right),
                 lambda: self.step(10)),
                (Key.Key_Home, self.to_start), (Key.Key_End, self.to_end))
        made = []
        for key, slot in keys:
            shortcut = QtGui.QShortcut(QtGui.QKeySequence(key), widget)
            shortcut.activated.connect(slot)
            made.append(shortcut)
        self.shortcuts.extend(made)
        return made

    # ------------------------------------------------------------------ state
    @property
    def playing(self) -> bool:
        return self.timer.isActive()

    @property
    def loop(self) -> bool:
        return self.loop_button.isChecked()

    def set_loop(self, on: bool) -> None:
        self.loop_button.setChecked(on)

    def set_speed(self, factor: float) -> None:
        self.speed_combo.setCurrentIndex(self.speed_combo.findData(float(factor)))

    @property
    def frame_time(self) -> float | None:
        """The performer's exact seconds per frame."""
        p = self.doc.scene.performer
        return p.frame_time if p is not None else None

    def play_range(self) -> tuple[int, int]:
        """First and last frame played: ``doc.scene.viewer.play_range`` clamped to the clip, or the
        whole clip."""
        last = max(self.doc.scene.num_frames - 1, 0)
        rng = self.doc.scene.viewer.play_range
        if rng is None:
            return 0, last
        lo, hi = (min(max(int(v), 0), last) for v in rng)
        return (lo, hi) if lo <= hi else (hi, lo)

    # ------------------------------------------------------------------ slots
    def play(self) -> None:
        if self.playing or self.frame_time is None or self.doc.scene.num_frames < 2:
            return
        lo, hi = self.play_range()
        frame = self.doc.scene.viewer.current_frame
        if self.loop and not lo <= frame <= hi:
            frame = lo
        elif not self.loop and frame >= (hi if frame <= hi else self.doc.scene.num_frames - 1):
            frame = lo                     # at the end: play again from the start
        self._set_frame(frame)
        self._restart_clock()
        self.timer.start(max(1, int(min(_MIN_TICK_MS, self.frame_time * 1000.0 / self.speed))))
        self._show_playing(True)

    def pause(self) -> None:
        if not self.playing:
            return
        self.timer.stop()
        self._show_playing(False)

    def toggle(self) -> None:
        self.pause() if self.playing else self.play()

    def step(self, n: int = 1) -> None:
        """Move ``n`` frames (stops playing)."""
        self.pause()
        self.doc.set_frame(self.doc.scene.viewer.current_frame + int(n))

    def to_start(self) -> None:
        """The play range's first frame (the clip's first if already there)."""
        lo, _hi = self.play_range()
        cur = self.doc.scene.viewer.current_frame
        self._jump(lo if cur != lo else 0)

    def to_end(self) -> None:
        """The play range's last frame (the clip's last if already there)."""
        _lo, hi = self.play_range()
        cur = self.doc.scene.viewer.current_frame
        self._jump(hi if cur != hi else self.doc.scene.num_frames - 1)

    # ------------------------------------------------------------------ internals
    def _jump(self, frame: int) -> None:
        self.doc.set_frame(frame)
        if self.playing:
            self._restart_clock()

    def _restart_clock(self) -> None:
        self._anchor_frame = self.doc.scene.viewer.current_frame
        self._clock.start()

    def _set_frame(self, frame: int) -> None:
        self._setting = True
        try:
            self.doc.set_frame(frame)
        finally:
            self._setting = False

    def _tick(self) -> None:
        ft = self.frame_time
        if ft is None:
            self.pause()
            return
        elapsed = self._clock.nsecsElapsed() * 1e-9 * self.speed
        frame = self._anchor_frame + int(math.floor(elapsed / ft + 1e-6))
        lo, hi = self.play_range()
        if self._anchor_frame > hi:         # started after the range: play to the clip's end
            lo, hi = 0, self.doc.scene.num_frames - 1
        if frame > hi:
            if self.loop and hi > lo:
                frame = lo + (frame - lo) % (hi - lo + 1)
            else:
                self._set_frame(hi)
                self.pause()
                return
        self._set_frame(frame)

    def _speed_changed(self, index: int) -> None:
        self.speed = float(self.speed_combo.itemData(index))
        if self.playing:
            self._restart_clock()
            self.timer.setInterval(
                max(1, int(min(_MIN_TICK_MS, self.frame_time * 1000.0 / self.speed))))

    def _show_playing(self, playing: bool) -> None:
        sp = QtWidgets.QStyle.StandardPixmap
        self.play_button.setIcon(self.style().standardIcon(
            sp.SP_MediaPause if playing else sp.SP_MediaPlay))
        self.play_button.setToolTip("Pause (Space)" if playing else "Play (Space)")
        self.playingChanged.emit(playing)

    def _widget_frame(self, frame: int) -> None:
        """The slider or the spin box moved the frame."""
        self._jump(frame)

    def _frame_changed(self, frame: int) -> None:
        """The document's frame changed (from this bar or anywhere else)."""
        if self.playing and not self._setting:
            self._restart_clock()           # someone else moved the frame: play on from there
        self._show_frame(frame)

    def _show_frame(self, frame: int) -> None:
        with _Blocker(self.slider), _Blocker(self.spin):
            self.slider.setValue(frame)
            self.spin.setValue(frame)
        ft = self.frame_time
        if ft is None:
            self.label.setText("no clip")
        else:
            last = max(self.doc.scene.num_frames - 1, 0)
            # fixed widths (in a fixed font) so the text does not jitter while playing
            width = len(f"{last * ft:.3f}")
            self.label.setText(f"{frame:>{len(str(last))}} / {last}  "
                               f"{frame * ft:>{width}.3f} s")

    def _sources_changed(self) -> None:
        n = self.doc.scene.num_frames
        last = max(n - 1, 0)
        with _Blocker(self.slider), _Blocker(self.spin):
            self.slider.setRange(0, last)
            self.slider.setPageStep(max(1, n // 20))
            self.spin.setRange(0, last)
        has = self.doc.scene.performer is not None
        for w in (self.start_button, self.back_button, self.play_button, self.forward_button,
                  self.end_button, self.slider, self.spin):
            w.setEnabled(has)
        if not has or n < 2:
            self.pause()
        if self.doc.scene.viewer.current_frame > last:
            self.doc.set_frame(last)
        self._fix_label_width(last)
        self._show_frame(self.doc.scene.viewer.current_frame)

    def _fix_label_width(self, last: int) -> None:
        """The frame label as wide as its widest text: a label whose size hint changes with
        each frame's text makes Qt lay out and repaint the whole window on every frame."""
        ft = self.frame_time or 0.0
        width = len(f"{last * ft:.3f}")
        widest = f"{last} / {last}  {last * ft:>{width}.3f} s" if ft else "no clip"
        self.label.fit(widest)
