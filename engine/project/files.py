"""Project files on disk: saving (atomic, with a ``.bak``), opening and reading the clips a
project refers to, checking the project against them, embedding them.

:func:`correction_keys` turns an IK correction into the keys a project stores (evaluating and
solving a project is the scene's part: :mod:`engine.scene`).
"""
from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path

from ..correction.displacement import ROOT, DisplacementMap
from ..correction.enforcement import Correction
from ..errors import BVHError, MappingError
from ..fileio import (FileWriteError, atomic_write, read_regular_file, reading,
                      resolve_write_target)
from ..formats.bvh import _decode, parse_bvh
from ..motion import Motion
from .json import _sub, project_from_json, project_to_json
from .model import (ROLES, MissingSourceError, OpenedProject, Project, ProjectError, Source,
                    _Invalid)

__all__ = ["save_project", "backup_path", "open_project", "load_project", "read_sources",
           "check_project", "embed_sources", "correction_keys"]


def backup_path(path) -> Path:
    """Where :func:`save_project` keeps the previous version: ``<name>.bak``."""
    path = Path(path)
    return path.with_name(path.name + ".bak")


def save_project(project: Project, path, *, backup: bool = True) -> None:
    """Write ``project`` to ``path`` atomically: a crash or kill at any moment leaves the
    previous file intact. With ``backup``, the previous file (when its content differs) is
    first kept as ``<name>.bak``, itself written atomically. Through a symbolic link, the
    link's target is written and its backup kept beside it; the link stays."""
    path = os.fspath(path)
    payload = project_to_json(project, path).encode("utf-8")
    target = resolve_write_target(path)
    if backup and os.path.isfile(target):
        try:
            previous = Path(target).read_bytes()
        except OSError as exc:
            raise FileWriteError(f"{path}: cannot keep a backup: the file cannot be read: "
                                 f"{exc.strerror or exc}") from None
        if previous != payload:
            atomic_write(backup_path(target), previous)
    atomic_write(target, payload)


def _read_text(path) -> str:
    with reading(path, ProjectError, "a project file", missing="no such project file"):
        data = read_regular_file(path)
    if not data.strip():
        raise ProjectError("the file is empty (a project is a JSON object)", path)
    _refuse_motion_file(data, path)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ProjectError(f"not a project file: byte {exc.start} is not UTF-8 text",
                           path) from None


def _refuse_motion_file(data: bytes, path) -> None:
    """A clip or a character opened as a project is named as what it is, with what to do
    (its JSON or UTF-8 error would say nothing of the kind). A JSON object is left to the
    project's own checks (a project may name a glTF file's members; a glTF file there is
    "not a Motion Composer project")."""
    from ..formats import FORMATS, HEAD_BYTES
    head = data[:HEAD_BYTES]
    if head.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"{"):
        return
    for fmt in FORMATS:
        if fmt.sniff(head):
            what = ("a character or its takes" if fmt.read_take else
                    "a character" if fmt.mesh else "a motion clip")
            article = "an" if fmt.name[0] in "AEFHILMNORSX" else "a"    # "an FBX file"
            raise ProjectError(f"this is {article} {fmt.name} file ({what}), not a project: "
                               "import it "
                               "as the performer or the target, or make a project from it "
                               "with 'motion-composer retarget ... --save-project'", path)


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


def read_sources(project: Project, *, path=None) -> tuple[Motion, Motion]:
    """The performer and target motions. ``path`` (the project file) is named in errors."""
    return tuple(_read_source(getattr(project, role), role, path) for role in ROLES)


def _read_source(source: Source, role: str, path) -> Motion:
    options = source.reader_options()
    if source.embedded is not None:
        options.pop("take", None)                  # an embedded clip is BVH text
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
    # the file's content says which reader (a glTF or FBX character's bind pose is the
    # target; an FBX performer is one of its takes)
    from ..errors import FBXError, FileFormatError, GLTFError
    from ..formats import read_motion, read_performer
    try:
        return (read_performer if role == "performer" and _has_takes(source.path) else
                read_motion)(source.path, **options)
    except BVHError as exc:
        if _about_position_mode(exc):
            raise ProjectError(exc.problem, path, f"{role}.position_mode") from None
        raise ProjectError(f"the {role} clip cannot be read: {exc}", path,
                           f"{role}.path") from None
    except FileFormatError as exc:
        what = "character" if isinstance(exc, (GLTFError, FBXError)) else "clip"
        raise ProjectError(f"the {role} {what} cannot be read: {exc}", path,
                           f"{role}.path") from None


def _has_takes(path) -> bool:
    """Whether the file is in a format whose performer is a take (FBX)."""
    from ..formats import sniff
    return sniff(path).read_take is not None


def _about_position_mode(exc: BVHError) -> bool:
    """A position-mode override naming a joint the clip does not translate."""
    return exc.line is None and "position mode" in exc.problem


def check_project(project: Project, performer: Motion, target: Motion, *, path=None,
                  check_map: bool = True) -> None:
    """Raise :class:`ProjectError` naming the field unless every joint the project names
    exists in its skeleton and every frame number lies in the clips. ``check_map=False``
    lets through a map the conversion cannot use yet (the root not mapped...): an autosave
    of a mapping half done."""
    try:
        _check(project, performer, target, check_map)
    except _Invalid as exc:
        raise ProjectError(exc.problem, path, exc.field) from None


def _check(project: Project, performer: Motion, target: Motion, check_map: bool) -> None:
    tsk, psk = target.skeleton, performer.skeleton
    F = performer.num_frames                  # the composed motion has the performer's frames
    for t, p in project.correspondence.pairs.items():
        where = _sub("correspondence.pairs", t)
        if t not in tsk.index:
            raise _Invalid(where, _not_a_joint(t, tsk, "target"))
        if p not in psk.index:
            raise _Invalid(where, _not_a_joint(p, psk, "performer"))
    try:
        if check_map:
            project.correspondence.validate(tsk, psk)
    except MappingError as exc:
        raise _Invalid("correspondence", exc.problem) from None
    for key, motion in (("performer_reference", performer), ("target_reference", target)):
        ref = getattr(project.bind_options, key)
        if not isinstance(ref, str) and ref >= motion.num_frames:
            raise _Invalid(f"binding.{key}", f"frame {ref} is past the clip's last frame "
                                             f"({motion.num_frames - 1})")
    for joint, _ in project.bind_options.pose_offsets:
        if joint not in tsk.index:
            raise _Invalid(_sub("binding.pose_offsets", joint),
                           _not_a_joint(joint, tsk, "target"))
    for i, c in enumerate(project.constraints):
        where = f"constraints[{i}]"
        if c.joint not in tsk.index:
            raise _Invalid(f"{where}.joint", _not_a_joint(c.joint, tsk, "target"))
        if c.smooth_out > F - 1:
            raise _Invalid(f"{where}.range", f"smooth_out {c.smooth_out} is past the last "
                                             f"frame ({F - 1})")
    for i, (joint, _) in enumerate(project.ik_options.joint_limits):
        if joint >= tsk.num_joints:
            raise _Invalid(f"ik.joint_limits[{i}]", f"joint {joint} is past the target's last "
                                                    f"joint ({tsk.num_joints - 1})")
    maps = [project.displacement] + [layer.displacement for layer in project.layers]
    for n, displacement in enumerate(maps):
        for i, (joint, _) in enumerate(displacement.curves):
            if joint != ROOT and joint not in tsk.index:
                raise _Invalid(f"layers[{n}].channels[{i}].joint",
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


# --------------------------------------------------------------------------- stored keys
#: key fitting of an IK correction stored in a project: [m] per joint over its lever, and at
#: most [rad] per rotation channel
POSITION_TOLERANCE = 1e-4
ROTATION_TOLERANCE = math.radians(0.02)


def correction_keys(correction: Correction | None) -> DisplacementMap:
    """An IK correction as the keys a project stores (fitted within 0.1 mm per joint above a
    point of the IK result, at most 0.02 degree per channel; on a character smaller than
    :data:`~engine.correction.ik.FULL_SIZE` the 0.1 mm shrinks with it, as the solve's
    lengths do, :func:`~engine.correction.ik.length_share`)."""
    if correction is None:
        return DisplacementMap()
    from ..correction.ik import length_share
    from ..describe import figure_size
    share = length_share(figure_size(correction.motion))
    return correction.displacement_map(position_tolerance=POSITION_TOLERANCE * share,
                                       rotation_tolerance=ROTATION_TOLERANCE)
