"""Every edit is an undoable command holding the scenes before and after (glue's rule).

Widgets call :meth:`app.gui.document.Document.edit` (or the ``push_*`` helpers here); a command
swaps one :class:`~engine.scene.Scene` for another, and nothing else changes the document.
"""
from __future__ import annotations

from pathlib import Path

from motion_composer.app.gui.qt import QtGui
from motion_composer.engine.conversion.correspondence import Correspondence
from motion_composer.engine.correction.constraints import Constraint

__all__ = ["push_scene", "replace_scene", "push_sources", "push_correspondence", "push_pair", "push_options",
           "push_constraints", "push_displacement", "push_layer_keys", "push_layers",
           "layer_map", "merge_id"]

_MERGE_IDS: dict[str, int] = {}


def merge_id(key: str) -> int:
    """A stable merge id for edits of one control (``key`` names it, e.g. "root scale")."""
    return _MERGE_IDS.setdefault(key, 1000 + len(_MERGE_IDS))


class SceneCommand(QtGui.QUndoCommand):
    """Make ``after`` the document's scene; undo makes ``before`` it again."""

    def __init__(self, doc, text: str, before, after, merge: str | None = None,
                 fields: tuple = (), regenerate: bool = False):
        super().__init__(text)
        self.doc, self.before, self.after = doc, before, after
        self.fields = fields
        # the solve makes the automatic constraints again: they are not part of the edit
        self.regenerate = regenerate
        self._merge_id = merge_id(merge) if merge else -1

    def redo(self):
        self.doc._apply(self.after)

    def undo(self):
        self.doc._apply(self.before)

    def id(self) -> int:            # noqa: A003 - Qt's name
        return self._merge_id

    def mergeWith(self, other) -> bool:
        # consecutive edits of one control become one step, named after the latest value
        if other.id() != self.id() or self._merge_id < 0:
            return False
        self.after = other.after
        self.setText(other.text())
        same = all(_same(getattr(self.before.project, f), getattr(self.after.project, f),
                         self.regenerate) for f in self.fields)
        self.setObsolete(same and bool(self.fields))   # back where it started: no step
        return True


def _same(a, b, regenerate: bool = False) -> bool:
    """Whether a project field is back to its value: constraints by :meth:`Constraint.same_as`
    (a goal moved by a floor change and back is a few ulps off), leaving out the automatic
    ones where the solve makes them again (``regenerate``); anything else by ``==``."""
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)) and any(
            isinstance(c, Constraint) for c in [*a, *b]):
        if regenerate:
            a, b = ([c for c in x if not c.auto] for x in (a, b))
        return len(a) == len(b) and all(x.same_as(y) for x, y in zip(a, b))
    return bool(a == b)


def push_scene(doc, text: str, before, after, merge: str | None = None,
               fields: tuple = (), regenerate: bool = False) -> None:
    doc.undo_stack.push(SceneCommand(doc, text, before, after, merge, fields, regenerate))


def replace_scene(doc, old, new) -> None:
    """Put ``new`` wherever the history holds ``old`` (a solve landed for it)."""
    stack = doc.undo_stack
    for i in range(stack.count()):
        command = stack.command(i)
        if isinstance(command, SceneCommand):
            if command.after is old:
                command.after = new
            if command.before is old:
                command.before = new


def push_sources(doc, performer=None, performer_path=None, target=None, target_path=None,
                 text: str = "Import") -> None:
    """Set the performer and/or the target as one command, keeping the map as it is (the
    window's import re-maps: :meth:`app.gui.document.Document.set_source`)."""
    from motion_composer.engine.project import Source
    before = after = doc.scene
    for role, motion, path in (("performer", performer, performer_path),
                               ("target", target, target_path)):
        if motion is not None:
            source = Source(path=str(Path(path).resolve()) if path is not None else None)
            after = after.with_source(role, motion, source, remap_pairs=False)
    push_scene(doc, text, before, after)


def push_correspondence(doc, correspondence: Correspondence, text: str) -> None:
    doc.edit(text, correspondence=correspondence)


def push_pair(doc, target_joint: str, performer_joint: str | None) -> None:
    """Map one target joint (or unmap it with None)."""
    new = doc.scene.correspondence.with_pair(target_joint, performer_joint)
    text = (f"Map {target_joint} to {performer_joint}" if performer_joint
            else f"Unmap {target_joint}")
    push_correspondence(doc, new, text)


def push_options(doc, bind_options=None, root_options=None, text: str = "Change binding",
                 merge: bool | str = False, solve: bool = False) -> None:
    """Set binding and root options. ``merge``: a key naming the control (or True for a
    generic one); consecutive pushes with the same key become one undo step. ``solve``: the
    new scene's correction is solved in the background (a chain's IK blend, whose reach
    goals only a solve meets)."""
    changes = {}
    if bind_options is not None:
        changes["bind_options"] = bind_options
    if root_options is not None:
        changes["root"] = root_options
    key = merge if isinstance(merge, str) else ("options" if merge else None)
    if solve and all(getattr(doc.scene.project, k) == v for k, v in changes.items()):
        return                                  # nothing changes: no step, no solve
    doc.edit(text, merge=key, solve=solve, **changes)


def push_constraints(doc, constraints: list, displacement=None, text: str = "Edit constraints",
                     solve: bool = False) -> None:
    changes = {"constraints": tuple(constraints)}
    if displacement is not None:
        changes["displacement"] = displacement
    doc.edit(text, solve=solve, **changes)


def push_displacement(doc, displacement, text: str = "Edit curves") -> None:
    doc.edit(text, displacement=displacement)


def layer_map(scene, layer: int):
    """The displacement map of layer ``layer`` of ``scene``: 0 is the solved layer, 1 and up
    the animator's layers in order."""
    return scene.displacement if layer == 0 else scene.layers[layer - 1].displacement


def push_layer_keys(doc, layer: int, displacement, text: str = "Edit curves") -> None:
    """Set the keys of one layer (0: the solved layer, see :func:`layer_map`), one command."""
    if layer == 0:
        push_displacement(doc, displacement, text)
        return
    layers = list(doc.scene.layers)
    layers[layer - 1] = layers[layer - 1].replace(displacement=displacement)
    doc.edit(text, layers=tuple(layers))


def push_layers(doc, layers, text: str, merge: str | None = None) -> None:
    """Set the animator's layers (a weight, a mute, a new layer), one command; ``merge``
    joins consecutive edits of one control (a weight being typed) into one step."""
    doc.edit(text, merge=merge, layers=tuple(layers))
