"""The Anatomic Binding (the paper's section 2.1): the Intermediate Skeleton, built once.

:func:`bind` builds the :class:`Binding` for a performer and a target character: the target's
joints and local axes, posed so that each target bone points along the performer's *virtual
bone* in the performer's reference pose. Its steps:

* reference poses (:class:`BindOptions`, :func:`reference_pose`): each skeleton's rest pose
  (zero rotations) or one of its frames; ``"auto"`` takes the rest pose when it stands upright
  (:func:`is_upright`), else frame 0.
* virtual bones: for each mapped target joint, the performer's vectors from its joint to the
  joints mapped to its mapped children, in the reference pose (:class:`_Bones`). The primary
  one leads to the child with the largest subtree. A bone gives no direction when it is shorter
  than a thousandth of the height, crosses a performer joint whose translation is animated, or
  is a short target bone pointing against its virtual bone; a joint whose primary bone gives
  none has no bones (the converter turns it with its performer joint).
* chains: the unmapped target joints between a mapped joint and its primary child.
* facing (with rest alignment): the target turned about the vertical through its pelvis so
  that its reference posture faces as the performer's (:func:`_facing`: a quarter turn at a time
  between two rest poses, exactly where either is a frame), before anything compares them.
* rest alignment (section 2.1.4, on by default): root to leaves, each target bone turned onto
  its virtual bone and rolled to match the other bones of a branching joint; off keeps the
  target's own initial posture.
* pose offsets (:attr:`BindOptions.pose_offsets`, the animator's retarget pose): each turns
  its joint in its binding frame after the alignment; ``rest_local``/``rest_world``/
  ``rest_positions`` are the binding pose with them, ``aligned_*`` the posture before them
  (what the converter turns, see :mod:`engine.conversion`), and the root figures below come
  from the latter.
* the root: the hip-height ratio (target hips over performer hips, each above its lowest
  point, in the bound and the reference pose; the target's unmapped nodes above its body
  root are not points of its body, and a body root on the floor is measured at the mapped
  joint below it),
  the default scale of the root's translation, and the joints whose position follows their
  performer joint's (``driven``).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from .chains import CHAINS, ChainSettings, ChainSettingsError
from .correspondence import Correspondence
from .followers import find_followers
from ..errors import MappingError, MotionComposerError
from ..kinematics import fk_arrays
from ..motion import Motion
from ..quaternions import about_axis, from_matrix, qconj, qmul, qrot, quat_between
from ..skeleton import Skeleton

__all__ = ["BindOptions", "Binding", "bind", "reference_pose", "is_upright"]

#: a virtual bone shorter than this fraction of the character's height has no direction
_MIN_BONE = 1e-3


@dataclass(frozen=True)
class BindOptions:
    """Choices of the Anatomic Binding.

    Attributes:
        performer_reference: the performer's reference pose: ``"rest"`` (zero rotations, the
            OFFSET pose), a frame number, or ``"auto"`` (the rest pose when it stands upright,
            else frame 0; Bandai, CC3 and Rokoko rest poses lie down).
        target_reference: the same for the target (its file's rest pose or one of its frames).
        rest_alignment: turn the target's bones onto the performer's virtual bones (the
            paper's *rest posture*); ``False`` keeps the target's own initial posture.
        distribute: how a target chain with unmapped inner joints turns: ``"even"`` spreads
            the turn over the chain's joints, ``"first"`` turns only the chain's first joint.
        pose_offsets: the animator's retarget pose: sorted pairs ``(target joint, (x, y, z,
            w))``, a unit quaternion turning the joint in its *binding frame* (its bound rest
            local frame: ``rest_local' = rest_local * offset``); every frame follows it (see
            :mod:`engine.conversion`). A dict or pairs are accepted and sorted; identities
            are dropped.
        chains: sorted pairs ``(chain name, ChainSettings)`` overriding the defaults
            (:mod:`engine.conversion.chains`); defaults are dropped.
        flat_feet: with rest alignment, stand each foot of the target as flat as it stands
            itself where the performer's foot stands flat, headed as the performer's, instead
            of laying it along the performer's foot (see :func:`_rest_posture`): feet of
            other shapes then stand flat on the floor through every stance. Off by default
            and in every project written before it, which were solved without it.
    """

    performer_reference: str | int = "auto"
    target_reference: str | int = "auto"
    rest_alignment: bool = True
    distribute: str = "even"
    pose_offsets: tuple = ()
    chains: tuple = ()
    flat_feet: bool = False

    def __post_init__(self):
        for ref in (self.performer_reference, self.target_reference):
            if not (ref in ("auto", "rest") or (isinstance(ref, (int, np.integer))
                                                 and not isinstance(ref, bool) and ref >= 0)):
                raise MotionComposerError(f"a reference pose is 'auto', 'rest' or a frame "
                                          f"number (0 or more), not {ref!r}")
        if self.distribute not in ("even", "first"):
            raise MotionComposerError(f"distribute must be 'even' or 'first', not "
                                      f"{self.distribute!r}")
        object.__setattr__(self, "pose_offsets", _offset_pairs(self.pose_offsets))
        object.__setattr__(self, "chains", _chain_pairs(self.chains))

    def offset(self, joint: str) -> np.ndarray:
        """``(4,)`` the pose offset of ``joint`` (identity if none)."""
        for name, q in self.pose_offsets:
            if name == joint:
                return np.array(q)
        return np.array([0.0, 0.0, 0.0, 1.0])

    def with_offset(self, joint: str, quat) -> "BindOptions":
        """These options with ``joint``'s pose offset set to ``quat`` (``(4,)``); ``None`` or
        the identity removes it."""
        kept = [(n, q) for n, q in self.pose_offsets if n != joint]
        if quat is not None:
            kept.append((joint, quat))
        return dataclasses.replace(self, pose_offsets=tuple(kept))

    def without_offsets(self) -> "BindOptions":
        """These options without any pose offset."""
        return dataclasses.replace(self, pose_offsets=())

    def chain(self, name: str) -> ChainSettings:
        """The settings of chain ``name`` (the defaults unless overridden)."""
        for n, settings in self.chains:
            if n == name:
                return settings
        if name not in CHAINS:
            raise MotionComposerError(f"{name!r} is not a chain (expected one of "
                                      f"{', '.join(CHAINS)})")
        return ChainSettings()

    def with_chain(self, name: str, settings: ChainSettings | None) -> "BindOptions":
        """These options with chain ``name``'s settings replaced (``None`` or the defaults
        remove the override)."""
        kept = [(n, s) for n, s in self.chains if n != name]
        if settings is not None:
            kept.append((name, settings))
        return dataclasses.replace(self, chains=tuple(kept))


#: how far from 1 a pose offset's norm may be (typed angles give unit quaternions to rounding)
_UNIT_TOLERANCE = 1e-6


def _offset_pairs(value) -> tuple:
    """``pose_offsets`` as sorted ``(joint, (x, y, z, w))`` pairs of floats, identities
    dropped; raises :class:`MotionComposerError` naming the joint of a bad value."""
    items = value.items() if isinstance(value, dict) else value
    out = {}
    for item in items:
        try:
            joint, quat = item
        except (TypeError, ValueError):
            raise MotionComposerError(f"pose_offsets: expected (joint, (x, y, z, w)) pairs, "
                                      f"not {item!r}") from None
        if not isinstance(joint, str) or not joint:
            raise MotionComposerError(f"pose_offsets: a joint's name, not {joint!r}")
        if joint in out:
            raise MotionComposerError(f"pose_offsets: a second offset for {joint!r}")
        try:
            q = tuple(float(x) for x in quat)
        except (TypeError, ValueError):
            q = ()
        if len(q) != 4 or not all(math.isfinite(x) for x in q) or \
                abs(math.sqrt(sum(x * x for x in q)) - 1.0) > _UNIT_TOLERANCE:
            raise MotionComposerError(f"pose_offsets[{joint!r}]: expected a unit quaternion "
                                      f"(x, y, z, w), not {quat!r}")
        if q[:3] != (0.0, 0.0, 0.0):
            out[joint] = q
    return tuple(sorted(out.items()))


def _chain_pairs(value) -> tuple:
    """``chains`` as sorted ``(chain name, ChainSettings)`` pairs, defaults dropped."""
    items = value.items() if isinstance(value, dict) else value
    out = {}
    for item in items:
        try:
            name, settings = item
        except (TypeError, ValueError):
            raise MotionComposerError(f"chains: expected (chain name, ChainSettings) pairs, "
                                      f"not {item!r}") from None
        if name not in CHAINS:
            raise MotionComposerError(f"chains: {name!r} is not a chain (expected one of "
                                      f"{', '.join(CHAINS)})")
        if not isinstance(settings, ChainSettings):
            raise MotionComposerError(f"chains[{name!r}]: expected ChainSettings, not "
                                      f"{settings!r}")
        if name.startswith("fingers") and settings.ik_blend > 0:
            raise ChainSettingsError("ik_blend", f"the {name} chain has no end effector to "
                                                 "reach with (keep it 0)")
        if name in out:
            raise MotionComposerError(f"chains: a second entry for {name!r}")
        if not settings.is_default:
            out[name] = settings
    return tuple(sorted(out.items()))


def is_upright(skeleton: Skeleton, rotations: np.ndarray, translations: np.ndarray) -> bool:
    """Whether a single pose stands up along +Y.

    Its body's vertical extent must be at least 0.7 of its widest horizontal extent (a
    T-pose's arm span is about its height; a skeleton lying along an axis fails; the nodes
    above the body left out: a still reference root on the ground below lying hips made a
    lying pose tall), and where the head and feet can be told
    (:func:`engine.conversion.automap.identify`), the head must be above the hips and the hips
    above the feet (CC3's zero pose stands upside down).
    """
    pose = fk_arrays(skeleton, rotations[None], translations[None])
    pts = np.delete(pose.all_positions()[0], skeleton.above_the_body(), axis=0)
    ext = pts.max(axis=0) - pts.min(axis=0)
    if ext[1] < 0.7 * max(ext[0], ext[2]):
        return False
    from .automap import identify
    try:
        roles = identify(skeleton)
    except MappingError:                      # not a humanoid: the extents decide
        return True
    y = pose.positions[0, :, 1]
    idx = skeleton.index
    hips, head = roles.get("hips"), roles.get("head")
    feet = [roles.get(k) for k in ("foot_l", "foot_r", "shin_l", "shin_r")]
    feet = [f for f in feet if f]
    if hips in idx and head in idx and y[idx[head]] <= y[idx[hips]]:
        return False
    if hips in idx and feet and min(y[idx[f]] for f in feet) >= y[idx[hips]]:
        return False
    return True


def reference_pose(motion: Motion, choice: str | int) -> tuple[np.ndarray, np.ndarray, str]:
    """Local rotations ``(J, 4)`` and translations ``(K, 3)`` of a reference pose, and a label.

    ``choice`` is ``"rest"`` (zero channel values: offsets, no rotation but the file's own
    up-axis turn at the root, the root at its first-frame position, and so is a joint whose
    position channels carry its whole place, its offset zero: the hips under a still ground
    root),
    a frame number, or ``"auto"`` (rest if it stands upright, else frame 0).
    """
    sk = motion.skeleton
    rest_rot = np.zeros((sk.num_joints, 4))
    rest_rot[:, 3] = 1.0
    # zero channel values: the root keeps the turn from the file's up axis to +Y
    rest_rot[0] = from_matrix(sk.source.rotation)
    rest_tra = sk.offsets[sk.translated].copy()
    # the root, and a joint with no offset of its own, stand where the first frame puts
    # them: with its channels at zero the hips of a file whose ground root stands still
    # (a reference node added above a capture's hips) would be on the ground, and the
    # root motion measured from there lifted the character by the performer's hip height
    placed = (np.arange(len(rest_tra)) == 0) | ~np.any(rest_tra, axis=1)
    rest_tra[placed] = motion.translations[0, placed]
    if choice == "auto":
        choice = "rest" if is_upright(sk, rest_rot, rest_tra) else 0
    if choice == "rest":
        return rest_rot, rest_tra, "rest pose (zero rotations)"
    frame = int(choice)
    if not 0 <= frame < motion.num_frames:
        raise MotionComposerError(f"reference frame {frame} is outside the clip "
                                  f"{motion.name or ''} (frames 0 to {motion.num_frames - 1})")
    return motion.rotations[frame].copy(), motion.translations[frame].copy(), f"frame {frame}"


@dataclass(frozen=True, eq=False)
class Binding:
    """The Intermediate Skeleton: everything :func:`convert` needs, computed once.

    Attributes (J target joints, Jp performer joints):
        target: the target skeleton.
        performer: the performer skeleton.
        correspondence: the map used.
        mapped: ``(J,)`` performer joint index driving each target joint, or -1.
        rest_world: ``(J, 4)`` world rotations of the bound rest posture with the pose
            offsets: the *binding pose* (the target's axes, the performer's bone directions
            when rest alignment is on, then each joint turned by its offset).
        rest_local: ``(J, 4)`` local rotations of the binding pose (``aligned_local *
            offsets``).
        rest_positions: ``(J, 3)`` [m] world joint positions of the binding pose.
        aligned_world, aligned_local, aligned_positions: the same before the pose offsets
            (what the converter turns; the very arrays above without offsets).
        offsets: ``(J, 4)`` each target joint's pose offset (identity where none).
        chain_of: target joint index -> the name of its chain
            (:func:`~engine.conversion.chains.chains_of`), for the chains whose settings
            differ from the defaults; empty without such settings.
        held: ``(H,)`` the joints of chains with weight 0, whose local rotation is their
            binding-pose one on every frame (the composer writes ``rest_local`` there).
        performer_rest_world: ``(Jp, 4)`` performer world rotations in its reference pose.
        performer_rest_positions: ``(Jp, 3)`` [m] performer positions in its reference pose.
        bones: per mapped target joint, its virtual bones (see :class:`_Bones`).
        chains: per mapped target joint, the unmapped joints between it and its primary
            child (turned together with ``distribute="even"``); none for a branching joint.
        body_root: the top-most mapped target joint (its translation follows the performer).
        above_mapped: ``(J,)`` joints with a mapped descendant or a follower below them (the
            only unmapped joints whose world rotation conversion needs).
        driven: target joints whose world position follows their performer joint's (scaled):
            the body root, and mapped joints with animated translation whose performer joint's
            translation is animated too (Bandai's hips under its ground-level root).
        root_translation: the target's reference translations ``(K, 3)``.
        hip_height_ratio: target hip height over performer hip height, both in their
            reference (bound) poses, the default root scale.
        options: the :class:`BindOptions` used.
        notes: how references were chosen, for display.
        followers: the control joints carried with the limbs
            (:class:`~engine.conversion.followers.Follower`: a foot kept as an IK target under
            the root); their ancestors count in ``above_mapped``.
    """

    target: Skeleton
    performer: Skeleton
    correspondence: Correspondence
    mapped: np.ndarray
    rest_world: np.ndarray
    rest_local: np.ndarray
    rest_positions: np.ndarray
    aligned_world: np.ndarray
    aligned_local: np.ndarray
    aligned_positions: np.ndarray
    offsets: np.ndarray
    chain_of: dict
    held: np.ndarray
    performer_rest_world: np.ndarray
    performer_rest_positions: np.ndarray
    bones: dict
    chains: dict
    body_root: int
    driven: list
    above_mapped: np.ndarray
    root_translation: np.ndarray
    hip_height_ratio: float
    options: BindOptions
    notes: dict = field(default_factory=dict)
    followers: tuple = ()


@dataclass(frozen=True, eq=False)
class _Bones:
    """The virtual bones of one mapped target joint ``j`` (performer joint ``p``).

    ``children``: target indices of its usable mapped children, primary first; ``performer``:
    their performer joints; ``target_local``: ``(C, 3)`` each child's position in ``j``'s frame
    in the bound rest posture; ``reference``: ``(C, 3)`` the performer's virtual bones
    (world, reference pose). ``roll_by_bones``: the roll comes from the secondary bones (a
    branching joint) rather than from the performer joint's twist. ``carries``: the one bone
    goes to a follower the joint carries (:mod:`.followers`), not to a child.
    """

    children: list
    performer: list
    target_local: np.ndarray
    reference: np.ndarray
    roll_by_bones: bool
    carries: bool = False


def _height_above_floor(positions: np.ndarray, joint: int, left_out: np.ndarray) -> float:
    """How far ``joint`` is above the lowest of ``positions`` (``(J + E, 3)``: joints first,
    then End Sites), leaving out the points ``left_out`` (``(J + E,)`` bool) marks."""
    return float(positions[joint, 1] - positions[~left_out, 1].min())


def _tails(skeleton: Skeleton, kept: np.ndarray, num_points: int) -> np.ndarray:
    """``(J + E,)`` bool: the points past the ``kept`` joints' ends: every End Site, and each
    joint under a kept joint with no kept joint at or below it (a toe's tip, a leaf bone, the
    control rig under a carried foot)."""
    J = skeleton.num_joints
    below = kept.copy()                       # a kept joint at or below
    for j in range(J - 1, 0, -1):
        below[skeleton.parents[j]] |= below[j]
    above = np.zeros(J, dtype=bool)           # a kept joint above
    for j in range(1, J):
        p = skeleton.parents[j]
        above[j] = above[p] or kept[p]
    out = np.ones(num_points, dtype=bool)
    out[:J] = above & ~below
    return out


def _align(from_dirs: np.ndarray, to_dirs: np.ndarray, roll_by_bones: bool) -> np.ndarray:
    """Rotation(s) taking ``from_dirs[..., 0, :]`` exactly onto ``to_dirs[..., 0, :]`` and rolling
    about it to best match the other directions (least squares in the normal plane).

    Shapes ``(..., C, 3)``; returns ``(..., 4)``.
    """
    swing = quat_between(from_dirs[..., 0, :], to_dirs[..., 0, :])
    if not roll_by_bones or from_dirs.shape[-2] < 2:
        return swing
    n = to_dirs[..., 0, :]
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    a = qrot(swing[..., None, :], from_dirs[..., 1:, :])
    b = to_dirs[..., 1:, :]
    a = a - np.sum(a * n[..., None, :], axis=-1, keepdims=True) * n[..., None, :]
    b = b - np.sum(b * n[..., None, :], axis=-1, keepdims=True) * n[..., None, :]
    a = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-12)
    b = b / np.maximum(np.linalg.norm(b, axis=-1, keepdims=True), 1e-12)
    sin = np.sum(np.sum(np.cross(a, b) * n[..., None, :], axis=-1), axis=-1)
    cos = np.sum(np.sum(a * b, axis=-1), axis=-1)
    roll = about_axis(n, np.arctan2(sin, cos))
    return qmul(roll, swing)


def _check_mapping(target: Skeleton, performer: Skeleton, corr: Correspondence) -> np.ndarray:
    corr.validate(target, performer)
    mapped = np.full(target.num_joints, -1, dtype=np.intp)
    for t, p in corr.pairs.items():
        mapped[target.index[t]] = performer.index[p]
    return mapped


#: a body root lower than this fraction of the stature stands on the floor (a ground-level
#: root): the hip height ratio is measured at the mapped joint below it
_GROUND_LEVEL = 0.05


def _hip_height_ratio(tsk: Skeleton, psk: Skeleton, mapped: np.ndarray, anchor: np.ndarray,
                      body_root: int, t_points: np.ndarray, p_points: np.ndarray,
                      followers: tuple = ()) -> float:
    """Target hip height over performer hip height (the default root scale), each above its
    floor in its bound posture (``t_points``, ``p_points``: joints then End Sites).

    Like for like: each side's floor is the lowest of the joints the two sides share (the
    mapped joints, and the control joints carried with the limbs with the performer joints
    whose turn they take, :mod:`.followers`) and of the joints off the mapped limbs. What
    hangs past a shared joint's end is left out on both sides: End Sites, toe tips, leaf
    bones and control rigs are each exporter's convention, not the body. Blender's FBX of
    Ely adds a leaf bone past each toe tip, its BVH of Ely an End Site there: bound to a
    BANDAI walk on a mid-stride frame, the pitched foot put them lowest, and the ratio read
    1.16 where Ely's glTF gave 1.09.

    Measured at the body root, or, when that stands on the floor on either side (Bandai's
    ``joint_Root`` mapped to the ``Armature`` node Blender's FBX puts above the hips), at
    the shallowest mapped joint under it that does not: a joint on the floor has no height
    to compare, and the ratio fell back to 1 (a 3 m robot walked at the performer's pace).
    On both sides the nodes above the joint measured are not points of the body either,
    mapped or not: Blender's ``Armature`` node mapped to a ground-level root sits at the
    origin, and counted as the target's floor it measured the hips from there (CC3's walk
    onto Ely from Blender's FBX got 0.93, from Ely's glTF 0.81); and a performer's
    ground-level root (Bandai's, CC3's) below its feet measured its hips from the ground
    where the target's were measured from its lowest joint."""
    t_size = max(float(np.ptp(t_points[:, 1])), 1e-9)
    p_size = max(float(np.ptp(p_points[:, 1])), 1e-9)
    t_kept, p_kept = mapped >= 0, np.zeros(psk.num_joints, dtype=bool)
    p_kept[mapped[t_kept]] = True
    for f in followers:
        t_kept[f.joint] = True
        if f.source >= 0:
            p_kept[f.source] = True
    t_tails = _tails(tsk, t_kept, len(t_points))
    p_tails = _tails(psk, p_kept, len(p_points))
    depth = np.zeros(tsk.num_joints, dtype=np.intp)
    for j in range(1, tsk.num_joints):
        depth[j] = depth[anchor[j]] + 1 if anchor[j] >= 0 else 0
    below = [j for j in range(tsk.num_joints) if mapped[j] >= 0 and
             (j == body_root or body_root in tsk.ancestors(j))]
    for j in sorted(below, key=lambda k: (depth[k], k)):
        pj = int(mapped[j])
        t_out, p_out = t_tails.copy(), p_tails.copy()
        t_out[tsk.ancestors(j)] = True
        p_out[psk.ancestors(pj)] = True
        t_hip = _height_above_floor(t_points, j, t_out)
        p_hip = _height_above_floor(p_points, pj, p_out)
        if t_hip > _GROUND_LEVEL * t_size and p_hip > _GROUND_LEVEL * p_size:
            return t_hip / p_hip
    return 1.0


def _nearest_mapped_ancestor(skeleton: Skeleton, mapped: np.ndarray) -> np.ndarray:
    anchor = np.full(skeleton.num_joints, -1, dtype=np.intp)
    for j in range(1, skeleton.num_joints):
        p = skeleton.parents[j]
        anchor[j] = p if mapped[p] >= 0 else anchor[p]
    return anchor


def _crosses(skeleton: Skeleton, top: int, joint: int, joints: set) -> bool:
    """Whether the path from ``top`` (exclusive) down to ``joint`` (inclusive) meets ``joints``."""
    k = joint
    while k >= 0 and k != top:
        if k in joints:
            return True
        k = int(skeleton.parents[k])
    return False


def bind(performer: Motion, target: Motion, correspondence: Correspondence,
         options: BindOptions | None = None) -> Binding:
    """Anatomic Binding: build the Intermediate Skeleton for ``performer`` onto ``target``.

    ``target`` is a motion whose skeleton is the character (its rest pose or one of its frames
    gives the target's initial posture, see :class:`BindOptions`).
    """
    options = options or BindOptions()
    tsk, psk = target.skeleton, performer.skeleton
    mapped = _check_mapping(tsk, psk, correspondence)
    anchor = _nearest_mapped_ancestor(tsk, mapped)
    body_root = [j for j in range(tsk.num_joints) if mapped[j] >= 0 and anchor[j] < 0][0]

    p_ref = _reference(performer, options.performer_reference)
    t_ref = _reference(target, options.target_reference)
    if options.rest_alignment:
        t_ref = _faced(target, t_ref, _facing(mapped, anchor, p_ref, t_ref))
    p_moving = _moving_joints(
        performer, max(float(np.ptp(p_ref.all_positions, axis=0).max()), 1e-6))
    t_moving = _moving_joints(
        target, max(float(np.ptp(t_ref.all_positions, axis=0).max()), 1e-6))
    followers = find_followers(tsk, psk, mapped, (t_ref.world, t_ref.positions),
                               (p_ref.world, p_ref.positions), performer)
    # a follower the file never translated gets position channels (the same poses): the
    # converted motion carries it in them
    placed = target.with_position_channels([f.joint for f in followers])
    if placed is not target:
        target, tsk = placed, placed.skeleton
        t_ref = _faced(target, _reference(target, options.target_reference), t_ref.facing)
    bones = _virtual_bones(tsk, psk, mapped, anchor, p_ref, t_ref, p_moving, t_moving,
                           followers)
    chains = _chains(tsk, bones)

    feet = (_feet_standing(performer, p_ref, target, t_ref, mapped, bones)
            if options.flat_feet and options.rest_alignment else {})
    aligned_world = _rest_posture(tsk, t_ref.rotations, bones, options.rest_alignment, feet)
    aligned_local = aligned_world.copy()
    aligned_local[1:] = qmul(qconj(aligned_world[tsk.parents[1:]]), aligned_world[1:])
    bound = fk_arrays(tsk, aligned_local[None], t_ref.translations[None])
    aligned_positions = bound.positions[0]
    bones = _bones_in_posture(bones, aligned_world, aligned_positions)
    offsets = _offsets(tsk, options)
    rest_world, rest_local, rest_positions = aligned_world, aligned_local, aligned_positions
    if options.pose_offsets:
        rest_local = qmul(aligned_local, offsets)
        posed = fk_arrays(tsk, rest_local[None], t_ref.translations[None])
        rest_world, rest_positions = posed.rotations[0], posed.positions[0]
    chain_of = _chain_of(tsk, options, aligned_positions)

    ratio = _hip_height_ratio(tsk, psk, mapped, anchor, body_root,
                              np.concatenate([aligned_positions, bound.end_positions[0]]),
                              p_ref.all_positions, followers)
    return Binding(target=tsk, performer=psk, correspondence=correspondence, mapped=mapped,
                   rest_world=rest_world, rest_local=rest_local, rest_positions=rest_positions,
                   aligned_world=aligned_world, aligned_local=aligned_local,
                   aligned_positions=aligned_positions, offsets=offsets, chain_of=chain_of,
                   held=np.array(sorted(j for j, name in chain_of.items()
                                        if options.chain(name).weight == 0.0), dtype=np.intp),
                   performer_rest_world=p_ref.world, performer_rest_positions=p_ref.positions,
                   bones=bones, chains=chains, body_root=body_root,
                   driven=_driven(tsk, mapped, body_root, p_moving),
                   above_mapped=_above_mapped(tsk, mapped, followers),
                   root_translation=t_ref.translations, hip_height_ratio=float(ratio),
                   options=options,
                   notes=_notes(p_ref, t_ref, ratio),
                   followers=followers)


def _notes(p_ref: _Reference, t_ref: _Reference, ratio: float) -> dict:
    notes = {"performer reference": p_ref.label, "target reference": t_ref.label,
             "hip height ratio": f"{ratio:.4f}"}
    if t_ref.facing is not None:
        turn = t_ref.facing[0]
        degrees = math.degrees(2.0 * math.atan2(turn[1], turn[3]))
        notes["target facing"] = (f"turned {(degrees + 180.0) % 360.0 - 180.0:+.1f} degrees "
                                  "about the vertical to face as the performer")
    return notes


def _offsets(tsk: Skeleton, options: BindOptions) -> np.ndarray:
    """``(J, 4)`` each target joint's pose offset (normalised; identity where none)."""
    offsets = np.zeros((tsk.num_joints, 4))
    offsets[:, 3] = 1.0
    for joint, q in options.pose_offsets:
        if joint not in tsk.index:
            raise MappingError(f"a pose offset names {joint!r}, which is not a joint of the "
                               f"target {tsk.names[0]!r}'s skeleton")
        offsets[tsk.index[joint]] = np.asarray(q) / np.linalg.norm(q)
    return offsets


def _chain_of(tsk: Skeleton, options: BindOptions, positions: np.ndarray) -> dict[int, str]:
    """Target joint index -> chain name for the chains ``options`` sets (``positions``
    ``(J, 3)`` [m]: the bound posture, which tells left from right)."""
    if not options.chains:
        return {}
    from .chains import chains_of
    chains = chains_of(tsk, positions)
    return {tsk.index[j]: name for name, _ in options.chains for j in chains.get(name, ())}


@dataclass(frozen=True, eq=False)
class _Reference:
    """A skeleton (``J`` joints, ``K`` translated, ``E`` End Sites) in its reference pose.

    ``rotations``: ``(J, 4)`` local rotations; ``translations``: ``(K, 3)`` [m] local
    translations; ``label``: which pose it is, for display; ``world``: ``(J, 4)`` world
    rotations; ``positions``: ``(J, 3)`` [m] world joint positions; ``all_positions``:
    ``(J + E, 3)`` [m] the joints' and then the End Sites' world positions; ``rest``: the
    rest pose, not a frame; ``facing``: the turn it was given (:func:`_faced`), or ``None``.
    """

    rotations: np.ndarray
    translations: np.ndarray
    label: str
    world: np.ndarray
    positions: np.ndarray
    all_positions: np.ndarray
    rest: bool
    facing: tuple | None = None
    #: the clip frame it is (``None``: the rest pose)
    frame: int | None = None


def _reference(motion: Motion, choice: str | int) -> _Reference:
    """``motion``'s reference pose (see :func:`reference_pose`) and its forward kinematics."""
    rot, tra, label = reference_pose(motion, choice)
    pose = fk_arrays(motion.skeleton, rot[None], tra[None], end_sites=True)
    rest = not label.startswith("frame")
    return _Reference(rot, tra, label, pose.rotations[0], pose.positions[0],
                      pose.all_positions()[0], rest,
                      frame=None if rest else int(label.split()[1]))


#: a performer joint's translation is animated where it moves by more than this share of the
#: skeleton's size: less is a writer's rounding, not a movement. Blender writes a position
#: channel on every bone not connected to its parent, its values the offset printed to six
#: decimals of the file's unit: on its export of the CMU walk they move by up to 1.0e-6 m
#: (7e-7 of the size), and a bound of 1e-6 m took the Chest2 of that file for a moving joint,
#: so that the arms' virtual bones across it gave no direction and turned 0.8 degrees from
#: the original file's (24 mm of a foot with contacts). A joint that truly moves (Bandai's
#: hips under its ground root) moves by centimetres.
MOVING_TRANSLATION = 1e-4


def _moving_joints(motion: Motion, size: float) -> set[int]:
    """Joints (not the root) whose translation is animated in ``motion`` (the performer, or a
    clip used as the target): moves by more than :data:`MOVING_TRANSLATION` of ``size`` (the
    skeleton's size [m]).

    A virtual bone across one of them stretches and turns with the translation (Bandai's hips
    under its ground root), so it gives no direction to follow, on either side: in a target
    clip's reference frame the bone from Bandai's ground root to its hips is where the walk
    has taken the hips (4 m along the floor on its first frame), not a bone.
    """
    sk = motion.skeleton
    slots = {int(j): k for k, j in enumerate(sk.translated)}
    return {j for j, k in slots.items() if j > 0 and
            np.ptp(motion.translations[:, k], axis=0).max() > MOVING_TRANSLATION * size}


def _virtual_bones(tsk: Skeleton, psk: Skeleton, mapped: np.ndarray, anchor: np.ndarray,
                   p_ref: _Reference, t_ref: _Reference, p_moving: set[int],
                   t_moving: set[int] = frozenset(), followers=()) -> dict:
    """Per mapped target joint, its :class:`_Bones`: the virtual bones towards its mapped
    children that give a direction, in the reference poses (``target_local`` in the target's
    reference posture; :func:`_bones_in_posture` moves it to the bound one). A chain's last
    joint with none that carries a follower (:mod:`.followers`: the robot's shin, whose foot
    is a control joint under the root) has one towards it, the performer's along the joint
    that continues its chain (the ankle), so that it points as the performer's bone does
    rather than turning as the performer's joint turned from its reference pose."""
    J = tsk.num_joints
    kids = _mapped_children(mapped, anchor)
    subtree = np.ones(J, dtype=np.intp)
    for j in range(J - 1, 0, -1):
        subtree[tsk.parents[j]] += subtree[j]
    scale_len = max(float(np.ptp(p_ref.all_positions[:, 1])), 1e-6)
    t_height = max(float(np.ptp(t_ref.positions[:, 1])), 1e-6)

    bones: dict[int, _Bones] = {}
    for j, children in kids.items():
        usable = [u for u in (_usable_bone(tsk, psk, mapped, j, c, p_ref, t_ref, p_moving,
                                           t_moving, scale_len, t_height)
                              for c in children) if u is not None]
        usable.sort(key=lambda item: -subtree[item[0]])
        # the primary bone is the one towards the largest subtree (the spine from the hips);
        # when that one has no direction (CMU's LowerBack sits on its hips), aligning a leg in
        # its place would roll the pelvis: the joint follows its performer joint instead
        main = max(children, key=lambda c: subtree[c]) if children else None
        if usable and main is not None and usable[0][0] != main:
            usable = []
        if not usable and not children:
            usable = [u for u in (_follower_bone(f, p_ref, mapped, p_moving, scale_len,
                                                 t_height) for f in followers if f.anchor == j)
                      if u is not None][:1]
            if usable:
                bones[j] = _Bones([usable[0][0]], [usable[0][1]], usable[0][3][None],
                                  usable[0][2][None], False, carries=True)
                continue
        if not usable:
            bones[j] = _Bones([], [], np.zeros((0, 3)), np.zeros((0, 3)), False)
            continue
        ref = np.array([u[1] for u in usable])
        loc = np.array([u[2] for u in usable])
        bones[j] = _Bones([u[0] for u in usable], [int(mapped[u[0]]) for u in usable], loc, ref,
                          _rolls_by_bones(ref))
    return bones


def _follower_bone(f, p_ref: _Reference, mapped: np.ndarray, p_moving: set[int],
                   scale_len: float, t_height: float):
    """The virtual bone from a follower's anchor to it (:func:`_virtual_bones`), as ``(the
    follower, its source performer joint, performer bone (3,) [m] in the world, target bone
    (3,) [m] in the anchor's reference frame)``, or ``None`` (no source, a bone too short, or a
    performer bone across an animated translation)."""
    if f.source < 0 or f.source in p_moving:
        return None
    v = p_ref.positions[f.source] - p_ref.positions[mapped[f.anchor]]
    if not (np.linalg.norm(v) > _MIN_BONE * scale_len and
            np.linalg.norm(f.offset) > _MIN_BONE * t_height):
        return None
    return f.joint, f.source, v, f.offset


def _usable_bone(tsk: Skeleton, psk: Skeleton, mapped: np.ndarray, j: int, c: int,
                 p_ref: _Reference, t_ref: _Reference, p_moving: set[int], t_moving: set[int],
                 scale_len: float, t_height: float):
    """The virtual bone from mapped target joint ``j`` to its mapped child ``c``, as ``(c,
    performer bone (3,) [m] in the world, target bone (3,) [m] in j's reference frame)``, or
    ``None`` when it gives no direction to follow (among others: it crosses a joint whose
    translation is animated, in the performer or in a target clip).

    ``scale_len`` and ``t_height`` [m]: the performer's and the target's heights.
    """
    if _crosses(psk, int(mapped[j]), int(mapped[c]), p_moving) or \
            _crosses(tsk, j, c, t_moving):
        return None
    v = p_ref.positions[mapped[c]] - p_ref.positions[mapped[j]]
    world_t = t_ref.positions[c] - t_ref.positions[j]
    t = qrot(qconj(t_ref.world[j]), world_t)
    if not (np.linalg.norm(v) > _MIN_BONE * scale_len and
            np.linalg.norm(t) > _MIN_BONE * t_height):
        return None
    # a short target bone pointing against its virtual bone is a rig's helper offset
    # (the robot's "Hips" sits 10 cm below its pelvis, the capture's spine goes up):
    # turning it over would fold the body, so it gives no direction
    cos = np.dot(v, world_t) / (np.linalg.norm(v) * np.linalg.norm(world_t))
    if cos < -0.5 and np.linalg.norm(world_t) < 0.1 * t_height:
        return None
    return c, v, t


def _rolls_by_bones(ref: np.ndarray) -> bool:
    """Whether the secondary virtual bones ``ref[1:]`` ``(C - 1, 3)`` stray far enough from the
    primary one ``ref[0]`` to give the roll about it (a branching joint)."""
    if len(ref) < 2:
        return False
    n = ref[0] / np.linalg.norm(ref[0])
    normal = ref[1:] - np.outer(ref[1:] @ n, n)
    return bool(np.any(np.linalg.norm(normal, axis=1) > 0.1 * np.linalg.norm(ref[1:], axis=1)))


def _chains(tsk: Skeleton, bones: dict) -> dict[int, list[int]]:
    """Per mapped target joint with a primary bone, the unmapped joints between it and its
    primary child, top first. A branching joint has none: its turn also places its other
    bones and carries its twist (a hand's thumb hangs off the hand, not off the metacarpal
    towards its primary finger), so it is not spread down one of them."""
    chains: dict[int, list[int]] = {}
    for j, b in bones.items():
        if b.children and not b.roll_by_bones and not b.carries:
            path = []
            k = tsk.parents[b.children[0]]
            while k != j:
                path.append(int(k))
                k = tsk.parents[k]
            chains[j] = path[::-1]
    return chains


#: [rad] rest poses face along their file's axes: two skeletons' rest poses that face apart
#: differ by a quarter turn or more (a file's rest facing +X, another's +Z), and what is left
#: of a quarter turn is their pelvises' own build (Mixamo's thighs sit a little behind and
#: apart from the CMU capture's: 0.3 to 0.9 degrees)
QUARTER_TURN = 0.5 * math.pi


def _mapped_children(mapped: np.ndarray, anchor: np.ndarray) -> dict[int, list[int]]:
    """Per mapped target joint, the mapped joints whose nearest mapped ancestor it is."""
    kids: dict[int, list[int]] = {int(j): [] for j in np.flatnonzero(mapped >= 0)}
    for j in np.flatnonzero((mapped >= 0) & (anchor >= 0)):
        kids[int(anchor[j])].append(int(j))
    return kids


def _facing(mapped: np.ndarray, anchor: np.ndarray, p_ref: _Reference,
            t_ref: _Reference):
    """``(turn, pelvis)``: the turn about the vertical (``(4,)``) that makes the target's
    reference posture face as the performer's, about its pelvis (a joint index; given by
    :func:`_faced`), or ``None`` where they face alike.

    The pelvis is the top-most mapped joint with two mapped children or more (below any
    ground root); the turn is the least-squares turn of the horizontal vectors from it to
    them onto the performer's (:func:`_facing_turn`). Between two rest poses it is the
    nearest quarter turn (:data:`QUARTER_TURN`).

    The binding compares the two reference postures in the world (which way a short bone
    points, which performer bone continues a control joint's limb), and a joint whose bones
    do not roll it takes its performer joint's turn from the reference pose. Faced
    elsewhere, the target kept that difference on every frame: Ely with its rest pose facing
    +X walked sideways under the CMU walk (whose hips have no bone of their own: LowerBack
    sits on them); facing -Z, its clavicles pointed against the performer's and were taken
    for a rig's helper offsets (no bone to follow); and a clip bound on its frame 0 (where
    its rest pose lies) turned the CMU T-pose's pelvis 46 to 123 degrees from the
    performer's, between legs that pointed as the performer's did."""
    kids = _mapped_children(mapped, anchor)
    pelvis = next((j for j in sorted(kids) if len(kids[j]) >= 2), None)
    if pelvis is None:
        return None
    turn = _facing_turn(np.array(kids[pelvis]), pelvis, mapped, p_ref, t_ref)
    if p_ref.rest and t_ref.rest:
        turn = round(turn / QUARTER_TURN) * QUARTER_TURN
    if turn == 0.0:
        return None
    return about_axis(np.array([0.0, 1.0, 0.0]), turn), pelvis


def _faced(motion: Motion, ref: _Reference, facing) -> _Reference:
    """``ref`` (``motion``'s reference pose) turned by ``facing`` (:func:`_facing`) about the
    vertical through the pelvis, from the top-most joint that branches down: the body and
    the control joints beside it (the robot's IK feet under its root) turn together, the
    nodes above them (a ground root, an ``Armature`` node) stay, and so does the pelvis (the
    branching joint moves about it where it has position channels, else turns about
    itself)."""
    if facing is None:
        return ref
    turn, pelvis = facing
    sk = motion.skeleton
    top = sk.body_top()
    rot, tra = ref.rotations.copy(), ref.translations.copy()
    parent = sk.parents[top]
    above = ref.world[parent] if parent >= 0 else np.array([0.0, 0.0, 0.0, 1.0])
    rot[top] = qmul(qconj(above), qmul(turn, ref.world[top]))
    slot = np.flatnonzero(sk.translated == top)
    if len(slot):
        centre = ref.positions[pelvis]
        moved = qrot(turn, ref.positions[top] - centre) + centre
        start = ref.positions[parent] if parent >= 0 else np.zeros(3)
        tra[slot[0]] = qrot(qconj(above), moved - start)
    pose = fk_arrays(sk, rot[None], tra[None], end_sites=True)
    return _Reference(rot, tra, ref.label, pose.rotations[0], pose.positions[0],
                      pose.all_positions()[0], ref.rest, facing, ref.frame)


def _facing_turn(kids: np.ndarray, pelvis: int, mapped: np.ndarray, p_ref: _Reference,
                 t_ref: _Reference) -> float:
    """[rad] the least-squares turn about +Y of the target's horizontal vectors from
    ``pelvis`` to ``kids`` onto the performer's between their joints (0 where they have no
    horizontal extent)."""
    t = t_ref.positions[kids] - t_ref.positions[pelvis]
    v = p_ref.positions[mapped[kids]] - p_ref.positions[mapped[pelvis]]
    sin = float(np.sum(t[:, 2] * v[:, 0] - t[:, 0] * v[:, 2]))
    cos = float(np.sum(t[:, 2] * v[:, 2] + t[:, 0] * v[:, 0]))
    return math.atan2(sin, cos) if math.hypot(sin, cos) > 0.0 else 0.0


def _feet_standing(performer: Motion, p_ref, target: Motion, t_ref, mapped: np.ndarray,
                   bones: dict) -> dict:
    """The target's mapped foot joints with virtual bones (each foot's ankle and the mapped
    joints below it, where the target is a humanoid whose feet can be told) -> ``(G_p,
    G_t)``: the turns of the performer joint and of the target joint from their reference
    poses to where each stands flat (:func:`_standing_turn`)."""
    from .automap import identify
    tsk = target.skeleton
    try:
        roles = identify(tsk)
    except MappingError:
        return {}
    p_size = max(float(np.ptp(p_ref.all_positions, axis=0).max()), 1e-6)
    t_size = max(float(np.ptp(t_ref.all_positions, axis=0).max()), 1e-6)
    out = {}
    for side in ("l", "r"):
        ankle = tsk.index.get(roles.get(f"foot_{side}"))
        if ankle is None:
            continue
        for j in range(tsk.num_joints):
            if (j in bones and bones[j].children and not bones[j].carries
                    and (j == ankle or ankle in tsk.ancestors(j))):
                b = bones[j]
                out[j] = (_standing_turn(performer, p_ref, int(mapped[j]), int(b.performer[0]),
                                         p_size),
                          _standing_turn(target, t_ref, j, int(b.children[0]), t_size))
    return out


def _standing_turn(motion: Motion, ref, joint: int, end: int, size: float) -> np.ndarray:
    """``(4,)`` the world turn of ``joint`` from ``ref`` (a reference pose of ``motion``) to
    where it stands flat in ``motion``, its bone towards ``end``.

    The reference stands flat (the identity) where it is the skeleton's rest pose, or a frame
    where the foot is low (``joint`` and ``end`` within
    :data:`~engine.conversion.followers.FLAT_LOW` of ``size`` of their planted heights, each
    one's 5th percentile over the clip); a frame where it is not (a mid-stride frame) turns to
    the frame of median pitch among the low ones, about the vertical as in the reference
    (:func:`~engine.conversion.followers._standing`); the identity where it is never low."""
    from .followers import _standing
    identity = np.array([0.0, 0.0, 0.0, 1.0])
    if ref.frame is None:
        return identity
    standing = _standing(motion, joint, end, size, ref.world[joint], ref.frame)
    return identity if standing is None else qmul(standing, qconj(ref.world[joint]))


def _heading_turn(from_dir: np.ndarray, to_dir: np.ndarray) -> np.ndarray | None:
    """The turn about the vertical taking ``from_dir``'s heading onto ``to_dir``'s, ``None``
    where either points within 30 degrees of straight up or down (no heading to speak of)."""
    a, b = from_dir[[0, 2]], to_dir[[0, 2]]
    if (np.linalg.norm(a) < 0.5 * np.linalg.norm(from_dir)
            or np.linalg.norm(b) < 0.5 * np.linalg.norm(to_dir)):
        return None
    angle = math.atan2(a[1] * b[0] - a[0] * b[1], a[0] * b[0] + a[1] * b[1])
    return about_axis(np.array([0.0, 1.0, 0.0]), angle)


def _rest_posture(tsk: Skeleton, t_rot: np.ndarray, bones: dict,
                  rest_alignment: bool, feet: dict | None = None) -> np.ndarray:
    """``(J, 4)`` world rotations of the bound rest posture, root to leaves: the target's
    reference local rotations ``t_rot`` ``(J, 4)``, each joint with bones turned onto its
    virtual bones when ``rest_alignment`` is on.

    A foot joint of ``feet`` (joint -> ``(G_p, G_t)``, the turns of its performer joint and of
    itself from their reference poses to where each stands flat, :func:`_feet_standing`) is
    not laid along its virtual bone: it is the target's own foot standing flat, turned about
    the vertical to head as the performer's standing foot, then turned back by ``G_p``, so
    that where the performer's foot stands flat the character's stands as flat as it does
    itself. A foot's shape (its ankle's height over its length) differs from figure to
    figure: laid along the performer's, the CMU feet stood 20-30 degrees off flat on every
    Mixamo and Maya character, and the contacts' flat-foot hold turned them by that much at
    every step. A foot bone within 30 degrees of the vertical (a fox's hind foot) has no
    heading: it is laid along its bone."""
    feet = feet or {}
    J = tsk.num_joints
    rest_world = np.empty((J, 4))
    reference = np.empty((J, 4))              # the target's reference posture, unaligned
    for j in range(J):
        parent = tsk.parents[j]
        w = t_rot[j] if parent < 0 else qmul(rest_world[parent], t_rot[j])
        reference[j] = t_rot[j] if parent < 0 else qmul(reference[parent], t_rot[j])
        if rest_alignment and j in bones and bones[j].children:
            b = bones[j]
            heading = None
            if j in feet:
                g_p, g_t = feet[j]
                standing = qmul(g_t, reference[j])
                heading = _heading_turn(qrot(standing, b.target_local[0]),
                                        qrot(g_p, b.reference[0]))
            if heading is not None:
                w = qmul(qconj(g_p), qmul(heading, standing))
            else:
                w = qmul(_align(qrot(w, b.target_local), b.reference, b.roll_by_bones), w)
        rest_world[j] = w
    return rest_world


def _bones_in_posture(bones: dict, rest_world: np.ndarray, rest_positions: np.ndarray) -> dict:
    """The bones with ``target_local`` taken in the bound posture (world rotations ``(J, 4)``,
    positions ``(J, 3)`` [m]) instead of the target's reference posture."""
    out = dict(bones)
    for j, b in bones.items():
        if b.children and not b.carries:          # a follower is carried rigidly
            loc = qrot(qconj(rest_world[j]), rest_positions[b.children] - rest_positions[j])
            out[j] = _Bones(b.children, b.performer, loc, b.reference, b.roll_by_bones)
    return out


def _above_mapped(tsk: Skeleton, mapped: np.ndarray, followers=()) -> np.ndarray:
    """``(J,)`` bool: the joints with a mapped descendant or a follower below them."""
    above = np.zeros(tsk.num_joints, dtype=bool)
    carried = {f.joint for f in followers}
    for j in range(tsk.num_joints):
        if mapped[j] >= 0 or j in carried:
            for a in tsk.ancestors(j):
                above[a] = True
    return above


def _driven(tsk: Skeleton, mapped: np.ndarray, body_root: int, p_moving: set[int]) -> list:
    """The target joints whose world position follows their performer joint's: the body root,
    and translated target joints whose performer joint's translation is animated."""
    driven = [body_root]
    for j in tsk.translated[1:]:
        p = int(mapped[j])
        if j != body_root and p in p_moving:
            driven.append(int(j))
    return driven
