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

from dataclasses import dataclass

import numpy as np

__all__ = ["UNITS", "AXES", "SourceFrame", "up_axis_rotation", "detect_units"]

#: metres per file unit. ``cmu`` is the CMU ASF length unit: 1/0.45 inch.
UNITS: dict[str, float] = {
    "m": 1.0,
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
    """

    units: str = "m"
    scale: float = 1.0
    up_axis: str = "+Y"
    detected: bool = False
    reason: str = ""

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


def detect_units(stature: float, *, cmu_names: bool) -> tuple[str, str]:
    """Guess a file's length unit from a human stature measured in that unit.

    Returns ``(units, reason)``. The CMU skeleton's joint names decide between CMU units and
    inches, whose statures overlap; otherwise the ranges are: under 3.5 metres, 15 to 100
    inches, 100 to 300 centimetres, 300 to 3000 millimetres. Outside those the unit is
    unknown and metres are assumed (the user can override).
    """
    s = float(stature)
    shown = f"{s:.4g}"
    if cmu_names and 15.0 <= s < 50.0:
        return "cmu", f"stature {shown} file units with CMU joint names: CMU units"
    if 0.3 <= s < 3.5:
        return "m", f"stature {shown} file units: metres"
    if 15.0 <= s < 100.0:
        return "in", f"stature {shown} file units: inches (a person of {s * 0.0254:.2f} m)"
    if 100.0 <= s < 300.0:
        return "cm", f"stature {shown} file units: centimetres"
    if 300.0 <= s < 3000.0:
        return "mm", f"stature {shown} file units: millimetres"
    return "m", f"stature {shown} file units fits no known unit: metres assumed"


def nearest_axis(vector: np.ndarray) -> str:
    """The signed coordinate axis closest in direction to ``vector``."""
    v = np.asarray(vector, dtype=float)
    k = int(np.argmax(np.abs(v)))
    return ("+" if v[k] >= 0 else "-") + "XYZ"[k]
