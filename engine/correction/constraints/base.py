"""What a constraint kind is: the interface each kind module implements.

A kind (one module each: :mod:`.position`, :mod:`.trajectory`, :mod:`.plane`,
:mod:`.orientation`) carries everything that differs between kinds, so that the constraint
record, the enforcement, the IK solver, the project files and the GUI ask the kind instead of
testing its name:

* its goal: validation (a :class:`ConstraintError` naming the field), its JSON encoding, the
  point it carries over to another kind, the goal taken from a pose;
* the IK task it is solved as (after mink: a task is an error and a Jacobian): the per-frame
  task goal, the input-ramp goal, the error rows and their Jacobian at the posture the solver
  describes with a :class:`~engine.correction.ik.TaskState`;
* a declarative description for the inspector (:class:`GoalField` per editable goal value)
  and the viewport (how its goal is drawn).

Adding a kind is a module with a :class:`ConstraintKind` subclass and its instance ``KIND``,
listed in :data:`~engine.correction.constraints.KINDS`; the inspector builds its page from
its fields, the viewport draws it if its ``draw`` is one of :data:`DRAWINGS`.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ... import limits
from ...errors import MotionComposerError

if TYPE_CHECKING:
    from ..ik import TaskState

__all__ = ["ConstraintError", "ConstraintKind", "GoalField", "DRAWINGS"]

#: how a goal is drawn in the viewport: a point, a path over the active range, a plane, the
#: axes of a frame at the joint
DRAWINGS = ("point", "path", "plane", "axes")


class ConstraintError(MotionComposerError):
    """A constraint that cannot be used; the message names the constraint and the field.

    Attributes:
        field: the offending field (``"goal.point"``, ``"range"``, ...), or ``None``.
    """

    def __init__(self, message: str, field: str | None = None):
        super().__init__(message)
        self.field = field


def unit_vector(v: np.ndarray) -> np.ndarray:
    """``v`` scaled to length 1; a vector already of unit length (within 1e-12) is kept bit for
    bit, so that a constraint read back from a file is the constraint that was written."""
    big = np.abs(v).max()
    if big > 1e150:                           # the norm would overflow to inf
        v = v / big
    norm = np.linalg.norm(v)
    return v if abs(norm - 1.0) <= 1e-12 else v / norm


def numbers(value, field: str, label: str, what: str) -> np.ndarray:
    """``value`` (numbers, or nested lists of them) as a float array; a
    :class:`ConstraintError` on ``field`` saying ``what`` it must be when an element is not a
    number (a string, a boolean, null) or the lists are ragged."""
    def plain(v) -> bool:
        if isinstance(v, np.ndarray):
            return v.dtype.kind in "iuf"
        if isinstance(v, (list, tuple)):
            return all(plain(x) for x in v)
        return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
    try:
        if not plain(value):
            raise ValueError
        return np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ConstraintError(f"{label}: {field} must be {what}, not {value!r}",
                              field) from None


def vector(value, n: int, field: str, label: str) -> np.ndarray:
    """``value`` as ``n`` finite floats; a :class:`ConstraintError` on ``field`` otherwise."""
    arr = numbers(value, field, label, f"{n} numbers").reshape(-1)
    if arr.shape != (n,) or not limits.all_usable(arr):
        raise ConstraintError(f"{label}: {field} must be {n} finite numbers of magnitude at "
                              f"most {limits.MAX_MAGNITUDE:g}, not {value!r}", field)
    return arr


@dataclass(frozen=True)
class GoalField:
    """One editable value of a goal, as the inspector shows it.

    Attributes:
        key: the goal's key (``"point"``, ``"normal"``, ``"quaternion"``).
        label: the form's row label.
        editor: ``"vector"`` three numbers; ``"euler"`` a rotation (a quaternion) shown as
            world XYZ Euler angles; ``"summary"`` read only, the kind's :meth:`summary`.
        unit: shown after each number (``"m"``, ``"°"``; ``""`` for none).
        name: the value in undo texts (``"Set plane point of ..."``).
        tooltip: what it is, in the GUI's words.
        decimals, step, bounds: the spin boxes' precision, step and range.
    """

    key: str
    label: str
    editor: str = "vector"
    unit: str = ""
    name: str = ""
    tooltip: str = ""
    decimals: int = 3
    step: float = 0.01
    bounds: tuple[float, float] = (-1e4, 1e4)


class ConstraintKind(ABC):
    """A constraint kind; one instance of each in :data:`~engine.correction.constraints.KINDS`.

    Attributes:
        name: the kind's name in files (``"position"``).
        label: its name in the GUI (``"Position"``).
        variants: the values of the kind's variant (a plane's side), ``(None,)`` for a kind
            without one.
        fields: the goal's values as the inspector edits them.
        draw: how the viewport draws the goal (one of :data:`DRAWINGS`).
        drag_key: the goal point the viewport's gizmo drags, or ``None``.
        fixed_point: the goal holds the joint at one point over the whole range.
        rows: the task's error rows in the IK.
        goal_size: the length of the task goal vector (per frame).
        angular: the task's error is an angle [rad] (else a length [m]).
    """

    name: str = ""
    label: str = ""
    variants: tuple = (None,)
    fields: tuple = ()
    draw: str = "point"
    drag_key: str | None = None
    fixed_point: bool = False
    rows: int = 3
    goal_size: int = 3
    angular: bool = False

    def __repr__(self) -> str:
        return f"<constraint kind {self.name}>"

    @property
    def residual_unit(self) -> str:
        """The unit of the task's residual: ``"rad"`` for an angular task, else ``"m"``."""
        return "rad" if self.angular else "m"

    # ------------------------------------------------------------------ goal
    @abstractmethod
    def validate(self, goal: dict, start: int, end: int, label: str) -> dict:
        """The goal as stored (arrays, normalised), for a constraint active from ``start`` to
        ``end``; a :class:`ConstraintError` naming the field otherwise."""

    def variant(self, goal: dict):
        """The goal's variant (one of :attr:`variants`)."""
        return None

    def choice_label(self, variant) -> str:
        """The kind combo's text for ``variant``."""
        return self.label

    def describe(self, goal: dict) -> str:
        """The kind in words, its variant included (``"plane above"``)."""
        return self.name

    def summary(self, c) -> str:
        """A read-only goal in words (for a ``"summary"`` field)."""
        return ""

    def goal_point(self, c, frames: np.ndarray) -> np.ndarray:
        """``(n, 3)`` [m] goal positions of ``c`` at ``frames`` (kinds whose goal is a point)."""
        raise ConstraintError(f"a {self.name} constraint has no goal point")

    def carried_point(self, c, frame: int):
        """The point ``c``'s goal carries over to another kind at ``frame`` (``None``)."""
        return None

    @abstractmethod
    def converted_goal(self, c, variant, here: np.ndarray, turn: np.ndarray, frame: int) -> dict:
        """``c``'s goal as this kind: what carries over is kept, the rest comes from the
        joint's world position ``here`` [m] and rotation ``turn`` (x, y, z, w) at ``frame``."""

    @abstractmethod
    def goal_from_pose(self, c, positions: np.ndarray, rotations: np.ndarray, frame: int,
                       index: int) -> dict:
        """``c``'s goal where joint ``index`` is in a pose (``(F, J, 3)`` world positions [m],
        ``(F, J, 4)`` world rotations) at ``frame``."""

    def moved_goal(self, goal: dict, offset: np.ndarray) -> dict:
        """``goal`` moved by ``offset`` ``(3,)`` [m] in the world with the character: its
        ``"point"`` moves (a position's, a plane's); directions and orientations do not."""
        return {**goal, "point": goal["point"] + offset} if "point" in goal else goal

    def retimed_goal(self, c, shift: int | None) -> dict:
        """``c``'s goal once its range changes (``shift``: the whole range moved by so many
        frames)."""
        return c.goal

    # ------------------------------------------------------------------ files
    def goal_to_json(self, goal: dict) -> dict:
        """The goal as plain JSON values (arrays as lists)."""
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in goal.items()}

    # ------------------------------------------------------------------ IK task
    @property
    def task_kind(self) -> "ConstraintKind":
        """The kind whose rows the IK solves this kind with (constraints of one task kind, on
        one joint and priority, share a task slot where their frames do not overlap)."""
        return self

    def neutral_goal(self) -> np.ndarray:
        """``(goal_size,)`` the task goal of a slot's frames no constraint owns."""
        return np.zeros(self.goal_size)

    @abstractmethod
    def task_goals(self, c, frames: np.ndarray) -> np.ndarray:
        """``(n, goal_size)`` the task goals of ``c`` at its active ``frames``."""

    def chain(self, skeleton, joint: int) -> list[int]:
        """The joints whose rotation moves the task on ``joint``, sorted: its ancestors."""
        return sorted(skeleton.ancestors(joint))

    def active(self, goal: np.ndarray, state: "TaskState") -> np.ndarray:
        """``(B,)`` where the task acts (a one-sided task does not while satisfied)."""
        return np.ones(state.batch, dtype=bool)

    def one_sided(self, goal: dict) -> bool:
        """Whether a constraint with the stored ``goal`` only pushes its joint (no pull while
        satisfied: :meth:`violated` says where it acts)."""
        return False

    def violated(self, goal: np.ndarray, position: np.ndarray) -> np.ndarray:
        """``(B,)`` where a one-sided task with task goals ``(B, goal_size)`` acts on its joint
        at world positions ``(B, 3)`` [m] (everywhere for a kind that is not one-sided)."""
        return np.ones(len(goal), dtype=bool)

    def acts(self, goal: np.ndarray, error: np.ndarray) -> np.ndarray:
        """``(B,)`` where the task acts given task goals ``(B, goal_size)`` and its error rows
        ``(B, rows)`` (as :meth:`active` at a posture with that error: everywhere for a kind
        that is not one-sided). The IK asks it of the error a step would leave."""
        return np.ones(len(goal), dtype=bool)

    @abstractmethod
    def error(self, goal: np.ndarray, state: "TaskState") -> np.ndarray:
        """``(B, rows)`` the task error (goal minus current) for task goals ``(B, goal_size)``."""

    @abstractmethod
    def jacobian(self, goal: np.ndarray, state: "TaskState") -> np.ndarray:
        """``(B, rows, 3 + 3C)`` d(current) / d(root translation, chain rotation vectors)."""
