"""A plane constraint: the joint above, on or below a plane.

``goal = {"point": [...], "normal": [...], "side": "above" | "on" | "below"}`` [m]; ``above``
is the side the normal points to. ``above`` and ``below`` are one-sided: no pull while
satisfied. The floor is a plane.

An optional ``"lift": [[frame, metres], ...]`` moves the plane along its normal from frame to
frame (linear between keys, held beyond the ends; keys at whole frames, increasing): the
floor under a carried foot that turns as the performer's, raised where its own mesh would
go under the floor (:func:`~engine.correction.contacts.contact_constraints`).

The IK task has one row, the signed distance to the plane; its task goal packs the plane per
frame as ``[point (3), normal (3), side (1)]`` with side +1 above, 0 on, -1 below.
"""
from __future__ import annotations

import numpy as np

from ..ik import TaskState
from .base import ConstraintError, ConstraintKind, GoalField, frame_keys, unit_vector, vector

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
        out = {"point": vector(goal.get("point", [0, 0, 0]), 3, "goal.point", label),
               "normal": unit_vector(normal), "side": side}
        if "lift" in goal:
            out["lift"] = frame_keys(goal["lift"], ["metres"], "goal.lift", label)
        return out

    def variant(self, goal):
        return goal["side"]

    def choice_label(self, variant):
        return f"{self.label}: {variant}"

    def describe(self, goal):
        return f"{self.name} {goal['side']}" + (" (moving)" if "lift" in goal else "")

    @staticmethod
    def lift(goal, frames) -> np.ndarray:
        """``(n,)`` [m] how far the plane of ``goal`` is moved along its normal at ``frames``
        (zeros without a ``"lift"``)."""
        frames = np.asarray(frames, dtype=float)
        if "lift" not in goal:
            return np.zeros(frames.shape)
        keys = goal["lift"]
        return np.interp(frames, keys[:, 0], keys[:, 1])

    def carried_point(self, c, frame):
        return np.array(c.goal["point"], dtype=float)

    def converted_goal(self, c, variant, here, turn, frame):
        point = c.kind_object.carried_point(c, frame)
        point = np.asarray(here, dtype=float) if point is None else point
        if c.kind_object is self:           # another side: the plane stays where it is
            return {**c.goal, "side": variant or "above"}
        return {"point": point, "normal": [0.0, 1.0, 0.0], "side": variant or "above"}

    def goal_from_pose(self, c, positions, rotations, frame, index):
        # through the joint at that frame: a plane that moves keeps its moves from there
        point = positions[frame, index] - self.lift(c.goal, [frame])[0] * c.goal["normal"]
        return {**c.goal, "point": point}

    def retimed_goal(self, c, shift):
        if shift and "lift" in c.goal:
            keys = np.array(c.goal["lift"], dtype=float)
            keys[:, 0] += shift
            return {**c.goal, "lift": keys}
        return c.goal

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
        goals = np.tile(self._plane(c), (len(frames), 1))
        if "lift" in c.goal:
            goals[:, 0:3] += self.lift(c.goal, frames)[:, None] * c.goal["normal"]
        return goals

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
