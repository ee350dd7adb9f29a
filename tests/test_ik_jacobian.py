"""Each analytic Jacobian against central finite differences, on real skeletons and postures."""
from __future__ import annotations

import numpy as np
import pytest

from motion_composer.engine.correction.constraints import KINDS
from motion_composer.engine.correction.ik import (IKOptions, Task, _Structure, quat_to_rotvec, rotvec_to_quat,
                                  solve_frames, task_error_and_jacobian)
from conftest import shared_path
from motion_composer.engine import read_bvh
from motion_composer.engine.kinematics import fk_arrays
from motion_composer.engine.quaternions import qmul
from ik_fixtures import walk_on_holden

EPS = 1e-6
POSITION, PLANE, ORIENTATION = KINDS["position"], KINDS["plane"], KINDS["orientation"]


def _posture():
    _, target, _, composed = walk_on_holden()
    frames = np.array([0, 250, 600, 900])
    return target.skeleton, composed.rotations[frames], composed.translations[frames]


def _perturb(structure, rot, tra, col, eps):
    rot, tra = rot.copy(), tra.copy()
    if col < 3:
        tra[:, 0, col] += eps
        return rot, tra
    k, axis = divmod(col - 3, 3)
    j = structure.joints[k]
    v = np.zeros(3)
    v[axis] = eps
    rot[:, j] = qmul(rotvec_to_quat(v), rot[:, j])
    return rot, tra


def _check(sk, tasks, rot, tra):
    structure = _Structure(sk, tasks)
    err, jac = task_error_and_jacobian(sk, structure, rot, tra)
    numeric = np.zeros_like(jac)
    for col in range(structure.n):
        rp, tp = _perturb(structure, rot, tra, col, EPS)
        rm, tm = _perturb(structure, rot, tra, col, -EPS)
        ep, _ = task_error_and_jacobian(sk, structure, rp, tp)
        em, _ = task_error_and_jacobian(sk, structure, rm, tm)
        numeric[:, :, col] = -(ep - em) / (2 * EPS)       # error = goal - f, so -d(error)
    assert np.abs(jac).max() > 0.1                         # not vacuous
    np.testing.assert_allclose(jac, numeric, atol=1e-6)
    return structure


def _world(sk, rot, tra):
    return fk_arrays(sk, rot, tra)


@pytest.mark.parametrize("joint", ["LeftFoot", "RightHand", "Head", "Hips"])
def test_position_jacobian(joint):
    sk, rot, tra = _posture()
    j = sk.index[joint]
    goal = _world(sk, rot, tra).positions[:, j] + [0.05, -0.02, 0.03]
    task = Task(POSITION, j, goal, np.ones(len(rot)))
    _check(sk, [task], rot, tra)


@pytest.mark.parametrize("normal", [[0, 1, 0], [0.3, 0.9, -0.2]])
def test_plane_jacobian(normal):
    sk, rot, tra = _posture()
    j = sk.index["LeftToeBase"]
    n = np.array(normal, float) / np.linalg.norm(normal)
    above = _world(sk, rot, tra).positions[:, j] + 0.02 * n    # the toe is below: active
    task = Task(PLANE, j, PLANE.task_goal(above, n, 0), np.ones(len(rot)))
    _check(sk, [task], rot, tra)


@pytest.mark.parametrize("joint", ["LeftHand", "Head", "RightFoot"])
def test_orientation_jacobian(joint):
    sk, rot, tra = _posture()
    j = sk.index[joint]
    # the goal is the current orientation: the error's map is linear to first order there
    goal = _world(sk, rot, tra).rotations[:, j]
    task = Task(ORIENTATION, j, goal, np.ones(len(rot)))
    _check(sk, [task], rot, tra)


def test_several_tasks_stack_their_rows():
    sk, rot, tra = _posture()
    pose = _world(sk, rot, tra)
    B = len(rot)
    tasks = [Task(POSITION, sk.index["LeftFoot"], pose.positions[:, sk.index["LeftFoot"]] + 0.01,
                  np.ones(B)),
             Task(ORIENTATION, sk.index["RightHand"], pose.rotations[:, sk.index["RightHand"]],
                  np.ones(B)),
             Task(PLANE, sk.index["RightToeBase"],
                  PLANE.task_goal(pose.positions[:, sk.index["RightToeBase"]] + [0, 0.01, 0],
                                  [0.0, 1.0, 0.0], 1), np.ones(B))]
    structure = _check(sk, tasks, rot, tra)
    assert structure.k == 7


def test_a_satisfied_one_sided_plane_has_no_rows():
    sk, rot, tra = _posture()
    j = sk.index["LeftToeBase"]
    below = _world(sk, rot, tra).positions[:, j] - [0, 0.05, 0]
    task = Task(PLANE, j, PLANE.task_goal(below, [0.0, 1.0, 0.0], 1), np.ones(len(rot)))
    structure = _Structure(sk, [task])
    err, jac = task_error_and_jacobian(sk, structure, rot, tra)
    assert np.all(err == 0) and np.all(jac == 0)


def test_a_satisfied_task_gives_a_zero_step():
    sk, rot, tra = _posture()
    j = sk.index["LeftHand"]
    here = _world(sk, rot, tra).positions[:, j]
    task = Task(POSITION, j, here, np.ones(len(rot)))
    out_rot, out_tra, res, it = solve_frames(sk, [task], rot, tra, rot, tra[:, 0],
                                             IKOptions(scale=1.7))
    assert np.all(it == 0)
    np.testing.assert_array_equal(out_rot, rot)
    np.testing.assert_array_equal(out_tra, tra)


def test_the_error_strictly_decreases_on_a_reachable_goal():
    sk, rot, tra = _posture()
    j = sk.index["RightHand"]
    goal = _world(sk, rot, tra).positions[:, j] + [0.15, 0.10, -0.05]
    task = Task(POSITION, j, goal, np.ones(len(rot)))
    errors = []
    for n in range(0, 12):
        _, _, res, _ = solve_frames(sk, [task], rot, tra, rot, tra[:, 0],
                                    IKOptions(scale=1.7, max_iterations=n, settle=0.0))
        errors.append(res[:, 0])
    errors = np.array(errors)
    assert errors[0].min() > 0.15
    moving = errors[:-1] > 1e-9
    assert np.all(errors[1:][moving] < errors[:-1][moving])
    assert errors[-1].max() < 1e-4


def test_rotation_vector_helpers_are_inverse_and_match_scipy():
    from scipy.spatial.transform import Rotation
    rng = np.random.default_rng(3)
    axis = rng.normal(size=(500, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    v = axis * rng.uniform(0, 3.1, size=(500, 1))         # the shortest rotation: below pi
    v[:5] = 0.0
    v[5:10] *= 1e-9
    q = rotvec_to_quat(v)
    np.testing.assert_allclose(np.abs(np.sum(q * Rotation.from_rotvec(v).as_quat(), 1)), 1,
                               atol=1e-12)
    np.testing.assert_allclose(quat_to_rotvec(q), v, atol=1e-9)


def test_the_poses_of_some_joints_are_forward_kinematics_bit_for_bit():
    """kinematics.fk_joints places the joints asked for and their ancestors only (the feet
    for contacts, the floor's check of the attraction posture): fk_arrays' rotations and
    positions to the last bit, with the root's translation alone or every joint's."""
    from motion_composer.engine.kinematics import fk_joints
    _, _, _, composed = walk_on_holden()
    bandai = read_bvh(shared_path("bandai1_walk_normal_001.bvh"))   # every joint translated
    for motion in (composed, bandai):
        sk = motion.skeleton
        frames = np.array([0, 5, 150, 190])
        rot, tra = motion.rotations[frames], motion.translations[frames]
        want = fk_arrays(sk, rot, tra, end_sites=False)
        for joints in ([sk.index[n] for n in sk.names[-3:]], [0], list(range(sk.num_joints))):
            q, p = fk_joints(sk, rot, tra, joints)
            assert np.array_equal(p, want.positions[:, joints])
            assert np.array_equal(q, want.rotations[:, joints])


@pytest.mark.parametrize("private", [True, False], ids=["numpy's gufunc", "the fallback"])
def test_the_solvers_small_solves_are_numpys(private, monkeypatch):
    """ik._solve (np.linalg.solve's gufunc without its checks) gives np.linalg.solve's values
    bit for bit and raises its error on a singular matrix; so does its fallback, the public
    function, which a numpy whose private module differs gets."""
    from motion_composer.engine.correction import ik
    if private:
        # the numpy this runs on passes the import-time probe: the fast path is the one tested
        assert ik._umath_linalg is not None and ik._private_solve_works()
    else:
        monkeypatch.setattr(ik, "_umath_linalg", None)
        assert not ik._private_solve_works()
    rng = np.random.default_rng(3)
    for n, k, m in [(1, 3, 1), (19, 9, 1), (7, 12, 5)]:
        a = rng.normal(size=(n, k, k)) + 4 * np.eye(k)
        b = rng.normal(size=(n, k, m))
        assert np.array_equal(ik._solve(a, b), np.linalg.solve(a, b))
    with pytest.raises(np.linalg.LinAlgError):
        ik._solve(np.zeros((2, 3, 3)), np.ones((2, 3, 1)))


@pytest.mark.parametrize("joint, offset", [("LeftLeg", [0.03, -0.35, 0.08]),
                                           ("RightForeArm", [0.2, 0.05, -0.1])])
def test_a_point_a_joint_carries(joint, offset):
    """A task on a point fixed in a joint's frame (``Task.point``: a control joint carried with
    a limb) has the point's Jacobian, the joint's own turn among its columns; the plane's too,
    and a task on the point where a child joint sits is that child's task, row for row."""
    sk, rot, tra = _posture()
    j = sk.index[joint]
    pose = _world(sk, rot, tra)
    point = pose.positions[:, j] + np.einsum(
        "bij,j->bi", _matrices(pose.rotations[:, j]), offset)
    B = len(rot)
    task = Task(POSITION, j, point + [0.04, 0.01, -0.02], np.ones(B), point=offset)
    structure = _check(sk, [task], rot, tra)
    assert j in structure.joints                        # the joint's own turn moves the point
    plane = Task(PLANE, j, PLANE.task_goal(point + [0, 0.02, 0], [0.0, 1.0, 0.0], 1),
                 np.ones(B), point=offset)
    _check(sk, [plane], rot, tra)
    child = sk.children[j][0]
    at_child = Task(POSITION, j, point, np.ones(B), point=sk.offsets[child])
    alone = Task(POSITION, child, point, np.ones(B))
    e1, j1 = task_error_and_jacobian(sk, _Structure(sk, [at_child]), rot, tra)
    e2, j2 = task_error_and_jacobian(sk, _Structure(sk, [alone]), rot, tra)
    np.testing.assert_allclose(e1, e2, atol=1e-12)
    np.testing.assert_allclose(j1, j2, atol=1e-12)


def test_points_and_joints_mixed_in_one_task_set():
    """Point tasks beside plain ones on the same joint, two points of one joint, and a point
    task of the same kind and chain length as a plain one (evaluated as one group): the
    stacked Jacobian matches finite differences, and each task's rows are its own alone."""
    sk, rot, tra = _posture()
    pose = _world(sk, rot, tra)
    B = len(rot)
    shin, foot, hand = sk.index["LeftLeg"], sk.index["LeftFoot"], sk.index["RightHand"]
    tasks = [Task(POSITION, shin, pose.positions[:, shin] + 0.02, np.ones(B),
                  point=[0.05, -0.3, 0.1]),
             Task(POSITION, shin, pose.positions[:, shin] - 0.01, np.ones(B)),
             Task(PLANE, shin, PLANE.task_goal(pose.positions[:, foot] + [0, 0.05, 0],
                                               [0.0, 1.0, 0.0], 1), np.ones(B),
                  point=[0.0, -0.45, 0.05]),
             Task(POSITION, foot, pose.positions[:, foot] + 0.03, np.ones(B)),
             Task(POSITION, hand, pose.positions[:, hand] + 0.02, np.ones(B), point=[0.1, 0, 0])]
    structure = _check(sk, tasks, rot, tra)
    err, jac = task_error_and_jacobian(sk, structure, rot, tra)
    cols = {int(j): 3 + 3 * k for k, j in enumerate(structure.joints)}
    for t, task in enumerate(tasks):
        alone = _Structure(sk, [task])
        e1, j1 = task_error_and_jacobian(sk, alone, rot, tra)
        rows = slice(structure.row0[t], structure.row0[t + 1])
        np.testing.assert_array_equal(err[:, rows], e1)
        mine = np.concatenate([[0, 1, 2]] + [np.arange(cols[int(j)], cols[int(j)] + 3)
                                              for j in alone.joints])
        np.testing.assert_allclose(jac[:, rows][:, :, mine], j1, atol=1e-12)


def test_an_orientation_of_a_carried_point_is_refused():
    sk, rot, _ = _posture()
    with pytest.raises(ValueError, match="orientation"):
        Task(ORIENTATION, sk.index["LeftLeg"], np.zeros((len(rot), 4)), np.ones(len(rot)),
             point=[0.0, -0.4, 0.0])


def _matrices(q):
    from motion_composer.engine.quaternions import qrot
    return np.stack([qrot(q, np.broadcast_to(e, q.shape[:-1] + (3,))) for e in np.eye(3)],
                    axis=-1)
