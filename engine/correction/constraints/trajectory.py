"""A trajectory constraint: the joint along a path, solved as a position task per frame.

``goal = {"points": [[x, y, z], ...]}`` one point per frame from ``start`` to ``end``, or
``goal = {"keys": [[frame, x, y, z], ...]}`` a path through keys (linear between them, held
beyond the ends); [m].
"""
from __future__ import annotations

import numpy as np

from ... import limits
from . import position
from .base import ConstraintError, GoalField, numbers
from .position import PositionKind

__all__ = ["TrajectoryKind", "KIND"]


class TrajectoryKind(PositionKind):
    """A position goal that moves: the rows of a position task, the goal of each frame on the
    path."""

    name = "trajectory"
    label = "Trajectory"
    fields = (GoalField("path", "Path", editor="summary",
                        tooltip="Take from pose records the joint's path over the active "
                                "range."),)
    draw = "path"
    drag_key = None
    fixed_point = False

    @property
    def task_kind(self):
        return position.KIND

    def validate(self, goal, start, end, label):
        if "points" in goal:
            pts = numbers(goal["points"], "goal.points", label,
                          "rows of [x, y, z] numbers, one per frame")
            n = end - start + 1
            if pts.ndim != 2 or pts.shape != (n, 3) or not limits.all_usable(pts):
                raise ConstraintError(f"{label}: goal.points must hold one [x, y, z] per "
                                      f"frame from start to end ({n} points of finite numbers "
                                      f"of magnitude at most {limits.MAX_MAGNITUDE:g}), got "
                                      f"shape {pts.shape}", "goal.points")
            return {"points": pts}
        if "keys" in goal:
            keys = numbers(goal["keys"], "goal.keys", label,
                           "rows of [frame, x, y, z] numbers, all of one length")
            if keys.ndim != 2 or keys.shape[1] != 4 or len(keys) < 1 or \
                    not limits.all_usable(keys) or np.any(np.diff(keys[:, 0]) <= 0):
                raise ConstraintError(f"{label}: goal.keys must be [[frame, x, y, z], ...] "
                                      "with increasing frames, finite numbers of magnitude "
                                      f"at most {limits.MAX_MAGNITUDE:g}", "goal.keys")
            return {"keys": keys}
        raise ConstraintError(f"{label}: a trajectory goal needs 'points' (one per "
                              "frame) or 'keys' ([frame, x, y, z] ...)", "goal")

    def summary(self, c):
        if "points" in c.goal:
            return f"{len(c.goal['points'])} points, one per frame from {c.start} to {c.end}"
        keys = np.asarray(c.goal["keys"])
        return (f"{len(keys)} key{'s' if len(keys) != 1 else ''} from frame "
                f"{keys[0, 0]:g} to {keys[-1, 0]:g}")

    def goal_point(self, c, frames):
        frames = np.asarray(frames)
        if "points" in c.goal:
            idx = np.clip(frames - c.start, 0, len(c.goal["points"]) - 1)
            return c.goal["points"][idx]
        keys = c.goal["keys"]
        return np.stack([np.interp(frames, keys[:, 0], keys[:, k]) for k in (1, 2, 3)], 1)

    def moved_goal(self, goal, offset):
        if "points" in goal:
            return {"points": goal["points"] + offset}
        keys = np.array(goal["keys"], dtype=float)
        keys[:, 1:] += offset
        return {"keys": keys}

    def carried_point(self, c, frame):
        return self.goal_point(c, np.array([min(max(frame, c.start), c.end)]))[0]

    def converted_goal(self, c, variant, here, turn, frame):
        if c.kind_object is self:
            return c.goal
        point = c.kind_object.carried_point(c, frame)
        point = np.asarray(here, dtype=float) if point is None else point
        return {"keys": [[c.start, *point]]}

    def goal_from_pose(self, c, positions, rotations, frame, index):
        return {"points": positions[c.start:c.end + 1, index].copy()}

    def retimed_goal(self, c, shift):
        """Points given per frame become keys at the same frames (their number is tied to the
        old range); ``shift`` moves the keys along."""
        goal = c.goal
        if "points" in goal:
            pts = np.asarray(goal["points"])
            frames = np.arange(c.start, c.start + len(pts), dtype=float)
            goal = {"keys": np.column_stack([frames, pts])}
        if shift:
            keys = np.array(goal["keys"], dtype=float)
            keys[:, 0] += shift
            goal = {"keys": keys}
        return goal


KIND = TrajectoryKind()
