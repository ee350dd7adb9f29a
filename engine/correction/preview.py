"""What a change of constraints can reach, so that a live preview solves only those frames.

A drag of a time handle or a goal changes one constraint; the frames whose solution can differ
are the *window* ``[lo, hi]`` covering the changed constraints' old and new ``[smooth_in,
smooth_out]`` (a drag of one side's handles reaches that side only, :func:`affected_frames`).
:func:`window_problem` cuts the constraint set down to what decides the window's frames: the
constraints overlapping it, plus those active at the pass-one key postures that its ramps take
(a ramp in the window eases in the correction its constraints make at its ``start``, or out
the one at its ``end``, section 3.3; the posture without them there starts from the frame
next to the key inside the ramp), each with its active range clipped to the frames ``[L,
H]`` spanning the window and those keys. Every frame of the window then sees the same
tasks and the same key postures as in the full solve, so the window is the full solve's (to
the solver's tolerance; a test checks it); :func:`splice` puts its frames into the motion shown
before the change.
"""
from __future__ import annotations

import dataclasses
import weakref

import numpy as np

__all__ = ["changed_window", "affected_frames", "overlapping", "window_problem", "retimed",
           "splice", "WindowSolver"]


def _same_but_range(a, b) -> bool:
    """``a`` and ``b`` differ at most in their time range."""
    if (a.joint, a.kind, a.priority, a.weight, a.enabled) != \
            (b.joint, b.kind, b.priority, b.weight, b.enabled) or a.goal.keys() != b.goal.keys():
        return False
    for key, value in a.goal.items():
        other = b.goal[key]
        if isinstance(value, np.ndarray) or isinstance(other, np.ndarray):
            if not np.array_equal(np.asarray(value), np.asarray(other)):
                return False
        elif value != other:
            return False
    return True


def affected_frames(old, new) -> tuple[int, int]:
    """The frames whose solution can differ between two versions of one constraint.

    A change of the time range only (a handle drag) reaches the side that moved: moving
    ``smooth_in`` or ``start`` changes ``[min smooth_in, max start]`` (the input ramp and the
    frames entering or leaving the active range); the active frames beyond keep the same goal
    and the output ramp the same key postures. Likewise on the ``end`` side. Any other change
    reaches the whole of both ``[smooth_in, smooth_out]``."""
    if not _same_but_range(old, new):
        return min(old.smooth_in, new.smooth_in), max(old.smooth_out, new.smooth_out)
    spans = []
    if (old.smooth_in, old.start) != (new.smooth_in, new.start):
        spans.append((min(old.smooth_in, new.smooth_in), max(old.start, new.start)))
    if (old.end, old.smooth_out) != (new.end, new.smooth_out):
        spans.append((min(old.end, new.end), max(old.smooth_out, new.smooth_out)))
    if not spans:
        return new.start, new.start
    return min(s[0] for s in spans), max(s[1] for s in spans)


def changed_window(before: list, after: list) -> tuple[int, int] | None:
    """Frames ``(lo, hi)`` covering what can change between two constraint lists of the same
    length (compared by identity: constraints are immutable, an edit makes a new one; see
    :func:`affected_frames`). ``None`` when nothing differs or the lengths differ (a
    constraint added or removed: solve everything)."""
    if len(before) != len(after):
        return None
    lo, hi = None, None
    for old, new in zip(before, after):
        if old is new:
            continue
        a, b = affected_frames(old, new)
        lo = a if lo is None else min(lo, a)
        hi = b if hi is None else max(hi, b)
    return None if lo is None else (lo, hi)


def overlapping(constraints: list, lo: int, hi: int) -> list:
    """The enabled constraints whose ``[smooth_in, smooth_out]`` meets ``[lo, hi]``."""
    return [c for c in constraints if c.enabled and c.smooth_in <= hi and c.smooth_out >= lo]


def retimed(c, rng: tuple, shift: int | None = None):
    """``c`` over the range ``rng`` (smooth_in, start, end, smooth_out). A trajectory given
    per frame becomes keys at the same frames (its length is tied to the old range);
    ``shift`` (a whole-range move) moves a trajectory's keys along."""
    goal = c.kind_object.retimed_goal(c, shift)
    return dataclasses.replace(c, goal=goal, smooth_in=int(rng[0]), start=int(rng[1]),
                               end=int(rng[2]), smooth_out=int(rng[3]))


def window_problem(constraints: list, lo: int, hi: int) -> list:
    """The constraints that decide frames ``lo..hi``, cut to the frames that matter.

    * every enabled constraint overlapping ``[lo, hi]``, widened to the key frame and the
      frame next to it of each ramp easing frames of the window (pass two's repair is eased
      from those: :func:`~engine.correction.enforcement._ease_repairs`);
    * the key frames its ramps need from pass one, where a ramp eases frames of the window
      (:mod:`~engine.correction.enforcement`: a ramp adds the correction its constraints
      make at its key frame, ``start`` of an input ramp, ``end`` of an output one), and the
      frame next to each inside the ramp (``start - 1``, ``end + 1``), whose correction the
      key posture without the ramp's constraints starts from; ``[L, H]`` spans the window
      and those frames;
    * every other enabled constraint active at one of those frames (it shapes that key
      posture, or the one it starts from), with its ramp if that is keyed on the same key
      frame and side (the ramps keyed on one frame are taken off it in turn);
    * each constraint's active range clipped to ``[L, H]``, dropping a ramp that lies wholly
      outside (a clipped end has no ramp: what lies beyond does not reach the window).

    A constraint that only shapes a key posture may be left one frame long with no ramps (a
    pin at the key): solve the problem with ``enforce(..., pins=True)``.
    """
    return [c if rng == c.range else retimed(c, rng)
            for c, rng in _window_ranges(constraints, lo, hi)]


def _ramp_keys(inside: list, lo: int, hi: int) -> tuple[set, set, set]:
    """The ramps of ``inside`` whose eased frames meet ``[lo, hi]`` (a ramp of fewer than two
    frames eases nothing, enforcement._ramp_units): their key frames by side (``start`` of
    the input ramps, ``end`` of the output ones), and those with the frames next to them
    inside the ramps, whose corrections the key postures start from."""
    rising, falling, keys = set(), set(), set()
    for c in inside:
        if c.start - c.smooth_in >= 2 and c.smooth_in + 1 <= hi and c.start - 1 >= lo:
            rising.add(c.start)
            keys.update((c.start - 1, c.start))
        if c.smooth_out - c.end >= 2 and c.end + 1 <= hi and c.smooth_out - 1 >= lo:
            falling.add(c.end)
            keys.update((c.end, c.end + 1))
    return rising, falling, keys


def _window_ranges(constraints: list, lo: int, hi: int) -> list:
    """:func:`window_problem`'s constraints, each as ``(constraint, its range in the
    problem)``."""
    # pass two's repairs are eased over the ramps from the key frame and the frame next to it
    # (enforcement._ease_repairs, over every ramp keyed on either: with ramps back to back,
    # each takes half), so the window first takes in those frames of its ramps: they are then
    # solved as the window is, with every constraint and ramp that reaches them
    _, _, keys = _ramp_keys(overlapping(constraints, lo, hi), lo, hi)
    lo, hi = min([lo, *keys]), max([hi, *keys])
    inside = overlapping(constraints, lo, hi)
    rising, falling, keys = _ramp_keys(inside, lo, hi)
    outside_keys = sorted(k for k in keys if not lo <= k <= hi)
    L, H = min([lo, *keys]), max([hi, *keys])
    chosen = list(inside)
    for c in constraints:
        if c.enabled and c not in chosen and any(c.start <= k <= c.end for k in outside_keys):
            chosen.append(c)
    out = []
    for c in constraints:                       # the document's order
        if not any(c is x for x in chosen):
            continue
        si, st, en, so = c.range
        if c not in inside:
            # only its active frames at the keys, and a ramp keyed on a key frame on the
            # same side: ramps keyed on one frame are taken off its posture in turn, the
            # shortest first (enforcement._virtual_frames), so it decides the posture the
            # window's ramp starts from
            if st not in rising:
                si = st
            if en not in falling:
                so = en
        if st < L:
            si = st = min(L, en)
        if en > H:
            en = so = max(H, st)
        out.append((c, (si, st, en, so)))
    return out


def splice(base, part, lo: int, hi: int, first: int = 0):
    """``base`` with frames ``lo..hi`` taken from ``part`` (same skeleton), whose frame 0 is
    ``base``'s frame ``first`` (0: the same length)."""
    from ..motion import Motion
    rot = np.array(base.rotations)
    tra = np.array(base.translations)
    rot[lo:hi + 1] = part.rotations[lo - first:hi + 1 - first]
    tra[lo:hi + 1] = part.translations[lo - first:hi + 1 - first]
    # both motions' frames, checked when they were made: no second check of the whole clip
    return Motion._trusted(base.skeleton, rot, tra, base.frame_time, base.name)


def _span(ranges: list, lo: int, hi: int) -> tuple[int, int]:
    """The frames ``[L, H]`` a window problem reaches: the window and its constraints'
    ``[smooth_in, smooth_out]`` (``ranges``: :func:`_window_ranges`)."""
    return (min([lo] + [rng[0] for _, rng in ranges]),
            max([hi] + [rng[3] for _, rng in ranges]))


class WindowSolver:
    """Window previews of one composed motion with one set of solver settings.

    A window problem (:func:`window_problem`) holds no constraint outside its frames ``[L,
    H]``, and every frame is solved on its own (the batch solve), so it is solved on those
    frames alone, cut from the clip and shifted to start at 0, instead of on whole-clip
    arrays: what :func:`~engine.correction.enforcement.enforce` would take from the whole clip
    is worked out once here and passed in, the settings' ``scale`` (the composed motion's
    stature) and the joints the composed motion holds still. The frames ``[L, H]`` then get
    the same tasks, key postures and attraction postures as in a solve of the whole clip.

    The solver refers to the composed motion weakly: one kept for the next drag does not keep
    a replaced conversion (a whole clip's arrays) alive."""

    def __init__(self, composed, options=None, carried=None):
        from ..describe import figure_size
        from .enforcement import _still_joints
        from .ik import IKOptions
        self._composed = weakref.ref(composed)
        self.given_options = options
        options = options if options is not None else IKOptions()
        if options.scale is None:
            options = dataclasses.replace(options, scale=figure_size(composed))
        self.options = options
        self.still = _still_joints(composed)
        #: the control joints carried with limbs (:func:`~.enforcement.enforce`'s)
        self.carried = carried

    def serves(self, composed, options) -> bool:
        """Whether this solver is the one for ``composed`` (by identity) and ``options``."""
        return composed is self._composed() and options == self.given_options

    def solve(self, constraints: list, lo: int, hi: int):
        """``(part, first)``: the solution of the window problem of ``constraints`` for frames
        ``lo..hi``, a motion whose frame 0 is the clip's frame ``first``."""
        from ..motion import Motion
        from .enforcement import enforce
        from .glitches import held_glitches
        ranges = _window_ranges(constraints, lo, hi)
        first, last = _span(ranges, lo, hi)
        # window_problem's constraints shifted by -first (one retimed copy each)
        shifted = []
        for c, rng in ranges:
            rng = tuple(x - first for x in rng)
            shifted.append(c if rng == c.range else retimed(c, rng, shift=-first or None))
        composed = self._composed()
        if composed is None:
            raise ValueError("the composed motion of this WindowSolver is gone")
        # the whole clip's one-frame glitches under its held goals, as a solve of it finds
        # them (the window's clipped ranges and cut edges would judge frames without the
        # frames around them), those inside the cut with a frame either side
        glitches = held_glitches(composed, constraints, self.options.scale) - first
        glitches = glitches[(glitches >= 1) & (glitches <= last - first - 1)]
        cut = Motion._trusted(composed.skeleton, composed.rotations[first:last + 1],
                              composed.translations[first:last + 1], composed.frame_time,
                              composed.name)
        # frames lo..hi alone are spliced: the rest of [first, last] is solved only where
        # they depend on it (the ramps' key postures)
        part = enforce(cut, shifted, options=self.options, pins=True, still=self.still,
                       frames=(lo - first, hi - first), carried=self.carried,
                       glitches=glitches).motion
        return part, first

    def preview(self, constraints: list, base_constraints: list, base_motion):
        """The motion for ``constraints``: ``base_motion`` (solved for ``base_constraints``)
        with the frames the change can reach solved again (:func:`changed_window`); ``None``
        when the change cannot be localised (a constraint added or removed)."""
        window = changed_window(base_constraints, constraints)
        if window is None:
            return None
        lo, hi = window
        part, first = self.solve(constraints, lo, hi)
        return splice(base_motion, part, lo, hi, first)
