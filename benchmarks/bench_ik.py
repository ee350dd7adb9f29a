"""Whole-body IK speed: automatic foot contacts plus a hand constraint, both passes.

    python benchmarks/bench_ik.py [--repeat N]

Measures, on one core (BLAS threads pinned to 1 before numpy loads):

* the CMU walk (``cmu_max_131_01_walk.bvh``, 994 frames) converted onto the Bandai skeleton,
  with automatic foot contacts (detected on the capture) and one hand position constraint
  (41 frames active, ramps of 20, second priority), both passes: frames per second over the whole clip
  (target >= 1000); the paper reports about 1.25 frames per second, GMR 35-70; beside it the
  planted ankles' and toes' drift and the worst angular speed around a ramp over its no-pop
  limit (``engine.correction.quality``, target <= 1);
* the interactive case: re-solving one 300-frame hand constraint (a path 15 cm above the
  hand's own) alone after an edit (target <= 0.1 s), so the window can follow a dragged
  handle;
* with ``--with-warm-start``, the paper's own scheme for comparison: the same job solved
  frame by frame with a warm start from t - 1 (no target; it reaches the same posture; about
  a minute);
* scaling: contact building (detection and constraints) on the walk tiled to 10,000 and
  40,000 frames, timed in this process: the 40k/10k ratio (target <= 4.4, linear), and the
  peak memory of IK with automatic contacts on 100,000 frames, measured in a fresh
  subprocess as ``ru_maxrss`` above its baseline once the tiled clip is converted (target
  < 1 GB).

Figures are medians of ``--repeat`` runs (5) after a warm-up. The load average is printed;
above 1 the targets read LOADED instead of PASS or MISS (a busy machine's figures are not
judged). This is a report, not a test.
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import prepare  # noqa: E402

ALLOCATOR = prepare(one_core=True)    # as motion-composer sets itself up

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from _common import (MIB_PER_MB, Row, environment, fmt_seconds, max_rss_mib,  # noqa: E402
                     print_table, proc_status_mib, run_child, sample_load, time_runs,
                     SHARED_DATA)

FPS_TARGET = 1000.0
EDIT_TARGET = 0.1           # [s]
SCALING_TARGET = 4.4        # 40k/10k time ratio of contact building
SCALING_FRAMES = (10_000, 40_000)
MEMORY_FRAMES = 100_000
MEMORY_TARGET = 1000.0      # [MB] peak above baseline (the 1 GB): 953.7 MiB
WALK = SHARED_DATA / "cmu_max_131_01_walk.bvh"
BANDAI = SHARED_DATA / "bandai1_walk_normal_001.bvh"


def _tiled_job(frames: int):
    """The walk repeated to ``frames`` frames, and its conversion onto Bandai."""
    from motion_composer.engine import read_bvh
    from motion_composer.engine.conversion import retarget
    from motion_composer.engine.conversion.automap import automap
    performer, target = read_bvh(WALK), read_bvh(BANDAI)
    corr = automap(target.skeleton, performer.skeleton)
    tiled = performer.frames(np.resize(np.arange(performer.num_frames), frames))
    return tiled, retarget(tiled, target, corr), corr


def _contact_building(performer, composed, corr):
    from motion_composer.engine.correction.contacts import contact_constraints, detect_contacts
    return contact_constraints(detect_contacts(performer), performer, composed, corr.pairs)


def _child_memory(frames: int) -> None:
    """Print, as JSON, the peak memory of contacts and IK on the tiled walk above the
    baseline of the converted clip."""
    from motion_composer.engine.correction.enforcement import enforce
    performer, composed, corr = _tiled_job(frames)
    baseline = max_rss_mib()
    t0 = time.perf_counter()
    cons = _contact_building(performer, composed, corr)
    enforce(composed, cons)
    print(json.dumps({"baseline_mib": baseline, "peak_above_mib": max_rss_mib() - baseline,
                      "hwm_mib": proc_status_mib("VmHWM"), "constraints": len(cons),
                      "seconds": time.perf_counter() - t0}))


def _scaling():
    """Seconds of contact building on the tiled walk of each of ``SCALING_FRAMES``."""
    jobs = [_tiled_job(n) for n in SCALING_FRAMES]
    _contact_building(*jobs[0])                                     # warm-up
    out = []
    for job in jobs:
        t0 = time.perf_counter()
        _contact_building(*job)
        out.append(time.perf_counter() - t0)
    return out



def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--with-warm-start", action="store_true",
                        help="also time the paper's frame-by-frame scheme (about a minute)")
    parser.add_argument("--child-memory", type=int, metavar="FRAMES", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child_memory:
        _child_memory(args.child_memory)
        return
    if not (WALK.is_file() and BANDAI.is_file()):
        sys.exit(f"error: this benchmark needs {WALK} and {BANDAI} (set MC_SHARED_DATA)")
    sample_load()
    # first, while this process is small (ru_maxrss carries over into a child)
    memory = run_child(Path(__file__), ["--child-memory", str(MEMORY_FRAMES)], timeout=1800)

    from motion_composer.engine import forward_kinematics, read_bvh
    from motion_composer.engine.correction.constraints import Constraint
    from motion_composer.engine.correction.contacts import contact_constraints, detect_contacts
    from motion_composer.engine.correction.enforcement import enforce
    from motion_composer.engine.correction.quality import quality
    from motion_composer.engine.conversion import retarget

    performer, target = read_bvh(WALK), read_bvh(BANDAI)
    from motion_composer.engine.conversion.automap import automap
    corr = automap(target.skeleton, performer.skeleton)
    how = "automatic mapping"
    composed = retarget(performer, target, corr)
    F = composed.num_frames

    contacts = detect_contacts(performer)
    cons = contact_constraints(contacts, performer, composed, corr.pairs)
    hand = "Hand_L"
    j = target.skeleton.index[hand]
    here = forward_kinematics(composed).positions[:, j]
    # the job: the hand reaches a point 15 cm above and 10 cm out from where it passes at
    # frame 500, held for 41 frames while the feet stay planted
    goal = here[500] + np.array([0.10, 0.15, 0.05])
    reach = Constraint(hand, "position", {"point": goal}, 460, 480, 520, 540, priority=2,
                       name="hand")
    job = cons + [reach]
    # the edit: a 300-frame hand path (the hand's own, 15 cm higher), re-solved alone
    path = here[350:650] + np.array([0.10, 0.15, 0.05])
    follow = Constraint(hand, "trajectory", {"points": path}, 330, 350, 649, 669,
                        name="hand path")

    full = time_runs(lambda: enforce(composed, job), args.repeat, label="both passes")
    result = enforce(composed, job)
    residual = max(np.nanmax(result.residual[i][c.start:c.end + 1])
                   for i, c in enumerate(job))
    figures = quality(performer, composed, result.motion, job, result.residual)
    drift = {part: [c for c in figures["contacts"] if c["part"] == part]
             for part in ("heel", "toe")}
    pops = figures["pops"][0] if figures["pops"] else None
    edit = time_runs(lambda: enforce(composed, [follow]), args.repeat, label="one constraint")
    edit_result = enforce(composed, [follow])
    edit_residual = float(np.nanmax(edit_result.residual[0][350:650]))
    warm = (time_runs(lambda: enforce(composed, job, warm_start=True), 1, warmup=0,
                      label="warm start") if args.with_warm_start else None)
    fps = F / full.median
    short, long = _scaling()
    ratio = long / short
    sample_load()

    print(f"allocator tuned as the application does: {ALLOCATOR}; {environment()}; BLAS threads pinned to 1")
    print(f"{WALK.name} ({F} frames) onto {BANDAI.name}'s skeleton, {how}; "
          f"{len(contacts)} contacts -> {len(cons)} constraints, plus a hand constraint\n")
    print_table("Whole-body IK (two passes)", [
        Row("whole clip, both passes (median)", fmt_seconds(full.median), "",
            note=full.spread()),
        Row("frames per second", f"{fps:,.0f}", f">= {FPS_TARGET:,.0f}", fps >= FPS_TARGET),
        Row("re-solve one 300-frame constraint", fmt_seconds(edit.median),
            f"<= {fmt_seconds(EDIT_TARGET)}", edit.median <= EDIT_TARGET, note=edit.spread()),
        Row("  its largest residual", f"{edit_residual * 1000:.3f} mm", "<= 1 mm",
            edit_residual <= 1e-3),
        *([Row("paper's scheme: frame by frame, warm start", fmt_seconds(warm.median), "",
               note=f"{F / warm.median:,.0f} frames per second")] if warm else []),
        Row("largest residual on active frames", f"{residual * 1000:.3f} mm", "<= 1 mm",
            residual <= 1e-3),
        *[Row(f"planted {name} drift, direct -> with contacts (mean, max)",
              f"{np.mean([c['drift_direct_m'] for c in held]) * 1000:.1f} -> "
              f"{np.mean([c['drift_corrected_m'] for c in held]) * 1000:.2f} mm", "",
              note=f"max {max(c['drift_corrected_m'] for c in held) * 1000:.2f} mm over "
                   f"{len(held)} contacts")
          for name, held in (("ankle (heel)", drift["heel"]), ("toe", drift["toe"])) if held],
        *([Row("worst angular speed / no-pop limit around a ramp", f"{pops['ratio']:.2f}",
               "<= 1", pops["ratio"] <= 1.0,
               note=f"{pops['joint']} at frame {pops['frame']}: {pops['speed_deg_s']:.0f} "
                    f"deg/s, limit {pops['limit_deg_s']:.0f}")] if pops else []),
        Row(f"contact building, {SCALING_FRAMES[0]:,} / {SCALING_FRAMES[1]:,} frames",
            f"{fmt_seconds(short)} / {fmt_seconds(long)}", ""),
        Row(f"  ratio {SCALING_FRAMES[1] // 1000}k/{SCALING_FRAMES[0] // 1000}k", f"{ratio:.2f}",
            f"<= {SCALING_TARGET}", ratio <= SCALING_TARGET),
        Row(f"IK with automatic contacts, {MEMORY_FRAMES:,} frames: peak memory",
            f"{memory['peak_above_mib']:,.0f} MiB", f"<= {MEMORY_TARGET / 1000:g} GB",
            memory["peak_above_mib"] <= MEMORY_TARGET * MIB_PER_MB,
            note=f"above a baseline of {memory['baseline_mib']:,.0f} MiB; "
                 f"{memory['constraints']:,} constraints in {fmt_seconds(memory['seconds'])}"),
    ])


if __name__ == "__main__":
    main()
