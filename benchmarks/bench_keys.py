"""Key fitting cost: a solve's correction fitted as keys and saved in a project.

    python benchmarks/bench_keys.py

The demo project (resources/demo/demo.mcp) is solved once (994 frames, every contact and the
hand). Two fits of its correction:

* keys fitted to the tasks (:func:`~engine.correction.keyfit.fit_to_tasks`, what a solve
  stores where they hold): the demo's edited motion, constraints and dense correction tiled
  1 and 4 times (994 and 3,976 frames); prints the seconds (wall and CPU), the keys per window
  frame and the 4x/1x ratio (target <= 4.4: linear);
* keys fitted to the dense curves (:meth:`DisplacementMap.from_dense` with the project's
  tolerances, what a solve keeps where the task fit misses): the correction tiled to 10,000
  and 100,000 frames, fitted, and the project holding those keys written; prints the
  seconds of each, the 100k/10k ratio (target <= 11: linear; before the fitted keys, saving a
  100k-frame project took 146 s) and the keys per frame.

Then the load average (LOADED instead of PASS or MISS above 1) and the targets line. This is
a report, not a test.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import REPO, Row, prepare, print_table  # noqa: E402

prepare(one_core=True)

import numpy as np  # noqa: E402

RATIO_TARGET = 11.0
FRAMES = (10_000, 100_000)
TILES = (1, 4)
TASK_RATIO_TARGET = 4.4


def _tiled(edited, constraints, correction, tiles: int):
    """The demo's edited motion, constraints and dense correction repeated ``tiles`` times
    (each copy's constraints moved to its frames)."""
    import dataclasses

    from motion_composer.engine.motion import Motion
    F = edited.num_frames
    motion = Motion(edited.skeleton, np.concatenate([edited.rotations] * tiles),
                    np.concatenate([edited.translations] * tiles), edited.frame_time,
                    edited.name)
    cons = [dataclasses.replace(c, smooth_in=c.smooth_in + k * F, start=c.start + k * F,
                                end=c.end + k * F, smooth_out=c.smooth_out + k * F)
            for k in range(tiles) for c in constraints if c.enabled]
    return (motion, cons, np.concatenate([correction.rotvecs] * tiles),
            np.concatenate([correction.root] * tiles))


def _task_fit(scene, solution) -> list:
    from motion_composer.engine.correction.keyfit import fit_to_tasks
    seconds, cpu = {}, {}
    for tiles in TILES:
        motion, cons, rotvecs, root = _tiled(scene.edited, solution.constraints,
                                             solution.correction, tiles)
        stats = {}
        t0, c0 = time.perf_counter(), time.process_time()
        keys = fit_to_tasks(motion, cons, rotvecs, root, stats=stats)
        seconds[tiles] = time.perf_counter() - t0
        cpu[tiles] = time.process_time() - c0
        count = sum(len(c) for c in keys.curves.values())
        print(f"task fit, {motion.num_frames:>6} frames: {seconds[tiles]:6.2f} s "
              f"({cpu[tiles]:.2f} s CPU), {count} keys on {len(keys.curves)} channels, worst "
              f"task {stats['worst_task_m'] * 1e3:.2f} mm beyond the dense solve")
    ratio = seconds[TILES[1]] / seconds[TILES[0]]
    cpu_ratio = cpu[TILES[1]] / cpu[TILES[0]]
    return [Row(f"task fit, {TILES[1]}x / {TILES[0]}x frames", f"{ratio:.1f}",
                f"<= {TASK_RATIO_TARGET:g} (linear)", ratio <= TASK_RATIO_TARGET,
                f"CPU {cpu_ratio:.1f}; {seconds[TILES[0]]:.2f} s and "
                f"{seconds[TILES[1]]:.2f} s")]


def main() -> int:
    from motion_composer.engine.correction.displacement import DisplacementMap
    from motion_composer.engine.project import open_project, save_project
    from motion_composer.engine.project.files import POSITION_TOLERANCE, ROTATION_TOLERANCE
    from motion_composer.engine.scene import Scene

    project, performer, target = open_project(REPO / "resources" / "demo" / "demo.mcp")
    scene = Scene(project, performer, target)
    solution = scene.solve(regenerate=True)
    correction = solution.correction
    task_rows = _task_fit(scene, solution)
    seconds = {}
    for frames in FRAMES:
        rows = np.resize(np.arange(len(correction.root)), frames)
        t0 = time.perf_counter()
        keys = DisplacementMap.from_dense(target.skeleton, correction.rotvecs[rows],
                                          correction.root[rows],
                                          position_tolerance=POSITION_TOLERANCE,
                                          rotation_tolerance=ROTATION_TOLERANCE)
        fit = time.perf_counter() - t0
        with tempfile.TemporaryDirectory() as folder:
            t0 = time.perf_counter()
            save_project(project.replace(displacement=keys), Path(folder) / "long.mcp")
            save = time.perf_counter() - t0
        count = sum(len(c) for c in keys.curves.values())
        seconds[frames] = fit + save
        print(f"{frames:>7} frames: fit {fit:6.2f} s, save {save:6.2f} s, "
              f"{count / (frames * len(keys.curves)):.3f} keys per channel-frame")
    ratio = seconds[FRAMES[1]] / seconds[FRAMES[0]]
    print_table("key fitting (tasks: 4x against 1x the demo; dense curves and saving: 100k "
                "frames against 10k)", task_rows + [
        Row("fit + save, 100k / 10k", f"{ratio:.1f}", f"<= {RATIO_TARGET:g} (linear)",
            ratio <= RATIO_TARGET,
            f"{seconds[FRAMES[0]]:.2f} s and {seconds[FRAMES[1]]:.2f} s")])
    return 0


if __name__ == "__main__":
    sys.exit(main())
