"""Automatic foot (and hand) contacts: detect where the performer plants a foot, then pin the
target's foot there with eased constraints.

Foot sliding is the first complaint of anyone who retargets: the converted foot follows the
performer's leg directions but the target's legs have other lengths, so a planted foot drifts.
:func:`detect_contacts` finds the performer's contacts from height and speed;
:func:`contact_constraints` turns each into an editable position constraint on the mapped
target joint (plus a keep-above-the-floor plane on its toe), with ramps.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .constraints import Constraint
from ..kinematics import fk_arrays
from ..motion import Motion
from ..skeleton import Skeleton

__all__ = ["Contact", "ContactOptions", "detect_contacts", "contact_constraints",
           "find_feet", "horizontal_drift", "estimate_floor"]


@dataclass(frozen=True)
class ContactOptions:
    """Thresholds for contact detection (relative to the character's size where it says so).

    Attributes:
        height: a point within this fraction of the stature above its planted height counts
            as low (0.03 of 1.7 m is 5 cm).
        speed: [statures per second] horizontal speed under which a low point is planted.
        min_duration: [s] shorter contacts are dropped.
        max_gap: [s] gaps shorter than this inside a contact are closed.
        ramp: [s] ease-in and ease-out around each contact.
    """

    height: float = 0.03
    speed: float = 0.25
    min_duration: float = 0.08
    max_gap: float = 0.07
    ramp: float = 0.12


@dataclass(frozen=True)
class Contact:
    """A detected contact: performer ``joint`` (and ``toe``) planted from ``start`` to ``end``
    (frames, inclusive)."""

    joint: str
    toe: str | None
    start: int
    end: int


def find_feet(skeleton: Skeleton) -> list[tuple[str, str | None]]:
    """``(ankle, toe)`` joint names of each foot (toe ``None`` where there is none), from the
    humanoid roles :func:`engine.conversion.automap.identify` finds; none for a skeleton that is not a
    humanoid."""
    from ..conversion.automap import identify
    from ..errors import MappingError
    try:
        roles = identify(skeleton)
    except MappingError:
        return []
    return [(roles.get(f"foot_{side}"), roles.get(f"toe_{side}")) for side in ("l", "r")
            if roles.get(f"foot_{side}")]


def estimate_floor(heights: np.ndarray) -> float:
    """The floor under a set of low points ``(F, n)``: the 2nd percentile of the lowest."""
    return float(np.percentile(np.min(heights, axis=1), 2.0))


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1) - 1
    return list(zip(starts.tolist(), ends.tolist()))


def detect_contacts(motion: Motion, feet: list[tuple[str, str | None]] | None = None,
                    options: ContactOptions | None = None) -> list[Contact]:
    """Contacts of ``motion``'s feet (``(ankle, toe)`` names; found by name when omitted)."""
    from ..describe import stature
    options = options or ContactOptions()
    sk = motion.skeleton
    feet = feet if feet is not None else find_feet(sk)
    if not feet or motion.num_frames < 2:        # a contact lasts two frames or more
        return []
    pose = fk_arrays(sk, motion.rotations, motion.translations, end_sites=False)
    pos = pose.positions
    size = max(stature(motion), 0.1)
    fps = motion.fps
    points = []
    for ankle, toe in feet:
        idx = [sk.index[ankle]] + ([sk.index[toe]] if toe else [])
        points.append(idx)
    low_all = np.concatenate([pos[:, idx, 1] for idx in points], axis=1)
    floor = estimate_floor(low_all)
    contacts = []
    for (ankle, toe), idx in zip(feet, points):
        planted = np.zeros(motion.num_frames, dtype=bool)
        for j in idx:
            y = pos[:, j, 1] - floor
            rest = np.percentile(y, 5.0)                        # its height when planted
            vel = np.gradient(pos[:, j][:, [0, 2]], axis=0) * fps
            speed = np.linalg.norm(vel, axis=1)
            planted |= (y < rest + options.height * size) & (speed < options.speed * size)
        gap = max(1, int(round(options.max_gap * fps)))
        for s, e in _runs(~planted):
            if 0 < s and e < len(planted) - 1 and e - s + 1 <= gap:
                planted[s:e + 1] = True
        shortest = max(2, int(round(options.min_duration * fps)))
        for s, e in _runs(planted):
            if e - s + 1 >= shortest:
                contacts.append(Contact(ankle, toe, s, e))
    contacts.sort(key=lambda c: (c.start, c.joint))
    return contacts


def contact_constraints(contacts: list[Contact], performer: Motion, composed: Motion,
                        pairs: dict[str, str], options: ContactOptions | None = None, *,
                        floor: float | None = None, priority: int = 1) -> list[Constraint]:
    """Constraints that pin the target's feet during the performer's ``contacts``.

    ``pairs``: target joint -> performer joint (the correspondence). Each contact gives a
    position constraint on the target joint mapped to the performer's ankle: horizontally at
    the converted foot's median position over the contact, vertically at the target's planted
    ankle height (measured above the ground the converted feet stand on) above ``floor``
    [m, the target's own vertical axis; that ground when None], plus the performer's own lift
    above its planted height, scaled to the target. Where the toe is
    mapped, a plane constraint keeps it on or above the floor over the same range.
    """
    from ..describe import stature
    options = options or ContactOptions()
    by_performer = {p: t for t, p in pairs.items()}
    sk = composed.skeleton
    F = composed.num_frames
    fps = composed.fps
    ramp = max(1, int(round(options.ramp * fps)))
    t_pos = fk_arrays(sk, composed.rotations, composed.translations, end_sites=False).positions
    p_pos = fk_arrays(performer.skeleton, performer.rotations, performer.translations,
                      end_sites=False).positions
    feet_t = sorted({by_performer[c.joint] for c in contacts if c.joint in by_performer})
    if not feet_t:
        return []
    # the ground is under the lowest point of the feet: the toes where they are mapped
    low_t = feet_t + sorted({by_performer[c.toe] for c in contacts if c.toe in by_performer})
    t_low = t_pos[:, [sk.index[n] for n in low_t], 1]
    ground = estimate_floor(t_low)              # where the converted feet stand
    t_floor = ground if floor is None else float(floor)
    p_feet = sorted({c.joint for c in contacts} | {c.toe for c in contacts if c.toe})
    p_low = p_pos[:, [performer.skeleton.index[n] for n in p_feet], 1]
    p_floor = estimate_floor(p_low)
    ratio = max(stature(composed), 0.1) / max(stature(performer), 0.1)
    # ramps: at most `ramp` frames, and never over the next contact of the same joint
    spans: dict[int, list[int]] = {}
    order = sorted(range(len(contacts)), key=lambda i: contacts[i].start)
    previous: dict[str, int] = {}
    for i in order:
        c = contacts[i]
        target = by_performer.get(c.joint)
        if target is None:
            continue
        lo = max(0, c.start - ramp)
        if target in previous:
            before = contacts[previous[target]]
            half = max(0, (c.start - before.end - 1) // 2)
            lo = max(lo, c.start - half)
            spans[previous[target]][1] = min(spans[previous[target]][1], before.end + half)
        spans[i] = [lo, min(F - 1, c.end + ramp)]
        previous[target] = i
    # each joint's planted height, once per joint (not per contact: linear in the clip)
    planted_t = {t: max(0.0, np.percentile(t_pos[:, sk.index[t], 1] - ground, 5.0))
                 for t in {by_performer[contacts[i].joint] for i in spans}}
    planted_p = {p: np.percentile(p_pos[:, performer.skeleton.index[p], 1] - p_floor, 5.0)
                 for p in {contacts[i].joint for i in spans}}
    out = []
    for i in order:
        if i not in spans:
            continue
        c = contacts[i]
        target = by_performer[c.joint]
        smooth_in, smooth_out = spans[i]
        j = sk.index[target]
        pj = performer.skeleton.index[c.joint]
        window = slice(c.start, c.end + 1)
        lift = float(np.median(p_pos[window, pj, 1] - p_floor)) - planted_p[c.joint]
        goal = np.median(t_pos[window, j], axis=0)
        goal[1] = t_floor + planted_t[target] + max(lift, 0.0) * ratio
        name = f"contact {target} {c.start}-{c.end}"
        out.append(Constraint(joint=target, kind="position", goal={"point": goal},
                              smooth_in=smooth_in, start=c.start, end=c.end,
                              smooth_out=smooth_out, priority=priority, name=name, auto=True,
                              meta={"source": "contact", "part": "heel",
                                    "performer_joint": c.joint}))
        toe = by_performer.get(c.toe) if c.toe else None
        if toe is not None:
            out.append(Constraint(joint=toe, kind="plane",
                                  goal={"point": [0.0, t_floor, 0.0], "normal": [0, 1, 0],
                                        "side": "above"},
                                  smooth_in=smooth_in, start=c.start, end=c.end,
                                  smooth_out=smooth_out, priority=priority,
                                  name=f"floor {toe} {c.start}-{c.end}", auto=True,
                                  meta={"source": "contact", "performer_joint": c.toe}))
    return out


def horizontal_drift(motion: Motion, joint: str, start: int, end: int) -> float:
    """[m] How far ``joint`` wanders horizontally from frame ``start`` to ``end``: the largest
    distance from its position at ``start``."""
    sk = motion.skeleton
    pose = fk_arrays(sk, motion.rotations[start:end + 1], motion.translations[start:end + 1],
                     end_sites=False)
    p = pose.positions[:, sk.index[joint]][:, [0, 2]]
    return float(np.linalg.norm(p - p[0], axis=1).max())
