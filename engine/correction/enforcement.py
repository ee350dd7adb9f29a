"""Enforcing Cartesian constraints over time (the paper's section 3): two passes and a
displacement map.

:func:`enforce` takes the composed (directly converted) motion, which is the attraction
posture of every frame, and a list of :class:`~engine.correction.constraints.Constraint`, and returns a
:class:`Correction`: the dense displacement (per joint rotation vectors and the root's
translation) that, added to the composed motion, meets the constraints, with residuals.

Pass one solves every frame inside an active range ``[start, end]`` with no smoothing; it gives
the key postures. Pass two, as section 3.3 says:

* input ramp ``[smooth_in, start)``: the effector's goal moves along the line from where the
  effector was at ``smooth_in`` (pass one; where it lies in another constraint's ramp, the
  pass-two posture there, see below) to the goal at ``start`` (Cartesian smoothing; a
  plane slides along its normal, an orientation turns along the shortest arc: each kind's
  ``ramp_goal``);
* active range: the goal itself;
* output ramp ``(end, smooth_out]``: the joint values of the constrained joint's chain, from
  the effector up to the root, are interpolated between the posture at ``end`` and the
  composed motion at ``smooth_out``; the other joints corrected at ``end`` (other
  constraints' chains) keep their correction there, fading out over the ramp. These values
  replace the attraction posture, so where another constraint is still active its IK pulls
  towards them rather than fighting them, and where none is they are the result. (The paper
  interpolates the chain towards the pass-one posture at ``smooth_out``; around other
  constraints that pops, see :func:`_output_ramps`.)

Frames that share the same set of tasks are solved together as one vectorised batch, each
starting from its attraction posture (the converted motion). With ``warm_start=True`` frames
are instead solved one by one in time order, each starting from the solution at t - 1, as the
paper does; both converge to the same posture, the posture nearest the attraction that meets
the tasks (a test checks it), and the batch is many times faster.

Outside every range ``[smooth_in, smooth_out]`` the displacement is exactly zero.

The steps, in order: :func:`_check` (the constraints that apply), :func:`_pass_one` (key
postures), :func:`_input_ramps` and :func:`_output_ramps`, :func:`_pass_two` (again where a
constraint is released or eases in inside another one's ramp, its fade or its ramp starting
from the pass-two posture, until those postures are the result's own), and
:func:`_correction` (the displacement and the corrected motion).
"""
from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from .constraints import ConstraintError
from .displacement import DisplacementMap
from .ik import IKOptions, Task, quat_to_rotvec, solve_frames
from ..errors import MotionComposerError
from ..kinematics import fk_arrays
from ..motion import Motion
from ..quaternions import qconj, qmul, qnormalize, qpow_many

__all__ = ["Correction", "Residuals", "enforce", "describe_residuals", "CHUNK_FRAMES"]

#: Frames solved together at most: a long clip is solved in chunks of this many frames so
#: that the solver's per-frame Jacobians stay within a bounded memory (a chunk's result is the
#: same as the whole batch's: every frame is solved on its own).
CHUNK_FRAMES = 2048

#: pass two is solved again at most this many times where ramps lie inside each other's
#: (each time from the postures the one before solved)
RELEASE_PASSES = 8

#: a joint whose rotation (quaternion components) never moves further than this from its
#: first frame's is held still by the conversion (rounding aside)
STILL = 1e-12


@dataclass(frozen=True, eq=False)
class Correction:
    """The result of :func:`enforce`.

    Attributes:
        motion: the corrected motion (composed motion plus displacement).
        rotvecs: ``(F, J, 3)`` [rad] dense rotation offsets (parent frame, ``exp(r) * local``).
        root: ``(F, 3)`` [m] root translation offsets.
        residual: constraint index -> ``(F,)`` the task's residual at each frame where it was
            solved (metres; radians for orientation; NaN where not solved); a
            :class:`Residuals` mapping, which keeps only the solved frames.
        iterations: ``(F,)`` solver iterations per frame in pass two.
        seconds: wall time of each pass.
    """

    motion: Motion
    rotvecs: np.ndarray
    root: np.ndarray
    residual: dict
    iterations: np.ndarray
    seconds: dict = field(default_factory=dict)

    def displacement_map(self, *, position_tolerance: float = 1e-4,
                         rotation_tolerance: float = np.radians(0.02)) -> DisplacementMap:
        """The correction as editable curves: fitted Hermite keys and slopes
        (:meth:`DisplacementMap.from_dense`), each joint's channels within
        ``position_tolerance`` [m] over its lever (at most ``rotation_tolerance`` [rad]),
        the root's within ``position_tolerance``; exactly zero where the correction is."""
        return DisplacementMap.from_dense(self.motion.skeleton, self.rotvecs, self.root,
                                          position_tolerance=position_tolerance,
                                          rotation_tolerance=rotation_tolerance)


class Residuals(Mapping):
    """Constraint index -> ``(F,)`` its residual at each frame where it was solved (NaN
    elsewhere), built on access from the solved frames alone: a long clip with thousands of
    contacts keeps memory linear in the clip, not in contacts x frames."""

    def __init__(self, num_frames: int, count: int):
        self._num_frames = num_frames
        self._parts: dict[int, list] = {i: [] for i in range(count)}

    def add(self, index: int, frames: np.ndarray, values: np.ndarray) -> None:
        """Record constraint ``index``'s residual ``values`` at ``frames`` (both ``(n,)``)."""
        self._parts[index].append((frames, values))

    def outside(self, frames: np.ndarray) -> "Residuals":
        """A copy without the values at ``frames`` (a boolean mask ``(F,)``)."""
        out = Residuals(self._num_frames, len(self._parts))
        for i, parts in self._parts.items():
            for f, values in parts:
                keep = ~frames[f]
                if keep.any():
                    out.add(i, f[keep], values[keep])
        return out

    def extend(self, other: "Residuals") -> None:
        """Add ``other``'s values (at frames this one does not hold)."""
        for i, parts in other._parts.items():
            self._parts[i].extend(parts)

    def __getitem__(self, index: int) -> np.ndarray:
        parts = self._parts[index]
        out = np.full(self._num_frames, np.nan)
        for frames, values in parts:
            out[frames] = values
        return out

    def __iter__(self):
        return iter(self._parts)

    def __len__(self) -> int:
        return len(self._parts)


def _check(constraints, composed: Motion) -> list:
    """The enabled constraints, each on a joint of the target and within the clip."""
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
        if c.smooth_in == c.start == c.end == c.smooth_out and 0 < c.start < F - 1:
            raise ConstraintError(
                f"constraint {c.name or c.joint!r}: the range {list(c.range)} holds the joint on "
                "one frame with no ramps, so it would jump there and back; give it ramps "
                "(smooth_in < start or end < smooth_out) or a longer range", "range")
        out.append(c)
    return out


def _assign_slots(entries, cons, sk, F) -> list[dict]:
    """Task slots: entries on the same joint, task kind and priority share a slot unless their
    frames overlap. Each slot holds the per-frame task goal and weight, and the index of the
    constraint that owns each frame."""
    slots: list[dict] = []
    for i, frames, goals in entries:
        if len(frames) == 0:
            continue
        c = cons[i]
        kind = c.kind_object.task_kind
        j = sk.index[c.joint]
        home = None
        for sl in slots:
            if sl["joint"] == j and sl["kind"] is kind and sl["priority"] == c.priority and \
                    not np.any(sl["weight"][frames] > 0):
                home = sl
                break
        if home is None:
            home = {"joint": j, "kind": kind, "priority": c.priority,
                    "goal": np.tile(kind.neutral_goal(), (F, 1)), "weight": np.zeros(F),
                    "owner": np.full(F, -1)}
            slots.append(home)
        home["goal"][frames] = goals
        home["weight"][frames] = c.weight
        home["owner"][frames] = i
    return slots


@dataclass(frozen=True, eq=False)
class _Problem:
    """What every solve of one :func:`enforce` shares: the composed motion (the attraction
    posture), the enabled constraints, the settings and the caller's hooks."""

    composed: Motion
    cons: list
    options: IKOptions
    warm_start: bool
    progress: object
    cancel: object
    chunk_frames: int = CHUNK_FRAMES
    locked: frozenset = frozenset()

    @property
    def skeleton(self):
        return self.composed.skeleton

    @property
    def num_frames(self) -> int:
        return self.composed.num_frames

    def check_cancel(self) -> None:
        if self.cancel is not None and self.cancel():
            raise MotionComposerError("the correction was cancelled")


def _still_joints(composed: Motion) -> frozenset:
    """Joints the correction does not turn: those the composed motion holds still while
    others move (a ground-level root node, a zero-length hip joint). Turning them would
    animate what the conversion leaves still (and a root node on the floor turns the whole
    body about a far pivot: the cheapest way for the solver, a pop for the animator)."""
    rot = composed.rotations
    if len(rot) < 2:
        return frozenset()
    still = np.all(np.abs(rot - rot[:1]) <= STILL, axis=(0, 2))
    return frozenset() if still.all() else frozenset(np.flatnonzero(still).tolist())


def _one_sided(c) -> bool:
    """Whether ``c`` only ever pushes (a plane on one side, no ramps): on a frame whose
    attraction posture is on its side and where no other task is solved it changes nothing."""
    return (c.kind_object.one_sided(c.goal) and c.smooth_in == c.start
            and c.end == c.smooth_out)


def _where_needed(problem: _Problem, entries, attraction_rot, attraction_tra) -> list:
    """``entries`` with each one-sided plane (:func:`_one_sided`, such as a whole-clip floor)
    kept only on the frames where the attraction posture puts its joint on the wrong side or
    another entry is solved: elsewhere the solve would return the attraction posture, so those
    frames stay the attraction posture bit for bit and cost nothing."""
    lone = [k for k, (i, _, _) in enumerate(entries) if _one_sided(problem.cons[i])]
    if not lone:
        return entries
    F = problem.num_frames
    solved = np.zeros(F, dtype=bool)
    for k, (_, frames, _) in enumerate(entries):
        if k not in lone:
            solved[frames] = True
    sk = problem.skeleton
    joints = sorted({sk.index[problem.cons[entries[k][0]].joint] for k in lone})
    # the effectors' positions on the frames solved for nothing else (in chunks: bounded
    # memory on a long clip)
    position = {j: np.zeros((F, 3)) for j in joints}
    free_frames = np.flatnonzero(~solved)
    for lo in range(0, len(free_frames), problem.chunk_frames):
        f = free_frames[lo:lo + problem.chunk_frames]
        pose = fk_arrays(sk, attraction_rot[f], attraction_tra[f], end_sites=False)
        for j in joints:
            position[j][f] = pose.positions[:, j]
    out = list(entries)
    for k in lone:
        i, frames, goals = entries[k]
        c = problem.cons[i]
        free = ~solved[frames]
        keep = ~free
        at = position[sk.index[c.joint]][frames[free]]
        keep[free] = c.kind_object.violated(goals[free], at)
        out[k] = (i, frames[keep], goals[keep])
    return out


def _solve(problem: _Problem, entries, attraction_rot, attraction_tra):
    """Solve the frames that ``entries`` cover: a list of (constraint index, frames, per-frame
    task goals), as :func:`_where_needed` leaves them. Entries share task slots where they do
    not overlap in time, so all frames form one batch. Returns rot, tra, residual per
    constraint, iterations."""
    sk, F = problem.skeleton, problem.num_frames
    rot = attraction_rot.copy()
    tra = attraction_tra.copy()
    residual = Residuals(F, len(problem.cons))
    iters = np.zeros(F, dtype=np.intp)
    slots = _assign_slots(entries, problem.cons, sk, F)
    if not slots:
        return rot, tra, residual, iters
    covered = np.zeros(F, dtype=bool)
    for slot in slots:
        covered |= slot["weight"] > 0
    frames = np.flatnonzero(covered)
    tasks = [Task(sl["kind"], sl["joint"], sl["goal"][frames], sl["weight"][frames],
                  sl["priority"])
             for sl in slots]
    if problem.warm_start:
        res, it = _solve_in_time_order(problem, tasks, frames, rot, tra, attraction_rot,
                                       attraction_tra)
    else:
        res, it = _solve_in_chunks(problem, tasks, frames, rot, tra, attraction_rot,
                                   attraction_tra)
    iters[frames] = it
    for col, sl in enumerate(slots):
        owner = sl["owner"][frames]
        order = np.argsort(owner, kind="stable")         # each owner's frames, in one sort
        ids, first = np.unique(owner[order], return_index=True)
        for i, sel in zip(ids, np.split(order, first[1:])):
            if i >= 0:
                residual.add(int(i), frames[sel], res[sel, col])
    problem.check_cancel()
    return rot, tra, residual, iters


def _solve_in_chunks(problem: _Problem, tasks, frames, rot, tra, attraction_rot,
                     attraction_tra):
    """``frames`` solved as batches of at most ``problem.chunk_frames``, each from its
    attraction posture; ``rot`` and ``tra`` are updated in place. Returns residuals ``(n, T)``
    and iterations ``(n,)``."""
    res = np.zeros((len(frames), len(tasks)))
    it = np.zeros(len(frames), dtype=np.intp)
    for lo in range(0, len(frames), problem.chunk_frames):
        part = slice(lo, lo + problem.chunk_frames)
        f = frames[part]
        rot[f], tra[f], res[part], it[part] = solve_frames(
            problem.skeleton, [task.take(part) for task in tasks], rot[f], tra[f],
            attraction_rot[f], attraction_tra[f, 0], problem.options, problem.locked)
        problem.check_cancel()
    return res, it


def _solve_in_time_order(problem: _Problem, tasks, frames, rot, tra, attraction_rot,
                         attraction_tra):
    """The paper's scheme: ``frames`` one by one, each from the solution at t - 1 where there
    is one; ``rot`` and ``tra`` are updated in place. Returns residuals and iterations."""
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
            problem.skeleton, [task.take([k]) for task in tasks], r0, t0,
            attraction_rot[f:f + 1], attraction_tra[f:f + 1, 0], problem.options,
            problem.locked)
        rot[f], tra[f] = r[0], t[0]
        if problem.cancel is not None and k % 64 == 0:
            problem.check_cancel()
        if problem.progress is not None and k % 64 == 0:
            problem.progress(k / len(frames))
    return res, it


def _active_entries(cons) -> list:
    """(constraint index, frames, task goals) of every constraint over ``[start, end]``."""
    entries = []
    for i, c in enumerate(cons):
        frames = np.arange(c.start, c.end + 1)
        entries.append((i, frames, c.kind_object.task_goals(c, frames)))
    return entries


def _pass_one(problem: _Problem):
    """The key postures: every frame inside an active range, with no smoothing."""
    composed = problem.composed
    entries = _where_needed(problem, _active_entries(problem.cons), composed.rotations,
                            composed.translations)
    rot1, tra1, _, _ = _solve(problem, entries, composed.rotations, composed.translations)
    return rot1, tra1


def _input_ramps(problem: _Problem, rot1, tra1) -> list:
    """Per constraint, the entry of its input ramp ``(smooth_in, start)`` (``None`` for none):
    the goal moves from where the effector is at ``smooth_in`` in the posture ``rot1``,
    ``tra1`` (pass one's, or an earlier pass two's where ramps overlap) to the goal at
    ``start`` (the kind's :meth:`~engine.correction.constraints.ConstraintKind.ramp_goal`)."""
    sk = problem.skeleton
    need = sorted({c.smooth_in for c in problem.cons if c.smooth_in < c.start})
    effector_at = {}
    if need:
        pose = fk_arrays(sk, rot1[need], tra1[need], end_sites=False)
        for k, f in enumerate(need):
            effector_at[f] = (pose.positions[k], pose.rotations[k])
    entries = []
    for i, c in enumerate(problem.cons):
        if c.smooth_in < c.start - 1:
            j = sk.index[c.joint]
            pos, wrot = effector_at[c.smooth_in]
            frames = np.arange(c.smooth_in + 1, c.start)
            u = (frames - c.smooth_in) / (c.start - c.smooth_in)
            goals = np.array([c.kind_object.ramp_goal(c, pos[j], wrot[j], x) for x in u])
            entries.append((i, frames, goals))
        else:
            entries.append(None)
    return entries


def _chain(sk, joint: int) -> np.ndarray:
    return np.array(sorted(sk.ancestors(joint) + [joint]), dtype=np.intp)


def _output_ramps(problem: _Problem, rot1, tra1):
    """The attraction posture over the output ramps ``(end, smooth_out)``.

    On the constrained joint's chain the joint values are interpolated from the posture at
    ``end`` to the composed motion at ``smooth_out``, the posture every frame after the ramp
    is solved from (the pass-one posture at ``smooth_out``, as the paper has it, would carry
    the corrections of the constraints active there, which their own tasks then add once
    more: a jump at ``smooth_out``). The other joints the posture at ``end`` corrects (other
    constraints' chains) keep that correction, fading out linearly over the ramp, so that the
    constraints still active start from where they were instead of sharing their correction
    anew among the joints the released one held (a jump at ``end``). Where ramps overlap, the
    one that faded least shapes a frame. ``rot1``, ``tra1``: the posture whose values at
    ``end`` the ramps start from. Returns the attraction rotations and translations and the
    frames they changed."""
    sk, F = problem.skeleton, problem.num_frames
    composed = problem.composed
    attraction_rot = composed.rotations.copy()
    attraction_tra = composed.translations.copy()
    touched = np.zeros(F, dtype=bool)
    held = np.zeros(F)                      # the share of its posture at end a frame keeps
    for c in problem.cons:
        if c.smooth_out > c.end + 1:
            frames = np.arange(c.end + 1, c.smooth_out)
            u = (frames - c.end) / (c.smooth_out - c.end)
            more = 1.0 - u > held[frames]
            frames, u = frames[more], u[more]
            if not len(frames):
                continue
            chain = _chain(sk, sk.index[c.joint])
            a, b = rot1[c.end, chain], composed.rotations[c.smooth_out, chain]
            steps = qpow_many(qmul(b, qconj(a)), u)                               # (n, C, 4)
            attraction_rot[frames[:, None], chain[None, :]] = qnormalize(qmul(steps, a))
            others = np.flatnonzero(np.any(rot1[c.end] != composed.rotations[c.end], axis=-1))
            others = np.setdiff1d(others, chain)
            if len(others):
                offset = qmul(rot1[c.end, others], qconj(composed.rotations[c.end, others]))
                fade = qpow_many(offset, 1.0 - u)                                 # (n, O, 4)
                attraction_rot[frames[:, None], others[None, :]] = qnormalize(
                    qmul(fade, composed.rotations[frames[:, None], others[None, :]]))
            root_a, root_b = tra1[c.end, 0], composed.translations[c.smooth_out, 0]
            attraction_tra[frames, 0] = root_a + (root_b - root_a) * u[:, None]
            held[frames] = 1.0 - u
            touched[frames] = True
    return attraction_rot, attraction_tra, touched


def _overlapping_ramps(cons) -> bool:
    """Whether a constraint ends, or starts its input ramp, inside another one's ramps (where
    pass two's posture differs from pass one's)."""
    ends = [c.end for c in cons if c.smooth_out > c.end + 1]
    ends += [c.smooth_in for c in cons if c.smooth_in < c.start - 1]
    return any(d.smooth_in <= e <= d.smooth_out and not d.start <= e <= d.end
               for e in ends for d in cons)


@dataclass(frozen=True, eq=False)
class _PassTwo:
    """A result of :func:`_pass_two`: the posture ``rot``, ``tra``, the residuals and
    iterations, the frames it ``changed``; what it was solved against (``attraction_rot``,
    ``attraction_tra`` and the input ramps' entries ``ramps``) and how many frames it solved
    ``again`` (all of them the first time)."""

    rot: np.ndarray
    tra: np.ndarray
    residual: Residuals
    iterations: np.ndarray
    changed: np.ndarray
    attraction_rot: np.ndarray
    attraction_tra: np.ndarray
    ramps: list
    again: int


def _moved(result: _PassTwo, attraction_rot, attraction_tra, ramps) -> np.ndarray:
    """``(F,)`` the frames whose attraction posture or input-ramp goal differs from what
    ``result`` was solved against."""
    moved = (np.any(attraction_rot != result.attraction_rot, axis=(1, 2))
             | np.any(attraction_tra != result.attraction_tra, axis=(1, 2)))
    for now, then in zip(ramps, result.ramps):
        if now is not None:
            moved[now[1][np.any(now[2] != then[2], axis=1)]] = True
    return moved


def _pass_two(problem: _Problem, released, previous: _PassTwo | None = None) -> _PassTwo:
    """The result: the active ranges and the input ramps solved against the attraction
    posture that the output ramps shape, each fading out from the posture ``released``
    (``(rot, tra)``) has at its ``end``, each input ramp starting from where ``released``
    puts the effector at ``smooth_in``. ``previous``: an earlier pass two, whose frames are
    kept where their attraction posture and goals are the same (every frame is solved on its
    own, so solving them again would give them again)."""
    ramps = _input_ramps(problem, *released)
    entries = []
    for active, ramp in zip(_active_entries(problem.cons), ramps):
        entries += [active] if ramp is None else [active, ramp]
    attraction_rot, attraction_tra, touched = _output_ramps(problem, *released)
    entries = _where_needed(problem, entries, attraction_rot, attraction_tra)
    changed = touched.copy()
    for _, frames, _ in entries:
        changed[frames] = True
    if previous is None:
        rot2, tra2, residual, iters = _solve(problem, entries, attraction_rot, attraction_tra)
        return _PassTwo(rot2, tra2, residual, iters, changed, attraction_rot, attraction_tra,
                        ramps, problem.num_frames)
    again = _moved(previous, attraction_rot, attraction_tra, ramps)
    entries = [(i, frames[again[frames]], goals[again[frames]]) for i, frames, goals in entries]
    rot2, tra2, residual, iters = _solve(problem, entries, attraction_rot, attraction_tra)
    keep = ~again
    rot2[keep], tra2[keep] = previous.rot[keep], previous.tra[keep]
    iters[keep] = previous.iterations[keep]
    residual.extend(previous.residual.outside(again))
    return _PassTwo(rot2, tra2, residual, iters, changed, attraction_rot, attraction_tra, ramps,
                    int(again.sum()))


def _correction(composed: Motion, rot2, tra2, changed, residual, iters, timings) -> Correction:
    """The displacement from the composed motion to the pass-two result on the ``changed``
    frames (exactly zero elsewhere) and the corrected motion."""
    sk = composed.skeleton
    base_rot = composed.rotations
    base_tra = composed.translations
    rot = base_rot.copy()
    tra = base_tra.copy()
    rot[changed] = rot2[changed]
    tra[changed, 0] = tra2[changed, 0]
    rotvecs = np.zeros((composed.num_frames, sk.num_joints, 3))
    moved = np.any(rot != base_rot, axis=-1)                       # (F, J), bit for bit
    rotvecs[moved] = quat_to_rotvec(qmul(rot[moved], qconj(base_rot[moved])))
    root = tra[:, 0] - base_tra[:, 0]
    motion = _apply_dense(composed, rotvecs, root, moved)
    return Correction(motion=motion, rotvecs=rotvecs, root=root, residual=residual,
                      iterations=iters, seconds=timings)


def enforce(composed: Motion, constraints, *, options: IKOptions | None = None,
            warm_start: bool = False, progress=None, cancel=None,
            chunk_frames: int = CHUNK_FRAMES) -> Correction:
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
        chunk_frames: at most this many frames are solved as one batch (bounds the memory
            of a long clip; the result does not depend on it); >= 1.
    """
    from ..describe import stature

    cons = _check(constraints, composed)
    options = options if options is not None else IKOptions()
    if options.scale is None:
        options = dataclasses.replace(options, scale=max(stature(composed), 0.1))
    if chunk_frames < 1:
        raise ValueError(f"chunk_frames must be at least 1, not {chunk_frames}")
    problem = _Problem(composed, cons, options, warm_start, progress, cancel, chunk_frames,
                       _still_joints(composed))
    timings = {}
    t0 = time.perf_counter()
    rot1, tra1 = _pass_one(problem)
    timings["pass one"] = time.perf_counter() - t0
    if progress is not None:
        progress(0.5)
    t0 = time.perf_counter()
    result = _pass_two(problem, (rot1, tra1))
    if _overlapping_ramps(problem.cons):
        # a constraint released (or easing in) while another one's ramp is still fading lets
        # go of (or starts from) the posture pass two solved there, not pass one's: solved
        # again from it (the frames whose attraction posture or goal that changes), until
        # the postures the ramps start from are the result's own (ramps one inside another)
        for _ in range(RELEASE_PASSES):
            result = _pass_two(problem, (result.rot, result.tra), previous=result)
            if not result.again:
                break
    rot2, tra2, residual, iters, changed = (result.rot, result.tra, result.residual,
                                            result.iterations, result.changed)
    timings["pass two"] = time.perf_counter() - t0
    if progress is not None:
        progress(1.0)
    return _correction(composed, rot2, tra2, changed, residual, iters, timings)


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


def describe_residuals(correction: Correction, constraints) -> list[dict]:
    """Per constraint: the largest and mean residual over its active range (in the kind's
    ``residual_unit``: metres, radians for orientation), and its range."""
    out = []
    active = [c for c in constraints if c.enabled]
    for i, c in enumerate(active):
        res = correction.residual.get(i)
        window = res[c.start:c.end + 1] if res is not None else np.array([np.nan])
        out.append({"constraint": c.name or c.joint, "joint": c.joint, "kind": c.kind,
                    "range": list(c.range), "residual_unit": c.kind_object.residual_unit,
                    "max_residual": float(np.nanmax(window)) if np.any(np.isfinite(window))
                    else None,
                    "mean_residual": float(np.nanmean(window)) if np.any(np.isfinite(window))
                    else None})
    return out
