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

from dataclasses import dataclass, field

import numpy as np

from ..errors import MotionComposerError
from ..motion import Motion
from ..quaternions import qmul

__all__ = ["Curve", "DisplacementMap", "reduce_keys", "INTERPOLATIONS", "ROOT"]

INTERPOLATIONS = ("linear", "smooth", "constant")
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
    """

    frames: np.ndarray
    values: np.ndarray
    interpolation: tuple[str, ...] = ()

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
        interp = tuple(self.interpolation) or ("linear",) * len(f)
        if len(interp) != len(f):
            raise MotionComposerError(f"a curve needs one interpolation per key ({len(f)} "
                                      f"keys, {len(interp)} interpolations)")
        for kind in interp:
            if kind not in INTERPOLATIONS:
                raise MotionComposerError(f"interpolation must be one of {INTERPOLATIONS}, "
                                          f"not {kind!r}")
        f.setflags(write=False)
        v.setflags(write=False)
        object.__setattr__(self, "frames", f)
        object.__setattr__(self, "values", v)
        object.__setattr__(self, "interpolation", interp)

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
            m = self._tangents()
            h = t1 - t0
            u2, u3 = u * u, u * u * u
            hermite = ((2 * u3 - 3 * u2 + 1) * v0 + (u3 - 2 * u2 + u) * h * m[seg]
                       + (-2 * u3 + 3 * u2) * v1 + (u3 - u2) * h * m[seg + 1])
            out = np.where(smooth, hermite, out)
        return out

    def _tangents(self) -> np.ndarray:
        """Catmull-Rom slopes (value per frame), zero at extrema and at the ends' flat sides."""
        f, v = self.frames, self.values
        m = np.zeros(len(f))
        if len(f) > 2:
            m[1:-1] = (v[2:] - v[:-2]) / (f[2:] - f[:-2])
            left = v[1:-1] - v[:-2]
            right = v[2:] - v[1:-1]
            m[1:-1] = np.where(left * right <= 0, 0.0, m[1:-1])      # extremum or flat: 0
        return m

    def with_keys(self, frames, values, interpolation=None) -> "Curve":
        return Curve(frames, values, interpolation or ())

    def to_dict(self) -> dict:
        return {"frames": self.frames.tolist(), "values": self.values.tolist(),
                "interpolation": list(self.interpolation)}

    @classmethod
    def from_dict(cls, data: dict) -> "Curve":
        return cls(data["frames"], data["values"], tuple(data.get("interpolation", ())))


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

    def apply(self, motion: Motion) -> Motion:
        """``motion`` with the offsets added (the input is not changed)."""
        if not self.curves:
            return motion
        rot, tra = self.offsets(motion.skeleton, motion.num_frames)
        moved = np.flatnonzero(np.any(rot != 0, axis=(0, 2)))
        rotations = motion.rotations.copy()
        if len(moved):
            from scipy.spatial.transform import Rotation
            exp = Rotation.from_rotvec(rot[:, moved].reshape(-1, 3)).as_quat()
            rotations[:, moved] = qmul(exp.reshape(len(rot), len(moved), 4),
                                       rotations[:, moved])
        translations = motion.translations.copy()
        translations[:, 0] += tra
        return motion.replace(rotations=rotations, translations=translations)

    @classmethod
    def from_dense(cls, skeleton, rotvecs: np.ndarray, root: np.ndarray, *,
                   rotation_tolerance: float = np.radians(0.05),
                   translation_tolerance: float = 2e-4) -> "DisplacementMap":
        """Keys for dense offsets ``rotvecs (F, J, 3)`` [rad] and ``root (F, 3)`` [m], reduced
        within the tolerances; channels that stay zero get no curve."""
        curves = {}
        for j in range(skeleton.num_joints):
            for c, channel in enumerate(ROTATION_CHANNELS):
                signal = rotvecs[:, j, c]
                if np.any(np.abs(signal) > rotation_tolerance * 1e-3):
                    curves[(skeleton.names[j], channel)] = reduce_keys(signal,
                                                                       rotation_tolerance)
        for c, channel in enumerate(TRANSLATION_CHANNELS):
            signal = root[:, c]
            if np.any(np.abs(signal) > translation_tolerance * 1e-3):
                curves[(ROOT, channel)] = reduce_keys(signal, translation_tolerance)
        return cls(curves)

    def to_dict(self) -> dict:
        return {"channels": [{"joint": j, "channel": c, **curve.to_dict()}
                             for (j, c), curve in self.curves.items()]}

    @classmethod
    def from_dict(cls, data: dict) -> "DisplacementMap":
        return cls({(item["joint"], item["channel"]): Curve.from_dict(item)
                    for item in data.get("channels", [])})


def reduce_keys(signal: np.ndarray, tolerance: float, *, smooth: bool = True) -> Curve:
    """Few keys whose curve stays within ``tolerance`` of a per-frame ``signal`` at every
    frame.

    With ``smooth`` (the default) the keys are ``smooth`` (Catmull-Rom, flattened at extrema
    and between equal keys, so a run of zeros stays exactly zero) and are added one at a time
    where the curve is furthest from the signal; otherwise linear keys by Ramer-Douglas-
    Peucker. Smooth keys need several times fewer keys for the same tolerance on motion
    curves, and they are what the curve editor shows.
    """
    y = np.asarray(signal, dtype=float)
    n = len(y)
    if n == 0:
        return Curve([], [])
    if n == 1:
        return Curve([0.0], [y[0]])
    x = np.arange(n, dtype=float)
    if smooth:
        keys = {0, n - 1}
        # start from the signal's turning points and the edges of flat runs: they are keys
        # in any good fit, and seeding them saves many rounds
        d = np.diff(y)
        turn = np.flatnonzero((d[:-1] * d[1:] <= 0) & ((d[:-1] != 0) | (d[1:] != 0))) + 1
        keys.update(turn.tolist())
        while True:
            idx = np.array(sorted(keys))
            curve = Curve(idx.astype(float), y[idx], ("smooth",) * len(idx))
            err = np.abs(curve.evaluate(x) - y)
            worst = int(np.argmax(err))
            if err[worst] <= tolerance:
                return curve
            # split every segment whose error is over the tolerance at its worst frame
            seg = np.searchsorted(idx, x, side="right") - 1
            over = err > tolerance
            add = []
            for s_ in np.unique(seg[over]):
                m = np.flatnonzero((seg == s_) & over)
                add.append(int(m[np.argmax(err[m])]))
            keys.update(add)
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
