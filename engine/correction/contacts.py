"""Automatic foot contacts: detect where the performer plants a foot, heel and toe apart, then
hold the target's foot there with eased constraints.

Foot sliding is the first complaint of anyone who retargets: the converted foot follows the
performer's leg directions but the target's legs have other lengths, so a planted foot drifts;
and it follows the performer's foot pitch, so on a character whose ankle stands higher or lower
above its toe the converted toe floats or sinks. :func:`detect_contacts` finds the performer's
contacts from height and speed, per foot part (heel strike, flat, heel-off with the toe
pivoting, toe-off); :func:`contact_constraints` holds the target's ankle and toe at the heights
they have in the character's own rest pose above its floor (:func:`target_ground`), the toe
where it planted while the heel rises, with ramps.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np

from .constraints import Constraint
from ..kinematics import fk_arrays, fk_joints
from ..motion import Motion
from ..quaternions import qconj, qmul, qrot, quat_between
from ..skeleton import Skeleton

__all__ = ["Contact", "ContactOptions", "Ground", "detect_contacts", "contact_constraints",
           "capture_noise", "find_feet", "horizontal_drift", "held_until", "estimate_floor",
           "target_ground", "converted_ground", "below_foot", "PART_MIN_FRAMES", "PART_HEIGHT"]

#: a part's planted run is this many frames or more (a heel strike lasts a few frames)
PART_MIN_FRAMES = 3
#: within a contact a part is held where it is within this share of ``ContactOptions.height``
#: above its lowest height in the contact: a heel rising off the floor is let go (heel-off)
#: while the foot as a whole is still on the ground
PART_HEIGHT = 2.0 / 3.0
#: heel-off (:func:`_heel_offs`): a heel run's last frames where the heel rises faster than
#: ``HEEL_RISE`` statures per second on every frame, by ``HEEL_OFF`` of the stature or more
#: in all, with the toe held, are the heel rising as the foot pivots about the toe
HEEL_OFF = 0.005
HEEL_RISE = 0.05
#: [s] on a noisy capture (:data:`NOISY`) the detector measures a foot part's speed and
#: height on its path smoothed over this many seconds (:func:`_smoothed`): a capture's noise,
#: a few millimetres a frame, is metres per second at 120 frames a second, and broke a walk's
#: plants into pieces
SMOOTH = 1.0 / 60.0
#: a capture is noisy where its noise (:func:`_noise`, per axis and frame) moves a still foot
#: from one frame to the next (sqrt 2 times the noise, times the frame rate) at over this share
#: of ``ContactOptions.speed``: a still foot then reads as moving on more than 2 % of its
#: frames. A clean capture's paths are read as they are (smoothing moves a contact's first
#: and last frames where the foot slows at the limit)
NOISY = 0.5


@dataclass(frozen=True)
class ContactOptions:
    """Thresholds for contact detection (relative to the character's size where it says so).

    Attributes:
        height: a point within this fraction of the stature above its planted height counts
            as low (0.03 of 1.7 m is 5 cm).
        speed: [statures per second] horizontal speed under which a low point is planted.
        min_duration: [s] shorter contacts are dropped (but for one the clip's first or last
            frame cuts, which may be longer than it shows: it is kept from
            :data:`PART_MIN_FRAMES` frames).
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
    """A detected foot contact: performer ``joint`` (the ankle, and ``toe``) on the ground from
    ``start`` to ``end`` (frames, inclusive), and within it the runs ``(first, last)`` where
    each part is planted: ``heel`` (the ankle) and ``ball`` (the toe joint). A step is heel
    strike (a heel run alone), flat (both), heel-off with the toe pivoting (a ball run alone),
    toe-off. ``heel_off``: per heel run the last frame its heel is down (:func:`_heel_offs`;
    the run's last frame where it stays down; empty: every run's last frame); after it, to
    the run's end, the heel rises while the toe is held."""

    joint: str
    toe: str | None
    start: int
    end: int
    heel: tuple = ()
    ball: tuple = ()
    heel_off: tuple = ()

    def heel_down(self) -> tuple:
        """The last frame the heel is down in each heel run."""
        return self.heel_off or tuple(e for _, e in self.heel)


@dataclass(frozen=True)
class Ground:
    """Where the target's feet stand: the floor and each foot joint's height above it when
    planted.

    Attributes:
        floor: [m] the floor's height (internal +Y up).
        heights: target joint -> [m] its height above the floor when its part is planted (its
            height in the character's rest pose above the rest pose's floor).
        flat: target ankle -> ``(rotation (4,), toe (3,) or None)``: the ankle's world rotation
            with the foot flat (x, y, z, w; the rest pose's) and the vector [m] from the ankle
            to its toe then (``None`` without a toe).
        soles: target ankle -> ``(V, 3)`` [m] its foot's mesh vertices in its own frame,
            for a foot without a toe joint that turns as the performer's (a carried foot,
            which :func:`~engine.conversion.followers.above_floor` turns back towards flat
            where they would go under the floor); empty without a mesh.
    """

    floor: float
    heights: dict
    flat: dict
    soles: dict = field(default_factory=dict)


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


#: frames of forward kinematics at a time for the feet (a bounded working set: the cost stays
#: linear in the clip's length)
FK_CHUNK = 4096


def _foot_poses(skeleton: Skeleton, rotations: np.ndarray, translations: np.ndarray,
                joints) -> tuple[dict, dict]:
    """World positions ``{joint index: (F, 3)}`` [m] and rotations ``{joint index: (F, 4)}``
    of ``joints`` (indices) over a clip's local ``rotations`` and ``translations``, by forward
    kinematics of their chains alone (:func:`~engine.kinematics.fk_joints`) in chunks of
    :data:`FK_CHUNK` frames."""
    joints = sorted(set(joints))
    F = len(rotations)
    pos = {j: np.empty((F, 3)) for j in joints}
    rot = {j: np.empty((F, 4)) for j in joints}
    for lo in range(0, F, FK_CHUNK):
        hi = min(F, lo + FK_CHUNK)
        world_q, world_p = fk_joints(skeleton, rotations[lo:hi], translations[lo:hi], joints)
        for k, j in enumerate(joints):
            pos[j][lo:hi] = world_p[:, k]
            rot[j][lo:hi] = world_q[:, k]
    return pos, rot


def _smoothed(path: np.ndarray, sigma: float) -> np.ndarray:
    """``path (F, 3)`` smoothed along the frames: a running median over ``2 round(sigma) + 1``
    frames (a capture's spike of a frame or two goes, a landing's edge stays where it is),
    then a Gaussian of ``sigma`` frames (the noise averaged); the clip's edges held."""
    if sigma <= 0 or len(path) < 2:
        return path
    from scipy.ndimage import gaussian_filter1d, median_filter
    size = 2 * int(round(sigma)) + 1
    median = median_filter(path, size=(size, 1), mode="nearest")
    return gaussian_filter1d(median, sigma, axis=0, mode="nearest", truncate=3.0)


def _noise(paths: list, size: float) -> float:
    """[m] The noise of a capture's foot paths ``(F, 3)`` per axis and frame: the median
    length of their second differences where each is low (within 1 % of ``size`` of its 5th
    percentile height, where a foot stands still), over sqrt 6 (white noise's ratio)."""
    bends = []
    for p in paths:
        if len(p) < 3:
            continue
        y = p[:, 1]
        low = (y < np.percentile(y, 5.0) + 0.01 * size)[1:-1]
        bends.append(np.linalg.norm(p[2:] - 2.0 * p[1:-1] + p[:-2], axis=1)[low])
    bends = [b for b in bends if len(b)]
    return float(np.median(np.concatenate(bends))) / np.sqrt(6.0) if bends else 0.0


def _judged(pos: dict, size: float, fps: float, options: ContactOptions) -> tuple[float, bool]:
    """The noise [m] of the foot paths ``pos`` (:func:`_noise`) and whether it makes the
    capture noisy (:data:`NOISY`)."""
    noise = _noise([pos[j] for j in pos], size)
    return noise, bool(noise * np.sqrt(2.0) * fps > NOISY * options.speed * size)


def capture_noise(motion: Motion, feet: list[tuple[str, str | None]] | None = None,
                  options: ContactOptions | None = None) -> tuple[float, bool]:
    """[m] The noise of ``motion``'s foot paths (per axis and frame, :func:`_noise`; feet
    ``(ankle, toe)`` found by name when omitted), and whether :func:`detect_contacts` reads
    them as a noisy capture's, smoothed (:data:`NOISY`)."""
    from ..describe import figure_size
    sk = motion.skeleton
    feet = feet if feet is not None else find_feet(sk)
    joints = [sk.index[n] for foot in feet for n in foot if n]
    if not joints or motion.num_frames < 3:
        return 0.0, False
    pos, _ = _foot_poses(sk, motion.rotations, motion.translations, joints)
    return _judged(pos, figure_size(motion), motion.fps, options or ContactOptions())


def estimate_floor(heights: np.ndarray) -> float:
    """The floor under a set of low points ``(F, n)``: the 2nd percentile of the lowest."""
    return float(np.percentile(np.min(heights, axis=1), 2.0))


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1) - 1
    return list(zip(starts.tolist(), ends.tolist()))


def _close_gaps(mask: np.ndarray, gap: int) -> np.ndarray:
    """``mask`` with its inner gaps of at most ``gap`` frames filled."""
    mask = mask.copy()
    for s, e in _runs(~mask):
        if 0 < s and e < len(mask) - 1 and e - s + 1 <= gap:
            mask[s:e + 1] = True
    return mask


def _close_edges(mask: np.ndarray, low: np.ndarray, gap: int) -> np.ndarray:
    """``mask`` with the frames before its first run and after its last filled where they are
    at most ``gap`` frames, all ``low``, and reach the clip's edge. A contact the clip cuts
    may be longer than it shows, and a speed at the edge is one-sided (a plant at the first
    frame reads as sliding into it): a low foot at the edge is taken as planted with the run
    beside it."""
    mask = mask.copy()
    runs = _runs(~mask)
    for s, e in runs[:1] + runs[-1:]:
        if (s == 0 or e == len(mask) - 1) and e - s + 1 <= gap and low[s:e + 1].all() \
                and 0 < len(mask) - (e - s + 1):
            mask[s:e + 1] = True
    return mask


def _part_runs(mask: np.ndarray, start: int, gap: int) -> tuple:
    """The runs ``(first, last)`` of a part's held ``mask`` over a contact from ``start`` (gaps
    closed, runs of :data:`PART_MIN_FRAMES` frames or more)."""
    inner = _close_gaps(mask, gap)
    return tuple((start + a, start + b) for a, b in _runs(inner) if b - a + 1 >= PART_MIN_FRAMES)


def _heel_offs(heel: tuple, ball: tuple, y: np.ndarray, band: float, rise: float) -> tuple:
    """Per heel run the last frame its heel is down: the frame before the run's last frames
    where the heel height ``y`` [m] rises on every frame by more than ``rise`` [m] and by
    ``band`` [m] or more in all, with the ball held on each (heel-off: the heel rises and
    the foot pivots about the toe); else the run's last frame. Held flat to the run's end,
    the foot stayed flat while the performer's heel rose up to ``PART_HEIGHT`` of
    ``ContactOptions.height`` (20 mm in six frames at the CMU jumps' take-off, frames
    1533-1539) and the leg's correction grew until the ramp out eased it off, faster than
    the no-pop rule allows."""
    pivot = np.zeros(len(y), dtype=bool)
    for a, b in ball:
        pivot[a:b + 1] = True
    out = []
    for a, b in heel:
        k = b
        while k > a and y[k] - y[k - 1] > rise and pivot[k]:
            k -= 1
        down = k < b and y[b] - y[k] >= band and k - a + 1 >= PART_MIN_FRAMES
        out.append(k if down else b)
    return tuple(out)


def detect_contacts(motion: Motion, feet: list[tuple[str, str | None]] | None = None,
                    options: ContactOptions | None = None) -> list[Contact]:
    """Contacts of ``motion``'s feet (``(ankle, toe)`` names; found by name when omitted).

    A part (the heel: the ankle joint; the ball: the toe joint) is planted where it is low
    (within ``options.height`` of the stature above its planted height, the 5th percentile of
    its height above the floor) and slow (horizontally under ``options.speed`` statures per
    second). On a noisy capture (:data:`NOISY`) speeds and heights are measured on the path
    smoothed over :data:`SMOOTH` seconds, and a part coming down faster than the speed limit
    is not planted. A foot is on the ground where either part is
    planted, gaps under ``options.max_gap`` closed (and, where the foot is low, the frames
    between a contact and the clip's edge) and contacts under ``options.min_duration``
    dropped unless the clip cuts them; each contact keeps the runs where each part is held:
    slow, and within :data:`PART_HEIGHT` of ``options.height`` above its lowest height in
    the contact, and each heel run's heel-off (:func:`_heel_offs`)."""
    from ..describe import figure_size
    options = options or ContactOptions()
    sk = motion.skeleton
    feet = feet if feet is not None else find_feet(sk)
    if not feet or motion.num_frames < 2:        # a contact lasts two frames or more
        return []
    size = figure_size(motion)
    fps = motion.fps
    points = []
    for ankle, toe in feet:
        idx = [sk.index[ankle]] + ([sk.index[toe]] if toe else [])
        points.append(idx)
    pos, _ = _foot_poses(sk, motion.rotations, motion.translations,
                         [j for idx in points for j in idx])
    low_all = np.stack([pos[j][:, 1] for idx in points for j in idx], axis=1)
    floor = estimate_floor(low_all)
    gap = max(1, int(round(options.max_gap * fps)))
    shortest = max(2, int(round(options.min_duration * fps)))
    # a noisy capture's paths are smoothed: its noise alone would move a still foot
    noisy = _judged(pos, size, fps, options)[1]
    contacts = []
    for (ankle, toe), idx in zip(feet, points):
        parts, heights, slows, lows = [], [], [], []
        for j in idx:
            path = _smoothed(pos[j], SMOOTH * fps) if noisy else pos[j]
            y = path[:, 1] - floor
            rest = np.percentile(y, 5.0)                        # its height when planted
            vel = np.gradient(path[:, [0, 2]], axis=0) * fps
            # on a smoothed path a part still coming down is not planted yet: a jump's
            # landing that swings the foot to and fro reads as slow at the turn
            falling = (np.gradient(y) * fps < -options.speed * size) if noisy else \
                np.zeros(len(y), dtype=bool)
            slow = (np.linalg.norm(vel, axis=1) < options.speed * size) & ~falling
            lows.append(y < rest + options.height * size)
            parts.append(lows[-1] & slow)
            heights.append(y)
            # a part is held while it has not moved off since the frame before
            step = np.zeros(len(y))
            step[1:] = np.linalg.norm(np.diff(path[:, [0, 2]], axis=0), axis=1) * fps
            slows.append((step < options.speed * size) & ~falling)
        planted = _close_edges(_close_gaps(np.logical_or.reduce(parts), gap),
                               np.logical_or.reduce(lows), gap)
        for s, e in _runs(planted):
            # a contact the clip cuts may be longer than it shows: at the clip's edge it is
            # kept as long as it can hold a part
            cut = s == 0 or e == len(planted) - 1
            if e - s + 1 >= (PART_MIN_FRAMES if cut else shortest):
                # within the contact a part is held near its lowest there
                held = [slow[s:e + 1] & (y[s:e + 1] < y[s:e + 1].min() +
                                         PART_HEIGHT * options.height * size)
                        for y, slow in zip(heights, slows)]
                heel = _part_runs(held[0], s, gap)
                ball = _part_runs(held[1], s, gap) if toe else ()
                off = _heel_offs(heel, ball, heights[0], HEEL_OFF * size,
                                 HEEL_RISE * size / fps)
                contacts.append(Contact(ankle, toe, s, e, heel, ball, off))
    contacts.sort(key=lambda c: (c.start, c.joint))
    return contacts


def target_ground(target: Motion, feet: list[tuple[str, str | None]], *,
                  reference: str | int = "auto", floor: float | None = None,
                  sole: float | None = None) -> Ground:
    """The :class:`Ground` of a character from its feet ``(ankle, toe)`` (target joint names).

    The feet stand as in the character's reference pose
    (:func:`~engine.conversion.binding.reference_pose`, as the binding chooses it); where that
    pose is a frame of a clip (a BVH target whose zero pose does not stand), each foot stands
    as on the frame of the clip where it is lowest, and the floor is the clip's (the floor
    under its feet), so that a foot raised on the reference frame is not taken as planted.

    A foot joint's planted height is its height above the floor; the rest floor is the lowest
    point of the feet (``sole`` [m], the lowest mesh vertex of the feet in the reference pose,
    where the character has a mesh; else the lowest foot joint or End Site). The floor is at
    ``floor`` [m] where given, else where the character stands."""
    from ..conversion.binding import reference_pose
    sk = target.skeleton
    rot, tra, label = reference_pose(target, reference)
    if label.startswith("frame"):
        pose = fk_arrays(sk, target.rotations, target.translations, end_sites=True)
    else:
        pose = fk_arrays(sk, rot[None], tra[None], end_sites=True)
    y = pose.positions[..., 1]
    ends = pose.end_positions[..., 1]
    joints, lows = {}, []
    for ankle, toe in feet:
        idx = [sk.index[n] for n in (ankle, toe) if n]
        below = {k for k in range(sk.num_joints) if k in idx or set(sk.ancestors(k)) & set(idx)}
        sites = [k for k, site in enumerate(sk.end_sites) if site.parent in below]
        joints[ankle] = idx
        lows.append(np.concatenate([y[:, idx], ends[:, sites]], axis=1).min(axis=1))
    if not lows:
        return Ground(0.0 if floor is None else float(floor), {}, {})
    # each foot as on the frame where it is lowest; the floor under the lowest of them
    chosen = [int(np.argmin(y[:, joints[ankle]].sum(axis=1))) for ankle, _ in feet]
    lowest = min(float(low[f]) for low, f in zip(lows, chosen))
    rest_floor = lowest if sole is None else min(float(sole), lowest)
    heights, flat = {}, {}
    for (ankle, toe), f in zip(feet, chosen):
        for j in joints[ankle] + below_foot(sk, ankle, toe):
            heights[sk.names[j]] = float(y[f, j]) - rest_floor
        a = sk.index[ankle]
        if toe or ankle not in flat:        # a foot's own toe, not lost to a toeless map
            flat[ankle] = (pose.rotations[f, a], pose.positions[f, sk.index[toe]] -
                           pose.positions[f, a] if toe else None)
    return Ground(rest_floor if floor is None else float(floor), heights, flat)


def below_foot(skeleton: Skeleton, ankle: str, toe: str | None,
               carried=frozenset()) -> list[int]:
    """The joints below a foot other than its ``ankle`` and ``toe`` (indices): a toe's end
    joint (Mixamo's ``*Toe_End``), separate toes (CC3's five per foot). They are foot joints
    too: a plant that holds the ankle and the toe joint can still bend the toe's tip into the
    floor, so the floor rule holds each of them at or above its own rest height. Joints that
    hang from one of the ``carried`` joints (names of control joints carried with a limb,
    such as the robot's feet) are left out: they are placed after the IK, which cannot move
    them (a leaf bone Blender's FBX exporter adds under such a foot)."""
    a = skeleton.index[ankle]
    held = {a} | ({skeleton.index[toe]} if toe else set())
    return [k for k in range(skeleton.num_joints)
            if k not in held and a in skeleton.ancestors(k)
            and not any(skeleton.names[p] in carried for p in skeleton.ancestors(k))]


def converted_ground(composed: Motion, feet: list[tuple[str, str | None]], *,
                     floor: float | None = None) -> Ground:
    """A :class:`Ground` from the direct conversion alone, for a caller without the character's
    rest pose: each foot flat as on the frame where it is lowest, on the floor under the lowest
    of them (or on ``floor``)."""
    sk = composed.skeleton
    pos, wrot = _foot_poses(sk, composed.rotations, composed.translations,
                            [sk.index[n] for foot in feet for n in foot if n])
    chosen = []
    for ankle, toe in feet:
        idx = [sk.index[n] for n in (ankle, toe) if n]
        chosen.append((idx, int(np.argmin(sum(pos[j][:, 1] for j in idx)))))
    ground = min(min(float(pos[j][f, 1]) for j in idx) for idx, f in chosen)
    heights, flat = {}, {}
    for (ankle, toe), (idx, f) in zip(feet, chosen):
        for j in idx:
            heights[sk.names[j]] = float(pos[j][f, 1]) - ground
        a = sk.index[ankle]
        flat[ankle] = (wrot[a][f], pos[sk.index[toe]][f] - pos[a][f] if toe else None)
    return Ground(ground if floor is None else float(floor), heights, flat)


@dataclass(frozen=True)
class _FlatFeet:
    """Where one contact holds its foot: ``ankles`` (the goal of each heel run), ``toes`` (of
    each ball run) and ``turns`` (the ankle's world rotation on each flat ``(first, last)``:
    the frames where heel and ball are both held)."""

    ankles: list
    toes: list
    turns: dict


def _flat_turn(rot: np.ndarray, rest_turn: np.ndarray, rest_toe: np.ndarray):
    """The foot held flat over frames whose converted ankle world rotations are ``rot (n, 4)``:
    their mean, pitched about a horizontal axis (the smallest turn) so that the toe stands as
    high above the ankle as in the rest pose (``rest_turn``, ``rest_toe``: the rest pose's
    ankle rotation and ankle-to-toe vector). The converted foot's heading and roll are kept,
    so that a foot the performer turns out or rolls stays so; only what the character's other
    ankle height needs changes. Returns the rotation and its ankle-to-toe vector."""
    q = rot * np.where(rot @ rot[len(rot) // 2] < 0.0, -1.0, 1.0)[:, None]
    mean = q.sum(axis=0)
    mean /= np.linalg.norm(mean)
    toe = qrot(qmul(mean, qconj(rest_turn)), rest_toe)
    length = float(np.linalg.norm(toe))
    flat = np.hypot(toe[0], toe[2])
    if flat < 1e-9 * max(length, 1e-12):
        return mean, toe                            # a foot along the vertical: no heading
    rise = float(np.clip(rest_toe[1] / max(length, 1e-12), -1.0, 1.0))
    goal = np.array([toe[0] / flat * np.sqrt(1.0 - rise * rise) * length, rise * length,
                     toe[2] / flat * np.sqrt(1.0 - rise * rise) * length])
    pitch = quat_between(toe, goal)
    return qmul(pitch, mean), goal


def _flat_feet(heel_runs, ball_runs, rot, ankle, toe, rest_turn, rest_toe,
               heights) -> _FlatFeet:
    """The goals of one contact's heel and ball runs (see :class:`_FlatFeet`), from the
    converted ankle's world rotations ``rot (F, 4)``, the converted ankle and toe positions
    ``(F, 3)`` and the planted ``heights`` (ankle, toe) [m].

    Each flat holds the foot as :func:`_flat_turn` turns it there. The runs are placed in
    time order: a part that comes down while the other is held is placed from it through
    the flat foot (a heel strike puts the toe, a toe that holds while the heel lifts and
    the foot pivots puts the heel where it comes down again, turned as the foot then is);
    a part that comes down alone is placed at its converted median, at its planted height.
    """
    flats = sorted({(max(bs, hs), min(be, he)) for bs, be in ball_runs for hs, he in heel_runs
                    if hs <= be and bs <= he})
    turns, reach = {}, {}
    for fs, fe in flats:
        turns[(fs, fe)], reach[(fs, fe)] = _flat_turn(rot[fs:fe + 1], rest_turn, rest_toe)
    ankles, toes = [None] * len(heel_runs), [None] * len(ball_runs)
    order = sorted([(s, 0, i) for i, (s, _) in enumerate(heel_runs)] +
                   [(s, 1, k) for k, (s, _) in enumerate(ball_runs)])
    for _, part, n in order:
        s, e = (heel_runs if part == 0 else ball_runs)[n]
        other, placed = (ball_runs, toes) if part == 0 else (heel_runs, ankles)
        # the other part held since before (or, for a toe, since as) this one comes down
        held = [m for m, (os_, oe) in enumerate(other) if placed[m] is not None and
                os_ <= s <= oe and (os_ < s or part == 1)]
        if held:
            m = held[-1]
            first = (max(s, other[m][0]), min(e, other[m][1]))
            offset = reach[first] if part == 1 else -reach[first]
            goal = placed[m] + offset
        else:
            goal = np.median((ankle if part == 0 else toe)[s:e + 1], axis=0)
        goal = np.array(goal, dtype=float)
        goal[1] = heights[part]
        (ankles if part == 0 else toes)[n] = goal
    return _FlatFeet(ankles, toes, turns)


def _pivot(heel: np.ndarray, toes: list, ball: tuple, ankle: np.ndarray, toe: np.ndarray,
           s: int, off: int, e: int) -> np.ndarray:
    """The path ``(e - s + 1, 3)`` of a heel run ``s .. e`` down at ``heel`` (its goal) to
    ``off`` (heel-off) and then turning about the held toe (``toes``: the goals of the ball
    runs ``ball``) as the converted foot turns since ``off`` (the smallest turn of its
    ankle-to-toe vector; ``ankle``, ``toe`` the converted positions ``(F, 3)``), never under
    the planted height. The foot keeps its length, so the held toe and the heel's path agree,
    the heel rises as the performer's does, and it drifts as the performer's heel drifts
    about its toe."""
    path = np.tile(np.asarray(heel, dtype=float), (e - s + 1, 1))
    frames = np.arange(off + 1, e + 1)
    foot = ankle[frames] - toe[frames]
    turn = quat_between(np.broadcast_to(ankle[off] - toe[off], foot.shape), foot)
    for k, (bs, be) in enumerate(ball):
        here = (frames >= bs) & (frames <= be)
        if here.any():
            lever = np.broadcast_to(heel - toes[k], (int(here.sum()), 3))
            path[frames[here] - s] = toes[k] + qrot(turn[here], lever)
    path[:, 1] = np.maximum(path[:, 1], heel[1])
    return path


def _drift(points: np.ndarray) -> float:
    """The largest horizontal distance of ``points (n, 3)`` from the first."""
    return float(np.linalg.norm(points[:, [0, 2]] - points[0, [0, 2]], axis=1).max())


def _spans(runs: list[tuple[str, int, int]], ramp: int, F: int) -> list[tuple[int, int]]:
    """``(smooth_in, smooth_out)`` of each run ``(joint, start, end)``: at most ``ramp`` frames
    either side, and never over the next run of the same joint (they meet halfway)."""
    spans = [[max(0, s - ramp), min(F - 1, e + ramp)] for _, s, e in runs]
    previous: dict[str, int] = {}
    for i in sorted(range(len(runs)), key=lambda k: runs[k][1]):
        joint, s, _ = runs[i]
        if joint in previous:
            k = previous[joint]
            end = runs[k][2]
            half = max(0, (s - end - 1) // 2)
            spans[i][0] = max(spans[i][0], s - half)
            spans[k][1] = min(spans[k][1], end + half)
        previous[joint] = i
    return [tuple(x) for x in spans]


def _back_to_back(ranges: list[tuple[int, int, int, int, int]]) -> list[int]:
    """Each hold's last frame: its ``end``, or where another contact's hold eases in just
    after the foot is let go, the frame before that one's key frame (back to back with it).

    ``ranges``: per hold ``(contact, smooth_in, start, end, smooth_out)``, ``contact`` a
    number per foot contact. The holds a contact lets go last (``end``, with a ramp out)
    in the half of another contact's ramp in next to its key frame (``start``), one frame
    or more before it, are held on to the frame before the key, where their own ramps out
    still have two frames or more after that: a walk at 120 frames a second, its left toe
    let go on frame 495 and its right heel planted on 497. Holding the toe on 496 is what
    the feet of a walk do, both down until the other has landed; and the enforcement eases
    such holds well only back to back. A key posture holds the goals held on the frame
    next to it inside its ramps (enforcement._virtual_frames), so that the ramp's
    correction is what it adds to them: the heel's key posture on 497 did not hold the toe,
    its correction dragged the toe, held to 495, and pass two pulling the toe back lifted
    the heel 70 mm off its goal until the key frame, where it came down in one frame (the
    hips turned 1.85 times the no-pop limit). Holding such goals in the key postures
    instead was tried: the frame between, which holds neither, then added two corrections
    each made with the other's goal held, and threw the toe 145 mm off. A hold the foot
    lets go before its last (the flat foot's orientation at heel-off, while the toe holds
    on) is not held longer."""
    last: dict[int, int] = {}
    for contact, _, _, e, _ in ranges:
        last[contact] = max(last.get(contact, e), e)
    keys = sorted((s, (lo + s + 1) // 2, contact) for contact, lo, s, _, _ in ranges
                  if s - lo >= 2)
    frames = [k for k, _, _ in keys]
    out = []
    for contact, _, _, e, hi in ranges:
        end = e
        if e == last[contact] and hi - e >= 2:
            # the key frames k with e + 1 < k <= hi - 1, earliest first (a few per hold: the
            # whole is linear in the clip)
            for k, mid, other in keys[bisect.bisect_right(frames, e + 1):
                                      bisect.bisect_right(frames, hi - 1)]:
                if other != contact and mid <= e:
                    end = k - 1
                    break
        out.append(end)
    return out


def contact_constraints(contacts: list[Contact], performer: Motion, composed: Motion,
                        pairs: dict[str, str], options: ContactOptions | None = None, *,
                        floor: float | None = None, ground: Ground | None = None,
                        priority: int = 1, carried=frozenset()) -> list[Constraint]:
    """Constraints that hold the target's feet during the performer's ``contacts``.

    ``pairs``: target joint -> performer joint (the correspondence). The foot is held whole
    while flat and by its toe while it pivots:

    * each flat (a heel run to its heel-off and a ball run overlapping) holds the ankle's
      world orientation: the converted foot's mean orientation over the flat, pitched so that
      the toe stands as high above the ankle as in the rest pose (the converted heading and
      roll kept: a foot turned out, or turned between two flats of one contact as it
      pivots, stays so);
    * a heel run pins the target ankle at its planted height above the floor, to heel-off
      (:attr:`Contact.heel_off`), and from there to the run's end holds it on the path the
      pivot about the held toe gives it (:func:`_pivot`: the heel rises as the converted
      foot pitches, and the flat's orientation is let go); a ball run pins the target toe at
      its planted height. A part that comes down while the other is held
      is placed from it through the flat foot's orientation (a heel strike places the toe
      where the flat foot puts it, and it stays there while the heel rises; a heel that comes
      down again about a held toe lands where the foot's new heading puts it); a part that
      comes down alone is held at its converted median position. Where the target has no
      mapped toe the ankle is pinned over the whole contact and its world orientation is
      held too (the converted orientation at the contact's middle frame);
    * a foot let go a few frames before another lands (in the half of the other's ramp in
      next to its key frame) is held on until the frame before it (:func:`_back_to_back`);
    * on every frame each held foot joint stays at or above its planted height (a one-sided
      plane: the floor rule), and so does each joint below a held foot whose height the
      ``ground`` gives (:func:`below_foot`: a toe's end joint, separate toes).

    ``ground``: where the feet stand (:func:`target_ground`); by default the direct
    conversion's own (:func:`converted_ground`, on ``floor`` where given). ``carried``: the
    target ankles that are control joints carried with a limb
    (:mod:`engine.conversion.followers`, the robot's ``FootL`` past its shin): they are
    pinned through the limb, and turn as the performer's ankle (flat where it is), so no
    orientation is held on them.
    """
    options = options or ContactOptions()
    by_performer = {p: t for t, p in pairs.items()}
    sk = composed.skeleton
    F = composed.num_frames
    ramp = max(1, int(round(options.ramp * composed.fps)))
    used = [c for c in contacts if c.joint in by_performer]
    if not used:
        return []
    feet_t = sorted({(by_performer[c.joint], by_performer.get(c.toe) if c.toe else None)
                     for c in used}, key=lambda f: f[0])
    t_pos, t_rot = _foot_poses(sk, composed.rotations, composed.translations,
                               [sk.index[n] for foot in feet_t for n in foot if n])
    if ground is None:
        ground = converted_ground(composed, feet_t, floor=floor)
    # the character's size, for a carried foot's heel (below)
    from ..describe import figure_size
    size = figure_size(composed) if carried else None
    # the performer's heels and both sizes, to judge a heel's pivot (below)
    p_sk = performer.skeleton
    pivoting = sorted({p_sk.index[c.joint] for c in used
                       if any(off < e for off, (_, e) in zip(c.heel_down(), c.heel))})
    p_heel = {} if not pivoting else {
        p_sk.names[j]: v for j, v in _foot_poses(p_sk, performer.rotations,
                                                 performer.translations, pivoting)[0].items()}
    p_size, t_size = (figure_size(performer), figure_size(composed)) if pivoting else (1, 1)
    # (target joint, what, start, end, smooth_in, part, contact, goal, priority below)
    runs = []
    for c in used:
        ankle = by_performer[c.joint]
        toe = by_performer.get(c.toe) if c.toe else None
        a = sk.index[ankle]
        frames = slice(c.start, c.end + 1)
        if toe is None and c.toe and ankle in carried:
            # a carried foot without a toe, its contact found from the performer's heel and
            # toe: its ankle stays where it planted through the whole contact, on the floor
            # while the heel is down and rising as the converted one rises through heel-off
            # (held down there, a foot that pitches with the performer's drove its toe into
            # the floor); a path, one point per frame
            # (a contact on the ball alone, the heel never down, keeps the converted height,
            # at least its median over the contact: on tiptoe the foot pitches, and held at
            # its flat height its toe went 0.6 m into the floor)
            y = t_pos[a][frames, 1]
            flat = ground.floor + ground.heights[ankle]
            # the heel is down where the performer's is held and the converted one is low
            # (a heel held on tiptoe is not)
            down = [f for s, e in c.heel for f in range(s, e + 1)
                    if y[f - c.start] < flat + options.height * size]
            path = np.tile(np.median(t_pos[a][down or frames], axis=0),
                           (c.end - c.start + 1, 1))
            path[:, 1] = (flat + np.maximum(y - y[np.array(down) - c.start].min(), 0.0)
                          if down else np.maximum(y, np.median(y)))
            runs.append((ankle, "path", c.start, c.end, None, "heel", c, path, 0))
            continue
        if toe is None:
            # without a toe the ankle holds the whole contact, its orientation too: the
            # converted foot's over the contact, flat (pitched so that the character's own
            # toe stands as high above the ankle as in its rest pose) where the character
            # has a toe the performer has not; else as converted at the contact's middle
            goal = np.median(t_pos[a][frames], axis=0)
            goal[1] = ground.floor + ground.heights[ankle]
            rest_turn, rest_toe = ground.flat.get(ankle, (None, None))
            turn = (t_rot[a][(c.start + c.end) // 2] if rest_toe is None else
                    _flat_turn(t_rot[a][frames], rest_turn, rest_toe)[0])
            runs.append((ankle, "pin", c.start, c.end, None, "heel", c, goal, 0))
            if ankle not in carried:
                runs.append((ankle, "turn", c.start, c.end, None, None, c, turn, 1))
            continue
        rest_turn, rest_toe = ground.flat[ankle]
        # a heel that comes down within a ramp after the toe is taken as down with it: the
        # flat foot is held from the toe's landing on
        heel_runs = [(min(hs, next((bs for bs, be in c.ball if 0 < hs - bs < ramp and
                                    hs <= be), hs)), he) for hs, he in c.heel]
        # the foot is flat while the heel is down, to heel-off, and then turns about the
        # toe (_pivot) where the heel then moves no further from where it was at heel-off
        # than the performer's does from its own, as fractions of each one's size (the
        # ankle swings along as the foot turns about the toe, the more the higher it stands
        # over it: the glTF fox's, a digitigrade's, far more than a human's); elsewhere the
        # heel is held down to the run's end, the foot flat (while the performer's heel
        # rises a little, as before heel-off was told apart)
        down = list(c.heel_down())
        pivots: dict[int, np.ndarray] = {}
        while True:
            flat_runs = [(hs, min(he, off)) for (hs, he), off in zip(heel_runs, down)]
            feet = _flat_feet(flat_runs, c.ball, t_rot[a], t_pos[a], t_pos[sk.index[toe]],
                              rest_turn, rest_toe, (ground.floor + ground.heights[ankle],
                                                    ground.floor + ground.heights[toe]))
            pivots.clear()
            held = False                # a heel held to its run's end: its flat changes
            for i, (s, e) in enumerate(heel_runs):
                if down[i] < e:
                    path = _pivot(feet.ankles[i], feet.toes, c.ball, t_pos[a],
                                  t_pos[sk.index[toe]], s, down[i], e)
                    tail = slice(down[i], e + 1)
                    if _drift(path[tail.start - s:]) * p_size <= \
                            _drift(p_heel[c.joint][tail]) * t_size:
                        pivots[i] = path
                    else:
                        down[i], held = e, True
            if not held:
                break
        toe_first = False
        pins = []
        for k, (s, e) in enumerate(c.ball):
            flats = [(max(s, hs), min(e, he)) for hs, he in flat_runs if hs <= e and s <= he]
            for flat in flats if ankle not in carried else ():
                runs.append((ankle, "turn", flat[0], flat[1], None, None, c,
                             feet.turns[flat], 1))
            first = flats[0][0] if flats else None
            if first is not None and first - s >= ramp:
                # the toe lands first: it is held from then on, and the heel comes down
                # about it (the heel's pin one level lower, so that it yields while it eases
                # in)
                toe_first = True
                first = None
            # else from the flat foot on, the toe is where the flat foot puts it: held from
            # there, it needs no ramp in (a ramp in would pull it against the flat foot's)
            pins.append((toe, "pin", s if first is None else first, e, first, "toe", c,
                         feet.toes[k], 0))
        for i, (s, e) in enumerate(heel_runs):
            # a heel coming down after the toe took off eases in once the toe is let go
            # (easing in against the held toe would pull the foot apart)
            after = max((be for bs, be in c.ball if be < s), default=None)
            if any(bs < s <= be for bs, be in c.ball):
                # a heel coming down while the toe is held needs no ramp in: the flat foot's
                # turn easing in brings it down about the toe, onto its goal at ``s`` (a
                # straight ramp would pull the ankle off the circle the held toe allows)
                after = s
            goal = pivots.get(i, feet.ankles[i])
            runs.append((ankle, "pin", s, e, after, "heel", c, goal, int(toe_first)))
        runs += pins
    spans = _spans([(r[0] + r[1], r[2], r[3]) for r in runs], ramp, F)
    spans = [(lo if r[4] is None else min(max(lo, r[4]), r[2]), hi)
             for r, (lo, hi) in zip(runs, spans)]
    ends = _back_to_back([(id(r[6]), lo, r[2], r[3], hi) for r, (lo, hi) in zip(runs, spans)])
    out = []
    # names are labels (the user may rename them): the joint and the hold's number along the
    # clip, never its frames, which go stale when a handle moves
    number: dict[tuple, int] = {}
    for (joint, _, s, e, first, part, c, goal, below), (lo, hi), end in zip(runs, spans, ends):
        label = ("contact" if part is not None else "foot flat", joint)
        number[label] = number.get(label, 0) + 1
        if end > e and goal.ndim == 2:                  # a path: held at its last point
            goal = np.concatenate([goal, np.repeat(goal[-1:], end - e, axis=0)])
        e = end
        performer_joint = c.toe if part == "toe" else c.joint
        if part is not None:
            # a pin on a point, or a carried foot's path (a point per frame)
            kind, held = (("trajectory", {"points": goal}) if goal.ndim == 2 else
                          ("position", {"point": goal}))
            out.append(Constraint(joint=joint, kind=kind, goal=held,
                                  smooth_in=lo, start=s, end=e, smooth_out=hi,
                                  priority=priority + below, name=f"contact {joint} #{number[label]}",
                                  auto=True,
                                  meta={"source": "contact", "part": part,
                                        "performer_joint": performer_joint}))
        else:
            # one level lower: while it eases in or out it yields to the pins and the floor
            out.append(Constraint(joint=joint, kind="orientation", goal={"quaternion": goal},
                                  smooth_in=lo, start=s, end=e, smooth_out=hi,
                                  priority=priority + below, name=f"foot flat {joint} #{number[label]}",
                                  auto=True, meta={"source": "contact",
                                                   "performer_joint": performer_joint}))
    # the floor rule: each held foot joint at or above its planted height over the floor,
    # on every frame (one-sided: it acts only where the joint would go lower); so are the
    # joints below a held foot that the ground knows (a toe's end joint, separate toes),
    # which follow the ankle and toe's performer joints
    held = {r[0] for r in runs if r[5] is not None}
    floors = {joint: pairs[joint] for joint in held}
    for ankle, toe in feet_t:
        if ankle in held:
            for k in below_foot(sk, ankle, toe, carried):
                name = sk.names[k]
                if name in ground.heights and name not in floors:
                    floors[name] = pairs.get(name) or pairs[toe if toe in held else ankle]
    for joint in sorted(floors):
        height = ground.floor + ground.heights[joint]
        out.append(Constraint(joint=joint, kind="plane",
                              goal={"point": [0.0, height, 0.0], "normal": [0, 1, 0],
                                    "side": "above"},
                              smooth_in=0, start=0, end=F - 1, smooth_out=F - 1,
                              priority=priority, name=f"floor {joint}", auto=True,
                              meta={"source": "contact", "floor": True,
                                    "performer_joint": floors[joint]}))
    out.sort(key=lambda k: ("floor" in k.meta, k.start, k.name))
    return out


def held_until(constraint: Constraint) -> int:
    """The last frame a contact's pin holds its joint in place horizontally: its ``end``, but
    for a heel that pivots about its toe (a path whose points leave their first one at
    heel-off: :func:`_pivot`) the frame of heel-off. Its drift is measured to there: after
    it the heel moves as the foot turns, by design."""
    points = constraint.goal.get("points")
    if points is None:                                  # a pin on a point
        return constraint.end
    p = np.asarray(points)[:, [0, 2]]
    moved = np.flatnonzero(np.any(p != p[0], axis=1))
    return constraint.start + (int(moved[0]) - 1 if len(moved) else len(p) - 1)


def horizontal_drift(motion: Motion, joint: str, start: int, end: int) -> float:
    """[m] How far ``joint`` wanders horizontally from frame ``start`` to ``end``: the largest
    distance from its position at ``start``."""
    sk = motion.skeleton
    pose = fk_arrays(sk, motion.rotations[start:end + 1], motion.translations[start:end + 1],
                     end_sites=False)
    return _drift(pose.positions[:, sk.index[joint]])
