"""BVH reading, forward kinematics and writing: speed against bvhio, and peak memory.

    python benchmarks/bench_bvh.py [--repeat N] [--ref-repeat N] [--file PATH] [--no-reference]

Measures on ``cc3_cmu_02_06_pickup.bvh`` from the shared data (1118 frames, 100 joints, 3.3 MB),
or the file given with ``--file``:

* reference: ``bvhio.readAsHierarchy(path)``, median of ``--ref-repeat`` runs (3; ~3 s each);
* ours: ``engine.read_bvh(path)`` then ``engine.forward_kinematics(motion)`` (world rotations
  and positions of every joint and End Site, every frame), median of ``--repeat`` runs (9);
* the ratio of the two medians (target >= 30x);
* ``engine.formats.bvh.write_bvh`` of the motion to a temporary folder, median (target < 0.2 s);
* peak memory of one read plus FK in a fresh interpreter (target < 200 MB): the peak RSS minus
  the RSS after imports, and tracemalloc's peak (numpy reports its array buffers to tracemalloc,
  so this counts numpy data and Python objects, not the interpreter or the libraries).

The reference does less than ours: it builds bvhio's joint tree with local keyframes but
computes no world positions. This is a report, not a test: it exits 0 whether or not the
targets are met.
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import prepare  # noqa: E402

ALLOCATOR = prepare(one_core=False)    # as motion-composer sets itself up

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402

from _common import (Row, data_file, environment, fmt_seconds, max_rss_mib,  # noqa: E402
                     print_table, proc_status_mib, run_child, time_interleaved, time_runs)

FILE = "cc3_cmu_02_06_pickup.bvh"
FALLBACK = "cmu_131_01_walk.bvh"
RATIO_TARGET = 30.0
WRITE_TARGET = 0.2          # [s]
MEMORY_TARGET = 200.0       # [MB], taken as MiB: the stricter reading


def read_and_fk(path):
    from motion_composer import engine
    motion = engine.read_bvh(path)
    return motion, engine.forward_kinematics(motion)


# --------------------------------------------------------------------------- memory children
def child_memory(path: str, mode: str) -> dict:
    """Run in a fresh interpreter: memory of one read plus FK, measured one way."""
    import gc

    import numpy as np

    # imports count towards the baseline, not the figure
    from motion_composer import engine  # noqa: F401
    gc.collect()
    if mode == "rss":
        base_peak, base_hwm = max_rss_mib(), proc_status_mib("VmHWM")
        base_now = proc_status_mib("VmRSS")
        motion, pose = read_and_fk(path)
        peak, hwm = max_rss_mib(), proc_status_mib("VmHWM")
        return {"baseline_peak_mib": base_peak, "baseline_rss_mib": base_now, "peak_mib": peak,
                "delta_mib": peak - base_peak,
                "hwm_delta_mib": None if hwm is None else hwm - base_hwm}
    import tracemalloc
    tracemalloc.start()
    motion, pose = read_and_fk(path)
    current, peak = tracemalloc.get_traced_memory()
    snap = tracemalloc.take_snapshot().filter_traces(
        [tracemalloc.DomainFilter(True, np.lib.tracemalloc_domain)])
    numpy_live = sum(stat.size for stat in snap.statistics("filename"))
    tracemalloc.stop()
    result_bytes = (motion.rotations.nbytes + motion.translations.nbytes +
                    pose.rotations.nbytes + pose.positions.nbytes + pose.end_positions.nbytes)
    return {"peak_mib": peak / 2**20, "live_mib": current / 2**20,
            "numpy_live_mib": numpy_live / 2**20, "result_mib": result_bytes / 2**20}


# --------------------------------------------------------------------------- main
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=9,
                        help="timed runs of our reader and writer (default 9; use >= 7)")
    parser.add_argument("--ref-repeat", type=int, default=3,
                        help="timed runs of bvhio, ~3 s each (default 3)")
    parser.add_argument("--file", help=f"BVH file to measure (default: {FILE} from the shared "
                                       "data)")
    parser.add_argument("--no-reference", action="store_true",
                        help="skip bvhio (quick runs: no ratio)")
    parser.add_argument("--child-memory", choices=["rss", "tracemalloc"], help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    if args.child_memory:
        print(json.dumps(child_memory(args.file, args.child_memory)))
        return 0

    path = data_file(FILE, FALLBACK, args.file)
    repeat = max(1, args.repeat)
    ref_repeat = max(1, args.ref_repeat)
    if repeat < 7 or ref_repeat < 3:
        print("note: fewer runs than the standard 7 (ours) and 3 (bvhio); medians are rougher\n")

    # (e) memory first, each way in its own fresh interpreter, while this process is still small:
    # on Linux a child inherits its parent's ru_maxrss (see _common.max_rss_mib)
    script = Path(__file__).resolve()
    parent_peak = max_rss_mib()
    rss = run_child(script, ["--file", str(path), "--child-memory", "rss"])
    traced = run_child(script, ["--file", str(path), "--child-memory", "tracemalloc"])

    from motion_composer.engine.formats.bvh import write_bvh

    motion, pose = read_and_fk(path)                 # also the warm-up run
    sk = motion.skeleton
    print(f"file: {path} ({path.stat().st_size / 1e6:.1f} MB): {motion.num_frames} frames, "
          f"{sk.num_joints} joints, {sk.num_channels} channels, {len(sk.end_sites)} End Sites")
    print(f"      {environment()}; allocator tuned as the application does: {ALLOCATOR}\n")

    rows: list[Row] = []

    # (a) reference, (b) ours and (c) their ratio; the two take turns, so that a change in the
    # machine's load while the benchmark runs affects both alike
    ours_fn = lambda: read_and_fk(path)                               # noqa: E731
    bvhio = None
    if args.no_reference:
        ref_note = "skipped (--no-reference)"
    else:
        try:
            import bvhio
        except ImportError:
            ref_note = "n/a: bvhio is not installed (pip install bvhio)"
    if bvhio is None:
        ours = time_runs(ours_fn, repeat, warmup=0)
        rows.append(Row("reference: bvhio.readAsHierarchy", "-", note=ref_note))
        rows.append(Row("ours: read_bvh + forward_kinematics", fmt_seconds(ours.median),
                        note=f"median; {ours.spread()}"))
    else:
        timed = time_interleaved({"ref": (lambda: bvhio.readAsHierarchy(str(path)), ref_repeat),
                                  "ours": (ours_fn, repeat)}, rounds=ref_repeat)
        ref, ours = timed["ref"], timed["ours"]
        ratio = ref.median / ours.median
        rows.append(Row("reference: bvhio.readAsHierarchy", fmt_seconds(ref.median),
                        note=f"median, no warm-up; {ref.spread()}"))
        rows.append(Row("ours: read_bvh + forward_kinematics", fmt_seconds(ours.median),
                        note=f"median; {ours.spread()}; taking turns with the reference"))
        rows.append(Row("ratio reference / ours", f"{ratio:.1f}x", f">= {RATIO_TARGET:.0f}x",
                        ratio >= RATIO_TARGET))

    # (d) writing
    with tempfile.TemporaryDirectory(prefix="mc_bench_") as folder:
        out = Path(folder) / "out.bvh"
        write = time_runs(lambda: write_bvh(motion, out), repeat, label="write")
        size = out.stat().st_size
    rows.append(Row("write_bvh (atomic, fsynced)", fmt_seconds(write.median),
                    f"< {WRITE_TARGET} s", write.median < WRITE_TARGET,
                    f"median; {write.spread()}; {size / 1e6:.1f} MB written"))

    rows.append(Row("peak RSS of read + FK, above baseline", f"{rss['delta_mib']:.1f} MiB",
                    f"< {MEMORY_TARGET:.0f} MB", rss["delta_mib"] < MEMORY_TARGET,
                    f"ru_maxrss: peak {rss['peak_mib']:.1f} - {rss['baseline_peak_mib']:.1f} MiB "
                    f"after imports" + ("" if rss["hwm_delta_mib"] is None else
                                        f"; VmHWM says {rss['hwm_delta_mib']:.1f} MiB")))
    if rss["baseline_peak_mib"] <= parent_peak + 1.0:
        rows[-1].note += (f" (UNRELIABLE: the child's baseline is the parent's "
                          f"{parent_peak:.1f} MiB)")
    rows.append(Row("tracemalloc peak of read + FK", f"{traced['peak_mib']:.1f} MiB",
                    f"< {MEMORY_TARGET:.0f} MB", traced["peak_mib"] < MEMORY_TARGET,
                    "numpy buffers and Python objects; "
                    f"{traced['numpy_live_mib']:.1f} MiB of numpy buffers live at the end "
                    f"(result arrays {traced['result_mib']:.1f} MiB)"))

    print_table(f"BVH benchmark, {path.name}", rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
