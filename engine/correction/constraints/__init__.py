"""Cartesian constraints (the paper's section 3.2): a joint, a goal, a kind and a time range.

Kinds and goals (positions in metres, internal axes: +Y up), one module each; :data:`KINDS`
maps a kind's name to the object that says what the kind does (:mod:`.base`):

* ``position`` (:mod:`.position`): ``goal = {"point": [x, y, z]}``.
* ``trajectory`` (:mod:`.trajectory`): ``goal = {"points": [[x, y, z], ...]}`` one point per
  frame from ``start`` to ``end``, or ``goal = {"keys": [[frame, x, y, z], ...]}`` a path
  through keys (linear between them, held beyond the ends).
* ``plane`` (:mod:`.plane`): ``goal = {"point": [...], "normal": [...], "side": "above" |
  "on" | "below"}``. ``above`` and ``below`` are one-sided: no pull while satisfied. The floor
  is a plane.
* ``orientation`` (:mod:`.orientation`): ``goal = {"quaternion": [x, y, z, w]}`` the joint's
  world orientation.

The time range ``smooth_in <= start <= end <= smooth_out`` (frames): active on
``[start, end]``, eased in over ``[smooth_in, start]`` and out over ``[end, smooth_out]``. A
priority level (1 is the highest; a lower level acts only in the null space of the higher
ones) and a weight (scales the task's rows within its level).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, replace

import numpy as np

from ... import limits
from . import orientation, plane, position, trajectory
from .base import ConstraintError, ConstraintKind

__all__ = ["Constraint", "ConstraintError", "ConstraintKind", "KINDS", "PLANE_SIDES",
           "constraints_to_json", "constraints_from_json", "floor_constraint"]

#: kind name -> kind, in the order the GUI lists them
KINDS: dict[str, ConstraintKind] = {k.name: k for k in (position.KIND, trajectory.KIND,
                                                        plane.KIND, orientation.KIND)}
PLANE_SIDES = plane.KIND.variants

#: the largest weight: a task's rows scaled further only drown the other tasks of its level
#: in rounding error
MAX_WEIGHT = 1e6


@dataclass(frozen=True, eq=False)
class Constraint:
    """One Cartesian constraint on a target joint over a time range (see the module doc)."""

    joint: str
    kind: str
    goal: dict
    smooth_in: int
    start: int
    end: int
    smooth_out: int
    priority: int = 1
    weight: float = 1.0
    name: str = ""
    enabled: bool = True
    auto: bool = False
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        label = f"constraint {self.name or self.joint!r}"
        if not isinstance(self.joint, str) or not self.joint:
            raise ConstraintError(f"{label}: 'joint' must name a target joint", "joint")
        if not isinstance(self.kind, str) or self.kind not in KINDS:
            raise ConstraintError(f"{label}: kind must be one of {', '.join(KINDS)}, not "
                                  f"{self.kind!r}", "kind")
        times = []
        for key in ("smooth_in", "start", "end", "smooth_out"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) and not (
                    isinstance(value, float) and value.is_integer()):
                raise ConstraintError(f"{label}: {key} must be a whole frame number, not "
                                      f"{value!r}", "range")
            object.__setattr__(self, key, int(value))
            times.append(int(value))
        if not times[0] <= times[1] <= times[2] <= times[3]:
            raise ConstraintError(
                f"{label}: the time range must satisfy smooth_in <= start <= end <= "
                f"smooth_out, got {times[0]}, {times[1]}, {times[2]}, {times[3]}", "range")
        if times[0] < 0:
            raise ConstraintError(f"{label}: smooth_in must be frame 0 or later, not {times[0]}",
                                  "range")
        if isinstance(self.priority, bool) or not isinstance(self.priority, (int, np.integer)) \
                or self.priority < 1:
            raise ConstraintError(f"{label}: priority must be a whole number from 1 (highest), "
                                  f"not {self.priority!r}", "priority")
        if isinstance(self.weight, bool) or not (
                isinstance(self.weight, (int, float)) and limits.problem(self.weight) is None
                and 0 < self.weight <= MAX_WEIGHT):
            raise ConstraintError(f"{label}: weight must be a positive number of at most "
                                  f"{MAX_WEIGHT:g}, not {self.weight!r}", "weight")
        if not isinstance(self.goal, dict):
            raise ConstraintError(f"{label}: goal must be an object, not {self.goal!r}", "goal")
        goal = self.kind_object.validate(dict(self.goal), self.start, self.end, label)
        for v in goal.values():
            if isinstance(v, np.ndarray):
                v.setflags(write=False)
        object.__setattr__(self, "goal", goal)
        object.__setattr__(self, "weight", float(self.weight))

    @property
    def kind_object(self) -> ConstraintKind:
        """What the constraint's kind does (``KINDS[kind]``)."""
        return KINDS[self.kind]

    # ------------------------------------------------------------------ time
    @property
    def range(self) -> tuple[int, int, int, int]:
        return self.smooth_in, self.start, self.end, self.smooth_out

    def with_range(self, smooth_in, start, end, smooth_out) -> "Constraint":
        return replace(self, smooth_in=smooth_in, start=start, end=end, smooth_out=smooth_out)

    def with_priority(self, priority: int) -> "Constraint":
        return replace(self, priority=priority)

    def moved(self, offset) -> "Constraint":
        """The constraint with its goal moved by ``offset`` ``(3,)`` [m] in the world
        (:meth:`ConstraintKind.moved_goal`)."""
        return replace(self, goal=self.kind_object.moved_goal(
            self.goal, np.asarray(offset, dtype=float)))

    def goal_point(self, frames: np.ndarray) -> np.ndarray:
        """``(n, 3)`` goal positions at ``frames`` for position and trajectory kinds."""
        return self.kind_object.goal_point(self, np.asarray(frames))

    def same_as(self, other, tol: float = 1e-9) -> bool:
        """Whether ``other`` is this constraint again: every field equal, the goal's numbers
        within ``tol`` [m, or the goal's own units] (a goal moved there and back ends a few
        ulps away)."""
        return isinstance(other, Constraint) and _close(self.to_dict(), other.to_dict(), tol)

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict:
        data = {"joint": self.joint, "kind": self.kind,
                "goal": self.kind_object.goal_to_json(self.goal),
                "range": [self.smooth_in, self.start, self.end, self.smooth_out],
                "priority": self.priority, "weight": self.weight}
        if self.name:
            data["name"] = self.name
        if not self.enabled:
            data["enabled"] = False
        if self.auto:
            data["auto"] = True
        if self.meta:
            data["meta"] = self.meta
        return data

    @classmethod
    def from_dict(cls, data: dict, index: int | None = None) -> "Constraint":
        label = f"constraint {index + 1}" if index is not None else "constraint"
        if not isinstance(data, dict):
            raise ConstraintError(f"{label}: expected an object, not {type(data).__name__}")
        for key in ("joint", "kind", "goal", "range"):
            if key not in data:
                raise ConstraintError(f"{label}: the field {key!r} is missing", key)
        rng = data["range"]
        if not isinstance(rng, (list, tuple)) or len(rng) != 4:
            raise ConstraintError(f"{label}: 'range' must be [smooth_in, start, end, "
                                  f"smooth_out], not {rng!r}", "range")
        unknown = set(data) - {"joint", "kind", "goal", "range", "priority", "weight", "name",
                               "enabled", "auto", "meta"}
        if unknown:
            raise ConstraintError(f"{label}: unknown field(s) {', '.join(sorted(unknown))}")
        return cls(joint=data["joint"], kind=data["kind"], goal=data["goal"],
                   smooth_in=rng[0], start=rng[1], end=rng[2], smooth_out=rng[3],
                   priority=data.get("priority", 1), weight=data.get("weight", 1.0),
                   name=data.get("name", ""), enabled=data.get("enabled", True),
                   auto=data.get("auto", False), meta=data.get("meta", {}))


def _close(a, b, tol: float) -> bool:
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(
            _close(a[k], b[k], tol) for k in a)
    if isinstance(a, (list, tuple, np.ndarray)):
        return isinstance(b, (list, tuple, np.ndarray)) and len(a) == len(b) and all(
            _close(x, y, tol) for x, y in zip(a, b))
    if isinstance(a, float) or isinstance(b, float):
        return (isinstance(a, (int, float)) and isinstance(b, (int, float))
                and abs(a - b) <= tol)
    return a == b


def constraints_to_json(constraints) -> str:
    return json.dumps({"constraints": [c.to_dict() for c in constraints]}, indent=2) + "\n"


def constraints_from_json(text: str, path=None) -> list[Constraint]:
    where = f"{path}: " if path else ""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConstraintError(f"{where}not valid JSON at line {exc.lineno}, column "
                              f"{exc.colno}: {exc.msg}") from None
    items = data.get("constraints") if isinstance(data, dict) else data
    if not isinstance(items, list):
        raise ConstraintError(f'{where}expected a JSON object with a "constraints" list')
    out = []
    for i, item in enumerate(items):
        try:
            out.append(Constraint.from_dict(item, i))
        except ConstraintError as exc:
            raise ConstraintError(f"{where}{exc}", exc.field) from None
    return out


def floor_constraint(joint: str, num_frames: int, height: float = 0.0, *,
                     priority: int = 1) -> Constraint:
    """Keep ``joint`` on or above the floor plane at ``height`` [m] over the whole clip."""
    return Constraint(joint=joint, kind="plane",
                      goal={"point": [0.0, height, 0.0], "normal": [0.0, 1.0, 0.0],
                            "side": "above"},
                      smooth_in=0, start=0, end=num_frames - 1, smooth_out=num_frames - 1,
                      priority=priority, name=f"floor {joint}", auto=True)
