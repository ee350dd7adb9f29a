"""Control joints that follow the body: a character's IK targets kept in step with the limbs.

Game and Blender rigs often keep a foot (or a hand's weapon socket) as a joint of its own,
parented to the root rather than to the leg: Quaternius' robot's ``FootL`` sits under the root
``Bone`` at the end of the leg chain ``UpperLegL > LowerLegL``, Unreal's ``ik_foot_l`` under
``ik_foot_root`` on ``foot_l``, and Kenney's Maya character its ``LeftFootCtrl`` under ``Root``
on ``LeftFoot``. In the character's own clips an IK solver kept the shin pointing at that joint;
retargeted, nothing moves it, so the skinned foot stays where the rest pose put it while the
legs walk away.

A *follower* is such a joint: unmapped, hanging off the trunk (the joints from the root to
the hips) rather than a limb, with no mapped joint below it, and standing
either on a mapped joint or past the end of a mapped chain along its last bone. It is carried
rigidly with that joint (its *anchor*), as the character's own IK carried the chain to it, and
turns as the performer joint that continues the anchor's chain (the performer's ankle past its
knee) where there is one, else with the anchor. A follower the file never translated (a
character without animation) is given position channels by the binding.

:func:`find_followers` finds them when the binding is made; the converter and composer place
them (:mod:`.converter`, :mod:`.composer`), and :func:`follow` places them again on a motion
whose limbs a correction or an animator's layer changed. A point goal on a follower (a foot
contact, the floor) is met through its anchor's chain: the IK's task acts on the point of the
anchor's frame it stands on (:func:`carriers`, :func:`engine.correction.ik.effector`), and a
follower that takes a performer foot joint's turn is that foot for the automatic contacts
(:meth:`engine.scene.Scene.foot_pairs`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kinematics import fk_joints
from ..motion import Motion
from ..quaternions import qconj, qmul, qrot, qslerp, to_matrix, twist_about
from ..skeleton import Skeleton

__all__ = ["Follower", "find_followers", "follow", "carriers"]

#: a joint within this share of the character's size of a mapped joint stands on it
ON_JOINT = 0.01
#: past a chain's end: within this angle of the end bone's direction [deg] ...
ALONG_DEG = 30.0
#: ... and at most this many times the end bone's length beyond its end joint
REACH = 2.5
#: a performer foot is flat where its ankle and its toe are both within this share of the
#: performer's size of their planted heights (each one's 5th percentile over the clip, as
#: :func:`engine.correction.contacts.detect_contacts` has them)
FLAT_LOW = 0.03

#: of several performer children, the one that continues the chain is within this angle of the
#: target's anchor-to-follower direction in the two reference poses [deg] (loose: the two
#: poses may bend the limb otherwise)
CONTINUES_DEG = 60.0

FK_CHUNK = 4096


@dataclass(frozen=True, eq=False)
class Follower:
    """A target ``joint`` carried with mapped target joint ``anchor``.

    Attributes:
        offset: ``(3,)`` [m] its position in the anchor's frame in the target's reference
            pose (where the character's own rig placed it).
        source: the performer joint whose turn it takes, or -1 (it turns with the anchor).
        turn: ``(4,)`` its world rotation after the source's (or the anchor's) in the two
            reference poses: ``world = source world * turn``.
        toe: where the source is a performer foot, its toe (else -1): the follower then
            turns as that foot's heading and pitch turn from standing flat, never rolling
            (:meth:`foot_turn`).
        standing: ``(4,)`` the source's world rotation as it stands flat (the reference
            pose's heading); ``pitch`` [rad] its foot's pitch (ankle to toe) then; ``axis``
            ``(3,)`` the horizontal axis about which a turn by a positive angle pitches that
            foot down; ``rest`` ``(4,)`` the follower's world rotation in the target's
            reference pose.
    """

    joint: int
    anchor: int
    offset: np.ndarray
    source: int
    turn: np.ndarray
    toe: int = -1
    standing: np.ndarray | None = None
    pitch: float = 0.0
    axis: np.ndarray | None = None
    rest: np.ndarray | None = None

    def foot_turn(self, source: np.ndarray, ankle: np.ndarray, toe: np.ndarray) -> np.ndarray:
        """``(F, 4)`` the follower's world rotation from the performer foot's world rotation
        ``source (F, 4)`` and its ankle's and toe's positions ``(F, 3)``: its reference
        rotation pitched as the foot's pitch differs from standing flat, then turned about
        the vertical as the ankle's heading turned. A capture's foot also rolls about its
        own length, which a line skeleton does not show; carried onto a rigid foot a metre
        long (the robot's) that roll stood it on its edge (113 degrees off flat on a frame
        of the CMU walk)."""
        F = len(source)
        d = qmul(source, qconj(np.broadcast_to(self.standing, (F, 4))))
        heading = np.zeros((F, 4))
        heading[:, 1], heading[:, 3] = d[:, 1], d[:, 3]
        norm = np.linalg.norm(heading, axis=1, keepdims=True)
        heading = np.where(norm > 1e-9, heading / np.maximum(norm, 1e-12), [0.0, 0.0, 0.0, 1.0])
        half = 0.5 * (_pitch(toe - ankle) - self.pitch)
        pitched = np.concatenate([np.outer(np.sin(half), self.axis), np.cos(half)[:, None]],
                                 axis=1)
        return qmul(heading, qmul(pitched, np.broadcast_to(self.rest, (F, 4))))


def _trunk(tsk: Skeleton, has_mapped_below: np.ndarray, mapped: np.ndarray) -> set:
    """The joints from the root down to where the mapped body branches (the hips: legs and
    spine part there), which carry the whole body and nothing else."""
    trunk, j = set(), int(np.flatnonzero(tsk.parents < 0)[0])
    while True:
        trunk.add(j)
        below = [c for c in np.flatnonzero(tsk.parents == j)
                 if has_mapped_below[c] or mapped[c] >= 0]
        if len(below) != 1:
            return trunk
        j = int(below[0])


def _mapped_below(tsk: Skeleton, mapped: np.ndarray) -> np.ndarray:
    """``(J,)`` bool: the joints with a mapped joint below them."""
    below = np.zeros(tsk.num_joints, dtype=bool)
    for j in np.flatnonzero(mapped >= 0):
        below[tsk.ancestors(int(j))] = True
    return below


def _candidates(tsk: Skeleton, mapped: np.ndarray, has_mapped_below: np.ndarray) -> list[int]:
    """Unmapped non-root joints hanging off the trunk (:func:`_trunk`: no mapped limb carries
    them) with no mapped joint below them, parents first (a joint below a follower moves
    with it: :func:`find_followers` skips it; below a candidate that follows nothing, such
    as Unreal's ``ik_foot_root`` at the origin, it may follow: ``ik_foot_l`` on ``foot_l``).

    Whether the file animated a joint's translation is not asked: a character delivered
    without animation (or with an action that never moved its feet) has its control joints
    at rest, and the robot walked away from its own feet (the binding gives such a joint
    position channels: :func:`~engine.conversion.binding.bind`)."""
    trunk = _trunk(tsk, has_mapped_below, mapped)
    out = []
    for j in range(tsk.num_joints):
        above = tsk.ancestors(j)
        if tsk.parents[j] < 0 or mapped[j] >= 0 or has_mapped_below[j] \
                or any(mapped[a] >= 0 and a not in trunk for a in above):
            continue
        out.append(j)
    return out


def _anchor(tsk: Skeleton, mapped: np.ndarray, has_mapped_below: np.ndarray,
            positions: np.ndarray, j: int, size: float) -> int:
    """The mapped joint ``j`` follows (-1: none), from the target's reference pose
    ``positions``: the one it stands on, else the chain end (no mapped joint below) it lies
    nearest past, along its last bone."""
    joints = np.flatnonzero(mapped >= 0)
    gaps = np.linalg.norm(positions[joints] - positions[j], axis=1)
    if gaps.min() <= ON_JOINT * size:
        return int(joints[np.argmin(gaps)])
    best, found = np.inf, -1
    for k in joints:
        k = int(k)
        p = tsk.parents[k]
        if has_mapped_below[k] or p < 0:
            continue
        bone = positions[k] - positions[p]
        past = positions[j] - positions[k]
        length, reach = float(np.linalg.norm(bone)), float(np.linalg.norm(past))
        if length < 1e-9 or reach > REACH * length:
            continue
        if bone @ past >= np.cos(np.radians(ALONG_DEG)) * length * reach and reach < best:
            best, found = reach, k
    return found


def _source(psk: Skeleton, p_positions: np.ndarray, anchor_p: int, direction: np.ndarray,
            shortest: float) -> int:
    """The performer child of ``anchor_p`` that continues its chain (-1: none): its only child
    with a bone longer than ``shortest`` [m], or of several the one nearest ``direction`` (the
    target's, anchor to follower, in the two reference poses) within :data:`CONTINUES_DEG`."""
    kids = [int(c) for c in np.flatnonzero(psk.parents == anchor_p)
            if np.linalg.norm(p_positions[c] - p_positions[anchor_p]) > shortest]
    if len(kids) == 1:
        return kids[0]
    best, found = np.cos(np.radians(CONTINUES_DEG)), -1
    for c in kids:
        bone = p_positions[c] - p_positions[anchor_p]
        cos = float(bone @ direction) / (np.linalg.norm(bone) * max(np.linalg.norm(direction),
                                                                    1e-12))
        if cos > best:
            best, found = cos, c
    return found


def _toe(psk: Skeleton, p_positions: np.ndarray, joint: int, shortest: float) -> int:
    """The performer joint's farthest child with a bone longer than ``shortest`` [m] (a
    foot's toe), or -1."""
    kids = [int(c) for c in np.flatnonzero(psk.parents == joint)]
    lengths = [float(np.linalg.norm(p_positions[c] - p_positions[joint])) for c in kids]
    if not kids or max(lengths) <= shortest:
        return -1
    return kids[int(np.argmax(lengths))]


def _pitch(v: np.ndarray) -> np.ndarray:
    """[rad] how far vectors ``(..., 3)`` point below the horizontal (+Y up)."""
    return np.arctan2(-v[..., 1], np.linalg.norm(v[..., [0, 2]], axis=-1))


def _standing(motion: Motion, ankle: int, toe: int, size: float,
              reference: np.ndarray, frame: int | None = None) -> np.ndarray | None:
    """The performer ``ankle``'s world rotation as it stands flat, turned about the vertical
    to the heading nearest its ``reference`` world rotation; or None (the foot is never low,
    or is low on ``frame``, the reference's own frame: it stands flat there as it is).
    Flat is the frame of median pitch (``ankle`` to ``toe``) among those where both are low
    (:data:`FLAT_LOW`); its roll is the capture's own."""
    F = motion.num_frames
    rot, pos = np.empty((F, 2, 4)), np.empty((F, 2, 3))
    for lo in range(0, F, FK_CHUNK):
        hi = min(F, lo + FK_CHUNK)
        rot[lo:hi], pos[lo:hi] = fk_joints(motion.skeleton, motion.rotations[lo:hi],
                                           motion.translations[lo:hi], [ankle, toe])
    y = pos[..., 1]
    low = np.flatnonzero(np.all(y < np.percentile(y, 5.0, axis=0) + FLAT_LOW * size, axis=1))
    if not len(low) or frame in low:
        return None
    pitch = _pitch(pos[low, 1] - pos[low, 0])
    flat = rot[low[int(np.argmin(np.abs(pitch - np.median(pitch))))], 0]
    # the turn about the vertical (the twist about +Y) from the flat foot to the reference
    d = qmul(reference, qconj(flat))
    twist = np.array([0.0, d[1], 0.0, d[3]])
    norm = float(np.linalg.norm(twist))
    return flat if norm < 1e-9 else qmul(twist / norm, flat)


def find_followers(tsk: Skeleton, psk: Skeleton, mapped: np.ndarray, reference: tuple,
                   performer: tuple, motion: Motion | None = None) -> tuple:
    """The :class:`Follower` joints of a binding: ``mapped`` (target joint -> performer joint
    or -1) and two poses, each ``(world rotations (J, 4), positions (J, 3))``: the target's
    own reference pose (where its IK placed its control joints: which limb carries a joint,
    and where on it, are read there) and the performer's reference pose.

    A follower that takes the turn of a performer foot (a ``source`` with a toe below it)
    turns as that foot turns from standing flat (:func:`_standing`, found in the
    performer's ``motion``) in heading and pitch (:meth:`Follower.foot_turn`), not as the
    ankle turns from the reference pose: a clip bound on a mid-stride frame (BANDAI's) has
    the foot pitched there, and the robot's foot stood 56 degrees off the floor through the
    whole clip."""
    t_world, t_pos = reference
    p_world, p_pos = performer
    size = max(float(np.ptp(t_pos, axis=0).max()), 1e-9)
    p_size = max(float(np.ptp(p_pos, axis=0).max()), 1e-9)
    below = _mapped_below(tsk, mapped)
    out = []
    for j in _candidates(tsk, mapped, below):
        if set(tsk.ancestors(j)) & {f.joint for f in out}:
            continue
        k = _anchor(tsk, mapped, below, t_pos, j, size)
        if k < 0:
            continue
        offset = qrot(qconj(t_world[k]), t_pos[j] - t_pos[k])
        source = -1
        if np.linalg.norm(offset) > ON_JOINT * size:
            source = _source(psk, p_pos, int(mapped[k]), t_pos[j] - t_pos[k], ON_JOINT * p_size)
        turn = (qmul(qconj(p_world[source]), t_world[j]) if source >= 0 else
                qmul(qconj(t_world[k]), t_world[j]))
        foot = {}
        toe = _toe(psk, p_pos, source, ON_JOINT * p_size) if source >= 0 else -1
        standing = (_standing(motion, source, toe, p_size, p_world[source])
                    if toe >= 0 and motion is not None else None)
        if standing is not None:
            # the foot as it stands flat, and the axis across it that pitches it down
            v = qrot(standing, qrot(qconj(p_world[source]), p_pos[toe] - p_pos[source]))
            axis = np.cross(v, [0.0, 1.0, 0.0])
            if np.linalg.norm(axis) > 1e-9:
                axis /= np.linalg.norm(axis)
                down = np.r_[axis * np.sin(0.05), np.cos(0.05)]
                if _pitch(qrot(down, v)) < _pitch(v):
                    axis = -axis
                foot = dict(toe=toe, standing=standing, pitch=float(_pitch(v)), axis=axis,
                            rest=t_world[j])
        out.append(Follower(joint=j, anchor=k, offset=offset, source=source, turn=turn,
                            **foot))
    return tuple(out)


def follow(followers, motion: Motion, reference: Motion | None = None) -> Motion:
    """``motion`` with each follower's translation set so that it stands where its anchor
    carries it. For a motion whose limbs changed after the conversion placed them: a
    correction, a displacement layer.

    ``reference``: the motion those changes were made to (the same frames), for a
    correction: a follower that takes a performer joint's turn keeps the world rotation it
    has there, with its own rotation's change in ``motion`` on top, so that its parent's
    change does not turn it (the IK turning the robot's root by a degree or two swung its
    metre-long feet, which turn as the performer's, and took its soles centimetres into the
    floor). Without a ``reference`` (an animator's layer: a root turned turns the feet), or
    for a follower that turns with its anchor, its rotation is left as it is."""
    if not followers:
        return motion
    sk = motion.skeleton
    slot = {int(j): k for k, j in enumerate(sk.translated)}
    joints = sorted({f.anchor for f in followers} | {int(sk.parents[f.joint]) for f in followers})
    turned = [f for f in followers if f.source >= 0] if reference is not None else []
    parents = sorted({int(sk.parents[f.joint]) for f in turned})
    translations = motion.translations.copy()
    rotations = motion.rotations.copy() if turned else motion.rotations
    F = motion.num_frames
    for lo in range(0, F, FK_CHUNK):
        hi = min(F, lo + FK_CHUNK)
        rot, pos = fk_joints(sk, motion.rotations[lo:hi], motion.translations[lo:hi], joints)
        at = {j: n for n, j in enumerate(joints)}
        if turned:
            was, _ = fk_joints(sk, reference.rotations[lo:hi], reference.translations[lo:hi],
                               parents)
        for f in followers:
            a, p = at[f.anchor], at[int(sk.parents[f.joint])]
            world = pos[:, a] + qrot(rot[:, a], np.broadcast_to(f.offset, (hi - lo, 3)))
            translations[lo:hi, slot[f.joint]] = qrot(qconj(rot[:, p]), world - pos[:, p])
        for f in turned:
            p = int(sk.parents[f.joint])
            new, old = rot[:, at[p]], was[:, parents.index(p)]
            # where the parent did not turn the joint is left bit for bit
            moved = np.flatnonzero(np.any(new != old, axis=-1))
            rotations[lo + moved, f.joint] = qmul(qmul(qconj(new[moved]), old[moved]),
                                                  motion.rotations[lo + moved, f.joint])
    return motion.replace(rotations=rotations, translations=translations)


def lowest(turn: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``(F,)`` [m] the lowest height of ``points`` ``(V, 3)`` (in a joint's frame) above the
    joint, turned by ``turn`` ``(F, 4)``: the lowest point of a foot's mesh, per frame."""
    return (to_matrix(turn)[:, 1, :] @ points.T).min(axis=1)      # the turned heights


#: bisection steps of :func:`above_floor` (the share of the turn back to flat to 1e-9)
_BISECTIONS = 30

#: [s] how long :func:`above_floor` takes at least to turn a foot back to flat, and to let it
#: go (the no-pop rule's own window)
FLAT_EASE = 0.25


def above_floor(followers, motion: Motion, floor: float, soles: dict) -> Motion:
    """``motion`` with each foot follower in ``soles`` (joint index -> ``(V, 3)`` [m] its
    mesh's vertices in its own frame) turned back towards standing flat where its turn would
    take a vertex under ``floor`` [m]: on each such frame just as far as it takes to bring
    the lowest one onto the floor, eased in and out over :data:`FLAT_EASE` around it (a
    heel that dips 3 cm near the ankle needed 15 degrees in one frame, 923 deg/s on the CC3
    walk; eased over the contacts' ramp, 0.12 s, the Rokoko dance's foot still turned 1.07
    times the no-pop limit). A rigid foot pivots on its tip as its ankle rises, never
    through the floor. Flat is the follower's rest rotation turned to its
    heading (the twist about the vertical of its turn from rest); a foot whose ankle stands
    lower than its rest height over the floor (which the floor constraint does not allow)
    is left flat. For the robot's metre-long feet, which turn as the performer's: pitched as
    the performer's foot through a toe-off or a swing, their tips went 0.2-0.4 m under the
    floor."""
    sk = motion.skeleton
    chosen = [f for f in followers if f.joint in soles and f.rest is not None]
    if not chosen:
        return motion
    parents = [int(sk.parents[f.joint]) for f in chosen]
    rot, pos = fk_joints(sk, motion.rotations, motion.translations,
                         [f.joint for f in chosen] + parents)
    rotations = motion.rotations.copy()
    up = np.array([0.0, 1.0, 0.0])
    n = len(chosen)
    for k, f in enumerate(chosen):
        turn, points = rot[:, k], soles[f.joint]
        need = floor - pos[:, k, 1]                 # the lowest vertex's least height
        bad = np.flatnonzero(lowest(turn, points) < need)
        if not len(bad):
            continue
        heading = twist_about(qmul(turn, qconj(f.rest)), up)
        flat = qmul(heading, np.broadcast_to(f.rest, heading.shape))
        lo, hi = np.zeros(len(bad)), np.ones(len(bad))
        for _ in range(_BISECTIONS):
            mid = 0.5 * (lo + hi)
            ok = lowest(qslerp(turn[bad], flat[bad], mid), points) >= need[bad]
            hi = np.where(ok, mid, hi)
            lo = np.where(ok, lo, mid)
        share = np.zeros(len(turn))
        share[bad] = hi
        share = _eased(share, 1.0 / max(1.0, FLAT_EASE * motion.fps))
        moved = np.flatnonzero(share > 0.0)
        world = qslerp(turn[moved], flat[moved], share[moved])
        rotations[moved, f.joint] = qmul(qconj(rot[moved, n + k]), world)
    return motion.replace(rotations=rotations)


def _eased(share: np.ndarray, step: float) -> np.ndarray:
    """The least curve at or above ``share`` ``(F,)`` that changes by at most ``step`` from
    frame to frame (a cone's two sides)."""
    out = share.copy()
    for t in range(1, len(out)):
        out[t] = max(out[t], out[t - 1] - step)
    for t in range(len(out) - 2, -1, -1):
        out[t] = max(out[t], out[t + 1] - step)
    return out


def carriers(followers) -> dict:
    """Per follower joint ``(anchor, offset)``: the point of its anchor's frame it stands on,
    where a goal on it is met (the IK holds it through the limb:
    :func:`engine.correction.ik.effector`)."""
    return {f.joint: (f.anchor, f.offset) for f in followers}
