"""Start the composer window: ``motion-composer [PROJECT] [--demo] [--self-test]``."""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from motion_composer.app.resources import resource_path
from motion_composer.engine.errors import MotionComposerError

REPO_RESOURCES = resource_path("")           # the source tree's resources/, or the bundle's
DEMO_PROJECT = resource_path("demo/demo.mcp")
#: a skinned glTF character (our own, made by tests/data/make_test_character.py): the
#: self-test's skinned target
SKINNED_CHARACTER = resource_path("characters/test_character.glb")
ICON = resource_path("icons/motion-composer.png")

#: frames the self-test steps through, at least
SELF_TEST_FRAMES = 60
#: the self-test gives up after this long (a dialog left open, a hung driver...)
SELF_TEST_TIMEOUT_S = 120
#: the target skeleton's colour in the viewport (COLORS["target"] in 8-bit), and how many
#: pixels of it the self-test wants to see
TARGET_RGB = (242, 153, 64)
MIN_TARGET_PIXELS = 100
#: Qt platforms with no screen, hence no one to answer a dialog
HEADLESS_PLATFORMS = ("offscreen", "minimal")
#: the exit code of a load that failed without a screen (the command line's user error)
EXIT_LOAD_FAILED = 2


def demo_project() -> Path:
    """The demo project: ``$MC_DEMO_PROJECT`` when set (for tests of the self-test), else the
    bundled ``resources/demo/demo.mcp``."""
    override = os.environ.get("MC_DEMO_PROJECT")
    return Path(override) if override else DEMO_PROJECT


class NoDisplayError(MotionComposerError):
    """The window was asked for where there is no display to show it on."""


def _has_display() -> bool:
    """Whether Qt can show a window here: on X11 and Wayland systems a display server is named
    (``DISPLAY``, ``WAYLAND_DISPLAY``) or ``QT_QPA_PLATFORM`` names a platform that needs none
    (``offscreen``, ``minimal``, ``vnc``, ``eglfs``...: any but ``xcb`` and ``wayland*``);
    Windows and macOS always have one."""
    if sys.platform.startswith(("win", "darwin")):
        return True
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return True
    platform = os.environ.get("QT_QPA_PLATFORM", "").split(":")[0].strip()
    return bool(platform) and platform != "xcb" and not platform.startswith("wayland")


def _check_display(*, headless: bool) -> None:
    """Refuse a window that cannot be shown, before Qt aborts the process on it (SIGABRT and
    its own messages). ``headless``: a screenshot or the self-test, which need no screen: they
    then draw on Qt's offscreen platform, without the 3D viewport (no OpenGL there), say so in
    one line and silence Qt's warnings about the missing OpenGL context."""
    if _has_display():
        return
    if not headless:
        raise NoDisplayError("no display: run it under xvfb-run, or use --screenshot")
    os.environ["QT_QPA_PLATFORM"] = "offscreen"
    rules = os.environ.get("QT_LOGGING_RULES")
    os.environ["QT_LOGGING_RULES"] = ";".join(filter(None, [rules, "default.warning=false"]))
    print("motion-composer: note: no display: drawing offscreen, without the 3D viewport",
          file=sys.stderr)


def _set_icon(app, window) -> None:
    from motion_composer.app.gui.qt import QtGui
    app.setDesktopFileName("motion-composer")       # matches packaging/motion-composer.desktop
    if ICON.is_file():
        icon = QtGui.QIcon(str(ICON))
        app.setWindowIcon(icon)
        window.setWindowIcon(icon)


def _without_dialogs(window) -> None:
    """Make ``window`` ask nothing: errors are kept in ``window.errors`` instead of shown in a
    dialog, questions get their safe answer (no, nothing chosen, discard), and no autosave is
    offered (so none is declined, which would delete it)."""
    window.errors = []
    window.offer_recovery = lambda project_path=None: False
    window.show_error = window.errors.append
    window.ask_yes_no = lambda question: False
    window.ask_open_path = lambda caption, filters: ""
    window.ask_unsaved = lambda: "discard"


def _import_before_qt() -> None:
    """Import the modules the window needs that do not use Qt before Qt: PySide6 replaces
    Python's import with one that reads the whole source of every module imported after it
    (shiboken's check for its ``__feature__`` imports), 40-60 ms of the window's start for
    PyOpenGL's modules and the engine's. They load a moment earlier, nothing else changes."""
    import OpenGL.GL  # noqa: F401  (pyqtgraph's 3D view draws through it)
    import motion_composer.engine.scene  # noqa: F401  (the document's scene and project)


def run(project: str | None = None, *, demo: bool = False, screenshot: str | None = None,
        frame: int | None = None, quit_after_ms: int | None = None,
        self_test: bool = False) -> int:
    """Open the window (on ``project`` or the demo) and run the event loop.

    ``screenshot``: save a PNG of the window once it is drawn, then quit (for documentation
    and self-tests); ``frame``: go to that frame first; ``self_test``: see :func:`self_test`.
    With ``screenshot`` or without a screen (an offscreen Qt platform) no dialog opens: a
    project that does not load prints one line on stderr and returns 2.

    Raises:
        NoDisplayError: where there is no display, unless ``screenshot`` or ``self_test``
            (drawn on Qt's offscreen platform then), before Qt is started.
    """
    _check_display(headless=self_test or screenshot is not None)
    _import_before_qt()
    from motion_composer.app.gui.qt import QtCore, application
    from motion_composer.app.runtime import tune_allocator

    tune_allocator()
    if self_test:
        return _run_self_test()
    app = application()
    from motion_composer.app.gui.main_window import MainWindow
    window = MainWindow()
    _set_icon(app, window)
    headless = screenshot is not None or app.platformName() in HEADLESS_PLATFORMS
    if headless:
        _without_dialogs(window)
    window.show()
    path = demo_project() if demo else project
    if not start(window, project, demo=demo) and headless and path is not None:
        reason = window.errors[-1] if window.errors else f"{path} did not open"
        print(f"motion-composer: error: {' '.join(reason.split())}", file=sys.stderr)
        return EXIT_LOAD_FAILED
    if frame is not None:
        window.doc.set_frame(frame)
    if screenshot is not None:
        def shoot():
            window.viewport.frame_all()
            app.processEvents()
            window.screenshot().save(screenshot)
            app.quit()
        QtCore.QTimer.singleShot(1500, shoot)
    elif quit_after_ms is not None:
        QtCore.QTimer.singleShot(quit_after_ms, app.quit)
    return app.exec()


def start(window, project: str | None = None, *, demo: bool = False) -> bool:
    """What the window shows first: ``project`` (or the demo) through
    :meth:`~app.gui.main_window.MainWindow.open_project`, which offers its autosave when that
    is newer; with no project, the autosave of an unsaved session that crashed, if any.
    True when something opened."""
    path = demo_project() if demo else project
    if path is not None:
        return window.open_project(path)
    return window.offer_recovery()


# ---------------------------------------------------------------------------- self-test
class SelfTestFailure(Exception):
    """A check of the self-test did not hold; the message says which."""


def _gl_expected(app) -> bool:
    """Whether this platform can give the viewport an OpenGL context at all ('offscreen' and
    'minimal' cannot; X11, Wayland, Windows and macOS can, so there it must work)."""
    return app.platformName() not in ("offscreen", "minimal")


def _count_pixels(image, rgb, tol: int = 40) -> int:
    import numpy as np
    from motion_composer.app.gui.qt import QtGui
    image = image.convertToFormat(QtGui.QImage.Format.Format_RGB32)
    arr = np.frombuffer(image.constBits(), dtype=np.uint8).reshape(
        image.height(), image.bytesPerLine() // 4, 4)[:, :image.width(), :3][..., ::-1]
    return int(np.sum(np.all(np.abs(arr.astype(int) - rgb) < tol, axis=-1)))


def _wait(app, seconds: float, until=None) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        app.processEvents()
        if until is not None and until():
            return
        time.sleep(0.005)


def _check_skinned_target(app, window) -> str:
    """Import the bundled skinned character as the target of the demo's performer, step two
    frames and check that its mesh followed. Returns the figures for the report."""
    import numpy as np

    path = SKINNED_CHARACTER
    if not path.is_file():
        raise SelfTestFailure(f"the bundled skinned character is missing: {path}")
    errors = window.errors
    if not window.import_file("target", path):
        raise SelfTestFailure(f"the skinned character did not open: "
                              f"{' '.join((errors[-1] if errors else 'no reason given').split())}")
    doc = window.doc
    character = doc.scene.character
    if character is None or not character.meshes or not doc.scene.ready:
        raise SelfTestFailure("the skinned character opened without its mesh or map")
    skin = window.viewport.skin
    last = doc.scene.num_frames - 1
    doc.set_frame(0)
    app.processEvents()
    if skin is None or not skin.visible():
        raise SelfTestFailure("the viewport does not show the skinned character's mesh")
    first = np.array(skin.opts["meshdata"].vertexes(), copy=True)
    doc.set_frame(last // 2)
    app.processEvents()
    if np.allclose(skin.opts["meshdata"].vertexes(), first):
        raise SelfTestFailure("the skinned mesh did not move with the motion")
    if errors:
        raise SelfTestFailure(f"an error was shown: {' '.join(errors[-1].split())}")
    return (f"skinned target {path.name} ({character.num_vertices} vertices, "
            f"{character.skeleton.num_joints} joints) followed the motion")


def self_test(app, window) -> str:
    """Load the demo into ``window``, step through frames, check that the viewport drew, then
    take the bundled skinned character as the target and check that its mesh follows.
    Returns the figures for the report; raises :class:`SelfTestFailure`."""
    import numpy as np

    started = time.perf_counter()
    window.resize(1280, 800)
    window.show()
    _wait(app, 5.0, until=lambda: window.windowHandle() is not None and
          window.windowHandle().isExposed())
    path = demo_project()
    if not path.is_file():
        raise SelfTestFailure(f"the demo project is missing: {path}")
    errors = window.errors
    t0 = time.perf_counter()
    if not window.open_project(path):
        raise SelfTestFailure(f"the demo project did not open: "
                              f"{' '.join((errors[-1] if errors else 'no reason given').split())}")
    load_s = time.perf_counter() - t0
    doc = window.doc
    if not doc.scene.ready:
        raise SelfTestFailure("the demo opened but is not ready (sources or map missing)")
    if doc.scene.num_frames <= 0 or doc.motion is None:
        raise SelfTestFailure(f"the demo has no motion ({doc.scene.num_frames} frames)")
    if doc.scene.evaluation_error:
        raise SelfTestFailure(f"the demo did not evaluate: {doc.scene.evaluation_error}")

    figure = window.viewport.figures.get("target")
    steps = min(SELF_TEST_FRAMES, doc.scene.num_frames)
    first = max(0, min(doc.scene.viewer.current_frame, doc.scene.num_frames - steps))
    before = None if figure is None else np.array(figure.points, copy=True)
    t0 = time.perf_counter()
    for f in range(first, first + steps):
        doc.set_frame(f)
        app.processEvents()
        if doc.scene.viewer.current_frame != f:
            raise SelfTestFailure(f"set_frame({f}) left the document at frame "
                                  f"{doc.scene.viewer.current_frame}")
    step_s = time.perf_counter() - t0
    if errors:
        raise SelfTestFailure(f"an error was shown: {' '.join(errors[-1].split())}")
    if figure is not None and steps > 1 and np.allclose(figure.points, before):
        raise SelfTestFailure("the target skeleton did not move while stepping frames")

    if _gl_expected(app):
        window.viewport.frame_all()
        _wait(app, 0.3)
        viewport = window.viewport
        image = viewport.render_image()
        if not viewport.isValid() or image.isNull():
            raise SelfTestFailure(f"the viewport has no OpenGL context on the "
                                  f"'{app.platformName()}' platform")
        pixels = _count_pixels(image, TARGET_RGB)
        if pixels < MIN_TARGET_PIXELS:
            raise SelfTestFailure(f"the viewport did not draw the target skeleton "
                                  f"({pixels} target-coloured pixels of "
                                  f"{image.width()}x{image.height()})")
        context = viewport.context()
        gl = context.format() if context is not None else None
        drew = (f"viewport {image.width()}x{image.height()} drew {pixels} target pixels"
                + (f" (OpenGL {gl.majorVersion()}.{gl.minorVersion()})" if gl else ""))
    else:
        drew = f"viewport not checked (no OpenGL on the '{app.platformName()}' platform)"
    demo = (f"demo {doc.scene.num_frames} frames, {doc.scene.target.skeleton.num_joints} target "
            f"joints, loaded in {load_s:.2f} s; stepped {steps} frames "
            f"({first}-{first + steps - 1}) at {steps / max(step_s, 1e-9):.0f} fps; {drew}")
    skinned = _check_skinned_target(app, window)
    return f"{demo}; {skinned}; {time.perf_counter() - started:.1f} s in all"


def _run_self_test() -> int:
    """``motion-composer --self-test``: start, load the demo, step frames, load a skinned
    target, quit. Prints one line, ``self-test: ok (...)`` with exit code 0 or
    ``self-test: FAILED: reason`` with 1."""
    import tempfile
    import threading

    def report(ok: bool, text: str) -> None:
        print(f"self-test: {'ok (' + text + ')' if ok else 'FAILED: ' + text}", flush=True)

    def give_up() -> None:                 # a dialog left open, a hung driver...
        report(False, f"no answer after {SELF_TEST_TIMEOUT_S} s")
        os._exit(1)

    watchdog = threading.Timer(SELF_TEST_TIMEOUT_S, give_up)
    watchdog.daemon = True
    watchdog.start()
    saved_state_home = os.environ.get("XDG_STATE_HOME")
    with tempfile.TemporaryDirectory(prefix="mc-self-test-") as scratch:
        # no trace in the user's settings (recent files) or autosave folder
        os.environ["XDG_STATE_HOME"] = os.path.join(scratch, "state")
        try:
            from motion_composer.app.gui.qt import QtCore, application
            QtCore.QSettings.setDefaultFormat(QtCore.QSettings.Format.IniFormat)
            QtCore.QSettings.setPath(QtCore.QSettings.Format.IniFormat,
                                     QtCore.QSettings.Scope.UserScope,
                                     os.path.join(scratch, "settings"))
            app = application()
            from motion_composer.app.gui.main_window import MainWindow
            window = MainWindow()
            _set_icon(app, window)
            _without_dialogs(window)
            try:
                figures = self_test(app, window)
            finally:
                # hidden rather than closed: closing also discards the demo's autosave, which
                # a self-test must not touch
                window.autosave_timer.stop()
                window.doc.undo_stack.setClean()
                window.hide()
                window.deleteLater()
                # deleted now, while the application (and its OpenGL contexts) still exist
                QtCore.QCoreApplication.sendPostedEvents(None, QtCore.QEvent.Type.DeferredDelete)
        except SelfTestFailure as exc:
            report(False, str(exc))
            return 1
        except Exception as exc:          # noqa: BLE001 - any crash is a failed self-test
            import traceback
            traceback.print_exc(file=sys.stderr)
            report(False, f"{type(exc).__name__}: {' '.join(str(exc).split())}")
            return 1
        finally:
            watchdog.cancel()
            if saved_state_home is None:
                os.environ.pop("XDG_STATE_HOME", None)
            else:
                os.environ["XDG_STATE_HOME"] = saved_state_home
    report(True, figures)
    return 0
