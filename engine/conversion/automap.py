"""Automatic joint correspondence: recognise a humanoid's joints, then map role to role.

:func:`identify` finds the *roles* of a skeleton's joints (hips, spine, chest, neck, head, and
per side clavicle, upper arm, forearm, hand, thigh, shin, foot, toe and finger joints);
:func:`automap` identifies both skeletons and pairs the joints that play the same role, giving
a :class:`~engine.conversion.correspondence.Correspondence` that passes
:meth:`~engine.conversion.correspondence.Correspondence.validate`, with a note per pair saying
how it was decided.

How roles are found
-------------------
Names alone are not trusted: the same word means different joints in different conventions
(``LeftShoulder`` is the clavicle in CMU-MB, Mixamo, FAIR1 and Unity but the upper arm in
CMU-MAX; ``LeftLeg`` is the shin in CMU-MB but a thigh elsewhere; ``LeftHip`` is CMU-MAX's
thigh). So identification is structural, with names as evidence:

1. *Names are normalised* (:func:`parse_name`): namespaces and prefixes go (``mixamorig:``,
   ``CC_Base_``, ``RL_``, ``Bip01``, ``b_``, ``joint_``, ``DEF-`` ...), a trailing ``_012``
   counter goes, the name is cut into words (``LHipJoint`` -> ``L Hip Joint``,
   ``Palm2L`` -> ``Palm 2 L``, ``lhand`` -> ``l hand``), the side word (``Left``/``Right``,
   ``L``/``R``, ``l``/``r`` before or after, with or without a separator) is taken out and
   what remains is matched against synonym tables. A name gives a *set* of possible roles
   (``shoulder`` -> {clavicle, upper arm}; ``leg`` -> {thigh, shin}; a sided ``hip`` ->
   {leg root, thigh}). Twist, share, roll, IK, pole-target, face, breast and end joints are
   *helpers*: they never receive a role.
2. *Anchors*: the head, both hands and the end of both legs (the foot, or the last named leg
   joint when the leg has no foot, as on RobotExpressive, whose ``FootL``/``FootR`` are IK
   bones parented to the root and are rejected because no leg joint is above them). Where
   names do not give all five, the *structural fallback* finds them (below).
3. From the anchors: the **hips** are the lowest common ancestor of both legs and the head
   (where legs and spine meet: ``CC_Base_Hip`` rather than ``CC_Base_Pelvis``, which carries
   only the legs and becomes the ``pelvis`` role; RobotExpressive's ``Body`` rather than its
   ``Hips``, because its legs hang from ``Body`` and its ``Hips`` joint turns only the upper
   body). The **chest** is the lowest common ancestor of both hands and the head; the
   **spine** is the chain from the hips (excluded) to the chest (included); the **neck**
   chain runs from the chest to the head (both excluded). A root above the hips is a
   **ground root** (role ``root``: Bandai's ``joint_Root``, CC3's ``RL_BoneRoot``,
   RobotExpressive's ``Bone``, Unreal's ``root``).
4. *Limb chains*: each arm is the chain from the chest to the hand, each leg the chain from
   where the legs part to the foot (and on to the toe). Roles are placed along a chain in
   anatomical order (clavicle < upper arm < forearm < hand; leg root < thigh < shin < foot <
   toe) by a small dynamic programme that scores every placement: agreement with the name
   (exact or ambiguous), disagreement, the structural position counted back from the chain's
   end, and a penalty for skipping a joint that is not a helper. So ``LeftShoulder`` before
   ``LeftArm`` is a clavicle and ``LeftShoulder`` after ``LeftCollar`` an upper arm.
5. *Sides* come from names where the names have them; otherwise from geometry in a reference
   pose. The body's left is read from the legs' hinges, which do not depend on how the body
   is turned: a knee bends backwards and a foot points forwards, so
   ``(knee - hip) x (ankle - knee)`` and ``(toe - ankle) x (ankle - knee)`` both point to the
   left (right-handed axes: standing along +Y and facing +Z, the left is +X). Where the legs
   are straight and have no toes, left = up x forward with up = hips -> head and forward
   from the feet. The limb whose thigh (upper arm) lies further along ``left`` is the left
   one.
6. *Fingers* are found by name under the forearm (so a thumb hanging from the forearm, as on
   RobotExpressive, counts) and numbered per finger from the hand outwards; metacarpals
   (``LeftInHandIndex``, ``index_metacarpal_l``) are number 0. Conventions: Mixamo
   ``LeftHandThumb1``, CC3 ``CC_Base_L_Thumb1``, Unreal ``thumb_01_l``, Unity
   ``LeftThumbProximal``, 3ds Max Biped ``Finger0`` (thumb) ... ``Finger4``, and MakeHuman
   ``finger1-1.L`` (``finger1`` the thumb ... ``finger5`` the little finger, ``-1``/``-2``/``-3``
   the phalanges; ``metacarpal1.L`` the index finger's metacarpal ... ``metacarpal4.L`` the
   little finger's). A hand with no finger names gets its fingers from its shape
   (:func:`_fingers_by_geometry`: the thumb is the digit set apart from the others, the
   rest are ordered across the hand).

Structural fallback (joints whose names say nothing, e.g. ``joint_0`` ... ``joint_N``): helper
leaves aside, the shortest limb ends (thumbs, fingers, toes, face joints) are pruned until five
ends remain: two legs, two arms and the head. The chest is the deepest joint with exactly
three of these ends below it (arms and head), the legs are the other two; of the chest's three
branches the two most alike (joint count and length: mirror images) are the arms and the odd
one the head. The hand is the first joint beyond 60 % of its arm's length where the unpruned
skeleton branches (fingers and thumb), else the first joint beyond 75 %; the thigh and shin
are the two longest consecutive bones of the leg. Sides then come from geometry, so pass a
real pose (``positions``) where the zero-rotation pose is not anatomical (Bandai, CC3, Rokoko).

How roles are mapped (:func:`automap`)
---------------------------------------
Role to role, wherever both skeletons have the role. Spine chains of different lengths: the
first spine joints map to each other and so do the chests; each middle target joint takes the
performer's middle joint nearest in normalised arc length (bone lengths from the hips to the
chest), one target joint per performer joint, so ancestry is never inverted. The neck chain is
mapped the same way (its first joints when either chain has only one). Fingers map by finger
and number. A final pass drops any pair that would break
:meth:`~engine.conversion.correspondence.Correspondence.validate` (none do on the conventions
tested).

Decision on ground roots: the target's **hips always map to the performer's hips** (the body
root that carries the pelvis motion); joints between a ground root and the hips
(RobotExpressive has none, its ``Body`` is the hips) stay unmapped. The target's ground root
(``root``) is mapped only to the performer's ground root, and only when that carries the
travel the same way on both sides, as told by the position channels:

* both have a ground root, and the performer's hips have no position channels (its ground
  root carries the travel: CC3 ``RL_BoneRoot``) or the target's hips have position channels
  too (both can carry it at the hips: Bandai <- Bandai): ``root <- root``;
* otherwise (the performer has no ground root, or its travel is on its hips while the
  target's hips cannot translate: CC3-RLROOT <- Bandai, whose ``joint_Root`` stands still) the
  target's ground root stays **unmapped** and ``notes[<ground root>]`` says why and that the
  hips carry the motion. :meth:`Correspondence.validate` accepts an unmapped root above a
  mapped hips, and :func:`engine.conversion.retarget` then places the body from the hips.

Mapping the target's ground root to the performer's hips instead would leave no performer
joint for the target's hips (the map is one to one) and pin the body's root on the floor
joint; the rule above was checked by retargeting: Bandai <- CC3-RLROOT travels 3.71 m for
the performer's 3.82 m with the roots mapped (the unmapped alternative goes wrong), and
CC3-RLROOT <- Bandai travels with the root unmapped (mapped, it would stand still).
"""
from __future__ import annotations

import functools
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

import numpy as np

from .correspondence import Correspondence
from ..errors import MappingError
from ..skeleton import Skeleton

__all__ = ["Roles", "NameInfo", "identify", "automap", "parse_name", "ARM_ROLES", "LEG_ROLES",
           "FINGERS", "SIDES"]

#: the arm's roles from the chest outwards
ARM_ROLES = ("clavicle", "upper_arm", "forearm", "hand")
#: the leg's roles from the hips downwards (``hip_joint``: a leg root between the hips and the
#: thigh, CMU's ``LHipJoint``)
LEG_ROLES = ("hip_joint", "thigh", "shin", "foot", "toe")
FINGERS = ("thumb", "index", "middle", "ring", "pinky")
SIDES = ("l", "r")

_LABELS = {"clavicle": "clavicle", "upper_arm": "upper arm", "forearm": "forearm",
           "hand": "hand", "hip_joint": "leg root", "thigh": "thigh", "shin": "shin",
           "foot": "foot", "toe": "toe"}


# ============================================================================ names
@dataclass(frozen=True)
class NameInfo:
    """What a joint's name says.

    Attributes:
        side: ``"l"``, ``"r"`` or ``None``.
        core: the normalised name without side and digits (``"upperarm"``).
        numbers: the numbers in the name, in order.
        helper: a twist/share/roll/IK/pole/face/end joint that never takes a role.
        roles: the body roles the name allows (``{"clavicle", "upper_arm"}`` for a shoulder);
            empty when the name says nothing.
        finger: ``"thumb"`` ... ``"pinky"`` for a finger joint, ``""`` for an unspecified
            finger joint (CMU's ``LFingers``), ``None`` otherwise.
        metacarpal: a finger's root inside the palm (``LeftInHandIndex``).
    """

    side: str | None
    core: str
    numbers: tuple[int, ...] = ()
    helper: bool = False
    roles: frozenset = frozenset()
    finger: str | None = None
    metacarpal: bool = False


_PREFIX = re.compile(r"^(?:cc_base_|rl_|bip0*1(?:[ _]|$)|biped_|b_|joint_|jnt_|def[-_]|"
                     r"org[-_]|mch[-_]|bn_)", re.I)
_WORDS = re.compile(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|\d+")
_HELPER_PARTS = ("twist", "share", "pole", "target", "breast", "ribs", "tongue", "teeth",
                 "facial", "jaw", "eye", "nub", "helper", "corrective", "socket", "weapon",
                 "prop", "dummy", "attach", "hair", "skirt", "cloth", "cape")
_HELPER_WORDS = {"ik", "end", "top", "roll", "ctrl", "ctl", "fk", "tip", "null"}
_FINGER_WORDS = (("thumb", "thumb"), ("index", "index"), ("middle", "middle"), ("mid", "middle"),
                 ("ring", "ring"), ("pinky", "pinky"), ("pinkie", "pinky"),
                 ("little", "pinky"))
# checked in order: the first word contained in the core decides
_BODY_WORDS = (
    ("hipjoint", {"hip_joint"}),
    ("upleg", {"thigh"}), ("upperleg", {"thigh"}), ("legupper", {"thigh"}),
    ("thigh", {"thigh"}),
    ("lowerleg", {"shin"}), ("lowleg", {"shin"}), ("leglower", {"shin"}), ("calf", {"shin"}),
    ("shin", {"shin"}), ("knee", {"shin"}),
    ("foot", {"foot"}), ("ankle", {"foot"}),
    ("clavicle", {"clavicle"}), ("collar", {"clavicle"}), ("clav", {"clavicle"}),
    ("shoulder", {"clavicle", "upper_arm"}), ("shldr", {"clavicle", "upper_arm"}),
    ("upperarm", {"upper_arm"}), ("uparm", {"upper_arm"}), ("armupper", {"upper_arm"}),
    ("uarm", {"upper_arm"}), ("humerus", {"upper_arm"}),
    ("forearm", {"forearm"}), ("lowerarm", {"forearm"}), ("lowarm", {"forearm"}),
    ("armlower", {"forearm"}), ("farm", {"forearm"}), ("elbow", {"forearm"}),
    ("wrist", {"hand"}), ("hand", {"hand"}), ("palm", {"hand"}),
    ("leg", {"thigh", "shin"}),
    ("arm", {"upper_arm"}),
)
_TRUNK_WORDS = (("pelvis", "hips"), ("hip", "hips"), ("head", "head"), ("skull", "head"),
                ("neck", "neck"), ("spine", "spine"), ("back", "spine"), ("waist", "spine"),
                ("abdomen", "spine"), ("torso", "spine"), ("chest", "spine"),
                ("thorax", "spine"), ("ribcage", "spine"))


def _classify(core: str, words: list[str], sided: bool):
    """(helper, roles, finger, metacarpal, trunk) for a normalised core."""
    if not core:
        return False, frozenset(), None, False, None
    if any(p in core for p in _HELPER_PARTS) or any(w in _HELPER_WORDS for w in words) or \
            (core.endswith("end") and _ends_known(core[:-3])):
        return True, frozenset(), None, False, None
    if "toe" in core or "ball" in core:
        return False, frozenset({"toe"}), None, False, None
    meta = "inhand" in core or "meta" in core or "carpal" in core
    for word, finger in _FINGER_WORDS:
        if word in core:
            return False, frozenset(), finger, meta, None
    if "finger" in core:
        return False, frozenset(), "", meta, None
    if core in ("hip", "hips") and sided:
        return False, frozenset({"hip_joint", "thigh"}), None, False, None
    for word, roles in _BODY_WORDS:
        if word in core:
            return False, frozenset(roles), None, False, None
    for word, trunk in _TRUNK_WORDS:
        if word in core:
            return False, frozenset(), None, False, trunk
    return False, frozenset(), None, False, None


#: whole words that a side letter may be glued to (``lhand``, ``shoulderl``, ``leftarm``)
_VOCAB = ({w for w, _ in _BODY_WORDS} | {w for w, _ in _TRUNK_WORDS} |
          {w for w, _ in _FINGER_WORDS} |
          {"hips", "toe", "toes", "toebase", "ball", "finger", "fingers", "fingerbase",
           "upperleg", "lowerleg", "upperarm", "lowerarm", "forearm", "upleg", "twist"})


def _known(word: str) -> bool:
    return word in _VOCAB


_END_AFTER = tuple(_VOCAB | _HELPER_WORDS)


def _ends_known(text: str) -> bool:
    """Whether ``text`` ends with a known word (``head`` of ``headend``): an ``end`` glued to
    a body word marks an end joint, but ``bend`` does not (Daz's ``lShldrBend``, its upper
    arm, was taken for a helper)."""
    return any(text.endswith(w) for w in _END_AFTER)


_SIDE_WORDS = {"l": "l", "left": "l", "r": "r", "right": "r"}


def parse_name(name: str) -> NameInfo:
    """Normalise a joint name and read its side and possible roles (see the module notes)."""
    info, _ = _parse(name)
    return info


@functools.lru_cache(maxsize=4096)      # a pure function of the name, asked for every read
def _parse(name: str) -> tuple[NameInfo, str | None]:
    s = re.split(r"[:|]", str(name))[-1].strip()
    for _ in range(3):
        s2 = _PREFIX.sub("", s)
        if s2 == s:
            break
        s = s2
    s = re.sub(r"_\d+$", "", s) if re.search(r"[A-Za-z]", re.sub(r"_\d+$", "", s)) else s
    # MakeHuman fingers: finger1-1 = the thumb's first phalanx ... finger5-3 = the little
    # finger's last; metacarpal1 = the index finger's metacarpal ... metacarpal4 = the little's
    makehuman = re.search(r"finger([1-5])-(\d)", s, re.I)
    mh_metacarpal = re.fullmatch(r"metacarpal([1-4])\W*[LRlr]?", s)
    # 3ds Max Biped fingers: Finger0 = thumb ... Finger4 = pinky, Finger01 its second joint
    biped = None if makehuman else re.search(r"finger(\d)(\d?)", s, re.I)
    words = [w.lower() for w in _WORDS.findall(s)]
    sides = set()
    kept: list[str] = []
    for w in words:
        if w in _SIDE_WORDS:
            sides.add(_SIDE_WORDS[w])
            continue
        if not w.isdigit() and not _known(w):
            split = False
            for pre, side in (("left", "l"), ("right", "r"), ("l", "l"), ("r", "r")):
                if w.startswith(pre) and len(w) > len(pre) + 1 and _known(w[len(pre):]):
                    sides.add(side)
                    kept.append(w[len(pre):])
                    split = True
                    break
                if w.endswith(pre) and len(w) > len(pre) + 1 and _known(w[:-len(pre)]):
                    sides.add(side)
                    kept.append(w[:-len(pre)])
                    split = True
                    break
            if split:
                continue
        kept.append(w)
    side = sides.pop() if len(sides) == 1 else None
    core = "".join(w for w in kept if not w.isdigit())
    if not sides and core[:1] in ("l", "r") and _known(core[1:]):
        # a side letter glued to an abbreviation split off as its own word: OptiTrack
        # Motive's LFArm (words "LF", "Arm") is the left forearm
        side, core = core[0], core[1:]
        kept = [core]
    numbers = tuple(int(w) for w in kept if w.isdigit())
    helper, roles, finger, meta, trunk = _classify(core, kept, side is not None)
    if biped and not helper:
        finger = FINGERS[min(int(biped.group(1)), 4)]
        numbers = (int(biped.group(2)) + 1 if biped.group(2) else 1,)
        roles = frozenset()
    if makehuman and not helper:
        finger = FINGERS[int(makehuman.group(1)) - 1]
        numbers = (int(makehuman.group(2)),)
        roles = frozenset()
    if mh_metacarpal and not helper:
        finger, meta = FINGERS[int(mh_metacarpal.group(1))], True
    return NameInfo(side, core, numbers, helper, roles, finger, meta), trunk


# ============================================================================ roles
@dataclass(frozen=True)
class Roles(Mapping):
    """The humanoid roles of one skeleton's joints: a read-only mapping from role key to joint
    name, plus the chains.

    Role keys: ``root`` (a ground-level root above the hips, only when there is one),
    ``hips``, ``pelvis`` (a joint below the hips carrying both legs, CC3), ``chest``,
    ``neck`` (the first neck joint), ``head``; per side ``s`` in ``l``/``r``:
    ``clavicle_s``, ``upper_arm_s``, ``forearm_s``, ``hand_s``, ``hip_joint_s`` (a leg root
    between hips and thigh, CMU's ``LHipJoint``), ``thigh_s``, ``shin_s``, ``foot_s``,
    ``toe_s``, and finger joints ``<finger><n>_s`` (``index1_l``; ``0`` a metacarpal).
    A role the skeleton lacks is absent (RobotExpressive has no ``foot_l``).

    Attributes:
        joints: role key -> joint name.
        spine: the spine chain, hips (excluded) to chest (included).
        neck_chain: the joints between the chest and the head.
        how: role key -> how it was decided (``"name"``, ``"structure"``, with the side's
            source), for notes and display.
        method: ``"names"`` when the anchors (head, hands, legs) came from names,
            ``"structure"`` when from the structural fallback.
        sides: ``"names"``, ``"geometry"`` or ``"unknown"``.
    """

    joints: dict[str, str]
    spine: tuple[str, ...] = ()
    neck_chain: tuple[str, ...] = ()
    how: dict[str, str] = field(default_factory=dict, compare=False)
    method: str = "names"
    sides: str = "names"

    def __getitem__(self, key: str) -> str:
        return self.joints[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.joints)

    def __len__(self) -> int:
        return len(self.joints)

    def role_of(self, joint: str) -> str | None:
        """The role key of a joint name, or ``None``."""
        for k, v in self.joints.items():
            if v == joint:
                return k
        if joint in self.spine:
            return f"spine{self.spine.index(joint)}"
        return None


class _Tree:
    """Structural queries on a skeleton (parents, paths, bone lengths)."""

    def __init__(self, sk: Skeleton):
        self.sk = sk
        self.parents = [int(p) for p in sk.parents]
        self.children = [list(c) for c in sk.children]
        self.depth = [int(d) for d in sk.depth]
        self.bone = np.linalg.norm(sk.offsets, axis=1)        # parent -> joint
        self.bone[0] = 0.0
        ends = np.zeros(sk.num_joints)
        for site in sk.end_sites:
            ends[site.parent] = max(ends[site.parent], float(np.linalg.norm(site.offset)))
        self.end = ends

    def chain_up(self, j: int) -> list[int]:
        out = [j]
        while self.parents[out[-1]] >= 0:
            out.append(self.parents[out[-1]])
        return out

    def is_ancestor(self, a: int, j: int) -> bool:
        """Whether ``a`` is ``j`` or above it."""
        while j >= 0:
            if j == a:
                return True
            j = self.parents[j]
        return False

    def lca(self, joints) -> int:
        joints = list(joints)
        common = set(self.chain_up(joints[0]))
        for j in joints[1:]:
            common &= set(self.chain_up(j))
        return max(common, key=lambda k: self.depth[k])

    def path(self, top: int, bottom: int) -> list[int]:
        """Joints from ``top`` (excluded) down to ``bottom`` (included)."""
        out = []
        j = bottom
        while j != top and j >= 0:
            out.append(j)
            j = self.parents[j]
        return out[::-1]

    def subtree(self, j: int) -> list[int]:
        out, stack = [], [j]
        while stack:
            k = stack.pop()
            out.append(k)
            stack.extend(self.children[k])
        return out


def _zero_pose(sk: Skeleton) -> np.ndarray:
    pos = np.zeros((sk.num_joints, 3))
    pos[0] = sk.offsets[0]
    for j in range(1, sk.num_joints):
        pos[j] = pos[sk.parents[j]] + sk.offsets[j]
    return pos


def identify(skeleton: Skeleton, positions=None) -> Roles:
    """Find the humanoid roles of ``skeleton``'s joints (see the module notes).

    Args:
        skeleton: any skeleton.
        positions: ``(J, 3)`` (or ``(1, J, 3)``) [m] world joint positions of a reference pose,
            used to tell left from right where names do not; default the zero-rotation pose
            (pass a real frame for skeletons whose zero pose is not anatomical).

    Raises:
        MappingError: when no humanoid (two legs, two arms and a head) can be found.
    """
    sk = skeleton
    tree = _Tree(sk)
    parsed = [_parse(n) for n in sk.names]
    info = [p[0] for p in parsed]
    if positions is None:
        pos = _zero_pose(sk)
    else:
        pos = np.asarray(positions, dtype=float).reshape(-1, sk.num_joints, 3)[0]
    method = "names"
    anchors = _named_anchors(tree, info, [p[1] for p in parsed])
    if anchors is None or not _humanoid(tree, anchors):
        method = "structure"
        anchors = _structural_anchors(tree, info)
    head, hands, legs, leg_is_foot = anchors
    hips = tree.lca([legs[0], legs[1], head])
    chest = tree.lca([hands[0], hands[1], head])
    if not _humanoid(tree, anchors):
        raise MappingError(f"the skeleton's arms and head do not branch from above its legs "
                           f"(hips {sk.names[hips]!r}, chest {sk.names[chest]!r}); map it by "
                           "hand")
    joints: dict[str, str] = {}
    how: dict[str, str] = {}
    src = "name" if method == "names" else "structure"
    if hips != 0:
        joints["root"] = sk.names[0]
        how["root"] = "above the hips"
    joints["hips"] = sk.names[hips]
    how["hips"] = "where legs and spine meet"
    legs_root = tree.lca([legs[0], legs[1]])
    spine = tree.path(hips, chest)
    if legs_root != hips and legs_root not in spine and tree.is_ancestor(hips, legs_root):
        joints["pelvis"] = sk.names[legs_root]
        how["pelvis"] = "carries both legs, below the hips"
    else:
        legs_root = hips
    joints["chest"] = sk.names[chest]
    how["chest"] = "where arms and neck branch"
    neck_chain = tree.path(chest, head)[:-1]
    if neck_chain:
        joints["neck"] = sk.names[neck_chain[0]]
        how["neck"] = "first joint from chest to head"
    joints["head"] = sk.names[head]
    how["head"] = src

    # limbs, without sides yet
    arms = [_arm_chain(tree, info, chest, h) for h in hands]
    leg_roles = [_leg_chain(tree, info, legs_root, e, is_foot, method == "structure")
                 for e, is_foot in zip(legs, leg_is_foot)]

    # sides
    side_method = "names"
    if method == "names":
        order_arms, order_legs = (0, 1), (0, 1)          # anchors were found per side
    else:
        order_arms = _sides_by_name(info, [list(a.values()) for a in arms])
        order_legs = _sides_by_name(info, [list(a.values()) for a in leg_roles])
        if order_arms is None or order_legs is None:
            left = _left_axis(pos, hips, head, leg_roles)
            if left is None:
                side_method = "unknown"
                order_arms, order_legs = (0, 1), (0, 1)
            else:
                side_method = "geometry"
                order_legs = _order_by(pos, left, leg_roles, ("thigh", "shin", "foot"))
                order_arms = _order_by(pos, left, arms, ("upper_arm", "forearm", "hand"))
    side_note = {"names": "side by name", "geometry": "side by geometry",
                 "unknown": "side unknown"}[side_method]
    for side, k in zip(SIDES, order_arms):
        for role, j in arms[k].items():
            joints[f"{role}_{side}"] = sk.names[j]
            how[f"{role}_{side}"] = f"{_how(info[j], role)}, {side_note}"
    for side, k in zip(SIDES, order_legs):
        for role, j in leg_roles[k].items():
            joints[f"{role}_{side}"] = sk.names[j]
            how[f"{role}_{side}"] = f"{_how(info[j], role)}, {side_note}"
    for side, k in zip(SIDES, order_arms):
        arm = arms[k]
        base = arm.get("forearm", arm.get("hand"))
        fingers, finger_how = _fingers(tree, info, base, set(arm.values()), side), "name"
        if not fingers and "hand" in arm:
            fingers, finger_how = _fingers_by_geometry(tree, info, arm["hand"], pos), \
                "hand geometry"
        for key, j in fingers.items():
            joints[f"{key}_{side}"] = sk.names[j]
            how[f"{key}_{side}"] = finger_how
    return Roles(joints, tuple(sk.names[j] for j in spine),
                 tuple(sk.names[j] for j in neck_chain), how, method, side_method)


def _how(info: NameInfo, role: str) -> str:
    if role in info.roles:
        return "name" if len(info.roles) == 1 else "ambiguous name + chain position"
    return "chain position"


# ---------------------------------------------------------------------------- anchors
def _humanoid(tree: _Tree, anchors) -> bool:
    """Whether arms and head branch (at the chest) strictly above where legs and head meet
    (the hips)."""
    head, hands, legs, _ = anchors
    hips = tree.lca([legs[0], legs[1], head])
    chest = tree.lca([hands[0], hands[1], head])
    return chest != hips and tree.is_ancestor(hips, chest)


def _named_anchors(tree: _Tree, info: list[NameInfo], trunks: list[str | None]):
    """Head, hands (l, r) and leg ends (l, r) from names, or None if any is missing."""
    J = tree.sk.num_joints
    heads = [j for j in range(J) if not info[j].helper and info[j].side is None and
             trunks[j] == "head"]
    if not heads:
        return None
    head = min(heads, key=lambda j: (tree.depth[j], j))
    hands, legs, is_foot = [], [], []
    leg_words = {"hip_joint", "thigh", "shin"}
    for side in SIDES:
        cands = [j for j in range(J) if info[j].side == side and not info[j].helper and
                 info[j].roles == {"hand"} and info[j].finger is None]
        if not cands:
            return None
        d = min(tree.depth[j] for j in cands)
        top = [j for j in cands if tree.depth[j] == d]
        with_middle = [j for j in top if any(info[k].finger == "middle"
                                             for k in tree.subtree(j))]
        hands.append((with_middle or top)[0])
        feet = [j for j in range(J) if info[j].side == side and not info[j].helper and
                info[j].roles == {"foot"} and
                any(info[a].roles and info[a].roles <= leg_words and info[a].side in (side, None)
                    for a in tree.chain_up(j)[1:])]
        if feet:
            legs.append(min(feet, key=lambda j: (tree.depth[j], j)))
            is_foot.append(True)
            continue
        leg = [j for j in range(J) if info[j].side == side and not info[j].helper and
               info[j].roles and info[j].roles <= leg_words]
        if not leg:
            return None
        legs.append(max(leg, key=lambda j: (tree.depth[j], -j)))
        is_foot.append(False)
    if len({head, *hands, *legs}) < 5 or any(
            tree.is_ancestor(a, b) for a in hands + legs for b in hands + legs if a != b):
        return None
    return head, hands, legs, is_foot


def _structural_anchors(tree: _Tree, info: list[NameInfo]):
    """Head, two hands and two leg ends from the shape of the hierarchy alone."""
    sk = tree.sk
    J = sk.num_joints
    # helper joints whose whole subtree is helpers are left out
    active = [True] * J
    for j in range(J - 1, -1, -1):
        if info[j].helper and all(not active[c] for c in tree.children[j]):
            active[j] = False
    active[0] = True
    kids = [[c for c in tree.children[j] if active[c]] for j in range(J)]
    full_kids = [list(k) for k in kids]

    def leaves():
        return [j for j in range(1, J) if active[j] and not kids[j]]

    def branch(leaf):
        """Joints from the leaf up to (excluding) the nearest junction, and their length."""
        joints, length, j = [], tree.end[leaf], leaf
        while j > 0 and len(kids[tree.parents[j]]) < 2:
            joints.append(j)
            length += tree.bone[j]
            j = tree.parents[j]
        joints.append(j)
        length += tree.bone[j]
        return joints, length

    ends = leaves()
    while len(ends) > 5:
        joints, _ = min((branch(e) for e in ends), key=lambda b: b[1])
        for j in joints:
            active[j] = False
        top = tree.parents[joints[-1]]
        kids[top] = [c for c in kids[top] if active[c]]
        ends = leaves()
    if len(ends) != 5:
        raise MappingError(f"cannot recognise a humanoid: the skeleton has {len(ends)} limb "
                           "ends where two legs, two arms and a head were expected; map it "
                           "by hand")

    def below(j):
        return [e for e in ends if tree.is_ancestor(j, e)]

    juncs = [j for j in range(J) if active[j] and len(kids[j]) >= 2 and len(below(j)) == 3]
    if not juncs:
        raise MappingError("cannot recognise a humanoid: no joint carries two arms and a "
                           "head; map it by hand")
    chest = max(juncs, key=lambda j: tree.depth[j])
    upper = below(chest)
    legs = [e for e in ends if e not in upper]
    branches = [tree.path(chest, e) for e in upper]
    # each branch's length, its End Site counted up to the length of its bones (an End Site
    # longer than the rest of the limb is a mistyped or fuzzed offset, not a fingertip)
    bones = [sum(tree.bone[j] for j in b) for b in branches]
    lengths = [n + min(tree.end[b[-1]], n) for n, b in zip(bones, branches)]

    def unlike(a, b):
        la, lb = lengths[a], lengths[b]
        return abs(la - lb) / max(la, lb, 1e-9) + 0.2 * abs(len(branches[a]) - len(branches[b]))

    def proximal(j, branch, total):
        """Step up from ``j`` through zero-length bones (coincident joints, such as CC3's
        FacialBone on its Head) to the first joint of that place on the branch."""
        while tree.bone[j] <= 1e-3 * total and tree.parents[j] in branch:
            j = tree.parents[j]
        return j

    pairs = [(0, 1), (0, 2), (1, 2)]
    arm_pair = min(pairs, key=lambda p: unlike(*p))
    k_head = ({0, 1, 2} - set(arm_pair)).pop()
    head_branch = branches[k_head]
    head = next((j for j in head_branch if len(full_kids[j]) >= 2), head_branch[-1])
    head = proximal(head, head_branch, lengths[k_head])
    hands = []
    for k in arm_pair:
        b, total = branches[k], lengths[k]
        cum = np.cumsum([tree.bone[j] for j in b])
        hand = next((j for j, c in zip(b, cum) if c >= 0.6 * total and len(full_kids[j]) >= 2),
                    None)
        if hand is None:
            # the branch's length counts its End Site: one longer than a quarter of it leaves
            # no joint that far along, and the hand is the branch's last joint
            hand = next((j for j, c in zip(b, cum) if c >= 0.75 * total - 1e-12), b[-1])
        hands.append(proximal(hand, b, total))
    return head, hands, legs, [False, False]


# ---------------------------------------------------------------------------- chains
def _place(chain: list[int], roles: tuple[str, ...], info: list[NameInfo],
           priors: dict[str, int]) -> dict[str, int]:
    """Place ``roles`` (in order) on ``chain`` (in order) to best agree with names, the
    structural ``priors`` (role -> chain index) and contiguity. Returns role -> joint."""
    n, k = len(chain), len(roles)
    if not n or not k:
        return {}
    neg = -1e9
    solid = np.cumsum([0] + [0 if info[j].helper else 1 for j in chain])

    def score(i, r):
        inf = info[chain[i]]
        if inf.helper or inf.finger is not None:
            return neg
        s = 0.5
        if inf.roles:
            if roles[r] in inf.roles:
                s += 4.0 if len(inf.roles) == 1 else 2.0
            else:
                s -= 4.0
        if priors.get(roles[r]) == i:
            s += 1.0
        return s

    g = np.full((k, n), neg)
    back: dict[tuple[int, int], tuple[int, int] | None] = {}
    for r in range(k):
        for i in range(n):
            s = score(i, r)
            if s <= neg / 2:
                continue
            best, arg = 0.0, None
            for r2 in range(r):
                for i2 in range(i):
                    if g[r2, i2] <= neg / 2:
                        continue
                    v = g[r2, i2] - (solid[i] - solid[i2 + 1])
                    if v > best:
                        best, arg = v, (r2, i2)
            g[r, i] = s + best
            back[(r, i)] = arg
    if g.max() <= 0:
        return {}
    cell: tuple[int, int] | None = tuple(int(x) for x in np.unravel_index(np.argmax(g), g.shape))
    out = {}
    while cell is not None:
        r, i = cell
        out[roles[r]] = chain[i]
        cell = back[cell]
    return out


def _arm_chain(tree: _Tree, info, chest: int, hand: int) -> dict[str, int]:
    chain = tree.path(chest, hand)
    body = chain[:-1]
    n = len(chain)
    priors = {"forearm": n - 2, "upper_arm": n - 3, "clavicle": n - 4}
    out = _place(body, ARM_ROLES[:3], info, {r: i for r, i in priors.items() if i >= 0})
    out["hand"] = hand
    return {r: out[r] for r in ARM_ROLES if r in out}


def _leg_chain(tree: _Tree, info, legs_root: int, end: int, is_foot: bool,
               structural: bool) -> dict[str, int]:
    chain = tree.path(legs_root, end)
    if is_foot:
        n = len(chain)
        priors = {"shin": n - 2, "thigh": n - 3, "hip_joint": n - 4}
        out = _place(chain[:-1], LEG_ROLES[:3], info,
                     {r: i for r, i in priors.items() if i >= 0})
        out["foot"] = end
        toe = _toe_after(tree, info, end)
        if toe is not None:
            out["toe"] = toe
        return {r: out[r] for r in LEG_ROLES if r in out}
    # extend to a leaf along the longest non-helper branch
    j = end
    while True:
        nxt = [c for c in tree.children[j] if not info[c].helper]
        if not nxt:
            break
        j = max(nxt, key=lambda c: (_reach(tree, info, c), -c))
        chain.append(j)
    priors = {}
    if structural:
        bones = [tree.bone[c] for c in chain[1:]] + [tree.end[chain[-1]]]
        if len(chain) >= 2:
            i = max(range(len(chain) - 1), key=lambda i: (bones[i] + bones[i + 1], -i))
            priors = {"hip_joint": i - 1, "thigh": i, "shin": i + 1, "foot": i + 2,
                      "toe": i + 3}
            priors = {r: x for r, x in priors.items() if 0 <= x < len(chain)}
    out = _place(chain, LEG_ROLES, info, priors)
    return {r: out[r] for r in LEG_ROLES if r in out}


def _reach(tree: _Tree, info, j: int) -> float:
    """Longest bone-length path from ``j`` down to a leaf (helpers left out)."""
    best = tree.end[j]
    for c in tree.children[j]:
        if not info[c].helper:
            best = max(best, tree.bone[c] + _reach(tree, info, c))
    return best


def _toe_after(tree: _Tree, info, foot: int) -> int | None:
    kids = [c for c in tree.children[foot] if not info[c].helper]
    if not kids:
        return None
    named = [c for c in kids if "toe" in info[c].roles]
    return (named or [max(kids, key=lambda c: (tree.bone[c] + _reach(tree, info, c), -c))])[0]


def _fingers(tree: _Tree, info, base: int, skip: set, side: str) -> dict[str, int]:
    found: dict[str, list[int]] = {}
    for j in tree.subtree(base):
        inf = info[j]
        if j in skip or inf.helper or not inf.finger or inf.side not in (side, None):
            continue
        found.setdefault(inf.finger, []).append(j)
    out = {}
    for finger, joints in found.items():
        joints.sort(key=lambda j: (tree.depth[j], j))
        n = 1
        for j in joints:
            if info[j].metacarpal:
                key = f"{finger}0"
            else:
                key = f"{finger}{n}"
                n += 1
            out.setdefault(key, j)
    return out


def _finger_chains(tree: _Tree, info, hand: int) -> list[list[int]]:
    """The digit chains of a hand: from each non-helper child of ``hand`` down its longest
    branch."""
    chains = []
    for c in tree.children[hand]:
        if info[c].helper:
            continue
        chain = [c]
        while True:
            kids = [k for k in tree.children[chain[-1]] if not info[k].helper]
            if not kids:
                break
            chain.append(max(kids, key=lambda k: (tree.bone[k] + _reach(tree, info, k), -k)))
        chains.append(chain)
    return chains


def _fingers_by_geometry(tree: _Tree, info, hand: int, pos: np.ndarray) -> dict[str, int]:
    """Finger roles of a hand whose joints have no finger names, from its shape in ``pos``
    (``(J, 3)`` reference positions).

    Each child chain of the hand is a digit, stood for by the centroid of its joints. With
    three digits or more, the **thumb** is the digit farthest from the centroid of the others
    (it leaves the palm towards its front, the fingers lie side by side); with two, the
    shorter one (fewer joints, then less reach: CMU's ``LThumb`` beside
    ``LeftFingerBase > LFingers``). The other digits are ordered across the hand (in the
    plane normal to the fingers' mean direction from the wrist), by their position along the
    line from the thumb to the digit farthest from it: index, middle, ring, pinky. A finger
    chain of four joints or more whose first bone (from the hand) is shorter than its second
    starts with a metacarpal (number 0: Rokoko's ``LeftInHandIndex``); otherwise the joints
    are numbered 1, 2, ... from the hand (Mixamo's ``Index1``, whose first bone crosses the
    palm). A single digit, or more than five, says nothing: no roles. A hand whose fingers
    hang from the forearm (RobotExpressive's palms) gets none this way.
    """
    chains = _finger_chains(tree, info, hand)
    if not 2 <= len(chains) <= 5:
        return {}
    centres = np.array([pos[chain].mean(axis=0) for chain in chains])
    if len(chains) == 2:
        thumb = min(range(2), key=lambda i: (len(chains[i]),
                                             tree.bone[chains[i][0]] +
                                             _reach(tree, info, chains[i][0])))
    else:
        apart = [np.linalg.norm(centres[i] - np.delete(centres, i, axis=0).mean(axis=0))
                 for i in range(len(chains))]
        thumb = int(np.argmax(apart))
    rest = [i for i in range(len(chains)) if i != thumb]
    # across the hand: in the plane normal to the fingers' direction (the wrist to their
    # centroid), so that how far each finger reaches does not count
    along = centres[rest].mean(axis=0) - pos[hand]
    along = along / max(float(np.linalg.norm(along)), 1e-12)
    flat = centres - centres[thumb]
    flat = flat - np.outer(flat @ along, along)
    far = max(rest, key=lambda i: float(np.linalg.norm(flat[i])))
    rest.sort(key=lambda i: float(np.dot(flat[i], flat[far])))
    out = {}
    for finger, i in zip(FINGERS, [thumb] + rest):
        chain = chains[i]
        if finger != "thumb" and len(chain) >= 4 and tree.bone[chain[0]] < tree.bone[chain[1]]:
            out[f"{finger}0"] = chain[0]
            chain = chain[1:]
        for n, j in enumerate(chain, start=1):
            out[f"{finger}{n}"] = j
    return out


# ---------------------------------------------------------------------------- sides
def _sides_by_name(info, chains: list[list[int]]) -> tuple[int, int] | None:
    """(index of the left chain, index of the right chain) if names say so, else None."""
    votes = []
    for chain in chains:
        v = sum(1 if info[j].side == "l" else -1 if info[j].side == "r" else 0 for j in chain)
        votes.append(v)
    if votes[0] > 0 > votes[1]:
        return 0, 1
    if votes[1] > 0 > votes[0]:
        return 1, 0
    return None


def _left_axis(pos: np.ndarray, hips: int, head: int, legs: list[dict]) -> np.ndarray | None:
    """The body's left direction in ``pos`` (see the module notes), or None if the pose does
    not tell."""
    def p(leg, role):
        return pos[leg[role]]

    # the leg's hinges: a knee bends backwards and a foot points forwards, so both
    # (knee - hip) x (ankle - knee) and (toe - ankle) x (ankle - knee) point to the body's
    # left whatever the pose's orientation (bent over, lying, upside down)
    left = np.zeros(3)
    scale = 0.0
    for leg in legs:
        if all(r in leg for r in ("thigh", "shin", "foot")):
            thigh = p(leg, "shin") - p(leg, "thigh")
            shin = p(leg, "foot") - p(leg, "shin")
            left += np.cross(thigh, shin)
            scale += np.linalg.norm(thigh) * np.linalg.norm(shin)
            if "toe" in leg:
                foot = p(leg, "toe") - p(leg, "foot")
                left += np.cross(foot, shin)
                scale += np.linalg.norm(foot) * np.linalg.norm(shin)
    if scale > 0 and np.linalg.norm(left) > 0.05 * scale:
        return left / np.linalg.norm(left)
    # straight legs and no toes: left = up x forward, forward from whatever the feet give
    up = pos[head] - pos[hips]
    if np.linalg.norm(up) < 1e-9:
        return None
    up = up / np.linalg.norm(up)
    fwd = np.zeros(3)
    for leg in legs:
        if "foot" in leg and "toe" in leg:
            fwd += p(leg, "toe") - p(leg, "foot")
        if all(r in leg for r in ("thigh", "shin", "foot")):
            fwd += p(leg, "shin") - 0.5 * (p(leg, "thigh") + p(leg, "foot"))
    fwd -= np.dot(fwd, up) * up
    if np.linalg.norm(fwd) < 1e-9:
        return None
    left = np.cross(up, fwd)
    return left / np.linalg.norm(left)


def _order_by(pos, left, limbs: list[dict], keys) -> tuple[int, int]:
    for key in keys:
        if key in limbs[0] and key in limbs[1]:
            d = np.dot(pos[limbs[0][key]] - pos[limbs[1][key]], left)
            if abs(d) > 1e-9:
                return (0, 1) if d > 0 else (1, 0)
    return 0, 1


# ============================================================================ mapping
def _bone_arc(tree: _Tree, chain: list[int]) -> np.ndarray:
    """Normalised arc length along ``chain`` by bone lengths: 0 at its first joint, 1 at its
    last."""
    s = np.cumsum([tree.bone[j] for j in chain])
    span = s[-1] - s[0]
    if len(chain) < 2:
        return np.zeros(len(chain))
    if span <= 1e-12:
        return np.linspace(0.0, 1.0, len(chain))
    return (s - s[0]) / span


def _map_chain(tt: _Tree, pt: _Tree, tchain: list[int], pchain: list[int], keep: str,
               label: str) -> list[tuple[int, int, str]]:
    """Pairs (target, performer, note) for two chains: ends exactly, middles by arc length."""
    if not tchain or not pchain:
        return []
    nt, np_ = len(tchain), len(pchain)
    if nt == 1 or np_ == 1:
        if keep == "last":
            return [(tchain[-1], pchain[-1], f"{label} end {nt}/{nt} -> {np_}/{np_}")]
        return [(tchain[0], pchain[0], f"{label} 1/{nt} -> 1/{np_}")]
    out = [(tchain[0], pchain[0], f"{label} 1/{nt} -> 1/{np_} (first)"),
           (tchain[-1], pchain[-1], f"{label} {nt}/{nt} -> {np_}/{np_} (last)")]
    if nt > 2 and np_ > 2:
        ta = _bone_arc(tt, tchain)
        pa = _bone_arc(pt, pchain)
        choice = {}
        for i in range(1, nt - 1):
            j = 1 + int(np.argmin(np.abs(pa[1:-1] - ta[i])))
            d = abs(pa[j] - ta[i])
            if j not in choice or d < choice[j][1] - 1e-12:
                choice[j] = (i, d)
        for j, (i, _) in sorted(choice.items()):
            out.append((tchain[i], pchain[j],
                        f"{label} {i + 1}/{nt} -> {j + 1}/{np_} by arc length "
                        f"({ta[i]:.2f} vs {pa[j]:.2f})"))
    return out


def _translates(sk: Skeleton, j: int) -> bool:
    return any(c.endswith("position") for c in sk.channels[j])


def automap(target: Skeleton, performer: Skeleton, *, target_positions=None,
            performer_positions=None) -> Correspondence:
    """Map ``target`` joints to ``performer`` joints by humanoid role (see the module notes).

    Args:
        target, performer: the two skeletons.
        target_positions, performer_positions: ``(J, 3)`` [m] reference poses for telling
            left from right where names do not (see :func:`identify`).

    Returns:
        A :class:`Correspondence` in target joint order; ``notes`` says per target joint how
        its pair was decided (and, for an unmapped ground root, why it is unmapped).

    Raises:
        MappingError: when either skeleton is not recognisably humanoid.
    """
    tr = identify(target, target_positions)
    pr = identify(performer, performer_positions)
    tt, pt = _Tree(target), _Tree(performer)
    ti, pi = target.index, performer.index
    candidates: list[tuple[int, int, str]] = []
    notes: dict[str, str] = {}

    def add(role: str, label: str):
        if role in tr and role in pr:
            candidates.append((ti[tr[role]], pi[pr[role]],
                               f"{label} (target: {tr.how.get(role, '')}; performer: "
                               f"{pr.how.get(role, '')})"))

    if "root" in tr:
        p_hips_move = _translates(performer, pi[pr["hips"]])
        t_hips_move = _translates(target, ti[tr["hips"]])
        if "root" in pr and (not p_hips_move or t_hips_move):
            why = ("the performer's ground root carries its travel" if not p_hips_move else
                   "both hips carry their travel")
            candidates.append((ti[tr["root"]], pi[pr["root"]], f"ground root <- ground root "
                               f"({why})"))
        elif "root" in pr:
            notes[tr["root"]] = ("ground root: unmapped, the hips carry the motion (the "
                                 "performer's travel is on its hips, and this target's hips "
                                 "have no position channels)")
        else:
            notes[tr["root"]] = ("ground root: unmapped, the hips carry the motion (the "
                                 "performer has no separate ground root)")
    add("hips", "hips")
    add("pelvis", "pelvis")
    tsp, psp = [ti[n] for n in tr.spine], [pi[n] for n in pr.spine]
    candidates += _map_chain(tt, pt, tsp, psp, "last", "spine")
    tnk, pnk = [ti[n] for n in tr.neck_chain], [pi[n] for n in pr.neck_chain]
    candidates += _map_chain(tt, pt, tnk, pnk, "first", "neck")
    add("head", "head")
    for side in SIDES:
        for role in ARM_ROLES + LEG_ROLES:
            add(f"{role}_{side}", f"{_LABELS[role]} {side.upper()}")
        for finger in FINGERS:
            for n in range(5):
                add(f"{finger}{n}_{side}", f"{finger} {n} {side.upper()}")

    # keep the map one to one and ancestry-preserving, parents first
    candidates.sort(key=lambda c: c[0])
    kept: dict[int, int] = {}
    used: set[int] = set()
    for t, p, note in candidates:
        if t in kept or p in used:
            continue
        anc = next((a for a in tt.chain_up(t)[1:] if a in kept), None)
        if anc is None and kept:
            notes[target.names[t]] = f"dropped ({note}): no mapped ancestor"
            continue
        if anc is not None and not pt.is_ancestor(kept[anc], p):
            notes[target.names[t]] = (f"dropped ({note}): would invert ancestry under "
                                      f"{target.names[anc]!r}")
            continue
        kept[t] = p
        used.add(p)
        notes[target.names[t]] = note
    pairs = {target.names[t]: performer.names[kept[t]] for t in sorted(kept)}
    corr = Correspondence(pairs, notes)
    corr.validate(target, performer)
    return corr
