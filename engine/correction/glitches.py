"""One-frame glitches of a capture under held goals.

An optical capture now and then throws the whole body out and back in a single frame (a
marker taken for another for one frame): the CMU jumps, at 120 fps, turn their hips 4.5
degrees on frame 975 and back on 976, the thighs and the feet with them, the planted feet 5 mm
off and back. The direct conversion keeps that frame as it is, and outside the corrected
ranges so does the result. Under a held goal it cannot: the planted foot stays where it is,
so the frame's correction is the glitch undone, and solved from the glitched posture it is
undone at whichever joints the attraction gives up (the knee and the ankle of a standing leg,
which the conversion barely turns: a pop 1.4 to 2 times the no-pop limit on every character
the jumps were put on).

A frame is taken for such a glitch where, in the composed motion,

* the body (its topmost branching joint, :meth:`~engine.skeleton.Skeleton.body_top`) turns
  out and back: its world rotation lies off the midway of its neighbours' by more than half
  the turn between those neighbours (out and back, not on its way) and by more than
  :data:`RATIO` times as much as on any of the frames two and three before and after it (a
  move of a body's own, however fast, bends its path alike over a few frames), and
* a joint held there (a two-sided task active on the frame and both its neighbours) jumps
  out and back alike: off the midway of its neighbours' places by more than half the step
  between them, by :data:`RATIO` times the frames around, and by more than :data:`FLOOR` of
  the figure's size.

On those frames the attraction posture (every joint and the root) is the midway between the
frames around the glitch; the correction there is that, solved to the goals, less the
glitched frame, so the result passes the frame as its neighbours do. Measured on the shared
captures (clips of six conventions at 30 to 120 fps): the two frames of the CMU jumps are
12.0 and 9.7 times their surroundings at the hips and 16.0 and 10.6 at a planted foot; no
other frame of any clip passes 4.8 at the body, and a foot's single-frame spike on the Bandai
kick (12.6) comes with a body that moves on (1.0): left alone.
"""
from __future__ import annotations

import numpy as np

from ..kinematics import fk_arrays
from ..motion import Motion
from ..quaternions import qmul, qslerp
from ..rotations import angle_between

__all__ = ["RATIO", "FLOOR", "held_glitches", "without_glitches"]

#: how many times its surroundings' bend a frame's excursion must be (see the module)
RATIO = 8.0
#: a held joint's excursion at least this share of the figure's size (jitter aside)
FLOOR = 1e-3


def _out_and_back(excursion: np.ndarray, half_step: np.ndarray, floor: float = 0.0):
    """``(F,)`` bool: frames whose ``excursion`` off their neighbours' midway is more than
    ``half_step`` (half the way between the neighbours), :data:`RATIO` times the largest
    excursion two and three frames either side, and ``floor``; the first and last three
    frames are never judged."""
    F = len(excursion)
    out = np.zeros(F, dtype=bool)
    if F < 7:
        return out
    e = excursion[3:-3]
    around = np.maximum.reduce([excursion[:-6], excursion[1:-5], excursion[5:-1],
                                excursion[6:]])
    out[3:-3] = (e > half_step[3:-3]) & (e > RATIO * around) & (e > floor)
    return out


def _body(composed: Motion) -> int:
    """The joint whose world turn is the body's: the topmost branching joint
    (:meth:`~engine.skeleton.Skeleton.body_top`) where it turns; where neither it nor any
    joint above it ever turns (a rig's still root carrying the hips beside the feet's
    controls: Kenney's Maya character, whose ``Root`` holds ``HipsCtrl`` and two
    ``FootCtrl``, or the robot's ``Bone``), the topmost branching joint under its child that
    carries the most joints, and so on down. Judged at a still root, no frame of a clip would
    ever turn out and back."""
    from .enforcement import _still_joints
    sk = composed.skeleton
    still = _still_joints(composed)
    top = sk.body_top()
    while all(j in still for j in (top, *sk.ancestors(top))) and sk.children[top]:
        j = max(sk.children[top], key=lambda k: sk.subtree_sizes[k])
        while len(sk.children[j]) == 1:
            j = sk.children[j][0]
        if not sk.children[j]:
            break
        top = j
    return top


def held_glitches(composed: Motion, constraints, size: float) -> np.ndarray:
    """The frames of ``composed`` that are one-frame glitches under a held goal (see the
    module), sorted; ``constraints`` are a solve's (disabled ones and one-sided planes hold
    nothing); ``size`` is the figure's size [m]. Linear in the clip and cheap: the body's
    turn is found from the joints above it, the held joints' places only around the frames
    where it turns out and back."""
    F = composed.num_frames
    sk = composed.skeleton
    held = [(sk.index[c.joint], c.start, c.end) for c in constraints
            if c.enabled and c.joint in sk.index and not c.kind_object.one_sided(c.goal)]
    if F < 9 or not held:
        return np.zeros(0, dtype=int)
    top = _body(composed)
    q = composed.rotations[:, top]
    for a in sk.ancestors(top):                        # its world rotation
        q = qmul(composed.rotations[:, a], q)
    body = np.zeros(F)
    step = np.zeros(F)
    body[1:-1] = angle_between(q[1:-1], qslerp(q[:-2], q[2:], 0.5))
    step[1:-1] = angle_between(q[:-2], q[2:]) / 2.0
    turned = np.flatnonzero(_out_and_back(body, step))
    found = []
    for f in turned[(turned >= 4) & (turned <= F - 5)]:
        # the joints held on the frame and both its neighbours
        joints = sorted({j for j, start, end in held if start < f < end})
        if not joints:
            continue
        near = slice(f - 4, f + 5)                  # f and the excursions three either side
        x = fk_arrays(sk, composed.rotations[near], composed.translations[near],
                      end_sites=False).positions[:, joints]
        off = np.zeros((9, len(joints)))
        half = np.zeros((9, len(joints)))
        off[1:-1] = np.linalg.norm(x[1:-1] - (x[:-2] + x[2:]) / 2.0, axis=-1)
        half[1:-1] = np.linalg.norm(x[2:] - x[:-2], axis=-1) / 2.0
        if any(_out_and_back(off[:, k], half[:, k], FLOOR * size)[4]
               for k in range(len(joints))):
            found.append(int(f))
    return np.array(found, dtype=int)


def without_glitches(composed: Motion, frames) -> Motion:
    """``composed`` with each of ``frames`` (single frames inside the clip; a run of them is
    spanned from the frames before and after it) replaced by the way between its neighbours:
    every joint's rotation on the arc, the root's translation on the line (the one
    translation the correction moves)."""
    frames = np.unique(np.asarray(frames, dtype=int))
    if len(frames) == 0:
        return composed
    rot = composed.rotations.copy()
    tra = composed.translations.copy()
    F = composed.num_frames
    runs = np.split(frames, np.flatnonzero(np.diff(frames) > 1) + 1)
    for run in runs:
        a, b = int(run[0]) - 1, int(run[-1]) + 1
        if a < 0 or b >= F:
            raise ValueError(f"a glitch at frames {run.tolist()} needs a frame either side")
        for f in run:
            u = (f - a) / (b - a)
            rot[f] = qslerp(rot[a], rot[b], u)
            tra[f, 0] = tra[a, 0] + u * (tra[b, 0] - tra[a, 0])
    return Motion._trusted(composed.skeleton, rot, tra, composed.frame_time, composed.name)

