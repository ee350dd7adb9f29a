"""The Motion Composer (the paper's section 2.3): copy the Intermediate Skeleton's local
values onto the target and add the root's translation; :func:`retarget` runs bind, convert
and compose in one call."""
from __future__ import annotations

import numpy as np

from ..motion import Motion
from ..quaternions import qconj, qmul, qrot
from .binding import BindOptions, Binding, bind
from .converter import IntermediatePose, RootOptions, _chain_fk, convert
from .correspondence import Correspondence

__all__ = ["compose", "retarget"]


def compose(binding: Binding, pose: IntermediatePose, frame_time: float,
            name: str = "") -> Motion:
    """Motion Composer: the target motion with the intermediate skeleton's local values."""
    tsk = binding.target
    world = pose.world
    F = world.shape[0]
    local = np.empty_like(world)
    local[:] = binding.rest_local                         # unmapped joints below the mapped
    known = np.flatnonzero(pose.known)
    top = known[tsk.parents[known] < 0]
    local[:, top] = world[:, top]
    inner = known[tsk.parents[known] >= 0]
    local[:, inner] = qmul(qconj(world[:, tsk.parents[inner]]), world[:, inner])
    translations = np.broadcast_to(binding.root_translation,
                                   (F,) + binding.root_translation.shape).copy()
    slot = {int(j): k for k, j in enumerate(tsk.translated)}
    for j in binding.driven:
        target_pos = pose.positions[j]
        # the nearest joint at or above j whose translation is animated carries it
        carrier = j
        while carrier not in slot:
            carrier = int(tsk.parents[carrier])
        parent = tsk.parents[carrier]
        if carrier == j and parent < 0:
            translations[:, slot[j]] = target_pos
            continue
        rot, pos = _chain_fk(tsk, local, translations, slot, j)
        shift = target_pos - pos[j]
        if parent >= 0:
            shift = qrot(qconj(rot[parent]), shift)
        translations[:, slot[carrier]] += shift
    return Motion._trusted(tsk, local, translations, frame_time, name)


def retarget(performer: Motion, target: Motion, correspondence: Correspondence, *,
             bind_options: BindOptions | None = None, root: RootOptions | None = None,
             progress=None) -> Motion:
    """Convert ``performer``'s motion onto ``target``'s character (bind, convert, compose)."""
    binding = bind(performer, target, correspondence, bind_options)
    pose = convert(binding, performer, root, progress=progress)
    name = f"{performer.name}_on_{target.name}" if performer.name and target.name else ""
    return compose(binding, pose, performer.frame_time, name=name)
