"""Linear blend skinning, vectorised over frames and vertices.

A :class:`~engine.formats.gltf.Mesh` holds its vertices in the bind pose, which is the
skeleton's zero-rotation pose (see :mod:`engine.formats.gltf`): there every joint's world
rotation is the identity and its position its bind position ``b_j``. In a pose where joint ``j`` has world rotation
``R_j`` and position ``p_j`` (from :func:`engine.kinematics.forward_kinematics`), a vertex
``v`` bound to joints ``j_k`` with weights ``w_k`` moves to

    v' = sum_k w_k * (R_{j_k} (v - b_{j_k}) + p_{j_k})

which is glTF's ``sum_k w_k * world_k * inverseBind_k * v`` written in the engine's terms
(uniform scales are already baked into the positions). The blended 3x4 matrix is built per
vertex and frame in chunks, so memory stays bounded for long clips.
"""
from __future__ import annotations

import numpy as np

from .kinematics import WorldPose, forward_kinematics
from .motion import Motion
from .quaternions import to_matrix

__all__ = ["joint_matrices", "skin_vertices", "skin_mesh", "skin_character",
           "quat_matrices"]

#: vertices x frames handled in one block (about 100 MB of float64 3x4 matrices)
_BLOCK = 1_000_000


def quat_matrices(q: np.ndarray) -> np.ndarray:
    """``(..., 4)`` unit quaternions x-y-z-w -> ``(..., 3, 3)`` rotation matrices."""
    return to_matrix(q)


def joint_matrices(rotations: np.ndarray, positions: np.ndarray,
                   bind_positions: np.ndarray) -> np.ndarray:
    """``(F, J, 3, 4)`` skinning matrices: each takes a bind-pose point to the posed world.

    Args:
        rotations: ``(F, J, 4)`` world joint rotations (identity in the bind pose).
        positions: ``(F, J, 3)`` [m] world joint positions.
        bind_positions: ``(J, 3)`` [m] joint positions in the bind pose.
    """
    rot = quat_matrices(rotations)
    out = np.empty(rot.shape[:-2] + (3, 4))
    out[..., :3] = rot
    out[..., 3] = np.asarray(positions) - np.einsum("fjab,jb->fja", rot,
                                                    np.asarray(bind_positions, dtype=float))
    return out


def skin_vertices(bind_vertices: np.ndarray, joints: np.ndarray, weights: np.ndarray,
                  matrices: np.ndarray) -> np.ndarray:
    """Deformed vertices ``(F, V, 3)``.

    Args:
        bind_vertices: ``(V, 3)`` bind-pose positions.
        joints: ``(V, K)`` joint index per influence.
        weights: ``(V, K)`` weights (rows summing to 1).
        matrices: ``(F, J, 3, 4)`` from :func:`joint_matrices`.
    """
    v = np.asarray(bind_vertices, dtype=float)
    joints = np.asarray(joints)
    weights = np.asarray(weights, dtype=float)
    F = matrices.shape[0]
    V, K = joints.shape
    out = np.empty((F, V, 3))
    step = max(1, _BLOCK // max(V, 1))
    for f0 in range(0, F, step):
        m = matrices[f0:f0 + step]                               # (f, J, 3, 4)
        blend = np.zeros((m.shape[0], V, 3, 4))
        for k in range(K):
            w = weights[:, k]
            if not np.any(w):
                continue
            blend += w[None, :, None, None] * m[:, joints[:, k]]
        out[f0:f0 + step] = np.einsum("fvab,vb->fva", blend[..., :3], v) + blend[..., 3]
    return out


def skin_mesh(mesh, pose: WorldPose, bind_positions: np.ndarray) -> np.ndarray:
    """``(F, V, 3)`` [m] ``mesh``'s vertices in the poses of ``pose`` (its joints' world
    rotations and positions over frames)."""
    mats = joint_matrices(pose.rotations, pose.positions, bind_positions)
    return skin_vertices(mesh.positions, mesh.joints, mesh.weights, mats)


def skin_character(character, motion: Motion | None = None,
                   frames=None) -> list[np.ndarray]:
    """Every mesh of ``character`` deformed by ``motion`` (its bind pose by default): a list of
    ``(F, V, 3)`` arrays in :attr:`Character.meshes` order.

    Args:
        frames: a slice or index array of frames to skin (all by default).
    """
    if motion is None:
        motion = character.rest_motion()
    if motion.skeleton.names != character.skeleton.names:
        from .errors import MotionComposerError
        raise MotionComposerError(f"the motion {motion.name!r} is not on the character "
                                  f"{character.name!r}'s skeleton")
    if frames is not None:
        motion = motion.frames(frames)
    pose = forward_kinematics(motion, end_sites=False)
    mats = joint_matrices(pose.rotations, pose.positions, character.bind_positions)
    return [skin_vertices(m.positions, m.joints, m.weights, mats) for m in character.meshes]
