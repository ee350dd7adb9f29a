"""Key fitting cost: a solve's dense correction fitted as keys and saved in a project.

    python benchmarks/bench_keys.py

The demo project (resources/demo/demo.mcp) is solved once; its dense correction (994 frames,
every contact and the hand) is tiled to 10,000 and 100,000 frames and fitted as keys
(:meth:`DisplacementMap.from_dense` with the project's tolerances), then the project holding
those keys is written. Prints the seconds of each, the 100k/10k ratio (target <= 11: linear;
before the fitted keys, saving a 100k-frame project took 146 s) and the keys per frame, and
the load average (LOADED instead of PASS or MISS above 1), ending with the targets line. This
is a report, not a test.
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


def main() -> int:
    from motion_composer.engine.correction.displacement import DisplacementMap
    from motion_composer.engine.project import open_project, save_project
    from motion_composer.engine.project.files import POSITION_TOLERANCE, ROTATION_TOLERANCE
    from motion_composer.engine.scene import Scene

    project, performer, target = open_project(REPO / "resources" / "demo" / "demo.mcp")
    correction = Scene(project, performer, target).solve(regenerate=True).correction
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
    print_table("key fitting and saving, 100k frames against 10k", [
        Row("fit + save, 100k / 10k", f"{ratio:.1f}", f"<= {RATIO_TARGET:g} (linear)",
            ratio <= RATIO_TARGET,
            f"{seconds[FRAMES[0]]:.2f} s and {seconds[FRAMES[1]]:.2f} s")])
    return 0


if __name__ == "__main__":
    sys.exit(main())
