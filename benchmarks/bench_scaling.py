"""Linear in frames: every stage timed on 10,000 and 40,000 frames in one process.

    python benchmarks/bench_scaling.py [--repeat N] [--stage NAME ...]

The jumps clip (``cmu_mb_01_01_jumps.bvh``, 2752 frames, 31 joints) is tiled to each length.
Each stage is timed on both lengths taking turns (medians of ``--repeat`` runs, 3, after a
warm-up); its 40k/10k ratio of wall time is judged against 4, within 10 % (3.6 to 4.4), the
ratio of this process's CPU time printed beside it (on a shared machine the other work
stretches the wall times, not the CPU time; a wait on the disk is in the wall time only).
Stages, each on the one before's result:

* read: ``read_bvh`` of the tiled clip written to a temporary folder;
* conversion: ``transfer`` (convert + compose) onto the Bandai skeleton (the bind is done
  once per length, outside the timing);
* contacts: automatic contact building, ``detect_contacts`` on the performer then
  ``contact_constraints`` onto the conversion;
* IK: ``enforce`` of the conversion with those constraints (both passes);
* key reduction: ``DisplacementMap.from_dense`` of that correction with the project's
  tolerances (what a solve stores);
* save: ``save_project`` of a project holding the clips' paths, the map, the constraints and
  those keys (no backup: each run writes the same file);
* export: ``evaluate_project`` of that project (the performer and target given, as the
  window has them: bind, conversion, the keys applied) then ``write_bvh`` of its motion;
* write: ``write_bvh`` of the converted motion (atomic, fsynced), and ``format_bvh`` of it
  alone (the text, no file), to tell the disk's wait from the work.

With a load average over 1 the targets read LOADED. This is a report, not a test.
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import prepare  # noqa: E402

ALLOCATOR = prepare(one_core=True)    # as motion-composer sets itself up

import argparse  # noqa: E402
import math  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from typing import Callable  # noqa: E402

from _common import (Row, SHARED_DATA, environment, fmt_seconds, print_table,  # noqa: E402
                     time_interleaved)

CLIP = SHARED_DATA / "cmu_mb_01_01_jumps.bvh"
TARGET = SHARED_DATA / "bandai1_walk_normal_001.bvh"
FRAMES = (10_000, 40_000)
RATIO = 4.0                   # 40k / 10k, linear
TOLERANCE = 0.10              # within 10 % of it
TIMED_SECONDS = 3.0           # a fast stage is timed this long (both lengths together) ...
MAX_RUNS = 21                 # ... in at most this many runs per length


class Job:
    """What the stages share at one length: the tiled clip and, made when first asked for,
    its file, its binding onto the target and its conversion (the later stages' input)."""

    def __init__(self, frames: int, folder: Path):
        import numpy as np

        from motion_composer.engine import read_bvh
        from motion_composer.engine.conversion.automap import automap
        self.frames = frames
        self.folder = folder
        clip = read_bvh(CLIP)
        self.performer = clip.frames(np.resize(np.arange(clip.num_frames), frames))
        self.target = read_bvh(TARGET)
        self.correspondence = automap(self.target.skeleton, self.performer.skeleton)
        self._cache: dict = {}

    def cached(self, key: str, make: Callable[[], object]):
        if key not in self._cache:
            self._cache[key] = make()
        return self._cache[key]

    @property
    def path(self) -> Path:
        """The tiled clip written as a BVH file."""
        from motion_composer.engine.formats.bvh import write_bvh
        out = self.folder / f"tiled_{self.frames}.bvh"
        return self.cached("path", lambda: (write_bvh(self.performer, out), out)[1])

    @property
    def binding(self):
        from motion_composer.engine.conversion import bind
        return self.cached("binding", lambda: bind(self.performer, self.target,
                                                   self.correspondence))

    @property
    def composed(self):
        """The direct conversion onto the target."""
        from motion_composer.engine.conversion import transfer
        return self.cached("composed", lambda: transfer(self.binding, self.performer))

    @property
    def constraints(self) -> list:
        """The automatic foot contacts of the performer, as constraints on the conversion."""
        return self.cached("constraints", lambda: build_contacts(self))

    @property
    def correction(self):
        """The IK correction of the conversion under :attr:`constraints`."""
        from motion_composer.engine.correction.enforcement import enforce
        return self.cached("correction", lambda: enforce(self.composed, self.constraints))

    @property
    def keys(self):
        """:attr:`correction` as the keys a project stores."""
        return self.cached("keys", lambda: reduce_keys(self))

    @property
    def project(self):
        """A project of the tiled clip onto the target with the contacts and the keys."""
        from motion_composer.engine.project import Project, Source
        return self.cached("project", lambda: Project(
            performer=Source(path=str(self.path)), target=Source(path=str(TARGET)),
            correspondence=self.correspondence, auto_contacts=True,
            constraints=tuple(self.constraints), displacement=self.keys))


def build_contacts(job: Job) -> list:
    from motion_composer.engine.correction.contacts import contact_constraints, detect_contacts
    return contact_constraints(detect_contacts(job.performer), job.performer, job.composed,
                               job.correspondence.pairs)


def reduce_keys(job: Job):
    from motion_composer.engine.correction.displacement import DisplacementMap
    from motion_composer.engine.project.files import POSITION_TOLERANCE, ROTATION_TOLERANCE
    correction = job.correction
    return DisplacementMap.from_dense(job.target.skeleton, correction.rotvecs, correction.root,
                                      position_tolerance=POSITION_TOLERANCE,
                                      rotation_tolerance=ROTATION_TOLERANCE)


def read_stage(job: Job):
    from motion_composer.engine import read_bvh
    path = job.path
    return lambda: read_bvh(path)


def conversion_stage(job: Job):
    from motion_composer.engine.conversion import transfer
    binding, performer = job.binding, job.performer
    return lambda: transfer(binding, performer)


def contacts_stage(job: Job):
    job.composed                                            # made outside the timing
    return lambda: build_contacts(job)


def ik_stage(job: Job):
    from motion_composer.engine.correction.enforcement import enforce
    composed, constraints = job.composed, job.constraints
    return lambda: enforce(composed, constraints)


def keys_stage(job: Job):
    job.correction
    return lambda: reduce_keys(job)


def save_stage(job: Job):
    from motion_composer.engine.project import save_project
    project, out = job.project, job.folder / f"project_{job.frames}.mcp"
    return lambda: save_project(project, out, backup=False)


def export_stage(job: Job):
    from motion_composer.engine.formats.bvh import write_bvh
    from motion_composer.engine.scene import evaluate_project
    project, performer, target = job.project, job.performer, job.target
    out = job.folder / f"exported_{job.frames}.bvh"
    return lambda: write_bvh(evaluate_project(project, performer, target).motion, out)


def write_stage(job: Job):
    from motion_composer.engine.formats.bvh import write_bvh
    motion, out = job.composed, job.folder / f"written_{job.frames}.bvh"
    return lambda: write_bvh(motion, out)


def format_stage(job: Job):
    from motion_composer.engine.formats.bvh import format_bvh
    motion = job.composed
    return lambda: format_bvh(motion)


@dataclass(frozen=True)
class Stage:
    """One line of the report: ``prepare(job)`` returns the call to time on ``job``'s frames,
    or the stage is a slot still to be filled (None)."""

    name: str
    prepare: Callable[[Job], Callable[[], object]] | None


STAGES = [
    Stage("read (read_bvh)", read_stage),
    Stage("conversion (transfer onto Bandai)", conversion_stage),
    Stage("contacts (detection and constraints)", contacts_stage),
    Stage("IK (automatic contacts, both passes)", ik_stage),
    Stage("key reduction (from_dense of the correction)", keys_stage),
    Stage("save (save_project with the keys)", save_stage),
    Stage("export (evaluate_project, write_bvh)", export_stage),
    Stage("write (write_bvh, fsynced)", write_stage),
    Stage("format_bvh (the text of write, no file)", format_stage),
]


def runs_for(warm_up: float, repeat: int) -> int:
    """Timed runs per length for a stage whose warm-up (one call at each length) took
    ``warm_up`` seconds: at least ``repeat``, and more for a stage that fast, up to
    :data:`MAX_RUNS`, so that it is timed for about :data:`TIMED_SECONDS`. A median of three
    calls of tens of milliseconds moved the conversion's ratio from 3.4 to 4.3 between runs
    on a quiet machine; the slow stages keep their ``repeat``."""
    if warm_up <= 0:
        return MAX_RUNS
    return max(repeat, min(MAX_RUNS, math.ceil(TIMED_SECONDS / warm_up)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per length (3)")
    parser.add_argument("--stage", action="append", metavar="NAME",
                        help="only the stages whose name starts with NAME (repeatable)")
    args = parser.parse_args()
    missing = [p for p in (CLIP, TARGET) if not p.is_file()]
    if missing:
        sys.exit(f"error: this benchmark needs {', '.join(map(str, missing))} "
                 "(set MC_SHARED_DATA)")
    stages = [s for s in STAGES if not args.stage or any(s.name.startswith(n)
                                                         for n in args.stage)]
    rows: list[Row] = []
    low, high = RATIO * (1 - TOLERANCE), RATIO * (1 + TOLERANCE)
    with tempfile.TemporaryDirectory(prefix="mc_scaling_") as folder:
        jobs = [Job(n, Path(folder)) for n in FRAMES]
        for stage in stages:
            if stage.prepare is None:
                rows.append(Row(stage.name, "-", f"{low:.1f}..{high:.1f}",
                                note="slot: not measured here yet"))
                continue
            calls = [stage.prepare(job) for job in jobs]
            started = time.perf_counter()
            for call in calls:                                         # warm-up
                call()
            runs = runs_for(time.perf_counter() - started, args.repeat)
            timed = time_interleaved({n: (call, runs) for n, call in zip(FRAMES, calls)},
                                     rounds=runs)
            short, long = timed[FRAMES[0]], timed[FRAMES[1]]
            ratio = long.median / short.median
            cpu = long.cpu_median / short.cpu_median
            rows.append(Row(stage.name, f"{ratio:.2f}", f"{low:.1f}..{high:.1f}",
                            low <= ratio <= high,
                            note=f"{fmt_seconds(short.median)} / {fmt_seconds(long.median)} "
                                 f"({short.spread()} / {long.spread()}); CPU time "
                                 f"{cpu:.2f}x ({fmt_seconds(short.cpu_median)} / "
                                 f"{fmt_seconds(long.cpu_median)})"))
    print(f"allocator tuned as the application does: {ALLOCATOR}; {environment()}; "
          f"BLAS threads pinned to 1")
    print(f"{CLIP.name} tiled to {FRAMES[0]:,} and {FRAMES[1]:,} frames; medians of at "
          f"least {args.repeat} runs per length (a fast stage up to {MAX_RUNS}, about "
          f"{TIMED_SECONDS:g} s of runs), taking turns\n")
    print_table(f"Scaling: time at {FRAMES[1] // 1000}k frames / at {FRAMES[0] // 1000}k",
                rows)


if __name__ == "__main__":
    main()
