"""An orientation constraint: the joint's world orientation, ``goal = {"quaternion": [x, y, z,
w]}``. Its IK rows are the rotation vector from the current orientation to the goal [rad]."""
from __future__ import annotations

import numpy as np

from ...quaternions import qconj, qmul_small
from ..ik import TaskState, quat_to_rotvec
from .base import ConstraintError, ConstraintKind, GoalField, unit_vector, vector

__all__ = ["OrientationKind", "KIND"]


class OrientationKind(ConstraintKind):
    """The joint's world rotation at a goal; its own rotation moves it too."""

    name = "orientation"
    label = "Orientation"
    fields = (GoalField("quaternion", "XYZ", editor="euler", unit="°", name="orientation",
                        tooltip="The joint's world orientation as intrinsic XYZ Euler angles "
                                "[deg] (stored as a quaternion)",
                        decimals=1, step=1.0, bounds=(-180.0, 180.0)),)
    draw = "axes"
    rows = 3
    goal_size = 4
    angular = True

    def validate(self, goal, start, end, label):
        q = vector(goal.get("quaternion"), 4, "goal.quaternion", label)
        if np.linalg.norm(q) < 1e-9:
            raise ConstraintError(f"{label}: goal.quaternion must not be zero",
                                  "goal.quaternion")
        return {"quaternion": unit_vector(q)}

    def converted_goal(self, c, variant, here, turn, frame):
        return c.goal if c.kind_object is self else {"quaternion": np.asarray(turn)}

    def goal_from_pose(self, c, positions, rotations, frame, index):
        return {"quaternion": rotations[frame, index].copy()}

    # ------------------------------------------------------------------ IK task
    def neutral_goal(self):
        return np.array([0.0, 0.0, 0.0, 1.0])

    def task_goals(self, c, frames):
        return np.broadcast_to(c.goal["quaternion"], (len(frames), 4)).copy()

    def chain(self, skeleton, joint):
        return sorted(skeleton.ancestors(joint) + [joint])

    def error(self, goal: np.ndarray, state: TaskState) -> np.ndarray:
        # qmul's values bit for bit, in fewer calls (the solver's batches are small)
        return quat_to_rotvec(qmul_small(goal, qconj(state.rotation)))

    def jacobian(self, goal: np.ndarray, state: TaskState) -> np.ndarray:
        root = np.zeros((state.batch, 3, 3))
        return np.concatenate([root, *state.frames], axis=2)


KIND = OrientationKind()
