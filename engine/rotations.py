"""Euler angles at the edges, quaternions inside.

BVH channels hold Euler angles in degrees with a per-joint axis order; everything else in the
engine works with unit quaternions (x, y, z, w) through :class:`scipy.spatial.transform.Rotation`.
"""
from __future__ import annotations

import math
import warnings

import numpy as np

from .quaternions import from_euler

__all__ = ["euler_to_quat", "quat_to_euler", "identity_quats", "euler_with_bound"]


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


#: [rad] the bound's constant part (see :func:`euler_with_bound`)
_BOUND_CONSTANT = 2.0 ** -40
#: [rad] the bound's factor on ``1 / hypot`` of a pair (see :func:`euler_with_bound`)
_BOUND_PAIR = 2.0 ** -46
#: scipy's gimbal-lock threshold on the middle angle (0 to pi) [rad]
_GIMBAL = 1e-7


def euler_with_bound(q: np.ndarray, order: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Intrinsic Euler angles in degrees of component quaternions, computed as scipy's
    ``Rotation.from_quat(q).as_euler(order, degrees=True)`` computes them, with numpy, about
    2x faster (``arctan`` in place of the C library's slower ``atan2``, ``sqrt`` in place of
    ``hypot``), and a bound on how far each row's angles may lie from scipy's.

    Args:
        q: ``(4, n)`` quaternions x, y, z, w as component rows.
        order: three distinct axes, ``"ZYX"`` meaning R = Rz Ry Rx (a BVH joint's channels).

    Returns:
        ``angles`` ``(3, n)`` [deg] in ``order``; ``bound`` ``(n,)`` [deg]: no angle of row
        ``r`` is further than ``bound[r]`` from scipy's; ``doubt`` ``(n,)``: rows where the bound
        does not hold, because scipy's result there jumps between two formulas or by a turn
        for a change within the bound (take scipy's values for them).

    The algorithm (scipy's, from Bernardes and Viollet 2022, as its C code does it, for
    Tait-Bryan orders): normalise ``q``; form ``a, b, c, d`` from its components by the axes;
    the middle angle is ``2 atan2(|(c, d)|, |(a, b)|) - pi/2``, the outer ones ``atan2(b, a)
    +- atan2(d, c)`` (the first times the permutation's sign); each is wrapped into
    ``[-pi, pi]`` and turned into degrees. Where the middle angle lies within 1e-7 rad of a
    gimbal lock scipy takes other formulas: those rows are in ``doubt``.

    The bound. The normalisation, ``a, b, c, d``, sums, products and the wrap are the same
    floating-point operations in the same order as scipy's, so they differ from scipy's only
    where its compiler contracts a product and a sum into one rounding: by at most ``eta <=
    8`` units of the last place of 2 (2^-48) in ``a, b, c, d``. What differs is the
    functions: ``atan2``, ``hypot`` (scipy: the C library's, within 1 ulp; numpy's ``arctan``
    within 1 ulp, or 4 where numpy uses SVML) here and there. An angle from ``atan2(y, x)``
    moves by at most ``|d(x, y)| / |(x, y)|`` for a change ``d(x, y)`` of its arguments, so
    with all function and rounding errors of magnitudes up to 2 pi (each within 4 ulp, at
    most 2^-49, a dozen of them: under 2^-45) the angles differ from scipy's by at most
    ``2^-45 + 2 sqrt(2) eta (1 / |(a, b)| + 1 / |(c, d)|)`` rad; the bound returned is
    ``64 (2^-40 + 2^-46 (1 / |(a, b)| + 1 / |(c, d)|))`` degrees, over 30x that in both
    terms (57.3 degrees a radian, and the rounding of the conversion to degrees,
    2^-45 degrees, inside the factor 64). A wrap that one side takes and the other not
    (an angle within the bound of +-pi) and a gimbal case on one side only (the middle
    angle within 2^-40 of its thresholds) are in ``doubt``, as are rows with a zero pair
    (infinite bound) or a non-finite value. ``tests/test_bvh_euler_bound.py`` measures the
    difference on every clip and on adversarial rotations against this bound.
    """
    if len(order) != 3 or len(set(order.upper())) != 3:
        raise ValueError(f"expected three distinct axes, not {order!r}")
    q = np.asarray(q, dtype=float)
    x, y, z, w = q
    norm = np.sqrt(((x * x + y * y) + z * z) + w * w)
    q = q / norm
    i, j, k = ("XYZ".index(axis) for axis in order.upper()[::-1])    # scipy's: reversed
    sign = float((i - j) * (j - k) * (k - i) // 2)
    a = q[3] - q[j]
    b = q[i] + q[k] * sign
    c = q[j] + q[3]
    d = q[k] * sign - q[i]
    with np.errstate(divide="ignore", invalid="ignore"):
        ab = np.sqrt(a * a + b * b)
        cd = np.sqrt(c * c + d * d)
        middle = 2 * _atan2(cd, ab)
        half_sum, half_diff = _atan2(b, a), _atan2(d, c)
        bound = _BOUND_CONSTANT + _BOUND_PAIR * (1.0 / ab + 1.0 / cd)
    doubt = ((middle <= _GIMBAL + _BOUND_CONSTANT)
             | (np.abs(middle - np.pi) <= _GIMBAL + _BOUND_CONSTANT) | ~(bound < 1.0))
    angles = np.empty((3,) + a.shape)
    np.add(half_sum, half_diff, out=angles[0])
    angles[0] *= sign
    np.subtract(middle, np.pi / 2, out=angles[1])
    np.subtract(half_sum, half_diff, out=angles[2])
    for row in angles:
        doubt |= np.abs(np.abs(row) - np.pi) <= bound
        for beyond, turn in ((row < -np.pi, 2 * np.pi), (row > np.pi, -2 * np.pi)):
            if beyond.any():                                 # rare in a clip
                np.add(row, turn, out=row, where=beyond)
    doubt |= ~np.isfinite(angles).all(axis=0)
    return np.rad2deg(angles, out=angles), 64.0 * bound, doubt


def _atan2(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``atan2(y, x)`` within a few ulp: ``arctan(y / x)`` (the quotient is correctly rounded
    and ``arctan`` well conditioned: a relative change ``e`` of its argument moves it by at
    most ``e / 2``), plus pi with the sign of ``y`` where ``x`` is negative (its sign bit, and
    ``y``'s, so that ``atan2(-0, -1)`` is -pi and ``atan2(1, -0)`` is pi/2, as in C). Where
    both are zero it is NaN (the caller's doubt)."""
    r = np.arctan(y / x)
    r += np.copysign(np.pi, y) * np.signbit(x)
    return r


def angle_between(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """The rotation angle in radians between two arrays of quaternions ``(..., 4)``.

    Computed as ``2 atan2(|v|, |w|)`` of ``qa conj(qb)``, accurate for tiny angles too
    (``arccos`` of a dot product loses everything below about 1e-8 rad).
    """
    from .quaternions import qconj, qmul
    d = qmul(np.asarray(qa, dtype=float), qconj(np.asarray(qb, dtype=float)))
    return 2.0 * np.arctan2(np.linalg.norm(d[..., :3], axis=-1), np.abs(d[..., 3]))
