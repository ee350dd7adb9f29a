"""The Motion Composer (the paper's section 2.3): copy the Intermediate Skeleton's local
values onto the target and add the root's translation; :func:`retarget` runs bind, convert
and compose in one call, and :func:`transfer` converts and composes a run of frames at a time."""
from __future__ import annotations

import numpy as np

from ..kinematics import joint_major
from ..motion import Motion
from ..quaternions import cconj, cmul, crot
from .binding import BindOptions, Binding, bind
from .converter import IntermediatePose, RootOptions, _check_performer, chunks, convert_frames
from .correspondence import Correspondence

__all__ = ["compose", "retarget", "transfer"]


def compose(binding: Binding, pose: IntermediatePose, frame_time: float,
            name: str = "") -> Motion:
    """Motion Composer: the target motion with the intermediate skeleton's local values."""
    F = pose.world.shape[0]
    rotations, translations = _outputs(binding, F)
    for lo, hi in chunks(F):
        world = joint_major(pose.world[lo:hi])
        positions = {j: p[lo:hi].T for j, p in pose.positions.items()}
        _compose_into(binding, world, positions, pose.known, rotations[lo:hi],
                      translations[lo:hi])
    return Motion._trusted(binding.target, rotations, translations, frame_time, name)


def transfer(binding: Binding, performer: Motion, root: RootOptions | None = None, *,
             name: str = "", progress=None, lift: float = 0.0) -> Motion:
    """``compose(binding, convert(binding, performer, root, lift=lift), ...)`` value for
    value, a run of frames at a time: the intermediate pose of only one run is ever in
    memory, and its rotations stay component arrays from the performer's forward kinematics
    to the target's local values (no round trip through ``(F, J, 4)``)."""
    root = root or RootOptions()
    _check_performer(binding, performer)
    F = performer.num_frames
    rotations, translations = _outputs(binding, F)
    for lo, hi in chunks(F):
        world, positions, known = convert_frames(binding, performer, lo, hi, root, lift)
        _compose_into(binding, world, positions, known, rotations[lo:hi], translations[lo:hi])
        if progress is not None:
            progress(hi / F)
    return Motion._trusted(binding.target, rotations, translations, performer.frame_time, name)


def _outputs(binding: Binding, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """The composed motion's arrays, to fill: rotations ``(F, J, 4)``, translations
    ``(F, K, 3)``."""
    K = len(binding.target.translated)
    return np.empty((frames, binding.target.num_joints, 4)), np.empty((frames, K, 3))


def _compose_into(binding: Binding, world: np.ndarray, positions: dict, known: np.ndarray,
                  rotations: np.ndarray, translations: np.ndarray) -> None:
    """Compose one run of frames: from the intermediate world rotations ``(4, J, n)`` (filled
    where ``known``) and driven positions ``{j: (3, n)}`` [m], fill the target's local
    ``rotations (n, J, 4)`` and ``translations (n, K, 3)``."""
    tsk = binding.target
    F = world.shape[2]
    rotations[:] = binding.rest_local                     # unmapped joints below the mapped
    known = np.flatnonzero(known)
    parents = tsk.parents[known]
    local = np.empty((4, len(known), F))
    top = parents < 0
    local[:, top] = world[:, known[top]]
    local[:, ~top] = cmul(cconj(world[:, parents[~top]]), world[:, known[~top]])
    rotations[:, known] = local.T
    rows = {int(j): local[:, k] for k, j in enumerate(known)}
    # weight-0 chains: exactly the binding pose (the converter's value to rounding)
    rotations[:, binding.held] = binding.rest_local[binding.held]
    for j in binding.held:
        if j in rows:
            rows[int(j)] = np.broadcast_to(binding.rest_local[j][:, None], (4, F))
    moved = np.empty((3, len(tsk.translated), F))
    moved[:] = binding.root_translation.T[:, :, None]
    slot = {int(j): k for k, j in enumerate(tsk.translated)}
    for j in binding.driven:
        target_pos = positions[j]
        # the nearest joint at or above j whose translation is animated carries it
        carrier = j
        while carrier not in slot:
            carrier = int(tsk.parents[carrier])
        parent = tsk.parents[carrier]
        if carrier == j and parent < 0:
            moved[:, slot[j]] = target_pos
            continue
        rot, pos = _chain_fk(binding, rows, moved, slot, j)
        shift = target_pos - pos[j]
        if parent >= 0:
            shift = crot(cconj(rot[parent]), shift)
        moved[:, slot[carrier]] += shift
    for f in binding.followers:
        # carried with its anchor: where the anchor's frame puts it, in its parent's frame
        rot, pos = _chain_fk(binding, rows, moved, slot, f.anchor)
        at = pos[f.anchor] + crot(rot[f.anchor], np.broadcast_to(f.offset[:, None], (3, F)))
        parent = int(tsk.parents[f.joint])
        rot, pos = _chain_fk(binding, rows, moved, slot, parent)
        moved[:, slot[f.joint]] = crot(cconj(rot[parent]), at - pos[parent])
    translations[:] = moved.T


def _chain_fk(binding: Binding, rows: dict, translations: np.ndarray, slot: dict, joint: int):
    """World rotations and positions of target ``joint`` and its ancestors only: dicts of
    ``(4, n)`` and ``(3, n)`` component arrays, from the local rotations ``rows`` of the known
    joints (``{j: (4, n)}``; the others' are their bound rest ones) and ``translations``
    ``(3, K, n)`` of the joints in ``slot`` (the others' are their offsets)."""
    skeleton = binding.target
    chain = [joint] + skeleton.ancestors(joint)
    F = translations.shape[2]
    rot, pos = {}, {}
    for k in reversed(chain):
        local = rows.get(k, binding.rest_local[k][:, None])
        t = translations[:, slot[k]] if k in slot else skeleton.offsets[k][:, None]
        p = skeleton.parents[k]
        if p < 0:
            rot[k], pos[k] = np.broadcast_to(local, (4, F)), np.broadcast_to(t, (3, F))
        else:
            rot[k] = cmul(rot[p], local)
            pos[k] = pos[p] + crot(rot[p], t)
    return rot, pos


def retarget(performer: Motion, target: Motion, correspondence: Correspondence, *,
             bind_options: BindOptions | None = None, root: RootOptions | None = None,
             progress=None) -> Motion:
    """Convert ``performer``'s motion onto ``target``'s character (bind, convert, compose)."""
    binding = bind(performer, target, correspondence, bind_options)
    name = f"{performer.name}_on_{target.name}" if performer.name and target.name else ""
    return transfer(binding, performer, root, name=name, progress=progress)
