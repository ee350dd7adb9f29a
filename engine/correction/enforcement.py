"""Enforcing Cartesian constraints over time (the paper's section 3): key postures, eased
ramps and a displacement map.

:func:`enforce` takes the composed (directly converted) motion, which is the attraction
posture of every frame, and a list of :class:`~engine.correction.constraints.Constraint`, and returns a
:class:`Correction`: the dense displacement (per joint rotation vectors and the root's
translation) that, added to the composed motion, meets the constraints, with residuals.

Every frame is solved from the composed motion with the tasks active there (``[start, end]``
of each constraint, and the one-sided planes such as the floor where they are needed): the
key postures (a frame whose composed posture puts a joint under a floor is solved from above
it as well, and the posture nearer the composed one kept: :func:`_nearer_from_above`). A ramp
eases its constraints' correction in and out along a smoothstep ``s`` of the ramp's fraction
(zero slope at both ends): the correction they make at the ramp's key frame (``start`` of an
input ramp ``(smooth_in, start)``, ``end`` of an output ramp
``(end, smooth_out)``), the posture solved there with them less the posture solved there
without them, is added to each ramp frame's own posture (solved with the tasks active on
that frame) times ``s`` (input) or ``1 - s`` (output). A ramp alone gives ``exp(s r)
direct`` with ``r`` the key posture's correction, the form the no-pop rule of issue 14 is
built on: no joint turns faster than the direct conversion plus 1.5 times the correction
over the ramp. Ramps keyed on the same frame are taken off it one at a time, shortest first,
so that their corrections add up to the key posture's (with the first go the constraints
that switch on or off there without a ramp of their own, such as a toe held from the flat
foot on: the posture without the ramps is the one inside them). The key postures hold the
goals held across the ramp too (another's ramp keyed back to back, on the frame next to the
key frame), so that each ramp's correction is what it adds to them. A key posture of its own
starts from the correction solved on the frame next to the key frame inside the ramp, which
holds the same tasks as the posture without the ramp's constraints: near a stretched leg,
postures far apart meet the same tasks, and one found from the composed posture instead can
differ from its neighbour's by degrees, which the ramp would turn in one frame. The sum
meets the tasks held on those frames (another foot's contact) only nearly; they are solved
again from it (pass two), the posture each frame starts from and is pulled towards. That
repair depends on the tasks held, which change at a ramp's key frame: the change is eased
over the ramp like its correction, and the ramp's frames are solved again from there
(:func:`_ease_repairs`).

(The paper moves the goal along a straight line over the input ramp and interpolates the
joint values over the output ramp; solved from the converted motion the line's postures can
turn a stretched knee or shift the compromise between the root and the hips from frame to
frame. Holding the goal at its key frame on every ramp frame instead, and blending those
postures, still pops: the converted joint runs away from the held goal, so the held posture's
correction grows or shrinks within the ramp faster than the ramp eases it.)

Frames that share the same set of tasks are solved together as one vectorised batch, each
starting from its attraction posture (the converted motion). With ``warm_start=True`` frames
are instead solved one by one in order, each starting from the solution before, as the paper
does; both converge to the same posture, the posture nearest the attraction that meets the
tasks (a test checks it), and the batch is many times faster.

Outside every range ``[smooth_in, smooth_out]`` the displacement is exactly zero.

The steps, in order: :func:`_check` (the constraints that apply), :func:`_ramp_units` and
:func:`_virtual_frames` (the postures to solve: the clip's frames and the key frames without
their ramps), :func:`_pass_one` (solving them and :func:`_blend`), :func:`_pass_two` (the
held tasks again on the blended frames), :func:`_ease_repairs` (pass two's repairs eased
across the key frames) and :func:`_correction` (the displacement and the corrected motion).
"""
from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from .constraints import ConstraintError
from .displacement import DisplacementMap
from .ik import IKOptions, Task, column_scale, effector, quat_to_rotvec, solve_frames
from ..errors import MotionComposerError
from ..kinematics import fk_joints
from ..motion import Motion
from ..quaternions import qconj, qmul, qnormalize, qrot

__all__ = ["Correction", "Residuals", "enforce", "describe_residuals", "largest_residuals",
           "CHUNK_FRAMES"]

#: Frames solved together at most: a long clip is solved in chunks of this many frames so
#: that the solver's per-frame Jacobians stay within a bounded memory (a chunk's result is the
#: same as the whole batch's: every frame is solved on its own).
CHUNK_FRAMES = 2048

#: a joint whose rotation (quaternion components) never moves further than this from its
#: first frame's is held still by the conversion (rounding aside)
STILL = 1e-12

#: ramps (of distinct frames or direction) that may overlap on one frame at most (automatic
#: contacts overlap two or three; a tangle of more is refused by name: a user's handles
#: moved by mistake, whose corrections would pile up)
MAX_OVERLAPPING_RAMPS = 8


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
        iterations: ``(F,)`` solver iterations per frame: the most of its solves in pass one,
            pass two's where a ramp's blend was solved again.
        seconds: wall time of each pass.
        glitches: the frames solved from the way between their neighbours: the capture
            thrown out and back for one frame under a held goal
            (:func:`~engine.correction.glitches.held_glitches`).
    """

    motion: Motion
    rotvecs: np.ndarray
    root: np.ndarray
    residual: dict
    iterations: np.ndarray
    seconds: dict = field(default_factory=dict)
    glitches: tuple = ()

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

    def worst(self) -> np.ndarray:
        """``(F,)`` per frame the largest residual of any constraint solved there (-inf where
        none was), in one pass over the values held."""
        out = np.full(self._num_frames, -np.inf)
        for parts in self._parts.values():
            for frames, values in parts:
                np.maximum.at(out, frames, np.where(np.isnan(values), -np.inf, values))
        return out

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


def _check(constraints, composed: Motion, pins: bool = False) -> list:
    """The enabled constraints, each on a joint of the target and within the clip; a
    one-frame range with no ramps inside the clip is refused unless ``pins``."""
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
        if not pins and c.smooth_in == c.start == c.end == c.smooth_out and \
                0 < c.start < F - 1:
            raise ConstraintError(
                f"constraint {c.name or c.joint!r}: the range {list(c.range)} holds the joint on "
                "one frame with no ramps, so it would jump there and back; give it ramps "
                "(smooth_in < start or end < smooth_out) or a longer range", "range")
        out.append(c)
    return out


def _assign_slots(entries, cons, sk, F) -> list[dict]:
    """Task slots: entries on the same joint, task kind and priority share a slot unless their
    frames overlap. Each slot holds the per-frame task goal and weight, and the index of the
    constraint that owns each frame. A one-sided entry that another slot already holds on
    every one of its frames, with the same goals and weight (the floor the automatic
    contacts make and the project's floor on the same joint), is that slot's *twin*
    (``twins``: constraint index -> frames): its residual is the slot's. Solved as a second
    task, it held its joint on the bound through the active set's releases, which free one
    hold at a time while its twin keeps the joint there: the CMU walk onto the Bandai
    skeleton with ``--auto-contacts --floor 0`` pinned a toe to the floor on one frame of a
    swing (5.7 cm below both neighbours, a pop of 1.8 times the no-pop limit)."""
    slots: list[dict] = []
    for i, frames, goals in entries:
        if len(frames) == 0:
            continue
        c = cons[i]
        kind = c.kind_object.task_kind
        j = sk.index[c.joint]
        if c.kind_object.one_sided(c.goal):
            twin = next((sl for sl in slots if sl["joint"] == j and sl["kind"] is kind and
                         sl["priority"] == c.priority and
                         np.all(sl["weight"][frames] == c.weight) and
                         np.array_equal(sl["goal"][frames], goals)), None)
            if twin is not None:
                twin["twins"][i] = frames
                continue
        home = None
        for sl in slots:
            if sl["joint"] == j and sl["kind"] is kind and sl["priority"] == c.priority and \
                    not np.any(sl["weight"][frames] > 0):
                home = sl
                break
        if home is None:
            home = {"joint": j, "kind": kind, "priority": c.priority,
                    "goal": np.tile(kind.neutral_goal(), (F, 1)), "weight": np.zeros(F),
                    "owner": np.full(F, -1), "twins": {}}
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
    #: ``(F,)`` per frame the frame a warm start begins from (-1: none); ``None``: ``f - 1``
    previous: np.ndarray | None = None
    #: ``(F,)`` the frames whose result is wanted (:func:`enforce`'s ``frames``); ``None``:
    #: every frame
    wanted: np.ndarray | None = None
    #: joint -> ``(anchor, offset)``: the control joints carried with limbs, held through
    #: them (:func:`~.ik.effector`)
    carried: dict | None = None

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
    kept only on the frames where another entry is solved or where the attraction posture
    puts its joint, or another plane's, on the wrong side: elsewhere the solve would return
    the attraction posture, so those frames stay the attraction posture bit for bit and cost
    nothing."""
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
    # where each acts (a carried control joint: the point its limb carries)
    acts = {j: effector(j, problem.carried) for j in joints}
    anchors = sorted({a for a, _ in acts.values()})
    # the effectors' positions on the frames solved for nothing else (in chunks: bounded
    # memory on a long clip)
    position = {j: np.zeros((F, 3)) for j in joints}
    free_frames = np.flatnonzero(~solved)
    for lo in range(0, len(free_frames), problem.chunk_frames):
        f = free_frames[lo:lo + problem.chunk_frames]
        # those joints alone (fk_arrays' positions bit for bit)
        turn, pose = fk_joints(sk, attraction_rot[f], attraction_tra[f], anchors)
        for j, (a, point) in acts.items():
            k = anchors.index(a)
            position[j][f] = pose[:, k] if point is None else \
                pose[:, k] + qrot(turn[:, k], np.broadcast_to(point, (len(f), 3)))
    # a frame where one plane acts is solved, and then every plane holds there too: left
    # out, a plane its joint is on the right side of at the start could not stop the solve
    # pushing the joint through it (a floor under one foot lifting the body while the other
    # foot sinks: 49 mm into the floor on the bundled walk's frames 225, with the residual
    # reporting none)
    acting = solved.copy()
    for k in lone:
        i, frames, goals = entries[k]
        c = problem.cons[i]
        free = ~solved[frames]
        at = position[sk.index[c.joint]][frames[free]]
        acting[frames[free][c.kind_object.violated(goals[free], at)]] = True
    out = list(entries)
    for k in lone:
        i, frames, goals = entries[k]
        keep = acting[frames]
        out[k] = (i, frames[keep], goals[keep])
    return out


def _solve(problem: _Problem, entries, attraction_rot, attraction_tra, start=None,
           only=None):
    """Solve the frames that ``entries`` cover: a list of (constraint index, frames, per-frame
    task goals), as :func:`_where_needed` leaves them, each from the attraction posture, or
    from ``start`` (rot, tra), which then receives the solved frames in place (a second
    solve over a long clip's arrays costs no copy of them). Entries share task slots where
    they do not overlap in time, so all frames form one batch. ``only`` (a mask ``(F,)``)
    solves those of the frames alone (with a warm start a frame starts from the one before
    only where that one was solved in this call; pass two's eased repairs each start from
    their own posture): the slots are assigned over every entry's frames first, so that the
    frames solved get the same tasks, in the same slots, as in the solve of all (each frame
    of a batch is solved on its own: the same values).
    Returns rot, tra, residual per constraint, iterations."""
    sk, F = problem.skeleton, problem.num_frames
    rot, tra = (attraction_rot.copy(), attraction_tra.copy()) if start is None else start
    residual = Residuals(F, len(problem.cons))
    iters = np.zeros(F, dtype=np.intp)
    slots = _assign_slots(entries, problem.cons, sk, F)
    if not slots:
        return rot, tra, residual, iters
    covered = np.zeros(F, dtype=bool)
    for slot in slots:
        covered |= slot["weight"] > 0
    if only is not None:
        covered &= only
    frames = np.flatnonzero(covered)
    if not len(frames):
        return rot, tra, residual, iters
    tasks = []
    for sl in slots:
        joint, point = effector(sl["joint"], problem.carried)
        tasks.append(Task(sl["kind"], joint, sl["goal"][frames], sl["weight"][frames],
                          sl["priority"], point=point))
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
        for i, held in sl["twins"].items():
            at = np.flatnonzero(np.isin(frames, held))
            if len(at):
                residual.add(int(i), frames[at], res[at, col])
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
    previous = (np.arange(problem.num_frames) - 1 if problem.previous is None
                else problem.previous)
    solved = np.zeros(problem.num_frames, dtype=bool)
    for k, f in enumerate(frames):
        p = previous[f]
        if p >= 0 and solved[p]:
            r0 = rot[p:p + 1].copy()
            t0 = tra[f:f + 1].copy()
            t0[:, 0] = tra[p, 0]
        else:
            r0, t0 = rot[f:f + 1], tra[f:f + 1]
        r, t, res[k:k + 1], it[k:k + 1] = solve_frames(
            problem.skeleton, [task.take([k]) for task in tasks], r0, t0,
            attraction_rot[f:f + 1], attraction_tra[f:f + 1, 0], problem.options,
            problem.locked)
        rot[f], tra[f] = r[0], t[0]
        solved[f] = True
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


def smoothstep(u: np.ndarray) -> np.ndarray:
    """``3u^2 - 2u^3``: from 0 at ``u = 0`` to 1 at ``u = 1``, with zero slope at both ends and
    at most 1.5 between (:data:`~engine.correction.quality.SMOOTHSTEP_PEAK`)."""
    return u * u * (3.0 - 2.0 * u)


def _ramp_units(cons) -> list:
    """The ramps, those with the same frames and direction taken together (a foot's heel pin
    and its flat turn): ``(lo, hi, rising, constraint indices)``; the ramp's inner frames are
    ``lo + 1 .. hi - 1``, where the constraints' share is ``smoothstep((t - lo) / (hi - lo))``
    (rising, an input ramp ``(smooth_in, start)``) or one minus it (an output ramp
    ``(end, smooth_out)``)."""
    units: dict[tuple, list] = {}
    for i, c in enumerate(cons):
        if c.start - c.smooth_in >= 2:
            units.setdefault((c.smooth_in, c.start, True), []).append(i)
        if c.smooth_out - c.end >= 2:
            units.setdefault((c.end, c.smooth_out, False), []).append(i)
    return [(lo, hi, rising, idx) for (lo, hi, rising), idx in sorted(units.items())]


def _check_overlaps(problem: _Problem, units) -> None:
    """Refuse a frame inside more than :data:`MAX_OVERLAPPING_RAMPS` ramps, by name."""
    F = problem.num_frames
    count = np.zeros(F + 1, dtype=np.intp)
    for lo, hi, _, _ in units:
        if hi - lo >= 2:
            count[lo + 1] += 1
            count[hi] -= 1
    count = np.cumsum(count)[:F]
    if len(count) and count.max() > MAX_OVERLAPPING_RAMPS:
        t = int(np.argmax(count > MAX_OVERLAPPING_RAMPS))
        here = [k for k, (lo, hi, _, _) in enumerate(units) if lo < t < hi]
        names = sorted({problem.cons[i].name or problem.cons[i].joint
                        for k in here for i in units[k][3]})
        raise ConstraintError(
            f"{len(here)} ramps overlap at frame {t} (constraints {', '.join(names)}); "
            f"at most {MAX_OVERLAPPING_RAMPS} can be eased together: shorten or move some "
            "of their smooth_in/smooth_out handles", "range")


def _virtual_frames(problem: _Problem, units):
    """The postures to solve: each clip frame once with the tasks active there, then at each
    ramp's key frame (``start`` of an input ramp, ``end`` of an output one) the same frame
    again without its ramps' constraints, removed one ramp at a time.

    The ramps keyed on one frame and side are removed shortest first: each one's correction
    (:func:`_pass_one`) is then what its constraints add given the longer ramps' still held,
    as they mostly are while the shorter one eases. In the same way the constraints held on
    the ramps' inner frames but not on the key frame (another's ramp keyed on the frame next
    to it, back to back: a toe let go on frame 72 while the other heel is planted on 73) are
    held in the key postures too, at their goals on the frame next to the key frame (a key
    posture with its ramps' constraints is then a posture of its own, not the clip frame's):
    each ramp's correction is what it adds to the tasks held across it. Added up
    separately, two corrections each solved without the other's goals missed both by far
    (12 degrees of the hips apart on the CC3 walk onto the glTF fox), and pass two's repair
    jumped between the two frames.

    Returns ``src (V,)`` each virtual frame's clip frame (the first ``F`` are the clip's
    frames), per virtual frame the constraint indices it leaves out, per constraint the
    virtual frames that hold it at its goal on their ``inner`` frame, per ramp ``(unit,
    virtual frame with its constraints, virtual frame without)``, and ``inner (V,)`` per
    virtual frame beyond the clip's the clip frame next to its key frame on the ramps' side
    (``start - 1`` of an input ramp, ``end + 1`` of an output one; -1 for the clip's own):
    the frame whose tasks are the key frame's without the ramps', and those added."""
    F = problem.num_frames
    src = list(range(F))
    inner_of = [-1] * F
    removed: list[tuple] = [()] * F
    added: dict[int, list] = {}
    deltas = []
    groups: dict[tuple, list] = {}
    for k, (lo, hi, rising, _) in enumerate(units):
        groups.setdefault((hi if rising else lo, rising), []).append(k)
    cons = problem.cons
    starts = np.array([c.start for c in cons], dtype=np.intp)
    ends = np.array([c.end for c in cons], dtype=np.intp)
    for (key, rising), ks in sorted(groups.items()):
        ks.sort(key=lambda k: (units[k][1] - units[k][0], k))
        # constraints that switch on (off) at the key frame without a ramp of their own (a
        # toe held from the flat foot on) go with the shortest ramp keyed there: the posture
        # without the ramps is then the one inside them
        inner = key - 1 if rising else key + 1
        eased = {i for k in ks for i in units[k][3]}
        at_key = (starts <= key) & (ends >= key)
        at_inner = (starts <= inner) & (ends >= inner)
        switch = tuple(i for i in np.flatnonzero(at_key & ~at_inner).tolist()
                       if i not in eased)
        extra = np.flatnonzero(at_inner & ~at_key).tolist()
        before, gone, first = key, switch, len(src)
        if extra:
            src.append(key)
            inner_of.append(inner)
            removed.append(())
            before = len(src) - 1
        for k in ks:
            gone = gone + tuple(units[k][3])
            src.append(key)
            inner_of.append(inner)
            removed.append(gone)
            deltas.append((k, before, len(src) - 1))
            before = len(src) - 1
        for i in extra:
            added.setdefault(i, []).extend(range(first, len(src)))
    return (np.array(src, dtype=np.intp), removed, added, deltas,
            np.array(inner_of, dtype=np.intp))


def _virtual_entries(problem: _Problem, src, removed, added, inner) -> list:
    """Entries over virtual frames: each constraint where it is active at the clip frame (its
    goal there), unless the virtual frame leaves it out, and on the virtual frames that add
    it (its goal at their ``inner`` frame)."""
    F = problem.num_frames
    keys = np.arange(F, len(src))                # the key frames' postures without ramps
    entries = []
    for i, c in enumerate(problem.cons):
        more = keys[(src[keys] >= c.start) & (src[keys] <= c.end)]
        more = more[[i not in removed[v] for v in more]] if len(more) else more
        extra = np.array(added.get(i, ()), dtype=np.intp)
        held = np.concatenate([np.arange(c.start, c.end + 1), more, extra]).astype(np.intp)
        at = np.concatenate([np.arange(c.start, c.end + 1), src[more], inner[extra]])
        entries.append((i, held, c.kind_object.task_goals(c, at.astype(np.intp))))
    return entries


def _offsets(rot, base):
    """Rotation vectors ``(n, J, 3)`` of ``rot * base^-1``: exactly zero where a joint's
    rotation is its base's bit for bit."""
    moved = np.any(rot != base, axis=-1)
    out = np.zeros(moved.shape + (3,))
    out[moved] = quat_to_rotvec(qmul(rot[moved], qconj(base[moved])))
    return out


def _blend(problem: _Problem, rot_v, tra_v, src, units, deltas):
    """The clip's posture: each frame as solved with the tasks active there, plus on the
    frames inside ramps each ramp's correction at its key frame (the posture with its
    constraints less the posture without, as rotation vectors per joint and the root's
    offset) times its share, a smoothstep over the ramp. Returns rot, tra and the frames
    inside ramps."""
    composed = problem.composed
    F = problem.num_frames
    base_rot = composed.rotations
    rot, tra = rot_v[:F].copy(), tra_v[:F].copy()
    blended = np.zeros(F, dtype=bool)
    if not deltas:
        return rot, tra, blended
    J = base_rot.shape[1]
    total = np.zeros((F, J, 3))
    shift = np.zeros((F, 3))
    for k, with_, without in deltas:
        lo, hi, rising, _ = units[k]
        t = np.arange(lo + 1, hi)
        if not len(t):
            continue
        key = src[with_]
        pair = _offsets(rot_v[[with_, without]], base_rot[[key, key]])
        s = smoothstep((t - lo) / (hi - lo))
        share = s if rising else 1.0 - s
        total[t] += share[:, None, None] * (pair[0] - pair[1])[None]
        shift[t] += share[:, None] * (tra_v[with_, 0] - tra_v[without, 0])[None]
        blended[t] = True
    from .ik import rotvec_to_quat
    frames = np.flatnonzero(blended)
    r = rot[frames]
    turned = np.any(total[frames] != 0.0, axis=-1)
    if turned.any():
        offset = _offsets(r, base_rot[frames]) + total[frames]
        r[turned] = qnormalize(qmul(rotvec_to_quat(offset[turned]), base_rot[frames][turned]))
    rot[frames] = r
    tra[frames, 0] += shift[frames]
    return rot, tra, blended


def _virtual(problem: _Problem, src) -> _Problem:
    """The problem over virtual frames (the composed motion's frames ``src``). Its first
    ``F`` are the clip's frames, so a warm start begins from the frame before as over the
    clip; the key frames beyond them start from their neighbour's correction
    (:func:`_start_from_inner`)."""
    composed = problem.composed
    motion = Motion._trusted(composed.skeleton, composed.rotations[src],
                             composed.translations[src], composed.frame_time, composed.name)
    return dataclasses.replace(problem, composed=motion)


def _map_residuals(residual: Residuals, src, keep, num_frames: int) -> Residuals:
    """Residuals over virtual frames ``keep`` (a mask) as residuals over their clip frames."""
    out = Residuals(num_frames, len(residual))
    for i in residual:
        values = residual[i]
        v = np.flatnonzero(keep & np.isfinite(values))
        if len(v):
            out.add(i, src[v], values[v])
    return out


def _pass_one(problem: _Problem):
    """The key postures and the blend over the ramps: the clip's frames solved from the
    composed motion (and from above the floors: :func:`_nearer_from_above`), then each key
    posture of its own (without its ramps' constraints, or with the goals held across the
    ramp: :func:`_virtual_frames`) solved from the correction next to it on the ramps' side
    (:func:`_start_from_inner`), then each ramp's correction eased in or out over it
    (:func:`_blend`). Returns rot, tra, residuals (of the clip's frames), iterations, the
    frames solved and the frames blended (both ``(F,)``)."""
    F = problem.num_frames
    units = _ramp_units(problem.cons)
    _check_overlaps(problem, units)
    src, removed, added, deltas, inner = _virtual_frames(problem, units)
    virtual = _virtual(problem, src)
    entries = _where_needed(virtual, _virtual_entries(problem, src, removed, added, inner),
                            virtual.composed.rotations, virtual.composed.translations)
    clip = np.arange(len(src)) < F
    needed = _needed_virtual(problem, units, deltas, inner, len(src))
    clip_entries = _restricted(entries, clip)
    rot_v, tra_v, residual_v, iters_v = _solve(virtual, clip_entries,
                                               virtual.composed.rotations,
                                               virtual.composed.translations, only=needed)
    residual_v = _nearer_from_above(virtual, clip_entries, rot_v, tra_v, residual_v,
                                    iters_v, needed)
    if not clip.all():
        # a key posture without its ramps that holds no task at all is the composed posture
        # itself: started from a neighbour's correction it would stay there, unsolved, and
        # keep what the neighbour holds and it does not (before key postures held the goals
        # held across their ramps: a toe let go on frame 138 of the CC3 walk onto the fox
        # while the other foot is planted on 139, the planted foot's correction, 9 degrees
        # of the leg, was taken off at 138 and eased back in over the toe's ramp)
        held = np.zeros(len(src), dtype=bool)
        for _, frames, _ in entries:
            held[frames] = True
        _start_from_inner(virtual.composed, rot_v, tra_v, inner, ~clip & held)
        # each from its start, in the paper's scheme too; solved into rot_v, tra_v
        _, _, residual_k, iters_k = _solve(
            dataclasses.replace(virtual, previous=np.full(len(src), -1, np.intp)),
            _restricted(entries, ~clip), virtual.composed.rotations,
            virtual.composed.translations, start=(rot_v, tra_v), only=needed)
        residual_v.extend(residual_k)
        iters_v[~clip] = iters_k[~clip]
    rot, tra, blended = _blend(problem, rot_v, tra_v, src, units, deltas)
    iters = np.zeros(F, dtype=np.intp)
    np.maximum.at(iters, src, iters_v)
    solved = np.zeros(F, dtype=bool)
    for _, frames, _ in entries:
        solved[src[frames]] = True
    return rot, tra, _map_residuals(residual_v, src, clip, F), iters, solved, blended


#: how much nearer its attraction posture (in the solver's weighted norm,
#: :func:`_distance`) a frame solved from above the one-sided planes must end than the same
#: frame solved from the attraction posture to be kept instead (:func:`_nearer_from_above`):
#: a solve's own scatter is far below it, a trap far above (0.3 at the least measured)
NEARER = 1e-3


def _distance(problem: _Problem, rot, tra, frames) -> np.ndarray:
    """``(n,)`` how far the postures ``rot``, ``tra`` are from the attraction posture on
    ``frames``, in the norm the solver's least-norm steps minimise: each joint's turn and the
    root's translation divided by their weights (:func:`~.ik.column_scale`)."""
    sk, composed = problem.skeleton, problem.composed
    weight = column_scale(sk, np.arange(sk.num_joints), problem.options.scale)
    out = np.zeros(len(frames))
    for lo in range(0, len(frames), problem.chunk_frames):
        f = frames[lo:lo + problem.chunk_frames]
        turn = quat_to_rotvec(qmul(rot[f], qconj(composed.rotations[f])))
        shift = tra[f, 0] - composed.translations[f, 0]
        out[lo:lo + len(f)] = np.sqrt(
            np.sum((shift / weight[:3]) ** 2, axis=1)
            + np.sum((turn / weight[3:].reshape(-1, 3)) ** 2, axis=(1, 2)))
    return out


def _nearer_from_above(problem: _Problem, entries, rot, tra, residual: Residuals, iters,
                       only) -> Residuals:
    """Pass one's frames whose attraction posture puts a joint on the wrong side of a
    one-sided plane (a floor) solved again from above the planes (:func:`_above_planes`);
    where that ends nearer the attraction posture (by :data:`NEARER`) with its tasks met as
    well, it replaces the first solve's frame in ``rot``, ``tra`` and ``iters`` (in place).
    Returns the residuals with those frames'. The solver is a local method: started under
    the floor its first step pushes every joint up at once and can pin a foot on its own
    floor, a hold the pull to the attraction keeps (with flat feet, the CMU jumps' landing
    onto Kenney's Maya character: frame 2262 ends 0.46 from its attraction where a start
    above the floors ends at 0.10, the hips 216 mm under the frame before's). Started above,
    the pull brings the joints down onto the planes. Both are solved and the nearer kept,
    not the start above alone: from most starts under a floor both end at the same posture
    (to a solve's scatter), and a start above changing those frames' last bits would move
    what depends on them (the key fit's choices) for nothing."""
    composed = problem.composed
    start_tra = _above_planes(problem, entries, composed.rotations, composed.translations,
                              only)
    lifted = np.any(start_tra[:, 0] != composed.translations[:, 0], axis=1)
    if not lifted.any():
        return residual
    again = dataclasses.replace(problem, previous=np.full(problem.num_frames, -1, np.intp))
    rot_a, tra_a, residual_a, iters_a = _solve(
        again, entries, composed.rotations, composed.translations,
        start=(composed.rotations.copy(), start_tra), only=lifted)
    f = np.flatnonzero(lifted)
    first, second = _distance(problem, rot, tra, f), _distance(problem, rot_a, tra_a, f)
    met = residual_a.worst()[f] <= np.maximum(residual.worst()[f], problem.options.met_below())
    take = f[met & (second < first - NEARER)]
    if not len(take):
        return residual
    rot[take], tra[take] = rot_a[take], tra_a[take]
    iters[take] += iters_a[take]
    replaced = np.zeros(problem.num_frames, dtype=bool)
    replaced[take] = True
    out = residual.outside(replaced)
    out.extend(residual_a.outside(~replaced))
    return out


def _needed_virtual(problem: _Problem, units, deltas, inner, count: int):
    """``(V,)`` the virtual frames (:func:`_virtual_frames`) whose postures the frames of
    ``problem.wanted`` depend on (``None``: all, every frame wanted): those wanted; the key
    postures with and without the constraints of each ramp with an inner frame wanted
    (:func:`_blend`); and the clip frame each such key posture of its own starts from
    (:func:`_start_from_inner`). Every posture is solved on its own from its start, so the
    others can be left out."""
    wanted = problem.wanted
    if wanted is None:
        return None
    F = problem.num_frames
    needed = np.zeros(count, dtype=bool)
    needed[:F] = wanted
    for k, with_, without in deltas:
        lo, hi = units[k][0], units[k][1]
        if wanted[lo + 1:hi].any():
            needed[[with_, without]] = True
    keys = np.flatnonzero(needed[F:]) + F
    needed[inner[keys]] = True
    return needed


def _start_from_inner(composed: Motion, rot, tra, inner, frames) -> None:
    """Start postures for the key postures of their own (``frames``, a mask over virtual
    frames: without their ramps' constraints, or with the goals held across the ramps),
    written into ``rot`` and ``tra`` (which hold the composed posture there): the composed
    posture with the correction solved at the ``inner`` clip frame (per joint its rotation
    offset; the root's translation offset). That frame holds the same tasks as the posture
    without the ramps' constraints; a solve from the composed posture could end in another
    of the postures that meet them (a leg near its full stretch under a reach: 2.8 degrees of
    the hips and a centimetre of the root apart on the CMU walk onto Bandai), and the ramp
    would turn the difference in one frame."""
    base_rot, base_tra = composed.rotations, composed.translations
    v = np.flatnonzero(frames)
    n = inner[v]
    # joints the correction leaves alone start (and, with no task to move them, stay) bit
    # for bit where they are
    moved = np.any(rot[n] != base_rot[n], axis=-1)
    r = base_rot[v]
    r[moved] = qnormalize(qmul(qmul(rot[n][moved], qconj(base_rot[n][moved])), r[moved]))
    rot[v] = r
    shifted = np.any(tra[n, 0] != base_tra[n, 0], axis=-1)
    tra[v] = base_tra[v]
    tra[v[shifted], 0] += tra[n[shifted], 0] - base_tra[n[shifted], 0]


def _pass_two(problem: _Problem, rot, tra, held, only=None):
    """The tasks ``held`` (entries, :func:`_active_entries` on the blended frames) solved
    again from the blend ``rot``, ``tra`` (the key postures' corrections added up meet them
    only nearly), on the frames of ``only`` (a mask; ``None``: ``problem.wanted``). Those
    frames start next to their solution, so they settle to a tenth of the usual step: their
    tasks end as close as a solve from afar brings them. Returns rot, tra, residuals,
    iterations."""
    options = problem.options
    entries = _where_needed(problem, held, rot, tra)
    # each from its blend, with a warm start too: the blend is next to the solution, and a
    # start from the frame before's could keep a one-sided task (a floor) holding a joint
    # the blend lifts off it
    closer = dataclasses.replace(problem, options=dataclasses.replace(
        options, settle=options.settle * 0.1),
        previous=np.full(problem.num_frames, -1, dtype=np.intp))
    only = problem.wanted if only is None else only
    start = (rot.copy(), _above_planes(problem, entries, rot, tra, only))
    return _solve(closer, entries, rot, tra, start=start, only=only)


#: sweeps of the dual ascent that finds the root's move out of one-sided planes
#: (:func:`_above_planes`): planes of one normal (floors) need one, a corner a few
PLANE_SWEEPS = 50


def _above_planes(problem: _Problem, entries, rot, tra, only) -> np.ndarray:
    """A copy of ``tra`` with the root moved, on each frame of ``entries`` (and of ``only``,
    a mask; ``None``: all) where the posture ``rot``, ``tra`` puts a joint on the wrong side
    of a one-sided plane (a floor), by the shortest translation that brings every such joint
    onto its side: pass two's start there. The blend can put the feet centimetres under the
    floor (a landing's ramp in adds the key frame's turn of the foot, flat, to a foot still
    pitched toe down: the CMU jumps onto Kenney's Maya character, toes 83 mm under); from
    there the first step pushes every joint up at once, turns the feet heel down about the
    toes and pins the ankle on its own floor, a hold the pull to the blend keeps (0.18 from
    the blend, in the solver's weighted norm, where the posture nearest it that meets the
    floors is 0.05), and the neighbouring frames, which took the other way, lift the body
    (the hips 90 mm apart in one frame). From above the planes the pull to the blend brings
    the joints down onto them, and each frame ends at the posture nearest its blend."""
    tra = tra.copy()
    sk = problem.skeleton
    lone = []
    for i, frames, goals in entries:
        if problem.cons[i].kind_object.one_sided(problem.cons[i].goal) and len(frames):
            if only is not None:
                keep = only[frames]
                frames, goals = frames[keep], goals[keep]
            lone.append((sk.index[problem.cons[i].joint], frames, goals))
    if not lone:
        return tra
    acts = {j: effector(j, problem.carried) for j, _, _ in lone}
    anchors = sorted({a for a, _ in acts.values()})
    frames = np.unique(np.concatenate([f for _, f, _ in lone]))
    for lo in range(0, len(frames), problem.chunk_frames):
        f = frames[lo:lo + problem.chunk_frames]
        turn, pose = fk_joints(sk, rot[f], tra[f], anchors)
        # per plane and frame: a . d >= b for the root's move d (a the normal towards the
        # allowed side, b how far the joint is on the wrong side); -inf where not held
        a = np.zeros((len(f), len(lone), 3))
        b = np.full((len(f), len(lone)), -np.inf)
        for k, (j, fr, goals) in enumerate(lone):
            row = np.searchsorted(f, fr)
            inside = (row < len(f)) & (f[np.minimum(row, len(f) - 1)] == fr)
            row, goals = row[inside], goals[inside]
            anchor, point = acts[j]
            at = pose[row, anchors.index(anchor)]
            if point is not None:
                at = at + qrot(turn[row, anchors.index(anchor)],
                               np.broadcast_to(point, (len(row), 3)))
            toward = goals[:, 3:6] * goals[:, 6:7]
            a[row, k] = toward
            b[row, k] = -np.sum((at - goals[:, 0:3]) * toward, axis=1)
        out = (b > 0.0).any(axis=1)
        if not out.any():
            continue
        a, b = a[out], b[out]
        # the shortest d (Hildreth's dual coordinate ascent; each a is a unit vector)
        d = np.zeros((len(a), 3))
        lam = np.zeros(b.shape)
        for _ in range(PLANE_SWEEPS):
            moved = False
            for k in range(len(lone)):
                # -lam where the plane is not held on the frame (b = -inf): lam stays 0
                change = np.maximum(-lam[:, k], b[:, k] - np.sum(a[:, k] * d, axis=1))
                lam[:, k] += change
                d += change[:, None] * a[:, k]
                moved = moved or bool(np.any(change != 0.0))
            if not moved:                 # met exactly (floors: after the first sweep)
                break
        tra[f[out], 0] += d
    return tra


def _repair_boundaries(units) -> list:
    """The places where the tasks held change at a ramp's key frame: per pair of frames
    ``(a, a + 1)`` with an output ramp keyed on ``a`` or an input ramp keyed on ``a + 1``,
    ``(a, sides)`` with ``sides`` the longest such ramp on each side, ``(lo, hi, rising)``
    (its inner frames ``lo + 1 .. hi - 1``)."""
    longest: dict[tuple, tuple] = {}
    for lo, hi, rising, _ in units:
        key = (hi - 1, rising) if rising else (lo, rising)
        if key not in longest or hi - lo > longest[key][1] - longest[key][0]:
            longest[key] = (lo, hi)
    pairs: dict[int, list] = {}
    for (a, rising), (lo, hi) in sorted(longest.items()):
        pairs.setdefault(a, []).append((lo, hi, rising))
    return sorted(pairs.items())


def _repair_frames(units, wanted: np.ndarray) -> np.ndarray:
    """``wanted`` (a mask ``(F,)``) and the frames whose pass-two repair :func:`_ease_repairs`
    reads for them: the key frame and the frame next to it inside of each ramp with a wanted
    inner frame."""
    out = wanted.copy()
    for a, sides in _repair_boundaries(units):
        if any(wanted[lo + 1:hi].any() for lo, hi, _ in sides):
            out[[a, a + 1]] = True
    return out


def _ease_repairs(problem: _Problem, units, rot1, tra1, rot2, tra2, blended, held):
    """Pass two's repairs eased over the ramps. Pass two solves the tasks held on a ramp's
    frames again from the blend, and the repair it makes there (the result less the blend)
    depends on the tasks held: where a ramp's key frame, inside another ramp, holds a task
    the next frame no longer holds (a toe pinned to its last frame while the heel eases
    out), the repair changes by degrees between the two frames (6.4 degrees of the hips to
    0.6 on the CMU walk onto the fox), a turn in one frame. That change is eased like the
    ramp's own correction: added to each of the ramp's frames times the ramp's share (the
    longest ramp keyed there), so that the repair flows from the key frame's into the ramp's
    own; the tasks ``held`` on those frames (pass two's) are then solved again from there,
    as pass two solves them (the same entries over every blended frame, so the same task
    slots: a solve of some frames gives the same values bit for bit). Returns rot, tra,
    residuals, iterations and the mask ``(F,)`` of the frames eased (``None`` where nothing
    changes); ``rot2`` and ``tra2`` are overwritten."""
    F = problem.num_frames
    base = problem.composed.rotations
    want = problem.wanted
    eased = np.zeros(F, dtype=bool)
    parts = []
    for a, sides in _repair_boundaries(units):
        pair = [a, a + 1]
        if not blended[pair].any():
            continue                          # neither repaired: the blend holds there
        repair = (_offsets(rot2[pair], base[pair]) - _offsets(rot1[pair], base[pair]))
        shift = (tra2[pair, 0] - tra1[pair, 0])
        jump_rot, jump_tra = repair[0] - repair[1], shift[0] - shift[1]
        if not (np.any(jump_rot != 0.0) or np.any(jump_tra != 0.0)):
            continue
        # an input ramp on the left eases the frames before towards the repair after, an
        # output ramp on the right the frames after towards the repair before; with both
        # (a toe let go on the frame before the other heel is planted) each takes half,
        # else each would take the whole jump and the two frames would swap their repairs
        half = 1.0 / len(sides)
        for lo, hi, rising in sides:
            t = np.arange(lo + 1, hi)
            if want is not None:
                t = t[want[t]]
            if not len(t):
                continue
            s = smoothstep((t - lo) / (hi - lo))
            share = -half * s if rising else half * (1.0 - s)
            parts.append((t, share, jump_rot, jump_tra))
            eased[t] = True
    if not parts:
        return None
    # the eased start postures, written into rot2 and tra2 (read above, not needed after),
    # a chunk of frames at a time: bounded memory on a long clip
    from .ik import rotvec_to_quat
    rot, tra = rot2, tra2
    first = np.array([t[0] for t, _, _, _ in parts])
    last = np.array([t[-1] for t, _, _, _ in parts])
    frames = np.flatnonzero(eased)
    for lo in range(0, len(frames), problem.chunk_frames):
        f = frames[lo:lo + problem.chunk_frames]
        total = np.zeros((len(f), base.shape[1], 3))
        move = np.zeros((len(f), 3))
        for k in np.flatnonzero((last >= f[0]) & (first <= f[-1])):
            t, share, jr, jt = parts[k]
            inside = (t >= f[0]) & (t <= f[-1])
            row = np.searchsorted(f, t[inside])          # t lies in the eased frames f
            total[row] += share[inside, None, None] * jr[None]
            move[row] += share[inside, None] * jt[None]
        here = base[f]
        offset = _offsets(rot[f], here) + total
        turned = np.any(total != 0.0, axis=-1)
        r = rot[f]
        r[turned] = qnormalize(qmul(rotvec_to_quat(offset[turned]), here[turned]))
        rot[f] = r
        tra[f, 0] += move
    rot, tra, residual, iters = _pass_two(problem, rot, tra, held, only=eased)
    return rot, tra, residual, iters, eased


def _restricted(entries, mask: np.ndarray) -> list:
    """``entries`` on the frames of ``mask`` only."""
    return [(i, frames[mask[frames]], goals[mask[frames]]) for i, frames, goals in entries]


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
            chunk_frames: int = CHUNK_FRAMES, pins: bool = False,
            still: frozenset | None = None, frames: tuple[int, int] | None = None,
            carried: dict | None = None, glitches=None) -> Correction:
    """Correct ``composed`` so that ``constraints`` hold, with the two passes of section 3.3.

    Args:
        composed: the directly converted motion: the attraction posture of every frame.
        constraints: :class:`Constraint` list (disabled ones are skipped).
        options: solver settings (default :class:`IKOptions`); an unset ``scale`` is
            the composed motion's size (:func:`~engine.describe.figure_size`: its stature).
        warm_start: solve frame by frame from the solution at t - 1 (the paper's scheme)
            instead of in batches from the attraction posture.
        progress: called with a fraction in [0, 1].
        cancel: called between batches; returning True stops with
            :class:`~engine.errors.MotionComposerError`.
        chunk_frames: at most this many frames are solved as one batch (bounds the memory
            of a long clip; the result does not depend on it); >= 1.
        pins: solve one-frame ranges with no ramps inside the clip, which a user's
            constraint may not have (its joint would jump there and back) but the live
            preview's window problem makes: a constraint that only shapes a key posture,
            held on that frame (:func:`~engine.correction.preview.window_problem`).
        still: the joints the correction leaves alone; ``None`` (the default): those the
            composed motion holds still (:func:`_still_joints`). A solve of a few frames cut
            from a clip (the live preview's window) passes the whole clip's.
        frames: ``(lo, hi)``: only frames ``lo..hi`` are wanted (the live preview's window,
            spliced into the motion shown). The postures they depend on are solved as in a
            solve of every frame, each on its own, so those frames get its values bit for
            bit; the others are left out where nothing wanted depends on them, and the
            correction is zero outside ``lo..hi`` (no residuals, no iterations there).
            Ignored with ``warm_start``, where each frame starts from the one before: every
            frame is solved and kept. ``None`` (the default): every frame.
        carried: joint index -> ``(anchor, offset)``: control joints the binding carries with
            a limb (:func:`engine.conversion.followers.carriers`), whose goals the IK meets
            through the limb (:func:`~.ik.effector`): the motion it returns leaves them where
            they were, for :func:`~engine.conversion.followers.follow` to place.
        glitches: the frames to solve from the way between their neighbours (one-frame
            glitches of the capture under held goals); ``None`` (the default): those
            :func:`~engine.correction.glitches.held_glitches` finds in ``composed`` (a solve of
            a few frames cut from a clip passes the whole clip's, shifted).
    """
    from ..describe import figure_size
    from .glitches import held_glitches, without_glitches

    cons = _check(constraints, composed, pins)
    sk = composed.skeleton
    for c in cons if carried else ():
        j = sk.index[c.joint]
        if j in carried and c.kind_object.task_kind.angular:
            raise ConstraintError(f"constraint {c.name or c.joint!r}: {c.joint} is carried with "
                                  "a limb, which holds a point on it, not its orientation")
        control = next((a for a in sk.ancestors(j) if a in carried), None)
        if control is not None:
            raise ConstraintError(f"constraint {c.name or c.joint!r}: {c.joint} hangs from "
                                  f"{sk.names[control]}, which is carried with a limb and "
                                  "placed after the IK")
    options = options if options is not None else IKOptions()
    if options.scale is None:
        options = dataclasses.replace(options, scale=figure_size(composed))
    if chunk_frames < 1:
        raise ValueError(f"chunk_frames must be at least 1, not {chunk_frames}")
    wanted = None
    if frames is not None:
        lo, hi = (int(x) for x in frames)
        if not 0 <= lo <= hi < composed.num_frames:
            raise ValueError(f"frames must be (lo, hi) with 0 <= lo <= hi < "
                             f"{composed.num_frames}, not {frames!r}")
        if not warm_start:
            wanted = np.zeros(composed.num_frames, dtype=bool)
            wanted[lo:hi + 1] = True
    # the attraction posture: a one-frame glitch under a held goal is taken from the frames
    # around it (the correction undoes it there, at every joint alike)
    glitches = (held_glitches(composed, cons, options.scale) if glitches is None else
                np.unique(np.asarray(glitches, dtype=int)))
    attraction = without_glitches(composed, glitches)
    problem = _Problem(attraction, cons, options, warm_start, progress, cancel, chunk_frames,
                       _still_joints(composed) if still is None else frozenset(still),
                       wanted=wanted, carried=carried or None)
    units = _ramp_units(cons)
    # the frames pass two's repairs are eased from are solved too (bit for bit as in a solve
    # of every frame: each is solved on its own)
    reading = problem if wanted is None else dataclasses.replace(
        problem, wanted=_repair_frames(units, wanted))
    timings = {}
    t0 = time.perf_counter()
    rot1, tra1, residual, iters, changed, blended = _pass_one(reading)
    timings["pass one"] = time.perf_counter() - t0
    if progress is not None:
        progress(0.5)
    t0 = time.perf_counter()
    held = _restricted(_active_entries(cons), blended)
    rot2, tra2, residual2, iters2 = _pass_two(reading, rot1, tra1, held)
    eased = _ease_repairs(problem, units, rot1, tra1, rot2, tra2, blended, held)
    if eased is not None:
        rot2, tra2, residual3, iters3, again = eased
        residual2 = residual2.outside(again)
        residual2.extend(residual3)
        iters2[again] = iters3[again]
    residual.extend(residual2)
    iters[blended] = iters2[blended]
    changed |= blended
    if wanted is not None:                      # the wanted frames' correction alone
        changed &= wanted
        iters[~wanted] = 0
        residual = residual.outside(~wanted)
    timings["pass two"] = time.perf_counter() - t0
    if progress is not None:
        progress(1.0)
    correction = _correction(composed, rot2, tra2, changed, residual, iters, timings)
    return dataclasses.replace(correction, glitches=tuple(int(f) for f in glitches))


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


def largest_residuals(rows) -> dict:
    """The largest residual of :func:`describe_residuals` ``rows`` per unit: ``{"m": metres
    (0.0 without a metric constraint), "rad": radians (None without an angular one)}``. A
    position and an orientation are not one figure: 0.013 rad is no 13 mm."""
    out = {"m": 0.0, "rad": None}
    for row in rows:
        value = row["max_residual"]
        if value is None:
            continue
        unit = row["residual_unit"]
        out[unit] = value if out[unit] is None else max(out[unit], value)
    return out
