"""Retarget profiles: what belongs to a pair of skeletons rather than to one clip, in one file.

A :class:`Profile` holds the correspondence, the binding options (reference poses, rest
alignment, chain turns, the pose offsets and the chain settings), the root options, the IK
options and the automatic-contact settings: set up once on one clip, applied to a whole
library (``retarget --profile``, ``batch --profile``, or loaded in the window), like Unreal's
retargeter assets or a HumanIK characterisation. Clips, constraints, layers, the floor and
the viewer state stay in projects.

The file (``.mcprofile``) is JSON written like a project (:mod:`engine.project.json`: fixed
key order, shortest float reprs), with the same objects under the same names::

    {
      "format": "motion-composer-profile",
      "version": 1,
      "correspondence": {"pairs": {...}, "notes": {...}},
      "binding": {"performer_reference": "auto", ..., "pose_offsets": {...}, "chains": {...}},
      "root": {"mode": "scaled", "scale": null},
      "contacts": {"auto": true, "options": {...}},
      "ik": {...}
    }

Bad input raises :class:`ProfileError` naming the file and the JSON field.
"""
from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field

import numpy as np

from ..conversion.binding import BindOptions
from ..conversion.converter import RootOptions
from ..conversion.correspondence import Correspondence
from ..correction.contacts import ContactOptions
from ..correction.ik import IKOptions
from ..fileio import atomic_write, read_regular_file, reading
from ..conversion.chains import ChainSettings, euler_to_offset
from .json import (_binding, _chains, _contacts, _correspondence, _encode, _ik, _list, _num,
                   _obj, _parse, _root, _sub, binding_dict, ik_dict)
from .model import Project, ProjectError, _Invalid, _checked_version, _show

__all__ = ["Profile", "ProfileError", "profile_of", "apply_profile", "save_profile",
           "read_profile", "profile_to_json", "profile_from_json", "PROFILE_FORMAT",
           "PROFILE_VERSION", "PROFILE_SUFFIX", "SettingsFileError", "read_pose_offsets",
           "read_chain_settings"]

PROFILE_FORMAT = "motion-composer-profile"
#: the profile format version this module writes (and the newest it reads)
PROFILE_VERSION = 1
PROFILE_SUFFIX = ".mcprofile"


class ProfileError(ProjectError):
    """A profile file that cannot be used (``path``, ``field`` and ``problem`` as for
    :class:`ProjectError`)."""


@dataclass(frozen=True, eq=False)
class Profile:
    """Everything of a retargeting session that belongs to the pair of skeletons.

    Attributes: as the :class:`~engine.project.Project` fields of the same names.
    """

    correspondence: Correspondence = field(default_factory=Correspondence)
    bind_options: BindOptions = field(default_factory=BindOptions)
    root: RootOptions = field(default_factory=RootOptions)
    ik_options: IKOptions = field(default_factory=IKOptions)
    contact_options: ContactOptions = field(default_factory=ContactOptions)
    auto_contacts: bool = False

    def __post_init__(self):
        if self.ik_options.scale is not None:
            raise ValueError("a profile's IK options leave scale None: each run takes the "
                             "character's stature")


_FIELDS = tuple(f.name for f in dataclasses.fields(Profile))


def profile_of(project: Project) -> Profile:
    """The profile of ``project``: its map, binding, root, IK and contact settings."""
    return Profile(**{name: getattr(project, name) for name in _FIELDS})


def apply_profile(project: Project, profile: Profile) -> Project:
    """``project`` with ``profile``'s settings in place of its own (its clips, constraints,
    layers, floor and viewer kept)."""
    return project.replace(**{name: getattr(profile, name) for name in _FIELDS})


def profile_to_json(profile: Profile) -> str:
    """The profile file's text (deterministic: the same profile gives the same bytes)."""
    corr = {"pairs": dict(profile.correspondence.pairs)}
    if profile.correspondence.notes:
        corr["notes"] = dict(sorted(profile.correspondence.notes.items()))
    data = {
        "format": PROFILE_FORMAT,
        "version": PROFILE_VERSION,
        "correspondence": corr,
        "binding": binding_dict(profile.bind_options),
        "root": {"mode": profile.root.mode,
                 "scale": list(profile.root.scale) if profile.root.scale is not None
                 else None},
        "contacts": {"auto": bool(profile.auto_contacts),
                     "options": {f.name: float(getattr(profile.contact_options, f.name))
                                 for f in dataclasses.fields(ContactOptions)}},
        "ik": ik_dict(profile.ik_options),
    }
    return _encode(data, 0, "") + "\n"


def profile_from_json(text: str, path=None) -> Profile:
    """A profile from a file's text; ``path`` is named in errors (:class:`ProfileError`)."""
    try:
        data = _parse(text)
        _obj(data, "", required=("format", "version", "correspondence"),
             optional=("binding", "root", "contacts", "ik"))
        if data["format"] != PROFILE_FORMAT:
            raise _Invalid("format", f"not a Motion Composer profile (expected \"format\": "
                                     f"\"{PROFILE_FORMAT}\", not {_show(data['format'])})")
        _checked_version(data["version"], first=1, newest=PROFILE_VERSION, kind="profile",
                         label="profile version", verb="use")
        auto_contacts, contact_options = _contacts(data.get("contacts", {}))
        return Profile(correspondence=_correspondence(data["correspondence"]),
                       bind_options=_binding(data.get("binding", {})),
                       root=_root(data.get("root", {})), ik_options=_ik(data.get("ik", {})),
                       contact_options=contact_options, auto_contacts=auto_contacts)
    except _Invalid as exc:
        raise ProfileError(exc.problem, path, exc.field) from None


def save_profile(path, profile: Profile) -> None:
    """Write ``profile`` to ``path`` atomically (a crash leaves the previous file intact)."""
    atomic_write(os.fspath(path), profile_to_json(profile).encode("utf-8"))


def read_profile(path) -> Profile:
    """The profile in the file at ``path``; raises :class:`ProfileError` naming the file and
    the field of any bad value."""
    return profile_from_json(_read_text(path, ProfileError, "profile"), path)


def _read_text(path, error, kind: str) -> str:
    """The text of the ``kind`` file at ``path`` (UTF-8, a BOM allowed); ``error`` (a
    :class:`ProjectError` class) when it cannot be read, is empty or is not text."""
    with reading(path, error, f"a {kind} file", missing=f"no such {kind} file"):
        data = read_regular_file(path)
    if not data.strip():
        raise error(f"the file is empty (a {kind} file is a JSON object)", path)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise error(f"not a {kind} file: byte {exc.start} is not UTF-8 text", path) from None


# --------------------------------------------------------------------------- settings files
class SettingsFileError(ProjectError):
    """A pose-offsets or chain-settings file (``retarget --pose-offsets`` / ``--chain-settings``)
    that cannot be used (``path``, ``field`` and ``problem`` as for :class:`ProjectError`)."""


def read_pose_offsets(path) -> dict[str, np.ndarray]:
    """The pose offsets of a JSON file ``{"LeftArm": [x, y, z], ...}``: typed angles in degrees
    about each joint's binding-frame axes (intrinsic XYZ, :func:`euler_to_offset`), as unit
    quaternions ``(4,)`` by joint. Raises :class:`SettingsFileError` naming the field."""
    text = _read_text(path, SettingsFileError, "pose-offsets")
    try:
        out = {}
        for joint, value in _obj(_parse(text), "").items():
            where = _sub("", joint)
            if not joint:
                raise _Invalid(where, "expected a target joint's name, not an empty string")
            angles = [_num(x, f"{where}[{i}]") for i, x in enumerate(_list(value, where))]
            if len(angles) != 3:
                raise _Invalid(where, f"expected [x, y, z] angles in degrees, not "
                                      f"{_show(value)}")
            out[joint] = euler_to_offset(angles)
        return out
    except _Invalid as exc:
        raise SettingsFileError(exc.problem, path, exc.field) from None


def read_chain_settings(path, base: BindOptions | None = None) -> dict[str, ChainSettings]:
    """The chain settings of a JSON file ``{"arm_l": {"weight": 0.5, "twist": false,
    "distribute": "first", "ik_blend": 1.0}, ...}`` by chain; a setting a chain leaves out
    keeps ``base``'s (default: the defaults). Raises :class:`SettingsFileError` naming the
    field."""
    text = _read_text(path, SettingsFileError, "chain-settings")
    base = base or BindOptions()
    try:
        data = _obj(_parse(text), "")
        given = dict(_chains(data, ""))
        return {name: dataclasses.replace(base.chain(name), **{
            key: getattr(given[name], key) for key in data[name]}) for name in given}
    except _Invalid as exc:
        raise SettingsFileError(exc.problem, path, exc.field) from None
