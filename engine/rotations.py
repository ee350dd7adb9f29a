"""Euler angles at the edges, quaternions inside.

BVH channels hold Euler angles in degrees with a per-joint axis order; everything else in the
engine works with unit quaternions (x, y, z, w) through :class:`scipy.spatial.transform.Rotation`.
"""
from __future__ import annotations

import warnings

import numpy as np

from .quaternions import from_euler

__all__ = ["euler_to_quat", "quat_to_euler", "identity_quats"]


def identity_quats(shape) -> np.ndarray:
    """Identity quaternions of shape ``shape + (4,)``."""
    q = np.zeros(tuple(np.atleast_1d(shape)) + (4,))
    q[..., 3] = 1.0
    return q


def euler_to_quat(angles_deg: np.ndarray, order: str) -> np.ndarray:
    """Quaternions ``(N, 4)`` from intrinsic Euler angles ``(N, len(order))`` in degrees.

    ``order`` is the channel order, e.g. ``"ZYX"`` for ``Zrotation Yrotation Xrotation``; it
    may have one to three axes. An empty order gives identities.
    """
    angles = np.asarray(angles_deg, dtype=float)
    n = angles.shape[0]
    if not order:
        return identity_quats(n)
    return from_euler(angles.reshape(n, len(order)), order)


def _complete(order: str) -> str:
    """A three-axis intrinsic sequence starting with ``order`` (one or two distinct axes)."""
    rest = [a for a in "XYZ" if a not in order]
    return order + "".join(rest[: 3 - len(order)])


def quat_to_euler(quats: np.ndarray, order: str, *, unwrap: bool = True) -> np.ndarray:
    """Intrinsic Euler angles in degrees ``(F, len(order))`` for quaternions ``(F, 4)``.

    With ``unwrap`` (frames along axis 0) each angle is made continuous over frames by adding
    multiples of 360 degrees, as animators' curve editors expect. For one- and two-axis orders
    the remaining axes are decomposed and dropped; the caller checks they were zero with
    :func:`euler_residual` if that matters.
    """
    from scipy.spatial.transform import Rotation
    quats = np.asarray(quats, dtype=float)
    if not order:
        return np.zeros((quats.shape[0], 0))
    seq = order.upper() if len(order) == 3 else _complete(order.upper())
    with warnings.catch_warnings():
        # at gimbal lock scipy sets the third angle to zero and warns; the angles still
        # give the same rotation, which is all a channel needs
        warnings.simplefilter("ignore", UserWarning)
        angles = Rotation.from_quat(quats).as_euler(seq, degrees=True)
    if len(order) == 2:
        # seq is Tait-Bryan (A, B, C), where (a, b, c) and (a + 180, 180 - b, c + 180) are the
        # same rotation. scipy returns |b| <= 90, so a rotation A(a) B(b) with |b| > 90 comes
        # back with c = +-180: take the other triple, whose dropped angle C is then ~0.
        flip = np.abs(angles[:, 2]) > 90.0
        angles[flip, 0] += 180.0
        angles[flip, 1] = 180.0 - angles[flip, 1]
        angles[:, :2] = (angles[:, :2] + 180.0) % 360.0 - 180.0
    angles = angles[:, : len(order)]
    if unwrap and len(angles) > 1:
        angles = np.unwrap(angles, period=360.0, axis=0)
    return angles


def angle_between(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """The rotation angle in radians between two arrays of quaternions ``(..., 4)``.

    Computed as ``2 atan2(|v|, |w|)`` of ``qa conj(qb)``, accurate for tiny angles too
    (``arccos`` of a dot product loses everything below about 1e-8 rad).
    """
    from .quaternions import qconj, qmul
    d = qmul(np.asarray(qa, dtype=float), qconj(np.asarray(qb, dtype=float)))
    return 2.0 * np.arctan2(np.linalg.norm(d[..., :3], axis=-1), np.abs(d[..., 3]))
