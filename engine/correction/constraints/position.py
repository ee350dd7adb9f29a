"""A position constraint: the joint at one point, ``goal = {"point": [x, y, z]}`` [m]."""
from __future__ import annotations

import numpy as np

from ..ik import TaskState
from .base import ConstraintKind, GoalField, vector

__all__ = ["PositionKind", "KIND"]


class PositionKind(ConstraintKind):
    """The joint's world position at a goal point; the IK's 3 rows are the position error."""

    name = "position"
    label = "Position"
    fields = (GoalField("point", "Point", unit="m", name="point",
                        tooltip="The goal position [m], world axes, +Y up"),)
    draw = "point"
    drag_key = "point"
    fixed_point = True
    rows = 3
    goal_size = 3

    def validate(self, goal, start, end, label):
        return {"point": vector(goal.get("point"), 3, "goal.point", label)}

    def goal_point(self, c, frames):
        return np.broadcast_to(c.goal["point"], (len(frames), 3)).copy()

    def carried_point(self, c, frame):
        return np.array(c.goal["point"], dtype=float)

    def converted_goal(self, c, variant, here, turn, frame):
        point = c.kind_object.carried_point(c, frame)
        return {"point": np.asarray(here, dtype=float) if point is None else point}

    def goal_from_pose(self, c, positions, rotations, frame, index):
        return {"point": positions[frame, index].copy()}

    # ------------------------------------------------------------------ IK task
    def task_goals(self, c, frames):
        return self.goal_point(c, np.asarray(frames))

    def error(self, goal: np.ndarray, state: TaskState) -> np.ndarray:
        return goal - state.position

    def jacobian(self, goal: np.ndarray, state: TaskState) -> np.ndarray:
        return state.point_jacobian()


KIND = PositionKind()
