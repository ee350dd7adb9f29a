"""How good a correction is, in the figures both ``retarget --report`` and the window's quality
panel show: one function, :func:`quality`.

* ``constraints``: each enabled constraint's residual over its active range (the largest, the
  mean and the frame of the largest; metres, radians for orientation kinds).
* ``contacts``: each automatic foot contact (heel or toe): how far the target's joint drifts
  horizontally over the contact, in the direct conversion and corrected.
* ``pops``: per joint, its worst ratio of angular speed to the no-pop limit around the ramps
  (:func:`pop_limits`): 1 or less means no pop.
* ``bone_directions``: per mapped target bone, the largest angle between the performer's bone
  (the virtual bone it follows) and the corrected target bone, and where.
* ``per_frame``: the foot slide (the largest horizontal distance of a planted joint from where
  its contact started) and the largest metric residual, per frame.

Before a solve, :func:`goal_jumps` reads the request itself: where the user's goals for one
joint ask it to jump, it says so in one line (a solve's warnings).
"""
from __future__ import annotations

import numpy as np

from ..kinematics import fk_arrays
from ..motion import Motion
from ..quaternions import qconj, qmul
from .contacts import held_until

__all__ = ["quality", "angular_speed", "ramps", "pop_limits", "goal_jumps", "POP_WINDOW",
           "POP_FACTOR", "SMOOTHSTEP_PEAK", "JUMP_FLOOR"]

#: [s] around a ramp, the direct conversion's fastest turn within this is the reference
POP_WINDOW = 0.25
#: a joint may turn this many times faster than the direct conversion's fastest turn near a ramp
POP_FACTOR = 1.2
#: the steepest slope of a smoothstep 3u^2 - 2u^3 over [0, 1] (at u = 1/2)
SMOOTHSTEP_PEAK = 1.5
#: [rad/s] no limit is lower: a turn this slow is no pop (a twelfth of a degree a frame at
#: 120 fps, a third at 30). Where the capture holds a joint still and the correction there is
#: small, the rule's limit falls towards zero, and a correction that eases in at a few
#: degrees a second (a knee under a foot that two overlapping ramps let go, 5-7 deg/s on the
#: CMU walk onto Ely and on the demo) would count as a pop that no eye sees; the pops the
#: rule is for turn hundreds of degrees a second
_SPEED_FLOOR = np.radians(10.0)


#: [statures] two goals of one joint closer than this are no jump, whatever the frames between
JUMP_FLOOR = 0.01


def _angle(q: np.ndarray) -> np.ndarray:
    """[rad] the rotation angle of quaternions ``(..., 4)``, in [0, pi]."""
    return 2.0 * np.arctan2(np.linalg.norm(q[..., :3], axis=-1), np.abs(q[..., 3]))


def angular_speed(motion: Motion) -> np.ndarray:
    """``(F, J)`` [rad/s] how fast each joint's local rotation turns into each frame (from the
    frame before; 0 at frame 0)."""
    q = motion.rotations
    out = np.zeros(q.shape[:2])
    if len(q) > 1:
        out[1:] = _angle(qmul(q[1:], qconj(q[:-1]))) * motion.fps
    return out


def ramps(constraints, num_frames: int) -> list[tuple[int, int]]:
    """``(a, b)`` frame spans (``a < b``) over which constraints ease in or out: ``[smooth_in,
    start]`` and ``[end, smooth_out]``; a constraint that switches on or off within the clip
    without a ramp (or with a ramp of one frame) gives the shortest ramp of two frames or more
    keyed on that frame and side (which enforcement eases it with), else the one-frame span
    around that switch."""
    out = set()
    last = num_frames - 1
    enabled = [c for c in constraints if c.enabled]
    # the shortest input (output) ramp keyed on each frame: a constraint that switches on
    # (off) there without a ramp of its own is eased with it (a toe held from the flat foot
    # on, a heel planted as the foot's flat turn ends; see enforcement._virtual_frames), so
    # it is judged over that ramp, not allowed a one-frame jump
    rising: dict[int, int] = {}
    falling: dict[int, int] = {}
    for c in enabled:
        if c.start - c.smooth_in >= 2:
            rising[c.start] = max(rising.get(c.start, c.smooth_in), c.smooth_in)
        if c.smooth_out - c.end >= 2:
            falling[c.end] = min(falling.get(c.end, c.smooth_out), c.smooth_out)
    for c in enabled:
        if c.start - c.smooth_in >= 2:
            out.add((c.smooth_in, c.start))
        elif c.start in rising:               # no ramp, or one of a frame: eased with it
            out.add((rising[c.start], c.start))
        elif c.start > 0:
            out.add((c.start - 1, c.start))
        if c.smooth_out - c.end >= 2:
            out.add((c.end, c.smooth_out))
        elif c.end in falling:
            out.add((c.end, falling[c.end]))
        elif c.end < last:
            out.add((c.end, c.end + 1))
    return sorted(out)


def pop_limits(direct: Motion, corrected: Motion, spans) -> np.ndarray:
    """``(F, J)`` [rad/s] each joint's limit on the frames around the ramp spans ``(a, b)``
    (those turned into from ``a - 1`` to ``b + 1``), ``inf`` on frames around none.

    The limit (issue 14 point 2) is the larger of :data:`POP_FACTOR` times the direct
    conversion's fastest turn at the joint within :data:`POP_WINDOW` of the ramp, and that turn
    plus what a smoothstep over the ramp needs for the correction's size there (the largest
    turn of the joint's correction from its value at either end of the ramp). Where ramps
    overlap, the correction is eased by all of them at once: a frame around several has the
    sum of their smoothsteps' needs (and the fastest of their direct turns). Judged against
    each ramp alone, a joint eased by one ramp while another begins would be held to the
    other's need only, which no easing meets (a foot's ramp out moving the hips under the
    other foot, planted and about to ease out itself).
    """
    F = direct.num_frames
    fps = direct.fps
    speed = angular_speed(direct)
    J = speed.shape[1]
    offset = qmul(corrected.rotations, qconj(direct.rotations))          # (F, J, 4)
    w = int(round(POP_WINDOW * fps))
    base = np.zeros((F, J))
    need = np.zeros((F, J))
    around = np.zeros(F, dtype=bool)
    for a, b in spans:
        fastest = speed[max(0, a - w):min(F, b + w + 1)].max(axis=0)
        part = offset[a:b + 1]
        size = np.maximum(_angle(qmul(part, qconj(part[:1]))),
                          _angle(qmul(part, qconj(part[-1:])))).max(axis=0)
        frames = slice(max(1, a), min(F, b + 2))
        base[frames] = np.maximum(base[frames], fastest)
        need[frames] += SMOOTHSTEP_PEAK * size * fps / (b - a)
        around[frames] = True
    limit = np.maximum(np.maximum(POP_FACTOR * base, base + need), _SPEED_FLOOR)
    limit[~around] = np.inf
    return limit


def goal_jumps(direct: Motion, constraints) -> list[str]:
    """One line per pair of the user's constraints that ask a joint to jump.

    Two enabled constraints with goal points (position, trajectory) on one joint, the second
    taking the joint ``n`` frames after the first lets it go (``start - end``; no third one
    holding it between them): the goal where the first ends and the goal where the second
    starts lie further apart than the joint travels in ``n`` frames at :data:`POP_FACTOR`
    times its fastest in the direct conversion within :data:`POP_WINDOW` of them, and more
    than :data:`JUMP_FLOOR` of the stature apart. The enforcement eases such a change over
    the ramps as well as it can, and the motion still pops there (a hand held at goals 19 cm
    apart on frames 120 and 121 of the bundled walk turned 2.6 times the no-pop limit):
    the request, not the solve, is what to change. Overlapping active ranges are a
    compromise, not a jump; automatic constraints (foot contacts, IK blends) follow the
    performer, who made the move."""
    from ..describe import stature
    from .constraints import ConstraintError
    groups: dict[str, list] = {}
    for c in constraints:
        if not c.enabled or c.auto:
            continue
        try:
            c.goal_point(np.array([c.start]))
        except ConstraintError:
            continue                                    # a plane, an orientation: no point
        groups.setdefault(c.joint, []).append(c)
    sk = direct.skeleton
    F = direct.num_frames
    w = int(round(POP_WINDOW * direct.fps))
    size = None
    out = []
    for joint, group in groups.items():
        if len(group) < 2 or joint not in sk.index:
            continue
        group.sort(key=lambda c: (c.start, c.end))
        for a, b in zip(group, group[1:]):
            n = b.start - a.end
            if n <= 0 or any(c.start < b.start and c.end > a.end
                             for c in group if c is not a and c is not b):
                continue
            gap = float(np.linalg.norm(b.goal_point(np.array([b.start]))[0] -
                                       a.goal_point(np.array([a.end]))[0]))
            if size is None:
                size = stature(direct)
            if gap <= JUMP_FLOOR * size:
                continue
            near = slice(max(0, a.end - w), min(F - 1, b.start + w) + 1)
            pos = fk_arrays(sk, direct.rotations[near], direct.translations[near],
                            end_sites=False).positions[:, sk.index[joint]]
            step = float(np.linalg.norm(np.diff(pos, axis=0), axis=1).max(initial=0.0))
            travel = POP_FACTOR * step * n
            if gap > travel:
                frames = f"{n} frame{'s' if n > 1 else ''}"
                if travel > 0:
                    ratio = gap / travel
                    how = (f"{ratio:.{1 if ratio < 10 else 0}f} times as far as the "
                           f"conversion moves it in {frames}")
                else:
                    how = f"and the conversion holds it still for {frames}"
                out.append(f"{joint}: {a.name or a.kind!r} holds it to frame {a.end} and "
                           f"{b.name or b.kind!r} from frame {b.start}, at goals "
                           f"{gap * 100:.1f} cm apart, {how}: the motion jumps there (leave "
                           "more frames between them or move a goal)")
    return out


def _residuals(constraints, residual) -> list[dict]:
    out = []
    for i, c in enumerate(constraints):
        res = residual[i][c.start:c.end + 1] if residual is not None else np.array([np.nan])
        solved = np.isfinite(res)
        if solved.any():
            k = int(np.nanargmax(res))
            entry = {"max_residual": float(res[k]), "mean_residual": float(np.nanmean(res)),
                     "frame": c.start + k}
        else:
            entry = {"max_residual": None, "mean_residual": None, "frame": None}
        out.append({"name": c.name or c.joint, "joint": c.joint, "kind": c.kind,
                    "residual_unit": c.kind_object.residual_unit, **entry})
    return out


def _contacts(constraints, direct_pos, corrected_pos, index) -> tuple[list[dict], np.ndarray]:
    """The contacts' drift, and per frame the largest slide of a planted joint."""
    slide = np.zeros(len(direct_pos))
    out = []
    seen = set()
    for c in constraints:
        if not (c.auto and c.meta.get("source") == "contact" and "part" in c.meta):
            continue
        key = (c.joint, c.start, c.end)
        if key in seen:                     # a contact held by two constraints counts once
            continue
        seen.add(key)
        j = index[c.joint]
        span = slice(c.start, held_until(c) + 1)        # a heel's pivot moves it, by design
        drifts = []
        for pos in (direct_pos, corrected_pos):
            p = pos[span, j][:, [0, 2]]
            drifts.append(np.linalg.norm(p - p[0], axis=1))
        slide[span] = np.maximum(slide[span], drifts[1])
        out.append({"joint": c.joint, "part": c.meta["part"], "start": c.start, "end": c.end,
                    "drift_direct_m": float(drifts[0].max()),
                    "drift_corrected_m": float(drifts[1].max())})
    return out, slide


def _pops(direct: Motion, corrected: Motion, constraints) -> list[dict]:
    names = corrected.skeleton.names
    speed = angular_speed(corrected)
    limit = pop_limits(direct, corrected, ramps(constraints, direct.num_frames))
    around = np.isfinite(limit)
    # -1 off the ramps: the worst frame of a joint is always one around a ramp
    ratio = np.where(around, speed / np.where(around, limit, 1.0), -1.0)
    where = ratio.argmax(axis=0)
    J = len(names)
    worst = ratio[where, np.arange(J)]
    order = np.argsort(-worst, kind="stable")
    return [{"joint": names[j], "ratio": float(worst[j]), "frame": int(where[j]),
             "speed_deg_s": float(np.degrees(speed[where[j], j])),
             "limit_deg_s": float(np.degrees(limit[where[j], j]))}
            for j in order if around[:, j].any()]


def _bone_directions(binding, performer: Motion, corrected_pos) -> list[dict]:
    """Per mapped target bone (named by its child joint): the largest angle between the
    performer's (virtual) bone and the corrected target bone."""
    if binding is None:
        return []
    p_pos = fk_arrays(performer.skeleton, performer.rotations, performer.translations,
                      end_sites=False).positions
    names = binding.target.names
    out = []
    for j, bones in binding.bones.items():
        p = int(binding.mapped[j])
        for c, pc in zip(bones.children, bones.performer):
            a = p_pos[:, pc] - p_pos[:, p]
            b = corrected_pos[:, c] - corrected_pos[:, j]
            cos = np.sum(a * b, axis=1) / np.maximum(
                np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-12)
            angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
            k = int(angle.argmax())
            out.append({"joint": names[c], "max_error_deg": float(angle[k]), "frame": k})
    return out


def quality(performer: Motion, direct: Motion, corrected: Motion, constraints, residual,
            binding=None) -> dict:
    """The quality figures of a correction (see the module doc), JSON-ready.

    Args:
        performer: the performer's motion (the capture).
        direct: the direct conversion (composed motion), ``F`` frames.
        corrected: the corrected motion (the direct conversion when nothing was solved).
        constraints: the enabled constraints, in the order ``residual`` indexes them.
        residual: constraint index -> ``(F,)`` residual (NaN where not solved), or ``None``.
        binding: the :class:`~engine.conversion.binding.Binding` (for bone directions), or
            ``None`` to leave them out.
    """
    constraints = [c for c in constraints if c.enabled]
    sk = direct.skeleton
    direct_pos = fk_arrays(sk, direct.rotations, direct.translations, end_sites=False).positions
    corrected_pos = fk_arrays(sk, corrected.rotations, corrected.translations,
                              end_sites=False).positions
    contacts, slide = _contacts(constraints, direct_pos, corrected_pos, sk.index)
    worst = np.zeros(direct.num_frames)
    if residual is not None:
        for i, c in enumerate(constraints):
            if not c.kind_object.angular:
                worst = np.fmax(worst, residual[i])
    return {"constraints": _residuals(constraints, residual),
            "contacts": contacts,
            "pops": _pops(direct, corrected, constraints),
            "bone_directions": _bone_directions(binding, performer, corrected_pos),
            "per_frame": {"foot_slide_m": slide.tolist(), "max_residual_m": worst.tolist()}}
