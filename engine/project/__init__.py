"""Project files: one file holds a whole retargeting session.

A :class:`Project` is plain data: the performer and target clips (paths, or the BVH text
embedded), the correspondence, the binding and root choices, automatic-contact settings and a
floor, the constraints (automatic ones included, as edited), the displacement map currently
applied (the IK correction reduced to keys, plus the animator's hand edits) and the viewer state.
Loading never runs IK: the final motion is the direct conversion plus the saved displacement map,
so it is the same, bit for bit, as before saving (:func:`evaluate_project`). :func:`solve_project`
runs IK again and stores the new correction.

The file is JSON (``.mcp``), human-readable, written deterministically (fixed key order,
floats as Python's shortest round-trip repr, number lists packed on lines), so save, load, save
gives the same bytes::

    {
      "format": "motion-composer-project",
      "version": 1,
      "performer": {"path": "clips/walk.bvh", "units": null, "scale": null, "up_axis": null,
                    "position_mode": null},
      "target": {...},
      "correspondence": {"pairs": {"Hips": "Hips", ...}},
      "binding": {"performer_reference": "auto", "target_reference": "auto",
                  "rest_alignment": true, "distribute": "even"},
      "root": {"mode": "scaled", "scale": null},
      "contacts": {"auto": true, "options": {"height": 0.03, ...}},
      "floor": null,
      "viewer": {"current_frame": 0, "play_range": null, "camera": {...},
                 "shown": ["performer", "target"], "options": {}},
      "constraints": [{"joint": "LeftFoot", "kind": "position", ...}, ...],
      "displacement": {"channels": [{"joint": "LeftLeg", "channel": "rx", "frames": [...],
                                     "values": [...], "interpolation": "linear"}, ...]},
      "embedded": {"performer": "HIERARCHY\\n..."}
    }

Source paths are stored relative to the project file's folder (so a project folder moved with
its clips still opens) and held absolute in memory. ``embedded`` (last, as it is long) holds the
BVH text of clips embedded so that a project can be sent on its own; an embedded clip is read
from the project, its path is kept only to say where it came from.

Every format change gets a new version and a migrator from the one before (:data:`MIGRATIONS`);
an older file is migrated forward on load, a newer one is refused with a clear message.

Bad input raises :class:`ProjectError` naming the file and the field as a JSON path
(``constraints[3].range``); a clip that is not where the project says raises
:class:`MissingSourceError` naming the missing path. Saving is atomic
(:func:`engine.fileio.atomic_write`) and keeps one backup of the previous file
(``<name>.bak``); :func:`write_autosave` and :func:`find_autosave` support crash recovery.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

from ..formats.bvh import _decode, parse_bvh
from ..correction.constraints import KINDS, Constraint, ConstraintError
from ..correction.contacts import ContactOptions
from ..correction.enforcement import Correction
from ..conversion.correspondence import Correspondence
from ..correction.displacement import (INTERPOLATIONS, ROOT, ROTATION_CHANNELS,
                                       TRANSLATION_CHANNELS, Curve, DisplacementMap)
from ..errors import BVHError, MappingError, MotionComposerError
from ..fileio import FileWriteError, atomic_write
from ..correction.ik import IKOptions
from ..motion import Motion
from ..scene import Job, run_job
from ..conversion.binding import BindOptions
from ..conversion.converter import RootOptions
from ..units import AXES, UNITS

__all__ = ["Project", "Source", "ViewerState", "ProjectError", "MissingSourceError",
           "ProjectMotion", "OpenedProject", "FORMAT", "VERSION", "SUFFIX", "MIGRATIONS",
           "project_to_json", "project_from_json", "save_project", "load_project",
           "open_project", "read_sources", "check_project", "evaluate_project",
           "solve_project", "correction_keys", "embed_sources", "autosave_path",
           "write_autosave", "find_autosave", "discard_autosave", "backup_path"]

FORMAT = "motion-composer-project"
#: the format version this module writes (and the newest it reads)
VERSION = 1
SUFFIX = ".mcp"
ROLES = ("performer", "target")
#: skeletons the viewer can show
SKELETONS = ("performer", "intermediate", "target")
#: key reduction of an IK correction stored in a project [rad], [m]
ROTATION_TOLERANCE = math.radians(0.01)
TRANSLATION_TOLERANCE = 5e-5


# --------------------------------------------------------------------------- errors
class ProjectError(MotionComposerError):
    """A project file that cannot be used.

    Attributes:
        path: the project file (``None`` for text that came from no file).
        field: where in the file, as a JSON path (``"constraints[3].range"``), or ``None``
            when the problem is not in one field (broken JSON).
        problem: the message without the location.
    """

    def __init__(self, problem: str, path=None, field: str | None = None):
        self.path = os.fspath(path) if path is not None else None
        self.field = field or None
        self.problem = problem
        where = [p for p in (self.path, self.field) if p]
        super().__init__(": ".join(where + [problem]))

    def __reduce__(self):                     # survives pickling (worker processes)
        return _rebuild, (type(self), dict(self.__dict__), str(self))


class MissingSourceError(ProjectError):
    """A clip the project refers to is not where the project says (moved, renamed, deleted).

    Attributes:
        role: ``"performer"`` or ``"target"``.
        missing: the absolute path that was not found (ask the user where the clip went).
    """

    def __init__(self, role: str, missing, path=None):
        self.role = role
        self.missing = os.fspath(missing)
        super().__init__(f"the {role} clip {self.missing} is not there (moved, renamed or "
                         "deleted?); locate it, or embed the clip in the project", path,
                         f"{role}.path")


def _rebuild(cls, state: dict, message: str):
    error = Exception.__new__(cls)
    Exception.__init__(error, message)
    error.__dict__.update(state)
    return error


class _Invalid(Exception):
    """Raised inside the reader and writer; turned into :class:`ProjectError` with the path."""

    def __init__(self, field: str, problem: str):
        super().__init__(problem)
        self.field = field
        self.problem = problem


# --------------------------------------------------------------------------- the data
@dataclass(frozen=True)
class Source:
    """Where a clip comes from and how it was read.

    Attributes:
        path: the clip's file (absolute in memory; relative to the project's folder in the
            file), or ``None`` for a clip that exists only embedded.
        embedded: the clip's BVH text, when embedded in the project (it then wins over
            ``path``).
        units, scale, up_axis, position_mode: the reader overrides used (``None``: detected);
            see :func:`engine.formats.bvh.record_to_motion`.
    """

    path: str | None = None
    embedded: str | None = None
    units: str | None = None
    scale: float | None = None
    up_axis: str | None = None
    position_mode: str | dict | None = None

    def __post_init__(self):
        if self.path is not None:
            object.__setattr__(self, "path", os.fspath(self.path))
        if isinstance(self.position_mode, dict):
            object.__setattr__(self, "position_mode", dict(self.position_mode))

    def reader_options(self) -> dict:
        """The keyword arguments for :func:`engine.formats.bvh.read_bvh`."""
        options = {"units": self.units, "scale": self.scale, "up_axis": self.up_axis,
                   "position_mode": self.position_mode}
        return {k: v for k, v in options.items() if v is not None}

    def name(self, role: str) -> str:
        """The motion's name: the file's stem (as :func:`read_bvh` gives it), else the role."""
        return Path(self.path).stem if self.path else role


@dataclass(frozen=True)
class ViewerState:
    """What the viewer shows.

    Attributes:
        current_frame: the frame on screen.
        play_range: ``(first, last)`` frames played, or ``None`` for the whole clip.
        camera: named numbers or number lists, e.g. ``{"target": [x, y, z], "distance": 3.0,
            "azimuth": 30.0, "elevation": 10.0}``.
        shown: skeletons drawn, from :data:`SKELETONS`.
        options: other display settings, each a string, number, true/false or null.
    """

    current_frame: int = 0
    play_range: tuple[int, int] | None = None
    camera: dict = field(default_factory=dict)
    shown: tuple[str, ...] = ("performer", "target")
    options: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.play_range is not None:
            object.__setattr__(self, "play_range", tuple(self.play_range))
        object.__setattr__(self, "camera", dict(self.camera))
        object.__setattr__(self, "options", dict(self.options))
        object.__setattr__(self, "shown", tuple(s for s in SKELETONS if s in self.shown))


@dataclass(frozen=True, eq=False)
class Project:
    """A whole retargeting session (see the module doc). Plain data: change it with
    :func:`dataclasses.replace`."""

    performer: Source
    target: Source
    correspondence: Correspondence = field(default_factory=Correspondence)
    bind_options: BindOptions = field(default_factory=BindOptions)
    root: RootOptions = field(default_factory=RootOptions)
    auto_contacts: bool = False
    contact_options: ContactOptions = field(default_factory=ContactOptions)
    floor: float | None = None
    constraints: tuple = ()
    displacement: DisplacementMap = field(default_factory=DisplacementMap)
    viewer: ViewerState = field(default_factory=ViewerState)

    def __post_init__(self):
        object.__setattr__(self, "constraints", tuple(self.constraints))

    def replace(self, **changes) -> "Project":
        return dataclasses.replace(self, **changes)

    def job(self, performer: Motion, target: Motion, *, constraints=(),
            auto_contacts: bool = False, floor: float | None = None,
            ik_options: IKOptions | None = None) -> Job:
        """A pipeline :class:`Job` with this project's map and options."""
        return Job(performer=performer, target=target, correspondence=self.correspondence,
                   bind_options=self.bind_options, root=self.root,
                   constraints=tuple(constraints), auto_contacts=auto_contacts,
                   contact_options=self.contact_options, floor=floor, ik_options=ik_options)


class ProjectMotion(NamedTuple):
    """``composed``: the direct conversion; ``motion``: with the displacement map applied."""

    composed: Motion
    motion: Motion


class OpenedProject(NamedTuple):
    project: Project
    performer: Motion
    target: Motion


# --------------------------------------------------------------------------- evaluation
def read_sources(project: Project, *, path=None) -> tuple[Motion, Motion]:
    """The performer and target motions. ``path`` (the project file) is named in errors."""
    return tuple(_read_source(getattr(project, role), role, path) for role in ROLES)


def _read_source(source: Source, role: str, path) -> Motion:
    options = source.reader_options()
    if source.embedded is not None:
        try:
            return parse_bvh(source.embedded, None, name=source.name(role), **options)
        except BVHError as exc:
            if _about_position_mode(exc):
                raise ProjectError(exc.problem, path, f"{role}.position_mode") from None
            where = f"line {exc.line}: " if exc.line else ""
            raise ProjectError(f"the embedded {role} clip cannot be read: {where}{exc.problem}",
                               path, f"embedded.{role}") from None
    if source.path is None:
        raise ProjectError(f"the {role} has neither a path nor an embedded clip", path, role)
    try:
        present = os.path.isfile(source.path)
    except (OSError, ValueError):
        present = False
    if not present:
        raise MissingSourceError(role, os.path.abspath(source.path), path)
    # the file's content says which reader (a glTF character's bind pose is the target)
    from ..errors import FileFormatError, GLTFError
    from ..formats import read_motion
    try:
        return read_motion(source.path, **options)
    except BVHError as exc:
        if _about_position_mode(exc):
            raise ProjectError(exc.problem, path, f"{role}.position_mode") from None
        raise ProjectError(f"the {role} clip cannot be read: {exc}", path,
                           f"{role}.path") from None
    except FileFormatError as exc:
        what = "character" if isinstance(exc, GLTFError) else "clip"
        raise ProjectError(f"the {role} {what} cannot be read: {exc}", path,
                           f"{role}.path") from None


def _about_position_mode(exc: BVHError) -> bool:
    """A position-mode override naming a joint the clip does not translate."""
    return exc.line is None and "position mode" in exc.problem


def check_project(project: Project, performer: Motion, target: Motion, *, path=None) -> None:
    """Raise :class:`ProjectError` naming the field unless every joint the project names
    exists in its skeleton and every frame number lies in the clips."""
    try:
        _check(project, performer, target)
    except _Invalid as exc:
        raise ProjectError(exc.problem, path, exc.field) from None


def _check(project: Project, performer: Motion, target: Motion) -> None:
    tsk, psk = target.skeleton, performer.skeleton
    F = performer.num_frames                  # the composed motion has the performer's frames
    for t, p in project.correspondence.pairs.items():
        where = _sub("correspondence.pairs", t)
        if t not in tsk.index:
            raise _Invalid(where, _not_a_joint(t, tsk, "target"))
        if p not in psk.index:
            raise _Invalid(where, _not_a_joint(p, psk, "performer"))
    try:
        project.correspondence.validate(tsk, psk)
    except MappingError as exc:
        raise _Invalid("correspondence", exc.problem) from None
    for key, motion in (("performer_reference", performer), ("target_reference", target)):
        ref = getattr(project.bind_options, key)
        if not isinstance(ref, str) and ref >= motion.num_frames:
            raise _Invalid(f"binding.{key}", f"frame {ref} is past the clip's last frame "
                                             f"({motion.num_frames - 1})")
    for i, c in enumerate(project.constraints):
        where = f"constraints[{i}]"
        if c.joint not in tsk.index:
            raise _Invalid(f"{where}.joint", _not_a_joint(c.joint, tsk, "target"))
        if c.smooth_out > F - 1:
            raise _Invalid(f"{where}.range", f"smooth_out {c.smooth_out} is past the last "
                                             f"frame ({F - 1})")
    for i, (joint, _) in enumerate(project.displacement.curves):
        if joint != ROOT and joint not in tsk.index:
            raise _Invalid(f"displacement.channels[{i}].joint",
                           _not_a_joint(joint, tsk, "target"))
    v = project.viewer
    if v.current_frame > F - 1:
        raise _Invalid("viewer.current_frame", f"frame {v.current_frame} is past the last frame "
                                               f"({F - 1})")
    if v.play_range is not None and v.play_range[1] > F - 1:
        raise _Invalid("viewer.play_range", f"frame {v.play_range[1]} is past the last frame "
                                            f"({F - 1})")


def _not_a_joint(name: str, skeleton, side: str) -> str:
    import difflib
    close = difflib.get_close_matches(name, skeleton.names, n=3)
    hint = f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""
    return f"{name!r} is not a joint of the {side} skeleton{hint}"


def evaluate_project(project: Project, performer: Motion | None = None,
                     target: Motion | None = None) -> ProjectMotion:
    """The direct conversion and the final motion (the conversion plus the displacement map).

    No IK runs: the result is a pure function of the project's data, so a saved and reloaded
    project gives the same motion bit for bit. ``performer`` and ``target`` skip reading the
    sources again when the caller has them.
    """
    if performer is None or target is None:
        performer, target = read_sources(project)
    check_project(project, performer, target)
    composed = run_job(project.job(performer, target)).composed
    return ProjectMotion(composed, project.displacement.apply(composed))


def correction_keys(correction: Correction | None) -> DisplacementMap:
    """An IK correction as the keys a project stores (tight tolerances: 0.01 degree, 0.05 mm)."""
    if correction is None:
        return DisplacementMap()
    return correction.displacement_map(rotation_tolerance=ROTATION_TOLERANCE,
                                       translation_tolerance=TRANSLATION_TOLERANCE)


def solve_project(project: Project, performer: Motion | None = None,
                  target: Motion | None = None, *, regenerate: bool = False,
                  ik_options: IKOptions | None = None, progress=None, cancel=None) -> Project:
    """A copy whose displacement map is the IK correction of its constraints, as keys.

    With ``regenerate``, the automatic constraints are dropped and made again from the
    project's settings (``auto_contacts``, ``floor``); otherwise the constraints are solved as
    they are (automatic ones as edited). The map replaces the previous one, hand edits
    included.
    """
    if performer is None or target is None:
        performer, target = read_sources(project)
    check_project(project, performer, target)
    if regenerate:
        job = project.job(performer, target,
                          constraints=[c for c in project.constraints if not c.auto],
                          auto_contacts=project.auto_contacts, floor=project.floor,
                          ik_options=ik_options)
    else:
        job = project.job(performer, target, constraints=project.constraints,
                          ik_options=ik_options)
    result = run_job(job, progress=progress, cancel=cancel)
    return project.replace(constraints=tuple(result.constraints),
                           displacement=correction_keys(result.correction))


def embed_sources(project: Project, roles=ROLES) -> Project:
    """A copy with the clips of ``roles`` embedded (read from their files), so that the
    project can be sent on its own."""
    changes = {}
    for role in roles:
        source = getattr(project, role)
        if source.embedded is not None:
            continue
        if source.path is None or not os.path.isfile(source.path):
            raise MissingSourceError(role, os.path.abspath(source.path or ""))
        try:
            data = Path(source.path).read_bytes()
        except OSError as exc:
            raise ProjectError(f"the {role} clip {source.path} cannot be read: "
                               f"{exc.strerror or exc}", None, f"{role}.path") from None
        try:
            text = _decode(data, source.path)
        except BVHError as exc:
            raise ProjectError(f"the {role} clip cannot be embedded: {exc}", None,
                               f"{role}.path") from None
        changes[role] = dataclasses.replace(source, embedded=text)
    return project.replace(**changes)


# --------------------------------------------------------------------------- writing
def project_to_json(project: Project, path=None) -> str:
    """The project file's text. ``path`` (where it will be written) makes source paths
    relative to its folder; without it they are written as held."""
    folder = os.path.dirname(os.path.abspath(os.fspath(path))) if path is not None else None
    try:
        return _encode(_project_dict(project, folder), 0, "") + "\n"
    except _Invalid as exc:
        raise ProjectError(f"cannot be saved: {exc.problem}", path, exc.field) from None


def _project_dict(p: Project, folder) -> dict:
    corr = {"pairs": dict(p.correspondence.pairs)}
    if p.correspondence.notes:
        corr["notes"] = dict(sorted(p.correspondence.notes.items()))
    b = p.bind_options
    v = p.viewer
    out = {
        "format": FORMAT,
        "version": VERSION,
        "performer": _source_dict(p.performer, folder, "performer"),
        "target": _source_dict(p.target, folder, "target"),
        "correspondence": corr,
        "binding": {"performer_reference": _reference_out(b.performer_reference),
                    "target_reference": _reference_out(b.target_reference),
                    "rest_alignment": bool(b.rest_alignment), "distribute": b.distribute},
        "root": {"mode": p.root.mode,
                 "scale": list(p.root.scale) if p.root.scale is not None else None},
        "contacts": {"auto": bool(p.auto_contacts),
                     "options": {f.name: float(getattr(p.contact_options, f.name))
                                 for f in dataclasses.fields(ContactOptions)}},
        "floor": float(p.floor) if p.floor is not None else None,
        "viewer": {"current_frame": int(v.current_frame),
                   "play_range": [int(x) for x in v.play_range] if v.play_range else None,
                   "camera": dict(sorted(v.camera.items())),
                   "shown": list(v.shown),
                   "options": dict(sorted(v.options.items()))},
        "constraints": [c.to_dict() for c in p.constraints],
        "displacement": _displacement_dict(p.displacement),
    }
    embedded = {role: getattr(p, role).embedded for role in ROLES
                if getattr(p, role).embedded is not None}
    if embedded:
        out["embedded"] = embedded
    return out


def _displacement_dict(displacement: DisplacementMap) -> dict:
    """``DisplacementMap.to_dict`` with one interpolation name instead of a list where every
    key has the same (the IK's keys are all linear)."""
    channels = []
    for item in displacement.to_dict()["channels"]:
        kinds = item["interpolation"]
        if kinds and all(k == kinds[0] for k in kinds):
            item = dict(item, interpolation=kinds[0])
        channels.append(item)
    return {"channels": channels}


def _reference_out(ref):
    return ref if isinstance(ref, str) else int(ref)


def _source_dict(source: Source, folder, role: str) -> dict:
    if source.path is None and source.embedded is None:
        raise _Invalid(role, "needs a path to a clip or the clip embedded")
    path = source.path
    if path is not None and folder is not None:
        absolute = os.path.abspath(path)
        try:
            path = os.path.relpath(absolute, folder).replace(os.sep, "/")
        except ValueError:                    # another drive (Windows): keep it absolute
            path = absolute
    mode = source.position_mode
    return {"path": path, "units": source.units,
            "scale": float(source.scale) if source.scale is not None else None,
            "up_axis": source.up_axis,
            "position_mode": dict(mode) if isinstance(mode, dict) else mode}


_LINE = 100


def _encode(value, depth: int, where: str, lead: int = 0) -> str:
    """Deterministic, readable JSON: objects one key per line in the given order, lists of
    numbers packed on lines of at most 100 characters, floats as their shortest repr.
    ``lead``: the column where the value starts."""
    if isinstance(value, np.generic):
        value = value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return _scalar(value, where)
    pad = "  " * (depth + 1)
    end = "  " * depth
    if isinstance(value, dict):
        if not value:
            return "{}"
        items = []
        for k, v in value.items():
            if not isinstance(k, str):
                raise _Invalid(where, f"the key {k!r} is not a string")
            key = f"{pad}{_scalar(k, where)}: "
            items.append(key + _encode(v, depth + 1, _sub(where, k), len(key)))
        return "{\n" + ",\n".join(items) + "\n" + end + "}"
    if isinstance(value, (list, tuple, np.ndarray)):
        value = value.tolist() if isinstance(value, np.ndarray) else value
        if not value:
            return "[]"
        if all(type(v) is float or type(v) is int for v in value):     # the fast common case
            if not all(map(math.isfinite, value)):
                i = next(i for i, v in enumerate(value) if not math.isfinite(v))
                raise _Invalid(f"{where}[{i}]", f"{value[i]!r} is not a finite number")
            parts = list(map(repr, value))
        else:
            parts = [_encode(v, depth + 1, f"{where}[{i}]", len(pad))
                     for i, v in enumerate(value)]
        flat = all("\n" not in s for s in parts)
        one_line = "[" + ", ".join(parts) + "]"
        if flat and lead + len(one_line) + 1 <= _LINE:
            return one_line
        if flat and all(not isinstance(v, (dict, list, tuple)) for v in value):
            lines, line = [], ""
            for s in parts:
                if line and len(pad) + len(line) + len(s) + 3 > _LINE:
                    lines.append(line + ",")
                    line = s
                else:
                    line = f"{line}, {s}" if line else s
            lines.append(line)
            return "[\n" + "\n".join(pad + ln for ln in lines) + "\n" + end + "]"
        return "[\n" + ",\n".join(pad + s for s in parts) + "\n" + end + "]"
    raise _Invalid(where, f"{type(value).__name__} values cannot be saved")


def _scalar(value, where: str) -> str:
    if isinstance(value, float) and not math.isfinite(value):
        raise _Invalid(where, f"{value!r} is not a finite number")
    if isinstance(value, str):
        text = json.dumps(value, ensure_ascii=False)
        try:
            text.encode("utf-8")
        except UnicodeEncodeError:            # a lone surrogate: escape it
            text = json.dumps(value)
        return text
    return json.dumps(value)


# --------------------------------------------------------------------------- reading
def project_from_json(text: str, path=None) -> Project:
    """A project from a file's text; ``path`` (the file) resolves relative source paths and
    is named in errors. Sources are not read here (see :func:`open_project`)."""
    folder = os.path.dirname(os.path.abspath(os.fspath(path))) if path is not None else None
    try:
        data = _parse(text)
        data = migrate(data)
        return _build(data, folder)
    except _Invalid as exc:
        raise ProjectError(exc.problem, path, exc.field) from None


def _parse(text: str):
    def constant(name):
        raise _Invalid("", f"{name} is not a number a project may hold")

    def number(s):
        value = float(s)
        if not math.isfinite(value):
            raise _Invalid("", f"the number {s[:20]} is too large")
        return value

    def unique(pairs):
        out = {}
        for k, v in pairs:
            if k in out:
                raise _Invalid("", f"the key {k!r} appears twice in one object")
            out[k] = v
        return out

    try:
        return json.loads(text, parse_constant=constant, parse_float=number,
                          object_pairs_hook=unique)
    except json.JSONDecodeError as exc:
        tail = (" (the file ends there: it looks truncated)"
                if exc.pos >= len(text.rstrip()) else "")
        raise _Invalid("", f"not valid JSON at line {exc.lineno}, column {exc.colno}: "
                           f"{exc.msg}{tail}") from None
    except RecursionError:
        raise _Invalid("", "not a project: the JSON is nested too deeply") from None
    except ValueError as exc:                 # e.g. an integer with too many digits
        raise _Invalid("", f"not valid JSON: {exc}") from None


#: version n -> a function taking a version-n project (a dict) to version n + 1
MIGRATIONS: dict[int, Callable[[dict], dict]] = {}


def migrator(version: int):
    """Register a function migrating format ``version`` to ``version + 1``."""
    def register(function):
        MIGRATIONS[version] = function
        return function
    return register


def migrate(data) -> dict:
    """``data`` (a parsed project file of any supported version) in the current format."""
    if not isinstance(data, dict):
        raise _Invalid("", f"not a Motion Composer project: expected a JSON object, not "
                           f"{_kind(data)}")
    if data.get("format") != FORMAT:
        raise _Invalid("format", f"not a Motion Composer project (expected \"format\": "
                                 f"\"{FORMAT}\")")
    version = data.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 0:
        raise _Invalid("version", f"expected a format version (a whole number), not "
                                  f"{_show(version)}")
    if version > VERSION:
        raise _Invalid("version", f"this project was written by a newer Motion Composer "
                                  f"(format version {version}; this one reads up to "
                                  f"{VERSION}); update Motion Composer to open it")
    while version < VERSION:
        step = MIGRATIONS.get(version)
        if step is None:
            raise _Invalid("version", f"format version {version} is too old for this Motion "
                                      f"Composer (it reads {min(MIGRATIONS, default=VERSION)} "
                                      f"to {VERSION})")
        data = step(data)
        assert data["version"] == version + 1, "a migrator must raise the version by one"
        version = data["version"]
    return data


@migrator(0)
def _v0_to_v1(old: dict) -> dict:
    """Version 0 (the first sessions): sources were bare paths, the mapping a list of
    ``[target, performer]`` pairs under ``"mapping"``; no viewer state, contacts, floor or
    embedding."""
    data = {k: v for k, v in old.items() if k not in ("mapping", "performer", "target")}
    for role in ROLES:
        src = old.get(role)
        if not isinstance(src, str):
            raise _Invalid(role, f"expected the clip's path (format version 0), not "
                                 f"{_show(src)}")
        data[role] = {"path": src}
    mapping = old.get("mapping")
    if not isinstance(mapping, list):
        raise _Invalid("mapping", f"expected a list of [target, performer] joint pairs, not "
                                  f"{_show(mapping)}")
    pairs = {}
    for i, item in enumerate(mapping):
        if not (isinstance(item, list) and len(item) == 2 and all(isinstance(x, str)
                                                                  for x in item)):
            raise _Invalid(f"mapping[{i}]", f"expected [target joint, performer joint], not "
                                            f"{_show(item)}")
        pairs[item[0]] = item[1]
    data["correspondence"] = {"pairs": pairs}
    data["version"] = 1
    return data


_TOP = ("format", "version", "performer", "target", "correspondence", "binding", "root",
        "contacts", "floor", "viewer", "constraints", "displacement", "embedded")


def _build(data: dict, folder) -> Project:
    _obj(data, "", required=("format", "version", "performer", "target", "correspondence"),
         optional=_TOP)
    embedded = _obj(data.get("embedded", {}), "embedded", optional=ROLES)
    for role, text in embedded.items():
        _str(text, f"embedded.{role}")
    sources = {role: _source(data[role], role, folder, embedded.get(role)) for role in ROLES}
    auto_contacts, contact_options = _contacts(data.get("contacts", {}))
    return Project(
        performer=sources["performer"], target=sources["target"],
        correspondence=_correspondence(data["correspondence"]),
        bind_options=_binding(data.get("binding", {})),
        root=_root(data.get("root", {})),
        auto_contacts=auto_contacts, contact_options=contact_options,
        floor=_optional(_num, data.get("floor"), "floor"),
        constraints=tuple(_constraint(c, f"constraints[{i}]")
                          for i, c in enumerate(_list(data.get("constraints", []),
                                                      "constraints"))),
        displacement=_displacement(data.get("displacement", {})),
        viewer=_viewer(data.get("viewer", {})))


def _source(data, where: str, folder, embedded) -> Source:
    d = _obj(data, where, optional=("path", "units", "scale", "up_axis", "position_mode"))
    path = _optional(_str, d.get("path"), f"{where}.path")
    if path is not None:
        if not path or "\x00" in path:
            raise _Invalid(f"{where}.path", f"expected a file path, not {_show(path)}")
        if folder is not None and not os.path.isabs(path):
            path = os.path.join(folder, path)
        path = os.path.normpath(path)
    units = _optional(_choice, d.get("units"), f"{where}.units", tuple(UNITS))
    scale = _optional(_num, d.get("scale"), f"{where}.scale", positive=True)
    up_axis = _optional(_choice, d.get("up_axis"), f"{where}.up_axis", AXES)
    mode = d.get("position_mode")
    if isinstance(mode, dict):
        mode = {_str(k, f"{where}.position_mode"): _choice(v, _sub(f"{where}.position_mode", k),
                                                          ("absolute", "relative"))
                for k, v in mode.items()}
    elif mode is not None:
        mode = _choice(mode, f"{where}.position_mode", ("absolute", "relative"))
    if path is None and embedded is None:
        raise _Invalid(where, "needs the clip's path or the clip embedded in the project")
    return Source(path=path, embedded=embedded, units=units, scale=scale, up_axis=up_axis,
                  position_mode=mode)


def _correspondence(data) -> Correspondence:
    d = _obj(data, "correspondence", required=("pairs",), optional=("notes",))
    pairs = _obj(d["pairs"], "correspondence.pairs")
    for t, p in pairs.items():
        _str(p, _sub("correspondence.pairs", t))
    notes = _obj(d.get("notes", {}), "correspondence.notes")
    for t, n in notes.items():
        _str(n, _sub("correspondence.notes", t))
    return Correspondence(pairs, notes)


def _reference(value, where: str):
    if value in ("auto", "rest") and isinstance(value, str):
        return value
    if isinstance(value, int) and not isinstance(value, bool) and value >= 0:
        return value
    raise _Invalid(where, f"expected \"auto\", \"rest\" or a frame number, not {_show(value)}")


def _binding(data) -> BindOptions:
    keys = [f.name for f in dataclasses.fields(BindOptions)]
    d = _obj(data, "binding", optional=keys)
    default = BindOptions()
    return BindOptions(
        performer_reference=_reference(d.get("performer_reference",
                                             default.performer_reference),
                                       "binding.performer_reference"),
        target_reference=_reference(d.get("target_reference", default.target_reference),
                                    "binding.target_reference"),
        rest_alignment=_bool(d.get("rest_alignment", default.rest_alignment),
                             "binding.rest_alignment"),
        distribute=_choice(d.get("distribute", default.distribute), "binding.distribute",
                           ("even", "first")))


def _root(data) -> RootOptions:
    d = _obj(data, "root", optional=("mode", "scale"))
    mode = _choice(d.get("mode", "scaled"), "root.mode", ("scaled", "absolute", "in-place"))
    scale = d.get("scale")
    if scale is not None:
        scale = _list(scale, "root.scale")
        if len(scale) != 2:
            raise _Invalid("root.scale", f"expected [horizontal, vertical], not {_show(scale)}")
        scale = tuple(_num(s, f"root.scale[{i}]") for i, s in enumerate(scale))
    return RootOptions(mode=mode, scale=scale)


def _contacts(data) -> tuple[bool, ContactOptions]:
    d = _obj(data, "contacts", optional=("auto", "options"))
    keys = [f.name for f in dataclasses.fields(ContactOptions)]
    o = _obj(d.get("options", {}), "contacts.options", optional=keys)
    options = ContactOptions(**{k: _num(v, f"contacts.options.{k}", positive=True)
                                for k, v in o.items()})
    return _bool(d.get("auto", False), "contacts.auto"), options


_CONSTRAINT_KEYS = ("priority", "weight", "name", "enabled", "auto", "meta")


def _constraint(data, where: str) -> Constraint:
    d = _obj(data, where, required=("joint", "kind", "goal", "range"),
             optional=_CONSTRAINT_KEYS)
    joint = _str(d["joint"], f"{where}.joint")
    if not joint:
        raise _Invalid(f"{where}.joint", "expected a target joint's name, not an empty string")
    _choice(d["kind"], f"{where}.kind", KINDS)
    _obj(d["goal"], f"{where}.goal")
    rng = _list(d["range"], f"{where}.range")
    if len(rng) != 4:
        raise _Invalid(f"{where}.range", f"expected [smooth_in, start, end, smooth_out], not "
                                         f"{_show(rng)}")
    for i, x in enumerate(rng):
        _int(x, f"{where}.range[{i}]", minimum=0)
    if "priority" in d:
        _int(d["priority"], f"{where}.priority", minimum=1)
    if "weight" in d:
        _num(d["weight"], f"{where}.weight", positive=True)
    for key, check in (("name", _str), ("enabled", _bool), ("auto", _bool), ("meta", _obj)):
        if key in d:
            check(d[key], f"{where}.{key}")
    label = f"constraint {(d.get('name') or joint)!r}: "
    try:
        return Constraint.from_dict(d)
    except (ConstraintError, TypeError, ValueError) as exc:
        message = str(exc)
        message = message[len(label):] if message.startswith(label) else message
        sub = ("goal" if "goal" in message else
               "range" if "time range" in message or "smooth" in message else None)
        raise _Invalid(f"{where}.{sub}" if sub else where, message) from None


def _displacement(data) -> DisplacementMap:
    d = _obj(data, "displacement", optional=("channels",))
    curves = {}
    for i, item in enumerate(_list(d.get("channels", []), "displacement.channels")):
        where = f"displacement.channels[{i}]"
        c = _obj(item, where, required=("joint", "channel", "frames", "values"),
                 optional=("interpolation",))
        joint = _str(c["joint"], f"{where}.joint")
        allowed = TRANSLATION_CHANNELS if joint == ROOT else ROTATION_CHANNELS
        channel = _choice(c["channel"], f"{where}.channel", allowed)
        frames = [_num(x, f"{where}.frames[{k}]")
                  for k, x in enumerate(_list(c["frames"], f"{where}.frames"))]
        values = [_num(x, f"{where}.values[{k}]")
                  for k, x in enumerate(_list(c["values"], f"{where}.values"))]
        interp = c.get("interpolation", [])
        if isinstance(interp, str):           # one name for every key
            interp = [_choice(interp, f"{where}.interpolation", INTERPOLATIONS)] * len(frames)
        interp = tuple(_choice(x, f"{where}.interpolation[{k}]", INTERPOLATIONS)
                       for k, x in enumerate(_list(interp, f"{where}.interpolation")))
        if (joint, channel) in curves:
            raise _Invalid(where, f"a second curve for {joint} {channel}")
        try:
            curves[(joint, channel)] = Curve(frames, values, interp)
        except MotionComposerError as exc:
            message = str(exc)
            sub = ("interpolation" if "interpolation" in message else
                   "frames" if "increase" in message else "values")
            raise _Invalid(f"{where}.{sub}", message) from None
    return DisplacementMap(curves)


def _viewer(data) -> ViewerState:
    d = _obj(data, "viewer", optional=("current_frame", "play_range", "camera", "shown",
                                        "options"))
    frame = _int(d.get("current_frame", 0), "viewer.current_frame", minimum=0)
    play = d.get("play_range")
    if play is not None:
        play = _list(play, "viewer.play_range")
        if len(play) != 2:
            raise _Invalid("viewer.play_range", f"expected [first, last], not {_show(play)}")
        play = tuple(_int(x, f"viewer.play_range[{i}]", minimum=0) for i, x in enumerate(play))
        if play[0] > play[1]:
            raise _Invalid("viewer.play_range", f"the first frame {play[0]} is after the last "
                                                f"{play[1]}")
    camera = {}
    for k, v in _obj(d.get("camera", {}), "viewer.camera").items():
        where = _sub("viewer.camera", k)
        if isinstance(v, list):
            camera[k] = [_num(x, f"{where}[{i}]") for i, x in enumerate(v)]
        else:
            camera[k] = _num(v, where)
    shown = _list(d.get("shown", list(ViewerState().shown)), "viewer.shown")
    for i, s in enumerate(shown):
        _choice(s, f"viewer.shown[{i}]", SKELETONS)
    options = _obj(d.get("options", {}), "viewer.options")
    for k, v in options.items():
        if not (v is None or isinstance(v, (str, bool, int, float))):
            raise _Invalid(_sub("viewer.options", k), f"expected a string, number, true/false "
                                                      f"or null, not {_kind(v)}")
    return ViewerState(current_frame=frame, play_range=play, camera=camera, shown=tuple(shown),
                       options=options)


# --------------------------------------------------------------------------- field checks
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _sub(parent: str, key: str) -> str:
    """The JSON path of ``key`` in the object at ``parent``."""
    if _IDENT.fullmatch(key):
        return f"{parent}.{key}" if parent else key
    return f"{parent}[{json.dumps(key, ensure_ascii=False)}]"


def _kind(value) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true/false"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "an object"
    return type(value).__name__


def _show(value) -> str:
    try:
        text = json.dumps(value, ensure_ascii=False)
    except (TypeError, ValueError):
        text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _obj(value, where: str, *, required=(), optional=None) -> dict:
    if not isinstance(value, dict):
        raise _Invalid(where, f"expected an object, not {_kind(value)} ({_show(value)})")
    for key in required:
        if key not in value:
            raise _Invalid(_sub(where, key), "is missing")
    if optional is not None:
        known = dict.fromkeys((*required, *optional))
        for key in value:
            if key not in known:
                raise _Invalid(_sub(where, key), f"unknown field (expected one of "
                                                 f"{', '.join(known)})")
    return value


def _list(value, where: str) -> list:
    if not isinstance(value, list):
        raise _Invalid(where, f"expected a list, not {_kind(value)} ({_show(value)})")
    return value


def _str(value, where: str) -> str:
    if not isinstance(value, str):
        raise _Invalid(where, f"expected a string, not {_kind(value)} ({_show(value)})")
    return value


def _bool(value, where: str) -> bool:
    if not isinstance(value, bool):
        raise _Invalid(where, f"expected true or false, not {_kind(value)} ({_show(value)})")
    return value


def _int(value, where: str, *, minimum: int | None = None) -> int:
    if isinstance(value, float) and value.is_integer() and abs(value) < 2 ** 53:
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise _Invalid(where, f"expected a whole number, not {_kind(value)} ({_show(value)})")
    if minimum is not None and value < minimum:
        raise _Invalid(where, f"expected a whole number from {minimum}, not {value}")
    return value


def _num(value, where: str, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _Invalid(where, f"expected a number, not {_kind(value)} ({_show(value)})")
    value = float(value)
    if not math.isfinite(value):
        raise _Invalid(where, f"expected a finite number, not {value!r}")
    if positive and value <= 0:
        raise _Invalid(where, f"expected a positive number, not {value!r}")
    return value


def _choice(value, where: str, allowed) -> str:
    if not isinstance(value, str) or value not in allowed:
        raise _Invalid(where, f"expected one of {', '.join(allowed)}, not {_show(value)}")
    return value


def _optional(check, value, where: str, *args, **kwargs):
    return None if value is None else check(value, where, *args, **kwargs)


# --------------------------------------------------------------------------- files
def backup_path(path) -> Path:
    """Where :func:`save_project` keeps the previous version: ``<name>.bak``."""
    path = Path(path)
    return path.with_name(path.name + ".bak")


def save_project(project: Project, path, *, backup: bool = True) -> None:
    """Write ``project`` to ``path`` atomically: a crash or kill at any moment leaves the
    previous file intact. With ``backup``, the previous file (when its content differs) is
    first kept as ``<name>.bak``, itself written atomically."""
    path = os.fspath(path)
    payload = project_to_json(project, path).encode("utf-8")
    if backup and os.path.isfile(path):
        try:
            previous = Path(path).read_bytes()
        except OSError as exc:
            raise FileWriteError(f"{path}: cannot keep a backup: the file cannot be read: "
                                 f"{exc.strerror or exc}") from None
        if previous != payload:
            atomic_write(backup_path(path), previous)
    atomic_write(path, payload)


def _read_text(path) -> str:
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise ProjectError("no such project file", path) from None
    except IsADirectoryError:
        raise ProjectError("this is a folder, not a project file", path) from None
    except OSError as exc:
        raise ProjectError(f"cannot be read: {exc.strerror or exc}", path) from None
    if not data.strip():
        raise ProjectError("the file is empty (a project is a JSON object)", path)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ProjectError(f"not a project file: byte {exc.start} is not UTF-8 text",
                           path) from None


def open_project(path) -> OpenedProject:
    """Load a project and read its clips, checking every joint and frame it names."""
    project = project_from_json(_read_text(path), path)
    performer, target = read_sources(project, path=path)
    check_project(project, performer, target, path=path)
    return OpenedProject(project, performer, target)


def load_project(path, *, check_sources: bool = True) -> Project:
    """Load a project. With ``check_sources`` (the default) its clips are read and every
    joint and frame it names is checked against them."""
    if check_sources:
        return open_project(path).project
    return project_from_json(_read_text(path), path)


# --------------------------------------------------------------------------- autosave
def _state_folder() -> Path:
    if os.name == "nt":
        base = os.environ.get("LOCALAPPDATA") or os.path.expanduser("~/AppData/Local")
        return Path(base) / "Motion Composer"
    base = os.environ.get("XDG_STATE_HOME") or os.path.expanduser("~/.local/state")
    return Path(base) / "motion-composer"


def autosave_path(project_path=None) -> Path:
    """Where the autosave of ``project_path`` goes: ``.<name>.autosave`` beside it, or
    ``untitled.autosave`` in the per-user state folder (``$XDG_STATE_HOME/motion-composer``,
    else ``~/.local/state/motion-composer``) for a project never saved."""
    if project_path is None:
        return _state_folder() / "untitled.autosave"
    p = Path(os.path.abspath(os.fspath(project_path)))
    return p.with_name(f".{p.name}.autosave")


def write_autosave(project: Project, project_path=None) -> Path:
    """Write the autosave of a project saved at ``project_path`` (``None``: never saved),
    atomically, and return where it went. It is an ordinary project file."""
    target = autosave_path(project_path)
    if project_path is None:
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise FileWriteError(f"{target.parent}: cannot be created: "
                                 f"{exc.strerror or exc}") from None
    atomic_write(target, project_to_json(project, target))
    return target


def find_autosave(project_path=None) -> Path | None:
    """The autosave to offer at start, or None: one exists and is newer than the project
    file (or the project file is gone, or was never saved)."""
    auto = autosave_path(project_path)
    try:
        auto_time = auto.stat().st_mtime_ns
    except OSError:
        return None
    if project_path is None:
        return auto
    try:
        saved_time = os.stat(project_path).st_mtime_ns
    except OSError:
        return auto
    return auto if auto_time > saved_time else None


def discard_autosave(project_path=None) -> None:
    """Remove the autosave of ``project_path`` (after a save, or when the user declines it)."""
    try:
        autosave_path(project_path).unlink()
    except FileNotFoundError:
        pass
