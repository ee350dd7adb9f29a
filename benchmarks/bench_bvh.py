"""BVH reading, forward kinematics and writing, as ratios to numpy.loadtxt of the same MOTION
block, and peak memory.

    python benchmarks/bench_bvh.py [--repeat N] [--file PATH] [--big-mb N] [--bvhio]

Measures on ``cc3_cmu_02_06_pickup.bvh`` from the shared data (1118 frames, 100 joints, 3.3 MB),
or the file given with ``--file``, taking turns in this process with the reference,
``numpy.loadtxt`` of the file's MOTION rows (the C parser's floor for the same numbers):

* ours: ``engine.read_bvh(path)`` then ``engine.forward_kinematics(motion)`` (world rotations
  and positions of every joint and End Site, every frame): the ratio to the reference (target
  <= 2x);
* ``engine.formats.bvh.write_bvh`` of the motion to a temporary folder (formatting plus the
  atomic, fsynced write): the ratio to the reference (target <= 1.5x) and the time (target
  < 0.2 s); ``format_bvh`` alone for information;
* peak memory in fresh interpreters, ``ru_maxrss`` above the baseline after the imports: one
  read plus FK of the file (target < 200 MB), tracemalloc's peak of the same (numpy reports its
  array buffers to tracemalloc), and one read of the file's rows tiled to ``--big-mb`` MB (72)
  in a temporary folder (target: at most 3x the file's size);
* with ``--bvhio``, ``bvhio.readAsHierarchy(path)`` as a second reference (~3 s a run; it
  builds bvhio's joint tree with local keyframes but computes no world positions; target:
  ours >= 30x faster).

Medians of ``--repeat`` runs (9). With a load average over 1 the targets read LOADED. This is a
report, not a test: it exits 0 whether or not the targets are met.
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

from _common import (MIB_PER_MB, Row, data_file, environment, fmt_seconds,  # noqa: E402
                     max_rss_mib, print_table, proc_status_mib, ratio_row, run_child,
                     time_interleaved)

FILE = "cc3_cmu_02_06_pickup.bvh"
FALLBACK = "cmu_131_01_walk.bvh"
READ_TARGET = 2.0           # read + FK / loadtxt
WRITE_RATIO_TARGET = 1.5    # write / loadtxt
WRITE_TARGET = 0.2          # [s]
MEMORY_TARGET = 200.0       # [MB]: 190.7 MiB
BIG_TARGET = 3.0            # peak memory of a read / file size
BVHIO_TARGET = 30.0


def read_and_fk(path):
    from motion_composer import engine
    motion = engine.read_bvh(path)
    return motion, engine.forward_kinematics(motion)


def motion_rows(path: Path) -> tuple[str, list[str]]:
    """The file's text before its MOTION rows, and the rows (the lines after Frame Time:)."""
    lines = path.read_text(encoding="utf-8-sig").replace("\r\n", "\n").split("\n")
    at = next(k for k, line in enumerate(lines) if line.strip().lower().startswith("frame time"))
    return "\n".join(lines[:at - 1]), lines[at + 1:]


def tiled_file(path: Path, megabytes: float, folder: str) -> Path:
    """``path`` with its rows repeated to about ``megabytes`` MB, written into ``folder``."""
    head, rows = motion_rows(path)
    rows = [r for r in rows if r.strip()]
    size = sum(len(r) + 1 for r in rows)
    copies = max(1, round(megabytes * 1e6 / size))
    frame_time = next(line for line in path.read_text(encoding="utf-8-sig").splitlines()
                      if line.strip().lower().startswith("frame time"))
    out = Path(folder) / f"tiled_{path.stem}.bvh"
    with open(out, "w") as handle:
        handle.write(f"{head}\nFrames: {copies * len(rows)}\n{frame_time.strip()}\n")
        for _ in range(copies):
            handle.write("\n".join(rows) + "\n")
    return out


# --------------------------------------------------------------------------- memory children
def child_memory(path: str, mode: str) -> dict:
    """Run in a fresh interpreter: memory of one read (plus FK, but for ``big``)."""
    import gc

    import numpy as np

    # imports count towards the baseline, not the figure
    from motion_composer import engine
    gc.collect()
    if mode in ("rss", "big"):
        base_peak, base_hwm = max_rss_mib(), proc_status_mib("VmHWM")
        if mode == "big":
            motion = engine.read_bvh(path)
        else:
            motion, pose = read_and_fk(path)
        peak, hwm = max_rss_mib(), proc_status_mib("VmHWM")
        return {"baseline_peak_mib": base_peak, "peak_mib": peak, "delta_mib": peak - base_peak,
                "hwm_delta_mib": None if hwm is None else hwm - base_hwm,
                "frames": motion.num_frames}
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
                        help="timed runs of each call (default 9; use >= 7)")
    parser.add_argument("--file", help=f"BVH file to measure (default: {FILE} from the shared "
                                       "data)")
    parser.add_argument("--big-mb", type=float, default=72.0,
                        help="size of the tiled file for the memory of a large read (MB)")
    parser.add_argument("--bvhio", action="store_true",
                        help="also time bvhio.readAsHierarchy (~3 s a run)")
    parser.add_argument("--no-reference", action="store_true",
                        help="do not time bvhio even with --bvhio (the default without it)")
    parser.add_argument("--child-memory", choices=["rss", "tracemalloc", "big"],
                        help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    if args.child_memory:
        print(json.dumps(child_memory(args.file, args.child_memory)))
        return 0

    path = data_file(FILE, FALLBACK, args.file)
    repeat = max(1, args.repeat)
    if repeat < 7:
        print("note: fewer runs than the standard 7; medians are rougher\n")

    # memory first, each way in its own fresh interpreter, while this process is still small:
    # on Linux a child inherits its parent's ru_maxrss (see _common.max_rss_mib)
    script = Path(__file__).resolve()
    parent_peak = max_rss_mib()
    rss = run_child(script, ["--file", str(path), "--child-memory", "rss"])
    traced = run_child(script, ["--file", str(path), "--child-memory", "tracemalloc"])
    with tempfile.TemporaryDirectory(prefix="mc_bench_") as folder:
        big_path = tiled_file(path, args.big_mb, folder)
        big_size = big_path.stat().st_size / 2**20
        big = run_child(script, ["--file", str(big_path), "--child-memory", "big"])

    import numpy as np

    from motion_composer.engine.formats.bvh import format_bvh, write_bvh

    motion, pose = read_and_fk(path)
    sk = motion.skeleton
    _, rows = motion_rows(path)
    print(f"file: {path} ({path.stat().st_size / 1e6:.1f} MB): {motion.num_frames} frames, "
          f"{sk.num_joints} joints, {sk.num_channels} channels, {len(sk.end_sites)} End Sites")
    print(f"      {environment()}; allocator tuned as the application does: {ALLOCATOR}")
    print(f"      medians of {repeat} runs, taking turns with the reference\n")

    with tempfile.TemporaryDirectory(prefix="mc_bench_") as folder:
        out = Path(folder) / "out.bvh"
        calls = {"loadtxt": (lambda: np.loadtxt(rows, comments=None, ndmin=2), repeat),
                 "read": (lambda: read_and_fk(path), repeat),
                 "write": (lambda: write_bvh(motion, out), repeat),
                 "format": (lambda: format_bvh(motion), repeat)}
        for fn, _ in calls.values():                                   # warm-up
            fn()
        timed = time_interleaved(calls, rounds=repeat)
        size = out.stat().st_size
    ref, read, write = timed["loadtxt"], timed["read"], timed["write"]
    table = [
        Row("reference: numpy.loadtxt of the MOTION rows", fmt_seconds(ref.median),
            note=f"median; {ref.spread()}"),
        ratio_row("read_bvh + forward_kinematics / reference", read, ref, READ_TARGET),
        ratio_row("write_bvh (atomic, fsynced) / reference", write, ref, WRITE_RATIO_TARGET),
        Row("write_bvh", fmt_seconds(write.median), f"< {WRITE_TARGET} s",
            write.median < WRITE_TARGET, f"median; {write.spread()}; {size / 1e6:.1f} MB"),
        Row("  of which format_bvh (the text)", fmt_seconds(timed["format"].median),
            note=f"{timed['format'].median / ref.median:.2f}x the reference"),
    ]
    if args.bvhio and not args.no_reference:
        import bvhio
        bv = time_interleaved({"bvhio": (lambda: bvhio.readAsHierarchy(str(path)), 3),
                               "read": (lambda: read_and_fk(path), 3)}, rounds=3)
        table.append(ratio_row("bvhio.readAsHierarchy / read + FK", bv["bvhio"], bv["read"],
                               BVHIO_TARGET, at_most=False))

    table.append(Row("peak RSS of read + FK, above baseline", f"{rss['delta_mib']:.1f} MiB",
                     f"< {MEMORY_TARGET:.0f} MB", rss["delta_mib"] < MEMORY_TARGET * MIB_PER_MB,
                     f"ru_maxrss: peak {rss['peak_mib']:.1f} - {rss['baseline_peak_mib']:.1f} "
                     f"MiB after imports" + ("" if rss["hwm_delta_mib"] is None else
                                             f"; VmHWM says {rss['hwm_delta_mib']:.1f} MiB")))
    if rss["baseline_peak_mib"] <= parent_peak + 1.0:
        table[-1].note += (f" (UNRELIABLE: the child's baseline is the parent's "
                           f"{parent_peak:.1f} MiB)")
    table.append(Row("tracemalloc peak of read + FK", f"{traced['peak_mib']:.1f} MiB",
                     f"< {MEMORY_TARGET:.0f} MB",
                     traced["peak_mib"] < MEMORY_TARGET * MIB_PER_MB,
                     "numpy buffers and Python objects; "
                     f"{traced['numpy_live_mib']:.1f} MiB of numpy buffers live at the end "
                     f"(result arrays {traced['result_mib']:.1f} MiB)"))
    ratio = big["delta_mib"] / big_size
    table.append(Row(f"peak RSS of reading a {big_size:.0f} MiB file / its size",
                     f"{ratio:.2f}x", f"<= {BIG_TARGET:g}x", ratio <= BIG_TARGET,
                     f"{big['delta_mib']:.0f} MiB above the baseline after imports; "
                     f"{big['frames']:,} frames (the rows tiled, in a temporary folder)"))
    print_table(f"BVH benchmark, {path.name}", table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
