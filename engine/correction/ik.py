"""Whole-body inverse kinematics with an attraction posture (the paper's equation (1)).

    d_theta = J+ d_x + (I - J+ J) d_z

solved by damped least squares, with priority levels after Baerlocher and Boulic (level k acts
only in the null space of levels 1..k-1) and the attraction to the converted posture as the
last, lowest task. The unknowns are the root's translation and the rotation of every joint that
moves a constrained joint (the chains from the constrained joints up to the root); joints that
move nothing constrained are exactly at their attraction posture, which is what the null-space
term would converge to.

Each joint's increment is a rotation vector ``r`` in its parent's frame, applied as
``local' = exp(r) * local`` (the displacement map's own convention), so the Jacobian block of
joint ``a`` for a point task on joint ``e`` is ``-[p_e - p_a]x R_parent(a)``.

The solver is generic: a task's error rows and their Jacobian come from its constraint kind
(:mod:`engine.correction.constraints`, one module per kind) given the joint's
:class:`TaskState`; the solver stacks them by priority.

Everything is vectorised over a *batch* of frames that share the same tasks (their goals
differ per frame). :func:`solve_frames` iterates a batch to a tolerance or a cap; frames that
converge leave the batch.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..quaternions import qconj, qmul, qnormalize, qrot, to_matrix
from ..skeleton import Skeleton

if TYPE_CHECKING:
    from .constraints import ConstraintKind

__all__ = ["Task", "TaskState", "IKOptions", "solve_frames", "rotvec_to_quat",
           "quat_to_rotvec", "task_error_and_jacobian"]


def rotvec_to_quat(v: np.ndarray) -> np.ndarray:
    """Quaternions ``(..., 4)`` of rotation vectors ``(..., 3)`` [rad]."""
    v = np.asarray(v, dtype=float)
    angle = np.linalg.norm(v, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(x/2)/x with its limit 1/2 - x^2/48 near zero
    small = angle < 1e-8
    scale = np.where(small, 0.5 - angle * angle / 48.0,
                     np.sin(half) / np.where(small, 1.0, angle))
    return np.concatenate([v * scale, np.cos(half)], axis=-1)


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` of quaternions ``(..., 4)`` (the shortest rotation)."""
    q = np.asarray(q, dtype=float)
    q = np.where(q[..., 3:4] < 0, -q, q)
    s = np.linalg.norm(q[..., :3], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., 3:4])
    small = s < 1e-12
    scale = np.where(small, 2.0 / np.maximum(q[..., 3:4], 1e-12),
                     angle / np.where(small, 1.0, s))
    return q[..., :3] * scale


def _skew(v: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` cross-product matrices of ``(..., 3)`` vectors."""
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


@dataclass(frozen=True)
class TaskState:
    """The kinematics of one task's joint for a batch of ``B`` frames, at the current posture.

    Attributes:
        position: ``(B, 3)`` [m] the joint's world position.
        rotation: ``(B, 4)`` its world rotation (x, y, z, w).
        pivots: ``C`` arrays ``(B, 3)`` [m] world positions of the chain's joints (those whose
            rotation moves the task, in column order).
        frames: ``C`` arrays ``(B, 3, 3)`` the world rotation of each chain joint's parent: the
            frame its rotation-vector increment is expressed in.
    """

    position: np.ndarray
    rotation: np.ndarray
    pivots: list
    frames: list

    @property
    def batch(self) -> int:
        return self.position.shape[0]

    def point_jacobian(self) -> np.ndarray:
        """``(B, 3, 3 + 3C)`` d(joint position) / d(root translation, chain rotation vectors):
        the identity for the root, ``-[p - p_a]x R_parent(a)`` for chain joint ``a``."""
        B = self.batch
        blocks = [np.broadcast_to(np.eye(3), (B, 3, 3))]
        blocks += [-_skew(self.position - pa) @ m for pa, m in zip(self.pivots, self.frames)]
        return np.concatenate(blocks, axis=2)


@dataclass(frozen=True, eq=False)
class Task:
    """One Cartesian task slot for a batch of frames; its goal may differ per frame and it may
    be switched off on some frames (``weight`` 0 there), so frames whose tasks differ can
    still share one batch.

    Attributes:
        kind: the :class:`~engine.correction.constraints.ConstraintKind` whose error and
            Jacobian rows the task is.
        joint: the constrained joint's index.
        goal: ``(B, kind.goal_size)`` the kind's task goal per frame (a point, a quaternion,
            a plane).
        weight: ``(B,)`` scales the task's rows within its level; 0 switches it off.
        priority: 1 is the highest.
        label: for reports.
    """

    kind: ConstraintKind
    joint: int
    goal: np.ndarray
    weight: np.ndarray
    priority: int = 1
    label: str = ""

    @property
    def rows(self) -> int:
        return self.kind.rows

    def take(self, index) -> "Task":
        """The task on a subset of the batch's frames."""
        return Task(self.kind, self.joint, self.goal[index], self.weight[index], self.priority,
                    self.label)


@dataclass(frozen=True)
class IKOptions:
    """Solver settings.

    Attributes:
        tolerance: [m] a position or plane task is met below this error (orientation tasks
            use ``tolerance / scale`` radians with ``scale`` [m] the character's size).
        max_iterations: the cap per frame.
        damping: damped least squares lambda, as a fraction of ``scale`` [m].
        max_step: the largest task correction taken per iteration, as a fraction of ``scale``.
        attraction: gain [0, 1] of the pull towards the attraction posture per iteration.
        settle: a frame whose tasks are met is done once its largest step is below this
            (radians or metres): the null-space pull has converged too.
        joint_limits: joint index -> largest angle [rad] a joint may turn away from its
            attraction posture (optional).
        scale: [m] the character's size (its height); set by the caller.
    """

    tolerance: float = 1e-4
    max_iterations: int = 60
    damping: float = 0.005
    max_step: float = 0.05
    attraction: float = 0.5
    settle: float = 1e-5
    joint_limits: dict = field(default_factory=dict)
    scale: float = 1.7


class _Structure:
    """What a task set needs from the skeleton: the unknown joints and each task's chain."""

    def __init__(self, skeleton: Skeleton, tasks: list[Task]):
        self.tasks = tasks
        moving: set[int] = set()
        chains = []
        for t in tasks:
            chain = t.kind.chain(skeleton, t.joint)
            chains.append(np.array(chain, dtype=np.intp))
            moving.update(chain)
        self.joints = np.array(sorted(moving), dtype=np.intp)     # unknown rotations
        self.col = {int(j): 3 + 3 * k for k, j in enumerate(self.joints)}
        self.n = 3 + 3 * len(self.joints)
        self.chains = chains
        # FK needs every unknown joint, every task joint and their ancestors
        needed = set(self.joints.tolist())
        for t in tasks:
            needed.add(t.joint)
            needed.update(skeleton.ancestors(t.joint))
        self.fk_joints = np.array(sorted(needed), dtype=np.intp)
        self.levels = sorted({t.priority for t in tasks})
        self.row0 = np.cumsum([0] + [t.rows for t in tasks])
        self.k = int(self.row0[-1])


def _fk_partial(skeleton: Skeleton, joints: np.ndarray, rot: np.ndarray, tra: np.ndarray,
                slot: dict):
    """World rotations and positions ``{joint: (B, 4) / (B, 3)}`` for ``joints`` (closed under
    ancestors, sorted)."""
    wq, wp = {}, {}
    for j in joints:
        j = int(j)
        p = int(skeleton.parents[j])
        t = tra[:, slot[j]] if j in slot else skeleton.offsets[j]
        if p < 0:
            wq[j] = rot[:, j]
            wp[j] = np.broadcast_to(t, (rot.shape[0], 3))
        else:
            wq[j] = qmul(wq[p], rot[:, j])
            wp[j] = wp[p] + qrot(wq[p], t)
    return wq, wp


def task_error_and_jacobian(skeleton: Skeleton, structure: _Structure, rot: np.ndarray,
                            tra: np.ndarray, slot: dict, select=None, sticky=None):
    """Errors ``(B, K)`` and Jacobians ``(B, K, N)`` of the tasks at the current posture.

    Each task's rows are its kind's error and Jacobian at the posture. Columns: root
    translation (3), then 3 per unknown joint (rotation vector in its parent's frame). Rows
    of a task that is off or not active (a satisfied one-sided plane) are zero. Weights are
    not applied here.
    ``select`` picks the frames of the tasks' goals that ``rot`` holds (all by default).
    ``sticky``: ``(B, T)`` one-sided tasks already activated in this solve stay active (held
    on the plane) so that the attraction cannot pull them back through it on every other
    iteration; the array is updated in place.
    """
    B = rot.shape[0]
    wq, wp = _fk_partial(skeleton, structure.fk_joints, rot, tra, slot)
    err = np.zeros((B, structure.k))
    jac = np.zeros((B, structure.k, structure.n))
    parent_m = {}
    for ti, (task, chain, r0) in enumerate(zip(structure.tasks, structure.chains,
                                               structure.row0)):
        e = task.joint
        if select is not None:
            task = task.take(select)
        mats = []
        for a in chain:
            a = int(a)
            if a not in parent_m:
                p = int(skeleton.parents[a])
                parent_m[a] = (np.broadcast_to(np.eye(3), (B, 3, 3)) if p < 0
                               else to_matrix(wq[p]))
            mats.append(parent_m[a])
        cols = np.concatenate([np.arange(0, 3)] + [
            np.arange(structure.col[int(a)], structure.col[int(a)] + 3) for a in chain])
        state = TaskState(wp[e], wq[e], [wp[int(a)] for a in chain], mats)
        on = task.weight > 0
        active = on & task.kind.active(task.goal, state)
        if sticky is not None:
            active |= on & sticky[:, ti]
            sticky[:, ti] |= active
        rows = slice(r0, r0 + task.rows)
        err[:, rows] = np.where(active[:, None], task.kind.error(task.goal, state), 0.0)
        jac[:, rows, cols] = np.where(active[:, None, None],
                                      task.kind.jacobian(task.goal, state), 0.0)
    return err, jac


def _damped_solve(a: np.ndarray, rhs: np.ndarray, lam2: float) -> np.ndarray:
    """``a^T (a a^T + lam2 I)^-1 rhs`` for batches ``a (B, K, N)``, ``rhs (B, K)``."""
    k = a.shape[1]
    gram = a @ a.transpose(0, 2, 1) + lam2 * np.eye(k)
    y = np.linalg.solve(gram, rhs[..., None])
    return (a.transpose(0, 2, 1) @ y)[..., 0]


def _damped_pinv(a: np.ndarray, lam2: float) -> np.ndarray:
    k = a.shape[1]
    gram = a @ a.transpose(0, 2, 1) + lam2 * np.eye(k)
    return a.transpose(0, 2, 1) @ np.linalg.inv(gram)


def solve_frames(skeleton: Skeleton, tasks: list[Task], rot: np.ndarray, tra: np.ndarray,
                 attraction_rot: np.ndarray, attraction_root: np.ndarray,
                 options: IKOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Solve a batch of frames that share ``tasks``.

    Args:
        rot: ``(B, J, 4)`` starting local rotations (the attraction posture, or the solution
            of the previous frame for a warm start).
        tra: ``(B, K, 3)`` local translations of ``skeleton.translated`` (the root's first; only
            the root's is an unknown).
        attraction_rot, attraction_root: ``(B, J, 4)`` and ``(B, 3)`` the attraction posture.

    Returns:
        ``(rot, tra, residual, iterations)``: the solved posture, the residual per task and
        frame ``(B, T)`` (metres; radians for orientation), iterations used per frame ``(B,)``.
    """
    rot = np.array(rot, dtype=float)
    tra = np.array(tra, dtype=float)
    B = rot.shape[0]
    structure = _Structure(skeleton, tasks)
    slot = {int(j): k for k, j in enumerate(skeleton.translated)}
    scale = options.scale
    lam2 = (options.damping * scale) ** 2
    ns_lam2 = (1e-6 * scale) ** 2
    max_step = options.max_step * scale
    tol = options.tolerance
    weights = np.concatenate([np.repeat(t.weight[:, None], t.rows, axis=1) for t in tasks],
                             axis=1)                                             # (B, K)
    task_of_row = np.concatenate([[i] * t.rows for i, t in enumerate(tasks)])
    level_rows = [np.flatnonzero([tasks[i].priority == lvl for i in task_of_row])
                  for lvl in structure.levels]
    angular = np.concatenate([[t.kind.angular] * t.rows for t in tasks])
    row_tol = np.where(angular, tol / scale, tol)
    joints = structure.joints
    # joints that move nothing constrained sit at their attraction posture
    others = np.setdiff1d(np.arange(skeleton.num_joints), joints)
    rot[:, others] = attraction_rot[:, others]

    iterations = np.zeros(B, dtype=np.intp)
    residual = np.zeros((B, len(tasks)))
    active = np.arange(B)
    sticky_all = np.zeros((B, len(tasks)), dtype=bool)
    for it in range(options.max_iterations + 1):
        r, t = rot[active], tra[active]
        sticky = sticky_all[active]
        err, jac = task_error_and_jacobian(skeleton, structure, r, t, slot, active, sticky)
        sticky_all[active] = sticky
        task_err = np.sqrt(np.add.reduceat(err * err, structure.row0[:-1], axis=1))
        residual[active] = task_err
        met = np.all(np.abs(err) <= row_tol, axis=1)
        if it == options.max_iterations:
            break
        iterations[active] += 1
        err_raw = err
        # the last quarter of the cap only restores the first level (for frames still going:
        # unreachable lower levels, which would otherwise end mid-oscillation)
        polishing = len(level_rows) > 1 and it >= int(0.75 * options.max_iterations)
        # clamp the correction asked of each task
        norms = task_err[:, task_of_row]
        err = err * np.minimum(1.0, max_step / np.maximum(norms, 1e-12))
        w = weights[active]
        err = err * w
        jac = jac * w[:, :, None]
        nb = len(active)
        dq = np.zeros((nb, structure.n))
        stacked = None
        behind = np.zeros(nb)               # how far the higher levels are from being met
        for rows in level_rows:
            jl, el = jac[:, rows], err[:, rows]
            if stacked is None:
                jt = jl
                gate = 1.0
            else:
                jt = jl - (jl @ _damped_pinv(stacked, ns_lam2)) @ stacked
                # a lower level waits while a higher one is not met: its steps are first-order
                # invisible to the higher levels, but near their singularities (a stretched
                # leg) the second-order part would push them off faster than they recover
                gate = np.clip(2.0 - behind / 10.0, 0.0, 1.0)[:, None]
                if polishing:
                    gate = 0.0
            dq += gate * _damped_solve(jt, el - (jl @ dq[..., None])[..., 0], lam2)
            behind = np.maximum(behind, (np.abs(err_raw[:, rows]) / row_tol[rows]).max(axis=1))
            stacked = jl if stacked is None else np.concatenate([stacked, jl], axis=1)
        # attraction, in the null space of every task
        dz = np.zeros((nb, structure.n))
        dz[:, 0:3] = attraction_root[active] - t[:, 0]
        cur = r[:, joints]
        dz[:, 3:] = quat_to_rotvec(qmul(attraction_rot[active][:, joints],
                                        qconj(cur))).reshape(nb, -1)
        dz *= 0.0 if polishing else options.attraction
        dq += dz - (_damped_pinv(stacked, ns_lam2) @ (stacked @ dz[..., None]))[..., 0]
        # a frame is done when its tasks are met and the posture has stopped moving
        settled = met & (np.abs(dq).max(axis=1) < options.settle)
        if np.all(settled):
            iterations[active] -= 1
            break
        keep = ~settled
        iterations[active[settled]] -= 1
        active, dq, r, t, cur = active[keep], dq[keep], r[keep], t[keep], cur[keep]
        nb = len(active)
        # apply
        t = t.copy()
        t[:, 0] += dq[:, 0:3]
        step = dq[:, 3:].reshape(nb, len(joints), 3)
        # at most 0.3 rad for any joint in one step, scaling the whole step alike so that
        # it stays in the null space of the higher priorities
        biggest = np.linalg.norm(step, axis=-1).max(axis=1)
        shrink = np.minimum(1.0, 0.3 / np.maximum(biggest, 1e-12))
        step = step * shrink[:, None, None]
        t[:, 0] += dq[:, 0:3] * (shrink[:, None] - 1.0)
        new = qnormalize(qmul(rotvec_to_quat(step), cur))
        for j, limit in options.joint_limits.items():
            if j in structure.col:
                k = int(np.searchsorted(joints, j))
                off = quat_to_rotvec(qmul(new[:, k], qconj(attraction_rot[active][:, j])))
                ang = np.linalg.norm(off, axis=-1, keepdims=True)
                off = off * np.minimum(1.0, limit / np.maximum(ang, 1e-12))
                new[:, k] = qmul(rotvec_to_quat(off), attraction_rot[active][:, j])
        r = r.copy()
        r[:, joints] = new
        rot[active] = r
        tra[active] = t
    return rot, tra, residual, iterations
