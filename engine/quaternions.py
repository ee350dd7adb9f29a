"""Vectorised quaternion products, the hot path of kinematics.

scipy's :class:`~scipy.spatial.transform.Rotation` is the reference and is used wherever speed
does not matter, but on this machine composing 100,000 rotations with it costs about 50 ms
and ``from_euler`` about 200 ms, against 2 to 4 ms for the numpy below; forward kinematics and
BVH reading run these once per joint per call. The test suite checks every function here
against scipy value by value.

All quaternions are x, y, z, w (scipy's order), shape ``(..., 4)``. The hot paths (forward
kinematics, the Motion Converter and Composer) hold them as *component arrays* instead, shape
``(4, ...)`` with one contiguous row per component (and vectors as ``(3, ...)``): numpy's loops
then read and write contiguous memory, where the components of interleaved ``(..., 4)``
arrays are strided views (``cmul`` and friends below: on 2752 x 31 rotations about three
times faster than :func:`qmul`). :func:`cmul` and :func:`crot` give :func:`qmul`'s and
:func:`qrot`'s values bit for bit (the same arithmetic in the same order); the others agree
to rounding. The interleaved functions stay the general ones: on a few quaternions, turning
them into component arrays and back costs more than it saves.
"""
from __future__ import annotations

import numpy as np

__all__ = ["qmul", "qconj", "qrot", "from_euler", "axis_angle", "qnormalize", "quat_between",
           "twist_about", "qpow", "about_axis", "qpow_many", "qslerp", "to_matrix",
           "from_matrix", "from_rotvec", "components", "interleaved", "cmul", "cconj", "crot",
           "cquat_between", "ctwist_about", "cfrom_euler", "cto_matrix", "qmul_small",
           "cmul_small", "crot_small"]


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` (apply ``b`` first, then ``a``), broadcasting."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = aw * bx + ax * bw + ay * bz - az * by
    out[..., 1] = aw * by - ax * bz + ay * bw + az * bx
    out[..., 2] = aw * bz + ax * by - ay * bx + az * bw
    out[..., 3] = aw * bw - ax * bx - ay * by - az * bz
    return out


#: per output component of a quaternion product ``a * b`` (x, y, z, w), the component of
#: ``b`` that ``a``'s x, y and z multiply (rows), and its sign (the small-batch forms
#: :func:`qmul_small` and :func:`cmul_small`)
_MUL_INDEX = np.array([[3, 2, 1, 0], [2, 3, 0, 1], [1, 0, 3, 2]])
_MUL_SIGN = np.array([[1.0, -1.0, 1.0, -1.0], [1.0, 1.0, -1.0, -1.0], [-1.0, 1.0, 1.0, -1.0]])
_MUL_INDEX.setflags(write=False)
_MUL_SIGN.setflags(write=False)
#: the components ``[1, 2, 0]`` and ``[2, 0, 1]`` of a vector part (``_ROT_U``) and the
#: ones they multiply in a cross product ``u x v`` (``_ROT_V``), for :func:`crot_small`
_ROT_U = np.array([[1, 2, 0], [2, 0, 1]])
_ROT_V = np.array([[2, 0, 1], [1, 2, 0]])
_ROT_U.setflags(write=False)
_ROT_V.setflags(write=False)


def qmul_small(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`qmul` of float quaternions ``a, b (..., 4)`` (broadcasting), bit for bit: the
    same products, signs and sums in the same order (a subtracted product is added negated,
    which is exact), in a few calls on whole arrays instead of one per component. For small
    batches (an IK step's few hundred quaternions), where :func:`qmul` costs its calls, not
    its arithmetic; on large ones its temporaries make it the slower."""
    p = a[..., :3, None] * (b[..., _MUL_INDEX] * _MUL_SIGN)
    out = a[..., 3:4] * b
    out += p[..., 0, :]
    out += p[..., 1, :]
    out += p[..., 2, :]
    return out


def qconj(q: np.ndarray) -> np.ndarray:
    """The conjugate (the inverse of a unit quaternion)."""
    out = np.array(q, dtype=float, copy=True)
    out[..., :3] *= -1.0
    return out


def qrot(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v (..., 3)`` by unit quaternions ``q (..., 4)``, broadcasting.

    Uses v' = v + w t + u x t with t = 2 u x v (u the vector part, w the scalar part).
    """
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    ux, uy, uz, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    vx, vy, vz = v[..., 0], v[..., 1], v[..., 2]
    tx = 2.0 * (uy * vz - uz * vy)
    ty = 2.0 * (uz * vx - ux * vz)
    tz = 2.0 * (ux * vy - uy * vx)
    out = np.empty(np.broadcast_shapes(q.shape[:-1], v.shape[:-1]) + (3,))
    out[..., 0] = vx + w * tx + (uy * tz - uz * ty)
    out[..., 1] = vy + w * ty + (uz * tx - ux * tz)
    out[..., 2] = vz + w * tz + (ux * ty - uy * tx)
    return out


def axis_angle(axis: int, angles: np.ndarray) -> np.ndarray:
    """Quaternions for rotations of ``angles`` radians about coordinate ``axis`` (0, 1, 2)."""
    half = 0.5 * np.asarray(angles, dtype=float)
    q = np.zeros(half.shape + (4,))
    q[..., axis] = np.sin(half)
    q[..., 3] = np.cos(half)
    return q


#: rows per step of :func:`from_euler`: a step's temporaries (about 64 kB each) stay in the
#: cache and in the allocator's free lists. Whole-array temporaries of a large clip (0.9 MB
#: each for 112,000 rows) are fresh pages from the system on every call, and on the machines
#: measured their page faults cost as much as the arithmetic (benchmarks/README.md).
_EULER_ROWS = 8192


def from_euler(angles_deg: np.ndarray, order: str) -> np.ndarray:
    """Quaternions for intrinsic Euler angles ``(..., len(order))`` in degrees.

    ``order`` like ``"ZYX"`` means R = Rz Ry Rx (BVH's and scipy's upper-case reading).

    This equals ``qmul(qmul(axis_angle(a0, t0), axis_angle(a1, t1)), axis_angle(a2, t2))`` value
    for value (up to the sign of zeros), but multiplies by each elementary rotation with the
    two terms per component that are not zero (:func:`_mul_axis`), on separate contiguous
    component arrays, a block of rows at a time (:data:`_EULER_ROWS`).
    """
    angles = np.asarray(angles_deg, dtype=float)
    axes = ["XYZ".index(a.upper()) for a in order]
    rows = angles.reshape(-1, angles.shape[-1])
    out = np.empty((len(rows), 4))
    for start in range(0, len(rows), _EULER_ROWS):
        block = slice(start, start + _EULER_ROWS)
        out[block] = _euler_rows(rows[block], axes)
    return out.reshape(angles.shape[:-1] + (4,))


def _euler_rows(angles_deg: np.ndarray, axes: list[int]) -> np.ndarray:
    """:func:`from_euler` for ``(n, >= len(axes))`` angles, axes as indices 0, 1, 2."""
    half = 0.5 * np.radians(angles_deg[:, :len(axes)])
    # one contiguous row per angle, so that sin and cos take numpy's contiguous loops
    half = half.T.copy()
    sin, cos = np.sin(half), np.cos(half)
    zero = np.zeros(half.shape[1])
    q = [zero, zero, zero, cos[0]]                     # components x, y, z, w
    q[axes[0]] = sin[0]
    for k in range(1, len(axes)):
        q = _mul_axis(q, axes[k], sin[k], cos[k])
    return np.stack(q, axis=-1)


def _mul_axis(a: list, axis: int, s: np.ndarray, c: np.ndarray,
              out: np.ndarray | None = None) -> list:
    """Components of ``a * (s e_axis + c)``: ``a`` times a rotation about a coordinate axis.

    ``a`` and the result are lists of the four component arrays x, y, z, w (or, with ``out``,
    the result goes into the rows of ``out`` ``(4, ...)``, which must not overlap ``a``, and is
    ``out``). With ``k`` the axis and ``i, j`` the next two in cyclic order, the Hamilton
    product keeps two terms per component; each equals :func:`qmul`'s result exactly, since
    the terms dropped are zeros.
    """
    k, i, j = axis, (axis + 1) % 3, (axis + 2) % 3
    if out is None:
        out = [None] * 4
        out[k] = a[3] * s + a[k] * c
        out[i] = a[i] * c + a[j] * s
        out[j] = a[j] * c - a[i] * s
        out[3] = a[3] * c - a[k] * s
        return out
    t = np.empty(np.shape(s))
    for r, (p, u), (m, v), sign in ((k, (3, s), (k, c), 1), (i, (i, c), (j, s), 1),
                                    (j, (j, c), (i, s), -1), (3, (3, c), (k, s), -1)):
        np.multiply(a[p], u, out=out[r])
        np.multiply(a[m], v, out=t)
        if sign > 0:
            out[r] += t
        else:
            out[r] -= t
    return out


def qnormalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (``q / |q|``)."""
    q = np.asarray(q, dtype=float)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking direction ``a`` onto direction ``b`` (``(..., 3)`` each,
    any length). Opposite directions turn 180 degrees about an axis normal to ``a``."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    a, b = np.broadcast_arrays(a, b)
    # q = (a x b, |a||b| + a.b), normalised: the half-way rotation without normalising a, b
    q = np.empty(a.shape[:-1] + (4,))
    q[..., :3] = np.cross(a, b)
    lengths = np.sqrt(np.einsum("...i,...i->...", a, a) * np.einsum("...i,...i->...", b, b))
    q[..., 3] = lengths + np.einsum("...i,...i->...", a, b)
    opposite = q[..., 3] < 1e-9 * np.maximum(lengths, 1e-300)
    if np.any(opposite):
        aa = a[opposite]
        # any axis normal to a: cross with the coordinate axis least aligned with it
        pick = np.eye(3)[np.argmin(np.abs(aa), axis=-1)]
        axis = np.cross(aa, pick)
        q[opposite, :3] = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
        q[opposite, 3] = 0.0
    return q / np.sqrt(np.einsum("...i,...i->...", q, q))[..., None]


def twist_about(q: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The twist part of ``q`` about unit ``axis`` (swing-twist decomposition q = swing twist,
    twist about ``axis``). Where q is a half turn normal to the axis, the twist is identity."""
    q = np.asarray(q, dtype=float)
    axis = np.asarray(axis, dtype=float)
    along = np.sum(q[..., :3] * axis, axis=-1, keepdims=True)
    t = np.concatenate([along * axis, q[..., 3:4]], axis=-1)
    t = np.broadcast_to(t, np.broadcast_shapes(t.shape, q.shape)).copy()
    norm = np.linalg.norm(t, axis=-1, keepdims=True)
    small = norm[..., 0] < 1e-12
    t[small] = (0.0, 0.0, 0.0, 1.0)
    norm[small] = 1.0
    return t / norm


def qpow(q: np.ndarray, fraction: float) -> np.ndarray:
    """``q`` raised to ``fraction``: the same axis, ``fraction`` of the (shortest) angle."""
    q = np.asarray(q, dtype=float)
    q = np.where(q[..., 3:4] < 0, -q, q)
    vec = q[..., :3]
    s = np.linalg.norm(vec, axis=-1)
    angle = 2.0 * np.arctan2(s, q[..., 3])
    safe = np.where(s > 1e-12, s, 1.0)
    axis = vec / safe[..., None]
    half = 0.5 * fraction * angle
    out = np.empty(q.shape)
    out[..., :3] = axis * np.sin(half)[..., None]
    out[..., 3] = np.cos(half)
    out[s <= 1e-12] = (0.0, 0.0, 0.0, 1.0)
    return out


def qslerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Shortest-path spherical interpolation from unit ``q0`` to unit ``q1`` (``(..., 4)``) at
    fractions ``u`` (``(...)``, broadcasting): ``q0`` at 0, ``q1`` (or ``-q1``) at 1, at a
    constant angular rate between. Nearly equal pairs interpolate linearly, renormalised."""
    q0 = np.asarray(q0, dtype=float)
    q1 = np.asarray(q1, dtype=float)
    u = np.asarray(u, dtype=float)[..., None]
    d = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(d < 0, -q1, q1)
    d = np.minimum(np.abs(d), 1.0)
    near = d > 0.9995
    theta = np.arccos(d)
    sin = np.where(near, 1.0, np.sin(theta))
    a = np.where(near, 1.0 - u, np.sin((1.0 - u) * theta) / sin)
    b = np.where(near, u, np.sin(u * theta) / sin)
    out = a * q0 + b * q1
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def about_axis(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotations of ``angle`` radians about unit ``axis`` (``(..., 3)``), broadcasting."""
    axis = np.asarray(axis, dtype=float)
    half = 0.5 * np.asarray(angle, dtype=float)
    out = np.empty(np.broadcast_shapes(axis.shape[:-1], half.shape) + (4,))
    out[..., :3] = axis * np.sin(half)[..., None]
    out[..., 3] = np.cos(half)
    return out


def qpow_many(q: np.ndarray, fractions: np.ndarray) -> np.ndarray:
    """``q`` ``(..., 4)`` raised to each of ``fractions`` ``(n,)``: ``(n, ..., 4)``."""
    q = np.asarray(q, dtype=float)
    q = np.where(q[..., 3:4] < 0, -q, q)
    vec = q[..., :3]
    s = np.linalg.norm(vec, axis=-1)
    angle = 2.0 * np.arctan2(s, q[..., 3])
    axis = vec / np.where(s > 1e-12, s, 1.0)[..., None]
    f = np.asarray(fractions, dtype=float).reshape((-1,) + (1,) * angle.ndim)
    half = 0.5 * f * angle
    out = np.empty(half.shape + (4,))
    out[..., :3] = axis * np.sin(half)[..., None]
    out[..., 3] = np.cos(half)
    return out


def to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions ``(..., 4)``."""
    return cto_matrix(np.moveaxis(np.asarray(q, dtype=float), -1, 0))


def cto_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions as component arrays
    ``(4, ...)`` (:func:`components`)."""
    x, y, z, w = q
    # each product once (the same values as taken twice)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, xw, yw, zw = x * y, x * z, y * z, x * w, y * w, z * w
    out = np.empty(q.shape[1:] + (3, 3))
    out[..., 0, 0] = 1 - 2 * (yy + zz)
    out[..., 0, 1] = 2 * (xy - zw)
    out[..., 0, 2] = 2 * (xz + yw)
    out[..., 1, 0] = 2 * (xy + zw)
    out[..., 1, 1] = 1 - 2 * (xx + zz)
    out[..., 1, 2] = 2 * (yz - xw)
    out[..., 2, 0] = 2 * (xz - yw)
    out[..., 2, 1] = 2 * (yz + xw)
    out[..., 2, 2] = 1 - 2 * (xx + yy)
    return out


def from_matrix(m: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` of rotation matrices ``(..., 3, 3)`` (Shepperd's method:
    the decomposition led by the largest of the trace and the diagonal, as scipy's
    ``Rotation.from_matrix`` does for orthonormal matrices, without importing scipy)."""
    m = np.asarray(m, dtype=float)
    lead = np.concatenate([np.diagonal(m, axis1=-2, axis2=-1),
                           np.trace(m, axis1=-2, axis2=-1)[..., None]], axis=-1)
    choice = np.argmax(lead, axis=-1)
    trace = lead[..., 3]
    q = np.empty(m.shape[:-2] + (4,))
    on_trace = choice == 3
    q[..., 0] = np.where(on_trace, m[..., 2, 1] - m[..., 1, 2], 0.0)
    q[..., 1] = np.where(on_trace, m[..., 0, 2] - m[..., 2, 0], 0.0)
    q[..., 2] = np.where(on_trace, m[..., 1, 0] - m[..., 0, 1], 0.0)
    q[..., 3] = np.where(on_trace, 1.0 + trace, 0.0)
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        here = choice == i
        if not np.any(here):
            continue
        q[here, i] = 1.0 - trace[here] + 2.0 * m[here, i, i]
        q[here, j] = m[here, j, i] + m[here, i, j]
        q[here, k] = m[here, k, i] + m[here, i, k]
        q[here, 3] = m[here, k, j] - m[here, j, k]
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def from_rotvec(v: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` of rotation vectors ``(..., 3)`` [rad] (the exponential
    map; a series near zero, as scipy's ``Rotation.from_rotvec``)."""
    v = np.asarray(v, dtype=float)
    angle = np.linalg.norm(v, axis=-1)
    small = angle <= 1e-3
    safe = np.where(small, 1.0, angle)
    scale = np.where(small, 0.5 - angle ** 2 / 48 + angle ** 4 / 3840, np.sin(angle / 2) / safe)
    out = np.empty(v.shape[:-1] + (4,))
    out[..., :3] = v * scale[..., None]
    out[..., 3] = np.cos(angle / 2)
    return out


# --------------------------------------------------------------------------- component arrays
def components(q: np.ndarray) -> np.ndarray:
    """``(n, ...)`` component rows of ``(..., n)`` quaternions (n = 4) or vectors (n = 3), each
    row contiguous (a copy).

    The functions below broadcast the rows against each other (``a[k]`` with ``b[k]``), so
    ``(4, 7)`` and ``(4, 500, 7)`` combine as ``(7, 4)`` and ``(500, 7, 4)`` do; numpy's own
    broadcasting of whole component arrays would not."""
    q = np.asarray(q, dtype=float)
    return np.ascontiguousarray(np.moveaxis(q, -1, 0))


def interleaved(c: np.ndarray) -> np.ndarray:
    """``(..., n)`` C-contiguous quaternions or vectors from component rows ``(n, ...)``."""
    return np.ascontiguousarray(np.moveaxis(c, 0, -1))


def _rows(n: int, shape: tuple, out: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """``out`` (a new ``(n, *shape)`` array if None) and a view of it whose rows are arrays,
    ``(n, 1)`` for a single quaternion or vector, as ``out=`` arguments need."""
    out = np.empty((n,) + shape) if out is None else out
    return out, (out if shape else out[:, None])


def cmul(a: np.ndarray, b: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """:func:`qmul` on component arrays: ``a (4, ...) * b (4, ...)``, broadcasting, into ``out``
    (``(4, ...)``, not overlapping ``a`` or ``b``) when given. One temporary, no strided
    loops."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    shape = np.broadcast_shapes(np.shape(ax), np.shape(bx))
    out, rows = _rows(4, shape, out)
    x, y, z, w = rows
    t = np.empty(x.shape)
    np.multiply(aw, bx, out=x)
    x += np.multiply(ax, bw, out=t)
    x += np.multiply(ay, bz, out=t)
    x -= np.multiply(az, by, out=t)
    np.multiply(aw, by, out=y)
    y -= np.multiply(ax, bz, out=t)
    y += np.multiply(ay, bw, out=t)
    y += np.multiply(az, bx, out=t)
    np.multiply(aw, bz, out=z)
    z += np.multiply(ax, by, out=t)
    z -= np.multiply(ay, bx, out=t)
    z += np.multiply(az, bw, out=t)
    np.multiply(aw, bw, out=w)
    w -= np.multiply(ax, bx, out=t)
    w -= np.multiply(ay, by, out=t)
    w -= np.multiply(az, bz, out=t)
    return out


def cmul_small(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`cmul` of float component arrays ``a, b (4, ...)`` (broadcasting), bit for bit
    (the same products, signs and sums in the same order, as :func:`qmul_small`), in a few
    calls on whole arrays instead of sixteen on rows: for small batches (the solver's forward
    kinematics of a few joints and frames, where the calls cost more than the arithmetic).
    ``cmul`` stays the form for large arrays (one temporary, no gathers)."""
    p = a[:3, None] * (b[_MUL_INDEX] * _MUL_SIGN.reshape(_MUL_SIGN.shape + (1,) * (b.ndim - 1)))
    out = a[3] * b
    out += p[0]
    out += p[1]
    out += p[2]
    return out


def cfrom_euler(angles_deg: np.ndarray, order: str, out: np.ndarray | None = None
                ) -> np.ndarray:
    """:func:`from_euler` on component arrays: angles ``(len(order), ...)`` in degrees, one
    row per axis of ``order``, to rotations ``(4, ...)`` (into ``out`` when given, not
    overlapping the angles), bit for bit :func:`from_euler`'s values (the same arithmetic
    in the same order, the sign of zeros included)."""
    axes = ["XYZ".index(a.upper()) for a in order]
    half = np.radians(angles_deg, out=np.empty(np.shape(angles_deg)))     # C-contiguous rows
    half *= 0.5
    sin, cos = np.sin(half), np.cos(half)
    shape = half.shape[1:]
    out = np.empty((4,) + shape) if out is None else out
    if len(axes) == 1:
        out[:] = 0.0
        out[axes[0]] = sin[0]
        out[3] = cos[0]
        return out
    zero = np.zeros(shape)
    q = [zero, zero, zero, cos[0]]                     # components x, y, z, w
    q[axes[0]] = sin[0]
    for k in range(1, len(axes)):
        q = _mul_axis(q, axes[k], sin[k], cos[k], out if k == len(axes) - 1 else None)
    return out


def cconj(q: np.ndarray) -> np.ndarray:
    """:func:`qconj` on a component array ``(4, ...)``."""
    out = np.negative(q)
    out[3] = q[3]
    return out


def crot(q: np.ndarray, v: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """:func:`qrot` on component arrays: ``q (4, ...)`` rotating ``v (3, ...)``, broadcasting,
    into ``out`` (``(3, ...)``, not overlapping the inputs) when given."""
    ux, uy, uz, w = q
    vx, vy, vz = v
    shape = np.broadcast_shapes(np.shape(ux), np.shape(vx))
    out, rows = _rows(3, shape, out)
    t = np.empty(rows.shape)
    tx, ty, tz = t
    s = np.empty(tx.shape)
    # t = 2 u x v
    np.multiply(uy, vz, out=tx)
    tx -= np.multiply(uz, vy, out=s)
    tx *= 2.0
    np.multiply(uz, vx, out=ty)
    ty -= np.multiply(ux, vz, out=s)
    ty *= 2.0
    np.multiply(ux, vy, out=tz)
    tz -= np.multiply(uy, vx, out=s)
    tz *= 2.0
    # v + w t + u x t, summed left to right as (v + w t) + (u x t)
    for k, (c, (ui, ti), (uj, tj)) in enumerate([(vx, (uy, tz), (uz, ty)),
                                                (vy, (uz, tx), (ux, tz)),
                                                (vz, (ux, ty), (uy, tx))]):
        o = rows[k]
        np.multiply(w, t[k], out=o)
        np.add(c, o, out=o)
        cross = np.multiply(ui, ti)
        cross -= np.multiply(uj, tj, out=s)
        o += cross
    return out


def crot_small(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """:func:`crot` of float component arrays: ``q (4, ...)`` rotating ``v (3, ...)``
    (broadcasting), bit for bit (the same arithmetic in the same order), in a few calls on
    whole arrays instead of one per component: for small batches, as :func:`cmul_small`."""
    u = q[_ROT_U]                       # (2, 3, ...): u's components turned once, twice
    p = u * v[_ROT_V]
    t = p[0] - p[1]                     # t = 2 u x v
    t *= 2.0
    out = q[3] * t
    out += v                            # (v + w t) + (u x t), as crot sums them
    p = u * t[_ROT_V]
    out += p[0] - p[1]
    return out


def _cdot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot products of component arrays ``(n, ...)``, summed in component order (as numpy's
    ``sum`` and ``linalg.norm`` sum a short last axis)."""
    out = a[0] * b[0]
    for k in range(1, len(a)):
        out += a[k] * b[k]
    return out


def _einsum_dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot products of component arrays ``(3, ...)`` or ``(4, ...)`` summed as numpy's
    ``einsum("...i,...i->...")`` sums contiguous rows of three or four (components 0 and 2
    first, then 1 and 3: its two-lane kernel), so that :func:`cquat_between` gives
    :func:`quat_between`'s values bit for bit."""
    out = a[0] * b[0]
    out += a[2] * b[2]
    if len(a) == 3:
        out += a[1] * b[1]
        return out
    odd = a[1] * b[1]
    odd += a[3] * b[3]
    out += odd
    return out


def cquat_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`quat_between` on component arrays: directions ``a``, ``b`` ``(3, ...)`` (any
    length, broadcasting), rotations ``(4, ...)``."""
    ax, ay, az = a
    bx, by, bz = b
    shape = np.broadcast_shapes(ax.shape, bx.shape)
    # q = (a x b, |a||b| + a.b), normalised: the half-way rotation without normalising a, b
    q = np.empty((4,) + shape)
    np.subtract(ay * bz, az * by, out=q[0])
    np.subtract(az * bx, ax * bz, out=q[1])
    np.subtract(ax * by, ay * bx, out=q[2])
    lengths = np.sqrt(np.broadcast_to(_einsum_dot(a, a) * _einsum_dot(b, b), shape))
    np.add(lengths, _einsum_dot(a, b), out=q[3])
    opposite = q[3] < 1e-9 * np.maximum(lengths, 1e-300)
    if np.any(opposite):
        aa = np.stack([np.broadcast_to(c, shape)[opposite] for c in a], axis=-1)
        # any axis normal to a: cross with the coordinate axis least aligned with it
        pick = np.eye(3)[np.argmin(np.abs(aa), axis=-1)]
        axis = np.cross(aa, pick)
        q[:3, opposite] = (axis / np.linalg.norm(axis, axis=-1, keepdims=True)).T
        q[3, opposite] = 0.0
    q /= np.sqrt(_einsum_dot(q, q))
    return q


def ctwist_about(q: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """:func:`twist_about` on component arrays: ``q (4, ...)`` about unit ``axis (3, ...)``."""
    along = _cdot(q[:3], axis)
    shape = np.broadcast_shapes(along.shape, q.shape[1:])
    t = np.empty((4,) + shape)
    for k in range(3):
        np.multiply(along, axis[k], out=t[k])
    t[3] = q[3]
    norm = np.sqrt(_cdot(t, t))
    small = norm < 1e-12
    if np.any(small):
        t[:, small] = np.array([0.0, 0.0, 0.0, 1.0])[:, None]
        norm[small] = 1.0
    t /= norm
    return t
