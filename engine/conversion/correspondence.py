"""Node-to-node correspondence: which performer joint drives each target joint.

A :class:`Correspondence` maps target joint names to performer joint names, one to one.
Performer joints left out are ignored; target joints left out follow their parent. It is plain
data (saved as JSON with a top-level ``"pairs"`` object, so a mapping file doubles as a preset)
and is checked against both skeletons by :meth:`Correspondence.validate`.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

from ..errors import MappingError
from ..fileio import atomic_write, read_regular_file
from ..skeleton import Skeleton

__all__ = ["Correspondence", "BY_HAND"]

FORMAT = "motion-composer-mapping"
#: the note of a pair the user set by hand (pairs without a note are taken as set by hand too;
#: any other note says how auto-mapping decided)
BY_HAND = "set by hand"


@dataclass(frozen=True)
class Correspondence:
    """Target joint name -> performer joint name.

    Attributes:
        pairs: the mapping, in target joint order when it came from :func:`automap`.
        notes: optional per-target-joint notes (how auto-mapping decided), not used for
            conversion and not required in files.
    """

    pairs: dict[str, str] = field(default_factory=dict)
    notes: dict[str, str] = field(default_factory=dict, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "pairs", {str(k): str(v) for k, v in dict(self.pairs).items()})
        object.__setattr__(self, "notes", dict(self.notes))

    def __len__(self) -> int:
        return len(self.pairs)

    def set_by_hand(self, target_joint: str) -> bool:
        """The pair of ``target_joint`` was set by the user, not by auto-mapping."""
        return self.notes.get(target_joint, BY_HAND) == BY_HAND

    def target_of(self, performer_joint: str) -> str | None:
        """The target joint that ``performer_joint`` drives, or None."""
        for t, p in self.pairs.items():
            if p == performer_joint:
                return t
        return None

    def performer_of(self, target_joint: str) -> str | None:
        return self.pairs.get(target_joint)

    def with_pair(self, target_joint: str, performer_joint: str | None) -> "Correspondence":
        """A copy with one pair set (or removed with ``None``); a performer joint used by
        another target joint is taken from it, keeping the map one to one."""
        pairs = {t: p for t, p in self.pairs.items()
                 if t != target_joint and p != performer_joint}
        if performer_joint is not None:
            pairs[target_joint] = performer_joint
        # a pair set by hand loses the note of how it was decided automatically
        notes = {k: v for k, v in self.notes.items() if k in pairs and k != target_joint}
        return Correspondence(pairs, notes)

    # ------------------------------------------------------------------ validation
    def validate(self, target: Skeleton, performer: Skeleton, *, path=None) -> None:
        """Raise :class:`MappingError` unless this map can drive ``target`` from ``performer``.

        Checks: every name exists in its skeleton; no performer joint is used twice; the
        body's root is mapped (the target's root, or a joint above every other mapped joint,
        such as the hips below an unmapped ground-level root, which then keeps its own
        placement); ancestry is kept (if target joint B descends from A, B's performer joint
        descends from A's).
        """
        for t, p in self.pairs.items():
            if t not in target.index:
                raise MappingError(_unknown("target", t, target), path)
            if p not in performer.index:
                raise MappingError(_unknown("performer", p, performer) +
                                   f" (mapped from target joint {t!r})", path)
        used: dict[str, str] = {}
        for t, p in self.pairs.items():
            if p in used:
                raise MappingError(f"target joints {used[p]!r} and {t!r} are both mapped to "
                                   f"performer joint {p!r}; each performer joint may drive one "
                                   "target joint", path)
            used[p] = t
        # one mapped joint must sit above all others (the body's root: the target's root, or
        # its hips below an unmapped ground-level root such as Bandai's joint_Root)
        tops = [t for t in self.pairs
                if _nearest_mapped_ancestor(target, target.index[t], self.pairs) is None]
        if not tops:
            raise MappingError(f"no joint is mapped; map at least the target's root "
                               f"{target.names[0]!r} (or its hips)", path)
        if len(tops) > 1:
            raise MappingError(
                f"the target's root {target.names[0]!r} is unmapped and the mapped joints "
                f"{', '.join(repr(t) for t in sorted(tops, key=target.index.get)[:4])} have no "
                "mapped ancestor in common; map the target's root or hips", path)
        top = target.index[tops[0]]
        if top != 0:
            # an unmapped root is a ground-level node above the body (Bandai's joint_Root,
            # CC3's RL_BoneRoot, an armature's root bone): the mapped top must be the body's
            # root, not one limb. It is when it carries nearly the whole skeleton, or when
            # the performer joint driving it carries nearly the whole performer: a rig whose
            # root also holds control joints beside the body (a Maya rig's foot and knee
            # controls under its Root, outside the skin) has its hips carry only two thirds
            size = _subtree_size(target, top)
            driver = performer.index[self.pairs[tops[0]]]
            if size < 0.75 * target.num_joints and \
                    _subtree_size(performer, driver) < 0.75 * performer.num_joints:
                raise MappingError(
                    f"the target's root {target.names[0]!r} is unmapped and the top mapped "
                    f"joint {tops[0]!r} carries only {size} of {target.num_joints} joints; map "
                    "the target's root or hips", path)
        for t, p in self.pairs.items():
            a = _nearest_mapped_ancestor(target, target.index[t], self.pairs)
            if a is None:
                continue
            pa = self.pairs[target.names[a]]
            if performer.index[pa] not in performer.ancestors(performer.index[p]):
                raise MappingError(
                    f"the mapping inverts ancestry: target {t!r} descends from "
                    f"{target.names[a]!r}, but performer {p!r} does not descend from {pa!r}",
                    path)

    # ------------------------------------------------------------------ files
    def to_json(self) -> str:
        data = {"format": FORMAT, "version": 1, "pairs": self.pairs}
        if self.notes:
            data["notes"] = self.notes
        return json.dumps(data, indent=2, ensure_ascii=False) + "\n"

    def save(self, path: str | os.PathLike) -> None:
        """Write the mapping as JSON, atomically."""
        atomic_write(path, self.to_json())

    @classmethod
    def from_json(cls, text: str, path=None) -> "Correspondence":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            where = f"line {exc.lineno}, column {exc.colno}"
            raise MappingError(f"not valid JSON at {where}: {exc.msg}", path) from None
        if not isinstance(data, dict) or "pairs" not in data:
            raise MappingError('expected a JSON object with a "pairs" object (target joint '
                               "name to performer joint name)", path)
        pairs = data["pairs"]
        if not isinstance(pairs, dict) or not all(
                isinstance(k, str) and isinstance(v, str) for k, v in pairs.items()):
            raise MappingError('"pairs" must map target joint names to performer joint names '
                               "(strings to strings)", path)
        notes = data.get("notes", {})
        if not isinstance(notes, dict):
            notes = {}
        return cls(pairs, {str(k): str(v) for k, v in notes.items()})

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Correspondence":
        try:
            text = read_regular_file(path).decode("utf-8")
        except FileNotFoundError:
            raise MappingError("no such mapping file", path) from None
        except OSError as exc:
            raise MappingError(f"cannot be read: {exc.strerror or exc}", path) from None
        except UnicodeDecodeError as exc:
            raise MappingError(f"not a mapping file: byte {exc.start} is not UTF-8 text",
                               path) from None
        return cls.from_json(text, path)


def _unknown(side: str, name: str, skeleton: Skeleton) -> str:
    import difflib
    close = difflib.get_close_matches(name, skeleton.names, n=3)
    hint = f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""
    return f"{name!r} is not a joint of the {side} skeleton{hint}"


def _subtree_size(skeleton: Skeleton, j: int) -> int:
    return 1 + sum(1 for k in range(j + 1, skeleton.num_joints) if j in skeleton.ancestors(k))


def _nearest_mapped_ancestor(skeleton: Skeleton, j: int, pairs) -> int | None:
    for a in skeleton.ancestors(j):
        if skeleton.names[a] in pairs:
            return a
    return None
