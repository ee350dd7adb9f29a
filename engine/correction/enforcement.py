"""Enforcing Cartesian constraints over time (the paper's section 3): two passes and a
displacement map.

:func:`enforce` takes the composed (directly converted) motion, which is the attraction
posture of every frame, and a list of :class:`~engine.correction.constraints.Constraint`, and returns a
:class:`Correction`: the dense displacement (per joint rotation vectors and the root's
translation) that, added to the composed motion, meets the constraints, with residuals.

Pass one solves every frame inside an active range ``[start, end]`` with no smoothing; it gives
the key postures. Pass two, as section 3.3 says:

* input ramp ``[smooth_in, start)``: the effector's goal moves along the line from where the
  effector was at ``smooth_in`` (pass one) to the goal at ``start`` (Cartesian smoothing; a
  plane slides along its normal, an orientation turns along the shortest arc);
* active range: the goal itself;
* output ramp ``(end, smooth_out]``: the joint values of the constrained joint's chain, from
  the effector up to the root, are interpolated between the pass-one postures at ``end`` and at
  ``smooth_out``. The interpolated values replace the attraction posture on that chain, so
  where another constraint is still active its IK pulls towards them rather than fighting
  them, and where none is they are the result.

Frames that share the same set of tasks are solved together as one vectorised batch, each
starting from its attraction posture (the converted motion). With ``warm_start=True`` frames
are instead solved one by one in time order, each starting from the solution at t - 1, as the
paper does; both converge to the same posture, the posture nearest the attraction that meets
the tasks (a test checks it), and the batch is many times faster.

Outside every range ``[smooth_in, smooth_out]`` the displacement is exactly zero.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from .constraints import Constraint, ConstraintError
from .displacement import DisplacementMap
from .ik import IKOptions, Task, quat_to_rotvec, solve_frames
from ..kinematics import fk_arrays
from ..motion import Motion
from ..quaternions import qconj, qmul, qnormalize, qpow, qpow_many

__all__ = ["Correction", "enforce", "describe_residuals"]


@dataclass(frozen=True, eq=False)
class Correction:
    """The result of :func:`enforce`.

    Attributes:
        motion: the corrected motion (composed motion plus displacement).
        rotvecs: ``(F, J, 3)`` [rad] dense rotation offsets (parent frame, ``exp(r) * local``).
        root: ``(F, 3)`` [m] root translation offsets.
        residual: constraint index -> ``(F,)`` the task's residual at each frame where it was
            solved (metres; radians for orientation; NaN where not solved).
        iterations: ``(F,)`` solver iterations per frame in pass two.
        seconds: wall time of each pass.
    """

    motion: Motion
    rotvecs: np.ndarray
    root: np.ndarray
    residual: dict
    iterations: np.ndarray
    seconds: dict = field(default_factory=dict)

    def displacement_map(self, *, rotation_tolerance: float = np.radians(0.02),
                         translation_tolerance: float = 1e-4) -> DisplacementMap:
        """The correction as editable curves, keys reduced within the tolerances."""
        return DisplacementMap.from_dense(self.motion.skeleton, self.rotvecs, self.root,
                                          rotation_tolerance=rotation_tolerance,
                                          translation_tolerance=translation_tolerance)


def _check(constraints, composed: Motion):
    sk = composed.skeleton
    F = composed.num_frames
    out = []
    for c in constraints:
        if not c.enabled:
            continue
        if c.joint not in sk.index:
            raise ConstraintError(f"constraint {c.name or c.joint!r}: {c.joint!r} is not a "
                                  "joint of the target")
        if c.smooth_out > F - 1:
            raise ConstraintError(f"constraint {c.name or c.joint!r}: smooth_out {c.smooth_out} "
                                  f"is past the last frame ({F - 1})")
        out.append(c)
    return out


_SIDES = {"above": 1, "on": 0, "below": -1}


def _kind(c: Constraint) -> str:
    return "position" if c.kind in ("position", "trajectory") else c.kind


def _goals(c: Constraint, frames: np.ndarray) -> np.ndarray:
    """Per-frame goals of ``c`` on its active frames."""
    if c.kind in ("position", "trajectory"):
        return c.goal_point(frames)
    if c.kind == "plane":
        return np.broadcast_to(c.goal["point"], (len(frames), 3)).copy()
    return np.broadcast_to(c.goal["quaternion"], (len(frames), 4)).copy()


def _assign_slots(entries, cons, sk, F) -> list[dict]:
    """Task slots: entries on the same joint, kind and priority share a slot unless their
    frames overlap. Each slot holds per-frame goal, weight, plane normal and side, and the
    index of the constraint that owns each frame."""
    slots: list[dict] = []
    for i, frames, goals in entries:
        if len(frames) == 0:
            continue
        c = cons[i]
        kind = _kind(c)
        j = sk.index[c.joint]
        home = None
        for sl in slots:
            if (sl["joint"], sl["kind"], sl["priority"]) == (j, kind, c.priority) and \
                    not np.any(sl["weight"][frames] > 0):
                home = sl
                break
        if home is None:
            dim = 4 if kind == "orientation" else 3
            goal0 = np.zeros((F, dim))
            if dim == 4:
                goal0[:, 3] = 1.0
            home = {"joint": j, "kind": kind, "priority": c.priority, "goal": goal0,
                    "weight": np.zeros(F), "normal": np.tile([0.0, 1.0, 0.0], (F, 1)),
                    "side": np.zeros(F, dtype=np.int8), "owner": np.full(F, -1)}
            slots.append(home)
        home["goal"][frames] = goals
        home["weight"][frames] = c.weight
        home["owner"][frames] = i
        if kind == "plane":
            home["normal"][frames] = c.goal["normal"]
            home["side"][frames] = _SIDES[c.goal["side"]]
    return slots


def _chain(sk, joint: int) -> np.ndarray:
    return np.array(sorted(sk.ancestors(joint) + [joint]), dtype=np.intp)


def enforce(composed: Motion, constraints, *, options: IKOptions | None = None,
            warm_start: bool = False, progress=None, cancel=None) -> Correction:
    """Correct ``composed`` so that ``constraints`` hold, with the two passes of section 3.3.

    Args:
        composed: the directly converted motion: the attraction posture of every frame.
        constraints: :class:`Constraint` list (disabled ones are skipped).
        options: solver settings (default :class:`IKOptions`); an unset ``scale`` is
            the composed motion's stature.
        warm_start: solve frame by frame from the solution at t - 1 (the paper's scheme)
            instead of in batches from the attraction posture.
        progress: called with a fraction in [0, 1].
        cancel: called between batches; returning True stops with
            :class:`~engine.errors.MotionComposerError`.
    """
    from ..describe import stature
    from ..errors import MotionComposerError

    sk = composed.skeleton
    F = composed.num_frames
    cons = _check(constraints, composed)
    options = options if options is not None else IKOptions()
    if options.scale is None:
        options = dataclasses.replace(options, scale=max(stature(composed), 0.1))
    base_rot = composed.rotations
    base_tra = composed.translations
    timings = {}

    def check_cancel():
        if cancel is not None and cancel():
            raise MotionComposerError("the correction was cancelled")

    def run(entries, attraction_rot, attraction_tra):
        """Solve the frames that ``entries`` cover: a list of (constraint index, frames,
        per-frame goals). Entries share task slots where they do not overlap in time, so all
        frames form one batch. Returns rot, tra, residual per constraint, iterations."""
        rot = attraction_rot.copy()
        tra = attraction_tra.copy()
        residual = {i: np.full(F, np.nan) for i in range(len(cons))}
        iters = np.zeros(F, dtype=np.intp)
        slots = _assign_slots(entries, cons, sk, F)
        if not slots:
            return rot, tra, residual, iters
        covered = np.zeros(F, dtype=bool)
        for slot in slots:
            covered |= slot["weight"] > 0
        frames = np.flatnonzero(covered)
        tasks = [Task(sl["kind"], sl["joint"], sl["goal"][frames], sl["weight"][frames],
                      sl["normal"][frames], sl["side"][frames], sl["priority"])
                 for sl in slots]
        if warm_start:
            res = np.zeros((len(frames), len(tasks)))
            it = np.zeros(len(frames), dtype=np.intp)
            for k, f in enumerate(frames):
                if k and frames[k - 1] == f - 1:
                    r0 = rot[f - 1:f].copy()
                    t0 = tra[f:f + 1].copy()
                    t0[:, 0] = tra[f - 1, 0]
                else:
                    r0, t0 = rot[f:f + 1], tra[f:f + 1]
                r, t, res[k:k + 1], it[k:k + 1] = solve_frames(
                    sk, [task.take([k]) for task in tasks], r0, t0,
                    attraction_rot[f:f + 1], attraction_tra[f:f + 1, 0], options)
                rot[f], tra[f] = r[0], t[0]
                if cancel is not None and k % 64 == 0:
                    check_cancel()
                if progress is not None and k % 64 == 0:
                    progress(k / len(frames))
        else:
            r, t, res, it = solve_frames(sk, tasks, rot[frames], tra[frames],
                                         attraction_rot[frames], attraction_tra[frames, 0],
                                         options)
            rot[frames], tra[frames] = r, t
        iters[frames] = it
        for col, sl in enumerate(slots):
            owner = sl["owner"][frames]
            for i in np.unique(owner[owner >= 0]):
                sel = owner == i
                residual[int(i)][frames[sel]] = res[sel, col]
        check_cancel()
        return rot, tra, residual, iters

    # ---------------------------------------------------------------- pass one
    t0 = time.perf_counter()
    entries1 = []
    for i, c in enumerate(cons):
        frames = np.arange(c.start, c.end + 1)
        entries1.append((i, frames, _goals(c, frames)))
    rot1, tra1, _, _ = run(entries1, base_rot, base_tra)
    timings["pass one"] = time.perf_counter() - t0
    if progress is not None:
        progress(0.5)

    # ---------------------------------------------------------------- pass two
    t0 = time.perf_counter()
    need = sorted({c.smooth_in for c in cons if c.smooth_in < c.start})
    effector_at = {}
    if need:
        pose = fk_arrays(sk, rot1[need], tra1[need], end_sites=False)
        for k, f in enumerate(need):
            effector_at[f] = (pose.positions[k], pose.rotations[k])
    attraction_rot = base_rot.copy()
    attraction_tra = base_tra.copy()
    touched = np.zeros(F, dtype=bool)
    entries2 = []
    for i, c in enumerate(cons):
        j = sk.index[c.joint]
        frames = np.arange(c.start, c.end + 1)
        entries2.append((i, frames, _goals(c, frames)))
        if c.smooth_in < c.start - 1:
            pos, wrot = effector_at[c.smooth_in]
            frames = np.arange(c.smooth_in + 1, c.start)
            u = (frames - c.smooth_in) / (c.start - c.smooth_in)
            entries2.append((i, frames, np.array([_ramp_goal(c, pos[j], wrot[j], x)
                                                  for x in u])))
        if c.smooth_out > c.end + 1:
            chain = _chain(sk, j)
            frames = np.arange(c.end + 1, c.smooth_out)
            u = ((frames - c.end) / (c.smooth_out - c.end))[:, None]
            a, b = rot1[c.end, chain], rot1[c.smooth_out, chain]
            steps = qpow_many(qmul(b, qconj(a)), u[:, 0])                     # (n, C, 4)
            attraction_rot[frames[:, None], chain[None, :]] = qnormalize(qmul(steps, a))
            root_a, root_b = tra1[c.end, 0], tra1[c.smooth_out, 0]
            attraction_tra[frames, 0] = root_a + (root_b - root_a) * u
            touched[frames] = True
    rot2, tra2, residual, iters = run(entries2, attraction_rot, attraction_tra)
    timings["pass two"] = time.perf_counter() - t0
    if progress is not None:
        progress(1.0)

    # ---------------------------------------------------------------- displacement
    changed = touched.copy()
    for _, frames, _ in entries2:
        changed[frames] = True
    rot = base_rot.copy()
    tra = base_tra.copy()
    rot[changed] = rot2[changed]
    tra[changed, 0] = tra2[changed, 0]
    rotvecs = np.zeros((F, sk.num_joints, 3))
    moved = np.any(rot != base_rot, axis=-1)                       # (F, J), bit for bit
    rotvecs[moved] = quat_to_rotvec(qmul(rot[moved], qconj(base_rot[moved])))
    root = tra[:, 0] - base_tra[:, 0]
    motion = _apply_dense(composed, rotvecs, root, moved)
    return Correction(motion=motion, rotvecs=rotvecs, root=root, residual=residual,
                      iterations=iters, seconds=timings)


def _apply_dense(composed: Motion, rotvecs, root, moved) -> Motion:
    """The composed motion plus the displacement, exactly as a displacement map applies it;
    joints with no offset keep the composed values bit for bit."""
    from .ik import rotvec_to_quat
    rotations = composed.rotations.copy()
    rotations[moved] = qmul(rotvec_to_quat(rotvecs[moved]), rotations[moved])
    translations = composed.translations.copy()
    translations[:, 0] += root
    return Motion._trusted(composed.skeleton, rotations, translations, composed.frame_time,
                           composed.name)


def _ramp_goal(c: Constraint, pos: np.ndarray, wrot: np.ndarray, u: float):
    """The goal at fraction ``u`` of the input ramp, from where the effector was at
    ``smooth_in`` (``pos``, world rotation ``wrot``) to the goal at ``start``."""
    if c.kind in ("position", "trajectory"):
        end = c.goal_point(np.array([c.start]))[0]
        return pos + (end - pos) * u
    if c.kind == "plane":
        n = c.goal["normal"]
        point = c.goal["point"]
        s = float((pos - point) @ n)
        side = c.goal["side"]
        # the plane starts where the effector is (if it is on the wrong side) and slides to its
        # place at start
        if side == "above":
            s = min(s, 0.0)
        elif side == "below":
            s = max(s, 0.0)
        return point + n * s * (1.0 - u)
    g = c.goal["quaternion"]
    d = qmul(g, qconj(wrot))
    return qnormalize(qmul(qpow(d, u), wrot))


def describe_residuals(correction: Correction, constraints) -> list[dict]:
    """Per constraint: the largest and mean residual over its active range, and its range."""
    out = []
    active = [c for c in constraints if c.enabled]
    for i, c in enumerate(active):
        res = correction.residual.get(i)
        window = res[c.start:c.end + 1] if res is not None else np.array([np.nan])
        out.append({"constraint": c.name or c.joint, "joint": c.joint, "kind": c.kind,
                    "range": list(c.range),
                    "max_residual": float(np.nanmax(window)) if np.any(np.isfinite(window))
                    else None,
                    "mean_residual": float(np.nanmean(window)) if np.any(np.isfinite(window))
                    else None})
    return out
