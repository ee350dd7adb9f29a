"""Reach goals: a chain's IK blend (issue 18) as a goal on its end effector.

A chain whose :class:`~engine.conversion.chains.ChainSettings` has ``ik_blend > 0`` gets one
trajectory constraint on its effector (:func:`~engine.conversion.chains.effector`: the hand
of an arm, the ankle of a leg, the head, the chest) over the whole clip, named ``"reach
arm_l"`` and marked automatic. Its goal on frame ``t`` is::

    lerp(converted(t), scaled(t), ik_blend),
    scaled(t) = root(t) + S (performer_effector(t) - performer_root(t))

with ``converted`` the effector in the direct conversion, ``root`` the target's body root
there, and ``S = diag(h, v, h)`` the root motion's own scale (the root options' ``scale``,
else the hip-height ratio; 1 for the ``absolute`` mode): the performer's effector placed
about the character's root as the root motion places the root. So with blend 1 the hands
land where the performer's were, the character's size taken into account, wherever its arms
reach. The goals sit one priority level below the contacts (:func:`reach_constraints`), so
feet hold first.
"""
from __future__ import annotations

import numpy as np

from ..conversion.binding import Binding
from ..conversion.chains import chains_of, effector
from ..conversion.converter import RootOptions
from ..kinematics import fk_arrays
from ..motion import Motion
from .constraints import Constraint

__all__ = ["reach_constraints", "reach_goal", "unreached", "SOURCE"]

#: ``Constraint.meta["source"]`` of reach goals
SOURCE = "reach"


def reach_goal(binding: Binding, performer: Motion, composed: Motion, joint: str,
               root: RootOptions | None = None) -> np.ndarray:
    """``(F, 3)`` [m] the performer's effector mapped to target ``joint``, scaled from the root
    by the root motion's ratio, about the converted body root (``scaled(t)`` in the module
    doc)."""
    return _scaled(binding, _positions(binding.performer, performer),
                   _positions(binding.target, composed), joint, root or RootOptions())


def _positions(skeleton, motion: Motion) -> np.ndarray:
    """``(F, J, 3)`` [m] world joint positions."""
    return fk_arrays(skeleton, motion.rotations, motion.translations).positions


def _scaled(binding: Binding, p_pos: np.ndarray, t_pos: np.ndarray, joint: str,
            root: RootOptions) -> np.ndarray:
    """:func:`reach_goal` from the performer's and the composed motion's world positions
    ``(F, Jp, 3)`` and ``(F, J, 3)`` [m]."""
    psk = binding.performer
    body = binding.body_root
    if root.mode == "absolute":
        scale = np.ones(3)
    else:
        h, v = root.scale if root.scale is not None else (binding.hip_height_ratio,) * 2
        scale = np.array([h, v, h])
    p_effector = psk.index[binding.correspondence.pairs[joint]]
    lever = p_pos[:, p_effector] - p_pos[:, binding.mapped[body]]
    return t_pos[:, body] + lever * scale


def reach_constraints(binding: Binding, performer: Motion, composed: Motion,
                      root: RootOptions | None = None, *, priority: int = 2) -> list[Constraint]:
    """The reach goals of every chain with an IK blend (see the module doc), at ``priority``
    (one below the contacts'). A chain whose effector is not on the character or not mapped
    to a performer joint gets none (:func:`unreached` names them)."""
    root = root or RootOptions()
    chains = chains_of(binding.target, binding.aligned_positions)
    wanted = [(name, s, effector(chains, name)) for name, s in binding.options.chains
              if s.ik_blend > 0.0 and name in chains.effectors
              and effector(chains, name) in binding.correspondence.pairs]
    if not wanted:
        return []
    p_pos = _positions(binding.performer, performer)
    t_pos = _positions(binding.target, composed)
    F = composed.num_frames
    out = []
    for name, settings, joint in wanted:
        converted = t_pos[:, binding.target.index[joint]]
        scaled = _scaled(binding, p_pos, t_pos, joint, root)
        goal = converted + settings.ik_blend * (scaled - converted)
        out.append(Constraint(joint=joint, kind="trajectory", goal={"points": goal},
                              smooth_in=0, start=0, end=F - 1, smooth_out=F - 1,
                              priority=priority, name=f"reach {name}", auto=True,
                              meta={"source": SOURCE, "chain": name,
                                    "ik_blend": settings.ik_blend}))
    return out


def unreached(binding: Binding) -> list[str]:
    """Lines naming the chains with an IK blend whose effector has no goal (not on the
    character, or not mapped)."""
    chains = chains_of(binding.target, binding.aligned_positions)
    lines = []
    for name, settings in binding.options.chains:
        if settings.ik_blend <= 0.0:
            continue
        if name not in chains.effectors:
            lines.append(f"the {name} chain's IK blend has no effector on this character")
        elif effector(chains, name) not in binding.correspondence.pairs:
            lines.append(f"the {name} chain's IK blend: its effector "
                         f"{effector(chains, name)} is not mapped, no reach goal")
    return lines
