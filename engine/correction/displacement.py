"""Motion displacement maps (Bruderlin and Williams; the paper's section 2.2).

A displacement map is a set of offset curves added to a composed motion, which itself never
changes. Channels are the root's translation (``tx``, ``ty``, ``tz`` [m], world axes) and each
joint's rotation as a rotation vector (``rx``, ``ry``, ``rz`` [rad]) in the joint's parent frame,
applied before the joint's own rotation: ``local' = exp(offset) * local``. Rotation vectors
compose cleanly: a zero offset is no change, small offsets add, and an animator can edit each
component as a curve.

Each curve has keys (frame, value) and an interpolation per key (the segment after a key uses
that key's): ``linear``, ``smooth`` (cubic Hermite with Catmull-Rom tangents, flattened at
extrema so it never overshoots its keys) or ``constant`` (step). Before the first key and after
the last the end values hold. Every evaluation covers all frames at once.

:func:`reduce_keys` turns a dense per-frame signal (an IK result) into few linear keys within a
tolerance, so the curve editor shows curves a person can edit.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from ..errors import MotionComposerError
from ..motion import Motion
from ..quaternions import from_rotvec, qmul

__all__ = ["Curve", "DisplacementMap", "Layer", "reduce_keys", "fit_keys", "INTERPOLATIONS",
           "TANGENTS", "ROOT"]

INTERPOLATIONS = ("linear", "smooth", "constant")
TANGENTS = ("auto", "flat", "linear", "aligned", "broken")
ROOT = "<root>"
TRANSLATION_CHANNELS = ("tx", "ty", "tz")
ROTATION_CHANNELS = ("rx", "ry", "rz")


@dataclass(frozen=True, eq=False)
class Curve:
    """One channel's keys.

    Attributes:
        frames: ``(K,)`` key times in frames (increasing; fractional allowed).
        values: ``(K,)`` key values (metres or radians).
        interpolation: ``(K,)`` per key, the interpolation of the segment that starts at it.
        tangents: ``(K,)`` per key, how its tangent is made (:data:`TANGENTS`): ``auto``
            (Catmull-Rom, flat at extrema and at the ends), ``flat`` (zero slope), ``linear``
            (towards the neighbouring keys), ``aligned`` (the stored slope on both sides) or
            ``broken`` (the stored in and out slopes).
        slopes: ``(K, 2)`` the stored in and out slopes [value per frame] that ``aligned``
            and ``broken`` keys use (``aligned`` keys store the same slope twice).
    """

    frames: np.ndarray
    values: np.ndarray
    interpolation: tuple[str, ...] = ()
    tangents: tuple[str, ...] = ()
    slopes: np.ndarray | None = None

    def __post_init__(self):
        f = np.array(self.frames, dtype=float).reshape(-1)
        v = np.array(self.values, dtype=float).reshape(-1)
        if f.shape != v.shape:
            raise MotionComposerError(f"a curve needs as many values as key frames "
                                      f"({len(f)} frames, {len(v)} values)")
        if not (np.all(np.isfinite(f)) and np.all(np.isfinite(v))):
            raise MotionComposerError("curve keys must be finite numbers")
        if np.any(np.diff(f) <= 0):
            raise MotionComposerError("curve key frames must increase strictly")
        interp = _per_key(self.interpolation, "linear", len(f), "interpolation", INTERPOLATIONS)
        modes = _per_key(self.tangents, "auto", len(f), "tangent", TANGENTS)
        slopes = (np.zeros((len(f), 2)) if self.slopes is None
                  else np.array(self.slopes, dtype=float).reshape(-1, 2))
        if len(slopes) != len(f):
            raise MotionComposerError(f"a curve needs one [in, out] slope pair per key "
                                      f"({len(f)} keys, {len(slopes)} pairs)")
        if not np.all(np.isfinite(slopes)):
            raise MotionComposerError("curve slopes must be finite numbers")
        aligned = np.array([m == "aligned" for m in modes], dtype=bool)
        if np.any(slopes[aligned, 0] != slopes[aligned, 1]):
            raise MotionComposerError("an aligned tangent has one slope: its in and out "
                                      "slopes must be equal (make it broken to differ)")
        for a in (f, v, slopes):
            a.setflags(write=False)
        object.__setattr__(self, "frames", f)
        object.__setattr__(self, "values", v)
        object.__setattr__(self, "interpolation", interp)
        object.__setattr__(self, "tangents", modes)
        object.__setattr__(self, "slopes", slopes)

    def __len__(self) -> int:
        return len(self.frames)

    def evaluate(self, times: np.ndarray) -> np.ndarray:
        """Values at ``times`` (frames), vectorised."""
        t = np.asarray(times, dtype=float)
        f, v = self.frames, self.values
        if len(f) == 0:
            return np.zeros_like(t)
        if len(f) == 1:
            return np.full_like(t, v[0])
        seg = np.clip(np.searchsorted(f, t, side="right") - 1, 0, len(f) - 2)
        t0, t1 = f[seg], f[seg + 1]
        u = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)
        v0, v1 = v[seg], v[seg + 1]
        out = v0 + (v1 - v0) * u                                      # linear
        kinds = np.array(self.interpolation)[seg]
        step = kinds == "constant"
        out = np.where(step, np.where(u >= 1.0, v1, v0), out)
        smooth = kinds == "smooth"
        if np.any(smooth):
            m = self.tangent_slopes()
            h = t1 - t0
            b0, b1, b2, b3 = hermite_basis(u)
            hermite = b0 * v0 + b1 * h * m[seg, 1] + b2 * v1 + b3 * h * m[seg + 1, 0]
            out = np.where(smooth, hermite, out)
        return out

    def tangent_slopes(self) -> np.ndarray:
        """``(K, 2)`` the in and out slope [value per frame] of every key, as its tangent
        mode makes them."""
        f, v = self.frames, self.values
        out = np.array(self.slopes, dtype=float)
        auto = self._auto_slopes()
        chord = np.diff(v) / np.diff(f) if len(f) > 1 else np.zeros(0)
        left = np.r_[chord[:1], chord] if len(chord) else np.zeros(len(f))
        right = np.r_[chord, chord[-1:]] if len(chord) else np.zeros(len(f))
        modes = np.array(self.tangents, dtype=object)
        auto_keys = modes == "auto"
        out[auto_keys] = auto[auto_keys, None]
        out[modes == "flat"] = 0.0
        linear = modes == "linear"
        out[linear] = np.column_stack([left, right])[linear]
        return out

    def _auto_slopes(self) -> np.ndarray:
        """Catmull-Rom slopes (value per frame), zero at extrema and at the ends' flat sides."""
        f, v = self.frames, self.values
        m = np.zeros(len(f))
        if len(f) > 2:
            m[1:-1] = (v[2:] - v[:-2]) / (f[2:] - f[:-2])
            left = v[1:-1] - v[:-2]
            right = v[2:] - v[1:-1]
            m[1:-1] = np.where(left * right <= 0, 0.0, m[1:-1])      # extremum or flat: 0
        return m

    def with_keys(self, frames, values, interpolation=None, tangents=None,
                  slopes=None) -> "Curve":
        return Curve(frames, values, interpolation or (), tangents or (), slopes)

    def take(self, keep) -> "Curve":
        """The keys at indices (or a mask) ``keep``, with their interpolation and tangents."""
        idx = np.arange(len(self))[keep]
        return Curve(self.frames[idx], self.values[idx],
                     tuple(self.interpolation[i] for i in idx),
                     tuple(self.tangents[i] for i in idx), self.slopes[idx])

    def moved(self, frames, values) -> "Curve":
        """The same keys (interpolation, tangents) at new ``frames`` and ``values``."""
        return Curve(frames, values, self.interpolation, self.tangents, self.slopes)

    def with_tangent(self, index: int, mode: str, slopes=None) -> "Curve":
        """Key ``index`` with tangent ``mode``; ``aligned`` and ``broken`` take ``slopes``
        ``(in, out)`` (default: the slopes it has now)."""
        if mode not in TANGENTS:
            raise MotionComposerError(f"tangent must be one of {TANGENTS}, not {mode!r}")
        now = self.tangent_slopes()[index]
        pair = np.array(now if slopes is None else slopes, dtype=float)
        if mode == "aligned":
            pair = np.array([pair[1], pair[1]]) if slopes is None else pair
        stored = np.array(self.slopes)
        stored[index] = pair
        modes = list(self.tangents)
        modes[index] = mode
        return Curve(self.frames, self.values, self.interpolation, tuple(modes), stored)

    def to_dict(self, *, arrays: bool = False) -> dict:
        """The curve's fields as a project file holds them; with ``arrays``, its numbers as
        the read-only arrays instead of lists: the project writer turns one array at a time
        into text, so that a long solve's keys (1.2 million numbers at 40,000 frames) never
        exist all at once as Python floats, which cost fresh memory (page faults) on every
        save."""
        numbers = (lambda a: a) if arrays else np.ndarray.tolist
        out = {"frames": numbers(self.frames), "values": numbers(self.values),
               "interpolation": list(self.interpolation)}
        if self.tangents.count("auto") != len(self.tangents):
            out["tangents"] = list(self.tangents)
            out["slopes"] = numbers(self.slopes[:, 1])
            if "broken" in self.tangents:
                out["slopes_in"] = numbers(self.slopes[:, 0])
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "Curve":
        """The curve of :meth:`to_dict`'s data: ``slopes`` are the stored out slopes (the
        one slope of an aligned key), ``slopes_in`` the in slopes of broken keys (where a
        key is not broken its in slope is its out slope)."""
        return cls(data["frames"], data["values"], tuple(data.get("interpolation", ())),
                   tuple(data.get("tangents", ())),
                   stored_slopes(data.get("tangents", ()), data.get("slopes"),
                                 data.get("slopes_in")))


def stored_slopes(tangents, out, slopes_in) -> np.ndarray | None:
    """``(K, 2)`` in and out slopes from a file's per-key ``out`` slopes and, for broken
    keys, ``slopes_in`` (None without ``out``: no stored slopes)."""
    if out is None:
        return None
    out = np.asarray(out, dtype=float).reshape(-1)
    broken = np.array([m == "broken" for m in tangents], dtype=bool)
    inward = out.copy()
    if slopes_in is not None:
        given = np.asarray(slopes_in, dtype=float).reshape(-1)
        if len(given) != len(out):
            raise MotionComposerError(f"a curve needs one in slope per key ({len(out)} "
                                      f"keys, {len(given)} in slopes)")
        if len(broken) == len(out):
            inward[broken] = given[broken]
    return np.stack([inward, out], axis=-1)


def _per_key(kinds, default: str, count: int, what: str, allowed) -> tuple[str, ...]:
    kinds = tuple(kinds) or (default,) * count
    if len(kinds) != count:
        raise MotionComposerError(f"a curve needs one {what} per key ({count} keys, "
                                  f"{len(kinds)} given)")
    for kind in kinds:
        if kind not in allowed:
            raise MotionComposerError(f"{what} must be one of {allowed}, not {kind!r}")
    return kinds


def hermite_basis(u: np.ndarray):
    """The cubic Hermite basis at ``u`` in [0, 1]: the weights of the start value, start
    slope (times the segment length), end value and end slope (times the length)."""
    u2 = u * u
    u3 = u2 * u
    return 2 * u3 - 3 * u2 + 1, u3 - 2 * u2 + u, -2 * u3 + 3 * u2, u3 - u2


@dataclass(frozen=True, eq=False)
class DisplacementMap:
    """Offset curves by channel: ``(joint name or ROOT, channel)`` -> :class:`Curve`.

    Joint rotation channels are ``rx ry rz``; the root translation's are ``tx ty tz``.
    """

    curves: dict = field(default_factory=dict)

    def __post_init__(self):
        curves = {}
        for key, curve in dict(self.curves).items():
            joint, channel = key
            if joint == ROOT:
                if channel not in TRANSLATION_CHANNELS:
                    raise MotionComposerError(f"root channels are {TRANSLATION_CHANNELS}, not "
                                              f"{channel!r}")
            elif channel not in ROTATION_CHANNELS:
                raise MotionComposerError(f"joint channels are {ROTATION_CHANNELS}, not "
                                          f"{channel!r}")
            curves[(str(joint), str(channel))] = curve
        object.__setattr__(self, "curves", curves)

    def __len__(self) -> int:
        return len(self.curves)

    def offsets(self, skeleton, num_frames: int):
        """``(F, J, 3)`` rotation-vector offsets and ``(F, 3)`` root translation offsets."""
        rot = np.zeros((num_frames, skeleton.num_joints, 3))
        tra = np.zeros((num_frames, 3))
        t = np.arange(num_frames, dtype=float)
        for (joint, channel), curve in self.curves.items():
            if joint == ROOT:
                tra[:, TRANSLATION_CHANNELS.index(channel)] = curve.evaluate(t)
            else:
                j = skeleton.joint(joint)
                rot[:, j, ROTATION_CHANNELS.index(channel)] = curve.evaluate(t)
        return rot, tra

    def restricted_to(self, joints) -> "DisplacementMap":
        """This map without the curves of joints not in ``joints`` (the root's curves stay);
        ``self`` when nothing is dropped."""
        kept = tuple(c for c in self.curves if c[0] == ROOT or c[0] in joints)
        if len(kept) == len(self.curves):
            return self
        return DisplacementMap({key: self.curves[key] for key in kept})

    def apply(self, motion: Motion, weight: float = 1.0) -> Motion:
        """``motion`` with the offsets, scaled by ``weight``, added (the input is not
        changed; a weight of 1 is the map itself, 0 is ``motion``)."""
        if not self.curves or weight == 0.0:
            return motion
        rot, tra = self.offsets(motion.skeleton, motion.num_frames)
        if weight != 1.0:
            rot *= weight
            tra *= weight
        moved = np.flatnonzero(np.any(rot != 0, axis=(0, 2)))
        rotations = motion.rotations.copy()
        if len(moved):
            rotations[:, moved] = qmul(from_rotvec(rot[:, moved]), rotations[:, moved])
        translations = motion.translations.copy()
        translations[:, 0] += tra
        return motion.replace(rotations=rotations, translations=translations)

    @classmethod
    def from_dense(cls, skeleton, rotvecs: np.ndarray, root: np.ndarray, *,
                   position_tolerance: float = 1e-4,
                   rotation_tolerance: float = np.radians(0.02)) -> "DisplacementMap":
        """Fitted keys (:func:`fit_keys`) for dense offsets ``rotvecs (F, J, 3)`` [rad] and
        ``root (F, 3)`` [m]; channels that stay zero get no curve.

        A joint's rotation channels are fitted within ``position_tolerance`` [m] divided by
        its lever (the longest chain of bones below it), at most ``rotation_tolerance``
        [rad]: what a joint's error moves is its descendants, so a hip is fitted tighter than
        a toe and every joint stays within about ``position_tolerance`` per joint above it of
        the dense result. The root's translation is fitted within ``position_tolerance``."""
        curves = {}
        lever = chain_lengths(skeleton)
        for j in range(skeleton.num_joints):
            tolerance = min(rotation_tolerance, position_tolerance / max(lever[j], 1e-6))
            for c, channel in enumerate(ROTATION_CHANNELS):
                signal = rotvecs[:, j, c]
                if np.any(np.abs(signal) > tolerance * 1e-3):
                    curves[(skeleton.names[j], channel)] = fit_keys(signal, tolerance)
        for c, channel in enumerate(TRANSLATION_CHANNELS):
            signal = root[:, c]
            if np.any(np.abs(signal) > position_tolerance * 1e-3):
                curves[(ROOT, channel)] = fit_keys(signal, position_tolerance)
        return cls(curves)

    def to_dict(self, *, arrays: bool = False) -> dict:
        """The map as a project file holds it (``arrays``: see :meth:`Curve.to_dict`)."""
        return {"channels": [{"joint": j, "channel": c, **curve.to_dict(arrays=arrays)}
                             for (j, c), curve in self.curves.items()]}

    @classmethod
    def from_dict(cls, data: dict) -> "DisplacementMap":
        return cls({(item["joint"], item["channel"]): Curve.from_dict(item)
                    for item in data.get("channels", [])})


def reduce_keys(signal: np.ndarray, tolerance: float, *, smooth: bool = True) -> Curve:
    """Few keys whose curve stays within ``tolerance`` of a per-frame ``signal`` at every
    frame.

    With ``smooth`` (the default) the keys are fitted cubic Hermite keys with their slopes
    (:func:`fit_keys`); otherwise linear keys by Ramer-Douglas-Peucker. Smooth keys need
    several times fewer keys for the same tolerance on motion curves, and they are what the
    curve editor shows.
    """
    y = np.asarray(signal, dtype=float)
    n = len(y)
    if smooth:
        return fit_keys(y, tolerance)
    if n == 0:
        return Curve([], [])
    if n == 1:
        return Curve([0.0], [y[0]])
    x = np.arange(n, dtype=float)
    keep = np.zeros(n, dtype=bool)
    keep[[0, n - 1]] = True
    stack = [(0, n - 1)]
    while stack:
        a, b = stack.pop()
        if b - a < 2:
            continue
        seg = slice(a + 1, b)
        line = y[a] + (y[b] - y[a]) * (x[seg] - a) / (b - a)
        err = np.abs(y[seg] - line)
        k = int(np.argmax(err))
        if err[k] > tolerance:
            m = a + 1 + k
            keep[m] = True
            stack.append((a, m))
            stack.append((m, b))
    idx = np.flatnonzero(keep)
    return Curve(idx.astype(float), y[idx])


#: the first keys of a fit are this many frames apart; the fit then splits where it misses
FIT_SPACING = 64


def fit_keys(signal: np.ndarray, tolerance: float, *, spacing: int = FIT_SPACING) -> Curve:
    """Fitted cubic Hermite keys (values and slopes) within ``tolerance`` of ``signal`` at
    every frame, where ``signal`` is not zero; exactly zero where it is.

    The signal's windows (runs of frames over ``tolerance * 1e-3``, merged across gaps
    shorter than ``spacing``) are fitted one by one: a flat zero key just outside each end
    (so that the curve is exactly zero between windows, as a correction is outside its
    constraint ranges), keys every ``spacing`` frames inside, values and slopes by linear
    least squares over the window's frames; then every key interval where the curve misses
    the signal by more than ``tolerance`` gets a key at its worst frame (or, when that frame
    is already a key, at the middle of its neighbouring intervals), and the window is fitted
    again, until it holds. A jump in the signal thus ends with keys a frame apart around it,
    a smooth stretch with a key every ``spacing`` frames. Each fit is a banded linear
    system, so the cost is linear in the clip.

    Keys are ``smooth`` with ``aligned`` tangents (the fitted slope on both sides; zero at
    the zero keys of window ends).
    """
    y = np.asarray(signal, dtype=float).reshape(-1)
    n = len(y)
    if n == 0:
        return Curve([], [])
    if n == 1:
        return Curve([0.0], [y[0]])
    frames, values, slopes = [], [], []
    for a, b in _windows(np.abs(y) > tolerance * 1e-3, spacing):
        lo, hi = max(a - 1, 0), min(b + 1, n - 1)
        keys, v, m = _fit_window(y, lo, hi, lo < a, hi > b, tolerance, spacing)
        for k, key in enumerate(keys):
            pinned = (k == 0 and lo < a) or (k == len(keys) - 1 and hi > b)
            if frames and key <= frames[-1]:          # windows one frame apart share a key
                continue
            frames.append(float(key))
            values.append(0.0 if pinned else float(v[k]))
            slopes.append((0.0, 0.0) if pinned else (float(m[k]), float(m[k])))
    if not frames:
        return Curve([0.0], [0.0])
    return Curve(frames, values, ("smooth",) * len(frames), ("aligned",) * len(frames),
                 slopes)


def _windows(active: np.ndarray, gap: int) -> list[tuple[int, int]]:
    """``(first, last)`` frames of the runs of ``active``, runs less than ``gap`` frames
    apart merged."""
    idx = np.flatnonzero(active)
    if not len(idx):
        return []
    breaks = np.flatnonzero(np.diff(idx) > gap)
    return list(zip(np.r_[idx[0], idx[breaks + 1]].tolist(),
                    np.r_[idx[breaks], idx[-1]].tolist()))


def _fit_window(y, lo: int, hi: int, pin_lo: bool, pin_hi: bool, tolerance: float,
                spacing: int):
    """Keys, values and slopes over frames ``lo..hi`` of ``y`` (zero and flat at a pinned
    end), refined until the curve is within ``tolerance`` (see :func:`fit_keys`)."""
    t = np.arange(lo, hi + 1)
    target = y[lo:hi + 1]
    count = max(1, int(np.ceil((hi - lo) / spacing)))
    keys = np.unique(np.round(np.linspace(lo, hi, count + 1)).astype(np.intp))
    while True:
        v, m, fitted = _least_squares(keys, t, target, pin_lo, pin_hi)
        err = np.abs(fitted - target)
        over = err > tolerance
        if not np.any(over):
            return keys, v, m
        added = _splits(keys, t[over], err[over])
        if not len(added):
            return keys, v, m                       # every interval is one frame: exact
        keys = np.union1d(keys, added)


def _splits(keys: np.ndarray, frames: np.ndarray, err: np.ndarray) -> np.ndarray:
    """New keys: per key interval with frames over the tolerance, its worst frame, or the
    middles of the intervals beside it when that frame is a key already."""
    seg = np.searchsorted(keys, frames, side="right") - 1
    order = np.lexsort((-err, seg))
    seg = seg[order]
    first = np.ones(len(seg), dtype=bool)
    np.not_equal(seg[1:], seg[:-1], out=first[1:])
    worst = frames[order][first]
    # membership by the search the neighbours need anyway (np.isin's setup cost more than
    # the rest: this runs once per round of every channel's fit, whatever the clip's length)
    at = np.searchsorted(keys, worst)
    is_key = keys[np.minimum(at, len(keys) - 1)] == worst
    out = [worst[~is_key]]
    at = at[is_key]
    for lo_i, hi_i in ((at - 1, at), (at, at + 1)):
        ok = (lo_i >= 0) & (hi_i < len(keys))
        a, b = keys[lo_i[ok]], keys[hi_i[ok]]
        wide = b - a >= 2
        out.append((a[wide] + b[wide]) // 2)
    return np.unique(np.concatenate(out))


def _least_squares(keys: np.ndarray, t: np.ndarray, target: np.ndarray, pin_lo: bool,
                   pin_hi: bool):
    """Key values and slopes minimising the squared distance of the Hermite curve through
    ``keys`` to ``target`` at frames ``t`` (the first and last key zero and flat when
    pinned); returns values, slopes and the curve at ``t``. The normal equations are banded
    (a frame touches the 4 unknowns of its interval), solved in time linear in the frames."""
    from scipy.linalg import solveh_banded

    K = len(keys)
    if K == 1:
        return np.array([target[0]]), np.zeros(1), np.full(len(t), target[0])
    seg = np.clip(np.searchsorted(keys, t, side="right") - 1, 0, K - 2)
    h = (keys[seg + 1] - keys[seg]).astype(float)
    b0, b1, b2, b3 = hermite_basis((t - keys[seg]) / h)
    weights = np.stack([b0, b1 * h, b2, b3 * h], axis=1)  # of unknowns 2 seg .. 2 seg + 3
    n = 2 * K
    band = np.zeros((4, n))                       # upper form: band[3 + i - j, j] = N[i, j]
    for p in range(4):
        for q in range(p, 4):
            band[3 - (q - p)] += np.bincount(2 * seg + q, weights[:, p] * weights[:, q],
                                             minlength=n)
    rhs = np.zeros(n)
    for p in range(4):
        rhs += np.bincount(2 * seg + p, weights[:, p] * target, minlength=n)
    pinned = np.zeros(n, dtype=bool)
    pinned[:2] = pin_lo
    pinned[-2:] = pin_hi
    for j in np.flatnonzero(pinned):              # x[j] = 0: its row and column are identity
        for d in range(1, 4):
            if j + d < n:
                band[3 - d, j + d] = 0.0
            band[3 - d, j] = 0.0
        band[3, j] = 1.0
        rhs[j] = 0.0
    # a tiny ridge keeps keys a frame apart (more unknowns than frames) solvable
    band[3] += 1e-12
    x = solveh_banded(band, rhs)
    seg2 = 2 * seg
    fitted = (weights[:, 0] * x[seg2] + weights[:, 1] * x[seg2 + 1]
              + weights[:, 2] * x[seg2 + 2] + weights[:, 3] * x[seg2 + 3])
    return x[0::2], x[1::2], fitted


def chain_lengths(skeleton) -> np.ndarray:
    """``(J,)`` [m] per joint, the longest path of rest bones from it down to a joint or End
    Site below it (0 for a leaf): how far a turn of the joint can move something."""
    length = np.zeros(skeleton.num_joints)
    for site in skeleton.end_sites:
        length[site.parent] = max(length[site.parent], float(np.linalg.norm(site.offset)))
    for j in range(skeleton.num_joints - 1, 0, -1):
        p = skeleton.parents[j]
        length[p] = max(length[p], length[j] + float(np.linalg.norm(skeleton.offsets[j])))
    return length


@dataclass(frozen=True, eq=False)
class Layer:
    """One layer of a scene's displacement: a named map with a weight and a mute.

    Attributes:
        name: what the animator calls it.
        displacement: its curves.
        weight: its offsets are scaled by this (1: as keyed, 0: no effect).
        mute: a muted layer has no effect.
    """

    name: str = "edit"
    displacement: DisplacementMap = field(default_factory=DisplacementMap)
    weight: float = 1.0
    mute: bool = False

    def __post_init__(self):
        weight = float(self.weight)
        if not np.isfinite(weight) or not 0.0 <= weight <= 10.0:
            raise MotionComposerError(f"layer {self.name!r}: weight must be a number from 0 "
                                      f"to 10, not {self.weight!r}")
        object.__setattr__(self, "weight", weight)

    def apply(self, motion: Motion) -> Motion:
        """``motion`` with this layer added (unchanged when muted)."""
        return motion if self.mute else self.displacement.apply(motion, self.weight)

    def replace(self, **changes) -> "Layer":
        return dataclasses.replace(self, **changes)
