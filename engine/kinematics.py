"""Forward kinematics, vectorised over frames.

The only loop is over the hierarchy's depth levels (a 100-joint skeleton has about a dozen):
each step places every joint of one level, all frames at once, from its parent's world pose.
The work is done on component arrays (:mod:`engine.quaternions`): ``(4, J, F)`` rotations and
``(3, J, F)`` positions, one contiguous row of frames per joint and component.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .motion import Motion
from .quaternions import cmul, crot
from .skeleton import Skeleton

__all__ = ["WorldPose", "forward_kinematics", "fk_arrays", "fk_components", "fk_joints",
           "joint_major"]


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

    The pose's arrays are views of :func:`fk_components`' component arrays.
    """
    rotations = np.asarray(rotations, dtype=float)
    translations = np.asarray(translations, dtype=float)
    world_q, world_p, end_p = fk_components(skeleton, joint_major(rotations),
                                            joint_major(translations), end_sites=end_sites)
    return WorldPose(world_q.T, world_p.T, end_p.T)


def joint_major(values: np.ndarray) -> np.ndarray:
    """``(n, J, F)`` contiguous component arrays of ``(F, J, n)`` values (quaternions or
    vectors); their transpose ``.T`` is the other way back, as a view."""
    return np.ascontiguousarray(np.asarray(values, dtype=float).T)


def fk_components(skeleton: Skeleton, rotations: np.ndarray, translations: np.ndarray,
                  *, end_sites: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`fk_arrays` on component arrays: local ``rotations (4, J, F)`` and ``translations``
    ``(3, J, F)`` or ``(3, K, F)`` (``skeleton.translated`` only), [m]. Returns the world
    rotations ``(4, J, F)``, joint positions ``(3, J, F)`` and End Site positions
    ``(3, E, F)``."""
    J, F = rotations.shape[1:]
    slot = np.full(J, -1, dtype=np.intp)
    if translations.shape[1] == J and J != len(skeleton.translated):
        slot[:] = np.arange(J)
    else:
        slot[skeleton.translated] = np.arange(len(skeleton.translated))
    offsets = skeleton.offsets.T[:, :, None]                                 # (3, J, 1)
    parents = skeleton.parents
    world_q = np.empty((4, J, F))
    world_p = np.empty((3, J, F))
    world_q[:, 0] = rotations[:, 0]
    world_p[:, 0] = translations[:, slot[0]] if slot[0] >= 0 else offsets[:, 0]
    for joints in _levels(skeleton):
        up = parents[joints]
        parent_q = world_q[:, up]
        world_q[:, joints] = cmul(parent_q, rotations[:, joints])
        local_t = _local_translations(joints, slot, offsets, translations)
        world_p[:, joints] = world_p[:, up] + crot(parent_q, local_t)
    sites = skeleton.end_sites if end_sites else ()
    if sites:
        up = np.array([site.parent for site in sites])
        site_offsets = np.array([site.offset for site in sites]).T[:, :, None]  # (3, E, 1)
        end_p = world_p[:, up] + crot(world_q[:, up], site_offsets)
    else:
        end_p = np.empty((3, 0, F))
    return world_q, world_p, end_p


def fk_joints(skeleton: Skeleton, rotations: np.ndarray, translations: np.ndarray,
              joints) -> tuple[np.ndarray, np.ndarray]:
    """World rotations ``(F, n, 4)`` and positions ``(F, n, 3)`` [m] of ``joints`` (indices)
    alone, from the arrays :func:`fk_arrays` takes: only those joints and their ancestors are
    placed (a foot's chain is 5 or 6 joints of a body's 30 to 100), one depth level at a time
    in :func:`fk_components`' arithmetic, so the values are its values bit for bit (each
    joint's depend on its ancestors' alone). For the few effectors a caller looks at over a
    whole clip: the feet for contacts, a floor plane's joints."""
    joints = [int(j) for j in joints]
    rotations = np.asarray(rotations, dtype=float)
    translations = np.asarray(translations, dtype=float)
    J, F = skeleton.num_joints, rotations.shape[0]
    chain = np.array(sorted({0, *joints, *(int(a) for j in joints
                                          for a in skeleton.ancestors(j))}), dtype=np.intp)
    where = np.full(J, -1, dtype=np.intp)
    where[chain] = np.arange(len(chain))
    slot = np.full(J, -1, dtype=np.intp)
    if translations.shape[1] == J and J != len(skeleton.translated):
        slot[:] = np.arange(J)
    else:
        slot[skeleton.translated] = np.arange(len(skeleton.translated))
    slot = slot[chain]
    local_q = joint_major(rotations[:, chain])                               # (4, n, F)
    local_t = joint_major(translations[:, slot[slot >= 0]])                  # (3, m, F)
    slot[slot >= 0] = np.arange(int((slot >= 0).sum()))
    offsets = skeleton.offsets[chain].T[:, :, None]                          # (3, n, 1)
    world_q = np.empty((4, len(chain), F))
    world_p = np.empty((3, len(chain), F))
    world_q[:, 0] = local_q[:, 0]
    world_p[:, 0] = local_t[:, slot[0]] if slot[0] >= 0 else offsets[:, 0]
    depth = skeleton.depth[chain]
    for d in range(1, int(depth.max(initial=0)) + 1):
        here = np.flatnonzero(depth == d)
        up = where[skeleton.parents[chain[here]]]
        parent_q = world_q[:, up]
        world_q[:, here] = cmul(parent_q, local_q[:, here])
        world_p[:, here] = world_p[:, up] + crot(parent_q,
                                                 _local_translations(here, slot, offsets, local_t))
    picked = where[joints]
    return world_q[:, picked].T, world_p[:, picked].T


def _local_translations(joints: np.ndarray, slot: np.ndarray, offsets: np.ndarray,
                        translations: np.ndarray) -> np.ndarray:
    """Local translations of ``joints``: their offsets ``(3, n, 1)`` where none of them is
    animated, else ``(3, n, F)`` with the animated ones' rows of ``translations``."""
    moving = slot[joints] >= 0
    if not moving.any():
        return offsets[:, joints]
    out = np.empty((3, len(joints), translations.shape[2]))
    out[:] = offsets[:, joints]
    out[:, moving] = translations[:, slot[joints[moving]]]
    return out


def _levels(skeleton: Skeleton) -> list[np.ndarray]:
    """Joint indices by depth below the root, depth 1 first: every joint's parent is in the
    level before its own, so one level at a time can be placed in a single vectorised step."""
    depth = skeleton.depth
    return [np.flatnonzero(depth == d) for d in range(1, int(depth.max(initial=0)) + 1)]


def forward_kinematics(motion: Motion, *, end_sites: bool = True) -> WorldPose:
    """World rotations and positions of every joint (and End Site) of ``motion``, all frames."""
    return fk_arrays(motion.skeleton, motion.rotations, motion.translations, end_sites=end_sites)
