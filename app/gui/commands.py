"""Every edit is an undoable command holding the values before and after (glue's rule).

Widgets call the ``push_*`` helpers; nothing else changes the document.
"""
from __future__ import annotations

from app.gui.qt import QtGui
from engine.conversion.correspondence import Correspondence
from engine.conversion import BindOptions
from engine.conversion import RootOptions

__all__ = ["push_sources", "push_correspondence", "push_pair", "push_options",
           "push_constraints", "push_displacement"]


class _Swap(QtGui.QUndoCommand):
    """Set a document value through ``apply(value)``; undo sets the old one back."""

    def __init__(self, text: str, apply, before, after, merge_id: int = -1):
        super().__init__(text)
        self._apply, self.before, self.after, self._merge_id = apply, before, after, merge_id

    def redo(self):
        self._apply(self.after)

    def undo(self):
        self._apply(self.before)

    def id(self) -> int:            # noqa: A003 - Qt's name
        return self._merge_id

    def mergeWith(self, other) -> bool:
        # consecutive edits of one spin box become one step, named after the latest value
        if other.id() != self.id() or self._merge_id < 0:
            return False
        self.after = other.after
        self.setText(other.text())
        self.setObsolete(self.after == self.before)      # back where it started: no step
        return True


def push_sources(doc, performer=None, performer_path=None, target=None, target_path=None,
                 text: str = "Import") -> None:
    before = (doc.performer, doc.performer_path, doc.target, doc.target_path)
    after = (performer if performer is not None else doc.performer,
             performer_path if performer is not None else doc.performer_path,
             target if target is not None else doc.target,
             target_path if target is not None else doc.target_path)
    doc.undo_stack.push(_Swap(text, lambda v: doc._set_sources(*v), before, after))


def push_correspondence(doc, correspondence: Correspondence, text: str) -> None:
    doc.undo_stack.push(_Swap(text, doc._set_correspondence, doc.correspondence,
                              correspondence))


def push_pair(doc, target_joint: str, performer_joint: str | None) -> None:
    """Map one target joint (or unmap it with None)."""
    new = doc.correspondence.with_pair(target_joint, performer_joint)
    text = (f"Map {target_joint} to {performer_joint}" if performer_joint
            else f"Unmap {target_joint}")
    push_correspondence(doc, new, text)


_MERGE_IDS: dict[str, int] = {}


def merge_id(key: str) -> int:
    """A stable merge id for edits of one control (``key`` names it, e.g. "root scale")."""
    return _MERGE_IDS.setdefault(key, 1000 + len(_MERGE_IDS))


def push_options(doc, bind_options: BindOptions | None = None,
                 root_options: RootOptions | None = None, text: str = "Change binding",
                 merge: bool | str = False) -> None:
    """Set binding and root options. ``merge``: a key naming the control (or True for a
    generic one); consecutive pushes with the same key become one undo step."""
    before = (doc.bind_options, doc.root_options)
    after = (bind_options or doc.bind_options, root_options or doc.root_options)
    if after == before:
        return
    key = merge if isinstance(merge, str) else ("options" if merge else None)
    doc.undo_stack.push(_Swap(text, lambda v: doc._set_options(*v), before, after,
                              merge_id(key) if key else -1))


def push_constraints(doc, constraints: list, displacement=None, text: str = "Edit constraints"
                     ) -> None:
    before = (list(doc.constraints), doc.displacement)
    after = (list(constraints), displacement if displacement is not None else doc.displacement)
    doc.undo_stack.push(_Swap(text, lambda v: doc._set_constraints(*v), before, after))


def push_displacement(doc, displacement, text: str = "Edit curves") -> None:
    doc.undo_stack.push(_Swap(text, doc._set_displacement, doc.displacement, displacement))
