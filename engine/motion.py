"""Motions: a skeleton animated over frames, held as arrays (no per-frame objects)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .errors import ExportError, MotionComposerError
from .quaternions import qslerp
from .skeleton import Skeleton

__all__ = ["Motion", "parse_frame_range", "export_selection"]

#: output rates accepted by :meth:`Motion.resampled` [frames per second]
MAX_FPS = 1000.0
#: a rate ratio this close (relatively) to a whole number is that number: files write their
#: frame time rounded (CMU's 0.0083333 s is 1/120 s), so 120 fps -> 30 fps takes every 4th frame
_WHOLE_RATIO = 1e-4


@dataclass(frozen=True, eq=False)
class Motion:
    """A skeleton's animation.

    Attributes:
        skeleton: the animated skeleton.
        rotations: ``(F, J, 4)`` local joint rotations, unit quaternions x-y-z-w, each in its
            parent's frame (the root's in the world, internal axes).
        translations: ``(F, K, 3)`` [m] local translations of the joints listed by
            ``skeleton.translated`` (the root first). Each value *replaces* the joint's rest
            offset for that frame; joints not listed sit at their offset.
        frame_time: seconds per frame, exactly as the source gave it (119.88 fps exists).
        name: a label for display (the file's stem for a file).
    """

    skeleton: Skeleton
    rotations: np.ndarray
    translations: np.ndarray
    frame_time: float
    name: str = ""

    def __post_init__(self):
        rot = np.array(self.rotations, dtype=float, copy=True)
        tra = np.array(self.translations, dtype=float, copy=True)
        J = self.skeleton.num_joints
        K = len(self.skeleton.translated)
        if rot.ndim != 3 or rot.shape[1:] != (J, 4):
            raise MotionComposerError(f"rotations must have shape (frames, {J}, 4), "
                                      f"not {rot.shape}")
        if tra.shape != (rot.shape[0], K, 3):
            raise MotionComposerError(f"translations must have shape ({rot.shape[0]}, {K}, 3) "
                                      f"for this skeleton, not {tra.shape}")
        if not (np.isfinite(self.frame_time) and self.frame_time > 0):
            raise MotionComposerError(f"frame time must be a positive number of seconds, "
                                      f"not {self.frame_time!r}")
        norms = np.sqrt(np.einsum("...i,...i->...", rot, rot))[..., None]
        if rot.size and not (np.all(np.isfinite(rot)) and np.all(norms > 1e-9)):
            raise MotionComposerError("rotations must be finite, non-zero quaternions")
        if not np.all(np.isfinite(tra)):
            raise MotionComposerError("translations must be finite numbers")
        # renormalise only what needs it, so that unit input passes through bit for bit
        off = np.abs(norms - 1.0) > 1e-12
        if np.any(off):
            rot = np.where(off, rot / norms, rot)
        rot.setflags(write=False)
        tra.setflags(write=False)
        object.__setattr__(self, "rotations", rot)
        object.__setattr__(self, "translations", tra)
        object.__setattr__(self, "frame_time", float(self.frame_time))

    @classmethod
    def _trusted(cls, skeleton: Skeleton, rotations: np.ndarray, translations: np.ndarray,
                 frame_time: float, name: str = "") -> "Motion":
        """A motion from arrays the engine has just computed (unit quaternions, finite, the
        right shapes, owned by nobody else): no copies and no checks, for the hot paths.
        The arrays are made read-only."""
        motion = object.__new__(cls)
        rotations.setflags(write=False)
        translations.setflags(write=False)
        for key, value in (("skeleton", skeleton), ("rotations", rotations),
                           ("translations", translations), ("frame_time", float(frame_time)),
                           ("name", name)):
            object.__setattr__(motion, key, value)
        return motion

    @property
    def num_frames(self) -> int:
        return self.rotations.shape[0]

    @property
    def fps(self) -> float:
        """Frames per second, ``1 / frame_time``, never rounded."""
        return 1.0 / self.frame_time

    @property
    def duration(self) -> float:
        """Seconds from the first frame to the last."""
        return max(self.num_frames - 1, 0) * self.frame_time

    @property
    def root_positions(self) -> np.ndarray:
        """``(F, 3)`` [m] the root joint's position in the world."""
        return self.translations[:, 0]

    def local_translations(self) -> np.ndarray:
        """``(F, J, 3)`` [m] every joint's local translation (offsets where not animated)."""
        out = np.broadcast_to(self.skeleton.offsets, (self.num_frames,) +
                              self.skeleton.offsets.shape).copy()
        out[:, self.skeleton.translated] = self.translations
        return out

    def replace(self, **changes) -> "Motion":
        """A copy with some fields changed (the arrays are validated again)."""
        return dataclasses.replace(self, **changes)

    def with_position_channels(self, joints) -> "Motion":
        """This motion on :meth:`Skeleton.with_position_channels` of ``joints``: each joint
        given channels translates by its offset on every frame (the same poses)."""
        skeleton = self.skeleton.with_position_channels(joints)
        if skeleton is self.skeleton:
            return self
        local = self.local_translations()
        return Motion(skeleton, self.rotations, local[:, skeleton.translated],
                      self.frame_time, self.name)

    def frames(self, selection) -> "Motion":
        """The sub-motion at a slice or index array of frames."""
        return self.replace(rotations=self.rotations[selection],
                            translations=self.translations[selection])

    def excerpt(self, first: int | None, last: int | None) -> "Motion":
        """Frames ``first`` to ``last`` inclusive (0-based, as the timeline counts them;
        ``None``: the clip's first or last frame).

        Raises:
            ExportError: when the range is empty or reaches outside the clip.
        """
        F = self.num_frames
        first = 0 if first is None else int(first)
        last = F - 1 if last is None else int(last)
        if not (0 <= first <= last < F):
            raise ExportError(f"frames {first}:{last} lie outside the clip, which has frames "
                              f"0:{F - 1} (a range is first:last, inclusive, first <= last)")
        return self.frames(slice(first, last + 1))

    def resampled(self, fps: float) -> "Motion":
        """The motion at ``fps`` frames per second over the same span of time: rotations
        interpolated by slerp per joint, translations linearly.

        Output frame ``k`` is at ``k / fps`` seconds, i.e. at source frame ``k * r`` with
        ``r = fps_source / fps``; the last output frame is the last one not after the source's
        last frame. Where ``r`` is within 1e-4 (relatively) of a whole number ``n`` it is
        taken as ``n``, so the output is every ``n``-th source frame exactly (120 -> 30 fps).

        Raises:
            ExportError: for a rate that is not a number in (0, 1000].
        """
        try:
            fps = float(fps)
        except (TypeError, ValueError):
            raise ExportError(f"the output frame rate must be a number, not {fps!r}") from None
        if not (np.isfinite(fps) and 0 < fps <= MAX_FPS):
            raise ExportError(f"the output frame rate must be in (0, {MAX_FPS:g}] frames per "
                              f"second, not {fps!r}")
        ratio = (1.0 / fps) / self.frame_time
        if abs(ratio - round(ratio)) <= _WHOLE_RATIO * ratio:
            ratio = float(round(ratio))
        count = int(np.floor((self.num_frames - 1) / ratio + 1e-9)) + 1
        at = np.arange(count) * ratio                              # source frame of each
        lo = np.minimum(np.floor(at).astype(int), self.num_frames - 1)
        hi = np.minimum(lo + 1, self.num_frames - 1)
        u = at - lo                                                # (K,) in [0, 1)
        rot = qslerp(self.rotations[lo], self.rotations[hi], u[:, None])
        exact = u == 0.0
        rot[exact] = self.rotations[lo[exact]]
        tra = self.translations[lo] + u[:, None, None] * (self.translations[hi] -
                                                          self.translations[lo])
        return Motion(self.skeleton, rot, tra, 1.0 / fps, self.name)


def parse_frame_range(text: str) -> tuple[int | None, int | None]:
    """``"A:B"`` -> ``(A, B)``, first and last frame (0-based, inclusive); either may be left
    out (``"100:"``, ``":250"``) and is then ``None`` (the clip's first or last frame).

    Raises:
        ExportError: for anything else (the message shows the expected form).
    """
    parts = str(text).strip().split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        first, last = (int(p) if p.strip() else None for p in parts)
    except ValueError:
        raise ExportError(f"a frame range is FIRST:LAST (0-based, inclusive, e.g. 0:239 or "
                          f"120:), not {text!r}") from None
    if (first is not None and first < 0) or (last is not None and last < 0):
        raise ExportError(f"frame numbers start at 0, not {text!r}")
    return first, last


def export_selection(motion: Motion, frames: tuple[int | None, int | None] | None = None,
                     fps: float | None = None) -> Motion:
    """What an export writes: frames ``frames = (first, last)`` (inclusive, see
    :meth:`Motion.excerpt`; ``None``: all), then resampled to ``fps`` (``None``: the
    motion's own rate, untouched).

    Raises:
        ExportError: for a range outside the clip or a rate out of (0, 1000].
    """
    if frames is not None:
        motion = motion.excerpt(*frames)
    if fps is not None:
        motion = motion.resampled(fps)
    return motion
