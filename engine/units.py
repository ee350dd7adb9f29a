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

    def points_to_internal(self, points: np.ndarray) -> np.ndarray:
        """File-frame points ``(..., 3)`` in file units to internal metres, +Y up."""
        return (np.asarray(points, dtype=float) @ self.rotation.T) * self.scale

    def points_to_file(self, points: np.ndarray) -> np.ndarray:
        """Internal points ``(..., 3)`` back to the file's axes and units."""
        return (np.asarray(points, dtype=float) / self.scale) @ self.rotation


#: (low, high) metres: the statures a human figure is believed at
HUMAN_STATURE = (0.5, 2.5)
#: the stature [m] a unit is judged by when several put a figure in :data:`HUMAN_STATURE`
_TYPICAL_STATURE = 1.7
#: the units a stature can tell apart (feet are never guessed: a person of 5.6 units is far
#: more often a decimetre file than a file in feet)
_DETECTED = ("m", "dm", "cm", "mm", "in")


def detect_units(stature: float, *, cmu_names: bool,
                 humanoid: bool = True) -> tuple[str, str, str]:
    """Guess a file's length unit from the stature of the figure measured in that unit.

    Returns ``(units, reason, doubt)``. The candidates are metres, decimetres, centimetres,
    millimetres and inches (and CMU units when the CMU skeleton's joint names are there: its
    statures overlap those of inches and decimetres); the unit chosen is the one that puts
    the stature in :data:`HUMAN_STATURE` nearest (by ratio) to 1.7 m. When none does, the
    nearest one is still chosen and ``doubt`` says so (for a ``humanoid``: a stature outside
    the human range; for another figure only when no unit gives 5 cm to 50 m).
    """
    s = float(stature)
    shown = f"{s:.4g}"
    candidates = list(_DETECTED) + (["cmu"] if cmu_names else [])
    low, high = HUMAN_STATURE if humanoid else (0.05, 50.0)

    def distance(unit):
        return abs(math.log(s * UNITS[unit] / _TYPICAL_STATURE)) if s > 0 else math.inf

    fitting = [u for u in candidates if low <= s * UNITS[u] <= high]
    if cmu_names and "cmu" in fitting:
        fitting = ["cmu"]                     # CMU names with a CMU stature: CMU units
    units = min(fitting or candidates, key=distance)
    metres = s * UNITS[units]
    reason = (f"stature {shown} file units" + (" with CMU joint names" if units == "cmu"
                                               else "") + f": {_UNIT_WORDS[units]}")
    if units != "m":
        reason += f" (a {'person' if humanoid else 'figure'} of {metres:.2f} m)"
    doubt = ""
    if not fitting:
        what = "a person" if humanoid else "any figure"
        doubt = (f"a stature of {shown} file units fits no unit for {what} "
                 f"({low:g}-{high:g} m): read as {_UNIT_WORDS[units]} "
                 f"({metres:.3g} m)")
    return units, reason, doubt


_UNIT_WORDS = {"m": "metres", "dm": "decimetres", "cm": "centimetres", "mm": "millimetres",
               "in": "inches", "ft": "feet", "cmu": "CMU units"}


def nearest_axis(vector: np.ndarray) -> str:
    """The signed coordinate axis closest in direction to ``vector``."""
    v = np.asarray(vector, dtype=float)
    k = int(np.argmax(np.abs(v)))
    return ("+" if v[k] >= 0 else "-") + "XYZ"[k]
