"""The paper's frame-by-frame IK scheme against the batched solver: the same results, and the
ratio of their speeds.

    python benchmarks/bench_warm_start.py [--frames N]

The CMU walk (``cmu_max_131_01_walk.bvh``) converted onto the Bandai skeleton with automatic
foot contacts is corrected twice in this process, on one core (BLAS pinned to one thread):
batched (``enforce``, the default) and frame by frame with a warm start from t - 1
(``enforce(..., warm_start=True)``, section 3.3 of the paper; about 18 frames per second here).
The first ``--frames`` frames (300; 0 for the whole clip, about a minute) are used. Reports:

* the largest difference between the two corrected motions: joint positions (target <= 1 mm)
  and the largest constraint residual of each (target <= 1 mm);
* the time of each and batched / frame by frame as a speed ratio (a figure, no target).

Each is timed once after a warm-up of the batched solver. With a load average over 1 the
targets read LOADED. This is a report, not a test.
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import prepare  # noqa: E402

ALLOCATOR = prepare(one_core=True)    # as motion-composer sets itself up

import argparse  # noqa: E402

import numpy as np  # noqa: E402

from _common import (Row, SHARED_DATA, environment, fmt_seconds, print_table,  # noqa: E402
                     time_runs)

WALK = SHARED_DATA / "cmu_max_131_01_walk.bvh"
BANDAI = SHARED_DATA / "bandai1_walk_normal_001.bvh"
EQUAL_TARGET = 1e-3          # [m]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300,
                        help="frames of the walk to correct (300; 0: all, about a minute)")
    args = parser.parse_args()
    if not (WALK.is_file() and BANDAI.is_file()):
        sys.exit(f"error: this benchmark needs {WALK} and {BANDAI} (set MC_SHARED_DATA)")

    from motion_composer.engine import forward_kinematics, read_bvh
    from motion_composer.engine.conversion import retarget
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.correction.contacts import contact_constraints, detect_contacts
    from motion_composer.engine.correction.enforcement import enforce

    performer, target = read_bvh(WALK), read_bvh(BANDAI)
    if args.frames:
        performer = performer.frames(slice(0, args.frames))
    corr = automap(target.skeleton, performer.skeleton)
    composed = retarget(performer, target, corr)
    cons = contact_constraints(detect_contacts(performer), performer, composed, corr.pairs)
    F = composed.num_frames

    results = {}

    def solve(warm: bool):
        results[warm] = enforce(composed, cons, warm_start=warm)

    batched = time_runs(lambda: solve(False), 1, warmup=1, label="batched")
    framewise = time_runs(lambda: solve(True), 1, warmup=0, label="frame by frame")
    a, b = (forward_kinematics(results[w].motion).positions for w in (False, True))
    gaps = np.linalg.norm(a - b, axis=-1)                                  # (F, J)
    frame, joint = np.unravel_index(int(np.argmax(gaps)), gaps.shape)
    apart = float(gaps[frame, joint])
    turn = float(np.abs(results[False].rotvecs - results[True].rotvecs).max())

    def worst_residual(result) -> float:
        return max((float(np.nanmax(result.residual[i][c.start:c.end + 1]))
                    for i, c in enumerate(cons) if c.kind == "position"), default=0.0)

    res_b, res_f = worst_residual(results[False]), worst_residual(results[True])
    print(f"allocator tuned as the application does: {ALLOCATOR}; {environment()}; "
          f"BLAS threads pinned to 1")
    print(f"{WALK.name} ({F} frames) onto {BANDAI.name}'s skeleton; {len(cons)} contact "
          f"constraints\n")
    print_table("Batched IK against the paper's frame-by-frame scheme", [
        Row("largest joint position difference", f"{apart * 1000:.3f} mm",
            f"<= {EQUAL_TARGET * 1000:g} mm", apart <= EQUAL_TARGET,
            note=f"{composed.skeleton.names[joint]} at frame {frame}; largest rotation "
                 f"offset difference {np.degrees(turn):.3f} deg"),
        Row("largest residual, batched", f"{res_b * 1000:.3f} mm",
            f"<= {EQUAL_TARGET * 1000:g} mm", res_b <= EQUAL_TARGET),
        Row("largest residual, frame by frame", f"{res_f * 1000:.3f} mm",
            f"<= {EQUAL_TARGET * 1000:g} mm", res_f <= EQUAL_TARGET),
        Row("batched", fmt_seconds(batched.median),
            note=f"{F / batched.median:,.0f} frames per second"),
        Row("frame by frame (warm start)", fmt_seconds(framewise.median),
            note=f"{F / framewise.median:,.1f} frames per second"),
        Row("speed ratio batched / frame by frame", f"{framewise.median / batched.median:.0f}x"),
    ])


if __name__ == "__main__":
    main()
