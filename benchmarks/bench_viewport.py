"""Viewport frame rate and start-up: the full main window, stepped frame by frame.

    xvfb-run -a -s "-screen 0 1920x1200x24" python benchmarks/bench_viewport.py [--frames N]

* skeleton: the bundled demo (resources/demo/demo.mcp) in the main window at 1600 x 1000 with
  its docks shown; each step sets the next frame and waits until the viewport has drawn it
  (``frameSwapped``), so the figure counts distinct frames drawn per second;
* skinned: ``cc3_cmu_02_06_pickup.bvh`` (performer) on ``target_robot_expressive.glb``
  (target, skinned: 7,214 vertices) imported into the same window, stepped the same way;
* first frame T: process spawn to the demo's first drawn frame (``motion-composer --demo``,
  its ``start`` wrapped to time the viewport's next ``frameSwapped``);
* bare T0: process spawn to the first frame of a bare PySide6 window holding one
  pyqtgraph ``GLViewWidget`` (the floor under T); medians of ``--starts`` spawns each, taking
  turns;
* info: ``motion-composer info`` on the bundled walk (process spawn to exit).

The spawned children keep their compiled bytecode in ``/tmp/mc-bench-pycache``
(``PYTHONPYCACHEPREFIX``, even where ``PYTHONDONTWRITEBYTECODE`` is set): an installed program
starts from compiled modules, and compiling the project's sources on every start would be
counted otherwise (about 0.3 s of ``info``). One warm-up spawn of each fills it.

Needs an X server with OpenGL (Xvfb + Mesa here); a report, not a test: exits 0 either way.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import REPO, SHARED_DATA, Row, environment, prepare, print_table  # noqa: E402

import argparse  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import time  # noqa: E402

SKELETON_FPS, SKINNED_FPS, GOAL_FPS = 45.0, 30.0, 60.0
SKINNED_RATIO = 0.7
START_RATIO = 1.5
INFO_S = 0.5
PERFORMER = "cc3_cmu_02_06_pickup.bvh"
CHARACTER = "target_robot_expressive.glb"

#: a bare PySide6 window with one GLViewWidget: prints seconds from ``argv[1]`` (the parent's
#: time.time() at spawn) to its first swapped frame
BARE = """
import sys, time, os
spawn = float(sys.argv[1])
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")
from PySide6 import QtCore, QtWidgets
QtCore.QCoreApplication.setAttribute(QtCore.Qt.ApplicationAttribute.AA_ShareOpenGLContexts)
import pyqtgraph.opengl as gl
app = QtWidgets.QApplication([])
w = QtWidgets.QMainWindow()
v = gl.GLViewWidget()
w.setCentralWidget(v)
w.resize(1600, 1000)
def drawn():
    print(time.time() - spawn, flush=True)
    os._exit(0)
v.frameSwapped.connect(drawn)
w.show()
app.exec()
"""

#: ``motion-composer --demo``, timed from spawn to the viewport's first frame after the demo
#: opened (``start`` returns once it has: its frame is the next one drawn)
DEMO = """
import sys, time, os
spawn = float(sys.argv[1])
import motion_composer.app.gui.main as main
opened = main.start
def start(window, project=None, *, demo=False):
    ok = opened(window, project, demo=demo)
    def drawn():
        print(time.time() - spawn, flush=True)
        os._exit(0 if ok else 1)
    window.viewport.frameSwapped.connect(drawn)
    window.viewport.update()
    return ok
main.start = start
from motion_composer.app.cli import main as cli
sys.exit(cli(["--demo"]))
"""


def child_env() -> dict:
    """The spawned children's environment: the repository on the path, compiled bytecode
    kept (in a cache of its own), settings and autosaves in /tmp."""
    env = dict(os.environ, XDG_STATE_HOME="/tmp/mc-bench-state",
               PYTHONPYCACHEPREFIX="/tmp/mc-bench-pycache")
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    return env


def spawn_seconds(code: str, *args: str) -> float:
    """Seconds from spawning ``python -c code`` to the figure it prints."""
    env = child_env()
    t = time.time()
    out = subprocess.run([sys.executable, "-c", code, repr(t), *args], capture_output=True,
                         text=True, timeout=120, env=env, cwd=REPO)
    if out.returncode != 0 or not out.stdout.strip():
        raise RuntimeError(f"child failed (exit {out.returncode}):\n{out.stderr}")
    return float(out.stdout.strip().splitlines()[-1])


def info_seconds(path: Path) -> float:
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "motion_composer", "info", str(path)],
                   capture_output=True, check=True, cwd=REPO, env=child_env())
    return time.perf_counter() - t


def step_fps(app, window, frames: int) -> float:
    """Distinct frames drawn per second: each step sets the next frame and waits for the
    viewport's paint of it."""
    doc, view = window.doc, window.viewport
    drawn = []
    view.frameSwapped.connect(lambda: drawn.append(True))
    last = doc.scene.num_frames - 1
    first = doc.scene.viewer.current_frame

    def step(k):
        drawn.clear()
        doc.set_frame((first + 1 + k) % last)
        while not drawn:
            app.processEvents(QtCore_flags.WaitForMoreEvents)

    for k in range(5):                                    # warm-up
        step(k)
    t = time.perf_counter()
    for k in range(frames):
        step(5 + k)
    return frames / (time.perf_counter() - t)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=240, help="frames stepped per figure")
    parser.add_argument("--starts", type=int, default=3, help="spawns per start-up figure")
    args = parser.parse_args()
    if not os.environ.get("DISPLAY"):
        sys.exit("error: no display: run it under xvfb-run (it needs OpenGL)")
    load_start = os.getloadavg()[0]

    spawn_seconds(BARE), spawn_seconds(DEMO)            # warm-up: the bytecode cache
    first, bare = [], []
    for _ in range(args.starts):
        bare.append(spawn_seconds(BARE))
        first.append(spawn_seconds(DEMO))
    T, T0 = statistics.median(first), statistics.median(bare)
    small = REPO / "resources" / "clips" / "cmu_rest_tpose.bvh"
    info_seconds(small)                                   # warm the file cache
    info = statistics.median(info_seconds(small) for _ in range(args.starts))

    prepare()
    global QtCore_flags
    from motion_composer.app.gui.qt import QtCore, application
    QtCore_flags = QtCore.QEventLoop.ProcessEventsFlag
    QtCore.QSettings.setDefaultFormat(QtCore.QSettings.Format.IniFormat)
    QtCore.QSettings.setPath(QtCore.QSettings.Format.IniFormat,
                             QtCore.QSettings.Scope.UserScope, "/tmp/mc-bench-settings")
    os.environ["XDG_STATE_HOME"] = "/tmp/mc-bench-state"
    app = application([])
    from motion_composer.app.gui.main import _without_dialogs, demo_project
    from motion_composer.app.gui.main_window import MainWindow
    window = MainWindow()
    _without_dialogs(window)
    window.resize(1600, 1000)
    window.show()
    while not (window.windowHandle() and window.windowHandle().isExposed()):
        app.processEvents()
    assert window.open_project(demo_project()), window.errors
    skeleton = step_fps(app, window, args.frames)
    vw, vh = window.viewport.width(), window.viewport.height()

    performer, character = SHARED_DATA / PERFORMER, SHARED_DATA / CHARACTER
    if not character.is_file():
        character = REPO / "resources" / "characters" / CHARACTER
    skinned = None
    if performer.is_file() and character.is_file():
        assert window.import_file("performer", performer), window.errors
        assert window.import_file("target", character), window.errors
        assert window.doc.scene.ready and window.viewport.skin is not None
        skinned = step_fps(app, window, args.frames)
        vertices = window.doc.scene.character.num_vertices
    load = max(load_start, os.getloadavg()[0])
    window.doc.undo_stack.setClean()
    window.close()

    K = skinned if skinned is not None else float("nan")
    print(f"{environment()}; Xvfb, {window.viewport.context().format().majorVersion()}."
          f"{window.viewport.context().format().minorVersion()} GL"
          if window.viewport.context() else environment())
    print(f"main window 1600 x 1000, viewport {vw} x {vh}; {args.frames} frames stepped per "
          f"figure; start-up medians of {args.starts} spawns\n")
    print(f"viewport fps: skeleton {skeleton:.1f}, skinned {K:.1f}, first frame {T:.2f} s, "
          f"bare {T0:.2f} s, load {load:.2f}")
    rows = [
        Row("skeleton fps (demo, stepped)", f"{skeleton:.1f}", f">= {SKELETON_FPS:.0f} "
            f"(goal {GOAL_FPS:.0f})", skeleton >= SKELETON_FPS),
        Row("skinned fps (robot on pick-up)", "absent" if skinned is None else f"{K:.1f}",
            f">= {SKINNED_FPS:.0f} (goal {GOAL_FPS:.0f})",
            None if skinned is None else K >= SKINNED_FPS,
            note="" if skinned is None else f"{vertices} vertices"),
        Row("skinned / skeleton", "absent" if skinned is None else f"{K / skeleton:.2f}",
            f">= {SKINNED_RATIO}", None if skinned is None else K / skeleton >= SKINNED_RATIO),
        Row("first frame T (spawn to demo drawn)", f"{T:.2f} s", f"<= {START_RATIO} T0",
            T <= START_RATIO * T0, note=f"T / T0 = {T / T0:.2f}"),
        Row("bare T0 (PySide6 + GLViewWidget)", f"{T0:.2f} s", ""),
        Row("info on a small file (spawn to exit)", f"{info:.2f} s", f"< {INFO_S} s",
            info < INFO_S, note=small.name),
    ]
    print_table("Viewport", rows)


if __name__ == "__main__":
    main()
