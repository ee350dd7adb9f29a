"""Sparse solved keys fitted to the constraints' tasks, not to the dense curves (issue 15
point 1).

The IK's dense result moves every corrected channel on every frame of its windows, and a fit
of each channel to that curve within a fraction of a millimetre follows every wiggle of it
(a key every 3 or 4 frames). What the constraints ask for is a few task-space quantities (a
heel held on a point, a foot's orientation, a foot above the floor); many curves meet them.
:func:`fit_to_tasks` looks for few keys that meet the TASKS:

* **Channels and spans.** A joint is corrected where the dense result turns it (the root's
  translation where it moves). Its *windows* are the frames ``[smooth_in, smooth_out]`` of the
  constraints it serves (on it or below it; every constraint for the root's translation):
  the frames the budget counts. Within each run of its windows where the dense result
  moves it, its curves are keyed from the first moved frame to the last, with a zero, flat key
  just outside either end: the curves are exactly zero outside (the direct conversion bit for
  bit there). Where the dense result leaves the joint for a key interval (the first keys'
  spacing, ``2 / key_budget`` frames) or more within a run, the run is split there and the
  curves are zero over that rest too: a foot between its contacts under the floor plane (a
  window spanning the clip) is the conversion's, as it is in the dense result. Keyed
  through, the rest wobbled (the Rokoko dance onto the CMU T-pose turned the right foot
  46 deg/s between its contacts, 1.54 times the steady limit below, where the capture and
  the dense solve hold it still).
* **Key frames at a budget, staggered.** Each channel has its own keys, at most
  :data:`KEYS_PER_SECOND` per second of its windows (:func:`key_budget`; a tenth of the
  frames at 120 fps, issue 15's budget, and as many a second at lower rates, where a
  tenth of the frames cannot follow a walk): half of that evenly to begin with, each channel's
  phase shifted (golden ratio) so that a chain's channels do not all key the same frames:
  between them, the chain's task sees a new piece of curve every few frames (the direct
  conversion's foot wobbles by about a millimetre from frame to frame within a contact, which
  one cubic per contact and channel cannot follow; keys shared by all channels could not).
* **Keys at the ramps' ends, where the even keys are not kept.** A last fit (``at_ramps``,
  :func:`solved_keys`) gives every channel of a joint a key wherever a ramp of a constraint
  on that joint begins or ends too (:func:`_ramp_ends`; the evenly spaced keys within a
  third of a spacing of one are left out): the dense solve eases a correction in and out
  with a smoothstep between those frames, which one Hermite segment between two keys makes
  exactly. With even keys only, a correction that starts after a rest rises from its pinned
  zero key to a free key up to a spacing away, and a contact let go for a few frames is
  crossed by one cubic: the Rokoko dance onto the Mixamo FBX character, whose toe is held,
  let go for four frames and held again, turned a foot 2.18 times the no-pop limit where the
  dense solve keeps 1.00, and the solve kept 1,820 keys fitted to the dense curves; with
  keys at the ramps' ends, 977 keys fitted to the tasks, within the no-pop and steady
  limits. Not the first fit: on the CMU jumps onto the CMU T-pose (2,752 frames, landings
  every second) such keys were refused where the even ones are kept (the first fit, a minute
  a solve), after three fits taking 9.5 minutes on a busy machine. Only the constraints on
  the joint itself give it such keys (its ancestors' would take every contact's ramps: a
  channel of the demo's went to 12.1 % of its window frames, over the budget of 10 %). Where
  the ramps end more often than the budget allows, the evenly spaced keys go first, then
  ramps' ends where they are nearest each other (:func:`_thinned`).
* **Keys on a glitch undone.** Where the dense solve took a frame from the way between its
  neighbours (a capture's one-frame glitch under a held goal, :mod:`.glitches`), its
  correction spikes there: each channel it spikes by more than the fit's tolerance (at the
  joint's lever) is keyed on the frame and either side, and its speed into and out of the
  frame costs nothing. Keyed through like the rest, the keys could not follow the spike,
  missed the goals there and fell back to the dense curves (the CMU jumps onto the Mixamo
  characters: their dense solves' pops elsewhere, up to 1.46, came with them).
* **Values and slopes by damped Gauss-Newton.** Each key has a value and an in and an out
  slope (a ``broken`` tangent where they differ). The curves are linear in them (cubic
  Hermite basis, :func:`~.displacement.hermite_basis`), so a step minimises, over every held
  frame (``[start, end]``; a one-sided plane such as the floor where it acts at the keyed
  posture), the task errors linearised through the IK's own task Jacobians
  (:func:`~.ik.task_error_and_jacobian`, with the exponential map's left Jacobian, and for
  orientation tasks the logarithm's), plus a pull towards the dense correction (metres at the
  joint's lever: :data:`PULL` on frames where a task is held through the joint, so that the
  null space stays near the dense solve; :data:`PULL_FREE` on the others, the ramps) and a
  cost on the curves' speed (:data:`SPEED` on the ramps, :data:`SPEED_HELD` on held frames,
  against pops). Metric tasks weigh
  1 whatever their priority (each is held within 1 mm); an angle counts at
  :data:`ANGLE_LEVER` metres per radian, :data:`LEVEL_WEIGHT` less per level below the first.
  Steps are Levenberg-Marquardt (a step that does not lower the cost is damped and tried
  again).
* **Keys where a task misses.** Where a metric task still misses by more than
  :data:`TASK_TOLERANCE` beyond what the dense solve misses (an unreachable goal is missed by
  both), per run of missing frames, the worst frame gets a key on the :data:`PER_MISS`
  channels of the chain whose key interval there is the longest (room in their budget
  permitting, a quarter of it per round), and the fit runs again, :data:`ROUNDS` rounds at
  most.
* **A fit that stalls stops adding keys.** Each round of added keys should lower the
  largest miss; where :data:`STALLS` rounds in a row leave it over :data:`TASK_LIMIT` and no
  lower than the best before them, more keys will not hold the tasks: the fit goes back to
  the keys of its least miss (or its best within the limit, below) and on to the emphasis
  rounds below like any fit whose keys are all added. Such fits once ran every round to the
  end, most of a solve's time (the bundled walk onto the bundled T-pose with contacts and
  the floor at 0: 367 evaluations, 63 s, ending 1.6 mm off; stopped after 161), and until
  round 47 a stalled fit with nothing within the limit stopped there: emphasised, the CC3
  pickup onto Kenney's FBX character comes within it from 1.14 times the limit (its keys
  kept, the solve 399 s -> 91 s). Only the rounds that add keys are judged so: the emphasis
  rounds below wander (a fit of frames 100-399 of that walk went 0.87, 1.26, 0.91, 1.91,
  1.06 mm and ended at 0.56, kept).
* **A fit that no round has held stops when it runs away or its emphasis is spent.** It
  would not be kept: it stops when a round after its added keys misses by more than
  :data:`RUNAWAY` times the least miss since they were added (such rounds trade the tasks
  for smoothness; of the fits of the foot sweep that came back within the limit none went
  past 1.69 times), or when no emphasis round is left (calming and steadying do not lower
  a miss).
* **The best fit within the limit is kept.** Rounds can also lose a fit: keys added for a
  miss under :data:`TASK_LIMIT` but over :data:`TASK_TOLERANCE` move others, and a fit
  that held every task within the limit can end over it, or stall (frames 750-949 of that
  walk: 0.86, 0.62, then 1.75 and 2.24 mm). A fit that stalls after holding every task
  within the limit goes back to its best such keys and goes on from there without adding
  more (the rounds below); one that ends over the limit returns those keys.
* **The largest miss, not the sum.** The limit is on the largest task error, and least
  squares spreads what few keys leave: on a 30 fps walk most held frames missed by 0.2 to
  0.9 mm and a few, mostly at a contact's first or last frame, by 1.4 to 2.3 mm. Once no key
  can be added, each frame where a metric task still misses by more than
  :data:`TASK_TOLERANCE` counts more, by how much it misses (at most :data:`EMPHASIS_STEP`
  times per round; iteratively reweighted towards the maximum), :data:`EMPHASIS` rounds at
  most.
* **No pops.** In the same rounds, where the keyed motion turns a joint faster around a ramp
  than the no-pop rule allows (:func:`~.quality.pop_limits`; where the dense solve itself
  turns the joint faster, at its ratio there: :func:`_pop_allowance`), that joint's curve
  speed there costs 4 times more, :data:`CALMING` rounds at most. Likewise where the keys
  move the root's translation in a lurch the dense solve does not make (its correction's
  step into a frame over :data:`ROOT_MARGIN` times the dense one's within
  :data:`ROOT_REACH` frames, and over :data:`ROOT_FLOOR` statures a second:
  :func:`_root_allowance`), the root's curve speed there costs 4 times more; the no-pop rule
  judges turns only, and the root's translation between the tasks is what a leg's turns
  make up for (the CC3 walk onto the CMU T-pose: a 37 mm step at 60 fps where the dense one
  is 4 mm). Both in one round: calming after the emphasis undid it (a 60 fps walk went from
  0.59 mm back to 1.02 mm), emphasis after the calming popped again.
* **Steady keys.** Then, on every frame, where the keys turn a joint faster than
  :data:`STEADY_MARGIN` times the conversion or the dense solve does within
  :data:`POP_REACH` frames (:func:`_steady_limit`: between the tasks a chain's staggered keys
  traded turns that held a planted foot), that joint's curve speed there costs 4 times more,
  :data:`STEADYING` rounds at most, with the pops and lurches it brings calmed in the same
  rounds. Of the rounds that pop and lurch no more than before the steadying and hold the
  tasks as well, the one whose worst turn is the least over that limit is kept, as the
  delivered motion is judged (the round with the fewest such frames was kept before: the
  Rokoko dance onto the Mixamo FBX character 1.72 times over, where a round was 1.68).
  Keys a solve keeps that are still over that limit are fitted once more with every
  channel's keys staggered by :data:`RESTAGGER` of a spacing, and the steadier kept
  (:func:`solved_keys`; that dance then 0.99); keys still over it after that are not kept,
  like keys that pop (the solve keeps keys fitted to the dense curves: the CMU jumps onto
  Quaternius' robot turned a shin 13.6 times past it).

The unknowns are numbered in key order, so the normal equations are banded in time and are
factorised in that order (no fill outside the band): each iteration is linear in the frames
(the linear rows' part of the normal matrix is built once per fit), and the rounds are
bounded. Measured (``benchmarks/bench_keys.py``, the demo tiled 1 and 4 times, one thread on
a quiet machine, round 42): 7.6 s and 32.5 s (4.2 to 4.3). Per evaluation the cost is
linear (70 ms at 1x, 283 ms at 4x, all of a fit's time over its evaluations; the sparse LU
in time order: 62 ms at 3,765 unknowns, 185 ms at 14,976, where a dense banded Cholesky at
their width, about 300, took 302 and 613 ms); what can still grow is the count: 109
evaluations at 1x, 115 at 4x (6 and 10 rounds of emphasis, 5 and 7 of steadying), because a
round and a step's acceptance are global (one stretch that still misses refits the clip).
A trial step needs the tasks' errors only: their Jacobian in the unknowns (half of an
evaluation's own work, and a sparse product) is assembled only where a step is taken from.

:func:`solved_keys` is what :meth:`~engine.scene.Scene.solve` stores: the task-fitted keys
when they hold every task within :data:`TASK_LIMIT` (beyond the dense solve's own miss) and
pop no more than the dense solve, frame by frame and joint by joint (:data:`POP_MARGIN`,
:func:`_pop_allowance`), and (restaggered where they need it) turn no joint past the steady
limit, else ``None``: the solve keeps the keys fitted to the dense curves
(:func:`~.displacement.fit_keys`), so a solve never holds its constraints worse than before.

Measured (``tests/test_layers.py``; keys per window frame per channel, median and worst; the
largest distance of a joint from the dense solve's path, :func:`parting`, in % of the figure's
size): the demo (994 frames at 120 fps) 7.4 % and 8.6 %, every goal within 0.50 mm, 1.5 %;
the Bandai walk onto the CMU skeleton (195 frames at 30 fps) 21.0 % and 27.7 % (within its
budget of 40 %), within 0.46 mm, 3.3 %; the CMU walk onto the Bandai skeleton (994 frames at
120 fps) 7.8 % and 8.6 %, within 0.50 mm, 2.1 %. Every one pops no more than the dense solve.
Before the budget was counted per second and the first fit pulled harder, the 30 fps walk's
keys parted from the dense solve by 22 % (a swing toe 37 cm off); on 28 pairs of clips and
characters of ../shared/data (``benchmarks/keyed_fidelity_r32.txt``) every solve now keeps
keys fitted to the tasks (5 fell back to dense-following keys), parting by 0.7 to 6.6 %.
"""
from __future__ import annotations

import copy
import functools
from typing import NamedTuple

import numpy as np

from ..describe import figure_size, stature
from ..errors import MotionComposerError
from ..kinematics import fk_arrays
from ..motion import Motion
from ..quaternions import qmul
from .displacement import (ROOT, ROTATION_CHANNELS, TRANSLATION_CHANNELS, Curve,
                           DisplacementMap, chain_lengths, hermite_basis)
from .ik import (Task, _Structure, effector, effector_chain, length_share, rotvec_to_quat,
                 task_error_and_jacobian)

__all__ = ["fit_to_tasks", "solved_keys", "parting", "key_budget", "fit_share",
           "KEYS_PER_SECOND", "TASK_TOLERANCE", "TASK_LIMIT", "FIDELITY", "GIANT"]

# scipy (sparse) is imported where a fit needs it: opening a project stays off scipy, which
# costs about half a second to import


#: keys per second of a channel's constraint windows, at most (a tenth of the frames at
#: 120 fps). A budget per frame starved clips of low frame rate: at 30 fps a tenth of the
#: frames is 3 keys a second, fewer than a walk's steps need (a plant and a lift per foot
#: and step), and the Bandai walk (30 fps) onto the CMU skeleton's keys parted from the
#: dense solve by 22 % of the stature (a swing toe 37 cm away) while holding every task;
#: at 10.5 keys a second they part by 3.9 % (benchmarks/keyed_fidelity.py)
KEYS_PER_SECOND = 12.0
#: keys per frame at most, whatever the frame rate (a key every other frame)
MOST_PER_FRAME = 0.5


def key_budget(fps: float) -> float:
    """Keys per frame of a channel's constraint windows at most, at ``fps`` frames a second
    (:data:`KEYS_PER_SECOND`, at most :data:`MOST_PER_FRAME`), to 4 decimals: frame times
    are stored to about 7 digits (0.0083333 s is 120.0005 fps), which should not cost a
    key."""
    return min(round(KEYS_PER_SECOND / fps, 4), MOST_PER_FRAME)

#: [m] the figure size (:func:`~engine.describe.figure_size`) up to which the fit's lengths
#: in metres (:data:`TASK_TOLERANCE`, :data:`TASK_LIMIT`, :data:`ANGLE_LEVER`,
#: :data:`LEVER_FLOOR`) hold as they are (on a figure smaller than
#: :data:`~engine.correction.ik.FULL_SIZE` they shrink with it); on a bigger one they grow
#: with it (:func:`fit_share`), as the IK's tolerance does from the same size
#: (:data:`~engine.correction.ik.MIN_TOLERANCE`); a floor plane stays held to its
#: tolerance in metres (the foot rule is absolute). Held to a millimetre, the Khronos fox
#: (61 m as written) was held to a sixty-thousandth of its size: its key fits ran every
#: round and were refused (the CMU jumps: 9 minutes, fits missing by 2.7-3.4 m after
#: their calming rounds), as on the Kenney character (3.7 m) and the robot (4.2 m): 9 of
#: the 12 sweep pairs that kept dense-following keys in round 43
GIANT = 2.0


def fit_share(size: float) -> float:
    """The share of the key fit's lengths in metres that holds on a figure of ``size`` [m]:
    :func:`~engine.correction.ik.length_share` up to :data:`GIANT`, ``size / GIANT``
    beyond, so that a figure bigger than that is fitted as the same figure scaled down to
    it."""
    return length_share(size) if size <= GIANT else size / GIANT


#: [m] a held task missing its goal by more than this gets keys where it misses
TASK_TOLERANCE = 0.5e-3
#: the pull towards the dense correction, relative to the tasks' rows (per channel: metres at
#: the joint's lever), on frames where a task is held through the joint (the tasks decide
#: there) and on the others (the ramps and the gaps between holds: the dense solve's easing)
PULL = 0.005
PULL_FREE = 0.05
#: the pull on held frames of the first fit a solve tries (:func:`solved_keys`): where the
#: keys can follow it, they stay nearer the dense solve (a 120 fps walk 3 % of the stature
#: instead of 5, the 30 fps walk 2 % instead of 7); where they cannot (the bundled walk onto
#: the T-pose with the floor at 0, frames of 200 at a time: 2-16 mm off in 6 of 8 windows),
#: the solve fits again with :data:`PULL`
FAITHFUL_PULL = 0.05
#: [s] the curves' speed (per channel, metres per second at the joint's lever) counts this
#: much on frames where no task is held through the joint (the ramps: against pops), and
#: ``SPEED_HELD`` where one is
SPEED = 0.0005
SPEED_HELD = 0.0001
#: an angular task's rows weigh this much less per priority level below the first (a metric
#: task's are held within :data:`TASK_TOLERANCE` whatever its level)
LEVEL_WEIGHT = 0.1
#: [m per rad] an angular task's error counts as a length at this lever
ANGLE_LEVER = 0.1
#: [m] a joint's lever (the length of the chain it turns) counts as at least this much
LEVER_FLOOR = 1e-3
#: [m^2] the least damping of a Gauss-Newton step's normal equations (squared lengths)
RIDGE = 1e-12
#: damped Gauss-Newton iterations per fit at most, and rounds of added keys at most
ITERATIONS = 8
ROUNDS = 12
#: rounds of a costlier speed where the keys pop or lurch, at most (10 before the root's
#: lurches were calmed too: the CC3 walk onto Ely then needed 16 and fell back to the
#: dense-following keys with 10)
CALMING = 16
#: the keys may move the root's translation (its correction's change from frame to frame) at
#: most this many times as fast as the dense solve does within ``ROOT_REACH`` frames, and
#: always ``ROOT_FLOOR`` statures per second: the no-pop rule judges turns, and between the
#: tasks the root's translation was free to lurch where the dense solve glides (the CC3 walk
#: onto the CMU T-pose: the keyed x correction 30, 37, 0, -19 mm on frames 126-129 at 60 fps,
#: the dense one 2 mm; benchmarks/keyed_root_steps.py)
ROOT_MARGIN = 1.5
ROOT_REACH = 3
ROOT_FLOOR = 0.1
#: on every frame, not only around the ramps, the keys may turn a joint at most this many
#: times as fast as the conversion or the dense solve does within :data:`POP_REACH` frames,
#: and always ``STEADY_FLOOR`` [rad/s]: between the tasks a chain's staggered keys were free
#: to trade turns that hold a planted foot (the CMU jumps onto the CMU T-pose: a held right
#: foot's ankle at 236 deg/s on frame 122 where the conversion turns it 16 and the dense
#: solve 18; 174 of 2,752 frames had a joint past 1.5 times 1.2 times that, 71 past twice)
STEADY_MARGIN = 1.5
STEADY_FLOOR = np.radians(30.0)
#: rounds of a costlier speed where the keys turn a joint past that, at most
STEADYING = 16
#: where a kept fit's keys still turn a joint past that limit, the solve fits once more with
#: every channel's keys staggered this far along (a fraction of the key spacing) and keeps
#: the steadier (:func:`solved_keys`): which keys a fit adds, emphasises and calms is decided
#: round by round, and a fit that ends with a wobble can end without one from keys shifted
#: by half a spacing (benchmarks/sweep_feet.py, the 8 distinct pairs over the limit: 3 went
#: within it, 5 nearer, none further)
RESTAGGER = 0.5
#: rounds of emphasis on the frames where a task still misses, at most, and how much more
#: such a frame counts per round at most
EMPHASIS = 10
EMPHASIS_STEP = 4.0
#: rounds of added keys in a row that leave the largest miss over :data:`TASK_LIMIT` and no
#: lower than before, after which a fit stops adding keys
STALLS = 2
#: keys added per miss (a run of frames where a task misses) and round, on as many channels
PER_MISS = 2
#: a fit none of whose rounds held the tasks within :data:`TASK_LIMIT` stops once a round
#: after its added keys (emphasis, calming, steadying) misses by more than this many times
#: the least miss since they were added (where they left it: the last round of added keys;
#: after a stall, its least miss, the keys it went back to): it would not be kept. In the
#: fits of benchmarks/sweep_feet.py (rounds 46 and 47, every fit logged) none of those that
#: came within the limit after their added keys missed by more than 1.69 times that before
#: (the CMU jumps onto Kenney's FBX character, the firm pull after a stall: 1.03 then 1.74
#: times the limit, then 0.84; at 1.5 it was stopped); the CC3 walk onto the fox went from
#: 11.9 times the limit to 1.75 and 0.75. Those that ran past it went on to 5-289 times
#: the limit over up to 133 s of rounds and were refused (the CMU jumps onto the fox); on
#: the bundled walk onto the bundled T-pose with the right arm's and the left leg's IK
#: blend, three stalled fits at 41 mm went down to 9-13 mm with emphasis and back up to
#: 20-83 mm with calming
RUNAWAY = 2.0


class _Joint:
    """One corrected joint (``index`` -1: the root's translation): its keyed frames (the
    spans) and per channel its key frames and which of them are pinned to zero."""

    def __init__(self, index: int, spans: list, spacing: float, num_frames: int, cap: int,
                 phases, seeds=()):
        self.index = index
        self.cap = cap
        self.frames = np.concatenate([np.arange(a, b + 1) for a, b in spans])
        ends = [(max(a - 1, 0), min(b + 1, num_frames - 1), a, b) for a, b in spans]
        room = cap - 2 * len(spans)
        length = sum(hi - lo for lo, hi, _, _ in ends)
        spacing = max(spacing, length / max(room / 2, 1))
        self.keys, self.pinned = [], []
        for phase in phases:
            keys, pinned = [], []
            for lo, hi, a, b in ends:
                inner = lo + (phase + np.arange(int((hi - lo) / spacing) + 1)) * spacing
                inner = np.round(inner[inner < hi - 1]).astype(np.intp)
                seeded = np.asarray([f for f in seeds if lo < f < hi], dtype=np.intp)
                if len(seeded):
                    near = np.abs(inner[:, None] - seeded[None, :]).min(axis=1)
                    inner = inner[near >= max(2.0, spacing / 3)]
                if not len(inner) and not len(seeded) and hi - lo >= 2:
                    inner = np.array([(lo + hi) // 2])        # a short span: one free key
                k = np.unique(np.r_[lo, inner, seeded, hi]).astype(np.intp)
                keys.append(k)
                pin = np.zeros(len(k), dtype=bool)
                pin[0] = lo < a
                pin[-1] = hi > b
                pinned.append(pin)
            # spans one frame apart share their zero key
            k, first = np.unique(np.concatenate(keys), return_index=True)
            pin = np.concatenate(pinned)[first]
            k, pin = _thinned(k, pin, np.isin(k, seeds), cap)
            self.keys.append(k)
            self.pinned.append(pin)

    def room(self, channel: int) -> int:
        return self.cap - len(self.keys[channel])

    def gap(self, channel: int, frame: int) -> int:
        """The length of the key interval ``frame`` lies in (0 at a key)."""
        keys = self.keys[channel]
        at = int(np.searchsorted(keys, frame))
        if at < len(keys) and keys[at] == frame:
            return 0
        if at == 0 or at == len(keys):
            return 0
        return int(keys[at] - keys[at - 1])

    def add(self, channel: int, frame: int) -> bool:
        if self.room(channel) <= 0 or self.gap(channel, frame) < 2:
            return False
        keys = self.keys[channel]
        at = int(np.searchsorted(keys, frame))
        self.keys[channel] = np.insert(keys, at, frame)
        self.pinned[channel] = np.insert(self.pinned[channel], at, False)
        return True


def _thinned(keys: np.ndarray, pinned: np.ndarray, seeded: np.ndarray, cap: int):
    """``keys`` and ``pinned`` with at most ``cap`` keys: free keys taken out where their
    neighbours are nearest each other, the evenly spaced ones before the ramps' ends
    (``seeded``); the pinned zeros stay."""
    while len(keys) > cap:
        free = ~pinned & ~seeded
        if not free.any():
            free = ~pinned
            if not free.any():
                break
        around = np.r_[keys[1:], keys[-1]] - np.r_[keys[0], keys[:-1]]
        at = int(np.argmin(np.where(free, around, np.iinfo(np.intp).max)))
        keys, pinned, seeded = (np.delete(a, at) for a in (keys, pinned, seeded))
    return keys, pinned


def _spans(moved: np.ndarray, window: np.ndarray, gap: int) -> list[tuple[int, int]]:
    """Per run of ``window`` where ``moved``, its first and last moved frame; split where the
    run holds ``gap`` or more frames in a row that are not moved (the curve is zero there,
    as the dense correction is)."""
    out = []
    idx = np.flatnonzero(window)
    if not len(idx):
        return out
    breaks = np.flatnonzero(np.diff(idx) > 1)
    for a, b in zip(np.r_[idx[0], idx[breaks + 1]], np.r_[idx[breaks], idx[-1]]):
        m = a + np.flatnonzero(moved[a:b + 1])
        if not len(m):
            continue
        split = np.flatnonzero(np.diff(m) > gap)
        out.extend(zip(np.r_[m[0], m[split + 1]].tolist(), np.r_[m[split], m[-1]].tolist()))
    return out


def _ramp_ends(constraints, skeleton, joint: int, carried=None) -> list[int]:
    """The frames where the ramps of the constraints on ``joint`` begin and end."""
    out = set()
    for c in constraints:
        if effector(skeleton.index[c.joint], carried)[0] != joint:
            continue
        if c.start - c.smooth_in >= 2:
            out.update((c.smooth_in, c.start))
        if c.smooth_out - c.end >= 2:
            out.update((c.end, c.smooth_out))
    return sorted(out)


def _windows(constraints, skeleton, num_frames: int,
             carried=None) -> tuple[np.ndarray, np.ndarray]:
    """``(J, F)`` per joint the frames of the windows of the constraints on it or below it
    (on a point it carries: ``carried``, :func:`~.ik.effector`), and ``(F,)`` every
    constraint's window."""
    per_joint = np.zeros((skeleton.num_joints, num_frames), dtype=bool)
    every = np.zeros(num_frames, dtype=bool)
    for c in constraints:
        span = slice(c.smooth_in, c.smooth_out + 1)
        every[span] = True
        j, _ = effector(skeleton.index[c.joint], carried)
        for a in skeleton.ancestors(j) + [j]:
            per_joint[a, span] = True
    return per_joint, every


class _Layout:
    """The unknowns (key values and slopes of every channel, pinned keys excluded, numbered
    in key order so that the normal equations stay banded) and the sparse basis: row
    ``(joint, keyed frame, channel)`` -> the curve there, linear in the unknowns."""

    def __init__(self, joints: list[_Joint], num_frames: int):
        import scipy.sparse as sparse
        self.joints = joints
        self.num_frames = num_frames
        owner, when = [], []
        for g, jt in enumerate(joints):
            for c in range(3):
                for k in np.flatnonzero(~jt.pinned[c]):
                    owner.append((g, c, int(k)))
                    when.append(jt.keys[c][k])
        order = np.argsort(np.asarray(when, dtype=float), kind="stable")
        # per key its value, in slope and out slope
        self.base = {owner[o]: 3 * n for n, o in enumerate(order)}
        self.n = 3 * len(order)
        rows, cols, vals = [], [], []
        self.row_of = []                # per joint (F,) the row of its channel 0, or -1
        r0 = 0
        for g, jt in enumerate(joints):
            t = jt.frames
            row_of = np.full(num_frames, -1, dtype=np.intp)
            row_of[t] = r0 + 3 * np.arange(len(t))
            self.row_of.append(row_of)
            for c in range(3):
                keys = jt.keys[c]
                K = len(keys)
                seg = np.clip(np.searchsorted(keys, t, side="right") - 1, 0, K - 2)
                h = (keys[seg + 1] - keys[seg]).astype(float)
                b0, b1, b2, b3 = hermite_basis((t - keys[seg]) / h)
                idx = np.full(K, -1, dtype=np.intp)
                for k in np.flatnonzero(~jt.pinned[c]):
                    idx[k] = self.base[(g, c, int(k))]
                weights = np.stack([b0, b1 * h, b2, b3 * h], axis=1)
                unknown = np.stack([idx[seg], idx[seg] + 2, idx[seg + 1], idx[seg + 1] + 1],
                                   axis=1)
                unknown[:, :2] = np.where(idx[seg, None] < 0, -1, unknown[:, :2])
                unknown[:, 2:] = np.where(idx[seg + 1, None] < 0, -1, unknown[:, 2:])
                ok = unknown >= 0
                r = r0 + 3 * np.arange(len(t)) + c
                rows.append(np.broadcast_to(r[:, None], unknown.shape)[ok])
                cols.append(unknown[ok])
                vals.append(weights[ok])
            r0 += 3 * len(t)
        self.m = r0
        self.basis = sparse.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(self.m, self.n))
        self.basis_t = self.basis.T.tocsr()

    def values(self, x: np.ndarray) -> np.ndarray:
        return self.basis @ x

    def curve(self, x: np.ndarray, g: int, c: int):
        """Channel ``c`` of joint ``g``: key frames, values and slopes."""
        jt = self.joints[g]
        keys = jt.keys[c]
        v = np.zeros(len(keys))
        s = np.zeros((len(keys), 2))
        for k in np.flatnonzero(~jt.pinned[c]):
            b = self.base[(g, c, int(k))]
            v[k], s[k] = x[b], x[b + 1:b + 3]
        # the ends' outer slopes shape nothing: the inner ones
        s[0, 0], s[-1, 1] = s[0, 1], s[-1, 0]
        return keys, v, s


def _left_jacobian(r: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` the left Jacobian of SO(3) at rotation vectors ``r``: ``exp(r + d) ~
    exp(J d) exp(r)``."""
    theta = np.linalg.norm(r, axis=-1)[..., None, None]
    k = np.zeros(r.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -r[..., 2], r[..., 1], -r[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = r[..., 2], -r[..., 1], r[..., 0]
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    a = np.where(small, 0.5 - theta ** 2 / 24, (1 - np.cos(t)) / t ** 2)
    b = np.where(small, 1 / 6 - theta ** 2 / 120, (t - np.sin(t)) / t ** 3)
    return np.eye(3) + a * k + b * (k @ k)


class _Tasks:
    """The held tasks, the constraints of one task kind, joint, priority and weight in one
    batch: per batch its frames, goals, row weight and IK structure."""

    def __init__(self, constraints, skeleton, locked, share: float = 1.0, carried=None,
                 strict: float = 1.0):
        batches: dict = {}
        for c in constraints:
            kind = c.kind_object.task_kind
            frames = np.arange(c.start, c.end + 1)
            key = (kind.name, c.joint, c.priority, c.weight)
            entry = batches.setdefault(key, (kind, c, [], [], []))
            entry[2].append(frames)
            entry[3].append(c.kind_object.task_goals(c, frames))
            entry[4].append(np.full(len(frames), strict if c.kind_object.one_sided(c.goal)
                                    else 1.0))
        self.items = []
        #: per item, its metric error [m] per frame in the dense solve (None: not known yet)
        self.floor = None
        #: per item, how much more each of its frames counts (see :meth:`emphasise`)
        self.emphasis = []
        #: per item and frame, how many times its metric error counts against the tolerance
        #: and the limit: ``strict`` for a one-sided plane (a floor: the feet stay above it
        #: within the tolerance in metres whatever the figure's size), else 1
        self.strict = []
        for kind, c, frames, goals, strict_of in batches.values():
            self.strict.append(np.concatenate(strict_of))
            frames = np.concatenate(frames)
            joint, point = effector(skeleton.index[c.joint], carried)
            task = Task(kind, joint, np.concatenate(goals), np.ones(len(frames)), c.priority,
                        point=point)
            weight = c.weight ** 0.5
            if kind.angular:
                weight *= ANGLE_LEVER * share * LEVEL_WEIGHT ** (c.priority - 1)
            self.items.append((frames, _Structure(skeleton, [task], locked), weight,
                               kind.angular))
            self.emphasis.append(np.ones(len(frames)))

    def emphasise(self, sizes: dict, tolerance: float) -> bool:
        """Frames where a metric task (``sizes``: per item its error beyond the dense
        solve's per frame) misses by more than ``tolerance`` count more (by how
        much they miss, at most :data:`EMPHASIS_STEP` times per call): least squares spreads
        the error that few keys leave, and the limit is on the largest (iteratively
        reweighted towards the maximum). Returns whether any frame changed."""
        changed = False
        for item, size in sizes.items():
            over = size > tolerance
            if over.any():
                self.emphasis[item][over] *= np.minimum(size[over] / tolerance, EMPHASIS_STEP)
                changed = True
        return changed


def fit_to_tasks(edited: Motion, constraints, rotvecs: np.ndarray, root: np.ndarray, *,
                 budget: float | None = None, tolerance: float = TASK_TOLERANCE,
                 pull: float = PULL, stagger: float = 0.0, at_ramps: bool = False,
                 stats: dict | None = None, cancel=None, carried=None,
                 glitches=()) -> DisplacementMap:
    """Few Hermite keys for the dense correction ``rotvecs (F, J, 3)`` [rad], ``root
    (F, 3)`` [m] of ``edited`` (the motion the IK started from) under ``constraints``,
    fitted to the constraints' tasks (see the module doc). ``stats``, when given, receives
    the fit's figures (largest held-task error [m] and its limit on this figure,
    evaluations, rounds, whether it stalled,
    ran away (:data:`RUNAWAY`) or stopped with its emphasis spent,
    the largest miss after each round of added keys, and the kept keys' worst turn over the
    steady limit, at least 1, or ``None`` where it was not measured); ``stagger`` shifts
    every channel's first keys by that fraction of the key spacing; ``at_ramps`` keys each
    joint at the ends of the ramps of the constraints on it too (:func:`_ramp_ends`);
    ``cancel()`` returning True stops it (:class:`~engine.errors.MotionComposerError`).
    ``carried``: the control joints carried with limbs, held through them
    (:func:`~.ik.effector`). ``glitches``: the frames the dense solve took from the way
    between their neighbours (:attr:`~.enforcement.Correction.glitches`): each channel the
    dense correction spikes there (by more than ``tolerance`` at its joint's lever) is keyed
    on the frame and either side, and its speed into and out of it costs nothing (the
    correction there is the capture's one-frame glitch undone, a spike no smooth curve
    makes; the keys take it as the dense solve has it).

    On a character smaller than :data:`~engine.correction.ik.FULL_SIZE` the lengths in
    metres (``tolerance``, :data:`TASK_LIMIT`, :data:`ANGLE_LEVER`) shrink with it, and on
    one bigger than :data:`GIANT` they grow with it (:func:`fit_share`): its keys are those
    of the character scaled to that size."""
    import scipy.sparse as sparse
    sk = edited.skeleton
    F = edited.num_frames
    size = figure_size(edited)
    share = fit_share(size)
    tolerance = tolerance * share
    limit = TASK_LIMIT * share
    cons = [c for c in constraints if c.enabled]
    per_joint, every = _windows(cons, sk, F, carried)
    moved = np.any(rotvecs != 0, axis=2)                                    # (F, J)
    moved_root = np.any(root != 0, axis=1)
    budget = key_budget(edited.fps) if budget is None else budget
    spacing = 2.0 / budget
    # a key interval or more where a joint's dense correction is zero: zero there too
    gap = int(np.ceil(spacing))
    lever = np.r_[chain_lengths(sk), 1.0]            # the root's translation: 1 m per m
    lever[:-1] = np.maximum(lever[:-1], LEVER_FLOOR * share)
    # a glitch undone (the dense correction spikes there, moving the joint's chain more
    # than the fit's tolerance): keyed on it and either side, free to turn into and out of
    # it; the joints it does not spike keep their keys and speed cost (keyed there, a joint
    # the dense solve leaves alone took the spike: the FAIR jump's LHipJoint 1.79 times the
    # no-pop limit)
    spiked, unslowed = {}, set()
    curves = np.concatenate([rotvecs, root[:, None]], axis=1)    # the root's last: index -1
    for f in (int(f) for f in glitches if 0 < f < F - 1):
        spike = np.linalg.norm(curves[f] - (curves[f - 1] + curves[f + 1]) / 2, axis=-1)
        for j in np.flatnonzero(spike * lever > tolerance):
            j = int(j) if j < sk.num_joints else -1
            spiked.setdefault(j, []).extend((f - 1, f, f + 1))
            unslowed.update(((j, f), (j, f + 1)))
    joints = []
    for j in list(np.flatnonzero(moved.any(axis=0))) + [-1]:
        if j < 0:
            spans = _spans(moved_root, every, gap) if moved_root.any() else []
            window = every
        else:
            spans, window = _spans(moved[:, j], per_joint[j], gap), per_joint[j]
        if spans:
            # the channels' keys staggered (a chain's joints too): between them the chain's
            # tasks see a new piece of curve every few frames
            n = 3 * len(joints)
            phases = ((n + np.arange(3)) * 0.618034 + stagger) % 1.0
            # a curve keeps its span's two ends however short the clip (three frames at a
            # tenth of a key a frame rounded to none)
            seeds = list(_ramp_ends(cons, sk, j, carried)) if at_ramps else []
            seeds += spiked.get(int(j), [])
            joints.append(_Joint(int(j), spans, spacing, F,
                                 max(2, int(np.floor(budget * window.sum()))), phases,
                                 sorted(set(seeds))))
    if not joints:
        return DisplacementMap()
    locked = frozenset(range(sk.num_joints)) - {jt.index for jt in joints}
    # a floor is held to its tolerance in metres on a figure bigger than GIANT too (the foot
    # rule is absolute: at most 1 mm under a joint's rest height)
    tasks = _Tasks(cons, sk, locked, share, carried, strict=share / length_share(size))
    layout = _Layout(joints, F)
    # the rows (joint, keyed frame, channel) depend on the keyed frames only, not the keys
    dense = _stacked(layout, rotvecs, root)
    held = _held(cons, sk, F, carried)
    scale = np.concatenate([np.repeat(_lever(jt, lever) * np.where(
        held[jt.index][jt.frames], pull, PULL_FREE), 3) for jt in joints])
    speed_w = np.concatenate([np.repeat(_lever(jt, lever) * np.where(
        held[jt.index][jt.frames], SPEED_HELD, SPEED), 3) for jt in joints])
    _linearised(tasks, _keyed(edited, layout, dense), layout, dense, tolerance)  # the floor
    x = _least_squares(layout.basis, dense)
    reg_pull = sparse.diags(scale)
    dense_motion = _keyed(edited, layout, dense)
    allowed = _pop_allowance(edited, dense_motion, cons, 1.0)
    allowed_root = _root_allowance(edited, root)
    steady = _steady_limit(edited, dense_motion)
    boost = {}                    # (joint index, frame) -> how much more its speed costs
    total = rounds = calming = emphasised = stalls = steadied = 0
    ran_away = spent = False
    # the keys before they were steadied, and the steadiest since
    before = steadiest = None
    popping = set()
    best, adding, largest = np.inf, True, []
    closest = np.inf              # the least miss of any round
    low = None                    # the least since the added keys, while none held
    # the best keys that held every task within TASK_LIMIT: more rounds can lose them (keys
    # added for a miss under the limit, or a stall, move others off), and then they are kept
    kept, kept_worst, restored = None, np.inf, False
    while True:
        speed, at = _speeds(layout, edited.fps)
        weights = abs(speed) @ speed_w / (2 * edited.fps)
        weights *= np.array([boost.get(key, 1.0) for key in at]) if boost else 1.0
        if unslowed:
            weights *= np.array([key not in unslowed for key in at], dtype=float)
        reg = sparse.vstack([reg_pull @ layout.basis,
                             sparse.diags(weights) @ speed @ layout.basis]).tocsr()
        target = np.r_[scale * dense, np.zeros(speed.shape[0])]
        if cancel is not None and cancel():
            raise MotionComposerError("the correction was cancelled")
        x, worst, misses, sizes, used = _gauss_newton(tasks, edited, layout, x, reg, target,
                                                      tolerance, share)
        total += used
        closest = min(closest, worst)
        if not adding and closest > limit:
            if low is None:             # where the added keys left it
                low = best if stalls >= STALLS else largest[-1]
            if worst > RUNAWAY * low:
                ran_away = True
                break
            low = min(low, worst)
        if adding and worst <= limit and worst < kept_worst:
            kept, kept_worst = (copy.deepcopy(joints), x.copy()), worst
        if adding:
            # keys added where tasks miss lower the largest miss round after round; where
            # they have not for STALLS rounds in a row (over the limit), more keys will not
            # hold the tasks: stop adding, and go back to the best keys (within the limit if
            # any were), to be emphasised and calmed like any fit whose keys are all added
            stalls = stalls + 1 if limit < worst >= best else 0
            if worst < best:
                least = (copy.deepcopy(joints), x.copy())
            best = min(best, worst)
            largest.append(float(worst))
            if stalls >= STALLS:
                joints, x = copy.deepcopy((kept or least)[0]), (kept or least)[1].copy()
                layout = _Layout(joints, F)
                restored, adding = True, False
                continue
        adding = not restored and bool(misses) and rounds < ROUNDS and \
            _add_keys(joints, misses)
        if adding:
            rounds += 1
            # the new key set fitted to the curves as they are, then Gauss-Newton again
            values = layout.values(x)
            layout = _Layout(joints, F)
            x = _least_squares(layout.basis, values)
            continue
        # where tasks still miss, their frames count more; where a joint turns faster than
        # the no-pop rule (as the dense solve meets it) allows, its curves' speed costs
        # more; both at once, so that neither undoes what the other gained
        keyed = _keyed(edited, layout, layout.values(x))
        popping = _popping(edited, keyed, cons, allowed) | _lurching(edited, keyed,
                                                                     allowed_root)
        # then (once the keys keep those rules, or their rounds are spent) where they turn a
        # joint faster than the conversion and the dense solve do nearby
        # (:func:`_steady_limit`), its speed costs more too, and pops and lurches that brings
        # are calmed with it. Kept: of the keys with no more pops and lurches than before
        # and their tasks held as well, the ones whose worst wobble is the least over its
        # limit (of those as steady, the ones nearest the tasks)
        steadying = steadied > 0 or not popping or calming >= CALMING
        wobbling = set()
        if steadying:
            ratios = _steady_ratios(keyed, steady)
            f, j = np.nonzero(ratios > 1.0)
            wobbling = set(zip(j.tolist(), f.tolist()))
            now = _Snapshot(joints, x, worst, len(popping), max(1.0, float(ratios.max())))
            if before is None or (now.pops <= before.pops and
                                  now.worst <= max(limit, before.worst) and
                                  (now.over, now.worst) < (steadiest.over, steadiest.worst)):
                steadiest = now._replace(joints=copy.deepcopy(joints), x=x.copy())
            before = before or steadiest
        emphasise = bool(misses) and emphasised < EMPHASIS and \
            tasks.emphasise(sizes, tolerance)
        calm = bool(popping) and not steadying
        steady_more = steadying and steadied < STEADYING and \
            (now.over > 1.0 or now.pops > before.pops)
        if not emphasise and not calm and not steady_more:
            break
        if not emphasise and closest > limit:
            # no round held the tasks and none will emphasise their misses: calming and
            # steadying trade the tasks for smoothness, they do not bring them within the limit
            spent = True
            break
        emphasised += emphasise
        calming += calm
        steadied += steady_more
        for key in popping | wobbling if calm or steady_more else ():
            boost[key] = boost.get(key, 1.0) * 4.0
    unsteady = None
    if steadiest is not None:
        joints, x, worst = steadiest.joints, steadiest.x, steadiest.worst
        layout = _Layout(joints, F)
        unsteady = steadiest.over
    result = _as_map(sk, layout, x)
    if worst > limit and kept is not None and kept_worst < worst:
        result, worst, unsteady = _as_map(sk, _Layout(kept[0], F), kept[1]), kept_worst, None
    if stats is not None:
        stats.update({"worst_task_m": float(worst), "limit_m": float(limit),
                      "iterations": total, "rounds": rounds,
                      "calming": calming, "steadied": steadied, "emphasised": emphasised,
                      "stalled": stalls >= STALLS, "ran_away": ran_away,
                      "spent": spent,
                      "adding_misses_m": largest,
                      "unsteady": unsteady})
    return result


def _held(constraints, skeleton, num_frames: int, carried=None) -> dict:
    """Per joint (-1: the root's translation) ``(F,)`` where a constraint (not a one-sided
    plane over the whole clip) is held through it."""
    out = {j: np.zeros(num_frames, dtype=bool) for j in range(-1, skeleton.num_joints)}
    for c in constraints:
        if c.kind_object.one_sided(c.goal) and c.smooth_in == c.start and \
                c.end == c.smooth_out:
            continue
        for a in [-1] + effector_chain(c.kind_object, skeleton, skeleton.index[c.joint],
                                       carried):
            out[a][c.start:c.end + 1] = True
    return out


def _add_keys(joints: list[_Joint], misses: list) -> int:
    """Keys where tasks miss, the worst misses first: per run of missing frames of a task, at
    its worst frame, on the :data:`PER_MISS` channels of the task's chain whose key interval
    there is the longest (with room in their budget); a channel takes a quarter of its room
    per round at most (the fit then says where keys are still missing). Returns how many
    were added."""
    runs = []
    for groups, frames, size in misses:
        for run in np.split(np.arange(len(frames)), np.flatnonzero(np.diff(frames) != 1) + 1):
            k = run[np.argmax(size[run])]
            runs.append((float(size[k]), int(frames[k]), groups))
    runs.sort(key=lambda r: -r[0])
    allowance = {(g, c): max(1, joints[g].room(c) // 4) for g in range(len(joints))
                 for c in range(3)}
    added = 0
    for _, f, groups in runs:
        cand = [(joints[g].gap(c, f), g, c) for g in groups for c in range(3)
                if allowance[(g, c)] > 0 and joints[g].room(c) > 0
                and joints[g].gap(c, f) >= 2]
        cand.sort(reverse=True)
        for _, g, c in cand[:PER_MISS]:
            if joints[g].add(c, f):
                allowance[(g, c)] -= 1
                added += 1
    return added


def _speeds(layout: _Layout, fps: float):
    """Sparse ``(rows, m)``: per joint channel and pair of consecutive keyed frames (and
    between a span's end frame and the zero beyond it), the curve's change times ``fps`` (its
    speed); and per row ``(joint index, frame)``, the later frame of the pair."""
    import scipy.sparse as sparse
    rows, cols, vals, at = [], [], [], []
    n = 0
    for jt, row_of in zip(layout.joints, layout.row_of):
        f = jt.frames
        pair = np.flatnonzero(np.diff(f) == 1)
        breaks = np.flatnonzero(np.diff(f) > 1)
        first = f[np.r_[0, breaks + 1]]
        last = f[np.r_[breaks, len(f) - 1]]
        first = first[first > 0]
        last = last[last < layout.num_frames - 1]
        for c in range(3):
            r = n + np.arange(len(pair))
            e = n + len(pair) + np.arange(len(first) + len(last))
            rows += [r, r, e]
            cols += [row_of[f[pair]] + c, row_of[f[pair + 1]] + c, row_of[np.r_[first, last]] + c]
            vals += [np.full(len(pair), -fps), np.full(len(pair), fps),
                     np.r_[np.full(len(first), fps), np.full(len(last), -fps)]]
            at += [(jt.index, int(t)) for t in np.r_[f[pair + 1], first, last + 1]]
            n += len(pair) + len(first) + len(last)
    matrix = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                       np.concatenate(cols))),
                               shape=(n, layout.m))
    return matrix, at


def _popping(direct: Motion, keyed: Motion, constraints, allowed: np.ndarray) -> set:
    """``(joint index, frame)`` where ``keyed`` turns a joint faster than ``allowed (F, J)``
    times its no-pop limit around a ramp (:func:`_pop_ratios`, :func:`_pop_allowance`)."""
    f, j = np.nonzero(_pop_ratios(direct, keyed, constraints) > allowed)
    return set(zip(j.tolist(), f.tolist()))


#: frames either side of a joint's turn over the no-pop limit in the dense solve within which
#: the keys may turn it as fast (a fit moves such a turn by a frame or two)
POP_REACH = 2


def _pop_allowance(direct: Motion, dense: Motion, constraints, margin: float) -> np.ndarray:
    """``(F, J)`` the ratio to the no-pop limit the keys may reach at each frame and joint:
    1, or where the dense solve itself turns the joint faster (a capture's own one-frame jerk
    that a held foot absorbs), ``margin`` times its ratio there (within :data:`POP_REACH`
    frames). Per frame and joint, not the clip's worst: one jerk of the capture must not
    license a pop of the keys anywhere else in the clip (the CMU jumps onto the FAIR child:
    the dense solve's worst, 1.86 at frame 975, let the keys turn the left foot at 1.78 of
    its limit at 953, where the dense solve stays at 0.53)."""
    from scipy.ndimage import maximum_filter1d
    ratios = _pop_ratios(direct, dense, constraints)
    near = maximum_filter1d(ratios, 2 * POP_REACH + 1, axis=0, mode="nearest")
    return np.maximum(1.0, margin * near)


def _steady_limit(edited: Motion, dense: Motion) -> np.ndarray:
    """``(F, J)`` [rad/s] how fast the keys may turn each joint into each frame, on every
    frame (not only around the ramps): :data:`STEADY_MARGIN` times the fastest turn of the
    joint in ``edited`` (the motion the IK started from) or ``dense`` (the dense solve)
    within :data:`POP_REACH` frames, and at least :data:`STEADY_FLOOR`."""
    from scipy.ndimage import maximum_filter1d
    from .quality import angular_speed
    fastest = np.maximum(angular_speed(edited), angular_speed(dense))
    near = maximum_filter1d(fastest, 2 * POP_REACH + 1, axis=0, mode="nearest")
    return np.maximum(STEADY_MARGIN * near, STEADY_FLOOR)


def _steady_ratios(keyed: Motion, limit: np.ndarray) -> np.ndarray:
    """``(F, J)`` how fast ``keyed`` turns each joint into each frame over ``limit (F, J)``
    (:func:`_steady_limit`)."""
    from .quality import angular_speed
    return angular_speed(keyed) / limit


class _Snapshot(NamedTuple):
    """Keys seen while steadying: the key frames, values and slopes, the largest task miss
    [m], how many (joint, frame) pop or lurch, and the worst wobble over its limit (at least
    1)."""
    joints: list
    x: np.ndarray
    worst: float
    pops: int
    over: float


def _root_steps(edited: Motion, keyed: Motion) -> np.ndarray:
    """``(F,)`` [m] how far the root's translation correction (``keyed`` less ``edited``) moves
    into each frame from the frame before (0 at frame 0)."""
    correction = keyed.translations[:, 0] - edited.translations[:, 0]
    out = np.zeros(edited.num_frames)
    out[1:] = np.linalg.norm(np.diff(correction, axis=0), axis=1)
    return out


def _root_allowance(edited: Motion, root: np.ndarray) -> np.ndarray:
    """``(F,)`` [m] the step the keys' root correction may take into each frame: the dense
    correction ``root (F, 3)``'s largest step within :data:`ROOT_REACH` frames times
    :data:`ROOT_MARGIN`, and at least :data:`ROOT_FLOOR` statures a second."""
    from scipy.ndimage import maximum_filter1d
    dense = np.zeros(edited.num_frames)
    dense[1:] = np.linalg.norm(np.diff(root, axis=0), axis=1)
    near = maximum_filter1d(dense, 2 * ROOT_REACH + 1, mode="nearest")
    return np.maximum(ROOT_MARGIN * near, ROOT_FLOOR * stature(edited) / edited.fps)


def _lurching(edited: Motion, keyed: Motion, allowed: np.ndarray) -> set:
    """``(-1, frame)`` (the root's translation, as :func:`_speeds` names it) where ``keyed``
    moves the root's correction further into the frame than ``allowed``
    (:func:`_root_allowance`)."""
    return {(-1, int(f)) for f in np.flatnonzero(_root_steps(edited, keyed) > allowed)}


def _pop_ratios(direct: Motion, corrected: Motion, constraints) -> np.ndarray:
    """``(F, J)`` each joint's turning speed over its no-pop limit around the ramps
    (:func:`~.quality.pop_limits`; 0 off the ramps, where the limit is infinite)."""
    from .quality import angular_speed, pop_limits, ramps
    limit = pop_limits(direct, corrected, ramps(constraints, direct.num_frames))
    return angular_speed(corrected) / limit


def _gauss_newton(tasks, edited: Motion, layout: _Layout, x: np.ndarray, reg, target,
                  tolerance: float, share: float = 1.0):
    """Key values and slopes ``x`` improved by damped Gauss-Newton (Levenberg-Marquardt)
    steps on the held tasks' errors plus the linear rows ``reg x = target`` (the pull and
    the speed); returns ``x``, the largest metric task error beyond the dense solve's, the
    misses, the metric errors (as :func:`_linearised`) and the evaluations used. ``share``:
    :func:`fit_share` (the normal equations are in squared lengths)."""
    import scipy.sparse as sparse
    def state(x):
        values = layout.values(x)
        motion = _keyed(edited, layout, values)
        err, jac, worst, misses, sizes = _linearised(tasks, motion, layout, values, tolerance)
        rest = target - reg @ x
        return [err, jac, worst, misses, sizes, rest], float(err @ err + rest @ rest)

    now, cost = state(x)
    damping = 1e-4
    used = 1
    # the linear rows' part of the normal equations is the same on every iteration
    reg_t = reg.T.tocsr()
    reg_normal = reg_t @ reg
    for _ in range(ITERATIONS):
        # the Jacobian is assembled where a step is taken from, not at every trial
        now[1] = now[1]()
        err, jac, _, _, _, rest = now
        # J = R B (R: the tasks' rows in the keyed frames' rows, a few per frame and joint;
        # B: the basis, 4 entries a row): J'J = B' (R'R) B, with R'R block diagonal in
        # frames, is about a tenth of the products of J'J formed from J
        rows_t = jac.T.tocsr()
        normal = layout.basis_t @ ((rows_t @ jac) @ layout.basis) + reg_normal
        diag = normal.diagonal()
        g = layout.basis_t @ (rows_t @ err) + reg_t @ rest
        while True:
            used += 1
            step = _solve_spd(normal + sparse.diags(damping * diag + RIDGE * share ** 2), g)
            trial, trial_cost = state(x + step)
            if trial_cost < cost or damping > 1e6:
                break
            damping *= 10.0
        if trial_cost >= cost:
            break
        x, now = x + step, trial
        improvement = (cost - trial_cost) / max(cost, 1e-300)
        cost = trial_cost
        damping = max(damping / 10.0, 1e-9)
        if improvement < 1e-3:
            break
    return x, now[2], now[3], now[4], used


def _lever(jt: _Joint, lever: np.ndarray) -> float:
    return float(lever[-1] if jt.index < 0 else lever[jt.index])


def _stacked(layout: _Layout, rotvecs: np.ndarray, root: np.ndarray) -> np.ndarray:
    """The dense correction in the layout's rows."""
    out = np.empty(layout.m)
    for jt, row_of in zip(layout.joints, layout.row_of):
        src = root[jt.frames] if jt.index < 0 else rotvecs[jt.frames, jt.index]
        r = row_of[jt.frames]
        for c in range(3):
            out[r + c] = src[:, c]
    return out


def _least_squares(a, rhs: np.ndarray) -> np.ndarray:
    """The least-squares solution of ``a x = rhs`` (sparse ``a``) by its normal equations,
    with a tiny ridge (keys a frame apart have more unknowns than frames)."""
    import scipy.sparse as sparse
    a = sparse.csc_matrix(a)
    n = a.shape[1]
    return _solve_spd(a.T @ a + sparse.identity(n) * 1e-12, a.T @ rhs)


#: a normal matrix narrower than this is solved banded, a wider one by sparse LU
BAND = 60


def _solve_spd(normal, rhs: np.ndarray) -> np.ndarray:
    """``normal^-1 rhs`` for a sparse symmetric positive definite ``normal`` whose unknowns
    are numbered in time: banded (Cholesky in time linear in the unknowns), else a sparse
    LU."""
    import scipy.sparse as sparse
    from scipy.linalg import LinAlgError, solveh_banded
    coo = normal.tocoo()
    upper = coo.col >= coo.row
    row, col, data = coo.row[upper], coo.col[upper], coo.data[upper]
    width = int((col - row).max(initial=0))
    n = normal.shape[0]
    if width < BAND:
        band = np.zeros((width + 1, n))
        np.add.at(band, (width + row - col, col), data)
        try:
            return solveh_banded(band, rhs, check_finite=False)
        except LinAlgError:
            pass
    from scipy.sparse.linalg import splu
    return splu(sparse.csc_matrix(normal), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                options={"SymmetricMode": True}).solve(rhs)


def _keyed(edited: Motion, layout: _Layout, values: np.ndarray) -> Motion:
    """``edited`` with the curves' ``values`` applied (as a displacement map applies them)."""
    rotations = edited.rotations.copy()
    translations = edited.translations.copy()
    for jt, row_of in zip(layout.joints, layout.row_of):
        r = row_of[jt.frames]
        v = np.stack([values[r], values[r + 1], values[r + 2]], axis=1)
        if jt.index < 0:
            translations[jt.frames, 0] += v
        else:
            rotations[jt.frames, jt.index] = qmul(rotvec_to_quat(v),
                                                  rotations[jt.frames, jt.index])
    return Motion._trusted(edited.skeleton, rotations, translations, edited.frame_time,
                           edited.name)


def _linearised(tasks: _Tasks, motion: Motion, layout: _Layout, values: np.ndarray,
                tolerance: float):
    """The held tasks' weighted errors ``(R,)``, a function assembling their Jacobian in the
    keyed frames' rows (sparse ``(R, m)``; times ``layout.basis``, the Jacobian in the
    unknowns; only where a step is taken from: most trial steps are not), the largest metric
    task error [m] and the misses: per task missing its goal by more than ``tolerance``
    somewhere, ``(its chain's joints (layout indices), frames, errors there)``; and per metric
    task (item) its error beyond the dense solve's per frame."""
    import scipy.sparse as sparse
    sk = motion.skeleton
    group = {jt.index: g for g, jt in enumerate(layout.joints)}
    # per rotated joint and keyed frame, d(turn) / d(rotation vector)
    turn = []
    for jt, row_of in zip(layout.joints, layout.row_of):
        if jt.index < 0:
            turn.append(None)
            continue
        r = row_of[jt.frames]
        turn.append(_left_jacobian(np.stack([values[r], values[r + 1], values[r + 2]], 1)))
    errs, parts = [], []
    r0 = 0
    worst = 0.0
    misses = []
    floors = {}
    sizes = {}
    for item, (frames, structure, weight, angular) in enumerate(tasks.items):
        err, jac = task_error_and_jacobian(sk, structure, motion.rotations[frames],
                                           motion.translations[frames])
        B, K = err.shape
        blocks = [(group[a], col) for a, col in
                  [(-1, 0)] + [(int(a), 3 + 3 * k) for k, a in enumerate(structure.joints)]
                  if a in group]
        if not angular:
            # how much further from its goal than the dense solve (which may miss an
            # unreachable goal) the task is
            size = np.linalg.norm(err, axis=1)
            if tasks.floor is not None:
                size = (size - tasks.floor[item]) * tasks.strict[item]
            else:
                floors[item] = size
            worst = max(worst, float(size.max(initial=0.0)))
            sizes[item] = size
            bad = size > tolerance
            if bad.any():
                misses.append(([g for g, _ in blocks], frames[bad], size[bad]))
        weight = weight * tasks.emphasis[item][:, None]
        errs.append((weight * err).reshape(-1))
        parts.append((frames, err if angular else None, jac, weight, blocks, r0, K))
        r0 += B * K
    err = np.concatenate(errs) if errs else np.zeros(0)
    if tasks.floor is None:
        tasks.floor = floors

    def jacobian():
        rows, cols, vals = [], [], []
        for frames, angle, jac, weight, blocks, r0, K in parts:
            if angle is not None:
                # the IK's rows are d(rotation) (the error's first order); the error is a
                # logarithm: d log(exp(e) exp(-d)) = -J_r(e)^-1 d, J_r(e) = J_l(-e)
                jac = np.linalg.solve(_left_jacobian(-angle), jac)
            for g, col in blocks:
                row_of = layout.row_of[g][frames]
                inside = np.flatnonzero(row_of >= 0)
                if not len(inside):
                    continue
                block = jac[inside, :, col:col + 3]
                if turn[g] is not None:
                    first = layout.row_of[g][layout.joints[g].frames[0]]
                    block = block @ turn[g][(row_of[inside] - first) // 3]
                rr = np.broadcast_to((r0 + inside[:, None] * K + np.arange(K))[:, :, None],
                                     block.shape)
                cc = np.broadcast_to(row_of[inside][:, None, None] + np.arange(3), block.shape)
                rows.append(rr.reshape(-1))
                cols.append(cc.reshape(-1))
                vals.append((weight[inside, :, None] * block).reshape(-1))
        big = sparse.csr_matrix((np.concatenate(vals) if vals else np.zeros(0),
                                 (np.concatenate(rows) if rows else np.zeros(0, np.intp),
                                  np.concatenate(cols) if cols else np.zeros(0, np.intp))),
                                shape=(len(err), layout.m))
        return big

    return err, jacobian, worst, misses, sizes


def _as_map(skeleton, layout: _Layout, x: np.ndarray) -> DisplacementMap:
    curves = {}
    for g, jt in enumerate(layout.joints):
        names = TRANSLATION_CHANNELS if jt.index < 0 else ROTATION_CHANNELS
        joint = ROOT if jt.index < 0 else skeleton.names[jt.index]
        for c, channel in enumerate(names):
            keys, v, s = layout.curve(x, g, c)
            if not np.any(v) and not np.any(s):
                continue
            modes = tuple("aligned" if a == b else "broken" for a, b in s)
            curves[(joint, channel)] = Curve(keys.astype(float), v, ("smooth",) * len(keys),
                                             modes, s)
    return DisplacementMap(curves)


#: [m] solved keys hold every held task within this, or the dense-following keys are kept
TASK_LIMIT = 1e-3
#: solved keys take no joint further from where the dense solve puts it than this share of
#: the figure's size (:func:`~engine.describe.figure_size`), or the dense-following keys are
#: kept: the dense solve is the posture nearest the capture that meets the tasks, and keys
#: that meet them elsewhere (a swing foot 37 cm off its path, measured before the budget was
#: counted per second) are not the capture. On 28 pairs of ../shared/data the kept keys part
#: by 0.7 to 6.6 % (benchmarks/keyed_fidelity.py)
FIDELITY = 0.1
#: solved keys may turn a joint around a ramp at most this much more (in the no-pop rule's
#: ratio) than the dense solve does at that joint and frame (:func:`_pop_allowance`)
POP_MARGIN = 1.02


def parting(motion: Motion, dense: Motion) -> tuple[float, int, int]:
    """How far ``motion`` parts from the path ``dense`` (one skeleton) takes each joint: the
    largest distance [m] of a joint from the nearest of its positions in ``dense`` on the
    same frame and the frames either side, with that frame and joint index. A fit may smooth
    a one-frame jerk of the dense solve away, and a key may shift a turn by a frame: when the
    CMU walk onto the Bandai skeleton with ``--floor 0`` had each floor plane twice, its dense
    solve threw a toe 20 cm for one frame and back (``enforcement._assign_slots``), and the
    keys, 16 cm from it on that frame, were 2.6 % of the stature from its path."""
    return _parting(_positions(motion), _positions(dense))


def _positions(motion: Motion) -> np.ndarray:
    """``(F, J, 3)`` the joints' world positions."""
    return fk_arrays(motion.skeleton, motion.rotations, motion.translations,
                     end_sites=False).positions


def _parting(here: np.ndarray, path: np.ndarray) -> tuple[float, int, int]:
    """:func:`parting` of the joint positions ``here`` from ``path`` (both ``(F, J, 3)``)."""
    apart = np.linalg.norm(here - path, axis=-1)
    if len(path) > 1:
        apart[1:] = np.minimum(apart[1:], np.linalg.norm(here[1:] - path[:-1], axis=-1))
        apart[:-1] = np.minimum(apart[:-1], np.linalg.norm(here[:-1] - path[1:], axis=-1))
    f, j = np.unravel_index(int(apart.argmax()), apart.shape)
    return float(apart[f, j]), int(f), int(j)


def solved_keys(direct: Motion, edited: Motion, constraints, correction, *, cancel=None,
                carried=None, why: dict | None = None):
    """The solved layer's keys fitted to the tasks (:func:`fit_to_tasks`), pulled towards
    the dense correction with :data:`FAITHFUL_PULL` or, where those are not kept, with
    :data:`PULL`; or None when neither is kept, that is when the keys
    miss a held task by more than :data:`TASK_LIMIT`, take a joint further than
    :data:`FIDELITY` of the figure's size from the dense solve's path (:func:`parting`),
    break the no-pop rule (its worst
    ratio against ``direct``, the direct conversion, over 1) more than the dense solve does,
    or move the root in a lurch it does not make (:func:`_root_allowance`): the caller then
    keeps keys fitted to the dense curves. Kept keys that still turn a joint past the steady
    limit (:func:`_steady_limit`) are fitted once more with the keys staggered by
    :data:`RESTAGGER`, and the steadier of the two kept; where that one too is past the
    limit, they are not kept either (the weaker pull is not tried for a wobble: it is what
    holds tasks the faithful one misses, and pulls the keys less towards the dense solve,
    not more). Where neither pull's keys are kept, the faithful pull is fitted once more
    with keys at the ramps' ends too (``at_ramps``, restaggered likewise where they wobble),
    and judged alike; where those are not kept either, None (the keys fitted to the dense
    curves follow the dense solve, which sets the limits). ``cancel()``
    returning True stops the fit (:class:`~engine.errors.MotionComposerError`).
    ``carried``: :func:`fit_to_tasks`'s. ``why``, when given and the keys are not kept,
    receives ``"reason"``: what the last fit's keys broke, in words."""
    why = {} if why is None else why
    if correction is None:
        return None
    if edited.num_frames < 3:
        why["reason"] = "a clip of fewer than 3 frames is not fitted to the tasks"
        return None
    judge = _Judge(direct, edited, constraints, correction)
    fits = [(FAITHFUL_PULL, False), (PULL, False), (FAITHFUL_PULL, True)]
    if not any(c.start - c.smooth_in >= 2 or c.smooth_out - c.end >= 2 for c in judge.cons):
        fits.pop()                      # no ramps: keys at their ends are the same keys
    wobbled = False
    for pull, at_ramps in fits:
        if wobbled and not at_ramps:
            continue
        stats: dict = {}
        keys = fit_to_tasks(edited, constraints, correction.rotvecs, correction.root,
                            pull=pull, at_ramps=at_ramps, stats=stats, cancel=cancel,
                            carried=carried, glitches=correction.glitches)
        if not judge.keeps(keys, stats):
            continue
        over = judge.unsteady(keys)
        if over > 1.0:
            again: dict = {}
            other = fit_to_tasks(edited, constraints, correction.rotvecs, correction.root,
                                 pull=pull, stagger=RESTAGGER, at_ramps=at_ramps,
                                 stats=again, cancel=cancel, carried=carried,
                                 glitches=correction.glitches)
            if judge.keeps(other, again):
                steadier = judge.unsteady(other)
                if steadier < over:
                    keys, over = other, steadier
        # keys that still wobble a joint past the steady limit are not the solve's: the
        # keys fitted to the dense curves follow the dense solve, which sets that limit
        if over <= 1.0:
            return keys
        judge.reason = judge.wobble(keys)
        wobbled = True
    why["reason"] = judge.reason
    return None


class _Judge:
    """What :func:`solved_keys` keeps keys by, against the dense solve: what depends on it
    alone (its joint positions, where it pops, how fast its root moves) is found once, when
    a fit first needs it, for both fits."""

    def __init__(self, direct: Motion, edited: Motion, constraints, correction):
        self.direct, self.edited, self.correction = direct, edited, correction
        self.cons = [c for c in constraints if c.enabled]
        self.size = figure_size(edited)
        #: why the last keys judged were not kept, in words (None: they were)
        self.reason = None

    @functools.cached_property
    def path(self) -> np.ndarray:
        return _positions(self.correction.motion)

    @functools.cached_property
    def pops_allowed(self) -> np.ndarray:
        return _pop_allowance(self.direct, self.correction.motion, self.cons, POP_MARGIN)

    @functools.cached_property
    def root_allowed(self) -> np.ndarray:
        return _root_allowance(self.edited, self.correction.root)

    @functools.cached_property
    def steady_limit(self) -> np.ndarray:
        return _steady_limit(self.edited, self.correction.motion)

    def unsteady(self, keys: DisplacementMap) -> float:
        """The keys' worst turn over the steady limit (:func:`_steady_limit`), at least 1."""
        return max(1.0, float(_steady_ratios(keys.apply(self.edited),
                                             self.steady_limit).max()))

    def keeps(self, keys: DisplacementMap, stats: dict) -> bool:
        """Whether the keys (fitted with ``stats``) are kept; where not, :attr:`reason` says
        why, in words."""
        names = self.edited.skeleton.names
        worst, limit = stats.get("worst_task_m", 0.0), TASK_LIMIT * fit_share(self.size)
        if worst > limit:
            self.reason = (f"the keys fitted to the tasks missed one by {worst * 1e3:.2f} mm "
                           f"(at most {limit * 1e3:.2f} mm beyond the dense solve)")
            strict = fit_share(self.size) / length_share(self.size)
            if strict > 1.0:
                # a floor's metres count more there (_Tasks.strict): say so, not a giant miss
                self.reason += (f"; on this figure of {self.size:.3g} m a floor's millimetre "
                                f"counts {strict:.3g}")
            return False
        keyed = keys.apply(self.edited)
        # the keys stay near the dense solve
        apart, f, j = _parting(_positions(keyed), self.path)
        if apart > FIDELITY * self.size:
            self.reason = (f"the keys fitted to the tasks took {names[j]} "
                           f"{100 * apart / self.size:.1f} % of the figure's size from the "
                           f"dense solve at frame {f} (at most {100 * FIDELITY:.3g} %)")
            return False
        # the keys keep the no-pop rule where the dense solve keeps it, and break it no
        # further where it does not
        ratios = _pop_ratios(self.direct, keyed, self.cons)
        if np.any(ratios > self.pops_allowed):
            f, j = np.unravel_index(int(np.argmax(ratios / self.pops_allowed)), ratios.shape)
            self.reason = (f"the keys fitted to the tasks turned {names[j]} {ratios[f, j]:.2f} "
                           f"times the no-pop limit at frame {f} (the dense solve: at most "
                           f"{self.pops_allowed[f, j]:.2f})")
            return False
        # nor move the root in lurches the dense solve does not make
        lurches = _lurching(self.edited, keyed, self.root_allowed)
        if lurches:
            self.reason = (f"the keys fitted to the tasks moved the root in a lurch into frame "
                           f"{min(f for _, f in lurches)} that the dense solve does not make")
            return False
        return True

    def wobble(self, keys: DisplacementMap) -> str:
        """Where the keys turn a joint furthest past the steady limit, in words."""
        ratios = _steady_ratios(keys.apply(self.edited), self.steady_limit)
        f, j = np.unravel_index(int(np.argmax(ratios)), ratios.shape)
        return (f"the keys fitted to the tasks turned {self.edited.skeleton.names[j]} "
                f"{ratios[f, j]:.2f} times past the steady limit at frame {f}")
