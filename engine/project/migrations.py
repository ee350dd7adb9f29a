"""Format versions: every format change gets a new version and a migrator from the one
before; :func:`migrate` takes an older file's data forward to :data:`~.model.VERSION`."""
from __future__ import annotations

from typing import Callable

from .model import (FORMAT, ROLES, SOLVED_LAYER, VERSION, _Invalid, _checked_version, _kind,
                    _show)

__all__ = ["MIGRATIONS", "migrator", "migrate"]


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
    version = _checked_version(data.get("version"), first=0, newest=VERSION, kind="project",
                               label="format version", verb="open")
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


@migrator(1)
def _v1_to_v2(old: dict) -> dict:
    """Version 1 had no IK settings: its corrections were solved with the constants the
    solver then had built in, which version 2 holds in the ``"ik"`` object."""
    return dict(old, ik=dict(_SOLVER_BEFORE_V2), version=2)


@migrator(2)
def _v2_to_v3(old: dict) -> dict:
    """Version 2 had one displacement map, which a solve replaced whole (hand edits
    included): it becomes version 3's solved layer, and an empty animator layer ("edit") is
    added for the edits a solve keeps."""
    data = {k: v for k, v in old.items() if k not in ("displacement", "embedded")}
    displacement = old.get("displacement", {})
    if not isinstance(displacement, dict):
        raise _Invalid("displacement", f"expected an object with \"channels\", not "
                                       f"{_show(displacement)}")
    data["layers"] = [{"name": SOLVED_LAYER, "kind": "solved", **displacement},
                      {"name": "edit", "kind": "animator", "weight": 1.0, "mute": False,
                       "channels": []}]
    if "embedded" in old:                           # the embedded clips stay last
        data["embedded"] = old["embedded"]
    data["version"] = 3
    return data


@migrator(3)
def _v3_to_v4(old: dict) -> dict:
    """Version 3's ``"floor"`` was only the feet's floor plane: the direct conversion stood
    where the character stands in its reference pose, whatever the floor. Version 4 moves
    the conversion onto the floor (``"stand_on_floor"``); a version-3 project keeps its
    reading, so that it evaluates and solves as it did."""
    return dict(old, stand_on_floor=old.get("floor") is None, version=4)


#: the IK settings built into the solver up to format version 1
_SOLVER_BEFORE_V2 = {"tolerance": 1e-4, "max_iterations": 60, "damping": 0.005,
                     "max_step": 0.05, "attraction": 0.5, "settle": 1e-5,
                     "nullspace_damping": 1e-6, "step_cap": 0.3, "polish_share": 0.25,
                     "priority_gate": 10.0, "joint_limits": []}
