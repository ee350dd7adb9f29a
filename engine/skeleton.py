"""Skeletons: joint hierarchy, rest offsets, End Sites and each joint's channel layout.

Arrays follow the internal convention of :mod:`engine.units` (metres, +Y up). Joints are
numbered so that every parent comes before its children; joint 0 is the single root.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .errors import SkeletonError
from .units import SourceFrame

__all__ = ["Skeleton", "EndSite", "ROTATION_CHANNELS", "POSITION_CHANNELS"]

ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")

#: How a joint's position channels relate to its OFFSET.
#: ``absolute``: the channels are the local position and replace the OFFSET (Bandai, most roots).
#: ``relative``: the channels are added to the OFFSET (CC3 hip-rooted exports).
POSITION_MODES = ("absolute", "relative")


def _frozen(array, dtype=float) -> np.ndarray:
    out = np.array(array, dtype=dtype, copy=True)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class EndSite:
    """A BVH End Site: a leaf point (fingertip, toe tip, head top) fixed to its parent joint.

    Attributes:
        parent: index of the joint it hangs from.
        offset: ``(3,)`` [m] in the parent's local frame.
        name: a stable name for display, ``"<parent>_end"``.
    """

    parent: int
    offset: np.ndarray
    name: str

    def __post_init__(self):
        object.__setattr__(self, "offset", _frozen(self.offset).reshape(3))


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A joint hierarchy with rest offsets and channel layouts.

    Attributes:
        names: joint names, unique.
        parents: ``(J,)`` parent index per joint, ``-1`` for the root; ``parents[j] < j``.
        offsets: ``(J, 3)`` [m] each joint's position in its parent's frame at rest (for the
            root, in the world).
        channels: per joint, the channel names in file order (``"Zrotation"``, ...). A joint's
            rotation is the product of its rotation channels in this order (R = R1 R2 R3).
        position_modes: per joint, ``"absolute"`` or ``"relative"`` where it has position
            channels, else ``None`` (see :data:`POSITION_MODES`).
        end_sites: the End Sites, with offsets in their parent's frame.
        source: the units and up axis of the file this came from, restored on export.
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    position_modes: tuple[str | None, ...] = ()
    end_sites: tuple[EndSite, ...] = ()
    source: SourceFrame = field(default_factory=SourceFrame)

    def __post_init__(self):
        names = tuple(str(n) for n in self.names)
        n = len(names)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "parents", _frozen(self.parents, dtype=np.intp).reshape(-1))
        object.__setattr__(self, "offsets", _frozen(self.offsets).reshape(-1, 3))
        object.__setattr__(self, "channels", tuple(tuple(c) for c in self.channels))
        modes = tuple(self.position_modes) or tuple(
            "absolute" if any(c in POSITION_CHANNELS for c in ch) else None
            for ch in self.channels)
        object.__setattr__(self, "position_modes", modes)
        object.__setattr__(self, "end_sites", tuple(self.end_sites))
        if n == 0:
            raise SkeletonError("a skeleton needs at least one joint")
        if not (len(self.parents) == len(self.offsets) == len(self.channels) == len(modes) == n):
            raise SkeletonError(
                f"skeleton arrays disagree: {n} names, {len(self.parents)} parents, "
                f"{len(self.offsets)} offsets, {len(self.channels)} channel lists, "
                f"{len(modes)} position modes")
        if len(set(names)) != n:
            dup = sorted({x for x in names if names.count(x) > 1})
            raise SkeletonError(f"joint names must be unique; repeated: {', '.join(dup)}")
        if self.parents[0] != -1:
            raise SkeletonError(f"joint 0 ({names[0]}) must be the root (parent -1)")
        for j in range(1, n):
            if not 0 <= self.parents[j] < j:
                raise SkeletonError(
                    f"joint {names[j]!r} has parent index {int(self.parents[j])}; parents must "
                    "come before their children and only joint 0 may be a root")
        if not np.all(np.isfinite(self.offsets)):
            raise SkeletonError("joint offsets must be finite numbers")
        for j, (ch, mode) in enumerate(zip(self.channels, modes)):
            has_pos = any(c in POSITION_CHANNELS for c in ch)
            if has_pos and mode not in POSITION_MODES:
                raise SkeletonError(f"joint {names[j]!r}: position mode must be one of "
                                    f"{POSITION_MODES}, not {mode!r}")
            if not has_pos and mode is not None:
                raise SkeletonError(f"joint {names[j]!r} has no position channels but a "
                                    f"position mode {mode!r}")
        for site in self.end_sites:
            if not 0 <= site.parent < n:
                raise SkeletonError(f"End Site {site.name!r} names joint {site.parent}, "
                                    f"which does not exist")

    # ----------------------------------------------------------------- derived, read-only
    @property
    def num_joints(self) -> int:
        return len(self.names)

    @cached_property
    def index(self) -> dict[str, int]:
        """Joint name to index."""
        return {name: j for j, name in enumerate(self.names)}

    @cached_property
    def children(self) -> tuple[tuple[int, ...], ...]:
        kids: list[list[int]] = [[] for _ in self.names]
        for j in range(1, self.num_joints):
            kids[self.parents[j]].append(j)
        return tuple(tuple(k) for k in kids)

    @cached_property
    def rotation_orders(self) -> tuple[str, ...]:
        """Per joint, its rotation channels as an intrinsic axis sequence (``"ZYX"``), or ``""``.

        The sequence is scipy's intrinsic (upper-case) convention, which is BVH's reading:
        ``Zrotation Yrotation Xrotation`` means R = Rz Ry Rx.
        """
        return tuple("".join(c[0] for c in ch if c in ROTATION_CHANNELS) for ch in self.channels)

    @cached_property
    def translated(self) -> np.ndarray:
        """Indices of joints whose local translation is animated: the root and every joint with
        position channels, in joint order. :attr:`Motion.translations` follows this order."""
        idx = [0] + [j for j in range(1, self.num_joints)
                     if any(c in POSITION_CHANNELS for c in self.channels[j])]
        return _frozen(idx, dtype=np.intp)

    @cached_property
    def subtree_sizes(self) -> np.ndarray:
        """Per joint, how many joints it carries, itself included."""
        size = np.ones(self.num_joints, dtype=np.intp)
        for j in range(self.num_joints - 1, 0, -1):
            size[self.parents[j]] += size[j]
        return _frozen(size, dtype=np.intp)

    @cached_property
    def depth(self) -> np.ndarray:
        d = np.zeros(self.num_joints, dtype=np.intp)
        for j in range(1, self.num_joints):
            d[j] = d[self.parents[j]] + 1
        return d

    def joint(self, name: str) -> int:
        """The index of joint ``name``; :class:`SkeletonError` naming close matches if absent."""
        try:
            return self.index[name]
        except KeyError:
            import difflib
            close = difflib.get_close_matches(name, self.names, n=3)
            hint = f" (did you mean {', '.join(close)}?)" if close else ""
            raise SkeletonError(f"no joint named {name!r} in this skeleton{hint}") from None

    def ancestors(self, j: int) -> list[int]:
        """Joint ``j``'s ancestors from its parent up to the root."""
        out = []
        p = int(self.parents[j])
        while p >= 0:
            out.append(p)
            p = int(self.parents[p])
        return out

    def body_top(self) -> int:
        """The topmost joint that branches (the hips, where legs and spine part, or a root
        that carries controls beside them); the root for a figure that never branches."""
        counts = np.bincount(self.parents[1:], minlength=self.num_joints)
        branching = np.flatnonzero(counts >= 2)
        return int(branching[0]) if len(branching) else 0

    def above_the_body(self) -> list[int]:
        """The joints above :meth:`body_top`: nodes that carry the body, no part of it (a
        ground root, an exporter's ``reference`` or ``Armature`` node); none for a figure
        that never branches."""
        return self.ancestors(self.body_top())

    @property
    def num_channels(self) -> int:
        return sum(len(c) for c in self.channels)

    def describe_channels(self, j: int) -> str:
        return " ".join(self.channels[j]) if self.channels[j] else "(none)"

    def with_position_channels(self, joints) -> "Skeleton":
        """This skeleton with position channels (``absolute``) put before the rotation channels
        of each of ``joints`` that has none: a joint whose translation the engine sets (a
        control joint carried with a limb) in a file that never animated it."""
        add = {int(j) for j in joints} - {int(j) for j in self.translated}
        if not add:
            return self
        channels = tuple(POSITION_CHANNELS + ch if j in add else ch
                         for j, ch in enumerate(self.channels))
        modes = tuple("absolute" if j in add else m for j, m in enumerate(self.position_modes))
        return Skeleton(self.names, self.parents, self.offsets, channels, modes,
                        self.end_sites, self.source)
