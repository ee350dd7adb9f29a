"""Direct conversion speed (Motion Converter + Motion Composer), as a ratio to forward kinematics,
and its peak memory on 100,000 frames.

    python benchmarks/bench_retarget.py [--repeat N]

Converts ``cmu_mb_01_01_jumps.bvh`` (2752 frames at 120 fps, 31 joints) onto the Bandai
skeleton (22 joints) and the CC3 skeleton (100 joints), automatic mapping, and reports for each:

* the conversion (``transfer``: performer forward kinematics, every target joint's rotation,
  local values, root translation; what ``retarget`` runs after the one-off ``bind``) against
  the reference, one forward-kinematics pass of the performer's skeleton over the same frames
  (``forward_kinematics(performer)``), timed taking turns in this process: the ratio of the
  medians (target <= 3x) and frames per second (target >= 100,000);
* the staged path the scene caches (``convert`` then ``compose``) and the one-off Anatomic
  Binding, for information;
* the peak memory of ``retarget`` on the clip tiled to 100,000 frames, in a fresh interpreter:
  ``ru_maxrss`` above the baseline after the imports (target <= 600 MB), and above the inputs.

BLAS threads are pinned to 1. With a load average over 1 the targets read LOADED. This is a
report, not a test.
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import prepare  # noqa: E402

ALLOCATOR = prepare(one_core=True)    # as motion-composer sets itself up

import argparse  # noqa: E402
import json  # noqa: E402

from _common import (MIB_PER_MB, Row, SHARED_DATA, environment, fmt_seconds,  # noqa: E402
                     max_rss_mib, print_table, ratio_row, run_child, time_interleaved)

CLIP = SHARED_DATA / "cmu_mb_01_01_jumps.bvh"
TARGETS = {"Bandai": "bandai1_walk_normal_001.bvh", "CC3": "cc3_cmu_02_06_pickup.bvh"}
RATIO_TARGET = 3.0            # conversion / one FK pass of the performer
FPS_TARGET = 100_000.0
MEMORY_FRAMES = 100_000
MEMORY_TARGET = 600.0         # [MB]: 572.2 MiB


def _job(target_name: str):
    from motion_composer.engine import read_bvh
    from motion_composer.engine.conversion.automap import automap
    performer, target = read_bvh(CLIP), read_bvh(SHARED_DATA / target_name)
    return performer, target, automap(target.skeleton, performer.skeleton)


def _child_memory(target_name: str) -> None:
    """Print, as JSON, the peak memory of one retarget of the clip tiled to MEMORY_FRAMES."""
    import numpy as np

    from motion_composer.engine.conversion import retarget
    imported = max_rss_mib()
    performer, target, corr = _job(target_name)
    tiled = performer.frames(np.resize(np.arange(performer.num_frames), MEMORY_FRAMES))
    del performer
    inputs = max_rss_mib()
    result = retarget(tiled, target, corr)
    peak = max_rss_mib()
    print(json.dumps({"imported_mib": imported, "inputs_mib": inputs, "peak_mib": peak,
                      "result_mib": (result.rotations.nbytes + result.translations.nbytes)
                      / 2**20}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15,
                        help="timed runs of each call (default 15)")
    parser.add_argument("--child-memory", metavar="TARGET", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child_memory:
        _child_memory(args.child_memory)
        return
    missing = [p for p in [CLIP, *(SHARED_DATA / n for n in TARGETS.values())] if not p.is_file()]
    if missing:
        sys.exit(f"error: this benchmark needs {', '.join(map(str, missing))} "
                 "(set MC_SHARED_DATA)")
    # first, while this process is small (ru_maxrss carries over into a child)
    memory = {label: run_child(Path(__file__), ["--child-memory", name])
              for label, name in TARGETS.items()}

    from motion_composer.engine import forward_kinematics
    from motion_composer.engine.conversion import bind, compose, convert, transfer

    rows: list[Row] = []
    for label, name in TARGETS.items():
        performer, target, corr = _job(name)
        F = performer.num_frames
        binding = bind(performer, target, corr)
        calls = {"reference": (lambda: forward_kinematics(performer), args.repeat),
                 "conversion": (lambda: transfer(binding, performer), args.repeat),
                 "staged": (lambda: compose(binding, convert(binding, performer),
                                            performer.frame_time), args.repeat),
                 "bind": (lambda: bind(performer, target, corr), args.repeat)}
        for fn, _ in calls.values():                                   # warm-up
            fn()
        timed = time_interleaved(calls, rounds=args.repeat)
        conv, ref = timed["conversion"], timed["reference"]
        fps = F / conv.median
        where = f"onto {label} ({target.skeleton.num_joints} joints, {len(corr)} mapped)"
        rows += [
            Row(f"{where}: FK of the performer (reference)", fmt_seconds(ref.median),
                note=f"median; {ref.spread()}"),
            ratio_row("  conversion / reference", conv, ref, RATIO_TARGET),
            Row("  frames per second", f"{fps:,.0f}", f">= {FPS_TARGET:,.0f}",
                fps >= FPS_TARGET),
            Row("  staged: convert + compose", fmt_seconds(timed["staged"].median),
                note=f"{timed['staged'].median / ref.median:.2f}x the reference; "
                     f"{timed['staged'].spread()}"),
            Row("  anatomic binding (once)", fmt_seconds(timed["bind"].median),
                note=timed["bind"].spread()),
        ]
    for label, m in memory.items():
        above = m["peak_mib"] - m["imported_mib"]
        rows.append(Row(f"retarget of {MEMORY_FRAMES:,} frames onto {label}: peak memory",
                        f"{above:,.0f} MiB", f"<= {MEMORY_TARGET:,.0f} MB",
                        above <= MEMORY_TARGET * MIB_PER_MB,
                        note=f"ru_maxrss above {m['imported_mib']:,.0f} MiB after imports; "
                             f"{m['peak_mib'] - m['inputs_mib']:,.0f} MiB above the inputs; "
                             f"the result is {m['result_mib']:,.0f} MiB"))
    print(f"allocator tuned as the application does: {ALLOCATOR}; {environment()}; "
          f"BLAS threads pinned to 1")
    print(f"{CLIP.name}: {F} frames, {performer.skeleton.num_joints} joints; medians of "
          f"{args.repeat} runs taking turns\n")
    print_table("Direct conversion (transfer: convert + compose by runs of frames)", rows)


if __name__ == "__main__":
    main()
