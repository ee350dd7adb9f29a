"""Forward kinematics, vectorised over frames.

The only loop is over the hierarchy's depth levels (a 100-joint skeleton has about a dozen):
each step places every joint of one level, all frames at once, from its parent's world pose.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .motion import Motion
from .quaternions import qmul, qrot
from .skeleton import Skeleton

__all__ = ["WorldPose", "forward_kinematics", "fk_arrays"]


@dataclass(frozen=True, eq=False)
class WorldPose:
    """World placement of every joint and End Site over frames.

    Attributes:
        rotations: ``(F, J, 4)`` world rotations, x-y-z-w.
        positions: ``(F, J, 3)`` [m] world joint positions.
        end_positions: ``(F, E, 3)`` [m] world End Site positions, in ``skeleton.end_sites``
            order (an End Site's rotation is its parent's).
    """

    rotations: np.ndarray
    positions: np.ndarray
    end_positions: np.ndarray

    def all_positions(self) -> np.ndarray:
        """``(F, J + E, 3)`` joints then End Sites."""
        return np.concatenate([self.positions, self.end_positions], axis=1)


def fk_arrays(skeleton: Skeleton, rotations: np.ndarray, translations: np.ndarray,
              *, end_sites: bool = True) -> WorldPose:
    """Forward kinematics from raw arrays.

    Args:
        skeleton: the hierarchy.
        rotations: ``(F, J, 4)`` local rotations (unit quaternions).
        translations: ``(F, J, 3)`` [m] local translations of every joint (offsets included),
            or ``(F, K, 3)`` for the joints in ``skeleton.translated`` only.
    """
    rotations = np.asarray(rotations, dtype=float)
    F, J = rotations.shape[:2]
    translations = np.asarray(translations, dtype=float)
    # joint-major (J, F, ...) keeps each joint's frames together; a level's joints are
    # gathered from the inputs' transposed views, which costs no more than a copy up front
    local_q = rotations.transpose(1, 0, 2)
    if translations.shape[1] != J or J == len(skeleton.translated):
        local_t = np.empty((J, F, 3))
        local_t[:] = skeleton.offsets[:, None, :]
        local_t[skeleton.translated] = translations.transpose(1, 0, 2)
    else:
        local_t = translations.transpose(1, 0, 2)
    parents = skeleton.parents
    world_q = np.empty((J, F, 4))
    world_p = np.empty((J, F, 3))
    world_q[0] = local_q[0]
    world_p[0] = local_t[0]
    for joints in _levels(skeleton):
        up = parents[joints]
        parent_q = world_q[up]
        world_q[joints] = qmul(parent_q, local_q[joints])
        world_p[joints] = world_p[up] + qrot(parent_q, local_t[joints])
    sites = skeleton.end_sites if end_sites else ()
    if sites:
        up = np.array([site.parent for site in sites])
        offsets = np.array([site.offset for site in sites])[:, None, :]    # (E, 1, 3)
        end_p = world_p[up] + qrot(world_q[up], offsets)
    else:
        end_p = np.empty((0, F, 3))
    return WorldPose(world_q.transpose(1, 0, 2), world_p.transpose(1, 0, 2),
                     end_p.transpose(1, 0, 2))


def _levels(skeleton: Skeleton) -> list[np.ndarray]:
    """Joint indices by depth below the root, depth 1 first: every joint's parent is in the
    level before its own, so one level at a time can be placed in a single vectorised step."""
    depth = skeleton.depth
    return [np.flatnonzero(depth == d) for d in range(1, int(depth.max(initial=0)) + 1)]


def forward_kinematics(motion: Motion, *, end_sites: bool = True) -> WorldPose:
    """World rotations and positions of every joint (and End Site) of ``motion``, all frames."""
    return fk_arrays(motion.skeleton, motion.rotations, motion.translations, end_sites=end_sites)
