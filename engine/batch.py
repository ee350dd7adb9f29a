"""Batch retargeting: one recipe (mapping, binding, root, automatic contacts, floor) applied
to many clips, each in its own process; one failing clip never stops the rest.

A :class:`Recipe` is plain, picklable data, so the same :func:`process_clip` runs in a local
process pool or on a Dask cluster. Each clip gives a summary dict: ``status`` ``"written"`` or
``"failed"`` with the ``reason`` (one line, as the CLI prints errors), the output path, the
frame count, the largest constraint residual, contact drift figures and the time taken.

The output folder is checked before any work: it must be a folder (or not exist yet), every
clip must get its own output name, and no output may be a clip or the target. A run holds an
exclusive lock on the folder (:func:`folder_lock`) until it ends, so a second run into the same
folder is refused at once instead of overwriting the first run's results.
"""
from __future__ import annotations

import contextlib
import os
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path

from .correction.enforcement import largest_residuals
from .errors import MotionComposerError

__all__ = ["Recipe", "recipe_from_project", "process_clip", "run_batch", "output_path",
           "check_batch_outputs", "folder_lock", "BatchOutputError"]


class BatchOutputError(MotionComposerError):
    """A batch output folder that cannot be used: a file, a folder another run is writing
    into, or outputs that would overwrite each other or an input."""


@dataclass(frozen=True)
class Recipe:
    """What to do to every clip.

    Attributes:
        target_path: the character, any file :func:`engine.formats.read_motion` reads (a
            BVH, or a glTF character's bind pose).
        pairs: the correspondence, target joint -> performer joint; empty means automatic
            mapping for each clip (clips from different skeletons then work too).
        bind: BindOptions fields (pose offsets and chain settings included); root:
            RootOptions fields.
        auto_contacts: pin the feet where the performer plants them.
        floor: keep the feet on or above this height [m], or None.
        stand_on_floor: also move each conversion onto ``floor`` (the project's setting).
        suffix: appended to each clip's stem for its output name.
        target_reader: options for reading the target (units, up_axis, ...).
        performer_reader: options for reading every clip (none: detected per clip).
        ik: :class:`~engine.correction.ik.IKOptions` fields (none: the defaults).
    """

    target_path: str
    pairs: dict = field(default_factory=dict)
    bind: dict = field(default_factory=dict)
    root: dict = field(default_factory=dict)
    auto_contacts: bool = True
    floor: float | None = None
    stand_on_floor: bool = True
    suffix: str = ""
    target_reader: dict = field(default_factory=dict)
    ik: dict = field(default_factory=dict)
    performer_reader: dict = field(default_factory=dict)


def recipe_from_project(project, *, suffix: str = "") -> Recipe:
    """The rules of a saved project, for other clips: its target, mapping, binding, root
    options, automatic contacts, floor and IK settings. (Its own constraints name frames of
    its own clip, so they do not carry over; automatic contacts are detected again on each
    clip.)"""
    import dataclasses
    src = project.target
    if src.path is None:
        from .errors import MotionComposerError
        raise MotionComposerError("the project's target is only embedded; batch needs the "
                                  "target as a file")
    # shallow: the chain settings stay ChainSettings (asdict would make them dicts)
    bind = {f.name: getattr(project.bind_options, f.name)
            for f in dataclasses.fields(project.bind_options)}
    root = dataclasses.asdict(project.root)
    return Recipe(target_path=str(src.path), pairs=dict(project.correspondence.pairs),
                  bind=bind, root=root, auto_contacts=bool(project.auto_contacts),
                  floor=project.floor, stand_on_floor=bool(project.stand_on_floor),
                  suffix=suffix, target_reader=src.reader_options(),
                  ik=dataclasses.asdict(project.ik_options))


def output_path(recipe: Recipe, clip, out_dir) -> Path:
    """Where :func:`process_clip` writes ``clip``: ``out_dir/<stem><suffix>.bvh``."""
    return Path(out_dir) / f"{Path(clip).stem}{recipe.suffix}.bvh"


def check_batch_outputs(recipe: Recipe, clips, out_dir, inputs=()) -> None:
    """Refuse, before any work, an ``out_dir`` that exists and is not a folder, two clips with
    one output name, and an output that is one of the clips, the target or one of ``inputs``
    (pairs ``(what, path)``, e.g. the project file); raises :class:`BatchOutputError`."""
    from .fileio import FileWriteError, check_output_path

    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise BatchOutputError(f"-o {out_dir}: is a file; batch writes one file per clip into "
                               "a folder: give a folder (it is created if missing)")
    sources = [("the target", recipe.target_path), *inputs,
               *((f"the clip {c}", c) for c in clips)]
    seen: dict[str, str] = {}
    for clip in clips:
        out = output_path(recipe, clip, out_dir)
        key = os.path.realpath(out)
        if key in seen:
            raise BatchOutputError(f"the clips {seen[key]} and {clip} would both be written "
                                   f"to {out}; rename one, or run them into different folders")
        seen[key] = str(clip)
        if not os.path.isdir(out_dir):
            continue                           # a new folder holds no input and no device
        try:
            check_output_path(out, sources)
        except FileWriteError as exc:
            raise BatchOutputError(str(exc)) from None


@contextlib.contextmanager
def folder_lock(out_dir):
    """Hold an exclusive lock on the folder ``out_dir`` (created if missing) while the block
    runs; raise :class:`BatchOutputError` at once if another run holds it.

    The lock is an ``flock`` on the folder itself: nothing is left in the folder, and the
    system releases it when the process ends, however it ends.
    """
    import fcntl

    Path(out_dir).mkdir(parents=True, exist_ok=True)
    fd = os.open(out_dir, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise BatchOutputError(f"-o {out_dir}: another batch run is writing into this "
                                   "folder; wait for it to finish or choose another "
                                   "folder") from None
        yield
    finally:
        os.close(fd)                           # closing the descriptor releases the lock


def process_clip(recipe: Recipe, clip: str, out_dir: str) -> dict:
    """Retarget one clip with ``recipe`` and write ``out_dir/<stem><suffix>.bvh``.

    Never raises: a failure is reported in the summary with its reason.
    """
    from .formats import read_motion, read_performer
    from .formats.bvh import write_bvh
    from .conversion.correspondence import Correspondence
    from .errors import MotionComposerError
    from .conversion.binding import BindOptions
    from .conversion.converter import RootOptions
    from .correction.ik import IKOptions
    from .project import Project, Source
    from .scene import Scene

    started = time.perf_counter()
    summary = {"clip": str(clip), "status": "failed", "output": None, "reason": ""}
    try:
        performer = read_performer(clip, **recipe.performer_reader)
        target = read_motion(recipe.target_path, **recipe.target_reader)
        summary["warnings"] = [line for line in (
            performer.skeleton.source.warning(clip, "--performer-"),
            target.skeleton.source.warning(recipe.target_path, "--target-")) if line]
        if recipe.pairs:
            corr = Correspondence(recipe.pairs)
            corr.validate(target.skeleton, performer.skeleton)
        else:
            from .conversion.automap import automap
            corr = automap(target.skeleton, performer.skeleton)
        project = Project(performer=Source(os.path.abspath(clip), **recipe.performer_reader),
                          target=Source(recipe.target_path, **recipe.target_reader),
                          correspondence=corr, bind_options=BindOptions(**recipe.bind),
                          root=RootOptions(**recipe.root), auto_contacts=recipe.auto_contacts,
                          floor=recipe.floor, stand_on_floor=recipe.stand_on_floor,
                          ik_options=IKOptions(**recipe.ik))
        result = Scene(project, performer, target).solve(regenerate=True)
        summary["warnings"] += result.report["warnings"]
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        out = output_path(recipe, clip, out_dir)
        write_bvh(result.motion, out)
        largest = largest_residuals(result.report["constraints"])
        summary.update(status="written", output=str(out), frames=result.motion.num_frames,
                       constraints=len(result.constraints),
                       max_residual_m=largest["m"], max_residual_rad=largest["rad"],
                       contact_drift=result.report.get("contact_drift"))
    except MotionComposerError as exc:
        summary["reason"] = " ".join(str(exc).split())
    except Exception as exc:                  # noqa: BLE001 - a bug must not stop the batch
        summary["reason"] = f"unexpected {type(exc).__name__}: {exc}"
        summary["traceback"] = traceback.format_exc(limit=6)
    summary["seconds"] = time.perf_counter() - started
    return summary


def _pin_threads() -> None:
    # each worker is one process: keep BLAS to one thread so workers do not fight for cores
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")


def run_batch(recipe: Recipe, clips: list[str], out_dir: str, *, workers: int | None = None,
              scheduler: str | None = None, progress=None) -> list[dict]:
    """Process every clip; return the summaries in the order of ``clips``.

    ``workers``: local processes (default: the number of CPUs). ``scheduler``: a Dask
    scheduler address (``tcp://host:8786``) to run on a cluster instead (needs
    ``dask.distributed``). ``progress(done, total, summary)`` is called as clips finish.
    The outputs are checked first (:func:`check_batch_outputs`) and the folder is locked for
    the run (:func:`folder_lock`); both raise :class:`BatchOutputError` before any work.
    """
    check_batch_outputs(recipe, clips, out_dir)
    with folder_lock(out_dir):
        return _run_locked(recipe, clips, out_dir, workers, scheduler, progress)


def _run_locked(recipe, clips, out_dir, workers, scheduler, progress) -> list[dict]:
    total = len(clips)
    results: dict[int, dict] = {}
    if scheduler:
        try:
            from distributed import Client, as_completed as dask_completed
        except ImportError:
            raise MotionComposerError("--scheduler needs Dask: pip install 'dask[distributed]'"
                                      ) from None
        with Client(scheduler) as client:
            futures = {client.submit(process_clip, recipe, str(c), str(out_dir), pure=False): i
                       for i, c in enumerate(clips)}
            for future in dask_completed(futures):
                i = futures[future]
                results[i] = future.result()
                if progress is not None:
                    progress(len(results), total, results[i])
    else:
        workers = workers or os.cpu_count() or 1
        if workers <= 1 or total <= 1:
            for i, c in enumerate(clips):
                results[i] = process_clip(recipe, str(c), str(out_dir))
                if progress is not None:
                    progress(len(results), total, results[i])
        else:
            with ProcessPoolExecutor(max_workers=min(workers, total),
                                     initializer=_pin_threads) as pool:
                futures = {pool.submit(process_clip, recipe, str(c), str(out_dir)): i
                           for i, c in enumerate(clips)}
                for future in as_completed(futures):
                    i = futures[future]
                    try:
                        results[i] = future.result()
                    except Exception as exc:      # noqa: BLE001 - a worker died
                        results[i] = {"clip": str(clips[i]), "status": "failed",
                                      "reason": f"the worker process failed: {exc}"}
                    if progress is not None:
                        progress(len(results), total, results[i])
    return [results[i] for i in range(total)]
