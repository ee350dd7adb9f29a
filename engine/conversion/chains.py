"""Limb chains and the animator's hand on the binding: per-chain settings, left/right mirrors
and typed angles for pose offsets.

A *chain* is a run of target joints from the automatic roles
(:func:`engine.conversion.automap.identify`), root to tip:

* ``spine``: the spine, hips excluded, chest included;
* ``neck``: the joints from the chest (excluded) to the head (included);
* ``arm_l``/``arm_r``: from the chest (excluded) to the hand (the clavicle, upper arm,
  forearm, hand and any joint between them);
* ``leg_l``/``leg_r``: from where the legs part (the hips or a pelvis, excluded) to the toe;
* ``fingers_l``/``fingers_r``: every finger joint of that hand, and the joints between the
  hand and them.

Each chain's end effector (:func:`effector`) is the joint an IK blend places: the chest for the
spine, the head for the neck, the hand for an arm, the ankle (foot) for a leg; the fingers
have none.

:class:`ChainSettings` says how a chain follows the performer (see
:mod:`engine.conversion` for what each setting does in the converter). Pose offsets
(:attr:`engine.conversion.binding.BindOptions.pose_offsets`) are typed as angles
(:func:`euler_to_offset`) and mirrored to the other side (:func:`mirrored_offset`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .automap import FINGERS, SIDES, identify
from ..errors import MappingError, MotionComposerError
from ..quaternions import from_euler, qconj, qmul
from ..rotations import quat_to_euler
from ..skeleton import Skeleton

__all__ = ["ChainSettings", "ChainSettingsError", "CHAINS", "DISTRIBUTIONS", "chains_of",
           "chain_of_joint", "effector", "mirror_joint", "mirrored_offset", "left_axis",
           "euler_to_offset", "offset_to_euler"]

#: every chain a humanoid can have, in display order
CHAINS = ("spine", "neck", "arm_l", "arm_r", "leg_l", "leg_r", "fingers_l", "fingers_r")
#: a chain's own "chain turns" choice (None: the binding's global one)
DISTRIBUTIONS = (None, "even", "first")


class ChainSettingsError(MotionComposerError):
    """A chain setting out of its range.

    Attributes:
        field: the setting (``"weight"``, ``"twist"``, ``"distribute"``, ``"ik_blend"``).
        problem: the message without the field.
    """

    def __init__(self, field: str, problem: str):
        self.field = field
        self.problem = problem
        super().__init__(f"chain setting {field}: {problem}")


@dataclass(frozen=True)
class ChainSettings:
    """How one chain follows the performer.

    Attributes:
        weight: rotation transfer weight in [0, 1]: 0 keeps the character's binding pose on
            every frame, 1 follows the performer; between, each joint's local rotation is the
            slerp from its binding-pose value to the converted one.
        twist: transfer the twist about each joint's bone axis; ``False`` keeps the binding's
            twist (the converted rotation relative to the binding, less its twist).
        distribute: ``"even"`` or ``"first"`` for this chain, or ``None`` for the binding's
            global choice (:attr:`BindOptions.distribute`).
        ik_blend: in [0, 1], the weight of the performer's effector position (scaled from the
            root like the root motion) against the converted one, as a reach goal solved one
            priority below the contacts (:mod:`engine.correction.reach`); 0 adds no goal.
    """

    weight: float = 1.0
    twist: bool = True
    distribute: str | None = None
    ik_blend: float = 0.0

    def __post_init__(self):
        for name in ("weight", "ik_blend"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating,
                                                                 np.integer)):
                raise ChainSettingsError(name, f"expected a number from 0 to 1, not {value!r}")
            value = float(value)
            if not (math.isfinite(value) and 0.0 <= value <= 1.0):
                raise ChainSettingsError(name, f"expected a number from 0 to 1, not {value!r}")
            object.__setattr__(self, name, value)
        if not isinstance(self.twist, (bool, np.bool_)):
            raise ChainSettingsError("twist", f"expected true or false, not {self.twist!r}")
        object.__setattr__(self, "twist", bool(self.twist))
        if self.distribute not in DISTRIBUTIONS:
            raise ChainSettingsError("distribute", f"expected 'even', 'first' or None (the "
                                                   f"binding's choice), not "
                                                   f"{self.distribute!r}")

    @property
    def is_default(self) -> bool:
        """Whether these are the defaults (the chain follows as without settings)."""
        return self == ChainSettings()


class Chains(dict):
    """:func:`chains_of`'s result: chain name -> target joint names, root to tip, with each
    chain's end effector in ``effectors`` (chain name -> joint name; no fingers)."""

    def __init__(self, chains: dict, effectors: dict):
        super().__init__(chains)
        self.effectors = dict(effectors)


def chains_of(skeleton: Skeleton, positions=None) -> Chains:
    """Each chain's target joints, root to tip, from the automatic roles; chains the skeleton
    does not have are absent, and so is everything when it is not a humanoid.

    ``positions``: ``(J, 3)`` [m] a reference pose that tells left from right where the names
    do not (:func:`~engine.conversion.automap.identify`)."""
    try:
        roles = identify(skeleton, positions)
    except MappingError:
        return Chains({}, {})
    idx = skeleton.index
    parents = skeleton.parents

    def path(top: str, bottom: str) -> tuple[str, ...]:
        """Joint names from ``top`` (excluded) down to ``bottom`` (included), or ()."""
        out, j, stop = [], idx[bottom], idx[top]
        while j >= 0 and j != stop:
            out.append(skeleton.names[j])
            j = int(parents[j])
        return tuple(out[::-1]) if j == stop else ()

    chains, effectors = {}, {}
    if roles.spine:
        chains["spine"] = tuple(roles.spine)
        effectors["spine"] = roles.spine[-1]
    if "chest" in roles and "head" in roles:
        chains["neck"] = path(roles["chest"], roles["head"])
        effectors["neck"] = roles["head"]
    legs_root = roles.get("pelvis", roles["hips"])
    for s in SIDES:
        arm_end = next((roles[f"{r}_{s}"] for r in ("hand", "forearm", "upper_arm")
                        if f"{r}_{s}" in roles), None)
        if arm_end and "chest" in roles:
            chains[f"arm_{s}"] = path(roles["chest"], arm_end)
            effectors[f"arm_{s}"] = arm_end
        leg = [roles[f"{r}_{s}"] for r in ("toe", "foot", "shin", "thigh") if f"{r}_{s}" in roles]
        if leg:
            chains[f"leg_{s}"] = path(legs_root, leg[0])
            effectors[f"leg_{s}"] = next(roles[f"{r}_{s}"] for r in ("foot", "shin", "thigh")
                                         if f"{r}_{s}" in roles)
        base = roles.get(f"hand_{s}", roles.get(f"forearm_{s}"))
        fingers = [idx[v] for k, v in roles.items() if k.endswith(f"_{s}") and
                   k[:-2].rstrip("0123456789") in FINGERS]
        if base is not None and fingers:
            joints: set[int] = set()
            for f in fingers:
                joints.update(idx[n] for n in path(base, skeleton.names[f]))
            chains[f"fingers_{s}"] = tuple(skeleton.names[j] for j in sorted(joints))
    return Chains({name: chains[name] for name in CHAINS if chains.get(name)},
                  {name: effectors[name] for name in CHAINS if chains.get(name)
                   and name in effectors})


def chain_of_joint(chains: dict, joint: str) -> str | None:
    """The chain holding ``joint``, or None."""
    for name, joints in chains.items():
        if joint in joints:
            return name
    return None


def effector(chains: Chains, name: str) -> str:
    """The chain's end joint an IK blend places (wrist/hand for arms, ankle for legs, head for
    the neck, chest for the spine); raises :class:`MotionComposerError` for the fingers or a
    chain the skeleton does not have."""
    if name not in chains.effectors:
        what = "has no end effector" if name in chains else "is not on this character"
        raise MotionComposerError(f"the chain {name!r} {what}")
    return chains.effectors[name]


def mirror_joint(skeleton: Skeleton, joint: str, positions=None) -> str | None:
    """The other side's joint by the automatic roles (``LeftArm`` -> ``RightArm``), None for a
    middle joint or one whose side cannot be told. A sided joint without a role of its own
    (a twist joint in an arm) mirrors to the joint at the same place in the other side's
    chain when both chains have the same length."""
    try:
        roles = identify(skeleton, positions)
    except MappingError:
        return None
    role = roles.role_of(joint)
    if role is not None and role[-2:] in ("_l", "_r"):
        other = role[:-2] + ("_r" if role.endswith("_l") else "_l")
        return roles.get(other)
    chains = chains_of(skeleton, positions)
    name = chain_of_joint(chains, joint)
    if name is None or name[-2:] not in ("_l", "_r"):
        return None
    other = chains.get(name[:-2] + ("_r" if name.endswith("_l") else "_l"), ())
    mine = chains[name]
    return other[mine.index(joint)] if len(other) == len(mine) else None


def left_axis(binding) -> np.ndarray:
    """``(3,)`` the character's left in its bound rest posture before the pose offsets (unit):
    the mean of its left-minus-right joint positions (thighs, upper arms, hands, feet), the
    normal of its sagittal plane. Raises :class:`MotionComposerError` when no left/right
    pair is known."""
    sk = binding.target
    try:
        roles = identify(sk, binding.aligned_positions)
    except MappingError:
        raise MotionComposerError("the character's left and right cannot be told (no "
                                  "humanoid roles): nothing to mirror to") from None
    pos = binding.aligned_positions
    diffs = [pos[sk.index[roles[f"{r}_l"]]] - pos[sk.index[roles[f"{r}_r"]]]
             for r in ("thigh", "upper_arm", "hand", "foot")
             if f"{r}_l" in roles and f"{r}_r" in roles]
    if not diffs:
        raise MotionComposerError("the character has no left/right pair of limbs: nothing "
                                  "to mirror to")
    axis = np.mean(diffs, axis=0)
    return axis / np.linalg.norm(axis)


def mirrored_offset(binding, joint: str, quat) -> tuple[str, np.ndarray]:
    """``(other joint, offset)``: the pose offset ``quat`` ``(4,)`` of ``joint`` reflected
    through the character's sagittal plane (normal :func:`left_axis`), in the other joint's
    binding frame.

    The offset turns ``joint`` by ``R = A q A^-1`` in the world (``A`` its bound rest world
    rotation without its own offset); the mirror image of that turn is ``R' = M R M`` with
    ``M`` the reflection, whose quaternion is ``R``'s with its vector part reflected and
    negated (an axis is a pseudo-vector); the other joint's offset is ``B^-1 R' B``
    (``B`` its world rotation without its own offset). Raises :class:`MotionComposerError`
    for a middle joint."""
    sk = binding.target
    other = mirror_joint(sk, joint, binding.aligned_positions)
    if other is None:
        raise MotionComposerError(f"{joint!r} has no mirror joint on the other side (a middle "
                                  "joint, or its side cannot be told)")
    options = binding.options
    a = qmul(binding.rest_world[sk.index[joint]], qconj(options.offset(joint)))
    b = qmul(binding.rest_world[sk.index[other]], qconj(options.offset(other)))
    turn = qmul(qmul(a, np.asarray(quat, dtype=float)), qconj(a))
    n = left_axis(binding)
    v = turn[:3]
    mirrored = np.concatenate([-(v - 2.0 * np.dot(v, n) * n), turn[3:]])
    out = qmul(qmul(qconj(b), mirrored), b)
    return other, out / np.linalg.norm(out)


def euler_to_offset(degrees_xyz) -> np.ndarray:
    """The offset ``(4,)`` for typed angles ``(X, Y, Z)`` [deg] about the joint's binding-frame
    axes, intrinsic XYZ (``R = Rx Ry Rz``), with w >= 0."""
    angles = np.asarray(degrees_xyz, dtype=float)
    if angles.shape != (3,) or not np.all(np.isfinite(angles)):
        raise MotionComposerError(f"pose offset angles are three finite numbers (X, Y, Z "
                                  f"degrees), not {degrees_xyz!r}")
    q = from_euler(angles, "XYZ")
    return -q if q[3] < 0 else q


def offset_to_euler(quat) -> np.ndarray:
    """The typed angles ``(X, Y, Z)`` [deg] of an offset ``(4,)`` (the inverse of
    :func:`euler_to_offset` away from gimbal lock, Y within (-90, 90))."""
    q = np.asarray(quat, dtype=float)
    return quat_to_euler((q / np.linalg.norm(q))[None], "XYZ", unwrap=False)[0]
