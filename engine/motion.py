"""Motions: a skeleton animated over frames, held as arrays (no per-frame objects)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .errors import MotionComposerError
from .skeleton import Skeleton

__all__ = ["Motion"]


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

    def frames(self, selection) -> "Motion":
        """The sub-motion at a slice or index array of frames."""
        return self.replace(rotations=self.rotations[selection],
                            translations=self.translations[selection])
