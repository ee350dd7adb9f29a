"""The project's data: :class:`Project` and its parts, the format's constants and the
errors a project file raises (see :mod:`engine.project`)."""
from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

from .. import limits
from ..conversion.binding import BindOptions
from ..conversion.converter import RootOptions
from ..conversion.correspondence import Correspondence
from ..correction.contacts import ContactOptions
from ..correction.displacement import DisplacementMap, Layer
from ..correction.ik import IKOptions
from ..errors import MotionComposerError
from ..motion import Motion

__all__ = ["Project", "Source", "ViewerState", "ProjectError", "MissingSourceError",
           "OpenedProject", "FORMAT", "VERSION", "SUFFIX", "ROLES",
           "SKELETONS", "SOLVED_LAYER"]

FORMAT = "motion-composer-project"
#: the format version this module writes (and the newest it reads)
VERSION = 4
SUFFIX = ".mcp"
ROLES = ("performer", "target")
#: the solved layer's name in files and in the curve editor
SOLVED_LAYER = "solved"
#: skeletons the viewer can show
SKELETONS = ("performer", "intermediate", "target")


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


def _checked_version(version, *, first: int, newest: int, kind: str, label: str,
                     verb: str) -> int:
    """A file's format ``version``: a whole number from ``first`` up to ``newest`` (this
    program's); ``kind`` ("project"), ``label`` ("format version") and ``verb`` ("open") word
    the error a newer file gives."""
    if isinstance(version, bool) or not isinstance(version, int) or version < first:
        raise _Invalid("version", f"expected a format version (a whole number from {first}), "
                                  f"not {_show(version)}")
    if version > newest:
        raise _Invalid("version", f"this {kind} was written by a newer Motion Composer "
                                  f"({label} {version}; this one reads up to {newest}); "
                                  f"update Motion Composer to {verb} it")
    return version


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
            see :func:`engine.formats.bvh.record_to_motion`. ``up_axis`` is also a glTF or
            FBX file's: the axis its figure stands along where the file says another (see
            :func:`engine.formats.read_character`).
        take: the take of an FBX file (``None``: its first take for a performer, its bind
            pose for a target); a file with one motion (BVH, glTF) has none to choose.
    """

    path: str | None = None
    embedded: str | None = None
    units: str | None = None
    scale: float | None = None
    up_axis: str | None = None
    position_mode: str | dict | None = None
    take: str | None = None

    def __post_init__(self):
        if self.path is not None:
            object.__setattr__(self, "path", os.fspath(self.path))
        if isinstance(self.position_mode, dict):
            object.__setattr__(self, "position_mode", dict(self.position_mode))

    def reader_options(self) -> dict:
        """The keyword arguments for :func:`engine.formats.read_motion` (the BVH reader's
        overrides, and an FBX file's take)."""
        options = {"units": self.units, "scale": self.scale, "up_axis": self.up_axis,
                   "position_mode": self.position_mode, "take": self.take}
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

    @property
    def show_performer(self) -> bool:
        return "performer" in self.shown

    @property
    def show_intermediate(self) -> bool:
        return "intermediate" in self.shown

    @property
    def show_target(self) -> bool:
        return "target" in self.shown

    @property
    def side_by_side(self) -> bool:
        return bool(self.options.get("side_by_side", True))

    def with_(self, **changes) -> "ViewerState":
        """A copy with fields changed; ``show_performer``, ``show_intermediate``,
        ``show_target`` (bool) and ``side_by_side`` are accepted too."""
        shown = set(self.shown)
        options = dict(changes.pop("options", self.options))
        for name in SKELETONS:
            on = changes.pop(f"show_{name}", None)
            if on is not None:
                (shown.add if on else shown.discard)(name)
        if "side_by_side" in changes:
            options["side_by_side"] = bool(changes.pop("side_by_side"))
        return dataclasses.replace(self, shown=tuple(shown), options=options, **changes)


@dataclass(frozen=True, eq=False)
class Project:
    """A whole retargeting session (see the module doc). Plain data: change it with
    :func:`dataclasses.replace`.

    ``displacement`` is the solved layer: the IK correction as keys, which a solve
    replaces. ``layers`` are the animator's layers (:class:`~engine.correction.displacement.
    Layer`), applied in order on top of the composed motion; a solve starts from the composed
    motion with them applied and never changes them. The final motion is the solved layer
    applied on top of that.

    ``floor`` [m] is the floor the target's feet are kept on or above (``None``: the one the
    character stands on in its reference pose); with ``stand_on_floor`` the direct
    conversion is moved onto it too (:meth:`engine.scene.Scene.lift`), else it is only the
    feet's floor plane (how format 3 and older read it).

    ``ik_options`` are the settings its correction is solved with; their ``scale`` stays
    ``None`` (each run takes the character's stature), so it is not part of a project.
    """

    performer: Source
    target: Source
    correspondence: Correspondence = field(default_factory=Correspondence)
    bind_options: BindOptions = field(default_factory=BindOptions)
    root: RootOptions = field(default_factory=RootOptions)
    auto_contacts: bool = False
    contact_options: ContactOptions = field(default_factory=ContactOptions)
    floor: float | None = None
    stand_on_floor: bool = True
    ik_options: IKOptions = field(default_factory=IKOptions)
    constraints: tuple = ()
    displacement: DisplacementMap = field(default_factory=DisplacementMap)
    layers: tuple = (Layer(),)
    viewer: ViewerState = field(default_factory=ViewerState)

    def __post_init__(self):
        object.__setattr__(self, "constraints", tuple(self.constraints))
        object.__setattr__(self, "layers", tuple(self.layers))
        names = [layer.name for layer in self.layers]
        if len(set(names)) != len(names) or SOLVED_LAYER in names:
            raise MotionComposerError(f"animator layers need distinct names other than "
                                      f"{SOLVED_LAYER!r}, not {names}")
        if self.floor is not None and limits.problem(self.floor) is not None:
            raise MotionComposerError(f"floor: expected a finite height in metres of magnitude "
                                      f"at most {limits.MAX_MAGNITUDE:g}, not {self.floor!r}")
        if not isinstance(self.stand_on_floor, bool):
            raise MotionComposerError(f"stand_on_floor: expected true or false, not "
                                      f"{self.stand_on_floor!r}")
        if self.ik_options.scale is not None:
            raise ValueError("a project's IK options leave scale None: each run takes the "
                             "character's stature")

    def replace(self, **changes) -> "Project":
        return dataclasses.replace(self, **changes)


class OpenedProject(NamedTuple):
    project: Project
    performer: Motion
    target: Motion
