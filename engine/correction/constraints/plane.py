"""A plane constraint: the joint above, on or below a plane.

``goal = {"point": [...], "normal": [...], "side": "above" | "on" | "below"}`` [m]; ``above``
is the side the normal points to. ``above`` and ``below`` are one-sided: no pull while
satisfied. The floor is a plane.

The IK task has one row, the signed distance to the plane; its task goal packs the plane per
frame as ``[point (3), normal (3), side (1)]`` with side +1 above, 0 on, -1 below.
"""
from __future__ import annotations

import numpy as np

from ..ik import TaskState
from .base import ConstraintError, ConstraintKind, GoalField, unit_vector, vector

__all__ = ["PlaneKind", "KIND", "SIDES"]

#: a plane's sides and their sign in the task goal
SIDES = {"above": 1.0, "on": 0.0, "below": -1.0}

#: [m] a joint this little on the wrong side of a one-sided plane is on it: a posture solved
#: with the plane holding the joint leaves it there to rounding, and a solve that starts from
#: that posture (a warm start) must be free to lift it off, as one from elsewhere would
#: (the plane acting would hold it: the pull to the attraction moves only along the plane)
SLACK = 1e-7


class PlaneKind(ConstraintKind):
    """The signed distance of the joint to a plane: zero (on), or not negative (above) or not
    positive (below)."""

    name = "plane"
    label = "Plane"
    variants = tuple(SIDES)
    fields = (GoalField("point", "Point", unit="m", name="plane point",
                        tooltip="A point of the plane [m]"),
              GoalField("normal", "Normal", name="plane normal", step=0.05, bounds=(-1.0, 1.0),
                        tooltip="The plane's normal (normalised when stored); 'above' is the "
                                "side it points to"))
    draw = "plane"
    rows = 1
    goal_size = 7

    def validate(self, goal, start, end, label):
        normal = vector(goal.get("normal", [0, 1, 0]), 3, "goal.normal", label)
        if np.linalg.norm(normal) < 1e-9:
            raise ConstraintError(f"{label}: goal.normal must not be zero", "goal.normal")
        side = goal.get("side", "above")
        if side not in SIDES:
            raise ConstraintError(f"{label}: goal.side must be one of {', '.join(SIDES)}, not "
                                  f"{side!r}", "goal.side")
        return {"point": vector(goal.get("point", [0, 0, 0]), 3, "goal.point", label),
                "normal": unit_vector(normal), "side": side}

    def variant(self, goal):
        return goal["side"]

    def choice_label(self, variant):
        return f"{self.label}: {variant}"

    def describe(self, goal):
        return f"{self.name} {goal['side']}"

    def carried_point(self, c, frame):
        return np.array(c.goal["point"], dtype=float)

    def converted_goal(self, c, variant, here, turn, frame):
        point = c.kind_object.carried_point(c, frame)
        point = np.asarray(here, dtype=float) if point is None else point
        normal = c.goal["normal"] if c.kind_object is self else [0.0, 1.0, 0.0]
        return {"point": point, "normal": normal, "side": variant or "above"}

    def goal_from_pose(self, c, positions, rotations, frame, index):
        return {"point": positions[frame, index].copy(), "normal": c.goal["normal"],
                "side": c.goal["side"]}

    # ------------------------------------------------------------------ IK task
    @staticmethod
    def task_goal(point: np.ndarray, normal: np.ndarray, side) -> np.ndarray:
        """``(..., 7)`` task goals of planes through ``point`` ``(..., 3)`` with unit
        ``normal`` ``(..., 3)`` on ``side`` (+1 above, 0 on, -1 below, ``(...)``)."""
        point, normal = np.asarray(point, dtype=float), np.asarray(normal, dtype=float)
        shape = np.broadcast_shapes(point.shape, normal.shape)
        side = np.broadcast_to(np.asarray(side, dtype=float), shape[:-1])
        return np.concatenate([np.broadcast_to(point, shape), np.broadcast_to(normal, shape),
                               side[..., None]], axis=-1)

    def neutral_goal(self):
        return self.task_goal(np.zeros(3), np.array([0.0, 1.0, 0.0]), 0.0)

    def _plane(self, c) -> np.ndarray:
        return self.task_goal(c.goal["point"], c.goal["normal"], SIDES[c.goal["side"]])

    def task_goals(self, c, frames):
        return np.tile(self._plane(c), (len(frames), 1))

    @staticmethod
    def _distance(goal: np.ndarray, state: TaskState) -> np.ndarray:
        """``(B,)`` [m] the joint's signed distance to the planes."""
        return np.sum((state.position - goal[:, 0:3]) * goal[:, 3:6], axis=1)

    def active(self, goal, state):
        s = self._distance(goal, state)
        side = goal[:, 6]
        return (side == 0) | ((side > 0) & (s < -SLACK)) | ((side < 0) & (s > SLACK))

    def acts(self, goal, error):
        side = goal[:, 6]
        return (side == 0) | (side * error[:, 0] > 0)      # error = -distance

    def one_sided(self, goal):
        return SIDES[goal["side"]] != 0.0

    def violated(self, goal, position):
        distance = np.sum((position - goal[:, 0:3]) * goal[:, 3:6], axis=1)
        return distance * goal[:, 6] < -SLACK          # on the wrong side (never for "on")

    def error(self, goal, state):
        return -self._distance(goal, state)[:, None]

    def jacobian(self, goal, state):
        return np.einsum("bi,bij->bj", goal[:, 3:6], state.point_jacobian())[:, None, :]


KIND = PlaneKind()
