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

from ..conversion.binding import BindOptions
from ..conversion.converter import RootOptions
from ..conversion.correspondence import Correspondence
from ..correction.contacts import ContactOptions
from ..correction.ik import IKOptions
from ..fileio import atomic_write, read_regular_file, reading
from .json import (_contacts, _correspondence, _encode, _ik, _obj, _parse, _root, _binding,
                   binding_dict, ik_dict)
from .model import Project, ProjectError, _Invalid, _show

__all__ = ["Profile", "ProfileError", "profile_of", "apply_profile", "save_profile",
           "read_profile", "profile_to_json", "profile_from_json", "PROFILE_FORMAT",
           "PROFILE_VERSION", "PROFILE_SUFFIX"]

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
        version = data["version"]
        if isinstance(version, bool) or not isinstance(version, int) or version < 1:
            raise _Invalid("version", f"expected a format version (a whole number from 1), "
                                      f"not {_show(version)}")
        if version > PROFILE_VERSION:
            raise _Invalid("version", f"this profile was written by a newer Motion Composer "
                                      f"(profile version {version}; this one reads up to "
                                      f"{PROFILE_VERSION}); update Motion Composer to use it")
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
    with reading(path, ProfileError, "a profile file", missing="no such profile file"):
        data = read_regular_file(path)
    if not data.strip():
        raise ProfileError("the file is empty (a profile is a JSON object)", path)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ProfileError(f"not a profile file: byte {exc.start} is not UTF-8 text",
                           path) from None
    return profile_from_json(text, path)
