"""Units and up axes: the engine's one internal convention and how files map onto it.

The internal convention (used by every array the engine holds):

* lengths in **metres**;
* **+Y up**, right-handed;
* rotations as unit quaternions in scipy's order **x, y, z, w**.

A file keeps its own convention as a :class:`SourceFrame` (its units and its up axis) so that
the writer restores it on export. ``SourceFrame.to_internal`` is the rotation-and-scale that
takes file coordinates to internal ones; only the root's placement is rotated (offsets of other
joints are expressed in their parent's local frame, which the change of up axis does not touch).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["UNITS", "AXES", "SourceFrame", "up_axis_rotation", "detect_units",
           "HUMAN_STATURE"]

#: metres per file unit. ``cmu`` is the CMU ASF length unit: 1/0.45 inch; ``dm`` is
#: MakeHuman's BVH unit.
UNITS: dict[str, float] = {
    "m": 1.0,
    "dm": 0.1,
    "cm": 0.01,
    "mm": 0.001,
    "in": 0.0254,
    "ft": 0.3048,
    "cmu": 0.0254 / 0.45,
}

AXES = ("+X", "-X", "+Y", "-Y", "+Z", "-Z")

# Rotation matrices taking a file whose up axis is the key onto +Y up, each the smallest turn
# that does it (Z-up goes (x, y, z) -> (x, z, -y), as Blender and the glTF exporters do).
_TO_Y_UP = {
    "+Y": np.eye(3),
    "-Y": np.diag([1.0, -1.0, -1.0]),
    "+Z": np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]),
    "-Z": np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]),
    "+X": np.array([[0, -1.0, 0], [1.0, 0, 0], [0, 0, 1.0]]),
    "-X": np.array([[0, 1.0, 0], [-1.0, 0, 0], [0, 0, 1.0]]),
}


def up_axis_rotation(up_axis: str) -> np.ndarray:
    """The 3x3 rotation that takes vectors of a file with ``up_axis`` up onto +Y up."""
    try:
        return _TO_Y_UP[up_axis].copy()
    except KeyError:
        raise ValueError(f"up axis must be one of {', '.join(AXES)}, not {up_axis!r}") from None


@dataclass(frozen=True)
class SourceFrame:
    """A file's own units and up axis, and how they were decided.

    Attributes:
        units: a key of :data:`UNITS`, or ``"custom"`` with an explicit ``scale``.
        scale: metres per file unit.
        up_axis: one of :data:`AXES`.
        detected: ``True`` when units and up axis were inferred rather than given.
        reason: one sentence saying how they were decided (shown by ``info``).
        doubt: one sentence when a detected figure is not to be trusted (a human stature
            outside :data:`HUMAN_STATURE`, no unit that fits, an up axis the body does not
            show), else ``""``. Readers never print it: the caller shows it as one warning
            line naming the override (:attr:`overrides`).
        overrides: the overrides that would settle the doubt, as ``(option, suggested
            value)`` pairs: ``("units", "cm")``, ``("up_axis", "+Z")``; the value is ``""``
            when there is no suggestion.
    """

    units: str = "m"
    scale: float = 1.0
    up_axis: str = "+Y"
    detected: bool = False
    reason: str = ""
    doubt: str = ""
    overrides: tuple[tuple[str, str], ...] = ()

    @property
    def rotation(self) -> np.ndarray:
        """3x3 rotation from file axes to internal axes (+Y up)."""
        return up_axis_rotation(self.up_axis)

    def warning(self, path, flag_prefix: str) -> str:
        """The doubt as one line naming the file and the overrides that settle it, as
        command-line flags (``flag_prefix``: ``"--performer-"``, ``"--target-"``, ``"--"``):
        ``"clip.bvh: a stature of ...; if that is wrong, give --performer-units UNIT"``;
        the doubt alone where no override settles it; ``""`` without a doubt."""
        if not self.doubt:
            return ""
        if not self.overrides:              # nothing to give: the file is to be written again
            return f"{path}: {' '.join(self.doubt.split())}"
        shown = {"units": "UNIT", "up_axis": "AXIS"}
        flags = " or ".join(f"{flag_prefix}{option.replace('_', '-')} {value or shown[option]}"
                            for option, value in self.overrides)
        return f"{path}: {' '.join(self.doubt.split())}; if that is wrong, give {flags}"

    def points_to_internal(self, points: np.ndarray) -> np.ndarray:
        """File-frame points ``(..., 3)`` in file units to internal metres, +Y up."""
        return (np.asarray(points, dtype=float) @ self.rotation.T) * self.scale

    def points_to_file(self, points: np.ndarray) -> np.ndarray:
        """Internal points ``(..., 3)`` back to the file's axes and units."""
        return (np.asarray(points, dtype=float) / self.scale) @ self.rotation


#: (low, high) metres: the statures a human figure is believed at
HUMAN_STATURE = (0.5, 2.5)
#: the stature [m] a unit is judged by when several put a figure in :data:`HUMAN_STATURE`:
#: 1.7 m, but 1.4 m for CMU units (the CMU database's adults measure 1.3-1.5 m in them)
_TYPICAL_STATURE = {"cmu": 1.4}
#: the units a stature can tell apart (feet are never guessed: a person of 5.6 units is far
#: more often a decimetre file than a file in feet)
_DETECTED = ("m", "dm", "cm", "mm", "in")


def detect_units(stature: float, *, cmu_names: bool,
                 humanoid: bool = True) -> tuple[str, str, str, str]:
    """Guess a file's length unit from the stature of the figure measured in that unit.

    Returns ``(units, reason, doubt, other)``. The candidates are metres, decimetres,
    centimetres, millimetres and inches (and CMU units when the CMU skeleton's joint names are
    there: its statures overlap those of inches and decimetres); the unit chosen is the one
    that puts the stature in :data:`HUMAN_STATURE` nearest (by ratio) to a typical stature
    (1.7 m; 1.4 m for CMU units, so that a MakeHuman export of the CMU skeleton in
    decimetres, 17 units, is told from a CMU file, 22 to 27 units).

    ``doubt`` (else ``""``) says when the unit is not to be trusted: no unit puts the stature
    in the range (the nearest is still chosen; for a figure that is not a ``humanoid`` the
    range is 5 cm to 50 m), or a second unit other than CMU units fits nearly as well (within
    a ratio of 1.5 of the first: a child of 97 cm, or a giant of 2.46 m in inches), which is
    then ``other``, the override to suggest (else ``""``).
    """
    s = float(stature)
    shown = f"{s:.4g}"
    candidates = list(_DETECTED) + (["cmu"] if cmu_names else [])
    low, high = HUMAN_STATURE if humanoid else (0.05, 50.0)

    def distance(unit):
        typical = _TYPICAL_STATURE.get(unit, 1.7)
        return abs(math.log(s * UNITS[unit] / typical)) if s > 0 else math.inf

    fitting = sorted((u for u in candidates if low <= s * UNITS[u] <= high), key=distance)
    units = fitting[0] if fitting else min(candidates, key=distance)
    metres = s * UNITS[units]
    figure = "person" if humanoid else "figure"
    reason = (f"stature {shown} file units" + (" with CMU joint names" if units == "cmu"
                                               else "") + f": {_UNIT_WORDS[units]}")
    if units != "m":
        reason += f" (a {figure} of {metres:.2f} m)"
    doubt, other = "", ""
    if not fitting:
        what = "a person" if humanoid else "any figure"
        doubt = (f"a stature of {shown} file units fits no unit for {what} "
                 f"({low:g}-{high:g} m): read as {_UNIT_WORDS[units]} ({metres:.3g} m)")
    elif (len(fitting) > 1 and "cmu" not in fitting[:2] and
          distance(fitting[1]) - distance(fitting[0]) < _AMBIGUOUS):
        other = fitting[1]
        doubt = (f"a stature of {shown} file units is a {figure} of {metres:.2f} m in "
                 f"{_UNIT_WORDS[units]} or of {s * UNITS[other]:.2f} m in "
                 f"{_UNIT_WORDS[other]}: read as {_UNIT_WORDS[units]}")
    return units, reason, doubt, other


#: two units both fit a stature ambiguously when their ratios to the typical stature differ
#: by less than this (natural log of 1.5)
_AMBIGUOUS = math.log(1.5)

_UNIT_WORDS = {"m": "metres", "dm": "decimetres", "cm": "centimetres", "mm": "millimetres",
               "in": "inches", "ft": "feet", "cmu": "CMU units"}


def nearest_axis(vector: np.ndarray) -> str:
    """The signed coordinate axis closest in direction to ``vector``."""
    v = np.asarray(vector, dtype=float)
    k = int(np.argmax(np.abs(v)))
    return ("+" if v[k] >= 0 else "-") + "XYZ"[k]
