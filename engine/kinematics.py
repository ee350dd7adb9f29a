"""Forward kinematics, vectorised over frames.

The only loop is over joints (parents before children); every step handles all frames at once.
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
    if translations.shape[1] != J or J == len(skeleton.translated):
        full = np.broadcast_to(skeleton.offsets, (F, J, 3)).copy()
        full[:, skeleton.translated] = translations
        translations = full
    parents = skeleton.parents
    # joint-major scratch arrays keep each joint's frames contiguous
    local_q = np.ascontiguousarray(rotations.transpose(1, 0, 2))
    local_t = np.ascontiguousarray(translations.transpose(1, 0, 2))
    world_q = np.empty((J, F, 4))
    world_p = np.empty((J, F, 3))
    world_q[0] = local_q[0]
    world_p[0] = local_t[0]
    for j in range(1, J):
        p = parents[j]
        world_q[j] = qmul(world_q[p], local_q[j])
        world_p[j] = world_p[p] + qrot(world_q[p], local_t[j])
    sites = skeleton.end_sites if end_sites else ()
    end_p = np.empty((len(sites), F, 3))
    for e, site in enumerate(sites):
        end_p[e] = world_p[site.parent] + qrot(world_q[site.parent], site.offset)
    return WorldPose(world_q.transpose(1, 0, 2), world_p.transpose(1, 0, 2),
                     end_p.transpose(1, 0, 2))


def forward_kinematics(motion: Motion, *, end_sites: bool = True) -> WorldPose:
    """World rotations and positions of every joint (and End Site) of ``motion``, all frames."""
    return fk_arrays(motion.skeleton, motion.rotations, motion.translations, end_sites=end_sites)
