"""Helpers shared by the benchmark scripts: timing, data paths, child processes, the report table.

Benchmarks are reports, not tests: they print figures against targets and exit 0 either way.
Run them from anywhere; paths are resolved relative to the repository.
"""
from __future__ import annotations

import gc
import json
import os
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

REPO = Path(__file__).resolve().parent.parent


def prepare(*, one_core: bool = False) -> bool:
    """Set the process up as the application does, before numpy loads: keep freed memory for
    reuse (app/runtime.py) and, with ``one_core``, pin BLAS to one thread. Returns whether the
    allocator setting applied (the scripts print it)."""
    if one_core:
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ[var] = "1"
    if str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))
    from motion_composer.app.runtime import tune_allocator
    return tune_allocator()
CLIPS = REPO / "resources" / "clips"
#: ``../shared/data`` beside the repository, or ``$MC_SHARED_DATA`` (as in tests/conftest.py)
SHARED_DATA = Path(os.environ.get("MC_SHARED_DATA", REPO.parent / "shared" / "data"))


# --------------------------------------------------------------------------- data
def data_file(name: str, fallback: str, explicit: str | os.PathLike | None = None) -> Path:
    """The benchmark's input: ``explicit`` if given, else ``SHARED_DATA / name``, else the
    bundled clip ``fallback`` (saying so on stdout, since the figures then are not comparable).
    """
    if explicit is not None:
        path = Path(explicit)
        if not path.is_file():
            sys.exit(f"error: {path} is not a file")
        return path
    path = SHARED_DATA / name
    if path.is_file():
        return path
    bundled = CLIPS / fallback
    print(f"note: {path} is absent (set MC_SHARED_DATA to the shared data folder); "
          f"measuring the bundled {bundled.relative_to(REPO)} instead, so the figures are "
          "not comparable with the targets, which are set for the large file.\n")
    return bundled


# --------------------------------------------------------------------------- timing
@dataclass
class Timing:
    """Wall-clock seconds of repeated runs of one call."""

    label: str
    seconds: list[float] = field(default_factory=list)
    #: this process's CPU seconds of the same runs (``time.process_time``: what the machine's
    #: other work does not stretch, and no wait on a disk)
    cpu_seconds: list[float] = field(default_factory=list)

    @property
    def median(self) -> float:
        return statistics.median(self.seconds)

    @property
    def cpu_median(self) -> float:
        return statistics.median(self.cpu_seconds)

    @property
    def best(self) -> float:
        return min(self.seconds)

    @property
    def worst(self) -> float:
        return max(self.seconds)

    def spread(self) -> str:
        """``min..max`` over the runs, for the report."""
        return f"{fmt_seconds(self.best)}..{fmt_seconds(self.worst)} over {len(self.seconds)}"


def time_runs(fn: Callable[[], object], repeat: int, *, warmup: int = 1,
              label: str = "") -> Timing:
    """Time ``repeat`` calls of ``fn`` with :func:`time.perf_counter`, after ``warmup`` calls.

    The garbage collector runs before each call (not inside the timed part), so that one call's
    garbage is not collected on the next call's time.
    """
    sample_load()
    for _ in range(warmup):
        fn()
    timing = Timing(label)
    for _ in range(repeat):
        gc.collect()
        start, cpu = time.perf_counter(), time.process_time()
        fn()
        timing.seconds.append(time.perf_counter() - start)
        timing.cpu_seconds.append(time.process_time() - cpu)
    sample_load()
    return timing


def time_interleaved(calls: dict[str, tuple[Callable[[], object], int]],
                     rounds: int) -> dict[str, Timing]:
    """Time several calls taking turns, for a ratio that a change in the machine's load
    during the benchmark does not skew: ``{label: (fn, runs)}``, each call's runs spread over
    ``rounds`` rounds. No warm-up: warm the calls up first where that matters.
    """
    timings = {label: Timing(label) for label in calls}
    rounds = max(1, rounds)
    for r in range(rounds):
        for label, (fn, runs) in calls.items():
            # runs * (r + 1) // rounds - runs * r // rounds: spread evenly, summing to runs
            share = runs * (r + 1) // rounds - runs * r // rounds
            if share:
                runs_here = time_runs(fn, share, warmup=0)
                timings[label].seconds += runs_here.seconds
                timings[label].cpu_seconds += runs_here.cpu_seconds
    return timings


def fmt_seconds(seconds: float) -> str:
    """``0.0912 s`` style, milliseconds for short times."""
    return f"{seconds * 1e3:.1f} ms" if seconds < 1.0 else f"{seconds:.2f} s"


# --------------------------------------------------------------------------- child processes
def run_child(script: Path, args: list[str], *, timeout: float = 600) -> dict:
    """Run ``python script *args`` in a fresh interpreter and return the JSON it prints last.

    For figures that a long-lived process would distort (peak memory above all; but see
    :func:`max_rss_mib`). The child must print one JSON object as its last line of stdout.
    """
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    proc = subprocess.run([sys.executable, str(script), *args], capture_output=True, text=True,
                          timeout=timeout, env=env, cwd=REPO)
    if proc.returncode != 0:
        raise RuntimeError(f"child {script.name} {' '.join(args)} failed "
                           f"(exit {proc.returncode}):\n{proc.stderr}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


#: MiB in a MB: a target in MB (10^6 bytes, as the issue states them) compared with a figure in
#: MiB (2^20 bytes, what ru_maxrss gives) is ``figure <= target_mb * MIB_PER_MB``
MIB_PER_MB = 1e6 / 2**20


def max_rss_mib() -> float:
    """This process's peak resident set size so far, in MiB (``ru_maxrss``, KiB on Linux).

    Linux caveat: a child process starts with its parent's ``ru_maxrss`` (the kernel carries
    the peak across fork and exec), so in a child this only means something if the parent was
    smaller than the child's own baseline when it started the child. Start memory children
    early, before the parent grows; :func:`proc_status_mib` ``("VmHWM")`` has no such carry-over
    and serves as a cross-check.
    """
    import resource
    kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    if sys.platform == "darwin":           # bytes there
        kib /= 1024
    return kib / 1024


def proc_status_mib(key: str) -> float | None:
    """A memory line of ``/proc/self/status`` in MiB: ``"VmRSS"`` (now), ``"VmHWM"`` (peak).

    None where there is no such file (not Linux).
    """
    try:
        with open("/proc/self/status") as handle:
            for line in handle:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


# --------------------------------------------------------------------------- report
@dataclass
class Row:
    """One line of the report: a figure, optionally against a target."""

    what: str
    value: str
    target: str = ""
    ok: bool | None = None          # None: no target, just a figure
    note: str = ""


#: a 1-minute load average above this means other work shares the CPUs: figures are printed
#: but not judged (LOADED instead of PASS or MISS)
LOAD_LIMIT = 1.0
_highest_load = 0.0
_highest_others = 0.0


class _OthersLoad:
    """How much OTHER work shared the machine while this benchmark ran.

    The kernel's 1-minute load average counts this benchmark's own tasks: a script that keeps
    one core busy for two minutes raises it to about 0.9 by itself, and one run straight after
    another starts at what the first left, with no task behind it. So a thread samples, once a
    second, the tasks the kernel counts as runnable now (``procs_running`` in ``/proc/stat``)
    less those that are this process's threads or its children's (state ``R``): the mean of
    those counts is the other work's load over the run (1: another task kept one core busy
    throughout). Where ``/proc`` is absent nothing is sampled and the 1-minute load average
    alone is judged."""

    PERIOD = 1.0

    def __init__(self):
        import threading
        self.total = 0
        self.samples = 0
        self.available = Path("/proc/stat").is_file()
        if self.available:
            threading.Thread(target=self._run, daemon=True, name="others-load").start()

    @staticmethod
    def _running_total() -> int:
        for line in Path("/proc/stat").read_text().splitlines():
            if line.startswith("procs_running"):
                return int(line.split()[1])
        return 0

    @staticmethod
    def _running_ours() -> int:
        me = os.getpid()
        parents = {}
        for entry in os.scandir("/proc"):
            if not entry.name.isdigit():
                continue
            try:
                text = Path(entry.path, "stat").read_text()
            except OSError:
                continue
            rest = text[text.rindex(")") + 2:].split()
            parents[int(entry.name)] = int(rest[1])
        ours = {me}
        grew = True
        while grew:                     # this process and its descendants
            grew = False
            for pid, parent in parents.items():
                if parent in ours and pid not in ours:
                    ours.add(pid)
                    grew = True
        count = 0
        for pid in ours:
            try:
                tasks = os.scandir(f"/proc/{pid}/task")
            except OSError:
                continue
            for task in tasks:
                try:
                    text = Path(task.path, "stat").read_text()
                except OSError:
                    continue
                if text[text.rindex(")") + 2] == "R":
                    count += 1
        return count

    def _run(self) -> None:
        while True:
            try:
                others = max(self._running_total() - self._running_ours(), 0)
            except (OSError, ValueError, IndexError):
                return
            self.total += others
            self.samples += 1
            time.sleep(self.PERIOD)


_others = _OthersLoad()


def sample_load() -> float:
    """The 1-minute load average now; the highest one sampled is kept for :func:`print_table`
    (:func:`time_runs` samples before and after its runs, so a script need not)."""
    global _highest_load
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0
    _highest_load = max(_highest_load, load)
    return load


def highest_load() -> float:
    """The highest 1-minute load average sampled so far in this process (sampling once more)."""
    sample_load()
    return _highest_load


def others_load() -> float | None:
    """The other work's mean number of runnable tasks so far (:class:`_OthersLoad`), or
    ``None`` where it cannot be measured."""
    return _others.total / _others.samples if _others.available and _others.samples else None


#: the other work's mean runnable tasks above this (:func:`others_load`) means it took half a
#: core of the two on average: figures are printed but not judged
OTHERS_LIMIT = 0.5


def is_loaded() -> bool:
    """Whether other work shared the CPUs too much for the figures to be judged: the other
    work's load over :data:`OTHERS_LIMIT`, or, where that cannot be measured, the 1-minute
    load average over :data:`LOAD_LIMIT`."""
    others = others_load()
    return highest_load() > LOAD_LIMIT if others is None else others > OTHERS_LIMIT


def load_line() -> str:
    """The report's load line: the highest 1-minute load average, the other work's part, and
    whether the targets were judged."""
    load, others = highest_load(), others_load()
    text = f"load average (1 min, highest seen): {load:.2f}"
    if others is not None:
        text += (f"; other work's runnable tasks (this benchmark's own left out), mean of "
                 f"{_others.samples} samples: {others:.2f}")
    if is_loaded():
        text += (f" - over {LOAD_LIMIT if others is None else OTHERS_LIMIT:g}: "
                 "targets read LOADED, not judged")
    return text


def ratio_row(what: str, ours: Timing, reference: Timing, limit: float, *,
              at_most: bool = True, note: str = "") -> Row:
    """A row judging ``ours.median / reference.median`` against ``limit`` (at most it, or at
    least it with ``at_most=False``), the medians and spreads of both and the ratio of their
    CPU times in its note."""
    ratio = ours.median / reference.median
    ok = ratio <= limit if at_most else ratio >= limit
    detail = (f"{fmt_seconds(ours.median)} / {fmt_seconds(reference.median)} "
              f"({ours.spread()} / {reference.spread()})")
    if ours.cpu_seconds and reference.cpu_seconds:
        detail += f"; CPU time {ours.cpu_median / reference.cpu_median:.2f}x"
    return Row(what, f"{ratio:.2f}x", f"{'<=' if at_most else '>='} {limit:g}x", ok,
               "; ".join(filter(None, [detail, note])))


def print_table(title: str, rows: list[Row], *, loaded: bool | None = None) -> None:
    """Print ``rows`` as an aligned plain-text table with PASS/MISS per target, then the load
    and the line ``targets: P PASS, M MISS, L LOADED of T`` (a script prints one table, so this
    line ends its output).

    ``loaded``: the machine was too busy for the figures to be judged, so every target reads
    LOADED; by default :func:`is_loaded`."""
    if loaded is None:
        loaded = is_loaded()
    header = ("measure", "figure", "target", "result", "")
    cells = [(r.what, r.value, r.target,
              "" if r.ok is None else ("LOADED" if loaded else "PASS" if r.ok else "MISS"),
              r.note) for r in rows]
    widths = [max(len(str(c[i])) for c in [header, *cells]) for i in range(4)]
    line = "  ".join("-" * w for w in widths)
    print(title)
    print(line)
    print("  ".join(h.ljust(w) for h, w in zip(header, widths)).rstrip())
    print(line)
    for c in cells:
        text = "  ".join(str(x).ljust(w) for x, w in zip(c, widths))
        print((text + ("  " + c[4] if c[4] else "")).rstrip())
    print(line)
    results = [c[3] for c in cells if c[3]]
    print(load_line())
    print(f"targets: {results.count('PASS')} PASS, {results.count('MISS')} MISS, "
          f"{results.count('LOADED')} LOADED of {len(results)}")


def environment() -> str:
    """One line naming the interpreter, numpy and the machine, to read the figures against."""
    import platform

    import numpy
    return (f"Python {platform.python_version()}, numpy {numpy.__version__}, "
            f"{platform.machine()}, {os.cpu_count()} CPUs, {platform.system()}")
