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

import math
import numbers
import weakref
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .. import limits
from ..errors import IKOptionsError
from ..quaternions import cmul_small, crot_small, cto_matrix, qconj, qmul, qmul_small, qnormalize
from ..skeleton import Skeleton

if TYPE_CHECKING:
    from .constraints import ConstraintKind

__all__ = ["Task", "TaskState", "IKOptions", "solve_frames", "rotvec_to_quat",
           "quat_to_rotvec", "task_error_and_jacobian"]


def _norm(x: np.ndarray, keepdims: bool = False) -> np.ndarray:
    """``np.linalg.norm(x, axis=-1)`` of a real array, bit for bit (its own arithmetic for
    one axis), without its checks: the solver takes the norms of small arrays on every
    iteration."""
    return np.sqrt(np.add.reduce(x * x, axis=-1, keepdims=keepdims))


def rotvec_to_quat(v: np.ndarray) -> np.ndarray:
    """Quaternions ``(..., 4)`` of rotation vectors ``(..., 3)`` [rad]."""
    v = np.asarray(v, dtype=float)
    angle = _norm(v, keepdims=True)
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
    s = _norm(q[..., :3], keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., 3:4])
    small = s < 1e-12
    scale = np.where(small, 2.0 / np.maximum(q[..., 3:4], 1e-12),
                     angle / np.where(small, 1.0, s))
    return q[..., :3] * scale


_EYE3 = np.eye(3)
_EYE3.setflags(write=False)


@dataclass(frozen=True)
class TaskState:
    """The kinematics of one task's joint for a batch of ``B`` frames, at the current posture.

    Attributes:
        position: ``(B, 3)`` [m] the joint's world position.
        rotation: ``(B, 4)`` its world rotation (x, y, z, w).
        pivots: ``(C, B, 3)`` [m] world positions of the chain's joints (those whose rotation
            moves the task, in column order); a list of ``C`` arrays ``(B, 3)`` will do.
        frames: ``(C, B, 3, 3)`` the world rotation of each chain joint's parent: the frame its
            rotation-vector increment is expressed in; a list of ``C`` arrays ``(B, 3, 3)``
            will do.
        point: ``(B, 3, 3 + 3C)`` :meth:`point_jacobian` if known, else ``None``.
    """

    position: np.ndarray
    rotation: np.ndarray
    pivots: np.ndarray
    frames: np.ndarray
    point: np.ndarray | None = None

    @property
    def batch(self) -> int:
        return self.position.shape[0]

    def point_jacobian(self) -> np.ndarray:
        """``(B, 3, 3 + 3C)`` d(joint position) / d(root translation, chain rotation vectors):
        the identity for the root, ``-[p - p_a]x R_parent(a)`` for chain joint ``a``, whose
        column ``c`` is ``R_parent(a)[:, c] x (p - p_a)`` (all chain joints at once; ``point``
        when the solver has it already, from another task on the joint)."""
        if self.point is not None:
            return self.point
        B, C = self.batch, len(self.pivots)
        out = np.empty((B, 3, 3 + 3 * C))
        out[:, :, :3] = _EYE3
        if C:
            d = self.position - np.asarray(self.pivots).reshape(C, B, 3)          # (C, B, 3)
            m = np.asarray(self.frames).reshape(C, B, 3, 3)
            u0, u1, u2 = m[:, :, 0], m[:, :, 1], m[:, :, 2]          # rows of R: (C, B, 3c)
            d0, d1, d2 = d[..., 0:1], d[..., 1:2], d[..., 2:3]
            blocks = np.stack([u1 * d2 - u2 * d1, u2 * d0 - u0 * d2, u0 * d1 - u1 * d0])
            out[:, :, 3:] = blocks.transpose(2, 0, 1, 3).reshape(B, 3, 3 * C)
        return out


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
        point: ``(3,)`` [m] where the task acts is this point fixed in ``joint``'s frame,
            not the joint itself (``None``): a control joint carried with a limb
            (:mod:`engine.conversion.followers`, the robot's foot past its shin) is held
            through the limb. Point kinds only (not an orientation).
    """

    kind: ConstraintKind
    joint: int
    goal: np.ndarray
    weight: np.ndarray
    priority: int = 1
    label: str = ""
    point: np.ndarray | None = None

    def __post_init__(self):
        if self.point is not None:
            if self.kind.angular:
                raise ValueError(f"task {self.label or self.kind}: an orientation acts on a "
                                 "joint, not on a point carried by it")
            point = np.array(self.point, dtype=float).reshape(3)
            point.setflags(write=False)
            object.__setattr__(self, "point", point)

    @property
    def rows(self) -> int:
        return self.kind.rows

    @property
    def acts_on(self) -> tuple:
        """What the task moves, as a key: the joint, or the joint and the point it carries."""
        return (self.joint,) if self.point is None else (self.joint, self.point.tobytes())

    def take(self, index) -> "Task":
        """The task on a subset of the batch's frames."""
        return Task(self.kind, self.joint, self.goal[index], self.weight[index], self.priority,
                    self.label, self.point)


@dataclass(frozen=True)
class IKOptions:
    """Solver settings: plain, frozen, hashable data (a cache may key results by them).

    Every field is checked on construction; a value out of its range raises
    :class:`~engine.errors.IKOptionsError` naming the field. Lengths are given as fractions
    of ``scale`` (the character's size) so that one setting suits a child and a giant.

    Attributes:
        tolerance: [m] a position or plane task is met below this error (orientation tasks
            use ``tolerance / scale`` radians); on a character larger than ``tolerance /
            MIN_TOLERANCE`` (2 m at the default) at least :data:`MIN_TOLERANCE` times
            ``scale`` (:meth:`met_below`): a tolerance of 0.1 mm on a 100 m giant (the glTF
            fox is 61 m tall) is a millionth of it, which a stretched leg converges to so
            slowly that the lower priorities it gates (a planted foot's orientation) never
            run. On a character smaller than :data:`FULL_SIZE` it shrinks with it
            (:meth:`length_share`), and so does ``settle`` for the root's translation.
            Default 1e-4 (0.1 mm); positive.
        max_iterations: the cap of iterations per frame. Default 60; a whole number >= 0.
        damping: damped least squares lambda of the task levels, as a fraction of
            ``scale``. Larger is steadier near singularities (a stretched leg) and slower to
            converge. Default 0.005; positive.
        max_step: the largest correction asked of one task per iteration, as a fraction of
            ``scale``. Default 0.05; positive.
        attraction: gain [0, 1] of the pull towards the attraction posture per iteration.
            Default 0.5.
        settle: [rad or m] a frame is done once its largest step is below this: its tasks are
            met, or as near as the higher priorities let them be, and the null-space pull has
            converged too (a frame that stops with a lower level unmet polishes first, see
            ``polish_share``). Default 1e-5; >= 0.
        nullspace_damping: the lambda, as a fraction of ``scale``, of the damped
            pseudo-inverses that project a lower level and the attraction into the null space
            of the higher levels; small, so that the projection stays nearly exact.
            Default 1e-6; positive.
        step_cap: [rad] the largest turn of any joint in one iteration; a larger step is
            scaled down as a whole (so that it stays in the higher levels' null space).
            Default 0.3; positive.
        polish_share: the share [0, 1] of ``max_iterations`` at their end during which, with
            more than one priority level, only the first level is restored (no lower level,
            no attraction): frames still going there have unreachable lower levels, which
            would otherwise end mid-oscillation. A frame that stops moving earlier with a
            lower level unmet polishes from then on, until its step is below
            :data:`POLISH_SETTLE` times ``settle``. Default 0.25 (the last quarter).
        priority_gate: a lower priority level runs in full while the higher levels are at
            most this many times their tolerance from being met, fades out linearly to
            nothing at twice that, and waits beyond (its steps are first-order invisible to
            the higher levels, but near their singularities the second-order part would push
            them off faster than they recover). Default 10; positive.
        joint_limits: ``((joint index, angle [rad]), ...)`` sorted by joint: the largest angle
            a joint may turn away from its attraction posture. A ``{joint: angle}`` mapping is
            accepted and stored as pairs. Default none; angles >= 0.
        scale: [m] the character's size (:func:`~engine.describe.figure_size`: its stature),
            a per-run value: ``None`` (the default)
            lets :func:`~engine.correction.enforcement.enforce` take the composed motion's
            stature; :func:`solve_frames` needs it set.
    """

    tolerance: float = 1e-4
    max_iterations: int = 60
    damping: float = 0.005
    max_step: float = 0.05
    attraction: float = 0.5
    settle: float = 1e-5
    nullspace_damping: float = 1e-6
    step_cap: float = 0.3
    polish_share: float = 0.25
    priority_gate: float = 10.0
    joint_limits: tuple = ()
    scale: float | None = None

    def __post_init__(self):
        for name, low, high, open_low in _NUMBER_RANGES:
            object.__setattr__(self, name, _checked_number(name, getattr(self, name), low,
                                                           high, open_low))
        count = self.max_iterations
        if isinstance(count, bool) or not isinstance(count, numbers.Integral):
            raise IKOptionsError("max_iterations", f"expected a whole number, not {count!r}")
        if count < 0:
            raise IKOptionsError("max_iterations", f"expected a whole number >= 0, not {count}")
        object.__setattr__(self, "max_iterations", int(count))
        object.__setattr__(self, "joint_limits", _checked_limits(self.joint_limits))
        if self.scale is not None:
            object.__setattr__(self, "scale", _checked_number("scale", self.scale, 0.0, None,
                                                              True))

    def length_share(self) -> float:
        """The share of the lengths given in metres (``tolerance``, ``settle`` of the root's
        translation) that holds on this character: 1 from :data:`FULL_SIZE` up, ``scale /
        FULL_SIZE`` below (with ``scale`` unset: 1), so that a small character is solved as
        the same character scaled up to that size (a tenth of a millimetre on a figure of
        2 cm, a 1 m tall file written in the wrong unit, is half a percent of it)."""
        return 1.0 if self.scale is None else length_share(self.scale)

    def met_below(self) -> float:
        """[m] the error below which a position or plane task is met: ``tolerance``, or
        :data:`MIN_TOLERANCE` times ``scale`` on a character large enough for that to be
        more, or ``tolerance`` times :meth:`length_share` on one smaller than
        :data:`FULL_SIZE` (with ``scale`` unset: ``tolerance``)."""
        if self.scale is None:
            return self.tolerance
        return max(self.tolerance * self.length_share(), MIN_TOLERANCE * self.scale)


#: (field, lowest, highest or None, lowest excluded) of the real-valued settings
_NUMBER_RANGES = (("tolerance", 0.0, None, True), ("damping", 0.0, None, True),
                  ("max_step", 0.0, None, True), ("attraction", 0.0, 1.0, False),
                  ("settle", 0.0, None, False), ("nullspace_damping", 0.0, None, True),
                  ("step_cap", 0.0, None, True), ("polish_share", 0.0, 1.0, False),
                  ("priority_gate", 0.0, None, True))


def _checked_number(name: str, value, low: float, high: float | None, open_low: bool) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise IKOptionsError(name, f"expected a number, not {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise IKOptionsError(name, f"expected a finite number, not {value!r}")
    if limits.problem(value) is not None:
        raise IKOptionsError(name, f"expected a number of magnitude at most "
                                   f"{limits.MAX_MAGNITUDE:g}, not {value!r}")
    if value < low or (open_low and value == low) or (high is not None and value > high):
        wanted = (f"from {low:g} to {high:g}" if high is not None else
                  f"above {low:g}" if open_low else f">= {low:g}")
        raise IKOptionsError(name, f"expected a number {wanted}, not {value!r}")
    return value


def _checked_limits(limits) -> tuple:
    """``joint_limits`` as sorted ``(joint, angle)`` pairs."""
    pairs = limits.items() if isinstance(limits, Mapping) else limits
    try:
        pairs = [tuple(pair) for pair in pairs]
    except TypeError:
        raise IKOptionsError("joint_limits", f"expected {{joint index: angle}} or (joint, "
                                             f"angle) pairs, not {limits!r}") from None
    out = {}
    for pair in pairs:
        if len(pair) != 2:
            raise IKOptionsError("joint_limits", f"expected (joint index, angle), not {pair!r}")
        joint, angle = pair
        if isinstance(joint, bool) or not isinstance(joint, numbers.Integral) or joint < 0:
            raise IKOptionsError("joint_limits", f"expected a joint index (a whole number >= "
                                                 f"0), not {joint!r}")
        if int(joint) in out:
            raise IKOptionsError("joint_limits", f"joint {int(joint)} is limited twice")
        out[int(joint)] = _checked_number("joint_limits", angle, 0.0, None, False)
    return tuple(sorted(out.items()))


#: the tolerance's least share of the character's size (:meth:`IKOptions.met_below`): a
#: giant's tasks are met at this fraction of its stature, a twentieth of a millimetre per metre
#: (below the default tolerance on any character up to 2 m, which it leaves alone)
MIN_TOLERANCE = 5e-5

#: [m] the least size at which the lengths of :class:`IKOptions` given in metres hold as
#: they are: on a smaller character they shrink with it (:meth:`IKOptions.length_share`),
#: so that its solve is the same as that of the character scaled up to this size. Every
#: human figure of ``../shared/data`` is taller, and is solved as before
FULL_SIZE = 1.0


def length_share(size: float) -> float:
    """The share of a length given in metres that holds on a character of ``size`` [m]
    (its stature): 1 from :data:`FULL_SIZE` up, ``size / FULL_SIZE`` below."""
    return min(1.0, size / FULL_SIZE)


#: a polishing frame (only the first level acts) is done once its step is below this share
#: of ``settle``: the first level restored to rounding, as polishing up to the cap would
POLISH_SETTLE = 1e-6

#: a frame's held one-sided tasks are checked for release every this many iterations (and
#: when it would be done)
RELEASE_EVERY = 4

#: how many times stiffer each joint is than its children in the weighted least-norm step
#: (after Baerlocher and Boulic's joint weights); 1 weighs every joint's turn alike.
#: Measured with 2 (each joint twice as stiff as its parent's other children, the
#: compliance growing with the depth below the hips): the light distal joints took the
#: corrections, so that on the demo's reach the elbow and shoulder traded 70 degrees within
#: five frames of a stretched arm (the forearm at 2,800 deg/s against the conversion's 470),
#: and a capture's one-frame 6 mm shift was absorbed by a planted foot's turn (341 deg/s at
#: frame 975 of the CMU jumps onto Holden). ``None``: the plain least norm of the first
#: projects (every unknown alike, the root's metres as radians).
STIFFNESS: float | None = 1.0

#: [statures] the root translation that weighs as much as a turn of one radian. Weighed as
#: radians (the plain least norm) the root is cheap next to the joints: on the Bandai walk onto
#: the CMU skeleton it slid 30 cm to make up for the feet, and a ramp of four frames at 30 fps
#: eased in 15 cm in one frame; at 0.3 the largest correction is 14 cm and its largest step
#: 6.8 cm, and no pair of test_foot_contacts nor the demo turns a joint visibly faster (0.5: 24
#: and 11 cm; 1, the stature: 37 and 19 cm).
ROOT_TRANSLATION = 0.3


def column_scale(skeleton: Skeleton, joints: np.ndarray, scale: float) -> np.ndarray:
    """``(3 + 3 len(joints),)`` the weight of each unknown (the root translation's three,
    then three per joint of ``joints``): the square root of its compliance, :data:`STIFFNESS`
    to the power of half the joint's depth below the topmost of ``joints``, and
    :data:`ROOT_TRANSLATION` times ``scale`` (the stature) for the root translation (all ones
    with ``STIFFNESS`` ``None``)."""
    if STIFFNESS is None:
        return np.ones(3 + 3 * len(joints))
    depth = skeleton.depth[joints].astype(float)
    below = depth - depth.min(initial=0.0)
    return np.concatenate([np.full(3, ROOT_TRANSLATION * float(scale)),
                           np.repeat(STIFFNESS ** (0.5 * below), 3)])


#: per skeleton (weakly), :class:`_Structure`'s layouts by task set; at most this many kept
_LAYOUTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_LAYOUTS_PER_SKELETON = 256


try:                            # numpy's own gufunc behind np.linalg.solve, and its error hook
    from numpy.linalg import _umath_linalg
    from numpy.linalg._linalg import _raise_linalgerror_singular
except ImportError:             # another numpy's layout: np.linalg.solve itself
    _umath_linalg = None


def _solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.solve(a, b)`` of float stacks ``a (n, k, k)`` and ``b (n, k, m)``, bit
    for bit: its gufunc under its error state (a singular matrix raises ``LinAlgError``),
    without its checks and conversions, which cost more than a small solve (the solver
    makes four or five a frame batch and iteration). A numpy whose internals differ uses
    ``np.linalg.solve``."""
    if _umath_linalg is None:
        return np.linalg.solve(a, b)
    with np.errstate(call=_raise_linalgerror_singular, invalid="call", over="ignore",
                     divide="ignore", under="ignore"):
        return _umath_linalg.solve(a, b, signature="dd->d")


def _private_solve_works() -> bool:
    """numpy's private gufunc is called as this numpy version calls it, and gives
    ``np.linalg.solve``'s result: checked once, so that a numpy whose internals changed
    falls back to the public function instead of failing in a solve."""
    if _umath_linalg is None:
        return False
    a = np.array([[[2.0, 1.0], [1.0, 3.0]]])
    b = np.array([[[1.0], [2.0]]])
    try:
        with np.errstate(call=_raise_linalgerror_singular, invalid="call"):
            got = _umath_linalg.solve(a, b, signature="dd->d")
    except Exception:           # noqa: BLE001 - any change of the private API
        return False
    return bool(np.array_equal(got, np.linalg.solve(a, b)))


if not _private_solve_works():
    _umath_linalg = None


def _eye(n: int) -> np.ndarray:
    """The ``n x n`` identity, read-only and shared (the solves add it to small matrices on
    every iteration)."""
    out = _EYES.get(n)
    if out is None:
        out = _EYES[n] = np.eye(n)
        out.setflags(write=False)
    return out


_EYES: dict[int, np.ndarray] = {}


def effector(joint: int, carried=None) -> tuple[int, np.ndarray | None]:
    """Where a task on ``joint`` acts, as ``(Task.joint, Task.point)``: the joint itself, or
    for a joint in ``carried`` (joint -> ``(anchor, offset)``, the control joints a binding
    carries with its limbs: :func:`engine.conversion.followers.carriers`) the point
    ``offset`` [m] in its anchor's frame, which the limb's turns move."""
    if carried and joint in carried:
        anchor, offset = carried[joint]
        return int(anchor), offset
    return joint, None


def point_chain(kind, skeleton: Skeleton, joint: int, point=None) -> list[int]:
    """The joints whose turn moves a task of ``kind`` on ``joint`` (its kind's chain), and
    the joint itself where the task acts on a ``point`` it carries."""
    chain = kind.chain(skeleton, joint)
    return chain if point is None else sorted(chain + [joint])


def effector_chain(kind, skeleton: Skeleton, joint: int, carried=None) -> list[int]:
    """:func:`point_chain` of a task on ``joint`` where it acts (:func:`effector`): for a
    carried joint its anchor's chain and the anchor."""
    return point_chain(kind, skeleton, *effector(joint, carried))


class _Structure:
    """What a task set needs from the skeleton: the unknown joints, each task's chain, the
    index arrays that evaluate every task at once (the joints forward kinematics places,
    level by level, and where each task's joints and columns are among them), and each
    column's weight (``colscale``, see :func:`solve_frames`)."""

    def __init__(self, skeleton: Skeleton, tasks: list[Task], locked=frozenset(),
                 options: IKOptions | None = None):
        # everything but the tasks' goals and weights depends on the tasks' kinds, joints and
        # priorities only: worked out once per skeleton and task set (a live preview solves
        # the same few task sets on every step of a drag)
        # (and on the column weights' settings, which a caller may change)
        key = (tuple((t.kind, t.acts_on, t.priority) for t in tasks), frozenset(locked),
               None if options is None else options.scale, STIFFNESS, ROOT_TRANSLATION)
        layouts = _LAYOUTS.setdefault(skeleton, {})
        layout = layouts.get(key)
        if layout is None:
            self._layout(skeleton, tasks, locked, options)
            if len(layouts) >= _LAYOUTS_PER_SKELETON:
                layouts.clear()
            layouts[key] = {k: v for k, v in vars(self).items() if k != "tasks"}
        else:
            vars(self).update(layout)
        self.tasks = tasks
        # (B, T) each task's weight is not zero, for the batch it was made with
        self.task_on = (np.stack([t.weight > 0 for t in tasks], axis=1) if tasks else None)
        # per group of tasks evaluated together, their goals ``(G, B, goal_size)``
        self.group_goals = [None if joints is None else np.stack([tasks[ti].goal
                                                                  for ti in members])
                            for members, joints, _, _, _ in self.kind_groups]

    def _layout(self, skeleton: Skeleton, tasks: list[Task], locked, options) -> None:
        self.tasks = tasks
        moving: set[int] = set()
        chains = []
        for t in tasks:
            chain = [j for j in point_chain(t.kind, skeleton, t.joint, t.point)
                     if j not in locked]
            chains.append(np.array(chain, dtype=np.intp))
            moving.update(chain)
        self.joints = np.array(sorted(moving), dtype=np.intp)     # unknown rotations
        self.others = np.setdiff1d(np.arange(skeleton.num_joints), self.joints)
        self.col = {int(j): 3 + 3 * k for k, j in enumerate(self.joints)}
        self.n = 3 + 3 * len(self.joints)
        self.chains = chains
        # FK needs every unknown joint, every task joint and their ancestors
        needed = set(self.joints.tolist())
        for t in tasks:
            needed.add(t.joint)
            needed.update(skeleton.ancestors(t.joint))
        # by depth below the root (the root first), so that each FK level is a slice
        depth = skeleton.depth
        self.fk_joints = np.array(sorted(needed, key=lambda j: (int(depth[j]), j)),
                                  dtype=np.intp)
        self.levels = sorted({t.priority for t in tasks})
        self.row0 = np.cumsum([0] + [t.rows for t in tasks])
        self.k = int(self.row0[-1])
        self._index(skeleton)
        # the weighted least norm: the unknowns are solved as y = q / colscale, so that the
        # least-norm step in y is the step of least sum((q / colscale)^2) (a plain least norm
        # without options: the Jacobian as it is)
        self.colscale = (column_scale(skeleton, self.joints, options.scale)
                         if options is not None else np.ones(self.n))
        self.task_colscale = [self.colscale[cols] for cols in self.task_cols]
        # a step's size as ``settle`` judges it: the root translation's in metres of a
        # character of FULL_SIZE (IKOptions.length_share), the turns' in radians
        self.settle_scale = self.colscale.copy()
        if options is not None:
            self.settle_scale[:3] /= options.length_share()
        # (T, T): task k pins task t's joint (see ``pins``), for all frames at once
        self.pin_matrix = np.zeros((len(tasks), len(tasks)), dtype=np.intp)
        for t, pins in enumerate(self.pins):
            self.pin_matrix[pins, t] = 1

    def _index(self, skeleton: Skeleton) -> None:
        """Positions among ``fk_joints`` ("local"): FK levels ``(joints, parents)`` by depth
        below the root, each unknown joint's parent (-1 for the root), each task's joint and
        chain, and each task's Jacobian columns."""
        local = {int(j): k for k, j in enumerate(self.fk_joints)}
        parents = skeleton.parents
        self.fk_levels, self.fk_offsets = _fk_levels(skeleton, self.fk_joints)
        # the FK joints whose local translation is the clip's (not their offset), and where
        # that is among the translated joints
        slot = {int(j): k for k, j in enumerate(skeleton.translated)}
        self.fk_moved = [k for k, j in enumerate(self.fk_joints.tolist()) if j in slot]
        self.fk_moved_slot = [slot[int(self.fk_joints[k])] for k in self.fk_moved]
        self.unknown_parent = np.array([local.get(int(parents[j]), -1) for j in self.joints],
                                       dtype=np.intp)
        self.parent_root = self.unknown_parent < 0          # unknowns in the world frame
        self.parent_local = self.unknown_parent[~self.parent_root]
        unknown = {int(j): k for k, j in enumerate(self.joints)}
        # the points tasks act on that joints carry (Task.point), placed after the FK joints:
        # per point its joint's place among them and its offset ``(3, m, 1)``
        points: dict[tuple, int] = {}
        for t in self.tasks:
            if t.point is not None:
                points.setdefault(t.acts_on, len(points))
        self.point_joint = np.array([local[e[0]] for e in points], dtype=np.intp)
        self.point_offset = np.array([np.frombuffer(e[1]) for e in points]).reshape(
            -1, 3).T[:, :, None]
        n = len(self.fk_joints)
        self.task_local = [local[t.joint] if t.point is None else n + points[t.acts_on]
                           for t in self.tasks]
        self.chain_local = [np.array([local[int(a)] for a in c], dtype=np.intp)
                            for c in self.chains]
        self.chain_unknown = [np.array([unknown[int(a)] for a in c], dtype=np.intp)
                              for c in self.chains]
        self.task_cols = [np.concatenate([np.arange(0, 3)] + [
            np.arange(self.col[int(a)], self.col[int(a)] + 3) for a in c]) for c in self.chains]
        # per task, the tasks that pin its joint to a point (a one-sided task on that joint
        # does not hold it on its bound where one is on: the pin decides, and it may hold the
        # joint clear of the bound)
        self.pins = [[k for k, u in enumerate(self.tasks) if u.kind.fixed_point
                      and u.acts_on == t.acts_on] for t in self.tasks]
        # the point tasks' (not angular) point Jacobians, one per joint and chain (the tasks
        # on one joint share it), all computed together (:func:`_point_jacobians`): per task
        # its group (None: angular), per group the range of its pairs (the group's joint and
        # each joint of its chain, in column order: their local and unknown indices)
        groups: dict[tuple, int] = {}
        self.point_group = []
        pairs = []
        for ti, (t, chain) in enumerate(zip(self.tasks, self.chains)):
            if t.kind.angular:
                self.point_group.append(None)
                continue
            key = (t.acts_on, tuple(chain.tolist()))
            if key not in groups:
                groups[key] = len(groups)
                pairs.append(ti)
            self.point_group.append(groups[key])
        sizes = [len(self.chains[ti]) for ti in pairs]
        self.point_bounds = list(zip(np.cumsum([0] + sizes)[:-1].tolist(),
                                     np.cumsum(sizes).tolist()))
        self.pair_effector = np.array([self.task_local[ti] for ti in pairs
                                       for _ in self.chains[ti]], dtype=np.intp)
        self.pair_pivot = np.concatenate([self.chain_local[ti] for ti in pairs] +
                                         [np.zeros(0, dtype=np.intp)])
        self.pair_unknown = np.concatenate([self.chain_unknown[ti] for ti in pairs] +
                                           [np.zeros(0, dtype=np.intp)])
        # tasks evaluated together (:func:`_evaluate`): those of one kind whose chains are
        # equally long, their states stacked along the batch (task after task); per group
        # its tasks, their joints, chains (local and unknown indices, ``(G, C)``) and point
        # groups
        together: dict[tuple, list] = {}
        for ti, t in enumerate(self.tasks):
            together.setdefault((t.kind, len(self.chains[ti])), []).append(ti)
        self.kind_groups = []
        for members in together.values():
            if len(members) < 2:
                self.kind_groups.append((members, None, None, None, None))
                continue
            C = len(self.chains[members[0]])
            self.kind_groups.append((
                members, np.array([self.task_local[ti] for ti in members], dtype=np.intp),
                np.array([self.chain_local[ti] for ti in members], dtype=np.intp).reshape(-1, C),
                np.array([self.chain_unknown[ti] for ti in members],
                         dtype=np.intp).reshape(-1, C),
                [self.point_group[ti] for ti in members]))


def _fk_levels(skeleton: Skeleton, fk_joints: np.ndarray) -> tuple[list, np.ndarray]:
    """For :func:`_fk_partial`: the FK levels of ``fk_joints`` (closed under ancestors, sorted
    by depth below the root) as ``(slice, parents)``, the level's joints and their parents'
    positions among them, and their offsets ``(3, n, 1)``."""
    local = {int(j): k for k, j in enumerate(fk_joints)}
    parents = skeleton.parents
    depth = skeleton.depth[fk_joints]
    levels = []
    for d in range(1, int(depth.max(initial=0)) + 1):
        here = np.flatnonzero(depth == d)
        if not len(here):
            continue
        up = np.array([local[int(parents[fk_joints[h]])] for h in here], dtype=np.intp)
        levels.append((slice(int(here[0]), int(here[-1]) + 1), up))
    return levels, skeleton.offsets[fk_joints].T[:, :, None]


def _fk_partial(skeleton: Skeleton, structure: _Structure, rot: np.ndarray,
                tra: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World rotations ``(4, n, B)`` and positions ``(3, n, B)`` [m] of ``structure.fk_joints``
    (closed under ancestors, sorted by depth: the root first) as component arrays, one depth
    level at a time, from local rotations ``rot (B, J, 4)`` and the translated joints'
    translations ``tra (B, K, 3)`` (each translated joint's place there:
    ``structure.fk_moved_slot``). A level whose joints are not translated turns their
    offsets ``(3, m, 1)`` as they are (broadcast over the batch). The points the tasks act on
    that joints carry (``Task.point``) follow the joints, with their joints' rotations."""
    joints = structure.fk_joints
    B, n = rot.shape[0], len(joints)
    local_q = rot[:, joints].transpose(2, 1, 0)                                 # (4, n, B)
    moved = structure.fk_moved
    local_t = structure.fk_offsets
    if moved:
        local_t = np.repeat(local_t, B, axis=2)
        local_t[:, moved] = tra[:, structure.fk_moved_slot].transpose(2, 1, 0)
    wq = np.empty((4, n, B))
    wp = np.empty((3, n, B))
    wq[:, 0] = local_q[:, 0]
    wp[:, 0] = local_t[:, 0]
    for here, up in structure.fk_levels:            # a level's joints: a slice
        parent_q = wq[:, up]
        wq[:, here] = cmul_small(parent_q, local_q[:, here])
        np.add(wp[:, up], crot_small(parent_q, local_t[:, here]), out=wp[:, here])
    if len(structure.point_joint):
        carrier = wq[:, structure.point_joint]
        wq = np.concatenate([wq, carrier], axis=1)
        wp = np.concatenate([wp, wp[:, structure.point_joint]
                             + crot_small(carrier, structure.point_offset)], axis=1)
    return wq, wp


def _point_jacobians(structure: _Structure, positions: np.ndarray,
                     frames: np.ndarray) -> list[np.ndarray]:
    """Per point group of ``structure`` (a joint and its chain) its
    :meth:`TaskState.point_jacobian` ``(B, 3, 3 + 3C)``, bit for bit, all groups' blocks in
    one go: ``positions (n, B, 3)`` of the FK joints, ``frames (U, B, 3, 3)`` the unknowns'
    parent rotations."""
    B = positions.shape[1]
    if len(structure.pair_pivot):
        d = positions[structure.pair_effector] - positions[structure.pair_pivot]   # (P, B, 3)
        m = frames[structure.pair_unknown]                                      # (P, B, 3, 3)
        u0, u1, u2 = m[:, :, 0], m[:, :, 1], m[:, :, 2]
        d0, d1, d2 = d[..., 0:1], d[..., 1:2], d[..., 2:3]
        blocks = np.empty((3,) + u0.shape)
        np.subtract(u1 * d2, u2 * d1, out=blocks[0])
        np.subtract(u2 * d0, u0 * d2, out=blocks[1])
        np.subtract(u0 * d1, u1 * d0, out=blocks[2])
    out = []
    for lo, hi in structure.point_bounds:
        point = np.empty((B, 3, 3 + 3 * (hi - lo)))
        point[:, :, :3] = _EYE3
        if hi > lo:
            point[:, :, 3:] = blocks[:, lo:hi].transpose(2, 0, 1, 3).reshape(B, 3, 3 * (hi - lo))
        out.append(point)
    return out


def _evaluate(skeleton: Skeleton, structure: _Structure, rot: np.ndarray, tra: np.ndarray,
              select=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every task's error rows ``(B, K)`` and Jacobian ``(B, K, N)`` at the posture, whether
    the task acts there or not, with ``on (B, T)`` (its weight is not zero) and ``acting
    (B, T)`` (on, and for a one-sided task violated). ``select`` picks the frames of the
    tasks' goals that ``rot`` holds (all by default)."""
    B = rot.shape[0]
    wq, wp = _fk_partial(skeleton, structure, rot, tra)
    positions = wp.transpose(1, 2, 0)                                           # (n, B, 3)
    frames = np.empty((len(structure.unknown_parent), B, 3, 3))
    frames[structure.parent_root] = _EYE3
    frames[~structure.parent_root] = cto_matrix(wq[:, structure.parent_local])
    err = np.empty((B, structure.k))
    jac = np.zeros((B, structure.k, structure.n))
    task_on = structure.task_on
    on = (np.ones((B, 0), dtype=bool) if task_on is None else
          task_on.copy() if select is None else task_on[select])
    acting = np.empty_like(on)
    points = _point_jacobians(structure, positions, frames)
    tasks, row0 = structure.tasks, structure.row0
    for (members, joints, pivots, unknown, point_groups), goals in zip(
            structure.kind_groups, structure.group_goals):
        if joints is None:                      # a task alone
            ti = members[0]
            task = tasks[ti]
            goal = task.goal if select is None else task.goal[select]
            e = structure.task_local[ti]
            group = structure.point_group[ti]
            state = TaskState(positions[e], wq[:, e].T, positions[structure.chain_local[ti]],
                              frames[structure.chain_unknown[ti]],
                              None if group is None else points[group])
            rows = slice(row0[ti], row0[ti] + task.rows)
            acting[:, ti] = on[:, ti] & task.kind.active(goal, state)
            err[:, rows] = task.kind.error(goal, state)
            jac[:, rows, structure.task_cols[ti]] = (task.kind.jacobian(goal, state)
                                                     * structure.task_colscale[ti])
            continue
        # G tasks of one kind with chains of C joints, as one batch of G B frames (the same
        # arithmetic per frame: bit for bit the tasks one by one, but for the sign of zeros
        # where a Jacobian's entry is zero)
        kind, G, C = tasks[members[0]].kind, len(members), pivots.shape[1]
        goal = (goals if select is None else goals[:, select]).reshape(G * B, -1)
        state = TaskState(
            positions[joints].reshape(G * B, 3), wq[:, joints].reshape(4, G * B).T,
            positions[pivots].transpose(1, 0, 2, 3).reshape(C, G * B, 3),
            frames[unknown].transpose(1, 0, 2, 3, 4).reshape(C, G * B, 3, 3),
            None if point_groups[0] is None else
            np.concatenate([points[g] for g in point_groups]))
        active = kind.active(goal, state).reshape(G, B)
        error = kind.error(goal, state).reshape(G, B, kind.rows)
        jacobian = kind.jacobian(goal, state).reshape(G, B, kind.rows, 3 + 3 * C)
        for k, ti in enumerate(members):
            rows = slice(row0[ti], row0[ti] + kind.rows)
            acting[:, ti] = on[:, ti] & active[k]
            err[:, rows] = error[k]
            jac[:, rows, structure.task_cols[ti]] = jacobian[k] * structure.task_colscale[ti]
    return err, jac, on, acting


def task_error_and_jacobian(skeleton: Skeleton, structure: _Structure, rot: np.ndarray,
                            tra: np.ndarray, select=None):
    """Errors ``(B, K)`` and Jacobians ``(B, K, N)`` of the tasks at the current posture.

    Each task's rows are its kind's error and Jacobian at the posture. Columns: root
    translation (3), then 3 per unknown joint (rotation vector in its parent's frame). Rows
    of a task that is off or not active (a satisfied one-sided plane) are zero. Weights are
    not applied here.
    ``select`` picks the frames of the tasks' goals that ``rot`` holds (all by default).
    """
    err, jac, _, acting = _evaluate(skeleton, structure, rot, tra, select)
    rows = acting[:, np.repeat(np.arange(len(structure.tasks)), np.diff(structure.row0))]
    return np.where(rows, err, 0.0), np.where(rows[:, :, None], jac, 0.0)


class _Rows:
    """The rows of a task set (``K`` in all; the tasks sorted by priority, so that each level's
    rows are one slice): ``weights (B, K)``, each row's task ``task (K,)``, the first row of
    each task ``row0 (T + 1,)``, the rows of each priority level ``levels`` (slices, highest
    first), and each row's tolerance ``tol (K,)`` (metres; radians for orientation)."""

    def __init__(self, tasks: list[Task], structure: _Structure, options: IKOptions):
        self.weights = np.concatenate([np.repeat(t.weight[:, None], t.rows, axis=1)
                                       for t in tasks], axis=1)
        self.task = np.concatenate([[i] * t.rows for i, t in enumerate(tasks)])
        self.row0 = structure.row0
        self.levels = []
        for lvl in structure.levels:
            here = np.flatnonzero([tasks[i].priority == lvl for i in self.task])
            self.levels.append(slice(int(here[0]), int(here[-1]) + 1))
        angular = np.concatenate([[t.kind.angular] * t.rows for t in tasks])
        tol = options.met_below()
        # on a character smaller than FULL_SIZE the orientation rows count their radians as
        # the arc at FULL_SIZE times the length share (IKOptions.length_share), as the
        # position rows' metres shrink with it: their balance, the step clamp and the
        # damping are then those of the character scaled up to FULL_SIZE
        share = options.length_share()
        self.unit = None if share == 1.0 else np.where(angular, share, 1.0)
        self.tol = np.where(angular, tol / options.scale * share, tol)


def solve_frames(skeleton: Skeleton, tasks: list[Task], rot: np.ndarray, tra: np.ndarray,
                 attraction_rot: np.ndarray, attraction_root: np.ndarray,
                 options: IKOptions, locked=frozenset()
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Solve a batch of frames that share ``tasks``.

    Each iteration: the tasks' errors at the current posture; a step that restores the
    priority levels in turn (:func:`_levels_step`), plus the pull towards the attraction
    posture in the null space of every task (:func:`_attraction_step`); one-sided tasks hold
    their joint on their bound once they have acted; frames whose posture has stopped moving
    and whose held tasks the step without them would not push
    through (:func:`_pushed_through`) leave the batch; the step is applied
    (:func:`_apply_step`).

    The step is the least-norm step in weighted unknowns (:data:`STIFFNESS`): each
    Jacobian column is scaled by its joint's ``colscale`` and the step found for the scaled
    unknowns is scaled back, so that the solution is the posture nearest the attraction in
    that weighted norm (the root translation in statures, see :data:`ROOT_TRANSLATION`).

    Args:
        rot: ``(B, J, 4)`` starting local rotations (the attraction posture, or the solution
            of the previous frame for a warm start).
        tra: ``(B, K, 3)`` local translations of ``skeleton.translated`` (the root's first; only
            the root's is an unknown).
        attraction_rot, attraction_root: ``(B, J, 4)`` and ``(B, 3)`` the attraction posture.
        options: the settings; ``options.scale`` must be set.
        locked: joints whose rotation is no unknown (they stay at their attraction posture).

    Returns:
        ``(rot, tra, residual, iterations)``: the solved posture, the residual per task and
        frame ``(B, T)`` (metres; radians for orientation), iterations used per frame ``(B,)``.
    """
    if options.scale is None:
        raise ValueError("solve_frames needs options.scale, the character's size [m]")
    rot = np.array(rot, dtype=float)
    tra = np.array(tra, dtype=float)
    B = rot.shape[0]
    # by priority, so that each level's rows are one slice
    order = sorted(range(len(tasks)), key=lambda i: tasks[i].priority)
    tasks = [tasks[i] for i in order]
    structure = _Structure(skeleton, tasks, locked, options)
    rows = _Rows(tasks, structure, options)
    joints = structure.joints
    # joints that move nothing constrained sit at their attraction posture
    rot[:, structure.others] = attraction_rot[:, structure.others]
    # the last share of the cap only restores the first level (for frames still going:
    # unreachable lower levels, which would otherwise end mid-oscillation; a frame that
    # stops with a lower level unmet polishes from then on)
    polish_from = int((1.0 - options.polish_share) * options.max_iterations)

    iterations = np.zeros(B, dtype=np.intp)
    residual = np.zeros((B, len(tasks)))
    active = np.arange(B)
    held_all = np.zeros((B, len(tasks)), dtype=bool)
    polish_all = np.zeros(B, dtype=bool)
    lower = slice(rows.levels[1].start if len(rows.levels) > 1 else structure.k, structure.k)
    # the attraction posture of the unknown joints, taken once (the whole posture only for
    # joint limits)
    attraction_joints = attraction_rot[:, joints]
    for it in range(options.max_iterations + 1):
        r, t = rot[active], tra[active]
        err, jac, on, acting = _evaluate(skeleton, structure, r, t, active)
        err_on = np.where(acting[:, rows.task], err, 0.0)
        residual[active] = _task_norms(err_on, structure.row0)
        if rows.unit is not None:
            err, err_on, jac = err * rows.unit, err_on * rows.unit, jac * rows.unit[:, None]
        if it == options.max_iterations:
            break
        iterations[active] += 1
        if len(rows.levels) > 1 and it >= polish_from:
            polish_all[active] = True
        polishing = polish_all[active]
        cur = r[:, joints]
        home, home_root = attraction_joints[active], attraction_root[active]

        def step(frames, rows_on):
            """The step of ``frames`` (all of them: ``None``) with the rows ``rows_on (n, K)``
            (polishing or not)."""
            every = frames is None
            frames = np.arange(len(active)) if every else frames
            out = np.empty((len(frames), structure.n))
            for polish in (False, True):
                sel = (polishing[frames] == polish).nonzero()[0]
                if len(sel) == len(frames) and every:
                    f = sel = slice(None)
                elif len(sel):
                    f = frames[sel]
                else:
                    continue
                out[sel] = _step(err[f], jac[f], rows_on[sel], rows, active[f], structure.n,
                                 options, polish, t[f, 0], cur[f], home_root[f], home[f],
                                 0.0 if polish else options.attraction, structure.colscale)
            return out

        # one-sided tasks (a floor) act where violated; once they have acted they hold their
        # joint on the bound (an active set), so that the attraction does not pull it back
        # through on every other iteration, except where a task pins the same joint
        held = held_all[active] & on & ~acting
        dq = step(None, (acting | held)[:, rows.task])
        # a frame is done when its posture has stopped moving: each level is then met or as
        # near as the higher ones let it be (a step this small moves a task by far less than
        # its tolerance), and no task it holds would leave its bound without the hold: else
        # those are released and it goes on (so that the result is the posture nearest the
        # attraction that meets the tasks, whatever the start). Held tasks are checked so
        # then, and every few iterations (a hold may keep a lower level from being met)
        size = np.abs(dq * structure.settle_scale).max(axis=1)
        settled = size < np.where(polishing, POLISH_SETTLE * options.settle, options.settle)
        check = settled | (it % RELEASE_EVERY == RELEASE_EVERY - 1)
        frames = (check & held.any(axis=1)).nonzero()[0]
        if len(frames):
            free = step(frames, acting[frames][:, rows.task])
            stay = _pushed_through(structure, active[frames], err[frames], jac[frames], free,
                                   held[frames])
            # where the step without any hold pushes several through, each is asked again
            # with the others held: one may be kept up only by the others' hold
            several = (stay.sum(axis=1) > 1).nonzero()[0]
            for ti in stay[several].any(axis=0).nonzero()[0]:
                sub = several[stay[several, ti]]
                f = frames[sub]
                others = held[f].copy()
                others[:, ti] = False
                alone = step(f, (acting[f] | others)[:, rows.task])
                only = np.zeros_like(others)
                only[:, ti] = True
                stay[sub, ti] = _pushed_through(structure, active[f], err[f], jac[f], alone,
                                                only)[:, ti]
            # one released at a time (an active set): the others' answers assumed it held
            stay |= held[frames] & (np.cumsum(held[frames] & ~stay, axis=1) > 1)
            release = (held[frames] & ~stay).any(axis=1).nonzero()[0]
            frames, stay = frames[release], stay[release]
            held[frames] = stay
            dq[frames] = free[release]
            settled[frames] = False
            again = stay.any(axis=1).nonzero()[0]
            if len(again):
                dq[frames[again]] = step(frames[again],
                                         (acting | held)[frames[again]][:, rows.task])
        # a frame that stops with a lower level unmet (out of reach, or against a higher one)
        # polishes: the first level alone, restored from the lower levels' push
        short = settled & ~polishing & (np.abs(err_on[:, lower]) > rows.tol[lower]).any(axis=1)
        polish_all[active[short]] = True
        settled &= ~short
        pinned = (on @ structure.pin_matrix) > 0
        held_all[active] = (held | acting) & on & ~pinned
        if settled.all():
            iterations[active] -= 1
            break
        keep = ~settled
        iterations[active[settled]] -= 1
        active, dq, r, t, cur = active[keep], dq[keep], r[keep], t[keep], cur[keep]
        r, t = _apply_step(dq * structure.colscale, r, t, cur, structure,
                           attraction_rot[active] if options.joint_limits else None,
                           options)
        rot[active] = r
        tra[active] = t
    unsorted = np.empty_like(residual)
    unsorted[:, order] = residual
    return rot, tra, unsorted, iterations


def _task_norms(err: np.ndarray, row0: np.ndarray) -> np.ndarray:
    """``(b, T)`` the length of each task's error rows ``err (b, K)``, task ``i``'s rows
    starting at ``row0[i]``."""
    return np.sqrt(np.add.reduceat(err * err, row0[:-1], axis=1))


def _pushed_through(structure: _Structure, active: np.ndarray, err: np.ndarray,
                    jac: np.ndarray, dq: np.ndarray, idle: np.ndarray) -> np.ndarray:
    """``(b, T)`` where an ``idle`` task (on but not acting: a satisfied one-sided plane) would
    act after the step ``dq (b, N)``, to first order: the step pushes its joint through its
    bound (``err`` and ``jac``: every task's rows, acting or not, of the ``active``
    frames)."""
    out = np.zeros_like(idle)
    for ti in idle.any(axis=0).nonzero()[0]:
        task = structure.tasks[ti]
        frames = idle[:, ti].nonzero()[0]
        rows = slice(structure.row0[ti], structure.row0[ti] + task.rows)
        after = err[frames, rows] - np.einsum("bkn,bn->bk", jac[frames, rows], dq[frames])
        out[frames, ti] = task.kind.acts(task.goal[active[frames]], after)
    return out


def _step(err: np.ndarray, jac: np.ndarray, rows_on: np.ndarray, rows: _Rows,
          active: np.ndarray, n: int, options: IKOptions, polishing: bool, root: np.ndarray,
          cur: np.ndarray, home_root: np.ndarray, home: np.ndarray, gain: float,
          colscale: np.ndarray) -> np.ndarray:
    """The step ``(b, N)`` of the ``active`` frames: the levels restored in turn
    (:func:`_levels_step`) plus the attraction's pull with ``gain`` in the null space of every
    task (:func:`_attraction_step`)."""
    dq, stacked, gram = _levels_step(err, jac, rows_on, rows, active, n, options, polishing)
    if gain == 0.0:
        return dq
    return dq + _attraction_step(stacked, gram, root, cur, home_root, home, gain, options,
                                 colscale)


def _levels_step(err: np.ndarray, jac: np.ndarray, rows_on: np.ndarray, rows: _Rows,
                 active: np.ndarray, n: int, options: IKOptions,
                 polishing: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The step ``(b, N)`` that restores the priority levels in turn, each in the null space
    of the levels above, the stacked Jacobian ``(b, K', N)`` of the levels that act and its
    Gram matrix ``(b, K', K')`` (assembled from the products each level's projection computes
    anyway).

    ``err (b, K)`` and ``jac (b, K, N)`` are every row's error and Jacobian at the ``active``
    frames, ``rows_on (b, K)`` the rows that act there; while ``polishing`` only the first
    level acts.
    """
    scale = options.scale
    lam2 = (options.damping * scale) ** 2
    ns_lam2 = (options.nullspace_damping * scale) ** 2
    err_raw = np.where(rows_on, err, 0.0)
    # clamp the correction asked of each task
    norms = _task_norms(err_raw, rows.row0)[:, rows.task]
    w = rows.weights[active] * rows_on
    err = err_raw * np.minimum(1.0, options.max_step * scale / np.maximum(norms, 1e-12)) * w
    jac = jac * w[:, :, None]
    nb = len(active)
    dq = np.zeros((nb, n))
    stacked = gram = None
    behind = np.zeros(nb)                   # how far the higher levels are from being met
    for level in rows.levels[:1] if polishing else rows.levels:
        # the frames where this level has a task: elsewhere its rows are zero and add nothing
        on = (w[:, level] > 0).any(axis=1).nonzero()[0]
        some = len(on) > 0
        if len(on) == nb:
            on = slice(None)                # every frame: views instead of copies
        rows_all = jac[:, level]
        if stacked is None:
            block = rows_all @ rows_all.transpose(0, 2, 1)
            if some:
                jl, el = rows_all[on], err[on, level]
                dq[on] += _damped_solve(jl, el, lam2, block[on])
            stacked, gram = rows_all, block
        else:
            k, m = stacked.shape[1], level.stop - level.start
            grown = np.zeros((nb, k + m, k + m))
            grown[:, :k, :k] = gram
            if some:
                jl, el = rows_all[on], err[on, level]
                above = stacked[on]
                cross = above @ jl.transpose(0, 2, 1)                          # (f, k, m)
                # the rows' part in the null space of the levels above
                coef = _solve(gram[on] + ns_lam2 * _eye(k), cross)
                jt = jl - coef.transpose(0, 2, 1) @ above
                # a lower level waits while a higher one is not met: its steps are
                # first-order invisible to the higher levels, but near their singularities
                # (a stretched leg) the second-order part would push them off faster than
                # they recover
                gate = np.clip(2.0 - behind[on] / options.priority_gate, 0.0, 1.0)[:, None]
                dq[on] += gate * _damped_solve(jt, el - (jl @ dq[on][..., None])[..., 0], lam2)
                grown[on, :k, k:] = cross
                grown[on, k:, :k] = cross.transpose(0, 2, 1)
                grown[on, k:, k:] = jl @ jl.transpose(0, 2, 1)
            stacked, gram = jac[:, :level.stop], grown
        behind = np.maximum(behind, (np.abs(err_raw[:, level]) / rows.tol[level]).max(axis=1))
    return dq, stacked, gram


def _damped_solve(a: np.ndarray, rhs: np.ndarray, lam2: float,
                  gram: np.ndarray | None = None) -> np.ndarray:
    """``a^T (a a^T + lam2 I)^-1 rhs`` for batches ``a (B, K, N)``, ``rhs (B, K)``; ``gram``:
    ``a a^T`` when known."""
    gram = a @ a.transpose(0, 2, 1) if gram is None else gram
    y = _solve(gram + lam2 * _eye(a.shape[1]), rhs[..., None])
    return (a.transpose(0, 2, 1) @ y)[..., 0]


def _attraction_step(stacked: np.ndarray, gram: np.ndarray, root: np.ndarray,
                     cur: np.ndarray, home_root: np.ndarray, home: np.ndarray, gain: float,
                     options: IKOptions, colscale: np.ndarray) -> np.ndarray:
    """The pull ``(b, N)`` towards the attraction posture, in the null space of every task.

    ``root (b, 3)`` and ``cur (b, C, 4)`` are the current root translation and rotations of
    the unknown joints, ``home_root`` and ``home`` the attraction posture's; ``stacked``
    ``(b, K, N)`` the tasks' weighted Jacobian and ``gram (b, K, K)`` its Gram matrix. The
    pull and the step are in the weighted unknowns (``q / colscale (N,)``).
    """
    nb = len(root)
    dz = np.empty((nb, stacked.shape[2]))
    dz[:, 0:3] = home_root - root
    dz[:, 3:] = quat_to_rotvec(qmul_small(home, qconj(cur))).reshape(nb, -1)
    dz *= gain / colscale
    ns_lam2 = (options.nullspace_damping * options.scale) ** 2
    coef = _solve(gram + ns_lam2 * _eye(gram.shape[1]), stacked @ dz[..., None])
    return dz - (stacked.transpose(0, 2, 1) @ coef)[..., 0]


def _apply_step(dq: np.ndarray, r: np.ndarray, t: np.ndarray, cur: np.ndarray,
                structure: _Structure, home: np.ndarray | None,
                options: IKOptions) -> tuple[np.ndarray, np.ndarray]:
    """The posture ``(r, t)`` after the step ``dq (b, N)``: the root moves, the unknown
    joints (``cur (b, C, 4)`` now) turn, the whole step scaled down so that no joint turns
    more than ``options.step_cap``, and limited joints are held within their angle of the
    attraction posture ``home (b, J, 4)`` (not needed without joint limits)."""
    joints = structure.joints
    nb = len(dq)
    t = t.copy()
    t[:, 0] += dq[:, 0:3]
    step = dq[:, 3:].reshape(nb, len(joints), 3)
    # at most step_cap for any joint in one step, scaling the whole step alike so that it
    # stays in the null space of the higher priorities
    # initial: a task on the root alone turns no joint
    biggest = _norm(step).max(axis=1, initial=0.0)
    shrink = np.minimum(1.0, options.step_cap / np.maximum(biggest, 1e-12))
    step = step * shrink[:, None, None]
    t[:, 0] += dq[:, 0:3] * (shrink[:, None] - 1.0)
    new = qnormalize(qmul_small(rotvec_to_quat(step), cur))
    for j, limit in options.joint_limits:
        if j in structure.col:
            k = int(np.searchsorted(joints, j))
            off = quat_to_rotvec(qmul(new[:, k], qconj(home[:, j])))
            ang = _norm(off, keepdims=True)
            off = off * np.minimum(1.0, limit / np.maximum(ang, 1e-12))
            new[:, k] = qmul(rotvec_to_quat(off), home[:, j])
    r = r.copy()
    r[:, joints] = new
    return r, t
