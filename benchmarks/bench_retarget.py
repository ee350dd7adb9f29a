"""Direct conversion speed (Motion Converter + Motion Composer): frames per second.

    python benchmarks/bench_retarget.py [--repeat N]

Converts ``cmu_mb_01_01_jumps.bvh`` (2752 frames at 120 fps) onto the Bandai skeleton (22
joints) and the CC3 skeleton (100 joints), and reports for each, as medians of ``--repeat``
runs (9) after a warm-up:

* the conversion itself (``convert`` then ``compose``: performer forward kinematics, every
  target joint's rotation, local values, root translation): frames per second, target
  >= 100,000 (the paper: real time);
* the one-off Anatomic Binding (``bind``) that precedes it, for information;
* the whole ``retarget`` call (bind + convert + compose).

The mapping is the automatic one (``engine.conversion.automap``).
BLAS threads are pinned to 1. This is a report, not a test.
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import prepare  # noqa: E402

ALLOCATOR = prepare(one_core=True)    # as motion-composer sets itself up

import argparse  # noqa: E402

from _common import (Row, SHARED_DATA, environment, fmt_seconds, print_table,  # noqa: E402
                     time_runs)

FPS_TARGET = 100_000.0



def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=9)
    args = parser.parse_args()

    from motion_composer.engine import read_bvh
    from motion_composer.engine.conversion import bind
    from motion_composer.engine.conversion import compose, retarget
    from motion_composer.engine.conversion import convert

    clip = SHARED_DATA / "cmu_mb_01_01_jumps.bvh"
    targets = {"Bandai": "bandai1_walk_normal_001.bvh", "CC3": "cc3_cmu_02_06_pickup.bvh"}
    if not clip.is_file():
        sys.exit(f"error: this benchmark needs {clip} (set MC_SHARED_DATA)")
    performer = read_bvh(clip)
    F = performer.num_frames
    from motion_composer.engine.conversion.automap import automap
    print(f"allocator tuned as the application does: {ALLOCATOR}; {environment()}; BLAS threads pinned to 1")
    print(f"{clip.name}: {F} frames, {performer.skeleton.num_joints} joints\n")
    for label, name in targets.items():
        target = read_bvh(SHARED_DATA / name)
        corr, how = automap(target.skeleton, performer.skeleton), "automatic mapping"
        binding = bind(performer, target, corr)

        def conversion():
            return compose(binding, convert(binding, performer), performer.frame_time)

        conv = time_runs(conversion, args.repeat)
        binds = time_runs(lambda: bind(performer, target, corr), args.repeat)
        whole = time_runs(lambda: retarget(performer, target, corr), args.repeat)
        fps = F / conv.median
        print_table(f"onto {label} ({target.skeleton.num_joints} joints, {len(corr)} mapped, "
                    f"{how})", [
                        Row("conversion (convert + compose)", fmt_seconds(conv.median), "",
                            note=conv.spread()),
                        Row("frames per second", f"{fps:,.0f}", f">= {FPS_TARGET:,.0f}",
                            fps >= FPS_TARGET),
                        Row("anatomic binding (once)", fmt_seconds(binds.median), "",
                            note=binds.spread()),
                        Row("whole retarget call", fmt_seconds(whole.median), "",
                            note=f"{F / whole.median:,.0f} frames per second"),
                    ])
        print()


if __name__ == "__main__":
    main()
