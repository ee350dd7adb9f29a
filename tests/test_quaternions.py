"""engine.quaternions against scipy's Rotation, value by value, on seeded random data."""
from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from motion_composer.engine.quaternions import axis_angle, from_euler, qconj, qmul, qrot, qslerp
from motion_composer.engine.rotations import euler_to_quat, quat_to_euler

RNG_SEED = 20240611
N = 2000

ORDERS_1 = ["X", "Y", "Z"]
ORDERS_2 = ["".join(p) for p in itertools.permutations("XYZ", 2)]
ORDERS_3 = (["".join(p) for p in itertools.permutations("XYZ")] +               # Tait-Bryan
            [a + b + a for a in "XYZ" for b in "XYZ" if a != b])             # proper Euler
ALL_ORDERS = ORDERS_1 + ORDERS_2 + ORDERS_3


def _rng(salt: int = 0) -> np.random.Generator:
    return np.random.default_rng(RNG_SEED + salt)


def _unit_quats(rng, n=N) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _same_up_to_sign(a, b, atol=1e-12):
    """Element-wise equal after giving ``b`` the sign of ``a`` (q and -q: one rotation)."""
    sign = np.where(np.sum(a * b, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    np.testing.assert_allclose(a, sign * b, rtol=0, atol=atol)


def test_order_lists_are_complete():
    assert len(ALL_ORDERS) == 3 + 6 + 12 and len(set(ALL_ORDERS)) == len(ALL_ORDERS)
    assert "ZXZ" in ORDERS_3 and "ZYX" in ORDERS_3


def test_qmul_matches_scipy_composition():
    rng = _rng(1)
    a, b = _unit_quats(rng), _unit_quats(rng)
    got = qmul(a, b)
    want = (Rotation.from_quat(a) * Rotation.from_quat(b)).as_quat()
    _same_up_to_sign(got, want)
    # the Hamilton product itself (no sign freedom): check against the matrix form of a * b
    x1, y1, z1, w1 = a.T
    L = np.stack([np.stack([w1, -z1, y1, x1], -1), np.stack([z1, w1, -x1, y1], -1),
                  np.stack([-y1, x1, w1, z1], -1), np.stack([-x1, -y1, -z1, w1], -1)], 1)
    np.testing.assert_allclose(got, np.einsum("nij,nj->ni", L, b), rtol=0, atol=1e-14)


def test_qmul_broadcasts():
    rng = _rng(2)
    a = _unit_quats(rng, 35).reshape(5, 7, 4)
    b = _unit_quats(rng, 7)
    got = qmul(a, b[None])
    want = (Rotation.from_quat(a.reshape(-1, 4)) *
            Rotation.from_quat(np.tile(b, (5, 1)))).as_quat().reshape(5, 7, 4)
    _same_up_to_sign(got, want)


def test_qrot_matches_scipy_apply():
    rng = _rng(3)
    q = _unit_quats(rng)
    v = rng.normal(scale=50.0, size=(N, 3))
    np.testing.assert_allclose(qrot(q, v), Rotation.from_quat(q).apply(v), rtol=0, atol=1e-11)
    # one rotation, many vectors and many rotations, one vector
    np.testing.assert_allclose(qrot(q[0], v), Rotation.from_quat(q[0]).apply(v), rtol=0,
                               atol=1e-11)
    np.testing.assert_allclose(qrot(q, v[0]), Rotation.from_quat(q).apply(v[0]), rtol=0,
                               atol=1e-11)


def test_qconj_is_the_inverse():
    q = _unit_quats(_rng(4))
    _same_up_to_sign(qconj(q), Rotation.from_quat(q).inv().as_quat())
    _same_up_to_sign(qmul(q, qconj(q)), np.tile([0.0, 0.0, 0.0, 1.0], (N, 1)))


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_axis_angle_matches_rotvec(axis):
    angles = _rng(5 + axis).uniform(-4 * np.pi, 4 * np.pi, N)
    rotvec = np.zeros((N, 3))
    rotvec[:, axis] = angles
    _same_up_to_sign(axis_angle(axis, angles), Rotation.from_rotvec(rotvec).as_quat())


@pytest.mark.parametrize("order", ALL_ORDERS)
def test_from_euler_matches_scipy_intrinsic(order):
    rng = _rng(10 + ALL_ORDERS.index(order))
    angles = rng.uniform(-400.0, 400.0, size=(N, len(order)))   # beyond +-360 on purpose
    angles[:10] = rng.choice([-180.0, -90.0, 0.0, 90.0, 180.0], size=(10, len(order)))
    got = from_euler(angles, order)
    want = Rotation.from_euler(order, angles, degrees=True).as_quat()
    _same_up_to_sign(got, want)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, rtol=0, atol=1e-14)
    # the engine's edge function gives the same quaternions
    np.testing.assert_array_equal(euler_to_quat(angles, order), got)


@pytest.mark.parametrize("order", ["ZYX", "ZXZ", "YX"])
def test_from_euler_keeps_leading_shape(order):
    angles = _rng(40).uniform(-180, 180, size=(4, 6, len(order)))
    got = from_euler(angles, order)
    assert got.shape == (4, 6, 4)
    want = Rotation.from_euler(order, angles.reshape(-1, len(order)),
                               degrees=True).as_quat().reshape(4, 6, 4)
    _same_up_to_sign(got, want)


@pytest.mark.parametrize("order", ALL_ORDERS)
def test_quat_to_euler_gives_back_the_rotation(order):
    """Euler angles written for a rotation that the order can express give that rotation."""
    rng = _rng(60 + ALL_ORDERS.index(order))
    angles = rng.uniform(-170.0, 170.0, size=(N, len(order)))
    q = Rotation.from_euler(order, angles, degrees=True).as_quat()
    back = quat_to_euler(q, order, unwrap=False)
    assert back.shape == angles.shape
    _same_up_to_sign(Rotation.from_euler(order, back, degrees=True).as_quat(), q, atol=1e-10)


def test_qslerp_matches_scipys_slerp():
    rng = _rng(80)
    q0, q1 = _unit_quats(rng), _unit_quats(rng)
    q1[:10] = q0[:10]                              # equal pairs take the linear branch
    q1[10:20] = -q0[10:20]                         # the same rotation, other hemisphere
    u = rng.uniform(0.0, 1.0, size=len(q0))
    got = qslerp(q0, q1, u)
    for k in (0, 5, 10, 15, 100, 500, len(q0) - 1):
        want = Slerp([0.0, 1.0], Rotation.from_quat([q0[k], q1[k]]))([u[k]]).as_quat()
        _same_up_to_sign(got[k:k + 1], want, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, rtol=0, atol=1e-14)
    np.testing.assert_allclose(qslerp(q0, q1, np.zeros(len(q0))), q0, rtol=0, atol=1e-15)


def test_component_functions_give_the_interleaved_values_bit_for_bit():
    """The hot paths' component-array kernels equal the general functions exactly, with the
    broadcasting the hot paths use: per-joint constants ``(4, n, 1)`` against ``(4, n, F)``."""
    from motion_composer.engine.quaternions import (cconj, cmul, components, cquat_between,
                                                    crot, ctwist_about, interleaved,
                                                    quat_between, twist_about)
    rng = _rng(90)
    a = _unit_quats(rng, 7 * 300).reshape(300, 7, 4)
    b = _unit_quats(rng, 7 * 300).reshape(300, 7, 4)
    const = _unit_quats(rng, 7)
    v = rng.normal(scale=2.0, size=(300, 7, 3))
    axis = rng.normal(size=(7, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    v[0, 0] = -3.0 * axis[0]                         # opposite directions: a half turn
    v[1, 1] = 0.5 * axis[1]                          # the same direction: identity

    def per_joint(c):                                # (n, k) -> (k, n, 1)
        return components(c)[:, :, None]

    def joint_major(x):                              # (F, n, k) -> (k, n, F)
        return np.ascontiguousarray(x.T)

    def back(c):                                     # (k, n, F) -> (F, n, k)
        return np.ascontiguousarray(c.T)

    A, B, V = joint_major(a), joint_major(b), joint_major(v)
    np.testing.assert_array_equal(back(cmul(A, B)), qmul(a, b))
    np.testing.assert_array_equal(back(cmul(A, per_joint(const))), qmul(a, const))
    np.testing.assert_array_equal(back(cmul(per_joint(const), B)), qmul(const, b))
    np.testing.assert_array_equal(interleaved(cmul(components(const[0]), components(const[1]))),
                                  qmul(const[0], const[1]))
    np.testing.assert_array_equal(back(cconj(A)), qconj(a))
    np.testing.assert_array_equal(back(crot(A, V)), qrot(a, v))
    np.testing.assert_array_equal(back(crot(A, per_joint(axis))), qrot(a, axis))
    np.testing.assert_array_equal(back(cquat_between(per_joint(axis), V)),
                                  quat_between(axis, v))
    np.testing.assert_array_equal(back(cquat_between(V, V[:, ::-1])),
                                  quat_between(v, v[:, ::-1]))
    np.testing.assert_array_equal(back(ctwist_about(A, per_joint(axis))), twist_about(a, axis))
    half_turn = np.append(np.cross(axis[2], [1.0, 0.0, 0.0]), 0.0)
    a[2, 2] = half_turn / np.linalg.norm(half_turn)  # normal to the axis: the twist is identity
    np.testing.assert_array_equal(back(ctwist_about(joint_major(a), per_joint(axis))),
                                  twist_about(a, axis))


def test_small_batch_forms_give_the_general_values_bit_for_bit():
    """qmul_small, cmul_small and crot_small (a few whole-array calls, for the solver's small
    batches) give qmul's, cmul's and crot's values to the last bit on random data, signed
    zeros included: a batch of one, component arrays of one to three trailing dimensions,
    per-joint constants broadcast over the batch, and interleaved quaternions broadcasting."""
    from motion_composer.engine.quaternions import (cmul, cmul_small, crot, crot_small,
                                                    qmul_small)
    rng = _rng(95)

    def same(got, want):
        assert got.shape == want.shape
        assert np.array_equal(got, want)
        assert np.array_equal(np.signbit(got), np.signbit(want))

    for shape in [(1, 1), (3, 19), (5, 40), (7,), (2, 3, 5)]:
        for _ in range(10):
            a, b = rng.normal(size=(4,) + shape), rng.normal(size=(4,) + shape)
            v = rng.normal(size=(3,) + shape)
            first = (slice(None),) + (0,) * len(shape)
            a[first], b[first], v[first] = 0.0, -0.0, -0.0
            same(cmul_small(a, b), cmul(a, b))
            same(crot_small(a, v), crot(a, v))
            same(qmul_small(a.T, b.T), qmul(a.T, b.T))
            if len(shape) >= 2:                 # offsets (3, n, 1) broadcast over the batch
                one = v[..., :1]
                same(crot_small(a, one), crot(a, np.repeat(one, shape[-1], axis=-1)))
                same(cmul_small(a, b[..., :1]), cmul(a, b[..., :1]))
                same(qmul_small(a.T, b[..., :1].T), qmul(a.T, b[..., :1].T))


@pytest.mark.parametrize("order", ALL_ORDERS)
def test_cfrom_euler_gives_from_eulers_values_bit_for_bit(order):
    """Euler angles as component rows ``(n, Jg, F)``, as the BVH reader holds them, give
    :func:`from_euler`'s quaternions bit for bit, the sign of zeros included (zeros, negative
    zeros, half and whole turns, angles beyond a turn)."""
    from motion_composer.engine.quaternions import cfrom_euler
    rng = _rng(95)
    angles = rng.uniform(-400.0, 400.0, size=(300, 7, len(order)))
    angles[::5] = 0.0
    angles[::7] = -0.0
    angles[::3, 1, 0] = 180.0
    angles[::4, 2] = -360.0
    expected = from_euler(angles, order)                                  # (F, Jg, 4)
    got = cfrom_euler(np.ascontiguousarray(angles.T), order).T           # (F, Jg, 4) view
    assert np.ascontiguousarray(got).tobytes() == expected.tobytes()
    out = np.empty((4, 7, 300))
    assert cfrom_euler(angles.T, order, out) is out                      # strided angles too
    assert np.ascontiguousarray(out.T).tobytes() == expected.tobytes()


def test_from_matrix_equals_scipy_bit_for_bit():
    from motion_composer.engine.quaternions import from_matrix
    matrices = Rotation.random(2000, random_state=11).as_matrix()
    np.testing.assert_array_equal(from_matrix(matrices), Rotation.from_matrix(matrices).as_quat())
    # the axis turns of file conventions (Z up, X up, mirrored fronts): every proper one
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            m[range(3), perm] = signs
            if np.linalg.det(m) > 0:
                np.testing.assert_array_equal(from_matrix(m), Rotation.from_matrix(m).as_quat())


@pytest.mark.parametrize("size", [1e-6, 1e-3, 0.1, 3.0])
def test_from_rotvec_equals_scipy_bit_for_bit(size):
    from motion_composer.engine.quaternions import from_rotvec
    v = np.random.default_rng(5).normal(size=(1000, 3)) * size
    np.testing.assert_array_equal(from_rotvec(v), Rotation.from_rotvec(v).as_quat())
    np.testing.assert_array_equal(from_rotvec(np.zeros((2, 3))), [[0, 0, 0, 1]] * 2)
