"""The binding-pose rotation gizmo: three rings about a target joint's binding-frame axes.

The rings lie around the joint, each in the plane normal to one axis of the joint's *binding
frame* (the bound rest local frame a pose offset is expressed in: the joint's rest world
rotation before its offset). Dragging ring ``k`` by ``angle`` turns the joint about that
frame's axis ``k``: the new offset is ``about_axis(e_k, angle) * offset`` (:func:`turned`),
so the joint's rest world rotation turns about the ring's world axis by ``angle``.

The angle of a drag is read off the ring's plane: the pointer's ray is intersected with it
(:func:`plane_hit`) and the signed angle about the axis from the grabbed point to the hit is
the turn (:func:`turn_angle`, right-handed). A ring seen edge-on has no usable plane hit; the
viewport then projects the pointer's point on the plane facing the camera into the ring's.

Everything here is plain numpy on view-space (or any one right-handed space's) points; the
viewport draws and picks with it.
"""
from __future__ import annotations

import numpy as np

from motion_composer.engine.quaternions import about_axis, qconj, qmul, qrot

__all__ = ["RING_COLORS", "SEGMENTS", "binding_frame", "ring_axes", "ring_basis",
           "ring_points", "ring_point", "turn_angle", "plane_hit", "grazing", "turned",
           "nearest_ring", "with_turn"]

#: ring k's colour: x red, y green, z blue (as the orientation goals' axes)
RING_COLORS = ((1.0, 0.3, 0.3, 1.0), (0.3, 1.0, 0.3, 1.0), (0.35, 0.5, 1.0, 1.0))
#: straight segments per ring
SEGMENTS = 72
#: a ring whose plane the pointer's ray meets at a cosine below this is seen edge-on
GRAZING = 0.2


def binding_frame(rest_world: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """``(4,)`` the world rotation of a joint's binding frame: its rest world rotation
    ``rest_world`` ``(4,)`` (which includes its pose ``offset`` ``(4,)``, applied last) with the
    offset taken off."""
    return qmul(rest_world, qconj(offset))


def ring_axes(frame: np.ndarray) -> np.ndarray:
    """``(3, 3)`` the world directions of a binding frame's (``(4,)``) x, y and z axes, one a
    row: the rings' normals."""
    return qrot(np.broadcast_to(frame, (3, 4)), np.eye(3))


def ring_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``u``, ``w`` spanning the plane normal to unit ``axis`` ``(3,)``, with
    ``u x w = axis`` (so angles from ``u`` towards ``w`` turn right-handed about ``axis``)."""
    axis = np.asarray(axis, dtype=float)
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


def ring_point(center: np.ndarray, axis: np.ndarray, radius: float,
               angle: np.ndarray) -> np.ndarray:
    """``(..., 3)`` the points of the ring (``center`` ``(3,)``, unit ``axis``, ``radius``)
    at ``angle`` [rad] from :func:`ring_basis`'s ``u``, right-handed about ``axis``."""
    u, w = ring_basis(axis)
    a = np.asarray(angle, dtype=float)[..., None]
    return np.asarray(center, dtype=float) + radius * (np.cos(a) * u + np.sin(a) * w)


def ring_points(center: np.ndarray, axis: np.ndarray, radius: float,
                segments: int = SEGMENTS) -> np.ndarray:
    """``(segments + 1, 3)`` the ring as a closed polyline (first point repeated last)."""
    return ring_point(center, axis, radius, np.linspace(0.0, 2 * np.pi, segments + 1))


def turn_angle(center: np.ndarray, axis: np.ndarray, start: np.ndarray,
               now: np.ndarray) -> float:
    """[rad] in (-pi, pi]: the signed turn about unit ``axis`` through ``center`` that takes
    the direction to ``start`` onto the direction to ``now`` (both projected into the plane
    normal to the axis); 0 when either lies on the axis."""
    axis = np.asarray(axis, dtype=float)
    a, b = np.asarray(start, float) - center, np.asarray(now, float) - center
    a, b = a - axis * (a @ axis), b - axis * (b @ axis)
    if np.linalg.norm(a) < 1e-12 or np.linalg.norm(b) < 1e-12:
        return 0.0
    return float(np.arctan2(axis @ np.cross(a, b), a @ b))


def grazing(direction: np.ndarray, axis: np.ndarray) -> bool:
    """Whether a ray along ``direction`` meets the plane normal to unit ``axis`` too
    obliquely to read an angle off it (the ring is seen nearly edge-on)."""
    d = np.asarray(direction, dtype=float)
    return abs(d @ axis) < GRAZING * np.linalg.norm(d)


def plane_hit(origin: np.ndarray, direction: np.ndarray, center: np.ndarray,
              axis: np.ndarray) -> np.ndarray | None:
    """``(3,)`` where the ray ``origin + t direction`` meets the plane through ``center``
    normal to ``axis``, or None when it runs along the plane."""
    d = np.asarray(direction, dtype=float)
    den = d @ axis
    if abs(den) < 1e-12:
        return None
    return origin + ((np.asarray(center, float) - origin) @ axis / den) * d


def nearest_ring(pixels: list[np.ndarray], x: float, y: float,
                 radius: float) -> int | None:
    """The ring whose projected polyline (``pixels[k]``: ``(n, 2)`` pixel points) passes
    nearest to pixel (x, y), within ``radius`` pixels; None when none does."""
    best = None
    p = np.array([x, y], dtype=float)
    for k, line in enumerate(pixels):
        a, b = line[:-1], line[1:]
        ab = b - a
        t = np.clip(np.einsum("ij,ij->i", p - a, ab) /
                    np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12), 0.0, 1.0)
        d = float(np.min(np.linalg.norm(a + t[:, None] * ab - p, axis=1)))
        if d <= radius and (best is None or d < best[0]):
            best = (d, k)
    return None if best is None else best[1]


def turned(offset: np.ndarray, axis: int, angle: float) -> np.ndarray:
    """``(4,)`` the pose offset ``offset`` turned further by ``angle`` [rad] about its binding
    frame's axis ``axis`` (0, 1, 2: x, y, z)."""
    q = qmul(about_axis(np.eye(3)[axis], angle), offset)
    return q / np.linalg.norm(q)


def with_turn(rest_local: np.ndarray, joint: int, old: np.ndarray,
              new: np.ndarray) -> np.ndarray:
    """``(J, 4)`` the rest local rotations ``rest_local`` with joint ``joint``'s pose offset
    ``old`` replaced by ``new`` (``rest_local' = rest_local * offset``): the binding pose a
    drag shows before its edit is made."""
    out = np.array(rest_local, dtype=float)
    out[joint] = qmul(qmul(out[joint], qconj(old)), new)
    return out
