"""FBX 6.x ASCII trees in the FBX 7 layout, so that one scene reader reads both.

FBX 6 names objects instead of numbering them and spells properties differently; this module
rewrites what the scene reader uses (checked on ``maya_character_6100_ascii.fbx``, the same
Maya rig as ``maya_character_7500_binary.fbx``):

* ``Objects/Model: "Model::Hips", "LimbNode"`` becomes ``Model: <id>, "Hips\\x00\\x01Model",
  "LimbNode"`` with an id numbered here (1, 2, ...); ``Model::Scene`` is the scene root (0);
* ``Properties60/Property: name, type, flags, values...`` becomes ``Properties70/P: name,
  type, "", flags, values...``;
* ``Objects/GlobalSettings`` moves to the top level, as FBX 7 keeps it;
* ``Connections/Connect: "OO", "Model::A", "Model::B"`` becomes ``C: "OO", id(A), id(B)``.

What FBX 6 keeps elsewhere is not read, with a note: meshes (their geometry inside their
``Model``), skin deformers and bind poses, and the animation (``Takes`` with per-model
channels). A file with those is better re-exported as FBX 7.
"""
from __future__ import annotations

import numpy as np

from .nodes import Node

__all__ = ["from_fbx6"]

_SCENE = "Model::Scene"
_NOT_READ = ("Deformer", "Pose", "Geometry")


def _properties(block: Node | None) -> Node:
    """``Properties60`` as ``Properties70``."""
    out = Node("Properties70", [], [], block.offset if block is not None else None)
    for p in block.find_all("Property") if block is not None else ():
        if len(p.props) >= 3 and isinstance(p.props[0], str):
            out.children.append(Node("P", [p.props[0], p.props[1], "", *p.props[2:]], [],
                                      p.offset))
    return out


def from_fbx6(root: Node) -> tuple[Node, list[str]]:
    """The FBX 7 layout of an FBX 6 tree (see the module notes) and notes on what was left
    out."""
    objects = root.find("Objects")
    ids: dict[str, int] = {_SCENE: 0}
    models, settings, skipped = [], None, []
    for node in objects.children if objects is not None else ():
        if node.name == "GlobalSettings":
            settings = Node("GlobalSettings", [], [_properties(node.find("Properties60"))],
                            node.offset)
            continue
        if node.name != "Model" or not node.props or not isinstance(node.props[0], str):
            if node.name in _NOT_READ:
                skipped.append(node.name)
            continue
        full = node.props[0]
        cls, _, name = full.partition("::")
        sub = node.props[1] if len(node.props) > 1 and isinstance(node.props[1], str) else ""
        if sub == "Mesh" or node.find("Vertices") is not None:
            skipped.append("Mesh")
        oid = ids.setdefault(full, len(ids))
        children = [_properties(node.find("Properties60"))]
        models.append(Node("Model", [oid, f"{name}\x00\x01{cls or 'Model'}", sub], children,
                           node.offset))
    connections = Node("Connections", [], [])
    block = root.find("Connections")
    for c in block.find_all("Connect") if block is not None else ():
        if len(c.props) >= 3 and c.props[0] == "OO" and c.props[1] in ids and \
                c.props[2] in ids:
            connections.children.append(Node("C", ["OO", ids[c.props[1]], ids[c.props[2]]],
                                              [], c.offset))
    notes = []
    if skipped:
        kinds = ", ".join(sorted(set(skipped)))
        notes.append(f"FBX 6: the file's {kinds} objects are not read (re-export as FBX 7 "
                     "for meshes, skins and bind poses)")
    takes = root.find("Takes")
    animated = [t for t in (takes.find_all("Take") if takes is not None else ())
                if any(child.name == "Model" for child in t.children)]
    if animated:
        notes.append(f"FBX 6: the animation of {len(animated)} take(s) is not read (re-export "
                     "as FBX 7 for it)")
    tree = Node("FBX", [np.int32(int(root.props[0]))],
                [n for n in (settings,) if n is not None] +
                [Node("Objects", [], models, objects.offset if objects is not None else None),
                 connections], root.offset)
    return tree, notes
